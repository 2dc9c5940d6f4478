"""Units written in column names and how to bring them to the canonical s, V and µm.

A unit is read from the end of a column (or signal) name: ``Displacement [nm]``, ``Time (ms)``,
``t/s``, ``x in mm``, ``y_um``, ``u mV``. Brackets, parentheses, a slash and ``in`` state the unit
explicitly: a unit there that is unknown, or of the wrong kind (a voltage for the displacement),
is refused. A trailing ``_unit``, `` unit`` or ``.unit`` is taken only when it is a known unit
(``u_V`` is volts, ``u_in`` is not a unit), and refused when of the wrong kind (``Position_mV``, a
sensor's voltage, is not read as µm). Conversions are exact powers of ten (or 60 for
minutes), applied by one multiplication or one division so that ``1.5 nm`` becomes exactly the
float nearest to ``0.0015 µm``.
"""

from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

import numpy as np

#: role -> (quantity, canonical unit as written in meta)
ROLES = {"t": ("time", "s"), "u": ("voltage", "V"), "y": ("length", "um"), "r": ("length", "um")}

_QUANTITY_OF_ROLE = {"t": "time", "u": "voltage", "y": "length", "r": "length"}
_ROLE_WORDS = {"t": "the time", "u": "the input voltage", "y": "the output displacement",
               "r": "the reference displacement"}

# token (lower case, micro written as "u") -> (quantity, factor to the canonical unit)
_UNITS: dict[str, tuple[str, Fraction]] = {}
for _names, _q, _f in [
    (("s", "sec", "secs", "second", "seconds"), "time", Fraction(1)),
    (("ms", "msec", "millisecond", "milliseconds"), "time", Fraction(1, 1000)),
    (("us", "usec", "microsecond", "microseconds"), "time", Fraction(1, 10**6)),
    (("ns", "nanosecond", "nanoseconds"), "time", Fraction(1, 10**9)),
    (("min", "minute", "minutes"), "time", Fraction(60)),
    (("h", "hr", "hour", "hours"), "time", Fraction(3600)),
    (("day", "days"), "time", Fraction(86400)),  # Excel's serial dates count days
    (("v", "volt", "volts"), "voltage", Fraction(1)),
    (("mv", "millivolt", "millivolts"), "voltage", Fraction(1, 1000)),
    (("uv", "microvolt", "microvolts"), "voltage", Fraction(1, 10**6)),
    (("kv", "kilovolt", "kilovolts"), "voltage", Fraction(1000)),
    (("m", "meter", "meters", "metre", "metres"), "length", Fraction(10**6)),
    (("cm", "centimeter", "centimeters", "centimetre", "centimetres"), "length", Fraction(10**4)),
    (("mm", "millimeter", "millimeters", "millimetre", "millimetres"), "length", Fraction(1000)),
    (("um", "micron", "microns", "micrometer", "micrometers", "micrometre", "micrometres"),
     "length", Fraction(1)),
    (("nm", "nanometer", "nanometers", "nanometre", "nanometres"), "length", Fraction(1, 1000)),
    (("pm", "picometer", "picometers", "picometre", "picometres"), "length", Fraction(1, 10**6)),
]:
    for _n in _names:
        _UNITS[_n] = (_q, _f)

#: units read only where a name states them as units (``Time [h]``, ``t / day``), not as a
#: suffix: ``u_h`` and ``Position_h`` (a horizontal axis) stay names
_NOT_AS_SUFFIX = {"h", "hr", "hour", "hours", "day", "days"}

#: written where a unit would be but saying "no unit": taken as the canonical unit (and said so)
_DIMENSIONLESS = {"", "-", "--", "1", "none", "n/a", "na", "a.u.", "au", "arb", "arb.", "arb. units"}

_EXPLICIT = [
    re.compile(r"^(?P<base>.*?)\s*\[(?P<unit>[^\[\]]*)\]\s*$"),
    re.compile(r"^(?P<base>.*?)\s*\((?P<unit>[^()]*)\)\s*$"),
    re.compile(r"^(?P<base>.*?)\s*\{(?P<unit>[^{}]*)\}\s*$"),
]
_SLASH = re.compile(r"^(?P<base>[^/]*?\S)\s*/\s*(?P<unit>[^/\s]+)\s*$")
_IN = re.compile(r"^(?P<base>.*?\S)\s+in\s+(?P<unit>\S+)\s*$", re.IGNORECASE)
#: a unit after an underscore, a space or a dot (``t_s``, ``x um``, ``time.s``, as R and pandas
#: write names): only a known unit counts, so ``y.1`` (a renamed duplicate) stays a name
_SUFFIX = re.compile(r"^(?P<base>.*?[^_\s.])[_\s.]+(?P<unit>[^_\s.]+)$")
_LOOKS_LIKE_UNIT = re.compile(r"^[A-Za-zµμ°%/^.\-·*0-9]{1,5}$")
#: a scaled unit: a number, then a unit (``0.1 um``, ``x10 nm``, ``10^-6 m``, ``1e-3 V``)
_SCALED = re.compile(r"^(?P<num>[x×*]?\s*[-+]?[\d.]+(?:(?:e|E|\s*\^\s*)[-+]?\d+)?)\s*[x×*]?\s*(?P<unit>[A-Za-zµμ]+)$")


def scaled_unit(text: str) -> tuple[float, str] | None:
    """A scaled unit's factor to its quantity's canonical unit and the quantity (``0.1 um`` ->
    (0.1, "length"), ``x10 nm`` -> (0.01, "length"), ``10^-6 m`` -> (1.0, "length")), or None
    when ``text`` is not one."""
    m = _SCALED.match(text.strip())
    if not m or unit_key(m.group("unit")) not in _UNITS:
        return None
    num = re.sub(r"^[x×*]\s*", "", m.group("num")).replace(" ", "")
    num = re.sub(r"^10\^", "1e", num)
    try:
        value = float(num)
    except ValueError:
        return None
    quantity, factor = _UNITS[unit_key(m.group("unit"))]
    return value * float(factor), quantity


def unit_key(token: str) -> str:
    """A unit token in the lookup form: lower case, micro sign and Greek mu written as ``u``."""
    t = unicodedata.normalize("NFKC", token).strip().strip("'\"").strip()
    t = t.replace("μ", "u").replace("µ", "u")
    t = re.sub(r"\s+", " ", t).lower()
    if t.startswith("mu") and t[2:] in ("m", "s", "v"):  # "mum", "mus"
        t = "u" + t[2:]
    return t


def is_unit(token: str) -> bool:
    """True when ``token`` is a known unit or says "no unit" (``-``, ``a.u.``)."""
    k = unit_key(token)
    return k in _UNITS or k in _DIMENSIONLESS


@dataclass(frozen=True)
class NameUnit:
    """A column name split into its base (``displacement``) and the unit it states, if any."""

    base: str
    unit: str | None  # the token as written, or None
    explicit: bool  # in brackets / parentheses / after a slash or "in"


def split_unit(name: str) -> NameUnit:
    """Split ``"Displacement [nm]"`` into ``NameUnit("Displacement", "nm", True)``.

    Parenthesised text that does not look like a unit (``"y (sensor 2)"``) stays in the name.
    """
    text = str(name).strip().strip("'\"").strip()
    for rx in _EXPLICIT:
        m = rx.match(text)
        if m:
            unit = m.group("unit").strip()
            if is_unit(unit) or _LOOKS_LIKE_UNIT.match(unit) or scaled_unit(unit) is not None:
                # (a scaled unit, "[0.1 um]", was taken for part of the name and the values for
                # um, 10 times off: found by fuzzing; it is refused with its factor now)
                return NameUnit(m.group("base").strip(), unit, True)
            return NameUnit(text, None, False)
    for rx in (_SLASH, _IN):
        m = rx.match(text)
        if m and unit_key(m.group("unit")) in _UNITS:
            return NameUnit(m.group("base").strip(), m.group("unit"), True)
    m = _SUFFIX.match(text)
    if m and unit_key(m.group("unit")) in _UNITS and unit_key(m.group("unit")) not in _NOT_AS_SUFFIX:
        return NameUnit(m.group("base").strip(), m.group("unit"), False)
    return NameUnit(text, None, False)


def normal_name(name: str) -> str:
    """The name without its unit, lower case, separators as ``_``: ``"Input Voltage [V]"`` -> ``"input_voltage"``."""
    nu = split_unit(name)
    base = nu.base
    if nu.explicit:  # "t_s [s]": a unit suffix under the bracketed one
        inner = split_unit(base)
        if inner.unit is not None and not inner.explicit:
            base = inner.base
    base = unicodedata.normalize("NFKC", base).strip().strip("'\"").lower()
    return re.sub(r"[\s_\-.]+", "_", base).strip("_")


def describe_units() -> str:
    """The known units, for error messages."""
    return "s, ms, us, ns, min, h, day; V, mV, uV, kV; m, cm, mm, um (µm, micron), nm, pm"


@dataclass(frozen=True)
class Conversion:
    """How one column was brought to its canonical unit (recorded in ``meta["units"]``)."""

    column: str
    unit: str | None
    to: str
    factor: Fraction
    how: str  # "header", "file", "given", "assumed"

    def apply(self, values: np.ndarray) -> np.ndarray:
        """The values in the canonical unit: one exact multiplication or division."""
        f = self.factor
        if f == 1:
            return values
        with np.errstate(over="ignore", invalid="ignore"):
            if f.denominator == 1:
                return values * float(f.numerator)
            if f.numerator == 1:
                return values / float(f.denominator)
            return values * float(f)

    def to_meta(self) -> dict[str, Any]:
        d: dict[str, Any] = {"column": self.column, "unit": self.unit, "to": self.to,
                             "factor": float(self.factor)}
        if self.how == "assumed":
            d["note"] = f"no unit stated; taken as {self.to}"
        elif self.how == "given":
            d["note"] = "unit given by the caller"
        return d


class UnitError(ValueError):
    """A unit that is unknown or of the wrong kind (the caller adds the file name)."""


class ScaledUnitError(UnitError):
    """A scaled unit (``0.1 um``): its message gives the factor to pass instead."""


class WrongQuantityError(UnitError):
    """A known unit of another quantity than the column's role (a voltage read as displacement)."""

    def __init__(self, message: str, quantity: str) -> None:
        super().__init__(message)
        self.quantity = quantity


def conversion(role: str, column: str, *, stated: str | None = None, given: Any = None,
               name: str | None = None) -> Conversion:
    """The conversion of ``column`` (playing ``role``: t, u, y or r) to its canonical unit.

    ``given`` (from the caller's ``units=``) wins over ``stated`` (a unit the file gives in a
    units row or a ``Unit`` field), which wins over a unit written in the name (``name``, by
    default the column itself).
    """
    quantity, canonical = ROLES[role]
    if given is not None:
        if isinstance(given, (int, float, np.integer, np.floating)) and not isinstance(given, bool):
            g = float(given)
            if not np.isfinite(g) or g <= 0:
                raise UnitError(f"the factor given for {role} must be a positive number, got {given!r}")
            return Conversion(column, f"x{g:g}", canonical, Fraction(g).limit_denominator(10**12), "given")
        if not isinstance(given, str):
            raise UnitError(f"the unit given for {role} must be a unit name such as 'nm' or a factor, "
                            f"got {type(given).__name__}")
        return _checked(role, column, given, "given", explicit=True)
    if stated is not None and unit_key(stated) not in _DIMENSIONLESS:
        return _checked(role, column, stated, "file", explicit=True)
    nu = split_unit(column if name is None else name)
    if nu.unit is not None and unit_key(nu.unit) not in _DIMENSIONLESS:
        if nu.explicit:
            return _checked(role, column, nu.unit, "header", explicit=True)
        known = _UNITS.get(unit_key(nu.unit))
        if known is not None:
            # a known unit after the name is a stated one, also of the wrong kind: 'Position_mV'
            # (a sensor's voltage) was read as um, 1000 times off (found by fuzzing)
            return _checked(role, column, nu.unit, "header", explicit=False)
    return Conversion(column, None, canonical, Fraction(1), "assumed")


#: Units spelt with the SI prefix mega, a capital M before a small letter: read in any case, "Mm" and
#: "Ms" were taken for mm and ms (factors of 10^9 off; found by fuzzing). Refused, naming the milli
#: unit. (All capitals, "MS" or "MV", stay milli: loggers that write headers in capitals mean that.)
_MEGA = re.compile(r"^M[ms]$")


def _checked(role: str, column: str, unit: str, how: str, *, explicit: bool) -> Conversion:
    quantity, canonical = ROLES[role]
    if _MEGA.match(unit.strip()):
        raise UnitError(f"the unit {unit.strip()!r} of {column!r} ({_ROLE_WORDS[role]}) reads as mega "
                        f"({unit.strip()[1:]} x 10^6), which piezohyst does not take; for milli write "
                        f"'m{unit.strip()[1:]}'")
    key = unit_key(unit)
    if key in _DIMENSIONLESS:
        return Conversion(column, None, canonical, Fraction(1), "assumed")
    known = _UNITS.get(key)
    scaled = scaled_unit(unit) if known is None else None
    if scaled is not None and scaled[1] == quantity:
        factor = scaled[0]
        raise ScaledUnitError(f"the unit {unit!r} of {column!r} ({_ROLE_WORDS[role]}) is a scaled unit, which piezohyst "
                        f"does not read from a name: give its factor to {canonical} (units={{'{role}': {factor:g}}} in "
                        f"Python, --units {role}={factor:g} at the command line)")
    if known is None:
        raise UnitError(f"the unit {unit!r} of {column!r} ({_ROLE_WORDS[role]}) is not one piezohyst knows "
                        f"({describe_units()})")
    if known[0] != quantity:
        raise WrongQuantityError(f"{column!r} is in {unit}, a {known[0]}, but it is read as {_ROLE_WORDS[role]}, "
                        f"a {quantity} (in {canonical})", known[0])
    return Conversion(column, unit, canonical, known[1], how)
