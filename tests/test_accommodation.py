"""A stage without return-point memory (issue 11: stages of structures the models do not share).

Every model kind here closes its minor loops where they started (Preisach, P-I) or lets them
drift by its own law (the generalized Duhem model). The Jiles-Atherton structure
(:class:`tests.plants.census.JilesAthertonLike`) does neither: cycled between two inputs inside
its range, its loop climbs from cycle to cycle. The stage was written after every default and
nothing is tuned on it; its figures were first measured with the test below: feedforward alone
1.30 / 1.25 / 1.30 % e_max at 1 / 3 / 5 Hz, with feedback and learning 0.19 / 0.24 / 0.31 %.

Where the irreversible part relaxes more slowly (``k`` = 0.36-0.40 of the range rather than
0.2), the climb from cycle to cycle reaches 4-6 % of the span. Behind a slow amplifier (1.5-2 ms)
the feedforward alone missed by 8-10 %: the P-I stages of the search chose no output lags (the
P-I misfit hid the creep), every generalized Duhem model without them was ruled out (falling
branches) or lost to a Preisach model, and the Preisach model that was chosen returns to its
turning points. The Duhem stage now also tries the lag sets itself (a stage of that kind below,
written after the change was made on a probe stage: feedforward 9.83 / 9.22 % at 1 / 5 Hz before,
1.69 / 3.46 % after; hold-out 1.46 -> 0.61 % of span). Probe stages of the same structure with
faster amplifiers still miss by 1.5-4 %: no model kind here follows the climb exactly.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import piezohyst as ph
from tests.plants.census import JilesAthertonLike, jiles_atherton_stage
from tests.plants.zoo import Stage
from tests.test_zoo import FBL_CYCLES, FBL_READ, steady_range


def test_the_stage_minor_loops_do_not_close():
    # what makes the stage what it is: cycled between 30 and 120 V, the output at the top of each
    # cycle climbs (a Preisach or P-I model returns to the same point every cycle)
    el = JilesAthertonLike(0.0, 150.0, 10.0)
    u = ph.sinusoid(1.0, 6, 30.0, 120.0, 1e-3)
    y = np.array([el.step(v) for v in u])
    tops = y.reshape(6, -1).max(axis=1)
    assert np.all(np.diff(tops) > 0), tops
    assert tops[-1] - tops[0] > 0.01 * 10.0, tops


@pytest.fixture(scope="module")
def commissioned():
    stage = jiles_atherton_stage()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(stage)
    return stage, ctl, steady_range(stage)


@pytest.mark.slow
@pytest.mark.parametrize("freq", [1.0, 3.0, 5.0])
def test_feedforward_and_the_whole_controller_follow_it(commissioned, freq):
    stage, ctl, (a, b) = commissioned
    assert ctl.fit.info["holdout"]["percent_of_span"] < 1.5, ctl.fit.info["holdout"]
    period = int(round(1.0 / (freq * stage.dt)))
    ff = ctl.track(ph.sinusoid(freq, 3, a, b, stage.dt), feedback=False, learning=False, period=period)
    assert ff.e_max_percent <= 2.0, (ctl.fit.info["chosen"], ff.e_max_percent)
    out = ctl.track(ph.sinusoid(freq, FBL_CYCLES, a, b, stage.dt), period=period)
    assert out.info["feedback"] and out.info["learning"]
    last = slice((FBL_CYCLES - FBL_READ) * period, FBL_CYCLES * period)
    e_max = 100.0 * float(np.abs(out.error[last]).max()) / (b - a)
    assert e_max <= 1.0, (ctl.fit.info["chosen"], e_max, ctl.tuning.ki)


def slow_amplifier_stage() -> Stage:
    """Jiles-Atherton-like loop relaxing over 40 % of the range (``k = 0.4``), behind a 1.5 ms
    amplifier, a Kelvin-Voigt creep element and 3 samples of delay; 10 kHz, 0..120 V, 5 um."""
    return Stage("Jiles-Atherton k 0.4 behind a 1.5 ms amplifier, 10 kHz, 0..120 V, 5 um, delay 3",
                 JilesAthertonLike(0.0, 120.0, 5.0, k=0.4, c=0.4), 1e-4, (0.0, 120.0), tau_amp=1.5e-3,
                 kv=((0.03, 0.02),), fn_hz=2500.0, zeta=0.05, noise_um=0.0025, delay_samples=3, seed=7)


@pytest.mark.slow
def test_a_slow_amplifier_does_not_hide_the_lags_a_duhem_model_needs():
    # before the Duhem stage tried the lag sets itself: a Preisach model (delay 18, no lags),
    # hold-out 1.46 % of span, feedforward alone 9.83 / 9.22 % e_max at 1 / 5 Hz
    stage = slow_amplifier_stage()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(stage)
    assert ctl.fit.info["holdout"]["percent_of_span"] < 1.0, ctl.fit.info["chosen"]
    a, b = steady_range(stage)
    for freq in (1.0, 5.0):
        period = int(round(1.0 / (freq * stage.dt)))
        ff = ctl.track(ph.sinusoid(freq, 3, a, b, stage.dt), feedback=False, learning=False, period=period)
        assert ff.e_max_percent <= 5.0, (freq, ctl.fit.info["chosen"], ff.e_max_percent)
