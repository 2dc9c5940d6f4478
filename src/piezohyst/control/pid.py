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


def _limit(name: str, value: Any, none: float) -> float:
    """An output limit: a number, +-inf allowed, NaN not; None: no limit (``none``)."""
    if value is None:
        return none
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or math.isnan(value):
        raise TypeError(f"{name} must be a number (or None for no limit), got {value!r}")
    return float(value)


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

    # The settings are properties, checked whenever they are set, in the constructor or after it,
    # and the derivative filter's coefficients follow them (kd changed after construction kept its
    # old derivative while settings() showed the new one; limits given as strings were compared as
    # text: found by fuzzing). step() reads the checked values, as fast as plain attributes.

    def __init__(self, kp: float = 0.0, ki: float = 0.0, kd: float = 0.0, dt: float = 1e-4, *,
                 tf: float | None = None, u_min: float | None = -math.inf, u_max: float | None = math.inf):
        self._kp = as_scalar("kp", kp)
        self._ki = as_scalar("ki", ki)
        self._kd = as_scalar("kd", kd)
        self._dt = as_scalar("dt", dt, positive=True)
        self._tf = as_scalar("tf", tf, positive=True) if tf is not None else 2.0 * self._dt
        self._u_min = _limit("u_min", u_min, -math.inf)
        self._u_max = _limit("u_max", u_max, math.inf)
        if not (self._u_min < self._u_max):
            raise ValueError(f"u_min must be less than u_max, got {self._u_min:g} and {self._u_max:g}")
        self._filter()
        self.reset()

    def _filter(self) -> None:
        """The derivative filter's pole and gain from the present ``kd``, ``tf`` and ``dt``."""
        self._a = self._tf / (self._tf + self._dt)
        self._b = self._kd / (self._tf + self._dt)

    @property
    def kp(self) -> float:
        """Proportional gain."""
        return self._kp

    @kp.setter
    def kp(self, v: float) -> None:
        self._kp = as_scalar("kp", v)

    @property
    def ki(self) -> float:
        """Integral gain, 1/s."""
        return self._ki

    @ki.setter
    def ki(self, v: float) -> None:
        self._ki = as_scalar("ki", v)

    @property
    def kd(self) -> float:
        """Derivative gain, s."""
        return self._kd

    @kd.setter
    def kd(self, v: float) -> None:
        self._kd = as_scalar("kd", v)
        self._filter()

    @property
    def dt(self) -> float:
        """Sample period, s."""
        return self._dt

    @dt.setter
    def dt(self, v: float) -> None:
        self._dt = as_scalar("dt", v, positive=True)
        self._filter()

    @property
    def tf(self) -> float:
        """Derivative filter time constant, s."""
        return self._tf

    @tf.setter
    def tf(self, v: float) -> None:
        self._tf = as_scalar("tf", v, positive=True)
        self._filter()

    @property
    def u_min(self) -> float:
        """Lower output limit (-inf: none)."""
        return self._u_min

    @u_min.setter
    def u_min(self, v: float | None) -> None:
        v = _limit("u_min", v, -math.inf)
        if not v < self._u_max:
            raise ValueError(f"u_min must be less than u_max, got {v:g} and {self._u_max:g}")
        self._u_min = v

    @property
    def u_max(self) -> float:
        """Upper output limit (inf: none)."""
        return self._u_max

    @u_max.setter
    def u_max(self, v: float | None) -> None:
        v = _limit("u_max", v, math.inf)
        if not self._u_min < v:
            raise ValueError(f"u_min must be less than u_max, got {self._u_min:g} and {v:g}")
        self._u_max = v

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
        inc = self._ki * self._dt * e
        u_try = self._kp * e + self.integral + inc + self._d
        # conditional integration: no integrating further into a limit (own or the actuator's)
        pushes_up = inc > 0
        blocked = (pushes_up and (u_try > self._u_max or saturated > 0)) or (
            not pushes_up and (u_try < self._u_min or saturated < 0))
        if not blocked:
            self.integral += inc
        u = self._kp * e + self.integral + self._d
        return min(max(u, self._u_min), self._u_max)

    def settings(self) -> dict[str, float]:
        """The gains and limits as plain data."""
        return {"kp": self.kp, "ki": self.ki, "kd": self.kd, "dt": self.dt, "tf": self.tf,
                "u_min": self.u_min, "u_max": self.u_max}

    def __repr__(self) -> str:
        return f"PID(kp={self.kp:g}, ki={self.ki:g}, kd={self.kd:g}, dt={self.dt:g})"
