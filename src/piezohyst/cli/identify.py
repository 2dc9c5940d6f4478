"""``piezohyst identify``: fit a model (any kind, or the best on held-out data) and save it."""

from __future__ import annotations

import argparse
import math
from typing import Any

from ._common import (UsageError, add_data_options, console, guarded, load_cli_dataset, nonnegative_int, positive_int,
                      print_json, progress_wanted, sample_range, seed, shown, spinner)

#: --model choices: "auto" and every kind name and alias (from the registry, at parse time)
_MODEL_HELP = ("model kind: auto (every kind, chosen on held-out data), pi (the paper's P-I), bouc-wen (the "
               "paper's), rate-dependent, asymmetric-pi, preisach, bouc-wen-hysteresis, generalized-duhem "
               "(default auto)")


def _delay(text: str) -> Any:
    if text == "auto":
        return text
    try:
        d = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of samples >= 0 or 'auto', got {text!r}") from None
    if d < 0:
        raise argparse.ArgumentTypeError(f"the delay must be >= 0 samples, got {d}")
    return d


def _check_magnitude(ds: Any, source: str) -> None:
    """Refuse a record with nothing to identify (a constant column), or values whose squares
    overflow double precision in the fit (they give RMSE inf)."""
    import numpy as np

    n = max(len(ds), 1)
    for name, arr in (("u", ds.u), ("y", ds.y)):
        if float(np.ptp(arr)) == 0.0:
            flag = "--u-col" if name == "u" else "--y-col"
            raise UsageError(f"{source}: {name} is constant ({arr[0]:g}): nothing to identify (check {flag})")
        peak = float(np.max(np.abs(arr)))
        if peak * np.sqrt(n) > 1e150:  # the sum of squared errors would pass 1e300, near the float64 limit
            raise UsageError(f"{source}: {name} reaches {peak:.3g}; squares of values this large overflow double "
                             f"precision in the fit (RMSE inf): rescale the data (u in V, y in um)")


def cmd_identify(args: argparse.Namespace) -> int:
    import numpy as np

    import piezohyst as ph
    from .._fileio import check_output_file
    from ..modelio import check_model_file_name
    from ..models.base import kind_class

    kind = "auto" if args.model.strip().lower() == "auto" else args.model  # as kinds are: AUTO, PI, Preisach
    if kind != "auto":
        try:
            kind = kind_class(kind).kind
        except ValueError as exc:
            raise UsageError(f"--model {args.model}: {exc}") from None
    if args.output:  # refuse before the fit, not after it
        check_output_file(args.output, args.force)
        check_model_file_name(args.output)
    method = args.method or ("pso" if kind == "bouc-wen" else "lsq" if kind == "prandtl-ishlinskii" else "select")
    if method == "pso" and kind not in ("bouc-wen", "prandtl-ishlinskii"):
        raise UsageError(f"--method pso is for --model pi or bouc-wen (the paper's); {kind} is fitted by least squares")
    if method == "lsq" and kind not in ("prandtl-ishlinskii",):
        raise UsageError("--method lsq is for --model pi; the other kinds choose their structure on held-out data "
                         "(--method select, their default)")
    if args.warmup and method != "select":
        raise UsageError(f"--warmup is for the structure search (--method select); --method {method} fits every "
                         "training sample (start the training part later with --train instead)")
    # options that do not apply to this method are refused, as --warmup is (they were ignored
    # without a word: found by fuzzing)
    unused = []
    if method != "select":
        unused += [o for o, given in (("--history", args.history is not None),
                                      ("--keep-glitches", args.keep_glitches)) if given]
    if method == "lsq":
        unused += [o for o, given in (("--seed", args.seed is not None), ("--iterations", args.iterations is not None),
                                      ("--no-polish", args.no_polish)) if given]
    if method == "pso" and kind == "prandtl-ishlinskii" and args.no_polish:
        unused.append("--no-polish")
    if kind == "bouc-wen" and args.n is not None:
        unused.append("--n")
    if unused:
        raise UsageError(f"{', '.join(unused)} {'does' if len(unused) == 1 else 'do'} not apply to --model "
                         f"{args.model} --method {method} (--history and --keep-glitches are the structure search's, "
                         "--seed, --iterations and --no-polish the particle swarm's, --n the P-I and Preisach "
                         "models'); drop " + ("it" if len(unused) == 1 else "them"))
    args.seed = 0 if args.seed is None else args.seed
    args.iterations = 200 if args.iterations is None else args.iterations
    args.history = "auto" if args.history is None else args.history
    if kind == "bouc-wen" and method == "pso" and args.delay == "auto":
        raise UsageError("--delay auto is not available for --model bouc-wen with --method pso; give the delay in samples")
    ds = load_cli_dataset(args.data, args)
    _check_magnitude(ds, args.data)
    start, stop = args.train
    n = len(ds)
    for name, (a, b) in (("--train", args.train), ("--validate", args.validate)):
        if (a is not None and not 0 <= a < n) or (b is not None and not 0 < b <= n) or (
                (a or 0) >= (b if b is not None else n) - 1):
            raise UsageError(f"{name} {a if a is not None else ''}:{b if b is not None else ''} is outside the "
                             f"file's {n} samples (or holds fewer than 2)")
    vstart, vstop = args.validate
    if (vstart is not None or vstop is not None) and start is None and stop is None:
        # the hold-out is data the model was not fitted on: without --train, train on the rest of
        # the record where the validated part is its end or its start (it trained on everything,
        # the validated samples too, and reported their error as held out: found by fuzzing)
        va, vb = vstart or 0, vstop if vstop is not None else n
        if va >= 2 and vb < n:
            raise UsageError(f"--validate {va}:{vb} lies inside the record; give --train with the samples to fit on "
                             f"(outside {va}:{vb}), e.g. --train 0:{va}")
        if va >= 2:
            stop = va  # the part before the validated end
        elif vb <= n - 2:
            start = vb  # the part after the validated start
        else:
            raise UsageError(f"--validate {va}:{vb} leaves no sample of the record to fit on; validate on part of it "
                             "(e.g. its last third) or on another file (--validate-data)")
    elif vstart is not None or vstop is not None:
        ta, tb = start or 0, stop if stop is not None else n
        va, vb = vstart or 0, vstop if vstop is not None else n
        if max(ta, va) < min(tb, vb):
            raise UsageError(f"--train {ta}:{tb} and --validate {va}:{vb} share samples {max(ta, va)}:{min(tb, vb)}: "
                             "a hold-out error is only one on samples the model was not fitted on")
    train = ds.slice(start, stop) if (start is not None or stop is not None) else ds
    if args.warmup and args.warmup > len(train) - 100:
        raise UsageError(f"--warmup {args.warmup} leaves fewer than 100 of the {len(train)} training samples to fit on")
    if isinstance(args.delay, int) and args.delay > len(train) - 2:
        raise UsageError(f"--delay {args.delay} leaves fewer than 2 of the {len(train)} training samples")
    if args.n is not None:
        # parameters the structure holds: n weights (P-I), n(n+1)/2 cells (a Preisach grid of n levels)
        params = args.n * (args.n + 1) // 2 if kind in ("preisach", "auto") else args.n
        if params >= len(train):
            raise UsageError(f"--n {args.n} makes {params} parameters for the {len(train)} training samples: too many "
                             f"to fit")
    # validation sets: (name, data simulated from its first sample, first sample scored)
    validation = []
    if vstart is not None or vstop is not None:
        # simulate the record from its start, so the model carries its memory into the slice
        validation.append(("samples %s:%s" % (vstart or "", vstop or ""), ds.slice(None, vstop), vstart or 0))
    for vf in args.validate_data or []:
        vd = load_cli_dataset(vf, args)
        _check_magnitude(vd, vf)
        validation.append((vf, vd, 0))
    show = progress_wanted()
    if args.delay is None:
        args.delay = "auto" if method == "select" else 0

    def fit_it() -> Any:
        if kind == "bouc-wen" and method == "pso":
            return ph.fit_bouc_wen(train.u, train.y, train.dt, seed=args.seed, delay=args.delay,
                                   max_iter=args.iterations, polish=not args.no_polish, progress=show)
        if kind == "prandtl-ishlinskii" and method in ("lsq", "pso"):
            return ph.fit_pi(train.u, train.y, n=args.n or 20, method=method, seed=args.seed, delay=args.delay,
                             max_iter=args.iterations, progress=show and method == "pso")
        vsets = [(vd.u, vd.y, first) for _, vd, first in validation]
        return _select(ph, train, kind, args, vsets)

    # a check of the API refusing these data names the file (the flags were checked above)
    fit = guarded(fit_it, args.data)
    if method in ("lsq", "pso"):  # the paper's fits say nothing of the record's range; fit_model does
        from ..identify.monotone import range_warnings

        d = fit.delay
        fit.warnings = range_warnings(train.u[: len(train) - d], train.y[d:]) + list(fit.warnings)
    if not np.isfinite(fit.rmse):
        raise UsageError(f"{args.data}: the fit's RMSE is {fit.rmse} (not finite): the model cannot follow these "
                         f"data; check their units and scale")
    vrows = []
    for name, vd, first in validation:
        d = fit.delay
        resid = fit.residual(vd.u, vd.y, vd.dt)[max(first - d, 0):]
        if resid.size < 1:
            raise UsageError(f"{name}: no sample left to validate on after the model's delay of {d} samples")
        span = float(np.ptp(vd.y[first:]))
        # the validation record's sensor zero may differ: report with and without refitting it
        vrows.append({"data": name, "n_samples": int(resid.size), "rmse": float(np.sqrt(np.mean(resid**2))),
                      "rmse_percent_of_span": 100.0 * float(np.sqrt(np.mean(resid**2))) / span if span > 0 else None,
                      "rmse_offset_refit": float(np.std(resid)),
                      "max_abs_error": float(np.max(np.abs(resid - resid.mean())))})
    # the white part of the fit's residual: the sensor's noise, which no model can take out
    noise = ph.sensor_noise_rms(fit.residual(train.u, train.y, train.dt)) if len(train) > fit.delay + 2 else None
    beyond = math.sqrt(max(fit.rmse**2 - noise**2, 0.0)) if noise is not None else None
    out_path = None
    if args.output:
        out_path = str(ph.save_model(fit.model, args.output, fit=fit, dataset=train, force=args.force))
    result = {"model": fit.model.kind, "fit": fit.summary(), "parameters": fit.model.to_dict(),
              "invertible": bool(fit.model.is_invertible), "validation": vrows, "warnings": list(fit.warnings),
              "sensor_noise_rms": noise, "fit_rmse_beyond_noise": beyond,
              "train_samples": len(train), "written": out_path,
              # (every RMSE, error and noise figure above is in the output's unit, which was
              # stated nowhere in the JSON: found by a helper)
              "units": {"t": "s", "u": "V", "y": "um", "rmse": "um", "max_abs_error": "um", "offset": "um",
                        "sensor_noise_rms": "um", "delay": "samples", "percent_of_span": "%"}}
    if args.json:
        print_json(result)
        return 0
    _print_report(fit, vrows, out_path, ds, train, noise, beyond)
    return 0


def _select(ph: Any, train: Any, kind: str, args: argparse.Namespace, vsets: list[Any]) -> Any:
    """``fit_model`` with a spinner naming the stage (on a terminal's standard error)."""
    opts = dict(validation=vsets or None, delay=args.delay, n=args.n, seed=args.seed,
                bouc_wen_options={"max_iter": args.iterations, "polish": not args.no_polish}, warmup=args.warmup,
                glitches="keep" if args.keep_glitches else "bridge", history=args.history)
    dt = train.dt
    with spinner("identifying") as step:
        return ph.fit_model(train.u, train.y, dt, kind, progress=lambda s: step(f"choosing: {s}"), **opts)


def _print_report(fit: Any, vrows: list[dict[str, Any]], out_path: str | None, ds: Any, train: Any,
                  noise: float | None = None, beyond: float | None = None) -> None:
    from rich.table import Table

    con = console()
    src = ds.meta.get("source", "data")
    part = f"{len(train)} of {len(ds)} samples" if len(train) != len(ds) else f"{len(ds)} samples"
    con.print(f"Identified model: {fit.model.kind}, on {part} of {src}")
    cands = fit.info.get("candidates")
    if cands:
        t = Table(title=f"Candidates, scored on {fit.info['holdout']['on']} (lower is better)")
        for c in ("", "candidate", "hold-out RMSE µm", "% of span", "parameters"):
            t.add_column(c, justify="left" if c in ("", "candidate") else "right")
        for c in sorted(cands, key=lambda c: c["holdout_rmse"])[:15]:
            pct = c["holdout_percent_of_span"]
            t.add_row("*" if c["chosen"] else "", c["label"], f"{c['holdout_rmse']:.4g}",
                      f"{pct:.2f}" if pct is not None else "-", str(c["n_parameters"]))
        con.print(t)
        if len(cands) > 15:
            con.print(f"({len(cands) - 15} more candidates in --json)")
    elif fit.model.kind == "prandtl-ishlinskii":
        t = Table(title="P-I weights")
        for c in ("i", "r_i (V)", "w_i", "partial sum"):
            t.add_column(c, justify="right")
        m = fit.model
        for i, (r, w, s) in enumerate(zip(m.thresholds, m.weights, m.partial_sums), 1):
            t.add_row(str(i), f"{r:.4g}", f"{w:.5g}", f"{s:.5g}")
        con.print(t)
        con.print(f"weights w_i in µm/V; offset {m.offset:.6g} µm")
    elif fit.sensitivity:
        t = Table(title="Bouc-Wen parameters")
        for c in ("parameter", "value", "RMSE rise for 10 % change", "constrained by the data?"):
            t.add_column(c, justify="right" if c != "parameter" else "left")
        units = {"m": "kg", "b": "N s/m", "k": "N/m", "d1": "m/V", "alpha": "", "beta": "1/V", "gamma": "1/V"}
        for name, unit in units.items():
            s = fit.sensitivity.get(name, float("nan"))
            t.add_row(name, f"{getattr(fit.model, name):.5g} {unit}", f"{100 * s:.3g} %", "barely" if s < 0.01 else "yes")
        con.print(t)
    span = float(train.y.max() - train.y.min())
    con.print(f"fit RMSE {fit.rmse:.5g} µm ({100 * fit.rmse / span:.2f} % of span) | {fit.method} | "
              f"{fit.time_s:.2f} s" + (f" | delay {fit.delay} samples" if fit.delay else ""))
    if noise is not None and noise > 0.0 and beyond is not None:
        con.print(f"sensor noise {noise:.4g} µm RMS (the white part of the residual): the fit RMSE is "
                  f"{fit.rmse / noise:.3g}x it; what the model misses is about {beyond:.4g} µm RMS")
    if "pso_rmse" in fit.info and fit.method.endswith("polish"):
        con.print(f"PSO alone reached RMSE {fit.info['pso_rmse']:.5g} µm; the local refinement brought it to "
                  f"{fit.rmse:.5g} µm")
    for v in vrows:
        pct = v["rmse_percent_of_span"]
        con.print(f"validation on {v['data']}: RMSE {v['rmse']:.4g} µm" + (f" ({pct:.2f} % of span)" if pct else "")
                  + f", with its own offset {v['rmse_offset_refit']:.4g}, max |error| {v['max_abs_error']:.4g} µm "
                  f"({v['n_samples']} samples)")
    con.print(f"invertible: {bool(fit.model.is_invertible)}")
    for w in fit.warnings:
        con.print(f"warning: {w}")
    if out_path:
        con.print(f"model written to {shown(out_path)}")


def register(sub: Any, add: Any) -> None:
    p = add("identify", cmd_identify,
            "Identify a hysteresis model from a voltage/displacement record (the best kind and structure on "
            "held-out data, or the kind you name) and save it as JSON.",
            "piezohyst identify data/piezo-dbo/Model_Vi_Do.dat --u-col 0 --y-col 4 --fs 200 "
            "--model auto --train 0:4000 --validate 4000:8000 -o model.json")
    p.add_argument("data", help="data file: .csv/.txt/.dat (header or --u-col/--y-col), .mat or .npz")
    add_data_options(p)
    p.add_argument("--model", default="auto", metavar="KIND", help=_MODEL_HELP)
    p.add_argument("--method", choices=("select", "lsq", "pso"), default=None,
                   help="select: choose the structure on held-out data (default for every kind but the paper's); "
                   "lsq: pi by least squares with fixed operators (pi default); pso: the paper's particle swarm "
                   "(bouc-wen default, or pi)")
    p.add_argument("--n", type=positive_int, default=None,
                   help="play operators (pi) or grid levels (preisach); default: chosen on held-out data (20 for --method lsq/pso)")
    p.add_argument("--seed", type=seed, default=None, help="PSO seed (default 0)")
    p.add_argument("--iterations", type=positive_int, default=None, help="PSO iterations (default 200)")
    p.add_argument("--no-polish", action="store_true", help="bouc-wen: PSO only, no local refinement")
    p.add_argument("--delay", type=_delay, default=None,
                   help="samples by which the output lags the input, or 'auto' (default: searched on held-out data "
                   "with --method select, 0 with lsq/pso)")
    p.add_argument("--train", type=sample_range, default=(None, None), metavar="START:STOP", help="fit on these samples only")
    p.add_argument("--warmup", type=nonnegative_int, default=0, metavar="SAMPLES",
                   help="samples at the start of the training part that only set the model's state (e.g. a "
                   "conditioning sweep over the whole range): run through, neither fitted nor scored "
                   "(--method select; default 0)")
    p.add_argument("--history", choices=("auto", "none"), default=None,
                   help="the stage's state at the record's start: 'auto' (default, --method select) also fits the "
                   "chosen structure after a history down to the bottom of the record's input and back, and up to "
                   "its top and back (a stage at rest keeps the branch it came down or up on), and keeps one where "
                   "it predicts the held-out part better; 'none' starts every model de-energised")
    p.add_argument("--keep-glitches", action="store_true",
                   help="fit isolated gross glitches of the output as they are (default, with --method select: "
                   "one or two samples off their neighbours by more than 5 %% of the span are bridged, with a warning)")
    p.add_argument("--validate", type=sample_range, default=(None, None), metavar="START:STOP",
                   help="choose on, and report the error on, these samples of the same file (simulated from its "
                   "start); never shared with --train, and without it the record's other end is trained on "
                   "(--validate 6000: trains on 0:6000)")
    p.add_argument("--validate-data", action="append", metavar="FILE",
                   help="choose on, and report the error on, another file (same columns; may repeat)")
    p.add_argument("-o", "--output", help="write the model here (JSON; '-': stdout)")
    p.add_argument("--force", action="store_true", help="overwrite the output file if it exists")
    p.add_argument("--json", action="store_true", help="print the results as JSON only")
