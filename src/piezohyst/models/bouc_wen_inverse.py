"""The Bouc-Wen model's compensator: the hysteresis-estimate feedforward of eq. (10).

    u_c = (x_d + h_hat) / d1                                                  (10)

``h_hat`` comes from the identified model's eq. (8) *as the command is produced*. Since h_hat
depends on the command it is computing, each sample solves ``d1 u - H(h_hat_prev, u - u_prev) =
x_d`` for u exactly (Newton's method on the closed-form increment of
:func:`~piezohyst.models.bouc_wen.bw_h_update`), instead of lagging h_hat by a sample. It cancels
the quasi-static model; the dynamics of eq. (7) are left to feedback, as in the paper's eq. (11).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._numba import njit
from .._validation import FloatArray
from .base import Compensator
from .bouc_wen import BoucWen, bw_h_update


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


class BoucWenFeedforward(Compensator):
    """Bouc-Wen hysteresis-estimate feedforward, eq. (10): ``u_c = (x_d + h_hat) / d1``.

    Parameters
    ----------
    bw_model : BoucWen
        The identified model (SI units; its ``offset`` is removed from x_d first).
    u_range, max_slew : optional
        Output limits (see :class:`~piezohyst.models.base.Compensator`).
    """

    def __init__(self, bw_model: BoucWen, *, u_range: Any = None, max_slew: float | None = None):
        if not isinstance(bw_model, BoucWen):
            raise TypeError(f"bw_model must be a BoucWen, got {type(bw_model).__name__}")
        super().__init__(u_range=u_range, max_slew=max_slew)
        self.model = bw_model
        self._consts = (bw_model.d1, bw_model.alpha * bw_model.d1, bw_model.beta, bw_model.gamma)
        self._st = np.array([0.0, bw_model.h0])

    def _reset(self) -> None:
        self._st[:] = (0.0, self.model.h0)

    @property
    def h_hat(self) -> float:
        """The current hysteresis estimate, metres."""
        return float(self._st[1])

    def _step(self, x_d: float) -> float:
        return float(bw_ff_step(*self._consts, self._st, x_d * 1e-6 - self.model.offset))

    def _command(self, x_d: FloatArray) -> FloatArray:
        st = np.array([0.0, self.model.h0])
        return bw_ff_run(*self._consts, st, x_d * 1e-6 - self.model.offset)

    def __repr__(self) -> str:
        return f"BoucWenFeedforward({self.model!r})"
