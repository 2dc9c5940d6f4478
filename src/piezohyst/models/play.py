"""The backlash (play) operator, paper eqs. (1)-(2), as compiled kernels.

    y(k) = H_r[x, y0](k) = max{ x(k) - r, min{ x(k) + r, y(k-1) } }          (1)
    y(0) = max{ x(0) - r, min{ x(0) + r, y0 } }                              (2)

Eq. (2) is eq. (1) applied to the first sample with ``y(-1) = y0``, so one step function
serves both. Every kernel here takes the operator states ``z`` (one per threshold) and updates
them in place: the batch path (:func:`pi_simulate`, :func:`play_outputs`) and the streaming
path (:func:`pi_step`) run the very same :func:`play_step`, so they cannot drift apart.
"""

from __future__ import annotations

import numpy as np

from .._numba import njit
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
def pi_simulate(
    u: FloatArray, r: FloatArray, w: FloatArray, z: FloatArray, in_off: float, out_off: float
) -> FloatArray:  # pragma: no cover - compiled
    """Eq. (3) over a whole signal; ``z`` holds the initial state and ends as the final one."""
    n = u.shape[0]
    y = np.empty(n)
    for k in range(n):
        y[k] = pi_step(u[k], r, w, z, in_off, out_off)
    return y


@njit
def play_outputs(u: FloatArray, r: FloatArray, z: FloatArray) -> FloatArray:  # pragma: no cover
    """All operator outputs ``H_ri[u](k)`` as an (N, n) matrix (the regressors of a P-I fit)."""
    n = u.shape[0]
    m = r.shape[0]
    out = np.empty((n, m))
    for k in range(n):
        play_step(u[k], r, z)
        for i in range(m):
            out[k, i] = z[i]
    return out


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
