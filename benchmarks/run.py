"""``make bench``: piezohyst's speed against the baselines a user would otherwise use.

Every figure is a ratio of two times measured in this same run on this machine (a shared, noisy
machine makes absolute times meaningless): both sides warmed up, then timed in interleaved
rounds, the best (fastest) repetition of each kept. A baseline too slow to run in full is timed
on a stated subset and scaled; the row says so. Every row states its target and whether it was
met; a missed row says so and is never left out.

Prints a table and writes ``benchmarks/out/results.json`` (not tracked by git);
``python benchmarks/readme_table.py`` turns that file into the README's performance table.

Adding a row: write a function that takes a :class:`Bench` and calls ``b.row(...)`` (or
``b.skip(...)``), decorate it with ``@bench("short-name")``. Helpers: :func:`paired` (interleaved
best-of timing of several callables), :func:`cpu_of_command` (CPU seconds of a subprocess),
:func:`peak_rss_of_code` (peak memory of a snippet in a fresh process).

    PYTHONPATH=src python benchmarks/run.py            # every row
    PYTHONPATH=src python benchmarks/run.py pi- fit-pi  # rows whose name starts so
"""

from __future__ import annotations

import ctypes
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
OUT = HERE / "out"
SRC = HERE.parent / "src"


# -- measurement -----------------------------------------------------------------------------------
def paired(fns: dict[str, Callable[[], Any]], *, rounds: int = 5, repeat: int = 3,
           warm: bool = True, clock: str = "wall") -> dict[str, float]:
    """Best time (s) of each callable: one warm-up call each (``warm=False``: the caller has
    warmed them up, e.g. compiled on a smaller input), then ``rounds`` interleaved rounds of
    ``repeat`` calls each. On a shared machine other load only ever adds time, so the fastest
    repetition is the best estimate of the code's own cost, and interleaving lets a spell of
    load hit every side alike.

    ``clock="wall"``: elapsed time. ``clock="cpu"``: the CPU time of the calling thread, for
    comparisons where both sides run in this one thread: it leaves out the time the thread
    waits while other processes run, which on an oversubscribed machine is most of the wall
    time (it still includes the slow-down they cause through shared caches and cores)."""
    now = {"wall": time.perf_counter, "cpu": time.thread_time}[clock]
    if warm:
        for f in fns.values():
            f()
    best = {k: np.inf for k in fns}
    for _ in range(rounds):
        for k, f in fns.items():
            for _ in range(repeat):
                t0 = now()
                f()
                best[k] = min(best[k], now() - t0)
    return {k: float(v) for k, v in best.items()}


def _child_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def cpu_of_command(cmds: dict[str, list[str]], *, rounds: int = 5, env: dict[str, str] | None = None) -> dict[str, float]:
    """Best CPU time (user + system, s) of each command, in interleaved rounds after a warm-up."""
    best = {k: np.inf for k in cmds}
    for i in range(rounds + 1):
        for k, c in cmds.items():
            before = _child_cpu()
            subprocess.run(c, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
            if i:  # the first round warms the file cache
                best[k] = min(best[k], _child_cpu() - before)
    return {k: float(v) for k, v in best.items()}


def peak_rss_of_code(code: str, *, cap_bytes: int, timeout: float = 600) -> dict[str, Any]:
    """Run ``code`` in a fresh interpreter limited to ``cap_bytes`` of address space; return its
    peak resident memory (bytes), exit status and the JSON object it printed last (if any)."""
    pre = (f"import resource; resource.setrlimit(resource.RLIMIT_AS, ({cap_bytes}, {cap_bytes}))\n")
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    p = subprocess.run([sys.executable, "-c", pre + code], capture_output=True, text=True, timeout=timeout, check=False,
                       env=_env())
    peak_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # max over all children so far
    out: dict[str, Any] = {"returncode": p.returncode, "stderr_tail": p.stderr.strip().splitlines()[-3:]}
    for line in reversed(p.stdout.strip().splitlines()):
        try:
            out["result"] = json.loads(line)
            break
        except ValueError:
            continue
    res = out.get("result", {})
    # the child reports its own peak (exact); the children's maximum is a fallback
    out["peak_bytes"] = int(res.get("maxrss_kib", peak_kib if peak_kib > before else 0)) * 1024
    return out


def _env(**extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(SRC) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.update(extra)
    return env


def fmt_t(s: float | None) -> str:
    if s is None or not np.isfinite(s):
        return "-"
    if s >= 1:
        return f"{s:.3g} s"
    if s >= 1e-3:
        return f"{s * 1e3:.3g} ms"
    return f"{s * 1e6:.3g} µs"


def fmt_b(n: float) -> str:
    return f"{n / 2**30:.2f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


# -- the registry ----------------------------------------------------------------------------------
@dataclass
class Bench:
    """Collects the rows of one run."""

    rows: list[dict[str, Any]] = field(default_factory=list)

    def row(self, name: str, what: str, *, ours: str, baseline: str, ratio: float | None, ratio_is: str,
            target: str, met: bool | None, note: str = "", **figures: Any) -> None:
        """One result. ``ours``/``baseline`` are display strings (label and figure); ``ratio_is``
        says what the ratio is (e.g. "baseline / ours"); ``figures`` are the raw numbers."""
        self.rows.append({"name": name, "what": what, "ours": ours, "baseline": baseline,
                          "ratio": None if ratio is None else float(ratio), "ratio_is": ratio_is,
                          "target": target, "met": None if met is None else bool(met), "note": note,
                          "figures": {k: _plain(v) for k, v in figures.items()}})

    def skip(self, name: str, what: str, target: str, why: str) -> None:
        self.row(name, what, ours="-", baseline="-", ratio=None, ratio_is="-", target=target, met=None,
                 note=f"not run: {why}")


def _plain(v: Any) -> Any:
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


REGISTRY: list[tuple[str, Callable[[Bench], None]]] = []


def bench(name: str) -> Callable[[Callable[[Bench], None]], Callable[[Bench], None]]:
    def deco(fn: Callable[[Bench], None]) -> Callable[[Bench], None]:
        REGISTRY.append((name, fn))
        return fn
    return deco


# -- shared inputs ---------------------------------------------------------------------------------
N_PI = 1_000_000  # samples of the P-I records (100 s at 10 kHz)


def smooth_record(n: int = N_PI, dt: float = 1e-4) -> np.ndarray:
    """A smooth actuator command: a 1 Hz sinusoid with a slowly changing amplitude and a 3.3 Hz
    component, within 0..100 V (what a feedforward controller or an identification run sends)."""
    t = np.arange(n) * dt
    amp = 30 + 15 * np.sin(2 * np.pi * 0.013 * t)
    return 50 + amp * np.sin(2 * np.pi * t) + 4 * np.sin(2 * np.pi * 3.3 * t + 1.0)


def white_record(n: int = N_PI) -> np.ndarray:
    return np.random.default_rng(7).uniform(0.0, 100.0, n)


def model_with(m: int):
    import piezohyst as ph

    rng = np.random.default_rng(m)
    w = rng.uniform(0.2, 1.0, m) / m  # positive: an invertible, physical model
    return ph.PrandtlIshlinskii(ph.equal_thresholds(m, 100.0), w)


class CDense:
    """The dense P-I loop of benchmarks/pi_kernel.c, compiled with the system gcc."""

    def __init__(self, flags: list[str]):
        gcc = shutil.which("gcc") or shutil.which("cc")
        if gcc is None:
            raise RuntimeError("no C compiler (gcc or cc) on this machine")
        build = OUT / "build"
        build.mkdir(parents=True, exist_ok=True)
        lib = build / ("pi_kernel" + "".join(f.replace("-", "_").replace("=", "") for f in flags) + ".so")
        subprocess.run([gcc, *flags, "-shared", "-fPIC", str(HERE / "pi_kernel.c"), "-o", str(lib)], check=True)
        self.flags = " ".join(flags)
        self.lib = ctypes.CDLL(str(lib))
        dp = ctypes.POINTER(ctypes.c_double)
        self.lib.pi_simulate.argtypes = [dp, ctypes.c_size_t, dp, dp, dp, ctypes.c_size_t, dp]
        self._dp = dp

    def simulate(self, model, u: np.ndarray) -> np.ndarray:
        """Same contract as ``model.simulate(u)``: a fresh output array, state from the model."""
        dp = self._dp
        r, w = model.thresholds, model.weights
        z = np.array(model.initial_state)
        y = np.empty(u.size)
        self.lib.pi_simulate(u.ctypes.data_as(dp), u.size, r.ctypes.data_as(dp), w.ctypes.data_as(dp),
                             z.ctypes.data_as(dp), r.size, y.ctypes.data_as(dp))
        return y


_C: dict[str, CDense | str] = {}


def c_dense(kind: str) -> CDense | str:
    """The C reference ("O3" or "O3-fast-math"), or why it is missing."""
    if kind not in _C:
        flags = ["-O3", "-march=native"] + (["-ffast-math"] if kind == "O3-fast-math" else [])
        try:
            _C[kind] = CDense(flags)
        except (RuntimeError, subprocess.CalledProcessError, OSError) as exc:
            _C[kind] = str(exc)
    return _C[kind]


# -- P-I simulate ----------------------------------------------------------------------------------
def _pi_rows(b: Bench, name: str, u: np.ndarray, m: int, kind: str, target: float, smooth: bool) -> None:
    from piezohyst.models import play

    model = model_with(m)
    refs: dict[str, Callable[[], Any]] = {
        "ours": lambda: model.simulate(u),
        "numba dense": lambda: play.pi_simulate_dense(u, model.thresholds, model.weights,
                                                      np.array(model.initial_state), 0.0, 0.0),
    }
    labels = {"numba dense": "the dense loop in numba (piezohyst's simulate before the event-driven kernel)"}
    missing = {}
    for k in ("O3", "O3-fast-math"):
        c = c_dense(k)
        if isinstance(c, str):
            missing[k] = c
            continue
        refs[f"C {k}"] = (lambda c=c: c.simulate(model, u))
        labels[f"C {k}"] = f"the same dense loop in C, gcc {c.flags}"
    y = model.simulate(u)
    for k, f in refs.items():  # every reference computes the same thing
        err = float(np.abs(f() - y).max())
        if err > 1e-9 * max(1.0, float(np.abs(y).max())):
            raise AssertionError(f"{name}: {k} differs from simulate by {err}")
    # best of 21 per side: a few ms per call, so one spell of another process's memory traffic
    # decided the ratio of a best of 6 (one run's fast-math row: 2.3x, the next 3.7x)
    t = paired(refs, rounds=7, repeat=3, clock="cpu")
    kernel = "event-driven" if play.prefers_events(u, model.thresholds) else "dense"
    turns, moves = play.event_work(u, model.thresholds)
    rec = f"{u.size:,} samples of {kind}, {m} operators"
    for k in refs:
        if k == "ours":
            continue
        if smooth:
            ratio = t[k] / t["ours"]
            b.row(f"{name}-vs-{k.lower().replace(' ', '-')}", f"P-I simulate, {rec}", ours=f"{fmt_t(t['ours'])} ({kernel})",
                  baseline=f"{labels[k]}: {fmt_t(t[k])}", ratio=ratio, ratio_is="baseline / ours (speed-up)",
                  target=f">= {target:g}x faster", met=ratio >= target,
                  note=(f"CPU time of the calling thread (both sides single-threaded), per sample: "
                        f"{t['ours'] / u.size * 1e9:.2f} ns ours, {t[k] / u.size * 1e9:.2f} ns baseline; "
                        f"the input reverses at {turns:.2g} of the samples and moves {moves:.2g} operators per sample"),
                  ours_s=t["ours"], baseline_s=t[k], kernel=kernel)
        else:
            ratio = t["ours"] / t[k]
            b.row(f"{name}-vs-{k.lower().replace(' ', '-')}", f"P-I simulate, {rec}", ours=f"{fmt_t(t['ours'])} ({kernel})",
                  baseline=f"{labels[k]}: {fmt_t(t[k])}", ratio=ratio, ratio_is="ours / baseline (slow-down)",
                  target=f"<= {target:g} (no slower than {target:g}x)", met=ratio <= target,
                  note=(f"CPU time of the calling thread (both sides single-threaded); "
                        f"white noise reverses at {turns:.2g} of the samples and moves {moves:.2g} operators per "
                        f"sample, so the automatic choice runs the {kernel} loop"),
                  ours_s=t["ours"], baseline_s=t[k], kernel=kernel)
    for k, why in missing.items():
        b.skip(f"{name}-vs-c-{k.lower()}", f"P-I simulate, {rec}", f">= {target:g}x faster" if smooth else f"<= {target:g}",
               f"C {k} reference unavailable ({why})")


@bench("pi-smooth-20")
def pi_smooth_20(b: Bench) -> None:
    _pi_rows(b, "pi-smooth-20", smooth_record(), 20, "a smooth command", 3.0, True)


@bench("pi-smooth-200")
def pi_smooth_200(b: Bench) -> None:
    _pi_rows(b, "pi-smooth-200", smooth_record(), 200, "a smooth command", 20.0, True)


@bench("pi-white-5")
def pi_white_5(b: Bench) -> None:
    _pi_rows(b, "pi-white-5", white_record(), 5, "uniform white noise", 1.3, False)


@bench("pi-white-20")
def pi_white_20(b: Bench) -> None:
    _pi_rows(b, "pi-white-20", white_record(), 20, "uniform white noise", 1.3, False)


@bench("pi-numpy-loop")
def pi_numpy_loop(b: Bench) -> None:
    from piezohyst import paper_values as pv

    model = pv.pi_model()
    u = smooth_record()
    r, w = model.thresholds, model.weights

    def numpy_loop(uu: np.ndarray) -> np.ndarray:  # a plain NumPy loop over time, vectorised over operators
        z = np.zeros(r.size)
        y = np.empty(uu.size)
        for k in range(uu.size):
            z = np.minimum(np.maximum(z, uu[k] - r), uu[k] + r)
            y[k] = w @ z
        return y

    m = 100_000
    sub = u[:m]
    if not np.allclose(numpy_loop(sub[:5000]), model.simulate(sub[:5000])):
        raise AssertionError("the NumPy loop disagrees with simulate")
    t = paired({"ours": lambda: model.simulate(u), "numpy": lambda: numpy_loop(sub)}, rounds=2, repeat=1, clock="cpu")
    base = t["numpy"] * (u.size / m)
    ratio = base / t["ours"]
    b.row("pi-numpy-loop", f"P-I simulate, {u.size:,} samples of a smooth command, the paper's 20 operators",
          ours=fmt_t(t["ours"]), baseline=f"NumPy loop over time, vectorised over the operators: {fmt_t(base)}",
          ratio=ratio, ratio_is="baseline / ours (speed-up)", target=">= 50x faster", met=ratio >= 50,
          note=(f"CPU time of the calling thread; the NumPy loop is timed on the first {m:,} samples and scaled "
                f"x{u.size // m} (its cost is linear in N)"),
          ours_s=t["ours"], baseline_s=base, baseline_measured_s=t["numpy"], baseline_samples=m)


@bench("pi-regressors")
def pi_regressors_row(b: Bench) -> None:
    """play_outputs writes the (N, n) regressor matrix: is the write itself the cost?"""
    import numba

    from piezohyst.models import play

    @numba.njit(cache=False)
    def fill(u: np.ndarray, m: int) -> np.ndarray:  # the cheapest way to produce an (N, m) matrix from u
        out = np.empty((u.shape[0], m))
        for k in range(u.shape[0]):
            for i in range(m):
                out[k, i] = u[k]
        return out

    u = smooth_record(200_000)
    r = model_with(20).thresholds
    t = paired({"ours": lambda: play.play_outputs(u, r, np.zeros(r.size)), "fill": lambda: fill(u, r.size)},
               clock="cpu")
    ratio = t["ours"] / t["fill"]
    b.row("pi-regressors", f"play_outputs: the (N, n) operator outputs, {u.size:,} samples x 20 operators",
          ours=fmt_t(t["ours"]), baseline=f"only filling a new ({u.size:,}, 20) matrix from u: {fmt_t(t['fill'])}",
          ratio=ratio, ratio_is="ours / baseline", target="<= 1.5 (the write is the cost)", met=ratio <= 1.5,
          note="CPU time of the calling thread; why play_outputs stays dense: every element is written whatever the input, so an event-driven "
               "kernel could save at most the gap between the two",
          ours_s=t["ours"], baseline_s=t["fill"])


@bench("pi-gram")
def pi_gram_row(b: Bench) -> None:
    from piezohyst.models import play

    u = smooth_record(1_000_000)
    model = model_with(20)
    y = model.simulate(u) + np.random.default_rng(0).normal(0, 1e-3, u.size)
    r = model.thresholds

    def dense() -> tuple[np.ndarray, np.ndarray]:
        z = play.play_outputs(u, r, np.zeros(r.size))
        return z.T @ z, z.T @ y

    g = play.pi_gram(u, r, y)
    gd, _ = dense()
    err = float(np.abs(g.gram[0] - gd).max() / np.abs(gd).max())
    t = paired({"ours": lambda: play.pi_gram(u, r, y), "dense": dense}, rounds=3, repeat=2)
    ratio = t["ours"] / t["dense"]
    b.row("pi-gram", f"normal equations Z'Z, Z'y of a P-I fit, {u.size:,} samples x 20 operators",
          ours=f"pi_gram (compiled, blocks of 64 rows): {fmt_t(t['ours'])}",
          baseline=f"play_outputs (the whole {u.size * 20 * 8 / 2**20:.0f} MiB matrix), then Z'Z, Z'y: {fmt_t(t['dense'])}",
          ratio=ratio, ratio_is="ours / baseline", target="<= 1 (streaming costs no time)", met=ratio <= 1.0,
          note=f"largest relative difference of Z'Z: {err:.1e}", ours_s=t["ours"], baseline_s=t["dense"])


# -- Bouc-Wen, PSO, fits ---------------------------------------------------------------------------
@bench("compensator-limits")
def compensator_limits(b: Bench) -> None:
    """The inverse P-I's commands for a million samples kept to the amplifier's range by the
    compensator (``u_range``), against what a user would write by hand: the commands unlimited,
    then ``np.clip`` (found by a helper: 190x, the limits applied sample by sample in Python)."""
    import piezohyst as ph

    model = ph.PrandtlIshlinskii(ph.equal_thresholds(20, 100.0), np.full(20, 0.02))
    x = model.simulate(smooth_record()) * 1.05  # a reference 5 % beyond the stroke: some commands clip
    free = model.compensator()
    limited = model.compensator(u_range=(0.0, 100.0))
    if not np.array_equal(limited.command(x), np.clip(free.command(x), 0.0, 100.0)):
        raise AssertionError("compensator-limits: the limited commands differ from np.clip of the free ones")
    t = paired({"ours": lambda: limited.command(x), "by hand": lambda: np.clip(free.command(x), 0.0, 100.0)},
               rounds=5, repeat=3, clock="cpu")
    ratio = t["ours"] / t["by hand"]
    b.row("compensator-limits", f"InversePIFeedforward.command with u_range, {x.size:,} samples",
          ours=fmt_t(t["ours"]), baseline=f"the commands without limits, then np.clip: {fmt_t(t['by hand'])}",
          ratio=ratio, ratio_is="ours / baseline (slow-down)", target="<= 1.3 (no slower than by hand)",
          met=ratio <= 1.3, note=f"CPU time of the calling thread; {limited.limited:,} commands clipped",
          ours_s=t["ours"], baseline_s=t["by hand"])


@bench("bw-simulate")
def bw_simulate(b: Bench) -> None:
    import piezohyst as ph
    from piezohyst import paper_values as pv
    from piezohyst.models.bouc_wen import solve_ivp_reference

    bw = pv.bouc_wen_model()
    dt = 1e-4
    u = ph.sinusoid(1.0, 2, 0.0, 100.0, dt)  # 2 s at 10 kHz
    m = u.size // 10  # solve_ivp on the first 0.2 s
    sub = u[:m]
    t = paired({"ours": lambda: bw.simulate(u, dt),
                "ivp": lambda: solve_ivp_reference(bw, sub, dt, method="LSODA", rtol=1e-8)}, rounds=3, repeat=1,
               clock="cpu")
    x_ref, _ = solve_ivp_reference(bw, sub, dt, method="LSODA", rtol=1e-8)
    diff = float(np.abs(x_ref - bw.simulate(u, dt)[:m]).max())
    base = t["ivp"] * (u.size / m)
    ratio = base / t["ours"]
    b.row("bw-simulate", "BoucWen.simulate, paper parameters, 2 s at 10 kHz", ours=fmt_t(t["ours"]),
          baseline=f"scipy solve_ivp (LSODA, rtol 1e-8): {fmt_t(base)}", ratio=ratio,
          ratio_is="baseline / ours (speed-up)", target=">= 1000x faster, max difference <= 1 nm",
          met=ratio >= 1000 and diff <= 1e-9,
          note=(f"CPU time of the calling thread; solve_ivp timed on the first {m:,} samples (0.2 s, from rest, both warm, best of 3) and scaled "
                f"x{u.size // m} (its cost is about linear in the record); max |difference| there "
                f"{diff * 1e9:.3g} nm"),
          ours_s=t["ours"], baseline_s=base, baseline_measured_s=t["ivp"], max_diff_m=diff)


def _preisach_loops() -> tuple[Callable[..., Any], Callable[..., Any]]:
    """Compiled loops over a trajectory: the Preisach inverse's Newton solve (piezohyst's) and the
    60-halving bisection it replaced (written here, as it was), the same per-sample work else."""
    from piezohyst._numba import njit
    from piezohyst.models.preisach import preisach_solve, preisach_step, preisach_value

    @njit
    def bisect(target, v_prev, alpha, beta, inv_delta, z, mu, slope, offset, steps):  # pragma: no cover
        f0 = offset + slope * v_prev + preisach_value(v_prev, alpha, beta, inv_delta, z, mu)
        gap = target - f0
        if gap == 0.0:
            v = v_prev
        else:
            a = v_prev
            b = v_prev + gap / slope
            fa = f0 - target
            fb = offset + slope * b + preisach_value(b, alpha, beta, inv_delta, z, mu) - target
            if fa > 0.0:
                a, b = b, a
                fa, fb = fb, fa
            for _ in range(steps):
                m = 0.5 * (a + b)
                fm = offset + slope * m + preisach_value(m, alpha, beta, inv_delta, z, mu) - target
                if fm == 0.0:
                    a = m
                    b = m
                    fa = 0.0
                    fb = 0.0
                    break
                if fm < 0.0:
                    a = m
                    fa = fm
                else:
                    b = m
                    fb = fm
            if fb != fa:
                v = a - fa * (b - a) / (fb - fa)
                if not (v >= min(a, b) and v <= max(a, b)):
                    v = 0.5 * (a + b)
            else:
                v = a
        preisach_step(v, alpha, beta, inv_delta, z)
        return v

    def over_trajectory(solve: Callable[..., float]) -> Callable[..., Any]:
        @njit
        def run(x, alpha, beta, inv_delta, z, mu, slope, offset):  # pragma: no cover
            out = np.empty(x.shape[0])
            v = 0.0
            for k in range(x.shape[0]):
                v = solve(x[k], v, alpha, beta, inv_delta, z, mu, slope, offset, 60)
                out[k] = v
            return out

        return run  # type: ignore[no-any-return]

    run_newton, run_bisect = over_trajectory(preisach_solve), over_trajectory(bisect)
    return run_newton, run_bisect


@bench("preisach-inverse")
def preisach_inverse(b: Bench) -> None:
    import piezohyst as ph
    from piezohyst.models.preisach import grid_size

    rng = np.random.default_rng(0)
    m = ph.Preisach(lo=-10.0, hi=110.0, weights=rng.uniform(0.0, 0.0015, grid_size(16)), slope=0.012, offset=-0.03)
    n = 50_000
    k = np.arange(n)
    u = 50.0 + 50.0 * np.sin(2 * np.pi * k / 10_000) + 0.3 * np.sin(2 * np.pi * k / 37)
    x = m.simulate(u)
    a, bb, d = m._grid()
    newton, bisect = _preisach_loops()

    def call(fn: Callable[..., Any]) -> Any:
        return fn(x, a, bb, 1.0 / d, m.initial_state(), m.weights, m.slope, m.offset)

    t = paired({"ours": lambda: call(newton), "bisect": lambda: call(bisect)}, rounds=3, repeat=1, clock="cpu")
    diff = float(np.abs(call(newton) - call(bisect)).max())
    back = float(np.abs(m.simulate(call(newton)) - x).max())
    ratio = t["bisect"] / t["ours"]
    b.row("preisach-inverse", f"Preisach inverse, 16 levels ({a.size} hysterons), {n:,} samples of a dithered sinusoid",
          ours=f"{fmt_t(t['ours'])} ({t['ours'] / n * 1e9:.0f} ns per sample, bracketed Newton)",
          baseline=f"the same loop with the 60-halving bisection it replaced: {fmt_t(t['bisect'])}", ratio=ratio,
          ratio_is="baseline / ours (speed-up)", target=">= 5x faster, the same inputs to 1e-9 V",
          met=ratio >= 5.0 and diff <= 1e-9,
          note=(f"CPU time of the calling thread, both loops compiled, best of 3 after a warm-up; the dither reverses the input "
                f"every 18 samples; max |input difference| {diff:.2g} V, max |model(input) - target| {back:.2g} um"),
          ours_s=t["ours"], baseline_s=t["bisect"], max_input_diff_V=diff)


def _preisach_columns_every_sample() -> Callable[..., Any]:
    """The model search's Preisach regressors as the kernel computed them before it skipped the
    samples inside monotone stretches: every hysteron stepped at every sample, the kept rows
    written (written here, as it was)."""
    from piezohyst._numba import njit
    from piezohyst.models.preisach import preisach_step

    @njit
    def every(v, alpha, beta, inv_delta, z, out, stride):  # pragma: no cover - compiled
        for k in range(v.shape[0]):
            preisach_step(v[k], alpha, beta, inv_delta, z)
            if k % stride == 0:
                j = k // stride
                for h in range(z.shape[0]):
                    out[j, h] = z[h]

    return every


@bench("preisach-regressors")
def preisach_regressors(b: Bench) -> None:
    from piezohyst.models.preisach import demagnetised_state, grid_thresholds, preisach_outputs_into

    n, stride = 1_000_000, 33  # the model search's stride on a 10^6-sample record (30,000 rows)
    k = np.arange(n)
    u = 50.0 - 45.0 * np.cos(2 * np.pi * k / 5_000) * np.linspace(1.0, 0.2, n)
    a, bb, d = grid_thresholds(0.0, 100.0, 16)
    z0 = demagnetised_state(a, bb, d, 0.0)
    rows = -(-n // stride)
    every = _preisach_columns_every_sample()
    got, ref = np.empty((rows, a.size)), np.empty((rows, a.size))
    every(u[:1000], a, bb, 1.0 / d, z0.copy(), ref, stride)  # compile both on a small input
    preisach_outputs_into(u[:1000], a, bb, 1.0 / d, z0.copy(), got, stride)
    t = paired({"ours": lambda: preisach_outputs_into(u, a, bb, 1.0 / d, z0.copy(), got, stride),
                "every": lambda: every(u, a, bb, 1.0 / d, z0.copy(), ref, stride)},
               rounds=3, repeat=1, warm=False, clock="cpu")
    same = bool(np.array_equal(got, ref))
    ratio = t["every"] / t["ours"]
    b.row("preisach-regressors", f"Preisach regressors of the model search, 16 levels ({a.size} hysterons), {n:,} samples "
          f"of a smooth command, every {stride}th row kept",
          ours=f"{fmt_t(t['ours'])} (kept rows and turning points stepped)",
          baseline=f"the same kernel stepping every sample, as before: {fmt_t(t['every'])}", ratio=ratio,
          ratio_is="baseline / ours (speed-up)", target=">= 5x faster, the same rows bit for bit", met=ratio >= 5.0 and same,
          note=(f"CPU time of the calling thread, both compiled, best of 3; rows identical: {same}; where the search "
                f"keeps every row (records of up to 30,000 samples, stride 1) both do the same work"),
          ours_s=t["ours"], baseline_s=t["every"])


#: Iterations of each PSO run in the pso-overhead row (the times are divided by it).
PSO_ITERS = 300


def _pso_overhead_times(b: Bench) -> dict[str, float] | None:
    """Best times of 300 iterations of ours and of pyswarms (None: pyswarms is not installed)."""
    import logging

    import piezohyst as ph

    try:
        import pyswarms as ps
    except ImportError:
        b.skip("pso-overhead", "pso_minimize overhead per iteration", "<= 0.5x its time",
               "pyswarms not installed (pip install piezohyst[bench])")
        return None
    logging.getLogger("pyswarms").setLevel(logging.ERROR)
    iters = PSO_ITERS
    lb, ub = np.full(7, -5.0), np.full(7, 5.0)

    def f(x: np.ndarray) -> np.ndarray:
        return (x**2).sum(axis=1)

    def theirs() -> None:
        opt = ps.single.GlobalBestPSO(n_particles=50, dimensions=7, bounds=(lb, ub),
                                      options={"c1": 1.49618, "c2": 1.49618, "w": 0.7298})
        opt.optimize(f, iters=iters, verbose=False)

    return paired({"ours": lambda: ph.pso_minimize(f, [(-5.0, 5.0)] * 7, n_particles=50, max_iter=iters, seed=0),
                   "pyswarms": theirs}, rounds=4, repeat=2)


@bench("pso-overhead")
def pso_overhead(b: Bench) -> None:
    import logging

    # pyswarms' reporter (made as its modules load, and by each optimiser) hangs a file handler on
    # the root logger, writing report.log into the working directory and, at level INFO, every
    # later row's library logs into it: import and run it in a scratch folder, and take the
    # handlers and the level off again
    root = logging.getLogger()
    level, handlers, here = root.level, list(root.handlers), os.getcwd()
    with tempfile.TemporaryDirectory(prefix="piezohyst-bench-pyswarms-") as scratch:
        os.chdir(scratch)
        try:
            t = _pso_overhead_times(b)
        finally:
            os.chdir(here)
            for h in [h for h in root.handlers if h not in handlers]:
                root.removeHandler(h)
                h.close()
            root.setLevel(level)
    if t is None:
        return
    ours, base = t["ours"] / PSO_ITERS, t["pyswarms"] / PSO_ITERS
    ratio = ours / base
    b.row("pso-overhead", "pso_minimize overhead per iteration, 50 particles, 7-D, trivial objective",
          ours=fmt_t(ours), baseline=f"pyswarms GlobalBestPSO, same settings, quiet: {fmt_t(base)}", ratio=ratio,
          ratio_is="ours / baseline", target="<= 0.5x its time", met=ratio <= 0.5, ours_s=ours, baseline_s=base)


def _rig_record(seconds: float = 2.0):
    import piezohyst as ph

    rig = ph.VirtualRig(seed=0)
    return rig, rig.excite(ph.sinusoid(1.0, seconds, 0.0, 100.0, rig.dt))


@bench("fit-pi")
def fit_pi_rows(b: Bench) -> None:
    from scipy.optimize import lsq_linear, nnls

    import piezohyst as ph
    from piezohyst.identify import pi_regressors

    _, ds = _rig_record()  # 20,000 samples
    u, y = ds.u, ds.y
    lsq = ph.fit_pi(u, y, n=20, method="lsq")
    r = lsq.model.thresholds
    margin = float(lsq.info["margin"])

    # the same problem (weights through their partial sums s_i >= margin, a free offset) as a
    # user would pose it to scipy, regressors included in the time
    def design() -> np.ndarray:
        z = pi_regressors(u, r)
        zd = z.copy()
        zd[:, :-1] -= z[:, 1:]
        return zd

    def via_lsq_linear() -> np.ndarray:
        zd = design()
        a = np.hstack([zd, np.ones((u.size, 1))])
        lb = np.r_[np.full(r.size, margin), -np.inf]
        return np.asarray(lsq_linear(a, y, bounds=(lb, np.inf)).x)

    def via_nnls() -> np.ndarray:  # s = margin + s', offset = c+ - c-, all >= 0
        zd = design()
        a = np.hstack([zd, np.ones((u.size, 1)), -np.ones((u.size, 1))])
        sol, _ = nnls(a, y - zd.sum(axis=1) * margin, maxiter=50 * a.shape[1])
        return np.r_[sol[: r.size] + margin, sol[r.size] - sol[r.size + 1]]

    def rmse_of(x: np.ndarray) -> float:
        zd = design()
        return float(np.sqrt(np.mean((zd @ x[: r.size] + x[r.size] - y) ** 2)))

    t = paired({"ours": lambda: ph.fit_pi(u, y, n=20, method="lsq"), "lsq_linear": via_lsq_linear,
                "nnls": via_nnls, "pso": lambda: ph.fit_pi(u, y, n=20, method="pso", seed=0)}, rounds=3, repeat=2)
    rm = {"ours": lsq.rmse, "lsq_linear": rmse_of(via_lsq_linear()), "nnls": rmse_of(via_nnls()),
          "pso": ph.fit_pi(u, y, n=20, method="pso", seed=0).rmse}
    what = "fit_pi(method=\"lsq\"), 20,000 samples of the virtual rig, 20 operators"
    for k, label in (("lsq_linear", "scipy.optimize.lsq_linear (default trf) on the same bounded problem"),
                     ("nnls", "scipy.optimize.nnls on the same problem, shifted to x >= 0")):
        ratio = t[k] / t["ours"]
        same = abs(rm[k] - rm["ours"]) <= 1e-6 * rm["ours"] + 1e-12
        b.row(f"fit-pi-vs-{k.replace('_', '-')}", what, ours=f"{fmt_t(t['ours'])} (RMSE {rm['ours'] * 1e3:.4f} nm)",
              baseline=f"{label}: {fmt_t(t[k])} (RMSE {rm[k] * 1e3:.4f} nm)", ratio=ratio,
              ratio_is="baseline / ours (speed-up)", target=">= 1x faster, same optimum (RMSE within 1e-6)",
              met=ratio >= 1 and same, note="regressor matrix included on both sides",
              ours_s=t["ours"], baseline_s=t[k], rmse_ours=rm["ours"], rmse_baseline=rm[k])
    ratio = t["pso"] / t["ours"]
    b.row("fit-pi-vs-pso", what, ours=f"{fmt_t(t['ours'])} (RMSE {rm['ours'] * 1e3:.2f} nm)",
          baseline=f"fit_pi(method=\"pso\"), 40 x 200: {fmt_t(t['pso'])} (RMSE {rm['pso'] * 1e3:.2f} nm)",
          ratio=ratio, ratio_is="baseline / ours (speed-up)", target=">= 1x faster and RMSE no worse",
          met=ratio >= 1 and rm["ours"] <= rm["pso"] * (1 + 1e-9),
          note="the PSO baseline evaluates eq. (9) through the 20 x 20 Gram matrix, not by simulating each particle",
          ours_s=t["ours"], baseline_s=t["pso"], rmse_ours=rm["ours"], rmse_baseline=rm["pso"])


@bench("fit-pi-delay-auto")
def fit_pi_delay_auto(b: Bench) -> None:
    import piezohyst as ph

    _, ds = _rig_record(10.0)  # 100,000 samples
    # a few ms per call, the size of one scheduler time slice of another process on a busy
    # machine: best of 15 each (best of 2 was a draw between the quiet and the interrupted call)
    t = paired({"auto": lambda: ph.fit_pi(ds.u, ds.y, delay="auto"), "one": lambda: ph.fit_pi(ds.u, ds.y)},
               rounds=5, repeat=3)
    ratio = t["auto"] / t["one"]
    b.row("fit-pi-delay-auto", "fit_pi(delay=\"auto\") (delays 0..10), 100,000 samples of the virtual rig",
          ours=fmt_t(t["auto"]), baseline=f"one fit_pi at a given delay: {fmt_t(t['one'])}", ratio=ratio,
          ratio_is="ours / baseline", target="<= 2x one fit", met=ratio <= 2.0, ours_s=t["auto"], baseline_s=t["one"])


@bench("fit-pi-memory")
def fit_pi_memory(b: Bench) -> None:
    n, cap, target = 10_000_000, 4 * 2**30, 1.5 * 2**30
    code = f"""
import json, resource, numpy as np, piezohyst as ph
t = np.arange({n}) * 1e-4
u = 50 + (30 + 15 * np.sin(2 * np.pi * 0.013 * t)) * np.sin(2 * np.pi * t) + 4 * np.sin(2 * np.pi * 3.3 * t + 1)
del t
y = ph.PrandtlIshlinskii(ph.equal_thresholds(20, 100.0), np.linspace(0.04, 0.005, 20)).simulate(u)
y += np.random.default_rng(0).normal(0, 0.005, y.size)
try:
    fit = ph.fit_pi(u, y, n=20)
    status, rmse = "ok", fit.rmse
except MemoryError:
    status, rmse = "MemoryError", None
print(json.dumps({{"status": status, "rmse": rmse, "maxrss_kib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}}))
"""
    res = peak_rss_of_code(code, cap_bytes=cap)
    got = res.get("result", {})
    status = got.get("status", f"exit code {res['returncode']}")
    peak = res["peak_bytes"]
    if status == "ok":
        note = f"fit RMSE {got['rmse'] * 1e3:.3f} nm"
        met = peak <= target
        ours = fmt_b(peak)
    else:
        note = (f"the fit did not finish within the {fmt_b(cap)} address-space cap the bench sets to protect the "
                f"machine ({status}; the regressor matrix alone is {n * 21 * 8 / 2**30:.1f} GiB): needs the streamed "
                f"normal equations (piezohyst.models.play.pi_gram) in fit_pi")
        met = False
        ours = f"> {fmt_b(cap)} cap" if status == "MemoryError" else f"failed ({status})"
    b.row("fit-pi-memory", f"fit_pi, {n:,} samples, 20 operators: peak resident memory", ours=ours,
          baseline=f"the target: {fmt_b(target)}", ratio=(peak / target) if status == "ok" else None,
          ratio_is="peak / target", target="peak <= 1.5 GiB", met=met, note=note, peak_bytes=peak, status=status)


@bench("fit-bw")
def fit_bw(b: Bench) -> None:
    import piezohyst as ph

    rig, ds = _rig_record()  # 20,000 samples
    # warm-up (compilation) on a short record, so that the full fit need not run an extra time
    model = ph.fit_bouc_wen(ds.u[:2000], ds.y[:2000], rig.dt, max_iter=2, polish=False).model
    model.simulate(ds.u, rig.dt)
    k = 402  # scalar simulations timed; 8040 = 40 x 201 evaluations
    t = paired({"fit": lambda: ph.fit_bouc_wen(ds.u, ds.y, rig.dt, seed=0, n_particles=40, max_iter=200, polish=False),
                "sims": lambda: [model.simulate(ds.u, rig.dt) for _ in range(k)]}, rounds=2, repeat=1, warm=False)
    base = t["sims"] * 8040 / k
    ratio = t["fit"] / base
    b.row("fit-bw", "fit_bouc_wen, 40 particles x 200 iterations, 20,000 samples", ours=fmt_t(t["fit"]),
          baseline=f"8,040 scalar BoucWen.simulate calls on the same record: {fmt_t(base)}", ratio=ratio,
          ratio_is="ours / baseline", target="<= 0.25x", met=ratio <= 0.25,
          note=f"the scalar simulations timed {k} at a time and scaled x{8040 / k:g}",
          ours_s=t["fit"], baseline_s=base, baseline_measured_s=t["sims"])


@bench("realtime-step")
def realtime_step(b: Bench) -> None:
    import piezohyst as ph
    from piezohyst import paper_values as pv

    model = ph.PrandtlIshlinskii(ph.equal_thresholds(20, 100.0), np.array(pv.PI_WEIGHTS) * 0.0225)
    ff = ph.InversePIFeedforward(model)
    pid = ph.PID(kp=0.1, ki=500.0, kd=1e-5, dt=1e-4)
    ref = ph.sinusoid(5.0, 1, 0.25, 2.25, 1e-4)
    samples = []
    for _ in range(3):
        ff.reset()
        pid.reset()
        y = 0.0
        for r in ref:
            t0 = time.perf_counter_ns()
            u = ff.step(r + pid.step(r - y))
            samples.append(time.perf_counter_ns() - t0)
            y = 0.0225 * u
    s = np.array(samples[len(ref):]) * 1e-9  # the first pass warms up
    med, p99 = float(np.median(s)), float(np.percentile(s, 99))
    ratio = 100e-6 / med
    b.row("realtime-step", "one real-time control step (inverse-P-I feedforward + PID), called from Python",
          ours=f"{fmt_t(med)} median", baseline="the 100 µs period of a 10 kHz loop", ratio=ratio,
          ratio_is="budget / median (headroom)", target=">= 20x headroom", met=ratio >= 20,
          note=f"99th percentile {fmt_t(p99)}", median_s=med, p99_s=p99)


@bench("commission")
def commission_row(b: Bench) -> None:
    import piezohyst as ph

    class Recording:
        """The VirtualRig, recording every call so that the plant's own time can be replayed."""

        def __init__(self, plant: Any):
            self.plant, self.calls = plant, []
            self.dt, self.u_range = plant.dt, plant.u_range

        def reset(self) -> None:
            self.calls.append(("reset", None))
            self.plant.reset()

        def step(self, u: float) -> float:
            self.calls.append(("step", u))
            return self.plant.step(u)

        def excite(self, u: Any) -> Any:
            self.calls.append(("excite", np.array(u, dtype=float)))
            return self.plant.excite(u)

    rec = Recording(ph.VirtualRig(seed=0))
    t0 = time.perf_counter()
    ph.commission(rec)
    total = time.perf_counter() - t0
    calls = rec.calls

    def replay() -> None:
        rig = ph.VirtualRig(seed=0)
        for kind, v in calls:
            if kind == "step":
                rig.step(v)
            elif kind == "excite":
                rig.excite(v)
            else:
                rig.reset()

    inside = paired({"replay": replay}, rounds=1, repeat=3)["replay"]
    outside = total - inside
    ratio = outside / inside
    n_steps = sum(1 for c in calls if c[0] == "step")
    b.row("commission", "commission() on the VirtualRig: time outside the plant's own calls",
          ours=f"{fmt_t(outside)} outside", baseline=f"inside the plant (its {n_steps:,} steps and excitations replayed): "
          f"{fmt_t(inside)}", ratio=ratio, ratio_is="outside / inside", target="<= 1", met=ratio <= 1.0,
          note=f"one commission() timed in full ({fmt_t(total)}); the plant's calls replayed best of 3",
          total_s=total, inside_s=inside, outside_s=outside)


# -- whole commands against the previous release, in the same run ---------------------------------
#: The commit the 0.2 round started from (piezohyst 0.1.0 as it was): checked out into a temporary
#: folder with ``git archive`` and run with the same interpreter, so both sides share everything
#: but piezohyst's own code.
BASELINE_COMMIT = "cb9a0f0"


def _baseline_src() -> Path | str:
    """A checkout of :data:`BASELINE_COMMIT`'s ``src`` (cached under benchmarks/out), or why not."""
    dest = OUT / f"baseline-{BASELINE_COMMIT}"
    if (dest / "src" / "piezohyst").is_dir():
        return dest / "src"
    if shutil.which("git") is None:
        return "git is not installed"
    try:
        archive = subprocess.run(["git", "-C", str(HERE.parent), "archive", BASELINE_COMMIT, "src"],
                                 capture_output=True, check=True).stdout
    except subprocess.CalledProcessError as exc:
        return f"git archive {BASELINE_COMMIT} failed (a shallow clone?): {exc.stderr.decode(errors='replace').strip()[:120]}"
    import io
    import tarfile

    tmp = Path(tempfile.mkdtemp(dir=OUT.parent if OUT.exists() else None))
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(tmp, filter="data")
    OUT.mkdir(exist_ok=True)
    os.replace(tmp, dest)
    return dest / "src"


def _command_rows(b: Bench, name: str, what: str, args: list[str], target: float, rounds: int) -> None:
    old = _baseline_src()
    if isinstance(old, str):
        b.skip(name, what, f">= {target}x", old)
        return
    run = [sys.executable, "-c", "import sys; from piezohyst.cli import main; sys.exit(main(sys.argv[1:]))", *args]
    with tempfile.TemporaryDirectory() as tmp:
        # both sides with their bytecode caches, as installed (as the cli rows): the warm-up round
        # writes them, where a shell that sets PYTHONDONTWRITEBYTECODE would have each side compile
        # its modules on every run
        envs = {"ours": _env(PYTHONPATH=str(SRC)), "0.1.0": _env(PYTHONPATH=str(old))}
        for env in envs.values():
            env.pop("PYTHONDONTWRITEBYTECODE", None)
        best = {k: np.inf for k in envs}
        for i in range(rounds + 1):  # round 0 warms up (numba's cache, the file cache)
            for k, env in envs.items():
                t = time.perf_counter()
                subprocess.run(run + (["--out", str(Path(tmp) / f"{k}{i}")] if "reproduce" in args else []), env=env,
                               cwd=tmp, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
                if i:
                    best[k] = min(best[k], time.perf_counter() - t)
    ratio = best["0.1.0"] / best["ours"]
    b.row(name, what, ours=f"{fmt_t(best['ours'])}", baseline=f"piezohyst 0.1.0 ({BASELINE_COMMIT}): {fmt_t(best['0.1.0'])}",
          ratio=ratio, ratio_is="0.1.0 / ours (wall time)", target=f">= {target:g}x", met=ratio >= target,
          note=f"wall time of the whole command, best of {rounds} interleaved rounds after a warm-up each "
               "(which writes both sides' bytecode caches)",
          ours_s=best["ours"], baseline_s=best["0.1.0"])


@bench("cmd-reproduce")
def cmd_reproduce(b: Bench) -> None:
    _command_rows(b, "cmd-reproduce", "piezohyst reproduce (the paper's experiment, make demo)", ["reproduce"],
                  3.0, rounds=2)


@bench("cmd-benchmark-bouc-wen")
def cmd_benchmark_bw(b: Bench) -> None:
    _command_rows(b, "cmd-benchmark-bouc-wen", "piezohyst benchmark bouc-wen (identification benchmark)",
                  ["benchmark", "bouc-wen", "--json", "--data",
                   str(HERE.parent / "data" / "bouc-wen-benchmark" / "bouc-wen.mat")], 3.0, rounds=2)


@bench("fleet")
def fleet_row(b: Bench) -> None:
    try:
        import distributed  # noqa: F401
    except ImportError:
        b.skip("fleet", "fleet identification on 2 local Dask workers", ">= 1.6x", "dask[distributed] not installed")
        return
    sys.path.insert(0, str(HERE))
    from bench_fleet import bench_fleet

    r = bench_fleet()
    b.row("fleet", "fleet.identify_many: 40 P-I records on a 2-worker LocalCluster", ours=r["ours"],
          baseline=r["baseline"], ratio=r["ratio"], ratio_is="serial / cluster", target=r["target"], met=r["met"],
          note=r["note"], ceiling=r.get("ceiling"))


@bench("read-csv")
def read_csv(b: Bench) -> None:
    import piezohyst as ph

    try:
        import pandas as pd
    except ImportError:
        b.skip("read-csv", "load_dataset on a 2-million-row CSV", "within 2x of pandas.read_csv", "pandas missing")
        return
    n = 2_000_000
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "record.csv"
        rng = np.random.default_rng(0)
        t = np.arange(n) * 1e-4
        pd.DataFrame({"t": t, "u": 50 + 50 * np.sin(t), "y": 2 * np.sin(t) + rng.normal(0, 1e-3, n)}).to_csv(
            path, index=False, float_format="%.9g")
        t0 = time.perf_counter()
        ds = ph.load_dataset(path)
        once = time.perf_counter() - t0
        if ds.u.size != n:
            raise AssertionError("load_dataset read the wrong number of rows")
        fns = {"pandas": lambda: pd.read_csv(path)}
        if once < 5.0:
            fns["ours"] = lambda: ph.load_dataset(path)
        t_ = paired(fns, rounds=2, repeat=2)
        ours = t_.get("ours", once)
        ratio = ours / t_["pandas"]
        b.row("read-csv", f"load_dataset, a {n:,}-row CSV (t, u, y)", ours=fmt_t(ours),
              baseline=f"pandas.read_csv of the same file: {fmt_t(t_['pandas'])}", ratio=ratio,
              ratio_is="ours / baseline", target="<= 2x pandas", met=ratio <= 2.0,
              note="" if "ours" in t_ else f"load_dataset took {once:.1f} s: timed once, not best-of",
              ours_s=ours, baseline_s=t_["pandas"])


# -- start-up and compilation ----------------------------------------------------------------------
@bench("cli-help")
def cli_help(b: Bench) -> None:
    # both sides with their bytecode caches, as installed: the standard library ships compiled, and
    # the warm-up run writes ours (a shell with PYTHONDONTWRITEBYTECODE set would otherwise have our
    # side compile its 100 kB of CLI modules on every run, measured 150 against 100 ms)
    env = _env()
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    py = sys.executable
    cmds = {"argparse": [py, "-c", "import argparse"],
            "help": [py, "-c", "import sys; from piezohyst.cli import main; sys.argv = ['piezohyst', '--help']; main()"],
            "identify": [py, "-c", ("import sys; from piezohyst.cli import main; "
                                    "sys.argv = ['piezohyst', 'identify', '--help']; main()")]}
    try:
        t = cpu_of_command(cmds, env=env, rounds=3)
    except subprocess.CalledProcessError as exc:
        b.skip("cli-help", "piezohyst --help CPU", "<= 5x", f"a command failed: {exc}")
        return
    for k, label in (("help", "piezohyst --help"), ("identify", "piezohyst identify --help")):
        ratio = t[k] / t["argparse"]
        b.row(f"cli-{k}", f"{label}: CPU time (user + system) of the whole process", ours=fmt_t(t[k]),
              baseline=f"python -c \"import argparse\": {fmt_t(t['argparse'])}", ratio=ratio,
              ratio_is="ours / baseline", target="<= 5x", met=ratio <= 5.0,
              note="best of 3 runs each, interleaved, after a warm-up run (which writes the bytecode cache)",
              ours_s=t[k], baseline_s=t["argparse"])


COMPILE_WORKLOAD = r"""
import json, pkgutil, importlib, time, warnings
t0 = time.perf_counter()
import numpy as np, numba, piezohyst as ph
from piezohyst import paper_values as pv
from piezohyst.models import play
warnings.simplefilter("ignore")
dt = 1e-3
u = ph.sinusoid(1.0, 1, 0.0, 100.0, dt)
noise = np.random.default_rng(0).uniform(0, 100, 5000)
pi = pv.pi_model()
pi.simulate(u); pi.simulate(noise); pi.operator_outputs(u); pi.stepper().step(1.0); pi.inverse().simulate(pi.simulate(u))
play.pi_gram(u, pi.thresholds, pi.simulate(u), delays=[0, 2]); play.pi_simulate_events(noise, pi.thresholds[::-1].copy(), pi.weights, np.zeros(20), 0.0, 0.0)
play.pi_simulate_dense(u, pi.thresholds, pi.weights, np.zeros(20), 0.0, 0.0)
bw = pv.bouc_wen_model()
x = bw.simulate(u, dt); bw.stepper(dt).step(1.0); bw.hysteresis(u)
rig = ph.VirtualRig(); ds = rig.excite(ph.sinusoid(1.0, 0.2, 0.0, 100.0, rig.dt)); rig.step(1.0)
ph.fit_bouc_wen(u[:200], x[:200] * 1e6, dt, max_iter=1, n_particles=4, polish=False)
ff = ph.InversePIFeedforward(pi); ff.command(u[:100]); ff.step(1.0)
bf = ph.BoucWenFeedforward(bw); bf.command(x[:100] * 1e6); bf.step(1.0)
from piezohyst.identify import fit_rate_pi
rp = fit_rate_pi(ds.u, ds.y, rig.dt, delay=0).model
rp.simulate(ds.u[:100]); rp.inverse_stepper().step(1.0)
from piezohyst.models.bouc_wen_structural import StructuralBoucWen
sbw = StructuralBoucWen(m=2.0, c=10.0, k=5e4, alpha=5e4, beta=1e3, gamma=0.8, delta=-1.1)
ys = sbw.simulate(np.sin(np.arange(64) * 0.1), 750.0, substeps=2)
try:  # the swarm kernel of the Bouc-Wen benchmark (experiments/boucwen_benchmark.py), called as it does
    from piezohyst.models.bouc_wen_structural import fine_input, structural_swarm_rmse
    structural_swarm_rmse(np.tile(sbw.kernel_params(), (2, 1)), fine_input(np.sin(np.arange(64) * 0.1), 2), 1 / 1500, 2, ys, 0)
except Exception:
    pass  # a changed signature: the kernel shows up as not exercised
# the rest of the public paths; each guarded the same way
def _try(f):
    try:
        f()
    except Exception:
        pass
def structural_sensitivities_call():
    from piezohyst.models.bouc_wen_structural import fine_input, structural_sensitivities
    structural_sensitivities(sbw.kernel_params(), fine_input(np.sin(np.arange(64) * 0.1), 2), 1 / 1500, 2)
_try(structural_sensitivities_call)
yp = pi.simulate(u)
_try(lambda: ph.fit_pi(u, yp, method="lsq"))                                   # operators, strict simulate
_try(lambda: ph.fit_pi(u, yp, method="pso", n_particles=4, max_iter=2, seed=0))  # the paper's swarm
pr = ph.Preisach(lo=0.0, hi=100.0, weights=np.full(ph.models.preisach.grid_size(6), 0.002), slope=0.02)
_try(lambda: pr.compensator(None).command(pr.simulate(u)[:200]))
_try(lambda: pr.stepper().step(1.0))
_try(lambda: pr.hysteron_outputs(u))
from piezohyst.plant import rate_limited
_try(lambda: rate_limited(u, 0.5))                                          # commission's slew estimate
_try(lambda: ph.fit_pi(u, yp, delay="auto"))                                   # streamed Gram, every delay
_try(lambda: ph.track(rig, ph.sinusoid(5.0, 1, 0.3, 2.2, rig.dt), feedforward=ph.InversePIFeedforward(pv.pi_model()),
                      feedback=ph.PID(ki=100.0, dt=rig.dt)))                    # the paper's loop, compiled
_try(lambda: ph.fit_model(u, yp, dt, kind="preisach", delay=0))                # Preisach design
_try(lambda: ph.fit_model(u, bw.hysteresis(u), dt, kind="bouc-wen-hysteresis", delay=0))
_try(lambda: ph.fit_model(u, 1e6 * (bw.d1 * u - bw.hysteresis(u)), dt, kind="generalized-duhem", delay=0)
      .model.compensator().command(1e6 * (bw.d1 * u - bw.hysteresis(u))[:200]))  # Duhem design, band, inverse
_try(lambda: ph.commission(ph.VirtualRig(seed=0)).track(ph.sinusoid(5.0, 2, 0.3, 2.2, 1e-4)))  # compiled loops, guard
elapsed = time.perf_counter() - t0
for m in pkgutil.walk_packages(ph.__path__, "piezohyst."):
    if m.name.endswith("__main__"):  # running it would run the command line
        continue
    try:
        importlib.import_module(m.name)
    except Exception:
        pass
import sys
kernels = {}
for name, mod in list(sys.modules.items()):
    if not name.startswith("piezohyst"):
        continue
    for attr, obj in vars(mod).items():
        if isinstance(obj, numba.core.registry.CPUDispatcher) and obj.py_func.__module__ == name:
            kernels[f"{name}.{attr}"] = len(obj.signatures)
print(json.dumps({"elapsed": elapsed, "kernels": kernels}))
"""


@bench("compile")
def compile_cost(b: Bench) -> None:
    """What a first run pays for compiling every kernel, and what a second run pays (cache)."""
    with tempfile.TemporaryDirectory() as cache:
        env = _env(NUMBA_CACHE_DIR=cache)
        runs = []
        for _ in range(2):
            p = subprocess.run([sys.executable, "-c", COMPILE_WORKLOAD], env=env, capture_output=True, text=True,
                               check=False)
            if p.returncode:
                b.skip("compile", "numba compilation of every kernel", ">= 5x", f"the workload failed: "
                       f"{p.stderr.strip().splitlines()[-1] if p.stderr.strip() else p.returncode}")
                return
            runs.append(json.loads(p.stdout.strip().splitlines()[-1]))
    cold, warm = runs[0]["elapsed"], runs[1]["elapsed"]
    kernels = runs[0]["kernels"]
    missed = sorted(k for k, n in kernels.items() if n == 0)
    ratio = cold / warm
    b.row("compile", "numba kernels: first run (empty cache, compiles) vs second run (loads the on-disk cache)",
          ours=f"second run {fmt_t(warm)}", baseline=f"first run {fmt_t(cold)}", ratio=ratio,
          ratio_is="first / second", target=">= 5x (the cache works)", met=ratio >= 5,
          note=(f"import and one call of every public path (simulate both ways, operator_outputs, pi_gram, steppers, "
                f"rig, fit_bouc_wen, fit_rate_pi, feedforwards, structural Bouc-Wen and its sensitivities, fit_pi "
                f"by least squares, by PSO and at every delay, Preisach simulate, inverse and hysterons, the slew "
                f"estimate's rate limiter, fit_model of "
                f"Preisach, Bouc-Wen hysteresis and generalized Duhem models (and a Duhem inverse), the paper's PID loop, commission and track on the "
                f"VirtualRig) in a fresh process with "
                f"NUMBA_CACHE_DIR at an empty temporary directory; {len(kernels) - len(missed)} of {len(kernels)} "
                f"kernels compiled" + (f"; not exercised: {', '.join(missed)}" if missed else "")),
          cold_s=cold, warm_s=warm, kernels=kernels)


# -- the run ---------------------------------------------------------------------------------------
def machine() -> dict[str, Any]:
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

    gcc = shutil.which("gcc") or shutil.which("cc")
    gcc_v = (subprocess.run([gcc, "--version"], capture_output=True, text=True, check=False).stdout.splitlines()[0]
             if gcc else None)
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "numba": numba.__version__, "gcc": gcc_v, "platform": platform.platform(),
            "load_average": os.getloadavg()}


def main(argv: list[str]) -> int:
    sys.path.insert(0, str(SRC))
    from rich.console import Console
    from rich.table import Table

    con = Console(width=max(shutil.get_terminal_size((160, 24)).columns, 160), highlight=False, markup=False)
    chosen = [(n, f) for n, f in REGISTRY if not argv or any(n.startswith(a) for a in argv)]
    b = Bench()
    t_start = time.perf_counter()
    for name, fn in chosen:
        con.print(f"running {name} ...")
        t0 = time.perf_counter()
        try:
            fn(b)
        except Exception as exc:  # a broken row is reported as such, the others still run
            traceback.print_exc()
            b.row(name, f"{name} (crashed)", ours="-", baseline="-", ratio=None, ratio_is="-", target="-", met=False,
                  note=f"the benchmark itself failed: {type(exc).__name__}: {exc}")
        con.print(f"  ({time.perf_counter() - t0:.1f} s)")
    info = machine()
    table = Table(title=f"piezohyst benchmarks - {info['cpu']}, {info['cores']} cores, Python {info['python']}, "
                        f"numba {info['numba']}")
    for c in ("name", "what", "ours", "baseline (same run)", "ratio", "target", "met?"):
        table.add_column(c, overflow="fold")
    for r in b.rows:
        table.add_row(r["name"], r["what"], r["ours"], r["baseline"],
                      "-" if r["ratio"] is None else f"{r['ratio']:.3g} ({r['ratio_is']})", r["target"],
                      {True: "yes", False: "NO", None: "-"}[r["met"]])
    con.print(table)
    for r in b.rows:
        if r["note"]:
            con.print(f"  {r['name']}: {r['note']}")
    total = time.perf_counter() - t_start
    n_met = sum(r["met"] is True for r in b.rows)
    n_missed = sum(r["met"] is False for r in b.rows)
    con.print(f"  {n_met} rows met, {n_missed} missed, {len(b.rows) - n_met - n_missed} not run; took {total:.0f} s")
    from piezohyst._fileio import atomic_write_text, producer

    OUT.mkdir(exist_ok=True)
    doc = {"producer": producer(), "machine": info, "rows": b.rows, "total_s": total,
           "selected": argv or "all"}
    path = atomic_write_text(OUT / "results.json", json.dumps(doc, indent=2) + "\n", force=True)
    con.print(f"  wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
