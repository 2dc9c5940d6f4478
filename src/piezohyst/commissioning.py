"""Commissioning a stage: identify it, build the best feedforward and feedback, track (beyond the paper).

``ctl = commission(plant)`` runs an identification experiment on any object that follows the
Plant protocol (``reset()``, ``step(u)``: a per-sample loop) or the BufferedPlant protocol
(``play(table)``: a wave-table controller or a buffered DAQ), and returns a
:class:`CommissionedController` whose ``ctl.track(reference)`` returns a
:class:`~piezohyst.control.tracking.TrackingResult`. Nothing here assumes the plant is the
:class:`~piezohyst.rig.VirtualRig`: it is how a user commissions a real stage.

**Safety first.** Everything sent to the stage passes the safe layer of :mod:`piezohyst.plant`:
commands stay inside the amplifier's range and change by at most ``max_step_fraction`` of the range
per sample (default 2 %: 2 V per sample on 0-100 V, more below 2 kHz sampling, see
:func:`~piezohyst.plant.default_step_fraction`; change it with ``commission(...,
max_step_fraction=...)``, the range with ``u_range=...``, the command a plant that has not been
driven yet holds with ``u_rest=...``). The experiments are designed inside those limits (the
guard counts what it had to change, ``ctl.info["safety"]``; it is zero for the built-in
experiments); a user's own ``excitation`` that is not is refused, not altered.

What it does, and why (the contribution of each step is measured in ``piezohyst reproduce``'s
ablation and in ``tests/test_commission.py``):

1. **Identification experiment** (:func:`commissioning_excitation`, ~11 s): for fitting, a slow
   approach from rest (0 V, or the nearest end of the range) to the bottom of the range (the
   initial loading curve, which a tracking run from rest starts on), a full-range 1 Hz sinusoid
   (major loop), a 2 Hz sinusoid of decaying amplitude (nested minor loops: every threshold is
   exercised), full-range 5 and 10 Hz sinusoids (rate dependence) and a hold at mid-range
   (creep); for choosing among the candidate models, other frequencies and amplitudes over the
   same band (3 Hz, 1.5 Hz decaying, 7 Hz), so the choice rewards what carries over rather than
   what fits. Every change of segment is a raised-cosine ramp, no sinusoid is faster than the
   step limit allows at the plant's sample rate, and the table ends back at rest. Within the
   amplifier range the plant reports (``plant.u_range``) or the one given. A buffered plant
   plays it as one table (from the command it holds).
2. **Model**: chosen on held-out data among every linear kind and structure
   (:func:`~piezohyst.identify.fit_model`): P-I, asymmetric P-I, Preisach, Bouc-Wen hysteresis or
   generalised Duhem (Coleman-Hodgdon), with an input lag
   (amplifier + stack) and output lags (rate dependence, creep) where they predict better, the
   sensor delay searched over what the data show; each candidate is one bounded least-squares
   fit, invertible with a stable inverse by construction (:mod:`piezohyst.identify.linear`).
3. **Feedforward**: the model's compensator (its exact or numerical inverse), fed the
   reference ``delay`` samples ahead (the reference is known in advance; this cancels the
   sensor's delay). Every run starts with a lead-in: the desired displacement ramps from rest to
   the reference's first value slowly enough that the commands stay inside the step limit. From
   a rest above the bottom of the range (a bipolar range, or one that excludes 0 V) the command
   first goes down to the bottom (at least 0.25 s), as the identification run does, and the
   feedforward follows that through the model: going to the bottom wipes out the memory of the
   hysterons below the rest, in the stage whatever state its reset left, and in the model
   whatever state it assumes at rest (demagnetised), which the fit never checked, since the
   identification run leaves rest for the bottom first. (A Krasnosel'skii-Pokrovskii stage with
   hysterons over 0..180 V on a -30..150 V amplifier: feedforward 1.92 / 2.06 / 2.15 % e_max at
   1 / 3 / 5 Hz straight from rest, the model's hysterons below 0 V left demagnetised; 0.69 /
   0.56 / 0.61 % via the bottom; the zoo's and the census's bipolar stages moved by 0.11 % at
   most, either way.) With
   ``commission(..., conditioning=True)`` (or per run ``track(..., conditioning=True)``) a
   conditioning sweep comes first (:func:`conditioning_sweep`: from rest to the top of the range
   and the bottom, then a rise to the first target, at least 0.25 s per leg); it wipes out the
   stage's memory of whatever it did before, and the feedforward follows it through the model,
   so stage and model start the run in the same state. The identification run and the tuning's
   experiments then start with it too, and the fit runs its candidates through it without
   fitting it (``fit_model``'s ``warmup``): the model's initial state need not be the stage's.
   Without it, a run starts from the plant's state after ``reset()`` and the model's initial
   one, which agree only where reset restores the state the identification started from; a
   real stage's "reset" only returns the command to rest, and a stage resting mid-range keeps
   the memory of its last runs. Measured on the zoo (feedforward alone, e_max % of span at
   1/3/5 Hz, without -> with): the asymmetric Bouc-Wen stage when its reset keeps that memory
   1.88/2.63/3.35 -> 0.80/0.64/0.88 (and every stage within 0.03 of its figures from a true
   reset); from a true reset, dead zone 1.61/1.33/1.48 -> 0.90/0.63/0.97, falling after reversal
   0.87/1.00/1.22 -> 0.92/0.98/1.00, Duhem 0.26/0.23/0.24 -> 0.25/0.19/0.20 (1.04/1.16/1.30, a
   Preisach model, before a warm-up pinned the Duhem model's level at rest:
   :data:`~piezohyst.identify.linear.DUHEM_REST_PIN`), asymmetric
   Maxwell-slip 0.21/0.17/0.20 -> 0.26/0.21/0.22. It is off by default: it drives the stage over
   its full stroke before every run, and on the VirtualRig (whose reset is a true one) it costs:
   0.67/0.56/0.58 -> 0.80/0.65/0.64, and the tuned integral gain falls from 881 to 16 1/s (with
   the model it then chooses, a 40-operator P-I model, the tuning's first trial already overshoots,
   and a gain the plant limits is scaled for the steepest branch; with feedback 0.68/0.67/0.56 ->
   0.74/0.63/0.62).
4. **Feedback** (plants with a per-sample loop only): integral action added to the *command*,
   scaled by the model's mean inverse slope (V per µm), with anti-windup on the range. Its gain
   comes from the identified model and the measured delay (a phase-margin rule on the model's
   small-signal loop), refined on the plant only by bounded experiments that stop at the first
   sign of poor damping (:func:`~piezohyst.control.tuning.tune_integral_safely`; options in
   :class:`~piezohyst.control.tuning.SafeTuningOptions`, ``commission(..., tuning=...)``). Not
   to the feedforward's input: the inverse of the input lag is a lead with a high-frequency gain
   of ``1/(1-b)`` (8.5 for 0.8 ms at 10 kHz) that would hand the feedback's noise and the stage's
   resonance back to the loop amplified. The tuned gain is then checked where the experiments at
   a hold cannot look, on the branches a tracking run climbs (:meth:`CommissionedController.tune`):
   a 5 Hz sinusoid over 10-90 % of the identified stroke, tracked with the feedback and with the
   feedforward alone; where the feedback's RMS error is more than :data:`FEEDBACK_WORSE_RATIO`
   times the feedforward's, or its e_max more than :data:`FEEDBACK_WORSE_EMAX_RATIO` times, the
   gain is halved (at most :data:`VERIFY_HALVINGS` times, then no feedback). Found on two
   Maxwell-slip stages with a lightly damped resonance (1 kHz at 2.8 %, 180 Hz at 1 %): the
   probes at the hold stayed well damped, but on the steep part of the rising branch the loop
   rang at the resonance, and tracking with feedback was worse than without (5 Hz: e_max 1.80
   against 0.65 %, 0.72 against 0.42 %); on 31 other stages and the rig the RMS ratio was
   0.05-1.12. A plant that only plays tables has no per-sample loop:
   it gets no feedback, and its results say so (``info["feedback"]`` is False with the reason).
5. **Iterative learning** for references that repeat. On a per-sample plant, after each cycle
   the measured error corrects the feedforward's input for the next one, ``c <- Q(c + gamma e)``,
   with ``Q`` a zero-phase low-pass (cut-off ``ilc_cutoff_hz``, default 15 harmonics of the
   reference, at least 50 Hz, to begin with). On a buffered plant the same rule runs across plays
   of the whole table (play, measure, correct, play again; at most ``max_plays``). It converges
   when ``|Q(w)| |1 - gamma G(w)| < 1`` wherever Q passes, G being the response of the output to
   the correction; with the model's inverse in the loop ``G ~ 1`` below the cut-off, so
   ``gamma = 0.5`` gives a contraction of about 0.5 per cycle. Where the integral feedback acts
   within the reference's band (its crossover above the reference's fundamental:
   :func:`correction_into_feedback`), the correction shifts the feedback's reference as well as
   the feedforward's input (the feedback follows ``r + c``): added to the feedforward alone, it
   is a disturbance the integral feedback cancels below its bandwidth, ``G = P F / (1 + L)``, and
   learning slowed as the gain rose (with feedback and learning at 1/3/5 Hz: 0.30/0.64/0.70 %
   against 0.36/0.69/1.16 % on a rate-dependent slip stage, 1.59 against 1.97 % at 1 Hz on a
   bipolar Jiles-Atherton one, 0.14/0.18/0.15 against 0.22/0.18/0.30 % on the zoo's asymmetric
   Bouc-Wen stage; on the rig with a mismatched model, the cycle RMS 3.8-3.9 nm against 5.0-5.1
   nm after eight cycles). Where G is not ~1 (above an
   unmodelled resonance, where the loop is flat after reversals) it does not, and what decides is
   the figure of merit: on a per-sample plant every cycle is judged on its e_max against the best
   cycle so far, whose correction is kept. A cycle that improves little means the error left in
   the band is learnt: the band doubles (the error's sharp repeatable features, such as the corners
   at reversals, lie above 15 harmonics), up to ``MAX_CUTOFF_FRACTION`` (5 %) of the sample rate,
   a tenth of Nyquist, where one sample of delay misjudged costs 18 degrees of phase; but not
   where the identified loop is flat (or falls) just after reversals (the fit's slope there at
   its floor, ``fit.info["floor_at_margin"]``, which the fit also warns of): there G is near zero
   or negative exactly where those features are, learning them does not converge, and a widened
   band turned single cycles 50-80 % worse on such a stage (on the zoo's "falling after reversal"
   stage, over four noise seeds, the worst e_max with feedback and learning was 1.20 % with
   widening, 1.02 % without); nor in a run's last cycles: a widening is tried only while five
   cycles are left (the one it is tried in, the one after a revert, which still carries its
   transient, and three more), so a run's last three cycles never carry a failed one (the zoo's
   Maxwell-slip stage behind a 180 Hz resonance, 12 cycles at 3 Hz: its band widened past the
   resonance three cycles before the end, and the last three cycles read 0.15 / 0.71 / 0.66 %
   against 0.15 / 0.14 / 0.13 % then; a stage with two structural modes at 5 Hz, with a widening
   tried four cycles before the end: 4.34 / 4.16 / 0.66 % against 0.70 / 0.66 / 0.66 %); nor
   where the tuning's experiments saw an oscillation grow (a low, lightly damped resonance the
   model lacks, :attr:`CommissionedController.resonance_seen`): there the widened
   band reached the resonance in mid-run and rang it, two cycles at 5.4-5.6 % e_max in a 5 Hz run
   of that stage (0.47 % before and after) and 5.3 % on a census stage with the same resonance and
   logarithmic creep, before the revert. And wherever the identification run shows a lightly
   damped structural mode that the model leaves out (:attr:`CommissionedController.structural_mode`,
   by an output-error fit of one second-order mode after the model's prediction), the band, from
   its start to its widest, stays below half the mode's frequency: a 300 um stage whose payload
   puts its first mode at 60 Hz (2 % damping) ended 12 cycles of feedback and learning at 5.6 /
   11.9 % e_max at 1 / 5 Hz with the default band (50 Hz widened to 100 Hz; 75 Hz from the start),
   0.71 / 2.15 % with the band below 30 Hz (the feedforward alone: 2.5 / 5.0 %; at 5 Hz the mode
   rings at the reference's 12th harmonic, beyond what learning may reach). Such a stage's model
   is then fitted ahead of the mode, and the feedforward inverts it (:func:`_fit_ahead_of_mode`:
   the feedforward alone 2.47 / 4.97 -> 0.14 / 0.88 %). The band also stays below half the
   frequency of an oscillation the tuning's experiments saw grow
   (:attr:`CommissionedController.resonance_hz`), where the identification run showed no mode. A cycle worse
   than the best by more than 15 % restores the best correction and either narrows the band back
   (if it had been widened since) or halves the gain: what is left then does not repeat (noise, a
   loop that hunts), and a smaller gain averages it over cycles instead of copying it into the
   correction; after three halvings, or three cycles in a row without a new best (converged: what
   is left does not repeat), learning stops with the best correction. Where the best correction,
   restored, does not give its cycle's figure back (a lucky noisy cycle, a stage that drifts), that
   figure was not the learning's doing: the cycle becomes the new baseline and learning goes on
   (:class:`_Learning`). The run's ``info`` lists
   every cycle's RMS and e_max, the final gain and band. On a buffered plant learning stops (the best play is
   kept) as soon as a play's RMS error is no longer below 0.95 times the best so far.
"""

from __future__ import annotations

import math
import threading
import time
import warnings
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, Callable, Sequence

import numpy as np

from ._validation import FloatArray, as_count, as_flag, as_scalar, as_signal
from .control.tracking import (LoopWatch, TrackingResult, UnstableLoopError, _check_period, lead_in_after,
                               lead_in_from_rest, output_still)
from .control.tuning import SafeTuningOptions, TuningResult, tune_integral_safely
from .data import Dataset
from .identify import FitResult, fit_model
from .identify.select import MODE_SEARCH_TOP, structural_mode_search
from .identify.monotone import (DEAD_BINS, WEAK_CORRELATION, DeadRange, DeadRangeWarning, MonotoneRange,
                                NotMonotoneWarning, dead_range, monotone_range, rising_part, butterfly_hint)
from .models.base import Compensator, kind_class, kind_of
from .plant import (CommandLimits, GuardedPlant, check_plant, check_table, checked_excitation,
                    default_step_fraction, plant_mode, plant_u_range, stuck_reading)
from .signals import (estimate_period, mode_inverse, noise_e_max, second_order_filter,
                      sensor_noise_rms, sensor_resolution, sinusoid, transfer_peak_mode)

#: The kinds commissioning chooses from: fast to fit, each with an exact or numerical inverse.
COMMISSION_KINDS = ("prandtl-ishlinskii", "rate-dependent", "asymmetric-pi", "preisach", "bouc-wen-hysteresis",
                    "generalized-duhem")
#: What a result says when a plant has no per-sample loop.
NO_LOOP = ("no feedback: the plant only plays tables (BufferedPlant), so there is no per-sample loop to "
           "close; learning across plays corrects the feedforward instead")


#: Samples a period of the excitation's slowest sinusoid (1 Hz) at least: commissioning needs
#: this many samples a second.
EXCITATION_SAMPLES_PER_PERIOD = 20
#: The excitation's length, about (s), whatever the sample rate.
EXCITATION_SECONDS = 10.5


def _check_excitation_dt(dt: float) -> None:
    """A clear error for a sample period commissioning's excitation cannot use."""
    from .signals import MAX_SAMPLES

    if dt > 1.0 / EXCITATION_SAMPLES_PER_PERIOD:
        raise ValueError(
            f"the plant's dt is {dt:g} s ({1.0 / dt:.3g} Hz sampling): commissioning needs at least "
            f"{EXCITATION_SAMPLES_PER_PERIOD} Hz (its slowest excitation is a 1 Hz sinusoid, "
            f"{EXCITATION_SAMPLES_PER_PERIOD} samples a period). Is dt in seconds? For a slower stage, "
            "identify a record of your own with fit_model()")
    if EXCITATION_SECONDS / dt > MAX_SAMPLES:
        raise ValueError(
            f"the plant's dt is {dt:g} s ({1.0 / dt:.3g} Hz sampling): commissioning's excitation (about "
            f"{EXCITATION_SECONDS:g} s) would be {EXCITATION_SECONDS / dt:.3g} samples, more than "
            f"piezohyst.signals.MAX_SAMPLES ({MAX_SAMPLES:.3g}). Is dt in seconds?")


def _fastest_full_range_hz(limits: CommandLimits, dt: float) -> float:
    """The fastest full-range sinusoid whose command changes by at most half the step limit per
    sample: one of f Hz changes by at most ``pi f dt (high - low)``."""
    return 0.5 * limits.max_step / (math.pi * dt * limits.span)


def _excitation_parts(dt: float, limits: CommandLimits) -> tuple[list[FloatArray], list[FloatArray]]:
    """The segments fitted on and the segments chosen on (module docstring, step 1)."""
    _check_excitation_dt(dt)
    lo, hi = limits.low, limits.high
    mid, amp = 0.5 * (lo + hi), 0.5 * (hi - lo)
    # no sinusoid faster than the step limit allows. (At low sample rates the faster ones are
    # left with a few samples a period: as commands, steps between far-apart levels, which excite
    # a hysteresis as well as a sinusoid; capping them at 20 samples a period lost a P-I plant's
    # exact fit at 20 Hz sampling, 0 -> 4.4 % e_max.)
    f_cap = _fastest_full_range_hz(limits, dt)

    def sine(f: float, cycles: float) -> FloatArray:
        return sinusoid(min(f, f_cap), cycles, lo, hi, dt)

    def decaying(f: float, cycles: float, end: float) -> FloatArray:
        f = min(f, f_cap)
        t = np.arange(int(round(cycles / f / dt))) * dt
        return mid - amp * np.cos(2 * np.pi * f * t) * np.linspace(1.0, end, t.size)

    rest = limits.rest
    # from rest to the bottom of the range slowly: the initial loading curve is part of the model
    n = max(int(round(0.25 / dt)), 2)
    approach = rest + (lo - rest) * 0.5 * (1 - np.cos(np.pi * np.arange(n + 1) / n))
    fit = [approach, sine(1.0, 2), decaying(2.0, 6, 0.2), sine(5.0, 5), sine(10.0, 5), np.full(int(round(0.5 / dt)), mid)]
    choose = [sine(3.0, 3), decaying(1.5, 2, 0.5), sine(7.0, 4)]
    return fit, choose


def _join(parts: list[FloatArray], start: float, limits: CommandLimits, dt: float) -> FloatArray:
    out: list[FloatArray] = [np.empty(0)]
    last = start
    for seg in parts:
        out.append(limits.ramp(last, float(seg[0]), dt))
        out.append(seg)
        last = float(seg[-1])
    return np.concatenate(out)


#: A loop holds a measurement that changes in one sample by more than this many times the largest
#: change of the identification run (a sensor glitch, :attr:`CommissionedController.max_jump`) ...
GLITCH_JUMP_FACTOR = 10.0
#: ... and more than this share of its span.
GLITCH_JUMP_SPAN = 0.2
#: Share of a run's commands the safe layer may slow, or clip to the range, before
#: :func:`_warn_if_guarded` says so.
SLOWED_SHARE = 0.05
#: The tuned feedback is kept at a gain only if, on the verification run (module docstring, step 4),
#: its RMS error is at most this many times the feedforward alone's: with the sensor's noise alone
#: the two runs differ by a few percent (0.94-1.12 on the stages measured), a loop ringing at an
#: unmodelled resonance made it 1.6-2.2.
FEEDBACK_WORSE_RATIO = 1.25
#: ... and its e_max at most this many times the feedforward alone's: a loop that rings a
#: resonance after each reversal can leave the RMS error as it was and add to the peaks (e_max
#: 1.24-1.35x with RMS 1.01-1.09x on six census stages behind 420-600 Hz resonances, where one
#: halving took feedback and learning at 5 Hz from 1.14 / 1.23 / 1.29 % to 0.99 / 1.12 / 1.12 %
#: on three of them; 0.32-1.17x on the zoo, the VirtualRig and 58 other census stages).
FEEDBACK_WORSE_EMAX_RATIO = 1.2
#: Learning's band stays below this share of a structural mode's natural frequency
#: (:attr:`CommissionedController.structural_mode`).
MODE_BAND_SHARE = 0.5
#: Where a structural mode is found, the identification run is read through the mode's inverse up
#: to this many times its frequency (:func:`~piezohyst.signals.mode_inverse`), and the model is
#: fitted again to what the hysteresis puts out ahead of the mode
#: (:attr:`CommissionedController.output_mode`): the record's noise is amplified by at most the
#: square of it there.
MODE_DECONVOLUTION_BAND = 3.0
#: The verification run's frequency, Hz (capped where the step limit allows less), two cycles, the
#: second scored.
VERIFY_HZ = 5.0
#: Halvings of the gain the verification may make before it leaves the loop without feedback.
VERIFY_HALVINGS = 4
CLIPPED_SHARE = 0.05


def _warn_if_guarded(res: TrackingResult, what: str) -> None:
    """A :class:`~piezohyst.ClippingWarning` when the safe layer slowed more than
    :data:`SLOWED_SHARE` of a run's commands, or clipped more than :data:`CLIPPED_SHARE` of them
    to the amplifier's range: the error then says more about the step limit (a 5 Hz sinusoid at
    500 Hz sampling asked for 2.6 V per sample against 2) or about the range (a reference to
    160 % of the stroke: 30 % e_max, and nothing said) than about the controller."""
    from .rig import ClippingWarning

    safety = res.info.get("safety") or {}
    sent = int(safety.get("commands_sent", 0))
    slowed, clipped = int(safety.get("slew_limited", 0)), int(safety.get("clipped", 0))
    if sent and slowed > SLOWED_SHARE * sent:
        warnings.warn(f"{what}: the safe layer slowed {slowed} of {sent} commands to its step limit of "
                      f"{safety.get('max_step_V', float('nan')):.3g} V per sample: the reference asks for faster "
                      f"changes than the limits allow, and the error shows it; slow the reference, or commission "
                      f"with a larger max_step_fraction", ClippingWarning, stacklevel=3)
    if sent and clipped > CLIPPED_SHARE * sent:
        y = res.output[np.isfinite(res.output)]
        reached = f"{float(np.min(y)):.4g} to {float(np.max(y)):.4g} um" if y.size else "nothing"
        r_lo, r_hi = float(np.min(res.reference)), float(np.max(res.reference))
        spanned = bool(y.size) and float(np.min(y)) <= r_lo + 0.02 * (r_hi - r_lo) and \
            float(np.max(y)) >= r_hi - 0.02 * (r_hi - r_lo)
        # where the stage did reach the reference's extent, the range was short of what the speed
        # asked for, not of the stroke (found by fuzzing: a 50 Hz run told to keep within a reach it met)
        why = ("the stage spans the reference here, so at this speed the feedforward asks for more voltage "
               "than the range gives. Slow the reference" if spanned else
               "the error there is the range's, not the controller's. Keep the reference within what the "
               "stage reaches")
        warnings.warn(f"{what}: {clipped} of {sent} commands were clipped to the amplifier's range "
                      f"({safety.get('u_low_V', float('nan')):g} to {safety.get('u_high_V', float('nan')):g} V): the "
                      f"reference asks for {r_lo:.4g} to {r_hi:.4g} um, the stage reached {reached} in this run; "
                      f"{why}, or widen u_range if the amplifier allows", ClippingWarning, stacklevel=3)


def moving_part(u: FloatArray, y: FloatArray, bins: int = 20, share: float = 0.95) -> tuple[float, float] | None:
    """The part of the command's range over which the output does ``share`` of its changing,
    where that is at most half the range, else None: the output's mean in each of ``bins`` equal
    parts of the range, and the shortest run of parts whose steps between means add up to
    ``share`` of all of them. A stage that saturates (or a sensor at the end of its range) beyond
    a tenth of the range changes over that tenth; an output of noise alone changes everywhere.

    >>> u = np.linspace(0.0, 100.0, 1001)
    >>> moving_part(u, np.minimum(u, 10.0)), moving_part(u, np.sin(u))  # (the part's bins, whole)
    ((0.0, 15.0), None)
    """
    lo, hi = float(np.min(u)), float(np.max(u))
    if not hi > lo:
        return None
    idx = np.minimum(((u - lo) / (hi - lo) * bins).astype(np.int64), bins - 1)
    counts = np.bincount(idx, minlength=bins)
    if np.any(counts == 0):
        return None
    means = np.bincount(idx, weights=y, minlength=bins) / counts
    steps = np.abs(np.diff(means))
    total = float(steps.sum())
    if not total > 0.0:
        return None
    best: tuple[int, int] | None = None
    for a in range(steps.size):
        acc = np.cumsum(steps[a:])
        b = a + int(np.searchsorted(acc, share * total))
        if b < steps.size and (best is None or b - a < best[1] - best[0]):
            best = (a, b)
    if best is None or (best[1] - best[0] + 2) > bins // 2:
        return None
    width = (hi - lo) / bins
    return lo + best[0] * width, lo + (best[1] + 2) * width


def _limits(dt: float, u_range: Any, max_step_fraction: float | None, rest: float | None) -> CommandLimits:
    """The safe layer's limits for ``u_range`` at sample period ``dt``: the step limit given, or
    :func:`~piezohyst.plant.default_step_fraction` of ``dt``."""
    step = default_step_fraction(dt) if max_step_fraction is None else max_step_fraction
    return CommandLimits.for_range(u_range, max_step_fraction=step, rest=rest)


def commissioning_excitation(dt: float, u_range: tuple[float, float] = (0.0, 100.0), *,
                             max_step_fraction: float | None = None, start: float | None = None) -> FloatArray:
    """The identification experiment's command (V): see the module docstring, step 1.

    Every segment starts where the previous one ended or is joined to it by a raised-cosine ramp,
    and the whole command changes by at most half of ``max_step_fraction * (high - low)`` per
    sample (default :func:`~piezohyst.plant.default_step_fraction` of ``dt``): a sinusoid that
    would be faster at this ``dt`` is slowed to that limit. ``start`` is the command the plant
    holds before (default: 0 V, or the nearest end of the range); the table
    begins with a ramp from it and ends with a ramp back to it. Its first
    :func:`identification_length` samples are fitted on; the rest only chooses among the
    candidate models.
    """
    limits = _limits(dt, u_range, max_step_fraction, start)
    fit, choose = _excitation_parts(dt, limits)
    head = _join(fit, limits.rest, limits, dt)
    tail = _join(choose, float(head[-1]), limits, dt)
    back = limits.ramp(float(tail[-1]), limits.rest, dt)
    return np.concatenate([head, tail, back])


def conditioning_sweep(limits: CommandLimits, dt: float, leg_s: float = 0.25, *, top: bool = True) -> FloatArray:
    """The conditioning sweep's command (V): from rest to the top of the range and down to the
    bottom, raised-cosine legs of at least ``leg_s`` seconds each, inside the step limit (module
    docstring, step 3). It wipes out a hysteresis' memory of whatever came before. With
    ``top=False`` only down to the bottom (what every run's lead-in does from a rest above it)."""
    out, last = [np.array([limits.rest])], limits.rest
    for end in ((limits.high, limits.low) if top else (limits.low,)):
        if end == last:
            continue
        n = max(limits.ramp_length(end - last, dt), int(math.ceil(leg_s / dt)))
        k = np.arange(1, n + 1) / n
        out.append(last + (end - last) * 0.5 * (1.0 - np.cos(np.pi * k)))
        last = end
    return np.concatenate(out)


def identification_length(dt: float, u_range: tuple[float, float] = (0.0, 100.0), *,
                          max_step_fraction: float | None = None, start: float | None = None) -> int:
    """Samples of :func:`commissioning_excitation` that are fitted on (the rest is for choosing)."""
    limits = _limits(dt, u_range, max_step_fraction, start)
    return int(_join(_excitation_parts(dt, limits)[0], limits.rest, limits, dt).size)


def _lowpass_periodic(x: FloatArray, dt: float, cutoff_hz: float) -> FloatArray:
    """Zero-phase low-pass of one period of a periodic signal (FFT, bins above the cut-off removed)."""
    spec = np.fft.rfft(x)
    freqs = np.fft.rfftfreq(x.size, dt)
    spec[freqs > cutoff_hz] = 0.0
    return np.fft.irfft(spec, x.size)


def correction_into_feedback(ki: float, period_s: float) -> bool:
    """Whether the learned correction shifts the integral feedback's reference too (module
    docstring, step 5): where the feedback acts within the reference's band, its crossover
    (``ki / 2 pi``: the loop's gain is scaled to about one, ``volts_per_um``) above the reference's
    fundamental. There it would cancel a correction given to the feedforward alone. Below it, it
    does not cancel the correction, and following ``r + c`` would only make it integrate the
    correction's mean over every cycle, a slow mode that learning then fights: on the zoo's two
    stages with gains of 1.5-2.5 1/s, 0.62 -> 0.72 % at 5 Hz (dead zone) and 0.78 -> 0.91 % at 1 Hz
    (falling after reversal), means over four noise seeds.

    >>> correction_into_feedback(300.0, 0.2), correction_into_feedback(2.45, 1.0)
    (True, False)
    """
    return bool(ki > 0.0 and period_s > 0.0 and ki / (2.0 * math.pi) > 1.0 / period_s)


def _ratio(feedback: float, feedforward: float) -> float:
    return feedback / feedforward if feedforward > 0 else (1.0 if feedback == 0 else math.inf)


def _feedback_helps(check: dict[str, Any]) -> bool:
    """A verification check (:meth:`CommissionedController._verify_feedback`) that keeps its gain."""
    return bool(check["ratio"] <= FEEDBACK_WORSE_RATIO and check["e_max_ratio"] <= FEEDBACK_WORSE_EMAX_RATIO)


class _Learning:
    """The iterative learning of one per-sample tracking run (module docstring, step 5).

    ``update(corr, e, e_max)`` takes the correction applied during a cycle, that cycle's error and
    its largest magnitude (the figure of merit), and returns the correction for the next cycle and
    whether learning goes on.

    * Judged on e_max, over every cycle, against the best cycle so far (whose correction is kept).
    * A cycle worse than the best by more than ``TOLERANCE`` (e_max of one cycle is noisy) means the
      last change did harm: the best correction is restored and, if the band had been widened
      since the best, the band goes back to the best's and stays there; otherwise the gain is
      halved: with the repeatable error learnt, what is left does not repeat (noise, a feedback
      loop hunting), and a smaller gain averages it over more cycles instead of copying it into
      the correction. Learning stops when the gain has been halved ``MAX_HALVINGS`` times.
      The cycle after a revert is neither judged nor learnt from: it still carries the bad
      cycle's transient (the feedback's integral, the stage's memory). The one after it runs
      with the best correction restored; if it is still worse than the best by ``TOLERANCE``,
      the best figure was not the correction's doing (a noisy cycle's lucky e_max, a stage that
      drifts from cycle to cycle) and it becomes the new baseline, learnt from as usual: judged
      against a figure nothing can reproduce, every later cycle looked harmful and learning was
      halved until it stopped with no correction at all (the zoo's falling-after-reversal stage
      at 3 Hz: a first judged cycle of 0.0331 µm, then 0.0388-0.0406 µm with the restored
      correction, three halvings and learning off, 1.08 % e_max; now 0.90 %).
    * ``PATIENCE`` cycles in a row without a new best mean learning has converged: what is left
      does not repeat, and learning on would copy it into the correction (a stage whose loop
      gain changes sign after reversals turned that into single cycles 40 % worse). Learning
      stops with the best correction.
    * A cycle that improves on the best by less than ``STALL``, after at least two cycles in the
      current band, means learning has converged in it: the band (the zero-phase low-pass Q)
      doubles, up to ``cutoff_max``, so the error's sharper repeatable features (the corners at
      reversals) can be learnt too; whether the plant still follows there is judged by the next
      cycles, as above.
    """

    TOLERANCE = 0.15
    STALL = 0.05
    MAX_HALVINGS = 3
    PATIENCE = 3
    #: cycles a run must still have for a wider band to be tried: the one it is tried in, the one
    #: after a revert (which still carries the tried one's transient), and the three a run is
    #: judged by (its last three: a failed widening never reaches them)
    CYCLES_TO_UNDO_WIDENING = 5

    def __init__(self, p: int, dt: float, gain: float, cutoff: float, cutoff_max: float):
        self.dt = dt
        self.gain = gain
        self.cutoff = cutoff
        self.cutoff_max = max(cutoff_max, cutoff)
        self.best = math.inf
        self.best_corr = np.zeros(p)
        self.best_cutoff = cutoff
        self.halvings = 0
        self.reverts = 0
        self.widen = True
        self.settling = False
        self.rejudge = False
        self.rebaselined = 0
        self.in_band = 0
        self.since_best = 0
        self.stopped = False

    def update(self, corr: FloatArray, e: FloatArray, e_max: float) -> tuple[FloatArray, bool]:
        if self.settling:  # the cycle after a revert still carries the bad one's transient
            self.settling = False
            self.rejudge = True
            return corr, True
        if self.rejudge:
            self.rejudge = False
            if e_max > (1.0 + self.TOLERANCE) * self.best:
                # the best correction, restored, does not give the best cycle's figure back: the
                # loop moved (noise gave that cycle a lucky e_max, or the stage drifts from cycle to
                # cycle), not the learning; this cycle's figure is the baseline from now on
                self.best = e_max
                self.since_best = 0
                self.in_band = 0
                self.rebaselined += 1
                return _lowpass_periodic(corr + self.gain * e, self.dt, self.cutoff), True
        if e_max > (1.0 + self.TOLERANCE) * self.best:
            self.reverts += 1
            self.settling = True
            if self.cutoff > self.best_cutoff:
                self.cutoff = self.best_cutoff
                self.widen = False
            else:
                self.gain *= 0.5
                self.halvings += 1
            return self.best_corr.copy(), self.halvings < self.MAX_HALVINGS
        stalled = e_max > (1.0 - self.STALL) * self.best
        if e_max < self.best:
            self.best, self.best_corr, self.best_cutoff = e_max, corr.copy(), self.cutoff
            self.since_best = 0
        else:
            self.since_best += 1
            if self.since_best >= self.PATIENCE:  # converged: what is left does not repeat
                self.stopped = True
                return self.best_corr.copy(), False
        self.in_band += 1
        # a band is widened once it has had two cycles to converge in
        if stalled and self.in_band >= 2 and self.widen and self.cutoff < self.cutoff_max:
            self.cutoff = min(2.0 * self.cutoff, self.cutoff_max)
            self.in_band = 0
        return _lowpass_periodic(corr + self.gain * e, self.dt, self.cutoff), True


@dataclass
class CommissionedController:
    """Feedforward (the identified model's inverse) + integral feedback + iterative learning,
    behind the safe layer (module docstring)."""

    plant: Any
    fit: FitResult
    tuning: TuningResult | None
    identification: Dataset
    learning_gain: float = 0.5
    ilc_cutoff_hz: float | None = None
    time_s: float = 0.0
    #: the learning's widest band, as a fraction of the sample rate (module docstring, step 5)
    MAX_CUTOFF_FRACTION = 0.05
    info: dict[str, Any] = field(default_factory=dict)
    limits: CommandLimits | None = None
    max_plays: int = 8
    #: start every run with the conditioning sweep (module docstring, step 3)
    conditioning: bool = False
    #: the conditioning sweep's legs last at least this long, s (about a 2 Hz half-cycle each)
    CONDITIONING_LEG_S = 0.25
    #: The structural mode the model was fitted ahead of and the feedforward inverts (``f_hz``,
    #: ``zeta``, ``explained``), or None (:func:`_fit_ahead_of_mode`): the model is then the
    #: hysteresis before the mode, and every run's targets pass through the mode's inverse below
    #: :data:`MODE_BAND_SHARE` of its frequency (:meth:`feedforward_targets`).
    output_mode: dict[str, float] | None = None

    @property
    def model(self) -> Any:
        """The identified model (the fit's)."""
        return self.fit.model

    @property
    def delay(self) -> int:
        """The sensor delay found by the identification, in samples (previewed by the feedforward)."""
        return self.fit.delay

    @property
    def mode(self) -> str:
        """``"step"`` (a per-sample loop: feedback possible) or ``"buffered"`` (tables only)."""
        return plant_mode(self.plant)

    @cached_property
    def sensor_noise_um(self) -> float | None:
        """The RMS of the sensor's white noise (µm), from what the model leaves of the
        identification run (:func:`~piezohyst.signals.sensor_noise_rms`); None without one.
        Tracking runs report the floor it puts under their e_max (``info["noise_floor_percent"]``)."""
        left = self._identification_left
        if left is None or not np.all(np.isfinite(left)):
            return None
        return sensor_noise_rms(left)

    @cached_property
    def _identification_left(self) -> FloatArray | None:
        """What the model leaves of the identification run (``fit.residual``), or None."""
        ds = getattr(self, "identification", None)
        if ds is None or len(ds) < 3 + self.delay:
            return None
        dt = self.plant.dt if self.model.dynamic else None
        m = self.output_mode
        if m is None:
            return self.fit.residual(ds.u, ds.y, dt)
        # the model predicts what the hysteresis puts out ahead of the mode: through the mode
        # it predicts the record
        ahead = self._identification_ahead
        pred = ahead[self.delay:] - self.fit.residual(ds.u, ahead, dt)
        b, a = second_order_filter(m["f_hz"], m["zeta"], self.plant.dt)
        from scipy.signal import lfilter

        return np.asarray(ds.y[self.delay:] - (lfilter(b, a, pred - pred[0]) + pred[0]), dtype=np.float64)

    @cached_property
    def _identification_ahead(self) -> FloatArray:
        """The identification run read back through :attr:`output_mode`'s inverse (see
        :data:`MODE_DECONVOLUTION_BAND`): what the model is fitted to."""
        m = self.output_mode
        assert m is not None
        return mode_inverse(np.asarray(self.identification.y, dtype=np.float64), self.plant.dt, m["f_hz"], m["zeta"],
                            band_hz=MODE_DECONVOLUTION_BAND * m["f_hz"])

    def feedforward_targets(self, reference: Any, period: int | None = None) -> FloatArray:
        """What the feedforward is asked to produce so that the stage follows ``reference`` (µm):
        the reference itself, or where the model was fitted ahead of a structural mode
        (:attr:`output_mode`), the reference through the mode's inverse below
        :data:`MODE_BAND_SHARE` of its frequency (:func:`~piezohyst.signals.mode_inverse`; the
        whole reference is known in advance; ``period``: samples after which it repeats)."""
        r = as_signal("reference", reference, min_length=1)
        m = self.output_mode
        if m is None or r.size < 3:
            return r
        return mode_inverse(r, self.plant.dt, m["f_hz"], m["zeta"], band_hz=MODE_BAND_SHARE * m["f_hz"],
                            period=period)

    def noise_floor(self, result: TrackingResult) -> dict[str, float] | None:
        """What the sensor's noise alone would make of ``result``'s e_max: ``sensor_noise_um``
        and, over the run's scored samples, the e_max that noise reaches with probability one half
        (:func:`~piezohyst.signals.noise_e_max`) in µm and as % of the reference's span; for a
        sensor that reads in counts (``sensor_resolution_um``) at least half a count. An e_max
        near it is as small as this sensor can show; below it, the error is noise."""
        if not isinstance(result, TrackingResult):
            raise TypeError(f"noise_floor takes the TrackingResult of a track() run, got {type(result).__name__}")
        sigma = self.sensor_noise_um
        if sigma is None or result.metrics.samples < 1:
            return None
        floor = noise_e_max(sigma, result.metrics.samples)
        step = self.sensor_resolution_um
        if step is not None:  # a sensor that reads in counts shows no error finer than half of one
            floor = max(floor, 0.5 * step)
        span = result.metrics.span
        return {"sensor_noise_um": sigma, **({"sensor_resolution_um": step} if step is not None else {}),
                "noise_floor_um": floor, "noise_floor_percent": 100.0 * floor / span if span > 0 else math.nan}

    @cached_property
    def sensor_resolution_um(self) -> float | None:
        """The step (µm) of a sensor that reads in counts, from the identification run's readings
        (:func:`~piezohyst.signals.sensor_resolution`); None where they show no grid. Half of it is
        a floor under any tracking run's e_max (:meth:`noise_floor`): the noise, measured from
        what the model leaves, does not see a count that holds still."""
        ds = getattr(self, "identification", None)
        return None if ds is None or len(ds) < 2 else sensor_resolution(ds.y)

    @property
    def max_jump(self) -> float | None:
        """The most (µm) a measurement may change in one sample before a loop holds it as a sensor
        glitch (:class:`~piezohyst.plant.SensorDropouts`): :data:`GLITCH_JUMP_FACTOR` times the
        largest change in the identification run (its glitches bridged), and at least
        :data:`GLITCH_JUMP_SPAN` of its span. None without an identification run."""
        ds = getattr(self, "identification", None)
        if ds is None or len(ds) < 3:
            return None
        from .identify.glitches import bridge_glitches, find_glitches

        y = bridge_glitches(ds.y, find_glitches(ds.y))
        return max(GLITCH_JUMP_FACTOR * float(np.max(np.abs(np.diff(y)))), GLITCH_JUMP_SPAN * float(np.ptp(y)))

    def _limits(self) -> CommandLimits:
        if self.limits is None:
            rng = plant_u_range(self.plant) or (0.0, 100.0)
            self.limits = CommandLimits.for_range(rng)
        return self.limits

    def __repr__(self) -> str:
        """One line (the dataclass's own repr printed the fit and the identification run in full,
        134,000 characters); :meth:`describe` has it all as data."""
        ki = f"{self.tuning.ki:.4g} 1/s" if self.tuning else "none"
        return (f"CommissionedController(plant={type(self.plant).__name__}, model={kind_of(self.model)}, "
                f"structure={self.fit.info.get('chosen', self.fit.method)!r}, delay={self.delay}, ki={ki}, "
                f"mode={self.mode!r}, conditioning={self.conditioning})")

    def describe(self) -> dict[str, Any]:
        """The controller in plain data: model kind and structure, fit and hold-out errors, delay, gains."""
        m = self.model
        hold = self.fit.info.get("holdout", {})
        return {
            "model": kind_of(m), "structure": self.fit.info.get("chosen", self.fit.method),
            "fit_rmse_um": self.fit.rmse, "holdout_rmse_um": hold.get("rmse"),
            "holdout_percent_of_span": hold.get("percent_of_span"), "delay_samples": self.delay,
            "mode": self.mode,
            "feedback": (f"integral, ki = {self.tuning.ki:.4g} 1/s" if self.tuning and self.tuning.ki > 0 else
                         f"none (tuned to ki = 0: {_why_no_feedback(self.tuning)})" if self.tuning else
                         NO_LOOP if self.mode == "buffered" else "none (not tuned)"),
            "ki": self.tuning.ki if self.tuning else None,
            "ki_ultimate": self.tuning.ki_ultimate if self.tuning else None,
            "learning_gain": self.learning_gain, "commissioning_time_s": self.time_s,
            "sensor_noise_um": self.sensor_noise_um,
            "structural_mode": self.structural_mode,
            "resonance_hz": self.resonance_hz,
            "feedforward_inverts_mode": self.output_mode is not None,
            "limits": self._limits().to_dict(),
            "warnings": list(self.fit.warnings),
        }

    def tune(self, options: SafeTuningOptions | None = None) -> dict[str, Any]:
        """Tune the integral feedback on the plant (module docstring, step 4), as ``commission``
        does with ``tune=True``: for a controller commissioned with ``tune=False``, or to tune
        again with other ``options``. The bounded experiments at a hold give the gain; a tracking
        run then checks it on the branches (:meth:`verification_reference`) and halves it while
        the feedback does worse than the feedforward alone (``tuning.verification`` lists the
        checks). Returns what the safe layer counted during the experiments."""
        if self.mode != "step":
            raise ValueError(NO_LOOP.replace("no feedback: ", "cannot tune feedback: "))
        tguard = GuardedPlant(self.plant, self._limits(), max_jump=self.max_jump)
        self.tuning = tune_integral_safely(tguard, self.feedforward(), self.model, delay=self.delay,
                                           level=float(np.median(self.identification.y)),
                                           volts_per_um=self.volts_per_um, options=options,
                                           conditioning=self.conditioning_command() if self.conditioning else None,
                                           rise_s=self.CONDITIONING_LEG_S)
        counts = tguard.counts()
        self._verify_feedback()
        if self.tuning is not None and not self.tuning.ki > 0:
            warnings.warn(f"commissioning {type(self.plant).__name__}: no integral feedback (ki = 0): "
                          f"{_why_no_feedback(self.tuning)}; the controller tracks with its feedforward alone "
                          "(and learning, where on), and nothing takes out what the model misses, drift included",
                          NoFeedbackWarning, stacklevel=2)
        return counts

    def verification_reference(self) -> tuple[FloatArray, int]:
        """The verification run's reference (µm) and period (samples): two cycles of a
        :data:`VERIFY_HZ` sinusoid (slower where the step limit asks) over 10-90 % of the
        identification run's output span."""
        dt = self.plant.dt
        lim = self._limits()
        lo, hi = (float(v) for v in np.percentile(self.identification.y, [0.5, 99.5]))
        f = min(VERIFY_HZ, _fastest_full_range_hz(lim, dt)) if lim.span > 0 else VERIFY_HZ
        period = max(int(round(1.0 / (f * dt))), 1)
        # a whole number of samples per cycle: two cycles of a frequency slowed by the step limit
        # (4150.6 samples) came one sample short of two rounded periods, and the run was refused
        ref = sinusoid(1.0 / (period * dt), 2, lo + 0.1 * (hi - lo), lo + 0.9 * (hi - lo), dt)
        return ref, period

    def _verify_feedback(self) -> None:
        """Module docstring, step 4: halve the tuned gain while the feedback tracks the
        verification run worse than the feedforward alone; the checks go to
        ``tuning.verification``."""
        tu = self.tuning
        if tu is None or not tu.ki > 0:
            return
        ref, period = self.verification_reference()
        checks: list[dict[str, Any]] = []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the runs' clipping and slowing are the tuning's business
            ff = self.track(ref, feedback=False, learning=False, period=period)
            for i in range(VERIFY_HALVINGS + 1):
                self.tuning = tu  # the gain the run tracks with
                try:
                    fb = self.track(ref, learning=False, period=period)
                    fb_rmse, fb_emax = fb.rmse, fb.e_max
                except UnstableLoopError:
                    fb_rmse = fb_emax = math.inf
                checks.append({"ki": tu.ki, "rmse_feedback_um": fb_rmse, "rmse_feedforward_um": ff.rmse,
                               "ratio": _ratio(fb_rmse, ff.rmse), "e_max_feedback_um": fb_emax,
                               "e_max_feedforward_um": ff.e_max, "e_max_ratio": _ratio(fb_emax, ff.e_max)})
                if _feedback_helps(checks[-1]):
                    break
                tu = replace(tu, ki=tu.ki / 2.0 if i < VERIFY_HALVINGS else 0.0)
        halved = len(checks) - 1 if _feedback_helps(checks[-1]) else len(checks)
        f_hz = 1.0 / (period * self.plant.dt)

        def said(c: dict[str, Any]) -> str:
            return f"feedback RMS {c['ratio']:.2f}x and e_max {c['e_max_ratio']:.2f}x the feedforward's"

        note = f"; verified on a {f_hz:.3g} Hz run over 10-90 % of the stroke: {said(checks[-1])}"
        if halved:
            note += (f" after halving the gain {halved} time(s) (at ki = {checks[0]['ki']:.4g}: {said(checks[0])}: "
                     f"the loop does worse than no loop on the branches)" if tu.ki > 0
                     else f"; no feedback (at ki = {checks[0]['ki']:.4g}: {said(checks[0])}, and no better than "
                          f"{FEEDBACK_WORSE_RATIO:g}x and {FEEDBACK_WORSE_EMAX_RATIO:g}x after {VERIFY_HALVINGS} halvings)")
        self.tuning = replace(tu, method=tu.method + note, verification=tuple(checks),
                                          margins=tu.margins if not halved else {})

    def feedforward(self) -> Compensator:
        """The identified model's compensator (desired µm in, volts out), at the plant's rate."""
        return self.model.compensator(self.plant.dt if self.model.dynamic else None)

    @property
    def volts_per_um(self) -> float:
        """1 / the model's mean slope: converts a feedback correction in µm into volts."""
        return float(np.ptp(self.identification.u) / np.ptp(self.identification.y))

    def conditioning_command(self) -> FloatArray:
        """This controller's :func:`conditioning_sweep` (legs of :attr:`CONDITIONING_LEG_S`). A run
        then rises from the bottom to its first target as slowly (a quick rise would ring a lightly
        damped stage into the run's first cycle)."""
        return conditioning_sweep(self._limits(), self.plant.dt, self.CONDITIONING_LEG_S)

    def _lead_in(self, ff: Compensator, limits: CommandLimits, y_to: float, conditioning: bool) -> tuple[FloatArray, FloatArray]:
        """Desired µm and commands from rest to ``y_to``: through the conditioning sweep (the
        model's output along it, from its initial state) when ``conditioning``; else from a rest
        above the bottom of the range down to the bottom first (module docstring, step 3), else
        straight."""
        dt = self.plant.dt
        if conditioning:
            return lead_in_after(ff, self.model, self.conditioning_command(), y_to, limits, dt,
                                 rise_s=self.CONDITIONING_LEG_S)
        if limits.rest > limits.low + 1e-9 * limits.span:
            return lead_in_after(ff, self.model, conditioning_sweep(limits, dt, self.CONDITIONING_LEG_S, top=False),
                                 y_to, limits, dt, rise_s=self.CONDITIONING_LEG_S)
        return lead_in_from_rest(ff, self.model, y_to, limits, dt)

    def track(self, reference: Any, *, feedback: bool | None = None, learning: bool = True,
              period: int | None = None, label: str = "", max_plays: int | None = None,
              conditioning: bool | None = None) -> TrackingResult:
        """Follow ``reference`` (µm, one sample per ``plant.dt``).

        ``feedback`` switches the integral feedback: None (default) uses it where the plant has a
        per-sample loop; True on a plant that only plays tables is an error (there is no loop to
        close). ``learning`` switches the iterative learning: on a per-sample plant it is used when
        the reference repeats (``period`` samples, estimated when omitted), cycle by cycle; on a
        buffered plant the whole table is played again, corrected, up to ``max_plays`` times, and
        the best play is returned (``info["play_rms_um"]`` lists every play).
        ``conditioning`` (default: the controller's :attr:`conditioning`, off) starts the run with
        the conditioning sweep over the whole range (module docstring, step 3).
        """
        r = as_signal("reference", reference, min_length=2)
        period = _check_period(period, r.size)  # (learning divided by period=0 before the metrics saw it)
        self._check_reachable(r)
        for name, flag in (("feedback", feedback), ("learning", learning), ("conditioning", conditioning)):
            as_flag(name, flag, default_ok=True)  # (feedback="no" ran with feedback)
        cond = self.conditioning if conditioning is None else bool(conditioning)
        lim = self._limits()
        if self.conditioning and not cond and not lim.rest > lim.low + 1e-9 * lim.span:
            # from a rest at the bottom the run rises straight from whatever state the stage is in
            # (from a rest above it, the lead-in goes down to the bottom first, which wipes the
            # memory out as the sweep does). The tutorial's run so, on the VirtualRig, whose reset()
            # restores the de-energised state, missed by 47 % of span and said only that commands clipped
            warnings.warn("this controller's model was identified after the conditioning sweep and knows the "
                          "stage's state only after one; this run without it rises from rest from whatever state "
                          "the stage is in: a stage that came down to rest keeps the sweep's remanence, but one "
                          "reset to its de-energised state (a simulator's reset()) starts off by that remanence",
                          UserWarning, stacklevel=2)
        if feedback and self.mode != "buffered" and self.tuning is None:
            # (it ran without feedback and said nothing: found by fuzzing)
            raise ValueError("feedback=True, but this controller's feedback was never tuned (commissioned with "
                             "tune=False): call ctl.tune() first, or track with feedback=False")
        if self.mode == "buffered":
            if feedback:
                raise ValueError(NO_LOOP.replace("no feedback: ", "cannot use feedback: "))
            res = self._track_buffered(r, learning=learning, period=period, label=label,
                                       max_plays=self.max_plays if max_plays is None else int(max_plays),
                                       conditioning=cond)
        else:
            res = self._track_step(r, feedback=True if feedback is None else bool(feedback), learning=learning,
                                   period=period, label=label, conditioning=cond)
        _warn_if_guarded(res, "track")
        res.info.update(self.noise_floor(res) or {})
        return res

    #: How far beyond the identification run's output a reference may reach, in that output's span,
    #: before :meth:`track` refuses it; less is run, and the run warns where the range clipped it
    #: (``ClippingWarning``, with the figures).
    REACH_MARGIN = 1.0

    def _check_reachable(self, r: FloatArray) -> None:
        """Refuse a reference beyond what the stage reached over its whole range in the
        identification run by more than :data:`REACH_MARGIN` of that reach: no controller
        follows it (a reference 100 um beyond a 2.5 um stroke was reported as a loop gone
        unstable at its first sample; found by fuzzing)."""
        y = np.asarray(self.identification.y, dtype=np.float64)
        y = y[np.isfinite(y)]
        if y.size < 2:
            return
        y_lo, y_hi = float(y.min()), float(y.max())
        margin = self.REACH_MARGIN * (y_hi - y_lo)
        a, b = float(r.min()), float(r.max())
        if a < y_lo - margin or b > y_hi + margin:
            u = self.identification.u
            raise ValueError(f"the reference ({a:.4g} .. {b:.4g} um) is beyond what the stage reached over "
                             f"{float(np.min(u)):g}..{float(np.max(u)):g} V in its identification run ({y_lo:.4g} .. "
                             f"{y_hi:.4g} um); no controller can follow it: keep the reference within that reach")

    @cached_property
    def structural_mode(self) -> dict[str, float] | None:
        """A lightly damped structural mode that the identification run shows and the model
        leaves out (:func:`~piezohyst.signals.lightly_damped_mode`: ``f_hz``, ``zeta``, the share
        of the model's residual it ``explained``), searched from twice the run's fastest
        excitation frequency up to twice the learning's widest band; None where none is found.

        Learning keeps its band below :data:`MODE_BAND_SHARE` of its frequency (module
        docstring, step 5): there the stage's response to the correction, ``1 / (1 - (f /
        f_n)^2)``, is at most 1.33, and ``|1 - gamma G|`` stays below 1; at the mode it is
        ``1 / (2 zeta)``, and learning there rings it instead of converging. Found on a probe
        stage with a 60 Hz mode at 2 % damping (a 300 um long-stroke stage; 60.6 Hz estimated):
        the default band (50 Hz, or 15 harmonics: 75 Hz at 5 Hz) reached it, and feedback and
        learning ended at 5.6 / 11.9 % e_max at 1 / 5 Hz, 0.71 / 2.15 % with the band below half
        the mode. (On one with a 100 Hz mode at 5 %, 0.19 / 1.28 % before and 0.19 / 1.32 % after:
        its error at 5 Hz is the mode's ringing, above the band either way.)
        """
        if self.output_mode is not None:  # the model is fitted ahead of it
            return self.output_mode
        if "structural_mode" not in self.fit.info:  # a fit made without the search (e.g. by fit_pi)
            left = self._identification_left
            if left is None:
                return None
            y = np.asarray(self.identification.y, dtype=np.float64)[self.delay:]
            structural_mode_search(self.fit, y, y - left, getattr(self.plant, "dt", None))
        found = self.fit.info["structural_mode"]
        return dict(found) if found else None

    def _mode_cap(self) -> float:
        mode, seen = self.structural_mode, self.resonance_hz
        found = ([mode["f_hz"]] if mode else []) + ([seen] if seen is not None else [])
        return MODE_BAND_SHARE * min(found) if found else math.inf

    @property
    def resonance_hz(self) -> float | None:
        """The frequency (Hz) of the lowest oscillation that the tuning's experiments saw grow
        under the loop (:attr:`resonance_seen`), or None: a resonance the model lacks, which
        learning's band keeps below :data:`MODE_BAND_SHARE` of, as of a :attr:`structural_mode`.
        Found on a 300 um stage with a 55 Hz mode at 1.4 % sampled at 2 kHz, whose identification
        run showed no mode (the model's lags took up the mode's slow effect): learning's band at
        5 Hz starts at 75 Hz, and feedback and learning ended 12 cycles at 11.5 % e_max (the
        feedforward alone 3.2 %)."""
        if self.tuning is None:
            return None
        seen = [float(e["oscillation_hz"]) for e in self.tuning.experiments
                if e.get("oscillation_grows") and e.get("oscillation_hz")]
        return min(seen) if seen else None

    def _cutoff(self, per: int | None, dt: float) -> float:
        if self.ilc_cutoff_hz:
            return self.ilc_cutoff_hz
        return min(max(50.0, 15.0 / (per * dt)) if per else 50.0, self._mode_cap())

    def _widest_band(self, per: int | None, dt: float) -> float:
        """How far learning may widen its band (module docstring, step 5): to
        :attr:`MAX_CUTOFF_FRACTION` of the sample rate, unless the loop is flat just after
        reversals, or the tuning's experiments saw an oscillation grow (a resonance the model
        lacks): the band then stays where it starts."""
        if self.ilc_cutoff_hz:
            return self.ilc_cutoff_hz
        if self.fit.info.get("floor_at_margin") or self.resonance_seen:
            return self._cutoff(per, dt)
        return min(self.MAX_CUTOFF_FRACTION / dt, self._mode_cap())

    @property
    def resonance_seen(self) -> bool:
        """Whether the tuning's experiments saw an oscillation build under an answer that looked
        damped (``oscillation_grows``): the mark of a low, lightly damped resonance the model
        lacks (:func:`~piezohyst.control.tuning.tune_integral_safely`)."""
        return self.tuning is not None and any(e.get("oscillation_grows") for e in self.tuning.experiments)

    def _track_step(self, r: FloatArray, *, feedback: bool, learning: bool, period: int | None,
                    label: str, conditioning: bool = False) -> TrackingResult:
        # the loop compiled where every part has a kernel (the VirtualRig, a rate-dependent P-I
        # inverse, a PID); it gives up at the first sample where anything unusual happens, and the
        # run is then made again from the start in Python, which handles it as it always has
        try:
            res = self._track_step_run(r, feedback=feedback, learning=learning, period=period, label=label,
                                       compiled=True, conditioning=conditioning)
            if res is None:
                res = self._track_step_run(r, feedback=feedback, learning=learning, period=period, label=label,
                                           compiled=False, conditioning=conditioning)
        except UnstableLoopError as exc:
            raise self._too_fast_for_the_step_limit(r, exc) from None
        assert res is not None  # the Python loop always ends with a result (or raises)
        return res

    def _too_fast_for_the_step_limit(self, r: FloatArray, exc: UnstableLoopError) -> UnstableLoopError:
        """``exc``, or where the reference asks the feedforward for faster commands than the step
        limit lets through, an error that says so: the guard slowed the command, and the feedback
        wound up against it (a stage behind an 800 V/s amplifier, commissioned within it, and a
        5 Hz sinusoid over 80 % of its range: "lower the feedback gains" was not the remedy)."""
        lim = self._limits()
        try:
            ff = np.asarray(self.feedforward().command(self.feedforward_targets(r)), dtype=np.float64)
        except Exception:  # noqa: BLE001 - only a better message
            return exc
        fastest = float(np.max(np.abs(np.diff(ff)))) if ff.size > 1 else 0.0
        if not fastest > lim.max_step:
            return exc
        dt = self.plant.dt
        reason = (f"{exc.reason}; the reference asks the feedforward for steps of up to {fastest:.3g} V per sample "
                  f"({fastest / dt:.4g} V/s), more than the step limit lets through ({lim.max_step:.3g} V per sample, "
                  f"{lim.max_step / dt:.4g} V/s, max_step_fraction={lim.max_step / lim.span:.3g}): the command was "
                  "slowed and the feedback wound up against it")
        return UnstableLoopError(f"{reason}. Slow the reference down (or, if the amplifier follows faster, raise "
                                 "max_step_fraction)", reason=reason, sample=exc.sample)

    def _track_step_run(self, r: FloatArray, *, feedback: bool, learning: bool, period: int | None,
                        label: str, compiled: bool, conditioning: bool = False) -> TrackingResult | None:
        plant = self.plant
        dt = plant.dt
        limits = self._limits()
        guard = GuardedPlant(plant, limits, max_jump=self.max_jump)
        n = r.size
        per = period if period is not None else estimate_period(r)
        learn = learning and per is not None and n >= 2 * per
        p = int(per) if per is not None else 1  # the period where learning uses it
        ff = self.feedforward()
        rt = self.feedforward_targets(r, per)
        pid = self.tuning.pid(dt) if (feedback and self.tuning is not None) else None
        # (the kernel follows the reference itself: not where the targets invert a mode)
        kernel = _loop_kernel_args(plant, ff, pid) if compiled and self.output_mode is None else None
        if compiled and kernel is None:
            return None
        d = self.delay
        corr = np.zeros(p) if learn else None
        corr_prev = corr
        fade_start = fade_end = 0
        learning_on = learn
        cycle_rms: list[float] = []
        cycle_emax: list[float] = []
        learning_stopped: str | None = None
        learned = False  # a correction has been applied in this run
        vpu = self.volts_per_um
        span = float(np.ptp(r))
        watch = LoopWatch(r, u_range=guard.u_range, feedback_on=pid is not None,
                          limit=10 * span + 10, dt=dt, describe=lambda: f"controller {self.describe()}",
                          noise=self.sensor_noise_um)
        guard.reset()
        # lead-in: from rest to the first target, slowly enough for the step limit
        desired, cmd = self._lead_in(ff, limits, float(rt[min(d, n - 1)]), conditioning)
        try:
            guard.ramp_to(float(cmd[0]))
            ff.reset()
            y_prev = 0.0
            for x in desired[:-1]:
                y_prev = guard.step(ff.step(float(x)))
        except BaseException:
            # (a fault here left the stage where the lead-in had taken it, 83 V: found by fuzzing)
            guard.back_to_rest()
            raise
        lead_samples = guard.sent
        y = np.empty(n)
        u = np.empty(n)
        # where the range clipped the command, learning cannot act: no correction builds up there
        clipped_at = np.zeros(n + d, dtype=bool)
        # the correction the target of each reference sample carried: the feedback's reference too,
        # where the feedback acts within the reference's band (module docstring, step 5)
        c_of = np.zeros(n)
        c_to_feedback = bool(learn and pid is not None and self.tuning is not None
                             and correction_into_feedback(self.tuning.ki, p * dt))
        sat = 0
        # (the band only where learning runs: it may look for a structural mode, a search of its own)
        learner = _Learning(p, dt, self.learning_gain, self._cutoff(per, dt) if learn else math.inf,
                            self._widest_band(per, dt) if learn else math.inf)

        def fade(k: int) -> float:
            """The weight of the new correction at sample k while it takes over from the old one."""
            return 0.5 * (1.0 - math.cos(math.pi * (k - fade_start) / (fade_end - fade_start)))

        def end_of_cycle(k: int) -> None:
            """Learning after the cycle that ends at sample k."""
            nonlocal corr, corr_prev, learning_on, learned, fade_start, fade_end
            c0 = k + 1 - p
            e = r[c0:k + 1] - y[c0:k + 1]
            rms = float(np.sqrt(np.mean(e**2)))
            e_max = float(np.max(np.abs(e)))
            e = np.where(clipped_at[c0:k + 1], 0.0, e)
            cycle_rms.append(rms)
            cycle_emax.append(e_max)
            # the first cycle starts from the lead-in, on the virgin branch where the model
            # began: its error is a transient (the figures of merit leave it out too), so
            # learning starts from the second cycle
            if learning_on and len(cycle_rms) > 1:
                corr_prev = corr
                # a wider band is tried only while the run has cycles left to undo it: the cycle it
                # is tried in, and after a revert the one that still carries its transient
                learner.widen = learner.widen and (n - (k + 1)) // p >= _Learning.CYCLES_TO_UNDO_WIDENING
                corr, learning_on = learner.update(corr, e, e_max)  # type: ignore[arg-type]
                # over one period of the learning's band: the blend adds nothing above it
                fade_start, fade_end = k + 1, k + 1 + max(2, int(math.ceil(1.0 / (learner.cutoff * dt))))
                learned = True

        def corr_for(k0: int, k1: int) -> Any:
            """The correction as the compiled loop reads it in samples k0..k1-1 (one period at
            most, so each phase once): the blend of a new correction written into a copy; the
            string "python" where that cannot be (the run's last samples reuse the last phase)."""
            if corr is None or k0 >= fade_end:
                return corr
            eff = corr.copy()
            for k in range(k0, min(fade_end, k1)):
                if k + d > n - 1:
                    return "python"
                i = (k + d) % p
                eff[i] = corr_prev[i] + fade(k) * (corr[i] - corr_prev[i])  # type: ignore[index]
            return eff

        finished = False
        try:
            if kernel is not None:
                # the feedforward's state arrays as they are now (reset() replaces them)
                if not _run_loop_compiled(_loop_kernel_args(plant, ff, pid), plant, guard, ff, pid, watch, r, y, u,
                                          clipped_at, c_of, c_to_feedback, d, vpu, y_prev, p if learn else n,
                                          corr_for,
                                          end_of_cycle if learn else None):
                    return None
            else:
                for k in range(n):
                    # the feedback follows the corrected reference (module docstring, step 5)
                    fb = pid.step(r[k - 1] + c_of[k - 1] - y_prev, sat) * vpu if (pid is not None and k > 0) else 0.0
                    j = min(k + d, n - 1)
                    c = corr[j % p] if corr is not None else 0.0
                    if k < fade_end:  # a new correction takes over smoothly, not as a step at the switch
                        c = corr_prev[j % p] + fade(k) * (c - corr_prev[j % p])  # type: ignore[index]
                    if c_to_feedback:
                        c_of[j] = c
                    target = rt[j] + c
                    uk = ff.step(target) + fb
                    try:
                        watch.command(k, uk)
                    except UnstableLoopError as exc:
                        # a learned correction drove the loop to the amplifier's limits (a stage
                        # whose loop is flat after reversals turns a small correction of the target
                        # into a large one of the command): drop it, stop learning, and give the loop
                        # one window to settle; without learning, or once more, the gains make the
                        # loop unstable, as before
                        if not learned or learning_stopped is not None:
                            raise
                        corr = np.zeros(p)
                        fade_end = 0
                        learning_on = False
                        learning_stopped = exc.reason
                        watch.n_lo = watch.n_hi = 0
                    yk = guard.step(uk)
                    sat = guard.last_saturation
                    clipped_at[k + d] = sat != 0
                    u[k] = guard.last
                    y[k] = yk
                    watch.output(k, yk, y)
                    y_prev = yk
                    if learn and (k + 1) % p == 0:
                        end_of_cycle(k)
            finished = True
        finally:
            # leave the stage at rest (a later reset() is then no jump); after a fault, as far as
            # the plant still answers, and the fault is what is raised (the ramp's own error
            # replaced it: found by fuzzing)
            if finished:
                guard.ramp_to(limits.rest)
            else:
                guard.back_to_rest()
        return TrackingResult(t=np.arange(n) * dt, reference=r, output=y, command=u, period=per,
                              clipped=guard.clipped, label=label,
                              info={"mode": "step", "feedback": pid is not None, "learning": learn,
                                    "cycle_rms_um": cycle_rms, "cycle_e_max_um": cycle_emax,
                                    "learning_gain": learner.gain if learn else None,
                                    "learning_cutoff_hz": learner.cutoff if learn else None,
                                    "learning_reverts": learner.reverts if learn else 0,
                                    "lead_in_samples": lead_samples,
                                    "learning_stopped": learning_stopped,
                                    "correction_into_feedback": c_to_feedback,
                                    "safety": guard.counts()})

    def _track_buffered(self, r: FloatArray, *, learning: bool, period: int | None, label: str,
                        max_plays: int, conditioning: bool = False) -> TrackingResult:
        if max_plays < 1:
            raise ValueError(f"max_plays must be >= 1, got {max_plays}")
        from .signals import cycles_after_first

        plant = self.plant
        dt = plant.dt
        limits = self._limits()
        held = self.info.get("held_command", limits.rest)
        if held is None or not math.isfinite(held):
            raise ValueError("the last table played stopped part-way (the plant's play() failed): the amplifier may "
                             "hold any command of it, and the next table would start with a jump from where it is "
                             "assumed to be; bring the stage to rest, then say so (ctl.info['held_command'] = the rest "
                             f"command, {limits.rest:g} V)")
        guard = GuardedPlant(plant, limits, last=float(held))
        n = r.size
        per = period if period is not None else estimate_period(r)
        folded = per is not None and n >= 2 * per
        window = cycles_after_first(n, per)
        d = self.delay
        idx = np.minimum(np.arange(n) + d, n - 1)
        ff = self.feedforward()
        rt = self.feedforward_targets(r, per)
        cutoff = self._cutoff(per, dt) if learning else math.inf  # nothing is learnt without learning
        corr = np.zeros(n)
        corr_period = np.zeros(per) if folded else None  # type: ignore[arg-type]
        plays: list[float] = []
        best: tuple[float, FloatArray, FloatArray] | None = None
        for _ in range(max_plays if learning else 1):
            targets = rt[idx] + corr[idx]
            desired, _c = self._lead_in(ff, limits, float(targets[0]), conditioning)
            cmd = ff.command(np.concatenate([desired[:-1], targets]))
            lead = desired.size - 1
            pre = limits.ramp(guard.last, min(max(float(cmd[0]), limits.low), limits.high), dt)
            # every table ends back at rest, as every run on a per-sample plant does (it ended at its
            # last command, and a later commission() on the stage started with a jump from there to
            # rest: found by fuzzing)
            post = limits.ramp(min(max(float(cmd[-1]), limits.low), limits.high), limits.rest, dt)
            table = guard.guard_table(np.concatenate([pre, cmd, post]))
            try:
                played = self._play(table)
            except BaseException:
                self.info["held_command"] = math.nan  # where it stopped is not known
                raise
            self.info["held_command"] = float(table[-1])
            y_all = self._bridge_glitches(played, guard)
            y_all = y_all[: y_all.size - post.size]
            still = output_still(y_all, table) if float(np.ptp(table)) > 0.0 else None
            if still:
                # a sensor that reads one value whatever the command: learning drove the commands to
                # the range's end against it, and the warning blamed the range (found by fuzzing)
                raise ValueError(f"the stage's output did not move over this play {still}: is the sensor reading "
                                 "and the amplifier on? Nothing was learnt from it")
            y = y_all[pre.size + lead:]
            e = r - y
            rms = float(np.sqrt(np.mean(e[window] ** 2)))
            # where the range clipped the command (it shows d samples later), learning cannot act
            asked = cmd[lead:]
            clipped = np.concatenate([np.zeros(d, dtype=bool), (asked < limits.low) | (asked > limits.high)])[:n]
            e = np.where(clipped, 0.0, e)
            plays.append(rms)
            if best is None or rms < best[0]:
                best = (rms, y, table[pre.size + lead:table.size - post.size])
            else:
                break  # the error stopped falling: the best play stands
            if len(plays) > 1 and rms > 0.95 * min(plays[:-1]):
                break
            if folded:  # the cycles after the first, phase-aligned, averaged: one period's error
                p = int(per)  # type: ignore[arg-type]
                e_per = e[p:(n // p) * p].reshape(-1, p).mean(axis=0)
                corr_period = _lowpass_periodic(corr_period + self.learning_gain * e_per, dt, cutoff)  # type: ignore[operator]
                corr = np.resize(corr_period, n)
            else:
                corr = _lowpass_periodic(corr + self.learning_gain * e, dt, cutoff)
        assert best is not None
        return TrackingResult(t=np.arange(n) * dt, reference=r, output=best[1], command=best[2], period=per,
                              clipped=guard.clipped, label=label,
                              info={"mode": "buffered", "feedback": False, "feedback_note": NO_LOOP,
                                    "learning": bool(learning), "plays": len(plays), "play_rms_um": plays,
                                    "safety": guard.counts()})

    def _play(self, table: FloatArray) -> FloatArray:
        from .plant import play_checked

        return play_checked(self.plant, table)

    @staticmethod
    def _bridge_glitches(y: FloatArray, guard: GuardedPlant) -> FloatArray:
        """A played record with its isolated sensor glitches bridged (:mod:`piezohyst.identify.glitches`,
        as the fit does), counted in ``guard``'s ``sensor_glitches`` and warned about once: learning
        across plays would otherwise copy them into the next table's correction."""
        from .identify.glitches import bridge_glitches, find_glitches
        from .plant import SensorDropoutWarning

        spikes = find_glitches(y)
        if not spikes.size:
            return y
        if not guard.dropouts.glitches:
            warnings.warn(f"the plant's played record has {spikes.size} isolated glitch"
                          f"{'es' if spikes.size > 1 else ''} (first at sample {int(spikes[0])}): a sensor's? "
                          "Bridged by interpolation; sensor_glitches in the run's safety counts says how many",
                          SensorDropoutWarning, stacklevel=4)
        guard.dropouts.glitches += int(spikes.size)
        return bridge_glitches(y, spikes)


def _fit_ahead_of_mode(ctl: CommissionedController, refit: Callable[[FloatArray], FitResult],
                       say: Callable[[str], None]) -> CommissionedController:
    """``ctl``, or where its identification run shows a lightly damped structural mode that the
    model leaves out (:attr:`~CommissionedController.structural_mode`), a controller whose model
    is fitted (``refit``, the same choice of kinds and structures) to the run read back through
    the mode's inverse (:data:`MODE_DECONVOLUTION_BAND`) and whose feedforward inverts the mode
    (:attr:`~CommissionedController.output_mode`), kept if through the mode it leaves less of the
    run than the first model (``info["ahead_of_mode"]`` gives both RMS errors).

    Why: the mode's ringing after every turn of the run is no hysteresis, yet the first fit bends
    its model and its delay towards it (delays of 9-23 samples where the stage had 0-3), and its
    feedforward rings the mode at the reference's harmonics. On eight random stages of four
    structures with a mode at 41-390 Hz found (0.5-2 % damping; 2-20 kHz), the feedforward alone
    went from 0.14-8.15 % e_max at 1 Hz and 0.18-36.9 % at 5 Hz to 0.13-7.48 % and 0.21-24.7 %
    (e.g. 2.29 / 4.02 -> 0.24 / 0.91 %, 1.73 / 2.70 -> 0.59 / 0.74 %, 0.54 / 1.21 -> 0.18 / 0.67 %;
    worse on two, at 5 Hz: 3.74 -> 3.91 %, 0.18 -> 0.21 %); on three of twelve stages drawn
    afterwards, 0.82 / 1.71 -> 0.18 / 0.96 %, 1.51 / 3.73 -> 0.58 / 0.94 %, 0.27 / 0.36 -> 0.16 /
    0.18 %. Searching for the mode costs every commissioning about 0.3 s on the VirtualRig's
    100,000-sample run (where it finds none).
    """
    m = ctl.structural_mode
    before = ctl._identification_left
    if before is None:
        return ctl
    if m is None:
        # a well-damped mode that the model's delay and lags took up no longer shows in what the
        # model leaves, but the run's transfer function peaks at it (transfer_peak_mode): on four
        # stages with modes damped 4.7-9.3 % at 51-69 Hz (delays of 15-85 samples fitted where the
        # stages had 0-3), the feedforward alone at 1 / 5 Hz went from 1.05 / 2.89, 1.96 / 2.71,
        # 0.86 / 1.28 and 1.57 / 1.53 % to 0.36 / 0.91, 1.58 / 1.67, 0.59 / 0.34 and 1.33 / 0.52 %.
        # A peak of the hysteresis' own distortion where the command has little power fits worse
        # ahead of it, and is dropped; at a null of the command's spectrum (146.6 Hz at 20 kHz,
        # where such peaks stood on three of six probe stages) none is read (MODE_INPUT_SHARE)
        f_hi = (ctl.fit.info.get("search") or {}).get("f_hi_hz")
        dt = ctl.plant.dt
        peak = (transfer_peak_mode(ctl.identification.u, ctl.identification.y, dt, f_min=2.0 * float(f_hi),
                                   f_max=MODE_SEARCH_TOP / dt) if f_hi else None)
        if peak is None:
            return ctl
        m = {"f_hz": peak["f_hz"], "zeta": peak["zeta"], "explained": math.nan}
        found_by = "the run's transfer function"
    else:
        found_by = "what the model leaves"
    say(f"fitting again ahead of a structural mode at {m['f_hz']:.4g} Hz ({100 * m['zeta']:.2g} % damping)")
    trial = replace(ctl, output_mode=dict(m), info=dict(ctl.info))
    ahead = trial._identification_ahead
    if not np.all(np.isfinite(ahead)):  # a record with gaps: the first model stands
        return ctl
    try:
        trial.fit = refit(ahead)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:  # the first model stands, and says why
        ctl.info["ahead_of_mode"] = {"f_hz": m["f_hz"], "zeta": m["zeta"], "found_by": found_by, "kept": False,
                                     "error": f"{type(exc).__name__}: {exc}"}
        return ctl
    after = trial._identification_left
    rms_before = float(np.sqrt(np.mean(before**2)))
    rms_after = float(np.sqrt(np.mean(after**2))) if after is not None and np.all(np.isfinite(after)) else math.inf
    kept = rms_after < rms_before
    if kept and trial.output_mode is not None and math.isnan(trial.output_mode["explained"]):
        trial.output_mode["explained"] = 1.0 - (rms_after / rms_before) ** 2
    out = trial if kept else ctl
    out.info["ahead_of_mode"] = {"f_hz": m["f_hz"], "zeta": m["zeta"], "found_by": found_by,
                                 "rmse_before_um": rms_before, "rmse_after_um": rms_after, "kept": kept}
    return out


def _loop_kernel_args(plant: Any, ff: Any, pid: Any) -> tuple[Any, ...] | None:
    """The compiled loop's view of the feedforward, when the plant, the feedforward and the
    feedback all have kernels (exact types: a subclass may override a step)."""
    from .control.pid import PID
    from .models.rate import RateCompensator
    from .rig import VirtualRig

    if type(plant) is not VirtualRig or (pid is not None and type(pid) is not PID) or type(ff) is not RateCompensator:
        return None
    return ff._kernel_args()  # type: ignore[no-any-return]


def _run_loop_compiled(ff_args: Any, plant: Any, guard: GuardedPlant, ff: Any, pid: Any, watch: LoopWatch,
                       r: FloatArray, y: FloatArray, u: FloatArray, clipped_at: Any, c_of: FloatArray, c_to_feedback: bool,
                       d: int, vpu: float, y_prev: float,
                       chunk: int, corr_for: Callable[[int, int], Any], end_of_chunk: Callable[[int], None] | None) -> bool:
    """The loop of ``_track_step`` compiled (:func:`piezohyst.control.compiled_loop._guarded_loop`), in
    chunks of ``chunk`` samples, reading the correction ``corr_for(k0, k1)`` gives for each, with
    ``end_of_chunk(k)`` (the learning) after each whole one; the states of the guard, the plant, the feedforward and the PID are left as the Python loop leaves
    them. False when the kernel gave up (the run must be made again in Python, from the start)."""
    from .control.compiled_loop import COMPLETED, _guarded_loop, limits_arrays, limits_back, pid_arrays, pid_back

    if ff_args is None:
        return False
    n = r.size
    ff_lim, ff_lim_state = limits_arrays(ff)
    pid_g, pid_state = pid_arrays(pid)
    g, g_state = guard.kernel_arrays()
    wv = np.array([watch.lo_u, watch.hi_u, watch.limit, watch.follow_rms, watch.settle, watch.WINDOW, watch.CHATTER],
                  dtype=np.float64)
    w_state = np.array([watch.n_lo, watch.n_hi], dtype=np.float64)
    loop_state = np.array([y_prev, 0.0])
    rr = np.ascontiguousarray(r, dtype=np.float64)
    for k0 in range(0, n, chunk):
        k1 = min(k0 + chunk, n)
        corr = corr_for(k0, k1)
        if isinstance(corr, str):  # a blend the kernel cannot read as one array: Python from the start
            return False
        has_corr = corr is not None
        noise = plant._rng.standard_normal(k1 - k0)
        args = (k0, k1, rr, y, u, clipped_at, corr if has_corr else np.zeros(1), has_corr, c_of, c_to_feedback, d, vpu,
                plant._p, plant._kv_a, plant._kv_g, plant._amp_a, plant._st, plant._line, plant._consts, noise,
                *ff_args, ff_lim, ff_lim_state, pid is not None, pid_g, pid_state, g, g_state, wv,
                bool(watch.watch_chatter), bool(watch.watch_window), w_state, loop_state)
        k = _guarded_loop(*args)
        plant._n += k1 - k0
        if k != COMPLETED:
            return False
        if end_of_chunk is not None and k1 - k0 == chunk:
            end_of_chunk(k1 - 1)
    # the objects' states as the Python loop leaves them
    ff._kernel_back(ff_args)
    guard.set_kernel_state(g_state)
    watch.n_lo, watch.n_hi = int(w_state[0]), int(w_state[1])
    limits_back(ff, ff_lim_state)
    pid_back(pid, pid_state)
    return True


class NoFeedbackWarning(UserWarning):
    """Commissioning tuned no feedback (``ki = 0``): no gain tried was well damped on the plant, or
    the feedback tracked worse than the feedforward alone (:func:`_why_no_feedback` says which)."""


def _why_no_feedback(tu: TuningResult) -> str:
    """Why the tuning ``tu`` ended at ``ki = 0``, from its experiments and verification runs, in
    a clause (what a user can change: the sensor, the probe, the plant's limits)."""
    if tu.verification and not any(c["ki"] > 0 and _feedback_helps(c) for c in tu.verification):
        first = tu.verification[0]
        return (f"on the verification run the feedback tracked worse than the feedforward alone at every gain "
                f"from {first['ki']:.4g} 1/s down (RMS {first['ratio']:.2f}x, e_max {first['e_max_ratio']:.2f}x)")
    ex = list(tu.experiments)
    if not ex:
        return "no bounded experiment was run"
    gains = f"{min(e['ki'] for e in ex):.4g}..{max(e['ki'] for e in ex):.4g} 1/s"
    if all(e["aborted"] for e in ex):
        return (f"every bounded experiment ({len(ex)}, gains {gains}) was stopped: the error or the command left "
                "the bounds the safe layer allows at a hold (a stage that keeps moving after the command reverses, "
                "a model far off at the hold's level)")
    if all(e["oscillation_grows"] for e in ex if not e["aborted"]):
        return f"an oscillation grew in every experiment that ran (gains {gains}): a resonance the model leaves out"
    if not any(e["answered"] for e in ex if not e["aborted"]):
        probe = float(ex[0]["probe_V"])
        return (f"the stage never answered half of the {probe:.3g} V probe within an experiment (gains {gains}): a "
                "sensor coarser than the probe's effect, a dead band at the hold's level, or a stage too slow for "
                "the experiments' length")
    return f"no experiment was well damped (gains {gains}; overshoot limit exceeded or stopped)"


class AmplifierSlewWarning(UserWarning):
    """``commission``'s identification fits worst where the command moves fastest: the amplifier
    may not follow it (a slew-rate or current limit); see :func:`followed_step`."""


#: The slew estimate (:func:`followed_step`): the steps tried fall from the record's largest by
#: octaves to a 64th of it, then by half, quarter and eighth octaves around the best, then placed
#: between its neighbours; a step is taken when a P-I model of the record slowed to it fits with
#: at most this share of the RMS error of the record as sent ...
SLEW_FIT_RATIO = 0.9
#: ... and of the record passed through the first-order lag that fits best
#: (:data:`SLEW_LAG_RATIO`): an amplifier lag also makes slowed commands fit better (a lag of
#: 15 ms: 0.65-0.71 of the error as sent), but a lag itself fits far better still (0.11-0.20),
#: where behind a slew limit the lag fits worse than the slew (slowed / lagged 0.10-0.41 behind
#: 400-2000 V/s, 0.58-0.84 with an amplifier lag or a resonance of its own; without a slew limit
#: 1.0-7.8 on the rig, the zoo, the census and stages behind 3-30 ms lags)
SLEW_LAG_RATIO = 0.9
_slowing = threading.local()


def followed_step(u: Any, y: Any, *, warmup: int = 0, max_delay: int = 20,
                  ratio: float = SLEW_FIT_RATIO, lag_ratio: float = SLEW_LAG_RATIO) -> dict[str, Any] | None:
    """The largest command step per sample an amplifier seems to follow, from a record of commands
    ``u`` and displacements ``y``: the step ``s`` whose slewed commands
    (:func:`~piezohyst.plant.rate_limited`) a 20-operator P-I model (delay chosen on held-out data,
    up to ``max_delay``) fits best, the samples after ``warmup`` fitted. None when no step fits
    with at most ``ratio`` (default :data:`SLEW_FIT_RATIO`) of the error of the commands as sent (the amplifier
    follows them, or what the model misses is something else), or where the commands passed through
    a first-order lag fit about as well (``lag_ratio``, :data:`SLEW_LAG_RATIO`): an amplifier that
    lags, not one that slews.

    Where the lag fits better, the three are judged again by a P-I model with output lags
    (:func:`_judged_with_output_lags`), and the step is taken when the slowed commands pass both
    bars there.

    Returns ``{"max_step": s, "rmse_as_sent": ..., "rmse_slewed": ..., "input_lag_samples": tau,
    "rmse_input_lag": ..., "judged_by": "a P-I model" or "a P-I model with output lags", "tried": [(s, rmse),
    ...]}`` (the three errors of the model that judged; ``tried`` the plain P-I model's).
    """
    from .plant import rate_limited

    u = np.asarray(u, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    steps = np.abs(np.diff(u))
    largest = float(steps.max()) if steps.size else 0.0
    if not largest > 0 or u.size - warmup < 200:
        return None

    def rmse(step: float) -> float:
        return _pi_fit_rmse(rate_limited(u, step) if step < largest else u, y, warmup, max_delay)

    tried = {largest: rmse(largest)}
    for k in range(1, 7):  # octaves down to a 64th
        tried[largest * 2.0 ** -k] = rmse(largest * 2.0 ** -k)
    best = min(tried, key=tried.__getitem__)
    for k in (-4, -2, -1, 1, 2, 4):  # then half, quarter and eighth octaves around the best
        s = best * 2.0 ** (k / 8)
        if s < largest:
            tried[s] = rmse(s)
    best = min(tried, key=tried.__getitem__)
    if not math.isfinite(tried[largest]) or not tried[best] <= ratio * tried[largest]:
        return None
    best = _refined_step(rmse, tried, best, largest)
    tau, lagged = _best_input_lag(u, y, warmup, max_delay)
    found = {"max_step": best, "rmse_as_sent": tried[largest], "rmse_slewed": tried[best],
             "input_lag_samples": tau, "rmse_input_lag": lagged, "judged_by": "a P-I model",
             "tried": sorted(tried.items(), reverse=True)}
    if tried[best] <= lag_ratio * lagged:
        return found
    # the input lag fitted better; but a P-I model without output lags also takes an input lag
    # for the stage's own rate dependence (creep, a lag after the hysteresis), so the three are
    # judged again with those lags in the model
    again = _judged_with_output_lags(u, y, warmup, max_delay, largest, best, tau)
    if not (again["rmse_slewed"] <= ratio * again["rmse_as_sent"]
            and again["rmse_slewed"] <= lag_ratio * again["rmse_input_lag"]):
        return None
    return {**found, **again, "judged_by": "a P-I model with output lags"}


def _judged_with_output_lags(u: FloatArray, y: FloatArray, warmup: int, max_delay: int, largest: float,
                             step: float, tau: float) -> dict[str, float]:
    """The RMS errors of a 20-operator P-I model with output lags (every lag the record can
    identify, :func:`~piezohyst.identify.search_ranges`, in samples), each at the delay a plain
    P-I model chooses for it, fitted from the commands as sent, slowed to ``step``, and through
    the first-order lag of ``tau`` samples (:func:`followed_step`). Found on an asymmetric
    Bouc-Wen stage with an 18 ms lag after it, behind 3000 V/s (20 kHz, 0-120 V): slowed / lagged
    1.07 with the plain P-I model (a 3.8 ms input lag stood in for the stage's own lag), 0.87 with
    the lags; without the slew limit 1.03."""
    from .identify import Structure, fit_pi, fit_structure, search_ranges
    from .plant import rate_limited

    taus = search_ranges(u[warmup:], 1.0, u.size - warmup, one_rate_rule=False).creep_taus

    def rmse(v: FloatArray) -> float:
        try:
            d = fit_pi(v[warmup:], y[warmup:], 20, delay="auto", max_auto_delay=max_delay).delay
            fit, _ = fit_structure(v, y, 1.0, Structure("pi", 20, taus=taus, delay=d), warmup=warmup)
        except ValueError:
            return math.inf
        return float(fit.rmse)

    return {"rmse_as_sent": rmse(u), "rmse_slewed": rmse(rate_limited(u, step) if step < largest else u),
            "rmse_input_lag": rmse(_through_lag(u, tau))}


def _pi_fit_rmse(v: FloatArray, y: FloatArray, warmup: int, max_delay: int) -> float:
    """The RMS error of a 20-operator P-I model fitted from the commands ``v`` (as the amplifier
    passed them on, in a guess) to ``y``, the samples after ``warmup`` (delay chosen on held-out
    data, up to ``max_delay``); infinite where none fits (``v`` so far from what reached the stage
    that the output no longer rises with it)."""
    from .identify import fit_pi

    try:
        return float(fit_pi(v[warmup:], y[warmup:], 20, delay="auto", max_auto_delay=max_delay).rmse)
    except ValueError:
        return math.inf


def _through_lag(u: FloatArray, tau: float) -> FloatArray:
    """``u`` through a first-order lag of ``tau`` samples, from rest at its first command."""
    from .models.rate import first_order_lag

    return first_order_lag(u - u[0], math.exp(-1.0 / tau)) + u[0]


def _best_input_lag(u: FloatArray, y: FloatArray, warmup: int, max_delay: int) -> tuple[float, float]:
    """The time constant (samples) of the first-order lag, from half a sample to a twentieth of
    the record, through which a 20-operator P-I model fits ``u`` to ``y`` best, and that fit's
    RMS error: octaves, then bounded Brent between the best's neighbours."""
    from scipy.optimize import minimize_scalar

    def rmse(x: float) -> float:  # from rest at the first command
        return _pi_fit_rmse(_through_lag(u, 2.0 ** x), y, warmup, max_delay)

    grid = np.arange(-1.0, math.log2(max(u.size / 20.0, 1.0)) + 1e-9, 1.0)
    if grid.size == 0:
        return 0.0, math.inf
    errors = [rmse(x) for x in grid]
    i = int(np.argmin(errors))
    if grid.size > 1:
        got = minimize_scalar(rmse, bounds=(grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]),
                              method="bounded", options={"xatol": 1.0 / 16})
        if got.fun < errors[i]:
            return float(2.0 ** got.x), float(got.fun)
    return float(2.0 ** grid[i]), float(errors[i])


#: how finely :func:`followed_step` places the step between its grid's neighbours (octaves): a
#: step limit below the amplifier's slew throttles every fast command (behind 1500 V/s, a limit
#: at 1414 V/s left a 5 Hz run at 5.0 % e_max with feedback and learning, 1500 V/s at 0.42 %)
SLEW_STEP_OCTAVES = 1.0 / 64


def _refined_step(rmse: Callable[[float], float], tried: dict[float, float], best: float, largest: float) -> float:
    """The step between ``best``'s tried neighbours where ``rmse`` is least (bounded Brent on the
    step's logarithm, to :data:`SLEW_STEP_OCTAVES`); each step evaluated is added to ``tried``."""
    from scipy.optimize import minimize_scalar

    below = [s for s in tried if s < best]
    above = [s for s in tried if s > best]
    lo = math.log2(max(below) if below else best * 2.0 ** -0.125)
    hi = math.log2(min(above) if above else best)
    if not hi - lo > SLEW_STEP_OCTAVES:
        return best

    def objective(x: float) -> float:
        s = min(2.0 ** x, largest)
        if s not in tried:
            tried[s] = rmse(s)
        return tried[s]

    minimize_scalar(objective, bounds=(lo, hi), method="bounded", options={"xatol": SLEW_STEP_OCTAVES})
    return min(tried, key=tried.__getitem__)


def _slower_amplifier(plant: Any, call: dict[str, Any], ds: Dataset, warmup: int, limits: CommandLimits,
                      said: str, say: Callable[[str], None]) -> "CommissionedController | None":
    """Where the identification run looks like an amplifier slower than the excitation (``said``:
    what else showed it, if anything), its slew (:func:`followed_step`) and ``commission`` again with a step limit
    it follows, so that every command (the excitation's, the tuning's, tracking's) reaches the
    stage as sent; None where the caller set the step limit or the excitation, where this is
    the second time, or where no slew explains the run."""
    if call["max_step_fraction"] is not None or call["excitation"] is not None or getattr(_slowing, "active", False):
        return None
    say("the amplifier's slew rate, from the identification run")
    slew = followed_step(ds.u, ds.y, warmup=warmup)
    if slew is None:
        return None
    dt = float(ds.dt)
    fraction = slew["max_step"] / limits.span
    warnings.warn(f"commissioning {type(plant).__name__}: {said + '. ' if said else ''}"
                  f"{slew['judged_by'][0].upper() + slew['judged_by'][1:]} fits its "
                  f"identification run best with the commands "
                  f"slowed to {slew['max_step']:.3g} V per sample ({slew['max_step'] / dt:.4g} V/s; RMS error "
                  f"{slew['rmse_as_sent']:.3g} -> {slew['rmse_slewed']:.3g} um, against {slew['rmse_input_lag']:.3g} um "
                  f"through the first-order lag that fits best, {slew['input_lag_samples'] * dt * 1e3:.3g} ms): the "
                  "amplifier does not follow "
                  f"faster commands (a slew-rate or current limit). Commissioning again with max_step_fraction="
                  f"{fraction:.3g}, the controller's step limit from now on (declare the amplifier's, if you know "
                  "it, to skip this)", AmplifierSlewWarning, stacklevel=3)
    ctl = _commission_again(plant, call, _slowing, max_step_fraction=fraction)  # (it never slows again)
    ctl.info["slew_estimate"] = {k: v for k, v in slew.items() if k != "tried"}
    return ctl


#: how far inside the input at which a non-monotone stage follows the command again the range is
#: narrowed (fraction of the range)
MONOTONE_MARGIN = 0.02
_narrowing = threading.local()


#: The strokes (um, over the whole identification run) beyond which a reading is taken for one in
#: another unit: no piezo stage moves less than a nanometre over its whole range, nor more than
#: 10 cm.
PLAUSIBLE_STROKE_UM = (1e-3, 1e5)


def _warn_if_stroke_implausible(y: FloatArray, plant: Any) -> None:
    """Warn where the stage's stroke over its whole range reads below a nanometre or above 10 cm:
    a sensor read in metres (or in counts, nm) made every figure of the commissioning wrong by its
    factor, silently (found by fuzzing: a 17 um stage read in metres commissioned a stroke of
    1.7e-5 um)."""
    stroke = float(np.ptp(y[np.isfinite(y)])) if np.isfinite(y).any() else 0.0
    lo, hi = PLAUSIBLE_STROKE_UM
    if 0.0 < stroke < lo or stroke > hi:
        guess = "metres or millimetres" if stroke < lo else "nanometres or sensor counts"
        warnings.warn(f"the stage moved {stroke:.3g} um over its whole range in the identification run, which no piezo "
                      f"stage does: is {type(plant).__name__}.step()/play() reading in {guess}? piezohyst reads "
                      "the displacement in micrometres, and every figure scales with it", UserWarning, stacklevel=3)


def late_follow(u: FloatArray, y: FloatArray) -> tuple[int, float] | None:
    """``(lag, r)`` where the output follows the command ``lag`` samples late with correlation
    ``r >= 0.9`` (lags up to a quarter of the record, by FFT cross-correlation), and no lag of a
    few samples does as well; None otherwise. A sensor read 50 or more samples late made a stage
    look not monotone (and the suggested range came out reversed) or "hardly following" the
    command (found by fuzzing)."""
    a = np.asarray(u, dtype=np.float64) - float(np.mean(u))
    b = np.asarray(y, dtype=np.float64) - float(np.mean(y))
    n = a.size
    if n < 16 or not (np.any(a) and np.any(b)):
        return None
    size = 1 << int(math.ceil(math.log2(2 * n)))
    # sum_k y[k + lag] u[k] for lags 0 .. n/4, scaled by the overlap: the correlation at each lag
    # (the energies over the whole record stand for the overlap's: a verdict, not a figure)
    xc = np.fft.irfft(np.fft.rfft(b, size) * np.conj(np.fft.rfft(a, size)), size)[: n // 4]
    overlap = n - np.arange(xc.size)
    r = xc * (n / overlap) / math.sqrt(float(np.sum(a**2)) * float(np.sum(b**2)))
    lag = int(np.argmax(r))
    best = float(r[lag])
    if best < 0.9 or lag <= 4 or float(np.max(r[:5])) >= 0.9:
        return None
    return lag, min(best, 1.0)


def _commission_where_monotone(plant: Any, call: dict[str, Any], mono: MonotoneRange, limits: CommandLimits,
                               own_excitation: bool, late_said: Callable[[], str] = lambda: ""
                               ) -> "CommissionedController":
    """The identification showed the stage not monotone at an end of the range (a butterfly
    loop): commission again within the part where it is, with a warning; or, where that cannot be
    done safely (an excitation of the caller's, a rest command outside that part, a second time),
    refuse with the range to give."""
    lo, hi = limits.low, limits.high
    margin = MONOTONE_MARGIN * (hi - lo)
    new_lo = lo if mono.low is None else min(mono.low + margin, hi)
    new_hi = hi if mono.high is None else max(mono.high - margin, lo)
    what = mono.describe(lo, hi)
    fix = f"commission(plant, u_range=({new_lo:.4g}, {new_hi:.4g}))"
    if not new_hi - new_lo > 0.0:
        # (the range suggested came out reversed, 71..29 V: found by fuzzing, on a stage whose
        # sensor lagged 50 samples)
        raise ValueError(late_said() + f"{what.split(': the stage is not monotone')[0]}: no part of the range is left "
                         "where it is monotone, which no stage does; a sensor read late (a delay of many samples, a "
                         "buffer between the plant and the stage) looks so: check what step() returns")
    if own_excitation or getattr(_narrowing, "active", False) or not new_lo <= limits.rest <= new_hi \
            or not new_hi - new_lo > 0.2 * (hi - lo):
        raise ValueError(late_said() + f"{what}; {fix}")
    warnings.warn(f"{what}. Commissioning again within {new_lo:.4g}..{new_hi:.4g} V, the controller's range "
                  f"from now on ({100 * MONOTONE_MARGIN:g} % of the range inside that)", NotMonotoneWarning, stacklevel=3)
    return _commission_within(plant, call, new_lo, new_hi)


def _narrowed_to_moving(dead: DeadRange, limits: CommandLimits) -> tuple[float, float] | None:
    """The range commissioning moves to where ``dead`` was found: up to its edge (where no bin
    beyond moves: a bin into the dead part at most), the rest command always inside; None when
    that is not narrower by a bin of the detection at least (the rest command at a dead end keeps
    it).

    No margin beyond the edge: beyond a stop the stage's hidden state moves on where its output
    does not (a Maxwell-slip stage against a stop at 60 % of its stroke, feedforward at
    1 / 3 / 5 Hz with margins of 0, 2, 5 and 10 % of the range: 2.0 / 2.0 / 1.8, 1.8 / 2.0 / 2.0,
    3.1 / 3.2 / 3.1 and 4.2 / 4.4 / 4.4 % e_max; P-I elements against one at 80 % of theirs, the
    range ending at 78, 80, 82 and 84 V: 0.5, 0.7, 2.6 and 4.6 % at 1 Hz)."""
    lo, hi = limits.low, limits.high
    new_lo = lo if dead.low is None else max(lo, min(dead.low, limits.rest))
    new_hi = hi if dead.high is None else min(hi, max(dead.high, limits.rest))
    if (new_lo - lo) + (hi - new_hi) < (hi - lo) / DEAD_BINS:
        return None
    return new_lo, new_hi


def _commission_within(plant: Any, call: dict[str, Any], new_lo: float, new_hi: float) -> "CommissionedController":
    """``commission`` again with ``u_range=(new_lo, new_hi)``, once (a narrowing never narrows again)."""
    return _commission_again(plant, call, _narrowing, u_range=(new_lo, new_hi))


def _commission_again(plant: Any, call: dict[str, Any], once: threading.local, **changes: Any) -> "CommissionedController":
    """``commission`` again with the arguments ``call`` as ``changes`` changes them, with
    ``once.active`` set meanwhile (so that what asked for it does not ask again)."""
    once.active = True
    try:
        return commission(plant, **{**call, **changes})
    finally:
        once.active = False


def commission(plant: Any, seed: int = 0, *, u_range: tuple[float, float] | None = None, n: int | None = None,
               excitation: Any = None, tune: bool = True, learning_gain: float = 0.5,
               max_step_fraction: float | None = None, u_rest: float | None = None,
               tuning: SafeTuningOptions | None = None, kinds: Sequence[str] = COMMISSION_KINDS,
               max_plays: int = 8, progress: Callable[[str], None] | None = None,
               conditioning: bool = False) -> CommissionedController:
    """Identify ``plant`` and build its controller, safely (module docstring).

    Parameters
    ----------
    plant : Plant or BufferedPlant
        ``dt``, ``reset()``, ``step(u) -> y`` (V in, µm out), or ``dt`` and ``play(table) -> y``;
        ``u_range`` and ``excite`` are used when it has them.
    seed : int
        Kept for reproducible variants of the experiment; the default experiment is deterministic
        (the plant's own noise is the plant's business).
    u_range : (low, high), optional
        The amplifier's range, V; default the plant's ``u_range``, else (0, 100). No command
        outside it is ever sent.
    max_step_fraction : float, optional
        The largest change of the command from one sample to the next, as a fraction of the range
        (default 0.02: 2 V per sample on 0-100 V; below 2 kHz sampling, what a full-range 10 Hz
        sinusoid needs: :func:`~piezohyst.plant.default_step_fraction`). Ramps are as long as it
        requires at the plant's sample rate.
    u_rest : float, optional
        The command the plant holds before commissioning (default 0 V, or the nearest end of a
        range without 0): the first ramp starts there. A per-sample plant is at it after ``reset()``.
    excitation : array_like, optional
        Your own identification command instead of :func:`commissioning_excitation`; refused if it
        leaves the range or changes faster than the step limit (from ``u_rest``).
    tune : bool
        Tune integral feedback (plants with a per-sample loop only).
    tuning : SafeTuningOptions, optional
        Margins and experiment limits of the feedback tuning.
    n : int, optional
        Fix the P-I operators / Preisach levels (default: chosen on held-out data).
    kinds : sequence of str
        The model kinds to choose from.
    max_plays : int
        On a buffered plant, the most plays learning uses per ``track``.
    progress : callable, optional
        Called with a short description before each stage (and passed on to
        :func:`~piezohyst.identify.fit_model`); a :class:`~piezohyst.Progress` shows them.
    conditioning : bool
        Start the identification run and every tracking run with the conditioning sweep over the
        whole range (module docstring, step 3; the controller's ``conditioning``, also per run in
        ``track``); the identification's sweep is not fitted (``fit_model``'s ``warmup``), so the
        model's initial state need not be the stage's: for a stage whose hysteresis keeps the
        memory of what it did before. Off by default (the stage travels its full stroke before
        each run).

    Returns
    -------
    CommissionedController
        ``info["safety"]`` holds the limits and what the safe layer counted (commands sent,
        clipped, slowed; the largest step sent).
    """
    call = {k: v for k, v in locals().items() if k != "plant"}  # to commission again in a narrower range
    t0 = time.perf_counter()
    # the options are checked before anything is sent to the plant (an unknown kind, a tuning
    # given as a dict or a progress that cannot be called failed after the identification run,
    # and tune="no" tuned: found by fuzzing)
    for name, flag in (("tune", tune), ("conditioning", conditioning)):
        as_flag(name, flag)
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a whole number >= 0, got {seed!r}")
    if tuning is not None and not isinstance(tuning, SafeTuningOptions):
        raise TypeError(f"tuning must be a SafeTuningOptions (piezohyst.control.tuning.SafeTuningOptions(...)), "
                        f"got {type(tuning).__name__}")
    if tuning is not None and not tune:
        raise ValueError("tuning= sets the limits of the feedback's tuning, and tune=False skips it: drop one")
    if progress is not None and not callable(progress):
        raise TypeError(f"progress must be a function of one str (or None), got {type(progress).__name__}")
    if isinstance(kinds, str):
        kinds = [kinds]
    kinds = list(kinds)
    if not kinds:
        raise ValueError("kinds is empty: name the model kinds to choose among (default: every kind commission uses)")
    for k in kinds:
        kind_class(k)  # an unknown kind is a ValueError naming the kinds
    # learning converges for 0 < gain < 2 where the model's inverse makes G ~ 1 (module
    # docstring, step 5); a gain outside that grows the error cycle by cycle
    learning_gain = as_scalar("learning_gain", learning_gain, positive=True)
    if not learning_gain < 2.0:
        raise ValueError(f"learning_gain must be below 2 (learning diverges above), got {learning_gain:g}")
    if n is not None:
        n = as_count("n", n, minimum=1)
    max_plays = as_count("max_plays", max_plays, minimum=1)
    dt = check_plant(plant)
    mode = plant_mode(plant)
    if mode == "buffered" and tuning is not None:
        raise ValueError("tuning= sets the limits of the integral feedback's tuning; this plant only plays tables "
                         "(BufferedPlant), so there is no loop to tune: drop it")
    rng_u = plant_u_range(plant, u_range) or (0.0, 100.0)
    if max_step_fraction is None:
        max_step_fraction = default_step_fraction(dt)
    limits = _limits(dt, rng_u, max_step_fraction, u_rest)
    n_id = None
    if excitation is None:
        cmd = commissioning_excitation(dt, rng_u, max_step_fraction=max_step_fraction, start=limits.rest)
        n_id = identification_length(dt, rng_u, max_step_fraction=max_step_fraction, start=limits.rest)
    else:
        cmd = as_signal("excitation", excitation, min_length=50)
        chk = check_table(cmd, limits, start=limits.rest)
        if chk["outside"] or chk["largest_step_V"] > limits.max_step:
            raise ValueError(
                f"the excitation is not safe to send: {chk['outside']} command(s) outside {limits.low:g}.."
                f"{limits.high:g} V, largest step {chk['largest_step_V']:.4g} V (limit {limits.max_step:.4g} V "
                f"per sample, max_step_fraction={max_step_fraction:g}, from the rest command {limits.rest:g} V); "
                "ramp it or change the limits")
    warmup = 0
    if conditioning:
        # the stage's past wiped out first; the fit runs its model through the sweep, unfitted
        sweep = conditioning_sweep(limits, dt, CommissionedController.CONDITIONING_LEG_S)
        pre = np.concatenate([sweep, limits.ramp(float(sweep[-1]), limits.rest, dt)])
        cmd = np.concatenate([pre, cmd])
        warmup = int(pre.size)
        if n_id is not None:
            n_id += warmup
    guard = GuardedPlant(plant, limits)
    say = progress or (lambda s: None)
    say(f"identification run ({cmd.size * dt:.3g} s)")
    if mode == "step":
        guard.reset()
        if callable(getattr(plant, "excite", None)):  # compiled whole run (the VirtualRig), the same commands
            sent = guard.guard_table(cmd)
            try:
                ds = checked_excitation(plant, sent)  # (an ndarray back was an AttributeError deep inside)
            except BaseException as exc:
                # the plant played the table itself: where it stopped, no command of ours says
                # (found by a helper: a fault inside excite() left the stage at 76.6 V unsaid)
                exc.add_note(f"{type(plant).__name__}.excite() played the identification run (commands over "
                             f"{float(sent.min()):.4g}..{float(sent.max()):.4g} V) and failed, or gave back no record of "
                             f"it; piezohyst sent no command of its own during it and cannot tell where it left the "
                             f"stage: bring the stage to its rest command ({guard.limits.rest:.4g} V) before the next run")
                raise
            stuck_reading(np.asarray(ds.u), np.asarray(ds.y), guard.limits.span, dt, f"the plant ({type(plant).__name__})")
        else:
            try:
                y = guard.play(cmd)
            except BaseException:  # interrupted or the plant failed part-way: back to rest, as a run ends
                guard.back_to_rest()
                raise
            ds = Dataset(np.arange(cmd.size, dtype=np.float64) * dt, cmd, y, {"source": type(plant).__name__, "driven_by": "step"})
    else:
        y = guard.play(cmd)
        ds = Dataset(np.arange(cmd.size, dtype=np.float64) * dt, cmd, y, {"source": type(plant).__name__, "driven_by": "play"})
    ident_counts = guard.counts()
    _warn_if_stroke_implausible(ds.y[warmup:], plant)
    with np.errstate(invalid="ignore", divide="ignore"):
        r_run = float(np.corrcoef(ds.u[warmup:], ds.y[warmup:])[0, 1])
    # (a falling output, r < 0, is below the bound too; NaN, a constant output, is not above it)
    def late_said() -> str:
        """The lead of a refusal where the run's output follows its command many samples late."""
        late = late_follow(ds.u[warmup:], ds.y[warmup:]) if not r_run >= 0.9 else None
        return "" if late is None else (
            f"the output follows the command about {late[0]} samples ({late[0] * dt:.3g} s) late (correlation "
            f"{late[1]:.2f} at that lag, {r_run:.2f} without it): a sensor read that late, or a buffer between "
            f"{type(plant).__name__} and the stage, makes a stage look so; make step()/play() return the reading "
            "that follows each command. ")

    if not r_run >= WEAK_CORRELATION:
        rising = rising_part(ds.u[warmup:], ds.y[warmup:])
        hint = butterfly_hint(rising, "command", " V", "keep the command where it rises "
                              + ("" if rising is None else
                                 f"(commission(plant, u_range=({rising[0]:.4g}, {rising[1]:.4g})))"))
        method = f"{type(plant).__name__}.{'step' if mode == 'step' else 'play'}()"
        if not (r_run < 0.0 and (r_run <= -WEAK_CORRELATION or rising is not None)):  # (NaN: a constant output)
            # found by fuzzing: an amplifier switched off was told its sensor was mounted the other
            # way round, and a pure-noise output commissioned once in four seeds (a butterfly loop,
            # which rises over part of the range, keeps the message below)
            part = moving_part(ds.u[warmup:], ds.y[warmup:])
            if part is not None and not hint:
                hint = (f". Its output changes only over {part[0]:.4g}..{part[1]:.4g} V (a stage or a sensor that "
                        f"saturates beyond?): commission(plant, u_range=({part[0]:.4g}, {part[1]:.4g})) identifies "
                        "it there")
            raise ValueError(
                late_said() + "the plant's displacement hardly follows the command over the identification run ("
                + (f"correlation {r_run:.2f}" if math.isfinite(r_run) else "a constant output")
                + f" over {float(np.min(ds.u)):.4g}..{float(np.max(ds.u)):.4g} V; output span "
                f"{float(np.ptp(ds.y[warmup:])):.3g} um): is the amplifier on, the stage connected, and does "
                f"{method} return this stage's sensor reading in um?" + (" " + hint[2:] if hint else ""))
        raise ValueError(
            f"the plant's displacement falls as the command rises (its gain is negative, e.g. a sensor "
            f"mounted the other way round): make {method} return the displacement "
            "with the sign that rises with the command (multiply it by -1)" + hint)
    mono = monotone_range(ds.u[warmup:], ds.y[warmup:])
    # an amplifier slower than the excitation, looked for on every run whose step limit the caller
    # left to the default, before a model is fitted to the distorted run: where an amplifier lag
    # hides it, neither the fit's rate warning nor its hold-out error shows it (behind 1500-3000 V/s
    # with amplifier lags of 0.5-6 ms: no warning, hold-out 1-3 % of span, feedforward 2.7-4.1 %
    # e_max at 1 Hz); far slower, it goes on moving the stage after the command has reversed, which
    # looks like a stage that is not monotone (behind 400 V/s on 0-100 V it was refused with a
    # range of 6 V to commission in)
    slower = _slower_amplifier(plant, call, ds, warmup, limits, "" if mono.monotone else
                               f"the run looks not monotone ({mono.describe(limits.low, limits.high)})", say)
    if slower is not None:
        return slower
    if not mono.monotone:
        return _commission_where_monotone(plant, call, mono, limits, excitation is not None, late_said)
    dead = dead_range(ds.u[warmup:], ds.y[warmup:])
    if dead.found:
        narrowed = _narrowed_to_moving(dead, limits)
        what = dead.describe(limits.low, limits.high)
        if narrowed is not None and excitation is None and not getattr(_narrowing, "active", False):
            # the excitation's loops are centred on the range: over a range half dead they miss the
            # loops a tracking run makes where the stage moves (a unipolar element on -200..200 V:
            # feedforward 6.1 / 5.0 / 4.5 % e_max at 1 / 3 / 5 Hz, 1.0 / 0.7 / 0.8 % commissioned
            # again within -8..200 V)
            warnings.warn(f"{what}. Commissioning again within {narrowed[0]:.4g}..{narrowed[1]:.4g} V, the "
                          "controller's range from now on (where the stage moves, and the rest command)",
                          DeadRangeWarning, stacklevel=2)
            return _commission_within(plant, call, *narrowed)
        if narrowed is not None and excitation is not None:
            warnings.warn(f"{what}: the excitation given spends that part for nothing; "
                          f"commission(plant, u_range=({narrowed[0]:.4g}, {narrowed[1]:.4g})) identifies where it "
                          "moves", DeadRangeWarning, stacklevel=2)
    if n_id is not None:
        # fit on the identification part, choose on the rest; the winner is refitted on all of it
        fit = fit_model(ds.u, ds.y, dt, "auto", kinds=kinds, n=n, holdout=int(ds.u.size - n_id),
                        progress=progress, warmup=warmup)
    else:
        fit = fit_model(ds.u, ds.y, dt, "auto", kinds=kinds, n=n, progress=progress, warmup=warmup)
    ctl = CommissionedController(plant=plant, fit=fit, tuning=None, identification=ds, learning_gain=learning_gain,
                                 limits=limits, max_plays=max_plays, conditioning=bool(conditioning))

    def refit(y: FloatArray) -> FitResult:  # the same choice as above, of another record
        if n_id is not None:
            return fit_model(ds.u, y, dt, "auto", kinds=kinds, n=n, holdout=int(ds.u.size - n_id),
                             progress=progress, warmup=warmup)
        return fit_model(ds.u, y, dt, "auto", kinds=kinds, n=n, progress=progress, warmup=warmup)

    ctl = _fit_ahead_of_mode(ctl, refit, say)
    # (of the model kept: a mode's ringing after the fastest turns looked like a slow amplifier)
    by_rate = ctl.fit.info.get("residual_by_rate") or {}
    said = (f"{by_rate['warning']} (the excitation's largest step was {float(np.max(np.abs(np.diff(ds.u)))):.3g} V per "
            f"sample, max_step_fraction={limits.max_step / limits.span:.3g})"
            if by_rate.get("amplifier_may_not_follow") else "")
    if said:
        warnings.warn(f"commissioning {type(plant).__name__}: {said}", AmplifierSlewWarning, stacklevel=2)
    tune_counts = None
    if mode == "buffered":
        ctl.info["held_command"] = guard.last
        ctl.info["feedback"] = NO_LOOP
    elif tune:
        say("tuning the integral feedback on the plant (bounded experiments)")
        tune_counts = ctl.tune(tuning)
    ctl.time_s = time.perf_counter() - t0
    ctl.info["seed"] = seed
    ctl.info["safety"] = {"limits": limits.to_dict(), "identification": ident_counts, "tuning": tune_counts}
    return ctl
