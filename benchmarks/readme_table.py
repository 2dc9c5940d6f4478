"""Regenerate the README's performance table from the last ``make bench`` run.

    python benchmarks/readme_table.py [results.json] [README.md]

Reads ``benchmarks/out/results.json`` (written by ``benchmarks/run.py``) and replaces what lies
between the markers ``<!-- bench-table:begin -->`` and ``<!-- bench-table:end -->`` in the
README's "Performance" section with a Markdown table of every row: its target and whether it
was met, missed rows in bold. Nothing else in the README changes. The README is rewritten
atomically (a temporary file, then a rename).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
BEGIN = "<!-- bench-table:begin -->"
END = "<!-- bench-table:end -->"


def _cell(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def table(doc: dict[str, Any]) -> str:
    m = doc["machine"]
    rows = doc["rows"]
    met = sum(r["met"] is True for r in rows)
    missed = [r["name"] for r in rows if r["met"] is False]
    lines = [
        f"Last run: {doc['producer'].split('; at ')[-1]}, {m['cpu']}, {m['cores']} cores, Python {m['python']}, "
        f"numpy {m['numpy']}, numba {m['numba']}, {m.get('gcc') or 'no C compiler'}; load average "
        f"{', '.join(f'{x:.1f}' for x in m.get('load_average', []))}; {doc['total_s']:.0f} s. "
        f"{met} of {len(rows)} rows met their target"
        + (f"; missed: {', '.join(missed)}." if missed else "."),
        "",
        "| row | what | ours | baseline (same run) | ratio | target | met |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ratio = "-" if r["ratio"] is None else f"{r['ratio']:.3g} ({r['ratio_is']})"
        flag = {True: "yes", False: "**no**", None: "-"}[r["met"]]
        lines.append("| " + " | ".join(_cell(c) for c in (r["name"], r["what"], r["ours"], r["baseline"], ratio,
                                                            r["target"], flag)) + " |")
    notes = [f"- {r['name']}: {_cell(r['note'])}" for r in rows if r["note"]]
    if notes:
        lines += ["", "Notes from the same run:", "", *notes]
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    results = Path(argv[0]) if argv else HERE / "out" / "results.json"
    readme = Path(argv[1]) if len(argv) > 1 else HERE.parent / "README.md"
    if not results.exists():
        print(f"{results}: no such file; run `make bench` first", file=sys.stderr)
        return 1
    doc = json.loads(results.read_text(encoding="utf-8"))
    text = readme.read_text(encoding="utf-8")
    if text.count(BEGIN) != 1 or text.count(END) != 1 or text.index(BEGIN) > text.index(END):
        print(f"{readme}: needs exactly one {BEGIN} ... {END} block", file=sys.stderr)
        return 1
    head, rest = text.split(BEGIN)
    _, tail = rest.split(END)
    new = f"{head}{BEGIN}\n{table(doc)}\n{END}{tail}"
    fd, tmp = tempfile.mkstemp(dir=readme.parent, prefix=".README.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(new)
        os.replace(tmp, readme)
    except BaseException:
        os.unlink(tmp)
        raise
    print(f"updated the performance table of {readme} from {results} ({len(doc['rows'])} rows)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
