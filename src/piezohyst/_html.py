"""Small HTML tables for the ``_repr_html_`` of results and models (what Jupyter shows).

Plain HTML with inline styles only: no scripts, no external resources, every value escaped.
"""

from __future__ import annotations

import html
import math
from typing import Any, Iterable, Sequence

import numpy as np

_TABLE = 'style="border-collapse:collapse;font-size:90%;margin:0.3em 0"'
_CELL = 'style="text-align:left;padding:0.1em 0.8em 0.1em 0;vertical-align:top"'
#: arrays longer than this are summarised (count, range, first and last values)
MAX_LISTED = 8


def fmt(value: Any, spec: str = ".4g") -> str:
    """One value as text: numbers with ``spec``, None as a dash, the rest with ``str``."""
    if value is None:
        return "-"
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return "nan" if math.isnan(value) else format(float(value), spec)
    return str(value)


def array_text(values: Any) -> str:
    """A numeric array in a few words: all values when short, else count, range and ends."""
    a = np.asarray(values, dtype=float)
    if a.size == 0:
        return "(empty)"
    if a.ndim > 1:
        return f"{' x '.join(map(str, a.shape))} array, {fmt(a.min())} .. {fmt(a.max())}"
    if a.size <= MAX_LISTED:
        return "[" + ", ".join(fmt(v) for v in a) + "]"
    head = ", ".join(fmt(v) for v in a[:3])
    tail = ", ".join(fmt(v) for v in a[-2:])
    return f"{a.size} values, {fmt(a.min())} .. {fmt(a.max())}: [{head}, ..., {tail}]"


def table(rows: Iterable[tuple[str, Any]], *, caption: str | None = None, raw: Sequence[int] = ()) -> str:
    """A two-column table of ``(name, value)`` rows; values at the indices in ``raw`` are HTML already."""
    e = html.escape
    out = [f"<table {_TABLE}>"]
    if caption:
        out.append(f'<caption style="text-align:left;font-weight:bold">{e(caption)}</caption>')
    for i, (name, value) in enumerate(rows):
        cell = value if i in raw else e(fmt(value))
        out.append(f"<tr><th {_CELL}>{e(name)}</th><td {_CELL}>{cell}</td></tr>")
    out.append("</table>")
    return "".join(out)


def grid(header: Sequence[str], rows: Iterable[Sequence[Any]], *, caption: str | None = None,
         bold: Sequence[bool] | None = None) -> str:
    """A table with a header row; ``bold[i]`` sets row ``i`` in bold."""
    e = html.escape
    out = [f"<table {_TABLE}>"]
    if caption:
        out.append(f'<caption style="text-align:left;font-weight:bold">{e(caption)}</caption>')
    out.append("<tr>" + "".join(f"<th {_CELL}>{e(h)}</th>" for h in header) + "</tr>")
    for i, row in enumerate(rows):
        style = ' style="font-weight:bold"' if bold is not None and bold[i] else ""
        out.append(f"<tr{style}>" + "".join(f"<td {_CELL}>{e(fmt(v))}</td>" for v in row) + "</tr>")
    out.append("</table>")
    return "".join(out)


def parameters(params: dict[str, Any]) -> str:
    """A model's ``to_dict()`` as a table; nested ``{"kind", "parameters"}`` models as inner tables."""
    rows: list[tuple[str, Any]] = []
    raw = []
    for name, value in params.items():
        if isinstance(value, dict) and "kind" in value and "parameters" in value:
            raw.append(len(rows))
            rows.append((name, f"{html.escape(str(value['kind']))} model"
                               + parameters(value["parameters"])))
        elif isinstance(value, dict):
            raw.append(len(rows))
            rows.append((name, parameters(value)))
        elif isinstance(value, (list, tuple, np.ndarray)):
            try:
                rows.append((name, array_text(value)))
            except (TypeError, ValueError):
                rows.append((name, str(value)))
        else:
            rows.append((name, value))
    return table(rows, raw=raw)


def block(title: str, *parts: str) -> str:
    """A titled block holding HTML parts."""
    return (f'<div class="piezohyst-repr"><div style="font-weight:bold">{html.escape(title)}</div>'
            + "".join(parts) + "</div>")


def model_html(model: Any) -> str:
    """An HTML summary of a model (every kind's ``_repr_html_``): kind, units, invertibility,
    and its parameters as its model file holds them (nested models as inner tables)."""
    name = type(model).__name__
    kind = getattr(type(model), "kind", name)
    rows = [("kind", kind), ("output unit", getattr(model, "output_unit", "um").replace("um", "µm")),
            ("invertible", bool(getattr(model, "is_invertible", False))),
            ("needs dt (dynamic)", bool(getattr(model, "dynamic", False)))]
    return block(f"{name} model", table(rows), parameters(model.to_dict()))
