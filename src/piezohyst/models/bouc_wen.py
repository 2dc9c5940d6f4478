"""The Bouc-Wen model of the paper's PSA-driven system, eqs. (7)-(8).

    m x'' + b x' + k x = k (d1 u - h)                                        (7)
    h'  = alpha d1 u' - beta |u'| h - gamma u' |h|                           (8)

Units are the paper's SI units: u in volts, x and h in metres, d1 in m/V, m in kg, b in N s/m,
k in N/m. Conversions to micrometres happen at the plant and data-set boundary, not here.

How it is computed, exactly and without an ODE solver:

* **h is rate independent.** Eq. (8) divided by u' gives dh/du, which on a monotone input
  increment of size ``lam = |du|`` and direction ``s = sign(du)`` is the *linear* ODE
  ``dh/dlam = s alpha d1 - (beta + gamma s sign(h)) h``. It is solved in closed form over the
  increment; if h changes sign inside it, the solution is continued from h = 0 with the other
  regime (:func:`bw_h_update`). No Euler step, no step-size error.
* **The linear part is integrated exactly for the input the hold defines.** The default hold is
  first-order (``hold="foh"``): the input ramps linearly between samples and ``x[k]`` is the
  displacement at the instant ``u[k]`` is reached, so output sample k lines up with input
  sample k as in the P-I model. Within a sample h is then ``h0 - kap S(s)`` with
  ``S(s) = (1 - exp(-mu s)) / mu`` (``mu = c |du|``), so the forcing ``d1 u - h`` of eq. (7) is
  affine plus an exponential in time. Its exact response is a combination of the transition
  matrix and the moments ``M_n = int_0^1 exp(A (1 - s)) B s^n / n! ds`` (:func:`foh_moments`,
  computed once per model and ``dt``): a short series in ``mu`` for ``|mu| < 1/16``
  (truncation below 6.4e-16 of the sample's h increment), a closed form with one ``expm1``
  above, and where h changes sign inside a sample the sample is split at the crossing and each
  part integrated with one small matrix exponential. ``hold="zoh"`` holds each sample for one
  period (a staircase D/A): u and h jump at the sample instant and the forcing is then constant,
  which the same transition matrix integrates exactly; x is reported at the end of the period.
  The two holds differ by about half a sample of delay (0.3 nm at 1 Hz, 0-100 V, 10 kHz).

Accuracy, measured (``tests/test_bouc_wen.py``) against :func:`solve_ivp_reference` (LSODA,
rtol 1e-11; halving its step moves it by <= 1.2e-13 m): the two agree within 1 pm (largest
difference seen 2.5e-13 m) on single 50 V steps, unipolar and bipolar staircases with jumps of
10-190 V, and 0-2 kHz chirps through the paper parameters' lightly damped (zeta = 0.0017)
1.70 kHz resonance (71-114 um responses), for gamma of either sign and larger than beta,
overdamped and critically damped variants and h0 != 0: the reference's own resolution. (The
earlier discretisation, which took the forcing as linear within each sample, was off by 35 nm
after one 50 V step and by 95 nm on a 3 um staircase.)
The cost is that of a handful of multiply-adds per sample on smooth input: polynomials only, no
transcendental function, except where ``|mu| >= 1/16`` (fast input) or h changes sign.

The model starts at rest and de-energised: ``u = 0``, ``h = h0`` (default 0), x at equilibrium.
"""

from __future__ import annotations

import itertools
import math
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from numba import get_num_threads
from numpy.typing import NDArray

from .._numba import njit
from .._validation import FloatArray, as_scalar, as_signal
from .base import need_dt, register_kind

IntArray = NDArray[np.intp]

Hold = Literal["foh", "zoh"]

# layout of the parameter vector shared by the kernels. Entries 0-12 keep the layout that
# :func:`mech_step` (and the virtual rig) read; 13-33 serve the exact first-order-hold step.
_P_D1, _P_AD1, _P_BETA, _P_GAMMA = 0, 1, 2, 3
_P_PHI = 4  # transition matrix, 4 entries, row-major
_P_OFFSET = 12
_P_FOH = 13  # 1.0: first-order hold, 0.0: zero-order hold
_P_W = 14  # w0 dt
_P_BD = 15  # (b / m) dt
_P_MOM = 16  # the moments M_0 .. M_NSER, two entries each (module docstring)
_NSER = 8  # _swarm_blocks writes the series out for this value
_P_LEN = _P_MOM + 2 * (_NSER + 1)
# |c du| below this: the moment series (truncation < 1e-15 relative, see _h_phi1); above it the
# closed form with one expm1
_THETA = 1.0 / 16.0
# layout of the state vector: previous input, h, x, scaled velocity, previous forcing
_S_LEN = 5
# 1/n!, n = 0 .. _NSER + 1
_INVFACT = np.array([1.0 / math.factorial(n) for n in range(_NSER + 2)])


@njit
def _h_phi1(mu: float) -> float:  # pragma: no cover - compiled
    """(1 - exp(-mu)) / mu = sum_{n>=1} (-mu)^(n-1) / n!: the series below _THETA.

    Truncated after _NSER terms the error is below _THETA**_NSER / (_NSER + 1)! = 6.4e-16
    (relative), so both branches agree to rounding.
    """
    if abs(mu) < _THETA:
        nm = -mu
        acc = _INVFACT[_NSER]
        for n in range(_NSER - 1, 0, -1):
            acc = acc * nm + _INVFACT[n]
        return acc
    return -math.expm1(-mu) / mu


@njit
def _crossing(h: float, kap: float, mu: float) -> float:  # pragma: no cover - compiled
    """Fraction s0 of an increment at which h(s) = h - kap (1 - exp(-mu s)) / mu reaches 0.

    Called only when it does (h and h(1) of opposite signs), so h / kap > 0 and
    1 - mu h / kap = exp(-mu s0) > 0.
    """
    q = h / kap
    xq = mu * q
    if abs(xq) < 1e-8:
        s0 = q * (1.0 + 0.5 * xq)
    else:
        s0 = -math.log1p(-xq) / mu
    return min(max(s0, 0.0), 1.0)


@njit
def _regime(h: float, s: float, ad1: float) -> float:  # pragma: no cover - compiled
    """The sign that selects eq. (8)'s regime over an increment of direction ``s``: the sign of h,
    or at h = 0 the direction the drive ``s * ad1`` pushes it."""
    if h > 0.0:
        return 1.0
    if h < 0.0:
        return -1.0
    return s if ad1 >= 0.0 else -s


@njit
def bw_h_update(h: float, du: float, ad1: float, beta: float, gamma: float) -> float:  # pragma: no cover
    """Exact solution of eq. (8) over one input increment ``du`` (rate independent).

    ``ad1`` is ``alpha * d1``. With ``lam = |du|``, ``s = sign(du)``, ``sig = sign(h)``:
    ``dh/dlam = a - c h``, ``a = s * ad1``, ``c = beta + gamma * s * sig``, whose solution is
    ``h(lam) = h - kap (1 - exp(-c lam)) / (c lam)`` with ``kap = c lam h - ad1 du``. If h
    reaches 0 within the increment (the end value has the other sign: h is monotone along
    it) the rest is solved in the other regime; the logarithm that locates the crossing is
    evaluated only then.
    """
    if du == 0.0:
        return h
    s = 1.0 if du > 0.0 else -1.0
    lam = abs(du)
    sig = _regime(h, s, ad1)
    mu = (beta + gamma * s * sig) * lam
    kap = mu * h - ad1 * du
    h1 = h - kap * _h_phi1(mu)
    if not sig * h1 < 0.0:
        return h1
    s0 = _crossing(h, kap, mu)
    rest = lam * (1.0 - s0)
    mu2 = (beta - gamma * s * sig) * rest
    return s * ad1 * rest * _h_phi1(mu2)


@njit
def _matmul(a: FloatArray, b: FloatArray, out: FloatArray) -> None:  # pragma: no cover - compiled
    n = a.shape[0]
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += a[i, k] * b[k, j]
            out[i, j] = acc


@njit
def expm_small(a: FloatArray) -> FloatArray:  # pragma: no cover - compiled
    """Matrix exponential of a small square matrix (scaling and squaring, Taylor series).

    Checked against ``scipy.linalg.expm`` in the tests; used where a kernel must discretise a
    model without leaving compiled code. A matrix with a non-finite entry gives all NaN.
    """
    n = a.shape[0]
    norm = 0.0
    for i in range(n):
        row = 0.0
        for j in range(n):
            row += abs(a[i, j])
        norm = max(norm, row)
    result = np.zeros((n, n))
    if not math.isfinite(norm):
        result[:, :] = np.nan
        return result
    s = 0
    if norm > 0.5:
        s = int(math.ceil(math.log2(norm / 0.5)))
    x = a / (2.0**s)
    term = np.zeros((n, n))
    tmp = np.empty((n, n))
    for i in range(n):
        result[i, i] = 1.0
        term[i, i] = 1.0
    for p in range(1, 24):
        _matmul(term, x, tmp)
        for i in range(n):
            for j in range(n):
                term[i, j] = tmp[i, j] / p
                result[i, j] += term[i, j]
    for _ in range(s):
        _matmul(result, result, tmp)
        result[:, :] = tmp
    return result


@njit
def foh_moments(w: float, bd: float, out: FloatArray) -> None:  # pragma: no cover - compiled
    """Transition matrix and input moments of the scaled linear part over one sample.

    The linear part of eq. (7) in ``z = (x, v / w0)`` and sample units is ``z' = A z + B f``
    with ``A = [[0, w], [-w, -bd]]``, ``B = (0, w)``, ``w = w0 dt``, ``bd = (b / m) dt``.
    Writes ``Phi = exp(A)`` (4 entries, row-major) to ``out[0:4]`` and the moments
    ``M_n = int_0^1 exp(A (1 - s)) B s^n / n! ds``, n = 0 .. N, to ``out[4 + 2n : 6 + 2n]``
    (N from the length of ``out``). Scaling and doubling: on a sub-interval ``tau = 2^-q`` with
    ``|A tau| <= 1/2`` the series ``M_n(tau) = tau^(n+1) sum_j (A tau)^j B / (j + n + 1)!``
    converges to rounding in under 20 terms; doubling uses
    ``M_n(2 tau) = Phi(tau) M_n(tau) + sum_k tau^(n-k) / (n-k)! M_k(tau)``.
    Checked against ``scipy.linalg.expm`` of the augmented matrix in the tests.
    """
    nm = (out.shape[0] - 4) // 2
    norm = max(abs(w), abs(w) + abs(bd))
    q = 0
    if norm > 0.5:
        q = int(math.ceil(math.log2(norm / 0.5)))
    tau = 2.0 ** (-q)
    a00, a01, a10, a11 = 0.0, w * tau, -w * tau, -bd * tau
    for n in range(nm):
        out[4 + 2 * n] = 0.0
        out[5 + 2 * n] = 0.0
    # Krylov vectors (A tau)^j B accumulated into the moments, and Phi(tau) = sum (A tau)^j / j!
    k0, k1 = 0.0, w
    p00, p01, p10, p11 = 1.0, 0.0, 0.0, 1.0
    t00, t01, t10, t11 = 1.0, 0.0, 0.0, 1.0
    scale = abs(w) + 1e-300
    lead = 1.0  # 1 / (j + 1)!
    j = 0
    while True:
        fact = lead
        for n in range(nm):  # += (A tau)^j B / (j + n + 1)!
            out[4 + 2 * n] += k0 * fact
            out[5 + 2 * n] += k1 * fact
            fact /= j + n + 2
        j += 1
        lead /= j + 1
        n0 = a00 * k0 + a01 * k1
        k1 = a10 * k0 + a11 * k1
        k0 = n0
        n00 = (t00 * a00 + t01 * a10) / j
        n01 = (t00 * a01 + t01 * a11) / j
        n10 = (t10 * a00 + t11 * a10) / j
        n11 = (t10 * a01 + t11 * a11) / j
        t00, t01, t10, t11 = n00, n01, n10, n11
        p00 += t00
        p01 += t01
        p10 += t10
        p11 += t11
        if j >= 40 or (abs(t00) + abs(t01) + abs(t10) + abs(t11) < 1e-18
                       and (abs(k0) + abs(k1)) * lead < 1e-18 * scale):
            break
    for n in range(nm):
        sc = tau ** (n + 1)
        out[4 + 2 * n] *= sc
        out[5 + 2 * n] *= sc
    for _ in range(q):
        for n in range(nm - 1, -1, -1):  # from the top: M_n(2 tau) needs the old M_k, k <= n
            s0 = p00 * out[4 + 2 * n] + p01 * out[5 + 2 * n]
            s1 = p10 * out[4 + 2 * n] + p11 * out[5 + 2 * n]
            c = 1.0
            for k in range(n, -1, -1):  # c = tau^(n-k) / (n-k)!
                s0 += c * out[4 + 2 * k]
                s1 += c * out[5 + 2 * k]
                c = c * tau / (n - k + 1)
            out[4 + 2 * n] = s0
            out[5 + 2 * n] = s1
        q00 = p00 * p00 + p01 * p10
        q01 = p00 * p01 + p01 * p11
        q10 = p10 * p00 + p11 * p10
        q11 = p10 * p01 + p11 * p11
        p00, p01, p10, p11 = q00, q01, q10, q11
        tau *= 2.0
    out[0] = p00
    out[1] = p01
    out[2] = p10
    out[3] = p11


@njit
def bw_params(
    m: float, b: float, k: float, d1: float, alpha: float, beta: float, gamma: float,
    offset: float, dt: float, foh: bool,
) -> FloatArray:  # pragma: no cover - compiled
    """Pack eqs. (7)-(8) into the kernel parameter vector, discretising the linear part.

    The state is ``(x, v / w0)`` with ``w0 = sqrt(k/m)``, which keeps the matrix well scaled.
    :func:`foh_moments` gives the transition matrix and the input moments over one sample
    (``M_0``: the zero-order hold term, ``M_1``: the ramp term, higher ones for the series of
    :func:`bw_step`). Entries 8-11 are the input terms :func:`mech_step` uses for a forcing
    linear (or, with ``foh=False``, constant) over the sample.
    """
    w0 = math.sqrt(k / m)
    p = np.zeros(_P_LEN)
    mom = np.empty(4 + 2 * (_NSER + 1))
    foh_moments(w0 * dt, (b / m) * dt, mom)
    p[0] = d1
    p[1] = alpha * d1
    p[2] = beta
    p[3] = gamma
    p[4] = mom[0]
    p[5] = mom[1]
    p[6] = mom[2]
    p[7] = mom[3]
    g0x, g0v, g1x, g1v = mom[4], mom[5], mom[6], mom[7]
    if foh:
        p[8] = g0x - g1x
        p[9] = g0v - g1v
        p[10] = g1x
        p[11] = g1v
    else:
        p[8] = 0.0
        p[9] = 0.0
        p[10] = g0x
        p[11] = g0v
    p[12] = offset
    p[_P_FOH] = 1.0 if foh else 0.0
    p[_P_W] = w0 * dt
    p[_P_BD] = (b / m) * dt
    for j in range(2 * (_NSER + 1)):
        p[_P_MOM + j] = mom[4 + j]
    return p


@njit
def bw_initial_state(h0: float) -> FloatArray:  # pragma: no cover - compiled
    """At rest, de-energised: u = 0, h = h0, x at its equilibrium -h0, no velocity."""
    st = np.empty(_S_LEN)
    st[0] = 0.0
    st[1] = h0
    st[2] = -h0
    st[3] = 0.0
    st[4] = -h0
    return st


@njit
def mech_step(p: FloatArray, st: FloatArray, f: float) -> float:  # pragma: no cover - compiled
    """The linear part of eq. (7) over one sample, driven by ``f = d1 u - h`` (metres).

    Exact for a forcing linear in time over the sample (constant with ``foh=False``): the
    forcing's previous value is ``st[4]``. Updates ``st[2:5]`` (x, scaled velocity, previous
    forcing) and returns x without offset. The virtual rig drives it with its own forcing;
    :func:`bw_step` uses the exact step for the Bouc-Wen forcing instead.
    """
    x = st[2]
    v = st[3]
    fp = st[4]
    xn = p[4] * x + p[5] * v + p[8] * fp + p[10] * f
    st[3] = p[6] * x + p[7] * v + p[9] * fp + p[11] * f
    st[2] = xn
    st[4] = f
    return xn


@njit
def _piece(w: float, bd: float, x: float, v: float, f0: float, f1: float, kap: float,
           mu: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """(x, v) after one unit of time of ``z' = A z + B f``, ``A = [[0, w], [-w, -bd]]``,
    ``B = (0, w)``, forcing ``f0 + f1 s + kap (1 - exp(-mu s)) / mu``.

    One matrix exponential of the system augmented with the forcing's generator
    ``S' = 1 - mu S``, ``s' = 1``: exact for any mu (no division by it). The fallback of
    :func:`_unit_response` where its closed form would be ill-conditioned.
    """
    g = np.zeros((5, 5))
    g[0, 1] = w
    g[1, 0] = -w
    g[1, 1] = -bd
    g[1, 2] = kap * w
    g[1, 3] = f1 * w
    g[1, 4] = f0 * w
    g[2, 2] = -mu
    g[2, 4] = 1.0
    g[3, 4] = 1.0
    e = expm_small(g)
    return e[0, 0] * x + e[0, 1] * v + e[0, 4], e[1, 0] * x + e[1, 1] * v + e[1, 4]


@njit
def _unit_response(a: FloatArray, po: int, mo: int, w: float, bd: float, x: float, v: float, f0: float,
                   f1: float, kap: float, mu: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """(x, v) after one unit of time of the system of :func:`_piece` with the same forcing, from
    its transition matrix ``a[po:po+4]`` and moments ``M_n = a[mo+2n : mo+2n+2]``:
    ``Phi z + f0 M_0 + f1 M_1 + kap T(mu)``, ``T`` by its series below ``_THETA``, else in closed
    form ``(M_0 - (A + mu I)^-1 (Phi - exp(-mu) I) B) / mu`` (or by :func:`_piece` where that
    would lose digits)."""
    if abs(mu) < _THETA:
        nm = -mu
        t0 = a[mo + 2 * _NSER]
        t1 = a[mo + 2 * _NSER + 1]
        for n in range(_NSER - 1, 0, -1):
            t0 = t0 * nm + a[mo + 2 * n]
            t1 = t1 * nm + a[mo + 2 * n + 1]
    else:
        # smallest |eigenvalue| of A + mu I: the closed form loses digits ~ eps / that
        qd = 0.25 * bd * bd - w * w
        sh = mu - 0.5 * bd
        if qd < 0.0:
            nu = math.sqrt(sh * sh - qd)
        else:
            r = math.sqrt(qd)
            nu = min(abs(sh + r), abs(sh - r))
        if not nu > 1e-3:
            return _piece(w, bd, x, v, f0, f1, kap, mu)
        e = math.exp(-mu)
        det = mu * (mu - bd) + w * w
        b0 = a[po + 1] * w
        b1 = (a[po + 3] - e) * w
        e0 = ((mu - bd) * b0 - w * b1) / det
        e1 = (w * b0 + mu * b1) / det
        t0 = (a[mo] - e0) / mu
        t1 = (a[mo + 1] - e1) / mu
    xn = (f0 * a[mo] + f1 * a[mo + 2] + kap * t0) + (a[po] * x + a[po + 1] * v)
    vn = (f0 * a[mo + 1] + f1 * a[mo + 3] + kap * t1) + (a[po + 2] * x + a[po + 3] * v)
    return xn, vn


@njit
def _series(p: FloatArray, mu: float) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """For ``|mu| < _THETA``: ``phi1(mu) = (1 - exp(-mu)) / mu`` and the two entries of
    ``T(mu) = sum_{n>=1} (-mu)^(n-1) M_n`` (see :func:`_foh_common`), by Horner's rule."""
    nm = -mu
    phi = _INVFACT[_NSER]
    t0 = p[_P_MOM + 2 * _NSER]
    t1 = p[_P_MOM + 2 * _NSER + 1]
    for n in range(_NSER - 1, 0, -1):
        phi = phi * nm + _INVFACT[n]
        t0 = t0 * nm + p[_P_MOM + 2 * n]
        t1 = t1 * nm + p[_P_MOM + 2 * n + 1]
    return phi, t0, t1


@njit
def _foh_common(p: FloatArray, u0: float, h: float, x: float, v: float, du: float) -> tuple[bool, float, float, float]:  # pragma: no cover
    """Eqs. (7)-(8) over one sample of input ramping from ``u0`` by ``du``: (h, x, v) at its end.

    Exact (to rounding) for the piecewise-linear input: within the sample
    ``h(s) = h - kap S(s)``, ``S(s) = (1 - exp(-mu s)) / mu`` (eq. 8 solved in closed form), so the
    forcing of eq. (7) is ``(d1 u0 - h) + d1 du s + kap S(s)``, whose response is
    ``Phi z + (d1 u0 - h) M_0 + d1 du M_1 + kap T(mu)`` with
    ``T(mu) = int_0^1 exp(A (1 - s)) B S(s) ds = sum_{n>=1} (-mu)^(n-1) M_n`` (a series for
    ``|mu| < _THETA``) ``= (M_0 - (A + mu I)^-1 (Phi - exp(-mu) I) B) / mu`` (otherwise). If h
    changes sign inside the sample, the sample is split at the crossing (module docstring).
    This function takes the common case (``|mu| < _THETA`` in both regimes, no sign change) and
    returns ``(True, h, x, v)``, or ``(False, ...)`` and the caller calls :func:`_foh_general`;
    kept small so that it is inlined into the loops. The series of both regimes are evaluated
    before the sign of h is looked at, so in a sequential loop they stay off the
    sample-to-sample dependency chain.
    """
    ad1 = p[1]
    s = 1.0 if du >= 0.0 else -1.0
    lam = abs(du)
    mu_p = (p[2] + p[3] * s) * lam  # h > 0
    mu_m = (p[2] - p[3] * s) * lam  # h < 0
    ok = abs(mu_p) < _THETA and abs(mu_m) < _THETA
    if ok:
        phi_p, t0_p, t1_p = _series(p, mu_p)
        if p[3] == 0.0:
            phi_m, t0_m, t1_m = phi_p, t0_p, t1_p
        else:
            phi_m, t0_m, t1_m = _series(p, mu_m)
        # regime: the sign of h, or at h = 0 the direction the drive s * ad1 pushes it
        pos = (h > 0.0) | ((h == 0.0) & ((du >= 0.0) == (ad1 >= 0.0)))
        mu = mu_p if pos else mu_m
        phi = phi_p if pos else phi_m
        t0 = t0_p if pos else t0_m
        t1 = t1_p if pos else t1_m
        kap = mu * h - ad1 * du
        h1 = h - kap * phi
        ok = ((h1 >= 0.0) == pos) | (h1 == 0.0)  # no sign change inside the sample
    if ok:
        f0 = p[0] * u0 - h
        f1 = p[0] * du
        xn = (f0 * p[_P_MOM] + f1 * p[_P_MOM + 2] + kap * t0) + (p[4] * x + p[5] * v)
        vn = (f0 * p[_P_MOM + 1] + f1 * p[_P_MOM + 3] + kap * t1) + (p[6] * x + p[7] * v)
        return True, h1, xn, vn
    return False, h, x, v


@njit
def _foh_general(p: FloatArray, u0: float, h: float, x: float, v: float, du: float) -> tuple[float, float, float]:  # pragma: no cover
    """:func:`_foh_common` for any increment: series or closed form, split at a sign change of h.

    A part of a sample of length ``tau`` is a unit step of the same system with ``w tau``,
    ``bd tau`` and the forcing's slope, ``kap`` and ``mu`` times ``tau``; its transition matrix
    and moments come from :func:`foh_moments`.
    """
    ad1 = p[1]
    d1 = p[0]
    w = p[_P_W]
    bd = p[_P_BD]
    s = 1.0 if du >= 0.0 else -1.0
    lam = abs(du)
    sig = _regime(h, s, ad1)
    mu = (p[2] + p[3] * s * sig) * lam
    kap = mu * h - ad1 * du
    f0 = d1 * u0 - h
    f1 = d1 * du
    h1 = h - kap * _h_phi1(mu)
    if not sig * h1 < 0.0:
        x, v = _unit_response(p, _P_PHI, _P_MOM, w, bd, x, v, f0, f1, kap, mu)
        return h1, x, v
    # h changes sign inside the sample: split it at the crossing
    s0 = _crossing(h, kap, mu)
    mom = np.empty(4 + 2 * (_NSER + 1))
    foh_moments(w * s0, bd * s0, mom)
    x, v = _unit_response(mom, 0, 4, w * s0, bd * s0, x, v, f0, f1 * s0, kap * s0, mu * s0)
    rest = 1.0 - s0
    mu2 = (p[2] - p[3] * s * sig) * lam
    kap2 = -ad1 * du
    foh_moments(w * rest, bd * rest, mom)
    x, v = _unit_response(mom, 0, 4, w * rest, bd * rest, x, v, d1 * (u0 + du * s0), f1 * rest, kap2 * rest,
                          mu2 * rest)
    h1 = -kap2 * rest * _h_phi1(mu2 * rest)
    return h1, x, v


@njit
def bw_step(p: FloatArray, st: FloatArray, u: float) -> float:  # pragma: no cover - compiled
    """One sample of eqs. (7)-(8): update the state ``st`` in place, return x (m) + offset."""
    if p[_P_FOH] != 0.0:
        ok, h, x, v = _foh_common(p, st[0], st[1], st[2], st[3], u - st[0])
        if not ok:
            h, x, v = _foh_general(p, st[0], h, x, v, u - st[0])
        st[0] = u
        st[1] = h
        st[2] = x
        st[3] = v
        st[4] = p[0] * u - h
        return x + p[12]
    # zero-order hold: the input (and with it h) jumps at the start of the sample, then the
    # forcing is constant, which mech_step integrates exactly
    h = bw_h_update(st[1], u - st[0], p[1], p[2], p[3])
    st[0] = u
    st[1] = h
    return mech_step(p, st, p[0] * u - h) + p[12]


@njit
def bw_simulate(p: FloatArray, st: FloatArray, u: FloatArray) -> FloatArray:  # pragma: no cover
    """:func:`bw_step` over a whole signal (the state kept in registers, written back at the end)."""
    n = u.shape[0]
    out = np.empty(n)
    if p[_P_FOH] == 0.0:
        for k in range(n):
            out[k] = bw_step(p, st, u[k])
        return out
    up, h, x, v = st[0], st[1], st[2], st[3]
    off = p[12]
    for k in range(n):
        uk = u[k]
        ok, h, x, v = _foh_common(p, up, h, x, v, uk - up)
        if not ok:
            h, x, v = _foh_general(p, up, h, x, v, uk - up)
        up = uk
        out[k] = x + off
    st[0] = up
    st[1] = h
    st[2] = x
    st[3] = v
    st[4] = p[0] * up - h
    return out


@njit
def bw_hysteresis(u: FloatArray, h0: float, ad1: float, beta: float, gamma: float) -> FloatArray:  # pragma: no cover
    """h alone (eq. 8) over a signal, from the de-energised state ``u = 0, h = h0``."""
    out = np.empty(u.shape[0])
    h = h0
    up = 0.0
    for k in range(u.shape[0]):
        h = bw_h_update(h, u[k] - up, ad1, beta, gamma)
        up = u[k]
        out[k] = h
    return out


def _check_hold(hold: str) -> bool:
    if hold not in ("foh", "zoh"):
        raise ValueError(f"hold must be 'foh' or 'zoh', got {hold!r}")
    return hold == "foh"


@register_kind("bouc-wen", "bw", "boucwen")
@dataclass(frozen=True)
class BoucWen:
    """The paper's Bouc-Wen model of a piezo stack driving a flexure, eqs. (7)-(8).

    Parameters
    ----------
    m : float
        Inertia, kg (> 0). Paper: 0.75.
    b : float
        Damping, N s/m (>= 0). Paper: 27.96.
    k : float
        Stiffness, N/m (> 0). Paper: 8.54e7.
    d1 : float
        Piezoelectric constant, m/V (> 0). Paper: 2.15e-8.
    alpha, beta, gamma : float
        Loop magnitude and shape. Paper: 0.472, 0.072, 0. ``beta`` and ``gamma`` are in 1/V.
    offset : float
        Added to the displacement, m (a sensor zero; 0 in the paper).
    h0 : float
        Initial hysteresis state, m (0: de-energised).

    Examples
    --------
    >>> import piezohyst as ph, numpy as np
    >>> bw = ph.BoucWen(m=0.75, b=27.96, k=8.54e7, d1=2.15e-8, alpha=0.472, beta=0.072, gamma=0.0)
    >>> round(bw.natural_frequency_hz)  # sqrt(8.54e7 / 0.75) / (2 pi): the paper's "1.7 kHz"
    1698
    """

    m: float
    b: float
    k: float
    d1: float
    alpha: float
    beta: float
    gamma: float = 0.0
    offset: float = 0.0
    h0: float = 0.0

    def __post_init__(self) -> None:
        for name in ("m", "k", "d1"):
            object.__setattr__(self, name, as_scalar(name, getattr(self, name), positive=True))
        object.__setattr__(self, "b", as_scalar("b", self.b, nonnegative=True))
        for name in ("alpha", "beta", "gamma", "offset", "h0"):
            object.__setattr__(self, name, as_scalar(name, getattr(self, name)))

    # -- derived figures ------------------------------------------------------------------
    @property
    def natural_frequency_hz(self) -> float:
        """Undamped natural frequency sqrt(k/m) / 2 pi, Hz."""
        return math.sqrt(self.k / self.m) / (2 * math.pi)

    @property
    def damping_ratio(self) -> float:
        """b / (2 sqrt(k m))."""
        return self.b / (2 * math.sqrt(self.k * self.m))

    def parameters(self) -> dict[str, float]:
        """The seven parameters of eqs. (7)-(8) (plus offset and h0) as a dict."""
        return {
            "m": self.m, "b": self.b, "k": self.k, "d1": self.d1, "alpha": self.alpha,
            "beta": self.beta, "gamma": self.gamma, "offset": self.offset, "h0": self.h0,
        }

    def kernel_params(self, dt: float, hold: Hold = "foh") -> FloatArray:
        """The packed, discretised parameter vector the compiled kernels take."""
        dt = as_scalar("dt", dt, positive=True)
        foh = _check_hold(hold)
        return bw_params(self.m, self.b, self.k, self.d1, self.alpha, self.beta, self.gamma,
                         self.offset, dt, foh)

    # -- simulation -----------------------------------------------------------------------
    def simulate(self, u: Any, dt: float, *, hold: Hold = "foh") -> FloatArray:
        """Displacement x (metres, plus ``offset``) for the voltage signal ``u`` sampled every ``dt`` s."""
        x = as_signal("u", u)
        p = self.kernel_params(dt, hold)
        return bw_simulate(p, bw_initial_state(self.h0), x)

    def hysteresis(self, u: Any) -> FloatArray:
        """The hysteresis state h of eq. (8), metres. Rate independent: no ``dt``."""
        x = as_signal("u", u)
        return bw_hysteresis(x, self.h0, self.alpha * self.d1, self.beta, self.gamma)

    def quasi_static(self, u: Any) -> FloatArray:
        """``d1 u - h + offset``, metres: eq. (7) with the dynamics settled."""
        x = as_signal("u", u)
        return self.d1 * x - self.hysteresis(x) + self.offset

    def stepper(self, dt: float, *, hold: Hold = "foh") -> "BoucWenStepper":
        """A streaming simulator on the same kernel as :meth:`simulate`."""
        return BoucWenStepper(self, dt, hold=hold)

    # -- the model protocol (piezohyst.models.base) ---------------------------------------------
    kind: ClassVar[str]
    output_unit: ClassVar[str] = "m"
    dynamic: ClassVar[bool] = True

    @property
    def steepest_hysteresis_slope(self) -> float:
        """The largest ``dh/du`` of eq. (8) on any branch, over ``d1``: ``alpha max(1, 2 beta /
        (beta + gamma))`` (a branch that starts at the far end of the loop, ``|h| = alpha d1 /
        (beta + gamma)``, after a reversal; inf where the loop is unbounded). Below 1 the
        quasi-static output ``d1 u - h`` rises with ``u`` on every branch."""
        if not self.beta + self.gamma > 0.0:
            return math.inf
        return float(self.alpha * max(1.0, 2.0 * self.beta / (self.beta + self.gamma)))

    @property
    def is_invertible(self) -> bool:
        """True when eq. (10)'s per-sample solve has one answer: the loop is bounded and its
        quasi-static output rises on every branch (:attr:`steepest_hysteresis_slope` < 1). With
        beta = 0.07, gamma = -0.02 /V and alpha = 0.95 (fuzzing) the output fell along part of a
        branch, the solve stopped unconverged and the exported C code and Python differed by 96 V."""
        return self.steepest_hysteresis_slope < 1.0

    def predict(self, u: Any, dt: float | None = None) -> FloatArray:
        """The displacement in µm (the protocol's common unit): ``simulate(u, dt) * 1e6``."""
        return self.simulate(u, need_dt(dt, self.kind)) * 1e6

    def compensator(self, dt: float | None = None, *, u_range: Any = None,
                    max_slew: float | None = None) -> Any:
        """The hysteresis-estimate feedforward of eq. (10) (rate independent: ``dt`` unused).
        Refused where the loop is unbounded (``beta + gamma <= 0``: :meth:`check_bounded`) or its
        output falls along a branch (:meth:`check_monotone`)."""
        from .bouc_wen_inverse import BoucWenFeedforward

        if dt is not None:  # unused, but checked as every kind checks it (dt=-1 passed: found by fuzzing)
            as_scalar("dt", dt, positive=True)
        self.check_bounded()
        self.check_monotone()
        return BoucWenFeedforward(self, u_range=u_range, max_slew=max_slew)

    def check_monotone(self) -> None:
        """Raise ValueError unless the quasi-static output rises on every branch (:attr:`is_invertible`)."""
        slope = self.steepest_hysteresis_slope
        if not slope < 1.0:
            raise ValueError(f"the Bouc-Wen loop is not monotone: its output falls along part of a branch after a "
                             f"reversal (alpha max(1, 2 beta / (beta + gamma)) = {slope:.4g} >= 1 with "
                             f"alpha={self.alpha:g}, beta={self.beta:g}, gamma={self.gamma:g} 1/V), where eq. (10) "
                             f"has no unique command")

    def check_bounded(self) -> None:
        """Raise ValueError unless ``beta + gamma > 0``: on a long monotone input eq. (8) takes h
        towards ``alpha d1 / (beta + gamma)``; with ``beta + gamma <= 0`` it grows without bound,
        and the feedforward's commands became NaN (found by fuzzing: a model file with gamma = -1,
        and a command table of NaN written without a word)."""
        if not self.beta + self.gamma > 0.0:
            raise ValueError(f"the Bouc-Wen loop is unbounded: beta + gamma must be > 0 (eq. 8: |h| tends to "
                             f"alpha d1 / (beta + gamma)), got beta={self.beta:g}, gamma={self.gamma:g} 1/V")

    def to_dict(self) -> dict[str, float]:
        """The seven parameters of eqs. (7)-(8), the offset and h0, in SI units (plain data)."""
        return self.parameters()

    @classmethod
    def from_dict(cls, params: dict[str, Any]) -> "BoucWen":
        """Rebuild the model from :meth:`to_dict`'s data; unknown names are refused."""
        names = ("m", "b", "k", "d1", "alpha", "beta", "gamma", "offset", "h0")
        missing = [n for n in names[:6] if n not in params]
        if missing:
            raise KeyError(missing[0])
        unknown = set(params) - set(names)
        if unknown:
            raise ValueError(f"unknown Bouc-Wen parameter(s) {sorted(unknown)}")
        model = cls(**{n: params[n] for n in names if n in params})
        model.check_bounded()  # a file is data: refused as it loads, not when its commands are NaN
        return model

    def _repr_html_(self) -> str:
        """An HTML summary for Jupyter: kind, units, invertibility, parameters."""
        from .._html import model_html

        return model_html(self)


def solve_ivp_reference(model: BoucWen, u: Any, dt: float, *, method: str = "LSODA", rtol: float = 1e-10,
                        max_step: float | None = None) -> tuple[FloatArray, FloatArray]:
    """An independent, slow reference for eqs. (7)-(8): (x, h) in metres at the sample instants.

    One ODE in (x, v, h) with the input linear between samples (the first-order hold of
    :meth:`BoucWen.simulate`), integrated by ``scipy.integrate.solve_ivp`` with steps no longer
    than ``max_step`` (default ``dt``). For checks and benchmarks, not for work:
    :meth:`BoucWen.simulate` computes the same thousands of times faster. Check its
    convergence by halving ``max_step`` and tightening ``rtol``.
    """
    from scipy.integrate import solve_ivp

    # the kernels' first sample ramps from the de-energised state u = 0, h = h0
    x = np.concatenate([[0.0], as_signal("u", u, min_length=2)])
    t = np.arange(x.size) * dt
    slopes = np.diff(x) / dt
    m = model

    def rhs(tt: float, s: FloatArray) -> list[float]:
        _, v, h = s
        i = min(int(tt / dt), x.size - 2)
        du = slopes[i]
        uu = x[i] + du * (tt - t[i])
        dh = m.alpha * m.d1 * du - m.beta * abs(du) * h - m.gamma * du * abs(h)
        return [v, (m.k * (m.d1 * uu - h) - m.b * v - m.k * s[0]) / m.m, dh]

    sol = solve_ivp(rhs, (0.0, t[-1]), [-m.h0, 0.0, m.h0], method=method, t_eval=t, rtol=rtol,
                    atol=[1e-16, 1e-12, 1e-16], max_step=dt if max_step is None else max_step)
    if not sol.success:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    return sol.y[0, 1:] + m.offset, sol.y[2, 1:]


class BoucWenStepper:
    """Streaming Bouc-Wen simulation: ``step(u_k)`` returns x (metres) at sample k."""

    __slots__ = ("model", "dt", "_p", "_st")

    def __init__(self, model: BoucWen, dt: float, *, hold: Hold = "foh"):
        self.model = model
        self.dt = as_scalar("dt", dt, positive=True)
        self._p = model.kernel_params(self.dt, hold)
        self._st = bw_initial_state(model.h0)

    def reset(self) -> None:
        """Back to rest, de-energised."""
        self._st[:] = bw_initial_state(self.model.h0)

    @property
    def h(self) -> float:
        """Current hysteresis state, metres."""
        return float(self._st[1])

    def step(self, u_k: float) -> float:
        """Apply ``u_k`` (V) for one sample; return the displacement (m)."""
        x = float(u_k)
        if not math.isfinite(x):
            raise ValueError(f"u_k must be finite, got {u_k!r}")
        return float(bw_step(self._p, self._st, x))


# ------------------------------------------------------------------------------------------------
# whole-swarm evaluation for identification (paper eq. 9): time in the outer loop and particles
# in the inner one. The particles are packed in blocks of _LANES, each block
# one row of a 2-D array holding its parameters and states at fixed offsets, so that the common
# path (polynomials only) of all particles of a block runs as one vectorised loop.
_POOL: list[tuple[int, ThreadPoolExecutor]] = []
_POOL_LOCK = threading.Lock()


def _pool(n: int) -> ThreadPoolExecutor:
    """One executor of at least ``n`` threads, created on first use (the kernels release the GIL)."""
    with _POOL_LOCK:
        if not _POOL or _POOL[0][0] < n:
            if _POOL:
                _POOL.pop()[1].shutdown(wait=False)
            _POOL.append((n, ThreadPoolExecutor(max_workers=n, thread_name_prefix="piezohyst-bw")))
        return _POOL[0][1]

_LANES = 8
_R_H, _R_X, _R_V, _R_S1, _R_S2, _R_FLAG = range(_P_LEN, _P_LEN + 6)
_ROWS = _P_LEN + 6


@njit
def _swarm_blocks(w: FloatArray, p_all: FloatArray, first: int, u: FloatArray, y: FloatArray,
                  scale: float) -> None:  # pragma: no cover - compiled
    """Simulate the particles of the blocks ``w`` (rows: see ``_R_*``; particle ``first + i`` of
    ``p_all`` is lane ``i % _LANES`` of block ``i // _LANES``) and sum their residuals.

    Per sample and block, one branch-free loop takes the common path of :func:`_foh_common`
    (first-order hold, ``|mu| < _THETA``, no sign change of h) for all lanes, with the same
    operations except that the series is evaluated by Estrin's scheme (shorter dependency chains;
    the results agree to rounding), and keeps the old state of the lanes it flags; those are
    then stepped by :func:`_foh_general`. A lane whose state stops being finite is parked at rest
    with NaN sums. Zero-order hold: every lane by :func:`bw_h_update` and the constant-forcing step.
    """
    L = _LANES
    nb = w.shape[0]
    c1, c2, c3, c4 = _INVFACT[1], _INVFACT[2], _INVFACT[3], _INVFACT[4]
    c5, c6, c7, c8 = _INVFACT[5], _INVFACT[6], _INVFACT[7], _INVFACT[8]
    m = _P_MOM * L
    oh, ox, ov, o1, o2, of = _R_H * L, _R_X * L, _R_V * L, _R_S1 * L, _R_S2 * L, _R_FLAG * L
    foh = p_all[0, _P_FOH] != 0.0
    up = 0.0
    for j in range(u.shape[0]):
        du = u[j] - up
        s = 1.0 if du >= 0.0 else -1.0
        lam = abs(du)
        yj = y[j]
        for b in range(nb):
            nrare = 0
            if foh:
                for i in range(L):
                    h0 = w[b, oh + i]
                    ad1 = w[b, L + i]
                    sd = s if ad1 >= 0.0 else -s
                    sig = 1.0 if h0 > 0.0 else (-1.0 if h0 < 0.0 else sd)
                    mu = (w[b, 2 * L + i] + w[b, 3 * L + i] * s * sig) * lam
                    rare = not (abs(mu) < _THETA)
                    nm = 0.0 if rare else -mu
                    n2 = nm * nm
                    n4 = n2 * n2
                    kap = mu * h0 - ad1 * du
                    phi = ((c1 + c2 * nm) + n2 * (c3 + c4 * nm)) + n4 * ((c5 + c6 * nm) + n2 * (c7 + c8 * nm))
                    t0 = (((w[b, m + 2 * L + i] + w[b, m + 4 * L + i] * nm)
                           + n2 * (w[b, m + 6 * L + i] + w[b, m + 8 * L + i] * nm))
                          + n4 * ((w[b, m + 10 * L + i] + w[b, m + 12 * L + i] * nm)
                                  + n2 * (w[b, m + 14 * L + i] + w[b, m + 16 * L + i] * nm)))
                    t1 = (((w[b, m + 3 * L + i] + w[b, m + 5 * L + i] * nm)
                           + n2 * (w[b, m + 7 * L + i] + w[b, m + 9 * L + i] * nm))
                          + n4 * ((w[b, m + 11 * L + i] + w[b, m + 13 * L + i] * nm)
                                  + n2 * (w[b, m + 15 * L + i] + w[b, m + 17 * L + i] * nm)))
                    h1 = h0 - kap * phi
                    rare = rare | (sig * h1 < 0.0)
                    f0 = w[b, i] * up - h0
                    f1 = w[b, i] * du
                    xi = w[b, ox + i]
                    vi = w[b, ov + i]
                    xn = (f0 * w[b, m + i] + f1 * w[b, m + 2 * L + i] + kap * t0) + (w[b, 4 * L + i] * xi + w[b, 5 * L + i] * vi)
                    vn = (f0 * w[b, m + L + i] + f1 * w[b, m + 3 * L + i] + kap * t1) + (w[b, 6 * L + i] * xi + w[b, 7 * L + i] * vi)
                    r = (yj - xn) * scale
                    w[b, o1 + i] += 0.0 if rare else r
                    w[b, o2 + i] += 0.0 if rare else r * r
                    w[b, oh + i] = h0 if rare else h1
                    w[b, ox + i] = xi if rare else xn
                    w[b, ov + i] = vi if rare else vn
                    w[b, of + i] = 1.0 if rare else 0.0
                    nrare += rare
            else:
                for i in range(L):
                    h1 = bw_h_update(w[b, oh + i], du, w[b, L + i], w[b, 2 * L + i], w[b, 3 * L + i])
                    f = w[b, i] * u[j] - h1
                    xi = w[b, ox + i]
                    vi = w[b, ov + i]
                    xn = w[b, 4 * L + i] * xi + w[b, 5 * L + i] * vi + w[b, 10 * L + i] * f
                    w[b, ov + i] = w[b, 6 * L + i] * xi + w[b, 7 * L + i] * vi + w[b, 11 * L + i] * f
                    w[b, ox + i] = xn
                    w[b, oh + i] = h1
                    r = (yj - xn) * scale
                    w[b, o1 + i] += r
                    w[b, o2 + i] += r * r
                    w[b, of + i] = 0.0 if (abs(xn) < 1e300 and abs(h1) < 1e300) else 1.0
                    nrare += w[b, of + i] != 0.0
            if nrare > 0:
                for i in range(L):
                    if w[b, of + i] == 0.0:
                        continue
                    h0 = w[b, oh + i]
                    xi = w[b, ox + i]
                    vi = w[b, ov + i]
                    if foh and abs(h0) < 1e300 and abs(xi) < 1e300 and abs(vi) < 1e300:
                        h1, xn, vn = _foh_general(p_all[first + b * L + i], up, h0, xi, vi, du)
                        r = (yj - xn) * scale
                        w[b, o1 + i] += r
                        w[b, o2 + i] += r * r
                    else:
                        h1, xn, vn = h0, xi, vi
                    if not (abs(h1) < 1e300 and abs(xn) < 1e300 and abs(vn) < 1e300):
                        h1, xn, vn = 0.0, 0.0, 0.0  # diverged: parked at rest, its sums NaN
                        w[b, o1 + i] = np.nan
                    w[b, oh + i] = h1
                    w[b, ox + i] = xn
                    w[b, ov + i] = vn
        up = u[j]


def bw_swarm_rmse(
    theta: FloatArray, u: FloatArray, y: FloatArray, dt: float, foh: bool, fit_offset: bool,
    scale: float,
) -> FloatArray:
    """RMSE (eq. 9) of every particle ``theta[i] = (m, b, k, d1, alpha, beta, gamma)``.

    Residuals are multiplied by ``scale`` (1e6: metres to micrometres) before they are summed.
    With ``fit_offset`` the best constant offset is removed analytically (the RMSE is then the
    residual's standard deviation). Invalid or diverging particles get +inf. The particles are
    simulated with the step of :meth:`BoucWen.simulate` (equal to rounding), in blocks of
    ``_LANES``, spread over as many threads as numba is set to use (``numba.set_num_threads``).
    """
    th = np.ascontiguousarray(theta, dtype=np.float64)
    idx, p_all, w = _swarm_pack(th, float(dt), bool(foh))
    nb = w.shape[0]
    n_chunks = max(1, min(nb, get_num_threads()))
    if n_chunks == 1:
        if nb:
            _swarm_blocks(w, p_all, 0, u, y, float(scale))
    else:  # groups of blocks on threads: the compiled kernel releases the GIL
        cuts = [c * nb // n_chunks for c in range(n_chunks + 1)]
        parts = [np.ascontiguousarray(w[lo:hi]) for lo, hi in itertools.pairwise(cuts)]
        jobs = [_pool(n_chunks).submit(_swarm_blocks, part, p_all, lo * _LANES, u, y, float(scale))
                for part, lo in zip(parts, cuts[:-1])]
        for job in jobs:
            job.result()
        w = np.concatenate(parts)
    return _swarm_finish(w, idx, th.shape[0], u.shape[0], bool(fit_offset))


@njit
def _swarm_pack(theta: FloatArray, dt: float, foh: bool) -> tuple[IntArray, FloatArray, FloatArray]:  # pragma: no cover
    """The valid particles' indices, their parameter vectors (padded to whole blocks with copies
    of the last one, whose results are unused) and the blocks of :func:`_swarm_blocks`."""
    n_p = theta.shape[0]
    valid = np.zeros(n_p, dtype=np.bool_)
    for i in range(n_p):
        ok = theta[i, 0] > 0.0 and theta[i, 2] > 0.0 and theta[i, 1] >= 0.0 and theta[i, 3] > 0.0
        for j in range(7):
            ok = ok and math.isfinite(theta[i, j])
        valid[i] = ok
    idx = np.nonzero(valid)[0]
    nv = idx.size
    L = _LANES
    nb = (nv + L - 1) // L
    p_all = np.empty((nb * L, _P_LEN))
    for c in range(nb * L):
        i = idx[c] if c < nv else idx[nv - 1]
        p_all[c] = bw_params(theta[i, 0], theta[i, 1], theta[i, 2], theta[i, 3], theta[i, 4], theta[i, 5],
                             theta[i, 6], 0.0, dt, foh)
    w = np.zeros((nb, _ROWS * L))
    for b in range(nb):
        for i in range(L):
            for r in range(_P_LEN):
                w[b, r * L + i] = p_all[b * L + i, r]
    return idx, p_all, w


@njit
def _swarm_finish(w: FloatArray, idx: IntArray, n_p: int, n: int, fit_offset: bool) -> FloatArray:  # pragma: no cover
    """RMSE per particle from the blocks' sums; +inf for invalid or diverged particles."""
    res = np.full(n_p, np.inf)
    L = _LANES
    for c in range(idx.size):
        b = c // L
        i = c % L
        mean = w[b, _R_S1 * L + i] / n
        var = w[b, _R_S2 * L + i] / n - mean * mean if fit_offset else w[b, _R_S2 * L + i] / n
        val = math.sqrt(max(var, 0.0))
        res[idx[c]] = val if math.isfinite(val) else np.inf
    return res
