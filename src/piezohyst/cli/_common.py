"""Helpers every command shares: errors, console, JSON output, option parsers, data and rig options.

Nothing here imports numpy, numba or scipy at module level: ``piezohyst --help`` parses before
any of them is loaded.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any


class UsageError(Exception):
    """A problem with what the user asked for: reported as one line, exit code 2."""


def console(stderr: bool = False) -> Any:
    """A rich console; tables stay readable when the output is piped or captured."""
    import shutil

    from rich.console import Console

    width = None if sys.stdout.isatty() else max(shutil.get_terminal_size((140, 24)).columns, 140)
    return Console(stderr=stderr, highlight=False, markup=False, width=width)


def print_json(obj: Any) -> None:
    """Plain JSON on stdout (NaN and inf written as null, so every reader can parse it)."""
    from .._fileio import to_jsonable

    sys.stdout.write(json.dumps(to_jsonable(obj), indent=2, sort_keys=False, allow_nan=False) + "\n")


def freqs(text: str) -> list[float]:
    """``--freq 1,3,5``: positive frequencies in Hz."""
    try:
        out = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated frequencies in Hz, got {text!r}") from None
    if not out or any(not (f > 0) or f == float("inf") for f in out):
        raise argparse.ArgumentTypeError(f"frequencies must be positive and finite, got {text!r}")
    return out


def sample_range(text: str | None) -> tuple[int | None, int | None]:
    """``START:STOP`` sample indices (either may be empty)."""
    if not text:
        return (None, None)
    try:
        a, b = text.split(":")
        return (int(a) if a else None, int(b) if b else None)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START:STOP sample indices, got {text!r}") from None


def column(text: str) -> Any:
    """A column: a 0-based index or a header name."""
    return int(text) if text.lstrip("-").isdigit() else text


def add_data_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--u-col", type=column, default=None, help="input column (0-based index or header name)")
    p.add_argument("--y-col", type=column, default=None, help="output column (0-based index or header name)")
    p.add_argument("--t-col", type=column, default=None, help="time column (else --fs)")
    p.add_argument("--fs", type=float, default=None, help="sample rate in Hz when the file has no time column")


def data_options(args: argparse.Namespace) -> dict[str, Any]:
    """The :func:`~piezohyst.load_dataset` keywords given by :func:`add_data_options`' options
    (for a command that loads its records elsewhere, e.g. on a cluster's workers)."""
    return {"u_col": args.u_col, "y_col": args.y_col, "t_col": args.t_col, "fs": args.fs}


def load_cli_dataset(path: str, args: argparse.Namespace) -> Any:
    import piezohyst as ph

    return ph.load_dataset(path, **data_options(args))


def add_rig_options(p: argparse.ArgumentParser) -> None:
    """Options that choose the virtual rig (shared by every command that runs on it)."""
    p.add_argument("--seed", type=int, default=0, help="noise seed of the virtual rig (default 0)")
    p.add_argument("--rig-gamma", type=float, default=None, help="Bouc-Wen gamma of the rig (asymmetric loop; paper: 0)")
    p.add_argument("--rig-creep-scale", type=float, default=None, help="multiply the rig's creep (default 1)")
    p.add_argument("--rig-noise-scale", type=float, default=None, help="multiply the rig's sensor noise (default 1)")
    p.add_argument("--rig-settings", default=None, metavar="JSON", help="rig settings file (RigSettings fields)")


def rig_from_args(args: argparse.Namespace) -> Any:
    from ..rig import RigSettings, VirtualRig

    settings = RigSettings()
    if getattr(args, "rig_settings", None):
        try:
            doc = json.loads(Path(args.rig_settings).read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise UsageError(f"{args.rig_settings}: no such file") from None
        except json.JSONDecodeError as exc:
            raise UsageError(f"{args.rig_settings}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
        except RecursionError:
            raise UsageError(f"{args.rig_settings}: nested too deeply to be a rig settings file") from None
        if not isinstance(doc, dict):
            raise UsageError(f"{args.rig_settings}: expected a JSON object of rig settings")
        try:
            settings = RigSettings.from_dict(doc.get("rig", doc))
        except (TypeError, ValueError) as exc:
            raise UsageError(f"{args.rig_settings}: {exc}") from None
    over = {}
    if getattr(args, "rig_gamma", None) is not None:
        over["gamma"] = args.rig_gamma
    if getattr(args, "rig_creep_scale", None) is not None:
        over["creep_scale"] = args.rig_creep_scale
    if getattr(args, "rig_noise_scale", None) is not None:
        if not args.rig_noise_scale >= 0:
            raise UsageError("--rig-noise-scale must be >= 0")
        over["noise_rms_um"] = settings.noise_rms_um * args.rig_noise_scale
    try:
        return VirtualRig(settings, seed=args.seed, **over)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"rig settings: {exc}") from None
