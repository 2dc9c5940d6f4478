"""Concurrent and interrupted runs writing one output folder (issue 13).

Processes of ``piezohyst rig --freq 1 --cycles 1 --out X`` race for one folder, or are stopped
with SIGINT/SIGTERM at random moments; afterwards, whatever happened:

* **whole**: ``X`` is absent, or holds exactly one run's set (``fig2_loops.png``, ``rig_loops.csv``,
  ``manifest.json``) whose files all match the manifest's SHA-256 (each racer uses its own
  ``--seed``, so two runs' files differ: a mix would not match);
* **not overwritten without --force**: a set that existed, or that another racer published
  first, is left byte for byte;
* **nothing lost**: a file beside ``X``, or a foreign file inside it, survives;
* **no temporary files**: nothing but ``X`` and the sentinel is left in the parent folder.

Most runs are forked from a "zygote" process that has piezohyst, numpy and matplotlib already
imported (each is a separate process running :func:`piezohyst.cli.main`, with its own signals;
only the interpreter's start-up is shared), so that the 50+ runs stay within seconds; a few are
whole ``python -m piezohyst`` processes. The moments of the signals are drawn from a seeded
generator.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(not hasattr(os, "fork") or sys.platform == "win32", reason="POSIX processes")

ROOT = Path(__file__).resolve().parents[1]
SET = {"fig2_loops.png", "rig_loops.csv", "manifest.json"}
TRIALS: dict[str, int] = {}  # runs per kind, printed at the end

ZYGOTE = r"""
import json, os, signal, sys, time, traceback
import numpy as np
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot
import piezohyst.analysis, piezohyst.plots, piezohyst.rig
from piezohyst.cli import main

piezohyst.rig.VirtualRig(seed=0).excite(np.linspace(0.0, 1.0, 10))  # kernels loaded before forking
out = sys.stdout
out.write("ready\n"); out.flush()
for line in sys.stdin:
    jobs = json.loads(line)
    pids = []
    for job in jobs:
        pid = os.fork()
        if pid == 0:
            signal.signal(signal.SIGINT, signal.default_int_handler)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            fd = os.open(job["log"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            os.dup2(fd, 1); os.dup2(fd, 2)
            code = 99
            sys.argv = ["piezohyst", *job["argv"]]  # as the console script would see it
            try:
                code = main(job["argv"])
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else 1
            except BaseException:
                traceback.print_exc()
            try:
                sys.stdout.flush(); sys.stderr.flush()
            finally:
                os._exit(code)
        pids.append(pid)
    out.write(json.dumps({"pids": pids, "t": time.monotonic()}) + "\n"); out.flush()
    codes = []
    for pid in pids:
        _, status = os.waitpid(pid, 0)
        codes.append(os.waitstatus_to_exitcode(status))
    out.write(json.dumps(codes) + "\n"); out.flush()
"""


class Zygote:
    def __init__(self, cwd: Path):
        env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
               "MPLBACKEND": "Agg"}
        self.p = subprocess.Popen([sys.executable, "-c", ZYGOTE], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  text=True, env=env, cwd=str(cwd))
        assert self.p.stdout.readline().strip() == "ready"

    def run(self, jobs: list[dict], kill: list[tuple[float, int] | None] | None = None) -> list[int]:
        """Fork one process per job, send each its signal (delay s, signal) if any; their exit codes."""
        self.p.stdin.write(json.dumps(jobs) + "\n")
        self.p.stdin.flush()
        pids = json.loads(self.p.stdout.readline())["pids"]
        if kill:
            t0 = time.monotonic()
            for (delay, sig), pid in sorted(((k, pid) for k, pid in zip(kill, pids) if k), key=lambda x: x[0][0]):
                time.sleep(max(0.0, delay - (time.monotonic() - t0)))
                try:
                    os.kill(pid, sig)
                except ProcessLookupError:
                    pass
        return json.loads(self.p.stdout.readline())

    def close(self) -> None:
        self.p.stdin.close()
        self.p.wait(timeout=30)
        self.p.stdout.close()


@pytest.fixture(scope="module")
def zygote(tmp_path_factory):
    z = Zygote(tmp_path_factory.mktemp("zygote"))
    yield z
    z.close()


def _rig_argv(out: Path, seed: int, force: bool = False) -> list[str]:
    return ["rig", "--freq", "1", "--cycles", "1", "--seed", str(seed), "--out", str(out), "--json"] + (
        ["--force"] if force else [])


def _snapshot(folder: Path) -> dict[str, bytes] | None:
    if not folder.exists():
        return None
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def _check_whole(folder: Path) -> int | None:
    """The folder is absent or one run's whole set; return that run's seed (from the manifest)."""
    snap = _snapshot(folder)
    if snap is None:
        return None
    assert set(snap) == SET, f"not a whole set: {sorted(snap)}"
    man = json.loads(snap["manifest.json"])
    for name, entry in man["files"].items():
        assert hashlib.sha256(snap[name]).hexdigest() == entry["sha256"], f"{name} is from another run (mixed set)"
    producer = man["producer"]
    csv_producer = snap["rig_loops.csv"].split(b"\n", 1)[0].decode()
    seed = int(producer.split("--seed ")[1].split()[0])
    assert f"--seed {seed} " in csv_producer  # the CSV inside says the same run wrote it
    return seed


def _check_clean(parent: Path, keep: set[str]) -> None:
    """Nothing but the outputs and the sentinel: no temporary file or folder left behind."""
    left = {p.name for p in parent.iterdir()}
    assert left <= keep, f"left behind: {sorted(left - keep)}"
    for d in parent.iterdir():
        if d.is_dir():
            assert not [p.name for p in d.iterdir() if p.name.startswith(".")], f"temporary files in {d}"


def _trial_dir(tmp_path: Path, name: str) -> tuple[Path, Path]:
    parent = tmp_path / name
    parent.mkdir()
    (parent / "sentinel.txt").write_text("a file beside the output: must survive\n")
    return parent, parent / "X"


def _count(kind: str, n: int) -> None:
    TRIALS[kind] = TRIALS.get(kind, 0) + n


def _baseline(zygote: Zygote, parent: Path, out: Path, seed: int) -> dict[str, bytes]:
    assert zygote.run([{"argv": _rig_argv(out, seed), "log": str(parent / "base.log")}]) == [0]
    (parent / "base.log").unlink()
    return _snapshot(out)


# ------------------------------------------------------------------------------------------------
def test_racing_runs_without_force_publish_exactly_one_whole_set(zygote, tmp_path):
    for trial in range(7):
        parent, out = _trial_dir(tmp_path, f"race{trial}")
        seeds = [100 * trial + k for k in range(3)]
        jobs = [{"argv": _rig_argv(out, s), "log": str(tmp_path / f"race{trial}-{s}.log")} for s in seeds]
        codes = zygote.run(jobs)
        _count("racing, no --force", len(jobs))
        assert sorted(codes) == [0, 2, 2], codes  # one wins; the others refuse, they do not overwrite
        winner = seeds[codes.index(0)]
        assert _check_whole(out) == winner
        for s, c in zip(seeds, codes):
            if c == 2:
                err = (tmp_path / f"race{trial}-{s}.log").read_text()
                assert "--force" in err and "Traceback" not in err
        _check_clean(parent, {"X", "sentinel.txt"})


def test_runs_without_force_never_touch_an_existing_set(zygote, tmp_path):
    parent, out = _trial_dir(tmp_path, "existing")
    before = _baseline(zygote, parent, out, seed=7)
    for trial in range(3):
        jobs = [{"argv": _rig_argv(out, 200 + 10 * trial + k), "log": str(tmp_path / f"e{trial}{k}.log")}
                for k in range(3)]
        assert zygote.run(jobs) == [2, 2, 2]
        _count("racing onto an existing set, no --force", len(jobs))
        assert _snapshot(out) == before
    _check_clean(parent, {"X", "sentinel.txt"})


def test_racing_runs_with_force_leave_one_whole_set(zygote, tmp_path):
    parent, out = _trial_dir(tmp_path, "force")
    _baseline(zygote, parent, out, seed=9)
    for trial in range(4):  # each trial replaces the set the previous one left
        seeds = [300 + 10 * trial + k for k in range(3)]
        codes = zygote.run([{"argv": _rig_argv(out, s, force=True), "log": str(tmp_path / f"f{trial}{s}.log")}
                            for s in seeds])
        _count("racing with --force", len(seeds))
        assert codes == [0, 0, 0]
        assert _check_whole(out) in seeds
        _check_clean(parent, {"X", "sentinel.txt"})


def test_force_never_replaces_a_folder_with_other_files(zygote, tmp_path):
    parent, out = _trial_dir(tmp_path, "foreign")
    _baseline(zygote, parent, out, seed=11)
    (out / "notes.txt").write_text("the user's own file\n")
    before = _snapshot(out)
    codes = zygote.run([{"argv": _rig_argv(out, 400 + k, force=True), "log": str(tmp_path / f"n{k}.log")}
                        for k in range(2)])
    _count("--force onto a folder with a foreign file", 2)
    assert codes == [2, 2] and _snapshot(out) == before


def test_interrupted_runs_leave_the_old_set_or_the_new_one_whole(zygote, tmp_path):
    rng = np.random.default_rng(12)
    # how long an undisturbed run takes in the zygote: the signals fall anywhere inside it (and a
    # little after, so some runs finish first)
    parent, out = _trial_dir(tmp_path, "replace")
    t0 = time.monotonic()
    _baseline(zygote, parent, out, seed=1)
    span = time.monotonic() - t0
    for fresh, n in ((False, 12), (True, 8)):
        outcomes = {"old": 0, "new": 0, "absent": 0}
        for trial in range(n):
            if fresh:
                parent, out = _trial_dir(tmp_path, f"fresh{trial}")
            old = _snapshot(out)  # replacing: the set the previous trial left
            seed = (700 if fresh else 500) + trial
            sig = signal.SIGINT if trial % 2 else signal.SIGTERM
            delay = float(rng.uniform(0.0, 1.2 * span))
            log = tmp_path / f"i{int(fresh)}-{trial}.log"
            codes = zygote.run([{"argv": _rig_argv(out, seed, force=not fresh), "log": str(log)}],
                               kill=[(delay, sig)])
            _count("interrupted by SIGINT/SIGTERM", 1)
            assert codes[0] in (0, 130, 143, -int(sig)), codes  # -sig: killed before main() set its handler
            got = _check_whole(out)
            if got is None:
                assert fresh
                outcomes["absent"] += 1
            elif got == seed:
                outcomes["new"] += 1
            else:
                assert _snapshot(out) == old  # the previous set, byte for byte
                outcomes["old"] += 1
            if codes[0] in (130, 143):
                assert "no output was left half-written" in log.read_text()
            _check_clean(parent, {"X", "sentinel.txt"})
        print(f"\ninterrupted ({'fresh' if fresh else 'replacing a set'}): {outcomes}")


def test_whole_processes_race_and_are_interrupted(tmp_path):
    """The same through ``python -m piezohyst`` processes (interpreter start-up, signal handlers)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    parent, out = _trial_dir(tmp_path, "whole")

    def start(seed: int, force: bool = False) -> subprocess.Popen:
        log = open(tmp_path / f"whole-{seed}.log", "w")  # noqa: SIM115 - closed when the process ends
        p = subprocess.Popen([sys.executable, "-m", "piezohyst", *_rig_argv(out, seed, force)], env=env,
                             stdout=log, stderr=subprocess.STDOUT)
        log.close()  # the child has its own copy
        return p

    racers = [start(600), start(601)]
    codes = [p.wait(timeout=300) for p in racers]
    _count("racing, whole processes", 2)
    assert sorted(codes) == [0, 2]
    first = _check_whole(out)
    assert first == (600, 601)[codes.index(0)]
    before = _snapshot(out)
    # SIGTERM once the run is under way (its start-up is the slow part): old set or new, whole
    p = start(602, force=True)
    time.sleep(float(np.random.default_rng(14).uniform(0.5, 3.0)))
    if p.poll() is None:
        p.send_signal(signal.SIGTERM)
    code = p.wait(timeout=300)
    _count("interrupted, whole processes", 1)
    assert code in (0, 143, -signal.SIGTERM)
    got = _check_whole(out)
    assert got == 602 or _snapshot(out) == before
    _check_clean(parent, {"X", "sentinel.txt"})


def test_zz_summary(capsys):
    """Prints how many runs the tests above made (they must total at least 50)."""
    total = sum(TRIALS.values())
    with capsys.disabled():
        print(f"\nconcurrency and interruption: {total} runs: " + ", ".join(f"{k} {v}" for k, v in TRIALS.items()))
    if TRIALS:  # when run with the rest of this module
        assert total >= 50, TRIALS


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_handed_to_another_thread_waits_for_the_publish(signum):
    """The kernel hands a process's signal to any thread that does not block it, and Python then
    runs the handler in the main thread, inside the held block (found by a helper: 9 of 400
    interrupts of save_model with threads running left a temporary file behind). Delivered to
    another thread inside ``deferred_signals``, it is raised after the block, not in it."""
    import threading

    from piezohyst._fileio import deferred_signals

    class Term(Exception):
        pass

    def on_term(signum, frame):
        raise Term

    old = signal.signal(signal.SIGTERM, on_term)
    release = threading.Event()
    other = threading.Thread(target=release.wait, args=(10.0,))
    other.start()
    done = []
    try:
        with pytest.raises(KeyboardInterrupt if signum == signal.SIGINT else Term):
            with deferred_signals():
                signal.pthread_kill(other.ident, signum)
                t0 = time.monotonic()
                while time.monotonic() - t0 < 0.2:  # bytecode boundaries: where a handler would run
                    sum(range(100))
                done.append("published")
    finally:
        release.set()
        other.join()
        signal.signal(signal.SIGTERM, old)
    assert done == ["published"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handlers put back


def test_a_handler_that_fires_while_the_handlers_are_put_back_leaves_none_swapped(monkeypatch):
    """Found by a reviewer: signal.signal() runs the handlers of signals already pending before it
    sets one, so a Ctrl-C handed to another thread just after SIGINT's handler was put back raised
    out of the middle of the restoring: SIGTERM kept the block's noting handler for good (a process
    `kill` no longer ended) and the signals stayed blocked. Simulated: the second putting-back
    raises KeyboardInterrupt, as that pending handler would."""
    import piezohyst._fileio as fio

    real = signal.signal
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    calls = []

    def signal_with_a_pending_interrupt(sig, handler):
        calls.append(sig)
        if len(calls) == 5:  # the second handler put back (three swapped on entry: INT, TERM, HUP)
            raise KeyboardInterrupt
        return real(sig, handler)

    monkeypatch.setattr(fio.signal, "signal", signal_with_a_pending_interrupt)
    with pytest.raises(KeyboardInterrupt):
        with fio.deferred_signals():
            pass
    monkeypatch.setattr(fio.signal, "signal", real)
    assert {s: signal.getsignal(s) for s in before} == before  # every handler back
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    assert signal.SIGINT not in blocked and signal.SIGTERM not in blocked
