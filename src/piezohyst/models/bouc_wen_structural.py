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
against ``scipy.integrate.solve_ivp`` (DOP853, rtol 1e-10) in ``tests/test_boucwen_benchmark.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._numba import njit, njit_parallel, prange
from .._validation import FloatArray, as_scalar, as_signal


@njit
def _rhs(y: float, v: float, z: float, u: float, p: FloatArray) -> tuple[float, float, float]:  # pragma: no cover
    m, c, k, alpha, gb, db, nu = p[0], p[1], p[2], p[3], p[4], p[5], p[6]
    az = abs(z)
    if az > 0.0:
        zn = az**nu  # |z|^nu
        zn1z = zn / az * z  # |z|^(nu-1) z, well defined at z -> 0 for nu > 0
    else:
        zn = 0.0
        zn1z = 0.0
    dz = alpha * v - (gb * abs(v) * zn1z + db * v * zn)
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


@njit_parallel
def structural_swarm_rmse(theta: FloatArray, u_fine: FloatArray, h: float, substeps: int, y: FloatArray,
                          skip: int) -> FloatArray:  # pragma: no cover
    """RMSE of every particle ``theta[i] = (m, c, k, alpha, gamma', delta', nu)`` on ``y[skip:]``."""
    out = np.empty(theta.shape[0])
    for i in prange(theta.shape[0]):
        st = np.zeros(3)
        sim = structural_rk4(theta[i], u_fine, h, substeps, st)
        acc = 0.0
        n = 0
        for j in range(skip, y.shape[0]):
            d = sim[j] - y[j]
            acc += d * d
            n += 1
        val = math.sqrt(acc / n)
        out[i] = val if math.isfinite(val) else np.inf
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
