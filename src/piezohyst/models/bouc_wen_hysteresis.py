"""The rate-independent Bouc-Wen hysteresis, eq. (8), as a static kind (beyond the paper).

    y = offset + d1 v - h,       dh = alpha d1 dv - beta |dv| h - gamma dv |h|          (8)

This is the paper's Bouc-Wen model with its dynamics, eq. (7), settled (``x = d1 u - h``), in
micrometres: the Duhem-type memory (a loop's shape set by the state ``h`` alone, minor loops
that need not close) that the Preisach family (P-I, Preisach) does not have. Two facts make it a
member of the linear family of :mod:`piezohyst.identify.linear`:

* eq. (8) is homogeneous of degree one in ``(h, alpha d1)``: with ``h1`` the solution for
  ``alpha d1 = 1``, ``h = alpha d1 h1``. For fixed ``beta`` and ``gamma`` the output
  ``offset + d1 v - alpha d1 h1(v)`` is linear in ``d1``, ``alpha d1`` and the offset, and the
  shape ``(beta, gamma)`` is searched on held-out data;
* with ``|h1| <= 1 / (beta + gamma)`` (``beta > |gamma|``), ``dh1/dv`` lies in
  ``[0, M]``, ``M = 2 beta / (beta + gamma)``, so the output's slope lies in
  ``[d1 (1 - alpha M), d1]``: invertible when ``alpha M < 1`` (:attr:`min_slope` > 0).

**The operating range.** ``M`` is the slope after a reversal from the saturated state, which an
input confined to a range ``v_range = (lo, hi)`` may never reach. Along any branch
``dh1/dv = 1 + (beta - gamma) |h1|`` at most (the largest value, just after a reversal), so with
``H`` the largest ``|h1|`` an input within the range can reach from the de-energised state,
``M_range = 1 + (beta - gamma) H <= M`` (:func:`reachable_unit_h`, :func:`max_unit_slope`). A
model with a ``v_range`` is invertible when ``alpha M_range < 1``, and its inverse keeps the input
in the range (a target beyond what the range reaches gives the range's end, as a clipping
amplifier would): a skewed loop (``gamma < 0``) whose worst case ``alpha M >= 1`` lies outside any
stroke the stage is driven over is then still a member of the family, with a stable inverse.
The identification sets ``v_range`` to the range of its data (and 0 V, the de-energised state).

The inverse is numerical, as for the Preisach model: the output is increasing in the input with
slope at least :attr:`min_slope`, so each sample's command is bracketed and bisected to 1e-12 of
the bracket, with ``h`` advanced exactly over the increment
(:func:`~piezohyst.models.bouc_wen.bw_h_update`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from .._numba import njit
from .._validation import FloatArray, as_scalar, as_signal
from .base import InverseCompensator, c_bracketed_solve, check_dt, register_kind
from .bouc_wen import bw_h_update, bw_hysteresis

#: Halvings of the inverse's bracket before the final secant step.
BISECTION_STEPS = 60


def unit_hysteresis(v: FloatArray, beta: float, gamma: float) -> FloatArray:
    """``h1``: eq. (8) with ``alpha d1 = 1`` from the de-energised state (``v = 0, h = 0``)."""
    return bw_hysteresis(np.ascontiguousarray(v, dtype=np.float64), 0.0, 1.0, float(beta), float(gamma))


#: Nodes of the grid over the operating range on which :func:`reachable_unit_h` follows the states.
REACH_NODES = 200


@njit
def _reach_sweeps(v: FloatArray, j0: int, h0: float, beta: float, gamma: float, tol: float) -> FloatArray:  # pragma: no cover - compiled
    """Per node of ``v`` (increasing), the lowest and highest ``h1`` reachable there from ``h0`` at
    node ``j0`` with the input moving between the nodes: sweeps up and down the grid, each node's
    interval grown by the flow (exact, ``bw_h_update``) of the intervals before it, until nothing
    grows by more than ``tol``. The flow over an increment is increasing in the starting ``h``, so
    an interval's ends map to the ends of its image."""
    n = v.shape[0]
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    lo[j0] = h0
    hi[j0] = h0
    for _ in range(10000):
        changed = False
        for direction in (1, -1):
            start = 0 if direction == 1 else n - 1
            a = np.inf
            b = -np.inf
            j = start
            for _k in range(n):
                if j != start and a <= b:
                    du = v[j] - v[j - direction]
                    a = bw_h_update(a, du, 1.0, beta, gamma)
                    b = bw_h_update(b, du, 1.0, beta, gamma)
                    if a < lo[j]:
                        changed = changed or a < lo[j] - tol
                        lo[j] = a
                    if b > hi[j]:
                        changed = changed or b > hi[j] + tol
                        hi[j] = b
                if lo[j] <= hi[j]:
                    a = min(a, lo[j])
                    b = max(b, hi[j])
                j += direction
        if not changed:
            break
    out = np.empty(2 * n)
    out[:n] = lo
    out[n:] = hi
    return out


@functools.lru_cache(maxsize=4096)  # a model search builds many models of the same few shapes
def reachable_unit_h(beta: float, gamma: float, v_range: tuple[float, float]) -> float:
    """The largest ``|h1|`` (eq. 8 with ``alpha d1 = 1``) an input within ``v_range`` (which holds
    0 V) can reach from the de-energised state ``v = 0, h = 0`` (module docstring).

    The states are followed on :data:`REACH_NODES` nodes over the range with reversals at the
    nodes (:func:`_reach_sweeps`); a reversal between two nodes moves ``h1`` by at most one node
    spacing times the largest slope ``M`` before the next node, which is added. Never more than
    the bound of any range, ``1 / (beta + gamma)``."""
    lo, hi = float(v_range[0]), float(v_range[1])
    if not (lo <= 0.0 <= hi and hi > lo):
        raise ValueError(f"v_range must hold 0 V (the de-energised state) and have hi > lo, got {v_range}")
    v = np.unique(np.concatenate([np.linspace(lo, hi, REACH_NODES), [0.0]]))
    j0 = int(np.searchsorted(v, 0.0))
    ends = _reach_sweeps(v, j0, 0.0, float(beta), float(gamma), 1e-9 / (beta + gamma))
    pad = float(np.max(np.diff(v))) * 2.0 * beta / (beta + gamma)
    h = float(np.max(np.abs(ends))) + pad
    return min(h, 1.0 / (beta + gamma))


def max_unit_slope(beta: float, gamma: float, v_range: tuple[float, float] | None = None) -> float:
    """The largest ``dh1/dv`` on any branch: ``M = 2 beta / (beta + gamma)``, or with the input
    confined to ``v_range``, ``1 + (beta - gamma) H`` with ``H`` from :func:`reachable_unit_h`
    (module docstring)."""
    m = 2.0 * beta / (beta + gamma)
    if v_range is None:
        return m
    rng = (float(v_range[0]), float(v_range[1]))
    return min(m, 1.0 + (beta - gamma) * reachable_unit_h(float(beta), float(gamma), rng))


@njit
def _bwh_solve(target: float, v_prev: float, h_prev: float, d1: float, ad1: float, beta: float, gamma: float,
               offset: float, extra: float, s_min: float, steps: int, v_lo: float = -np.inf,
               v_hi: float = np.inf) -> float:  # pragma: no cover - compiled
    """The v with ``offset + (d1 + extra) v - h(v) = target``, h advanced from ``h_prev``; within
    ``[v_lo, v_hi]`` (the range's end when the target lies beyond it)."""
    f0 = offset + (d1 + extra) * v_prev - h_prev - target
    if f0 == 0.0:
        return v_prev
    a = v_prev
    b = v_prev - f0 / s_min
    clamped = False
    if b > v_hi:
        b = v_hi
        clamped = True
    elif b < v_lo:
        b = v_lo
        clamped = True
    fa = f0
    fb = offset + (d1 + extra) * b - bw_h_update(h_prev, b - v_prev, ad1, beta, gamma) - target
    if clamped and fb * f0 >= 0.0:
        return b  # the target lies beyond what the range reaches
    if fa > 0.0:
        a, b = b, a
        fa, fb = fb, fa
    for _ in range(steps):
        m = 0.5 * (a + b)
        fm = offset + (d1 + extra) * m - bw_h_update(h_prev, m - v_prev, ad1, beta, gamma) - target
        if fm == 0.0:
            return m
        if fm < 0.0:
            a = m
            fa = fm
        else:
            b = m
            fb = fm
    if fb != fa:
        v = a - fa * (b - a) / (fb - fa)
        if v >= min(a, b) and v <= max(a, b):
            return v
    return 0.5 * (a + b)


@register_kind("bouc-wen-hysteresis", "bw-hysteresis", "duhem")
@dataclass(frozen=True)
class BoucWenHysteresis:
    """The rate-independent Bouc-Wen hysteresis in µm (module docstring).

    Parameters
    ----------
    d1 : float
        Piezoelectric constant, µm/V (> 0).
    alpha, beta, gamma : float
        Eq. (8)'s shape: ``0 <= alpha``, ``beta > |gamma|`` (1/V).
    offset : float
        Added to the output, µm.
    v_range : (float, float), optional
        The operating range of the input, V (holding 0 V): invertibility is judged over the states
        it reaches and the inverse keeps its input in it (module docstring). None: every state.

    Examples
    --------
    >>> import numpy as np, piezohyst as ph
    >>> m = ph.models.BoucWenHysteresis(d1=0.02, alpha=0.4, beta=0.03, gamma=0.01)
    >>> u = ph.sinusoid(1.0, 2, 0.0, 100.0, 1e-3)
    >>> y = m.simulate(u)
    >>> bool(np.abs(m.simulate(m.compensator().command(y)) - y).max() < 1e-9)
    True
    """

    kind: ClassVar[str]
    output_unit: ClassVar[str] = "um"
    dynamic: ClassVar[bool] = False

    d1: float
    alpha: float
    beta: float
    gamma: float = 0.0
    offset: float = 0.0
    v_range: tuple[float, float] | None = None
    _m: float = field(init=False, repr=False, compare=False)  # max_unit_slope over v_range

    def __post_init__(self) -> None:
        object.__setattr__(self, "d1", as_scalar("d1", self.d1, positive=True))
        object.__setattr__(self, "alpha", as_scalar("alpha", self.alpha, nonnegative=True))
        object.__setattr__(self, "beta", as_scalar("beta", self.beta, positive=True))
        object.__setattr__(self, "gamma", as_scalar("gamma", self.gamma))
        object.__setattr__(self, "offset", as_scalar("offset", self.offset))
        if not self.beta > abs(self.gamma):
            raise ValueError(f"beta must exceed |gamma| (a bounded loop), got beta={self.beta:g}, gamma={self.gamma:g}")
        if self.v_range is not None:
            lo, hi = (as_scalar("v_range", x) for x in self.v_range)
            if not lo <= 0.0 <= hi or not hi > lo:
                raise ValueError(f"v_range must hold 0 V (the de-energised state) with high > low, got {self.v_range}")
            object.__setattr__(self, "v_range", (lo, hi))
        object.__setattr__(self, "_m", max_unit_slope(self.beta, self.gamma, self.v_range))

    @property
    def min_slope(self) -> float:
        """``d1 (1 - alpha M)``: the smallest slope on any branch (within ``v_range`` when it is
        set: ``M_range``; module docstring)."""
        return self.d1 * (1.0 - self.alpha * self._m)

    @property
    def is_invertible(self) -> bool:
        """True when every branch rises (``min_slope > 0``): the inverse exists and is unique."""
        return self.min_slope > 0

    def simulate(self, u: Any, dt: float | None = None) -> FloatArray:
        """The output (µm) for the input ``u`` (V) from the de-energised state (rate independent)."""
        check_dt(dt, None, self.kind)
        v = as_signal("u", u)
        return self.offset + self.d1 * v - self.alpha * self.d1 * unit_hysteresis(v, self.beta, self.gamma)

    def predict(self, u: Any, dt: float | None = None) -> FloatArray:
        """The same as :meth:`simulate` (rate independent: ``dt`` is not needed)."""
        return self.simulate(u, dt)

    def stepper(self, dt: float | None = None) -> "BoucWenHysteresisStepper":
        """A per-sample simulator carrying the hysteresis state between calls."""
        check_dt(dt, None, self.kind)
        return BoucWenHysteresisStepper(self)

    def slope_inverse(self, kappa: float = 0.0) -> "BoucWenHysteresisInverse":
        """Solves ``model(v) + kappa v = target`` sample by sample (module docstring)."""
        return BoucWenHysteresisInverse(self, kappa)

    def compensator(self, dt: float | None = None, *, u_range: Any = None,
                    max_slew: float | None = None) -> "BoucWenHysteresisCompensator":
        """The feedforward ``u = H^-1[x_d]``, clipped to ``u_range`` and rate-limited to ``max_slew`` V/sample."""
        check_dt(dt, None, self.kind)
        return BoucWenHysteresisCompensator(self, u_range=u_range, max_slew=max_slew)

    def to_dict(self) -> dict[str, Any]:
        """The parameters as plain data, for the model file (``from_dict`` reads them back)."""
        out: dict[str, Any] = {"d1": self.d1, "alpha": self.alpha, "beta": self.beta, "gamma": self.gamma,
                               "offset": self.offset}
        if self.v_range is not None:
            out["v_range"] = list(self.v_range)
        return out

    @classmethod
    def from_dict(cls, params: dict[str, Any]) -> "BoucWenHysteresis":
        """The model from :meth:`to_dict`'s parameters (``gamma``, ``offset`` default 0, no ``v_range``)."""
        rng = params.get("v_range")
        return cls(d1=params["d1"], alpha=params["alpha"], beta=params["beta"], gamma=params.get("gamma", 0.0),
                   offset=params.get("offset", 0.0), v_range=None if rng is None else (rng[0], rng[1]))

    def __repr__(self) -> str:
        rng = "" if self.v_range is None else f", v_range=({self.v_range[0]:.4g}, {self.v_range[1]:.4g}) V"
        return (f"BoucWenHysteresis(d1={self.d1:.4g} um/V, alpha={self.alpha:.4g}, beta={self.beta:.4g}/V, "
                f"gamma={self.gamma:.4g}/V, offset={self.offset:.4g}{rng})")


class BoucWenHysteresisStepper:
    def __init__(self, model: BoucWenHysteresis):
        self.model = model
        self.reset()

    def reset(self) -> None:
        self._v = 0.0
        self._h = 0.0

    def step(self, v: float) -> float:
        x = float(v)
        if not math.isfinite(x):
            raise ValueError(f"u_k must be finite, got {v!r}")
        m = self.model
        self._h = float(bw_h_update(self._h, x - self._v, m.alpha * m.d1, m.beta, m.gamma))
        self._v = x
        return m.offset + m.d1 * x - self._h


class BoucWenHysteresisInverse:
    """Solves ``model(v) + kappa v = target`` for v, sample by sample."""

    def __init__(self, model: BoucWenHysteresis, kappa: float = 0.0):
        s = model.min_slope + float(kappa)
        if not s > 0:
            raise ValueError(f"the Bouc-Wen hysteresis is not invertible: its smallest slope is {s:.4g}")
        self.model = model
        self.kappa = float(kappa)
        self._s = s
        self.reset()

    def reset(self) -> None:
        self._v = 0.0
        self._h = 0.0

    def step(self, target: float) -> float:
        m = self.model
        ad1 = m.alpha * m.d1
        lo, hi = m.v_range if m.v_range is not None else (-math.inf, math.inf)
        v = float(_bwh_solve(float(target), self._v, self._h, m.d1, ad1, m.beta, m.gamma, m.offset, self.kappa,
                             self._s, BISECTION_STEPS, lo, hi))
        self._h = float(bw_h_update(self._h, v - self._v, ad1, m.beta, m.gamma))
        self._v = v
        return v

    def inverse_parameters(self) -> dict[str, Any]:
        """What :func:`_bwh_solve` works with (the inverse is numerical, not a model)."""
        m = self.model
        return {"role": "numerical inverse: solve offset + (d1 + kappa) v - h(v) = x_d per sample by bisection",
                "d1": m.d1, "alpha_d1": m.alpha * m.d1, "beta": m.beta, "gamma": m.gamma, "offset": m.offset,
                "kappa": self.kappa, "min_slope": self._s, "bisection_steps": BISECTION_STEPS,
                "v_range": None if m.v_range is None else list(m.v_range)}

    def to_c(self, c: Any, prefix: str) -> str:
        """:func:`_bwh_solve` and the state update as C99, operation for operation."""
        from .bouc_wen_inverse import bw_h_update_c

        m = self.model
        upd = bw_h_update_c(c)
        vv = c.state_scalar(f"{prefix}_v", 0.0)
        hh = c.state_scalar(f"{prefix}_h", 0.0)
        d1x, ad1 = c.num(m.d1 + self.kappa), c.num(m.alpha * m.d1)
        beta, gamma, off, smin = c.num(m.beta), c.num(m.gamma), c.num(m.offset), c.num(self._s)
        fn = c.name(f"{prefix}_solve")
        c_bracketed_solve(
            c, fn, f"Bouc-Wen hysteresis, numerical inverse: bisection ({BISECTION_STEPS} halvings), one secant step",
            prologue=f"    const double v_prev = {vv};\n    const double h_prev = {hh};",
            f0=f"{off} + {d1x} * v_prev - h_prev - target",
            f_at=lambda x: f"{off} + {d1x} * {x} - {upd}(h_prev, {x} - v_prev, {ad1}, {beta}, {gamma}) - target",
            s_min=smin, steps=BISECTION_STEPS,
            v_range=None if m.v_range is None else (c.num(m.v_range[0]), c.num(m.v_range[1])),
            epilogue=f"    {hh} = {upd}(h_prev, v - v_prev, {ad1}, {beta}, {gamma});\n    {vv} = v;")
        return fn


class BoucWenHysteresisCompensator(InverseCompensator):
    """The numerical inverse (module docstring): desired µm in, volts out."""

    def __init__(self, model: BoucWenHysteresis, *, u_range: Any = None, max_slew: float | None = None):
        super().__init__(model, BoucWenHysteresisInverse(model), u_range=u_range, max_slew=max_slew)
