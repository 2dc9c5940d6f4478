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

    def inverse_parameters(self) -> dict[str, Any]:
        """The constants of eq. (10) as solved here (SI units: metres, volts)."""
        d1, ad1, beta, gamma = self._consts
        return {"role": "eq. (10): solve d1 u - H(h_prev, u - u_prev) = x_d 1e-6 - offset for u (Newton)",
                "d1": d1, "alpha_d1": ad1, "beta": beta, "gamma": gamma, "offset": self.model.offset,
                "h0": self.model.h0}

    def to_c(self, c: Any, prefix: str) -> str:
        """:func:`bw_ff_step` and :func:`~piezohyst.models.bouc_wen.bw_h_update` as C99, operation
        for operation (``exp``, ``log`` and ``expm1`` from libm)."""
        d1, ad1, beta, gamma = (c.num(float(v)) for v in self._consts)
        st_u = c.state_scalar(f"{prefix}_u", 0.0)
        st_h = c.state_scalar(f"{prefix}_h", float(self.model.h0))
        upd = bw_h_update_c(c)
        fn = c.name(f"{prefix}_step")
        c.function(f"""/* Bouc-Wen hysteresis-estimate feedforward, eq. (10), solved exactly per sample */
static double {fn}(double desired_um)
{{
    const double target = desired_um * 1e-6 - {c.num(float(self.model.offset))};
    const double u_prev = {st_u};
    const double h_prev = {st_h};
    double u = (target + h_prev) / {d1};
    int it;
    for (it = 0; it < 30; ++it) {{
        const double h = {upd}(h_prev, u - u_prev, {ad1}, {beta}, {gamma});
        const double g = {d1} * u - h - target;
        const double s = (u >= u_prev) ? 1.0 : -1.0;
        const double dh = {ad1} - {beta} * s * h - {gamma} * fabs(h);
        double slope = {d1} - dh;
        double step;
        if (slope <= 1e-3 * {d1}) slope = {d1};
        step = g / slope;
        u -= step;
        if (fabs(step) <= 1e-12 * (1.0 + fabs(u))) break;
    }}
    {st_u} = u;
    {st_h} = {upd}(h_prev, u - u_prev, {ad1}, {beta}, {gamma});
    return u;
}}""")
        return fn

    def __repr__(self) -> str:
        return f"BoucWenFeedforward({self.model!r})"


def bw_h_update_c(c: Any) -> str:
    """Register :func:`~piezohyst.models.bouc_wen.bw_h_update` as a C99 helper with the exporter
    ``c`` (operation for operation; ``exp``, ``log`` and ``expm1`` from libm); return its name."""
    phi1 = c.helper("ph_phi1", """/* (1 - exp(-x)) / x, accurate near 0 */
static double ph_phi1(double x)
{
    if (fabs(x) < 1e-9) return 1.0 - 0.5 * x;
    return -expm1(-x) / x;
}""")
    return str(c.helper("ph_bw_h_update", f"""/* exact solution of eq. (8) over one input increment du */
static double ph_bw_h_update(double h, double du, double ad1, double beta, double gamma)
{{
    double s, lam, a;
    int pass;
    if (du == 0.0) return h;
    s = (du > 0.0) ? 1.0 : -1.0;
    lam = fabs(du);
    a = s * ad1;
    for (pass = 0; pass < 2; ++pass) {{
        double sig, cc;
        if (h > 0.0) {{
            sig = 1.0;
        }} else if (h < 0.0) {{
            sig = -1.0;
        }} else {{
            sig = (a >= 0.0) ? 1.0 : -1.0;
        }}
        cc = beta + gamma * s * sig;
        if (h != 0.0 && a * sig < 0.0) {{
            double lam0 = -1.0;
            if (cc == 0.0) {{
                lam0 = -h / a;
            }} else {{
                const double ratio = a / (a - cc * h);
                if (ratio > 0.0) lam0 = -log(ratio) / cc;
            }}
            if (0.0 < lam0 && lam0 < lam) {{
                h = 0.0;
                lam -= lam0;
                continue;
            }}
        }}
        return h * exp(-cc * lam) + a * lam * {phi1}(cc * lam);
    }}
    return h;
}}"""))
