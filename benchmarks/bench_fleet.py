"""Bench row: fleet identification of 40 actuators on 2 local Dask workers against a serial loop.

``bench_fleet()`` returns one row (``name``, ``ours``, ``baseline``, ``ratio``, ``target``,
``met``, ``note``) for the bench runner; ``python benchmarks/bench_fleet.py`` prints it as JSON.

What is timed, in the same run: ``ph.fleet.identify_many(batch, client=...)`` over 40 simulated
P-I actuators (CSV records of 20,000 samples: a 1 Hz, 0-100 V sinusoid for 10 s at 2 kHz, the
record size of the issue's "68 ms per P-I fit" figure), each record read, fitted with
``fit_pi`` and measured (loop figures), first serially (``client="serial"``, the baseline: the
same function in a loop, in one process spawned like a worker; the same loop in the bench's own
process is reported beside it) and then on a LocalCluster of 2 worker processes of one thread
each. Both are warmed up once (imports, numba's cached kernels on every worker), then
timed in 5 alternating rounds (as many as the other rows' paired timings), best of each. The cluster's start-up is excluded from the ratio and
reported in the note; so are the CPU times (serial process; workers; client and scheduler),
the machine's load and its ceiling in the same rounds (the speed-up of embarrassingly parallel
pure-Python arithmetic on the same number of processes), since the machine is shared and no
code can beat that ceiling. No model files are
written (``out=None``): the row measures the fits' throughput, not the client's disk.
"""

from __future__ import annotations

import json
import os
import tempfile
import time

N_ACTUATORS = 40
WORKERS = 2
TARGET = 1.6
#: Iterations of the pure-Python loop that measures the machine's ceiling (~0.4 s on an idle core).
SPIN = 5_000_000


def _spin(n: int) -> int:
    """Pure CPU work with nothing shared: what ``workers`` processes can gain at best right now."""
    s = 0
    for i in range(n):
        s += i * i
    return s


def _serial_in_fresh_process(folder: str) -> float:
    """The serial loop timed in a process started like a Dask worker (spawned, numba's cached
    kernels, one thread): seconds for ``identify_many(folder, client="serial")``."""
    import piezohyst as ph

    t = time.perf_counter()
    ph.fleet.identify_many(folder, client="serial")
    return time.perf_counter() - t


def bench_fleet(*, n_actuators: int = N_ACTUATORS, workers: int = WORKERS, rounds: int = 5) -> dict:
    import numpy as np
    import psutil  # a dependency of distributed

    import piezohyst as ph

    def cpu(procs):
        return sum(sum(p.cpu_times()[:2]) for p in procs)

    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    load_before = os.getloadavg()[0]
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))
    list(pool.map(_spin, [1000] * workers))

    def ceiling() -> float:
        t = time.perf_counter()
        for _ in range(workers):
            _spin(SPIN)
        one = time.perf_counter() - t
        t = time.perf_counter()
        list(pool.map(_spin, [SPIN] * workers))
        return one / (time.perf_counter() - t)

    # the serial baseline runs in a process of its own started like the workers: the bench's own
    # process, warmed by every row before this one, ran the same fits faster than any fresh process
    # does (in one `make bench`: 0.33 s against 0.41 s for 40 records alone), which no worker is
    alone = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
    with tempfile.TemporaryDirectory(prefix="piezohyst-bench-fleet-") as tmp, pool, alone:
        ph.fleet.write_simulated_batch(tmp, n_actuators, seed=0, fs=2000.0, cycles=10)
        t0 = time.perf_counter()
        client = ph.fleet.local_cluster(workers)
        startup = time.perf_counter() - t0
        try:
            me = psutil.Process()
            workers_ = [psutil.Process(pid) for pid in client.run(os.getpid).values()]
            serial = ph.fleet.identify_many(tmp, client="serial")  # warm-up, and the reference figures
            parallel = ph.fleet.identify_many(tmp, client=client)  # warm-up of every worker
            alone.submit(_serial_in_fresh_process, tmp).result()  # warm-up of the serial process
            ts, ts_here, tc, cpu_s, cpu_w, cpu_c, ceil = [], [], [], [], [], [], []
            runs = [parallel]
            for _ in range(rounds):
                ceil.append(ceiling())
                c0, t = cpu([me]), time.perf_counter()
                ph.fleet.identify_many(tmp, client="serial")
                ts_here.append(time.perf_counter() - t)
                cpu_s.append(cpu([me]) - c0)
                ts.append(alone.submit(_serial_in_fresh_process, tmp).result())
                c0, w0, t = cpu([me]), cpu(workers_), time.perf_counter()
                parallel = ph.fleet.identify_many(tmp, client=client)
                runs.append(parallel)
                tc.append(time.perf_counter() - t)
                cpu_c.append(cpu([me]) - c0)
                cpu_w.append(cpu(workers_) - w0)
        finally:
            client.close()
            client.cluster.close()
    want = serial["fit_rmse_um"].to_numpy()
    odd = []  # what differs from the serial fits, round by round (round 0: the warm-up)
    for r, run in enumerate(runs):
        got = run["fit_rmse_um"].to_numpy()
        bad = (run["status"] != "ok").to_numpy() | ~((got == want) | (np.isnan(got) & np.isnan(want)))
        if bad.any():
            errors = "; ".join(sorted(set(run.loc[run["status"] != "ok", "error"].astype(str))))[:200]
            odd.append(f"round {r}: {int(bad.sum())} record(s) differ{' (' + errors + ')' if errors else ''}")
    same = not odd and bool((serial["status"] == "ok").all())
    best_s, best_c = min(ts), min(tc)
    ratio = best_s / best_c
    load_after = os.getloadavg()[0]
    return {
        "name": f"fleet identify, {n_actuators} P-I actuators (20,000-sample CSV records), {workers} local Dask workers",
        "ours": f"{best_c:.2f} s ({n_actuators / best_c:.1f} records/s)",
        "baseline": (f"serial loop of the same fits in one process started like a worker: {best_s:.2f} s "
                     f"({n_actuators / best_s:.1f} records/s)"),
        "ratio": ratio,
        "target": f">= {TARGET}x serial on {workers} cores, same fit RMSEs",
        "met": ratio >= TARGET and same,
        "note": (f"ratio = serial time / cluster time, best of {rounds} alternating rounds after one warm-up each; "
                 f"cluster start-up ({startup:.1f} s) excluded; fit RMSEs "
                 f"{'identical to serial in every round' if same else 'DIFFER from serial: ' + ', '.join(odd)}; all rounds serial {', '.join(f'{t:.2f}' for t in ts)} s "
                 f"(in the bench's own process, warmed by the rows before: {', '.join(f'{t:.2f}' for t in ts_here)} s, "
                 f"{min(ts_here) / best_c:.2f}x), cluster "
                 f"{', '.join(f'{t:.2f}' for t in tc)} s; CPU time per round (median): serial "
                 f"{np.median(cpu_s):.2f} s, workers {np.median(cpu_w):.2f} s + client and scheduler "
                 f"{np.median(cpu_c):.2f} s; the machine's ceiling in the same rounds ({workers} processes of pure "
                 f"Python arithmetic against one doing the same work): {', '.join(f'{c:.2f}' for c in ceil)}x; load "
                 f"average {load_before:.1f} before, {load_after:.1f} after, on {os.cpu_count()} cores (shared: "
                 f"when it is busy, the kernel's fair share per session caps what {workers} processes can take)"),
        "ceiling": max(ceil),
    }


if __name__ == "__main__":
    print(json.dumps(bench_fleet(), indent=2))
