"""``piezohyst track``: follow sinusoids, or a reference from a file (any shape), on the virtual rig
with a saved model's compensator (and PID), or with piezohyst's own commissioning; print the
paper's figures of merit and, with ``-o``, write the runs."""

from __future__ import annotations

import argparse
import math
from typing import Any

from ._common import (UsageError, add_rig_options, check_sinusoids, console, finite_float, freqs, nonnegative_float,
                      positive_float, positive_int, print_json, rig_from_args, rig_rate_note, shown, spinner)
from .compensate import compensator_for


def _gains(args: argparse.Namespace) -> str:
    return f"--kp {args.kp:g} --ki {args.ki:g} --kd {args.kd:g}"


def _unstable(exc: Any, args: argparse.Namespace, run: str, what: str) -> UsageError:
    """The loop went unstable: one line naming the settings to change (gains, or the reference)."""
    reason = getattr(exc, "reason", None) or str(exc).split(" with ")[0]
    where = f"at --freq {run}" if run.endswith(" Hz") else f"on --reference {run}"
    keep = (f"keep --low {args.low:g} .. --high {args.high:g} um" if args.reference is None
            else "keep the reference") + " within what the stage can reach"
    return UsageError(f"{where} the loop went unstable with {what}: {reason}; lower the gains, or {keep}")


def _check_reachable(rig: Any, args: argparse.Namespace, low: float | None = None, high: float | None = None) -> None:
    """Refuse a reference the stage cannot reach within its amplifier's range.

    The stage is driven open loop over its whole range (two cycles at the lowest --freq); a
    reference more than a tenth of that reach beyond it cannot be followed by any controller.
    ``low``/``high``: a --reference file's extremes (default: --low and --high).
    """
    import numpy as np

    from ..plant import open_loop
    from ..signals import sinusoid

    lo, hi = rig.u_range
    y = open_loop(rig, sinusoid(min(args.freq), 2, lo, hi, rig.dt)).y
    y_lo, y_hi = float(np.min(y)), float(np.max(y))
    margin = 0.1 * (y_hi - y_lo)
    a, b = (args.low, args.high) if low is None or high is None else (low, high)
    if a < y_lo - margin or b > y_hi + margin:
        what = (f"--low {a:g} .. --high {b:g} um" if low is None
                else f"the reference {args.reference} ({a:.4g} .. {b:.4g} um)")
        raise UsageError(f"{what} is beyond what the stage reaches with its "
                         f"{lo:g}..{hi:g} V amplifier ({y_lo:.4g} .. {y_hi:.4g} um, measured open loop); no "
                         f"controller can follow it")


def _references(args: argparse.Namespace, rig: Any) -> list[tuple[str, Any, Any]]:
    """``(label, reference, period)`` per run: the --freq sinusoids, or the --reference file
    (resampled to the rig's rate when its own differs; its period read off the file itself)."""
    from ..export.tables import resample_reference
    from ..signals import estimate_period, sinusoid
    from .compensate import load_reference

    if args.reference is None:
        return [(f"{f:g} Hz", sinusoid(f, args.cycles, args.low, args.high, rig.dt), int(round(1 / (f * rig.dt))))
                for f in args.freq]
    t, ref = load_reference(args.reference, args.ref_col, args.t_col, args.fs)
    dt_ref = float((t[-1] - t[0]) / (t.size - 1))
    if args.fs is not None and abs(dt_ref * args.fs - 1.0) > 1e-6:
        # (a file with a time column was run at its own rate, --fs ignored: found by fuzzing)
        raise UsageError(f"--fs {args.fs:g} Hz, but the time column of {args.reference} says {1.0 / dt_ref:.6g} Hz; "
                         "--fs is the rate of a file without a time column (drop it: the file is resampled to the "
                         "rig's rate)")
    if abs(dt_ref - rig.dt) > 1e-9 * rig.dt:
        t, ref = resample_reference(t, ref, 1.0 / rig.dt, periodic=False)
    return [(str(args.reference), ref, estimate_period(ref))]


def _write_runs(path: str, runs: list[tuple[str, Any]], args: argparse.Namespace) -> str:
    """The runs as CSV (one t, desired, measured, command group of columns per run)."""
    import numpy as np

    from .._fileio import atomic_write, producer

    def write(tmp):  # type: ignore[no-untyped-def]
        n = max(out.t.size for _, out in runs)
        cols, names = [], []
        for label, out in runs:
            tag = label.replace(" ", "") if label.endswith(" Hz") else "ref"
            names += [f"t_{tag}_s", f"x_d_{tag}_um", f"y_{tag}_um", f"u_{tag}_V"]
            for arr in (out.t, out.reference, out.output, out.command):
                c = np.full(n, np.nan)
                c[: arr.size] = arr
                cols.append(c)
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(f"# {producer()}\n# units: t in s, desired and measured displacement in um, command in V; "
                     f"one group of four columns per run\n")
            fh.write(",".join(names) + "\n")
            np.savetxt(fh, np.column_stack(cols), delimiter=",", fmt="%.10g")

    return str(atomic_write(path, write, force=args.force))


def cmd_track(args: argparse.Namespace) -> int:
    from .._fileio import check_writable
    from ..control.pid import PID
    from ..control.tracking import UnstableLoopError, track
    from ..modelio import load_model

    args.freq_given = args.freq is not None
    if args.freq is None:
        args.freq = [1.0, 3.0, 5.0]
    if args.output:
        check_writable(args.output, args.force)
    if args.reference is not None and args.freq_given:
        raise UsageError("give either --freq (sinusoids) or --reference (a trajectory file), not both")
    shaping = [o for o, v in (("--cycles", args.cycles), ("--low", args.low), ("--high", args.high)) if v is not None]
    if args.reference is not None and shaping:
        # (they were ignored without a word: found by fuzzing)
        raise UsageError(f"{', '.join(shaping)} shape{'s' if len(shaping) == 1 else ''} the sinusoids; --reference "
                         "runs the file's trajectory as it is (drop them, or drop --reference)")
    args.cycles = 4 if args.cycles is None else args.cycles
    args.low = 0.25 if args.low is None else args.low
    args.high = 2.25 if args.high is None else args.high
    if not args.low < args.high:
        raise UsageError(f"--low ({args.low:g} um) must be below --high ({args.high:g} um)")
    if args.cycles < 2:
        raise UsageError(f"--cycles must be at least 2 (the first cycle is the start-up and is not scored), "
                         f"got {args.cycles}")
    if (args.kp or args.ki or args.kd) and args.method == "best":
        raise UsageError(f"--method best tunes its own feedback; drop {_gains(args)}")
    if args.feedback != "pid" and (args.kp or args.ki or args.kd):
        raise UsageError(f"{_gains(args)} are the gains of the PID: add --feedback pid (or drop them)")
    if args.method == "best" and args.model:
        raise UsageError("--method best identifies on the rig itself; drop --model")
    if args.method == "model" and not args.model:
        raise UsageError("give --model MODEL.json (or --method best)")
    rig = rig_from_args(args)
    if args.reference is None:
        check_sinusoids(args.freq, args.cycles, rig.dt, rate_from=rig_rate_note(args))
        _check_reachable(rig, args)
    refs = _references(args, rig)
    if args.reference is not None:  # (found by fuzzing: a file 5 um below the stroke ran, 300 % e_max, exit 0)
        _check_reachable(rig, args, float(min(r.min() for _, r, _ in refs)), float(max(r.max() for _, r, _ in refs)))
    runs = []
    if args.method == "best":
        from ..commissioning import commission

        with spinner() as step:
            ctl = commission(rig, seed=args.seed, progress=lambda s: step(f"commissioning: {s}"))
            rows = []
            for label, ref, period in refs:
                step(f"tracking {label}")
                try:
                    out = ctl.track(ref, period=period)
                except UnstableLoopError as exc:
                    raise _unstable(exc, args, label, "the commissioned controller") from None
                runs.append((label, out))
                rows.append({"run": label, "freq_hz": _freq(label), "method": "best", **out.summary()})
        written = _write_runs(args.output, runs, args) if args.output else None
        return _print_track(args, rows, rig, extra={"controller": ctl.describe(), "written": written})
    model = load_model(args.model)
    try:
        ff = compensator_for(model, rig.dt, on_rig=True)
    except (ValueError, TypeError) as exc:
        raise UsageError(f"{args.model}: no compensator from this model: {exc}") from None
    with spinner() as step:
        rows = []
        for label, ref, period in refs:
            step(f"tracking {label}")
            pid = PID(args.kp, args.ki, args.kd, rig.dt) if args.feedback == "pid" else None
            try:
                out = track(rig, ref, ff, pid, period=period)
            except UnstableLoopError as exc:
                what = f"PID {_gains(args)}" if pid is not None else f"the feedforward of {args.model} alone"
                raise _unstable(exc, args, label, what) from None
            runs.append((label, out))
            rows.append({"run": label, "freq_hz": _freq(label), "method": f"{type(ff).__name__}" + (" + PID" if pid else ""),
                         **out.summary()})
    written = _write_runs(args.output, runs, args) if args.output else None
    return _print_track(args, rows, rig, extra={"written": written})


def _freq(label: str) -> float | None:
    return float(label.split()[0]) if label.endswith(" Hz") else None


def _print_track(args, rows, rig, extra=None) -> int:  # type: ignore[no-untyped-def]
    if args.json:
        ref = [args.low, args.high] if args.reference is None else args.reference
        print_json({"rig": rig.settings.to_dict(), "seed": args.seed, "reference": ref,
                    "reference_um": [args.low, args.high] if args.reference is None else None,
                    "results": rows, **(extra or {})})
        return 0
    from rich.table import Table

    what = f"reference {args.low:g}-{args.high:g} µm" if args.reference is None else f"reference {args.reference}"
    t = Table(title=f"Tracking on the virtual rig (seed {args.seed}), {what}")
    floor = any("noise_floor_percent" in r for r in rows)  # a commissioned controller's runs
    for c in ("run", "method", "e_max (µm)", "e_max % of span", "RMSE (µm)", "RMSE % of span", "clipped",
              *(("noise floor %",) if floor else ())):
        t.add_column(c, justify="right" if c not in ("method", "run") else "left")
    def pct(x: Any) -> str:  # a reference that does not move has no span to take a percentage of
        return f"{x:.2f}" if x is not None and math.isfinite(x) else "-"

    for r in rows:
        t.add_row(r["run"], r["method"], f"{r['e_max_um']:.4f}", pct(r["e_max_percent"]),
                  f"{r['rmse_um']:.4f}", pct(r["rmse_percent"]), str(r["clipped_samples"]),
                  *((f"{r['noise_floor_percent']:.2f}" if "noise_floor_percent" in r else "",) if floor else ()))
    con = console()
    con.print(t)
    if any(not (r["e_max_percent"] is not None and math.isfinite(r["e_max_percent"])) for r in rows):
        con.print("-: the reference does not move (its span is 0 um), so the errors have no span to be a "
                  "percentage of; read them in um")
    if floor:
        con.print("noise floor: the e_max the sensor's noise alone reaches over the scored samples (its RMS, "
                  "estimated from the identification run, in --json as sensor_noise_um)")
    if extra and extra.get("written"):
        con.print(f"wrote the runs to {shown(extra['written'])}")
    return 0


def register(sub: Any, add: Any) -> None:
    p = add("track", cmd_track,
            "Track sinusoids (or a reference file of any shape) on the virtual rig with a saved model's "
            "feedforward (and PID), or with --method best (piezohyst's own commissioning), and print the "
            "paper's figures of merit.",
            "piezohyst track --model pi.json --freq 1,3,5 --feedback pid --ki 500\n"
            "  piezohyst track --method best --reference raster.csv -o runs.csv")
    p.add_argument("--model", default=None, help="model file from 'piezohyst identify'")
    p.add_argument("--method", choices=("model", "best"), default="model",
                   help="model: the saved model's feedforward; best: identify on the rig and use everything piezohyst has")
    p.add_argument("--freq", type=freqs, default=None, help="frequencies in Hz (default 1,3,5)")
    p.add_argument("--reference", default=None, metavar="FILE",
                   help="desired displacement (µm) from a CSV/text file ('-': stdin) instead of sinusoids; "
                   "any shape; its period, if it repeats, is read off the file")
    p.add_argument("--ref-col", type=lambda v: int(v) if v.isdigit() else v, default=None,
                   help="reference column of --reference")
    p.add_argument("--t-col", type=lambda v: int(v) if v.isdigit() else v, default=None,
                   help="time column of --reference")
    p.add_argument("--fs", type=positive_float, default=None, help="sample rate (Hz) of --reference if it has no time column")
    p.add_argument("-o", "--output", default=None, help="write the runs (t, desired, measured, command) as CSV ('-': stdout)")
    p.add_argument("--force", action="store_true", help="overwrite the --output file")
    p.add_argument("--cycles", type=positive_int, default=None,
                   help="cycles per sinusoid, >= 2; the first is not scored (default 4)")
    p.add_argument("--low", type=finite_float, default=None, help="lowest desired displacement of the sinusoids, µm "
                   "(default 0.25)")
    p.add_argument("--high", type=finite_float, default=None, help="highest desired displacement of the sinusoids, "
                   "µm (default 2.25)")
    p.add_argument("--feedback", choices=("none", "pid"), default="none", help="add PID feedback (default none)")
    p.add_argument("--kp", type=nonnegative_float, default=0.0, help="PID proportional gain (µm/µm, >= 0)")
    p.add_argument("--ki", type=nonnegative_float, default=0.0, help="PID integral gain (1/s, >= 0)")
    p.add_argument("--kd", type=nonnegative_float, default=0.0, help="PID derivative gain (s, >= 0)")
    p.add_argument("--json", action="store_true", help="print the results as JSON only")
    add_rig_options(p)

