"""The asymmetric P-I model: a P-I model followed by a monotone static output map (beyond the paper).

    y = g( P[u] )            (or g( R[u] ) with R a rate-dependent P-I, :mod:`.rate`)

A classical P-I loop is point symmetric, and its branches' slopes are the same at the bottom and
the top of the stroke; real stacks' loops are asymmetric and saturate. After Kuhnen's modified P-I
model, the map is written through its inverse, a superposition of one-sided dead-zone operators
of the output (knots ``d_j`` on the output axis, ``c`` the knots' centre)::

    g^-1(y) = y + sum_{d_j > c} phi_j max(y - d_j, 0) + sum_{d_j < c} phi_j min(y - d_j, 0)

a continuous, piecewise-linear map whose slope is 1 between the innermost knots and
``1 + sum phi`` of the knots passed beyond them. Every slope > 0 makes g strictly increasing
(the identification bounds them below), so the model's exact inverse is a formula: the
compensator applies ``g^-1`` to the desired output and the P-I inverse (eqs. 12-15) to that.
Because ``g^-1`` is linear in ``phi``, ``P[u] = g^-1(y)`` is one constrained linear
least-squares problem in the P-I weights and ``phi`` together (Kuhnen's "generalised error";
:func:`piezohyst.identify.fit_asymmetric_pi`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from .._validation import FloatArray, as_scalar, as_signal, frozen
from .base import Compensator, kind_of, nested_from_dict, nested_to_dict, register_kind


@dataclass(frozen=True, eq=False)
class OutputMap:
    """``g^-1(y) = y + sum phi_j D_j(y)`` with one-sided dead zones (module docstring).

    Parameters
    ----------
    knots : array_like
        ``d_j``, strictly increasing (output units).
    coefficients : array_like
        ``phi_j``, one per knot.
    centre : float
        Knots above it are upper dead zones (``max(y - d, 0)``), those below lower ones
        (``min(y - d, 0)``); no knot may equal it.
    """

    knots: FloatArray
    coefficients: FloatArray
    centre: float

    def __post_init__(self) -> None:
        d = as_signal("knots", self.knots, min_length=0)
        phi = as_signal("coefficients", self.coefficients, min_length=0)
        if d.size != phi.size:
            raise ValueError(f"coefficients must have one entry per knot: {phi.size} for {d.size}")
        if np.any(np.diff(d) <= 0):
            raise ValueError("knots must be strictly increasing")
        c = as_scalar("centre", self.centre)
        if np.any(d == c):
            raise ValueError("no knot may sit at the centre")
        object.__setattr__(self, "knots", frozen(d))
        object.__setattr__(self, "coefficients", frozen(phi))
        object.__setattr__(self, "centre", c)
        if np.any(self.segment_slopes() <= 0):
            raise ValueError(f"the map must be increasing: its segment slopes are {self.segment_slopes()}")

    def _upper(self) -> Any:
        return self.knots > self.centre

    def segment_slopes(self) -> FloatArray:
        """Slopes of ``g^-1`` on the ``len(knots) + 1`` segments, from the lowest up.

        Segment ``i`` lies between ``knots[i-1]`` and ``knots[i]``: the upper dead zones below it
        and the lower dead zones above it are active there.
        """
        phi, up = self.coefficients, self._upper()
        m = self.knots.size
        return np.array([1.0 + phi[:i][up[:i]].sum() + phi[i:][~up[i:]].sum() for i in range(m + 1)])

    def inverse_map(self, y: Any) -> FloatArray:
        """``g^-1(y)`` (output units to the P-I model's units)."""
        ys = np.asarray(y, dtype=np.float64)
        out = np.array(ys, dtype=np.float64, copy=True)
        for d, phi, up in zip(self.knots, self.coefficients, self._upper()):
            out += phi * (np.maximum(ys - d, 0.0) if up else np.minimum(ys - d, 0.0))
        return out

    def forward_map(self, p: Any) -> FloatArray:
        """``g(p)``: the exact inverse of the piecewise-linear :meth:`inverse_map`."""
        ps = np.asarray(p, dtype=np.float64)
        if self.knots.size == 0:
            return np.array(ps, dtype=np.float64, copy=True)
        xk = self.inverse_map(self.knots)  # breakpoints of g, increasing
        s = self.segment_slopes()
        out = np.interp(ps, xk, self.knots)
        below = ps < xk[0]
        above = ps > xk[-1]
        out = np.where(below, self.knots[0] + (ps - xk[0]) / s[0], out)
        out = np.where(above, self.knots[-1] + (ps - xk[-1]) / s[-1], out)
        return out

    def min_inverse_slope(self) -> float:
        """The smallest slope of ``g^-1`` over its segments (> 0: g strictly increasing)."""
        return float(self.segment_slopes().min())

    def to_dict(self) -> dict[str, Any]:
        """The map as plain data: knots (µm), coefficients, centre (µm)."""
        return {"knots": self.knots.tolist(), "coefficients": self.coefficients.tolist(), "centre": self.centre}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "OutputMap":
        """Rebuild the map from :meth:`to_dict`'s data."""
        return cls(d["knots"], d["coefficients"], d["centre"])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, OutputMap):
            return NotImplemented
        return (np.array_equal(self.knots, other.knots) and np.array_equal(self.coefficients, other.coefficients)
                and self.centre == other.centre)

    __hash__ = None  # type: ignore[assignment]


@register_kind("asymmetric-pi", "api", "modified-pi")
@dataclass(frozen=True, eq=False)
class AsymmetricPI:
    """``y = g(inner[u])``: a P-I (or rate-dependent P-I) model and a monotone output map.

    Parameters
    ----------
    inner : PrandtlIshlinskii or RateDependent
        The hysteresis model before the map (input V).
    output_map : OutputMap
        ``g`` through its inverse (module docstring); output in µm.
    """

    kind: ClassVar[str]
    output_unit: ClassVar[str] = "um"

    inner: Any
    output_map: OutputMap

    def __post_init__(self) -> None:
        if not hasattr(self.inner, "compensator") or getattr(self.inner, "output_unit", "") != "um":
            raise TypeError(f"inner must be a model kind with output in um, got {type(self.inner).__name__}")
        if not isinstance(self.output_map, OutputMap):
            raise TypeError(f"output_map must be an OutputMap, got {type(self.output_map).__name__}")

    @property
    def dynamic(self) -> bool:  # type: ignore[override]
        """True when the inner model has dynamics (then ``dt`` is needed)."""
        return bool(self.inner.dynamic)

    @property
    def dt(self) -> float | None:
        """The inner model's sample period (s), or None for a rate-independent one."""
        return getattr(self.inner, "dt", None)

    @property
    def is_invertible(self) -> bool:
        """The inner model is invertible and the output map strictly increasing."""
        return bool(self.inner.is_invertible) and self.output_map.min_inverse_slope() > 0

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, AsymmetricPI):
            return NotImplemented
        return type(self.inner) is type(other.inner) and self.inner == other.inner and self.output_map == other.output_map

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"AsymmetricPI({self.inner!r}, knots={np.round(self.output_map.knots, 4).tolist()})"

    def simulate(self, u: Any, dt: float | None = None) -> FloatArray:
        """The output ``g(P[u])`` in µm for the input signal ``u`` (V)."""
        return self.output_map.forward_map(self.inner.simulate(u, dt))

    def predict(self, u: Any, dt: float | None = None) -> FloatArray:
        """The output in µm (the protocol's common unit; the same as :meth:`simulate`)."""
        return self.simulate(u, dt)

    def stepper(self, dt: float | None = None) -> "AsymmetricStepper":
        """A streaming evaluator: ``s.step(u_k)`` gives ``y(k)``, on the inner model's kernel."""
        return AsymmetricStepper(self, self.inner.stepper(dt))

    def compensator(self, dt: float | None = None, *, u_range: Any = None,
                    max_slew: float | None = None) -> "AsymmetricCompensator":
        """``inner^-1[g^-1(x_d)]``: exact."""
        return AsymmetricCompensator(self, self.inner.compensator(dt), u_range=u_range, max_slew=max_slew)

    def to_dict(self) -> dict[str, Any]:
        """The parameters as plain data: the nested inner model and the output map."""
        return {"inner": nested_to_dict(self.inner), "output_map": self.output_map.to_dict()}

    @classmethod
    def from_dict(cls, params: dict[str, Any]) -> "AsymmetricPI":
        """Rebuild the model from :meth:`to_dict`'s data."""
        return cls(inner=nested_from_dict(params["inner"], "the inner model of an asymmetric P-I model"),
                   output_map=OutputMap.from_dict(params["output_map"]))

    def describe(self) -> dict[str, Any]:
        """The inner kind, the map's knots (µm) and its segment slopes."""
        return {"inner": kind_of(self.inner), "knots": self.output_map.knots.tolist(),
                "map_slopes": self.output_map.segment_slopes().tolist()}

    def _repr_html_(self) -> str:
        """An HTML summary for Jupyter: kind, units, invertibility, parameters."""
        from .._html import model_html

        return model_html(self)


class AsymmetricStepper:
    def __init__(self, model: AsymmetricPI, inner: Any):
        self.model = model
        self._inner = inner

    def reset(self) -> None:
        self._inner.reset()

    def step(self, u_k: float) -> float:
        return float(self.model.output_map.forward_map(self._inner.step(u_k)))


class AsymmetricCompensator(Compensator):
    """``inner^-1[g^-1(x_d)]`` (the inner compensator without its own limits; these apply here)."""

    def __init__(self, model: AsymmetricPI, inner: Compensator, *, u_range: Any = None,
                 max_slew: float | None = None):
        super().__init__(u_range=u_range, max_slew=max_slew)
        self.model = model
        self._inner = inner

    def _reset(self) -> None:
        self._inner.reset()

    def _step(self, x_d: float) -> float:
        return self._inner._step(float(self.model.output_map.inverse_map(x_d)))

    def _command(self, x_d: FloatArray) -> FloatArray:
        return self._inner._command(self.model.output_map.inverse_map(x_d))

    def inverse_parameters(self) -> dict[str, Any]:
        """``g^-1`` (the output map's knots, coefficients, centre) and the inner model's inverse."""
        return {"role": "u = inner^-1[g^-1(x_d)], g^-1(y) = y + sum phi_j D_j(y)",
                "output_map": self.model.output_map.to_dict(), "inner": self._inner.inverse_parameters()}

    def to_c(self, c: Any, prefix: str) -> str:
        """``g^-1`` (:meth:`OutputMap.inverse_map`, term by term) then the inner inverse, in C99."""
        om = self.model.output_map
        inner = self._inner.to_c(c, f"{prefix}_in")
        lines = []
        for d, phi, up in zip(om.knots, om.coefficients, om._upper()):
            t = f"(x - {c.num(float(d))})"
            dead = f"(({t} > 0.0) ? {t} : 0.0)" if up else f"(({t} < 0.0) ? {t} : 0.0)"
            lines.append(f"    g += {c.num(float(phi))} * {dead};")
        fn = c.name(f"{prefix}_step")
        body = "\n".join(lines)
        c.function(f"""/* asymmetric P-I: the output map's inverse ({om.knots.size} dead-zone knot(s)), then the inner inverse */
static double {fn}(double x)
{{
    double g = x;
{body}
    return {inner}(g);
}}""")
        return fn


__all__ = ["AsymmetricPI", "OutputMap"]
