"""The ``piezohyst`` command. Thin: it parses, calls the public API, prints.

Every command that prints figures prints them as JSON instead with ``--json`` (nothing else on
stdout). Errors in what the user gave (a file, a value) end with exit code 2 and one line on
stderr; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any, Callable, Sequence

EXAMPLES = """\
examples:
  piezohyst reproduce --out results/          the paper's experiment on the virtual rig
  piezohyst identify data.csv --model pi --method lsq -o pi.json
  piezohyst rig --freq 1,3,5 --out loops/     open-loop loops of the virtual rig (Fig. 2)
  piezohyst models                            the paper's two models and their loops
Run 'piezohyst COMMAND --help' for each command's options and an example.
"""


class UsageError(Exception):
    """A problem with what the user asked for: reported as one line, exit code 2."""


def _console(stderr: bool = False):  # type: ignore[no-untyped-def]
    from rich.console import Console

    import shutil

    # tables stay readable when the output is piped or captured (no terminal width to ask)
    width = None if sys.stdout.isatty() else max(shutil.get_terminal_size((140, 24)).columns, 140)
    return Console(stderr=stderr, highlight=False, markup=False, width=width)


def _print_json(obj: Any) -> None:
    sys.stdout.write(json.dumps(obj, indent=2, sort_keys=False) + "\n")


def _freqs(text: str) -> list[float]:
    try:
        out = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated frequencies in Hz, got {text!r}") from None
    if not out or any(f <= 0 for f in out):
        raise argparse.ArgumentTypeError(f"frequencies must be positive, got {text!r}")
    return out


# ----------------------------------------------------------------------------------------------
# piezohyst models
def cmd_models(args: argparse.Namespace) -> int:
    import piezohyst as ph
    from piezohyst import paper_values as pv

    dt = 1e-4
    rows = []
    for freq in args.freq:
        u = ph.sinusoid(freq, 3, 0.0, 100.0, dt)
        bw = pv.bouc_wen_model()
        figs_bw = ph.loop_figures(u, bw.simulate(u, dt) * 1e6)
        pi = pv.pi_model()
        figs_pi = ph.loop_figures(u, pi.simulate(u))
        rows.append({"model": "Bouc-Wen, paper III-B", "freq_hz": freq, "span": figs_bw.span,
                     "unit": "um", "width": figs_bw.width, "width_percent": figs_bw.width_percent})
        rows.append({"model": "P-I, paper III-C", "freq_hz": freq, "span": figs_pi.span,
                     "unit": "model units", "width": figs_pi.width, "width_percent": figs_pi.width_percent})
    inv = pv.pi_model().inverse()
    u = ph.sinusoid(1.0, 2, 0.0, 100.0, dt)
    y = pv.pi_model().simulate(u)
    inv_err = float(abs(inv.simulate(y) - u).max())
    printed = ph.PrandtlIshlinskii(inv.thresholds, pv.PI_INVERSE_WEIGHTS_PRINTED)
    printed_err = float(abs(printed.simulate(y) - u).max())
    bw = pv.bouc_wen_model()
    result = {
        "loops": rows,
        "bouc_wen_resonance_hz": bw.natural_frequency_hz,
        "bouc_wen_damping_ratio": bw.damping_ratio,
        "inverse_pi": {
            "w1_computed": float(inv.weights[0]), "w1_printed": pv.PI_INVERSE_WEIGHTS_PRINTED[0],
            "max_error_computed_V": inv_err, "max_error_printed_V": printed_err,
        },
    }
    if args.json:
        _print_json(result)
        return 0
    from rich.table import Table

    con = _console()
    t = Table(title="The paper's models driven by a 0-100 V sinusoid (3rd cycle)")
    for col in ("model", "freq (Hz)", "span", "loop width at mid-range", "width % of span"):
        t.add_column(col, justify="right" if col != "model" else "left")
    for r in rows:
        t.add_row(r["model"], f"{r['freq_hz']:g}", f"{r['span']:.4g} {r['unit']}",
                  f"{r['width']:.4g} {r['unit']}", f"{r['width_percent']:.1f} %")
    con.print(t)
    con.print(f"Bouc-Wen linear part: resonance {bw.natural_frequency_hz:.0f} Hz, "
              f"damping ratio {bw.damping_ratio:.4f}")
    con.print(f"Inverse P-I by eqs. (13)-(15): w'_1 = {inv.weights[0]:.3f} (printed in the paper: "
              f"{pv.PI_INVERSE_WEIGHTS_PRINTED[0]}); max |u - P^-1[P[u]]| = {inv_err:.2e} V, "
              f"with the printed w': {printed_err:.1f} V")
    return 0


# ----------------------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    from piezohyst import __version__

    parser = argparse.ArgumentParser(
        prog="piezohyst",
        description="Hysteresis modelling, identification and compensation of piezoelectric "
        "actuators (Prandtl-Ishlinskii, Bouc-Wen, PSO, inverse feedforward + PID).",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"piezohyst {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks instead of one-line errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    def add(name: str, func: Callable[[argparse.Namespace], int], help: str, example: str) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help, description=help, epilog=f"example:\n  {example}",
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        p.set_defaults(func=func)
        return p

    p = add("models", cmd_models, "Simulate the paper's P-I and Bouc-Wen models and print their loops' figures.",
            "piezohyst models --freq 1,3,5 --json")
    p.add_argument("--freq", type=_freqs, default=[1.0], help="excitation frequencies in Hz, comma-separated (default 1)")
    p.add_argument("--json", action="store_true", help="print the figures as JSON only")

    for register in _REGISTRY:
        register(sub, add)
    return parser


# commands defined in other modules register themselves here (keeps this file readable)
_REGISTRY: list[Callable[..., None]] = []


def _load_commands() -> None:
    # importing a command module registers it
    from . import cli_benchmark, cli_control, cli_identify, cli_reproduce, cli_rig  # noqa: F401


def main(argv: Sequence[str] | None = None) -> int:
    _load_commands()
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 0
    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        print("piezohyst: interrupted", file=sys.stderr)
        return 130
    except (UsageError, ValueError, TypeError, OSError, KeyError) as exc:
        if args.debug:
            raise
        msg = str(exc) or type(exc).__name__
        print(f"piezohyst {args.command}: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
