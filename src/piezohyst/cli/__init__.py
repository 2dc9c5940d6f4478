"""The ``piezohyst`` command. Thin: it parses, calls the public API, prints.

One module per command (:mod:`.models`, :mod:`.identify`, :mod:`.compensate`, :mod:`.track`,
:mod:`.reproduce`, :mod:`.rig`, :mod:`.benchmark`), each with a ``register(sub, add)`` that
adds its parser; shared helpers in :mod:`._common`. The arrows run one way: this module imports
the commands, the commands import ``_common`` and the public API, never this module.

Every command that prints figures prints them as JSON instead with ``--json`` (nothing else on
stdout). Errors in what the user gave (a file, a value) end with exit code 2 and one line on
stderr; ``--debug`` (anywhere on the line) shows the traceback instead.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any, Callable, Sequence

from . import benchmark, compensate, identify, models, reproduce, rig, track
from ._common import UsageError

#: The commands, in the order ``--help`` lists them.
COMMANDS = (reproduce, identify, compensate, track, rig, models, benchmark)

EXAMPLES = """\
examples:
  piezohyst reproduce --out results/          the paper's experiment on the virtual rig
  piezohyst identify data.csv --model auto -o model.json
  piezohyst compensate --model model.json --reference ref.csv -o cmd.csv
  piezohyst track --method best --freq 1,3,5  commission the virtual rig and track
  piezohyst rig --freq 1,3,5 --out loops/     open-loop loops of the virtual rig (Fig. 2)
  piezohyst models                            the paper's two models and their loops
Run 'piezohyst COMMAND --help' for each command's options and an example.
"""


def build_parser() -> argparse.ArgumentParser:
    from .._version import __version__

    parser = argparse.ArgumentParser(
        prog="piezohyst",
        description="Hysteresis modelling, identification and compensation of piezoelectric "
        "actuators (Prandtl-Ishlinskii, asymmetric P-I, Preisach, Bouc-Wen; PSO and least squares; "
        "inverse feedforward + PID).",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"piezohyst {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks instead of one-line errors (anywhere on the line)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    def add(name: str, func: Callable[[argparse.Namespace], int], help: str, example: str) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help, description=help, epilog=f"example:\n  {example}",
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        p.set_defaults(func=func)
        return p

    for command in COMMANDS:
        command.register(sub, add)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args_in = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args_in
    args_in = [a for a in args_in if a != "--debug"]
    parser = build_parser()
    args = parser.parse_args(args_in)
    args.debug = debug
    if not getattr(args, "command", None):
        parser.print_help()
        return 0
    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        print("piezohyst: interrupted", file=sys.stderr)
        return 130
    except (UsageError, ValueError, TypeError, OSError, KeyError) as exc:
        if debug:
            raise
        msg = str(exc) or type(exc).__name__
        print(f"piezohyst {args.command}: error: {msg}", file=sys.stderr)
        return 2


__all__ = ["COMMANDS", "UsageError", "build_parser", "main"]
