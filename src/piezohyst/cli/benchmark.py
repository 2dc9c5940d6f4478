"""``piezohyst benchmark bouc-wen``: the Noel-Schoukens identification benchmark."""

from __future__ import annotations

import argparse

from ._common import UsageError, console, guarded, print_json, seed


def cmd_benchmark(args: argparse.Namespace) -> int:
    from ..data import data_dir
    from ..experiments.boucwen_benchmark import PUBLISHED, QUOTED_FLOOR, run_benchmark

    path = args.data or str(data_dir() / "bouc-wen-benchmark" / "bouc-wen.mat")
    from pathlib import Path

    if not Path(path).is_file():
        what = "no such file" if not Path(path).exists() else "not a file"
        raise UsageError(f"{path}: {what}" + ("" if args.data else " (the project's copy of the benchmark data; "
                                              "give --data)"))
    if args.json:
        res = guarded(lambda: run_benchmark(path, seed=args.seed), path)
        print_json(res.to_dict())
        return 0
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
    from rich.table import Table

    with Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(),
                  console=console(stderr=True), transient=True) as bar:
        task = bar.add_task("loading", total=None)
        res = guarded(lambda: run_benchmark(path, seed=args.seed, on_step=lambda s: bar.update(task, description=s)),
                      path)
    d = res.to_dict()
    con = console()
    t = Table(title="Bouc-Wen benchmark: multisine test record, RMS error (m), lower is better")
    t.add_column("method")
    t.add_column("RMS error (m)", justify="right")
    rows = [("piezohyst: grey-box PSO + least-squares refinement", d["test_rmse_m"]["multisine"]),
            ("piezohyst: PSO stage alone", d["stages"]["pso"]["test_rmse_m"]["multisine"])]
    rows += list(PUBLISHED)
    rows += [("the data's floor as quoted with it (true system, RK4 15 kHz)", QUOTED_FLOOR),
             ("true system re-simulated here (band-limited input, RK4 15 kHz)", d["true_system_test_rmse_m"]["multisine"])]
    for name, v in sorted(rows, key=lambda r: r[1]):
        t.add_row(name, f"{v:.3g}")
    con.print(t)
    con.print(f"sine-sweep test record: RMS error {d['test_rmse_m']['sinesweep']:.3g} m "
              f"(PSO stage alone {d['stages']['pso']['test_rmse_m']['sinesweep']:.3g} m; true system re-simulated "
              f"{d['true_system_test_rmse_m']['sinesweep']:.3g} m)")
    t = Table(title="Identified parameters (beta fixed to 1: only beta*gamma and beta*delta are identifiable)")
    for c in ("", *d["identified"].keys()):
        t.add_column(c, justify="right")
    t.add_row("identified", *(f"{v:.5g}" for v in d["identified"].values()))
    t.add_row("true", *(f"{v:.5g}" for v in d["true"].values()))
    con.print(t)
    st = d["stages"]
    con.print(f"identification from the training record only: {d['identification_time_s']:.1f} s "
              f"(best linear approximation {st['bla']['time_s']:.3f} s; PSO {st['pso']['time_s']:.1f} s, "
              f"training RMSE {st['pso']['rmse_m']:.3g} m; refinement {st['refinement']['time_s']:.1f} s, "
              f"training RMSE {st['refinement']['rmse_m']:.3g} m, which is the record's noise)")
    return 0


def register(sub, add) -> None:  # type: ignore[no-untyped-def]
    p = add("benchmark", cmd_benchmark,
            "Identify the Bouc-Wen benchmark system (Noel and Schoukens) from its training record and "
            "compare the test errors with the published results.",
            "piezohyst benchmark bouc-wen --data data/bouc-wen-benchmark/bouc-wen.mat")
    p.add_argument("name", choices=("bouc-wen",), help="which benchmark (bouc-wen)")
    p.add_argument("--data", default=None, help="the benchmark's .mat file (default: the project's copy)")
    p.add_argument("--seed", type=seed, default=0, help="PSO seed (default 0)")
    p.add_argument("--json", action="store_true", help="print the results as JSON only")

