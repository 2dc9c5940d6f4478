"""``piezohyst models``: the paper's two models and their loops."""

from __future__ import annotations

import argparse
from functools import partial
from typing import Any

from ._common import check_sinusoids, console, freqs, guarded, print_json


def cmd_models(args: argparse.Namespace) -> int:
    dt = 1e-4
    check_sinusoids(args.freq, 3, dt, cycles_flag="")  # before loading or allocating anything

    import numpy as np

    import piezohyst as ph
    from piezohyst import paper_values as pv

    rows = []
    for freq in args.freq:
        u = ph.sinusoid(freq, 3, 0.0, 100.0, dt)
        bw = pv.bouc_wen_model()
        figs_bw = guarded(partial(ph.loop_figures, u, bw.simulate(u, dt) * 1e6), f"--freq {freq:g} Hz")
        pi = pv.pi_model()
        figs_pi = guarded(partial(ph.loop_figures, u, pi.simulate(u)), f"--freq {freq:g} Hz")
        rows.append({"model": "Bouc-Wen, paper III-B", "freq_hz": freq, "span": figs_bw.span,
                     "unit": "um", "width": figs_bw.width, "width_percent": figs_bw.width_percent})
        rows.append({"model": "P-I, paper III-C", "freq_hz": freq, "span": figs_pi.span,
                     "unit": "model units", "width": figs_pi.width, "width_percent": figs_pi.width_percent})
    inv = pv.pi_model().inverse()
    u = ph.sinusoid(1.0, 2, 0.0, 100.0, dt)
    y = pv.pi_model().simulate(u)
    inv_err = float(abs(inv.simulate(y) - u).max())
    printed = ph.PrandtlIshlinskii(inv.thresholds, np.asarray(pv.PI_INVERSE_WEIGHTS_PRINTED, dtype=np.float64))
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
        print_json(result)
        return 0
    from rich.table import Table

    con = console()
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


def register(sub: Any, add: Any) -> None:
    p = add("models", cmd_models, "Simulate the paper's P-I and Bouc-Wen models and print their loops' figures.",
            "piezohyst models --freq 1,3,5 --json")
    p.add_argument("--freq", type=freqs, default=[1.0], help="excitation frequencies in Hz, comma-separated (default 1)")
    p.add_argument("--json", action="store_true", help="print the figures as JSON only")
