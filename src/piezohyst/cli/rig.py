"""``piezohyst rig``: drive the virtual rig open loop with the paper's sinusoids (Fig. 2)."""

from __future__ import annotations

import argparse
from functools import partial
from pathlib import Path

from ._common import (UsageError, add_rig_options, check_sinusoids, console, figure_formats, finite_float, freqs,
                      guarded, positive_float, print_json, rig_from_args, rig_rate_note)

#: The files ``rig --out`` writes (one set, with its manifest.json)
RIG_FILES = ("fig2_loops.png", "rig_loops.csv")


def cmd_rig(args: argparse.Namespace) -> int:
    from .._fileio import OutputFolder

    if args.cycles < 1:
        raise UsageError(f"--cycles must be at least 1 (a loop needs a whole cycle), got {args.cycles:g}")
    if not args.u_low < args.u_high:
        raise UsageError(f"--u-low ({args.u_low:g} V) must be below --u-high ({args.u_high:g} V)")
    out = Path(args.out) if args.out else None
    if out is None and tuple(args.format) != ("png",):  # (ignored without a word: found by fuzzing)
        raise UsageError("--format chooses the formats of the figures --out writes: give --out DIR")
    fmts = tuple(dict.fromkeys(("png", *args.format)))
    fig_files = [RIG_FILES[0].rsplit(".", 1)[0] + "." + f for f in fmts]
    folder = OutputFolder(out, (*fig_files, RIG_FILES[1]), force=args.force) if out is not None else None
    if folder is not None:  # refuse before the run, not after it
        folder.check()
    rig = rig_from_args(args)
    lo, hi = rig.u_range
    for flag, v in (("--u-low", args.u_low), ("--u-high", args.u_high)):
        if not lo <= v <= hi:
            raise UsageError(f"{flag} {v:g} V is outside the rig's amplifier range {lo:g}..{hi:g} V "
                             f"(the amplifier would clip it)")
    check_sinusoids(args.freq, args.cycles, rig.dt, rate_from=rig_rate_note(args))

    import numpy as np

    import piezohyst as ph

    from .. import plots

    rows, runs, columns = [], [], []
    for f in args.freq:
        u = ph.sinusoid(f, args.cycles, args.u_low, args.u_high, rig.dt)
        ds = rig.excite(u)
        period = int(round(1 / (f * rig.dt)))
        lf = guarded(partial(ph.loop_figures, ds.u, ds.y, period=period), f"--freq {f:g} Hz")
        rows.append({"freq_hz": f, "span_um": lf.span, "width_um": lf.width, "width_percent": lf.width_percent,
                     "clipped_samples": ds.meta["clipped_samples"]})
        runs.append((f"{f:g} Hz", ds.u[-period:], ds.y[-period:]))
        columns.append((f, ds))
    csv_path = None
    if folder is not None and out is not None:
        from .._fileio import atomic_write, producer

        plots.use_headless_backend()
        lines = plots.plot_loops(runs, title=f"Virtual rig, open loop, {args.u_low:g}-{args.u_high:g} V sinusoids (cf. paper Fig. 2)")

        def write(tmp):  # type: ignore[no-untyped-def]
            n = max(len(d) for _, d in columns)
            with open(tmp, "w", encoding="utf-8") as fh:
                fh.write(f"# {producer()}\n# units: t in s, u in V, y in um; one (t,u,y) triple per frequency\n")
                fh.write(",".join(f"t_{f:g}Hz_s,u_{f:g}Hz_V,y_{f:g}Hz_um" for f, _ in columns) + "\n")
                cols = []
                for _, d in columns:
                    for arr in (d.t, d.u, d.y):
                        c = np.full(n, np.nan)
                        c[: arr.size] = arr
                        cols.append(c)
                np.savetxt(fh, np.column_stack(cols), delimiter=",", fmt="%.9g")

        with folder as tmp_dir:  # both files appear together, or neither
            plots.save_formats(lines[0].axes, tmp_dir / RIG_FILES[0], fmts, force=True,
                               note=f"piezohyst rig: open-loop loops of the virtual rig at "
                                    f"{', '.join(f'{f:g}' for f, _ in columns)} Hz, {args.u_low:g}-{args.u_high:g} V "
                                    f"(cf. the paper's Fig. 2); displacement in um against voltage in V")
            atomic_write(tmp_dir / RIG_FILES[1], write, force=True)
        csv_path = out / RIG_FILES[1]
    result = {"rig": rig.settings.to_dict(), "seed": args.seed, "loops": rows,
              "written": [str(out / f) for f in fig_files] + [str(csv_path)] if out else []}
    if args.json:
        print_json(result)
        return 0
    from rich.table import Table

    t = Table(title=f"Virtual rig, open loop, {args.u_low:g}-{args.u_high:g} V sinusoids (last cycle)")
    for c in ("freq (Hz)", "span (µm)", "loop width (µm)", "width % of span", "clipped samples"):
        t.add_column(c, justify="right")
    for r in rows:
        t.add_row(f"{r['freq_hz']:g}", f"{r['span_um']:.4f}", f"{r['width_um']:.4f}", f"{r['width_percent']:.1f}",
                  str(r["clipped_samples"]))
    con = console()
    con.print(t)
    if out is not None:
        con.print(f"wrote {', '.join(result['written'])}")
    return 0


def register(sub, add) -> None:  # type: ignore[no-untyped-def]
    p = add("rig", cmd_rig, "Drive the virtual rig open loop with sinusoids and show its loops (the paper's Fig. 2).",
            "piezohyst rig --freq 1,3,5 --out loops/")
    p.add_argument("--freq", type=freqs, default=[1.0, 3.0, 5.0], help="frequencies in Hz (default 1,3,5)")
    p.add_argument("--cycles", type=positive_float, default=3, help="cycles per frequency (default 3)")
    p.add_argument("--u-low", type=finite_float, default=0.0, help="lowest voltage (default 0)")
    p.add_argument("--u-high", type=finite_float, default=100.0, help="highest voltage (default 100)")
    p.add_argument("--out", default=None,
                   help="folder for fig2_loops.png and rig_loops.csv (a new or empty folder; written as one set)")
    p.add_argument("--force", action="store_true", help="replace the files of a previous 'rig --out' in that folder")
    p.add_argument("--format", type=figure_formats, default=("png",),
                   help="figure formats besides PNG, comma-separated: pdf, svg (e.g. --format pdf)")
    p.add_argument("--json", action="store_true", help="print the figures as JSON only")
    add_rig_options(p)

