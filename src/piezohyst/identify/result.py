"""What an identification returns: :class:`FitResult`, and the checks every fit shares."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._validation import FloatArray, as_signal
from ..models.play import largest_loop_threshold


#: A record's input may go this share of the identified input span beyond it before
#: :meth:`FitResult.predict` (and ``piezohyst compensate``) say that the model extrapolates.
EXTRAPOLATION_TOLERANCE = 0.02


class ExtrapolationWarning(UserWarning):
    """An input (or a command) beyond the range the model was identified on: no record showed the
    stage there, and a hysteresis model's output beyond it is its structure's guess (a P-I model
    goes on at its last slope, a Preisach or Duhem model at its reversible one), not a measurement."""


def beyond_identified(u_min: float, u_max: float, identified: Any, what: str = "the input") -> str | None:
    """A sentence naming how far ``u_min .. u_max`` (``what``: the input, the command) leaves
    ``identified`` (``(lo, hi)`` V), or None when it stays within
    :data:`EXTRAPOLATION_TOLERANCE` of that span."""
    if identified is None:
        return None
    lo, hi = float(identified[0]), float(identified[1])
    tol = EXTRAPOLATION_TOLERANCE * max(hi - lo, 0.0)
    parts = []
    if u_min < lo - tol:
        parts.append(f"down to {u_min:.4g} V")
    if u_max > hi + tol:
        parts.append(f"up to {u_max:.4g} V")
    if not parts:
        return None
    return (f"{what} goes {' and '.join(parts)}, beyond the {lo:.4g} .. {hi:.4g} V the model was identified "
            f"on: there it extrapolates (identify it on a record that covers the range in use)")


#: An input's largest loop may exceed the largest one the model was identified on by this share of
#: it before :meth:`FitResult.predict` (and ``piezohyst compensate``) say that the loops are extrapolated.
LOOP_TOLERANCE = 0.1


def larger_loops(u: Any, identified: Any, what: str = "the input") -> str | None:
    """A sentence saying that ``u`` closes larger loops than the record the model was identified
    on (``identified``: that record's largest loop, V, twice
    :func:`~piezohyst.models.play.largest_loop_threshold`), or None when they stay within
    :data:`LOOP_TOLERANCE` of it (or nothing is known of it)."""
    if identified is None:
        return None
    uu = np.asarray(u, dtype=np.float64)
    if uu.size < 2 or not np.all(np.isfinite(uu)):
        return None
    loop = 2.0 * largest_loop_threshold(uu)
    known = float(identified)
    if not loop > known * (1.0 + LOOP_TOLERANCE) + 1e-12 * max(float(np.ptp(uu)), 1.0):
        return None
    return (f"{what} closes loops of up to {loop:.4g} V, larger than the largest of the record the model was "
            f"identified on ({known:.4g} V): operators (hysterons) that only larger loops reverse were not "
            f"identified, and there the model's hysteresis is extrapolated (identify it on a record with loops "
            f"as large as those in use, e.g. a cycle over the whole range)")


def extrapolation(u: Any, input_range: Any, largest_loop: Any, what: str = "the input") -> str | None:
    """What ``u`` asks of a model beyond its record: leaving its ``input_range``
    (:func:`beyond_identified`), or within it closing loops larger than its ``largest_loop``
    (:func:`larger_loops`; beyond the range the range's sentence says it all); None when neither.
    ``u`` is finite."""
    uu = np.asarray(u, dtype=np.float64)
    return beyond_identified(float(uu.min()), float(uu.max()), input_range, what) or larger_loops(uu, largest_loop, what)


@dataclass
class FitResult:
    """What an identification produced.

    Attributes
    ----------
    model : PrandtlIshlinskii or BoucWen
        The identified model.
    rmse : float
        RMSE of eq. (9) on the fitting data, in the units of ``y``.
    method : str
        ``"lsq"`` or ``"pso"`` (+ ``"+polish"``).
    time_s : float
        Wall-clock time of the fit.
    nit, nfev : int or None
        The optimiser's iterations and fitness evaluations.
    history : ndarray or None
        PSO's best fitness per iteration.
    delay : int
        Samples by which the output was taken to lag the input.
    sensitivity : dict or None
        Per parameter: relative rise of the RMSE when that parameter alone moves by 10 %
        (for alpha and gamma, which may sit at 0: by 10 % of itself or 1 % of its search range,
        whichever is larger). Below 1 %: barely constrained.
    info : dict
        Anything else worth keeping (PSO RMSE before polishing, bounds, messages; for
        :func:`~piezohyst.identify.fit_model`, the table of candidates and their hold-out errors).
    warnings : list of str
        What the fit found worth a user's attention (a large or structured hold-out error, a
        loop that no monotone model can represent, a constraint that binds).
    input_range : (float, float) or None
        The smallest and largest input (V) of the record the model was fitted on:
        :meth:`predict` warns (:class:`ExtrapolationWarning`) beyond it.
    largest_loop : float or None
        The largest loop (V) the input of that record closes (twice
        :func:`~piezohyst.models.play.largest_loop_threshold`): :meth:`predict` warns
        (:class:`ExtrapolationWarning`) where an input closes larger ones.
    """

    model: Any
    rmse: float
    method: str
    n_samples: int
    time_s: float
    nit: int | None = None
    nfev: int | None = None
    history: FloatArray | None = None
    message: str = ""
    delay: int = 0
    sensitivity: dict[str, float] | None = None
    info: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    input_range: tuple[float, float] | None = None
    largest_loop: float | None = None

    @property
    def poorly_constrained(self) -> list[str]:
        """Parameters whose 10 % change moves the RMSE by less than 1 %."""
        if not self.sensitivity:
            return []
        return [k for k, v in self.sensitivity.items() if v < 0.01]

    def summary(self) -> dict[str, Any]:
        """The fit's figures as plain data (JSON-ready)."""
        out: dict[str, Any] = {
            "method": self.method, "rmse": self.rmse, "n_samples": self.n_samples,
            "time_s": self.time_s, "nit": self.nit, "nfev": self.nfev, "delay": self.delay,
            "message": self.message,
        }
        if self.sensitivity is not None:
            out["sensitivity"] = dict(self.sensitivity)
            out["poorly_constrained"] = self.poorly_constrained
        for k, v in self.info.items():
            if isinstance(v, (int, float, str, bool)) or v is None:
                out[k] = v
        if "candidates" in self.info:
            out["candidates"] = self.info["candidates"]
        if "holdout" in self.info:
            out["holdout"] = self.info["holdout"]
        out["warnings"] = list(self.warnings)
        if self.input_range is not None:
            out["input_range_V"] = [float(self.input_range[0]), float(self.input_range[1])]
        if self.largest_loop is not None:
            out["largest_loop_V"] = float(self.largest_loop)
        return out

    def predict(self, u: Any, dt: float | None = None) -> FloatArray:
        """The fitted model's output for ``u`` in µm (the unit of ``y``); an input beyond
        :attr:`input_range` (by more than 2 % of it), or within it one that closes larger loops
        than :attr:`largest_loop` (by more than 10 % of it), is warned about (:class:`ExtrapolationWarning`)."""
        out = self.model.predict(u, dt)
        uu = np.asarray(u, dtype=np.float64)
        if uu.size and np.all(np.isfinite(uu)):
            import warnings

            said = extrapolation(uu, self.input_range, self.largest_loop)
            if said:
                warnings.warn(said, ExtrapolationWarning, stacklevel=2)
        return out  # type: ignore[no-any-return]

    def residual(self, u: Any, y: Any, dt: float | None = None) -> FloatArray:
        """``y`` less the model's prediction for ``u`` (:meth:`predict`, from rest), paired as the
        fit pairs them: the sensor lags by :attr:`delay` samples, so ``y[k + delay]`` meets the
        prediction at ``k``; ``len(y) - delay`` samples."""
        uu = as_signal("u", u, min_length=1)
        yy = as_signal("y", y, min_length=1)
        if yy.size != uu.size:
            raise ValueError(f"u and y must have the same length, got {uu.size} and {yy.size}")
        pred = np.asarray(self.predict(uu, dt), dtype=np.float64)
        d = self.delay
        return yy[d:] - pred[: pred.size - d] if d else yy - pred

    def plot(self, u: Any, y: Any = None, dt: float | None = None, *, split: int | None = None,
             title: str | None = None, data_label: str = "measured") -> Any:
        """The model against a record: loops, time series and the residual
        (:func:`piezohyst.plots.plot_fit`).

        Parameters
        ----------
        u, y : array_like or Dataset
            Input (V) and measured output (µm), from rest (the model is simulated from its
            initial state), or one Dataset as ``u`` (its ``dt`` is used).
        dt : float, optional
            Sample period (s); needed by models with dynamics.
        split : int, optional
            First sample not used for fitting (e.g. the start of a validation part): shaded, and
            its RMSE given apart.

        Returns
        -------
        matplotlib.figure.Figure
            Shown once when it is a Jupyter cell's value.

        Notes
        -----
        With a sensor delay of ``d`` samples the model's output for ``u[k]`` is compared with
        ``y[k + d]``, as in the fit.
        """
        from ..plots import figure_result, plot_fit

        if y is None and hasattr(u, "u") and hasattr(u, "y"):
            dt = getattr(u, "dt", None) if dt is None else dt
            data_label = str(getattr(u, "meta", {}).get("name", data_label)) if data_label == "measured" else data_label
            u, y = u.u, u.y
        if y is None:
            raise TypeError("plot needs the measured output y (or a Dataset as u)")
        us = as_signal("u", u, min_length=2)
        ys = as_signal("y", y, min_length=2)
        if us.size != ys.size:
            raise ValueError(f"u and y must have the same length, got {us.size} and {ys.size}")
        pred = self.predict(us, dt)
        d = self.delay
        if d:
            us, ys, pred = us[: us.size - d], ys[d:], pred[: pred.size - d]
        kind = getattr(self.model, "kind", type(self.model).__name__)
        head = title or f"{kind} model ({self.method}); fit RMSE {self.rmse:.4g} µm"
        arts = plot_fit(us, ys, pred, dt=dt, split=None if split is None else max(split - d, 0),
                        model_name=f"{kind} model", data_label=data_label, title=head)
        return figure_result(arts[0].axes.figure)

    def __repr__(self) -> str:
        """One line: the kind, the errors, the delay, how many warnings (the dataclass's own repr
        printed every candidate and array, 123,000 characters for a commissioned stage's fit)."""
        kind = getattr(self.model, "kind", type(self.model).__name__)
        hold = self.info.get("holdout") or {}
        parts = [f"{kind}", f"rmse={self.rmse:.4g}", f"method={self.method!r}", f"n_samples={self.n_samples}",
                 f"delay={self.delay}"]
        if isinstance(hold.get("percent_of_span"), (int, float)):
            parts.append(f"holdout={hold['percent_of_span']:.3g} % of span")
        chosen = self.info.get("chosen")
        if chosen and str(chosen) not in self.method:
            parts.append(f"chosen={chosen!r}")
        parts.append(f"warnings={len(self.warnings)}")
        return f"FitResult({', '.join(parts)})"

    def _repr_html_(self) -> str:
        """An HTML summary for Jupyter: the fit's figures, its warnings, the candidates tried
        and the model."""
        from .. import _html

        kind = getattr(self.model, "kind", type(self.model).__name__)
        rows: list[tuple[str, Any]] = [("model", kind), ("method", self.method),
                                       ("fit RMSE", f"{self.rmse:.4g} µm on {self.n_samples} samples")]
        hold = self.info.get("holdout")
        if isinstance(hold, dict) and hold.get("rmse") is not None:
            pct = hold.get("percent_of_span")
            rows.append(("hold-out RMSE", f"{hold['rmse']:.4g} µm"
                         + (f" ({pct:.3g} % of span)" if pct is not None else "")
                         + (f" on {hold['on']}" if hold.get("on") else "")))
        rows += [("sensor delay", f"{self.delay} samples"), ("time", f"{self.time_s:.3g} s")]
        if self.nit is not None:
            rows.append(("iterations / evaluations", f"{self.nit} / {self.nfev}"))
        if self.poorly_constrained:
            rows.append(("barely constrained", ", ".join(self.poorly_constrained)))
        parts = [_html.table(rows)]
        if self.warnings:
            import html

            parts.append("<b>Warnings</b><ul>" + "".join(f"<li>{html.escape(w)}</li>" for w in self.warnings) + "</ul>")
        cands = self.info.get("candidates")
        if isinstance(cands, list) and cands:
            ranked = sorted(cands, key=lambda c: (c.get("holdout_rmse") is None, c.get("holdout_rmse") or 0.0))
            shown = ranked[:12]
            cols = [("candidate", "label"), ("hold-out RMSE (µm)", "holdout_rmse"),
                    ("% of span", "holdout_percent_of_span"), ("fit RMSE (µm)", "fit_rmse"),
                    ("parameters", "n_parameters")]
            # a column no candidate has a number in says nothing
            cols = [(h, k) for h, k in cols if k == "label" or any(
                isinstance(c.get(k), (int, float)) and np.isfinite(c[k]) for c in shown)]
            parts.append(_html.grid(
                [h for h, _ in cols], [[c.get(k) for _, k in cols] for c in shown],
                caption=f"Candidates by hold-out error (best {len(shown)} of {len(cands)}; the chosen one in bold)",
                bold=[bool(c.get("chosen")) for c in shown]))
        model_html = getattr(self.model, "_repr_html_", None)
        if callable(model_html):
            parts.append(model_html())
        return _html.block(f"FitResult: {kind}", *parts)



def check_output_scale(u: FloatArray, y: FloatArray) -> None:
    """Refuse a record whose output per volt lies outside what floating point fits in (found by
    fuzzing: y scaled by 1e200 ended in ``rmse=inf`` or "array must not contain infs or NaNs",
    u scaled by 1e-300 in a weight of 5e295), naming the units to use. A constant u or y is left
    to the callers' own messages."""
    du, dy = float(np.ptp(u)), float(np.ptp(y))
    if not (du > 0.0 and dy > 0.0):
        return
    if not (1e-100 < dy / du < 1e100 and np.isfinite(float(np.dot(y, y)))):
        raise ValueError(f"the output per volt of input ({dy:.3g} over {du:.3g} V) is outside what floating point "
                         "can fit: give u in volts and y in a unit of length near the motion's scale (um, nm)")


def paired_signals(u: Any, y: Any, delay: int) -> tuple[FloatArray, FloatArray]:
    """``u`` and ``y`` checked and aligned for a sensor delay: ``u[k]`` pairs with ``y[k + delay]``."""
    us = as_signal("u", u, min_length=2)
    ys = as_signal("y", y, min_length=2)
    if us.size != ys.size:
        raise ValueError(f"u and y must have the same length, got {us.size} and {ys.size}")
    if isinstance(delay, bool) or not isinstance(delay, (int, np.integer)) or delay < 0:
        raise ValueError(f"delay must be an integer number of samples >= 0, got {delay!r}")
    if delay:
        if delay >= us.size - 1:
            raise ValueError(f"delay={delay} leaves fewer than 2 samples of {us.size}")
        us, ys = us[: us.size - delay], ys[delay:]
    if np.ptp(us) == 0:
        raise ValueError("u is constant: a constant input cannot identify a hysteresis model")
    return np.ascontiguousarray(us), np.ascontiguousarray(ys)



def simulate_fit(fit: FitResult, u: Any, dt: float | None = None) -> FloatArray:
    """The fitted model's output for ``u`` in the units the fit was made in (µm)."""
    return fit.predict(u, dt)


def unpack_data(u: Any, y: Any, dt: Any = None, *, need_dt: bool = False) -> tuple[Any, Any, Any]:
    """``(u, y, dt)`` from either arrays or one :class:`~piezohyst.data.Dataset` given as ``u``
    (every ``fit_*`` accepts both)."""
    from ..data import Dataset

    if isinstance(u, Dataset):
        if y is not None:
            raise TypeError("give either a Dataset or u and y, not both")
        return u.u, u.y, (u.dt if dt is None else dt)
    if y is None:
        raise TypeError("give the output y (or one Dataset instead of u)")
    if need_dt and dt is None:
        raise TypeError("give the sample period dt (s) (or one Dataset instead of u)")
    return u, y, dt
