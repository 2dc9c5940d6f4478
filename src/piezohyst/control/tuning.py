"""PID tuning on the plant itself (the method ``piezohyst reproduce`` uses and documents).

The stage's mechanics are a lightly damped resonance (the paper's m, b, k: 1.7 kHz, damping
ratio 0.0017) that a 1 Hz identification record cannot see. Proportional and derivative action
reach that resonance with little attenuation and would destabilise the loop, so the feedback
around the feedforward is integral-dominant, and its gain is found by experiment, in the spirit
of Ziegler and Nichols' closed-loop method:

1. hold a constant desired displacement (mid-range) through the feedforward, with integral
   feedback of gain ``ki``, for ``hold_s`` seconds, and record the error's RMS over the second
   half;
2. raise ``ki`` geometrically from ``ki_start`` until that RMS exceeds ``growth`` times its
   value at the smallest gain (the loop's resonance is being amplified: the ultimate gain
   ``ki_u``) or the loop goes unstable;
3. use ``ki = ki_u / gain_margin`` (default 3, about 10 dB of gain margin, as Ziegler-Nichols).

Only ``dt``, ``reset()`` and ``step()`` of the plant are used, so the same routine tunes a real
stage; the excursions stay small (the reference is constant; the run stops at the first sign of
amplification).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .pid import PID
from .tracking import UnstableLoopError, track


@dataclass(frozen=True)
class TuningResult:
    """The tuned gains and what the experiment saw."""

    kp: float
    ki: float
    kd: float
    ki_ultimate: float
    trials: tuple[tuple[float, float], ...]  # (ki, error RMS in µm; inf if unstable)
    method: str

    def pid(self, dt: float, **kw: Any) -> PID:
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
