"""Feedback tuning: on the plant the paper's way, and safely from the model (``commission``).

**Safe tuning** (:func:`tune_integral_safely`, what :func:`~piezohyst.commission` uses). The gain
comes from the identified model and the measured delay: the small-signal loop of integral feedback
around the model (:func:`small_signal_responses`, :func:`integral_loop_response`) gives the largest
gain with a phase margin of 60 degrees and a gain margin of 3 on every branch of the hysteresis
(a phase-margin rule for an integrator with delay). It is then refined on the plant only by
bounded experiments: small command probes (1 % of the range) at a ladder of gains in small steps,
stopped at the first gain whose answer overshoots the value it settles at (a loop losing its
damping, seen at the probe's amplitude) - never by raising the gain until the loop is unstable.
Its limits are :class:`SafeTuningOptions`.

**Experiment-based tuning** (:func:`tune_integral_feedback`, the method ``piezohyst reproduce``
uses for the paper's experiment, kept as it was). The stage's mechanics are a lightly damped
resonance (the paper's m, b, k: 1.7 kHz, damping ratio 0.0017) that a 1 Hz identification record
cannot see. Proportional and derivative action reach that resonance with little attenuation and
would destabilise the loop, so the feedback around the feedforward is integral-dominant, and its
gain is found by experiment, in the spirit of Ziegler and Nichols' closed-loop method:

1. hold a constant desired displacement (mid-range) through the feedforward, with integral
   feedback of gain ``ki``, for ``hold_s`` seconds, and record the error's RMS over the second
   half;
2. raise ``ki`` geometrically from ``ki_start`` until that RMS exceeds ``growth`` times its
   value at the smallest gain (the loop's resonance is being amplified: the ultimate gain
   ``ki_u``) or the loop goes unstable;
3. use ``ki = ki_u / gain_margin`` (default 3, about 10 dB of gain margin, as Ziegler-Nichols).

It drives the loop to its stability limit (on the VirtualRig the last trial is unstable, with
commands far outside the amplifier's range, which the rig clips): use it only on a simulation, or
where that is acceptable; :func:`tune_integral_safely` is for real stages.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._validation import FloatArray
from .pid import PID
from .tracking import UnstableLoopError, track


@dataclass(frozen=True)
class TuningResult:
    """The tuned gains and what the experiment saw."""

    kp: float
    ki: float
    kd: float
    ki_ultimate: float
    trials: tuple[tuple[float, float], ...]  # (ki, error RMS in µm or overshoot; inf if unstable/aborted)
    method: str
    ki_model: float | None = None
    margins: dict[str, Any] = field(default_factory=dict)
    experiments: tuple[dict[str, Any], ...] = ()
    #: a commissioned controller's checks of the gain on a tracking run
    #: (:meth:`~piezohyst.commissioning.CommissionedController.tune`): ki, the feedback's and the
    #: feedforward's RMS error and e_max and their ratios, one per gain tried
    verification: tuple[dict[str, Any], ...] = ()

    def pid(self, dt: float, **kw: Any) -> PID:
        """A :class:`~piezohyst.control.PID` with these gains at sample period ``dt`` (``kw``: its limits)."""
        return PID(self.kp, self.ki, self.kd, dt, **kw)


def tune_integral_feedback(
    plant: Any, feedforward: Any, *, level: float, hold_s: float = 0.3, ki_start: float = 5.0,
    factor: float = 1.5, growth: float = 3.0, gain_margin: float = 3.0, ki_max: float = 1e5,
    feedback_at: str = "reference", output_scale: float = 1.0,
) -> TuningResult:
    """Find the ultimate integral gain on ``plant`` and return ``ki = ki_u / gain_margin``.

    Parameters
    ----------
    plant : Plant
    feedforward : InversePIFeedforward or BoucWenFeedforward or None
        The feedforward the PID will run with (the loop it tunes is feedback around it).
    level : float
        Desired displacement to hold, µm (mid-range of the task).
    feedback_at, output_scale
        Where the PID's output enters (see :func:`~piezohyst.control.tracking.track`) and a
        factor on its gains (e.g. 1/slope in V/µm for feedback at the command): the returned
        ``ki`` is before that factor.
    """
    n = max(int(round(hold_s / plant.dt)), 20)
    ref = np.full(n, float(level))
    trials: list[tuple[float, float]] = []
    ki = ki_start
    base = None
    ki_u = None
    while ki <= ki_max:
        try:
            out = track(plant, ref, feedforward, PID(0.0, ki * output_scale, 0.0, plant.dt), period=None,
                        feedback_at=feedback_at)
            e = out.error[n // 2:]
            rms = float(np.sqrt(np.mean((e - e.mean()) ** 2)))
        except UnstableLoopError:
            rms = float("inf")
        trials.append((ki, rms))
        if base is None:
            base = rms
        elif not np.isfinite(rms) or rms > growth * base:
            ki_u = ki
            break
        ki *= factor
    if ki_u is None:
        ki_u = ki_max
    return TuningResult(kp=0.0, ki=ki_u / gain_margin, kd=0.0, ki_ultimate=ki_u, trials=tuple(trials),
                        method=f"ultimate integral gain by experiment, ki = ki_u / {gain_margin:g}")


# -- safe tuning: from the model, refined by bounded experiments ---------------------------------------
@dataclass(frozen=True)
class LoopResponse:
    """The frequency response of the integral loop with ``ki = 1`` (``L(w) = ki * loop[w]``).

    ``loops`` holds one response per small-signal linearisation of the model (the command rising
    on from a rising branch, and reversing): the slopes of a hysteretic stage differ between the
    two, and a gain must suit both.
    """

    freqs_hz: FloatArray
    loops: dict[str, FloatArray]
    delay: int
    dt: float

    def margins(self, ki: float) -> dict[str, dict[str, float]]:
        """Phase margin (degrees), gain margin and crossover (Hz) of ``ki * loop`` per branch."""
        return {name: _margins(self.freqs_hz, ki * lp) for name, lp in self.loops.items()}

    def ultimate_ki(self) -> float:
        """The smallest ki at which some branch's loop reaches -180 degrees with gain 1."""
        out = math.inf
        for lp in self.loops.values():
            out = min(out, _ki_for(self.freqs_hz, lp, 1e-9, 1.0))
        return out

    def ki_for(self, phase_margin_deg: float, gain_margin: float) -> float:
        """The largest ki that keeps both margins on every branch."""
        out = math.inf
        for lp in self.loops.values():
            out = min(out, _ki_for(self.freqs_hz, lp, phase_margin_deg, gain_margin))
        return out


def _phase(lp: FloatArray) -> FloatArray:
    return np.unwrap(np.angle(lp))


def _first_crossing(freqs: FloatArray, x: FloatArray, level: float) -> int | None:
    idx = np.flatnonzero(x <= level)
    return int(idx[0]) if idx.size else None


def _interp_at(freqs: FloatArray, x: FloatArray, y: FloatArray, i: int, level: float) -> tuple[float, float]:
    """Linear interpolation of (freq, y) where x crosses ``level`` between samples i-1 and i."""
    if i == 0:
        return float(freqs[0]), float(y[0])
    x0, x1 = x[i - 1], x[i]
    t = 0.0 if x1 == x0 else (level - x0) / (x1 - x0)
    return float(freqs[i - 1] + t * (freqs[i] - freqs[i - 1])), float(y[i - 1] + t * (y[i] - y[i - 1]))


def _ki_for(freqs: FloatArray, lp: FloatArray, pm_deg: float, gm: float) -> float:
    ph = _phase(lp)
    mag = np.log(np.abs(lp))
    ki = math.inf
    i = _first_crossing(freqs, ph, -math.pi + math.radians(pm_deg))
    if i is not None:
        ki = min(ki, math.exp(-_interp_at(freqs, ph, mag, i, -math.pi + math.radians(pm_deg))[1]))
    j = _first_crossing(freqs, ph, -math.pi)
    if j is not None:
        ki = min(ki, math.exp(-_interp_at(freqs, ph, mag, j, -math.pi)[1]) / gm)
    return ki


def _margins(freqs: FloatArray, lp: FloatArray) -> dict[str, float]:
    ph = _phase(lp)
    lmag = np.log(np.abs(lp))
    out = {"phase_margin_deg": math.inf, "crossover_hz": math.nan, "gain_margin": math.inf,
           "phase_crossover_hz": math.nan}
    i = _first_crossing(freqs, lmag, 0.0)  # |L| falls through 1
    if i is not None:
        f, p = _interp_at(freqs, lmag, ph, i, 0.0)
        out["crossover_hz"], out["phase_margin_deg"] = f, math.degrees(p + math.pi)
    j = _first_crossing(freqs, ph, -math.pi)
    if j is not None:
        f, m = _interp_at(freqs, ph, lmag, j, -math.pi)
        out["phase_crossover_hz"], out["gain_margin"] = f, math.exp(-m)
    return out


def _lead_to(u_level: float, u_range: tuple[float, float], dt: float) -> FloatArray:
    """The command that brings a model from rest (0 V, or the nearest end of the range) to
    ``u_level`` along a raised cosine (50 ms, at least 20 samples) and holds it as long."""
    lo, hi = u_range
    n = max(int(round(0.05 / dt)), 20)
    start = min(max(0.0, lo), hi)
    k = np.arange(1, n + 1) / n
    return np.concatenate([start + (u_level - start) * 0.5 * (1 - np.cos(np.pi * k)), np.full(n, u_level)])


def small_signal_responses(model: Any, dt: float, *, u_level: float, u_range: tuple[float, float],
                           length: int | None = None) -> dict[str, FloatArray]:
    """Impulse responses (µm per V per sample) of ``model`` linearised at the command ``u_level``.

    Generic through the model protocol (``predict``): the model is ramped from rest to
    ``u_level`` and held, then a step of 0.1 % of the range is applied up (the branch rising on)
    and down (a reversal); the difference from the run without a step, divided by the step, is
    the step response, its first difference the impulse response. ``length`` samples (default
    0.2 s, at least 256).
    """
    lo, hi = u_range
    span = hi - lo
    n = int(length or max(256, round(0.2 / dt)))
    lead = _lead_to(u_level, u_range, dt)
    step = 1e-3 * span
    runs = {}
    for name, du in (("base", 0.0), ("rising", step), ("reversal", -step)):
        u = np.concatenate([lead, np.full(n, u_level + du)])
        runs[name] = np.asarray(model.predict(u, dt if model.dynamic else None), dtype=np.float64)[lead.size:]
    out = {}
    for name in ("rising", "reversal"):
        s = (runs[name] - runs["base"]) / (step if name == "rising" else -step)
        out[name] = np.diff(np.concatenate([[0.0], s]))
    return out


def large_signal_slope_ratio(model: Any, dt: float, *, u_range: tuple[float, float],
                             impulse: dict[str, FloatArray]) -> float:
    """How much steeper the model's major loop gets than at the linearisation of ``impulse``.

    The integral loop's gain is ``ki * volts_per_um * slope``, and a tracking run sweeps the stage
    along its branches, whose local slope (µm per V) varies with the command and the distance
    from the last reversal: a gain with good margins where the loop was linearised (and probed)
    has less where the branch is steeper. The model is run over two full-range 1 Hz cycles; on the
    second, the slope over 2 % of the range (not a single sample: the hysteresis' and the lags'
    large-signal slope, not noise) is taken wherever the command moves; the ratio of its largest
    value to the steeper of the small-signal gains (the step responses' final values), at least 1.
    """
    steepest = major_loop_steepest_slope(model, dt, u_range=u_range)
    small = max(float(np.sum(h)) for h in impulse.values())
    if not (math.isfinite(steepest) and small > 0):
        return 1.0
    return max(1.0, steepest / small)


def major_loop_steepest_slope(model: Any, dt: float, *, u_range: tuple[float, float]) -> float:
    """The steepest large-signal slope (µm per V) of ``model``'s major loop: the second of two
    full-range 1 Hz cycles, the slope over 2 % of the range wherever the command moves."""
    lo, hi = u_range
    n = max(int(round(1.0 / dt)), 200)
    t = np.arange(2 * n) / n
    u = 0.5 * (lo + hi) - 0.5 * (hi - lo) * np.cos(2 * np.pi * t)
    y = np.asarray(model.predict(u, dt if model.dynamic else None), dtype=np.float64)[n:]
    u = u[n:]
    w = max(int(round(0.02 * n)), 1)
    du, dy = u[w:] - u[:-w], y[w:] - y[:-w]
    moving = np.abs(du) > 0.25 * np.abs(du).max()
    return float(np.max(dy[moving] / du[moving])) if moving.any() else 0.0


def approach_direction(u_level: float, u_range: tuple[float, float], rest: float | None = None) -> float:
    """+1 when a hold at ``u_level`` is reached from rest (``rest``; default 0 V, or the nearest end
    of the range) rising, -1 falling (a stage that rests at the top of its range, or a bipolar one
    held below 0 V)."""
    lo, hi = u_range
    return 1.0 if u_level >= (min(max(0.0, lo), hi) if rest is None else rest) else -1.0


def reversal_chord_slope(model: Any, dt: float, *, u_level: float, u_range: tuple[float, float], step: float,
                         approach: float | None = None) -> float:
    """The model's settled answer (µm per V) to a reversal of ``step`` volts at ``u_level``
    (ramped to from rest, held, then stepped back against ``approach``, the way the stage came:
    +1 rising, -1 falling; default :func:`approach_direction`): the slope a probe of that size
    sees there."""
    lead = _lead_to(u_level, u_range, dt)
    back = -(approach if approach is not None else approach_direction(u_level, u_range)) * step
    runs = []
    for du in (0.0, back):
        u = np.concatenate([lead, np.full(lead.size * 2, u_level + du)])
        runs.append(float(np.asarray(model.predict(u, dt if model.dynamic else None), dtype=np.float64)[-1]))
    return (runs[1] - runs[0]) / back


def integral_loop_response(impulse: dict[str, FloatArray], dt: float, *, delay: int, scale: float,
                           n_freqs: int = 600) -> LoopResponse:
    """``L(w)/ki`` of integral feedback at the command around the model's small-signal responses.

    ``u_fb(k) = scale * I(k)``, ``I(k) = I(k-1) + ki dt e(k)`` with ``e(k) = r - y(k-1)``: the loop
    is ``dt z/(z-1) * scale * H(z) * z^-(delay+1)`` (the measurement used at sample k is the
    previous one, and the plant's output shows ``delay`` samples late).
    """
    n = max(h.size for h in impulse.values())
    f_lo = 1.0 / (n * dt)
    freqs = np.geomspace(f_lo, 0.5 / dt, n_freqs)
    w = 2 * np.pi * freqs * dt
    zinv = np.exp(-1j * w)
    integ = dt / (1.0 - zinv)
    loops = {}
    for name, h in impulse.items():
        k = np.arange(h.size)
        hz = np.exp(-1j * np.outer(w, k)) @ h
        loops[name] = integ * scale * hz * zinv ** (delay + 1)
    return LoopResponse(freqs_hz=freqs, loops=loops, delay=int(delay), dt=float(dt))


@dataclass(frozen=True)
class SafeTuningOptions:
    """The limits of :func:`tune_integral_safely` (keyword argument ``tuning`` of ``commission``).

    Attributes
    ----------
    phase_margin_deg, gain_margin : float
        The model-based gain ``ki_model`` keeps both on every branch (60 degrees and 3, ~10 dB).
    probe_fraction : float
        The command disturbance of each experiment, as a fraction of the range (1 %), applied as
        one step no larger than half the safe layer's step limit.
    start_fraction, gain_step, max_factor : float
        The experiments try ``ki_model * start_fraction * gain_step**j`` up to
        ``ki_model * max_factor`` (and never beyond the model's own ultimate gain divided by
        ``back_off``), both scaled by how much flatter the stage is after a reversal than the
        tracking loop's steep branches (:func:`tune_integral_safely`, step 3), stopping at the
        first gain that is not well damped.
    repeats : int
        Probes (up and down) per gain, averaged: the answer's noise falls as 1/sqrt(2 repeats).
    overshoot_limit : float
        A gain is well damped when the feedback's averaged answer to the probe overshoots the
        value it settles at by no more than this fraction of it (:func:`answer_overshoot`; 0.3:
        about 45 degrees of phase margin for a loop dominated by one pair of poles). A trial is
        aborted at once when the error or the feedback moves four times further than the probe
        explains.
    back_off : float
        The final gain is the largest well-damped one divided by this.
    """

    phase_margin_deg: float = 60.0
    gain_margin: float = 3.0
    probe_fraction: float = 0.01
    start_fraction: float = 0.25
    gain_step: float = 1.25
    max_factor: float = 8.0
    repeats: int = 2
    overshoot_limit: float = 0.3
    back_off: float = 1.5

    def __post_init__(self) -> None:
        if not 0 < self.phase_margin_deg < 90:
            raise ValueError(f"phase_margin_deg must be in (0, 90), got {self.phase_margin_deg}")
        if not self.gain_margin > 1:
            raise ValueError(f"gain_margin must be > 1, got {self.gain_margin}")
        if not 0 < self.probe_fraction <= 0.1:
            raise ValueError(f"probe_fraction must be in (0, 0.1], got {self.probe_fraction}")
        if not 0 < self.start_fraction <= self.max_factor:
            raise ValueError("start_fraction must be > 0 and <= max_factor")
        if not self.gain_step > 1 or not self.back_off >= 1 or not self.overshoot_limit > 0:
            raise ValueError("gain_step must be > 1, back_off >= 1 and overshoot_limit > 0")
        if isinstance(self.repeats, bool) or not (isinstance(self.repeats, int) and self.repeats >= 1):
            raise ValueError(f"repeats must be a positive integer, got {self.repeats!r}")
        for name in ("phase_margin_deg", "gain_margin", "probe_fraction", "start_fraction", "gain_step",
                     "max_factor", "overshoot_limit", "back_off"):
            if not math.isfinite(getattr(self, name)):  # (back_off=inf tuned ki to 0 without a word)
                raise ValueError(f"{name} must be finite, got {getattr(self, name)!r}")


#: An oscillation grows under the feedback (:func:`tune_integral_safely`, step 2) when, in a trial,
#: the error's sample-to-sample RMS after a probe has settled is more than ``RIPPLE_LIMIT`` times
#: the feedforward-alone noise's somewhere, and more than ``RIPPLE_GROWTH`` times the previous
#: probe's the same way somewhere (noise alone: about 1 and 1 +- 0.15).
RIPPLE_LIMIT = 2.0
RIPPLE_GROWTH = 1.3
#: The feedback's averaged answer to a probe must reach at least this share of it within the trial
#: (at least 8 of the loop's nominal time constants) for the trial to show anything: a smaller one
#: means the stage barely answers a reversal at the hold (its loop there nearly open: a stage that
#: goes on falling after a reversal answered 0.00-0.01 of the probe), and its damping on the
#: branches a tracking run climbs is unknown.
MIN_ANSWER = 0.5
#: Seconds the feedforward alone holds the stage after a trial whose oscillation grew.
RING_DOWN_S = 0.5
#: A hold is settled (:func:`tune_integral_safely`, step 2) when its error is within this many
#: times the probe's own effect; a trial that starts further off first lets the feedback take
#: the error out, probe off.
SETTLED_PROBES = 2.0
#: ... and, once the feedback has taken that error out, it is settled when the feedback moved by
#: less than this share of the probe over one more stretch as long as a probe's (a stage still
#: creeping away from the model at the hold keeps the feedback moving: on a saturated P-I stage
#: whose feedforward drifted 0.5 um/s at the hold, the feedback went on moving several probes'
#: worth during the probes, which stopped the first trial twice and buried the answers of the
#: halved ones: ki = 0, no feedback at all), ...
SETTLED_FEEDBACK = 0.25
#: ... for at most this many stretches more.
SETTLE_STRETCHES = 8


def _error_changes(fbs: FloatArray, fb0: float) -> FloatArray:
    """The error's sample-to-sample changes over the second half of a probe segment, in units of
    the integral's gain: read off the integral feedback's outputs (``fb(k) - fb(k-1) = gain e(k)``
    where the integral is not held at a limit)."""
    e = np.diff(np.concatenate([[fb0], fbs]))
    return np.diff(e[e.size // 2:])


def _error_ripple(fbs: FloatArray, fb0: float, gain: float) -> float:
    """The error's sample-to-sample RMS over the second half of a probe segment (:func:`_error_changes`)."""
    if not gain > 0 or fbs.size < 8:
        return 0.0
    return float(np.std(_error_changes(fbs, fb0) / gain))


def ripple_frequency(fbs: FloatArray, fb0: float, dt: float) -> float | None:
    """The frequency (Hz) at which the error ripples over the second half of a probe segment, read
    off the integral feedback's outputs as :func:`_error_ripple` reads its size: the peak of the
    spectrum of the error's sample-to-sample change (Hann window); None on too short a segment.
    Where an oscillation grows under the loop, it is a resonance's frequency.

    >>> import numpy as np
    >>> dt = 1e-4
    >>> k = np.arange(4000)
    >>> fbs = np.cumsum(0.01 * np.sin(2 * np.pi * 60.0 * k * dt) * np.exp(k / 2000))
    >>> round(ripple_frequency(fbs, 0.0, dt))
    60
    """
    if fbs.size < 16 or not dt > 0:
        return None
    d = _error_changes(fbs, fb0)
    spec = np.abs(np.fft.rfft((d - d.mean()) * np.hanning(d.size)))
    if spec.size < 3:
        return None
    k = int(np.argmax(spec[1:])) + 1
    return float(k / (d.size * dt))


def answer_overshoot(answer: FloatArray) -> float:
    """How far the feedback's averaged answer to the probes (:func:`tune_integral_safely`, in
    units of the probe) overshoots the value it settles at (the mean of its last quarter), as a
    fraction of that value: what a loop's damping shows.

    On a linear stage the answer settles at 1 (the feedback cancels the probe exactly) and this is
    its peak less 1. On a hysteretic one it settles elsewhere: a probe up a steep branch, cancelled
    by a command down a flat one after the reversal, takes several times the probe (3.45 on a
    Maxwell-slip stage, whose peak was 3.61: 5 % overshoot, read as 261 % against 1, which stopped
    the ladder at its first gain), and alternating probes ride a minor loop that takes less than
    the probe (0.73 to 0.79 there: a peak 30 % above that read as none). An answer that never
    settles at half the probe shows nothing (``MIN_ANSWER``); it is measured against 1.
    """
    tail = answer[-max(1, answer.size // 4):]
    settled = float(np.mean(tail))
    if not settled >= MIN_ANSWER:
        return float(answer.max()) - 1.0
    return (float(answer.max()) - settled) / settled


def _smooth(x: FloatArray, w: int) -> FloatArray:
    if w <= 1:
        return x
    k = np.ones(w) / w
    return np.convolve(np.concatenate([np.full(w // 2, x[0]), x, np.full(w - 1 - w // 2, x[-1])]), k, "valid")


def hold_at_level(plant: Any, ff: Any, pid: Any, *, n: int, level: float, add: float, check: bool, e0: float,
                  fb0: float, tol_e: float, tol_fb: float, vpu: float, state: dict[str, Any]) -> FloatArray | None:
    """``n`` samples of :func:`tune_integral_safely`'s hold: integral feedback (``pid``, scaled by
    ``vpu``) on the error to ``level``, plus the feedforward of ``level`` and ``add`` (the probe),
    to the guarded ``plant``. The feedback's outputs, or None when ``check`` is on and the error or
    the feedback moved further than ``tol_e`` / ``tol_fb`` from ``e0`` / ``fb0`` (the sample that
    did is done). ``state`` (``y``, ``sat``, ``u_lo``, ``u_hi``) is carried from call to call.
    :func:`piezohyst.control.compiled_loop.run_hold` is this loop compiled."""
    fbs = np.empty(n)
    for k in range(n):
        fb = pid.step(level - state["y"], state["sat"]) * vpu
        u = ff.step(level) + fb + add
        state["y"] = plant.step(u)
        state["sat"] = plant.last_saturation
        state["u_lo"] = min(state["u_lo"], plant.last)
        state["u_hi"] = max(state["u_hi"], plant.last)
        fbs[k] = fb
        if check and (abs((level - state["y"]) - e0) > tol_e or abs(fb - fb0) > tol_fb):
            return None
    return fbs


def tune_integral_safely(
    plant: Any, feedforward: Any, model: Any, *, delay: int, level: float, volts_per_um: float,
    options: SafeTuningOptions | None = None, conditioning: Any = None, rise_s: float = 0.01,
) -> TuningResult:
    """Integral feedback (at the command, in V per µm) tuned from the model, refined on the plant
    by bounded experiments.

    1. **From the model**: the loop's frequency response with the identified model's
       small-signal responses (:func:`small_signal_responses`, both branches), the measured
       ``delay`` and one sample for the measurement; ``ki_model`` is the largest gain with the
       phase margin and the gain margin of ``options`` on every branch (a phase-margin rule for
       an integrator with delay: for ``K e^{-sT}`` it gives ``ki K = (pi/2 - pm) / T``).
    2. **Bounded experiments** on the plant (behind its :class:`~piezohyst.plant.GuardedPlant`):
       from rest, the command ramps smoothly to hold ``level`` µm through the feedforward; then,
       one gain after the other from ``start_fraction * ki_model`` up by ``gain_step``, a command
       step of ``probe_fraction`` of the range is applied and removed ``repeats`` times and the
       feedback's averaged answer (which must cancel the probe) is measured. The ladder stops at
       the first gain whose answer overshoots the value it settles at by more than
       ``overshoot_limit`` of it (:func:`answer_overshoot`: a loop losing its damping, seen at the
       probe's small amplitude; on a hysteretic stage the answer settles above or below the
       probe) or that moves further than the probe can explain (aborted at once), and never goes
       past ``max_factor * ki_model`` or the model's ultimate gain divided by ``back_off``, both times the reversal ratio over the large-signal
       slope ratio (step 3: what the probes' loop at the flat slope after a reversal must show for
       the tracking loop on the steep branches). A probe "explains" an error up to four times its
       effect at the steepest slope the model gives at the hold, either way (a loop that
       saturates after each reversal answers a reversal more steeply than on average). A trial
       that starts with the hold further off the level than :data:`SETTLED_PROBES` times the
       probe's effect at the mean slope (or is stopped with the hold off by less, but by more
       than a probe's command at the slope after a reversal: then once more) (the model off at that level,
       the stage still creeping or drifting) first lets the feedback take that error out, probe
       off, within the same bounds widened by that error (and the command that cancels it, at
       the slope after a reversal: cancelling it may reverse the stage's motion); the
       probes come after, so their answers are answers to the probes and not to the offset
       (without this, every trial on such a stage was aborted and it got no feedback at all).
       A trial whose averaged answer never reaches :data:`MIN_ANSWER` of the probe shows nothing
       (the stage barely answers a reversal at the hold) and does not count as well damped.
       A gain is not well damped either when, once each probe's answer has settled, the error's
       sample-to-sample RMS is more than :data:`RIPPLE_LIMIT` times the feedforward-alone noise
       and grows by more than :data:`RIPPLE_GROWTH` from one probe to the next one the same way:
       an oscillation building under an answer that looks damped (a low, lightly damped
       resonance the model lacks); the stage then rests :data:`RING_DOWN_S` before the next
       trial. The command then ramps back to rest. The loop is never taken near instability, and
       the commands stay within a few probe sizes of the hold (and the settled offset's command).
    3. ``ki`` = min(the largest well-damped gain / the reversal ratio, the ladder's model bound /
       the large-signal slope ratio) / ``back_off``. The probes after the first reverse the one
       before, so the experiments see the stage near a reversal, where a play-type stage is
       several times flatter than on the branches a tracking run climbs; the loop's gain grows with
       the slope. The reversal ratio is the model's major loop's steepest slope over the slope a
       probe sees after a reversal (:func:`major_loop_steepest_slope`,
       :func:`reversal_chord_slope`): a gain the probes found well damped holds for tracking
       divided by it. So the ladder climbs until the probes' loop is as strong as the tracking
       loop would be at the model's bound (the model's own margins divided by the large-signal
       slope ratio, :func:`large_signal_slope_ratio`): a resonance the model lacks then shows in
       the probes before it can ring in tracking. When already the first gain
       is not well damped (the model overestimates what the plant takes: an unmodelled
       resonance, more delay), the gain is halved until it is, at most five times (else
       ``ki = 0``: no feedback).

    Parameters
    ----------
    plant : GuardedPlant
        A plant driven sample by sample, behind the safe layer.
    feedforward : Compensator
        The model's compensator (the loop it tunes is feedback around it).
    model : HysteresisModel
        The identified model (for ``predict``).
    delay : int
        The identified delay, samples.
    level : float
        Desired displacement to hold, µm.
    volts_per_um : float
        The feedback's output scale (the model's mean inverse slope).
    conditioning : array_like, optional
        A conditioning sweep's command (V, from rest) that the experiments start with, followed
        through the model by the feedforward (as a commissioned controller's runs start with
        it); the rise from its end to ``level`` then lasts at least ``rise_s`` seconds.
    """
    from .compiled_loop import run_hold
    from .pid import PID
    from .tracking import lead_in_after, lead_in_from_rest

    opt = options or SafeTuningOptions()
    dt = plant.dt
    lim = plant.limits
    ff = feedforward
    # -- 1. from the model
    u_level = float(ff.command(np.full(max(int(round(0.05 / dt)), 20), level))[-1])
    u_level = min(max(u_level, lim.low), lim.high)
    impulse = small_signal_responses(model, dt, u_level=u_level, u_range=(lim.low, lim.high))
    resp = integral_loop_response(impulse, dt, delay=delay, scale=volts_per_um)
    slope_ratio = large_signal_slope_ratio(model, dt, u_range=(lim.low, lim.high), impulse=impulse)
    ki_model = resp.ki_for(opt.phase_margin_deg, opt.gain_margin)
    ki_u_model = resp.ultimate_ki()
    if not math.isfinite(ki_model) or ki_model <= 0:
        raise ValueError("the model's loop response gives no usable integral gain")
    pc = [m["phase_crossover_hz"] for m in resp.margins(ki_model).values() if math.isfinite(m["phase_crossover_hz"])]
    f_pc = min(pc) if pc else 0.05 / dt
    ki_top = min(opt.max_factor * ki_model, ki_u_model / opt.back_off)
    # The probes after the first reverse the one before, so the experiments see the stage near a
    # reversal, where a play-type stage is several times flatter than on the branch a tracking run
    # climbs (``reversal_ratio``: the major loop's steepest slope over the slope a probe sees
    # there). A gain the probes find well damped is proven for tracking only divided by that
    # ratio: an unmodelled resonance that the probes' loop keeps damped can ring in the tracking
    # loop, whose gain is that much larger. So the ladder climbs until the probes' loop is as
    # strong as the tracking loop at the model's bound (``ki_top`` at the model's linearisation):
    # no further into the model's margins than before, and any resonance the model lacks shows.
    probe = min(opt.probe_fraction * lim.span, 0.5 * lim.max_step)
    # the reversal a probe makes at the hold is against the way the hold was reached: from rest
    # (a stage may rest at the top of its range, or a bipolar one hold below 0 V: reached falling)
    # or, after a conditioning sweep, rising from the bottom. (Sending the first probe the same way
    # too, so that it sees the branch the stage was on, was tried: on stages held after a fall it
    # stopped the ladder at a quarter of the gain and left feedback and learning worse, 1.24 ->
    # 2.24 % at 3 Hz on a relay stage on -10..10 V.)
    toward = 1.0 if conditioning is not None else approach_direction(u_level, (lim.low, lim.high), lim.rest)
    chord = reversal_chord_slope(model, dt, u_level=u_level, u_range=(lim.low, lim.high), step=probe,
                                 approach=toward)
    steepest = major_loop_steepest_slope(model, dt, u_range=(lim.low, lim.high))
    reversal_ratio = max(1.0, steepest / chord) if chord > 0 and math.isfinite(steepest) else slope_ratio
    reversal_ratio = max(reversal_ratio, slope_ratio)
    ki_ladder_top = ki_top * reversal_ratio / slope_ratio
    # -- 2. bounded experiments, one continuous session (up to ki_ladder_top)
    plant.reset()
    if conditioning is not None:
        desired, cmd = lead_in_after(ff, model, conditioning, level, lim, dt, rise_s=rise_s)
    else:
        desired, cmd = lead_in_from_rest(ff, model, level, lim, dt)
    settle = max(int(round(0.05 / dt)), 20)
    desired = np.concatenate([desired, np.full(settle, level)])
    ys = np.empty(desired.size)
    try:
        plant.ramp_to(float(cmd[0]))
        ff.reset()
        for k, x in enumerate(desired):
            ys[k] = plant.step(ff.step(float(x)))
    except BaseException:
        plant.back_to_rest()  # (a fault here left the stage at the hold's voltage: found by fuzzing)
        raise
    noise = float(np.std(np.diff(ys[-settle:])) / math.sqrt(2.0))
    ripple0 = math.sqrt(2.0) * noise  # the error's sample-to-sample RMS with the feedforward alone
    volts_per_um_reversed = max(volts_per_um, 1.0 / chord) if chord > 0 else volts_per_um
    y_probe = probe / volts_per_um  # µm the probe moves the stage, roughly
    # ... and at most: the probes reverse the stage and move it on, and a loop that saturates
    # after each reversal (concave branches: Dahl- or Bouc-Wen-like) answers a reversal several
    # times more steeply than its mean slope (a Dahl stage: 0.93 um/V after a reversal against
    # 0.21 on average, so every probe's removal moved the error 4.4 probes' worth and every
    # trial was aborted: no feedback at all). The bound on the error allows the steepest of the
    # model's answers at the hold, either way.
    onward = reversal_chord_slope(model, dt, u_level=u_level, u_range=(lim.low, lim.high), step=probe,
                                  approach=-toward)
    y_probe_most = probe * max(1.0 / volts_per_um, chord, onward)
    tol_e, tol_fb = 4 * y_probe_most + 10 * noise, 4 * probe
    pid = PID(0.0, opt.start_fraction * ki_model, 0.0, dt)
    trials: list[tuple[float, float]] = []
    experiments: list[dict[str, Any]] = []
    state: dict[str, Any] = {"y": float(ys[-1]), "sat": 0, "u_lo": math.inf, "u_hi": -math.inf}

    def run(n: int, probe_on: bool, fb0: float, e0: float, check: bool, offset: float = 0.0,
            fb_room: float = 0.0) -> FloatArray | None:
        """n samples at the hold; the feedback's outputs, or None if the trial had to stop. With
        ``offset`` (µm: the hold's error the feedback is to cancel) the error may move that much
        further, and the feedback the command that cancels it: against the branch the stage came
        up or down, the command moves as far as the slope after a reversal asks (on a play-type
        stage several times the mean inverse slope). With ``fb_room`` (V) the feedback may move
        that much further (a hold still settling: as far as it moved over the stretch before)."""
        kw = dict(n=n, level=level, add=probe if probe_on else 0.0, check=check, e0=e0, fb0=fb0,
                  tol_e=tol_e + abs(offset), tol_fb=tol_fb + abs(offset) * volts_per_um_reversed + fb_room,
                  vpu=volts_per_um, state=state)
        fast = run_hold(plant, ff, pid, **kw)  # the same loop, compiled, where the parts have kernels
        return hold_at_level(plant, ff, pid, **kw) if fast is NotImplemented else fast  # type: ignore[no-any-return]

    def trial(ki: float) -> bool:
        """Probe the loop at gain ki; True when it is well damped (:func:`silent` after a False:
        it showed nothing either way)."""
        pid.ki = ki
        # long enough to settle (8 / ki) and to see ten periods of a loop oscillating where the
        # model's phase reaches -180 degrees
        n_p = int(min(max(math.ceil(8.0 / (ki * dt)), math.ceil(10.0 / (f_pc * dt)), 100),
                      max(round(0.25 / dt), 100)))
        for settle_anyway in (False, True):  # True: the second attempt of a trial stopped by an unsettled hold
            answers = []
            ringing: list[float] = []  # per probe segment: the error's sample-to-sample RMS, second half
            ripple_hz: list[float | None] = []  # ... and the frequency it ripples at
            aborted = False
            integral0 = pid.integral
            state["u_lo"], state["u_hi"] = math.inf, -math.inf
            offset = level - state["y"]
            settle = settle_anyway or abs(offset) > SETTLED_PROBES * y_probe
            if settle:
                # the feedforward alone holds the level with an error larger than the probe's effect
                # (a model off at this level, the stage still creeping): the feedback first takes it
                # out, probe off, so that the probes' answers are answers to the probes
                fb0 = pid.integral * volts_per_um
                fbs = run(n_p, False, fb0, offset, True, offset=offset)
                aborted = fbs is None
                # then until the feedback stops moving, each stretch allowed to move it as far as
                # the one before did (the error stays bounded as in any trial)
                moved = 0.0 if fbs is None else abs(float(fbs[-1]) - fb0)
                for _ in range(0 if aborted else SETTLE_STRETCHES):
                    if moved <= SETTLED_FEEDBACK * probe:
                        break
                    fb0 = pid.integral * volts_per_um
                    fbs = run(n_p, False, fb0, level - state["y"], True, fb_room=moved)
                    if fbs is None:
                        aborted = True
                        break
                    moved = abs(float(fbs[-1]) - fb0)
            for rep in range(0 if aborted else 2 * opt.repeats):
                sign = 1.0 if rep % 2 == 0 else -1.0  # probe on, then off
                fb0 = pid.integral * volts_per_um
                fbs = run(n_p, sign > 0, fb0, level - state["y"], True)
                if fbs is None:
                    aborted = True
                    break
                # the feedback cancels the probe: its answer runs from 0 towards 1 (of the probe)
                answers.append(-sign * (fbs - fb0) / probe)
                ringing.append(_error_ripple(fbs, fb0, ki * dt * volts_per_um))
                ripple_hz.append(ripple_frequency(fbs, fb0, dt))
            if aborted:  # back to where the trial began, probe off, feedforward alone, and settle
                pid.integral = integral0
                pid.ki = 0.0
                run(n_p, False, 0.0, 0.0, False)
                if not settle and abs(offset) * volts_per_um_reversed > probe:
                    # the probes started on a hold whose error, small against the probe's effect
                    # at the mean slope, takes more than a probe of command to cancel on the flat
                    # slope after their reversals, and that may be what stopped them (a viscous
                    # Maxwell-slip stage: 0.3-0.4 um took 11 V against a 1.2 V probe, and every
                    # trial was stopped: no feedback at all): once more, the hold settled first
                    pid.ki = ki
                    continue
                overshoot, peak = math.inf, math.nan
            else:
                mean = _smooth(np.mean(answers, axis=0), max(1, int(round(0.5 / (ki * dt)))))
                overshoot, peak = answer_overshoot(mean), float(mean.max())
            break
        # a loop that amplifies a resonance the model does not have: the probe's answer can look
        # well damped while an oscillation grows underneath it, from the sensor's noise, over
        # the trial (a 180 Hz, 1 % damped stage: overshoot 0.18 at a gain whose oscillation
        # doubled every 50 ms and ended the tracking run). Its mark: the error's sample-to-sample
        # RMS, once each probe's answer has settled, well above the feedforward-alone noise and
        # growing. The probes go up and down in turn, and a hysteretic stage's slope (the loop's
        # gain) differs between the two: each probe is compared with the last one the same way.
        ripple = max(ringing) / ripple0 if ringing and ripple0 > 0 else 0.0
        growth = max((ringing[j] / ringing[j - 2] for j in range(2, len(ringing)) if ringing[j - 2] > 0), default=1.0)
        grows = ripple > RIPPLE_LIMIT and growth > RIPPLE_GROWTH
        if grows:  # as after an abort: the trial's own integral, the feedforward alone, and settle
            # for long enough that the next trial starts from noise, not from this one's ringing
            # (a resonance the loop had driven rings down slowly: 88 ms per e-fold at 180 Hz, 1 %)
            pid.integral = integral0
            pid.ki = 0.0
            run(max(n_p, int(round(RING_DOWN_S / dt))), False, 0.0, 0.0, False)
        answered = aborted or peak >= MIN_ANSWER
        ok = overshoot <= opt.overshoot_limit and not grows and answered
        trials.append((ki, overshoot))
        experiments.append({"ki": ki, "overshoot": None if aborted else overshoot, "aborted": aborted,
                            "answered": answered, "answer_peak": None if aborted else peak,
                            "samples": n_p, "well_damped": ok, "probe_V": probe,
                            "command_band_V": (state["u_lo"], state["u_hi"]),
                            "hold_error_um": offset, "settled_first": settle, "settled_on_retry": settle_anyway,
                            "ripple_over_noise": ripple, "ripple_growth": growth, "oscillation_grows": grows,
                            # where it grows: the resonance's frequency, from the segment that rippled most
                            "oscillation_hz": ripple_hz[int(np.argmax(ringing))] if grows else None,
                            "ripples": [r / ripple0 if ripple0 > 0 else 0.0 for r in ringing]})
        return ok

    def silent() -> bool:
        """The last trial neither aborted, nor overshot, nor grew an oscillation, but the stage
        did not answer half its probe within the trial (the loop, flat after the probes'
        reversals, too slow at that gain to show its damping): it proved nothing either way."""
        e = experiments[-1]
        return (not e["aborted"] and not e["answered"] and not e["oscillation_grows"]
                and e["overshoot"] <= opt.overshoot_limit)

    ki_ok = 0.0
    finished = False
    try:
        ki = opt.start_fraction * ki_model
        first = trial(ki)
        if first or silent():  # up the ladder while the loop stays well damped (or shows nothing yet)
            ki_ok = ki if first else 0.0
            while ki * opt.gain_step <= ki_ladder_top * (1 + 1e-9):
                ki *= opt.gain_step
                if trial(ki):
                    ki_ok = ki
                elif ki_ok > 0 or not silent():
                    break
        else:  # the model overestimates what the plant takes: down, halving, at most five times
            for _ in range(5):
                ki *= 0.5
                if trial(ki):
                    ki_ok = ki
                    break
        finished = True
    finally:
        # back to rest, smoothly, whatever happened; after a fault the fault is what is raised
        if finished:
            plant.ramp_to(lim.rest)
        else:
            plant.back_to_rest()

    # What the experiments proved holds for tracking divided by the reversal ratio; what the model
    # allows (ki_top, its margins at its linearisation) divided by the large-signal slope ratio.
    # When the ladder reached its top these agree with the model's bound alone; when the plant
    # stopped it (a trial not well damped or aborted, an oscillation growing), the experiments
    # decide. (Before the ladder climbed this far, a Maxwell-slip stage with a 384 Hz resonance at
    # 3 % damping kept ki 456 1/s and tracked oscillating at the resonance, 8 % e_max with feedback
    # against 1.5 % without; and a play-type stage behind a 250 Hz resonance at 5 % damping and 12
    # samples of delay, whose probes stayed well damped up to the model's bound, kept 574 1/s and
    # tracked at 3.7 / 5.8 / 9.5 % with feedback, the loop between the amplifier's limits at 5 Hz.)
    plant_limited = any(not e["well_damped"] for e in experiments)  # (a growing oscillation is not well damped)
    ki_final = min(ki_ok / reversal_ratio, ki_top / slope_ratio) / opt.back_off
    margins = resp.margins(ki_final) if ki_final > 0 else {}
    if ki_final > 0:  # the same loop where the major loop is steepest
        margins["steepest"] = _margins(resp.freqs_hz, ki_final * slope_ratio * max(resp.loops.values(),
                                                                                    key=lambda lp: abs(lp[0])))
    method = (f"integral gain from the model (phase margin {opt.phase_margin_deg:g} deg, gain margin "
              f"{opt.gain_margin:g}, delay {delay} + 1 samples): ki_model = {ki_model:.4g}; bounded experiments "
              f"(probe {probe:.3g} V, overshoot <= {opt.overshoot_limit:g}) well damped up to {ki_ok:.4g}; "
              f"ki = min({ki_ok:.4g} / reversal ratio {reversal_ratio:.3g}, {ki_top:.4g} / large-signal slope "
              f"ratio {slope_ratio:.3g}) / {opt.back_off:g}"
              f"{': the experiments found the limit' if plant_limited else ''}")
    return TuningResult(kp=0.0, ki=ki_final, kd=0.0, ki_ultimate=ki_u_model, trials=tuple(trials),
                        method=method, ki_model=ki_model, margins=margins, experiments=tuple(experiments))
