"""``piezohyst export``: a saved model's compensator as C99 (``--to c``) or MATLAB (``--to matlab``).

``--to c --out DIR`` writes ``DIR/compensator.h`` and ``DIR/compensator.c`` (see
:mod:`piezohyst.export.c`): ``compensator_step(desired_um)`` returns what ``piezohyst compensate
--clip`` computes with the same model and range, sample for sample. ``--to matlab --out FILE.mat``
(or a directory) writes the model, its inverse and a reference command table
(:mod:`piezohyst.export.matlab`). Both say what produced them and the model file's SHA-256.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ._common import UsageError, amplifier_range, check_u_options, console, print_json

#: The longest feedback delay the C export compiles in (its ring buffer), samples.
MAX_FB_DELAY = 10000


def cmd_export(args: argparse.Namespace) -> int:
    import hashlib

    from .._fileio import producer
    from ..modelio import load_model_document, model_from_dict

    check_u_options(args.u_min, args.u_max)
    for name in ("max_slew", "fs"):
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v > 0):
            raise UsageError(f"--{name.replace('_', '-')} must be a positive, finite number, got {v}")
    for name in ("kp", "ki"):
        if not math.isfinite(getattr(args, name)):
            raise UsageError(f"--{name} must be finite, got {getattr(args, name)}")
        if getattr(args, name) < 0:  # (found by fuzzing: --kp -1 --ki -5 wrote positive feedback)
            raise UsageError(f"--{name} must be >= 0 (a negative gain is positive feedback), got {getattr(args, name)}")
    if not 0 <= args.fb_delay <= MAX_FB_DELAY:
        raise UsageError(f"--fb-delay must be 0..{MAX_FB_DELAY} samples (the compiled-in delay line), got {args.fb_delay}")
    model_path = Path(args.model)
    doc = load_model_document(model_path)
    model = model_from_dict(doc, source=str(model_path))
    lo, hi, range_from = amplifier_range(args.u_min, args.u_max, doc)
    if not getattr(model, "is_invertible", False):
        raise UsageError(f"the {model.kind} model is not invertible: it has no compensator to export")
    sha = hashlib.sha256(model_path.read_bytes()).hexdigest()
    own = getattr(model, "dt", None)
    if model.dynamic and args.fs is not None and own is not None and abs(1.0 / args.fs - own) > 1e-9 * own:
        raise UsageError(f"the model was identified at {1 / own:g} Hz; its compensator runs only at that rate "
                         f"(--fs {args.fs:g} refused)")
    dt = own if own is not None else (1.0 / args.fs if args.fs is not None else None)
    if args.ki != 0.0 and dt is None:
        raise UsageError("--ki needs the sample period of the loop: give --fs (the model has no rate of its own)")
    prov = producer()
    if args.to == "c":
        from ..export.c import export_c

        res = export_c(model, args.out, force=args.force, dt=own, u_range=(lo, hi), max_slew=args.max_slew,
                       provenance=[prov, f"model file: {model_path.name}; sha256 {sha}"], kp=args.kp, ki=args.ki,
                       fb_delay=args.fb_delay, fb_dt=dt)
    else:
        from ..export.matlab import export_matlab

        fb = [o for o, given in (("--kp", args.kp), ("--ki", args.ki), ("--fb-delay", args.fb_delay)) if given]
        if fb:  # (they were ignored without a word: found by fuzzing)
            raise UsageError(f"{', '.join(fb)} set the C code's feedback (--to c); the MATLAB file holds the model, its "
                             "inverse and a command table: drop them")
        out = Path(args.out)
        if out.suffix.lower() != ".mat":
            # an existing file, or a new name with another extension (mat/k4.txt became a folder
            # holding k4.txt/pi.mat), is neither
            if (out.suffix or out.exists()) and not out.is_dir():
                raise UsageError(f"{out}: give a .mat file name or a directory")
            out = out / (model_path.stem + ".mat")
        res = export_matlab(model, out, u_range=(lo, hi), dt=dt, force=args.force, max_slew=args.max_slew,
                            provenance={"producer": prov, "model_file": model_path.name, "model_sha256": sha})
    res["model_sha256"] = sha
    res["amplifier_range_V"], res["amplifier_range_from"] = [lo, hi], range_from
    if args.json:
        print_json(res)
    else:
        where = f"{res['header']} and {res['source']}" if args.to == "c" else res["written"]
        console().print(f"wrote the {model.kind} compensator ({lo:g}..{hi:g} V, from {range_from}) to {where}")
    return 0


def register(sub, add) -> None:  # type: ignore[no-untyped-def]
    p = add("export", cmd_export,
            "Export a model's compensator as C99 (compensator.h/.c: reset and step functions, no dynamic "
            "memory, libm only) or as a MATLAB .mat file (model, inverse, a reference command table).",
            "piezohyst export model.json --to c --u-min -20 --u-max 120 --out firmware/")
    p.add_argument("model", help="model file from 'piezohyst identify'")
    p.add_argument("--to", choices=("c", "matlab"), required=True, help="what to write")
    p.add_argument("--out", required=True, help="directory (c), or .mat file or directory (matlab)")
    p.add_argument("--u-min", type=float, default=None,
                   help="amplifier's lowest voltage; commands are clipped (default 0, or the low end of the input "
                        "range the model was identified on, as its file says, where that is lower)")
    p.add_argument("--u-max", type=float, default=None,
                   help="amplifier's highest voltage (default 100, or the high end of that range where higher)")
    p.add_argument("--max-slew", type=float, default=None,
                   help="largest command change per sample, V (default none)")
    p.add_argument("--fs", type=float, default=None,
                   help="sample rate, Hz, where the model has none of its own: the feedback's integral (c) and "
                        "the reference table (matlab); a model identified at a rate runs only at that rate")
    p.add_argument("--kp", type=float, default=0.0,
                   help="compiled-in proportional gain of compensator_step_fb, V/um (>= 0)")
    p.add_argument("--ki", type=float, default=0.0,
                   help="compiled-in integral gain of compensator_step_fb, V/(um s) (>= 0)")
    p.add_argument("--fb-delay", type=int, default=0, help="COMPENSATOR_FB_DELAY, samples (default 0)")
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    p.add_argument("--json", action="store_true", help="print the summary as JSON only")
