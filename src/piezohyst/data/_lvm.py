"""LabVIEW measurement files (``.lvm``, "LabVIEW Measurement" on the first line).

The file header states the delimiter (``Separator``), the decimal mark (``Decimal_Separator``)
and how the x values are written (``X_Columns``: ``One`` column for all channels, ``Multi``: one
per channel, ``No``: none, the time then being ``X0 + k Delta_X``). Each segment has a header of
its own (``Channels``, ``Y_Unit_Label``, ``X_Dimension``, ``X0``, ``Delta_X``, ending in
``***End_of_Header***``), a line of column names (``X_Value``, the channels, ``Comment``) and its
rows. Segments that continue one another in time are one record; segments whose time restarts
are separate records, refused with their lines named (split the file).

Read as a generic text table, the units of ``Y_Unit_Label`` were ignored (mm read as um), the
``X_Columns No`` layout found no table and a second segment was "not a number" (found by
fuzzing).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ._dataset import DataError

MAGIC = b"LabVIEW Measurement"
END = "***End_of_Header***"


def is_lvm(head: bytes) -> bool:
    """Whether a file's first bytes are a LabVIEW measurement file's."""
    return head.lstrip(b"\xef\xbb\xbf").lstrip().startswith(MAGIC)


def _text(p: Path) -> str:
    raw = p.read_bytes()
    for enc in ("utf-8-sig", "cp1252"):
        try:
            return raw.decode(enc)
        except UnicodeDecodeError:
            continue
    return raw.decode("latin-1")  # pragma: no cover - cp1252 leaves only five bytes undefined


def _fields(line: str, sep: str) -> list[str]:
    return [f.strip() for f in line.rstrip("\r\n").split(sep)]


def _number(text: str, dec: str) -> float:
    t = text.strip()
    if dec == ",":
        t = t.replace(",", ".")
    return float(t) if t else math.nan


def read_lvm(p: Path) -> Any:
    """The file as a DataFrame: a time column (``X_Value`` or ``X0 + k Delta_X``, s) and one per
    channel, named as the file names them; ``attrs["units"]`` holds each column's unit and
    ``attrs["lvm"]`` what the headers said."""
    import pandas as pd

    where = str(p)
    lines = _text(p).splitlines()
    head: dict[str, list[str]] = {}
    i = 0
    while i < len(lines) and not lines[i].strip().startswith(END):
        f = lines[i].split("\t")
        if f and f[0].strip():
            head[f[0].strip()] = [x.strip() for x in f[1:]]
        i += 1
    if i >= len(lines):
        raise DataError(f"{where}: a LabVIEW measurement file without the end of its header ({END})")
    sep = {"tab": "\t", "comma": ",", "semicolon": ";", "space": " "}.get(
        (head.get("Separator") or ["Tab"])[0].lower(), "\t")
    dec = (head.get("Decimal_Separator") or ["."])[0] or "."
    x_columns = (head.get("X_Columns") or ["One"])[0].lower()
    i += 1

    segments: list[dict[str, Any]] = []
    while i < len(lines):
        if not lines[i].strip():
            i += 1
            continue
        seg_head: dict[str, list[str]] = {}
        start = i + 1
        # a file written without segment headers (by hand, by other tools): names and rows follow
        headerless = _is_row(lines[i], sep, dec) or (i + 1 < len(lines) and _is_row(lines[i + 1], sep, dec))
        while not headerless and i < len(lines) and not lines[i].strip().startswith(END):
            f = _fields(lines[i], sep)
            if f and f[0]:
                seg_head[f[0]] = f[1:]
            i += 1
        if not headerless:
            if i >= len(lines):
                if seg_head:
                    raise DataError(f"{where}: the segment header from line {start} has no end ({END})")
                break
            i += 1
        names: list[str] | None = None
        if i < len(lines) and lines[i].strip() and not _is_row(lines[i], sep, dec):
            names = _fields(lines[i], sep)
            i += 1
        rows: list[list[str]] = []
        first_row = i + 1
        while i < len(lines) and lines[i].strip() and _is_row(lines[i], sep, dec):
            rows.append(_fields(lines[i], sep))
            i += 1
        if i < len(lines) and lines[i].strip() and not lines[i].split(sep)[0].strip() == "Channels":
            raise DataError(f"{where}: line {i + 1} ({lines[i].strip()[:40]!r}) is neither a row of numbers nor the "
                            f"start of a segment header (Channels)")
        segments.append({"head": seg_head, "names": names, "rows": rows, "line": first_row})
    if not segments or not any(s["rows"] for s in segments):
        raise DataError(f"{where}: a LabVIEW measurement file without data rows")

    used = [s for s in segments if s["rows"]]
    frames = [_segment_frame(s, x_columns, dec, where) for s in used]
    cols = list(frames[0][0].columns)
    for k, (df, _) in enumerate(frames[1:], start=2):
        if list(df.columns) != cols:
            raise DataError(f"{where}: segment {k} has other channels ({list(df.columns)}) than the first ({cols})")
    t_end = float(frames[0][0].iloc[-1, 0])
    for k, ((df, _), seg) in enumerate(zip(frames[1:], used[1:]), start=2):
        t0 = float(df.iloc[0, 0])
        if not t0 > t_end:
            raise DataError(f"{where}: segment {k} (rows from line {seg['line']}) starts at t = {t0:g} s, not after "
                            f"the previous one's end ({t_end:g} s): the segments are separate records; split the "
                            f"file there and read each")
        t_end = float(df.iloc[-1, 0])
    df = pd.concat([f for f, _ in frames], ignore_index=True) if len(frames) > 1 else frames[0][0]
    df.attrs["units"] = frames[0][1]
    df.attrs["lvm"] = {"segments": len(frames), "x_columns": x_columns, "decimal": dec,
                       "delimiter": {"\t": "tab"}.get(sep, sep)}
    return df


def _is_row(line: str, sep: str, dec: str) -> bool:
    f = _fields(line, sep)
    try:
        values = [_number(x, dec) for x in f if x]
    except ValueError:
        return False
    return bool(values)


def _segment_frame(seg: dict[str, Any], x_columns: str, dec: str, where: str) -> tuple[Any, dict[str, str]]:
    import pandas as pd

    h = seg["head"]
    n_ch = len(h.get("Y_Unit_Label", [])) or None
    rows = seg["rows"]
    width = max(len(r) for r in rows)
    table: np.ndarray
    try:
        table = np.array([[_number(x, dec) for x in (r + [""] * (width - len(r)))] for r in rows], dtype=np.float64)
    except ValueError as exc:  # pragma: no cover - _is_row checked every field
        raise DataError(f"{where}: rows from line {seg['line']}: {exc}") from None
    names = [x for x in (seg["names"] or [])]
    if x_columns == "multi":  # X_Value, Ch1, X_Value, Ch2, ...: the first x and every channel
        x = table[:, 0]
        data = table[:, 1::2]
        ch_names = [n for n in names[1::2]] if names else []
    else:
        x = table[:, 0]
        data = table[:, 1:]
        ch_names = names[1:] if names else []
    ch_names = [c for c in ch_names if c and c.lower() != "comment"]
    # a trailing empty field (rows written to line up with a Comment column) is no channel
    keep = [j for j in range(data.shape[1]) if not np.all(np.isnan(data[:, j]))]
    data = data[:, keep]
    if n_ch is not None:
        data = data[:, :n_ch]
    if np.all(np.isnan(x)):  # X_Columns No: the time from the segment header
        try:
            x0 = _number((h.get("X0") or ["0"])[0], dec)
            step = _number((h.get("Delta_X") or [""])[0], dec)
        except ValueError:
            step = math.nan
        if not (math.isfinite(step) and step > 0):
            raise DataError(f"{where}: the rows from line {seg['line']} have no x values and the segment header no "
                            f"Delta_X to count the time by")
        x = np.asarray((0.0 if not math.isfinite(x0) else x0) + np.arange(len(rows)) * step, dtype=np.float64)
    labels = [ch_names[j] if j < len(ch_names) and ch_names[j] else f"Channel {j}" for j in range(data.shape[1])]
    seen: dict[str, int] = {}
    for j, lab in enumerate(labels):  # unique names
        if lab in seen:
            seen[lab] += 1
            labels[j] = f"{lab} ({seen[lab]})"
        else:
            seen[lab] = 1
    units = list(h.get("Y_Unit_Label", []))
    dims = h.get("X_Dimension", [])
    in_time = not dims or dims[0].lower() == "time"
    x_name = names[0] if names and names[0] and not np.all(np.isnan(table[:, 0])) else "Time" if in_time else "X"
    df = pd.DataFrame({x_name: x, **{lab: data[:, j] for j, lab in enumerate(labels)}})
    unit_of = {x_name: "s"} if in_time else {}
    for j, lab in enumerate(labels):
        if j < len(units) and units[j]:
            unit_of[lab] = units[j]
    return df, unit_of
