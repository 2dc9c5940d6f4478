"""A record whose loops are smaller than its range (issue 11: models that fit any stage).

A multisine, a random walk or strokes around a working point never close a loop as large as
their range. A P-I operator whose threshold lies between half the largest loop and half the range
is then never reversed by the record (its weight is set by nothing but the way from rest), yet a
cycle over the whole range reverses it. Measured before this rule (fit on a 0-10 V four-tone
multisine of the zoo's stages, predicting a 0-10 V 3 Hz sinusoid, RMS % of span): dead zone +
play + saturation 19.5 %, asymmetric Maxwell-slip 3.4 %, falling after reversal 4.6 %; with it
2.4 %, 0.09 %, 0.19 %.
"""

import json
import warnings

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import piezohyst as ph
from piezohyst.identify.linear import loop_thresholds
from piezohyst.identify.result import ExtrapolationWarning
from piezohyst.models.play import largest_loop_threshold, play_moves_both_ways
from tests.plants.zoo import zoo


def multisine(lo, hi, dt, seconds=3.0, seed=1):
    """Four tones (0.7, 1.9, 4.3, 9.1 Hz) of random phase, scaled onto ``lo..hi``."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds / dt)) * dt
    x = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f in (0.7, 1.9, 4.3, 9.1))
    return lo + (hi - lo) * (x - x.min()) / np.ptp(x)


turning_points = st.lists(st.floats(-100.0, 100.0, allow_nan=False), min_size=2, max_size=12)


@settings(max_examples=150, deadline=None)
@given(points=turning_points)
# found by a random run: a subnormal start (the play rises from 0 to it, then falls) gives the
# smallest subnormal threshold, and r * (1 - 1e-9) rounded back to r itself
@example(points=[5e-324, -1.0])
def test_largest_loop_threshold_is_the_largest_operator_the_input_reverses(points):
    v = np.interp(np.linspace(0, len(points) - 1, 40 * len(points)), np.arange(len(points)), points)
    r = largest_loop_threshold(v)
    half = 0.5 * float(np.ptp(v))
    assert 0.0 <= r <= half
    # the supremum: an operator just below it moves both ways, none at or above it does
    assert not play_moves_both_ways(v, r * (1 + 1e-9) + 1e-12)
    if r > 0.0:
        assert play_moves_both_ways(v, min(r * (1 - 1e-9), float(np.nextafter(r, 0.0))))
        smaller = np.linspace(0.0, r, 7)[:-1]
        for s in smaller[smaller < r]:  # and so does every smaller one (monotone in r; a subnormal r rounds some to r)
            assert play_moves_both_ways(v, s)
    else:
        assert not play_moves_both_ways(v, 1e-9 * max(half, 1.0))


def test_the_largest_loop_spans_an_interrupted_leg():
    # 10 -> 6 -> 7 -> 1: the 10 -> 1 leg (9 V, interrupted by a 1 V loop) reverses operators up to 4.5 V
    assert largest_loop_threshold(np.array([0.0, 10.0, 6.0, 7.0, 1.0])) == 4.5
    assert largest_loop_threshold(np.array([0.0, 1.0, 2.0])) == 0.0  # never reverses


def test_thresholds_of_a_full_range_record_are_left_as_they_are():
    t = np.arange(4000) * 1e-3
    u = 50.0 - 50.0 * np.cos(2 * np.pi * t)  # 0..100 V, full loops
    for r in (ph.equal_thresholds(20, 100.0), np.arange(40) / 40 * 50.0):
        got, cap = loop_thresholds(r, u)
        assert cap is None and np.array_equal(got, r)


def test_no_threshold_is_left_between_the_largest_loop_and_half_the_range():
    u = multisine(0.0, 10.0, 5e-4)
    half = 0.5 * float(np.ptp(u))
    for r in (ph.equal_thresholds(10, 10.0), np.arange(20) / 20 * half):
        got, cap = loop_thresholds(r, u)
        assert cap is not None and cap < half
        assert got.size == r.size and np.all(np.diff(got) > 0)
        assert not np.any((got > cap) & (got < half))
        assert np.array_equal(got[got >= half], r[r >= half])  # eq. 4's loading curve stays


@pytest.mark.parametrize("index, most", [(0, 1.0), (3, 5.0), (5, 1.0)])
def test_a_model_fitted_on_small_loops_follows_a_full_range_cycle(index, most):
    stage = zoo(seed=0)[index]
    lo, hi = stage.u_range
    train = stage.excite(multisine(lo, hi, stage.dt))
    test = stage.excite(ph.sinusoid(3.0, 3, lo, hi, stage.dt))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = ph.fit_model(train, kind="auto")
    with pytest.warns(ExtrapolationWarning, match="closes loops of up to"):  # and it is said
        e = fit.residual(test.u, test.y, stage.dt)
    rms = 100.0 * float(np.sqrt(np.mean(e[e.size // 3:] ** 2))) / float(np.ptp(test.y))
    assert rms < most, (stage.name, fit.info["chosen"], rms)
    assert any("largest loop spans" in w for w in fit.warnings), fit.warnings


def test_a_record_with_a_full_cycle_is_not_warned_about_its_loops():
    stage = zoo(seed=0)[0]
    lo, hi = stage.u_range
    u = np.concatenate([ph.sinusoid(2.0, 1, lo, hi, stage.dt), multisine(lo, hi, stage.dt)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = ph.fit_model(stage.excite(u), kind="prandtl-ishlinskii")
    assert not any("largest loop spans" in w for w in fit.warnings), fit.warnings


def test_fit_pi_says_which_operators_the_record_never_reverses():
    stage = zoo(seed=0)[3]
    lo, hi = stage.u_range
    small = stage.excite(multisine(lo, hi, stage.dt))
    fit = ph.fit_pi(small.u, small.y)  # the paper's eq. (4) thresholds, as asked
    said = [w for w in fit.warnings if "never reversed by this record" in w]
    assert len(said) == 1, fit.warnings
    cap = largest_loop_threshold(small.u)
    r = fit.model.thresholds
    assert f"threshold {r[(r > cap) & (r < 0.5 * np.ptp(small.u))].min():.4g}" in said[0]
    full = stage.excite(ph.sinusoid(1.0, 2, lo, hi, stage.dt))
    assert not any("never reversed" in w for w in ph.fit_pi(full.u, full.y).warnings)


@pytest.mark.xfail(strict=True, reason=(
    "small strokes: on the census's saturated P-I stage the commissioned feedforward over 20 % of the "
    "stroke around its middle misses by 5.58 % of that span (its noise floor 0.97 %; the inverse is exact "
    "to 1e-11, so all of it is model error), where over 10-90 % it misses by 0.38 %; the chosen 16-level "
    "Preisach model predicts 6 V sinusoids at 10-80 V of its 0-100 V to 11-32 % of their span. Tried and "
    "not kept: cycles of 10 % of the range riding across it in commission's excitation (small strokes "
    "of 14 stages: 7 better, 7 worse; the zoo's 10-90 % figures worse), log-spaced P-I thresholds "
    "(small loops worse)"))
def test_a_small_stroke_around_the_middle_is_followed_by_the_feedforward():
    from tests.plants.census import census
    from tests.test_zoo import steady_range

    stage = [s for s in census(seed=0) if s.name.startswith("saturated P-I")][0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ctl = ph.commission(stage)
        a, b = steady_range(stage)
        mid, w = 0.5 * (a + b), 0.1 * (b - a)
        out = ctl.track(ph.sinusoid(1.0, 3, mid - w, mid + w, stage.dt), feedback=False, learning=False)
    assert out.e_max_percent < 2.0, out.e_max_percent


def test_a_record_that_never_reverses_keeps_its_thresholds():
    # a rise alone (or one whose reversals are noise) shows no loop to spread the thresholds over:
    # they stay as the rule gives them (the bench's compile workload once fitted such a record, and
    # every threshold had collapsed onto zero)
    rise = np.linspace(0.0, 100.0, 500)
    wiggle = rise + 0.01 * np.sin(np.arange(500))
    r = np.arange(20) / 20 * 50.0
    for u in (rise, wiggle):
        got, cap = loop_thresholds(r, u)
        assert cap is None and np.array_equal(got, r)
    rig = ph.VirtualRig()
    ds = rig.excite(ph.sinusoid(1.0, 0.2, 0.0, 100.0, rig.dt))  # a fifth of a cycle: rising only
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = ph.identify.fit_rate_pi(ds.u, ds.y, rig.dt, delay=0)
        assert np.all(np.diff(fit.model.static.thresholds) > 0)
        fit = ph.fit_model(ds, kind="prandtl-ishlinskii", delay=0)
    assert any("never reverses" in w for w in fit.warnings), fit.warnings


def riding(lo, hi, dt, frac=0.2, cycles=12, f=4.0):
    """Cycles of ``frac`` of the range whose centre moves from the bottom to the top: small loops only."""
    t = np.arange(int(round(cycles / f / dt))) * dt
    a = 0.5 * frac * (hi - lo)
    centre = lo + a + (hi - lo - 2 * a) * t / t[-1]
    return centre - a * np.cos(2 * np.pi * f * t)


def test_predicting_larger_loops_than_the_record_held_is_said(tmp_path, capsys):
    from piezohyst.cli import main

    stage = zoo(seed=0)[0]
    lo, hi = stage.u_range
    small = stage.excite(riding(lo, hi, stage.dt))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = ph.fit_model(small, kind="prandtl-ishlinskii")
    assert fit.largest_loop == pytest.approx(2 * largest_loop_threshold(small.u[: fit.n_samples + fit.delay]))
    assert fit.largest_loop < 0.5 * (hi - lo) and fit.summary()["largest_loop_V"] == fit.largest_loop
    full = ph.sinusoid(1.0, 2, lo, lo + 0.9 * (hi - lo), stage.dt)  # within the identified range
    with pytest.warns(ExtrapolationWarning, match="closes loops of up to"):
        fit.predict(full, stage.dt)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # its own kind of input: nothing to say
        fit.predict(riding(lo, hi, stage.dt, frac=0.18, f=3.0), stage.dt)
    # the model file keeps it, and a command table that needs larger loops says so
    rec = tmp_path / "small.csv"
    np.savetxt(rec, np.column_stack([small.t, small.u, small.y]), delimiter=",", header="t,u,y", comments="")
    assert main(["identify", str(rec), "--model", "pi", "-o", str(tmp_path / "m.json")]) == 0
    doc = json.loads((tmp_path / "m.json").read_text())
    assert doc["fit"]["largest_loop_V"] < 0.5 * (hi - lo)
    capsys.readouterr()
    ref = tmp_path / "ref.csv"
    y_lo, y_hi = float(np.percentile(small.y, 10)), float(np.percentile(small.y, 90))
    t = np.arange(int(1 / stage.dt)) * stage.dt
    np.savetxt(ref, np.column_stack([t, 0.5 * (y_lo + y_hi) - 0.5 * (y_hi - y_lo) * np.cos(2 * np.pi * t)]),
               delimiter=",", header="t,x", comments="")
    code = main(["compensate", "--model", str(tmp_path / "m.json"), "--reference", str(ref), "--u-min", str(lo),
                 "--u-max", str(hi), "--clip", "-o", str(tmp_path / "cmd.csv"), "--json"])
    assert code == 0
    said = capsys.readouterr()
    assert any("closes loops of up to" in w for w in json.loads(said.out)["warnings"])
    assert "warning: the command closes loops of up to" in said.err
