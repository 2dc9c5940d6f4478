"""``piezohyst compensate``: the command a saved model's compensator gives for a desired trajectory,
written as the wave table a controller plays (``.csv``, ``.npy``, ``.mat``, ``.h``; see
:mod:`piezohyst.export.tables`).

``--periodic`` makes a table that loops without a step (the compensator's periodic steady state);
``--fs`` puts the table on the controller's rate. Bad input (a non-finite number anywhere in the
reference file, ``--fs 0``, ``--u-min nan``, ``--u-min >= --u-max``, an extension it cannot write)
is one line on stderr and exit code 2. The checks of the numeric options are in
:func:`check_options` here (the shared helpers of ``_common`` are not this command's to change).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from ._common import UsageError, amplifier_range, check_u_options, console, print_json, shown


def compensator_for(model: Any, dt: float | None, *, on_rig: bool = False, **limits: Any) -> Any:
    """A model's compensator at sample period ``dt`` (any kind, through the model protocol);
    ``on_rig``: for a run on the virtual rig (``track``), whose rate the rig settings set."""
    if not getattr(model, "is_invertible", False):
        raise UsageError(f"the {model.kind} model is not invertible: it has no compensator")
    own = getattr(model, "dt", None)
    if model.dynamic and own is not None and dt is not None and abs(own - dt) > 1e-9 * own:
        if on_rig:  # (it advised --fs, which track reads only for a --reference file: found by fuzzing)
            raise UsageError(f"the model was identified at {1 / own:g} Hz (its lags are discretised at that rate) "
                             f"but the rig runs at {1 / dt:g} Hz; run the rig at the model's rate with --rig-settings "
                             f"FILE holding {{\"dt\": {own:g}}}, or identify the model at the rig's rate")
        raise UsageError(f"the model was identified at {1 / own:g} Hz (its lags are discretised at that rate) but "
                         f"the table would be sampled at {1 / dt:g} Hz; give --fs {1 / own:g} to resample the "
                         "reference to the model's rate, or identify the model at the table's rate")
    return model.compensator(dt if model.dynamic else None, **limits)


def check_options(args: argparse.Namespace) -> None:
    """The numeric options, checked before any file is read (one line each, exit 2)."""
    check_u_options(args.u_min, args.u_max)
    fs = getattr(args, "fs", None)
    if fs is not None and not (math.isfinite(fs) and fs > 0):
        raise UsageError(f"--fs must be a positive, finite sample rate in Hz, got {fs}")


def load_reference(path: str, ref_col: Any, t_col: Any, fs: float | None) -> tuple[Any, Any]:
    """A desired trajectory (µm) from a text/CSV file, with its time vector.

    Every number in the file must be finite (a NaN or inf anywhere is an error naming the row and
    column). Without a time column the reference is taken as sampled at ``fs``.
    """
    import numpy as np

    from ..data import DataError, read_table

    p = Path(path)
    if not p.exists():
        raise DataError(f"{p}: no such file")
    names, arr, header = read_table(p)
    bad = ~np.isfinite(arr)
    if bad.any():
        row, col = (int(v) for v in np.argwhere(bad)[0])
        raise DataError(f"{p}: {int(bad.sum())} value(s) are NaN or inf, the first in data row {row + 1}, "
                        f"column {names[col]!r}")
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
    if ref.size < 2:
        raise DataError(f"{p}: the reference needs at least 2 samples, got {ref.size}")
    if it is not None:
        t = arr[:, it]
    elif fs is not None:
        t = np.arange(ref.size) / fs
    else:
        raise DataError(f"{p}: no time column; give --fs")
    if np.any(np.diff(t) <= 0):
        raise DataError(f"{p}: time must be strictly increasing")
    steps = np.diff(t)
    if steps.size and np.max(np.abs(steps - np.median(steps))) > 1e-6 * np.median(steps):
        raise DataError(f"{p}: the time column is not uniformly sampled (steps from {steps.min():.6g} to "
                        f"{steps.max():.6g} s); a command table needs one sample per period")
    return t, ref


def _warn_if_extrapolating(doc: dict[str, Any], u: Any) -> str | None:
    """Warn when the commands leave the input range the model file (``doc``, its document) says
    it was identified on (its ``fit.input_range_V``), or within it close larger loops than its
    record did (``fit.largest_loop_V``; files without them say nothing); the warning, or None."""
    import warnings

    from ..identify.result import ExtrapolationWarning, extrapolation

    fit = doc.get("fit") or {}
    loop = fit.get("largest_loop_V")
    said = extrapolation(u, fit.get("input_range_V"),
                         loop if isinstance(loop, (int, float)) and not isinstance(loop, bool) else None, "the command")
    if said:
        warnings.warn(said, ExtrapolationWarning, stacklevel=2)
    return said


def cmd_compensate(args: argparse.Namespace) -> int:
    import hashlib

    import numpy as np

    from .._fileio import check_writable, producer
    from ..export.tables import periodic_table, resample_reference, table_format, write_table
    from ..modelio import load_model_document, model_from_dict

    check_options(args)
    out = check_writable(args.output, args.force)
    try:
        fmt = table_format(out)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    doc = load_model_document(args.model)  # once: the model, and the input range it was identified on
    model = model_from_dict(doc, source=str(args.model))
    lo, hi, range_from = amplifier_range(args.u_min, args.u_max, doc)
    sha = hashlib.sha256(Path(args.model).read_bytes()).hexdigest()
    t, ref = load_reference(args.reference, args.ref_col, args.t_col, args.fs)
    closed = bool(args.periodic and ref.size > 2
                  and abs(ref[-1] - ref[0]) <= 1e-12 * max(float(np.ptp(ref)), abs(float(ref[0])), 1e-300))
    if closed:
        # a period written closed (its last sample repeats its first) looped with that sample twice,
        # one sample longer than the period (found by fuzzing): the repeat is dropped
        t, ref = t[:-1], ref[:-1]
    dt_ref = float((t[-1] - t[0]) / (t.size - 1))
    resampled = False
    if args.fs is not None and abs(1.0 / args.fs - dt_ref) > 1e-9 * dt_ref:
        t, ref = resample_reference(t, ref, args.fs, periodic=args.periodic)
        resampled = True
    dt = 1.0 / args.fs if args.fs is not None else dt_ref
    ff = compensator_for(model, dt, u_range=(lo, hi) if args.clip else None)
    periodic_info = None
    if args.periodic:
        inner = float(np.max(np.abs(np.diff(ref))))
        wrap = float(abs(ref[0] - ref[-1]))
        if wrap > 2.0 * inner + 1e-12 * max(1.0, float(np.max(np.abs(ref)))):
            raise UsageError(f"the reference does not loop smoothly: it jumps {wrap:.4g} um from its last sample to its "
                             f"first, while its largest step inside is {inner:.4g} um; give one period (or whole periods)")
        plain = ff.command(ref)
        u, periodic_info = periodic_table(ff, ref, tol=1e-6 * (hi - lo))
        periodic_info["wrap_step_from_rest_V"] = float(abs(plain[0] - plain[-1]))
        periodic_info["closing_sample_dropped"] = closed
    else:
        u = ff.command(ref)
    bad = ~np.isfinite(u)
    if bad.any():  # (NaN passes the range check below: found by fuzzing, a table of NaN written)
        i = int(np.argmax(bad))
        raise UsageError(f"the {model.kind} model's compensator gave {int(bad.sum())} non-finite commands (first at "
                         f"t = {t[i]:.6g} s, for {ref[i]:.6g} um): check the model file {args.model}'s parameters")
    if args.clip:
        n_out = int(periodic_info["limited_samples"]) if periodic_info is not None else int(ff.limited)
    else:
        outside = (u < lo) | (u > hi)
        n_out = int(outside.sum())
        if n_out:
            i = int(np.argmax(outside))
            raise UsageError(
                f"the command leaves the amplifier range {lo:g}..{hi:g} V (from {range_from}) at {n_out} of "
                f"{u.size} samples (first at t = {t[i]:.6g} s: {u[i]:.4g} V); change the reference, give the "
                "amplifier's range (--u-min, --u-max) or pass --clip")
    n_limited = n_out
    extrapolating = _warn_if_extrapolating(doc, u)
    # three comment lines, as before tables had other formats (readers skip 4 lines: these and the header)
    comments = [producer(), f"model: {args.model} ({model.kind}); sha256 {sha}; reference: {args.reference}",
                f"units: t in s, x_d in um, u in V; amplifier range {lo:g}..{hi:g} V; clipped samples: {n_limited}; "
                f"sample rate {1.0 / dt:.12g} Hz" + (f" (resampled from the reference's {1.0 / dt_ref:.12g} Hz)"
                                                     if resampled else "")]
    if periodic_info is not None:
        comments[2] += (f"; periodic: one cycle of the steady state after {periodic_info['cycles']} cycles, "
                        f"wrap-around step {periodic_info['wrap_step_V']:.4g} V, largest inner step "
                        f"{periodic_info['largest_inner_step_V']:.4g} V")
    write_table(out, t, ref, u, dt=dt, comments=comments, force=args.force,
                meta={"producer": comments[0], "model_kind": model.kind, "model_sha256": sha,
                      "u_min_V": lo, "u_max_V": hi})
    res: dict[str, Any] = {"written": str(out), "format": fmt, "samples": int(u.size), "u_min_V": float(u.min()),
                           "u_max_V": float(u.max()), "clipped_samples": n_limited, "model_kind": model.kind,
                           "amplifier_range_V": [lo, hi], "amplifier_range_from": range_from,
                           "fs_hz": 1.0 / dt, "resampled": resampled,
                           "largest_step_V": float(np.max(np.abs(np.diff(u)))) if u.size > 1 else 0.0}
    if periodic_info is not None:
        res["periodic"] = periodic_info
    res["warnings"] = [extrapolating] if extrapolating else []
    if args.json:
        print_json(res)
    else:
        msg = (f"wrote {u.size} commands ({u.min():.3f} .. {u.max():.3f} V"
               + (f", {n_limited} clipped" if n_limited else "") + f", {1.0 / dt:g} Hz) to {shown(out)}")
        if periodic_info is not None and closed:
            msg += (f"\nthe reference's last sample repeats its first (a closed period): dropped, so the table "
                    f"loops every {u.size} samples")
        if periodic_info is not None:
            msg += (f"\nperiodic steady state after {periodic_info['cycles']} cycles"
                    + ("" if periodic_info["converged"] else " (NOT converged)")
                    + f": wrap-around step {periodic_info['wrap_step_V']:.4g} V, largest inner step "
                    f"{periodic_info['largest_inner_step_V']:.4g} V (from rest the table would wrap with "
                    f"{periodic_info['wrap_step_from_rest_V']:.4g} V)")
        console().print(msg)
    return 0


def register(sub, add) -> None:  # type: ignore[no-untyped-def]
    p = add("compensate", cmd_compensate,
            "Compute the voltage command that makes the modelled actuator follow a desired trajectory "
            "(offline feedforward: the wave table a controller plays).",
            "piezohyst compensate --model pi.json --reference ref.csv --periodic --fs 10000 -o table.h")
    p.add_argument("--model", required=True, help="model file from 'piezohyst identify'")
    p.add_argument("--reference", required=True, help="desired displacement (µm): CSV/text with a t column or --fs ('-': stdin)")
    p.add_argument("--ref-col", type=lambda v: int(v) if v.isdigit() else v, default=None, help="reference column")
    p.add_argument("--t-col", type=lambda v: int(v) if v.isdigit() else v, default=None, help="time column")
    p.add_argument("--fs", type=float, default=None,
                   help="the table's sample rate, Hz: a reference with a time column is resampled to it (linear "
                        "interpolation); one without is taken as sampled at it. A model with dynamics runs only "
                        "at the rate it was identified at (another rate is refused)")
    p.add_argument("-o", "--output", required=True,
                   help="table to write, by extension: .csv/.txt (t_s,x_d_um,u_V), .npy (commands, V), "
                        ".mat (MATLAB), .h (C array with its length and rate); '-': CSV to stdout")
    p.add_argument("--periodic", action="store_true",
                   help="the reference is one period of a looping table: write one cycle of the compensator's "
                        "periodic steady state (loops without a step)")
    p.add_argument("--u-min", type=float, default=None,
                   help="amplifier's lowest voltage (default 0, or the low end of the input range the model "
                        "was identified on, as its file says, where that is lower)")
    p.add_argument("--u-max", type=float, default=None,
                   help="amplifier's highest voltage (default 100, or the high end of that range where higher)")
    p.add_argument("--clip", action="store_true", help="clip commands to the range instead of refusing")
    p.add_argument("--force", action="store_true", help="overwrite the output file")
    p.add_argument("--json", action="store_true", help="print the summary as JSON only")
