"""Bench row: fleet identification of 40 actuators on 2 local Dask workers against a serial loop.

``bench_fleet()`` returns one row (``name``, ``ours``, ``baseline``, ``ratio``, ``target``,
``met``, ``note``) for the bench runner; ``python benchmarks/bench_fleet.py`` prints it as JSON.

What is timed, in the same run: ``ph.fleet.identify_many(batch, client=...)`` over 40 simulated
P-I actuators (CSV records of 20,000 samples: a 1 Hz, 0-100 V sinusoid for 10 s at 2 kHz, the
record size of the issue's "68 ms per P-I fit" figure), each record read, fitted with
``fit_pi`` and measured (loop figures), first serially in this process (``client="serial"``,
the baseline: the same function in a loop) and then on a LocalCluster of 2 worker processes of
one thread each. Both are warmed up once (imports, numba's cached kernels on every worker), then
timed in alternating rounds, best of each. The cluster's start-up is excluded from the ratio and
reported in the note; so are the CPU times (serial process; workers; client and scheduler) and
the machine's load, since the machine is shared. No model files are
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


def bench_fleet(*, n_actuators: int = N_ACTUATORS, workers: int = WORKERS, rounds: int = 3) -> dict:
    import numpy as np
    import psutil  # a dependency of distributed

    import piezohyst as ph

    def cpu(procs):
        return sum(sum(p.cpu_times()[:2]) for p in procs)

    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="piezohyst-bench-fleet-") as tmp:
        ph.fleet.write_simulated_batch(tmp, n_actuators, seed=0, fs=2000.0, cycles=10)
        t0 = time.perf_counter()
        client = ph.fleet.local_cluster(workers)
        startup = time.perf_counter() - t0
        try:
            me = psutil.Process()
            workers_ = [psutil.Process(pid) for pid in client.run(os.getpid).values()]
            serial = ph.fleet.identify_many(tmp, client="serial")  # warm-up, and the reference figures
            parallel = ph.fleet.identify_many(tmp, client=client)  # warm-up of every worker
            ts, tc, cpu_s, cpu_w, cpu_c = [], [], [], [], []
            for _ in range(rounds):
                c0, t = cpu([me]), time.perf_counter()
                ph.fleet.identify_many(tmp, client="serial")
                ts.append(time.perf_counter() - t)
                cpu_s.append(cpu([me]) - c0)
                c0, w0, t = cpu([me]), cpu(workers_), time.perf_counter()
                parallel = ph.fleet.identify_many(tmp, client=client)
                tc.append(time.perf_counter() - t)
                cpu_c.append(cpu([me]) - c0)
                cpu_w.append(cpu(workers_) - w0)
        finally:
            client.close()
            client.cluster.close()
    same = bool(np.array_equal(serial["fit_rmse_um"].to_numpy(), parallel["fit_rmse_um"].to_numpy())
                and (parallel["status"] == "ok").all())
    best_s, best_c = min(ts), min(tc)
    ratio = best_s / best_c
    load_after = os.getloadavg()[0]
    return {
        "name": f"fleet identify, {n_actuators} P-I actuators (20,000-sample CSV records), {workers} local Dask workers",
        "ours": f"{best_c:.2f} s ({n_actuators / best_c:.1f} records/s)",
        "baseline": f"serial loop of the same fits in one process: {best_s:.2f} s ({n_actuators / best_s:.1f} records/s)",
        "ratio": ratio,
        "target": f">= {TARGET}x serial on {workers} cores, same fit RMSEs",
        "met": ratio >= TARGET and same,
        "note": (f"ratio = serial time / cluster time, best of {rounds} alternating rounds after one warm-up each; "
                 f"cluster start-up ({startup:.1f} s) excluded; fit RMSEs {'identical' if same else 'DIFFER'} to "
                 f"serial; all rounds serial {', '.join(f'{t:.2f}' for t in ts)} s, cluster "
                 f"{', '.join(f'{t:.2f}' for t in tc)} s; CPU time per round (median): serial "
                 f"{np.median(cpu_s):.2f} s, workers {np.median(cpu_w):.2f} s + client and scheduler "
                 f"{np.median(cpu_c):.2f} s; load average {load_before:.1f} before, {load_after:.1f} after, on "
                 f"{os.cpu_count()} cores (shared machine: when it is busy, the kernel's fair share per session "
                 f"caps what 2 workers can take, and the wall ratio drops towards 1 whatever the code does)"),
    }


if __name__ == "__main__":
    print(json.dumps(bench_fleet(), indent=2))
