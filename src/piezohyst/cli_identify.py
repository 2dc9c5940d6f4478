"""``piezohyst identify``: fit a P-I or Bouc-Wen model to a data file and save it."""

from __future__ import annotations

import argparse
from typing import Any

from .cli import _REGISTRY, UsageError, _console, _print_json


def _slice(text: str | None) -> tuple[int | None, int | None]:
    if not text:
        return (None, None)
    try:
        a, b = text.split(":")
        return (int(a) if a else None, int(b) if b else None)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START:STOP sample indices, got {text!r}") from None


def _col(text: str) -> Any:
    return int(text) if text.lstrip("-").isdigit() else text


def load_cli_dataset(path: str, args: argparse.Namespace):  # type: ignore[no-untyped-def]
    import piezohyst as ph

    return ph.load_dataset(path, u_col=args.u_col, y_col=args.y_col, t_col=args.t_col, fs=args.fs)


def add_data_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--u-col", type=_col, default=None, help="input column (0-based index or header name)")
    p.add_argument("--y-col", type=_col, default=None, help="output column (0-based index or header name)")
    p.add_argument("--t-col", type=_col, default=None, help="time column (else --fs)")
    p.add_argument("--fs", type=float, default=None, help="sample rate in Hz when the file has no time column")


def cmd_identify(args: argparse.Namespace) -> int:
    import numpy as np

    import piezohyst as ph
    from piezohyst.identify import simulate_fit

    ds = load_cli_dataset(args.data, args)
    start, stop = args.train
    train = ds.slice(start, stop) if (start is not None or stop is not None) else ds
    if args.model == "pi":
        fit = ph.fit_pi(train.u, train.y, n=args.n, method=args.method, seed=args.seed,
                        delay=args.delay, progress=not args.json and args.method == "pso")
    else:
        if args.method != "pso":
            raise UsageError("the Bouc-Wen model is identified with --method pso")
        if args.delay == "auto":
            raise UsageError("--delay auto is for --model pi; give the Bouc-Wen delay in samples")
        fit = ph.fit_bouc_wen(train.u, train.y, train.dt, seed=args.seed, delay=args.delay,
                              max_iter=args.iterations, polish=not args.no_polish,
                              progress=not args.json)
    # (name, data set simulated from its first sample, first sample scored)
    validation = []
    vstart, vstop = args.validate
    if vstart is not None or vstop is not None:
        # simulate the record from its start, so the operators carry their memory into the slice
        validation.append(("samples %s:%s" % (vstart or "", vstop or ""), ds.slice(None, vstop), vstart or 0))
    for vf in args.validate_data or []:
        validation.append((vf, load_cli_dataset(vf, args), 0))
    vrows = []
    for name, vd, first in validation:
        pred = simulate_fit(fit, vd.u, vd.dt)
        d = fit.delay
        resid = (vd.y[d:] - pred[: pred.size - d] if d else vd.y - pred)[max(first - d, 0):]
        # the validation record's sensor zero may differ: report with and without refitting it
        vrows.append({"data": name, "n_samples": int(resid.size), "rmse": float(np.sqrt(np.mean(resid**2))),
                      "rmse_offset_refit": float(np.std(resid)),
                      "max_abs_error": float(np.max(np.abs(resid - resid.mean())))})
    out_path = None
    if args.output:
        out_path = str(ph.save_model(fit.model, args.output, fit=fit, dataset=train, force=args.force))
    result = {"model": args.model, "fit": fit.summary(), "parameters": _params(fit.model),
              "validation": vrows, "written": out_path}
    if args.json:
        _print_json(result)
        return 0
    _print_table(fit, vrows, out_path, ds)
    return 0


def _params(model) -> dict[str, Any]:  # type: ignore[no-untyped-def]
    import piezohyst as ph

    if isinstance(model, ph.PrandtlIshlinskii):
        return {"thresholds": model.thresholds.tolist(), "weights": model.weights.tolist(),
                "offset": model.offset, "invertible": model.is_invertible}
    return model.parameters()


def _print_table(fit, vrows, out_path, ds) -> None:  # type: ignore[no-untyped-def]
    from rich.table import Table

    import piezohyst as ph

    con = _console()
    t = Table(title=f"Identified {type(fit.model).__name__} ({fit.method}) on {len(ds)} samples of {ds.meta.get('source', 'data')}")
    if isinstance(fit.model, ph.PrandtlIshlinskii):
        t.add_column("i", justify="right")
        t.add_column("r_i (V)", justify="right")
        t.add_column("w_i", justify="right")
        t.add_column("partial sum", justify="right")
        for i, (r, w, s) in enumerate(zip(fit.model.thresholds, fit.model.weights, fit.model.partial_sums), 1):
            t.add_row(str(i), f"{r:.4g}", f"{w:.5g}", f"{s:.5g}")
        con.print(t)
        con.print(f"offset {fit.model.offset:.6g} (output units); invertible: {fit.model.is_invertible}")
    else:
        t.add_column("parameter")
        t.add_column("value", justify="right")
        t.add_column("RMSE rise for 10 % change", justify="right")
        t.add_column("constrained by the data?")
        units = {"m": "kg", "b": "N s/m", "k": "N/m", "d1": "m/V", "alpha": "", "beta": "1/V", "gamma": "1/V"}
        for name, unit in units.items():
            s = fit.sensitivity.get(name, float("nan"))
            t.add_row(name, f"{getattr(fit.model, name):.5g} {unit}", f"{100 * s:.3g} %",
                      "barely" if s < 0.01 else "yes")
        con.print(t)
    con.print(f"RMSE {fit.rmse:.5g} (units of y) | {fit.method} | {fit.time_s:.2f} s"
              + (f" | {fit.nit} iterations, {fit.nfev} evaluations" if fit.nfev else "")
              + (f" | delay {fit.delay} samples" if fit.delay else ""))
    if "pso_rmse" in fit.info and fit.method.endswith("polish"):
        con.print(f"PSO alone reached RMSE {fit.info['pso_rmse']:.5g}; the local refinement brought it to {fit.rmse:.5g}")
    for v in vrows:
        con.print(f"validation on {v['data']}: RMSE {v['rmse']:.4g}, with its own offset {v['rmse_offset_refit']:.4g}, "
                  f"max |error| {v['max_abs_error']:.4g} ({v['n_samples']} samples)")
    if out_path:
        con.print(f"model written to {out_path}")


def register(sub, add) -> None:  # type: ignore[no-untyped-def]
    p = add("identify", cmd_identify,
            "Identify a P-I or Bouc-Wen model from a voltage/displacement record and save it as JSON.",
            "piezohyst identify data/piezo-dbo/Model_Vi_Do.dat --u-col 0 --y-col 4 --fs 200 "
            "--model pi --method lsq --train 0:4000 --validate 4000:8000 -o pi.json")
    p.add_argument("data", help="data file: .csv/.txt/.dat (header or --u-col/--y-col), .mat or .npz")
    add_data_options(p)
    p.add_argument("--model", choices=("pi", "bouc-wen"), default="pi", help="model to identify (default pi)")
    p.add_argument("--method", choices=("lsq", "pso"), default="lsq",
                   help="pi: lsq (constrained least squares, global optimum) or pso (the paper's); bouc-wen: pso")
    p.add_argument("--n", type=int, default=20, help="number of play operators for pi (default 20, as the paper)")
    p.add_argument("--seed", type=int, default=0, help="PSO seed (default 0)")
    p.add_argument("--iterations", type=int, default=200, help="PSO iterations for bouc-wen (default 200)")
    p.add_argument("--no-polish", action="store_true", help="bouc-wen: PSO only, no local refinement")
    p.add_argument("--delay", type=lambda v: v if v == "auto" else int(v), default=0,
                   help="samples by which the output lags the input, or 'auto' (pi only: the best fit of 0..10) (default 0)")
    p.add_argument("--train", type=_slice, default=(None, None), metavar="START:STOP", help="fit on these samples only")
    p.add_argument("--validate", type=_slice, default=(None, None), metavar="START:STOP",
                   help="report the model's error on these samples of the same file")
    p.add_argument("--validate-data", action="append", metavar="FILE", help="report the error on another file (same columns)")
    p.add_argument("-o", "--output", help="write the model here (JSON)")
    p.add_argument("--force", action="store_true", help="overwrite the output file if it exists")
    p.add_argument("--json", action="store_true", help="print the results as JSON only")


_REGISTRY.append(register)
