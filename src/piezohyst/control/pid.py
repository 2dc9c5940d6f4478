"""Discrete PID with a filtered derivative, anti-windup and output limits.

Where it enters the loop of the paper's Fig. 5 (see :func:`piezohyst.track`): by default its
output is **added to the desired displacement before the feedforward** (``feedback_at=
"reference"``), so the feedforward's inverse turns the PID's correction, in µm, into volts. The
inverse then linearises the loop the PID sees (a plant of gain ~1 µm/µm), its gains are
dimensionless and carry over between stages of different sensitivity, and the hysteresis is
compensated for the correction too. With ``feedback_at="command"`` (or with no feedforward) the
output is in volts and is added to the command.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .._validation import as_scalar


class PID:
    """``u = kp e + ki integral(e) + kd de/dt``, discretised with step ``dt``.

    * integral: backward Euler, ``I += ki dt e``;
    * derivative: on the error, through a first-order filter of time constant ``tf`` (default
      ``2 dt``), ``D = tf/(tf+dt) D + kd/(tf+dt) (e - e_prev)``;
    * output limits ``(u_min, u_max)``: the output is clamped, and while it is clamped the
      integral does not integrate further in the same direction (conditional integration
      anti-windup).

    Parameters
    ----------
    kp, ki, kd : float
        Gains (ki in 1/s, kd in s, times the output unit per error unit).
    dt : float
        Sample period, s; must equal the plant's.
    tf : float, optional
        Derivative filter time constant, s.
    u_min, u_max : float, optional
        Output limits.
    """

    #: Settings checked whenever they are set, in the constructor or after it (kd changed after
    #: construction kept its old derivative coefficients, while settings() showed the new one;
    #: limits given as strings were compared as text: found by fuzzing).
    _CHECKED = {"kp": {}, "ki": {}, "kd": {}, "dt": {"positive": True}, "tf": {"positive": True}}
    kp: float
    ki: float
    kd: float
    dt: float
    tf: float
    u_min: float
    u_max: float

    def __init__(self, kp: float = 0.0, ki: float = 0.0, kd: float = 0.0, dt: float = 1e-4, *,
                 tf: float | None = None, u_min: float | None = -math.inf, u_max: float | None = math.inf):
        self.kp = kp
        self.ki = ki
        self.kd = kd
        self.dt = dt
        self.tf = tf if tf is not None else 2.0 * self.dt
        self.u_min = u_min  # type: ignore[assignment]  # (None: no limit; __setattr__ makes it a float)
        self.u_max = u_max  # type: ignore[assignment]
        if not (self.u_min < self.u_max):
            raise ValueError(f"u_min must be less than u_max, got {self.u_min:g} and {self.u_max:g}")
        self.reset()

    def __setattr__(self, name: str, value: Any) -> None:
        if name in PID._CHECKED:
            value = as_scalar(name, value, **PID._CHECKED[name])  # type: ignore[arg-type]
        elif name in ("u_min", "u_max"):  # None: no limit; +-inf allowed, NaN not
            if value is None:
                value = -math.inf if name == "u_min" else math.inf
            elif isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
                    or math.isnan(value):
                raise TypeError(f"{name} must be a number (or None for no limit), got {value!r}")
            else:
                value = float(value)
        object.__setattr__(self, name, value)

    @property
    def _a(self) -> float:
        """The derivative filter's pole, from the present ``tf`` and ``dt``."""
        return self.tf / (self.tf + self.dt)

    @property
    def _b(self) -> float:
        """The derivative filter's gain, from the present ``kd``, ``tf`` and ``dt``."""
        return self.kd / (self.tf + self.dt)

    def reset(self) -> None:
        """Clear the integral, the derivative filter and the previous error."""
        self.integral = 0.0
        self._d = 0.0
        self._e_prev = 0.0
        self._first = True

    def step(self, error: float, saturated: int = 0) -> float:
        """Advance one sample with ``e = reference - measurement``; return the output.

        ``saturated`` is +1 (or -1) when the actuator clipped the last command at its upper (or
        lower) limit: the integral then does not grow further in that direction.
        """
        e = float(error)
        if not math.isfinite(e):
            raise ValueError(f"the error must be finite, got {error!r}")
        if self._first:
            self._e_prev = e  # no derivative kick on the first sample
            self._first = False
        self._d = self._a * self._d + self._b * (e - self._e_prev)
        self._e_prev = e
        inc = self.ki * self.dt * e
        u_try = self.kp * e + self.integral + inc + self._d
        # conditional integration: no integrating further into a limit (own or the actuator's)
        pushes_up = inc > 0
        blocked = (pushes_up and (u_try > self.u_max or saturated > 0)) or (
            not pushes_up and (u_try < self.u_min or saturated < 0))
        if not blocked:
            self.integral += inc
        u = self.kp * e + self.integral + self._d
        return min(max(u, self.u_min), self.u_max)

    def settings(self) -> dict[str, float]:
        """The gains and limits as plain data."""
        return {"kp": self.kp, "ki": self.ki, "kd": self.kd, "dt": self.dt, "tf": self.tf,
                "u_min": self.u_min, "u_max": self.u_max}

    def __repr__(self) -> str:
        return f"PID(kp={self.kp:g}, ki={self.ki:g}, kd={self.kd:g}, dt={self.dt:g})"
