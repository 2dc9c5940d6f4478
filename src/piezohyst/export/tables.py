"""Wave tables: the command a controller's wave generator plays, in the file its tools read.

:func:`write_table` writes what the file's extension says (:data:`TABLE_FORMATS`):

* ``.csv`` / ``.txt`` - text, columns ``t_s,x_d_um,u_V``, ``#`` comment lines saying what wrote it;
* ``.npy`` - the commands alone, 1-D float64 volts (``numpy.load``);
* ``.mat`` - MATLAB: ``u_V``, ``x_d_um``, ``t_s`` (columns), ``dt_s``, ``fs_hz``, and what wrote it
  (``producer``, ``model_kind``, ``model_sha256``), readable with ``load`` and ``scipy.io.loadmat``;
* ``.h`` - a C header: ``static const double NAME[NAME_LENGTH]`` with ``NAME_LENGTH`` and
  ``NAME_RATE_HZ`` (``NAME`` from the file name), for a controller's firmware.

:func:`periodic_table` makes a table that loops without a step: the compensator runs the reference
cycle after cycle, from its initial state, until the hysteresis (and every lag) has reached its
periodic steady state - two successive cycles' commands agree to ``tol`` volts - and one cycle of
that steady state is the table. Looped, its wrap-around step is then one of its ordinary steps.

:func:`resample_reference` puts a reference on the controller's table rate (linear interpolation:
no overshoot between samples). A model with dynamics (lags, the Bouc-Wen mechanics) is discretised
at the sample period it was identified at, so its compensator only runs at that rate: a table rate
that differs is refused (``compensate`` says so), never silently converted.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from .._validation import FloatArray, as_scalar, as_signal

#: The table files ``write_table`` (and ``piezohyst compensate -o``) write, by extension.
TABLE_FORMATS = (".csv", ".txt", ".npy", ".mat", ".h")


def table_format(path: Any) -> str:
    """The output format of ``path`` by its extension, or a ValueError listing the formats."""
    suffix = Path(path).suffix.lower()
    if suffix not in TABLE_FORMATS:
        raise ValueError(f"{path}: cannot write a command table as {suffix or 'a file without an extension'!r}; "
                         f"the formats are {', '.join(TABLE_FORMATS)} (by the file's extension)")
    return suffix


#: C99's keywords: a table named after one (int.h) would not compile (found by fuzzing).
C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto if inline int long "
    "register restrict return short signed sizeof static struct switch typedef union unsigned void volatile "
    "while _Bool _Complex _Imaginary".split())


#: Names a table must not take either: C++'s keywords (the header is included from C++ too) and
#: what a firmware's C file includes beside it (<math.h>, <stdlib.h>, <stdio.h>, <string.h>:
#: exp.h, NAN.h and main.h did not compile, class.h and new.h not as C++; found by fuzzing).
C_TAKEN = C_KEYWORDS | frozenset(
    "alignas alignof and and_eq asm bitand bitor bool catch char16_t char32_t char8_t class compl concept "
    "consteval constexpr constinit const_cast co_await co_return co_yield decltype delete dynamic_cast explicit "
    "export false friend mutable namespace new noexcept not not_eq nullptr operator or or_eq private protected "
    "public reinterpret_cast requires static_assert static_cast template this thread_local throw true try typeid "
    "typename using virtual wchar_t xor xor_eq "
    "main errno NAN INFINITY HUGE_VAL EOF NULL EXIT_SUCCESS EXIT_FAILURE RAND_MAX stdin stdout stderr "
    "acos asin atan atan2 cos sin tan acosh asinh atanh cosh sinh tanh exp exp2 expm1 frexp ldexp log log10 "
    "log1p log2 logb modf scalbn cbrt fabs hypot pow sqrt erf erfc lgamma tgamma ceil floor nearbyint rint "
    "round trunc fmod remainder copysign nan nextafter fdim fmax fmin fma isnan isinf isfinite signbit "
    "abs labs div rand srand malloc calloc realloc free exit abort atoi atof atol strtod qsort bsearch "
    "printf fprintf sprintf snprintf puts putchar getchar fopen fclose fread fwrite "
    "memcpy memmove memset memcmp strlen strcpy strncpy strcmp strncmp strcat strchr strstr".split())


def c_identifier(stem: str) -> str:
    """A C identifier from a file name's stem (never a C or C++ keyword nor a standard library name)."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", stem).strip("_") or "table"
    return "table_" + name if name[0].isdigit() or name in C_TAKEN else name


def write_table(path: Any, t: FloatArray, x_d: FloatArray, u: FloatArray, *, dt: float,
                comments: list[str], meta: dict[str, Any] | None = None, force: bool = False) -> Path:
    """Write a command table in the format its extension names (module docstring), atomically;
    an existing file is not overwritten without ``force``."""
    from .._fileio import atomic_write, check_writable

    out = check_writable(path, force)
    fmt = table_format(out)
    t, x_d, u = (as_signal(n, a) for n, a in (("t", t), ("x_d", x_d), ("u", u)))
    # (found by fuzzing: tables of different lengths were written to .mat, a NaN command to .csv,
    # dt=0 divided by zero and dt<0 wrote a negative rate; a comment could end the C comment, and
    # one given as a string was written a character per line)
    if not t.size == x_d.size == u.size:
        raise ValueError(f"t, x_d and u must have the same length, got {t.size}, {x_d.size} and {u.size}")
    dt = as_scalar("dt", dt, positive=True)
    if isinstance(comments, str):
        comments = [comments]
    from .c import c_comment

    comments = [c_comment(c) for c in comments]
    meta = dict(meta or {})

    if fmt in (".csv", ".txt"):
        def write(tmp: Path) -> None:
            with open(tmp, "w", encoding="utf-8") as fh:
                for line in comments:
                    fh.write(f"# {line}\n")
                fh.write("t_s,x_d_um,u_V\n")
                np.savetxt(fh, np.column_stack([t, x_d, u]), delimiter=",", fmt="%.17g")
    elif fmt == ".npy":
        def write(tmp: Path) -> None:
            with open(tmp, "wb") as fh:
                np.save(fh, np.ascontiguousarray(u), allow_pickle=False)
    elif fmt == ".mat":
        def write(tmp: Path) -> None:
            from scipy.io import savemat

            doc = {"u_V": u.reshape(-1, 1), "x_d_um": x_d.reshape(-1, 1), "t_s": t.reshape(-1, 1),
                   "dt_s": float(dt), "fs_hz": 1.0 / float(dt), "comments": "\n".join(comments)}
            for k, v in meta.items():
                doc[re.sub(r"[^A-Za-z0-9_]", "_", k)] = "" if v is None else v
            with open(tmp, "wb") as fh:
                savemat(fh, doc, do_compression=True, oned_as="column")
    else:  # ".h"
        name = c_identifier(out.stem)
        macro = name.upper()

        def write(tmp: Path) -> None:
            from .c import c_number

            vals = [c_number(v) for v in u]
            rows = ",\n    ".join(", ".join(vals[i:i + 4]) for i in range(0, len(vals), 4))
            text = "/*\n" + "".join(f" * {line}\n" for line in comments) + " */\n"
            text += (f"#ifndef {macro}_H\n#define {macro}_H\n\n"
                     f"#define {macro}_LENGTH {u.size}\n#define {macro}_RATE_HZ {c_number(1.0 / dt)}\n\n"
                     f"/* the command, V, one value per 1/{macro}_RATE_HZ s */\n"
                     f"static const double {name}[{macro}_LENGTH] = {{\n    {rows}\n}};\n\n#endif /* {macro}_H */\n")
            tmp.write_text(text, encoding="utf-8")

    return atomic_write(out, write, force=force)


def _check_resampled_size(count: float, seconds: float, fs: float, max_memory: int | None) -> None:
    """Refuse a resampled reference that would not fit in memory before allocating it: a time
    column in milliseconds read as seconds, or a rate in kHz given as Hz, asked for billions of
    samples and was killed by the system without a word (found by fuzzing)."""
    from ..data._columns import default_limit, human

    limit = default_limit() if max_memory is None else int(max_memory)
    need = 8.0 * RESAMPLED_ARRAYS * count
    if not need <= limit:  # (also NaN)
        raise ValueError(f"the reference lasts {seconds:.6g} s: at {fs:.6g} Hz that is {count:.4g} samples, about "
                         f"{human(need)} of memory, over the limit of {human(limit)}. Is its time column in seconds "
                         f"and the rate in Hz (fs= in Python, --fs at the command line)? PIEZOHYST_MAX_MEMORY "
                         f"raises the limit")


#: Arrays of the resampled reference's length that a command keeps at once (time, reference,
#: command, output): what :func:`resample_reference`'s memory check counts.
RESAMPLED_ARRAYS = 4


def resample_reference(t: FloatArray, x: FloatArray, fs: float, *, periodic: bool = False,
                       max_memory: int | None = None) -> tuple[FloatArray, FloatArray]:
    """``x(t)`` on a grid of ``fs`` Hz from ``t[0]`` (linear interpolation).

    Without ``periodic`` the grid ends at ``t[-1]``; with it the reference is one period of
    ``len(x)`` samples (its duration ``len(x) * dt``) and the grid has ``round(duration * fs)``
    samples over that period, interpolated across the wrap-around. A grid that would need more than
    ``max_memory`` bytes (default ``PIEZOHYST_MAX_MEMORY``, else half the RAM) is refused.
    """
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"the table rate must be a positive number of Hz, got {fs}")
    # (found by fuzzing: NaN in x gave a NaN table, different lengths numpy's "fp and xp", empty
    # arrays an IndexError, a time column that runs backwards "shorter than two samples")
    t = as_signal("t", t, min_length=2)
    x = as_signal("x", x, min_length=2)
    if t.size != x.size:
        raise ValueError(f"t and x must have the same length, got {t.size} and {x.size}")
    if not np.all(np.diff(t) > 0):
        raise ValueError("t must increase from sample to sample")
    if max_memory is not None:  # ("1G" as load_dataset takes it; -1 said "over the limit of -1 bytes")
        from ..data._columns import parse_size

        max_memory = parse_size(max_memory, "max_memory")
    dt_old = float(np.median(np.diff(t))) if t.size > 1 else 1.0 / fs
    if periodic:
        period = x.size * dt_old
        count = period * fs
        _check_resampled_size(count, period, fs, max_memory)
        n = int(round(count))
        if n < 2:
            raise ValueError(f"one period ({period:.6g} s) is shorter than two samples at {fs:g} Hz")
        tn = t[0] + np.arange(n) / fs
        return tn, np.interp(tn - t[0], t - t[0], x, period=period)
    count = (t[-1] - t[0]) * fs * (1 + 1e-12)
    _check_resampled_size(count, float(t[-1] - t[0]), fs, max_memory)
    n = int(math.floor(count)) + 1
    if n < 2:
        raise ValueError(f"the reference ({t[-1] - t[0]:.6g} s) is shorter than two samples at {fs:g} Hz")
    tn = t[0] + np.arange(n) / fs
    return tn, np.interp(tn, t, x)


def periodic_table(compensator: Any, period: FloatArray, *, tol: float, max_samples: int = 5_000_000) -> tuple[FloatArray, dict[str, Any]]:
    """One cycle of the compensator's periodic steady state for the repeating reference ``period``
    (module docstring). Returns the table and what it took: ``cycles``, ``converged``, the last
    cycle-to-cycle change, the wrap-around step and the largest step inside (V)."""
    x = np.asarray(period, dtype=np.float64)
    n = x.size
    compensator.reset()
    prev = None
    cycles = 0
    change = math.inf
    max_cycles = max(2, max_samples // max(n, 1))
    cur = np.empty(n)
    limited = 0
    while cycles < max_cycles:
        before = int(getattr(compensator, "limited", 0))
        for k in range(n):
            cur[k] = compensator.step(float(x[k]))
        limited = int(getattr(compensator, "limited", 0)) - before
        cycles += 1
        if prev is not None:
            change = float(np.max(np.abs(cur - prev)))
            if change <= tol:
                break
        prev = cur.copy()
    compensator.reset()
    table = cur.copy()
    inner = float(np.max(np.abs(np.diff(table)))) if n > 1 else 0.0
    info = {"cycles": cycles, "converged": bool(change <= tol), "last_cycle_change_V": change, "tolerance_V": tol,
            "wrap_step_V": float(abs(table[0] - table[-1])), "largest_inner_step_V": inner,
            "limited_samples": limited}
    return table, info
