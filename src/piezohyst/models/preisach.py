"""The discrete Preisach model on a triangular grid, with its numerical inverse (beyond the paper).

    y(k) = offset + slope v(k) + sum_{0 <= j <= i < n} mu_ij gamma_ij[v](k)

The input range ``[lo, hi]`` is cut into ``n`` steps of ``delta = (hi - lo) / n``. Hysteron
``(i, j)`` switches up at ``alpha_i = lo + (i + 1) delta`` and down at ``beta_j = lo + j delta``
(``alpha_i - beta_j >= delta``): the classical triangle ``alpha >= beta`` of the Preisach plane,
one weight ``mu_ij >= 0`` per cell, ``n (n + 1) / 2`` weights. The plane does not end at the
range: cells whose ``beta`` lies below it switch up at ``alpha_i`` and never down again (the
initial loading curve of an actuator that starts de-energised at the bottom of its range, which
a P-I model has too), and cells whose ``alpha`` lies above it only ever switch down. Each of the
two strips acts as one hysteron per level, ``n`` up-only and ``n`` down-only weights, so a model
has ``n (n + 1) / 2 + 2 n`` weights. Each relay switches over one grid
step rather than at a point (a Krasnosel'skii-Pokrovskii kernel): its state ``z in [0, 1]`` is
pushed up by the ramp ``clip((v - alpha_i + delta) / delta, 0, 1)`` and down by
``clip((v - beta_j) / delta, 0, 1)``::

    z <- min(max(z, ramp_up(v)), ramp_down(v))

so the output is a continuous, piecewise-linear function of the input with the Preisach model's
nonlocal memory (wiping out, congruent minor loops), which a P-I model only approximates. The
diagonal cells (``i == j``) have no hysteresis: they are the model's reversible part inside the
grid, ``slope`` the reversible part everywhere.

With every ``mu_ij >= 0`` and ``slope > 0`` the model is strictly increasing in the input on
every branch, and its smallest slope anywhere is ``slope`` (:attr:`Preisach.min_slope`). The
output is linear in ``mu``, ``slope`` and ``offset``: constrained least squares identifies it
(:func:`piezohyst.identify.fit_preisach`).

**The inverse is numerical** (there is no closed form for a Preisach model): for each desired
output the compensator solves ``f(v) = target`` for the increasing, piecewise-linear ``f`` that
the current memory state defines. Because ``f`` rises at least at ``slope`` per volt, the
solution lies within ``|target - f(v_prev)| / slope`` of the previous input. Within that bracket
the solver takes Newton steps, each one pass over the hysterons that gives ``f`` and its slopes
just above and below the point (:func:`preisach_value_slopes`). On a linear piece a Newton step
lands on the root, so a sample whose step crosses no kink of ``f`` costs two passes (the previous
input's and the root's), and the input moves little from sample to sample. A step that would
leave the bracket, or one after a step that did not halve the residual, goes to the bracket's
middle instead, so the solve ends (at most :data:`SOLVE_STEPS` passes, at the best point found).
It stops when the residual is at the rounding of its terms (``64 eps`` of their sum). The solver
it replaced bisected the bracket 60 times: 60 passes for every sample. Measured on a random
model driven by a sinusoid with a small fast dither (reversals every 18 samples): 2.2 passes
per sample, 3.0 / 4.3 / 8.7 µs per compensator step with 8 / 16 / 30 levels (the bisection:
12.7 / 31 / 106 µs), the output's error below 1e-13 µm. ``tests/test_model_kinds.py`` checks
``model(compensator(x_d)) == x_d`` to 1e-9.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from .._numba import njit
from .._validation import FloatArray, as_scalar, as_signal, frozen
from .base import InverseCompensator, check_dt, register_kind
from .play import inside_monotone_stretch

#: Most passes of the inverse's bracketed Newton solve (module docstring); it ends at the best
#: point found if the residual has not reached rounding by then.
SOLVE_STEPS = 60
#: A residual within this fraction of the sum of its terms' sizes is at their rounding: the
#: inverse's solve stops there (64 eps).
RESIDUAL_ROUNDING = 64.0 * 2.220446049250313e-16


def grid_size(n: int) -> int:
    """Number of hysterons of an ``n``-level grid: ``n (n + 1) / 2 + 2 n`` (module docstring)."""
    return n * (n + 1) // 2 + 2 * n


def levels_of(size: int) -> int:
    """The ``n`` with ``grid_size(n) == size``, or ValueError."""
    n = int(round((math.sqrt(8 * size + 25) - 5) / 2))
    if n < 1 or grid_size(n) != size:
        raise ValueError(f"weights must have n (n + 1) / 2 + 2 n entries for an n-level grid; {size} is not such a number")
    return n


#: Stands for a threshold beyond the input's reach (finite, so the kernels stay in floating point).
FAR = 1e30


def grid_thresholds(lo: float, hi: float, n: int) -> tuple[FloatArray, FloatArray, float]:
    """``alpha``, ``beta`` per hysteron and ``delta``: the triangle (row-major over ``i``, then
    ``j <= i``), then ``n`` up-only hysterons (``beta`` below the range, one per ``alpha_i``) and
    ``n`` down-only ones (``alpha`` above it, one per ``beta_j``): see :class:`Preisach`."""
    delta = (hi - lo) / n
    ii, jj = np.tril_indices(n)
    levels = np.arange(n)
    alpha = np.concatenate([lo + (ii + 1) * delta, lo + (levels + 1) * delta, np.full(n, FAR)])
    beta = np.concatenate([lo + jj * delta, np.full(n, -FAR), lo + levels * delta])
    return alpha, beta, delta


@njit
def _ramp(x: float) -> float:  # pragma: no cover - compiled
    return 0.0 if x <= 0.0 else (1.0 if x >= 1.0 else x)


@njit
def preisach_step(v: float, alpha: FloatArray, beta: FloatArray, inv_delta: float, z: FloatArray) -> None:  # pragma: no cover
    """Advance every hysteron by one input sample (module docstring), in place."""
    for h in range(z.shape[0]):
        up = _ramp((v - alpha[h]) * inv_delta + 1.0)
        down = _ramp((v - beta[h]) * inv_delta)
        zh = z[h]
        if zh < up:
            zh = up
        if zh > down:
            zh = down
        z[h] = zh


@njit
def preisach_value(v: float, alpha: FloatArray, beta: FloatArray, inv_delta: float, z: FloatArray,
                   mu: FloatArray) -> float:  # pragma: no cover
    """``sum mu z`` after a step to ``v`` from state ``z``, without changing ``z``."""
    acc = 0.0
    for h in range(z.shape[0]):
        up = _ramp((v - alpha[h]) * inv_delta + 1.0)
        down = _ramp((v - beta[h]) * inv_delta)
        zh = z[h]
        if zh < up:
            zh = up
        if zh > down:
            zh = down
        acc += mu[h] * zh
    return acc


@njit
def preisach_outputs_into(v: FloatArray, alpha: FloatArray, beta: FloatArray, inv_delta: float, z: FloatArray,
                          out: FloatArray, stride: int = 1) -> None:  # pragma: no cover
    """:func:`preisach_outputs` at the rows ``0, stride, 2 stride, ...`` written into ``out`` (one
    row per kept sample, one column per hysteron; may be a view into a wider matrix).

    Only the kept samples, the input's turning points and the last sample are stepped (the
    samples inside a monotone stretch change no hysteron's state:
    :func:`~piezohyst.models.play.inside_monotone_stretch`), bit for bit as stepping every
    sample; the work falls from samples x hysterons to (kept rows + turning points) x hysterons,
    the stride times less on a smooth record."""
    last = 0.0
    for k in range(v.shape[0]):
        if k % stride != 0 and inside_monotone_stretch(v, k, last):
            continue  # the step to the stretch's end covers it
        preisach_step(v[k], alpha, beta, inv_delta, z)
        last = v[k]
        if k % stride == 0:
            j = k // stride
            for h in range(z.shape[0]):
                out[j, h] = z[h]


@njit
def preisach_outputs(v: FloatArray, alpha: FloatArray, beta: FloatArray, inv_delta: float,
                     z: FloatArray) -> FloatArray:  # pragma: no cover
    """Every hysteron's state for every sample, (N, n_hysterons): the regressors of a fit."""
    out = np.empty((v.shape[0], z.shape[0]))
    preisach_outputs_into(v, alpha, beta, inv_delta, z, out, 1)
    return out


@njit
def preisach_simulate(v: FloatArray, alpha: FloatArray, beta: FloatArray, inv_delta: float, z: FloatArray,
                      mu: FloatArray, slope: float, offset: float) -> FloatArray:  # pragma: no cover
    y = np.empty(v.shape[0])
    for k in range(v.shape[0]):
        preisach_step(v[k], alpha, beta, inv_delta, z)
        acc = 0.0
        for h in range(z.shape[0]):
            acc += mu[h] * z[h]
        y[k] = offset + slope * v[k] + acc
    return y


@njit
def preisach_value_slopes(v: float, alpha: FloatArray, beta: FloatArray, inv_delta: float, z: FloatArray,
                          mu: FloatArray) -> tuple[float, float, float]:  # pragma: no cover
    """``sum mu z`` after a step to ``v`` from state ``z`` (as :func:`preisach_value`), and its
    slopes in ``v`` just above and just below ``v``: the weights of the hysterons that a move
    that way drags along their ramps, times ``inv_delta``. One pass over the hysterons."""
    acc = 0.0
    d_up = 0.0
    d_down = 0.0
    for h in range(z.shape[0]):
        ua = (v - alpha[h]) * inv_delta + 1.0
        da = (v - beta[h]) * inv_delta
        up = _ramp(ua)
        down = _ramp(da)
        zh = z[h]
        if zh <= up:  # held at (or pushed to) its rising ramp: moves with a rise of v on the ramp
            if ua >= 0.0 and ua < 1.0:
                d_up += mu[h]
            if zh < up and ua > 0.0 and ua <= 1.0:
                d_down += mu[h]
            if zh < up:
                zh = up
        if zh >= down:  # at (or pushed to) its falling ramp: moves with a fall of v on the ramp
            if da > 0.0 and da <= 1.0:
                d_down += mu[h]
            if zh > down and da >= 0.0 and da < 1.0:
                d_up += mu[h]
            if zh > down:
                zh = down
        acc += mu[h] * zh
    return acc, d_up * inv_delta, d_down * inv_delta


@njit
def preisach_solve(target: float, v_prev: float, alpha: FloatArray, beta: FloatArray, inv_delta: float,
                   z: FloatArray, mu: FloatArray, slope: float, offset: float, steps: int) -> float:  # pragma: no cover
    """The input v whose step from state ``z`` gives ``target``; advances ``z`` to it.

    ``f(v) = offset + slope v + preisach_value(v)`` is increasing with slope >= ``slope`` > 0,
    so the root lies between ``v_prev`` and ``v_prev + (target - f(v_prev)) / slope``: Newton
    steps inside that bracket, each one pass (:func:`preisach_value_slopes`); a step that leaves
    the bracket, or follows one that did not halve the residual, goes to the bracket's middle
    instead (module docstring). Ends when the residual is at the rounding of its terms, when a
    step no longer moves, or after ``steps`` passes (at the best point found).
    """
    acc, d_up, d_down = preisach_value_slopes(v_prev, alpha, beta, inv_delta, z, mu)
    fx = offset + slope * v_prev + acc - target
    v = v_prev
    if fx != 0.0:
        end = v_prev - fx / slope
        lo = min(v_prev, end)  # f(lo) <= target <= f(hi)
        hi = max(v_prev, end)
        x = v_prev
        dx = slope + (d_up if fx < 0.0 else d_down)
        halve = False
        best, fbest = x, abs(fx)
        for _ in range(steps):
            xn = 0.5 * (lo + hi) if halve else x - fx / dx
            if not (xn > lo and xn < hi):
                xn = 0.5 * (lo + hi)
            if xn == x:
                break
            acc, d_up, d_down = preisach_value_slopes(xn, alpha, beta, inv_delta, z, mu)
            fn = offset + slope * xn + acc - target
            if abs(fn) < fbest:
                best, fbest = xn, abs(fn)
            if abs(fn) <= RESIDUAL_ROUNDING * (abs(target) + abs(offset) + abs(slope * xn) + abs(acc)):
                break
            if fn < 0.0:
                lo = xn
            else:
                hi = xn
            halve = abs(fn) > 0.5 * abs(fx)
            x = xn
            fx = fn
            dx = slope + (d_up if fn < 0.0 else d_down)
        v = best
    preisach_step(v, alpha, beta, inv_delta, z)
    return v


def demagnetised_state(alpha: FloatArray, beta: FloatArray, delta: float, at: float = 0.0) -> FloatArray:
    """The state of a de-energised actuator at input ``at``: hysterons centred below ``at`` are
    up, those above are down (the Preisach plane's staircase is the line ``alpha + beta = 2 at``);
    the P-I model's zero initial state is the same state. Up-only hysterons (those that stand for
    the cells below the range still down at ``at``) start down, down-only ones up."""
    z = np.where(0.5 * (alpha + beta) < at, 1.0, 0.0)
    z = np.where(beta <= -FAR, 0.0, np.where(alpha >= FAR, 1.0, z))
    up = np.clip((at - alpha) / delta + 1.0, 0.0, 1.0)
    down = np.clip((at - beta) / delta, 0.0, 1.0)
    return np.minimum(np.maximum(z, up), down)


@register_kind("preisach")
@dataclass(frozen=True, eq=False)
class Preisach:
    """Discrete Preisach model on a triangular ``n``-level grid over ``[lo, hi]`` (module docstring).

    Parameters
    ----------
    lo, hi : float
        The input range the grid covers, V.
    weights : array_like, shape (n (n + 1) / 2 + 2 n,)
        ``mu_ij >= 0``, row-major over ``i`` then ``j <= i`` (``numpy.tril_indices`` order),
        then the ``n`` up-only and the ``n`` down-only weights (module docstring).
    slope : float
        The reversible linear part, > 0 for an invertible model (output units per volt).
    offset : float
        Added to the output.

    Examples
    --------
    >>> import numpy as np, piezohyst as ph
    >>> m = ph.Preisach(lo=0.0, hi=10.0, weights=np.full(18, 0.1), slope=0.05)
    >>> u = ph.sinusoid(1.0, 2, 0.0, 10.0, 1e-3)
    >>> bool(np.allclose(m.simulate(m.compensator().command(m.simulate(u))), m.simulate(u), atol=1e-9))
    True
    """

    kind: ClassVar[str]
    output_unit: ClassVar[str] = "um"
    dynamic: ClassVar[bool] = False

    lo: float
    hi: float
    weights: FloatArray
    slope: float = 0.0
    offset: float = 0.0

    def __post_init__(self) -> None:
        lo = as_scalar("lo", self.lo)
        hi = as_scalar("hi", self.hi)
        if not hi > lo:
            raise ValueError(f"hi must be greater than lo, got lo={lo:g}, hi={hi:g}")
        mu = as_signal("weights", self.weights)
        levels_of(mu.size)
        if np.any(mu < 0):
            raise ValueError(f"weights must all be >= 0 (a Preisach density), got min {mu.min():.4g}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        object.__setattr__(self, "weights", frozen(mu))
        object.__setattr__(self, "slope", as_scalar("slope", self.slope, nonnegative=True))
        object.__setattr__(self, "offset", as_scalar("offset", self.offset))

    @property
    def n(self) -> int:
        """Grid levels."""
        return levels_of(self.weights.size)

    def _grid(self) -> tuple[FloatArray, FloatArray, float]:
        return grid_thresholds(self.lo, self.hi, self.n)

    def initial_state(self) -> FloatArray:
        """The hysterons' states at rest (the demagnetised state at input 0)."""
        a, b, d = self._grid()
        return demagnetised_state(a, b, d, 0.0)

    @property
    def min_slope(self) -> float:
        """The smallest slope on any branch anywhere: ``slope`` (hysterons add, never subtract)."""
        return self.slope

    @property
    def is_invertible(self) -> bool:
        """True when ``slope > 0`` (then every branch rises at least at ``slope``)."""
        return self.slope > 0

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Preisach):
            return NotImplemented
        return (self.lo == other.lo and self.hi == other.hi and np.array_equal(self.weights, other.weights)
                and self.slope == other.slope and self.offset == other.offset)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return (f"Preisach(n={self.n}, range={self.lo:g}..{self.hi:g}, sum(mu)={self.weights.sum():.4g}, "
                f"slope={self.slope:.4g}, offset={self.offset:g})")

    # -- simulation ------------------------------------------------------------------------------
    def simulate(self, u: Any, dt: float | None = None) -> FloatArray:
        """The output for the input ``u`` from the de-energised state (rate independent)."""
        check_dt(dt, None, self.kind)
        v = as_signal("u", u)
        a, b, d = self._grid()
        return preisach_simulate(v, a, b, 1.0 / d, self.initial_state(), self.weights, self.slope, self.offset)

    def predict(self, u: Any, dt: float | None = None) -> FloatArray:
        """The output in µm (the protocol's common unit; the same as :meth:`simulate`)."""
        return self.simulate(u, dt)

    def hysteron_outputs(self, u: Any) -> FloatArray:
        """Every hysteron's state per sample, (N, n (n + 1) / 2): the regressors of a fit."""
        v = as_signal("u", u)
        a, b, d = self._grid()
        return preisach_outputs(v, a, b, 1.0 / d, self.initial_state())

    def stepper(self, dt: float | None = None) -> "PreisachStepper":
        """A streaming evaluator: ``s.step(u_k)`` gives ``y(k)``, on the same kernel."""
        check_dt(dt, None, self.kind)
        return PreisachStepper(self)

    def slope_inverse(self, kappa: float = 0.0) -> "PreisachInverse":
        """A stepper that solves ``model(v) + kappa v = target`` for v (numerically, see module)."""
        return PreisachInverse(self, kappa)

    def compensator(self, dt: float | None = None, *, u_range: Any = None,
                    max_slew: float | None = None) -> "PreisachCompensator":
        """The numerical inverse (module docstring): desired µm in, volts out."""
        check_dt(dt, None, self.kind)
        return PreisachCompensator(self, u_range=u_range, max_slew=max_slew)

    # -- files -----------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The parameters as plain data: range (V), levels, weights, slope, offset."""
        return {"lo": self.lo, "hi": self.hi, "levels": self.n, "weights": self.weights.tolist(),
                "slope": self.slope, "offset": self.offset}

    @classmethod
    def from_dict(cls, params: dict[str, Any]) -> "Preisach":
        """Rebuild the model from :meth:`to_dict`'s data. A file of the first Preisach kind (its
        triangle's ``n (n + 1) / 2`` weights, before the edge strips joined it under the same
        schema version) loads with empty strips: the same model (its predictions equal to the
        last digit; it was refused: found by a helper loading files of every earlier commit)."""
        weights, lv = params["weights"], params.get("levels")  # (that kind wrote its levels too)
        if isinstance(weights, list) and isinstance(lv, int) and not isinstance(lv, bool) and lv >= 1 \
                and len(weights) == lv * (lv + 1) // 2:
            weights = [*weights, *([0.0] * (2 * lv))]
        m = cls(lo=params["lo"], hi=params["hi"], weights=weights,
                slope=params.get("slope", 0.0), offset=params.get("offset", 0.0))
        if "levels" in params and params["levels"] != m.n:
            raise ValueError(f"'levels' is {params['levels']!r} but the weights make a {m.n}-level grid")
        return m

    def _repr_html_(self) -> str:
        """An HTML summary for Jupyter: kind, units, invertibility, parameters."""
        from .._html import model_html

        return model_html(self)


class PreisachStepper:
    """Streaming simulation, on the kernel :meth:`Preisach.simulate` uses."""

    def __init__(self, model: Preisach):
        self.model = model
        self._a, self._b, d = model._grid()
        self._inv_d = 1.0 / d
        self.reset()

    def reset(self) -> None:
        self._z = self.model.initial_state()

    def step(self, v: float) -> float:
        x = float(v)
        if not math.isfinite(x):
            raise ValueError(f"u_k must be finite, got {v!r}")
        m = self.model
        preisach_step(x, self._a, self._b, self._inv_d, self._z)
        return float(m.offset + m.slope * x + float(np.dot(m.weights, self._z)))


class PreisachInverse:
    """Solves ``model(v) + kappa v = target`` sample by sample (see :func:`preisach_solve`)."""

    def __init__(self, model: Preisach, kappa: float = 0.0):
        s = model.slope + float(kappa)
        if not s > 0:
            raise ValueError(f"the Preisach model is not invertible: its smallest slope "
                             f"(slope + kappa = {s:.4g}) is not > 0")
        self.model = model
        self.kappa = float(kappa)
        self._s = s
        self._a, self._b, d = model._grid()
        self._inv_d = 1.0 / d
        self.reset()

    def reset(self) -> None:
        self._z = self.model.initial_state()
        self._v = 0.0

    def step(self, target: float) -> float:
        m = self.model
        self._v = float(preisach_solve(float(target), self._v, self._a, self._b, self._inv_d, self._z,
                                       m.weights, self._s, m.offset, SOLVE_STEPS))
        return self._v

    def inverse_parameters(self) -> dict[str, Any]:
        """What :func:`preisach_solve` works with (the inverse is numerical, not a model)."""
        m = self.model
        return {"role": "numerical inverse: solve offset + slope v + sum mu z(v) = x_d per sample by bracketed "
                        "Newton steps (exact on a linear piece of the branch)",
                "alpha": np.array(self._a), "beta": np.array(self._b), "inv_delta": self._inv_d,
                "mu": np.array(m.weights), "slope": self._s, "offset": m.offset,
                "initial_state": m.initial_state(), "solve_steps": SOLVE_STEPS}

    def to_c(self, c: Any, prefix: str) -> str:
        """:func:`preisach_solve` as C99, operation for operation (see :meth:`Compensator.to_c`)."""
        m = self.model
        nh = self._a.size
        al = c.array(f"{prefix}_alpha", self._a)
        be = c.array(f"{prefix}_beta", self._b)
        mu = c.array(f"{prefix}_mu", m.weights)
        z = c.state_array(f"{prefix}_z", m.initial_state())
        vv = c.state_scalar(f"{prefix}_v", 0.0)
        inv_d, slope, off = c.num(self._inv_d), c.num(self._s), c.num(m.offset)
        ramp = c.helper("ph_ramp", """static double ph_ramp(double x)
{
    return (x <= 0.0) ? 0.0 : ((x >= 1.0) ? 1.0 : x);
}""")
        value, advance, fn = c.name(f"{prefix}_value"), c.name(f"{prefix}_advance"), c.name(f"{prefix}_solve")
        body = f"""        const double up = {ramp}((v - {al}[h]) * {inv_d} + 1.0);
        const double down = {ramp}((v - {be}[h]) * {inv_d});
        double zh = {z}[h];
        if (zh < up) zh = up;
        if (zh > down) zh = down;"""
        c.function(f"""/* Preisach model on a triangular grid: {nh} hysterons */
/* sum mu z after a step to v, and its slopes just above and just below v (one pass) */
static double {value}(double v, double *d_up, double *d_down)
{{
    double acc = 0.0;
    double su = 0.0;
    double sd = 0.0;
    int h;
    for (h = 0; h < {nh}; ++h) {{
        const double ua = (v - {al}[h]) * {inv_d} + 1.0;
        const double da = (v - {be}[h]) * {inv_d};
        const double up = {ramp}(ua);
        const double down = {ramp}(da);
        double zh = {z}[h];
        if (zh <= up) {{
            if (ua >= 0.0 && ua < 1.0) su += {mu}[h];
            if (zh < up && ua > 0.0 && ua <= 1.0) sd += {mu}[h];
            if (zh < up) zh = up;
        }}
        if (zh >= down) {{
            if (da > 0.0 && da <= 1.0) sd += {mu}[h];
            if (zh > down && da >= 0.0 && da < 1.0) su += {mu}[h];
            if (zh > down) zh = down;
        }}
        acc += {mu}[h] * zh;
    }}
    *d_up = su * {inv_d};
    *d_down = sd * {inv_d};
    return acc;
}}

static void {advance}(double v)
{{
    int h;
    for (h = 0; h < {nh}; ++h) {{
{body}
        {z}[h] = zh;
    }}
}}

/* the numerical inverse: bracketed Newton steps (at most {SOLVE_STEPS} passes), exact on a linear piece */
static double {fn}(double target)
{{
    const double v_prev = {vv};
    double d_up, d_down;
    double acc = {value}(v_prev, &d_up, &d_down);
    double fx = {off} + {slope} * v_prev + acc - target;
    double v = v_prev;
    if (fx != 0.0) {{
        const double end = v_prev - fx / {slope};
        double lo = (v_prev < end) ? v_prev : end;
        double hi = (v_prev > end) ? v_prev : end;
        double x = v_prev;
        double dx = {slope} + ((fx < 0.0) ? d_up : d_down);
        int halve = 0;
        double best = x;
        double fbest = fabs(fx);
        int it;
        for (it = 0; it < {SOLVE_STEPS}; ++it) {{
            double xn = halve ? 0.5 * (lo + hi) : x - fx / dx;
            double fn;
            if (!(xn > lo && xn < hi)) xn = 0.5 * (lo + hi);
            if (xn == x) break;
            acc = {value}(xn, &d_up, &d_down);
            fn = {off} + {slope} * xn + acc - target;
            if (fabs(fn) < fbest) {{
                best = xn;
                fbest = fabs(fn);
            }}
            if (fabs(fn) <= {c.num(RESIDUAL_ROUNDING)} * (fabs(target) + fabs({off}) + fabs({slope} * xn) + fabs(acc))) break;
            if (fn < 0.0) lo = xn;
            else hi = xn;
            halve = fabs(fn) > 0.5 * fabs(fx);
            x = xn;
            fx = fn;
            dx = {slope} + ((fn < 0.0) ? d_up : d_down);
        }}
        v = best;
    }}
    {advance}(v);
    {vv} = v;
    return v;
}}""")
        return fn


class PreisachCompensator(InverseCompensator):
    """The Preisach model's feedforward: its numerical inverse (module docstring)."""

    def __init__(self, model: Preisach, *, u_range: Any = None, max_slew: float | None = None):
        super().__init__(model, PreisachInverse(model), u_range=u_range, max_slew=max_slew)
