"""The structural (force-driven) Bouc-Wen model of the Noel-Schoukens identification benchmark.

    m y'' + c y' + k y + z(y, y') = u
    z' = alpha y' - beta (gamma |y'| |z|^(nu-1) z + delta y' |z|^nu)

u is a force (N), y a displacement (m). Only the products ``beta gamma`` and ``beta delta`` enter
the equations, so beta is not identifiable on its own: :func:`~piezohyst.experiments.boucwen_benchmark`
fixes ``beta = 1`` and identifies ``gamma' = beta gamma`` and ``delta' = beta delta``.

Simulation (:func:`simulate_structural`): the input, sampled at ``fs``, is interpolated onto the
integration grid *band-limited* (FFT zero-padding, exact for the benchmark's periodic multisines,
which carry no energy above 150 Hz), and the state is integrated with classical Runge-Kutta 4 at
``fs * substeps`` (the benchmark integrates at 15 kHz, i.e. 20 substeps at 750 Hz). Checked
against ``scipy.integrate.solve_ivp`` (DOP853) on the exact input in
``tests/test_boucwen_benchmark.py``: within 6e-12 m without hysteresis (RK4's 4th order) and
1.4e-8 m with it (the kinks of |v| and |z| at reversals cost RK4 its order there).

For identification: :func:`structural_swarm_rmse` simulates a whole swarm (particles side by side,
threads over groups of them), and :func:`structural_sensitivities` integrates the parameter
sensitivities with the same RK4 steps, which gives the exact Jacobian of the simulated output for
the cost of about two simulations.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import get_num_threads

from .._numba import njit
from .._validation import FloatArray, as_scalar, as_signal
from .bouc_wen import _pool


@njit
def _rhs(y: float, v: float, z: float, u: float, p: FloatArray) -> tuple[float, float, float]:  # pragma: no cover
    m, c, k, alpha, gb, db, nu = p[0], p[1], p[2], p[3], p[4], p[5], p[6]
    az = abs(z)
    if az > 0.0:
        zn = az**nu  # |z|^nu; |z|^(nu-1) z = |z|^nu sign(z), well defined at z -> 0 for nu > 0
        sz = 1.0 if z > 0.0 else -1.0
    else:
        zn = 0.0
        sz = 0.0
    dz = alpha * v - zn * (gb * abs(v) * sz + db * v)
    dv = (u - c * v - k * y - z) / m
    return v, dv, dz


@njit
def structural_rk4(p: FloatArray, u_fine: FloatArray, h: float, substeps: int, state: FloatArray) -> FloatArray:  # pragma: no cover
    """Integrate from ``state`` (y, v, z); ``u_fine`` is the input at steps of ``h / 2``.

    Returns y at every ``substeps``-th integration step (the sample instants), starting with the
    initial state's y. ``state`` is updated in place.
    """
    n_steps = (u_fine.shape[0] - 1) // 2
    n_out = n_steps // substeps
    out = np.empty(n_out)
    y, v, z = state[0], state[1], state[2]
    for i in range(n_out):
        out[i] = y
        for s in range(substeps):
            j = 2 * (i * substeps + s)
            u0 = u_fine[j]
            u1 = u_fine[j + 1]
            u2 = u_fine[j + 2]
            k1y, k1v, k1z = _rhs(y, v, z, u0, p)
            k2y, k2v, k2z = _rhs(y + 0.5 * h * k1y, v + 0.5 * h * k1v, z + 0.5 * h * k1z, u1, p)
            k3y, k3v, k3z = _rhs(y + 0.5 * h * k2y, v + 0.5 * h * k2v, z + 0.5 * h * k2z, u1, p)
            k4y, k4v, k4z = _rhs(y + h * k3y, v + h * k3v, z + h * k3z, u2, p)
            y += h / 6.0 * (k1y + 2 * k2y + 2 * k3y + k4y)
            v += h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
            z += h / 6.0 * (k1z + 2 * k2z + 2 * k3z + k4z)
        if not (math.isfinite(y) and abs(y) < 1e6):
            for q in range(i + 1, n_out):
                out[q] = np.nan
            out[i] = np.nan
            break
    state[0], state[1], state[2] = y, v, z
    return out


@njit
def _rhs_sens(y: float, v: float, z: float, u: float, p: FloatArray, sy: FloatArray, sv: FloatArray,
              sz_: FloatArray, ky: FloatArray, kv: FloatArray, kz: FloatArray) -> tuple[float, float, float]:  # pragma: no cover
    """:func:`_rhs` and the sensitivity equations ``S' = J S + F_p`` for the 7 parameters.

    ``sy, sv, sz_`` are the stage's sensitivities of (y, v, z) to (m, c, k, alpha, gamma',
    delta', nu); their derivatives go to ``ky, kv, kz``. Where z = 0 the derivatives of
    |z|^nu are taken as 0 (a set of measure zero along a trajectory).
    """
    m, c, k, alpha, gb, db, nu = p[0], p[1], p[2], p[3], p[4], p[5], p[6]
    az = abs(z)
    if az > 0.0:
        lz = math.log(az)
        zn = math.exp(nu * lz)
        sgz = 1.0 if z > 0.0 else -1.0
        dzn = nu * zn / az  # d|z|^nu / d|z|
    else:
        lz = 0.0
        zn = 0.0
        sgz = 0.0
        dzn = 0.0
    av = abs(v)
    sgv = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    g = gb * av * sgz + db * v
    dz = alpha * v - zn * g
    dv = (u - c * v - k * y - z) / m
    # state Jacobian rows of (v', z'); y' = v
    jvy, jvv, jvz = -k / m, -c / m, -1.0 / m
    jzv = alpha - zn * (gb * sgv * sgz + db)
    jzz = -dzn * (gb * av + db * v * sgz)
    for q in range(7):
        ky[q] = sv[q]
        kv[q] = jvy * sy[q] + jvv * sv[q] + jvz * sz_[q]
        kz[q] = jzv * sv[q] + jzz * sz_[q]
    kv[0] -= dv / m
    kv[1] -= v / m
    kv[2] -= y / m
    kz[3] += v
    kz[4] -= zn * av * sgz
    kz[5] -= zn * v
    kz[6] -= g * zn * lz
    return v, dv, dz


@njit
def structural_sensitivities(p: FloatArray, u_fine: FloatArray, h: float, substeps: int) -> tuple[FloatArray, FloatArray]:  # pragma: no cover
    """:func:`structural_rk4` from rest, and the derivatives of its output with respect to the
    parameters ``(m, c, k, alpha, gamma', delta', nu)``: (y of shape (n,), dy/dp of shape (n, 7)).

    Forward sensitivities: the same RK4 steps applied to the system augmented with its variational
    equations, which is the exact derivative of the discrete RK4 map (wherever the right-hand side
    is differentiable), so a Jacobian costs one integration instead of one per parameter.
    """
    n_steps = (u_fine.shape[0] - 1) // 2
    n_out = n_steps // substeps
    out = np.empty(n_out)
    jac = np.empty((n_out, 7))
    y = v = z = 0.0
    s = np.zeros((3, 7))  # sensitivities of (y, v, z)
    st = np.empty((3, 7))  # a stage's sensitivities
    k = np.empty((4, 3, 7))  # the stages' derivatives of the sensitivities
    for i in range(n_out):
        out[i] = y
        jac[i] = s[0]
        for sub in range(substeps):
            j = 2 * (i * substeps + sub)
            u0 = u_fine[j]
            u1 = u_fine[j + 1]
            u2 = u_fine[j + 2]
            k1y, k1v, k1z = _rhs_sens(y, v, z, u0, p, s[0], s[1], s[2], k[0, 0], k[0, 1], k[0, 2])
            for r in range(3):
                for q in range(7):
                    st[r, q] = s[r, q] + 0.5 * h * k[0, r, q]
            k2y, k2v, k2z = _rhs_sens(y + 0.5 * h * k1y, v + 0.5 * h * k1v, z + 0.5 * h * k1z, u1, p,
                                      st[0], st[1], st[2], k[1, 0], k[1, 1], k[1, 2])
            for r in range(3):
                for q in range(7):
                    st[r, q] = s[r, q] + 0.5 * h * k[1, r, q]
            k3y, k3v, k3z = _rhs_sens(y + 0.5 * h * k2y, v + 0.5 * h * k2v, z + 0.5 * h * k2z, u1, p,
                                      st[0], st[1], st[2], k[2, 0], k[2, 1], k[2, 2])
            for r in range(3):
                for q in range(7):
                    st[r, q] = s[r, q] + h * k[2, r, q]
            k4y, k4v, k4z = _rhs_sens(y + h * k3y, v + h * k3v, z + h * k3z, u2, p,
                                      st[0], st[1], st[2], k[3, 0], k[3, 1], k[3, 2])
            y += h / 6.0 * (k1y + 2 * k2y + 2 * k3y + k4y)
            v += h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
            z += h / 6.0 * (k1z + 2 * k2z + 2 * k3z + k4z)
            for r in range(3):
                for q in range(7):
                    s[r, q] += h / 6.0 * (k[0, r, q] + 2 * k[1, r, q] + 2 * k[2, r, q] + k[3, r, q])
        if not (math.isfinite(y) and abs(y) < 1e6):
            out[i:] = np.nan
            jac[i:] = np.nan
            break
    return out, jac


@njit
def _swarm_chunk(theta: FloatArray, u_fine: FloatArray, h: float, substeps: int, y: FloatArray, skip: int,
                 out: FloatArray) -> None:  # pragma: no cover
    """RMSE on ``y[skip:]`` of the particles ``theta`` (rows), time in the outer loop and the
    particles in the inner one, so that their independent RK4 stages overlap in the processor
    (each stage waits on a power function); the arithmetic is that of :func:`structural_rk4`."""
    n_p = theta.shape[0]
    n_out = (u_fine.shape[0] - 1) // 2 // substeps
    yy = np.zeros(n_p)
    vv = np.zeros(n_p)
    zz = np.zeros(n_p)
    acc = np.zeros(n_p)
    for i in range(n_out):
        if i >= skip:
            yi = y[i]
            for q in range(n_p):
                d = yy[q] - yi
                acc[q] += d * d
        for s in range(substeps):
            j = 2 * (i * substeps + s)
            u0 = u_fine[j]
            u1 = u_fine[j + 1]
            u2 = u_fine[j + 2]
            for q in range(n_p):
                p = theta[q]
                y0 = yy[q]
                v0 = vv[q]
                z0 = zz[q]
                k1y, k1v, k1z = _rhs(y0, v0, z0, u0, p)
                k2y, k2v, k2z = _rhs(y0 + 0.5 * h * k1y, v0 + 0.5 * h * k1v, z0 + 0.5 * h * k1z, u1, p)
                k3y, k3v, k3z = _rhs(y0 + 0.5 * h * k2y, v0 + 0.5 * h * k2v, z0 + 0.5 * h * k2z, u1, p)
                k4y, k4v, k4z = _rhs(y0 + h * k3y, v0 + h * k3v, z0 + h * k3z, u2, p)
                yn = y0 + h / 6.0 * (k1y + 2 * k2y + 2 * k3y + k4y)
                if not abs(yn) < 1e6:  # diverged (or NaN): parked at rest, result NaN
                    acc[q] = np.nan
                    yy[q] = vv[q] = zz[q] = 0.0
                    continue
                yy[q] = yn
                vv[q] = v0 + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
                zz[q] = z0 + h / 6.0 * (k1z + 2 * k2z + 2 * k3z + k4z)
    for q in range(n_p):
        val = math.sqrt(acc[q] / max(n_out - skip, 1))
        out[q] = val if math.isfinite(val) else np.inf


def structural_swarm_rmse(theta: FloatArray, u_fine: FloatArray, h: float, substeps: int, y: FloatArray,
                          skip: int) -> FloatArray:
    """RMSE of every particle ``theta[i] = (m, c, k, alpha, gamma', delta', nu)`` on ``y[skip:]``.

    Equal to simulating each with :func:`structural_rk4` (to rounding; non-finite or diverging
    particles get +inf). The particles are split over as many threads as numba is set to use; the
    compiled kernel releases the GIL.
    """
    th = np.ascontiguousarray(theta, dtype=np.float64)
    out = np.empty(th.shape[0])
    n_chunks = max(1, min(th.shape[0], get_num_threads()))
    if n_chunks == 1:
        _swarm_chunk(th, u_fine, h, substeps, y, skip, out)
        return out
    cuts = [c * th.shape[0] // n_chunks for c in range(n_chunks + 1)]
    jobs = [_pool(n_chunks).submit(_swarm_chunk, th[lo:hi], u_fine, h, substeps, y, skip, out[lo:hi])
            for lo, hi in itertools.pairwise(cuts)]
    for job in jobs:
        job.result()
    return out


def upsample_bandlimited(u: Any, factor: int, *, periodic: bool = True) -> FloatArray:
    """Interpolate ``u`` onto a grid ``factor`` times finer, band-limited (FFT zero-padding).

    Exact for a periodic signal with no energy at the Nyquist frequency (the benchmark's
    multisines). A non-periodic record is mirrored first (even extension), so its ends do not
    wrap onto each other. Returns ``factor * (len(u) - 1) + 1`` samples: the original instants and
    everything between, with no extrapolation past the last sample.
    """
    x = as_signal("u", u, min_length=2)
    n = x.size
    ext = x if periodic else np.concatenate([x, x[-2:0:-1]])
    spec = np.fft.rfft(ext)
    m = ext.size * factor
    fine = np.fft.irfft(spec, m) * factor
    return fine[: factor * (n - 1) + 1]


@dataclass(frozen=True)
class StructuralBoucWen:
    """The benchmark's Bouc-Wen system (module docstring); SI units."""

    m: float
    c: float
    k: float
    alpha: float
    beta: float
    gamma: float
    delta: float
    nu: float = 1.0

    def __post_init__(self) -> None:
        for name in ("m", "k", "nu"):
            as_scalar(name, getattr(self, name), positive=True)
        for name in ("c", "alpha", "beta", "gamma", "delta"):
            as_scalar(name, getattr(self, name))

    def kernel_params(self) -> FloatArray:
        return np.array([self.m, self.c, self.k, self.alpha, self.beta * self.gamma, self.beta * self.delta, self.nu])

    def simulate(self, u: Any, fs: float, *, substeps: int = 20, periods: int = 1, periodic: bool = True) -> FloatArray:
        """Displacement (m) at the input's samples, from rest.

        ``periods > 1`` repeats a periodic input and returns the last period (the steady state,
        as the benchmark's test records are).
        """
        x = as_signal("u", u, min_length=2)
        fs = as_scalar("fs", fs, positive=True)
        if periods < 1:
            raise ValueError(f"periods must be >= 1, got {periods}")
        full = np.tile(x, periods) if periods > 1 else x
        return simulate_structural(self.kernel_params(), full, fs, substeps=substeps, periodic=periodic)[-x.size:]


def simulate_structural(p: FloatArray, u: FloatArray, fs: float, *, substeps: int = 20, periodic: bool = True) -> FloatArray:
    """Kernel-level simulation for a packed parameter vector (m, c, k, alpha, gamma', delta', nu)."""
    fine = fine_input(u, substeps, periodic=periodic)
    return structural_rk4(np.asarray(p, dtype=np.float64), fine, 1.0 / (fs * substeps), substeps, np.zeros(3))


def fine_input(u: FloatArray, substeps: int, *, periodic: bool = True) -> FloatArray:
    """The input at every half step of the integration grid, ``2 * substeps * len(u) + 1`` samples.

    Periodic: from the record's spectrum, the last interval closing onto the next period's first
    sample. Otherwise: mirrored, band-limited, the last sample held for the final interval.
    """
    x = np.asarray(u, dtype=np.float64)
    f = 2 * substeps
    if periodic:
        full = np.fft.irfft(np.fft.rfft(x), x.size * f) * f
        return np.concatenate([full, full[:1]])
    return upsample_bandlimited(np.concatenate([x, x[-1:]]), f, periodic=False)
