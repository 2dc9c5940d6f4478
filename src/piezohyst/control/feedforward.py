"""The paper's two feedforward controllers (Section IV).

* :class:`InversePIFeedforward` - the command is the inverse P-I model, eqs. (12)-(15), applied
  to the desired displacement: ``u = P^-1[x_d]``.
* :class:`BoucWenFeedforward` - the hysteresis-estimate controller of eq. (10),
  ``u_c = (x_d + h_hat) / d1``, with ``h_hat`` from the identified model's eq. (8) *as the
  command is produced*. Since h_hat depends on the command it is computing, each sample solves
  ``d1 u - H(h_hat_prev, u - u_prev) = x_d`` for u exactly (Newton's method on the closed-form
  increment of :func:`~piezohyst.models.bouc_wen.bw_h_update`), instead of lagging h_hat by a
  sample. It cancels the quasi-static model; the dynamics of eq. (7) are left to feedback, as in
  the paper's eq. (11).

Both take the desired displacement in µm and give volts. Both stream (``step(x_d_k)``) and run on
whole signals (``command(x_d)``) through the same compiled kernel.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .._numba import njit
from .._validation import FloatArray, as_signal
from ..models.bouc_wen import BoucWen, bw_h_update
from ..models.pi import PIStepper, PrandtlIshlinskii


class InversePIFeedforward:
    """Inverse P-I feedforward: ``u = P^-1[x_d]`` (eqs. 12-15).

    Parameters
    ----------
    pi_model : PrandtlIshlinskii
        The identified forward model, input V, output µm; it must be invertible.

    Examples
    --------
    >>> import piezohyst as ph
    >>> pi = ph.PrandtlIshlinskii(ph.equal_thresholds(3, 100.0), [0.02, 0.002, 0.001])
    >>> ff = ph.InversePIFeedforward(pi)
    >>> x_d = ph.sinusoid(1.0, 1, 0.1, 1.9, 1e-3)
    >>> bool(abs(pi.simulate(ff.command(x_d)) - x_d).max() < 1e-9)
    True
    """

    def __init__(self, pi_model: PrandtlIshlinskii):
        if not isinstance(pi_model, PrandtlIshlinskii):
            raise TypeError(f"pi_model must be a PrandtlIshlinskii, got {type(pi_model).__name__}")
        self.model = pi_model
        self.inverse = pi_model.inverse()  # raises ValueError naming the failing partial sum
        self._stepper = PIStepper(self.inverse)

    def reset(self) -> None:
        """Back to the de-energised state."""
        self._stepper.reset()

    def step(self, x_d: float) -> float:
        """The command (V) for the next desired displacement sample (µm)."""
        return self._stepper.step(x_d)

    def command(self, x_d: Any) -> FloatArray:
        """Commands (V) for a whole desired trajectory (µm), from the de-energised state."""
        return self.inverse.simulate(as_signal("x_d", x_d))

    def __repr__(self) -> str:
        return f"InversePIFeedforward({self.model!r})"


@njit
def bw_ff_step(d1: float, ad1: float, beta: float, gamma: float, st: FloatArray, target: float) -> float:  # pragma: no cover
    """Solve ``d1 u - H(h_prev, u - u_prev) = target`` (metres) for u; update ``st = [u_prev, h]``."""
    u_prev = st[0]
    h_prev = st[1]
    u = (target + h_prev) / d1  # eq. (10) with the previous estimate: the starting guess
    for _ in range(30):
        h = bw_h_update(h_prev, u - u_prev, ad1, beta, gamma)
        g = d1 * u - h - target
        s = 1.0 if u >= u_prev else -1.0
        dh = ad1 - beta * s * h - gamma * abs(h)  # dh/du at the end of the increment, eq. (8)
        slope = d1 - dh
        if slope <= 1e-3 * d1:
            slope = d1  # fall back to the fixed-point step
        step = g / slope
        u -= step
        if abs(step) <= 1e-12 * (1.0 + abs(u)):
            break
    st[0] = u
    st[1] = bw_h_update(h_prev, u - u_prev, ad1, beta, gamma)
    return u


@njit
def bw_ff_run(d1: float, ad1: float, beta: float, gamma: float, st: FloatArray, targets: FloatArray) -> FloatArray:  # pragma: no cover
    out = np.empty(targets.shape[0])
    for k in range(targets.shape[0]):
        out[k] = bw_ff_step(d1, ad1, beta, gamma, st, targets[k])
    return out


class BoucWenFeedforward:
    """Bouc-Wen hysteresis-estimate feedforward, eq. (10): ``u_c = (x_d + h_hat) / d1``.

    Parameters
    ----------
    bw_model : BoucWen
        The identified model (SI units; its ``offset`` is removed from x_d first).
    """

    def __init__(self, bw_model: BoucWen):
        if not isinstance(bw_model, BoucWen):
            raise TypeError(f"bw_model must be a BoucWen, got {type(bw_model).__name__}")
        self.model = bw_model
        self._consts = (bw_model.d1, bw_model.alpha * bw_model.d1, bw_model.beta, bw_model.gamma)
        self._st = np.array([0.0, bw_model.h0])

    def reset(self) -> None:
        self._st[:] = (0.0, self.model.h0)

    @property
    def h_hat(self) -> float:
        """The current hysteresis estimate, metres."""
        return float(self._st[1])

    def step(self, x_d: float) -> float:
        """The command (V) for the next desired displacement sample (µm)."""
        x = float(x_d)
        if not math.isfinite(x):
            raise ValueError(f"x_d must be finite, got {x_d!r}")
        return float(bw_ff_step(*self._consts, self._st, x * 1e-6 - self.model.offset))

    def command(self, x_d: Any) -> FloatArray:
        """Commands (V) for a whole desired trajectory (µm), from the de-energised state."""
        x = as_signal("x_d", x_d)
        st = np.array([0.0, self.model.h0])
        return bw_ff_run(*self._consts, st, x * 1e-6 - self.model.offset)

    def __repr__(self) -> str:
        return f"BoucWenFeedforward({self.model!r})"
