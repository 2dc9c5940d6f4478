"""Text tables read with pandas: the layout is sniffed from the first 64 KiB, the body parsed in C.

Sniffed: the encoding (UTF-8 with or without a byte-order mark, UTF-16 with a mark, else cp1252
or latin-1), the delimiter (tab, semicolon, comma, bar or runs of whitespace) and the decimal
mark (a decimal comma goes with any delimiter but the comma), ``#`` comment lines, lines of
preamble before the table (skipped and counted in ``meta``), a header line, a line of units
under it, an unnamed first column (a pandas index, dropped) and a trailing delimiter. Only the
columns asked for are parsed. Problems found by pandas are located again line by line (slowly,
only then) so that the message names the line and the column.
"""

from __future__ import annotations

import codecs
import csv
import json
import re
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._columns import ROLE_WORDS, Key, check_size, flag, guess_by_alias, match_name
from ._dataset import DataError
from ._units import is_unit

HEAD_BYTES = 1 << 16
#: (delimiter, decimal mark); None is runs of whitespace
CANDIDATES: list[tuple[str | None, str]] = [
    ("\t", "."), ("\t", ","), (";", "."), (";", ","), (",", "."), ("|", "."), ("|", ","),
    (None, "."), (None, ","),
]
#: a number with a decimal comma grouped in thousands by points (``1.010,2``, as German Excel
#: writes a cell formatted so)
_GROUPED_BODY = r"\d{1,3}(?:\.\d{3})+(?:,\d*)?"
#: a number as one field holds it, by decimal mark (unanchored: :func:`_all_numbers` joins them)
_NUM_BODY = {".": r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?",
             ",": r"[+-]?(?:" + _GROUPED_BODY + r"|\d+,?\d*|,\d+)(?:[eE][+-]?\d+)?"}
_NUM = {mark: re.compile("^" + body + "$") for mark, body in _NUM_BODY.items()}
_GROUPED = re.compile(r"^[+-]?" + _GROUPED_BODY + "$")
_SPECIAL = re.compile(r"^[+-]?(?:inf|infinity)$", re.IGNORECASE)
#: what pandas reads as missing (NaN)
_NA = {"", "na", "n/a", "nan", "-nan", "+nan", "null", "none", "#n/a", "<na>", "1.#ind", "1.#qnan",
       "-1.#ind", "-1.#qnan", "#n/a n/a", "-na"}
_RUN = 8  # data lines that must mostly agree where the table starts
_SAMPLE = 200  # content lines looked at to find the table's layout
_DELIM_NAMES = {"\t": "tab", ";": "semicolon", ",": "comma", "|": "bar", None: "whitespace"}
_LINE_SPLIT = re.compile(r"\r\n|\r|\n")


def _cls(field_text: str, decimal: str) -> str:
    """'n' a number, 'e' empty or missing, 'x' text."""
    f = field_text.strip().strip('"').strip()
    if f.lower() in _NA:
        return "e"
    if _NUM[decimal].match(f) or _SPECIAL.match(f):
        return "n"
    return "x"


#: (delimiter, decimal) -> a whole line of numbers only: such a line's classes are all "n" without
#: splitting it (most lines of a data file; the rest goes field by field through _cls)
def _all_numbers(delim: str | None, decimal: str) -> re.Pattern[str]:
    space = r"\s" if delim is None or not delim.isspace() else r"[^\S" + re.escape(delim) + "]"  # not the delimiter
    sep = r"\s+" if delim is None else space + "*" + re.escape(delim) + space + "*"
    num = _NUM_BODY[decimal]
    return re.compile(space + "*" + num + "(?:" + sep + num + ")*" + space + "*")


_ALL_NUMBERS = {(d, dec): _all_numbers(d, dec) for d, dec in CANDIDATES}


def _classify(line: str, delim: str | None, decimal: str) -> tuple[str, ...]:
    """The class of every field of a line (comments cut off), as ``_cls`` gives them."""
    fast = _ALL_NUMBERS.get((delim, decimal))
    if fast is not None and '"' not in line and "#" not in line and fast.fullmatch(line):
        return ("n",) * (len(line.split()) if delim is None else line.count(delim) + 1)
    return tuple(_cls(f, decimal) for f in _split(line.split("#", 1)[0], delim))


def _split(line: str, delim: str | None) -> list[str]:
    if delim is None:
        return line.split()
    if '"' in line:
        try:
            return next(csv.reader([line], delimiter=delim, skipinitialspace=True))
        except (csv.Error, StopIteration):
            pass
    return line.split(delim)


class NotText(Exception):
    """The bytes are not a text table (the caller says which formats are)."""


@dataclass
class Layout:
    """What the sniffer found (also what ``meta`` reports)."""

    encoding: str
    bom: int
    delimiter: str | None
    decimal: str
    skip: int  # physical lines before the first data line
    nfields: int
    names: list[str] | None  # header names, one per physical field
    header_line: int | None  # 1-based
    units: list[str] | None
    offered: list[int]  # physical field numbers the user can pick
    preamble: int  # non-comment lines skipped that are neither header nor units
    index_dropped: bool
    bytes_per_row: float
    data_offset: int  # bytes before the first data line
    trailing: bool  # every row ends with a delimiter (an empty last field, not offered)
    saved_meta: dict[str, Any] = field(default_factory=dict)
    header_mismatch: str | None = None
    units_line: bool = False  # ``units`` came from the line under the header
    text_columns: tuple[int, ...] = ()  # columns whose rows hold text, not numbers (clock times?)
    thousands: str | None = None  # "." where numbers with a decimal comma are grouped (1.010,2)


def detect_encoding(head: bytes) -> tuple[str, int]:
    """(encoding, length of the byte-order mark); raise NotText for binary data."""
    if head.startswith(codecs.BOM_UTF8):
        return "utf-8", 3
    if head.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        return "utf-16", 0  # the codec reads the mark itself
    sample = head[:4096]
    if b"\x00" in sample:
        even, odd = sample[0::2], sample[1::2]
        if odd.count(0) > 0.9 * len(odd) and even.count(0) < 0.1 * len(even):
            return "utf-16-le", 0
        if even.count(0) > 0.9 * len(even) and odd.count(0) < 0.1 * len(odd):
            return "utf-16-be", 0
        raise NotText("it contains NUL bytes")
    try:
        codecs.getincrementaldecoder("utf-8")().decode(head, final=False)
        return "utf-8", 0
    except UnicodeDecodeError:
        pass
    try:
        head.decode("cp1252")
        return "cp1252", 0
    except UnicodeDecodeError:
        return "latin-1", 0


def sniff(path: Path, head: bytes, size: int, delimiter: str | None = None,
          decimal: str | None = None, encoding: str | None = None) -> Layout:
    """The layout of a text table from its first bytes (DataError when there is no table)."""
    where = str(path)
    given = encoding is not None
    if encoding is None:
        encoding, bom = detect_encoding(head)
    else:
        # (found by fuzzing: an int failed in Python's words, codecs that are not text encodings
        # such as "rot13" or "zlib" failed deep inside, and a given encoding the file did not decode
        # in was silently replaced by latin-1)
        if not isinstance(encoding, str):
            raise DataError(f"{where}: encoding must be the name of a text encoding (e.g. 'utf-8', 'cp1252'), "
                            f"got {encoding!r}")
        try:
            info = codecs.lookup(encoding)
        except LookupError:
            raise DataError(f"{where}: unknown text encoding {encoding!r}") from None
        if not getattr(info, "_is_text_encoding", True):
            raise DataError(f"{where}: {encoding!r} is not a text encoding (it is a codec of bytes or of text to text)")
        bom = 3 if encoding.lower().replace("_", "-") in ("utf-8", "utf8") and head.startswith(codecs.BOM_UTF8) else 0
    truncated = size > len(head)
    try:
        text = codecs.getincrementaldecoder(encoding)(errors="strict").decode(head[bom:], final=not truncated)
    except (UnicodeDecodeError, UnicodeError) as exc:
        if given:
            raise DataError(f"{where}: the file is not {encoding} text ({exc}); give the encoding it is in, or "
                            "leave it out to have it found") from None
        if encoding.startswith("utf-16"):
            raise NotText("it is not valid UTF-16 text") from None
        text = head[bom:].decode("latin-1")
        encoding = "latin-1"
    text = text.lstrip("\ufeff")
    if "\x00" in text:
        raise NotText("it contains NUL characters")
    # (str.split is 20x quicker than the pattern; the same lines when only "\n" ends them)
    lines = text.split("\n") if "\r" not in text else _LINE_SPLIT.split(text)
    body = "".join(ln for ln in lines[:400] if not ln.lstrip().startswith("#"))[:4096]
    bad = sum(1 for ch in body if ord(ch) < 32 and ch not in "\t\f\v")
    if bad > 0.01 * max(1, len(body)):
        raise NotText("it contains control characters")
    if truncated:
        if len(lines) < 2:
            raise DataError(f"{where}: line 1 is longer than {HEAD_BYTES} bytes; not a table of numbers")
        lines = lines[:-1]  # the last line may be cut off
    elif lines and lines[-1] == "":
        lines = lines[:-1]

    saved_meta: dict[str, Any] = {}
    content: list[int] = []  # physical line numbers (0-based) with content
    for i, ln in enumerate(lines):
        s = ln.strip()
        if not s:
            continue
        if s.startswith("#"):
            if s.startswith("# meta:"):
                try:
                    m = json.loads(s[len("# meta:"):])
                    if isinstance(m, dict):
                        saved_meta = m
                except ValueError:
                    pass
            continue
        content.append(i)
    if not content:
        raise DataError(f"{where}: no data (the file is empty or holds only comments)")

    present = "".join(lines[li] for li in content[:_SAMPLE])
    candidates = [(delimiter, decimal or ".")] if delimiter is not None else \
        [c for c in CANDIDATES if (decimal is None or c[1] == decimal)
         and (c[0] is None or c[0] in present) and (c[1] == "." or decimal is not None or "," in present)]
    if delimiter is not None and decimal is None and delimiter != ",":
        candidates.append((delimiter, ","))
    cache: dict[tuple[int, str | None, str], tuple[str, ...]] = {}

    def classes(li: int, cand: tuple[str | None, str]) -> tuple[str, ...]:
        key = (li, cand[0], cand[1])
        if key not in cache:
            cache[key] = _classify(lines[li], cand[0], cand[1])
        return cache[key]

    sample = content[:_SAMPLE]

    def pattern(cand: tuple[str | None, str]) -> tuple[tuple[int, ...], int, list[str]] | None:
        """(score, field count, class per column) of the table this candidate sees, if any."""
        sigs = [classes(li, cand) for li in sample]
        counts = Counter(len(c) for c in sigs if "n" in c)
        if not counts:
            return None
        n = max(counts, key=lambda k: (counts[k], k))
        rows = [c for c in sigs if len(c) == n and "n" in c]  # a header does not vote
        cols = []
        for j in range(n):
            seen = Counter(c[j] for c in rows if c[j] != "e")
            cols.append("n" if seen["n"] >= seen["x"] and seen["n"] > 0 else "x" if seen else "e")
        numeric = cols.count("n")
        if numeric == 0:
            return None
        matches = sum(1 for c in sigs if fits_pattern(c, n, cols))
        if matches == 0:  # column classes voted from rows none of which fits them all (found by fuzzing)
            return None
        return (matches, int("x" not in cols), numeric, n), n, cols

    def fits_pattern(c: tuple[str, ...], n: int, cols: list[str]) -> bool:
        return len(c) == n and all(x == "e" or x == want or want == "e" for x, want in zip(c, cols))

    found = [(pt, cand) for cand in candidates if (pt := pattern(cand)) is not None]
    if not found:
        if len(content) == 1:
            raise DataError(f"{where}: only one line ({lines[content[0]].strip()[:60]!r}) and no data rows")
        raise DataError(f"{where}: no table of numbers found in the first {len(sample)} lines "
                        f"(tried tab, semicolon, comma, bar and whitespace delimiters, decimal point and comma)")
    found.sort(key=lambda pc: pc[0][0], reverse=True)  # stable: the earlier candidate wins ties
    (_score, n, cols), best = found[0]
    delim, dec = best
    ok = [fits_pattern(classes(li, best), n, cols) for li in sample]
    # the first fitting line most of whose next lines fit too (a preamble line may fit by chance),
    # else simply the first fitting line
    start = next((k for k, good in enumerate(ok)
                  if good and 2 * sum(ok[k + 1:k + 1 + _RUN]) >= len(ok[k + 1:k + 1 + _RUN])),
                 ok.index(True))
    # a ragged or damaged first data row still belongs to the table: walk back over lines that
    # start with a number (preamble lines start with a key: "Samples;1000")
    while start > 0 and classes(sample[start - 1], best)[:1] == ("n",) and not ok[start - 1]:
        start -= 1
    first_data = content[start]
    run = [li for li, good in zip(sample[start:start + _RUN], ok[start:start + _RUN]) if good]
    trailing = n > 1 and all(classes(li, best)[-1] == "e" for li in run)

    names: list[str] | None = None
    units: list[str] | None = None
    units_line = False  # the units stand in the line under the header
    header_line: int | None = None
    mismatch: str | None = None
    before = content[:start]

    def fields_of(li: int) -> list[str]:  # a header may hold "#" ("Sample #"): no comment stripping
        return [f.strip().strip('"').strip() for f in _split(lines[li], delim)]

    def fits(fs_: list[str]) -> bool:
        return len(fs_) == n or (trailing and len(fs_) == n - 1)

    def comment_header() -> list[str] | None:
        """numpy.savetxt writes its header as a comment (``# Time [s],Voltage [V],...``) right
        above the data: taken for one where the file has none (it said "no header line", and
        read by number its units were lost: found by fuzzing)."""
        li = first_data - 1
        while li >= 0 and not lines[li].strip():
            li -= 1
        if li < 0 or not lines[li].strip().startswith("#") or lines[li].strip().startswith("# meta:"):
            return None
        text = lines[li].strip().lstrip("#").strip()
        fs_ = [f.strip().strip('"').strip() for f in _split(text, delim)]
        if not fits(fs_) or not all(fs_[:n - int(trailing)]) or all(_cls(f, dec) == "n" for f in fs_):
            return None
        return fs_

    def without_extra_field(fs_: list[str]) -> list[str]:
        """A header with one field more than the rows: an empty one (a trailing delimiter on the
        header line alone) or LabVIEW's ``Comment`` column, which its rows leave out."""
        if not trailing and len(fs_) == n + 1 and fs_[-1].strip().lower() in ("", "comment"):
            return fs_[:-1]
        return fs_  # (with rows that end in a delimiter too, the extra field already lines up)

    if before:
        cand = without_extra_field(fields_of(before[-1]))
        if fits(cand):
            bare = [_unbracketed(f) for f in cand]  # "[s]", "(V)" as units rows write them too
            if len(before) >= 2 and all(is_unit(f) for f in bare) and fits(fields_of(before[-2])) and \
                    not all(is_unit(_unbracketed(f)) for f in fields_of(before[-2])):
                units, names, header_line = bare, fields_of(before[-2]), before[-2] + 1
                units_line = True
            else:
                names, header_line = cand, before[-1] + 1
        else:
            mismatch = (f"line {before[-1] + 1} has {len(cand)} fields but the data rows have "
                        f"{n - int(trailing)}")
    if names is None and not before:
        names = comment_header()
        if names is not None:
            header_line = None  # a comment: the data start right after it
    if names is not None:
        names = names + [""] * (n - len(names))
        if units is not None:
            units = units + [""] * (n - len(units))
    offered = list(range(n - 1 if trailing else n))
    index_dropped = False
    if names is not None and len(offered) >= 2 and names[0] in ("", "Unnamed: 0"):
        offered = offered[1:]
        index_dropped = True
    # the lines before the data that are neither header nor units line (a header in a comment is
    # not among them)
    preamble = len(before) - (0 if names is None or header_line is None else 2 if units_line else 1)

    # (German thousands points, "1.010,2" in a semicolon file, made the comma the delimiter and
    # the table four columns of text: found by fuzzing lab files)
    thousands = "." if dec == "," and delim != "." and any(
        _GROUPED.match(f.strip().strip('"').strip()) for li in sample[start:] for f in _split(lines[li], delim)) \
        else None
    rows_text = "\n".join(lines[li] for li in content[start:])
    row_bytes = (len(rows_text.encode(encoding, errors="replace")) + 1) / max(1, len(content) - start)
    offset = bom + len("\n".join(lines[:first_data]).encode(encoding, errors="replace")) + (1 if first_data else 0)
    return Layout(encoding=encoding, bom=bom, delimiter=delim, decimal=dec, skip=first_data, nfields=n,
                  names=names, header_line=header_line, units=units, units_line=units_line, offered=offered,
                  text_columns=tuple(j for j, c in enumerate(cols) if c == "x"), preamble=preamble,
                  index_dropped=index_dropped, bytes_per_row=max(2.0, float(row_bytes)),
                  data_offset=offset, trailing=trailing, saved_meta=saved_meta, header_mismatch=mismatch,
                  thousands=thousands)


def _unbracketed(field_text: str) -> str:
    """A units row's field without its brackets: ``[mm]`` -> ``mm`` (a row of them was taken for
    the header, and the names above it lost: found by fuzzing)."""
    f = field_text.strip()
    if len(f) >= 2 and (f[0], f[-1]) in (("[", "]"), ("(", ")"), ("{", "}")):
        return f[1:-1].strip()
    return f


# ------------------------------------------------------------------------------------------------
#: pandas reads a file of at least this many bytes with several threads (pandas >= 3.1)
_PANDAS_PARALLEL_BYTES = 5 * 1024 * 1024


def _parallel_read_beats_usecols(pd: Any, size: int, wanted: int, fields: int) -> bool:
    """Whether to read every column rather than pass ``usecols`` (which keeps pandas serial).

    pandas 3.1 reads a large local file in several threads, but only without ``usecols``.
    Measured on 10^6 rows, 2 threads: 4 fields of which 3 wanted, 0.064 s for all of them in
    parallel against 0.095 s for the 3 serially; 6 fields of which 3, 0.130 against 0.114 s. So
    with one field more than wanted (an index or a spare column) all of them are read; with more,
    or where pandas reads serially (older pandas, one CPU, a small file), only those wanted.
    """
    if fields > wanted + 1 or size < _PANDAS_PARALLEL_BYTES:
        return False
    try:
        threads = pd.get_option("mode.max_threads")  # the option came with the parallel reader
    except (KeyError, AttributeError, pd.errors.OptionError):
        return False
    if threads is None:
        from .._blas import usable_cores

        threads = usable_cores()
    return int(threads) > 1


class TextSource:
    """A text table as a :class:`~piezohyst.data._columns.Source`; keys are physical field numbers."""

    def __init__(self, path: Path, head: bytes, size: int, *, delimiter: str | None = None,
                 decimal: str | None = None, encoding: str | None = None) -> None:
        self.path = path
        self.where = str(path)
        self.size = size
        self.lay = sniff(path, head, size, delimiter, decimal, encoding)
        lay = self.lay
        self.meta: dict[str, Any] = {
            "format": "text", "encoding": lay.encoding, "delimiter": _DELIM_NAMES.get(lay.delimiter, lay.delimiter),
            "decimal": lay.decimal,
        }
        if lay.thousands is not None:
            self.meta["thousands"] = lay.thousands
        if lay.header_line is not None:
            self.meta["header_line"] = lay.header_line
        if lay.units is not None:
            self.meta["units_line"] = lay.header_line + 1 if lay.header_line else None
        if lay.preamble:
            self.meta["skipped_lines"] = lay.preamble
        if lay.index_dropped:
            self.meta["index_column_dropped"] = True
        self._cache_rows: dict[int, int] = {}

    @property
    def has_header(self) -> bool:
        return self.lay.names is not None

    def names(self) -> list[str]:
        if self.lay.names is None:
            return [str(i) for i in range(len(self.lay.offered))]
        return [self.lay.names[i] for i in self.lay.offered]

    def listing(self) -> str:
        if self.lay.names is None:
            hint = f" ({self.lay.header_mismatch})" if self.lay.header_mismatch else ""
            return f"the file has no header line{hint} and {len(self.lay.offered)} columns, numbered from 0"
        shown = ", ".join(repr(n) for n in self.names()[:12])
        return f"the columns are [{shown}{', ...' if len(self.lay.offered) > 12 else ''}]"

    def _named(self) -> list[tuple[Key, list[str]]]:
        return [(phys, [name]) for phys, name in zip(self.lay.offered, self.names())]

    def find(self, given: Any, role: str) -> Key:
        n = len(self.lay.offered)
        if isinstance(given, str) and self.lay.names is None and given.strip().isdigit():
            given = int(given)
        if isinstance(given, (int, np.integer)) and not isinstance(given, bool):
            if not 0 <= int(given) < n:
                raise DataError(f"{self.where}: column {int(given)} does not exist ({ROLE_WORDS[role]}, "
                                f"{flag(role)}); {self.listing()}")
            return self.lay.offered[int(given)]
        if not isinstance(given, str):
            raise DataError(f"{self.where}: a column is named by a string or a 0-based number, got {given!r} "
                            f"({flag(role)})")
        hits = match_name(given, self._named())
        if not hits and given.strip().isdigit() and int(given) < n:
            return self.lay.offered[int(given)]
        if len(hits) > 1:
            raise DataError(f"{self.where}: {given!r} matches several columns; give its 0-based number "
                            f"({flag(role)}); {self.listing()}")
        if not hits:
            raise DataError(f"{self.where}: unknown column {given!r} ({ROLE_WORDS[role]}); {self.listing()}")
        return hits[0]

    def guess(self, role: str) -> Key | None:
        if self.lay.names is None:
            return None
        return guess_by_alias(self._named(), role, self.where, describe=self.label)

    def companion_time(self, key: Key) -> Key | None:
        return None

    def label(self, key: Key) -> str:
        if self.lay.names is None:
            return str(self.lay.offered.index(key)) if key in self.lay.offered else str(key)
        return self.lay.names[int(key)]  # type: ignore[call-overload]

    def unit_name(self, key: Key) -> str:
        return self.label(key)

    def stated_unit(self, key: Key) -> str | None:
        if self.lay.units is None:
            return None
        u = self.lay.units[int(key)]  # type: ignore[call-overload]
        return u or None

    # -- reading ---------------------------------------------------------------------------------
    def estimate_rows(self) -> float:
        return max(0.0, self.size - self.lay.data_offset) / self.lay.bytes_per_row

    def read(self, keys: Sequence[Key], limit: int) -> list[np.ndarray]:
        cols = [int(k) for k in keys]  # type: ignore[call-overload]
        rows = self.estimate_rows()
        check_size(self.where, rows * len(cols) * 8 * 2.5 + 4 * HEAD_BYTES, limit,
                   f"reading {len(cols)} columns of about {rows:,.0f} rows")
        clocks = [k for k in cols if k in self.lay.text_columns and self._clock_times(k)]
        df = self._parse(cols, text=clocks)
        out = []
        for k in cols:
            col = df[f"c{k}"]
            if k in clocks:
                out.append(self._seconds(k, col))
                continue
            if col.dtype.kind not in "fiu":  # pragma: no cover - dtype=float64 is asked for
                raise DataError(f"{self.where}: column {self.label(k)!r} is not numeric")
            out.append(col.to_numpy(dtype=np.float64))
        return out

    def _clock_times(self, key: int) -> bool:
        """Whether a text column's first rows are dates and clock times (``2024-03-05
        14:00:00.000``, ``14:00:00.000``): read as seconds from the first sample, as a
        spreadsheet's or Parquet's are (a CSV's was "not a number", even with the sample rate
        given: found by fuzzing)."""
        import pandas as pd

        sample = []
        for _, fields in self._data_rows():
            if key < len(fields) and fields[key]:
                sample.append(fields[key])
            if len(sample) >= 20:
                break
        clock = [f for f in sample if re.search(r"\d:\d\d", f)]  # (most: a garbled row is named later)
        if not sample or len(clock) < 0.8 * len(sample):
            return False
        try:
            parsed = pd.to_datetime(pd.Series(clock), format="mixed")
        except (ValueError, TypeError, OverflowError):
            return False
        return bool(parsed.notna().all())

    def _seconds(self, key: int, col: Any) -> np.ndarray:
        import pandas as pd

        when = pd.to_datetime(col, format="mixed", errors="coerce")
        if when.isna().any():
            i = int(np.argmax(when.isna().to_numpy()))
            raise DataError(f"{self.where}: at {self.locate(key, i)}, {str(col.iloc[i])[:40]!r} in {self.label(key)!r} "
                            f"is not a clock time as the rows before are")
        self.meta.setdefault("clock_times", []).append(self.label(key))
        return np.asarray((when - when.iloc[0]).dt.total_seconds().to_numpy(dtype=np.float64), dtype=np.float64)

    def read_all(self, limit: int) -> np.ndarray:
        """Every offered column as a rows x columns float64 array (NaN allowed)."""
        cols = self.read(self.lay.offered, limit)
        return np.column_stack(cols) if cols else np.empty((0, 0))

    def _parse(self, keys: list[int], text: Sequence[int] = ()) -> Any:
        import pandas as pd

        lay = self.lay
        dtype: Any = np.float64 if not text else {f"c{i}": (str if i in text else np.float64)
                                                   for i in range(lay.nfields)}
        kwargs: dict[str, Any] = {
            "sep": lay.delimiter if lay.delimiter is not None else r"\s+", "decimal": lay.decimal,
            "skiprows": lay.skip, "header": None, "names": [f"c{i}" for i in range(lay.nfields)],
            "index_col": False, "dtype": dtype, "engine": "c", "skip_blank_lines": True,
        }
        if lay.thousands is not None:
            kwargs["thousands"] = lay.thousands
        if len(keys) < lay.nfields:
            if _parallel_read_beats_usecols(pd, self.size, len(keys), lay.nfields):
                try:  # the spare column may hold what is no number: then only the wanted ones
                    return self._checked(pd.read_csv(self.path, encoding=lay.encoding, **kwargs))
                except Exception:  # noqa: BLE001, S110 - the passes below read it, or say why not
                    pass
            kwargs["usecols"] = keys  # parsing fewer columns pays; asking for all of them costs
        if lay.encoding.startswith("utf-16") or lay.encoding == "utf-8":
            encodings = [lay.encoding]
        else:  # a cp1252 or latin-1 header over an ASCII body: the body parses fastest as UTF-8
            encodings = ["utf-8", lay.encoding]
        # the fast pass knows no comments and no quoted fields after spaces (each slows pandas
        # by half); a file that needs them fails it and is read by the tolerant pass
        passes = [{}, {"comment": "#", "skipinitialspace": lay.delimiter is not None}]
        df = None
        problem: BaseException | None = None
        for extra in passes:
            for enc in encodings:
                try:
                    df = pd.read_csv(self.path, encoding=enc, **kwargs, **extra)
                    break
                except UnicodeDecodeError:
                    continue
                except MemoryError:
                    raise DataError(f"{self.where}: ran out of memory reading it; lower PIEZOHYST_MAX_MEMORY so "
                                    f"such files are refused up front, or split the file") from None
                except Exception as exc:  # ValueError, ParserError, OverflowError, OSError, ...
                    problem = exc
                    break
            if df is not None:
                break
        if df is None:
            if problem is not None and self._late_thousands(keys):
                return self._parse(keys, text)
            if problem is None:
                raise DataError(f"{self.where}: cannot decode the file as {lay.encoding} text")
            msg = self._scan(keys)
            if msg is None:
                first = str(problem).strip().splitlines()[0] if str(problem).strip() else type(problem).__name__
                msg = f"cannot parse it as a {self.meta['delimiter']}-separated table ({first[:200]})"
            raise DataError(f"{self.where}: {msg}")
        return self._checked(df)

    def _late_thousands(self, keys: list[int]) -> bool:
        """True (and the layout told) where a decimal-comma file groups thousands by points only
        in rows after those the sniffer saw (a displacement in nm that passes 1000 late)."""
        lay = self.lay
        if lay.decimal != "," or lay.thousands is not None or lay.delimiter == ".":
            return False
        for _lineno, fields in self._data_rows():
            if any(k < len(fields) and _GROUPED.match(fields[k]) for k in keys):
                lay.thousands = self.meta["thousands"] = "."
                return True
        return False

    def _checked(self, df: Any) -> Any:
        if len(df) == 0:
            what = "a header" if self.lay.names is not None else "comments"
            raise DataError(f"{self.where}: {what} but no data rows")
        return df

    # -- the slow path: walk the lines to say where a problem is -----------------------------------
    def _lines(self) -> Any:
        enc = "utf-8-sig" if self.lay.encoding == "utf-8" else self.lay.encoding
        return open(self.path, encoding=enc, errors="replace", newline="")  # the caller closes it

    def _data_rows(self) -> Any:
        """(line number, fields) for each data row, as pandas counts them."""
        with self._lines() as fh:
            for lineno, line in enumerate(fh, start=1):
                if lineno <= self.lay.skip:
                    continue
                body = line.split("#", 1)[0]
                if not body.strip():
                    continue
                yield lineno, [f.strip().strip('"').strip() for f in _split(body.rstrip("\r\n"), self.lay.delimiter)]

    def _fields_ok(self, fields: list[str]) -> str | None:
        n = self.lay.nfields
        ok = {n, n - 1} if self.lay.trailing else {n}
        if len(fields) not in ok:
            return f"has {len(fields)} fields, expected {n - int(self.lay.trailing)}"
        return None

    def _scan(self, keys: list[int]) -> str | None:
        for lineno, fields in self._data_rows():
            bad = self._fields_ok(fields)
            if bad:
                return f"line {lineno} {bad}"
            for k in keys:
                if k < len(fields) and _cls(fields[k], self.lay.decimal) == "x":
                    hint = ""
                    if self.lay.decimal == "." and self.lay.delimiter != "," and \
                            re.fullmatch(r"[-+]?\d*,\d+(?:[eE][-+]?\d+)?", fields[k]):
                        # (the first rows were whole numbers: the decimal comma showed only later)
                        hint = ("; the file writes a decimal comma where its first rows did not show one: give "
                                "the decimal mark (decimal=',' in Python, --decimal , at the command line)")
                    return f"line {lineno}, column {self.label(k)!r}: {fields[k][:40]!r} is not a number{hint}"
        return None

    def _row(self, row: int) -> tuple[int, list[str]] | None:
        for r, (lineno, fields) in enumerate(self._data_rows()):
            if r == row:
                return lineno, fields
        return None

    def locate(self, key: Key, row: int) -> str:
        found = self._row(row)
        return f"line {found[0]}" if found else f"data row {row}"

    def explain(self, key: Key, row: int, value: float = float("nan")) -> str:
        found = self._row(row)
        if found is None:
            return f"data row {row}, column {self.label(key)!r} is {value}, not a finite number"
        lineno, fields = found
        bad = self._fields_ok(fields)
        if bad:
            return f"line {lineno} {bad}"
        k = int(key)  # type: ignore[call-overload]
        text = fields[k] if k < len(fields) else ""
        if text == "":
            return f"line {lineno}, column {self.label(key)!r} is empty"
        return f"line {lineno}, column {self.label(key)!r} reads {text[:40]!r}, not a finite number"


def read_table(path: str | Path, delimiter: str | None = None) -> tuple[list[str], np.ndarray, bool]:
    """A numeric text table: (column names, rows x columns float64 array, whether it had a header).

    The layout is sniffed as for :func:`~piezohyst.data.load_dataset` (delimiter, decimal comma,
    encoding, comments, preamble, units line, unnamed index column); values are not converted.
    NaN is allowed (an empty field); text is not. Without a header the names are ``"0"``,
    ``"1"``, ... Every problem is a :class:`DataError` naming the file and the line.
    """
    from ._load import open_checked

    p, head, size = open_checked(path)
    try:
        src = TextSource(p, head, size, delimiter=delimiter)
    except NotText as exc:
        # (it listed NumPy, MATLAB and HDF5 files as supported, which this reader is not: found by fuzzing)
        raise DataError(f"{p}: not a text table ({exc}); a reference or command table is read from text: columns "
                        "separated by commas, semicolons, tabs or spaces (from NumPy: numpy.savetxt(path, array, "
                        "delimiter=','))") from None
    from ._columns import default_limit

    arr = src.read_all(default_limit())
    if arr.shape[0] < 2:
        raise DataError(f"{p}: needs at least 2 samples, found {arr.shape[0]}")
    return src.names(), arr, src.has_header
