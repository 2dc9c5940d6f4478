"""A model whose initial state is the one a known input history leaves (any kind inside).

Every kind starts from its de-energised state: P-I operators at zero (eq. 2's ``y0``), a Preisach
plane's relays at its staircase from rest, Bouc-Wen's ``h = h0``. A stage at rest need not be
there: a stack that last came down from the top of its range keeps the remanent displacement of
that branch, and one that rests above the bottom of its range after coming up from it sits on
the rising branch. Its loop starts elsewhere than the model's, and the feedforward, which inverts
the model from the model's start, misses by the difference at every point that memory reaches.

:class:`AfterHistory` holds a model and the history that sets its state: commands through
waypoints (raised-cosine legs of ``leg_samples`` samples, then ``hold_samples`` at the last one),
run through the model before the signal and not returned. ``fit_model`` chooses the history
(none, down to the bottom of the record's input and back, or up to its top and back) on held-out
data (:mod:`piezohyst.identify.select`). The compensator replays the model's output along the
history through the inner inverse at every reset, so its state is the one the model's output
left (exact where the inner inverse is exact), and the exported C code does the same in
``compensator_reset``.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from .._validation import FloatArray, as_signal
from .base import Compensator, kind_of, nested_from_dict, nested_to_dict, register_kind

#: Longest history (samples): a history sets a state; it is not a record.
MAX_HISTORY_SAMPLES = 1_000_000


def history_input(waypoints: Any, leg_samples: int, hold_samples: int = 0) -> FloatArray:
    """The history's commands (V): ``waypoints[0]``, raised-cosine legs of ``leg_samples`` samples
    to each next waypoint (each leg ends on it), then ``hold_samples`` samples at the last."""
    pts = np.asarray(waypoints, dtype=np.float64)
    k = np.arange(1, leg_samples + 1) / leg_samples
    shape = 0.5 * (1.0 - np.cos(np.pi * k))
    legs = [np.append(a + (b - a) * shape[:-1], b) for a, b in zip(pts[:-1], pts[1:])]  # each ends on b exactly
    return np.concatenate([pts[:1], *legs, np.full(hold_samples, pts[-1])])


@register_kind("after-history", "history")
@dataclass(frozen=True, eq=False)
class AfterHistory:
    """``model`` started from the state the input history leaves (module docstring).

    Parameters
    ----------
    model : any registered kind with output in µm
        The model; its own initial state is where the history starts.
    waypoints : sequence of float
        The history's turning points, V; the first is where it starts (rest), the last where it
        ends and the signal starts (rest again, in what ``fit_model`` builds).
    leg_samples : int
        Samples of each raised-cosine leg between waypoints (with ``model.dt`` for a dynamic model,
        the history's duration).
    hold_samples : int
        Samples held at the last waypoint after the legs (lags settle there).
    """

    kind: ClassVar[str]
    output_unit: ClassVar[str] = "um"

    model: Any
    waypoints: tuple[float, ...]
    leg_samples: int
    hold_samples: int = 0

    def __post_init__(self) -> None:
        kind_of(self.model)  # a registered kind (TypeError naming the kinds otherwise)
        if getattr(self.model, "output_unit", "") != "um":
            raise TypeError(f"model must be a kind with output in um, got {type(self.model).__name__}")
        if isinstance(self.model, AfterHistory):
            raise TypeError("model is already after a history: give one history (its waypoints joined)")
        if isinstance(self.waypoints, (str, bytes, dict)):  # ("0100" became 0, 1, 0, 0 V: found by fuzzing)
            raise ValueError(f"waypoints must be a sequence of numbers (V), got {self.waypoints!r}")
        try:
            pts = tuple(float(v) for v in self.waypoints)
        except (TypeError, ValueError):  # not numbers, or not a sequence (None)
            raise ValueError(f"waypoints must be numbers (V), got {self.waypoints!r}") from None
        if len(pts) < 2 or not all(math.isfinite(v) for v in pts):
            raise ValueError(f"waypoints must be at least two finite values (V), got {list(pts)}")
        for name in ("leg_samples", "hold_samples"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer, float)) or not math.isfinite(v) \
                    or v != int(v) or v < (1 if name == "leg_samples" else 0):
                raise ValueError(f"{name} must be an integer >= {1 if name == 'leg_samples' else 0}, got {v!r}")
        n = (len(pts) - 1) * int(self.leg_samples) + int(self.hold_samples) + 1
        if n > MAX_HISTORY_SAMPLES:
            raise ValueError(f"the history is {n} samples long; at most {MAX_HISTORY_SAMPLES}")
        with np.errstate(all="ignore"):
            finite = bool(np.all(np.isfinite(history_input(pts, int(self.leg_samples), 0))))
        if not finite:
            raise ValueError(f"waypoints {list(pts)} V give a history that is not finite (too far apart)")
        object.__setattr__(self, "waypoints", pts)
        object.__setattr__(self, "leg_samples", int(self.leg_samples))
        object.__setattr__(self, "hold_samples", int(self.hold_samples))

    @property
    def dynamic(self) -> bool:
        """True when the inner model has dynamics (then ``dt`` is needed)."""
        return bool(self.model.dynamic)

    @property
    def dt(self) -> float | None:
        """The inner model's sample period (s), or None."""
        return getattr(self.model, "dt", None)

    @property
    def is_invertible(self) -> bool:
        """The inner model's invertibility (the history changes its state, not its branches)."""
        return bool(self.model.is_invertible)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, AfterHistory):
            return NotImplemented
        return (type(self.model) is type(other.model) and self.model == other.model and self.waypoints == other.waypoints
                and self.leg_samples == other.leg_samples and self.hold_samples == other.hold_samples)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        pts = ", ".join(f"{v:g}" for v in self.waypoints)
        return f"AfterHistory({self.model!r}, waypoints=({pts}) V)"

    def history(self) -> FloatArray:
        """The history's commands, V (:func:`history_input`)."""
        return history_input(self.waypoints, self.leg_samples, self.hold_samples)

    def history_output(self, dt: float | None = None) -> FloatArray:
        """The inner model's output along the history, µm (what the compensator replays)."""
        return np.asarray(self.model.predict(self.history(), dt), dtype=np.float64)

    def simulate(self, u: Any, dt: float | None = None) -> FloatArray:
        """The output (µm) for ``u`` (V), the model having run through the history first."""
        x = as_signal("u", u)
        h = self.history()
        return np.asarray(self.model.simulate(np.concatenate([h, x]), dt), dtype=np.float64)[h.size:]

    def predict(self, u: Any, dt: float | None = None) -> FloatArray:
        """The output in µm (the same as :meth:`simulate`)."""
        return self.simulate(u, dt)

    def stepper(self, dt: float | None = None) -> "HistoryStepper":
        """A streaming evaluator on the inner model's stepper, the history run at each reset."""
        return HistoryStepper(self.model.stepper(dt), self.history())

    def compensator(self, dt: float | None = None, *, u_range: Any = None,
                    max_slew: float | None = None) -> "HistoryCompensator":
        """The inner model's compensator, its state set at each reset by inverting the model's
        output along the history (exact where the inner inverse is)."""
        return HistoryCompensator(self, self.model.compensator(dt), self.history_output(dt),
                                  u_range=u_range, max_slew=max_slew)

    def to_dict(self) -> dict[str, Any]:
        """The nested model and the history (waypoints V, samples per leg, samples held)."""
        return {"model": nested_to_dict(self.model), "waypoints": list(self.waypoints),
                "leg_samples": self.leg_samples, "hold_samples": self.hold_samples}

    @classmethod
    def from_dict(cls, params: dict[str, Any]) -> "AfterHistory":
        """Rebuild the model from :meth:`to_dict`'s data."""
        return cls(model=nested_from_dict(params["model"], "the model of an after-history model"),
                   waypoints=params["waypoints"], leg_samples=params["leg_samples"],
                   hold_samples=params.get("hold_samples", 0))

    def describe(self) -> dict[str, Any]:
        """The inner kind and the history."""
        return {"model": kind_of(self.model), "waypoints_v": list(self.waypoints),
                "leg_samples": self.leg_samples, "hold_samples": self.hold_samples}

    def _repr_html_(self) -> str:
        """An HTML summary for Jupyter: kind, units, invertibility, parameters."""
        from .._html import model_html

        return model_html(self)


class HistoryStepper:
    """The inner stepper, started (and reset) where stepping it through the history left it."""

    def __init__(self, inner: Any, history: FloatArray):
        inner.reset()
        for v in history:
            inner.step(float(v))
        self._after = copy.deepcopy(inner)  # the state after the history: a reset restores a copy
        self._inner = inner

    def reset(self) -> None:
        self._inner = copy.deepcopy(self._after)

    def step(self, u_k: float) -> float:
        return float(self._inner.step(u_k))


class HistoryCompensator(Compensator):
    """The inner compensator (without its own limits; these apply here), its state at each reset
    the one inverting the model's output along the history leaves."""

    def __init__(self, model: AfterHistory, inner: Compensator, history_um: FloatArray, *, u_range: Any = None,
                 max_slew: float | None = None):
        self.model = model
        self._inner = inner
        self._history_um = np.ascontiguousarray(history_um, dtype=np.float64)
        super().__init__(u_range=u_range, max_slew=max_slew)
        self._inner.reset()
        for x in self._history_um:
            self._inner._step(float(x))
        # the state after the history, kept: a reset restores it (a copy) instead of replaying
        # thousands of samples through the inverse one by one
        self._after = copy.deepcopy(self._inner)

    def _reset(self) -> None:
        self._inner = copy.deepcopy(self._after)

    def _step(self, x_d: float) -> float:
        return float(self._inner._step(x_d))

    def _command(self, x_d: FloatArray) -> FloatArray:
        # the inner batch kernel from its own reset state, over the history and the trajectory
        self._inner.reset()
        n = self._history_um.size
        return np.asarray(self._inner._command(np.concatenate([self._history_um, x_d])), dtype=np.float64)[n:]

    def inverse_parameters(self) -> dict[str, Any]:
        """The inner inverse and the desired µm it is run through at each reset."""
        return {"role": "u = inner^-1[x_d], its state set at reset by running it through history_um",
                "history_um": self._history_um, "inner": self._inner.inverse_parameters()}

    def to_c(self, c: Any, prefix: str) -> str:
        """The inner inverse in C99, and in ``compensator_reset`` a loop that runs it through the
        model's output along the history (after the inner state's own reset)."""
        fn = self._inner.to_c(c, f"{prefix}_in")
        hist = c.array(f"{prefix}_history_um", self._history_um)
        c.reset.append(f"    for (i = 0; i < {self._history_um.size}; ++i) (void){fn}({hist}[i]);")
        return fn


__all__ = ["AfterHistory", "history_input"]
