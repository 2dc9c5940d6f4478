"""``piezohyst fleet identify``: identify every actuator of a batch on Dask, compare them, flag the odd ones.

Thin: :func:`piezohyst.fleet.identify_many` does the work (one Dask task per record), then
:func:`piezohyst.fleet.batch_statistics` and :func:`piezohyst.fleet.plot_histograms`; this module
parses, calls them and prints. The fit options and their defaults are ``piezohyst identify``'s
(the same ``--model`` and ``--delay`` parsers; the data options and their loading from
:mod:`._common`).
"""

from __future__ import annotations

import argparse
from typing import Any

from ._common import UsageError, add_data_options, console, data_options, positive_int, print_json
from ._common import seed as seed_type
from .identify import _MODEL_HELP, _delay


def _workers(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of worker processes, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"--workers must be at least 1, got {n}")
    from .._blas import too_many_workers

    why = too_many_workers(n)
    if why is not None:
        raise argparse.ArgumentTypeError(why.replace('pass its address', 'pass --scheduler'))
    return n


def _mads(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of median absolute deviations, got {text!r}") from None
    if not (v > 0) or v == float("inf"):
        raise argparse.ArgumentTypeError(f"--outlier-mads must be positive and finite, got {text!r}")
    return v


def _seconds(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not (v > 0) or v == float("inf"):
        raise argparse.ArgumentTypeError(f"--timeout must be positive and finite, got {text!r}")
    return v


def cmd_fleet_identify(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from .. import fleet
    from ..plots import use_headless_backend

    options = dict(method=args.method, n=args.n, seed=args.seed, max_iter=args.iterations,
                   polish=not args.no_polish, delay=args.delay, history=args.history, **data_options(args))
    use_headless_backend()
    t0 = time.perf_counter()
    try:
        # the histograms are written with the summary, as one set (written apart, a Ctrl-C between
        # them left a summary and histograms of two runs: found by a helper)
        df = fleet.identify_many(args.paths, kind=args.model, client=args.scheduler, out=args.out,
                                 force=args.force, workers=args.workers, progress=not args.quiet,
                                 outlier_mads=args.outlier_mads, timeout=args.timeout, histograms=True, **options)
    except fleet.MissingExtraError as exc:
        raise UsageError(str(exc)) from None
    elapsed = time.perf_counter() - t0
    stats = fleet.batch_statistics(df, threshold=args.outlier_mads)
    out = Path(args.out)
    hist = out / fleet.HISTOGRAMS
    summary = [out / "summary.csv"] + ([out / "summary.parquet"] if (out / "summary.parquet").exists() else [])
    ok = df["status"] == "ok"
    failed = df[~ok]
    where = "this machine" if args.scheduler is None else args.scheduler
    if args.json:
        print_json({"records": len(df), "ok": int(ok.sum()), "failed": len(failed),
                    "resumed": int((df["resumed"] & ok).sum()), "elapsed_s": elapsed, "cluster": where,
                    "written": {"summary": [str(p) for p in summary], "models": str(out / "models"),
                                "histograms": str(hist)},
                    "statistics": stats.to_dict(),
                    "failed_records": [{"record": r, "file": f, "error": e}
                                       for r, f, e in zip(failed["record"], failed["file"], failed["error"])],
                    "rows": df.to_dict(orient="records"),
                    "orphaned_model_files": df.attrs.get("orphaned_model_files", [])})
        return _exit_code(df, ok)
    _print_report(df, stats, elapsed, where, summary, hist, out)
    orphans = df.attrs.get("orphaned_model_files") or []
    if orphans:
        console().print(f"{len(orphans)} model file(s) in {out / 'models'} belong to no record of this batch (renamed "
                        f"or removed?), left as they are: {', '.join(Path(q).name for q in orphans[:5])}"
                        + (" ..." if len(orphans) > 5 else ""))
    return _exit_code(df, ok)


def _exit_code(df: Any, ok: Any) -> int:
    """0 where at least one record was identified (a record that failed is a row of the summary,
    not a failed batch); 2 where every record failed, as for any input the command cannot use, so
    that a script or a CI job sees it (found by fuzzing: a batch whose every record named a missing
    column exited 0)."""
    if len(df) and not bool(ok.any()):
        first = str(df["error"].iloc[0])
        console(stderr=True).print(f"piezohyst fleet identify: error: none of the {len(df)} records was identified "
                                   f"(the first: {first})")
        return 2
    return 0


def _print_report(df: Any, stats: Any, elapsed: float, where: str, summary: list[Any], hist: Any, out: Any) -> None:
    from rich.table import Table

    con = console()
    ok = df["status"] == "ok"
    resumed = int((df["resumed"] & ok).sum())
    con.print(f"{len(df)} records on {where} in {elapsed:.1f} s: {int(ok.sum())} identified"
              + (f" ({resumed} read back from {out / 'models'})" if resumed else "")
              + f", {int((~ok).sum())} failed")
    t = Table(title=f"Batch distributions ({int(ok.sum())} actuators)")
    for c in ("figure", "unit", "n", "median", "MAD", "5 %", "25 %", "75 %", "95 %"):
        t.add_column(c, justify="left" if c in ("figure", "unit") else "right")
    for _, d in stats.distributions.iterrows():
        t.add_row(d["label"], d["unit"], str(int(d["n"])),
                  *(f"{d[k]:.4g}" for k in ("median", "mad", "q05", "q25", "q75", "q95")))
    con.print(t)
    outl = stats.outliers
    if len(outl):
        t = Table(title=f"Outliers (beyond {stats.threshold:g} median absolute deviations)")
        for c in ("record", "gain µm/V", "loop width %", "fit RMSE %", "why"):
            t.add_column(c, justify="left" if c in ("record", "why") else "right")
        for _, r in outl.iterrows():
            t.add_row(r["record"], f"{r['gain_um_per_v']:.4g}", f"{r['loop_width_percent']:.4g}",
                      f"{r['fit_rmse_percent_of_span']:.4g}", r["outlier_reason"])
        con.print(t)
    else:
        con.print(f"no outliers beyond {stats.threshold:g} median absolute deviations")
    bad = df[~ok]
    if len(bad):
        t = Table(title="Failed records (the batch went on)")
        t.add_column("record")
        t.add_column("error")
        for r, e in zip(bad["record"], bad["error"]):
            t.add_row(r, e)
        con.print(t)
    con.print(f"written: {', '.join(str(p) for p in summary)}, {out / 'models'}/ (one model file per identified "
              f"record), {hist}")


def register(sub: Any, add: Any) -> None:
    p = add("fleet", lambda args: args.fleet_parser.print_help() or 0,
            "Batches of actuators: identify every record on a Dask cluster (local or remote), file the models, "
            "compare the actuators and flag the ones that differ.",
            "piezohyst fleet identify batch-07/ --model pi --out fleet-07")
    p.set_defaults(fleet_parser=p)
    fsub = p.add_subparsers(dest="fleet_command", metavar="SUBCOMMAND")
    q = fsub.add_parser(
        "identify", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="identify every record (one Dask task each, quick ones grouped); write DIR/models/, DIR/summary.csv, histograms",
        description="Identify every record of a batch, one Dask task per record (quick records grouped), on a local cluster (default: one "
        "worker process per core) or an existing scheduler; write DIR/models/<record>.json, DIR/summary.csv "
        "(+ .parquet with pyarrow) and DIR/fleet_histograms.png; print the batch's distributions and its "
        "outliers. A record that fails is a row with its error. Records whose model file is already in DIR are "
        "read back, not refitted (unless --force): an interrupted batch resumes.",
        epilog="examples:\n  piezohyst fleet identify batch-07/ --model pi --out fleet-07\n"
        "  piezohyst fleet identify 'lots/*/act-*.csv' --model auto --out fleet --workers 8\n"
        "  piezohyst fleet identify batch-07/ --model pi --out fleet-07 --scheduler tcp://10.0.0.5:8786 --json\n"
        "needs the fleet extra: pip install \"piezohyst[fleet]\"; on a cluster, the workers must read the "
        "data files at the same paths (see `python -c \"import piezohyst.fleet as f; help(f)\"`)")
    q.set_defaults(func=cmd_fleet_identify)
    q.add_argument("paths", nargs="+", metavar="PATHS",
                   help="data files, folders (their .csv/.txt/.dat/.tsv/.mat/.npz files) or glob patterns (quoted)")
    add_data_options(q)
    q.add_argument("--model", required=True, metavar="KIND", help=_MODEL_HELP.replace(" (default auto)", ""))
    q.add_argument("--method", choices=("select", "lsq", "pso"), default=None,
                   help="as for piezohyst identify: lsq (pi default), pso (bouc-wen default, or pi), select (the "
                   "other kinds and auto)")
    q.add_argument("--n", type=positive_int, default=None, help="play operators (pi: 20 with lsq/pso) or grid levels")
    q.add_argument("--seed", type=seed_type, default=0, help="PSO seed, the same for every record (default 0)")
    q.add_argument("--iterations", type=positive_int, default=200, help="PSO iterations (default 200)")
    q.add_argument("--no-polish", action="store_true", help="bouc-wen: PSO only, no local refinement")
    q.add_argument("--delay", type=_delay, default=None,
                   help="samples by which the output lags the input, or 'auto' (default: auto with --method select, "
                   "0 with lsq/pso)")
    q.add_argument("--history", choices=("auto", "none"), default=None,
                   help="--method select: each actuator's state at the record's start, as in identify (default: "
                   "auto with --model auto, none for a kind by name)")
    q.add_argument("--out", required=True, metavar="DIR", help="output folder (models/, summary.csv, histograms)")
    where = q.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS", default=None,
                       help="an existing Dask scheduler, e.g. tcp://host:8786 (default: a local cluster)")
    where.add_argument("--workers", type=_workers, default=None, metavar="N",
                       help="worker processes of the local cluster, one thread each (default: the cores)")
    q.add_argument("--timeout", type=_seconds, default=30.0, metavar="SECONDS",
                   help="how long to wait for the scheduler given with --scheduler (default 30)")
    q.add_argument("--outlier-mads", type=_mads, default=5.0, metavar="K",
                   help="flag actuators further than K median absolute deviations from the batch median (default 5)")
    q.add_argument("--force", action="store_true", help="refit records whose model file exists, and overwrite it")
    q.add_argument("--quiet", action="store_true", help="no progress bar (on stderr)")
    q.add_argument("--json", action="store_true", help="print the results as JSON only (progress stays on stderr)")
