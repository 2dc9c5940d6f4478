"""Rate dependence and creep around a rate-independent hysteresis model (beyond the paper).

    v(k)   = b v(k-1) + (1 - b) u(k),             b = exp(-dt / input_tau)   (amplifier + stack)
    s_i(k) = a_i s_i(k-1) + (1 - a_i) v(k),       a_i = exp(-dt / tau_i)
    y(k)   = S[v](k) + sum_i c_i s_i(k)

``S`` is any rate-independent kind that can be inverted with an extra linear term (the
Prandtl-Ishlinskii model of eq. (3), the Preisach model). The lags are the linear "creep
operator" of Krejci and Kuhnen: time constants from a few samples to a fraction of the record
describe what a rate-independent model cannot see, the widening of the loop with frequency and
the slow creep after a change. The output is *linear in every parameter* of S, c and the offset,
so the model is identified by constrained least squares with a global optimum
(:func:`piezohyst.identify.fit_rate_dependent`).

**The inverse, and why it cannot chatter.** With ``kappa = sum_i c_i (1 - a_i)`` the present
input acts through ``S[v](k) + kappa v(k)``; the rest of the lag terms is known from the past.
So the command for a desired ``x_d(k)`` is exact: solve ``S[v] + kappa v = x_d(k) - sum_i c_i a_i
s_i(k-1)`` for v (for P-I: the analytic inverse, eqs. 12-15, of the P-I model with ``kappa``
added to ``w_1``), then invert the input lag, ``u(k) = (v(k) - b v(k-1)) / (1 - b)``. Seen as a
linear system around a branch of local slope K, the lags give
``H(z) = K + sum_i c_i (1 - a_i) / (1 - a_i z^-1)``; each lag term has a positive real part and a
magnitude of at most 1 on the unit circle, so ``K + sum_i min(c_i, 0) > 0`` makes ``Re H > 0``
everywhere: H is minimum phase and its inverse is stable. The identification enforces exactly
that, with K the smallest slope of any branch of S (``S.min_slope``; for P-I the smallest
partial sum of the weights), which is the condition :attr:`RateDependent.inverse_is_stable`
reports. A lag entered with the previous sample's state (as earlier versions did) gives
``a_i - c_i (1 - a_i) / K`` as the pole of the inverse, outside the unit circle as soon as a fast
lag's weight exceeds the slope after a reversal: the command then oscillates at the Nyquist
frequency.

**A long input lag's lead, limited.** The exact inverse of the input lag is a lead of gain
``1 / (1 - b)``, about ``input_tau / dt``: at 20 kHz behind a 6.4 ms amplifier lag, 128. Each kink
of the static inverse (at every reversal of the reference) becomes a step of the command dozens
of times the reference's own. With ``input_lead_gain = G`` the lead acts on ``v`` passed through
a first-order filter of time constant ``input_tau / G`` (factor ``f = exp(-G dt / input_tau)``)::

    w(k) = f w(k-1) + (1 - f) v(k),     u(k) = (w(k) - b w(k-1)) / (1 - b)

whose gain at high frequency is about G and 1 at low frequency: the stage receives ``w``, ``v``
a fraction ``input_tau / G`` of a second late, in exchange for a command whose steps are at most
about G times those of ``v``. ``G = 0`` (the default) is the exact inverse. Model selection
(:mod:`piezohyst.identify.select`) sets G only where the exact lead's steps pass its bound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from .._numba import njit
from .._validation import FloatArray, as_scalar, as_signal, frozen
from .base import Compensator, check_dt, kind_of, nested_from_dict, nested_to_dict, register_kind
from .pi import PIStepper
from .play import pi_step
from .preisach import SOLVE_STEPS, PreisachInverse, preisach_solve


#: An argument a kernel does not use (see :meth:`RateCompensator._kernel_args`).
_NOTHING = np.zeros(1)


@njit
def _lag_kernel(x: FloatArray, a: float) -> FloatArray:  # pragma: no cover - compiled
    out = np.empty(x.shape[0])
    s = 0.0
    for k in range(x.shape[0]):
        s = (1.0 - a) * x[k] + a * s
        out[k] = s
    return out


@njit
def _lags_known(a: FloatArray, c: FloatArray, s: FloatArray) -> float:  # pragma: no cover - compiled
    """``sum_i c_i a_i s_i``: what the output lags add from the past (module docstring)."""
    known = 0.0
    for i in range(a.shape[0]):
        known += c[i] * a[i] * s[i]
    return known


@njit
def _input_lead(v: float, b: float, v_prev: FloatArray) -> float:  # pragma: no cover - compiled
    """The command for the stage input ``v``: the inverse of the input lag,
    ``u = (w - b w_prev) / (1 - b)`` with ``w = f w_prev + (1 - f) v`` (module docstring;
    ``v_prev = [w_prev, f]``; ``f = 0``: the exact inverse, ``w = v``)."""
    if b == 0.0:
        v_prev[0] = v
        return v
    f = v_prev[1]
    w = v if f == 0.0 else f * v_prev[0] + (1.0 - f) * v
    u = (w - b * v_prev[0]) / (1.0 - b)
    v_prev[0] = w
    return u


@njit
def _lags_advance(v: float, a: FloatArray, s: FloatArray, b: float, v_prev: FloatArray) -> float:  # pragma: no cover
    """The lags' states after the static inverse gave ``v``, and the command (:func:`_input_lead`)."""
    for i in range(a.shape[0]):
        s[i] = (1.0 - a[i]) * v + a[i] * s[i]
    return _input_lead(v, b, v_prev)


@njit
def _rate_pi_inverse_step(x_d: float, r: FloatArray, w: FloatArray, z: FloatArray, in_off: float, out_off: float,
                          a: FloatArray, c: FloatArray, s: FloatArray, b: float, v_prev: FloatArray) -> float:  # pragma: no cover
    """One sample of :class:`RateCompensator` with a P-I static part (module docstring): solve
    ``S_kappa[v] = x_d - sum_i c_i a_i s_i`` with the inverse P-I model (eqs. 12-15, ``pi_step``),
    update the lags, invert the input lag. NaN, with no state changed, when the inverse's input
    is not finite (the caller raises as the P-I stepper would)."""
    x = x_d - _lags_known(a, c, s)
    if not math.isfinite(x):
        return math.nan
    return _lags_advance(pi_step(x, r, w, z, in_off, out_off), a, s, b, v_prev)


@njit
def _rate_pi_inverse_run(x_d: FloatArray, r: FloatArray, w: FloatArray, z: FloatArray, in_off: float, out_off: float,
                         a: FloatArray, c: FloatArray, s: FloatArray, b: float, v_prev: FloatArray) -> FloatArray:  # pragma: no cover
    out = np.empty(x_d.shape[0])
    for k in range(x_d.shape[0]):
        out[k] = _rate_pi_inverse_step(x_d[k], r, w, z, in_off, out_off, a, c, s, b, v_prev)
    return out


def first_order_lag(x: FloatArray, a: float) -> FloatArray:
    """``s(k) = a s(k-1) + (1 - a) x(k)`` from rest (``s(-1) = 0``), the arithmetic of the steppers."""
    xs = np.ascontiguousarray(x, dtype=np.float64)
    if a == 0.0:
        return np.array(xs)
    return _lag_kernel(xs, float(a))


def lag_factor(tau: float, dt: float) -> float:
    """``exp(-dt / tau)``; 0 for ``tau == 0`` (no lag)."""
    return math.exp(-dt / tau) if tau > 0 else 0.0


@njit
def _rate_preisach_inverse_step(x_d: float, alpha: FloatArray, beta: FloatArray, inv_delta: float, z: FloatArray,
                                mu: FloatArray, slope: float, offset: float, steps: int, v_last: FloatArray,
                                a: FloatArray, c: FloatArray, s: FloatArray, b: float,
                                v_prev: FloatArray) -> float:  # pragma: no cover - compiled
    """One sample of :class:`RateCompensator` with a Preisach static part: ``known``, the Newton
    solve of :func:`~piezohyst.models.preisach.preisach_solve` from the last solution
    ``v_last`` (:class:`~piezohyst.models.preisach.PreisachInverse`'s), the lags, the input lag's
    inverse. NaN, with no state changed, when the solve's target is not finite."""
    x = x_d - _lags_known(a, c, s)
    if not math.isfinite(x):
        return math.nan
    v = preisach_solve(x, v_last[0], alpha, beta, inv_delta, z, mu, slope, offset, steps)
    v_last[0] = v
    return _lags_advance(v, a, s, b, v_prev)


@njit
def _rate_preisach_inverse_run(x_d: FloatArray, alpha: FloatArray, beta: FloatArray, inv_delta: float, z: FloatArray,
                               mu: FloatArray, slope: float, offset: float, steps: int, v_last: FloatArray,
                               a: FloatArray, c: FloatArray, s: FloatArray, b: float,
                               v_prev: FloatArray) -> FloatArray:  # pragma: no cover - compiled
    """:class:`RateCompensator` over a whole trajectory when the static part is a Preisach model,
    in one compiled call: its steps. NaN from the first sample whose solve target is not finite
    (the caller then runs the Python steps, which raise there)."""
    n = x_d.shape[0]
    out = np.empty(n)
    for k in range(n):
        out[k] = _rate_preisach_inverse_step(x_d[k], alpha, beta, inv_delta, z, mu, slope, offset, steps, v_last,
                                             a, c, s, b, v_prev)
        if math.isnan(out[k]):
            out[k:] = math.nan
            return out
    return out


#: The static part of a rate-dependent compensator, as :func:`rate_inverse_step` takes it.
RATE_PI, RATE_PREISACH = 0, 1


@njit
def rate_inverse_step(x_d: float, kind: int, f: FloatArray, i1: FloatArray, i2: FloatArray, i3: FloatArray,
                      i4: FloatArray, v_last: FloatArray, a: FloatArray, c: FloatArray, s: FloatArray, b: float,
                      v_prev: FloatArray) -> float:  # pragma: no cover - compiled
    """One sample of :class:`RateCompensator`, whichever static part it inverts: the arguments of
    :meth:`RateCompensator._kernel_args` (P-I: ``f = [input offset, output offset]``, ``i1, i2,
    i3`` = thresholds, weights, state; Preisach: ``f = [1 / delta, slope, offset, solve steps]``,
    ``i1 .. i4`` = alpha, beta, state, weights, ``v_last`` the last solution). NaN, with no state
    changed, when the static inverse's input is not finite. One kernel for both, so the compiled
    loops (:mod:`piezohyst.control.compiled_loop`) take either."""
    if kind == RATE_PI:
        return _rate_pi_inverse_step(x_d, i1, i2, i3, f[0], f[1], a, c, s, b, v_prev)
    return _rate_preisach_inverse_step(x_d, i1, i2, f[0], i3, i4, f[1], f[2], int(f[3]), v_last, a, c, s, b, v_prev)


@register_kind("rate-dependent", "rate-dependent-pi", "rate-pi", "rate")
@dataclass(frozen=True, eq=False)
class RateDependent:
    """A rate-independent model ``S`` plus an input lag and output lags (module docstring).

    Parameters
    ----------
    static : PrandtlIshlinskii or Preisach
        The rate-independent part ``S`` (its offset is the model's offset).
    taus : array_like
        Output-lag time constants, s (may be empty).
    lag_weights : array_like
        ``c_i``, output units per input unit.
    dt : float
        Sample period the model runs at, s.
    input_tau : float
        Time constant of the input lag, s (0: none).
    input_lead_gain : float
        The largest gain of the compensator's lead that inverts the input lag (module docstring;
        0: unlimited, the exact inverse). Changes the compensator, not the model's output.
    """

    kind: ClassVar[str]
    output_unit: ClassVar[str] = "um"
    dynamic: ClassVar[bool] = True

    static: Any
    taus: FloatArray
    lag_weights: FloatArray
    dt: float
    input_tau: float = 0.0
    input_lead_gain: float = 0.0
    _a: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if getattr(self.static, "dynamic", True) or not hasattr(self.static, "slope_inverse"):
            raise TypeError(f"static must be a rate-independent kind that can be inverted with a slope "
                            f"(P-I or Preisach), got {type(self.static).__name__}")
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
        if self.input_tau > 0.0 and not math.exp(-float(self.dt) / self.input_tau) < 1.0:
            # exp(-dt / tau) rounds to 1: the lag never moves, and its inverse divided by zero (fuzzing)
            raise ValueError(f"input_tau of {self.input_tau:g} s is too long to resolve at dt = {float(self.dt):g} s "
                             "(the lag would never move)")
        object.__setattr__(self, "input_lead_gain", as_scalar("input_lead_gain", self.input_lead_gain, nonnegative=True))
        if self.input_lead_gain > 0.0 and self.input_tau == 0.0:  # (stored, and had no effect: found by fuzzing)
            raise ValueError("input_lead_gain limits the lead that inverts an input lag; with input_tau = 0 there is "
                             "none: give input_tau, or leave input_lead_gain at 0")
        object.__setattr__(self, "_a", frozen(np.exp(-dt / taus)))

    # -- figures ---------------------------------------------------------------------------------
    @property
    def pi(self) -> Any:
        """The rate-independent part (the name earlier versions used, when it was always P-I)."""
        return self.static

    @property
    def input_lag_factor(self) -> float:
        """``b = exp(-dt / input_tau)`` (0 without an input lag)."""
        return lag_factor(self.input_tau, self.dt)

    @property
    def input_lead_factor(self) -> float:
        """``f = exp(-G dt / input_tau)`` of the lead's filter (module docstring; 0: the exact inverse)."""
        if not (self.input_lead_gain > 0.0 and self.input_tau > 0.0):
            return 0.0
        return math.exp(-self.input_lead_gain * self.dt / self.input_tau)

    @property
    def lag_factors(self) -> FloatArray:
        """``a_i = exp(-dt / tau_i)``."""
        return self._a

    @property
    def instantaneous_lag_gain(self) -> float:
        """``kappa = sum_i c_i (1 - a_i)``: what the lags add to the slope within one sample."""
        return float(np.sum(self.lag_weights * (1.0 - self._a)))

    @property
    def static_gain_of_lags(self) -> float:
        """``sum_i c_i``: what the lags add once everything has settled."""
        return float(self.lag_weights.sum())

    @property
    def min_slope(self) -> float:
        """The smallest slope of the instantaneous map (static part plus ``kappa``)."""
        return float(self.static.min_slope) + self.instantaneous_lag_gain

    @property
    def is_invertible(self) -> bool:
        """True when the smallest slope of any branch, lags included, is positive (a stable inverse)."""
        return bool(self.static.is_invertible or self.min_slope > 0) and self.min_slope > 0

    @property
    def inverse_is_stable(self) -> bool:
        """The sufficient condition of the module docstring: ``K + sum_i min(c_i, 0) > 0``."""
        return float(self.static.min_slope) + float(np.minimum(self.lag_weights, 0.0).sum()) > 0

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RateDependent):
            return NotImplemented
        return (type(self.static) is type(other.static) and self.static == other.static
                and np.array_equal(self.taus, other.taus)
                and np.array_equal(self.lag_weights, other.lag_weights) and self.dt == other.dt
                and self.input_tau == other.input_tau and self.input_lead_gain == other.input_lead_gain)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return (f"RateDependent({self.static!r}, taus={self.taus.tolist()}, "
                f"lag_weights={np.round(self.lag_weights, 6).tolist()}, dt={self.dt:g}, "
                f"input_tau={self.input_tau:g}"
                + (f", input_lead_gain={self.input_lead_gain:g})" if self.input_lead_gain else ")"))

    # -- simulation ------------------------------------------------------------------------------
    def lagged_input(self, u: Any) -> FloatArray:
        """``v``: the input after the input lag."""
        return first_order_lag(as_signal("u", u), self.input_lag_factor)

    def simulate(self, u: Any, dt: float | None = None) -> FloatArray:
        """The output (µm) for the input ``u`` (V) sampled at the model's ``dt``, from rest."""
        check_dt(dt, self.dt, self.kind)
        v = self.lagged_input(u)
        y = np.array(self.static.simulate(v), dtype=np.float64)
        for a, c in zip(self._a, self.lag_weights):
            y += c * first_order_lag(v, float(a))
        return y

    def predict(self, u: Any, dt: float | None = None) -> FloatArray:
        """The output in µm (the protocol's common unit; the same as :meth:`simulate`)."""
        return self.simulate(u, dt)

    def stepper(self, dt: float | None = None) -> "RateDependentStepper":
        """A streaming evaluator: ``s.step(u_k)`` gives ``y(k)``, on the same kernel."""
        check_dt(dt, self.dt, self.kind)
        return RateDependentStepper(self)

    def compensator(self, dt: float | None = None, *, u_range: Any = None,
                    max_slew: float | None = None) -> "RateCompensator":
        """The exact inverse of the module docstring, desired µm in, volts out."""
        check_dt(dt, self.dt, self.kind)
        return RateCompensator(self, u_range=u_range, max_slew=max_slew)

    def inverse_stepper(self) -> "RateCompensator":
        """The compensator without output limits (the name earlier versions used)."""
        return RateCompensator(self)

    # -- files -----------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The parameters as plain data: the nested static model, lags (s), weights, dt, input lag
        (and the compensator's lead limit, where one is set)."""
        out = {"static": nested_to_dict(self.static), "taus": self.taus.tolist(),
               "lag_weights": self.lag_weights.tolist(), "dt": self.dt, "input_tau": self.input_tau}
        if self.input_lead_gain:
            out["input_lead_gain"] = self.input_lead_gain
        return out

    @classmethod
    def from_dict(cls, params: dict[str, Any]) -> "RateDependent":
        """Rebuild the model from :meth:`to_dict`'s data."""
        static = nested_from_dict(params["static"], "the static part of a rate-dependent model")
        return cls(static=static, taus=params.get("taus", []), lag_weights=params.get("lag_weights", []),
                   dt=params["dt"], input_tau=params.get("input_tau", 0.0),
                   input_lead_gain=params.get("input_lead_gain", 0.0))

    def describe(self) -> dict[str, Any]:
        """The structure in a few plain numbers (for reports)."""
        return {"static": kind_of(self.static), "input_tau_s": self.input_tau,
                "input_lead_gain": self.input_lead_gain or None,
                "output_taus_s": self.taus.tolist(), "lag_weights": self.lag_weights.tolist(),
                "inverse_is_stable": self.inverse_is_stable}

    def _repr_html_(self) -> str:
        """An HTML summary for Jupyter: kind, units, invertibility, parameters."""
        from .._html import model_html

        return model_html(self)


#: The name of the first version, when the static part was always a P-I model.
RateDependentPI = RateDependent


class RateDependentStepper:
    """Streaming simulation of a :class:`RateDependent` model (same arithmetic as ``simulate``)."""

    def __init__(self, model: RateDependent):
        self.model = model
        self._static = model.static.stepper()
        self._b = model.input_lag_factor
        self.reset()

    def reset(self) -> None:
        self._static.reset()
        self._v = 0.0
        self._s = np.zeros(self.model.taus.size)

    def step(self, u_k: float) -> float:
        x = float(u_k)
        if not math.isfinite(x):
            raise ValueError(f"u_k must be finite, got {u_k!r}")
        b = self._b
        self._v = x if b == 0.0 else (1.0 - b) * x + b * self._v
        y = float(self._static.step(self._v))
        a = self.model._a
        for i in range(a.size):
            self._s[i] = (1.0 - a[i]) * self._v + a[i] * self._s[i]
            y += float(self.model.lag_weights[i]) * self._s[i]
        return y


class RateCompensator(Compensator):
    """Exact sample-by-sample inverse of a :class:`RateDependent` model (module docstring)."""

    def __init__(self, model: RateDependent, *, u_range: Any = None, max_slew: float | None = None):
        super().__init__(u_range=u_range, max_slew=max_slew)
        if not model.min_slope > 0:
            raise ValueError(f"the model is not invertible: its instantaneous map has slope "
                             f"{model.min_slope:.4g} <= 0 somewhere")
        self.model = model
        self.kappa = model.instantaneous_lag_gain
        self._inverse = model.static.slope_inverse(self.kappa)
        self._b = model.input_lag_factor
        self.reset()

    @property
    def inverse(self) -> Any:
        """The static part's inverse with the lags' instantaneous gain (a P-I model for P-I)."""
        return getattr(self._inverse, "model", self._inverse)

    def _reset(self) -> None:
        self._inverse.reset()
        self._s = np.zeros(self.model.taus.size)
        self._v_prev = np.array([0.0, self.model.input_lead_factor])  # [w(k-1), the lead's filter factor]
        self._args = self._build_kernel_args()

    @property
    def _v(self) -> float:
        """The input-lag state ``w(k-1)`` (``v(k-1)`` for the exact inverse)."""
        return float(self._v_prev[0])

    def _kernel_args(self) -> tuple[Any, ...] | None:
        """The arguments of :func:`rate_inverse_step` after ``x_d``, when the static part's inverse
        is a P-I stepper or a Preisach inverse (exact types): one compiled call per sample instead
        of the Python loop of :meth:`_step`, and what the compiled loops take. Their arrays are the
        steppers' own state (made once per reset); a Preisach inverse's last solution is held in
        ``v_last``: give it back with :meth:`_kernel_back` after a kernel ran."""
        return self._args  # type: ignore[no-any-return]

    def _build_kernel_args(self) -> tuple[Any, ...] | None:
        inv = self._inverse
        m = self.model
        if type(inv) is PIStepper:
            return (RATE_PI, np.array([inv._in, inv._out]), inv._r, inv._w, inv._z, _NOTHING, _NOTHING,
                    m._a, m.lag_weights, self._s, self._b, self._v_prev)
        if type(inv) is PreisachInverse:
            return (RATE_PREISACH, np.array([inv._inv_d, inv._s, inv.model.offset, float(SOLVE_STEPS)]), inv._a,
                    inv._b, inv._z, inv.model.weights, np.array([inv._v]), m._a, m.lag_weights, self._s, self._b,
                    self._v_prev)
        return None

    def _kernel_back(self, args: tuple[Any, ...]) -> None:
        """Take back the state :meth:`_kernel_args` copied out (a Preisach inverse's last solution)."""
        if args[0] == RATE_PREISACH:
            self._inverse._v = float(args[6][0])

    def _step(self, x_d: float) -> float:
        args = self._kernel_args()
        if args is not None:
            u = rate_inverse_step(float(x_d), *args)
            if math.isnan(u):
                lag_part = sum(float(c) * float(a) * s for c, a, s in zip(args[8], args[7], self._s))
                raise ValueError(f"u_k must be finite, got {x_d - lag_part!r}")
            self._kernel_back(args)
            return float(u)
        m = self.model
        v = float(self._inverse.step(x_d - _lags_known(m._a, m.lag_weights, self._s)))
        return float(_lags_advance(v, m._a, self._s, self._b, self._v_prev))

    def _command(self, x_d: FloatArray) -> FloatArray:
        args = self._kernel_args()
        if args is None:
            return super()._command(x_d)
        xs = np.ascontiguousarray(x_d, dtype=np.float64)
        if args[0] == RATE_PREISACH:  # the Newton solves and the lags in one compiled call
            _, f, alpha, beta, z, mu, v_last, a, c, s, b, v_prev = args
            out = _rate_preisach_inverse_run(xs, alpha, beta, f[0], z, mu, f[1], f[2], SOLVE_STEPS, v_last, a, c, s,
                                             b, v_prev)
            self._kernel_back(args)
        else:
            _, f, r, w, z, _, _, a, c, s, b, v_prev = args
            out = _rate_pi_inverse_run(xs, r, w, z, f[0], f[1], a, c, s, b, v_prev)
        if np.isnan(out).any():  # the sample where the stepper raises, from a fresh start
            self.reset()
            return super()._command(x_d)
        return out

    def inverse_parameters(self) -> dict[str, Any]:
        """The recursion of the module docstring: the static part's inverse with the lags'
        instantaneous gain ``kappa``, the lag factors and weights, the input-lag factor."""
        inv = self._inverse
        static = inv.inverse_parameters() if hasattr(inv, "inverse_parameters") else inv.model.to_dict()
        return {"role": "known = sum c_i a_i s_i; v = S_kappa^-1(x_d - known); s_i = (1 - a_i) v + a_i s_i; "
                        "w = f w_prev + (1 - f) v; u = (w - b w_prev) / (1 - b); w_prev = w",
                "input_lead_filter_factor": self.model.input_lead_factor,
                "static_inverse": static, "kappa": self.kappa, "lag_factors": np.array(self.model._a),
                "lag_weights": np.array(self.model.lag_weights), "input_lag_factor": self._b,
                "dt": self.model.dt}

    def to_c(self, c: Any, prefix: str) -> str:
        """:meth:`_step` as C99: the static inverse (its own piece), the lags, the input lag."""
        m = self.model
        n = m.taus.size
        inner = self._inverse.to_c(c, f"{prefix}_s")
        v = c.state_scalar(f"{prefix}_v", 0.0)
        b = self._b
        fn = c.name(f"{prefix}_step")
        if n:
            a = c.array(f"{prefix}_a", m._a)
            w = c.array(f"{prefix}_c", m.lag_weights)
            st = c.state_array(f"{prefix}_lag", np.zeros(n))
            known = (f"    for (i = 0; i < {n}; ++i) known += {w}[i] * {a}[i] * {st}[i];\n")
            update = (f"    for (i = 0; i < {n}; ++i) {st}[i] = (1.0 - {a}[i]) * v + {a}[i] * {st}[i];\n")
            decl = "    int i;\n"
        else:
            known = update = decl = ""
        f = self.model.input_lead_factor
        if b == 0.0:
            lag = f"u = v;\n    {v} = v;"
        elif f == 0.0:
            lag = f"u = (v - {c.num(b)} * {v}) / (1.0 - {c.num(b)});\n    {v} = v;"
        else:  # the lead limited to input_lead_gain (module docstring)
            lag = (f"{{ const double w = {c.num(f)} * {v} + (1.0 - {c.num(f)}) * v;\n"
                   f"      u = (w - {c.num(b)} * {v}) / (1.0 - {c.num(b)});\n      {v} = w; }}")
        c.function(f"""/* rate-dependent inverse: {n} output lag(s), input lag factor b = {b:.17g} */
static double {fn}(double x)
{{
    double known = 0.0;
    double v, u;
{decl}{known}    v = {inner}(x - known);
{update}    {lag}
    return u;
}}""")
        return fn


#: The name of the first version.
RatePIInverse = RateCompensator
