"""From a source of named columns (a text table, a MATLAB struct, a DataFrame) to a :class:`Dataset`.

Every reader describes its file as a :class:`Source`: the names it can offer, how a name given
by the user or guessed from the aliases maps to a column, a unit the file states, and how to read
the columns. :func:`assemble` does the rest once for every format: picking t, u and y, units,
NaN/inf with their line or sample, time checks (increasing, uniform or resampled, agreeing with
``fs``) and the provenance in ``meta``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Hashable, Sequence
from typing import Any, Protocol

import numpy as np

from ._dataset import DataError, Dataset
from ._units import ROLES, ScaledUnitError, UnitError, WrongQuantityError, conversion, normal_name

#: names (without their unit, lower case, separators as "_") that identify a column's role
ALIASES: dict[str, tuple[str, ...]] = {
    "t": ("t", "time", "times", "tout", "timestamp", "time_stamp", "elapsed_time", "x_value",
          "zeit", "temps", "tiempo"),
    "u": ("u", "v", "voltage", "volt", "volts", "vin", "v_in", "u_in", "input", "input_voltage",
          "command", "drive", "drive_voltage", "piezo_voltage", "actuator_voltage",
          "amplifier_voltage", "excitation", "spannung"),
    "y": ("y", "x", "displacement", "disp", "position", "pos", "output", "y_out",
          "output_displacement", "measured_displacement", "sensor", "extension", "stroke",
          "deflection", "weg", "auslenkung"),
    "r": ("r", "ref", "reference", "desired", "xd", "x_d", "y_d", "yd", "target", "setpoint",
          "trajectory", "x", "y"),
}

ROLE_WORDS = {"t": "the time", "u": "the input voltage u", "y": "the output displacement y",
              "r": "the reference"}
#: how to name a column, in both spellings
FLAGS = {"t": ("t_col=", "--t-col"), "u": ("u_col=", "--u-col"), "y": ("y_col=", "--y-col"),
         "r": ("ref_col=", "--ref-col")}
#: a time step further than this from the median step makes the time column non-uniform
UNIFORM_TOLERANCE = 0.01
#: The longest step (in median steps) resampling bridges: a longer one is a pause in the recording,
#: and interpolating across it would invent data.
MAX_RESAMPLED_GAP = 10.0

Key = Hashable


def flag(role: str) -> str:
    """``"u_col= in Python, --u-col at the command line"``."""
    py, cli = FLAGS[role]
    return f"{py} in Python, {cli} at the command line"


class Source(Protocol):
    """What :func:`assemble` needs from a reader."""

    where: str  # the file (or "DataFrame") for messages
    meta: dict[str, Any]  # what the reader learnt (format, encoding, ...)

    def listing(self) -> str:
        """The columns or signals on offer, for messages."""

    def find(self, given: Any, role: str) -> Key:
        """The column the caller named (raise DataError if there is none)."""

    def guess(self, role: str) -> Key | None:
        """The column whose name says it plays ``role``, if exactly one does."""

    def companion_time(self, key: Key) -> Key | None:
        """A time vector that belongs with this signal (a struct's ``time`` field), if any."""

    def label(self, key: Key) -> str:
        """The column's name as the file writes it (units parsed from it)."""

    def stated_unit(self, key: Key) -> str | None:
        """A unit the file states apart from the name (a units row, a ``Unit`` field)."""

    def unit_name(self, key: Key) -> str:
        """The name a unit may be written in (the label, or a signal's ``Name``)."""

    def read(self, keys: Sequence[Key], limit: int) -> list[np.ndarray]:
        """The columns as 1-D float64 arrays (refusing matrices, text and sizes over ``limit``)."""

    def locate(self, key: Key, row: int) -> str:
        """Where row ``row`` of a column is in the file (``"line 57"``, ``"sample 57"``)."""

    def explain(self, key: Key, row: int, value: float) -> str:
        """Where row ``row`` of a column is and what is written there (for a bad ``value``)."""


# ------------------------------------------------------------------------------------------------
def match_name(given: str, names: Sequence[tuple[Key, Sequence[str]]]) -> list[Key]:
    """Keys whose name matches ``given``: exactly, then ignoring case, then ignoring the unit."""
    g = str(given).strip()
    tests = (lambda n: n.strip() == g,
             lambda n: n.strip().lower() == g.lower(),
             lambda n: normal_name(n) == normal_name(g) and normal_name(g) != "")
    for test in tests:
        hits = list(dict.fromkeys(k for k, labels in names for n in labels if test(n)))
        if hits:
            return hits
    return []


def guess_by_alias(names: Sequence[tuple[Key, Sequence[str]]], role: str, where: str,
                   describe: Any = str) -> Key | None:
    """The one key whose name is an alias of ``role``; None if none is. Two columns named by
    different aliases are as ambiguous as two of one name: ``Time`` and ``T`` (a temperature)
    took ``T`` for the time, and ``Command`` (a position setpoint) won over ``Drive Voltage [V]``,
    the first alias in the list winning (found by fuzzing)."""
    normed = [(k, {normal_name(n) for n in labels}) for k, labels in names]
    hits = list(dict.fromkeys(k for alias in ALIASES[role] for k, ns in normed if alias in ns))
    if len(hits) == 1:
        return hits[0]
    if len(hits) > 1:
        which = ", ".join(repr(describe(h)) for h in hits[:6])
        raise DataError(f"{where}: several columns could be {ROLE_WORDS[role]} ({which}); "
                        f"name one ({flag(role)})")
    return _guess_in_triples(normed, role, where, describe)


def _guess_in_triples(normed: list[tuple[Key, set[str]]], role: str, where: str, describe: Any) -> Key | None:
    """``t_<tag>``, ``u_<tag>``, ``y_<tag>`` (units apart): one record per tag, as ``piezohyst rig``
    writes one (t, u, y) triple per frequency (``t_1Hz_s, u_1Hz_V, y_1Hz_um``). With one tag whose
    u and y are both there, its column of ``role``; with several, the caller must choose."""
    if role not in ("t", "u", "y"):
        return None
    groups: dict[str, dict[str, Key]] = {}
    for k, ns in normed:
        for n in ns:
            if len(n) > 2 and n[0] in "tuy" and n[1] == "_":
                groups.setdefault(n[2:], {}).setdefault(n[0], k)
    triples = {tag: g for tag, g in groups.items() if "u" in g and "y" in g}
    if len(triples) > 1 and role != "t":  # the time: the caller pairs it with the chosen u
        which = ", ".join(repr(describe(g[role])) for g in triples.values() if role in g)
        if which:
            raise DataError(f"{where}: the file holds {len(triples)} records ({', '.join(sorted(triples))}); "
                            f"several columns could be {ROLE_WORDS[role]} ({which}); name the record's u and y "
                            f"(u_col=, y_col= in Python, --u-col, --y-col at the command line)")
    if len(triples) == 1:
        return next(iter(triples.values())).get(role)
    return None


def default_limit() -> int:
    """The most memory a reader may allocate: ``PIEZOHYST_MAX_MEMORY`` (bytes; K/M/G suffixes), else half the RAM."""
    env = os.environ.get("PIEZOHYST_MAX_MEMORY")
    if env:
        return parse_size(env, "PIEZOHYST_MAX_MEMORY")
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        if total > 0:
            return int(total // 2)
    except (AttributeError, ValueError, OSError):
        pass
    return 4 << 30


def parse_size(text: Any, what: str) -> int:
    """``"2G"`` -> 2147483648; plain numbers are bytes."""
    s = str(text).strip().upper().removesuffix("B").removesuffix("I")
    mult = 1
    for suffix, m in (("K", 1 << 10), ("M", 1 << 20), ("G", 1 << 30), ("T", 1 << 40)):
        if s.endswith(suffix):
            s, mult = s[:-1], m
            break
    try:
        v = float(s) * mult
    except ValueError:
        raise DataError(f"{what} must be a size in bytes such as 2000000000 or 2G, got {text!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise DataError(f"{what} must be a positive size in bytes, got {text!r}")
    return int(v)


def human(n: float) -> str:
    """Bytes as ``"1.5 GiB"``."""
    for unit, size in (("TiB", 1 << 40), ("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{int(n)} bytes"


def check_size(where: str, need: float, limit: int, what: str) -> None:
    """Refuse before allocating ``need`` bytes when that is over ``limit``."""
    if need > limit:
        raise DataError(f"{where}: {what} needs about {human(need)} of memory, over the limit of "
                        f"{human(limit)}; raise it with max_memory= in Python or the "
                        f"PIEZOHYST_MAX_MEMORY environment variable (e.g. PIEZOHYST_MAX_MEMORY=16G)")


def check_fs(fs: Any, where: str) -> float:
    """``fs`` as a positive finite float (DataError otherwise)."""
    if isinstance(fs, bool) or not isinstance(fs, (int, float, np.integer, np.floating)):
        raise DataError(f"{where}: the sample rate must be a number in Hz (fs= in Python, --fs at the "
                        f"command line), got {fs!r}")
    v = float(fs)
    if not math.isfinite(v) or v <= 0:
        raise DataError(f"{where}: the sample rate must be a positive number of Hz (fs= in Python, --fs "
                        f"at the command line), got {fs}")
    return v


def check_units_arg(units: Any, where: str) -> dict[str, Any]:
    if units is None:
        return {}
    if not isinstance(units, dict):
        raise DataError(f"{where}: units must be a dict such as {{'y': 'nm'}}, got {type(units).__name__}")
    bad = [k for k in units if k not in ("t", "u", "y")]
    if bad:
        raise DataError(f"{where}: units keys must be 't', 'u' or 'y', got {bad}")
    for role, value in units.items():  # an unknown unit or one of the wrong kind, before reading
        try:
            conversion(role, role, given=value)
        except UnitError as exc:
            raise DataError(f"{where}: {exc}") from None
    return dict(units)


#: Excel's serial dates (days since 1899-12-30) from 1954 to 2119
_EXCEL_SERIAL_DAYS = (20_000.0, 80_000.0)
#: a step below this, in seconds, is a sample rate above 5 MHz: no piezo record's
_IMPLAUSIBLE_STEP = 2e-7


def _refuse_excel_serial_days(where: str, label: str, how: str, t: np.ndarray, mean: float) -> None:
    """Refuse a time column without a unit whose values are Excel serial dates (days).

    A spreadsheet's date-time column saved as numbers reads 46354.5 for 2026-11-28 12:00, and
    steps of 1.16e-8 for a millisecond: taken as seconds, a record sampled at 86.4 MHz, which
    every model with dynamics and every model file then carried (found by fuzzing lab files).
    Refused only where both hold: values in the dates' range and a step no acquisition makes in
    seconds (``mean``: the mean step); the message names the unit to state."""
    if how != "assumed":
        return
    lo, hi = _EXCEL_SERIAL_DAYS
    if not (lo <= float(t[0]) and float(t[-1]) <= hi and 0.0 < mean < _IMPLAUSIBLE_STEP):
        return
    import datetime

    start = datetime.datetime(1899, 12, 30) + datetime.timedelta(days=float(t[0]))
    raise DataError(
        f"{where}: the time column {label!r} states no unit and looks like Excel serial dates (days since "
        f"1899-12-30: {float(t[0]):.10g} is {start:%Y-%m-%d %H:%M:%S}): read as seconds its steps of {mean:.3g} "
        f"would be a sample rate of {1.0 / mean:.4g} Hz; in days they are {mean * 86400:.6g} s. State its unit "
        f"(units={{'t': 'day'}} in Python, --units t=day at the command line)")


def _time_of_the_same_record(src: Source, ku: Key, ky: Key) -> Key | None:
    """``t_<tag>`` when u and y are ``u_<tag>`` and ``y_<tag>`` (:func:`_guess_in_triples`)."""
    nu, ny = normal_name(src.label(ku)), normal_name(src.label(ky))
    if not (nu.startswith("u_") and ny.startswith("y_") and nu[2:] == ny[2:] and nu[2:]):
        return None
    try:
        return src.find(f"t_{nu[2:]}", "t")
    except DataError:
        return None


# ------------------------------------------------------------------------------------------------
def _single_precision_resolution(raw: np.ndarray, t: np.ndarray) -> float | None:
    """The resolution (s) of a time column that holds single-precision numbers, at its largest
    value; None where it holds finer ones (told from its first samples at once, most often)."""
    def single(x: np.ndarray) -> bool:
        # a value beyond single precision's range is no single-precision number (it overflowed to
        # inf in the cast, with numpy's RuntimeWarning: found by fuzzing)
        with np.errstate(over="ignore", invalid="ignore"):
            return bool(np.array_equal(x, x.astype(np.float32).astype(np.float64)))

    if raw.size < 3 or raw[-1] == raw[0] or not single(raw[:1024]) or not single(raw):
        return None
    scale = float(t[-1] - t[0]) / float(raw[-1] - raw[0])  # the unit's factor to seconds
    return float(np.spacing(np.float32(np.max(np.abs(raw))))) * abs(scale)


def _single_precision_grid(t: np.ndarray, mean: float, resolution: float) -> np.ndarray | None:
    """The uniform grid ``t[0] + k mean`` where the time column's single-precision numbers are at
    most a quarter of a step apart (``resolution``, s) and every sample lies within that of the
    grid (steps jittering by it are no sign of a non-uniform record, while a dropped sample, half a
    step off the grid, still shows); None otherwise."""
    if not resolution <= 0.25 * mean:
        return None
    grid = t[0] + np.arange(t.size) * mean
    return grid if float(np.max(np.abs(t - grid))) <= resolution else None


def assemble(src: Source, *, t_col: Any = None, u_col: Any = None, y_col: Any = None,
             fs: Any = None, units: Any = None, resample: bool = False,
             max_memory: int | None = None, extra_meta: dict[str, Any] | None = None) -> Dataset:
    """Pick t, u and y from ``src``, convert, check and return the :class:`Dataset`."""
    where = src.where
    units = check_units_arg(units, where)
    if fs is not None:
        fs = check_fs(fs, where)
    limit = default_limit() if max_memory is None else int(max_memory)

    keys: dict[str, Key | None] = {}
    for role, given in (("u", u_col), ("y", y_col)):
        k = src.find(given, role) if given is not None else src.guess(role)
        if k is None:
            raise DataError(f"{where}: cannot tell which column is {ROLE_WORDS[role]}; name it "
                            f"({flag(role)}); {src.listing()}")
        keys[role] = k
    if keys["u"] == keys["y"]:
        raise DataError(f"{where}: u and y are both {src.label(keys['u'])!r}; name two different columns "
                        f"(u_col=, y_col= in Python, --u-col, --y-col at the command line)")
    kt: Key | None
    if t_col is not None:
        kt = src.find(t_col, "t")
    else:
        kt = src.guess("t")
        if kt is None:
            ct_u, ct_y = src.companion_time(keys["u"]), src.companion_time(keys["y"])
            if ct_u is not None and ct_y is not None and ct_u != ct_y:
                # two structs (Simulink To Workspace blocks u and y) each with its own time
                a, b = src.read([ct_u, ct_y], limit)
                if not np.array_equal(a, b):
                    raise DataError(f"{where}: u and y come with different time vectors ({src.label(ct_u)!r} and "
                                    f"{src.label(ct_y)!r}); name the time column ({flag('t')})")
            kt = ct_u if ct_u is not None else ct_y
        if kt is None:
            kt = _time_of_the_same_record(src, keys["u"], keys["y"])
    if kt is not None and kt in (keys["u"], keys["y"]):
        raise DataError(f"{where}: the time column {src.label(kt)!r} is also u or y; name the columns "
                        f"({flag('t')})")
    keys["t"] = kt

    roles = [r for r in ("t", "u", "y") if keys[r] is not None]
    arrays = dict(zip(roles, src.read([keys[r] for r in roles], limit)))
    labels = {r: src.label(keys[r]) for r in roles}
    n = {r: arrays[r].size for r in roles}
    if len(set(n.values())) > 1:
        sizes = ", ".join(f"{labels[r]!r} ({ROLE_WORDS[r]}) has {n[r]}" for r in roles)
        raise DataError(f"{where}: the columns differ in length: {sizes} samples")
    length = n["u"]
    # a shorter record in a table of several (``piezohyst rig`` writes one per frequency, a
    # spreadsheet pads its columns): the rows after it are empty in all the chosen columns
    empty = np.ones(length, dtype=bool)
    for r in roles:
        empty &= ~np.isfinite(arrays[r])
    tail = int(length - (np.flatnonzero(~empty)[-1] + 1)) if (~empty).any() else length
    if 0 < tail < length:
        length -= tail
        arrays = {r: a[:length] for r, a in arrays.items()}
    else:
        tail = 0
    if length < 2:
        raise DataError(f"{where}: needs at least 2 samples, found {length}")

    convs = {}
    out: dict[str, np.ndarray] = {}
    for r in roles:
        a = arrays[r]
        bad = ~np.isfinite(a)
        if bad.any():
            i = int(np.argmax(bad))
            count = int(bad.sum())
            more = f" ({count} values in {labels[r]!r} are not finite numbers)" if count > 1 else ""
            raise DataError(f"{where}: {src.explain(keys[r], i, float(a[i]))}{more}")
        try:
            convs[r] = conversion(r, labels[r], stated=src.stated_unit(keys[r]), given=units.get(r),
                                  name=src.unit_name(keys[r]))
        except WrongQuantityError as exc:
            if r == "y" and exc.quantity == "voltage":  # a displacement sensor's output, in volts
                raise DataError(f"{where}: {exc}; give the sensor's sensitivity as a factor to um, e.g. 10 "
                                f"for 10 um per volt (units={{'y': 10.0}} in Python, --units y=10 at the "
                                f"command line), or name another column ({flag('y')})") from None
            raise DataError(f"{where}: {exc}; name the right column ({flag(r)}) or give its unit "
                            f"(units={{'{r}': ...}} in Python, --units {r}=... at the command line)") from None
        except ScaledUnitError as exc:  # its message says what to give
            raise DataError(f"{where}: {exc}") from None
        except UnitError as exc:
            # (the hint said units={'u': 'um'} whatever the column: found by fuzzing)
            unit, example = {"t": ("s", "Time [s]"), "u": ("V", "Voltage [V]")}.get(r, ("um", "Displacement [um]"))
            raise DataError(f"{where}: {exc}; declare the unit (units={{'{r}': '{unit}'}} in Python, --units "
                            f"{r}={unit} at the command line) or write a known unit in the name, e.g. "
                            f"'{example}'") from None
        v = convs[r].apply(a)
        if not np.all(np.isfinite(v)):
            i = int(np.argmax(~np.isfinite(v)))
            raise DataError(f"{where}: at {src.locate(keys[r], i)}, {a[i]:g} {convs[r].unit} is too large to "
                            f"convert to {ROLES[r][1]}")
        out[r] = v

    meta: dict[str, Any] = dict(extra_meta or {})
    meta.update(src.meta)
    if tail:
        meta["empty_rows_dropped_at_the_end"] = tail
    meta["columns"] = {r: (labels[r] if keys[r] is not None else None) for r in ("t", "u", "y")}
    meta["units"] = {r: convs[r].to_meta() for r in roles}

    if "t" in out:
        t = out["t"]
        with np.errstate(over="ignore", invalid="ignore"):
            steps = np.diff(t)
        if not np.all(steps > 0):
            i = int(np.argmax(~(steps > 0)))
            raise DataError(f"{where}: time must increase from sample to sample, but at {src.locate(keys['t'], i + 1)} "
                            f"(t = {t[i + 1]:.10g} s) after t = {t[i]:.10g} s")
        if not np.all(np.isfinite(steps)):
            raise DataError(f"{where}: the time column {labels['t']!r} spans more than a float can hold")
        # uniform if every step is within the tolerance of the mean step (then of the median too);
        # only a record that is not needs the median (a sort) to say how far off it is
        mean = float(t[-1] - t[0]) / (t.size - 1)
        _refuse_excel_serial_days(where, labels["t"], convs["t"].how, t, mean)
        dev = np.abs(steps - mean)
        j = int(np.argmax(dev))
        med = mean
        if float(dev[j]) > UNIFORM_TOLERANCE * mean:
            med = float(np.median(steps))
            dev = np.abs(steps - med)
            j = int(np.argmax(dev))
        rel = float(dev[j]) / med
        # single precision rounds the steps (even within the tolerance: dt 0.14 % off)
        single = _single_precision_resolution(arrays["t"], t) if float(dev[j]) > 0.0 else None
        if single is not None:
            grid = _single_precision_grid(t, mean, single)
            if grid is not None:
                # (a float32 time column at t ~ 1000 s, steps of 1e-4 s rounded to 6.1e-5 or
                # 1.22e-4, was "not uniform", and resampled at the median 1.22e-4 s lost 18 % of
                # the record: found by fuzzing)
                meta["time_single_precision"] = {
                    "note": "the time column holds single-precision numbers, whose steps jitter by their "
                            "resolution: taken as uniform at the mean step", "dt": mean,
                    "largest_step_deviation": rel}
                out["t"] = t = grid
                med, rel, j = mean, 0.0, 0
        target_dt = 1.0 / fs if fs is not None else med
        if fs is not None and abs(med * fs - 1.0) > UNIFORM_TOLERANCE:
            raise DataError(f"{where}: the sample rate {fs:g} Hz disagrees with the time column "
                            f"{labels['t']!r} (1 / median step = {1.0 / med:.6g} Hz); give one of them "
                            f"(fs= in Python, --fs at the command line) or resample")
        if rel > UNIFORM_TOLERANCE:
            if single is not None and single > 0.25 * mean:
                # (resampling at the median step, itself rounded, lost 18 % of the record)
                raise DataError(
                    f"{where}: the time column {labels['t']!r} holds single-precision numbers, whose resolution "
                    f"at its end ({float(t[-1]):.6g} s) is {single:.3g} s, {100 * single / mean:.3g} % of its mean "
                    f"step of {mean:.6g} s: its steps cannot be told from its rounding, and resampling would "
                    f"follow the rounding; write the time in double precision, or drop the column and give the "
                    f"sample rate (fs= in Python, --fs at the command line)")
            if not resample:
                raise DataError(
                    f"{where}: the time column {labels['t']!r} is not uniformly sampled: the step to "
                    f"{src.locate(keys['t'], j + 1)} is {steps[j]:.6g} s against a median step of {med:.6g} s "
                    f"({100 * rel:.3g} % off; {100 * UNIFORM_TOLERANCE:g} % allowed); resample it onto a "
                    f"uniform grid (resample=True in Python, --resample at the command line) or fix the file")
            gap = int(np.argmax(steps))
            if steps[gap] > MAX_RESAMPLED_GAP * med:
                # (a 60 s pause in a 4 s record became 60,000 interpolated samples, and identify
                # scored its hold-out on that invented ramp: found by fuzzing)
                raise DataError(
                    f"{where}: the time column {labels['t']!r} has a gap of {steps[gap]:.6g} s (about "
                    f"{steps[gap] / med:.3g} median steps) at {src.locate(keys['t'], gap + 1)}: resampling would "
                    f"invent the record across it; split the file there (or identify on one side: --train)")
            span = float(t[-1] - t[0])
            count = math.floor(span / target_dt * (1 + 1e-12)) + 1
            check_size(where, 8.0 * 3 * count, limit, f"resampling to {count} samples")
            grid = t[0] + np.arange(count) * target_dt
            for r in ("u", "y"):
                out[r] = np.interp(grid, t, out[r])
            meta["resampled"] = {"method": "linear interpolation", "dt": target_dt,
                                 "samples_before": int(t.size), "samples_after": count,
                                 "largest_step_deviation": rel}
            out["t"] = grid
            t = grid
    else:
        if fs is None:
            raise DataError(f"{where}: no time column; give the sample rate (fs= in Python, --fs at the command "
                            f"line) or name the time column ({flag('t')})")
        with np.errstate(over="ignore"):  # a sample rate so low that k / fs overflows: refused just below
            out["t"] = np.arange(length) / fs
        meta["fs"] = fs

    if out["t"].size >= 2 and not np.all(np.isfinite(out["t"])):
        raise DataError(f"{where}: the time axis does not fit in a float")
    return Dataset._checked(out["t"], out["u"], out["y"], meta)
