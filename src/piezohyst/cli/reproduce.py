"""``piezohyst reproduce``: the paper's experiment on the virtual rig (the project's main job)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import (
    UsageError,
    add_rig_options,
    console,
    figure_formats,
    print_json,
    progress_wanted,
    rig_from_args,
    rig_rate_note,
)


def _check_rig_for_experiment(rig, args) -> None:  # type: ignore[no-untyped-def]
    """Refuse, before the run, a rig whose sample period cannot carry the experiment's records."""
    from ..commissioning import commissioning_excitation
    from ._common import MAX_SAMPLES, check_sinusoids

    check_sinusoids([1.0, 3.0, 5.0], 4, rig.dt, freq_flag="the experiment's", cycles_flag="",
                    rate_from=rig_rate_note(args))
    # the commissioning record: its length in seconds does not depend on the sample period
    probe = 1e-2
    seconds = commissioning_excitation(probe).size * probe
    n = seconds / rig.dt
    if n > MAX_SAMPLES:
        raise UsageError(f"{args.rig_settings or 'the rig'}: dt = {rig.dt:g} s makes the {seconds:g} s commissioning "
                         f"record {n:.3g} samples; the limit is {MAX_SAMPLES:.3g}")
    try:
        commissioning_excitation(rig.dt)
    except ValueError as exc:
        raise UsageError(f"{args.rig_settings or 'the rig'}: dt = {rig.dt:g} s is too coarse for the experiment "
                         f"({exc})") from None


def cmd_reproduce(args: argparse.Namespace) -> int:
    from contextlib import ExitStack

    from .._figures import BackgroundFigures

    written = []
    with ExitStack() as stack:
        bg = None
        if args.out and BackgroundFigures.useful():
            # the paper's figures are drawn by a second process while commissioning runs here; it
            # starts first, so that its imports (matplotlib) overlap this process's (numba, scipy).
            # Any refusal below stops it again.
            bg = stack.enter_context(BackgroundFigures())
        from ..experiments.paper import _with_png, results_folder, write_results_into

        out = Path(args.out) if args.out else None
        fmts = _with_png(args.format)
        folder = results_folder(out, force=args.force, formats=fmts) if out is not None else None
        if folder is not None:  # refuse before an expensive run, not after
            folder.check()
        rig = rig_from_args(args)
        _check_rig_for_experiment(rig, args)
        # the set is written into the folder's temporary twin and published when the block ends
        tmp = stack.enter_context(folder) if folder is not None else None
        if bg is not None:
            # on an error the worker is killed before the temporary folder it writes into is removed
            stack.push(lambda exc_type, exc, tb: bg.close(kill=True) if exc_type is not None else None)
        exp = _run(args, rig, None if bg is None or tmp is None else _submitter(bg, tmp, fmts))
        if tmp is not None:
            figures = bg.result() if bg is not None else None
            written = [str(p) for p in write_results_into(exp, tmp, out, formats=fmts, figures=figures)]
    if args.json:
        print_json({**exp.to_dict(), "written": written})
        return 0
    _print_tables(exp, written)
    return 0


def _submitter(bg, tmp, fmts):  # type: ignore[no-untyped-def]
    """The hook that hands the paper's part of the experiment to the figure worker."""
    def submit(part) -> None:  # type: ignore[no-untyped-def]
        from ..experiments.paper import figure_jobs

        bg.submit(figure_jobs(part), tmp, fmts)
    return submit


def _run(args, rig, hook):  # type: ignore[no-untyped-def]
    from ..experiments.paper import run_paper_experiment

    if not progress_wanted():
        return run_paper_experiment(rig, seed=args.seed, on_paper_part=hook)
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    total = 3 + 1 + 2 + 2 + 3 * 4 + 1 + 3
    with Progress(TextColumn("{task.description:<55}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TimeElapsedColumn(), console=console(stderr=True), transient=True) as bar:
        task = bar.add_task("starting", total=total)

        def on_step(desc: str) -> None:
            bar.update(task, description=desc, advance=1)

        return run_paper_experiment(rig, seed=args.seed, on_step=on_step, on_paper_part=hook)


def _print_tables(exp, written) -> None:  # type: ignore[no-untyped-def]
    from rich.table import Table

    from .. import paper_values as pv
    from ..experiments.paper import MODEL_TITLES, MODELS

    con = console()
    for m in MODELS:
        t = Table(title=MODEL_TITLES[m] + " - virtual rig beside the paper")
        t.add_column("Excitation")
        for c in ("e_max µm", "(paper)", "%", "(paper)", "RMSE µm", "(paper)"):
            t.add_column(c, justify="right")
        for r in exp.table(m):
            t.add_row(r["excitation"], f"{r['e_max_um']:.3f}", f"{r['paper_e_max_um']:.3f}" if r["paper_e_max_um"] else "-",
                      f"{r['e_max_percent']:.1f}", f"{r['paper_e_max_percent']:.1f}" if r["paper_e_max_percent"] else "-",
                      f"{r['rmse_um']:.4f}", f"{r['paper_rmse_um']:.4f}" if r["paper_rmse_um"] else "-")
        con.print(t)
        tu = exp.tuning[m]
        con.print(f"  PID around it: kp={tu.kp:g}, ki={tu.ki:.4g} 1/s, kd={tu.kd:g} ({tu.method})")
    if exp.ablation:
        t = Table(title="Table III - piezohyst: best feedforward alone and with feedback (piezohyst's targets)")
        for c in ("Excitation", "e_max µm", "e_max %", "target", "RMSE µm", "RMSE %", "target", "met"):
            t.add_column(c, justify="left" if c == "Excitation" else "right")
        for r in exp.table_piezohyst():
            t.add_row(r["excitation"], f"{r['e_max_um']:.4f}", f"{r['e_max_percent']:.2f}", f"<= {r['target_e_max_percent']:g}",
                      f"{r['rmse_um']:.4f}", f"{r['rmse_percent']:.2f}", f"<= {r['target_rmse_percent']:g}",
                      "yes" if r["meets_target"] else "NO")
        con.print(t)
        from ..experiments.paper import ABLATION

        t = Table(title="Ablation: e_max % of span / RMSE nm, each row adds one means")
        t.add_column("configuration")
        for f in exp.freqs:
            t.add_column(f"{f:g} Hz", justify="right")
        for key, name in ABLATION.items():
            t.add_row(name, *(f"{exp.ablation[key][f].e_max_percent:.2f} / {1e3 * exp.ablation[key][f].rmse:.1f}"
                              for f in exp.freqs))
        con.print(t)
    t = Table(title="Identified Bouc-Wen parameters (PSO) beside the paper's")
    for c in ("", "m (kg)", "b (N s/m)", "k (N/m)", "d1 (m/V)", "alpha", "beta (1/V)", "gamma (1/V)"):
        t.add_column(c, justify="right")
    names = ("m", "b", "k", "d1", "alpha", "beta", "gamma")
    t.add_row("identified", *(f"{getattr(exp.bw_fit.model, n):.4g}" for n in names))
    t.add_row("paper", *(f"{pv.BOUC_WEN[n]:.4g}" for n in names))
    t.add_row("constrained?", *("barely" if exp.bw_fit.sensitivity[n] < 0.01 else "yes" for n in names))
    con.print(t)
    con.print(f"Bouc-Wen fit RMSE {exp.bw_fit.rmse * 1e3:.2f} nm; P-I fit (PSO) RMSE {exp.pi_fit.rmse * 1e3:.2f} nm "
              f"(least-squares optimum on the same data: {exp.pi_lsq_rmse * 1e3:.2f} nm)")
    con.print("The paper's claims on the rig:")
    for c in exp.claims():
        con.print(f"  [{'holds' if c['holds'] else 'does NOT hold'}] {c['claim']}")
    con.print(f"finished in {exp.time_s:.1f} s")
    if written:
        con.print(f"wrote {len(written)} files to {Path(written[0]).parent} (report.md, figures, results.json)")


def register(sub, add) -> None:  # type: ignore[no-untyped-def]
    p = add("reproduce", cmd_reproduce,
            "Run the paper's whole experiment on the virtual rig: identify both models with PSO, build both "
            "feedforward controllers, tune PID, track 1/3/5 Hz, print Tables I and II beside the paper's, "
            "write the figures and a report.",
            "piezohyst reproduce --out results/ --seed 0")
    p.add_argument("--out", default=None, help="folder for report.md, results.json and the figures (a new or empty "
                   "folder; written as one set, with a manifest.json)")
    p.add_argument("--force", action="store_true", help="replace the files of a previous 'reproduce --out' in that folder")
    p.add_argument("--format", type=figure_formats, default=("png",),
                   help="figure formats besides PNG, comma-separated: pdf, svg (e.g. --format pdf,svg)")
    p.add_argument("--json", action="store_true", help="print the results as JSON only")
    add_rig_options(p)

