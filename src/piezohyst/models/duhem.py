"""The generalised (semilinear) Duhem model of Coleman and Hodgdon (beyond the paper).

    dy = |dv| (F(v) - lam y) + G(v) dv,          y_out = offset + y

A Duhem model's memory is the output itself: after a reversal the output relaxes, at the rate
``lam`` per volt of travel, towards a curve set by ``F`` and ``G``, whatever the earlier
reversals were. Its minor loops neither close nor wipe out the Preisach way, so P-I and Preisach
models, whose memory is the sequence of dominant extrema, only approximate it: on a stage of this
structure a Preisach fit that predicts its identification record within 0.6 % of span misses a
loop over part of the range by 3 to 9 % (measured on the Coleman-Hodgdon element of the test zoo,
:mod:`tests.plants.zoo`). The Bouc-Wen hysteresis (:mod:`.bouc_wen_hysteresis`) is the member
with constant ``F`` and ``G`` (``gamma = 0``); Coleman and Hodgdon's model of ferromagnetic and
piezoelectric hysteresis is the member with ``F = lam f`` (``f`` the anhysteretic curve) and
``G = g``.

``F`` and ``G`` are piecewise linear over the ``knots`` (held constant beyond them), so along a
monotone move of the input, in the travel ``x = |v - v0|`` and with ``s`` its direction, the model
is ``dy/dx = -lam y + phi(x)`` with the forcing ``phi = F(v) + s G(v)`` linear between the knots
the move crosses. Each such segment, of length ``l``, is solved in closed form::

    y <- a y + l (wa phi_a + wb phi_b),   a = exp(-z),   z = lam l,
    wa = (1 - (1 + z) exp(-z)) / z^2,     wb = (z - 1 + exp(-z)) / z^2

(``phi_a``, ``phi_b`` the forcing at the segment's start and end; both weights tend to 1/2 as
``z -> 0`` and are summed from their series there, where the closed forms cancel). The step is
exact, the same in one move as in several, and continuous in where the move ends (it replaced
sub-steps that froze ``F`` and ``G`` at their midpoints, whose number jumped as the move's length
crossed multiples of theirs: a jump in the output that the inverse's bisection took for a
crossing). The output is *linear in the values of F and G at the knots* once ``lam`` is fixed: for a
given ``lam`` the best ``F`` and ``G`` are one linear least-squares problem
(:func:`duhem_columns`, :mod:`piezohyst.identify.linear`), and ``lam`` is chosen on held-out data
(:func:`piezohyst.identify.fit_model`).

**Slopes and the inverse.** Along an ascending branch ``dy/dv = G + F - lam y``, along a descending
one ``dy/dv = G - F + lam y``: both positive for every state an input within ``v_range`` reaches
from rest makes the model invertible. :attr:`GeneralizedDuhem.min_slope` is the smallest of them
over those states: the reachable band of ``y`` is followed on :data:`REACH_NODES` nodes of the
range by sweeps up and down (the flow over an increment is increasing in the starting ``y``, so a
band's ends map to the ends of its image), each node's band holding its anhysteretic value
``F / lam`` too (where ever smaller oscillations about the node lead), widened by one node spacing
times the largest slope.
The inverse is numerical, as for the Preisach model: each sample's command is bracketed by the
smallest slope and bisected to 1e-12 of the bracket, with the state advanced exactly as
:meth:`~GeneralizedDuhem.simulate` does; it keeps the input in ``v_range`` (a target beyond what
the range reaches gives the range's end, as a clipping amplifier would).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from .._numba import njit
from .._validation import FloatArray, as_scalar, as_signal, frozen
from .base import InverseCompensator, c_bracketed_solve, check_dt, register_kind

#: Halvings of the inverse's bracket before the final secant step.
BISECTION_STEPS = 60
#: Nodes over the operating range on which :func:`reachable_band` follows the states.
REACH_NODES = 2000


@njit
def _segment(x: float, knots: FloatArray) -> tuple[int, int, float]:  # pragma: no cover - compiled
    """``(lo, hi, w)``: ``x`` lies a fraction ``w`` of the way from knot ``lo`` to knot ``hi``
    (``lo == hi``, ``w = 0`` beyond the ends, where F and G are held constant)."""
    k = knots.shape[0]
    if x <= knots[0]:
        return 0, 0, 0.0
    if x >= knots[k - 1]:
        return k - 1, k - 1, 0.0
    lo = 0
    hi = k - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if knots[mid] <= x:
            lo = mid
        else:
            hi = mid
    return lo, hi, (x - knots[lo]) / (knots[hi] - knots[lo])


@njit
def _interp(x: float, knots: FloatArray, vals: FloatArray) -> float:  # pragma: no cover - compiled
    """The piecewise-linear function through ``(knots, vals)``, constant beyond the ends."""
    lo, hi, w = _segment(x, knots)
    if lo == hi:
        return vals[lo]
    return vals[lo] + w * (vals[hi] - vals[lo])


#: Below this ``lam`` times a segment's length, :func:`_weights` sums series (the closed forms
#: cancel): their terms' coefficients, ``(k+1) / (k+2)!`` and ``1 / (k+2)!`` for ``(-z)^k``, as
#: many as are exact to rounding there.
SERIES_BELOW = 0.1
_WA = tuple((k + 1.0) / math.factorial(k + 2) for k in range(10))
_WB = tuple(1.0 / math.factorial(k + 2) for k in range(10))


@njit
def _weights(z: float) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """``(a, wa, wb)`` of a segment with ``z = lam l``: ``a = exp(-z)``,
    ``wa = (1 - (1 + z) exp(-z)) / z^2`` and ``wb = (z - 1 + exp(-z)) / z^2`` (module docstring):
    by Horner from their series below :data:`SERIES_BELOW`, else from
    ``e1 = -expm1(-z) / z = wa + wb`` and ``wb = (1 - e1) / z``."""
    a = math.exp(-z)
    if z < SERIES_BELOW:
        wa = 0.0
        wb = 0.0
        for k in range(len(_WA) - 1, -1, -1):
            wa = _WA[k] - z * wa
            wb = _WB[k] - z * wb
        return a, wa, wb
    e1 = -math.expm1(-z) / z
    wb = (1.0 - e1) / z
    return a, e1 - wb, wb


@njit
def _first_above(x: float, knots: FloatArray) -> int:  # pragma: no cover - compiled
    """The index of the first knot above ``x`` (the number of knots at or below it)."""
    lo = 0
    hi = knots.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if knots[mid] <= x:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit
def _forcing(x: float, i: int, s: float, knots: FloatArray, f: FloatArray,
             g: FloatArray) -> float:  # pragma: no cover - compiled
    """``F(x) + s G(x)``, ``i`` the number of knots at or below ``x`` (constant beyond the knots,
    as :func:`_interp`)."""
    k_n = knots.shape[0]
    if i == 0:
        return f[0] + s * g[0]
    if i == k_n:
        return f[k_n - 1] + s * g[k_n - 1]
    w = (x - knots[i - 1]) / (knots[i] - knots[i - 1])
    return (f[i - 1] + w * (f[i] - f[i - 1])) + s * (g[i - 1] + w * (g[i] - g[i - 1]))


@njit
def duhem_advance(v0: float, y0: float, v1: float, knots: FloatArray, f: FloatArray, g: FloatArray,
                  lam: float) -> float:  # pragma: no cover - compiled
    """``y`` after the input moves from ``v0`` to ``v1`` from the state ``y0``: exact, segment by
    segment between the knots it crosses (module docstring)."""
    if v1 == v0:
        return y0
    s = 1.0 if v1 > v0 else -1.0
    i0 = _first_above(v0, knots)
    i1 = _first_above(v1, knots)
    y = y0
    va = v0
    pa = _forcing(v0, i0, s, knots, f, g)
    if v1 > v0:
        for j in range(i0, i1):  # the knots in (v0, v1]; v1 itself ends the last segment below
            if knots[j] == v1:
                break
            pb = f[j] + g[j]
            ln = knots[j] - va
            a, wa, wb = _weights(lam * ln)
            y = a * y + ln * (wa * pa + wb * pb)
            va = knots[j]
            pa = pb
        ln = v1 - va
    else:
        for j in range(i0 - 1, i1 - 1, -1):  # the knots in (v1, v0]; v0 itself starts no segment
            if knots[j] == v0:
                continue
            pb = f[j] - g[j]
            ln = va - knots[j]
            a, wa, wb = _weights(lam * ln)
            y = a * y + ln * (wa * pa + wb * pb)
            va = knots[j]
            pa = pb
        ln = va - v1
    a, wa, wb = _weights(lam * ln)
    return a * y + ln * (wa * pa + wb * _forcing(v1, i1, s, knots, f, g))


@njit
def duhem_simulate(u: FloatArray, knots: FloatArray, f: FloatArray, g: FloatArray,
                   lam: float) -> FloatArray:  # pragma: no cover - compiled
    """``y`` (without the offset) for the input ``u`` from rest (``v = 0``, ``y = 0``)."""
    out = np.empty(u.shape[0])
    v = 0.0
    y = 0.0
    for k in range(u.shape[0]):
        y = duhem_advance(v, y, u[k], knots, f, g, lam)
        v = u[k]
        out[k] = y
    return out


@njit
def _add_hats(state: FloatArray, x: float, knots: FloatArray, cg: float,
              cf: float) -> None:  # pragma: no cover - compiled
    """Adds ``cg`` times the hat functions at ``x`` to the ``G`` columns of ``state`` and ``cf``
    times them to its ``F`` columns (two neighbours, or the end one beyond the knots)."""
    k_n = knots.shape[0]
    lo, hi, w = _segment(x, knots)
    if lo == hi:
        state[lo] += cg
        state[k_n + lo] += cf
    else:
        state[lo] += cg * (1.0 - w)
        state[hi] += cg * w
        state[k_n + lo] += cf * (1.0 - w)
        state[k_n + hi] += cf * w


@njit
def _columns_segment(state: FloatArray, va: float, vb: float, ln: float, s: float, knots: FloatArray,
                     lam: float) -> None:  # pragma: no cover - compiled
    """One segment of :func:`duhem_advance` (from ``va`` to ``vb``, ``ln`` long, direction ``s``)
    on the columns of :func:`duhem_columns_into`."""
    a, wa, wb = _weights(lam * ln)
    for j in range(state.shape[0]):
        state[j] *= a
    _add_hats(state, va, knots, ln * wa * s, ln * wa)
    _add_hats(state, vb, knots, ln * wb * s, ln * wb)


@njit
def duhem_columns_into(u: FloatArray, knots: FloatArray, lam: float, stride: int,
                       out: FloatArray) -> None:  # pragma: no cover - compiled
    """The model's output for each knot's hat function as ``G`` (columns ``0..K-1``) and as ``F``
    (columns ``K..2K-1``), from rest, at the samples ``0, stride, ...``: the output of any ``F``,
    ``G`` is these columns times their knot values (the recursion is linear in them)."""
    k_n = knots.shape[0]
    state = np.zeros(2 * k_n)
    v = 0.0
    for k in range(u.shape[0]):
        v1 = u[k]
        if v1 != v:  # the segments of duhem_advance
            s = 1.0 if v1 > v else -1.0
            i0 = _first_above(v, knots)
            i1 = _first_above(v1, knots)
            va = v
            if v1 > v:
                for j in range(i0, i1):
                    if knots[j] == v1:
                        break
                    _columns_segment(state, va, knots[j], knots[j] - va, s, knots, lam)
                    va = knots[j]
            else:
                for j in range(i0 - 1, i1 - 1, -1):
                    if knots[j] == v:
                        continue
                    _columns_segment(state, va, knots[j], va - knots[j], s, knots, lam)
                    va = knots[j]
            _columns_segment(state, va, v1, abs(v1 - va), s, knots, lam)
        v = v1
        if k % stride == 0:
            row = k // stride
            for j in range(2 * k_n):
                out[row, j] = state[j]


def duhem_columns(u: Any, knots: Any, lam: float, stride: int = 1, *, out: FloatArray | None = None) -> FloatArray:
    """The regressors of :func:`duhem_columns_into`, shape ``(ceil(N / stride), 2 K)``."""
    v = np.ascontiguousarray(u, dtype=np.float64)
    kn = np.ascontiguousarray(knots, dtype=np.float64)
    rows = -(-v.size // stride)
    dest = np.empty((rows, 2 * kn.size)) if out is None else out
    duhem_columns_into(v, kn, float(lam), int(stride), dest)
    return dest


@njit
def _band_sweeps(nodes: FloatArray, j0: int, knots: FloatArray, f: FloatArray, g: FloatArray, lam: float,
                 tol: float, max_sweeps: int) -> FloatArray:  # pragma: no cover - compiled
    """Per node, the lowest and highest ``y`` reachable there from ``y = 0`` at node ``j0``, the
    input moving between nodes: sweeps up and down until no end moves by more than ``tol`` in a
    sweep. Every
    node starts with its anhysteretic value ``F / lam`` as well, the limit of ever smaller
    oscillations about it (followed one node pair per sweep, it took thousands of sweeps).

    Returns the lows, the highs and a status: 0 converged; 1 stopped because a branch over the
    band found so far is flat or falls (the band only grows, so the model is not invertible; a
    model whose branches fall lets oscillations ratchet its state outwards, sweep after sweep);
    2 not converged within ``max_sweeps``."""
    n = nodes.shape[0]
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    for j in range(n):
        an = _interp(nodes[j], knots, f) / lam
        lo[j] = an
        hi[j] = an
    lo[j0] = min(lo[j0], 0.0)
    hi[j0] = max(hi[j0], 0.0)
    up = np.empty(n)
    down = np.empty(n)
    for j in range(n):
        fj = _interp(nodes[j], knots, f)
        gj = _interp(nodes[j], knots, g)
        up[j] = gj + fj
        down[j] = gj - fj
    status = 2
    for _ in range(max_sweeps):
        changed = False
        for direction in (1, -1):
            start = 0 if direction == 1 else n - 1
            a = np.inf
            b = -np.inf
            j = start
            for _k in range(n):
                if j != start and a <= b:
                    a = duhem_advance(nodes[j - direction], a, nodes[j], knots, f, g, lam)
                    b = duhem_advance(nodes[j - direction], b, nodes[j], knots, f, g, lam)
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
            status = 0
            break
        falling = False
        for j in range(n):
            if up[j] - lam * hi[j] <= 0.0 or down[j] + lam * lo[j] <= 0.0:
                falling = True
        if falling:
            status = 1
            break
    out = np.empty(2 * n + 1)
    out[:n] = lo
    out[n:2 * n] = hi
    out[2 * n] = status
    return out


#: Sweeps :func:`reachable_band` makes at most (a model with rising branches needs a few).
MAX_SWEEPS = 1000
#: How far beyond the knots (in knot spans) ``v_range`` may reach: the band is judged on
#: :data:`REACH_NODES` nodes over the whole range, ever coarser as it widens (under the sub-steps
#: :func:`duhem_advance` once took, the sweeps' work grew with the range: a damaged file's 9.2e18 V
#: took hours).
MAX_RANGE_SPANS = 100


def reachable_band(knots: FloatArray, f: FloatArray, g: FloatArray, lam: float,
                   v_range: tuple[float, float]) -> tuple[FloatArray, FloatArray, FloatArray, int]:
    """Nodes over ``v_range`` and the lowest and highest ``y`` an input within it reaches there
    from rest, widened by one node spacing times the largest slope (module docstring), and the
    status of :func:`_band_sweeps` (0: the band is complete)."""
    lo, hi = v_range
    nodes = np.unique(np.concatenate([np.linspace(lo, hi, REACH_NODES), [0.0]]))
    j0 = int(np.searchsorted(nodes, 0.0))
    # Sweeps stop when no end moves by a thousandth of the widening below: what is left then is the
    # creep of oscillations between two neighbouring nodes towards their own limit, which lies
    # within ~G h / 2 of the nodes' anhysteretic values (h the node spacing) and moves by a factor
    # exp(-2 lam h) per sweep (thousands of sweeps); the widening covers it.
    spacing = float(np.max(np.diff(nodes)))
    tol = 1e-3 * spacing * max(float(np.abs(f).max()) + float(np.abs(g).max()), 1e-300)
    out = _band_sweeps(nodes, j0, knots, f, g, lam, tol, MAX_SWEEPS)
    n = nodes.size
    ends, status = out[:2 * n], int(out[2 * n])
    ylo, yhi = ends[:n], ends[n:]
    worst = float(np.abs(f).max()) + float(np.abs(g).max()) + lam * float(np.max(np.abs(ends)))
    pad = spacing * worst
    return nodes, ylo - pad, yhi + pad, status


def reaches_beyond_knots(lo: float, hi: float, knot_lo: float, knot_hi: float) -> bool:
    """Whether an operating range ``lo .. hi`` V reaches more than :data:`MAX_RANGE_SPANS` times the
    knots' span beyond them (a model's ``v_range``, which holds 0 V: its state runs from rest)."""
    span = knot_hi - knot_lo
    return lo < knot_lo - MAX_RANGE_SPANS * span or hi > knot_hi + MAX_RANGE_SPANS * span


@register_kind("generalized-duhem", "coleman-hodgdon", "semilinear-duhem")
@dataclass(frozen=True, eq=False)
class GeneralizedDuhem:
    """The generalised Duhem (Coleman-Hodgdon) hysteresis in µm (module docstring).

    Parameters
    ----------
    knots : array_like
        Input values ``F`` and ``G`` are given at, V, strictly increasing (at least two).
    f, g : array_like
        ``F`` and ``G`` at the knots, µm/V (piecewise linear between, constant beyond).
    lam : float
        The relaxation rate after a reversal, 1/V (> 0).
    offset : float
        Added to the output, µm.
    v_range : (float, float), optional
        The operating range of the input, V (holding 0 V, the rest state): invertibility is
        judged over the states it reaches and the inverse keeps its input in it. Default: the
        knots' span and 0 V.

    Examples
    --------
    >>> import numpy as np, piezohyst as ph
    >>> knots = np.linspace(0.0, 100.0, 5)
    >>> m = ph.GeneralizedDuhem(knots, f=0.04 * np.tanh(knots / 80.0), g=np.full(5, 0.2), lam=0.04)
    >>> u = ph.sinusoid(1.0, 2, 0.0, 100.0, 1e-3)
    >>> y = m.simulate(u)
    >>> bool(m.is_invertible and np.abs(m.simulate(m.compensator().command(y)) - y).max() < 1e-9)
    True
    """

    kind: ClassVar[str]
    output_unit: ClassVar[str] = "um"
    dynamic: ClassVar[bool] = False

    knots: FloatArray
    f: FloatArray
    g: FloatArray
    lam: float
    offset: float = 0.0
    v_range: tuple[float, float] | None = None
    _min_slope: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        knots = as_signal("knots", self.knots, min_length=2)
        if not np.all(np.diff(knots) > 0):
            raise ValueError("knots must be strictly increasing")
        f = as_signal("f", self.f)
        g = as_signal("g", self.g)
        if f.size != knots.size or g.size != knots.size:
            raise ValueError(f"f and g need one value per knot ({knots.size}), got {f.size} and {g.size}")
        object.__setattr__(self, "knots", frozen(knots))
        object.__setattr__(self, "f", frozen(f))
        object.__setattr__(self, "g", frozen(g))
        object.__setattr__(self, "lam", as_scalar("lam", self.lam, positive=True))
        object.__setattr__(self, "offset", as_scalar("offset", self.offset))
        if self.v_range is None:
            rng = (min(float(knots[0]), 0.0), max(float(knots[-1]), 0.0))
        else:
            lo, hi = (as_scalar("v_range", x) for x in self.v_range)
            if not lo <= 0.0 <= hi or not hi > lo:
                raise ValueError(f"v_range must hold 0 V (the rest state) with high > low, got {self.v_range}")
            if reaches_beyond_knots(lo, hi, float(knots[0]), float(knots[-1])):
                raise ValueError(
                    f"v_range {lo:g}..{hi:g} V reaches more than {MAX_RANGE_SPANS} times the knots' span beyond "
                    f"them ({float(knots[0]):g}..{float(knots[-1]):g} V): beyond the knots F and G are constant and "
                    "the model says nothing new, while its invertibility is judged on nodes spread over the whole "
                    "range, ever coarser as it widens; give the range the input really covers")
            rng = (lo, hi)
        object.__setattr__(self, "v_range", rng)
        # parameters near the float range's end (a damaged file) overflow here: then no bound
        with np.errstate(all="ignore"):
            nodes, ylo, yhi, status = reachable_band(self.knots, self.f, self.g, self.lam, rng)
            mid = 0.5 * (nodes[1:] + nodes[:-1])
            big_f = np.interp(np.concatenate([nodes, mid]), self.knots, self.f)
            big_g = np.interp(np.concatenate([nodes, mid]), self.knots, self.g)
            # between two nodes the band is within the union of theirs
            lo_all = np.concatenate([ylo, np.minimum(ylo[1:], ylo[:-1])])
            hi_all = np.concatenate([yhi, np.maximum(yhi[1:], yhi[:-1])])
            up = big_g + big_f - self.lam * hi_all
            down = big_g - big_f + self.lam * lo_all
            slope = float(min(up.min(), down.min()))
        if status == 2 or not math.isfinite(slope):  # the band may still grow, or overflowed: no bound
            slope = -math.inf
        object.__setattr__(self, "_min_slope", slope)

    @property
    def min_slope(self) -> float:
        """The smallest branch slope over the states an input within ``v_range`` reaches (µm/V);
        for a model whose branches fall, the smallest found before the search stopped (<= 0), or
        ``-inf`` when the states' band did not settle (:data:`MAX_SWEEPS`) or overflowed."""
        return self._min_slope

    @property
    def is_invertible(self) -> bool:
        """True when every branch rises (``min_slope > 0``): the inverse exists and is unique."""
        return self._min_slope > 0

    def simulate(self, u: Any, dt: float | None = None) -> FloatArray:
        """The output (µm) for the input ``u`` (V) from rest (rate independent)."""
        check_dt(dt, None, self.kind)
        v = as_signal("u", u)
        return self.offset + duhem_simulate(v, self.knots, self.f, self.g, self.lam)

    def predict(self, u: Any, dt: float | None = None) -> FloatArray:
        """The same as :meth:`simulate` (rate independent: ``dt`` is not needed)."""
        return self.simulate(u, dt)

    def stepper(self, dt: float | None = None) -> "GeneralizedDuhemStepper":
        """A per-sample simulator carrying the state between calls."""
        check_dt(dt, None, self.kind)
        return GeneralizedDuhemStepper(self)

    def slope_inverse(self, kappa: float = 0.0) -> "GeneralizedDuhemInverse":
        """Solves ``model(v) + kappa v = target`` sample by sample (module docstring)."""
        return GeneralizedDuhemInverse(self, kappa)

    def compensator(self, dt: float | None = None, *, u_range: Any = None,
                    max_slew: float | None = None) -> "GeneralizedDuhemCompensator":
        """The feedforward ``u = H^-1[x_d]``, clipped to ``u_range`` and rate-limited to ``max_slew`` V/sample."""
        check_dt(dt, None, self.kind)
        return GeneralizedDuhemCompensator(self, u_range=u_range, max_slew=max_slew)

    def to_dict(self) -> dict[str, Any]:
        """The parameters as plain data, for the model file (``from_dict`` reads them back)."""
        return {"knots": self.knots.tolist(), "f": self.f.tolist(), "g": self.g.tolist(), "lam": self.lam,
                "offset": self.offset, "v_range": list(self.v_range)}  # type: ignore[arg-type]

    @classmethod
    def from_dict(cls, params: dict[str, Any]) -> "GeneralizedDuhem":
        """The model from :meth:`to_dict`'s parameters (``offset`` defaults to 0, ``v_range`` to the knots')."""
        rng = params.get("v_range")
        return cls(knots=params["knots"], f=params["f"], g=params["g"], lam=params["lam"],
                   offset=params.get("offset", 0.0), v_range=None if rng is None else (rng[0], rng[1]))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, GeneralizedDuhem):
            return NotImplemented
        return (np.array_equal(self.knots, other.knots) and np.array_equal(self.f, other.f)
                and np.array_equal(self.g, other.g) and self.lam == other.lam and self.offset == other.offset
                and self.v_range == other.v_range)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        assert self.v_range is not None
        return (f"GeneralizedDuhem({self.knots.size} knots over {self.knots[0]:.4g}..{self.knots[-1]:.4g} V, "
                f"lam={self.lam:.4g}/V, offset={self.offset:.4g}, v_range=({self.v_range[0]:.4g}, "
                f"{self.v_range[1]:.4g}) V, min slope {self._min_slope:.4g} um/V)")


class GeneralizedDuhemStepper:
    def __init__(self, model: GeneralizedDuhem):
        self.model = model
        self.reset()

    def reset(self) -> None:
        self._v = 0.0
        self._y = 0.0

    def step(self, v: float) -> float:
        x = float(v)
        if not math.isfinite(x):
            raise ValueError(f"u_k must be finite, got {v!r}")
        m = self.model
        self._y = float(duhem_advance(self._v, self._y, x, m.knots, m.f, m.g, m.lam))
        self._v = x
        return m.offset + self._y


@njit
def _duhem_solve(target: float, v_prev: float, y_prev: float, knots: FloatArray, f: FloatArray, g: FloatArray,
                 lam: float, offset: float, kappa: float, s_min: float, steps: int,
                 v_lo: float, v_hi: float) -> float:  # pragma: no cover - compiled
    """The v in ``[v_lo, v_hi]`` with ``offset + y(v) + kappa v = target`` (the range's end when
    the target lies beyond it), ``y`` advanced from ``y_prev`` at ``v_prev``."""
    f0 = offset + y_prev + kappa * v_prev - target
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
    fb = offset + duhem_advance(v_prev, y_prev, b, knots, f, g, lam) + kappa * b - target
    if clamped and fb * f0 >= 0.0:
        return b  # the target lies beyond what the range reaches
    if fa > 0.0:
        a, b = b, a
        fa, fb = fb, fa
    for _ in range(steps):
        m = 0.5 * (a + b)
        fm = offset + duhem_advance(v_prev, y_prev, m, knots, f, g, lam) + kappa * m - target
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


class GeneralizedDuhemInverse:
    """Solves ``model(v) + kappa v = target`` for v, sample by sample."""

    def __init__(self, model: GeneralizedDuhem, kappa: float = 0.0):
        s = model.min_slope + float(kappa)
        if not s > 0:
            raise ValueError(f"the generalized Duhem model is not invertible: its smallest slope is {s:.4g}")
        self.model = model
        self.kappa = float(kappa)
        self._s = s
        self.reset()

    def reset(self) -> None:
        self._v = 0.0
        self._y = 0.0

    def step(self, target: float) -> float:
        m = self.model
        lo, hi = m.v_range  # type: ignore[misc]
        v = float(_duhem_solve(float(target), self._v, self._y, m.knots, m.f, m.g, m.lam, m.offset,
                               self.kappa, self._s, BISECTION_STEPS, lo, hi))
        self._y = float(duhem_advance(self._v, self._y, v, m.knots, m.f, m.g, m.lam))
        self._v = v
        return v

    def inverse_parameters(self) -> dict[str, Any]:
        """What :func:`_duhem_solve` works with (the inverse is numerical, not a model)."""
        m = self.model
        return {"role": "numerical inverse: solve offset + y(v) + kappa v = x_d per sample by bisection",
                "knots": m.knots.tolist(), "f": m.f.tolist(), "g": m.g.tolist(), "lam": m.lam, "offset": m.offset,
                "kappa": self.kappa, "min_slope": self._s, "bisection_steps": BISECTION_STEPS,
                "v_range": list(m.v_range)}  # type: ignore[arg-type]

    def to_c(self, c: Any, prefix: str) -> str:
        """:func:`_duhem_solve` and :func:`duhem_advance` as C99, operation for operation."""
        m = self.model
        k_n = m.knots.size
        kn = c.array(f"{prefix}_knots", m.knots)
        ff = c.array(f"{prefix}_f", m.f)
        gg = c.array(f"{prefix}_g", m.g)
        vv = c.state_scalar(f"{prefix}_v", 0.0)
        yy = c.state_scalar(f"{prefix}_y", 0.0)
        lam, off = c.num(m.lam), c.num(m.offset)
        kap, smin = c.num(self.kappa), c.num(self._s)
        lo, hi = c.num(m.v_range[0]), c.num(m.v_range[1])  # type: ignore[index]
        above, forcing = c.name(f"{prefix}_above"), c.name(f"{prefix}_forcing")
        flow, advance, fn = c.name(f"{prefix}_flow"), c.name(f"{prefix}_advance"), c.name(f"{prefix}_solve")
        wa_c = c.array(f"{prefix}_series_wa", np.array(_WA))
        wb_c = c.array(f"{prefix}_series_wb", np.array(_WB))
        c.function(f"""/* generalized Duhem model: F, G piecewise linear over {k_n} knots (constant beyond) */
static int {above}(double x)
{{
    int lo = 0;
    int hi = {k_n};
    while (lo < hi) {{
        const int mid = (lo + hi) / 2;
        if ({kn}[mid] <= x) lo = mid + 1; else hi = mid;
    }}
    return lo;
}}

/* F(x) + s G(x), i the number of knots at or below x */
static double {forcing}(double x, int i, double s)
{{
    double w;
    if (i == 0) return {ff}[0] + s * {gg}[0];
    if (i == {k_n}) return {ff}[{k_n - 1}] + s * {gg}[{k_n - 1}];
    w = (x - {kn}[i - 1]) / ({kn}[i] - {kn}[i - 1]);
    return ({ff}[i - 1] + w * ({ff}[i] - {ff}[i - 1])) + s * ({gg}[i - 1] + w * ({gg}[i] - {gg}[i - 1]));
}}

/* y after a segment of length ln over which the forcing runs linearly from pa to pb, exactly */
static double {flow}(double y, double ln, double pa, double pb)
{{
    const double z = {lam} * ln;
    const double a = exp(-z);
    double wa = 0.0;
    double wb = 0.0;
    if (z < {c.num(SERIES_BELOW)}) {{
        int k;
        for (k = {len(_WA) - 1}; k >= 0; --k) {{
            wa = {wa_c}[k] - z * wa;
            wb = {wb_c}[k] - z * wb;
        }}
    }} else {{
        const double e1 = -expm1(-z) / z;
        wb = (1.0 - e1) / z;
        wa = e1 - wb;
    }}
    return a * y + ln * (wa * pa + wb * pb);
}}

/* y after the input moves from v0 to v1: segment by segment between the knots it crosses */
static double {advance}(double v0, double y0, double v1)
{{
    double y = y0;
    double va = v0;
    double pa;
    double s;
    int i0;
    int i1;
    int j;
    if (v1 == v0) return y0;
    s = (v1 > v0) ? 1.0 : -1.0;
    i0 = {above}(v0);
    i1 = {above}(v1);
    pa = {forcing}(v0, i0, s);
    if (v1 > v0) {{
        for (j = i0; j < i1; ++j) {{
            double pb;
            if ({kn}[j] == v1) break;
            pb = {ff}[j] + {gg}[j];
            y = {flow}(y, {kn}[j] - va, pa, pb);
            va = {kn}[j];
            pa = pb;
        }}
        return {flow}(y, v1 - va, pa, {forcing}(v1, i1, s));
    }}
    for (j = i0 - 1; j > i1 - 1; --j) {{
        double pb;
        if ({kn}[j] == v0) continue;
        pb = {ff}[j] - {gg}[j];
        y = {flow}(y, va - {kn}[j], pa, pb);
        va = {kn}[j];
        pa = pb;
    }}
    return {flow}(y, va - v1, pa, {forcing}(v1, i1, s));
}}""")
        c_bracketed_solve(
            c, fn, f"generalized Duhem model, numerical inverse: bisection ({BISECTION_STEPS} halvings), one secant "
            "step, within the operating range",
            prologue=f"    const double v_prev = {vv};\n    const double y_prev = {yy};",
            f0=f"{off} + y_prev + {kap} * v_prev - target",
            f_at=lambda x: f"{off} + {advance}(v_prev, y_prev, {x}) + {kap} * {x} - target",
            s_min=smin, steps=BISECTION_STEPS, v_range=(lo, hi),
            epilogue=f"    {yy} = {advance}(v_prev, y_prev, v);\n    {vv} = v;")
        return fn


class GeneralizedDuhemCompensator(InverseCompensator):
    """The numerical inverse (module docstring): desired µm in, volts out."""

    def __init__(self, model: GeneralizedDuhem, *, u_range: Any = None, max_slew: float | None = None):
        super().__init__(model, GeneralizedDuhemInverse(model), u_range=u_range, max_slew=max_slew)
