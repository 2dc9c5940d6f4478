"""``piezohyst compensate``: the command a saved model's compensator gives for a desired trajectory."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ._common import UsageError, console, print_json


def compensator_for(model: Any, dt: float | None, **limits: Any) -> Any:
    """A model's compensator at sample period ``dt`` (any kind, through the model protocol)."""
    if not getattr(model, "is_invertible", False):
        raise UsageError(f"the {model.kind} model is not invertible: it has no compensator")
    own = getattr(model, "dt", None)
    if model.dynamic and own is not None and dt is not None and abs(own - dt) > 1e-9 * own:
        raise UsageError(f"the model was identified at {1 / own:g} Hz but the reference is sampled at "
                         f"{1 / dt:g} Hz; resample the reference to the model's rate")
    return model.compensator(dt if model.dynamic else None, **limits)


def load_reference(path: str, ref_col: Any, t_col: Any, fs: float | None) -> tuple[Any, Any]:
    """A desired trajectory (µm) from a text/CSV file, with its time vector."""
    import numpy as np

    from ..data import DataError, read_table

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
        if not (fs > 0 and np.isfinite(fs)):
            raise DataError(f"{p}: --fs must be a positive sample rate in Hz, got {fs}")
        t = np.arange(ref.size) / fs
    else:
        raise DataError(f"{p}: no time column; give --fs")
    if not np.all(np.isfinite(t)):
        raise DataError(f"{p}: the time column contains NaN or inf")
    if np.any(np.diff(t) <= 0):
        raise DataError(f"{p}: time must be strictly increasing")
    steps = np.diff(t)
    if steps.size and np.max(np.abs(steps - np.median(steps))) > 1e-6 * np.median(steps):
        raise DataError(f"{p}: the time column is not uniformly sampled (steps from {steps.min():.6g} to "
                        f"{steps.max():.6g} s); a command table needs one sample per period")
    return t, ref


def cmd_compensate(args: argparse.Namespace) -> int:
    import numpy as np

    from .._fileio import atomic_write, check_writable, producer
    from ..modelio import load_model

    lo, hi = args.u_min, args.u_max
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise UsageError(f"--u-min and --u-max must be finite volts, got {lo} and {hi}")
    if not lo < hi:
        raise UsageError(f"--u-min ({lo:g}) must be below --u-max ({hi:g})")
    out = check_writable(args.output, args.force)
    if out.suffix.lower() not in (".csv", ".txt"):
        raise UsageError(f"{out}: the command file is written as CSV; give a .csv (or .txt) name")
    model = load_model(args.model)
    t, ref = load_reference(args.reference, args.ref_col, args.t_col, args.fs)
    dt = float(np.median(np.diff(t))) if t.size > 1 else None
    ff = compensator_for(model, dt, u_range=(lo, hi) if args.clip else None)
    u = ff.command(ref)
    if args.clip:
        n_out = int(ff.limited)
    else:
        outside = (u < lo) | (u > hi)
        n_out = int(outside.sum())
        if n_out:
            i = int(np.argmax(outside))
            raise UsageError(
                f"the command leaves the amplifier range {lo:g}..{hi:g} V at {n_out} of {u.size} samples "
                f"(first at t = {t[i]:.6g} s: {u[i]:.4g} V); change the reference or pass --clip")

    def write(tmp):  # type: ignore[no-untyped-def]
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(f"# {producer()}\n# model: {args.model} ({model.kind}); reference: {args.reference}\n")
            fh.write(f"# units: t in s, x_d in um, u in V; amplifier range {lo:g}..{hi:g} V; clipped samples: {n_out}\n")
            fh.write("t_s,x_d_um,u_V\n")
            np.savetxt(fh, np.column_stack([t, ref, u]), delimiter=",", fmt="%.17g")

    atomic_write(out, write, force=args.force)
    res = {"written": str(out), "samples": int(u.size), "u_min_V": float(u.min()), "u_max_V": float(u.max()),
           "clipped_samples": n_out, "model_kind": model.kind}
    if args.json:
        print_json(res)
    else:
        console().print(f"wrote {u.size} commands ({u.min():.3f} .. {u.max():.3f} V"
                        + (f", {n_out} clipped" if n_out else "") + f") to {out}")
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
