"""A rate-dependent P-I model: the P-I model of eq. (3) on a lagged input, plus a bank of lags.

    v(k)   = b v(k-1) + (1 - b) u(k),             b = exp(-dt / input_tau)   (amplifier + stack)
    y(k)   = offset + sum_j w_j H_rj[v](k) + sum_i c_i s_i(k-1),
    s_i(k) = a_i s_i(k-1) + (1 - a_i) v(k),        a_i = exp(-dt / tau_i)

The lags are the linear "creep operator" of Krejci and Kuhnen: with time constants from
milliseconds to tens of seconds they describe what a rate-independent P-I model cannot see, the
widening of the loop with frequency and the slow creep after a change. The output is still
*linear in every parameter* (w and c), so the model is identified by constrained least squares
with a global optimum (:func:`piezohyst.identify.fit_rate_pi`).

The lag terms enter with the state of the previous sample, so the present input acts only through
the P-I part. The model is therefore invertible sample by sample exactly when its P-I part is
(every partial sum of w > 0): the stack voltage that gives ``x_d(k)`` is the inverse P-I (eqs.
12-15) applied to ``x_d(k) - offset - sum_i c_i s_i(k-1)``, and the command that gives that
voltage is the exact inverse of the input lag, ``u(k) = (v(k) - b v(k-1)) / (1 - b)``
(:class:`RatePIInverse`). The input lag is where the fast dynamics belong: put in the output bank,
lags of a few milliseconds carry most of the instantaneous gain and their inverse is a recursion
that rings at the Nyquist frequency; as an input lag their inverse is a formula.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._numba import njit
from .._validation import FloatArray, as_scalar, as_signal, frozen
from .pi import PrandtlIshlinskii
from .play import pi_step, play_step


@njit
def input_lag(u: FloatArray, b: float) -> FloatArray:  # pragma: no cover
    """``v(k) = b v(k-1) + (1 - b) u(k)`` from rest."""
    v = np.empty(u.shape[0])
    acc = 0.0
    for k in range(u.shape[0]):
        acc = b * acc + (1.0 - b) * u[k]
        v[k] = acc
    return v


@njit
def rate_pi_simulate(v: FloatArray, r: FloatArray, w: FloatArray, z: FloatArray, a: FloatArray,
                     c: FloatArray, s: FloatArray, offset: float) -> FloatArray:  # pragma: no cover
    """The model's output for an already lagged input ``v``."""
    n = v.shape[0]
    y = np.empty(n)
    for k in range(n):
        lag = 0.0
        for i in range(a.shape[0]):
            lag += c[i] * s[i]
        play_step(v[k], r, z)
        acc = offset + lag
        for j in range(r.shape[0]):
            acc += w[j] * z[j]
        y[k] = acc
        for i in range(a.shape[0]):
            s[i] = a[i] * s[i] + (1.0 - a[i]) * v[k]
    return y


@njit
def lag_outputs(u: FloatArray, a: FloatArray) -> FloatArray:  # pragma: no cover
    """``s_i(k-1)`` for every sample and lag, from rest: the lag regressors, (N, m)."""
    n = u.shape[0]
    m = a.shape[0]
    out = np.empty((n, m))
    s = np.zeros(m)
    for k in range(n):
        for i in range(m):
            out[k, i] = s[i]
            s[i] = a[i] * s[i] + (1.0 - a[i]) * u[k]
    return out


@njit
def rate_pi_inverse_step(x_d: float, rinv: FloatArray, winv: FloatArray, zinv: FloatArray, in_off: float,
                         out_off: float, a: FloatArray, c: FloatArray, s: FloatArray, offset: float) -> float:  # pragma: no cover
    lag = 0.0
    for i in range(a.shape[0]):
        lag += c[i] * s[i]
    u = pi_step(x_d - offset - lag, rinv, winv, zinv, in_off, out_off)
    for i in range(a.shape[0]):
        s[i] = a[i] * s[i] + (1.0 - a[i]) * u
    return u


#: Default output-lag time constants (s): rate dependence from 10 ms, creep to 3 s, about two per
#: decade. Longer ones cannot be told apart from a constant in a commissioning run of ~10 s.
DEFAULT_TAUS = (0.01, 0.03, 0.1, 0.3, 1.0, 3.0)
#: Input-lag time constants (s) tried by the identification (0: none).
DEFAULT_INPUT_TAUS = (0.0, 1e-4, 2e-4, 4e-4, 6e-4, 8e-4, 1e-3, 1.5e-3, 2e-3, 3e-3)


@dataclass(frozen=True, eq=False)
class RateDependentPI:
    """P-I model (eq. 3) plus first-order lags of the input: see the module docstring.

    Parameters
    ----------
    pi : PrandtlIshlinskii
        The rate-independent part (its offset is the model's offset).
    taus : array_like
        Lag time constants, s.
    lag_weights : array_like
        ``c_i``, output units per input unit.
    dt : float
        Sample period the model runs at, s.
    input_tau : float
        Time constant of the input lag, s (0: none).
    """

    pi: PrandtlIshlinskii
    taus: FloatArray
    lag_weights: FloatArray
    dt: float
    input_tau: float = 0.0
    _a: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.pi, PrandtlIshlinskii):
            raise TypeError(f"pi must be a PrandtlIshlinskii, got {type(self.pi).__name__}")
        taus = as_signal("taus", self.taus, min_length=0)
        if np.any(taus <= 0):
            raise ValueError(f"taus must all be > 0, got {taus}")
        c = as_signal("lag_weights", self.lag_weights, min_length=0)
        if c.size != taus.size:
            raise ValueError(f"lag_weights must have one entry per tau: {c.size} for {taus.size}")
        dt = as_scalar("dt", self.dt, positive=True)
        object.__setattr__(self, "taus", frozen(taus))
        object.__setattr__(self, "lag_weights", frozen(c))
        object.__setattr__(self, "dt", dt)
        object.__setattr__(self, "input_tau", as_scalar("input_tau", self.input_tau, nonnegative=True))
        object.__setattr__(self, "_a", frozen(np.exp(-dt / taus)))

    @property
    def input_lag_factor(self) -> float:
        """``b = exp(-dt / input_tau)`` (0 without an input lag)."""
        return math.exp(-self.dt / self.input_tau) if self.input_tau > 0 else 0.0

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RateDependentPI):
            return NotImplemented
        return (self.pi == other.pi and np.array_equal(self.taus, other.taus)
                and np.array_equal(self.lag_weights, other.lag_weights) and self.dt == other.dt
                and self.input_tau == other.input_tau)

    __hash__ = None  # type: ignore[assignment]

    @property
    def is_invertible(self) -> bool:
        return self.pi.is_invertible

    @property
    def static_gain_of_lags(self) -> float:
        """sum of c_i: how much the lags add once everything has settled."""
        return float(self.lag_weights.sum())

    def simulate(self, u: Any) -> FloatArray:
        x = as_signal("u", u)
        p = self.pi
        v = input_lag(x, self.input_lag_factor) - p.input_offset
        return rate_pi_simulate(v, p.thresholds, p.weights, np.array(p.initial_state),
                                self._a, self.lag_weights, np.zeros(self._a.size), p.offset)

    def inverse_stepper(self) -> "RatePIInverse":
        return RatePIInverse(self)


class RatePIInverse:
    """Exact sample-by-sample inverse of a :class:`RateDependentPI` (a feedforward stepper)."""

    def __init__(self, model: RateDependentPI):
        if model.pi.input_offset != 0.0:
            raise ValueError("the P-I part of a rate-dependent model must have input_offset 0")
        self.model = model
        base = PrandtlIshlinskii(model.pi.thresholds, model.pi.weights, model.pi.initial_state)
        self.inverse = base.inverse()  # raises when the P-I part is not invertible
        self.reset()

    def reset(self) -> None:
        self._z = np.array(self.inverse.initial_state)
        self._s = np.zeros(self.model.taus.size)
        self._v = 0.0
        self._b = self.model.input_lag_factor

    def step(self, x_d: float) -> float:
        """The command (V) for the next desired output sample."""
        x = float(x_d)
        if not math.isfinite(x):
            raise ValueError(f"x_d must be finite, got {x_d!r}")
        inv = self.inverse
        v = float(rate_pi_inverse_step(x, inv.thresholds, inv.weights, self._z, inv.input_offset, inv.offset,
                                       self.model._a, self.model.lag_weights, self._s, self.model.pi.offset))
        u = (v - self._b * self._v) / (1.0 - self._b)  # exact inverse of the input lag
        self._v = v
        return u

    def command(self, x_d: Any) -> FloatArray:
        xs = as_signal("x_d", x_d)
        self.reset()
        out = np.array([self.step(v) for v in xs])
        self.reset()
        return out
