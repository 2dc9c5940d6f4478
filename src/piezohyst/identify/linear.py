"""Linear-in-parameters identification: P-I, asymmetric P-I and Preisach models, with lags.

Every model these fits produce has an output that is linear in its parameters once its
*structure* is fixed (:class:`Structure`: the static kind and size, the output map's knots, the
lags' time constants, the input lag, the sensor delay). For a fixed structure the best
parameters are one bounded linear least-squares problem, solved to its global optimum
(:func:`~piezohyst.identify.lsq.bounded_lstsq`). The structure itself is chosen on held-out
data by :func:`piezohyst.identify.fit_model`.

The constraints are written as bounds through a change of variables, so that every fitted model
is invertible with a stable inverse (see :mod:`piezohyst.models.rate`):

* the static part's smallest branch slope is ``s0`` (P-I: every partial sum of the weights
  ``S_j = s0 + t_j``, ``t_j >= 0``; Preisach: the reversible slope, all weights ``>= 0``);
* the output lags' weights are ``c_i = p_i - q_i`` (``p, q >= 0``) and
  ``s0 = margin + e + sum_i q_i`` (``e >= 0``): the stability condition
  ``s0 + sum_i min(c_i, 0) >= margin`` holds for every feasible point, and every model that
  satisfies it is feasible;
* the asymmetric P-I model's output map ``g^-1(y) = y + sum phi_j D_j(y)`` has its slopes written
  as ``MAP_MARGIN + tau``, ``tau >= 0``, so ``g`` is increasing with slopes at most
  ``1 / MAP_MARGIN`` times the inner model's, and as flat as the data show where the stage
  saturates (Kuhnen's "generalised error" formulation: ``P[u] = g^-1(y)`` is linear in the P-I
  weights and ``phi``).

``margin`` defaults to :data:`DEFAULT_MARGIN` times the data's mean slope ``ptp(y) / ptp(u)``:
the compensator's gain right after a reversal is at most ``1 / margin``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from collections.abc import Callable
from typing import Any

import numpy as np

from .._numba import njit
from .._validation import FloatArray
from ..models.asymmetric_pi import AsymmetricPI, OutputMap
from ..models.bouc_wen_hysteresis import BoucWenHysteresis, max_unit_slope, unit_hysteresis
from ..models.duhem import GeneralizedDuhem, _segment, duhem_columns
from ..models.pi import PrandtlIshlinskii, equal_thresholds
from ..models.play import largest_loop_threshold, play_moves_both_ways, play_outputs_strided_into
from ..models.preisach import Preisach, demagnetised_state, grid_size, grid_thresholds, preisach_outputs_into
from ..models.rate import RateDependent, first_order_lag, lag_factor
from .lsq import bounded_lstsq_gram
from .result import FitResult

#: Smallest branch slope a fit allows, as a fraction of the data's mean slope.
DEFAULT_MARGIN = 0.02
#: Smallest slope of the inverse of an asymmetric P-I model's output map (so ``g`` is at most
#: ten times steeper than the inner model).
MAP_MARGIN = 0.1
#: Tikhonov weight on Preisach weights, relative to the mean diagonal of the normal equations:
#: the interior of the Preisach plane is barely seen by major loops; this keeps it small.
PREISACH_RIDGE = 1e-4
#: The same for the strips beyond the grid (:class:`~piezohyst.models.preisach.Preisach`): small
#: enough to leave every strip the record moves as it fits, large enough to keep a strip it never
#: moves (whose weight the data do not decide) at zero.
PREISACH_STRIP_RIDGE = 1e-8
#: A generalised Duhem design whose rows start after a warm-up pins its relaxation target at rest,
#: ``F(0) = 0`` (so the model's state at rest, y = 0, is the anhysteretic one), with this weight
#: relative to the mean diagonal of F's normal equations. Shifting F by ``lam c`` and the offset
#: by ``-c`` changes only the state the model starts from, and a warm-up that sweeps the range
#: leaves ``exp(-lam travel)`` of that (2 % on the zoo's Coleman-Hodgdon stage): the level is
#: barely seen, and the fit took it to a start 65 um off the loop whose fading followed a drift;
#: from that start the branches fell (not invertible), and with ``conditioning=True`` that stage
#: lost its Duhem model to a Preisach one (feedforward 0.26 -> 1.04 % e_max at 1 Hz).
DUHEM_REST_PIN = 1e3


#: A record whose largest loop is below this share of its span (one that never reverses, or only
#: by noise) keeps its P-I thresholds as they are (:func:`loop_thresholds`).
LOOPS_TOO_SMALL = 0.05


def loop_thresholds(r: FloatArray, v: FloatArray) -> tuple[FloatArray, float | None]:
    """P-I thresholds ``r`` (ascending, from 0) for a structure fitted on the input ``v``, with none
    that the record leaves unidentified although a cycle within its range reverses it: ``r`` itself
    unless some threshold lies between :func:`largest_loop_threshold` (the cap) and half the span,
    else those below half the span spread evenly below the cap, the others as they were; and the
    cap where it applied (else None).

    Such an operator follows only the input's running extreme over the record (its weight is set
    by the way from rest, or by nothing), yet a cycle over the whole range reverses it: fitted on a
    0-10 V multisine whose loops reach 9 V, the paper's thresholds put one at 4.5 V, and the model
    that predicted the record's later part to 0.7 % of the span missed a 0-10 V sinusoid by 20 %.
    Thresholds of at least half the span never reverse within the range (eq. 4's upper half on a
    unipolar record: the loading curve from rest) and stay.
    """
    inside, cap = _below_half_span(r, v)
    if cap is None:
        return r, None
    return np.concatenate([np.arange(inside.size, dtype=np.float64) / inside.size * cap, r[inside.size:]]), cap


def _below_half_span(r: FloatArray, v: FloatArray) -> tuple[FloatArray, float | None]:
    """The thresholds of ``r`` (ascending) below half the span of ``v``, and the record's
    :func:`largest_loop_threshold` where the largest of them is above it (else None; also None
    where the record's loops are below :data:`LOOPS_TOO_SMALL` of its span, or it never reverses:
    it then tells nothing of any operator's reversal, and its thresholds stay)."""
    x = np.ascontiguousarray(v, dtype=np.float64)
    rr = np.asarray(r, dtype=np.float64)
    half = 0.5 * float(np.ptp(x)) if x.size else 0.0
    inside = rr[rr < half]
    if inside.size == 0 or play_moves_both_ways(x, float(inside.max())):
        return inside, None
    cap = largest_loop_threshold(x)
    return inside, (cap if cap > LOOPS_TOO_SMALL * half else None)


def unreversed_thresholds(r: FloatArray, v: FloatArray) -> FloatArray:
    """The thresholds of ``r`` that the input ``v`` never reverses although a cycle within its
    range would (above :func:`largest_loop_threshold`, below half the span): see
    :func:`loop_thresholds`; empty when there are none."""
    inside, cap = _below_half_span(r, v)
    return inside[:0] if cap is None else inside[inside > cap]


@dataclass(frozen=True)
class Structure:
    """What is fixed before the least-squares fit (see the module docstring).

    Attributes
    ----------
    static : {"pi", "preisach", "bouc-wen", "duhem"}
        The rate-independent part (``"bouc-wen"``: the Bouc-Wen hysteresis of
        :mod:`piezohyst.models.bouc_wen_hysteresis`, its shape fixed by ``shape``; ``"duhem"``:
        the generalised Duhem model of :mod:`piezohyst.models.duhem`, its relaxation rate
        ``lam = shape[0]`` fixed, ``F`` and ``G`` fitted at ``size`` knots over the input's range).
    size : int
        P-I operators, Preisach grid levels or Duhem knots (unused for Bouc-Wen).
    map_knots : int
        Knots of the asymmetric P-I model's output map (0: no map; P-I only).
    taus : tuple of float
        Output-lag time constants, s.
    input_tau : float
        Input-lag time constant, s (0: none).
    delay : int
        Samples by which the output lags the input.
    thresholds : {"span", "eq4"}
        P-I thresholds over half the input's span (operators that move in steady state) or by
        the paper's eq. (4) over ``max|u|`` (or ``u_max`` when given).
    """

    static: str = "pi"
    size: int = 20
    map_knots: int = 0
    taus: tuple[float, ...] = ()
    input_tau: float = 0.0
    delay: int = 0
    thresholds: str = "span"
    u_max: float | None = None
    shape: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if self.static not in ("pi", "preisach", "bouc-wen", "duhem"):
            raise ValueError(f"static must be 'pi', 'preisach', 'bouc-wen' or 'duhem', got {self.static!r}")
        if self.static == "duhem" and not (self.shape[0] > 0 and self.size >= 2):
            raise ValueError(f"a Duhem structure needs lam = shape[0] > 0 and at least 2 knots, got {self.shape}, "
                             f"{self.size}")
        if self.static == "bouc-wen" and not self.shape[0] > abs(self.shape[1]):
            raise ValueError(f"a Bouc-Wen shape needs beta > |gamma|, got {self.shape}")
        if self.map_knots and self.static != "pi":
            raise ValueError("an output map goes with a P-I static part")
        if self.map_knots % 2:
            raise ValueError(f"map_knots must be even (half on each side of the centre), got {self.map_knots}")
        if self.thresholds not in ("span", "eq4"):
            raise ValueError(f"thresholds must be 'span' or 'eq4', got {self.thresholds!r}")

    @property
    def rate_dependent(self) -> bool:
        """True when the structure has an input lag or output lags."""
        return bool(self.taus) or self.input_tau > 0

    @property
    def kind(self) -> str:
        """The model kind this structure fits (``"asymmetric-pi"``, ``"rate-dependent"``, ...)."""
        if self.map_knots:
            return "asymmetric-pi"
        if self.rate_dependent:
            return "rate-dependent"
        return {"pi": "prandtl-ishlinskii", "preisach": "preisach", "bouc-wen": "bouc-wen-hysteresis",
                "duhem": "generalized-duhem"}[self.static]

    def label(self) -> str:
        """A one-line description (static part, size, lags, delay), as the candidates tables show."""
        name = {"pi": f"P-I n={self.size}" + (" (eq. 4 thresholds)" if self.thresholds == "eq4" else ""),
                "preisach": f"Preisach {self.size} levels",
                "bouc-wen": f"Bouc-Wen hysteresis beta={self.shape[0]:.3g}/V gamma={self.shape[1]:.3g}/V",
                "duhem": f"generalized Duhem {self.size} knots lam={self.shape[0]:.3g}/V"}[self.static]
        if self.map_knots:
            name = f"asymmetric {name}, {self.map_knots} map knots"
        parts = [name]
        if self.input_tau:
            parts.append(f"input lag {_fmt_s(self.input_tau)}")
        if self.taus:
            parts.append("lags " + ",".join(_fmt_s(t) for t in self.taus))
        parts.append(f"delay {self.delay}")
        return "; ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        """The structure as plain data: kind of static part, size, map knots, lags (s), delay."""
        out = {"static": self.static, "size": self.size, "map_knots": self.map_knots,
               "taus_s": list(self.taus), "input_tau_s": self.input_tau, "delay": self.delay,
               "thresholds": self.thresholds}
        if self.static == "bouc-wen":
            out["beta_per_V"], out["gamma_per_V"] = self.shape
        if self.static == "duhem":
            out["lam_per_V"] = self.shape[0]
        return out


def _fmt_s(t: float) -> str:
    return f"{t * 1e3:.3g} ms" if t < 1 else f"{t:.3g} s"


@dataclass
class Prepared:
    """The regressors of one structure over a whole record (built once, fitted on any rows).

    The design holds, per sample, ``[static variables (p) | floor (1) | lags (m) | 1]``, kept as
    two blocks: ``static``, the static part's columns, shared with every structure of the same
    static part (the same array, not a copy: a 16-level Preisach grid's is 70 MB on a search's
    rows), and ``extra``, this structure's own ``[floor | lags | 1]``. Every fit of the structure
    is a linear change of variables of these columns (``fit_prepared``), so the normal equations
    are kept per number of rows and a delay only removes the last rows' share. Every product is
    the one the whole design gives, to the last bit (the Gram matrix is formed on the two blocks
    side by side: a block-wise one would differ in its rounding, and with it a search's choice
    where two candidates are within rounding of each other).
    """

    structure: Structure
    v: FloatArray
    static: FloatArray  # (ceil(N / stride), p): the record's rows 0, stride, 2 stride, ...
    extra: FloatArray  # (ceil(N / stride), m + 2): floor, lags, 1
    p: int
    m: int
    a_lag: FloatArray
    decode_info: dict[str, Any]
    stride: int = 1
    #: the whole design as one array, when ``static`` and ``extra`` are views of it (a one-off
    #: design, a refit on all the data: its products then need no copy of it)
    whole: FloatArray | None = field(default=None, repr=False)
    _gram: dict[int, FloatArray] = field(default_factory=dict, repr=False)
    #: ``E' [S | E]`` per number of rows (this design's own rows of its Gram matrix)
    _extra: dict[int, FloatArray] = field(default_factory=dict, repr=False)
    #: ``S' S`` of the static block per number of rows, shared by every design of that block
    #: (the same dict, kept by the caller's cache): most of a Gram matrix's work on a wide grid
    static_grams: dict[int, FloatArray] | None = field(default=None, repr=False)

    @property
    def rows(self) -> int:
        """Stored rows (every ``stride``-th sample of the record)."""
        return int(self.static.shape[0])

    @property
    def base(self) -> FloatArray:
        """The whole design ``[static | extra]``, to look at (a copy, unless the design is one array)."""
        return self._rows(0, self.rows)

    def n_rows(self, rows: int) -> int:
        """Stored rows among the record's rows ``[0, rows)``."""
        return -(-rows // self.stride)

    def _rows(self, start: int, stop: int) -> FloatArray:
        """Rows ``start:stop`` of the whole design (a copy, unless the design is one array)."""
        if self.whole is not None:
            return self.whole[start:stop]
        return np.hstack([self.static[start:stop], self.extra[start:stop]])

    def gram(self, rows: int) -> FloatArray:
        """``B' B`` over the stored rows among the record's rows ``[0, rows)``, ``B = [static |
        extra]``: block by block, ``S' S`` (shared with the static block's other designs),
        ``E' S`` and ``E' E``, each from the nearest cached count of rows (a shorter set of rows
        only removes the last rows' share)."""
        k = self.n_rows(rows)
        g = self._gram.get(k)
        if g is not None:
            return g
        if self.static_grams is None:  # a one-off design: one array, one product
            g = _cached_product(self._gram, k, lambda a, b: _self_product(self._rows(a, b)))
            return g
        p = self.p
        ss = _cached_product(self.static_grams, k, lambda a, b: _self_product(self.static[a:b]))

        def extra_rows(a: int, b: int) -> FloatArray:
            e = self.extra[a:b]
            return np.hstack([e.T @ self.static[a:b], _self_product(e)])

        ext = _cached_product(self._extra, k, extra_rows)
        g = np.empty((self.q, self.q))
        g[:p, :p] = ss
        g[p:, :] = ext
        g[:p, p:] = ext[:, :p].T
        self._gram[k] = g
        return g

    @property
    def q(self) -> int:
        """Columns of the design: ``p`` static, the floor, ``m`` lags and the constant."""
        return self.p + self.m + 2

    def tmatvec(self, k: int, y: FloatArray) -> FloatArray:
        """``B[:k]' y[::stride]``."""
        yc = np.ascontiguousarray(y, dtype=np.float64)
        if self.whole is not None:
            return _tmatvec(self.whole, k, yc, self.stride)  # type: ignore[no-any-return]
        return np.concatenate([_tmatvec(self.static, k, yc, self.stride), _tmatvec(self.extra, k, yc, self.stride)])

    def tmatmul(self, k: int, x: FloatArray) -> FloatArray:
        """``B[:k]' x`` for a matrix ``x`` of ``k`` rows."""
        return self._rows(0, k).T @ x

    def matvec(self, start: int, stop: int, coef: FloatArray) -> FloatArray:
        """``B[start:stop] coef``, each row summed in column order."""
        if self.whole is not None:
            return _matvec2(self.whole, np.empty((self.rows, 0)), start, stop, coef)  # type: ignore[no-any-return]
        return _matvec2(self.static, self.extra, start, stop, coef)  # type: ignore[no-any-return]


def _self_product(b: FloatArray) -> FloatArray:
    """``b' b`` (numpy forms it with one symmetric rank-k update)."""
    return b.T @ b  # type: ignore[no-any-return]


def _cached_product(cache: dict[int, FloatArray], k: int, rows_product: Callable[[int, int], FloatArray]) -> FloatArray:
    """A product over rows ``[0, k)`` (``rows_product(a, b)`` over rows ``[a, b)``) from ``cache``:
    as it is, or a cached one over up to 20 % more rows less those rows' share, or formed anew."""
    g = cache.get(k)
    if g is not None:
        return g
    bigger = [r for r in cache if r > k]
    if bigger:
        r0 = min(bigger)
        if r0 - k <= 0.2 * k:
            g = cache[r0] - rows_product(k, r0)
            cache[k] = g
            return g
    g = rows_product(0, k)
    cache[k] = g
    return g


def prepare(u: FloatArray, dt: float | None, st: Structure, *, u_ref: FloatArray | None = None,
            cache: dict[Any, Any] | None = None, stride: int = 1, first: int = 0) -> Prepared:
    """Regressors of structure ``st`` for the input ``u`` (from rest).

    ``u_ref`` (default ``u``) is the part of the record the structure's data-derived settings
    (thresholds, grid) come from: the fitting rows, so nothing is read off held-out data.
    ``cache`` (a dict kept by the caller for one record) shares the blocks structures have in
    common: the lagged input, the static part's columns, each lag's column. With ``stride > 1``
    only every ``stride``-th row is kept (the states are still computed at every sample). With
    ``first > 0`` (a multiple of ``stride``) the operators run from ``u[0]`` but the design's rows
    start at sample ``first``: a warm-up that sets the states and is not fitted (the design is
    that of the record ``u[first:]`` started from the state ``u[:first]`` leaves).
    """
    if first:
        if first % stride or not 0 < first < u.size:
            raise ValueError(f"first={first} must be a multiple of stride={stride} inside the record")
        all_rows = prepare(u, dt, st, u_ref=u_ref, cache=cache, stride=stride)
        f = first // stride
        grams = None
        if cache is not None:  # S'S of these rows, shared by the designs of the same static block
            grams = cache.setdefault(("static-gram-from", first, *_static_key(st, u if u_ref is None else u_ref,
                                                                             stride)), {})
        return Prepared(st, all_rows.v[first:], all_rows.static[f:], all_rows.extra[f:], all_rows.p, all_rows.m,
                        all_rows.a_lag, {**all_rows.decode_info, "after_warmup": True}, stride,
                        all_rows.whole[f:] if all_rows.whole is not None else None, static_grams=grams)
    ref = u if u_ref is None else u_ref
    if st.rate_dependent and dt is None:
        raise ValueError("a rate-dependent structure needs the sample period dt")
    memo: dict[Any, Any] = {} if cache is None else cache
    key_v = ("v", st.input_tau, ref.size)
    if key_v not in memo:
        b = lag_factor(st.input_tau, dt) if st.input_tau and dt is not None else 0.0
        v_all = first_order_lag(u, b) if b else np.array(u, dtype=np.float64)
        v_ref_all = first_order_lag(ref, b) if b else np.asarray(ref, dtype=np.float64)
        memo[key_v] = (v_all, v_ref_all)
    v, v_ref = memo[key_v]
    # the blocks are kept at the stored rows only (the states behind them run over every sample)
    key_s = ("static", *_static_key(st, ref, stride))
    a_lag = np.exp(-float(dt or 0.0) / np.asarray(st.taus, dtype=np.float64)) if st.taus else np.zeros(0)
    m = a_lag.size
    rows = slice(None, None, stride)
    whole = None
    if cache is None:
        # a one-off design (a refit on all the data): one array, the static part's columns written
        # straight into it (on a 10^6-sample record with a 16-level Preisach grid, 1.3 GB less at
        # the peak than building them beside it, and no copy for its products)
        p = _static_width(st)
        whole = np.empty((-(-u.size // stride), p + m + 2))
        static_cols, floor, info = _static_columns(v, v_ref, st, stride, out=whole[:, :p])
        extra = whole[:, p:]
    else:
        if key_s in memo:
            static_cols, floor, info = memo[key_s]
        else:
            static_cols, floor, info = _static_columns(v, v_ref, st, stride)
            memo[key_s] = (static_cols, floor, info)
        static_grams = memo.setdefault(("static-gram", *key_s[1:]), {})
        extra = np.empty((static_cols.shape[0], m + 2))
    extra[:, 0] = floor
    for i, al in enumerate(a_lag):
        key_l = ("lag", st.input_tau, float(al), ref.size, stride)
        if key_l not in memo:
            memo[key_l] = np.ascontiguousarray(first_order_lag(v, float(al))[rows])  # not a view of all N
        extra[:, 1 + i] = memo[key_l]
    extra[:, -1] = 1.0
    return Prepared(st, v, static_cols, extra, static_cols.shape[1], m, a_lag, info, stride, whole,
                    static_grams=None if cache is None else static_grams)


def _static_key(st: Structure, ref: FloatArray, stride: int) -> tuple[Any, ...]:
    """What a static block depends on besides the record: a cache key for it and its products."""
    return (st.static, st.size, st.thresholds, st.u_max, st.shape, st.input_tau, ref.size, stride)


def _static_width(st: Structure) -> int:
    """How many free columns the static part of ``st`` has (:func:`_static_columns`)."""
    return {"pi": st.size, "bouc-wen": 1, "duhem": 2 * st.size}.get(st.static) or grid_size(st.size)


def _static_columns(v: FloatArray, v_ref: FloatArray, st: Structure, stride: int = 1, *,
                    out: FloatArray | None = None) -> tuple[FloatArray, FloatArray, dict[str, Any]]:
    """The static part's free columns, its floor column and what decoding needs, at the samples
    ``0, stride, 2 stride, ...`` (the operators' states are computed at every sample). With
    ``out`` (:func:`_static_width` columns, one row per kept sample, e.g. a view into the
    design) the columns are written there, the same numbers, and ``out`` is returned as them."""
    info: dict[str, Any] = {}
    rows = slice(None, None, stride)
    if st.static == "pi":
        if st.thresholds == "eq4":
            r = equal_thresholds(st.size, st.u_max if st.u_max else float(np.abs(v_ref).max()))
        else:
            half_span = 0.5 * float(np.ptp(v_ref))
            r = np.arange(st.size, dtype=np.float64) / st.size * half_span
        if st.u_max is None:  # (thresholds the caller set by u_max stay as asked)
            r, cap = loop_thresholds(r, v_ref)
            if cap is not None:
                info["loop_cap"] = cap
        n_rows = -(-v.size // stride)
        zd = np.empty((n_rows, r.size)) if out is None else out
        play_outputs_strided_into(np.ascontiguousarray(v), r, np.zeros(r.size), stride, zd)
        for j in range(r.size - 1):  # y = sum_j S_j (z_j - z_{j+1}): the partial sums' columns, in place
            zd[:, j] -= zd[:, j + 1]
        static_cols, floor = zd, zd.sum(axis=1)  # sum of the columns = z_1 = v (r_1 = 0)
        info["thresholds"] = r
    elif st.static == "bouc-wen":
        beta, gamma = st.shape
        h1 = np.ascontiguousarray(unit_hysteresis(v, beta, gamma)[rows])  # not a view of all N
        # invertible over the states the data's range reaches (and 0 V, the de-energised state)
        v_range = (min(float(v_ref.min()), 0.0), max(float(v_ref.max()), 0.0))
        mslope = max_unit_slope(beta, gamma, v_range)
        vs = v[rows]
        static_cols = (mslope * vs - h1)[:, None]  # coefficient alpha d1 >= 0; slope floor on v
        if out is not None:
            out[:, 0] = static_cols[:, 0]
            static_cols = out
        floor = np.array(vs, dtype=np.float64)
        info["max_unit_slope"] = mslope
        info["v_range"] = v_range
    elif st.static == "duhem":
        # G at the knots (columns 0..K-1, each G_j = floor + t_j, t_j >= 0), then F (free)
        knots = np.linspace(float(v_ref.min()), float(v_ref.max()), st.size)
        static_cols = duhem_columns(v, knots, st.shape[0], stride, out=out)
        floor = static_cols[:, :st.size].sum(axis=1)  # the output for G = 1, F = 0
        info["knots"] = knots
        info["v_range"] = (min(float(v_ref.min()), 0.0), max(float(v_ref.max()), 0.0))
    else:
        lo, hi = float(v_ref.min()), float(v_ref.max())
        pad = 1e-9 * (hi - lo)
        lo, hi = lo - pad, hi + pad
        a, bb, d = grid_thresholds(lo, hi, st.size)
        z0 = demagnetised_state(a, bb, d, 0.0)
        static_cols = np.empty((-(-v.size // stride), a.size)) if out is None else out
        preisach_outputs_into(np.ascontiguousarray(v), a, bb, 1.0 / d, z0, static_cols, stride)
        floor = np.array(v[rows], dtype=np.float64)
        info["grid"] = (lo, hi)
    return static_cols, floor, info


def _map_columns(y: FloatArray, knots: FloatArray, centre: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Columns, shift and bounds of the output map's variables ``tau`` (module docstring).

    Returns (columns (N, K), constant (N,), upper bounds (K,)) such that
    ``-sum_j phi_j D_j(y) = columns @ tau + constant``.
    """
    up = knots > centre
    upper = np.sort(knots[up])  # outward from the centre
    lower = np.sort(knots[~up])[::-1]
    cols, const = [], np.zeros(y.size)
    for side, ks in ((1, upper), (-1, lower)):
        if not ks.size:
            continue
        d = [np.maximum(y - k, 0.0) if side > 0 else np.minimum(y - k, 0.0) for k in ks]
        # slope beyond knot m = 1 + sum_{l<=m} phi_l = MAP_MARGIN + tau_m
        # => phi_1 = tau_1 + MAP_MARGIN - 1, phi_m = tau_m - tau_{m-1}
        const -= (MAP_MARGIN - 1.0) * d[0]
        for m in range(ks.size):
            nxt = d[m + 1] if m + 1 < ks.size else 0.0
            cols.append(-(d[m] - nxt))
    hi = np.full(len(cols), np.inf)
    return np.column_stack(cols), const, hi


def _decode_map(tau: FloatArray, knots: FloatArray, centre: float) -> OutputMap:
    up = knots > centre
    upper = np.sort(knots[up])
    lower = np.sort(knots[~up])[::-1]
    phi_by_knot: dict[float, float] = {}
    i = 0
    for ks in (upper, lower):
        prev = None
        for k in ks:
            t = float(tau[i])
            phi_by_knot[float(k)] = (t + MAP_MARGIN - 1.0) if prev is None else t - prev
            prev = t
            i += 1
    ks = np.sort(knots)
    return OutputMap(ks, np.array([phi_by_knot[float(k)] for k in ks], dtype=np.float64), centre)


class FewOutputLevelsError(ValueError):
    """The output takes fewer distinct values than an asymmetric P-I model's map has knots (a
    noise-free record that dwells on a few levels, e.g. steps between two commands)."""


def map_knots_for(y: FloatArray, count: int) -> tuple[FloatArray, float]:
    """Knots at the quantiles ``i / (count + 1)`` of ``y`` and the centre between the middle two.

    Where the output dwells on one value (a noise-free stage's dead zone or saturation, a
    coarsely quantised sensor) two quantiles can coincide: the knots are then the quantiles of
    the distinct values the output takes."""
    levels = np.arange(1, count + 1) / (count + 1)
    q = np.unique(np.quantile(y, levels))
    if q.size != count:
        q = np.unique(np.quantile(np.unique(y), levels))
    if q.size != count:
        raise FewOutputLevelsError(f"the output takes {np.unique(y).size} distinct value(s), too few for an "
                                   f"output map of {count} knots (an asymmetric P-I model): a record that dwells on "
                                   "a few levels; record one that moves through the range (sinusoids)")
    centre = 0.5 * (q[count // 2 - 1] + q[count // 2])
    return q, float(centre)


@njit
def _tmatvec(b: FloatArray, rows: int, y: FloatArray, stride: int) -> FloatArray:  # pragma: no cover - compiled
    """``b[:rows].T @ y[::stride]``, single-threaded (BLAS threads only contend on a shared machine)."""
    q = b.shape[1]
    out = np.zeros(q)
    for k in range(rows):
        yk = y[k * stride]
        for j in range(q):
            out[j] += b[k, j] * yk
    return out


@njit
def _matvec2(a: FloatArray, b: FloatArray, start: int, stop: int, c: FloatArray) -> FloatArray:  # pragma: no cover
    """``[a | b][start:stop] @ c``, each row summed in column order (a's columns, then b's)."""
    out = np.empty(stop - start)
    p = a.shape[1]
    q = b.shape[1]
    for k in range(start, stop):
        acc = 0.0
        for j in range(p):
            acc += a[k, j] * c[j]
        for j in range(q):
            acc += b[k, j] * c[p + j]
        out[k - start] = acc
    return out


def _design(pre: Prepared, margin: float, fit_offset: bool) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, int]:
    """The change of variables from the design's variables to the base columns' coefficients.

    Returns ``T`` and ``shift`` with ``coef = T @ x + shift`` (``coef`` multiplies ``base``), the
    bounds of ``x``, and ``ne`` (1 when the floor has its own variable). Variables:
    ``[t (p) | e (ne) | p_lag (m) | q_lag (m) | offset (fit_offset)]`` (module docstring).
    """
    st, p, m = pre.structure, pre.p, pre.m
    # P-I: the floor column is the sum of the partial sums' columns, so a floor variable would be
    # redundant with them (S_j = floor + t_j already); Preisach: slope = floor.
    ne = 0 if st.static in ("pi", "duhem") else 1
    nx = p + ne + 2 * m + (1 if fit_offset else 0)
    q = p + m + 2
    t = np.zeros((q, nx))
    t[:p, :p] = np.eye(p)
    if ne:
        t[p, p] = 1.0
    for i in range(m):
        t[p + 1 + i, p + ne + i] = 1.0  # p_i: + lag column
        t[p, p + ne + m + i] = 1.0  # q_i: + floor ...
        t[p + 1 + i, p + ne + m + i] = -1.0  # ... - lag column
    if fit_offset:
        t[q - 1, nx - 1] = 1.0
    shift = np.zeros(q)
    shift[p] = margin
    lb = np.zeros(nx)
    ub = np.full(nx, np.inf)
    if st.static == "duhem":
        lb[st.size:p] = -np.inf  # F may take either sign; G's slack t_j >= 0
    if fit_offset:
        lb[-1] = -np.inf
    return t, shift, lb, ub, ne


def fit_prepared(pre: Prepared, y: FloatArray, rows: int, dt: float | None, *,
                 margin: float, fit_offset: bool = True,
                 predict: tuple[int, int] | None = None) -> tuple[Any, dict[str, Any], FloatArray]:
    """The best parameters of ``pre.structure`` on base rows ``[0, rows)`` paired with ``y``
    (``len(y) == rows``; the caller applies the delay). Returns the model, what the solve saw,
    and the model's prediction over base rows ``predict = (start, stop)`` (default all; µm, the
    regressors times the parameters: the same numbers the model's ``simulate`` gives). A
    :class:`Prepared` with ``stride > 1`` fits on every ``stride``-th row only (a model search on a
    long record: the normal equations of a subsample of a smooth record are those of the whole, to
    within what the choice among candidates needs) and predicts those rows of ``predict``."""
    st, p, m = pre.structure, pre.p, pre.m
    yy = np.asarray(y, dtype=np.float64)
    t, shift, lb, ub, ne = _design(pre, margin, fit_offset)
    stride = pre.stride
    k_rows = pre.n_rows(rows)
    gb = pre.gram(rows)
    bty = pre.tmatvec(k_rows, yy)
    # rhs = y - base @ shift; A = base @ T (+ the map's columns)
    gram = t.T @ gb @ t
    atb = t.T @ (bty - gb @ shift)
    knots = centre = None
    if st.map_knots:
        ys = yy[::stride]
        knots, centre = map_knots_for(ys, st.map_knots)
        mc, const, hi = _map_columns(ys, knots, centre)
        k = mc.shape[1]
        # A = [B T | mc], rhs = ys - B shift - const. Every product goes through the stored
        # columns B (q of them) rather than B T (as many as the design's variables): B' [mc const]
        # and mc' [mc ys const] are the only products over the rows, the rest is q x q algebra.
        bc = pre.tmatmul(k_rows, np.column_stack([mc, const]))
        mm = mc.T @ np.column_stack([mc, ys, const])
        g2 = np.empty((gram.shape[0] + k, gram.shape[0] + k))
        g2[:-k, :-k] = gram
        cross = t.T @ bc[:, :k]
        g2[:-k, -k:] = cross
        g2[-k:, :-k] = cross.T
        g2[-k:, -k:] = mm[:, :k]
        gram = g2
        atb = np.concatenate([t.T @ (bty - gb @ shift - bc[:, k]), mm[:, k] - bc[:, :k].T @ shift - mm[:, k + 1]])
        # the map's variables go before the offset in x; keep them last here and reorder below
        lb = np.concatenate([lb, np.zeros(k)])
        ub = np.concatenate([ub, hi])
    ridge = None
    if st.static == "preisach":
        ridge = np.zeros(gram.shape[0])
        ridge[:p] = PREISACH_RIDGE * float(np.mean(np.diag(gram)[:p]))
        # the strips beyond the range: what the data see, all but unpenalised; the little weight
        # keeps a strip the record never moves at zero (a column constant over the fit is the
        # offset's twin, and its weight otherwise anything: a new record that moves it by a
        # fraction then predicted millions of µm)
        ridge[p - 2 * st.size:p] = PREISACH_STRIP_RIDGE * float(np.mean(np.diag(gram)[:p]))
    if st.static == "duhem" and pre.decode_info.get("after_warmup"):
        phi = _rest_weights(pre.decode_info["knots"])  # F(0) = phi @ F, F the variables k..2k-1
        k = st.size
        gram = gram.copy()
        gram[k:2 * k, k:2 * k] += DUHEM_REST_PIN * float(np.mean(np.diag(gram)[k:2 * k])) * np.outer(phi, phi)
    x = bounded_lstsq_gram(gram, atb, lb, ub, ridge=ridge)
    nx = t.shape[1]
    xb, tau_map = x[:nx], (x[nx:] if st.map_knots else None)
    coef = t @ xb + shift  # coefficients of the base columns
    tt = xb[:p]
    e = float(xb[p]) if ne else 0.0
    qq = xb[p + ne + m:p + ne + 2 * m]
    offset = float(coef[-1])
    s0 = margin + e + float(qq.sum())
    c = coef[p + 1:p + 1 + m]
    if st.static == "pi":
        s_part = coef[:p] + coef[p]  # S_j = t_j + floor coefficient
        w = np.diff(np.concatenate([[0.0], s_part]))
        static: Any = PrandtlIshlinskii(pre.decode_info["thresholds"], w, offset=offset)
    elif st.static == "bouc-wen":
        ad1 = float(tt[0])
        d1 = ad1 * pre.decode_info["max_unit_slope"] + float(coef[p])
        static = BoucWenHysteresis(d1=d1, alpha=ad1 / d1, beta=st.shape[0], gamma=st.shape[1], offset=offset,
                                   v_range=pre.decode_info["v_range"])
    elif st.static == "duhem":
        k = st.size
        static = GeneralizedDuhem(pre.decode_info["knots"], f=coef[k:2 * k], g=coef[:k] + coef[p], lam=st.shape[0],
                                  offset=offset, v_range=pre.decode_info["v_range"])
    else:
        lo, hi_ = pre.decode_info["grid"]
        static = Preisach(lo=lo, hi=hi_, weights=np.maximum(tt, 0.0), slope=float(coef[p]), offset=offset)
    model: Any = static
    if st.rate_dependent:
        if dt is None:
            raise ValueError("a rate-dependent structure needs dt")
        model = RateDependent(static, np.asarray(st.taus, dtype=np.float64), c, dt, input_tau=st.input_tau)
    start, stop = predict if predict is not None else (0, pre.rows * stride)
    inner_pred = pre.matvec(pre.n_rows(start), pre.n_rows(stop), coef)
    pred = inner_pred
    if st.map_knots:
        omap = _decode_map(tau_map, knots, centre)  # type: ignore[arg-type]
        model = AsymmetricPI(model, omap)
        pred = omap.forward_map(inner_pred)
    if st.static == "pi":
        slack = float(tt.min())
    elif st.static == "bouc-wen":
        slack = e
    elif st.static == "duhem":
        slack = float(tt[:st.size].min())
    else:  # inside the grid the diagonal (reversible) hysterons add to the slope
        ii, jj = np.tril_indices(st.size)
        lo, hi_ = pre.decode_info["grid"]
        slack = e + float(tt[: ii.size][ii == jj].min()) * st.size / (hi_ - lo)
    info = {"margin": margin, "slope_floor": s0 - e + slack,
            "floor_at_margin": bool(slack <= 1e-6 * margin), "n_parameters": int(gram.shape[0])}
    return model, info, pred


def _rest_weights(knots: FloatArray) -> FloatArray:
    """The weights of a piecewise-linear function's values at ``knots`` that give its value at
    0 V, as :class:`~piezohyst.models.duhem.GeneralizedDuhem` reads F (held constant beyond the
    ends: the model's own :func:`~piezohyst.models.duhem._segment`)."""
    lo, hi, w = _segment(0.0, np.ascontiguousarray(knots, dtype=np.float64))
    phi = np.zeros(knots.size)
    phi[lo] += 1.0 - w
    phi[hi] += w
    return phi


def mean_slope(u: FloatArray, y: FloatArray) -> float:
    su = float(np.ptp(u))
    if su == 0:
        raise ValueError("u is constant: a constant input cannot identify a hysteresis model")
    return float(np.ptp(y)) / su


#: Rows a fit on all the data holds in its design matrix at most; a longer record is fitted on
#: every k-th row (the operators still run over every sample), its RMSE over every row.
REFIT_ROWS = 1_000_000
#: Bytes a fit on all the data holds in its design matrix at most: fewer rows for a structure of
#: many columns. A 30-level Preisach refit on 10^6 samples held 4.3 GiB (its 4.5 GiB peak) for an
#: RMSE 0.08 % below the fit on every tenth row (0.65 GiB; found by a helper timing records the
#: benchmarks do not use); 512 MiB keeps a P-I structure's 10^6 rows and a 16-level grid's 370,000.
REFIT_BYTES = 512 * 2**20


def _row_cap(st: Structure, max_rows: int | None) -> int | None:
    """The rows a refit of ``st`` keeps at most: ``max_rows``, and within :data:`REFIT_BYTES`."""
    if max_rows is None:
        return None
    width = _static_width(st) + len(st.taus) + 2
    return max(1, min(int(max_rows), REFIT_BYTES // (8 * width)))


def fit_structure(u: FloatArray, y: FloatArray, dt: float | None, st: Structure, *, n_fit: int | None = None,
                  margin: float | None = None, fit_offset: bool = True,
                  prepared: Prepared | None = None, max_rows: int | None = REFIT_ROWS,
                  warmup: int = 0) -> tuple[FitResult, FloatArray]:
    """Fit ``st`` on samples ``[0, n_fit)`` of the record (default all) and predict the whole record.

    Returns the fit and the prediction over the whole record (µm), aligned with ``y`` (the
    prediction's sample k is compared with ``y[k]``; the first ``delay`` samples repeat the first
    prediction, as nothing is known before the record starts). A record of more than
    ``max_rows`` fitting rows (default :data:`REFIT_ROWS`; None: no limit) is fitted on every
    k-th of them, k the smallest that keeps it within (the design matrix of a 10^7-sample record
    with a 16-level Preisach grid and lags would be 14 GB), and the model then predicts every
    sample (its own simulation), from which the RMSE is taken.

    With ``warmup`` the first samples only set the model's state (:func:`prepare`'s ``first``,
    rounded up to the row stride): the fit, the RMSE and the returned prediction are of
    ``y[warmup:]`` (``n_fit`` counts from the record's start).
    """
    if warmup:
        n_all = u.size if n_fit is None else int(n_fit)
        w = int(warmup)
        cap = _row_cap(st, max_rows)
        stride = 1 if cap is None else max(1, -(-(n_all - w - st.delay) // cap))
        w = -(-w // stride) * stride
        if margin is None:
            margin = DEFAULT_MARGIN * mean_slope(u[w:n_all], y[w:n_all])
        pre = prepare(u, dt, st, u_ref=u[w:n_all], stride=stride, first=w)
        fit, pred = fit_structure(u[w:], y[w:], dt, st, n_fit=n_all - w, margin=margin, fit_offset=fit_offset,
                                  prepared=pre, max_rows=max_rows)
        if pre.stride > 1:  # the model's own simulation, from the record's start
            model = fit.model
            full = np.asarray(model.predict(u, dt if getattr(model, "dynamic", False) else None), dtype=np.float64)
            d = st.delay
            pred = (np.concatenate([np.full(d, full[0]), full[: u.size - d]]) if d else full)[w:]
            fit.rmse = float(np.sqrt(np.mean((y[w + d:n_all] - pred[d:n_all - w]) ** 2)))
        fit.info["warmup"] = w
        return fit, pred
    t0 = time.perf_counter()
    n = u.size
    n_fit = n if n_fit is None else int(n_fit)
    d = st.delay
    if n_fit - d < 10:
        raise ValueError(f"{n_fit} samples with a delay of {d} leave too few to fit")
    if margin is None:
        margin = DEFAULT_MARGIN * mean_slope(u[:n_fit], y[:n_fit])
    cap = _row_cap(st, max_rows)
    stride = 1 if prepared is not None or cap is None else max(1, -(-(n_fit - d) // cap))
    pre = prepared if prepared is not None else prepare(u, dt, st, u_ref=u[:n_fit], stride=stride)
    model, info, pred_u = fit_prepared(pre, y[d:n_fit], n_fit - d, dt, margin=margin, fit_offset=fit_offset,
                                       predict=(0, stride) if pre.stride > 1 else None)
    if pre.stride > 1:
        pred_u = np.asarray(model.predict(u, dt if getattr(model, "dynamic", False) else None), dtype=np.float64)
        info["fit_every_kth_row"] = int(pre.stride)
    pred = np.concatenate([np.full(d, pred_u[0]), pred_u[: n - d]]) if d else pred_u
    resid = y[d:n_fit] - pred[d:n_fit]
    rmse = float(np.sqrt(np.mean(resid**2)))
    info.update({"structure": st.to_dict(), "label": st.label()})
    fit = FitResult(model=model, rmse=rmse, method=f"bounded least squares ({st.label()})",
                    n_samples=int(n_fit - d), time_s=time.perf_counter() - t0, delay=int(d), info=info,
                    input_range=(float(u[:n_fit].min()), float(u[:n_fit].max())),
                    largest_loop=2.0 * largest_loop_threshold(u[:n_fit]))
    inst = _instantaneous_min_slope(model)
    if info["floor_at_margin"] and inst is not None and inst <= 2.0 * margin:
        fit.warnings.append(
            f"the loop is nearly flat (or falling) just after reversals: the model's smallest slope there is "
            f"{inst:.3g} per volt, at the allowed floor ({DEFAULT_MARGIN:g} of the mean slope), so the "
            f"compensator's gain there is limited; feedback must do the rest")
    return fit, pred


def _instantaneous_min_slope(model: Any) -> float | None:
    """Smallest slope of the map from this sample's input to this sample's output."""
    inner = getattr(model, "inner", model)
    if isinstance(inner, RateDependent):
        return float(inner.min_slope)
    ms = getattr(inner, "min_slope", None)
    return float(ms) if ms is not None else None


def with_delay(st: Structure, d: int) -> Structure:
    return replace(st, delay=int(d))


__all__ = ["DEFAULT_MARGIN", "Structure", "fit_structure", "prepare", "fit_prepared", "mean_slope",
           "map_knots_for"]
