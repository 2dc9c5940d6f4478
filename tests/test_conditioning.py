"""The conditioning sweep that can start a commissioned run (commissioning module docstring, step 3).

A real stage's ``reset()`` only returns the command to rest: its hysteresis keeps the memory of
what it did before. The sweep (rest, top of the range, bottom, rest) wipes that memory out, and the
feedforward follows it through the model, so a run's result does not depend on the stage's past;
the identification starts with it too, and the fit runs through it without fitting it.
"""

import warnings

import numpy as np
import pytest

import piezohyst as ph

from .plants.zoo import zoo


class KeepsMemory:
    """A zoo stage whose ``reset()`` leaves its hysteresis element as it is, as hardware does
    (the amplifier, creep, mechanics, delay line and the noise generator are reset)."""

    def __init__(self, stage):
        self.stage = stage
        self.dt = stage.dt
        self.u_range = stage.u_range

    def reset(self) -> None:
        el = self.stage.element
        kept = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in vars(el).items()}
        self.stage.reset()
        vars(el).update(kept)

    def step(self, u: float) -> float:
        return self.stage.step(u)

    def drive(self, volts) -> None:
        """Some earlier use of the stage, ending at rest."""
        for v in volts:
            self.stage.step(float(v))


@pytest.fixture(scope="module")
def memory_stage():
    # bipolar, rest (0 V) mid-range: where the stage was last, above rest or below, stays in its
    # memory when it returns to rest (a unipolar stage resting at the bottom of its range forgets
    # everything but its virgin state on the way down). Relays: a full sweep wipes them exactly.
    stage = next(s for s in zoo(seed=0) if s.name.startswith("relay Preisach"))
    plant = KeepsMemory(stage)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(plant, tune=False, conditioning=True)
    return plant, ctl


def _after(plant, ctl, where, **kw):
    """A run of the feedforward after the stage went to ``where`` (a fraction of its range) and back to rest."""
    lo, hi = plant.u_range
    n = int(0.2 / plant.dt)
    rest = min(max(0.0, lo), hi)
    leg = rest + (lo + (hi - lo) * where - rest) * 0.5 * (1 - np.cos(np.pi * np.arange(1, n + 1) / n))
    plant.drive(np.concatenate([leg, leg[::-1]]))
    span = float(np.ptp(ctl.identification.y))
    mid = float(np.mean(ctl.identification.y))
    ref = ph.sinusoid(5.0, 2, mid - 0.2 * span, mid + 0.2 * span, plant.dt)
    return ctl.track(ref, feedback=False, learning=False, **kw)


def test_a_run_does_not_depend_on_what_the_stage_did_before(memory_stage):
    plant, ctl = memory_stage
    a = _after(plant, ctl, 0.95)
    b = _after(plant, ctl, 0.05)
    # same commands, same noise (reset reseeds it), the memory wiped out by the sweep: the same run
    np.testing.assert_array_equal(a.command, b.command)
    assert np.max(np.abs(a.output - b.output)) <= 1e-9 * np.ptp(a.reference)
    assert a.info["lead_in_samples"] >= ctl.conditioning_command().size


def test_without_the_sweep_a_run_from_mid_range_goes_down_to_the_bottom_first(memory_stage):
    # (before every run's lead-in did, this run showed the past: the stage's memory of being near
    # the top or near the bottom before) from a rest above the bottom of the range every run's
    # lead-in goes down to the bottom first, which wipes relays out as the full sweep does
    plant, ctl = memory_stage
    a = _after(plant, ctl, 0.95, conditioning=False)
    b = _after(plant, ctl, 0.05, conditioning=False)
    assert np.max(np.abs(a.output - b.output)) <= 1e-9 * np.ptp(a.reference)
    assert a.info["lead_in_samples"] < ctl.conditioning_command().size


def test_the_identification_starts_with_the_sweep_and_does_not_fit_it(memory_stage):
    plant, ctl = memory_stage
    v = ctl.conditioning_command()
    assert ctl.fit.info["warmup"] >= v.size
    np.testing.assert_array_equal(ctl.identification.u[: v.size], v)


def test_the_sweep_covers_the_range_inside_the_step_limit(memory_stage):
    plant, ctl = memory_stage
    lim = ctl._limits()
    v = ctl.conditioning_command()
    assert v[0] == lim.rest and v[-1] == lim.low
    assert v.max() == lim.high and v.min() == lim.low
    assert np.abs(np.diff(v)).max() <= lim.max_step
    # each leg lasts at least CONDITIONING_LEG_S
    assert v.size >= 2 * ctl.CONDITIONING_LEG_S / plant.dt


@pytest.mark.slow
def test_a_conditioned_controller_run_without_the_sweep_from_the_bottom_says_what_it_assumes():
    """docs/tutorial.md ran ``ctl.track(ref, feedback=False, conditioning=False)`` on the
    VirtualRig, whose reset() restores the de-energised state: the model (identified after the
    sweep) started off by its remanence, 47 % e_max, and only a clipping warning said anything."""
    plant = ph.VirtualRig(seed=0)
    ctl = ph.commission(plant, conditioning=True)
    ref = ph.sinusoid(2.0, 2, 0.3, 2.0, plant.dt)
    with pytest.warns(UserWarning, match="identified after the conditioning sweep"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ph.ClippingWarning)
            ctl.track(ref, feedback=False, learning=False, conditioning=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # with the sweep: nothing to say
        ctl.track(ref, feedback=False, learning=False)
    # a short, readable repr in a terminal (the dataclasses' printed 134,000 and 123,000 characters)
    assert len(repr(ctl)) < 400 and "VirtualRig" in repr(ctl)
    assert len(repr(ctl.fit)) < 600 and repr(ctl.fit).startswith("FitResult(")
