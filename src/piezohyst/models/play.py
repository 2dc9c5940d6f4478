"""The backlash (play) operator, paper eqs. (1)-(2), as compiled kernels.

    y(k) = H_r[x, y0](k) = max{ x(k) - r, min{ x(k) + r, y(k-1) } }          (1)
    y(0) = max{ x(0) - r, min{ x(0) + r, y0 } }                              (2)

Eq. (2) is eq. (1) applied to the first sample with ``y(-1) = y0``, so one step function
serves both. Every kernel here takes the operator states ``z`` (one per threshold) and updates
them in place.

Two ways to run eq. (3) over a whole signal give the same outputs to rounding:

* the dense loop (:func:`pi_simulate_dense`): every operator at every sample, ``N * n`` work,
  the very :func:`pi_step` that the streaming path (:class:`~piezohyst.models.pi.PIStepper`)
  calls, so the two give identical outputs;
* the event-driven loop (:func:`pi_simulate_events`): work proportional to the operators that
  actually move, ``O(N + moves)``; on smooth records tens to hundreds of times less work.

:func:`pi_simulate` picks one per call from a cheap look at the input (:func:`event_work`):
the event-driven loop for smooth records, the dense one where nearly every sample reverses
and moves many operators (white noise). :func:`pi_gram` accumulates the normal equations of a
P-I fit in chunks, without the ``(N, n)`` regressor matrix, likewise event-driven (a run of rows
between two events at a time) where the input is smooth and dense where it is not.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .._numba import njit, njit_fast
from .._validation import FloatArray, as_signal


@njit
def play_step(x: float, r: FloatArray, z: FloatArray) -> None:  # pragma: no cover - compiled
    """Advance every play operator by one input sample ``x`` (eq. 1), in place.

    ``max{x - r, min{x + r, z}}`` is written as a branch-free clamp, which the compiler turns
    into vector instructions across the operators (x - r <= x + r, so the two are identical).
    """
    for i in range(r.shape[0]):
        z[i] = min(max(z[i], x - r[i]), x + r[i])


@njit
def pi_step(
    x: float, r: FloatArray, w: FloatArray, z: FloatArray, in_off: float, out_off: float
) -> float:  # pragma: no cover - compiled
    """One sample of a Prandtl-Ishlinskii model (eq. 3): update ``z``, return the output."""
    xs = x - in_off
    acc = 0.0
    for i in range(r.shape[0]):  # eq. (1) fused with the weighted sum of eq. (3)
        zi = min(max(z[i], xs - r[i]), xs + r[i])
        z[i] = zi
        acc += w[i] * zi
    return acc + out_off


@njit
def _pi_dense_into(
    u: FloatArray, r: FloatArray, w: FloatArray, z: FloatArray, in_off: float, out_off: float,
    y: FloatArray, k0: int, k1: int,
) -> None:  # pragma: no cover - compiled
    for k in range(k0, k1):
        y[k] = pi_step(u[k], r, w, z, in_off, out_off)


# The dense loop of the automatic choice: the weighted sum of eq. (3) may be reassociated
# (vectorised over the operators), so the outputs differ from pi_step's strict left-to-right sum
# by rounding only, and that rounding is the optimiser's (a process that compiled the kernel and
# one that loaded it from numba's cache can differ in the last bits; strictly ordered, this loop
# was 3x slower). The fits' sums below are strictly ordered: a fit is the same in every process.
# (It took four samples at once for up to 32 operators until 2026-11-26, composing four clamps
# into one to shorten the dependency chain; measured on this machine's AMD EPYC, 10^6 samples of
# white noise, that was the slower loop: 5 operators 5.49 -> 4.57 ms, 20 operators 9.34 -> 4.95 ms
# with the plain loop, against 6.47 ms for gcc -O3 -ffast-math, benchmarks/run.py pi-white-*.)
@njit_fast({"reassoc", "contract", "nsz"})
def _pi_dense_fast_into(
    u: FloatArray, r: FloatArray, w: FloatArray, z: FloatArray, in_off: float, out_off: float,
    y: FloatArray, k0: int, k1: int,
) -> None:  # pragma: no cover - compiled
    m = r.shape[0]
    for q in range(k0, k1):
        xs = u[q] - in_off
        acc = 0.0
        for i in range(m):
            zi = min(max(z[i], xs - r[i]), xs + r[i])
            z[i] = zi
            acc += w[i] * zi
        y[q] = acc + out_off


@njit
def pi_simulate_dense(
    u: FloatArray, r: FloatArray, w: FloatArray, z: FloatArray, in_off: float, out_off: float
) -> FloatArray:  # pragma: no cover - compiled
    """Eq. (3) over a whole signal, every operator at every sample (``N * n`` work).

    ``z`` holds the initial state and ends as the final one. Identical, sample for sample, to
    calling :func:`pi_step` in a loop (the streaming path).
    """
    n = u.shape[0]
    y = np.empty(n)
    _pi_dense_into(u, r, w, z, in_off, out_off, y, 0, n)
    return y


# -- the event-driven kernel ---------------------------------------------------------------------
# Why it works. Take sorted thresholds and a state whose neighbours differ by no more than their
# thresholds, |z_{i+1} - z_i| <= r_{i+1} - r_i ("consistent": the state at rest, any constant
# state, and every state reached from a consistent one, since eq. (1) is a clamp and keeps the
# condition). Then a rise of the input to x moves exactly the operators with z_i + r_i < x: a
# *prefix* of the sorted operators, as z_i + r_i grows with i; a fall moves the prefix with
# z_i - r_i > x. So the state is a stack of segments of operators (the wiping-out memory of the
# P-I model):
#   * operators 0..j-1 glued to the input: z_i = x - s r_i (s = +1 rising, -1 falling);
#   * segments frozen at a past reversal e_t of sense s_t: z_i = e_t - s_t r_i, i < b_t;
#   * below them the initial states, untouched so far.
# At a reversal the glued segment freezes (a push, O(1)). As the input moves on, the next
# operator j starts to move when x - s r_j passes its state (one test per sample); a frozen
# segment of the other sense is taken over one operator at a time (each one that moves), one of
# the same sense all at once when x passes its extremum (a pop, O(1)). The output
#     y = x sum_{i<j} w_i - s sum_{i<j} w_i r_i + sum_{i>=j} w_i z_i                    (eq. 3)
# is kept as x * cw + c from prefix sums of w and w r and the sums the stack stores, refreshed
# only when j or the stack changes. The work is O(N + operator moves) instead of O(N * n); the
# tests and states are the dense loop's own floating-point operations (x - r_j > z_j, ...).

_CALM = 8  # samples in a row with nothing to do before the event-driven loop goes to _quiet_run
_BLOCK = 256  # samples run densely between two checks of a state that is not (yet) consistent


@njit
def state_is_consistent(r: FloatArray, z: FloatArray) -> bool:  # pragma: no cover - compiled
    """True if ``r`` is non-decreasing and ``|z_{i+1} - z_i| <= r_{i+1} - r_i`` (to rounding).

    Under this condition the operators that an input rise (or fall) moves are a prefix of the
    sorted operators, which the event-driven kernel relies on. A state violating it only by
    rounding (a few units in the last place) passes: the kernel's error stays at rounding level.
    """
    for i in range(r.shape[0] - 1):
        dr = r[i + 1] - r[i]
        if dr < 0.0:
            return False
        tol = 8.0 * 2.220446049250313e-16 * (abs(z[i]) + abs(z[i + 1]) + abs(r[i + 1]))
        if abs(z[i + 1] - z[i]) > dr + tol:
            return False
    return True


@njit
def _quiet_run(
    u: FloatArray, y: FloatArray, k: int, in_off: float, s: float, sxp: float, rj: float,
    szj: float, cw: float, c: float,
) -> int:  # pragma: no cover - compiled
    """Outputs ``x cw + c`` from sample ``k`` on while nothing happens; return the first sample
    where the input reverses or the next operator starts to move (``len(u)`` if none)."""
    uu = u[k:]
    yy = y[k:]
    for q in range(uu.shape[0]):
        x = uu[q] - in_off
        sx = s * x
        if sx < sxp or sx - rj > szj:
            return k + q
        yy[q] = x * cw + c
        sxp = sx
    return u.shape[0]


@njit
def _pi_events_into(
    u: FloatArray, r: FloatArray, w: FloatArray, z: FloatArray, in_off: float, out_off: float,
    y: FloatArray, k0: int,
) -> None:  # pragma: no cover - compiled
    """Event-driven eq. (3) over ``u[k0:]`` into ``y[k0:]``; ``z`` must be consistent."""
    m = r.shape[0]
    n = u.shape[0]
    wsum = np.zeros(m + 1)  # wsum[j] = sum_{i<j} w_i
    wrsum = np.zeros(m + 1)  # wrsum[j] = sum_{i<j} w_i r_i
    tail = 0.0  # sum of w_i z_i over the initial states not yet taken over (i >= j, empty stack)
    for i in range(m):
        wsum[i + 1] = wsum[i] + w[i]
        wrsum[i + 1] = wrsum[i] + w[i] * r[i]
        tail += w[i] * z[i]
    k = k0
    s = 0.0
    while k < n:  # nothing moves until operator 0 does; its sense starts the first run
        x = u[k] - in_off
        if x - r[0] > z[0]:
            s = 1.0
            break
        if x + r[0] < z[0]:
            s = -1.0
            break
        y[k] = tail + out_off
        k += 1
    if k == n:
        return
    # the stack of frozen segments: extremum, sense, end (exclusive), sum of w_i z_i beyond it
    st_e = np.empty(m)
    st_s = np.empty(m)
    st_b = np.empty(m, dtype=np.int64)
    st_below = np.empty(m)
    depth = 0
    j = 0  # operators 0..j-1 are glued to the input
    sxp = s * (u[k] - in_off)  # s times the previous shifted sample (the first is no reversal)
    # The next operator moves when sx - rj > szj, with sx = s x: exactly the dense loop's
    # x - r_j > z_j rising, x + r_j < z_j falling (a product by +-1 is exact). -inf: look now.
    rj = 0.0
    szj = -np.inf
    cw = c = 0.0  # y = x cw + c
    calm = 0  # samples in a row with nothing to do
    while k < n:
        if calm >= _CALM:  # a quiet stretch: on to the next event in a tight loop of its own
            k1 = _quiet_run(u, y, k, in_off, s, sxp, rj, szj, cw, c)
            calm = 0
            if k1 > k:
                sxp = s * (u[k1 - 1] - in_off)
                k = k1
            if k == n:
                break
        x = u[k] - in_off
        sx = s * x
        calm += 1
        if sx < sxp:  # a reversal at the previous sample, xp = s * sxp
            calm = 0
            if j > 0:  # freeze the glued segment: push (xp, s, j)
                if depth > 0:
                    t = depth - 1
                    bt = st_b[t]
                    below = (st_e[t] * (wsum[bt] - wsum[j])
                             - st_s[t] * (wrsum[bt] - wrsum[j]) + st_below[t])
                else:
                    below = tail
                st_e[depth] = s * sxp
                st_s[depth] = s
                st_b[depth] = j
                st_below[depth] = below
                depth += 1
                j = 0
            s = -s
            sx = -sx
            szj = -np.inf
        if sx - rj > szj:
            calm = 0
            while True:  # glue every operator that starts to move at x
                if depth > 0:
                    t = depth - 1
                    if st_s[t] == s:  # same sense: the whole segment moves once x passes e_t
                        if sx > s * st_e[t]:
                            j = st_b[t]
                            depth -= 1
                            continue
                        break
                    if not sx - r[j] > s * (st_e[t] - st_s[t] * r[j]):
                        break
                    j += 1
                    if j == st_b[t]:
                        depth -= 1
                else:
                    if j == m or not sx - r[j] > s * z[j]:
                        break
                    tail -= w[j] * z[j]
                    j += 1
            # the next test and the output's coefficients
            cw = wsum[j]
            if depth > 0:
                t = depth - 1
                bt = st_b[t]
                if st_s[t] == s:
                    rj = 0.0
                    szj = s * st_e[t]
                else:
                    rj = r[j]
                    szj = s * (st_e[t] - st_s[t] * r[j])
                c = (st_e[t] * (wsum[bt] - wsum[j]) - st_s[t] * (wrsum[bt] - wrsum[j])
                     + st_below[t] - s * wrsum[j] + out_off)
            else:
                if j < m:
                    rj = r[j]
                    szj = s * z[j]
                else:
                    rj = 0.0
                    szj = np.inf
                c = tail - s * wrsum[j] + out_off
        y[k] = x * cw + c
        sxp = sx
        k += 1
    xp = s * sxp
    # write the state back: glued operators, then the frozen segments from the top down
    for i in range(j):
        z[i] = xp - s * r[i]
    start = j
    for t in range(depth - 1, -1, -1):
        for i in range(start, st_b[t]):
            z[i] = st_e[t] - st_s[t] * r[i]
        start = st_b[t]


@njit
def pi_simulate_events(
    u: FloatArray, r: FloatArray, w: FloatArray, z: FloatArray, in_off: float, out_off: float
) -> FloatArray:  # pragma: no cover - compiled
    """Eq. (3) over a whole signal, event-driven: work proportional to the operators that move.

    Same outputs as :func:`pi_simulate_dense` to rounding, for any thresholds and state: while
    the state is not consistent (:func:`state_is_consistent`; e.g. an arbitrary initial state
    or unsorted thresholds) it runs the dense loop, checking again every few hundred samples.
    ``z`` holds the initial state and ends as the final one.
    """
    n = u.shape[0]
    y = np.empty(n)
    k = 0
    while k < n and not state_is_consistent(r, z):
        k1 = min(n, k + _BLOCK)
        _pi_dense_into(u, r, w, z, in_off, out_off, y, k, k1)
        k = k1
    if k < n:
        _pi_events_into(u, r, w, z, in_off, out_off, y, k)
    return y


# -- the automatic choice ------------------------------------------------------------------------
_PROBE = 4096  # samples the cheap look reads at most
# Costs per sample in ns, measured on an x86-64 (benchmarks/calibrate_pi.py): the event-driven
# loop, _EV_SAMPLE plus _EV_TURN per reversal and _EV_MOVE per operator move; the dense loop,
# _DENSE_SAMPLE plus _DENSE_OP per operator. Only their ratios matter, and only near the break-even.
_EV_SAMPLE = 1.5
_EV_TURN = 30.0
_EV_MOVE = 15.0
_DENSE_SAMPLE = 4.0
_DENSE_OP = 0.4


@njit
def event_work(u: FloatArray, r: FloatArray) -> tuple[float, float]:  # pragma: no cover
    """Estimated reversals and operator moves per sample of the event-driven loop on ``u``.

    A cheap look: at most ``_PROBE`` samples (and at most a 16th of the record) in up to 16
    blocks spread over it. A run of the input between two reversals, of height ``h``, moves
    about the operators with ``2 r_i < h`` (those whose backlash it crosses). ``r`` must be
    sorted.
    """
    n = u.shape[0]
    probe = min(_PROBE, max(64, n // 16))
    blocks = 16
    length = probe // blocks
    if n <= probe or length < 16:
        blocks = 1
        length = min(n, probe)
    stride = (n - length) // (blocks - 1) if blocks > 1 else 0
    two_r = 2.0 * r
    turns = 0.0
    moves = 0.0
    for b in range(blocks):
        s = b * stride
        d = 0
        start = u[s]
        prev = u[s]
        for k in range(s + 1, s + length):
            x = u[k]
            if x > prev:
                if d < 0:  # a bottom at prev: the fall from start to prev is done
                    turns += 1.0
                    moves += np.searchsorted(two_r, start - prev)
                    start = prev
                d = 1
            elif x < prev:
                if d > 0:
                    turns += 1.0
                    moves += np.searchsorted(two_r, prev - start)
                    start = prev
                d = -1
            prev = x
        moves += np.searchsorted(two_r, abs(prev - start))
    seen = max(1, blocks * (length - 1))
    return turns / seen, moves / seen


@njit
def prefers_events(u: FloatArray, r: FloatArray) -> bool:  # pragma: no cover - compiled
    """True if the event-driven loop is expected to beat the dense one on ``u`` (cost model).

    The estimated costs per sample, from :func:`event_work` and the constants above, compared.
    """
    m = r.shape[0]
    for i in range(m - 1):
        if r[i + 1] < r[i]:
            return False  # unsorted thresholds: the event-driven loop would run dense anyway
    if u.shape[0] < 2:
        return False
    turns, moves = event_work(u, r)
    return _EV_SAMPLE + _EV_TURN * turns + _EV_MOVE * moves < _DENSE_SAMPLE + _DENSE_OP * m


@njit
def pi_simulate_strict(
    u: FloatArray, r: FloatArray, w: FloatArray, z: FloatArray, in_off: float, out_off: float
) -> FloatArray:  # pragma: no cover - compiled
    """:func:`pi_simulate` with every sum in the order the code gives it: the event-driven kernel,
    or the dense loop of :func:`pi_step` (not the reassociated one). The same numbers in every
    process, whatever the optimiser did: what a fit's residual (its RMSE) is computed with."""
    if prefers_events(u, r):
        return pi_simulate_events(u, r, w, z, in_off, out_off)
    return pi_simulate_dense(u, r, w, z, in_off, out_off)


@njit
def pi_simulate(
    u: FloatArray, r: FloatArray, w: FloatArray, z: FloatArray, in_off: float, out_off: float
) -> FloatArray:  # pragma: no cover - compiled
    """Eq. (3) over a whole signal; ``z`` holds the initial state and ends as the final one.

    Runs :func:`pi_simulate_events` or :func:`pi_simulate_dense`, whichever the cost model of
    :func:`prefers_events` expects to be faster on ``u``; both give the same outputs to rounding.
    """
    if prefers_events(u, r):
        return pi_simulate_events(u, r, w, z, in_off, out_off)
    y = np.empty(u.shape[0])
    _pi_dense_fast_into(u, r, w, z, in_off, out_off, y, 0, u.shape[0])
    return y


@njit
def _play_outputs_into(
    u: FloatArray, r: FloatArray, z: FloatArray, out: FloatArray, colsum: FloatArray
) -> None:  # pragma: no cover - compiled
    """The operator outputs into ``out`` (rows = samples), their column sums added to ``colsum``."""
    for k in range(u.shape[0]):
        play_step(u[k], r, z)
        for i in range(r.shape[0]):
            out[k, i] = z[i]
            colsum[i] += z[i]


@njit
def inside_monotone_stretch(v: FloatArray, k: int, last: float) -> bool:  # pragma: no cover - compiled
    """Whether sample ``k`` lies inside a monotone stretch of the input, ``last`` (the last sample
    stepped) -> ``v[k]`` -> ``v[k + 1]``, so that a kernel of rate-independent elements may skip it:
    neither the first nor the last sample. A play operator's state after a monotone stretch is its
    state after one step to the stretch's end (rising, ``z <= x_prev + r <= x + r`` keeps the
    upper clamp idle and ``max(z, x_1 - r, x_2 - r) = max(z, x_2 - r)``; falling likewise), and so
    is a Preisach hysteron's (both of its ramps rise with the input): ``max`` and ``min`` are
    exact and the clamps monotone in floating point, so skipping changes no bit."""
    if k == 0 or k + 1 >= v.shape[0]:
        return False
    return bool((v[k] - last) * (v[k + 1] - v[k]) >= 0.0)


@njit
def play_outputs_strided_into(u: FloatArray, r: FloatArray, z: FloatArray, stride: int,
                              out: FloatArray) -> None:  # pragma: no cover
    """``play_outputs(u, r, z)[::stride]`` written into ``out`` (one row per kept sample; may be a
    view into a wider matrix) without the whole matrix (a model search on a long record: a
    10^6-sample record's 20 operators held 160 MB to keep 30,000 rows). Only the kept rows, the
    turning points and the last sample are stepped (:func:`inside_monotone_stretch`): the rows
    are bit for bit those of stepping every sample, at the stride times less work on a smooth
    record."""
    m = r.shape[0]
    n = u.shape[0]
    last = 0.0
    for k in range(n):
        if k % stride != 0 and inside_monotone_stretch(u, k, last):
            continue
        x = u[k]
        last = x
        for i in range(m):
            z[i] = min(max(z[i], x - r[i]), x + r[i])
        if k % stride == 0:
            j = k // stride
            for i in range(m):
                out[j, i] = z[i]


@njit
def play_outputs(u: FloatArray, r: FloatArray, z: FloatArray) -> FloatArray:  # pragma: no cover
    """All operator outputs ``H_ri[u](k)`` as an (N, n) matrix (the regressors of a P-I fit);
    ``z`` (the initial states) is left at the final states.

    Dense on purpose: every element of the matrix is written whatever the input, and writing
    it is the cost (``make bench`` compares it with merely filling a matrix of that size), so
    the event-driven bookkeeping would save nothing here. Each row is eq. (1) applied to the
    row before it, so the states live in the matrix itself and nothing is copied.
    """
    n, m = u.shape[0], r.shape[0]
    out = np.empty((n, m))
    if n == 0:
        return out
    x = u[0]
    for i in range(m):
        out[0, i] = min(max(z[i], x - r[i]), x + r[i])
    for k in range(1, n):
        x = u[k]
        prev = out[k - 1]
        row = out[k]
        for i in range(m):
            row[i] = min(max(prev[i], x - r[i]), x + r[i])
    for i in range(m):
        z[i] = out[n - 1, i]
    return out


@njit_fast({"reassoc"})
def _all_finite(x: FloatArray) -> bool:  # pragma: no cover - compiled
    # 0 * x is NaN exactly where x is NaN or infinite; the sum may be vectorised (reassoc only:
    # the compiler must not assume the absence of NaN or inf, which is what is being tested)
    acc = 0.0
    for i in range(x.shape[0]):
        acc += 0.0 * x[i]
    return acc == 0.0


def finite_signal(name: str, value: Any) -> FloatArray:
    """:func:`~piezohyst._validation.as_signal`, with a fast path for what it would return as is
    (a 1-D, C-contiguous, finite float64 array): one compiled pass instead of a temporary
    boolean array. Anything else goes to ``as_signal``, which raises its errors."""
    if (isinstance(value, np.ndarray) and value.dtype == np.float64 and value.ndim == 1
            and value.size >= 1 and value.flags.c_contiguous and _all_finite(value)):
        return value
    return as_signal(name, value)


def play_operator(x: object, r: float, y0: float = 0.0) -> FloatArray:
    """The backlash operator ``H_r[x, y0]`` of eqs. (1)-(2) over a whole signal.

    Parameters
    ----------
    x : array_like, 1-D
        Input signal.
    r : float
        Threshold (half the backlash width), ``r >= 0``.
    y0 : float
        Initial state ``y0`` of eq. (2).

    Returns
    -------
    ndarray
        The operator output, same length as ``x``.
    """
    xs = as_signal("x", x)
    if not np.isfinite(r) or r < 0:
        raise ValueError(f"r must be a finite threshold >= 0, got {r}")
    if not np.isfinite(y0):
        raise ValueError(f"y0 must be finite, got {y0}")
    z = np.array([float(y0)])
    return play_outputs(xs, np.array([float(r)]), z)[:, 0]


# -- streamed normal equations -------------------------------------------------------------------
_CHUNK_BYTES = 16 * 2**20  # the operator outputs held at once by pi_gram's BLAS path


def default_chunk_rows(n_operators: int) -> int:
    """Rows of operator outputs :func:`pi_gram` computes at once above 64 operators (16 MiB)."""
    return max(1024, _CHUNK_BYTES // (8 * n_operators))

# Up to this many operators pi_gram accumulates in one compiled, single-threaded pass (blocks of
# _GRAM_BLOCK rows kept in cache); above it, chunk by chunk through BLAS, whose blocked matrix
# product wins once the n^2 / 2 products per row dominate.
_GRAM_COMPILED_MAX = 64
_GRAM_BLOCK = 64


# The sums of the normal equations run in four lanes (elements k = l mod 4 in lane l, added
# left to right, the lanes added last): the compiler puts the lanes in one vector register, and
# the order of every addition is fixed by the code. (With numba's fastmath "reassoc" instead, the
# order was the optimiser's: a process that compiled the kernels and one that loaded them from
# numba's cache differed in the last bits of Z'y.)
@njit
def _sum4(x: FloatArray) -> float:  # pragma: no cover - compiled
    """The sum of ``x`` in four lanes (above). Indices from ``range``, on a slice: numba then
    knows them non-negative and checks no wrap-around (an offset index was twice as slow)."""
    n = x.shape[0]
    a0 = a1 = a2 = a3 = 0.0
    m = n // 4
    for b in range(m):
        k = 4 * b
        a0 += x[k]
        a1 += x[k + 1]
        a2 += x[k + 2]
        a3 += x[k + 3]
    for k in range(4 * m, n):
        a0 += x[k]
    return (a0 + a1) + (a2 + a3)


@njit
def _dot4(x: FloatArray, v: FloatArray) -> float:  # pragma: no cover - compiled
    """``sum_k x[k] v[k]`` (same lengths) in four lanes, as :func:`_sum4`."""
    n = x.shape[0]
    a0 = a1 = a2 = a3 = 0.0
    m = n // 4
    for b in range(m):
        k = 4 * b
        a0 += x[k] * v[k]
        a1 += x[k + 1] * v[k + 1]
        a2 += x[k + 2] * v[k + 2]
        a3 += x[k + 3] * v[k + 3]
    for k in range(4 * m, n):
        a0 += x[k] * v[k]
    return (a0 + a1) + (a2 + a3)


@njit
def _centred_sums4(u: FloatArray, c: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """``sum_k (u[k] - c)`` and ``sum_k (u[k] - c)^2``, each in four lanes, as :func:`_sum4`."""
    n = u.shape[0]
    a0 = a1 = a2 = a3 = 0.0
    b0 = b1 = b2 = b3 = 0.0
    m = n // 4
    for b in range(m):
        k = 4 * b
        v0 = u[k] - c
        v1 = u[k + 1] - c
        v2 = u[k + 2] - c
        v3 = u[k + 3] - c
        a0 += v0
        a1 += v1
        a2 += v2
        a3 += v3
        b0 += v0 * v0
        b1 += v1 * v1
        b2 += v2 * v2
        b3 += v3 * v3
    for k in range(4 * m, n):
        v0 = u[k] - c
        a0 += v0
        b0 += v0 * v0
    return (a0 + a1) + (a2 + a3), (b0 + b1) + (b2 + b3)


@njit
def _centred_dot4(u: FloatArray, c: float, y: FloatArray) -> float:  # pragma: no cover - compiled
    """``sum_k (u[k] - c) y[k]`` (same lengths) in four lanes, as :func:`_sum4`."""
    n = u.shape[0]
    a0 = a1 = a2 = a3 = 0.0
    m = n // 4
    for b in range(m):
        k = 4 * b
        a0 += (u[k] - c) * y[k]
        a1 += (u[k + 1] - c) * y[k + 1]
        a2 += (u[k + 2] - c) * y[k + 2]
        a3 += (u[k + 3] - c) * y[k + 3]
    for k in range(4 * m, n):
        a0 += (u[k] - c) * y[k]
    return (a0 + a1) + (a2 + a3)


@njit
def _gram_into(
    u: FloatArray, r: FloatArray, z: FloatArray, y: FloatArray, delays: Any, gram: FloatArray,
    zty: FloatArray, colsum: FloatArray,
) -> None:  # pragma: no cover - compiled
    """For the rows k = 0..len(u)-1 of Z (operator outputs, states z carried on): the upper
    triangle of gram += Z'Z, zty[:, q] += sum_k Z_k y[k + delays[q]], colsum += Z'1."""
    n = u.shape[0]
    m = r.shape[0]
    nd = delays.shape[0]
    buf = np.empty((m, _GRAM_BLOCK))  # buf[i, k]: operator i at row a + k (columns contiguous)
    for a in range(0, n, _GRAM_BLOCK):
        nb = min(n, a + _GRAM_BLOCK) - a
        for k in range(nb):
            x = u[a + k]
            for i in range(m):
                zi = min(max(z[i], x - r[i]), x + r[i])
                z[i] = zi
                buf[i, k] = zi
        for i in range(m):
            bi = buf[i]
            bk = bi[:nb]
            colsum[i] += _sum4(bk)
            for q in range(nd):
                o = a + delays[q]
                zty[i, q] += _dot4(bk, y[o:o + nb])
            for j in range(i, m):
                gram[i, j] += _dot4(bk, buf[j, :nb])


# -- event-driven normal equations ---------------------------------------------------------------
# The idea of the event-driven simulation (above) applied to Z'Z, Z'y_d and Z'1. Between two
# events (a reversal of the input, an operator starting to move) every operator's output is
# either glued to the input, z_i(k) = u(k) - s r_i (operators 0..j-1, one sense s), or constant,
# z_i(k) = c_i. Over such a run of rows k = p..q-1, with v(k) = u(k) - u(p) (centred on the
# run's first input, so no large sums cancel) and a_i = u(p) - s r_i or c_i,
#     sum z_i z_l = [i,l<j] S_vv + ([i<j] a_l + [l<j] a_i) S_v + a_i a_l (q - p)
#     sum z_i y(k+d) = [i<j] S_vy,d + a_i S_y,d        sum z_i = [i<j] S_v + a_i (q - p)
# so a run costs the sums S_v, S_vv, S_y,d, S_vy,d over its rows (2 + 2D per row, vectorised),
# and one update of the n^2 + nD + n accumulators: on smooth records a few runs per operator
# and reversal, where the dense pass spends (n(n+1)/2 + nD) products on every row. The sums of a
# run start from zero (no prefix sums are differenced) and a run is cut every _GRAM_RUN rows, so
# the rounding is that of blockwise sums, as in the dense pass. The events are found with the
# dense loop's own comparisons (x - r_j > z_j rising, x + r_j < z_j falling) and the states it
# leaves are the dense loop's own values (x - s r_i of the input where an operator stopped), so
# they agree bit for bit wherever the moving operators are a prefix (consistent states: above).
#
# Where the input reverses nearly every row (noise), every row is a run of its own and the
# update costs more than the dense row: the event-driven pass gives up on a chunk of rows once
# it has met more than one event per _GRAM_EVENT_ROWS rows (judged after _GRAM_TRY rows), and
# the dense pass takes the chunk's rest and the next 1, 2, 4, 8 chunks (after 1, 2, 3, 4+ such
# failures in a row), so white noise pays for a try on one chunk in nine.
_GRAM_RUN = 2048  # longest run summed at once
_GRAM_CHUNK = 4096  # rows per choice between the event-driven and the dense pass
_GRAM_TRY = 64  # rows the event-driven pass runs before it judges its event rate
_GRAM_EVENT_ROWS = 6  # gives up above one event per this many rows (an event costs several dense rows)


@njit
def _run_sums(u: FloatArray, y: FloatArray, delays: Any, p: int, q: int, c: float,
              glued: bool, sums: FloatArray) -> None:  # pragma: no cover - compiled
    """``sums`` = [S_v, S_vv, S_y,d..., S_vy,d...] over the rows p..q-1, v = u - c (the u sums
    only if ``glued``: nothing moves with the input otherwise), each in four lanes (``_sum4``)."""
    nd = delays.shape[0]
    n = q - p
    uu = u[p:q]
    sv = svv = 0.0
    if glued:
        sv, svv = _centred_sums4(uu, c)
    sums[0] = sv
    sums[1] = svv
    for t in range(nd):
        o = p + delays[t]
        yy = y[o:o + n]
        sums[2 + t] = _sum4(yy)
        sums[2 + nd + t] = _centred_dot4(uu, c, yy) if glued else 0.0


@njit
def _add_run(a: FloatArray, j: int, rows: int, sums: FloatArray, gram: FloatArray, zty: FloatArray,
             colsum: FloatArray) -> None:  # pragma: no cover - compiled
    """One run's share of the accumulators: operators 0..j-1 are v + a_i, the rest a_i. Only
    the upper triangle of ``gram`` is right (as :func:`_gram_into`'s); the update goes over the
    whole square nonetheless, full rows vectorising better than rows cut at the diagonal."""
    m = a.shape[0]
    nd = zty.shape[1]
    sv, svv, nr = sums[0], sums[1], float(rows)
    for i in range(m):  # a_i a_q L + [i<j] a_q S_v: a rank-one update, row by row
        b = a[i] * nr
        if i < j:
            b += sv
        gi = gram[i]
        for q in range(m):
            gi[q] += a[q] * b
    for i in range(j):  # + [q<j] a_i S_v + [i,q<j] S_vv; above the diagonal, q < j means i < j
        gi = gram[i]
        c = svv + a[i] * sv
        for q in range(j):
            gi[q] += c
    for i in range(j):
        colsum[i] += sv + a[i] * nr
        for t in range(nd):
            zty[i, t] += sums[2 + nd + t] + a[i] * sums[2 + t]
    for i in range(j, m):
        colsum[i] += a[i] * nr
        for t in range(nd):
            zty[i, t] += a[i] * sums[2 + t]


@njit
def _flush_run(u: FloatArray, y: FloatArray, delays: Any, r: FloatArray, cst: FloatArray, j: int,
               s: float, p: int, q: int, gram: FloatArray, zty: FloatArray, colsum: FloatArray,
               a: FloatArray, sums: FloatArray) -> None:  # pragma: no cover - compiled
    """Rows p..q-1, over which operators 0..j-1 are glued to the input with sense ``s`` and the
    others hold ``cst``, into the accumulators (cut every _GRAM_RUN rows)."""
    m = r.shape[0]
    for i in range(j, m):
        a[i] = cst[i]
    while p < q:
        e = min(q, p + _GRAM_RUN)
        c = u[p] if j > 0 else 0.0
        for i in range(j):
            a[i] = c - s * r[i]
        _run_sums(u, y, delays, p, e, c, j > 0, sums)
        _add_run(a, j, e - p, sums, gram, zty, colsum)
        p = e


@njit
def _gram_events_into(
    u: FloatArray, r: FloatArray, z: FloatArray, y: FloatArray, delays: Any, gram: FloatArray,
    zty: FloatArray, colsum: FloatArray, k0: int, k1: int, event_rows: int,
) -> int:  # pragma: no cover - compiled
    """As :func:`_gram_into` for the rows k0..k1-1 (``y[k + d]`` with global indices), event by
    event; ``r`` sorted and ``z`` consistent (:func:`state_is_consistent`). Returns the row it
    stopped before: ``k1``, or earlier if it met more than one event per ``event_rows`` rows
    (0: never gives up); ``z`` then holds the states after the rows done, for the dense pass."""
    m = r.shape[0]
    nd = delays.shape[0]
    cst = z.copy()  # the states of the operators not glued to the input
    a = np.empty(m)
    sums = np.empty(2 + 2 * nd)
    k = k0
    s = 0.0
    while k < k1:  # nothing moves until operator 0 does; its sense starts the first run
        x = u[k]
        if x - r[0] > cst[0]:
            s = 1.0
            break
        if x + r[0] < cst[0]:
            s = -1.0
            break
        k += 1
    _flush_run(u, y, delays, r, cst, 0, 1.0, k0, k, gram, zty, colsum, a, sums)
    if k == k1:
        return k1
    j = 0  # operators 0..j-1 are glued to the input
    start = k  # the current run's first row
    events = 0
    sxp = s * u[k]  # s times the previous input (the first is no reversal)
    while k < k1:
        x = u[k]
        sx = s * x
        rev = sx < sxp
        if rev or (j < m and sx - r[j] > s * cst[j]):
            if k > start:
                _flush_run(u, y, delays, r, cst, j, s, start, k, gram, zty, colsum, a, sums)
                start = k
                events += 1
                if k - k0 >= _GRAM_TRY and events * event_rows > k - k0:
                    break  # too many events: the dense pass goes on from row k
            if rev:  # the glued operators stop where the previous input left them
                xp = s * sxp
                for i in range(j):
                    cst[i] = xp - s * r[i]
                j = 0
                s = -s
                sx = -sx
            while j < m and sx - r[j] > s * cst[j]:  # every operator that starts to move at x
                j += 1
        sxp = sx
        k += 1
    if k == k1:
        _flush_run(u, y, delays, r, cst, j, s, start, k1, gram, zty, colsum, a, sums)
    xp = s * sxp  # the last input done
    for i in range(j):
        z[i] = xp - s * r[i]
    for i in range(j, m):
        z[i] = cst[i]
    return k


@njit
def _gram_auto_into(
    u: FloatArray, r: FloatArray, z: FloatArray, y: FloatArray, delays: Any, gram: FloatArray,
    zty: FloatArray, colsum: FloatArray, chunk: int, event_rows: int,
) -> None:  # pragma: no cover - compiled
    """:func:`_gram_into`'s sums, in chunks of ``chunk`` rows: event-driven where the events are
    sparse enough (``event_rows``: :func:`_gram_events_into`), dense elsewhere and wherever ``r``
    is unsorted or ``z`` not consistent."""
    n = u.shape[0]
    m = r.shape[0]
    ordered = True
    for i in range(m - 1):
        if r[i + 1] < r[i]:
            ordered = False
    k = 0
    wait = 0  # chunks to run dense before the event-driven pass is tried again
    failed = 0  # its failures in a row
    while k < n:
        kc = min(n, k + chunk)
        if wait > 0:
            wait -= 1
        elif ordered and state_is_consistent(r, z):
            k = _gram_events_into(u, r, z, y, delays, gram, zty, colsum, k, kc, event_rows)
            if k < kc:  # it gave up: wait 1, 2, 4, 8 chunks before the next try
                wait = 1 << min(failed, 3)
                failed += 1
            else:
                failed = 0
        if k < kc:
            _gram_into(u[k:kc], r, z, y[k:], delays, gram, zty, colsum)
        k = kc


@njit
def _y_sums(y: FloatArray, delays: Any) -> tuple[FloatArray, FloatArray]:  # pragma: no cover
    """``1'y[d:]`` and ``y[d:]'y[d:]`` for every delay: the whole record's sums less those of its
    first ``d`` samples, in four lanes (``_sum4``; compiled: numpy's dot goes to a threaded BLAS,
    whose spinning costs this thread more than the sum itself on a busy machine)."""
    s1 = _sum4(y)
    s2 = _dot4(y, y)
    nd = delays.shape[0]
    ysum = np.empty(nd)
    yty = np.empty(nd)
    for t in range(nd):
        head = y[:delays[t]]
        ysum[t] = s1 - _sum4(head)
        yty[t] = s2 - _dot4(head, head)
    return ysum, yty


@dataclass(frozen=True)
class GramStats:
    """The normal equations of a linear P-I fit, for one or more output delays.

    For delay ``d``, the regressor matrix ``Z_d`` has the rows ``H_ri[u](k)`` for
    ``k = 0 .. N-d-1`` (the operator outputs of eq. 1 driven by ``u``) and the target is
    ``y_d = y[d:]``: the pairing ``u[k]`` with ``y[k + d]`` of a sensor that lags by ``d``
    samples. Entry ``i`` of every field belongs to ``delays[i]``.

    Attributes
    ----------
    delays : ndarray of int, shape (D,)
    n_samples : ndarray of int, shape (D,)
        ``N - d``, the rows of ``Z_d``.
    gram : ndarray, shape (D, n, n)
        ``Z_d' Z_d``.
    zty : ndarray, shape (D, n)
        ``Z_d' y_d``.
    zsum : ndarray, shape (D, n)
        Column sums of ``Z_d`` (``Z_d' 1``).
    ysum, yty : ndarray, shape (D,)
        ``1' y_d`` and ``y_d' y_d``.
    """

    delays: Any
    n_samples: Any
    gram: Any
    zty: Any
    zsum: Any
    ysum: Any
    yty: Any

    def normal_equations(self, i: int = 0, *, offset: bool = True) -> tuple[FloatArray, FloatArray, float, int]:
        """``(A'A, A'y, y'y, N)`` for ``delays[i]``, ``A = [Z_d, 1]`` (or ``Z_d`` without offset).

        The least-squares residual of any ``x`` is ``x'A'Ax - 2 x'A'y + y'y``, so the RMSE of eq.
        (9) follows without the data: ``sqrt(that / N)``.
        """
        g, b = self.gram[i], self.zty[i]
        nr = int(self.n_samples[i])
        if not offset:
            return g.copy(), b.copy(), float(self.yty[i]), nr
        n = g.shape[0]
        ata = np.empty((n + 1, n + 1))
        ata[:n, :n] = g
        ata[:n, n] = ata[n, :n] = self.zsum[i]
        ata[n, n] = nr
        return ata, np.append(b, self.ysum[i]), float(self.yty[i]), nr

    def normal_equations_all(self, *, offset: bool = True) -> tuple[FloatArray, FloatArray, FloatArray, Any]:
        """:meth:`normal_equations` of every delay at once, stacked along a first axis."""
        nr = np.asarray(self.n_samples)
        yty = np.asarray(self.yty, dtype=np.float64)
        if not offset:
            return np.array(self.gram, dtype=np.float64), np.array(self.zty, dtype=np.float64), yty, nr
        k, n = self.zty.shape
        ata = np.empty((k, n + 1, n + 1))
        ata[:, :n, :n] = self.gram
        ata[:, :n, n] = ata[:, n, :n] = self.zsum
        ata[:, n, n] = nr
        aty = np.concatenate([self.zty, np.asarray(self.ysum)[:, None]], axis=1)
        return ata, aty, yty, nr


def pi_gram(
    u: Any, thresholds: Any, y: Any, *, delays: Any = (0,), initial_state: Any = None,
    chunk_rows: int | None = None,
) -> GramStats:
    """Accumulate the normal equations of a P-I fit without the ``(N, n)`` regressor matrix.

    The operator outputs ``H_ri[u]`` (eq. 1, the columns of eq. 3's linear model) are computed
    a block of rows at a time, carrying the operator states from block to block, and only their
    products are kept: ``Z'Z``, ``Z'y``, ``Z'1``, ``1'y``, ``y'y`` for every delay at once (one
    pass over the data, whatever the number of delays). Up to 64 operators one compiled pass does
    it all: event-driven, a run of rows between two events (a reversal of the input, an operator
    starting to move) at a time, where those are sparse (smooth inputs), and in blocks of 64 rows
    elsewhere; with more operators, chunks of ``chunk_rows`` rows go through BLAS.
    Memory: at most one chunk (16 MiB by default) instead of ``8 N n`` bytes.

    Parameters
    ----------
    u, y : array_like, 1-D, same length N
        Input and measured output.
    thresholds : array_like, shape (n,)
        The operators' thresholds ``r_i`` (any order; ``>= 0``).
    delays : sequence of int
        Output delays ``d`` in samples (``0 <= d <= N - 2``): ``u[k]`` is paired with ``y[k + d]``.
    initial_state : array_like, shape (n,), optional
        The operators' initial states ``y0`` (eq. 2); default zeros, the de-energised actuator.
    chunk_rows : int, optional
        With more than 64 operators: rows of ``Z`` computed at once (default: 16 MiB worth).

    Returns
    -------
    GramStats
        One set of normal equations per delay, in the order given.

    Examples
    --------
    >>> import numpy as np, piezohyst as ph
    >>> from piezohyst.models.play import pi_gram
    >>> u = ph.sinusoid(1.0, 2, 0.0, 10.0, 1e-3); r = ph.equal_thresholds(4, 10.0)
    >>> g = pi_gram(u, r, 2 * u, delays=[0, 3])
    >>> z = ph.PrandtlIshlinskii(r, np.ones(4)).operator_outputs(u)
    >>> bool(np.allclose(g.gram[1], z[:-3].T @ z[:-3]) and np.allclose(g.zty[1], z[:-3].T @ (2 * u[3:])))
    True
    """
    us = as_signal("u", u, min_length=2)
    ys = as_signal("y", y, min_length=2)
    if us.size != ys.size:
        raise ValueError(f"u and y must have the same length, got {us.size} and {ys.size}")
    r = as_signal("thresholds", thresholds)
    if np.any(r < 0):
        raise ValueError(f"thresholds must be >= 0, got a minimum of {r.min()}")
    n, m = us.size, r.size
    if initial_state is None:
        z = np.zeros(m)
    else:
        z = np.array(as_signal("initial_state", initial_state))
        if z.size != m:
            raise ValueError(f"initial_state must have one entry per threshold: got {z.size} for {m}")
    d_arr = np.atleast_1d(np.asarray(delays))
    if d_arr.ndim != 1 or d_arr.size == 0 or not np.issubdtype(d_arr.dtype, np.integer):
        raise ValueError(f"delays must be a non-empty sequence of integers, got {delays!r}")
    if d_arr.min() < 0 or d_arr.max() > n - 2:
        raise ValueError(f"delays must lie in 0 .. {n - 2} (N - 2) for {n} samples, got {delays!r}")
    d_arr = d_arr.astype(np.int64)
    if chunk_rows is None:
        chunk_rows = default_chunk_rows(m)
    if isinstance(chunk_rows, bool) or not isinstance(chunk_rows, (int, np.integer)) or chunk_rows < 1:
        raise ValueError(f"chunk_rows must be a positive integer, got {chunk_rows!r}")
    return _gram_stats(us, r, ys, d_arr, z, int(chunk_rows))[0]


def _gram_stats(us: FloatArray, r: FloatArray, ys: FloatArray, d_arr: Any, z: FloatArray,
                chunk_rows: int) -> tuple[GramStats, FloatArray]:
    """:func:`pi_gram` on validated arrays (``z``: the initial states, overwritten), and the
    operators' states after the first ``N - max(delays)`` inputs (the rows every delay uses),
    from which a later stretch of the record can be continued."""
    n, m = us.size, r.size
    nd = d_arr.size
    dmax = int(d_arr.max())
    common = n - dmax  # rows every delay uses
    gram = np.zeros((m, m))
    zty = np.zeros((m, nd))
    zsum = np.zeros(m)
    if m <= _GRAM_COMPILED_MAX:
        # z carries the states on
        _gram_auto_into(us[:common], r, z, ys, d_arr, gram, zty, zsum, _GRAM_CHUNK, _GRAM_EVENT_ROWS)
        gram = np.triu(gram) + np.triu(gram, 1).T
    else:
        # one buffer, refilled chunk after chunk; column-major, which BLAS multiplies fastest
        buf = np.empty((min(chunk_rows, common), m), order="F")
        for a in range(0, common, chunk_rows):
            b = min(common, a + chunk_rows)
            zc = buf[: b - a]
            _play_outputs_into(us[a:b], r, z, zc, zsum)  # z carries the states on
            gram += zc.T @ zc
            zty += zc.T @ np.stack([ys[a + d:b + d] for d in d_arr], axis=1)
    # the last dmax rows belong to the smaller delays only (u[k] with y[k + d], k + d < N)
    at_common = z.copy()
    zt = play_outputs(us[common:], r, z) if dmax else np.empty((0, m))
    out_g = np.empty((nd, m, m))
    out_b = np.empty((nd, m))
    out_s = np.empty((nd, m))
    for i, d in enumerate(d_arr):
        extra = zt[: dmax - d]
        out_g[i] = gram + extra.T @ extra
        out_s[i] = zsum + extra.sum(axis=0)
        out_b[i] = zty[:, i] + extra.T @ ys[common + d: n]
    # sums over y[d:]: the whole record's, less its first d samples'
    ysum, yty = _y_sums(ys, d_arr)
    return GramStats(delays=d_arr, n_samples=n - d_arr, gram=out_g, zty=out_b, zsum=out_s,
                     ysum=ysum, yty=yty), at_common


@njit
def play_moves_both_ways(v: FloatArray, r: float) -> bool:  # pragma: no cover - compiled
    """Whether the play operator of threshold ``r``, from rest (``z = 0``), moves both up and down over ``v``."""
    z = 0.0
    up = down = False
    for x in v:
        if x - r > z:
            z = x - r
            up = True
        elif x + r < z:
            z = x + r
            down = True
        if up and down:
            return True
    return False


def largest_loop_threshold(v: FloatArray) -> float:
    """Half the largest loop the input ``v`` closes: the supremum of the play thresholds ``r`` whose
    operator (eq. (1), from rest) moves both up and down over ``v`` (:func:`play_moves_both_ways`
    for every smaller ``r``, for none larger), in one pass.

    A play operator of threshold ``r`` reverses only where the input travels ``2 r`` against its
    last direction. Over a record whose loops are all smaller than its span (a multisine, a random
    walk, small strokes around a working point) every operator above this threshold follows the
    input's running extreme and nothing else: their weights are not identified by the record, yet
    a full-stroke cycle reverses them. ``0`` for an input that never reverses.

    From rest (``z = 0``) the operator moves both ways exactly where the input rises above ``r``
    and falls below ``-r`` (in either order), or falls ``2 r`` below its running maximum once that
    is above ``r``, or rises ``2 r`` above its running minimum once that is below ``-r``: the
    supremum is the largest of those three bounds over the record.

    >>> largest_loop_threshold(np.array([0.0, 10.0, 4.0, 8.0]))  # the 10 -> 4 leg: a loop of 6
    3.0
    """
    x = np.ascontiguousarray(v, dtype=np.float64)
    return float(_largest_loop_threshold(x)) if x.size else 0.0


@njit
def _largest_loop_threshold(v: FloatArray) -> float:  # pragma: no cover - compiled
    hi = lo = v[0]  # the running maximum and minimum before the sample
    best = 0.0
    for i in range(1, v.shape[0]):
        x = v[i]
        fall = min(0.5 * (hi - x), hi)  # down 2 r from the running maximum, once above r
        rise = min(0.5 * (x - lo), -lo)  # up 2 r from the running minimum, once below -r
        if fall > best:
            best = fall
        if rise > best:
            best = rise
        if x > hi:
            hi = x
        if x < lo:
            lo = x
    both = min(max(hi, 0.0), max(-lo, 0.0))  # above r and below -r, in either order
    return max(best, both)
