"""Measure the cost model behind the automatic choice of P-I kernel (piezohyst.models.play).

    PYTHONPATH=src python benchmarks/calibrate_pi.py

Times the event-driven and the dense loop on a family of records (sinusoids with and without
noise of several sizes, random walks, white noise) and operator counts, fits

    event ns/sample ~ _EV_SAMPLE + _EV_TURN * reversals + _EV_MOVE * moves   (per sample)
    dense ns/sample ~ _DENSE_SAMPLE + _DENSE_OP * n_operators

by least squares (reversals and moves from play.event_work, the same cheap look the choice
uses), prints the constants and how often the choice they make is within 15 % of the faster
loop. Nothing here is run by the tests or `make bench`; it documents where the constants in
play.py come from.
"""

from __future__ import annotations

import time

import numpy as np

from piezohyst.models import play as P


def records(n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    t = np.arange(n) * 1e-4
    base = 50 + 45 * np.sin(2 * np.pi * t)
    out = {"sine": base, "two tones": 50 + 30 * np.sin(2 * np.pi * t) + 15 * np.sin(2 * np.pi * 3.3 * t)}
    for rel in (1e-4, 1e-3, 1e-2, 5e-2):
        out[f"sine + noise {rel:g}"] = base + rng.normal(0, 100 * rel, n)
    for step in (0.1, 1.0, 5.0):
        out[f"walk {step:g}"] = 50 + np.cumsum(rng.normal(0, step, n)) % 100
    out["white"] = rng.uniform(0, 100, n)
    return out


def best(f, rounds: int = 5) -> float:
    f()
    ts = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return min(ts)


def main() -> None:
    rng = np.random.default_rng(0)
    n = 200_000
    rows = []
    for m in (2, 5, 10, 20, 50, 100, 200, 400):
        r = np.arange(m) / (m + 1) * 100.0
        w = rng.uniform(0.01, 1.0, m)
        y = np.empty(n)
        for name, u in records(n, rng).items():
            turns, moves = P.event_work(u, r)
            te = best(lambda u=u, r=r, w=w, m=m, y=y: P._pi_events_into(u, r, w, np.zeros(m), 0.0, 0.0, y, 0))
            td = best(lambda u=u, r=r, w=w, m=m, y=y: P._pi_dense_fast_into(u, r, w, np.zeros(m), 0.0, 0.0, y, 0, n))
            rows.append((m, name, turns, moves, te / n * 1e9, td / n * 1e9))
    a = np.array([[1.0, t, mv] for _, _, t, mv, _, _ in rows])
    ev = np.array([row[4] for row in rows])
    d = np.array([[1.0, row[0]] for row in rows])
    de = np.array([row[5] for row in rows])
    ce, *_ = np.linalg.lstsq(a / ev[:, None], np.ones_like(ev), rcond=None)  # relative error
    cd, *_ = np.linalg.lstsq(d / de[:, None], np.ones_like(de), rcond=None)
    print(f"_EV_SAMPLE = {ce[0]:.2f}, _EV_TURN = {ce[1]:.2f}, _EV_MOVE = {ce[2]:.2f}")
    print(f"_DENSE_SAMPLE = {cd[0]:.2f}, _DENSE_OP = {cd[1]:.3f}")
    good = 0
    for (m, name, turns, moves, te, td), _ in zip(rows, range(len(rows))):
        pick_ev = ce[0] + ce[1] * turns + ce[2] * moves < cd[0] + cd[1] * m
        now_ev = P._EV_SAMPLE + P._EV_TURN * turns + P._EV_MOVE * moves < P._DENSE_SAMPLE + P._DENSE_OP * m
        chosen = te if now_ev else td
        ok = chosen <= 1.15 * min(te, td)
        good += ok
        print(f"{m:4d} {name:20s} turns {turns:.3f} moves {moves:7.3f}  events {te:7.2f}  dense {td:7.2f}"
              f"  fit picks {'events' if pick_ev else 'dense '}  play.py picks {'events' if now_ev else 'dense '}"
              f"{'' if ok else '  <-- more than 15 % off the faster'}")
    print(f"play.py's constants pick within 15 % of the faster loop in {good} of {len(rows)} cases")


if __name__ == "__main__":
    main()
