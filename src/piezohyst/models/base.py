"""One protocol for every hysteresis model kind, and the registry of kinds by name.

Every kind (Prandtl-Ishlinskii, asymmetric P-I, Preisach, rate-dependent wrappers, Bouc-Wen)
implements :class:`HysteresisModel`:

* ``simulate(u, dt=None)`` - the output for an input signal, in the kind's ``output_unit``
  (``dt`` where the kind has dynamics; rate-independent kinds accept and ignore it);
* ``predict(u, dt=None)`` - the same in micrometres, the unit of every data set;
* ``stepper(dt=None)`` - a streaming evaluator, ``reset()`` / ``step(u_k)``, on the kernel that
  ``simulate`` runs, so the two give the same numbers;
* ``compensator(dt=None, *, u_range=None, max_slew=None)`` - the feedforward that inverts the
  model: desired displacement (µm) in, command (V) out (:class:`Compensator`);
* ``to_dict()`` / ``from_dict(params)`` - plain JSON data, so model files never hold code;
* ``is_invertible`` and ``dynamic`` (True when the model needs ``dt``).

The registry maps a kind's name (and aliases, e.g. ``"pi"``) to its class. Model files, the
CLI, ``compensate``, ``track``, ``commission`` and the C export all go through it: a new kind is
one module that registers itself with :func:`register_kind`, imported once in
``piezohyst/models/__init__.py``, and ``tests/test_model_kinds.py`` checks every duty of it.
"""

from __future__ import annotations

import math
from typing import Any, Callable, ClassVar, Protocol, TypeVar, runtime_checkable

import numpy as np

from .._validation import FloatArray, as_scalar, as_signal

T = TypeVar("T")


@runtime_checkable
class Stepper(Protocol):
    """Streaming evaluation: ``reset()``, then ``step(x)`` once per sample."""

    def reset(self) -> None: ...

    def step(self, x: float) -> float: ...  # noqa: E704


@runtime_checkable
class HysteresisModel(Protocol):
    """What every model kind offers (see the module docstring)."""

    kind: ClassVar[str]
    output_unit: ClassVar[str]

    @property
    def is_invertible(self) -> bool:
        """True when the model has a stable inverse (its compensator can be built)."""

    @property
    def dynamic(self) -> bool:
        """True when the model has dynamics and needs the sample period ``dt``."""

    def simulate(self, u: Any, dt: float | None = None) -> FloatArray:
        """The output for the input signal ``u`` (V), in the kind's ``output_unit``."""

    def predict(self, u: Any, dt: float | None = None) -> FloatArray:
        """The output for ``u`` in µm, the unit of every data set."""

    def stepper(self, dt: float | None = None) -> Stepper:
        """A streaming evaluator (``reset()``, ``step(u_k)``) on the kernel :meth:`simulate` runs."""

    def compensator(self, dt: float | None = None, *, u_range: Any = None,
                    max_slew: float | None = None) -> "Compensator":
        """The feedforward that inverts the model: desired µm in, volts out, limited after the inverse."""

    def to_dict(self) -> dict[str, Any]:
        """The parameters as plain JSON data (what a model file holds)."""

    @classmethod
    def from_dict(cls, params: dict[str, Any]) -> Any:
        """Rebuild a model from :meth:`to_dict`'s data."""


# -- the registry ----------------------------------------------------------------------------------
_KINDS: dict[str, type] = {}
_ALIASES: dict[str, str] = {}


def _checked_from_dict(fn: Callable[..., Any], name: str) -> Any:
    """``from_dict`` with its parameters checked to be a mapping and a missing one named: called on
    the class directly, a missing name was a bare ``KeyError: 'thresholds'`` and ``None`` "'NoneType'
    object is not subscriptable" (found by fuzzing; model files said it already)."""
    import functools
    from collections.abc import Mapping

    @functools.wraps(fn)
    def from_dict(cls: Any, params: Any) -> Any:
        if not isinstance(params, Mapping):
            raise TypeError(f"the parameters of a {name} model are a dict (what to_dict() returns), got "
                            f"{type(params).__name__}")
        try:
            return fn(cls, params)
        except KeyError as exc:
            raise ValueError(f"parameter {exc} is missing for a {name} model") from None

    from_dict._checked = True  # type: ignore[attr-defined]
    return classmethod(from_dict)


def register_kind(name: str, *aliases: str) -> Callable[[type[T]], type[T]]:
    """Class decorator: register a model kind under ``name`` (and ``aliases``)."""

    def deco(cls: type[T]) -> type[T]:
        if name in _KINDS and _KINDS[name] is not cls:
            raise ValueError(f"model kind {name!r} is registered twice")
        cls.kind = name  # type: ignore[attr-defined]
        own = cls.__dict__.get("from_dict")
        if isinstance(own, classmethod) and not getattr(own.__func__, "_checked", False):
            cls.from_dict = _checked_from_dict(own.__func__, name)  # type: ignore[attr-defined]
        if not hasattr(cls, "_repr_html_"):  # every kind shows as a table in Jupyter
            from .._html import model_html

            cls._repr_html_ = model_html  # type: ignore[attr-defined]
        _KINDS[name] = cls
        for a in (name, *aliases):
            _ALIASES[a] = name
        return cls

    return deco


def kinds() -> list[str]:
    """The registered kind names."""
    return list(_KINDS)


def kind_names_and_aliases() -> list[str]:
    """Every name a user may give for a kind (``--model`` accepts these)."""
    return sorted(_ALIASES)


def kind_class(name: str) -> type[Any]:
    """The class registered as ``name`` (or an alias of it)."""
    key = _ALIASES.get(str(name).strip().lower())
    if key is None:
        raise ValueError(f"unknown model kind {name!r}; the kinds are {kinds()} "
                         f"(aliases: {sorted(set(_ALIASES) - set(_KINDS))})")
    return _KINDS[key]


def kind_of(model: Any) -> str:
    """The registered kind name of ``model``."""
    name = getattr(type(model), "kind", None)
    if not isinstance(name, str) or _KINDS.get(name) is not type(model):
        raise TypeError(f"{type(model).__name__} is not a registered model kind; the kinds are {kinds()}")
    return name


def model_from_dict(kind: str, params: Any) -> Any:
    """Rebuild a model of ``kind`` from its ``to_dict()`` parameters."""
    if not isinstance(params, dict):
        raise ValueError(f"the parameters of a {kind!r} model must be an object, got {type(params).__name__}")
    return kind_class(kind).from_dict(params)  # type: ignore[attr-defined]


def nested_to_dict(model: Any) -> dict[str, Any]:
    """``{"kind": ..., "parameters": ...}`` of a model held inside another (wrappers)."""
    return {"kind": kind_of(model), "parameters": model.to_dict()}


def nested_from_dict(doc: Any, what: str) -> Any:
    if not isinstance(doc, dict) or "kind" not in doc or "parameters" not in doc:
        raise ValueError(f"{what} must be an object with 'kind' and 'parameters'")
    return model_from_dict(doc["kind"], doc["parameters"])


# -- helpers for implementations -------------------------------------------------------------------
def check_dt(dt: Any, own: float | None, kind: str) -> float | None:
    """Validate ``dt`` against a model's own sample period (None: the model has none)."""
    if dt is None:
        return own
    d = as_scalar("dt", dt, positive=True)
    if own is not None and not math.isclose(d, own, rel_tol=1e-9):
        raise ValueError(f"this {kind} model was identified at dt = {own:g} s; it cannot run at dt = {d:g} s")
    return d


def need_dt(dt: Any, kind: str) -> float:
    if dt is None:
        raise ValueError(f"a {kind} model has dynamics: give the sample period dt (s)")
    return as_scalar("dt", dt, positive=True)


#: The amplifier's range (V) where nothing states one: a unipolar 0..100 V piezo amplifier.
DEFAULT_U_RANGE = (0.0, 100.0)


def check_u_range(u_range: Any) -> tuple[float, float] | None:
    """``(low, high)`` volts, finite and ordered, or None."""
    if u_range is None:
        return None
    if isinstance(u_range, (str, bytes, dict)) or (hasattr(u_range, "keys") and callable(u_range.keys)):
        # (a dict was read as its keys, {0: 0, 1: 100} as 0..1 V: found by fuzzing)
        raise ValueError(f"u_range must be (low, high) in volts, got {u_range!r}")
    try:
        lo, hi = (float(v) for v in u_range)
    except (TypeError, ValueError):
        raise ValueError(f"u_range must be (low, high) in volts, got {u_range!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"u_range must be finite, got ({lo}, {hi})")
    if not lo < hi:
        raise ValueError(f"u_range must be (low, high) with low < high, got ({lo:g}, {hi:g})")
    return lo, hi


class Compensator:
    """The feedforward that inverts a model: desired displacement (µm) in, command (V) out.

    Subclasses implement ``_reset()``, ``_step(x_d) -> u`` (and may override ``_command`` with a
    batch kernel that gives the same numbers). This base class validates the input and applies
    the output limits *after* the inverse, identically in :meth:`step` and :meth:`command` (and
    in the exported C code): the command is clipped to ``u_range`` and its change per sample is
    limited to ``max_slew`` volts. The inverse's own state follows the unlimited command, so a
    clipped stretch does not corrupt what comes after it.
    """

    def __init__(self, *, u_range: Any = None, max_slew: float | None = None):
        self.u_range = check_u_range(u_range)
        self.max_slew = as_scalar("max_slew", max_slew, positive=True) if max_slew is not None else None
        self._u_last: float | None = None
        self.limited = 0  # samples the limits changed since the last reset

    # -- to implement -------------------------------------------------------------------------
    def _reset(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _step(self, x_d: float) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def _command(self, x_d: FloatArray) -> FloatArray:
        return np.array([self._step(float(v)) for v in x_d])

    # -- public -------------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the model's initial (de-energised) state."""
        self._reset()
        self._u_last = None
        self.limited = 0

    def _limit(self, u: float) -> float:
        v = u
        if self.max_slew is not None and self._u_last is not None:
            v = min(max(v, self._u_last - self.max_slew), self._u_last + self.max_slew)
        if self.u_range is not None:
            v = min(max(v, self.u_range[0]), self.u_range[1])
        if v != u:
            self.limited += 1
        self._u_last = v
        return v

    def step(self, x_d: float) -> float:
        """The command (V) for the next desired displacement sample (µm)."""
        x = float(x_d)
        if not math.isfinite(x):
            raise ValueError(f"the desired displacement must be finite, got {x_d!r}")
        return self._limit(float(self._step(x)))

    def command(self, x_d: Any) -> FloatArray:
        """Commands (V) for a whole desired trajectory (µm), from the initial state.

        The compensator is reset before and after, so it can be called at any time.
        """
        xs = as_signal("x_d", x_d)
        self.reset()
        raw = np.asarray(self._command(xs), dtype=np.float64)
        if self.u_range is None and self.max_slew is None:
            out = raw
        elif self.max_slew is None:  # the range alone: numpy's clip (vectorised)
            assert self.u_range is not None
            out = np.clip(raw, self.u_range[0], self.u_range[1])
            self.limited += int(np.count_nonzero(out != raw))
        else:  # the slew limit is a recursion: one compiled pass (models._limits)
            from ._limits import limit_run

            lo, hi = self.u_range if self.u_range is not None else (-math.inf, math.inf)
            out, changed = limit_run(raw, float(lo), float(hi), float(self.max_slew))
            self.limited += int(changed)
        limited = self.limited
        self.reset()
        self.limited = limited  # what the limits did to this command stays readable
        return out

    def settings(self) -> dict[str, Any]:
        """The output limits: ``u_range`` (V) and ``max_slew`` (V per sample)."""
        return {"u_range": list(self.u_range) if self.u_range else None, "max_slew": self.max_slew}

    # -- export (piezohyst.export): what the C and MATLAB exporters need from each kind ----------
    def inverse_parameters(self) -> dict[str, Any]:
        """The inverse's state-free parameters as plain data (arrays and numbers), for files
        other tools read (MATLAB). Each kind's compensator says what its inverse is."""
        return {}

    def to_c(self, c: Any, prefix: str) -> str:
        """Emit this compensator's inverse (without the output limits, which the exporter adds) as
        C99 through the emitter ``c`` (:class:`piezohyst.export.c.CEmitter`): constants, static
        state, its reset, and a function ``static double NAME(double desired_um)``; return NAME.
        It must compute what :meth:`_step` computes, operation for operation."""
        raise TypeError(f"{type(self).__name__} has no C implementation (its kind does not provide to_c)")


class InverseCompensator(Compensator):
    """A compensator that is one inverse object with the output limits of :class:`Compensator`:
    the inverse provides ``reset()``, ``step(x_d)``, ``inverse_parameters()`` and ``to_c(c,
    prefix)``, and this class passes each through (the numerically inverted kinds use it)."""

    def __init__(self, model: Any, inverse: Any, *, u_range: Any = None, max_slew: float | None = None):
        super().__init__(u_range=u_range, max_slew=max_slew)
        self.model = model
        self._inv = inverse

    def _reset(self) -> None:
        self._inv.reset()

    def _step(self, x_d: float) -> float:
        return self._inv.step(x_d)

    def inverse_parameters(self) -> dict[str, Any]:
        return self._inv.inverse_parameters()

    def to_c(self, c: Any, prefix: str) -> str:
        return self._inv.to_c(c, prefix)


def c_bracketed_solve(c: Any, fn: str, comment: str, *, prologue: str, f0: str, f_at: Callable[[str], str],
                      s_min: str, steps: int, v_range: tuple[str, str] | None, epilogue: str) -> None:
    """Add to ``c`` the C99 function ``double fn(double target)`` of the numerical inverses
    (Bouc-Wen hysteresis, generalized Duhem), operation for operation as their compiled Python
    solvers: the residual ``f0`` at the last command ``v_prev`` (declared by ``prologue``), the
    bracket ``[v_prev, v_prev - f0 / s_min]`` (clamped to ``v_range``, where a target beyond what
    the range reaches gives its end), ``steps`` halvings of it on the residual ``f_at(x)`` (C
    code of the residual at ``x``), one secant step inside the last bracket, then ``epilogue``
    (the state update) and ``return v``."""
    if v_range is None:
        clamp = f"        fb = {f_at('b')};\n"
    else:
        lo, hi = v_range
        clamp = (f"        int clamped = 0;\n"
                 f"        if (b > {hi}) {{ b = {hi}; clamped = 1; }} else if (b < {lo}) {{ b = {lo}; clamped = 1; }}\n"
                 f"        fb = {f_at('b')};\n"
                 f"        if (clamped && fb * f0 >= 0.0) {{ v = b; done = 1; }}\n")
    c.function(f"""/* {comment} */
static double {fn}(double target)
{{
{prologue}
    const double f0 = {f0};
    double v;
    if (f0 == 0.0) {{
        v = v_prev;
    }} else {{
        double a = v_prev;
        double b = v_prev - f0 / {s_min};
        double fa = f0;
        double fb;
        int it;
        int done = 0;
{clamp}        if (fa > 0.0) {{
            double t = a; a = b; b = t;
            t = fa; fa = fb; fb = t;
        }}
        for (it = 0; {"" if v_range is None else "!done && "}it < {steps}; ++it) {{
            const double mid = 0.5 * (a + b);
            const double fm = {f_at("mid")};
            if (fm == 0.0) {{
                v = mid;
                done = 1;
                break;
            }}
            if (fm < 0.0) {{
                a = mid; fa = fm;
            }} else {{
                b = mid; fb = fm;
            }}
        }}
        if (!done) {{
            v = 0.5 * (a + b);
            if (fb != fa) {{
                const double lo = (b < a) ? b : a;
                const double hi = (b > a) ? b : a;
                const double sec = a - fa * (b - a) / (fb - fa);
                if (sec >= lo && sec <= hi) v = sec;
            }}
        }}
    }}
{epilogue}
    return v;
}}""")
