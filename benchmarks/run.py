"""``make bench``: piezohyst's speed against the baselines a user would otherwise use.

Every figure is a ratio of times measured in this same run on this machine (shared, noisy
machines make absolute times meaningless). Prints a table (figure, ours, baseline, ratio, target,
met?) and writes benchmarks/results.json. A missed target says so and why.
"""

from __future__ import annotations

import ctypes
import json
import logging
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROWS: list[dict] = []


def timeit(fn, *, repeat=5, number=1):
    """Best wall time of ``number`` calls over ``repeat`` repetitions (after one warm-up).

    The minimum, as Python's ``timeit`` recommends: on a shared machine other load only ever
    adds time, so the fastest repetition is the best estimate of the code's own cost.
    """
    fn()
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        for _ in range(number):
            fn()
        ts.append((time.perf_counter() - t) / number)
    return float(np.min(ts))


def paired(fa, fb, *, rounds=5, repeat=3):
    """Times of two functions measured in alternating rounds, so load spikes hit both alike."""
    ta, tb = [], []
    for _ in range(rounds):
        ta.append(timeit(fa, repeat=repeat))
        tb.append(timeit(fb, repeat=repeat))
    return float(min(ta)), float(min(tb))


def row(n, what, ours, baseline_name, baseline, ratio, target, met, note=""):
    ROWS.append({"row": n, "what": what, "ours": ours, "baseline": baseline_name, "baseline_value": baseline,
                 "ratio": ratio, "target": target, "met": met, "note": note})


def fmt_t(s):
    return f"{s * 1e3:.3g} ms" if s < 1 else f"{s:.3g} s"


# ------------------------------------------------------------------------------------------------
def bench_pi_simulate():
    from piezohyst import paper_values as pv

    model = pv.pi_model()
    rng = np.random.default_rng(0)
    n = 1_000_000
    u = np.clip(50 + np.cumsum(rng.normal(0, 1.0, n)) % 100, 0, 100)
    ours = timeit(lambda: model.simulate(u), repeat=5)
    r, w = model.thresholds, model.weights

    def numpy_loop(uu):  # a plain NumPy loop over time, vectorised over the operators
        z = np.zeros(r.size)
        y = np.empty(uu.size)
        for k in range(uu.size):
            z = np.minimum(np.maximum(z, uu[k] - r), uu[k] + r)
            y[k] = w @ z
        return y

    m = 100_000  # the loop is timed on 1/10 of the samples and scaled (it is linear in n)
    base = timeit(lambda: numpy_loop(u[:m]), repeat=3) * (n / m)
    assert np.allclose(numpy_loop(u[:m]), model.simulate(u[:m]))
    ratio = base / ours
    row(1, "P-I simulate, 20 operators, 1,000,000 samples", fmt_t(ours), "NumPy loop over time (vectorised over operators)",
        fmt_t(base), ratio, ">= 50x faster", ratio >= 50, "NumPy loop timed on 100,000 samples and scaled x10")

    # row 2: the same kernel in C (gcc -O3)
    gcc = shutil.which("gcc") or shutil.which("cc")
    if gcc is None:
        row(2, "P-I simulate vs C -O3", fmt_t(ours), "C, gcc -O3", None, None, "within 2x of C", None,
            "skipped: no C compiler on this machine")
        return
    build = HERE / "_build"
    build.mkdir(exist_ok=True)
    lib = build / "pi_kernel.so"
    subprocess.run([gcc, "-O3", "-march=native", "-shared", "-fPIC", str(HERE / "pi_kernel.c"), "-o", str(lib)], check=True)
    c = ctypes.CDLL(str(lib))
    dp = ctypes.POINTER(ctypes.c_double)
    c.pi_simulate.argtypes = [dp, ctypes.c_size_t, dp, dp, dp, ctypes.c_size_t, dp]
    y = np.empty(n)

    def c_run():
        z = np.zeros(r.size)
        c.pi_simulate(u.ctypes.data_as(dp), n, r.ctypes.data_as(dp), w.ctypes.data_as(dp), z.ctypes.data_as(dp), r.size,
                      y.ctypes.data_as(dp))

    ours, c_t = paired(lambda: model.simulate(u), c_run)
    assert np.allclose(y, model.simulate(u))
    ratio = ours / c_t
    row(2, "P-I simulate, same, against the physical limit", fmt_t(ours), "the same loop in C, gcc -O3 -march=native",
        fmt_t(c_t), ratio, "within 2x of C (ratio <= 2)", ratio <= 2.0, "ratio = our time / C time")


def bench_bouc_wen():
    import piezohyst as ph
    from piezohyst.models.bouc_wen import solve_ivp_reference
    from piezohyst import paper_values as pv

    bw = pv.bouc_wen_model()
    dt = 1e-4
    u = ph.sinusoid(1.0, 2, 0.0, 100.0, dt)  # 2 s at 10 kHz
    ours = timeit(lambda: bw.simulate(u, dt), repeat=7)
    t0 = time.perf_counter()
    x_ref, _ = solve_ivp_reference(bw, u, dt, method="LSODA", rtol=1e-8)
    base = time.perf_counter() - t0
    diff = float(np.abs(x_ref - bw.simulate(u, dt)).max())
    ratio = base / ours
    row(3, "BoucWen.simulate, paper parameters, 2 s at 10 kHz", fmt_t(ours), "scipy solve_ivp (LSODA, rtol 1e-8)",
        fmt_t(base), ratio, ">= 1000x faster, max difference <= 1 nm", ratio >= 1000 and diff <= 1e-9,
        f"max |difference| = {diff * 1e9:.3f} nm")


def bench_pso_overhead():
    import piezohyst as ph

    try:
        import pyswarms as ps
    except ImportError:
        row(4, "pso_minimize overhead per iteration", None, "pyswarms GlobalBestPSO", None, None, "<= 0.5x its time", None,
            "skipped: pyswarms not installed (pip install piezohyst[bench])")
        return
    logging.getLogger("pyswarms").setLevel(logging.ERROR)
    bounds = [(-5.0, 5.0)] * 7
    iters = 300

    def f(x):
        return (x**2).sum(axis=1)

    lb, ub = np.full(7, -5.0), np.full(7, 5.0)

    def theirs():
        opt = ps.single.GlobalBestPSO(n_particles=50, dimensions=7, options={"c1": 1.49618, "c2": 1.49618, "w": 0.7298},
                                      bounds=(lb, ub))
        opt.optimize(f, iters=iters, verbose=False)

    ours, base = paired(lambda: ph.pso_minimize(f, bounds, n_particles=50, max_iter=iters, seed=0), theirs,
                        rounds=4, repeat=2)
    ours, base = ours / iters, base / iters
    ratio = ours / base
    row(4, "pso_minimize overhead per iteration, 50 particles, 7-D, trivial objective", f"{ours * 1e6:.1f} µs",
        "pyswarms GlobalBestPSO, same settings, quiet", f"{base * 1e6:.1f} µs", ratio, "<= 0.5x its time", ratio <= 0.5,
        "ratio = our time / pyswarms' time")


def bench_fit_pi():
    import piezohyst as ph

    rig = ph.VirtualRig(seed=0)
    ds = rig.excite(ph.sinusoid(1.0, 2, 0.0, 100.0, rig.dt))  # 20,000 samples
    lsq_t, pso_t = paired(lambda: ph.fit_pi(ds.u, ds.y, n=20, method="lsq"),
                          lambda: ph.fit_pi(ds.u, ds.y, n=20, method="pso", seed=0))
    lsq = ph.fit_pi(ds.u, ds.y, n=20, method="lsq")
    pso = ph.fit_pi(ds.u, ds.y, n=20, method="pso", seed=0)
    ratio = pso_t / lsq_t
    met = ratio >= 100 and lsq.rmse <= pso.rmse
    note = (f"RMSE: lsq {lsq.rmse * 1e3:.2f} nm, pso {pso.rmse * 1e3:.2f} nm (40 x 200). ")
    if ratio < 100:
        note += ("Missed: the PSO baseline already evaluates eq. (9) exactly through the 20x20 Gram matrix "
                 "(8,040 evaluations in a few ms, no simulation per particle), so little is left to beat; "
                 "against PSO that simulates each particle's model (row 5b) the ratio is far above 100x. "
                 "Closing it against this baseline would need the regressor matrix (0.4 ms) and the Gram "
                 "product (0.7 ms) to cost nothing.")
    row(5, "fit_pi, 20,000 samples, 20 thresholds: lsq", fmt_t(lsq_t), 'fit_pi(method="pso") on the same data',
        fmt_t(pso_t), ratio, "lsq faster by >= 100x, and RMSE no worse", met, note)

    # 5b, for context: PSO as most would write it, simulating every particle's model
    model = lsq.model
    r = model.thresholds
    from piezohyst.models.play import pi_simulate

    def swarm_by_simulation(wmat):
        return np.array([np.sqrt(np.mean((ds.y - (pi_simulate(ds.u, r, wv, np.zeros(r.size), 0.0, 0.0) + model.offset)) ** 2))
                         for wv in wmat])

    one_iter = timeit(lambda: swarm_by_simulation(np.tile(model.weights, (40, 1))), repeat=3)
    sim_pso = one_iter * 201
    row("5b", "the same, context: PSO simulating every particle (compiled kernel)", fmt_t(lsq_t),
        "40 particles x 201 evaluations, one iteration timed and extrapolated", fmt_t(sim_pso), sim_pso / lsq_t,
        "(context, no target)", None, "one swarm evaluation timed, times 201")


def bench_fit_bouc_wen():
    import piezohyst as ph
    from piezohyst.models.bouc_wen import solve_ivp_reference

    rig = ph.VirtualRig(seed=0)
    ds = rig.excite(ph.sinusoid(1.0, 2, 0.0, 100.0, rig.dt))  # 20,000 samples
    ph.fit_bouc_wen(ds.u[:2000], ds.y[:2000], rig.dt, max_iter=2, polish=False)  # compile outside the timing
    t0 = time.perf_counter()
    fit = ph.fit_bouc_wen(ds.u, ds.y, rig.dt, seed=0, n_particles=40, max_iter=200, polish=False)
    ours = time.perf_counter() - t0
    def one_particle():  # what a pyswarms objective would do for one particle
        x, _ = solve_ivp_reference(fit.model, ds.u, rig.dt, method="LSODA", rtol=1e-8)
        return np.sqrt(np.mean((x * 1e6 - ds.y) ** 2))

    t0 = time.perf_counter()
    one_particle()
    per_particle = time.perf_counter() - t0
    base = per_particle * 40 * 201
    ratio = base / ours
    row(6, "fit_bouc_wen, 40 particles x 200 iterations, 20,000 samples", fmt_t(ours),
        "pyswarms + solve_ivp per particle", fmt_t(base), ratio, "whole fit <= 10 s; >= 1000x faster",
        ours <= 10 and ratio >= 1000,
        f"baseline extrapolated: one particle's solve_ivp simulation timed ({per_particle:.2f} s) x 40 x 201 "
        f"evaluations; pyswarms' own overhead (row 4) is negligible beside it. Fit RMSE {fit.rmse * 1e3:.2f} nm")


def bench_realtime_step():
    import piezohyst as ph
    from piezohyst import paper_values as pv

    model = ph.PrandtlIshlinskii(ph.equal_thresholds(20, 100.0), np.array(pv.PI_WEIGHTS) * 0.0225)
    ff = ph.InversePIFeedforward(model)
    pid = ph.PID(kp=0.1, ki=500.0, kd=1e-5, dt=1e-4)
    ref = ph.sinusoid(5.0, 1, 0.25, 2.25, 1e-4)
    y = 0.0
    samples = []
    for _ in range(3):
        ff.reset()
        pid.reset()
        for r in ref:
            t0 = time.perf_counter_ns()
            u = ff.step(r + pid.step(r - y))
            samples.append(time.perf_counter_ns() - t0)
            y = 0.0225 * u
    med = float(np.median(samples[len(ref):])) * 1e-9  # a distribution, so the median, as the target says
    p99 = float(np.percentile(samples[len(ref):], 99)) * 1e-9
    headroom = 100e-6 / med
    row(7, "one real-time control step (inverse-P-I feedforward + PID), called from Python", f"{med * 1e6:.2f} µs",
        "the 100 µs budget of a 10 kHz loop", "100 µs", headroom, "median <= 5 µs (>= 20x headroom)", med <= 5e-6,
        f"99th percentile {p99 * 1e6:.2f} µs; ratio = headroom (budget / median)")


def compile_cost():
    """What the first run pays for compiling the kernels, and what a second run pays (cache)."""
    code = ("import time; t=time.perf_counter(); import numpy as np, piezohyst as ph; "
            "from piezohyst import paper_values as pv; u=ph.sinusoid(1,1,0,100,1e-3); "
            "pv.pi_model().simulate(u); pv.bouc_wen_model().simulate(u,1e-3); "
            "ph.VirtualRig().excite(u); ph.fit_bouc_wen(u[:200], pv.bouc_wen_model().simulate(u,1e-3)[:200]*1e6, 1e-3, max_iter=1, polish=False); "
            "print(time.perf_counter()-t)")
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        cold = float(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout)
        warm = float(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout)
    return cold, warm


def machine():
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import numba
    import scipy

    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "numba": numba.__version__, "platform": platform.platform()}


def main():
    from rich.console import Console
    from rich.table import Table

    con = Console(width=max(shutil.get_terminal_size((160, 24)).columns, 160), highlight=False, markup=False)
    t_start = time.perf_counter()
    steps = [bench_pi_simulate, bench_bouc_wen, bench_pso_overhead, bench_fit_pi, bench_fit_bouc_wen, bench_realtime_step]
    for s in steps:
        con.print(f"running {s.__name__} ...")
        s()
    cold, warm = compile_cost()
    info = machine()
    table = Table(title=f"piezohyst benchmarks - {info['cpu']}, {info['cores']} cores, Python {info['python']}, numba {info['numba']}")
    for c in ("#", "what", "ours", "baseline (same run)", "baseline", "ratio", "target", "met?"):
        table.add_column(c, overflow="fold")
    for r in ROWS:
        table.add_row(str(r["row"]), r["what"], r["ours"] or "-", r["baseline"], r["baseline_value"] or "-",
                      f"{r['ratio']:.3g}" if r["ratio"] is not None else "-", r["target"],
                      {True: "yes", False: "NO", None: "-"}[r["met"]])
    con.print(table)
    for r in ROWS:
        if r["note"]:
            con.print(f"  row {r['row']}: {r['note']}")
    con.print(f"  numba compilation: a first run (empty cache) pays {cold:.1f} s to compile the kernels; "
              f"a second run loads them from the cache in {warm:.1f} s (import included).")
    total = time.perf_counter() - t_start
    con.print(f"  make bench took {total:.0f} s")
    sys.path.insert(0, str(HERE.parent / "src"))
    from piezohyst._fileio import atomic_write_text, producer

    doc = {"producer": producer(), "machine": info, "rows": ROWS,
           "compile_s": {"first_run": cold, "cached": warm}, "total_s": total}
    atomic_write_text(HERE / "results.json", json.dumps(doc, indent=2) + "\n", force=True)
    con.print(f"  wrote {HERE / 'results.json'}")


if __name__ == "__main__":
    main()
