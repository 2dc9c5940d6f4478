"""``piezohyst benchmark bouc-wen``: the Noel-Schoukens identification benchmark."""

from __future__ import annotations

import argparse

from ._common import UsageError, console, guarded, print_json, seed, spinner


def _seeds(text: str) -> list[int]:
    try:
        out = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not out or any(s < 0 for s in out):
        raise argparse.ArgumentTypeError(f"seeds must be integers >= 0, got {text!r}")
    return out


def _scales(text: str) -> list[float]:
    try:
        out = [float(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    # (a scale of 1e308 made the bounds themselves infinite, and the error blamed the data file)
    if not out or not all(1.0 <= s <= MAX_BOUNDS_SCALE for s in out):
        raise argparse.ArgumentTypeError(f"bounds scales must be numbers from 1 to {MAX_BOUNDS_SCALE:g}, got {text!r}")
    return out


#: The widest ``--bounds-scale``: every bound that many times wider (the README's runs use 10).
MAX_BOUNDS_SCALE = 1e6


def cmd_benchmark(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..data import data_dir
    from ..experiments.boucwen_benchmark import (
        BEST_PUBLISHED,
        PUBLISHED,
        QUOTED_FLOOR,
        run_benchmarks,
        summary,
    )

    path = args.data or str(data_dir() / "bouc-wen-benchmark" / "bouc-wen.mat")
    if not Path(path).is_file():
        what = "no such file" if not Path(path).exists() else "not a file"
        raise UsageError(f"{path}: {what}" + ("" if args.data else " (the project's copy of the benchmark data; "
                                              "give --data)"))
    if args.seed is not None and args.seeds is not None:
        raise UsageError("give --seed or --seeds, not both")
    seeds = args.seeds if args.seeds is not None else [args.seed if args.seed is not None else 0]
    scales = args.bounds_scale
    with spinner("loading") as step:
        results = guarded(lambda: run_benchmarks(path, seeds=seeds, bounds_scales=scales, on_step=step), path)
    if args.json:
        out = results[0].to_dict()  # the first run's fields at the top, as before --seeds existed
        out["runs"] = [r.to_dict() for r in results]
        out["summary"] = summary(results)
        print_json(out)
        return 0
    from rich.table import Table

    runs = [r.to_dict() for r in results]
    d = runs[0]
    con = console()
    t = Table(title="Bouc-Wen benchmark: multisine test record, RMS error (m), lower is better")
    t.add_column("method")
    t.add_column("RMS error (m)", justify="right")
    grey = "piezohyst: grey-box (true model structure), PSO + multi-start + least squares"
    if len(runs) == 1:
        rows = [(grey, d["test_rmse_m"]["multisine"]),
                ("piezohyst: PSO stage alone", d["stages"]["pso"]["test_rmse_m"]["multisine"])]
    else:
        rows = [((f"{grey}, bounds x{s['bounds_scale']:g}: median of {s['runs']} seeds (worst "
                 f"{s['worst_multisine_rmse_m']:.3g})"), s["median_multisine_rmse_m"]) for s in summary(results)]
    rows += [(f"black-box: {name}", v) for name, v in PUBLISHED]
    rows += [("the data's floor as quoted with it (true system, RK4 15 kHz)", QUOTED_FLOOR),
             ("true system re-simulated here (band-limited input, RK4 15 kHz)", d["true_system_test_rmse_m"]["multisine"])]
    for name, v in sorted(rows, key=lambda r: r[1]):
        t.add_row(name, f"{v:.3g}")
    con.print(t)
    t = Table(title="Per run (identified from the training record only; bounds derived from it, xS wider)")
    for c in ("bounds", "seed", "multisine (m)", "sine sweep (m)", "training (m)", "PSO stage alone (m)",
              f"< {BEST_PUBLISHED:.3g}", "time (s)"):
        t.add_column(c, justify="right")
    for r in runs:
        t.add_row(f"x{r['bounds_scale']:g}", str(r["seed"]), f"{r['test_rmse_m']['multisine']:.3g}",
                  f"{r['test_rmse_m']['sinesweep']:.3g}", f"{r['train_rmse_m']:.3g}",
                  f"{r['stages']['pso']['test_rmse_m']['multisine']:.3g}",
                  "yes" if r["beats_best_published"] else "NO", f"{r['identification_time_s']:.1f}")
    con.print(t)
    for s in summary(results):
        con.print(f"bounds x{s['bounds_scale']:g}: {s['below_best_published']} of {s['runs']} runs below the best "
                  f"published multisine error ({BEST_PUBLISHED:.3g} m)")
    t = Table(title="Identified parameters (beta fixed to 1: only beta*gamma and beta*delta are identifiable)")
    t.add_column("")
    for c in d["identified"]:
        t.add_column(c, justify="right")
    for r in runs:
        t.add_row(f"bounds x{r['bounds_scale']:g}, seed {r['seed']}", *(f"{v:.5g}" for v in r["identified"].values()))
    t.add_row("true", *(f"{v:.5g}" for v in d["true"].values()))
    con.print(t)
    st = d["stages"]
    con.print(f"first run: identification {d['identification_time_s']:.1f} s (best linear approximation and box "
              f"{st['bla']['time_s']:.3f} s; PSO {st['pso']['time_s']:.1f} s, training RMSE {st['pso']['rmse_m']:.3g} m; "
              f"multi-start from {st['multistart']['starts']} distinct points of the search "
              f"{st['multistart']['time_s']:.1f} s; "
              f"refinement {st['refinement']['time_s']:.1f} s, training RMSE {st['refinement']['rmse_m']:.3g} m, "
              f"which is the record's noise)")
    return 0


def register(sub, add) -> None:  # type: ignore[no-untyped-def]
    p = add("benchmark", cmd_benchmark,
            "Identify the Bouc-Wen benchmark system (Noel and Schoukens) from its training record and "
            "compare the test errors with the published results.",
            "piezohyst benchmark bouc-wen --seeds 0,1,2,3,4 --bounds-scale 1,10")
    p.add_argument("name", choices=("bouc-wen",), help="which benchmark (bouc-wen)")
    p.add_argument("--data", default=None, help="the benchmark's .mat file (default: the project's copy)")
    p.add_argument("--seed", type=seed, default=None, help="PSO seed (default 0); see --seeds for several")
    p.add_argument("--seeds", type=_seeds, default=None, help="PSO seeds, comma-separated: one run each")
    p.add_argument("--bounds-scale", type=_scales, default=[1.0],
                   help="widen every search bound this many times (comma-separated for several; default 1: "
                        "the bounds derived from the training data)")
    p.add_argument("--json", action="store_true", help="print the results as JSON only")

