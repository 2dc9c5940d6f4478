"""Commissioning a stage: identify it, build the best feedforward and feedback, track (beyond the paper).

``ctl = commission(plant)`` runs an identification experiment on any object that follows the
Plant protocol, and returns a :class:`CommissionedController` whose ``ctl.track(reference)``
returns a :class:`~piezohyst.control.tracking.TrackingResult`. Nothing here assumes the plant is
the :class:`~piezohyst.rig.VirtualRig`: it is how a user commissions a real stage.

What it does, and why (the contribution of each step is measured in ``piezohyst reproduce``'s
ablation and in ``tests/test_commission.py``):

1. **Identification experiment** (:func:`commissioning_excitation`, ~9.5 s): a full-range 1 Hz
   sinusoid (major loop), a 2 Hz sinusoid of decaying amplitude (nested minor loops: every
   threshold is exercised), full-range 5 and 10 Hz sinusoids (rate dependence), a hold at
   mid-range (creep) and a 3 Hz sinusoid. Within the amplifier range the plant reports
   (``plant.u_range``) or the one given.
2. **Model**: chosen on held-out data among every linear kind and structure
   (:func:`~piezohyst.identify.fit_model`): P-I, asymmetric P-I or Preisach, with an input lag
   (amplifier + stack) and output lags (rate dependence, creep) where they predict better, the
   sensor delay searched over what the data show; each candidate is one bounded least-squares
   fit, invertible with a stable inverse by construction (:mod:`piezohyst.identify.linear`).
3. **Feedforward**: the model's compensator (its exact or numerical inverse), fed the
   reference ``delay`` samples ahead (the reference is known in advance; this cancels the
   sensor's delay).
4. **Feedback**: integral action, tuned on the plant
   (:func:`~piezohyst.control.tuning.tune_integral_feedback`, ``ki = ki_u / 3``), added to the
   *command*, scaled by the model's mean slope (V per µm), with anti-windup on the plant's
   saturation. Not to the feedforward's input: the inverse of the input lag is a lead with a
   high-frequency gain of ``1/(1-b)`` (8.5 for 0.8 ms at 10 kHz) that would hand the
   feedback's noise and the stage's resonance back to the loop amplified (measured: a
   sustained 1.7 kHz oscillation on the rig).
5. **Iterative learning** for references that repeat: after each cycle the measured error
   corrects the feedforward's input for the next one, ``c <- Q(c + gamma e)``, with ``Q`` a
   zero-phase low-pass (cut-off ``ilc_cutoff_hz``, default 15 harmonics of the reference,
   at least 50 Hz). It converges when ``|Q(w)| |1 - gamma G(w)| < 1`` wherever Q passes, G being
   the response of the output to the correction; with the model's inverse in the loop
   ``G ~ 1`` below the cut-off, so ``gamma = 0.5`` gives a contraction of about 0.5 per cycle.
   Learning stops (the best correction is kept) as soon as a cycle's RMS error is no longer
   below 0.95 times the best so far.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ._validation import FloatArray, as_signal
from .control.tracking import LoopWatch, TrackingResult
from .control.tuning import TuningResult, tune_integral_feedback
from .data import Dataset
from .plant import open_loop
from .identify import FitResult, fit_model
from .models.base import Compensator, kind_of
from .signals import estimate_period, sinusoid

#: The kinds commissioning chooses from: fast to fit, each with an exact or numerical inverse.
COMMISSION_KINDS = ("prandtl-ishlinskii", "rate-dependent", "asymmetric-pi", "preisach")


def commissioning_excitation(dt: float, u_range: tuple[float, float] = (0.0, 100.0)) -> FloatArray:
    """The identification experiment's command (V): see the module docstring, step 1."""
    lo, hi = u_range
    mid, amp = 0.5 * (lo + hi), 0.5 * (hi - lo)
    parts = [sinusoid(1.0, 2, lo, hi, dt)]
    t = np.arange(int(round(4.0 / dt))) * dt
    parts.append(mid - amp * np.cos(2 * np.pi * 2.0 * t) * np.linspace(1.0, 0.2, t.size))
    for f in (5.0, 10.0):
        parts.append(sinusoid(f, 5, lo, hi, dt))
    parts.append(np.full(int(round(1.0 / dt)), mid))
    parts.append(sinusoid(3.0, 3, lo, hi, dt))
    return np.concatenate(parts)


def _lowpass_periodic(x: FloatArray, dt: float, cutoff_hz: float) -> FloatArray:
    """Zero-phase low-pass of one period of a periodic signal (FFT, bins above the cut-off removed)."""
    spec = np.fft.rfft(x)
    freqs = np.fft.rfftfreq(x.size, dt)
    spec[freqs > cutoff_hz] = 0.0
    return np.fft.irfft(spec, x.size)


@dataclass
class CommissionedController:
    """Feedforward (exact inverse of the identified rate-dependent P-I) + integral feedback + ILC."""

    plant: Any
    fit: FitResult
    tuning: TuningResult | None
    identification: Dataset
    learning_gain: float = 0.5
    ilc_cutoff_hz: float | None = None
    time_s: float = 0.0
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def model(self) -> Any:
        """The identified model (the fit's)."""
        return self.fit.model

    @property
    def delay(self) -> int:
        """The sensor delay found by the identification, in samples (previewed by the feedforward)."""
        return self.fit.delay

    def describe(self) -> dict[str, Any]:
        """The controller in plain data: model kind and structure, fit and hold-out errors, delay, gains."""
        m = self.model
        hold = self.fit.info.get("holdout", {})
        return {
            "model": kind_of(m), "structure": self.fit.info.get("chosen", self.fit.method),
            "fit_rmse_um": self.fit.rmse, "holdout_rmse_um": hold.get("rmse"),
            "holdout_percent_of_span": hold.get("percent_of_span"), "delay_samples": self.delay,
            "ki": self.tuning.ki if self.tuning else None,
            "ki_ultimate": self.tuning.ki_ultimate if self.tuning else None,
            "learning_gain": self.learning_gain, "commissioning_time_s": self.time_s,
            "warnings": list(self.fit.warnings),
        }

    def feedforward(self) -> Compensator:
        """The identified model's compensator (desired µm in, volts out), at the plant's rate."""
        return self.model.compensator(self.plant.dt if self.model.dynamic else None)

    @property
    def volts_per_um(self) -> float:
        """1 / the model's mean slope: converts a feedback correction in µm into volts."""
        return float(np.ptp(self.identification.u) / np.ptp(self.identification.y))

    def track(self, reference: Any, *, feedback: bool = True, learning: bool = True,
              period: int | None = None, label: str = "") -> TrackingResult:
        """Follow ``reference`` (µm, one sample per ``plant.dt``) from rest.

        ``feedback`` switches the integral feedback, ``learning`` the iterative learning (used
        only when the reference repeats: ``period`` samples, estimated when omitted).
        """
        r = as_signal("reference", reference, min_length=2)
        plant = self.plant
        dt = plant.dt
        n = r.size
        per = period if period is not None else estimate_period(r)
        learn = learning and per is not None and n >= 2 * per
        ff = self.feedforward()
        pid = self.tuning.pid(dt) if (feedback and self.tuning is not None) else None
        d = self.delay
        corr = np.zeros(per) if learn else None
        best_corr = corr
        best_rms = np.inf
        learning_on = learn
        cycle_rms: list[float] = []
        vpu = self.volts_per_um
        span = float(np.ptp(r))
        watch = LoopWatch(r, u_range=getattr(plant, "u_range", None), feedback_on=pid is not None,
                          limit=10 * span + 10, dt=dt, describe=lambda: f"controller {self.describe()}")
        plant.reset()
        y = np.empty(n)
        u = np.empty(n)
        y_prev = 0.0
        sat = 0
        cutoff = self.ilc_cutoff_hz or (max(50.0, 15.0 / (per * dt)) if per else 50.0)
        for k in range(n):
            fb = pid.step(r[k - 1] - y_prev, sat) * vpu if (pid is not None and k > 0) else 0.0
            j = min(k + d, n - 1)
            target = r[j] + (corr[j % per] if corr is not None else 0.0)  # type: ignore[index, operator]
            uk = ff.step(target) + fb
            sat = watch.command(k, uk)
            yk = float(plant.step(uk))
            u[k] = uk
            y[k] = yk
            watch.output(k, yk, y)
            y_prev = yk
            if learn and (k + 1) % per == 0:
                c0 = k + 1 - per
                e = r[c0:k + 1] - y[c0:k + 1]
                rms = float(np.sqrt(np.mean(e**2)))
                cycle_rms.append(rms)
                if learning_on:
                    if rms < best_rms:
                        best_rms, best_corr = rms, corr.copy()  # type: ignore[union-attr]
                        # the error of cycle m shows the correction applied in it; align by phase
                        corr = _lowpass_periodic(corr + self.learning_gain * np.roll(e, -(c0 % per)), dt, cutoff)  # type: ignore[operator]
                        if rms > 0.95 * (cycle_rms[-2] if len(cycle_rms) > 1 else np.inf):
                            learning_on = False
                            corr = best_corr
                    else:  # the error stopped falling: keep the best correction
                        learning_on = False
                        corr = best_corr
        clipped = getattr(plant, "clipped", None)
        return TrackingResult(t=np.arange(n) * dt, reference=r, output=y, command=u, period=per,
                              clipped=int(clipped) if clipped is not None else None, label=label,
                              info={"feedback": feedback, "learning": learn, "cycle_rms_um": cycle_rms})


def commission(plant: Any, seed: int = 0, *, u_range: tuple[float, float] | None = None, n: int | None = None,
               excitation: Any = None, tune: bool = True, learning_gain: float = 0.5,
               progress: Callable[[str], None] | None = None) -> CommissionedController:
    """Identify ``plant`` and build its controller (module docstring).

    Parameters
    ----------
    plant : Plant
        ``dt``, ``reset()``, ``step(u) -> y`` (V in, µm out); ``u_range`` and ``excite`` are used
        when it has them.
    seed : int
        Kept for reproducible variants of the experiment; the default experiment is deterministic
        (the plant's own noise is the plant's business).
    u_range : (low, high), optional
        The amplifier's range, V; default the plant's ``u_range``, else (0, 100).
    excitation : array_like, optional
        Your own identification command instead of :func:`commissioning_excitation`.
    n : int, optional
        Fix the P-I operators / Preisach levels (default: chosen on held-out data).
    progress : callable, optional
        Called with a short description before each stage (and passed on to
        :func:`~piezohyst.identify.fit_model`); a :class:`~piezohyst.Progress` shows them.
    """
    t0 = time.perf_counter()
    dt = getattr(plant, "dt", None)
    if not isinstance(dt, (int, float)) or not dt > 0:
        raise TypeError("plant must follow the Plant protocol: a positive float 'dt', reset() and step(u)")
    rng_u = u_range if u_range is not None else tuple(getattr(plant, "u_range", (0.0, 100.0)))
    if not rng_u[0] < rng_u[1]:
        raise ValueError(f"u_range must be (low, high) with low < high, got {rng_u}")
    cmd = commissioning_excitation(dt, rng_u) if excitation is None else as_signal("excitation", excitation)  # type: ignore[arg-type]
    say = progress or (lambda s: None)
    say(f"identification run ({cmd.size * dt:.3g} s)")
    ds = open_loop(plant, cmd)
    fit = fit_model(ds.u, ds.y, dt, "auto", kinds=COMMISSION_KINDS, n=n, progress=progress)
    ctl = CommissionedController(plant=plant, fit=fit, tuning=None, identification=ds, learning_gain=learning_gain)
    if tune:
        say("tuning the integral feedback on the plant")
        level = float(np.median(ds.y))
        ctl.tuning = tune_integral_feedback(plant, ctl.feedforward(), level=level, feedback_at="command",
                                            output_scale=ctl.volts_per_um)
    ctl.time_s = time.perf_counter() - t0
    ctl.info["seed"] = seed
    return ctl
