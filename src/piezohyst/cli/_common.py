"""Helpers every command shares: errors, console, JSON output, option parsers, data and rig options.

Nothing here imports numpy, numba or scipy at module level: ``piezohyst --help`` parses before
any of them is loaded.

Option types refuse bad values at parse time, naming the flag (argparse prefixes its messages
with ``argument --flag:``): numbers must be finite, counts positive, seeds non-negative.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import linecache
import math
import os
import re
import sys
from pathlib import Path
from typing import Any, Callable, Iterator

#: The longest record (samples) a command builds; beyond it a run would take gigabytes per signal.
#: (50 million samples: 400 MB per float64 signal, 83 minutes at 10 kHz.)
MAX_SAMPLES = 50_000_000


class UsageError(Exception):
    """A problem with what the user asked for: reported as one line, exit code 2."""


class Terminated(KeyboardInterrupt):
    """SIGTERM/SIGHUP, raised in the main thread so that every ``finally`` (temporary files) runs."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse, with its errors on one line (no usage block): ``piezohyst CMD: error: ...``; a
    negative number in exponent notation is a value, not an option (``--u-min -1e3``: argparse
    before Python 3.13 took ``-1e3`` for an unknown option, found by fuzzing)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")

    def error(self, message: str) -> Any:  # type: ignore[override]
        msg = " ".join(message.split())
        self.exit(2, f"{self.prog}: error: {msg} (see '{self.prog} --help')\n")


#: True while a command writes its output file to stdout (``-o -``): summaries then go to stderr.
STDOUT_TAKEN = False


def progress_wanted() -> bool:
    """Whether a long run shows its progress: on standard error when that is a terminal
    (:func:`piezohyst.progress.detect_mode`), with or without --json (which keeps standard output
    to the data alone); identify, reproduce and benchmark showed none with --json (found by a
    helper). Not into a file or a pipe, where a spinner left a blank line before an error message
    (found by the same helper)."""
    from ..progress import detect_mode

    return detect_mode() == "terminal"


@contextlib.contextmanager
def spinner(first: str = "starting") -> Iterator[Callable[[str], None]]:
    """A transient spinner on standard error naming the step under way, where
    :func:`progress_wanted`; ``step(text)`` names the next one (a no-op otherwise)."""
    if not progress_wanted():
        yield lambda text: None
        return
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    with Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(),
                  console=console(stderr=True), transient=True) as bar:
        task = bar.add_task(first, total=None)
        yield lambda text: bar.update(task, description=text)


def console(stderr: bool = False) -> Any:
    """A rich console; tables stay readable when the output is piped or captured."""
    import shutil

    from rich.console import Console

    class _Console(Console):
        def on_broken_pipe(self) -> None:
            # rich exits with 1 here, which this tool keeps for its own bugs ("| head -1" ended
            # with 1 and no word: found by a helper); main() ends the run as a closed pipe does
            raise BrokenPipeError(32, "the reader of the output closed it")

    width = None if sys.stdout.isatty() else max(shutil.get_terminal_size((140, 24)).columns, 140)
    return _Console(stderr=stderr or STDOUT_TAKEN, highlight=False, markup=False, width=width)


#: Arguments that name an input file (``-`` reads it from stdin) and the suffix it is given then.
STDIN_ARGS = {"data": ".csv", "reference": ".csv", "model": ".json"}
#: Arguments that name an output file (``-`` writes it to stdout) and the suffix by command.
STDOUT_SUFFIX = {"identify": ".json", "compensate": ".csv", "track": ".csv"}


#: The temporary files that stand for stdin and stdout in this run (path -> "stdin"/"stdout"):
#: what messages show instead of the paths (:func:`shown`).
STREAM_NAMES: dict[str, str] = {}


def shown(text: object) -> str:
    """``text`` with the temporary files of ``-`` (stdin, stdout) named as the streams they stand
    for: an error about an empty stdin named /tmp/piezohyst-.../stdin.csv, and ``-o -`` said it
    wrote to a file that did not exist (found by fuzzing)."""
    out = str(text)
    for path, name in STREAM_NAMES.items():
        out = out.replace(path, name)
    return out


def run_with_std_streams(args: argparse.Namespace, run: Any) -> int:
    """Run a command with ``-`` for an input file (stdin) or for ``-o`` (stdout).

    The stream goes through a temporary file (the readers and writers take paths: formats are
    told by the suffix, which for stdin is text/CSV or, for a model, JSON). With ``-o -`` the
    command's own summary goes to stderr, so stdout holds the file alone.
    """
    import tempfile

    global STDOUT_TAKEN
    STREAM_NAMES.clear()
    ins = [a for a in STDIN_ARGS if getattr(args, a, None) == "-"]
    out_dash = getattr(args, "output", None) == "-"
    if not ins and not out_dash:
        return int(run(args))
    if len(ins) > 1:
        raise UsageError(f"only one input can come from stdin ('-'); got it for {', '.join('--' + a for a in ins)}")
    if out_dash and getattr(args, "json", False):
        raise UsageError("-o - writes the file itself to stdout; drop --json, or write the file elsewhere")
    with tempfile.TemporaryDirectory(prefix="piezohyst-") as tmp:
        if ins:
            p = Path(tmp) / ("stdin" + STDIN_ARGS[ins[0]])
            p.write_bytes(sys.stdin.buffer.read())
            setattr(args, ins[0], str(p))
            STREAM_NAMES[str(p)] = "stdin"
        target = None
        if out_dash:
            target = Path(tmp) / ("stdout" + STDOUT_SUFFIX.get(getattr(args, "command", ""), ".csv"))
            args.output = str(target)
            STREAM_NAMES[str(target)] = "stdout"
            STDOUT_TAKEN = True
        try:
            code = int(run(args))
        finally:
            STDOUT_TAKEN = False
        if target is not None and code == 0:
            sys.stdout.buffer.write(target.read_bytes())
            sys.stdout.flush()
        return code


def print_json(obj: Any) -> None:
    """Plain, strict JSON on stdout (NaN and inf written as null, so every reader can parse it)."""
    from .._fileio import dumps_strict

    sys.stdout.write(dumps_strict(obj, indent=2, sort_keys=False) + "\n")


# ------------------------------------------------------------------------------------------------
# errors: whose fault, and how to say it
def is_deliberate(exc: BaseException) -> bool:
    """True when ``exc`` was raised by a ``raise`` statement in piezohyst's own code (a check of
    what the caller gave), not by numpy, the standard library or a slip in our code (a bad call,
    a missing key): the difference between the user's error and a bug."""
    tb = exc.__traceback__
    if tb is None:
        return False
    while tb.tb_next is not None:
        tb = tb.tb_next
    filename = tb.tb_frame.f_code.co_filename
    pkg = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    if not os.path.abspath(filename).startswith(pkg + os.sep):
        return False
    line = linecache.getline(filename, tb.tb_lineno)
    if not line:  # installed without sources (.pyc only): from our code, so give the user the benefit
        return True
    return line.lstrip().startswith("raise")


def cli_spelling(message: str, flags: dict[str, str]) -> str:
    """The API's Python spelling in a message (``fs=``, ``force=True``) in the command line's
    (``--fs``, ``--force``); ``flags`` maps keyword names to option strings."""
    def flag(name: str) -> str | None:
        return flags.get(name) or flags.get(name.replace("-", "_"))

    def true_kw(m: re.Match[str]) -> str:
        f = flag(m.group(1))
        return f if f else m.group(0)

    def kw(m: re.Match[str]) -> str:
        f = flag(m.group(1))
        if not f:
            return m.group(0)
        return f + (" " + m.group(2) if m.group(2) else "")

    # "name it (u_col= in Python, --u-col at the command line)": at the command line, the latter
    message = re.sub(r"(?<=\()[^();]*? in Python, ([^();]*?) at the command line(?=\))", r"\1", message)
    out = re.sub(r"(?<![\w-])([A-Za-z_]\w*)=True\b", true_kw, message)
    out = re.sub(r"(?<![\w-])([A-Za-z_]\w*)=(\S?)", kw, out)
    out = out.replace(f"{flags.get('force', '--force')} / {flags.get('force', '--force')}", flags.get("force", "--force"))
    return out


def one_line(text: object) -> str:
    return " ".join(str(text).split())


# ------------------------------------------------------------------------------------------------
# option types
def _number(text: str, flag_kind: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {flag_kind}, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected {flag_kind}, got {text!r} (not finite)")
    return v


def finite_float(text: str) -> float:
    """A finite number (no NaN, no inf)."""
    return _number(text, "a finite number")


def positive_float(text: str) -> float:
    """A finite number > 0."""
    v = _number(text, "a positive number")
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return v


def nonnegative_float(text: str) -> float:
    """A finite number >= 0."""
    v = _number(text, "a number >= 0")
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return v


def _integer(text: str, least: int, what: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if v < least:
        raise argparse.ArgumentTypeError(f"must be {what}, got {v}")
    return v


def positive_int(text: str) -> int:
    """An integer >= 1."""
    return _integer(text, 1, "an integer >= 1")


def nonnegative_int(text: str) -> int:
    """An integer >= 0."""
    return _integer(text, 0, "an integer >= 0")


def seed(text: str) -> int:
    """A random seed: an integer >= 0 (what numpy's generators accept)."""
    return nonnegative_int(text)


def figure_formats(text: str) -> tuple[str, ...]:
    """``--format pdf,svg``: figure formats (png, pdf, svg), checked without importing matplotlib."""
    known = ("png", "pdf", "svg")
    items = [f.strip().lower().lstrip(".") for f in text.split(",") if f.strip()]
    bad = [f for f in items if f not in known]
    if bad or not items:
        raise argparse.ArgumentTypeError(f"unknown figure format(s) {', '.join(bad) or repr(text)}; "
                                         f"the formats are {', '.join(known)}")
    return tuple(dict.fromkeys(items))


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
    """``START:STOP`` sample indices (either may be empty; both >= 0)."""
    if not text:
        return (None, None)
    try:
        a, b = text.split(":")
        out = (int(a) if a else None, int(b) if b else None)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START:STOP sample indices, got {text!r}") from None
    if any(v is not None and v < 0 for v in out):
        raise argparse.ArgumentTypeError(f"sample indices count from 0, got {text!r}")
    return out


def column(text: str) -> Any:
    """A column: a 0-based index or a header name."""
    return int(text) if text.lstrip("-").isdigit() else text


def unit_setting(text: str) -> tuple[str, Any]:
    """One ``--units`` setting: ``y=nm`` (a unit) or ``y=10`` (a factor to the canonical unit:
    a sensor of 10 um per volt)."""
    role, sep, value = text.partition("=")
    role, value = role.strip(), value.strip()
    if not sep or role not in ("t", "u", "y") or not value:
        raise argparse.ArgumentTypeError(f"{text!r} is not ROLE=UNIT with ROLE t, u or y (e.g. y=nm, or y=10 "
                                         "for a sensor of 10 um per volt)")
    try:
        return role, float(value)
    except ValueError:
        return role, value


#: delimiter names a shell makes easier to type than the characters
DELIMITER_NAMES = {"tab": "\t", "comma": ",", "semicolon": ";", "bar": "|", "\\t": "\t"}


def delimiter_setting(text: str) -> str:
    """``--delimiter``: one character, or tab, comma, semicolon, bar."""
    d = DELIMITER_NAMES.get(text.strip().lower(), text)
    if len(d) != 1 or d.isalnum() or d in ".\"'":
        raise argparse.ArgumentTypeError(f"{text!r} is not a delimiter: give one character or tab, comma, "
                                         "semicolon, bar")
    return d


def check_sinusoids(fs_list: list[float], cycles: float, dt: float, *, freq_flag: str = "--freq",
                    cycles_flag: str = "--cycles", rate_from: str = "") -> None:
    """Refuse, before allocating, sinusoids that the sample period cannot carry or memory cannot hold."""
    rate = 1.0 / dt
    count = f"{cycles_flag} {cycles:g}" if cycles_flag else f"{cycles:g} cycles"
    for f in fs_list:
        if not f * dt < 0.5:
            raise UsageError(f"{freq_flag} {f:g} Hz is not below the Nyquist frequency {0.5 * rate:g} Hz "
                             f"of the {rate:g} Hz sample rate{rate_from}")
        n = cycles / (f * dt)
        if not n <= MAX_SAMPLES:
            raise UsageError(f"{freq_flag} {f:g} Hz with {count} needs {n:.3g} samples at "
                             f"{rate:g} Hz{rate_from}; the limit is {MAX_SAMPLES:.3g} samples")
        if round(n) < 2:
            raise UsageError(f"{freq_flag} {f:g} Hz with {count} is fewer than 2 samples "
                             f"at {rate:g} Hz{rate_from}")


# ------------------------------------------------------------------------------------------------
# data and rig options
def add_data_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--u-col", type=column, default=None, help="input column (0-based index or header name)")
    p.add_argument("--y-col", type=column, default=None, help="output column (0-based index or header name)")
    p.add_argument("--t-col", type=column, default=None, help="time column (else --fs)")
    p.add_argument("--fs", type=positive_float, default=None, help="sample rate in Hz when the file has no time column")
    p.add_argument("--units", type=unit_setting, action="append", default=None, metavar="ROLE=UNIT",
                   help="the unit of a column, over what its name says (repeatable): t=ms, u=mV, y=nm; or a "
                        "factor to s, V or um: y=10 for a displacement sensor's volts at 10 um/V")
    p.add_argument("--delimiter", type=delimiter_setting, default=None,
                   help="a text file's delimiter, over what is sniffed: one character, or tab, comma, semicolon, bar")
    p.add_argument("--decimal", choices=(".", ","), default=None,
                   help="a text file's decimal mark, over what is sniffed")
    p.add_argument("--encoding", default=None,
                   help="a text file's encoding, over what is sniffed (e.g. utf-8, cp1252, utf-16)")
    p.add_argument("--resample", action="store_true",
                   help="a time column that is not uniformly sampled (dropped or jittered samples) is interpolated "
                        "onto a uniform grid (at --fs, else the median step) instead of refused")


def data_options(args: argparse.Namespace) -> dict[str, Any]:
    """The :func:`~piezohyst.load_dataset` keywords given by :func:`add_data_options`' options
    (for a command that loads its records elsewhere, e.g. on a cluster's workers)."""
    for flag, v in (("--u-col", args.u_col), ("--y-col", args.y_col), ("--t-col", args.t_col)):
        if isinstance(v, int) and v < 0:
            raise UsageError(f"{flag} {v}: columns count from 0")
    units: dict[str, Any] | None = None
    for role, value in getattr(args, "units", None) or []:
        if units is not None and role in units and units[role] != value:
            raise UsageError(f"--units gives {role} twice ({units[role]!r} and {value!r})")
        units = {**(units or {}), role: value}
    return {"u_col": args.u_col, "y_col": args.y_col, "t_col": args.t_col, "fs": args.fs,
            "resample": bool(getattr(args, "resample", False)), "units": units,
            "delimiter": getattr(args, "delimiter", None), "decimal": getattr(args, "decimal", None),
            "encoding": getattr(args, "encoding", None)}


def load_cli_dataset(path: str, args: argparse.Namespace) -> Any:
    import piezohyst as ph

    return ph.load_dataset(path, **data_options(args))


def add_rig_options(p: argparse.ArgumentParser) -> None:
    """Options that choose the virtual rig (shared by every command that runs on it)."""
    p.add_argument("--seed", type=seed, default=0, help="noise seed of the virtual rig (default 0)")
    p.add_argument("--rig-gamma", type=finite_float, default=None,
                   help="Bouc-Wen gamma of the rig (asymmetric loop; paper: 0)")
    p.add_argument("--rig-creep-scale", type=nonnegative_float, default=None, help="multiply the rig's creep (default 1)")
    p.add_argument("--rig-noise-scale", type=nonnegative_float, default=None,
                   help="multiply the rig's sensor noise (default 1)")
    p.add_argument("--rig-settings", default=None, metavar="JSON", help="rig settings file (RigSettings fields)")


#: Largest rig-settings file read (settings are a few hundred bytes).
MAX_SETTINGS_BYTES = 1024 * 1024


def read_json_file(path: str, what: str, limit: int = MAX_SETTINGS_BYTES) -> Any:
    """A small JSON file, every problem a :class:`UsageError` naming the file."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            raw = fh.read(limit + 1)
    except FileNotFoundError:
        raise UsageError(f"{p}: no such file") from None
    except IsADirectoryError:
        raise UsageError(f"{p}: is a folder, not a {what}") from None
    except OSError as exc:
        raise UsageError(f"{p}: cannot read it ({exc.strerror or exc})") from None
    if len(raw) > limit:
        raise UsageError(f"{p}: more than {limit} bytes; too large for a {what}")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise UsageError(f"{p}: not a text file (cannot decode it as UTF-8)") from None

    from .._fileio import loads_strict

    try:
        return loads_strict(text, bad_constant=lambda name: UsageError(f"{p}: {name} is not a JSON number "
                                                                       "(write a finite number)"),
                            bad_number=lambda num: UsageError(f"{p}: {num} is out of range for a number"))
    except json.JSONDecodeError as exc:
        raise UsageError(f"{p}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except RecursionError:
        raise UsageError(f"{p}: nested too deeply to be a {what}") from None


def rig_from_args(args: argparse.Namespace) -> Any:
    from ..rig import RigSettings, VirtualRig

    settings = RigSettings()
    src = "rig settings"
    if getattr(args, "rig_settings", None):
        src = args.rig_settings
        doc = read_json_file(args.rig_settings, "rig settings file")
        if not isinstance(doc, dict):
            raise UsageError(f"{args.rig_settings}: expected a JSON object of rig settings")
        inner = doc.get("rig", doc)
        if not isinstance(inner, dict):
            raise UsageError(f"{args.rig_settings}: \"rig\" must be an object of rig settings")
        try:
            settings = RigSettings.from_dict(inner)
        except (TypeError, ValueError) as exc:
            raise UsageError(f"{args.rig_settings}: {one_line(exc)}") from None
        except RecursionError:
            raise UsageError(f"{args.rig_settings}: nested too deeply to be a rig settings file") from None
    over = {}
    if getattr(args, "rig_gamma", None) is not None:
        over["gamma"] = args.rig_gamma
    if getattr(args, "rig_creep_scale", None) is not None:
        over["creep_scale"] = args.rig_creep_scale
    if getattr(args, "rig_noise_scale", None) is not None:
        over["noise_rms_um"] = settings.noise_rms_um * args.rig_noise_scale
    try:
        return VirtualRig(settings, seed=args.seed, **over)
    except (TypeError, ValueError) as exc:
        flags = {"gamma": "--rig-gamma", "creep_scale": "--rig-creep-scale", "noise_rms_um": "--rig-noise-scale"}
        named = [f for k, f in flags.items() if k in over and k in str(exc)]
        raise UsageError(f"{named[0] if named else src}: {one_line(exc)}") from None


def rig_rate_note(args: argparse.Namespace) -> str:
    """Where the sample rate comes from, for messages (the rig-settings file, if one was given)."""
    return f" (the rig's, from {args.rig_settings})" if getattr(args, "rig_settings", None) else " (the rig's)"


def guarded(call: Callable[[], Any], prefix: str) -> Any:
    """Run ``call``; a ValueError/TypeError raised by one of our checks, or a FitError, becomes a
    UsageError starting with ``prefix`` (the file or flag it is about). Anything else passes through."""
    from .._validation import FitError

    try:
        return call()
    except FitError as exc:  # the data gave the fit nothing to converge on
        raise UsageError(f"{prefix}: {one_line(exc)}") from exc
    except (ValueError, TypeError) as exc:
        if is_deliberate(exc) and prefix not in str(exc):
            raise UsageError(f"{prefix}: {one_line(exc)}") from exc
        raise


def check_u_options(u_min: float | None, u_max: float | None) -> None:
    """``--u-min`` / ``--u-max`` as given: finite, and the one below the other (a UsageError)."""
    for flag, v in (("--u-min", u_min), ("--u-max", u_max)):
        if v is not None and not math.isfinite(v):
            raise UsageError(f"--u-min and --u-max must be finite volts, got {flag} {v}")
    if u_min is not None and u_max is not None and not u_min < u_max:
        raise UsageError(f"--u-min ({u_min:g}) must be below --u-max ({u_max:g})")


def amplifier_range(u_min: float | None, u_max: float | None, doc: dict[str, Any]) -> tuple[float, float, str]:
    """The amplifier's range for a model file's compensator: ``--u-min`` / ``--u-max`` where
    given; else 0 / 100 V, widened to the input range the model was identified on where that
    reaches further (its record's, ``fit.input_range_V``: the amplifier drove the stage there, so a
    stage identified on -100..100 V or 0..150 V is driven there too; a narrower record keeps
    0..100 V, and commands beyond what it identified are warned of, not refused).
    ``doc`` is a model file as :func:`~piezohyst.modelio.load_model_document` read it (which checked
    its ``fit`` block). Returns ``(low, high, where each came from)``."""
    from ..models.base import DEFAULT_U_RANGE  # (here: the command line parses before numpy loads)

    # no record said (a model saved without its fit): the default alone
    rec = (doc.get("fit") or {}).get("input_range_V") or DEFAULT_U_RANGE
    ends = []
    for given, flag, recorded, default, wider in ((u_min, "--u-min", rec[0], DEFAULT_U_RANGE[0], min),
                                                  (u_max, "--u-max", rec[1], DEFAULT_U_RANGE[1], max)):
        if given is not None:
            ends.append((float(given), flag))
        elif wider(recorded, default) != default:
            ends.append((float(recorded), "the model's identified input range"))
        else:
            ends.append((default, f"the default {default:g} V"))
    (lo, lo_from), (hi, hi_from) = ends
    if not lo < hi:
        raise UsageError(f"the amplifier range {lo:g}..{hi:g} V (low from {lo_from}, high from {hi_from}) is empty; "
                         "give --u-min and --u-max")
    return lo, hi, lo_from if lo_from == hi_from else f"{lo_from} and {hi_from}"
