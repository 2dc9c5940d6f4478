"""``piezohyst compensate`` and ``piezohyst track``: using a saved model."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from .cli import _REGISTRY, UsageError, _console, _freqs, _print_json
from .cli_rig import add_rig_options, rig_from_args


def feedforward_for(model: Any):  # type: ignore[no-untyped-def]
    """The paper's feedforward for a model: inverse P-I or Bouc-Wen hysteresis estimate."""
    from .control.feedforward import BoucWenFeedforward, InversePIFeedforward
    from .models import BoucWen, PrandtlIshlinskii

    if isinstance(model, PrandtlIshlinskii):
        return InversePIFeedforward(model)
    if isinstance(model, BoucWen):
        return BoucWenFeedforward(model)
    raise UsageError(f"no feedforward for a {type(model).__name__}")


def load_reference(path: str, ref_col: Any, t_col: Any, fs: float | None) -> tuple[np.ndarray, np.ndarray]:
    """A desired trajectory (µm) from a text/CSV file, with its time vector."""
    from .data import DataError, read_table

    p = Path(path)
    if not p.exists():
        raise DataError(f"{p}: no such file")
    names, arr, header = read_table(p)
    low = [n.lower().split("_")[0].split(" ")[0] for n in names]

    def pick(given: Any, aliases: tuple[str, ...]) -> int | None:
        if given is not None:
            if isinstance(given, int):
                if not 0 <= given < len(names):
                    raise DataError(f"{p}: column {given} does not exist ({len(names)} columns)")
                return given
            if given in names:
                return names.index(given)
            raise DataError(f"{p}: unknown column {given!r}; the columns are {names}")
        for a in aliases:
            if a in low:
                return low.index(a)
        return None

    ir = pick(ref_col, ("x", "reference", "ref", "desired", "y", "xd"))
    it = pick(t_col, ("t", "time"))
    if ir is None:
        if arr.shape[1] == 1:
            ir = 0
        elif arr.shape[1] == 2 and not header:
            it, ir = 0, 1  # a bare two-column file: time, reference
        else:
            raise DataError(f"{p}: cannot tell which column is the desired displacement; give --ref-col")
    ref = arr[:, ir]
    if not np.all(np.isfinite(ref)):
        raise DataError(f"{p}: the reference contains NaN or inf")
    if it is not None:
        t = arr[:, it]
    elif fs is not None:
        t = np.arange(ref.size) / fs
    else:
        raise DataError(f"{p}: no time column; give --fs")
    if np.any(np.diff(t) <= 0):
        raise DataError(f"{p}: time must be strictly increasing")
    return t, ref


def cmd_compensate(args: argparse.Namespace) -> int:
    from ._fileio import atomic_write, check_writable, producer
    from .modelio import load_model

    model = load_model(args.model)
    t, ref = load_reference(args.reference, args.ref_col, args.t_col, args.fs)
    out = check_writable(args.output, args.force)
    ff = feedforward_for(model)
    u = ff.command(ref)
    lo, hi = args.u_min, args.u_max
    outside = (u < lo) | (u > hi)
    n_out = int(outside.sum())
    if n_out and not args.clip:
        i = int(np.argmax(outside))
        raise UsageError(
            f"the command leaves the amplifier range {lo:g}..{hi:g} V at {n_out} of {u.size} samples "
            f"(first at t = {t[i]:.6g} s: {u[i]:.4g} V); change the reference or pass --clip"
        )
    if n_out:
        u = np.clip(u, lo, hi)

    def write(tmp):  # type: ignore[no-untyped-def]
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(f"# {producer()}\n# model: {args.model} ({type(model).__name__}); reference: {args.reference}\n")
            fh.write(f"# units: t in s, x_d in um, u in V; amplifier range {lo:g}..{hi:g} V; clipped samples: {n_out}\n")
            fh.write("t_s,x_d_um,u_V\n")
            np.savetxt(fh, np.column_stack([t, ref, u]), delimiter=",", fmt="%.10g")

    atomic_write(out, write, force=args.force)
    res = {"written": str(out), "samples": int(u.size), "u_min_V": float(u.min()), "u_max_V": float(u.max()),
           "clipped_samples": n_out, "model_kind": type(model).__name__}
    if args.json:
        _print_json(res)
    else:
        _console().print(f"wrote {u.size} commands ({u.min():.3f} .. {u.max():.3f} V"
                         + (f", {n_out} clipped" if n_out else "") + f") to {out}")
    return 0


def cmd_track(args: argparse.Namespace) -> int:
    from .control.pid import PID
    from .control.tracking import track
    from .modelio import load_model
    from .signals import sinusoid

    rig = rig_from_args(args)
    if args.method == "best":
        from .commission import commission

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
    ff = feedforward_for(model)
    rows = []
    for f in args.freq:
        ref = sinusoid(f, args.cycles, args.low, args.high, rig.dt)
        pid = PID(args.kp, args.ki, args.kd, rig.dt) if args.feedback == "pid" else None
        out = track(rig, ref, ff, pid, period=int(round(1 / (f * rig.dt))))
        rows.append({"freq_hz": f, "method": f"{type(ff).__name__}" + (" + PID" if pid else ""), **out.summary()})
    return _print_track(args, rows, rig)


def _print_track(args, rows, rig, extra=None) -> int:  # type: ignore[no-untyped-def]
    if args.json:
        _print_json({"rig": rig.settings.to_dict(), "seed": args.seed, "reference_um": [args.low, args.high],
                     "results": rows, **(extra or {})})
        return 0
    from rich.table import Table

    t = Table(title=f"Tracking on the virtual rig (seed {args.seed}), reference {args.low:g}-{args.high:g} µm")
    for c in ("freq (Hz)", "method", "e_max (µm)", "e_max % of span", "RMSE (µm)", "RMSE % of span", "clipped"):
        t.add_column(c, justify="right" if c != "method" else "left")
    for r in rows:
        t.add_row(f"{r['freq_hz']:g}", r["method"], f"{r['e_max_um']:.4f}", f"{r['e_max_percent']:.2f}",
                  f"{r['rmse_um']:.4f}", f"{r['rmse_percent']:.2f}", str(r["clipped_samples"]))
    _console().print(t)
    return 0


def register(sub, add) -> None:  # type: ignore[no-untyped-def]
    p = add("compensate", cmd_compensate,
            "Compute the voltage command that makes the modelled actuator follow a desired trajectory "
            "(offline feedforward, e.g. for a wave-table controller).",
            "piezohyst compensate --model pi.json --reference ref.csv -o cmd.csv")
    p.add_argument("--model", required=True, help="model file from 'piezohyst identify'")
    p.add_argument("--reference", required=True, help="desired displacement (µm): CSV/text with a t column or --fs")
    p.add_argument("--ref-col", type=lambda v: int(v) if v.isdigit() else v, default=None, help="reference column")
    p.add_argument("--t-col", type=lambda v: int(v) if v.isdigit() else v, default=None, help="time column")
    p.add_argument("--fs", type=float, default=None, help="sample rate (Hz) if the file has no time column")
    p.add_argument("-o", "--output", required=True, help="command file to write (CSV: t_s,x_d_um,u_V)")
    p.add_argument("--u-min", type=float, default=0.0, help="amplifier's lowest voltage (default 0)")
    p.add_argument("--u-max", type=float, default=100.0, help="amplifier's highest voltage (default 100)")
    p.add_argument("--clip", action="store_true", help="clip commands to the range instead of refusing")
    p.add_argument("--force", action="store_true", help="overwrite the output file")
    p.add_argument("--json", action="store_true", help="print the summary as JSON only")

    p = add("track", cmd_track,
            "Track sinusoids on the virtual rig with a saved model's feedforward (and PID), or with "
            "--method best (piezohyst's own commissioning), and print the paper's figures of merit.",
            "piezohyst track --model pi.json --freq 1,3,5 --feedback pid --ki 500")
    p.add_argument("--model", default=None, help="model file from 'piezohyst identify'")
    p.add_argument("--method", choices=("model", "best"), default="model",
                   help="model: the saved model's feedforward; best: identify on the rig and use everything piezohyst has")
    p.add_argument("--freq", type=_freqs, default=[1.0, 3.0, 5.0], help="frequencies in Hz (default 1,3,5)")
    p.add_argument("--cycles", type=int, default=4, help="cycles per run; the first is not scored (default 4)")
    p.add_argument("--low", type=float, default=0.25, help="lowest desired displacement, µm (default 0.25)")
    p.add_argument("--high", type=float, default=2.25, help="highest desired displacement, µm (default 2.25)")
    p.add_argument("--feedback", choices=("none", "pid"), default="none", help="add PID feedback (default none)")
    p.add_argument("--kp", type=float, default=0.0, help="PID proportional gain (µm/µm)")
    p.add_argument("--ki", type=float, default=0.0, help="PID integral gain (1/s)")
    p.add_argument("--kd", type=float, default=0.0, help="PID derivative gain (s)")
    p.add_argument("--json", action="store_true", help="print the results as JSON only")
    add_rig_options(p)


_REGISTRY.append(register)
