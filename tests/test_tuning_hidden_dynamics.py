"""Safe tuning on stages whose probes near a reversal cannot see what a tracking run meets.

Both stages were found by probes of structures outside the zoo (not tuned on: the numbers below
were set once, before the fix, as a plausible stage of each kind):

* play operators (a loop that is several times flatter just after a reversal than late on a
  branch) behind a low, lightly damped resonance and a long sensor delay. The tuning's probes
  reverse one another, so they see the stage at its flattest: the integral gain they found well
  damped, applied along a branch, drove the resonance (feedback alone 3.7 / 5.8 / 9.5 % e_max at
  1 / 3 / 5 Hz against 0.3-0.5 % with the feedforward alone, and the loop between the amplifier's
  limits with learning at 5 Hz);
* a play loop with strong creep on its output that the runs before left behind (as on a real
  stack, bringing the stage back to 0 V does not undo it) and a 16-bit sensor: at the hold the
  feedforward is off by 2-3 % of the stroke; cancelling that reverses the command, and on the
  flat slope after the reversal the command had to move further than the trial allowed, so every
  trial was stopped and the stage got no feedback at all (ki = 0);
* Maxwell-slip elements (a census stage of the zoo's elements, seed 29) behind a 1 kHz resonance
  at 2.8 % damping, 20 kHz: the probes at the hold were well damped up to 3,688 1/s and the gain
  kept (639) allowed for the reversal ratio the model gives, but on the steep upper part of the
  rising branch the loop rang at 980 Hz, and tracking with feedback was worse than without (e_max
  1.07 / 1.80 % at 1 / 5 Hz against 0.76 / 0.65 %). The commissioned controller now checks the
  gain on a tracking run and halves it while the feedback does worse than no feedback;
* ramp hysterons (Krasnosel'skii-Pokrovskii, a census stage of structures outside the zoo) behind
  a 600 Hz resonance: there the feedback left the RMS error as it was and added to the peaks, so
  the check reads the e_max too;
* a Dahl loop (a census of structures outside the zoo), whose branches are steepest just after a
  reversal and saturate along the way (concave: the opposite of a play-type loop). A probe's
  removal reverses the stage, which then answers 4.4x more than the probe's effect at the mean
  slope: the bound on the trial's error allowed 4x, so every trial was stopped and the stage got
  no feedback at all (ki = 0). The bound now allows the steepest answer the model gives at the
  hold, either way;
* Maxwell-slip elements whose slip is viscous (rate-dependent loops; a probe of structures outside
  the zoo and the census): the feedforward held the level 0.3-0.4 um off, less than twice a
  probe's effect at the mean slope, so the trials probed at once; but on the flat slope after
  the probes' reversals cancelling that error took 11 V of command against a 1.2 V probe, and
  every trial was stopped, then at half the gains the stage answered too slowly to show anything
  (a quarter of the probe): ki = 0, feedback alone 0.54 / 0.75 % e_max at 1 / 5 Hz. A hold that
  needs more than twice a probe's command is now settled first, and a trial that shows nothing
  (not stopped, no overshoot, no growing oscillation, the answer too slow) sends the ladder up,
  not down (only an answered trial proves a gain). (With input lags searched over a wider range
  its model now holds the level within 0.02 um; the tests below make the two conditions: a stage
  4 % stiffer than its model, and a ladder started at a fiftieth of the model's gain.)
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import piezohyst as ph
from piezohyst.commissioning import FEEDBACK_WORSE_EMAX_RATIO, FEEDBACK_WORSE_RATIO
from tests.plants.zoo import AsymmetricMaxwellSlip, Stage
from tests.test_zoo import steady_range


class Plays:
    """Play operators (thresholds up to 35 % of the range, weights falling with the threshold): a
    symmetric loop, with a softening output."""

    def __init__(self, v_span: float, stroke_um: float, n: int = 20):
        self.r = np.linspace(0.0, 0.35 * v_span, n)
        w = np.exp(-np.linspace(0.0, 3.0, n))
        self.w = w / w.sum() * stroke_um / v_span
        self.stroke = stroke_um
        self.reset()

    def reset(self) -> None:
        self.z = np.zeros(self.r.size)

    def step(self, v: float) -> float:
        self.z = np.minimum(np.maximum(self.z, v - self.r), v + self.r)
        y = float(self.w @ self.z)
        return y - 0.1 * y**3 / self.stroke**2


class CreepingPlays:
    """Eight play operators (thresholds up to 40 % of the range, weights falling linearly to 0.3)
    whose output creeps: six lags from 10 ms to 3 s, 1.5 % each (9 % in all, about a logarithm of
    time), sampled at ``dt``. As on a real stack, ``reset()`` (the stage brought back to 0 V)
    does not undo the creep of the runs before: it decays on its own time scales."""

    def __init__(self, v_span: float, stroke_um: float, dt: float):
        self.r = np.linspace(0.0, 0.4 * v_span, 8)
        w = np.linspace(1.0, 0.3, 8)
        self.w = w / w.sum() * stroke_um / v_span
        self.a = np.exp(-dt / np.array([0.01, 0.03, 0.1, 0.3, 1.0, 3.0]))
        self.s = np.zeros(self.a.size)
        self.reset()

    def reset(self) -> None:
        self.z = np.zeros(self.r.size)

    def step(self, v: float) -> float:
        self.z = np.minimum(np.maximum(self.z, v - self.r), v + self.r)
        h = float(self.w @ self.z)
        self.s = self.a * self.s + (1.0 - self.a) * h
        return h + 0.015 * float(self.s.sum())


class Quantised:
    """A sensor of ``q`` µm resolution after the element."""

    def __init__(self, inner: object, q: float):
        self.inner, self.q = inner, q

    def reset(self) -> None:
        self.inner.reset()  # type: ignore[attr-defined]

    def step(self, v: float) -> float:
        return round(self.inner.step(v) / self.q) * self.q  # type: ignore[attr-defined]


class KrasnoselskiiPokrovskii:
    """Ramp hysterons (Krasnosel'skii-Pokrovskii) on an ``n``-level grid over ``0..v_max``, each
    ramp ``eps`` volts wide, with a density that falls with the hysteron's width and peaks at
    40 % of the range."""

    def __init__(self, v_max: float, stroke_um: float, n: int = 20, eps: float = 0.07):
        a = np.linspace(0.0, v_max, n)
        al, be = np.meshgrid(a, a, indexing="ij")
        keep = al >= be
        self.al, self.be, self.eps = al[keep], be[keep], eps * v_max
        mu = np.exp(-(self.al - self.be) / (0.3 * v_max)) * np.exp(
            -(((self.al + self.be) / 2 - 0.4 * v_max) ** 2) / (0.5 * v_max) ** 2)
        self.mu = mu * stroke_um / mu.sum()
        self.reset()

    def reset(self) -> None:
        self.s = -np.ones(self.al.size)

    def step(self, v: float) -> float:
        up = np.clip((v - self.al) / self.eps * 2 + 1, -1, 1)
        down = np.clip((v - self.be) / self.eps * 2 - 1, -1, 1)
        self.s = np.minimum(np.maximum(self.s, up), down)
        return float(self.mu @ (self.s + 1) / 2)


class Dahl:
    """Dahl's model with exponent ``a``: ``dz/dv = sigma (1 - z sign(dv) / F)^a``, ``F`` a fraction
    of the stroke, reached over ``reach`` of the range; plus a linear part for the rest of the
    stroke. Integrated in sub-steps of at most ``v_max / 2000``."""

    def __init__(self, v_max: float, stroke_um: float, a: float = 0.5, frac: float = 0.3, reach: float = 0.1):
        self.v_max, self.a = v_max, a
        self.f = frac * stroke_um
        self.sigma = self.f / (reach * v_max)
        self.k = (stroke_um - 2 * self.f) / v_max
        self.reset()

    def reset(self) -> None:
        self.v, self.z = 0.0, 0.0

    def step(self, v: float) -> float:
        dv = v - self.v
        n = int(abs(dv) / (self.v_max / 2000)) + 1
        h = dv / n
        s = 1.0 if h > 0 else -1.0
        for _ in range(n):
            self.z += self.sigma * h * max(0.0, 1.0 - self.z * s / self.f) ** self.a
        self.v = v
        return self.k * v + self.z


class ViscousMaxwellSlip:
    """Maxwell-slip elements (thresholds up to 40 % of the range, weights falling linearly to 0.4)
    whose slip is viscous: an element past its threshold moves towards it with time constant
    ``tau`` (loops that widen with the rate), sampled at ``dt``."""

    def __init__(self, v_max: float, stroke_um: float, dt: float, n: int = 10, tau: float = 0.004):
        self.r = np.linspace(0.0, 0.4 * v_max, n)
        w = np.linspace(1.0, 0.4, n)
        self.w = w / w.sum() * stroke_um / v_max
        self.a = 1.0 - np.exp(-dt / tau)
        self.reset()

    def reset(self) -> None:
        self.z = np.zeros(self.r.size)

    def step(self, v: float) -> float:
        self.z += self.a * (np.clip(self.z, v - self.r, v + self.r) - self.z)
        return float(self.w @ self.z)


def _verified(stage):
    """The stage commissioned (clipping warnings aside), its tuning (with feedback) and the checks of its gain."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(stage)
    tu = ctl.tuning
    assert tu is not None and tu.ki > 0
    return ctl, tu, tu.verification


def _e_max_last(ctl, stage, freq: float, *, learning: bool, cycles: int = 6) -> float:
    a, b = steady_range(stage)
    ref = ph.sinusoid(freq, cycles, a, b, stage.dt)
    period = int(round(1.0 / (freq * stage.dt)))
    out = ctl.track(ref, feedback=True, learning=learning, period=period)
    return 100.0 * float(np.abs(out.error[(cycles - 2) * period:]).max()) / float(np.ptp(ref))


@pytest.mark.slow
def test_gain_probed_near_a_reversal_does_not_drive_a_resonance_along_a_branch():
    stage = Stage("plays behind 250 Hz at 5 %, 12 samples of delay, 20 kHz, -10..60 V", Plays(70.0, 8.0),
                  5e-5, (-10.0, 60.0), kv=((0.04, 0.3),), fn_hz=250.0, zeta=0.05, noise_um=0.002,
                  delay_samples=12)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(stage)
    assert ctl.tuning is not None and ctl.tuning.ki > 0
    # the ladder climbed past the gains the old rule stopped at, until the stage answered
    assert not all(e["well_damped"] for e in ctl.tuning.experiments), ctl.tuning.method
    a, b = steady_range(stage)
    for freq in (1.0, 5.0):
        period = int(round(1.0 / (freq * stage.dt)))
        ff = ctl.track(ph.sinusoid(freq, 3, a, b, stage.dt), feedback=False, learning=False,
                       period=period).e_max_percent
        fb = _e_max_last(ctl, stage, freq, learning=False)
        # feedback must not make tracking worse than the feedforward alone (it was 10-20x worse)
        assert fb <= ff + 0.2, (freq, fb, ff, ctl.tuning.method)


@pytest.mark.slow
def test_creep_at_the_hold_does_not_stop_every_trial():
    dt = 2e-4
    stage = Stage("creeping plays, 16-bit sensor, 5 kHz, 0..150 V",
                  Quantised(CreepingPlays(150.0, 40.0, dt), 1.5 * 40.0 / 65536), dt, (0.0, 150.0),
                  tau_amp=2e-4, fn_hz=900.0, zeta=0.06, noise_um=0.0, delay_samples=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(stage)
    assert ctl.tuning is not None and ctl.tuning.ki > 0, ctl.tuning.method if ctl.tuning else None
    a, b = steady_range(stage)
    period = int(round(1.0 / (3.0 * stage.dt)))
    ff = ctl.track(ph.sinusoid(3.0, 3, a, b, stage.dt), feedback=False, learning=False, period=period).e_max_percent
    fbl = _e_max_last(ctl, stage, 3.0, learning=True)
    assert fbl < 0.6 * ff, (fbl, ff)


@pytest.mark.slow
def test_feedback_that_rings_along_a_branch_is_halved_until_it_helps():
    stage = Stage("Maxwell-slip behind 1 kHz at 2.8 %, 3 samples of delay, 20 kHz, -10..10 V",
                  AsymmetricMaxwellSlip(10.0, 77.7, n=14, ratio=0.681), 5e-5, (-10.0, 10.0),
                  kv=((0.0684, 0.0111), (0.0228, 0.00429)), fn_hz=1023.6, zeta=0.028, noise_um=0.178,
                  delay_samples=3, seed=3)
    ctl, tu, checks = _verified(stage)
    # the gain the experiments allowed did worse than the feedforward alone on the branches ...
    assert checks[0]["ratio"] > FEEDBACK_WORSE_RATIO, tu.method
    # ... and the one kept does not, and is what the last check measured
    assert checks[-1]["ratio"] <= FEEDBACK_WORSE_RATIO and checks[-1]["ki"] == tu.ki < checks[0]["ki"]
    assert "halving" in tu.method
    a, b = steady_range(stage)
    for freq in (1.0, 5.0):
        period = int(round(1.0 / (freq * stage.dt)))
        ref = ph.sinusoid(freq, 3, a, b, stage.dt)
        ff = ctl.track(ref, feedback=False, learning=False, period=period)
        fb = ctl.track(ref, learning=False, period=period)
        # with the gain it had, 1.4x and 2.2x the feedforward's RMS error
        assert fb.rmse <= 1.1 * ff.rmse, (freq, fb.rmse, ff.rmse)


def test_verification_keeps_a_gain_that_helps():
    """On the rig the feedback helps on the branches: one check, the tuned gain kept, the
    model's margins still reported for it."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(ph.VirtualRig(seed=0))
    tu = ctl.tuning
    assert len(tu.verification) == 1 and tu.verification[0]["ki"] == tu.ki > 0
    assert tu.verification[0]["ratio"] <= FEEDBACK_WORSE_RATIO
    assert "verified on a 5 Hz run" in tu.method and tu.margins


@pytest.mark.slow
def test_feedback_that_adds_to_the_peaks_is_halved_too():
    """A census stage (seed 102, not tuned on): ramp hysterons behind a 600 Hz resonance at 4 %
    damping, 2 kHz. The feedback the experiments allowed left the RMS error as it was on the
    verification run (1.01x) but rang the resonance after each reversal: e_max 1.31x, and with
    learning 1.42 / 1.23 % at 3 / 5 Hz against the feedforward alone's 0.98 / 0.99 %."""
    stage = Stage("KP behind 600 Hz at 4 %, 2 kHz, 0..150 V", KrasnoselskiiPokrovskii(150.0, 67.1, n=20, eps=0.0719),
                  5e-4, (0.0, 150.0), tau_amp=1e-4, fn_hz=600.0, zeta=0.0426, noise_um=0.0144, delay_samples=4,
                  seed=4)
    ctl, tu, checks = _verified(stage)
    assert checks[0]["ratio"] <= FEEDBACK_WORSE_RATIO  # the RMS alone would have kept it
    assert checks[0]["e_max_ratio"] > FEEDBACK_WORSE_EMAX_RATIO, tu.method
    assert checks[-1]["e_max_ratio"] <= FEEDBACK_WORSE_EMAX_RATIO and tu.ki < checks[0]["ki"]
    for freq in (3.0, 5.0):
        # 1.42 / 1.23 % with the gain it had; 1.00 / 1.08 % now
        assert _e_max_last(ctl, stage, freq, learning=True, cycles=8) < 1.15, (freq, tu.method)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::piezohyst.ClippingWarning")
def test_a_loop_steepest_after_reversal_gets_feedback():
    """A census stage of Dahl's model (not tuned on): ki = 0 before, every trial stopped when the
    probe's removal moved the error 4.4 probes' worth; the feedback it gets now helps. (Its loop
    drifts down over the first cycles, so the bottom of the steady range is just out of reach at
    0 V: the runs clip there, the same with and without feedback.)"""
    stage = Stage("Dahl, exponent 0.5, 10 kHz, 0..100 V", Dahl(100.0, 20.0), 1e-4, (0.0, 100.0), tau_amp=2e-4,
                  kv=((0.05, 0.01),), fn_hz=2000.0, zeta=0.05, noise_um=0.004, delay_samples=1)
    ctl, tu, checks = _verified(stage)
    assert not tu.experiments[0]["aborted"], tu.method
    assert checks[-1]["ratio"] <= FEEDBACK_WORSE_RATIO, tu.method
    a, b = steady_range(stage)
    for freq in (1.0, 5.0):
        period = int(round(1.0 / (freq * stage.dt)))
        ff = ctl.track(ph.sinusoid(freq, 3, a, b, stage.dt), feedback=False, learning=False,
                       period=period).e_max_percent
        assert _e_max_last(ctl, stage, freq, learning=False) < ff, (freq, ff, tu.method)


@pytest.mark.slow
def test_learning_keeps_its_band_where_the_tuning_saw_a_resonance():
    """The zoo's Maxwell-slip stage behind a 180 Hz resonance at 1 % damping: the tuning sees an
    oscillation grow, and learning no longer widens its band towards the resonance. It did, in
    mid-run: cycles 6 and 7 of 12 at 5 Hz read 5.56 / 5.41 % e_max before the revert (the last
    three, 0.47 %, hid it); now no cycle after the first exceeds 0.5 % (measured)."""
    from tests.plants.zoo import zoo

    stage = zoo(seed=0)[6]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(stage)
    assert ctl.resonance_seen, ctl.tuning.method
    a, b = steady_range(stage)
    period = int(round(1.0 / (5.0 * stage.dt)))
    out = ctl.track(ph.sinusoid(5.0, 12, a, b, stage.dt), period=period)
    per_cycle = [100.0 * float(np.abs(out.error[k * period:(k + 1) * period]).max()) / (b - a) for k in range(12)]
    assert max(per_cycle[1:]) < 1.0, per_cycle
    assert out.info["learning_cutoff_hz"] == 75.0  # 15 harmonics of 5 Hz, where it started


@pytest.mark.slow
def test_a_hold_flat_after_reversals_is_settled_before_probing():
    """The viscous Maxwell-slip stage (module docstring; not tuned on), tuned with a model of the
    stage as it was (25 um) while it now moves 4 % further (26 um: the feedforward holds the level
    0.25-0.38 um off, under two probes' effect, but 8 V of command away at the slope after a
    reversal): the first trial was stopped before and the halvings kept 1.3 1/s; it is now tried
    again with the hold settled first, and the gain found (149 1/s) helps."""
    from dataclasses import replace

    def stage(stroke_um: float) -> Stage:
        return Stage("viscous Maxwell-slip, 10 kHz, 0..120 V, delay 1", ViscousMaxwellSlip(120.0, stroke_um, 1e-4),
                     1e-4, (0.0, 120.0), tau_amp=2e-4, kv=((0.05, 0.02),), fn_hz=2500.0, zeta=0.05, noise_um=0.006,
                     delay_samples=1, seed=21)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = replace(ph.commission(stage(25.0), tune=False), plant=stage(26.0))
        ctl.tune()
    tu = ctl.tuning
    first = tu.experiments[0]
    assert first["settled_on_retry"] and not first["aborted"] and first["answered"], tu.method
    # a gain of the model's order (149 against ki_model 134 1/s); before, the first trial was
    # stopped and the halvings kept 1.3 1/s
    assert tu.ki > 0.1 * tu.ki_model, tu.method
    a, b = steady_range(ctl.plant)
    for freq in (1.0, 5.0):
        period = int(round(1.0 / (freq * ctl.plant.dt)))
        ff = ctl.track(ph.sinusoid(freq, 3, a, b, ctl.plant.dt), feedback=False, learning=False,
                       period=period).e_max_percent
        assert _e_max_last(ctl, ctl.plant, freq, learning=False) < 0.8 * ff, (freq, ff, tu.method)


@pytest.mark.slow
def test_a_first_trial_too_slow_to_answer_climbs_the_ladder():
    """The viscous Maxwell-slip stage, its ladder started at a fiftieth of the model's gain: the
    first trials answer too slowly to show anything (neither stopped nor overshooting). They used
    to send the ladder down, halving five times into ever slower answers (ki = 0); they now send
    it up, and only an answered trial sets the gain."""
    from piezohyst.control.tuning import SafeTuningOptions

    stage = Stage("viscous Maxwell-slip, 10 kHz, 0..120 V, delay 1", ViscousMaxwellSlip(120.0, 25.0, 1e-4), 1e-4,
                  (0.0, 120.0), tau_amp=2e-4, kv=((0.05, 0.02),), fn_hz=2500.0, zeta=0.05, noise_um=0.006,
                  delay_samples=1, seed=21)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(stage, tuning=SafeTuningOptions(start_fraction=0.02))
    tu = ctl.tuning
    first = tu.experiments[0]
    assert not first["aborted"] and not first["answered"] and not first["well_damped"], tu.method
    climbed = [e for e in tu.experiments if e["ki"] > first["ki"]]
    assert climbed and any(e["answered"] and e["well_damped"] for e in climbed), tu.method
    assert tu.ki > 0.1 * tu.ki_model, tu.method
