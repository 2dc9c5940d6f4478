"""The Prandtl-Ishlinskii (P-I) hysteresis model, paper eqs. (3)-(4), and its analytic
inverse, eqs. (12)-(15).

    y(k) = w^T H_r[x, y0](k)                                                 (3)
    r_i  = (i - 1) / (n + 1) * max|x(t)|,  i = 1..n                          (4)

A note on the paper's printed inverse weights (Section IV-B). Computed exactly by the paper's
own eqs. (13)-(15) from its own forward weights (Section III-C), the first inverse weight is
``w'_1 = 1 / w_1 = 1 / 0.616 = 1.623``, not the printed 1.834, and the other printed values do
not follow either; driving the printed inverse with the forward model's output of a 0-100 V
sinusoid leaves about 21 V of error (see ``tests/test_pi.py``). This module always *computes*
the inverse; the printed numbers are kept only in :mod:`piezohyst.paper_values` for that check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from .._validation import FloatArray, as_scalar, as_signal, frozen
from .base import Compensator, check_dt, register_kind
from .play import finite_signal, pi_simulate, pi_step


def _few_values(r: FloatArray, k: int = 5) -> str:
    return ", ".join(f"{v:g}" for v in r[:k]) + (", ..." if r.size > k else "")


def equal_thresholds(n: int = 20, u_max: float = 100.0) -> FloatArray:
    """Thresholds of eq. (4): ``r_i = (i - 1) / (n + 1) * u_max`` for ``i = 1..n``.

    Parameters
    ----------
    n : int
        Number of play operators (the paper uses 20).
    u_max : float
        ``max |x(t)|`` of the input the model is meant for (the paper: 100 V).

    Examples
    --------
    >>> equal_thresholds(4, 100.0)
    array([ 0., 20., 40., 60.])
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    u_max = as_scalar("u_max", u_max, positive=True)
    return np.arange(n, dtype=np.float64) / (n + 1) * u_max


def _check_thresholds(r: FloatArray) -> None:
    if r.size > 1 and np.any(np.diff(r) < 0) and r.min() == 0.0:
        # ([2, 1, 0] was told "must start at 0": found by a helper)
        raise ValueError(f"thresholds must increase from 0 (0 = r_1 < r_2 < ..., eq. 3): they are given in another "
                         f"order ({_few_values(r)}); sort them, with their weights")
    if r[0] != 0.0:
        raise ValueError(f"thresholds must start at 0 (r_1 = 0, eq. 3), got r_1 = {r[0]}")
    steps = np.diff(r)
    if np.any(steps <= 0):
        i = int(np.argmax(steps <= 0))
        raise ValueError(
            f"thresholds must be strictly increasing (0 = r_1 < r_2 < ... < r_n), "
            f"but r_{i + 2} = {r[i + 1]} <= r_{i + 1} = {r[i]}"
        )


@register_kind("prandtl-ishlinskii", "pi", "p-i")
@dataclass(frozen=True, eq=False)
class PrandtlIshlinskii:
    """Prandtl-Ishlinskii hysteresis model, eq. (3), with optional offsets.

    ``y = offset + sum_i w_i H_{r_i}[x - input_offset, y0_i]``. The paper's model is the case
    ``offset = input_offset = 0``; an output offset is useful for sensors with an arbitrary
    zero, and the input offset lets the inverse of an offset model be a P-I model too.

    Parameters
    ----------
    thresholds : array_like, shape (n,)
        ``0 = r_1 < r_2 < ... < r_n`` (e.g. from :func:`equal_thresholds`, eq. 4).
    weights : array_like, shape (n,)
        ``w_1 .. w_n``; may be negative.
    initial_state : array_like, shape (n,), optional
        Operator states ``y0`` (eq. 2). Default: zeros, the de-energised actuator.
    offset : float
        Added to the output.
    input_offset : float
        Subtracted from the input before the operators.

    Examples
    --------
    >>> import piezohyst as ph, numpy as np
    >>> pi = ph.PrandtlIshlinskii(ph.equal_thresholds(3, 3.0), [1.0, 0.5, 0.25])
    >>> bool(pi.is_invertible)
    True
    >>> u = np.array([0.0, 2.0, 1.0])
    >>> np.allclose(pi.inverse().simulate(pi.simulate(u)), u)
    True
    """

    kind: ClassVar[str]
    output_unit: ClassVar[str] = "um"
    dynamic: ClassVar[bool] = False

    thresholds: FloatArray
    weights: FloatArray
    initial_state: FloatArray = field(default=None)  # type: ignore[arg-type]  # None: zeros, set in __post_init__
    offset: float = 0.0
    input_offset: float = 0.0

    def __post_init__(self) -> None:
        r = as_signal("thresholds", self.thresholds)
        _check_thresholds(r)
        w = as_signal("weights", self.weights)
        if w.size != r.size:
            raise ValueError(
                f"weights must have one entry per threshold: got {w.size} weights for "
                f"{r.size} thresholds"
            )
        if self.initial_state is None:
            z0 = np.zeros_like(r)
        else:
            z0 = as_signal("initial_state", self.initial_state)
            if z0.size != r.size:
                raise ValueError(
                    f"initial_state must have one entry per threshold: got {z0.size} for "
                    f"{r.size} thresholds"
                )
        object.__setattr__(self, "thresholds", frozen(r))
        object.__setattr__(self, "weights", frozen(w))
        object.__setattr__(self, "initial_state", frozen(z0))
        object.__setattr__(self, "offset", as_scalar("offset", self.offset))
        object.__setattr__(self, "input_offset", as_scalar("input_offset", self.input_offset))

    # -- identity -------------------------------------------------------------------------
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PrandtlIshlinskii):
            return NotImplemented
        return (
            np.array_equal(self.thresholds, other.thresholds)
            and np.array_equal(self.weights, other.weights)
            and np.array_equal(self.initial_state, other.initial_state)
            and self.offset == other.offset
            and self.input_offset == other.input_offset
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return (
            f"PrandtlIshlinskii(n={self.n}, r=[{self.thresholds[0]:g} .. {self.thresholds[-1]:g}], "
            f"sum(w)={self.weights.sum():.4g}, offset={self.offset:g}, "
            f"input_offset={self.input_offset:g})"
        )

    @property
    def n(self) -> int:
        """Number of play operators."""
        return int(self.thresholds.size)

    # -- simulation -----------------------------------------------------------------------
    def simulate(self, u: Any, dt: float | None = None) -> FloatArray:
        """Output of eq. (3) for the input signal ``u``, starting from ``initial_state``.

        Runs :func:`piezohyst.models.play.pi_simulate`: event-driven (work proportional to
        the operators that move) on smooth inputs, the dense loop on inputs such as white
        noise; the two agree to rounding. The model is rate independent: ``dt`` is accepted
        (every kind takes it) and unused.
        """
        check_dt(dt, None, self.kind)
        x = finite_signal("u", u)
        z = np.array(self.initial_state)
        return pi_simulate(x, self.thresholds, self.weights, z, self.input_offset, self.offset)

    def operator_outputs(self, u: Any) -> FloatArray:
        """The play-operator outputs ``H_ri[u]`` as an (N, n) array (without the weights)."""
        from .play import play_outputs

        x = as_signal("u", u) - self.input_offset
        return play_outputs(np.ascontiguousarray(x), self.thresholds, np.array(self.initial_state))

    def predict(self, u: Any, dt: float | None = None) -> FloatArray:
        """The output in µm (the protocol's common unit; the same as :meth:`simulate`)."""
        return self.simulate(u, dt)

    def stepper(self, dt: float | None = None) -> "PIStepper":
        """A streaming evaluator: ``s.step(u_k)`` gives ``y(k)``, on the same kernel."""
        check_dt(dt, None, self.kind)
        return PIStepper(self)

    def compensator(self, dt: float | None = None, *, u_range: Any = None,
                    max_slew: float | None = None) -> "InversePIFeedforward":
        """The inverse-P-I feedforward, eqs. (12)-(15): desired µm in, volts out."""
        check_dt(dt, None, self.kind)
        return InversePIFeedforward(self, u_range=u_range, max_slew=max_slew)

    # -- files ----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The parameters as plain data (see :mod:`piezohyst.modelio`)."""
        return {"thresholds": self.thresholds.tolist(), "weights": self.weights.tolist(),
                "initial_state": self.initial_state.tolist(), "offset": self.offset,
                "input_offset": self.input_offset}

    @classmethod
    def from_dict(cls, params: dict[str, Any]) -> "PrandtlIshlinskii":
        """Rebuild the model from :meth:`to_dict`'s data."""
        return cls(thresholds=params["thresholds"], weights=params["weights"],
                   initial_state=params.get("initial_state"),  # type: ignore[arg-type]  # None: zeros
                   offset=params.get("offset", 0.0),
                   input_offset=params.get("input_offset", 0.0))

    def with_extra_slope(self, kappa: float) -> "PrandtlIshlinskii":
        """``P[u] + kappa u``: the same model with ``kappa`` added to ``w_1`` (``r_1 = 0``, so
        ``H_r1[u] = u``). Rate-dependent wrappers invert their instantaneous map through it."""
        w = np.array(self.weights)
        w[0] += float(kappa)
        return PrandtlIshlinskii(self.thresholds, w, self.initial_state, self.offset, self.input_offset)

    def slope_inverse(self, kappa: float = 0.0) -> "PIStepper":
        """A stepper that solves ``P[v] + kappa v = target`` for v, sample by sample, exactly:
        the analytic inverse (eqs. 12-15) of :meth:`with_extra_slope`. Used by rate-dependent
        wrappers (:mod:`piezohyst.models.rate`)."""
        return PIStepper(self.with_extra_slope(kappa).inverse())

    @property
    def min_slope(self) -> float:
        """The smallest slope of any branch: the smallest partial sum of the weights."""
        return float(self.partial_sums.min())

    # -- inverse, eqs. (12)-(15) ----------------------------------------------------------
    @property
    def partial_sums(self) -> FloatArray:
        """``S_i = w_1 + ... + w_i``: the slopes of the model's loading curve."""
        return np.cumsum(self.weights)

    @property
    def is_invertible(self) -> bool:
        """True when every partial sum of the weights is > 0 (the condition of eqs. 13-15) and the
        inverse's weights, eq. (15), are finite numbers (weights of 1e-300 passed the first and
        their inverse overflowed: found by fuzzing)."""
        s = self.partial_sums
        return bool(np.all(s > 0)) and bool(np.all(np.isfinite(_inverse_weights(self.weights, s))))

    def inverse(self) -> "PrandtlIshlinskii":
        """The analytic inverse model, eqs. (12)-(15), itself a :class:`PrandtlIshlinskii`.

        ``r'_i = sum_{j<=i} w_j (r_i - r_j)`` (13),
        ``y'_0i = sum_{j<=i} w_j y0_i + sum_{j>i} w_j y0_j`` (14),
        ``w'_1 = 1/w_1``, ``w'_i = -w_i / (S_i S_{i-1})`` (15), with ``S_i`` the partial sums.
        The offsets swap roles, so ``inverse().simulate(simulate(u)) == u``.

        Raises
        ------
        ValueError
            If a partial sum of the weights is not positive (the model is not invertible).
        """
        w, r, y0 = self.weights, self.thresholds, self.initial_state
        s = self.partial_sums
        bad = np.flatnonzero(s <= 0)
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"model is not invertible: the partial sum of the weights "
                f"w_1 + ... + w_{i + 1} = {s[i]:.6g} is <= 0 (eqs. 13-15 need every partial "
                f"sum > 0)"
            )
        n = self.n
        w_inv = _inverse_weights(w, s)
        if not np.all(np.isfinite(w_inv)):
            i = int(np.flatnonzero(~np.isfinite(w_inv))[0])
            raise ValueError(
                f"model is not invertible in floating point: the inverse's weight w'_{i + 1} of eq. (15) "
                f"overflows (the partial sums of the weights reach down to {float(np.min(s)):.3g}, whose "
                f"inverse slope is beyond the range of a float)")
        r_inv = np.array([np.dot(w[: i + 1], r[i] - r[: i + 1]) for i in range(n)])
        # the tail sums sum_{j>i} w_j y0_j, computed once
        tail = np.concatenate([np.cumsum((w * y0)[::-1])[::-1][1:], [0.0]])
        y0_inv = s * y0 + tail
        return PrandtlIshlinskii(
            thresholds=r_inv,
            weights=w_inv,
            initial_state=y0_inv,
            offset=self.input_offset,
            input_offset=self.offset,
        )

    def with_state(self, initial_state: Any) -> "PrandtlIshlinskii":
        """The same model with another initial state (e.g. where a previous run ended)."""
        return PrandtlIshlinskii(
            self.thresholds, self.weights, initial_state, self.offset, self.input_offset
        )

    def _repr_html_(self) -> str:
        """An HTML summary for Jupyter: kind, units, invertibility, parameters."""
        from .._html import model_html

        return model_html(self)


def _inverse_weights(w: FloatArray, s: FloatArray) -> FloatArray:
    """Eq. (15): ``w'_1 = 1/w_1``, ``w'_i = -w_i / (S_i S_{i-1})`` (inf where it overflows)."""
    out = np.empty(w.size)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        out[0] = 1.0 / w[0]
        out[1:] = -w[1:] / (s[1:] * s[:-1])
    return out


class PIStepper:
    """Streaming P-I evaluation: one input sample in, one output sample out.

    Runs :func:`piezohyst.models.play.pi_step`, the kernel that
    :func:`~piezohyst.models.play.pi_simulate_dense` loops over, so the two give identical
    outputs; :meth:`PrandtlIshlinskii.simulate` agrees with both to rounding.
    """

    __slots__ = ("model", "_r", "_w", "_z", "_in", "_out")

    def __init__(self, model: PrandtlIshlinskii):
        self.model = model
        self._r = model.thresholds
        self._w = model.weights
        self._in = model.input_offset
        self._out = model.offset
        self._z = np.array(model.initial_state)

    def reset(self) -> None:
        """Back to the model's initial state."""
        self._z[:] = self.model.initial_state

    @property
    def state(self) -> FloatArray:
        """A copy of the current operator states."""
        return self._z.copy()

    def step(self, u_k: float) -> float:
        """Advance by one sample and return the model output."""
        x = float(u_k)
        if not math.isfinite(x):
            raise ValueError(f"u_k must be finite, got {u_k!r}")
        return float(pi_step(x, self._r, self._w, self._z, self._in, self._out))

    def to_c(self, c: Any, prefix: str) -> str:
        """This stepper as C99 (see :meth:`Compensator.to_c`): :func:`pi_step`, operation for operation."""
        n = self._r.size
        r = c.array(f"{prefix}_r", self._r)
        w = c.array(f"{prefix}_w", self._w)
        z = c.state_array(f"{prefix}_z", self.model.initial_state)
        fn = c.name(f"{prefix}_step")
        c.function(f"""/* Prandtl-Ishlinskii model, eqs. (1)-(3): {n} play operators */
static double {fn}(double x)
{{
    const double xs = x - {c.num(self._in)};
    double acc = 0.0;
    int i;
    for (i = 0; i < {n}; ++i) {{
        const double lo = xs - {r}[i];
        const double hi = xs + {r}[i];
        double zi = {z}[i];
        zi = (lo > zi) ? lo : zi;
        zi = (hi < zi) ? hi : zi;
        {z}[i] = zi;
        acc += {w}[i] * zi;
    }}
    return acc + {c.num(self._out)};
}}""")
        return fn


class InversePIFeedforward(Compensator):
    """Inverse P-I feedforward: ``u = P^-1[x_d]`` (eqs. 12-15), the compensator of a P-I model.

    Parameters
    ----------
    pi_model : PrandtlIshlinskii
        The identified forward model, input V, output µm; it must be invertible.
    u_range, max_slew : optional
        Output limits (see :class:`~piezohyst.models.base.Compensator`).

    Examples
    --------
    >>> import piezohyst as ph
    >>> pi = ph.PrandtlIshlinskii(ph.equal_thresholds(3, 100.0), [0.02, 0.002, 0.001])
    >>> ff = ph.InversePIFeedforward(pi)
    >>> x_d = ph.sinusoid(1.0, 1, 0.1, 1.9, 1e-3)
    >>> bool(abs(pi.simulate(ff.command(x_d)) - x_d).max() < 1e-9)
    True
    """

    def __init__(self, pi_model: PrandtlIshlinskii, *, u_range: Any = None, max_slew: float | None = None):
        if not isinstance(pi_model, PrandtlIshlinskii):
            raise TypeError(f"pi_model must be a PrandtlIshlinskii, got {type(pi_model).__name__}")
        super().__init__(u_range=u_range, max_slew=max_slew)
        self.model = pi_model
        self.inverse = pi_model.inverse()  # raises ValueError naming the failing partial sum
        self._stepper = PIStepper(self.inverse)

    def _reset(self) -> None:
        self._stepper.reset()

    def _step(self, x_d: float) -> float:
        return self._stepper.step(x_d)

    def _command(self, x_d: FloatArray) -> FloatArray:
        return self.inverse.simulate(x_d)

    def inverse_parameters(self) -> dict[str, Any]:
        """The inverse P-I model of eqs. (12)-(15) (its ``to_dict``): ``u = P'[x_d]``."""
        return {"kind": "prandtl-ishlinskii", "role": "inverse model, eqs. (12)-(15): u = P'[x_d]",
                **self.inverse.to_dict()}

    def to_c(self, c: Any, prefix: str) -> str:
        """The C code of this compensator (see :mod:`piezohyst.export.c`); the stepper's, which it wraps."""
        return self._stepper.to_c(c, prefix)

    def __repr__(self) -> str:
        return f"InversePIFeedforward({self.model!r})"
