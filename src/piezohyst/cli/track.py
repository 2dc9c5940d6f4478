"""``piezohyst track``: follow sinusoids on the virtual rig with a saved model's compensator (and PID),
or with piezohyst's own commissioning, and print the paper's figures of merit."""

from __future__ import annotations

import argparse
from typing import Any

from ._common import (UsageError, add_rig_options, check_sinusoids, console, finite_float, freqs, nonnegative_float,
                      positive_int, print_json, rig_from_args, rig_rate_note)
from .compensate import compensator_for


def _gains(args: argparse.Namespace) -> str:
    return f"--kp {args.kp:g} --ki {args.ki:g} --kd {args.kd:g}"


def _unstable(exc: Any, args: argparse.Namespace, f: float, what: str) -> UsageError:
    """The loop went unstable: one line naming the settings to change (gains, or the reference)."""
    reason = getattr(exc, "reason", None) or str(exc).split(" with ")[0]
    return UsageError(f"at --freq {f:g} Hz the loop went unstable with {what}: {reason}; lower the gains, or "
                      f"keep --low {args.low:g} .. --high {args.high:g} um within what the stage can reach")


def _check_reachable(rig: Any, args: argparse.Namespace) -> None:
    """Refuse a reference the stage cannot reach within its amplifier's range.

    The stage is driven open loop over its whole range (two cycles at the lowest --freq); a
    reference more than a tenth of that reach beyond it cannot be followed by any controller.
    """
    import numpy as np

    from ..plant import open_loop
    from ..signals import sinusoid

    lo, hi = rig.u_range
    y = open_loop(rig, sinusoid(min(args.freq), 2, lo, hi, rig.dt)).y
    y_lo, y_hi = float(np.min(y)), float(np.max(y))
    margin = 0.1 * (y_hi - y_lo)
    if args.low < y_lo - margin or args.high > y_hi + margin:
        raise UsageError(f"--low {args.low:g} .. --high {args.high:g} um is beyond what the stage reaches with its "
                         f"{lo:g}..{hi:g} V amplifier ({y_lo:.4g} .. {y_hi:.4g} um, measured open loop); no "
                         f"controller can follow it")


def cmd_track(args: argparse.Namespace) -> int:
    from ..control.pid import PID
    from ..control.tracking import UnstableLoopError, track
    from ..modelio import load_model
    from ..signals import sinusoid

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
    check_sinusoids(args.freq, args.cycles, rig.dt, rate_from=rig_rate_note(args))
    _check_reachable(rig, args)
    if args.method == "best":
        from ..commissioning import commission

        ctl = commission(rig, seed=args.seed)
        rows = []
        for f in args.freq:
            ref = sinusoid(f, args.cycles, args.low, args.high, rig.dt)
            try:
                out = ctl.track(ref, period=int(round(1 / (f * rig.dt))))
            except UnstableLoopError as exc:
                raise _unstable(exc, args, f, "the commissioned controller") from None
            rows.append({"freq_hz": f, "method": "best", **out.summary()})
        return _print_track(args, rows, rig, extra={"controller": ctl.describe()})
    model = load_model(args.model)
    try:
        ff = compensator_for(model, rig.dt)
    except (ValueError, TypeError) as exc:
        raise UsageError(f"{args.model}: no compensator from this model: {exc}") from None
    rows = []
    for f in args.freq:
        ref = sinusoid(f, args.cycles, args.low, args.high, rig.dt)
        pid = PID(args.kp, args.ki, args.kd, rig.dt) if args.feedback == "pid" else None
        try:
            out = track(rig, ref, ff, pid, period=int(round(1 / (f * rig.dt))))
        except UnstableLoopError as exc:
            what = f"PID {_gains(args)}" if pid is not None else f"the feedforward of {args.model} alone"
            raise _unstable(exc, args, f, what) from None
        rows.append({"freq_hz": f, "method": f"{type(ff).__name__}" + (" + PID" if pid else ""), **out.summary()})
    return _print_track(args, rows, rig)


def _print_track(args, rows, rig, extra=None) -> int:  # type: ignore[no-untyped-def]
    if args.json:
        print_json({"rig": rig.settings.to_dict(), "seed": args.seed, "reference_um": [args.low, args.high],
                     "results": rows, **(extra or {})})
        return 0
    from rich.table import Table

    t = Table(title=f"Tracking on the virtual rig (seed {args.seed}), reference {args.low:g}-{args.high:g} µm")
    for c in ("freq (Hz)", "method", "e_max (µm)", "e_max % of span", "RMSE (µm)", "RMSE % of span", "clipped"):
        t.add_column(c, justify="right" if c != "method" else "left")
    for r in rows:
        t.add_row(f"{r['freq_hz']:g}", r["method"], f"{r['e_max_um']:.4f}", f"{r['e_max_percent']:.2f}",
                  f"{r['rmse_um']:.4f}", f"{r['rmse_percent']:.2f}", str(r["clipped_samples"]))
    console().print(t)
    return 0


def register(sub: Any, add: Any) -> None:
    p = add("track", cmd_track,
            "Track sinusoids on the virtual rig with a saved model's feedforward (and PID), or with "
            "--method best (piezohyst's own commissioning), and print the paper's figures of merit.",
            "piezohyst track --model pi.json --freq 1,3,5 --feedback pid --ki 500")
    p.add_argument("--model", default=None, help="model file from 'piezohyst identify'")
    p.add_argument("--method", choices=("model", "best"), default="model",
                   help="model: the saved model's feedforward; best: identify on the rig and use everything piezohyst has")
    p.add_argument("--freq", type=freqs, default=[1.0, 3.0, 5.0], help="frequencies in Hz (default 1,3,5)")
    p.add_argument("--cycles", type=positive_int, default=4, help="cycles per run, >= 2; the first is not scored (default 4)")
    p.add_argument("--low", type=finite_float, default=0.25, help="lowest desired displacement, µm (default 0.25)")
    p.add_argument("--high", type=finite_float, default=2.25, help="highest desired displacement, µm (default 2.25)")
    p.add_argument("--feedback", choices=("none", "pid"), default="none", help="add PID feedback (default none)")
    p.add_argument("--kp", type=nonnegative_float, default=0.0, help="PID proportional gain (µm/µm, >= 0)")
    p.add_argument("--ki", type=nonnegative_float, default=0.0, help="PID integral gain (1/s, >= 0)")
    p.add_argument("--kd", type=nonnegative_float, default=0.0, help="PID derivative gain (s, >= 0)")
    p.add_argument("--json", action="store_true", help="print the results as JSON only")
    add_rig_options(p)

