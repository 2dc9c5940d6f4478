"""The ``piezohyst`` command. Thin: it parses, calls the public API, prints.

One module per command (:mod:`.models`, :mod:`.identify`, :mod:`.compensate`, :mod:`.export`, :mod:`.track`,
:mod:`.reproduce`, :mod:`.rig`, :mod:`.fleet`, :mod:`.benchmark`), each with a ``register(sub, add)`` that
adds its parser; shared helpers in :mod:`._common`. The arrows run one way: this module imports
the commands, the commands import ``_common`` and the public API, never this module.

An input file given as ``-`` is read from stdin, and ``-o -`` writes the output file to stdout
(the summary then goes to stderr). Every command that prints figures prints them as JSON
instead with ``--json`` (nothing else on
stdout). Exit codes:

* 0: done;
* 2: the user's error (a file, a flag, a value; an output that exists or cannot be written; a
  loop the given gains make unstable): one line on stderr naming the file or the flag, in the
  command line's spelling (``--fs``, not ``fs=``);
* 1: a bug in piezohyst (an exception nobody raised on purpose): one line saying so and how to
  report it;
* 130/143: interrupted (Ctrl-C) / terminated (SIGTERM); temporary files are removed, outputs are
  left whole or absent.

``--debug`` (anywhere on the line) shows the traceback instead of the one line.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import warnings
from typing import Any, Callable, Sequence

from . import benchmark, compensate, export, fleet, identify, models, reproduce, rig, track
from ._common import (ArgumentParser, Terminated, UsageError, cli_spelling, is_deliberate, one_line, shown,
                      run_with_std_streams)

#: The commands, in the order ``--help`` lists them.
COMMANDS = (reproduce, identify, compensate, export, track, rig, models, fleet, benchmark)

EXAMPLES = """\
examples:
  piezohyst reproduce --out results/          the paper's experiment on the virtual rig
  piezohyst identify data.csv --model auto -o model.json
  piezohyst compensate --model model.json --reference ref.csv -o cmd.csv
  piezohyst export model.json --to c --out firmware/   the compensator as C99
  piezohyst track --method best --freq 1,3,5  commission the virtual rig and track
  piezohyst rig --freq 1,3,5 --out loops/     open-loop loops of the virtual rig (Fig. 2)
  piezohyst models                            the paper's two models and their loops
  piezohyst fleet identify batch/ --model pi --out fleet/   every actuator of a batch, on Dask
Run 'piezohyst COMMAND --help' for each command's options and an example.
"""


def build_parser() -> argparse.ArgumentParser:
    from .._version import __version__

    parser = ArgumentParser(
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


def _user_errors() -> tuple[type[BaseException], ...]:
    """The exceptions that are the user's (or the environment's) doing, not a bug."""
    from .._fileio import OutputError
    from ..control.tracking import UnstableLoopError
    from ..data import DataError
    from ..modelio import ModelFileError
    from .._validation import FitError
    from ..plant import SensorDropoutError  # (the plant's sensor, not a bug)

    return (UsageError, OutputError, DataError, ModelFileError, UnstableLoopError, FitError, SensorDropoutError)


def _flags(parser: argparse.ArgumentParser, command: str | None) -> dict[str, str]:
    """keyword name -> option string, for the command's options (``fs`` -> ``--fs``)."""
    out: dict[str, str] = {}
    parsers = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and command in action.choices:
            parsers.append(action.choices[command])
    for p in parsers[1:]:  # a command's own subcommands ("fleet identify"): their options too
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                parsers.extend(action.choices.values())
    for p in parsers:
        for action in p._actions:
            longs = [o for o in action.option_strings if o.startswith("--")]
            if longs:
                out.setdefault(action.dest, longs[0])
    return out


def _message(exc: BaseException) -> str:
    # what was added on the way (where a stage was left: GuardedPlant.back_to_rest) is said too
    notes = "".join(f"; {one_line(n)}" for n in getattr(exc, "__notes__", ()) or ())
    if isinstance(exc, OSError) and not isinstance(exc, _user_errors()) and exc.filename:
        return f"{exc.filename}: {exc.strerror or exc}{notes}"
    if isinstance(exc, MemoryError):
        return (f"not enough memory for this run ({one_line(exc) or 'MemoryError'}); ask for less (shorter "
                f"records, fewer parameters) or free memory{notes}")
    return (one_line(exc) or type(exc).__name__) + notes


#: the signal that interrupted this run, if one did (set by the handlers below)
_signalled: list[int] = []


def _on_terminate(signum: int, frame: Any) -> None:
    _signalled.append(signum)
    raise Terminated(signum)


def _on_interrupt(signum: int, frame: Any) -> None:
    _signalled.append(signum)
    raise KeyboardInterrupt


def _interrupt_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or termination an error was raised while handling (a library cleaning up after the
    interrupt can fail in its turn: matplotlib, stopped mid-draw, then raises "Invalid bounding box")."""
    seen: set[int] = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:
        if isinstance(cur, KeyboardInterrupt):
            return cur
        seen.add(id(cur))
        cur = cur.__cause__ or cur.__context__
    return None


def _silence_stdout() -> None:
    """Point stdout at the null device, so the interpreter's last flush does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # a replaced stdout (a notebook, a test)
        pass


def main(argv: Sequence[str] | None = None) -> int:
    args_in = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args_in
    args_in = [a for a in args_in if a != "--debug"]
    from .._provenance import set_command_line

    set_command_line(["piezohyst", *args_in])
    # SIGTERM/SIGHUP end the run like Ctrl-C: every finally runs (temporary files are removed)
    handlers = {}
    _signalled.clear()
    if threading.current_thread() is threading.main_thread():
        for name in ("SIGTERM", "SIGHUP"):
            sig = getattr(signal, name, None)
            if sig is not None:
                handlers[sig] = signal.signal(sig, _on_terminate)
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # (not when a caller ignores it)
            handlers[signal.SIGINT] = signal.signal(signal.SIGINT, _on_interrupt)
    prog = "piezohyst"
    parser: argparse.ArgumentParser | None = None
    command = None
    try:
        parser = build_parser()
        args = parser.parse_args(args_in)
        args.debug = debug
        if not getattr(args, "command", None):
            parser.print_help()
            return 0
        command = args.command
        prog = f"piezohyst {command}"
        if getattr(args, "fleet_command", None):  # "piezohyst fleet identify", as its usage errors say
            prog = f"{prog} {args.fleet_command}"
        if debug:
            return run_with_std_streams(args, args.func)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            code = run_with_std_streams(args, args.func)
        seen = set()
        for w in caught:  # after the results, once each, on one line each
            text = one_line(w.message)
            if text not in seen:
                seen.add(text)
                print(f"{prog}: warning: {cli_spelling(text, _flags(parser, command))}", file=sys.stderr)
        return code
    except BrokenPipeError:
        # the reader of stdout went away ("| head -1"): nothing to say to it, and the shell's code
        # for a writer a closed pipe ends (128 + SIGPIPE), as other tools give under pipefail
        _silence_stdout()
        return 141
    except KeyboardInterrupt as exc:
        if debug and not isinstance(exc, Terminated):
            raise
        term = isinstance(exc, Terminated)
        print(f"{prog}: {'terminated' if term else 'interrupted'}; no output was left half-written", file=sys.stderr)
        return 143 if term else 130
    except Exception as exc:
        if debug:
            raise
        behind = _interrupt_behind(exc)
        if behind is not None or _signalled:
            term = isinstance(behind, Terminated) or (behind is None and _signalled[-1] != signal.SIGINT)
            print(f"{prog}: {'terminated' if term else 'interrupted'}; no output was left half-written",
                  file=sys.stderr)
            return 143 if term else 130
        users = isinstance(exc, _user_errors()) or isinstance(exc, (OSError, MemoryError)) or (
            isinstance(exc, (ValueError, TypeError)) and is_deliberate(exc))
        if users:
            msg = shown(cli_spelling(_message(exc), _flags(parser, command) if parser is not None else {}))
            print(f"{prog}: error: {msg}", file=sys.stderr)
            return 2
        print(f"{prog}: internal error: {type(exc).__name__}: {_message(exc)[:300]} -- this is a bug in piezohyst, "
              "not in what you gave; please report it with the output of the same command run with --debug "
              "(the traceback)", file=sys.stderr)
        return 1
    finally:
        set_command_line(None)
        for sig, old in handlers.items():
            signal.signal(sig, old)


__all__ = ["COMMANDS", "UsageError", "build_parser", "main"]
