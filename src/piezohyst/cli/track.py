"""``piezohyst track``: follow sinusoids on the virtual rig with a saved model's compensator (and PID),
or with piezohyst's own commissioning, and print the paper's figures of merit."""

from __future__ import annotations

import argparse
from typing import Any

from ._common import UsageError, add_rig_options, console, freqs, print_json, rig_from_args
from .compensate import compensator_for


def cmd_track(args: argparse.Namespace) -> int:
    from ..control.pid import PID
    from ..control.tracking import track
    from ..modelio import load_model
    from ..signals import sinusoid

    rig = rig_from_args(args)
    if args.method == "best":
        from ..commissioning import commission

        if args.model:
            raise UsageError("--method best identifies on the rig itself; drop --model")
        ctl = commission(rig, seed=args.seed)
        rows = []
        for f in args.freq:
            ref = sinusoid(f, args.cycles, args.low, args.high, rig.dt)
            out = ctl.track(ref, period=int(round(1 / (f * rig.dt))))
            rows.append({"freq_hz": f, "method": "best", **out.summary()})
        return _print_track(args, rows, rig, extra={"controller": ctl.describe()})
    if not args.model:
        raise UsageError("give --model MODEL.json (or --method best)")
    model = load_model(args.model)
    ff = compensator_for(model, rig.dt)
    rows = []
    for f in args.freq:
        ref = sinusoid(f, args.cycles, args.low, args.high, rig.dt)
        pid = PID(args.kp, args.ki, args.kd, rig.dt) if args.feedback == "pid" else None
        out = track(rig, ref, ff, pid, period=int(round(1 / (f * rig.dt))))
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
    p.add_argument("--cycles", type=int, default=4, help="cycles per run; the first is not scored (default 4)")
    p.add_argument("--low", type=float, default=0.25, help="lowest desired displacement, µm (default 0.25)")
    p.add_argument("--high", type=float, default=2.25, help="highest desired displacement, µm (default 2.25)")
    p.add_argument("--feedback", choices=("none", "pid"), default="none", help="add PID feedback (default none)")
    p.add_argument("--kp", type=float, default=0.0, help="PID proportional gain (µm/µm)")
    p.add_argument("--ki", type=float, default=0.0, help="PID integral gain (1/s)")
    p.add_argument("--kd", type=float, default=0.0, help="PID derivative gain (s)")
    p.add_argument("--json", action="store_true", help="print the results as JSON only")
    add_rig_options(p)

