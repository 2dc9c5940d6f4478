"""Beyond the paper (issue #7): each means improves the figure it is for, inside one run."""

import json
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import piezohyst as ph
from piezohyst.cli import main

from .plants import PIPlant, error_below


@pytest.fixture(scope="module")
def rig_and_controller():
    rig = ph.VirtualRig(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(rig)
    return rig, ctl


def ref(freq, rig, cycles=4):
    return ph.sinusoid(freq, cycles, 0.25, 2.25, rig.dt)


def test_least_squares_beats_pso_for_feedforward(rig_and_controller):
    rig, _ = rig_and_controller
    ds = rig.excite(ph.sinusoid(1.0, 2, 0.0, 100.0, rig.dt))
    lsq = ph.fit_pi(ds.u, ds.y)
    pso = ph.fit_pi(ds.u, ds.y, method="pso", seed=0)
    r = ref(1.0, rig)
    a = ph.track(rig, r, ph.InversePIFeedforward(lsq.model))
    b = ph.track(rig, r, ph.InversePIFeedforward(pso.model))
    assert lsq.rmse < pso.rmse and a.rmse < b.rmse


def test_rate_dependent_model_beats_rate_independent_at_5hz(rig_and_controller):
    rig, ctl = rig_and_controller
    ds = ctl.identification
    plain = ph.fit_pi(ds.u, ds.y, delay=ctl.delay)
    r = ref(5.0, rig)
    a = ctl.track(r, feedback=False, learning=False)
    b = ph.track(rig, r, ph.InversePIFeedforward(plain.model))
    assert a.rmse < 0.5 * b.rmse
    assert ctl.fit.rmse < plain.rmse


def test_feedback_improves_on_feedforward(rig_and_controller):
    # in the band the integral acts in; the whole RMSE of both is the sensor's 3 nm noise floor
    # (measured 3.12 nm feedforward alone, 3.15 nm with feedback: the feedback passes some noise on)
    rig, ctl = rig_and_controller
    r = ref(3.0, rig)
    fb, ff = ctl.track(r, learning=False), ctl.track(r, feedback=False, learning=False)
    assert error_below(fb) < error_below(ff)
    assert abs(np.mean(fb.error[fb.period:])) < 0.1 * abs(np.mean(ff.error[ff.period:]))  # no offset left
    assert fb.rmse < 1.05 * ff.rmse


def test_learning_reduces_the_error_of_a_mismatched_model():
    # the rate-independent P-I model on a plant with rate dependence, no feedback: the only
    # thing that can remove the rate error is learning from one cycle to the next
    rig = ph.VirtualRig(seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(rig, tune=False)
    crude = ph.fit_rate_pi(ctl.identification.u, ctl.identification.y, rig.dt, taus=[], input_taus=[0.0], delay=0)
    ctl.fit = crude
    out = ctl.track(ref(5.0, rig, cycles=8), feedback=False, learning=True)
    rms = out.info["cycle_rms_um"]
    assert rms[-1] < 0.5 * rms[0]
    no_learning = ctl.track(ref(5.0, rig, cycles=8), feedback=False, learning=False)
    assert out.rmse < no_learning.rmse


def test_learning_is_not_cancelled_by_the_feedback():
    """The same mismatched model with integral feedback on: the learned correction shifts the
    feedback's reference too. Added to the feedforward's input alone, it was a disturbance the
    feedback cancelled below its bandwidth (the response of the output to it, P F / (1 + L)):
    the cycle RMS stayed at 5.0-5.1 nm over eight cycles (seeds 1-3: 0.92-0.98 of the second
    cycle's); now 3.8-3.9 nm (0.75-0.79), near the rig's 3 nm noise."""
    rig = ph.VirtualRig(seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(rig)
    ctl.fit = ph.fit_rate_pi(ctl.identification.u, ctl.identification.y, rig.dt, taus=[], input_taus=[0.0], delay=0)
    out = ctl.track(ref(5.0, rig, cycles=8), feedback=True, learning=True)
    assert out.info["feedback"] and ctl.tuning.ki > 0
    rms = out.info["cycle_rms_um"]
    assert rms[-1] < 0.85 * rms[1], rms  # learning starts after the second cycle
    assert out.info["correction_into_feedback"]


def test_the_correction_goes_into_the_feedback_only_where_the_feedback_acts_in_band():
    """Below the feedback's crossover (ki / 2 pi) the reference's fundamental is out of its reach:
    there following r + c only made the integrator sum the correction's mean cycle after cycle
    (0.62 -> 0.72 % at 5 Hz on the zoo's dead-zone stage, ki 1.6 1/s, mean of four seeds)."""
    import dataclasses

    from piezohyst.commissioning import correction_into_feedback

    assert correction_into_feedback(2 * np.pi * 5.01, 0.2) and not correction_into_feedback(2 * np.pi * 4.99, 0.2)
    assert not correction_into_feedback(0.0, 0.2) and not correction_into_feedback(100.0, 0.0)
    rig = ph.VirtualRig(seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(rig)
        r = ref(5.0, rig, cycles=3)
        assert ctl.track(r).info["correction_into_feedback"]  # ki of several hundred 1/s
        ctl.tuning = dataclasses.replace(ctl.tuning, ki=2.0)
        slow = ctl.track(r)
    assert slow.info["feedback"] and not slow.info["correction_into_feedback"]
    assert not ctl.track(r, learning=False).info["correction_into_feedback"]


def test_goal_figures_on_the_default_rig(rig_and_controller):
    # issue #7's table, default seed, the paper's 1/3/5 Hz sinusoids
    rig, ctl = rig_and_controller
    for f in (1.0, 3.0, 5.0):
        ff = ctl.track(ref(f, rig), feedback=False, learning=False)
        fb = ctl.track(ref(f, rig))
        assert ff.e_max_percent <= 2.0 and ff.rmse_percent <= 0.6, f
        assert fb.e_max_percent <= 1.0 and fb.rmse_percent <= 0.3, f


@pytest.mark.parametrize("variant", [dict(seed=11), dict(gamma=0.03), dict(creep_scale=2.0), dict(noise_rms_um=0.006)])
def test_rigs_it_was_not_tuned_on_stay_within_twice_the_goal(variant):
    seed = variant.pop("seed", 0)
    rig = ph.VirtualRig(seed=seed, **variant)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(rig)
    for f in (1.0, 5.0):
        ff = ctl.track(ref(f, rig), feedback=False, learning=False)
        fb = ctl.track(ref(f, rig))
        assert ff.e_max_percent <= 4.0 and ff.rmse_percent <= 1.2
        assert fb.e_max_percent <= 2.0 and fb.rmse_percent <= 0.6


def test_commission_works_on_any_plant():
    # a plant that is not a VirtualRig (no excite, no u_range): a pure P-I model
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(20, 100.0), np.linspace(0.03, -0.0005, 20))
    plant = PIPlant(true, dt=1e-3)
    # its loop does not come back to 0 um at 0 V: the reference's low points need negative commands,
    # and the safe layer never sends a command outside the stated range
    ctl = ph.commission(plant, u_range=(-50.0, 100.0), tune=False)
    out = ctl.track(ph.sinusoid(2.0, 3, 0.5, 2.5, plant.dt), feedback=False, learning=False)
    assert out.rmse < 1e-3


def test_commission_says_when_the_sample_rate_cannot_carry_its_excitation():
    """dt given in the wrong unit: 0.1 (meant as ms) is 10 Hz sampling, too slow for the 1 Hz
    excitation (before: an IndexError from an empty segment at dt >= 1 s); 1e-9 would be 10^10
    samples (before: an error about a sinusoid's cycles). A slow but usable rate commissions."""
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(20, 100.0), np.linspace(0.03, -0.0005, 20))
    for dt, what in ((0.1, "10 Hz sampling.*at least 20 Hz.*Is dt in seconds"),
                     (1.0, "1 Hz sampling.*at least 20 Hz"), (1e-9, r"1.05e\+10 samples.*Is dt in seconds")):
        with pytest.raises(ValueError, match=what):
            ph.commission(PIPlant(true, dt=dt), u_range=(-50.0, 100.0), tune=False)
    plant = PIPlant(true, dt=0.05)
    ctl = ph.commission(plant, u_range=(-50.0, 100.0), tune=False)
    out = ctl.track(ph.sinusoid(0.5, 3, 0.5, 2.5, plant.dt), feedback=False, learning=False)
    assert out.rmse < 1e-3


def test_commission_refuses_a_non_plant():
    with pytest.raises(TypeError, match="Plant protocol"):
        ph.commission(object())


def test_track_best_cli_with_variants(capsys):
    assert main(["track", "--method", "best", "--freq", "1,5", "--seed", "2", "--rig-gamma", "0.02",
                 "--rig-noise-scale", "1.5", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["rig"]["gamma"] == 0.02
    assert res["rig"]["noise_rms_um"] == pytest.approx(0.0045)
    assert [r["freq_hz"] for r in res["results"]] == [1.0, 5.0]
    assert all(r["e_max_percent"] < 2.0 for r in res["results"])
    # the rig reads its sensor one sample late (VirtualRig's delay_samples = 1, echoed in the
    # document); its amplifier's 0.8 ms lag and the held command add phase the model's input lag
    # does not all take up, so the fitted delay is at least the rig's and at most two samples more
    # (measured: 2). A delay of 0 would let the feedforward's preview lag the stage.
    rig_delay = res["rig"]["delay_samples"]
    assert rig_delay == 1
    assert rig_delay <= res["controller"]["delay_samples"] <= rig_delay + 2


class _Backlash500Hz:
    """A pure backlash (16 V wide) with a curved output, sampled at 500 Hz, 2 samples of delay: a
    stage whose loop is flat for 16 V after each reversal. Found by trying stages not in the zoo."""

    dt, u_range = 2e-3, (0.0, 120.0)

    def reset(self):
        self.z, self.line, self.rng = 0.0, [0.0, 0.0], np.random.default_rng(0)

    def step(self, u):
        u = min(max(u, 0.0), 120.0)
        self.z = min(max(self.z, u - 8.0), u + 8.0)
        self.line.append(0.01 * (0.5 * self.z + 0.002 * self.z**2) + self.rng.normal(0.0, 0.002))
        return self.line.pop(0)


def test_learning_that_drives_the_loop_to_the_limits_is_dropped_not_fatal():
    # at 5 Hz (100 samples a cycle) a step limit of 2 % of the range per sample (the default at
    # every sample rate then) cannot cross the 16 V gap in time, and the first learned correction
    # threw the loop between the amplifier's limits: track() raised UnstableLoopError. Now the
    # correction is dropped, learning stops, and the result says why.
    stage = _Backlash500Hz()
    stage.reset()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ctl = ph.commission(stage, max_step_fraction=0.02)
    lo, hi = np.percentile(ctl.identification.y, [10, 90])
    with pytest.warns(ph.ClippingWarning, match="slowed"):  # and the run says the limit slowed it
        out = ctl.track(ph.sinusoid(5.0, 6, lo, hi, stage.dt), period=100)
    assert out.info["learning"] and "oscillates between the amplifier's limits" in out.info["learning_stopped"]
    assert np.all(np.isfinite(out.output))
    # without learning the same loop runs as before, and at 1 Hz learning works undisturbed
    with pytest.warns(ph.ClippingWarning, match="slowed"):
        alone = ctl.track(ph.sinusoid(5.0, 6, lo, hi, stage.dt), learning=False, period=100)
    assert alone.info["learning_stopped"] is None
    slow = ctl.track(ph.sinusoid(1.0, 4, lo, hi, stage.dt), period=500)
    assert slow.info["learning_stopped"] is None and slow.e_max_percent < 3.0


def test_a_reference_beyond_the_stroke_is_said_to_be_the_ranges_error(rig_and_controller):
    """A reference that asks for more than the stage reaches within the amplifier's range: the
    guard clips the command for much of the run, and track says so with the figures (before:
    e_max of 30 % and nothing said). Within the stroke nothing is said."""
    rig, ctl = rig_and_controller
    top = float(np.max(ctl.identification.y))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ctl.track(ref(1.0, rig, cycles=2), feedback=False, learning=False)
    with pytest.warns(ph.ClippingWarning, match=r"clipped to the amplifier's range \(0 to 100 V\).*the stage reached"):
        out = ctl.track(ph.sinusoid(1.0, 2, 0.25, 1.6 * top, rig.dt), feedback=False, learning=False)
    assert out.info["safety"]["clipped"] > 0.05 * out.info["safety"]["commands_sent"]


def test_track_checks_period_and_reach_before_it_runs(rig_and_controller):
    # found by fuzzing: period=0 divided by zero in learning (ZeroDivisionError), a negative one
    # made a negative array, and a reference 100 um beyond the 2.5 um stroke was reported as a loop
    # gone unstable at its first sample
    rig, ctl = rig_and_controller
    r = ref(1.0, rig, cycles=3)
    for bad in (0, np.int64(0), -5):
        with pytest.raises(ValueError, match="period must be >= 1 sample"):
            ctl.track(r, period=bad)
    with pytest.raises(ValueError, match="beyond what the stage reached .* no controller can follow it"):
        ctl.track(r + 100.0)


def test_feedback_asked_of_an_untuned_controller_is_refused():
    # found by fuzzing: feedback=True on a controller commissioned with tune=False ran without
    # feedback and said nothing
    rig = ph.VirtualRig(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(rig, tune=False)
    r = ref(1.0, rig, cycles=2)
    with pytest.raises(ValueError, match="never tuned .* ctl.tune"):
        ctl.track(r, feedback=True)
    assert ctl.track(r).info["feedback"] is False  # the default: feedback where there is one
    with pytest.raises(TypeError, match="TrackingResult"):  # (an AttributeError on .metrics before)
        ctl.noise_floor(None)


class _SlewLimited:
    """A stage element behind an amplifier that slews by at most ``rate`` V/s."""

    def __init__(self, inner, rate, dt):
        self.inner, self.max_step = inner, rate * dt
        self.v = None

    def reset(self):
        self.inner.reset()
        self.v = None

    def step(self, v):
        self.v = float(v) if self.v is None else self.v + min(max(float(v) - self.v, -self.max_step), self.max_step)
        return self.inner.step(self.v)


def test_commissioning_finds_an_amplifier_slower_than_the_excitation_and_slows_down(rig_and_controller):
    """Behind a 2000 V/s amplifier the commissioning excitation (up to 7850 V/s on 0-100 V) is
    distorted where it is fastest; undeclared, the feedforward missed by 2.4-2.8 % with no word,
    then with a warning only. commission() now estimates the slew from its identification run
    (1963 V/s), says so, and commissions again within it: feedforward 0.17 / 0.26 % at 1 / 5 Hz.
    The rig's own fit shows nothing of the kind."""
    from piezohyst.commissioning import AmplifierSlewWarning

    from .plants.zoo import AsymmetricMaxwellSlip, Stage
    from .test_zoo import steady_range

    _, rig_ctl = rig_and_controller
    assert not rig_ctl.fit.info["residual_by_rate"]["amplifier_may_not_follow"]
    assert "slew_estimate" not in rig_ctl.info
    stage = Stage("Maxwell-slip behind a 2000 V/s amplifier", _SlewLimited(AsymmetricMaxwellSlip(100.0, 20.0), 2000.0, 1e-4),
                  1e-4, (0.0, 100.0), tau_amp=1e-4, fn_hz=2000, zeta=0.05, noise_um=0.003, delay_samples=1, seed=21)
    with pytest.warns(AmplifierSlewWarning, match="fits its identification run best.*first-order lag.*Commissioning again with max_step_fraction"):
        ctl = ph.commission(stage, tune=False)
    est = ctl.info["slew_estimate"]["max_step"]
    assert 0.17 <= est <= 0.21, est  # 2000 V/s x 0.1 ms = 0.2 V per sample
    assert ctl.limits.max_step == pytest.approx(est)
    assert not ctl.fit.info["residual_by_rate"]["amplifier_may_not_follow"]
    a, b = steady_range(stage)
    for f in (1.0, 5.0):
        run = ctl.track(ph.sinusoid(f, 3, a, b, stage.dt), feedback=False, learning=False)
        assert run.e_max_percent < 1.0, (f, run.e_max_percent)


def test_a_declared_step_limit_is_not_second_guessed():
    """With max_step_fraction given, commission() only warns (the 2000 V/s stage above, declared
    faster than it is)."""
    from piezohyst.commissioning import AmplifierSlewWarning

    from .plants.zoo import AsymmetricMaxwellSlip, Stage

    stage = Stage("Maxwell-slip behind a 2000 V/s amplifier", _SlewLimited(AsymmetricMaxwellSlip(100.0, 20.0), 2000.0, 1e-4),
                  1e-4, (0.0, 100.0), tau_amp=1e-4, fn_hz=2000, zeta=0.05, noise_um=0.003, delay_samples=1, seed=21)
    with pytest.warns(AmplifierSlewWarning, match="moves fastest") as said:
        ctl = ph.commission(stage, tune=False, max_step_fraction=0.02)
    assert not any("Commissioning again" in str(w.message) for w in said)
    assert "slew_estimate" not in ctl.info and ctl.limits.max_step == pytest.approx(2.0)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::piezohyst.ClippingWarning")
def test_an_amplifier_far_slower_than_the_excitation_is_not_taken_for_a_butterfly_loop():
    """Behind 400 V/s the stage goes on moving after the command reverses, which the monotone check
    read as a butterfly loop: commission() refused with a 6 V range to commission in. It now finds
    the slew (413 V/s) and tracks a 1 Hz sinusoid (10-90 %) within 0.3 % with the feedforward
    alone."""
    from piezohyst.commissioning import AmplifierSlewWarning

    from .plants.zoo import AsymmetricMaxwellSlip, Stage
    from .test_zoo import steady_range

    stage = Stage("Maxwell-slip behind a 400 V/s amplifier", _SlewLimited(AsymmetricMaxwellSlip(100.0, 20.0), 400.0, 1e-4),
                  1e-4, (0.0, 100.0), tau_amp=1e-4, kv=((0.05, 0.02),), fn_hz=2000.0, zeta=0.05, noise_um=0.005,
                  delay_samples=1, seed=31)
    with pytest.warns(AmplifierSlewWarning, match="not monotone.*Commissioning again"):
        ctl = ph.commission(stage)
    assert 0.036 <= ctl.info["slew_estimate"]["max_step"] <= 0.044
    a, b = steady_range(stage)
    assert ctl.track(ph.sinusoid(1.0, 3, a, b, stage.dt), feedback=False, learning=False).e_max_percent < 0.5


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::piezohyst.ClippingWarning")
def test_a_reference_faster_than_the_step_limit_is_named_as_the_cause_of_a_wound_up_loop():
    """Behind 800 V/s (commissioned within 825 V/s), a 5 Hz sinusoid over 10-90 % asks for 1460 V/s:
    the guard slows the command, the integral winds up against it and the loop ends between the
    amplifier's limits. The error said "lower the feedback gains"; it now names the step limit
    and the reference's speed. A 3 Hz one tracks (0.25 % e_max)."""
    from piezohyst.commissioning import AmplifierSlewWarning

    from .plants.zoo import AsymmetricMaxwellSlip, Stage
    from .test_zoo import steady_range

    stage = Stage("Maxwell-slip behind an 800 V/s amplifier", _SlewLimited(AsymmetricMaxwellSlip(100.0, 20.0), 800.0, 1e-4),
                  1e-4, (0.0, 100.0), tau_amp=1e-4, kv=((0.05, 0.02),), fn_hz=2000.0, zeta=0.05, noise_um=0.005,
                  delay_samples=1, seed=31)
    with pytest.warns(AmplifierSlewWarning, match="fits its identification run best.*Commissioning again"):
        ctl = ph.commission(stage)
    a, b = steady_range(stage)
    assert ctl.track(ph.sinusoid(3.0, 6, a, b, stage.dt), learning=False).e_max_percent < 1.0
    with pytest.raises(ph.UnstableLoopError, match="more than the step limit lets through.*Slow the reference"):
        ctl.track(ph.sinusoid(5.0, 6, a, b, stage.dt), learning=False)


def test_an_amplifier_lag_is_not_taken_for_a_slew_limit():
    """Behind a first-order lag of 15 ms, commands slowed to 620 V/s fit with 0.43 of the error of
    the commands as sent, and that passed for a slew limit (the bar was a half). The lag itself
    fits far better (the slowed commands 3.9 times its error): no slew. Behind a slew limit and a
    2 ms lag together, the slew still fits better than any lag and is found."""
    from piezohyst.commissioning import followed_step
    from piezohyst.models.rate import first_order_lag
    from piezohyst.plant import rate_limited

    dt = 1e-4
    t = np.arange(40_000) * dt
    u = 50.0 + 45.0 * np.sin(2 * np.pi * 3.0 * t) * np.exp(-t) + 3.0 * np.sign(np.sin(2 * np.pi * 40.0 * t))
    pi = ph.PrandtlIshlinskii(np.linspace(0.0, 40.0, 8), np.linspace(0.06, 0.01, 8))

    def lagged(x, tau):
        return first_order_lag(x - x[0], np.exp(-dt / tau)) + x[0]

    assert followed_step(u, pi.simulate(lagged(u, 15e-3))) is None
    got = followed_step(u, pi.simulate(lagged(rate_limited(u, 0.1), 2e-3)))
    assert got is not None and 0.085 <= got["max_step"] <= 0.105, got
    assert got["rmse_slewed"] <= 0.9 * got["rmse_input_lag"]


def test_a_slew_is_found_where_a_plain_pi_model_takes_the_stages_own_lag_for_an_input_lag():
    """An asymmetric Bouc-Wen stage with an 18 ms lag after its hysteresis, behind 3000 V/s (the
    excitation's 10 Hz sinusoid asks for 3770 V/s). Found on a random stage like it (its slew
    before the amplifier's lag): a 20-operator P-I model fitted the commands slowed to the slew
    with 0.78 of the error of the commands as sent, but a 3.8 ms input lag fitted better still
    (it stood in for the stage's own lag), and no slew was found; the fit took the slowed peaks
    for a delay of 38 samples (5 + 10 of amplifier), and the feedforward missed by 1.96 / 8.85 %
    e_max at 1 / 5 Hz (0.72 / 0.67 % once found). A P-I model with output lags now judges the
    three again; the same stage behind an amplifier that follows: nothing."""
    from piezohyst.commissioning import commissioning_excitation, followed_step

    from .plants.zoo import AsymmetricBoucWen, Stage

    def stage(element):
        return Stage("asymmetric Bouc-Wen, 18 ms lag after it", element, 5e-5, (0.0, 120.0), tau_amp=5e-4,
                     kv=((0.09, 0.018), (0.025, 2.9)), fn_hz=3800.0, zeta=0.06, noise_um=0.02, delay_samples=5,
                     seed=815)

    slewed = stage(_SlewLimited(AsymmetricBoucWen(120.0, 100.0), 3000.0, 5e-5))
    u = commissioning_excitation(slewed.dt, slewed.u_range)
    got = followed_step(u, slewed.excite(u).y)
    assert got is not None and got["judged_by"] == "a P-I model with output lags", got
    assert 0.14 <= got["max_step"] <= 0.155, got["max_step"]  # 3000 V/s: 0.15 V per sample
    assert followed_step(u, stage(AsymmetricBoucWen(120.0, 100.0)).excite(u).y) is None


@pytest.mark.parametrize("true_step", [0.075, 0.13, 0.29])
def test_followed_step_places_the_slew_between_its_grid_points(true_step):
    """The grid of octaves and eighth octaves placed a slew to 9 % at best, and a limit below the
    amplifier's throttles every fast command: a saturated P-I stage behind 1500 V/s, commissioned
    within 1414 V/s, tracked 5 Hz at 5.0 % e_max with feedback and learning; within 1500 V/s at
    0.42 %. The step is now refined between the grid's neighbours (to a 64th of an octave)."""
    from piezohyst.commissioning import followed_step
    from piezohyst.plant import rate_limited

    dt = 1e-4
    t = np.arange(40_000) * dt
    u = 50.0 + 45.0 * np.sin(2 * np.pi * 3.0 * t) * np.exp(-t) + 3.0 * np.sign(np.sin(2 * np.pi * 40.0 * t))
    pi = ph.PrandtlIshlinskii(np.linspace(0.0, 40.0, 8), np.linspace(0.06, 0.01, 8))
    got = followed_step(u, pi.simulate(rate_limited(u, true_step)))
    assert got is not None
    assert abs(got["max_step"] / true_step - 1.0) < 0.03, (got["max_step"], true_step)  # old grid: 6.4 / 3.2 / 10 %
    assert got["rmse_slewed"] == min(r for _, r in got["tried"])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-100.0, 100.0), min_size=1, max_size=60), st.floats(0.01, 50.0))
def test_a_rate_limited_command_never_steps_further_and_passes_what_is_within(xs, step):
    from piezohyst.plant import rate_limited

    x = np.array(xs)
    out = rate_limited(x, step)
    assert out[0] == x[0]
    assert np.all(np.abs(np.diff(out)) <= step * (1 + 1e-12))
    # a signal whose every step is within the limit is delivered as sent
    slow = x[0] + np.cumsum(np.clip(np.diff(x, prepend=x[0]), -step, step))
    np.testing.assert_allclose(rate_limited(slow, step), slow, rtol=0, atol=1e-9)


def test_followed_step_finds_a_slew_and_nothing_where_the_amplifier_follows():
    from piezohyst.commissioning import followed_step
    from piezohyst.plant import rate_limited

    dt = 1e-4
    t = np.arange(40_000) * dt
    u = 50.0 + 45.0 * np.sin(2 * np.pi * 3.0 * t) * np.exp(-t) + 3.0 * np.sign(np.sin(2 * np.pi * 40.0 * t))
    pi = ph.PrandtlIshlinskii(np.linspace(0.0, 40.0, 8), np.linspace(0.06, 0.01, 8))  # 0-100 V -> ~15 um
    y_fast = pi.simulate(u)
    y_slow = pi.simulate(rate_limited(u, 0.1))  # 1000 V/s
    assert followed_step(u, y_fast) is None
    got = followed_step(u, y_slow)
    assert got is not None and 0.09 <= got["max_step"] <= 0.11, got
    assert got["rmse_slewed"] < 0.5 * got["rmse_as_sent"]
    # a record no P-I model fits (the output falls as the input rises; for a Dahl stage, only once
    # the commands are slowed far enough) is no slew, not an error
    assert followed_step(u, -y_fast) is None


def _assert_the_last_three_of_12_cycles_near_the_best(stage, freq):
    """``commission(stage)``, then 12 cycles of feedback and learning at ``freq``: none of the
    last three cycles more than 1.5x the run's best."""
    from .test_zoo import steady_range

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(stage)
    a, b = steady_range(stage)
    period = int(round(1.0 / (freq * stage.dt)))
    out = ctl.track(ph.sinusoid(freq, 12, a, b, stage.dt), period=period)
    per_cycle = out.info["cycle_e_max_um"]
    assert max(per_cycle[-3:]) <= 1.5 * min(per_cycle), per_cycle


@pytest.mark.slow
def test_learning_does_not_try_a_wider_band_it_could_not_undo():
    """Learning widens its band when it stalls, and undoes a widening that made a cycle worse;
    that costs the cycle tried and the one after (which still carries its transient). Found on the
    zoo's Maxwell-slip stage behind a 180 Hz resonance at 1 % damping, 12 cycles at 3 Hz: the band
    was widened to 200 Hz three cycles before the end, the loop rang at the resonance, and the
    run ended on those two cycles (e_max 0.71 and 0.66 % against 0.14 % before them). A wider
    band is now tried only while five cycles are left (the next test)."""
    from .plants.zoo import zoo

    stage = zoo(seed=0)[6]
    assert "low resonance" in stage.name
    _assert_the_last_three_of_12_cycles_near_the_best(stage, 3.0)


@pytest.mark.slow
def test_a_failed_wider_band_never_reaches_a_runs_last_three_cycles():
    """A wider band that fails costs the cycle it is tried in and the settling one after the
    revert. Tried while only three or four cycles were left, those two fell among a run's last
    three: on a stage with two structural modes (406 and 967 Hz, 10 % of the output through the
    second; hysterons from the bottom of a -100..100 V range), 12 cycles at 5 Hz read 0.80 ... 0.67
    / 0.69 / 4.34 / 4.16 / 0.66 / 0.69 % e_max (a wider band tried in the ninth cycle rang, and
    was reverted). A wider band is now tried only while five cycles are left: the run's last three
    follow the band that converged (0.70 / 0.66 / 0.66 % there)."""
    from .plants.census import KrasnoselskiiPokrovskii
    from .plants.zoo import Shifted, TwoModeStage

    stage = TwoModeStage("two modes, 10 kHz, -100..100 V, 100 um", Shifted(KrasnoselskiiPokrovskii(200.0, 100.0), -100.0),
                         1e-4, (-100.0, 100.0), tau_amp=1e-4, kv=((0.0629, 0.0204), (0.0122, 0.706)), fn_hz=405.7,
                         zeta=0.02705, noise_um=0.0209, seed=911, fn2_hz=967.2, zeta2=0.0325, share=0.1026)
    _assert_the_last_three_of_12_cycles_near_the_best(stage, 5.0)


def test_learning_takes_a_best_it_cannot_reproduce_as_the_new_baseline():
    """A cycle worse than the best by more than the tolerance restores the best correction; the
    cycle after the settling one runs with it. If that one is still worse by the tolerance, the
    best figure was not the correction's doing (a lucky noisy cycle, a stage that drifts): it
    becomes the new baseline and learning goes on, instead of halving its gain until it stops
    with no correction (found on the zoo's falling-after-reversal stage at 3 Hz: 1.08 % e_max,
    learning off after three halvings; 0.90 % now). Where the restored correction does give the
    best back, nothing changes."""
    from piezohyst.commissioning import _Learning

    p, dt = 200, 1e-3
    e = 0.01 * np.sin(2 * np.pi * np.arange(p) / p)

    def learner():
        return _Learning(p, dt, gain=0.5, cutoff=20.0, cutoff_max=100.0)

    lr = learner()
    c1, on = lr.update(np.zeros(p), e, 1.0)  # the first judged cycle: the best
    c2, on = lr.update(c1, e, 1.3)  # worse by more than 15 %: revert to the best's correction
    assert lr.halvings == 1 and not np.any(c2) and lr.settling
    c3, on = lr.update(c2, e, 1.3)  # the settling cycle: neither judged nor learnt from
    c4, on = lr.update(c3, e, 1.28)  # the best's correction again, still 28 % worse: a new baseline
    assert on and lr.best == 1.28 and lr.halvings == 1 and lr.rebaselined == 1
    assert np.abs(c4).max() > 0  # and it learns from this cycle

    lr = learner()
    c1, on = lr.update(np.zeros(p), e, 1.0)
    c2, on = lr.update(c1, e, 1.3)
    c3, on = lr.update(c2, e, 1.3)
    c4, on = lr.update(c3, e, 1.05)  # the restored correction gives the best back: judged as usual
    assert lr.best == 1.0 and lr.rebaselined == 0 and lr.halvings == 1


def test_a_run_from_a_rest_mid_range_starts_from_the_bottom_as_the_identification_did():
    """A Krasnosel'skii-Pokrovskii stage (hysterons over 0..180 V) on a -30..150 V amplifier, resting
    at 0 V. The identification run goes from rest down to the bottom first, so the fit never saw
    the model's assumed state at rest (demagnetised at 0 V); tracking runs went straight from rest
    and started in it, and the model's hysterons below 0 V that no run reaches kept model and stage
    apart: the feedforward missed by 1.9-2.2 % of span (a constant offset) at 1-5 Hz. Every run's
    lead-in now goes down to the bottom of the range first too (the model with it)."""
    from .plants.census import KrasnoselskiiPokrovskii
    from .plants.zoo import Stage
    from .test_zoo import steady_range

    stage = Stage("KP over 0..180 V on a -30..150 V amplifier", KrasnoselskiiPokrovskii(180.0, 40.0, a_frac=0.03), 1e-4,
                  (-30.0, 150.0), tau_amp=2e-4, kv=((0.05, 0.05),), fn_hz=1500.0, zeta=0.06, noise_um=0.01,
                  delay_samples=3, seed=33)
    ctl = ph.commission(stage, tune=False)
    a, b = steady_range(stage)
    for f in (1.0, 5.0):
        run = ctl.track(ph.sinusoid(f, 3, a, b, stage.dt), feedback=False, learning=False)
        assert run.e_max_percent < 1.0, (f, run.e_max_percent)
        assert run.info["safety"]["clipped"] == 0


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::piezohyst.ClippingWarning")
def test_a_slow_amplifier_behind_a_lag_is_found_without_any_other_sign():
    """Behind 1500 V/s and a 6 ms amplifier lag (a random census of stages outside the zoo) the
    input lag absorbs part of the slewing: no rate warning, a hold-out error of a few % of span,
    so the slew was never looked for and the feedforward missed by 4.1 % at 1 Hz. It is looked
    for on every commissioning now (0.1-0.3 s on the rig, zoo and census stages, which have none)."""
    from piezohyst.commissioning import AmplifierSlewWarning

    from .plants.zoo import AsymmetricBoucWen, Stage
    from .test_zoo import steady_range

    stage = Stage("asymmetric Bouc-Wen behind 1500 V/s and a 6 ms amplifier lag",
                  _SlewLimited(AsymmetricBoucWen(100.0, 20.0), 1500.0, 1e-4), 1e-4, (0.0, 100.0), tau_amp=6e-3,
                  kv=((0.05, 0.05),), fn_hz=2662.0, zeta=0.05, noise_um=0.004, delay_samples=2, seed=8)
    with pytest.warns(AmplifierSlewWarning, match="Commissioning again"):
        ctl = ph.commission(stage, tune=False)
    assert 1200 <= ctl.info["slew_estimate"]["max_step"] / stage.dt <= 1700
    a, b = steady_range(stage)
    assert ctl.track(ph.sinusoid(1.0, 3, a, b, stage.dt), feedback=False, learning=False).e_max_percent < 1.5


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::piezohyst.ClippingWarning")
def test_a_long_amplifier_lag_at_a_high_sample_rate_keeps_its_input_lag():
    """A saturated P-I stage at 20 kHz behind a 6 ms amplifier lag: the model with the input lag
    predicts its hold-out part to 0.1 % of span, but the exact inverse of that lag (a lead of gain
    about 120) turned every kink of the static inverse into a command step 29-49 times the
    reference's; every such candidate was refused for chatter and the rate-independent fallback
    (with a sensor delay of 93 samples standing in for the lag) tracked at 3-4 % of span with the
    feedforward alone (the integral gain 1.15 1/s). The same model is now kept with its lead's
    gain limited: the command's steps within the bound, the feedforward within 1 %."""
    from .plants.census import SaturatedPI
    from .plants.zoo import Stage
    from .test_zoo import steady_range

    stage = Stage("saturated P-I at 20 kHz behind a 6 ms amplifier lag", SaturatedPI(150.0, 20.0), 5e-5, (0.0, 150.0),
                  tau_amp=6e-3, kv=((0.05, 0.05),), fn_hz=1000.0, zeta=0.03, noise_um=0.004, delay_samples=2, seed=307)
    ctl = ph.commission(stage, tune=False)
    model = getattr(ctl.model, "inner", ctl.model)
    assert getattr(model, "input_tau", 0.0) > 3e-3, ctl.fit.info["chosen"]
    assert getattr(model, "input_lead_gain", 0.0) > 0.0
    a, b = steady_range(stage)
    for f in (1.0, 5.0):
        per = int(round(1.0 / (f * stage.dt)))
        ref = ph.sinusoid(f, 3, a, b, stage.dt)
        run = ctl.track(ref, feedback=False, learning=False, period=per)
        assert run.e_max_percent < 1.0, (f, run.e_max_percent)
        cmd = run.command[per:]
        gain = np.ptp(cmd) / np.ptp(ref)
        assert np.abs(np.diff(cmd)).max() <= 20 * gain * np.abs(np.diff(ref)).max()


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::piezohyst.ClippingWarning")
@pytest.mark.filterwarnings("ignore::piezohyst.commissioning.AmplifierSlewWarning")
def test_safe_tuning_waits_for_a_creeping_hold_to_settle():
    """Behind a 3000 V/s amplifier a saturated P-I stage is commissioned within the slew it shows;
    at the tuning's hold its feedforward then drifts (0.5 um/s), and the feedback that takes the
    hold's error out went on moving several probes' worth during the probes: the first trial was
    stopped twice, the halved ones' answers were buried in the drift, and the stage got no
    feedback at all (ki = 0; 5 Hz with feedback and learning 0.98 % e_max). The hold is now
    settled until the feedback stops moving: ki 141 1/s, 0.33 %."""
    from .plants.census import SaturatedPI
    from .plants.zoo import Stage

    stage = Stage("saturated P-I behind 3000 V/s", _SlewLimited(SaturatedPI(200.0, 20.0), 3000.0, 2e-4), 2e-4,
                  (0.0, 200.0), tau_amp=2e-3, kv=((0.05, 0.5),), fn_hz=738.0, zeta=0.04, noise_um=0.004,
                  delay_samples=1, seed=314)
    ctl = ph.commission(stage)
    assert "slew_estimate" in ctl.info
    assert ctl.tuning.ki > 0.1 * ctl.tuning.ki_model, ctl.tuning.method
    assert any(e["settled_first"] for e in ctl.tuning.experiments)


class _AmplifierOff:
    """A stage whose amplifier is off: the sensor reads the stage at rest plus its noise."""

    dt = 1e-4
    u_range = (0.0, 100.0)

    def __init__(self, noise_only: bool = False, seed: int = 0):
        self.rig = ph.VirtualRig(seed=seed)
        self.noise_only = noise_only
        self.rng = np.random.default_rng(seed)

    def reset(self):
        self.rig.reset()

    def step(self, u):
        return float(self.rng.normal(0.0, 1.0)) if self.noise_only else self.rig.step(0.0)


@pytest.mark.parametrize("noise_only, seed", [(False, 0), (True, 2)])
def test_a_stage_that_does_not_follow_the_command_is_refused_as_such(noise_only, seed):
    # found by fuzzing: an amplifier switched off was told its sensor was mounted the other way
    # round; a pure-noise output (this seed) commissioned with a 10 % hold-out error
    with pytest.raises(ValueError, match="hardly follows the command") as err:
        ph.commission(_AmplifierOff(noise_only, seed))
    assert "amplifier on" in str(err.value) and "_AmplifierOff.step()" in str(err.value)


class _StuckSensor:
    dt = 1e-4
    u_range = (0.0, 100.0)

    def reset(self):
        pass

    def step(self, u):
        return 3.0


def test_a_stuck_sensor_is_said_to_give_a_constant_output():
    # the message said "correlation nan" for a reading that never moves
    with pytest.raises(ValueError, match=r"hardly follows the command .*\(a constant output over 0\.\.100 V"):
        ph.commission(_StuckSensor())


def test_track_flags_must_be_booleans(rig_and_controller):
    rig, ctl = rig_and_controller
    for name in ("feedback", "learning", "conditioning"):  # feedback="no" ran with feedback on
        with pytest.raises(TypeError, match=name):
            ctl.track(ref(1.0, rig, 2), **{name: "no"})


class _SaturatedSensor(_AmplifierOff):
    """A stage whose sensor stops at 0.12 um, reached at about 5 V of its 0..100 V."""

    def step(self, u):
        return min(self.rig.step(u), 0.12)


def test_a_stage_that_moves_over_a_small_part_of_the_range_is_pointed_there():
    # found by fuzzing: it commissioned over 0..100 V without a word, and tracking then blamed the
    # step limit ("slow the reference down") for a 1 Hz sinusoid
    with pytest.raises(ValueError, match=r"changes only over 0\.\.10 V.*u_range=\(0, 10\)"):
        ph.commission(_SaturatedSensor())


def test_clipping_at_speed_is_not_blamed_on_the_reach(rig_and_controller):
    # found by fuzzing: at 50 Hz the stage spanned the reference, yet the warning told the user to
    # keep the reference within what the stage reaches; beyond the reach, that is still the advice
    rig, ctl = rig_and_controller
    with pytest.warns(ph.ClippingWarning, match="spans the reference here, so at this speed"):
        ctl.track(ph.sinusoid(50.0, 5, 0.2, 1.8, rig.dt))
    with pytest.warns(ph.ClippingWarning, match="Keep the reference within what the stage reaches"):
        ctl.track(ph.sinusoid(1.0, 2, -1.0, 3.0, rig.dt))
