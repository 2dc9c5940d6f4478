"""Figures as data, drawn here or in a separate process while the caller goes on computing.

A :class:`FigureJob` is everything one figure needs: the name of a function of
:mod:`piezohyst.plots`, its arguments (arrays and strings, computed by the caller) and the file's
note. :func:`render` draws and saves a list of them; it is the only code that draws, whether it
runs in the caller's process or in the worker of :class:`BackgroundFigures`, so the files are the
same either way (only the time in their metadata differs by when they were written).

Why a separate process: drawing with matplotlib (text layout, ticks, rasterising) is Python work
that holds the interpreter's lock, so a thread would not overlap it with anything; a process on
a second core draws the figures of a finished part of an experiment while the caller computes
the rest (``piezohyst reproduce``: the paper's figures while commissioning runs). The worker is a
fresh interpreter started with :data:`sys.executable` (not ``multiprocessing``, which would import
the caller's main script again in the child), imports only numpy, matplotlib and
:mod:`piezohyst.plots` (this module is outside :mod:`piezohyst.experiments`, whose package imports
the whole identification stack), and talks over its stdin and stdout in pickles. If it fails or dies, the
figures are drawn in the caller's process instead, which then raises whatever error drawing
really has; warnings the worker saw are issued again in the caller's process.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import threading
import warnings
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class FigureJob:
    """One figure: ``plots.<plot>(*args, **kwargs)`` saved as ``file`` with ``note`` in its metadata."""

    key: str
    file: str
    plot: str
    args: tuple[Any, ...] = ()
    kwargs: dict[str, Any] = field(default_factory=dict)
    note: str = ""


def render(jobs: list[FigureJob], out: Any, formats: tuple[str, ...], *, force: bool = True,
           producer: str | None = None) -> dict[str, Path]:
    """Draw and save ``jobs`` into the folder ``out`` (created if missing) in every format of
    ``formats``; ``{key: path}`` with the first format's file under the job's key and each
    further format's under ``"key.fmt"``."""
    from . import plots

    plots.use_headless_backend()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    for job in jobs:
        arts = getattr(plots, job.plot)(*job.args, **job.kwargs)
        fig = arts[0].axes.figure
        files = plots.save_formats(fig, out / job.file, formats, force=force, note=job.note, producer=producer)
        paths[job.key] = files[0]
        for f, pth in zip(formats[1:], files[1:]):
            paths[f"{job.key}.{f}"] = pth
    return paths


def _warm_up() -> None:
    """Import and exercise what drawing needs (matplotlib, its fonts and text layout) while the
    caller still computes."""
    import io

    from . import plots

    plots.use_headless_backend()
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(2, 2), layout="constrained")
    ax.plot([0.0, 1.0], [0.0, 1.0])
    ax.set_xlabel("u (V)")
    ax.set_title("warm-up", fontsize=9)
    fig.savefig(io.BytesIO(), format="png", dpi=30)
    plt.close(fig)


def serve() -> None:
    """The worker's loop: read ``(jobs, out, formats, force, producer)`` pickles from stdin, draw
    them, answer ``("ok", paths, warnings)`` or ``("error", message, warnings)``; stop at ``None``
    or the end of stdin."""
    import signal

    # Ctrl-C reaches the whole process group: the caller decides what happens (it stops this
    # worker when it leaves its block), so no second traceback from here
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    inp = sys.stdin.buffer
    reply = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything printed goes to stderr, not into the replies
    try:
        _serve(inp, reply)
    except (BrokenPipeError, EOFError):  # the caller is gone
        pass


def _serve(inp: Any, reply: Any) -> None:
    try:
        _warm_up()
    except Exception:  # drawing will fail again and say why
        pass
    while True:
        try:
            req = pickle.load(inp)
        except EOFError:
            return
        if req is None:
            return
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            try:
                paths = render(*req[:3], force=req[3], producer=req[4])
                msg: tuple[Any, ...] = ("ok", paths)
            except Exception as exc:  # the caller draws again itself and raises the real error
                msg = ("error", f"{type(exc).__name__}: {exc}")
        msg = (*msg, [(str(w.message), w.category) for w in seen])
        try:
            pickle.dump(msg, reply)
        except Exception:  # a warning category that does not pickle
            pickle.dump((*msg[:2], [(m, UserWarning) for m, _ in msg[2]]), reply)
        reply.flush()


class BackgroundFigures:
    """A worker process that draws figures while the caller goes on (module docstring).

    Start it early (its imports then overlap the caller's work), :meth:`submit` the jobs once
    their data exist, take the files with :meth:`result`. A thread hands the worker one job at a
    time; :meth:`result` draws in the caller's process whatever the worker has not started yet
    (when two or more are left), so the two processes finish the set together. Use it as a
    context manager: leaving the block stops the worker (and kills it when the block ends with an
    error), so it never outlives the folder it writes into.
    """

    #: :meth:`result` draws here when at least this many jobs have not been started by the worker
    #: (one left is about as quick to wait for as to draw after importing matplotlib here)
    STEAL_FROM = 2

    def __init__(self) -> None:
        root = str(Path(__file__).resolve().parents[1])  # the folder piezohyst is imported from
        code = (f"import sys; sys.path.insert(0, {root!r}); "
                "from piezohyst._figures import serve; serve()")
        self._proc: subprocess.Popen[bytes] | None = None
        try:
            self._proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        except OSError:  # no worker: result() draws everything here
            self._proc = None
        self._lock = threading.Lock()
        self._spec: tuple[Path, tuple[str, ...], bool, str] | None = None
        self._jobs: list[FigureJob] = []
        self._pending: deque[int] = deque()
        self._done: dict[int, dict[str, Path]] = {}
        self._failed: list[int] = []
        self._warnings: list[tuple[str, Any]] = []
        self._thread: threading.Thread | None = None

    @staticmethod
    def useful() -> bool:
        """Whether a second process can run at the same time (more than one CPU is ours, and an
        interpreter to start)."""
        if not sys.executable:
            return False
        from ._blas import usable_cores

        return usable_cores() > 1

    def submit(self, jobs: list[FigureJob], out: Any, formats: tuple[str, ...], *, force: bool = True,
               producer: str | None = None) -> None:
        """Hand ``jobs`` (:func:`render`'s arguments) to the worker; returns at once."""
        if self._spec is not None:
            raise RuntimeError("one set of figures per worker: take the result first")
        if producer is None:
            from ._fileio import producer as _producer

            producer = _producer()
        self._spec = (Path(out), tuple(formats), bool(force), producer)
        self._jobs = list(jobs)
        self._pending = deque(range(len(self._jobs)))
        self._done, self._failed, self._warnings = {}, [], []
        self._thread = threading.Thread(target=self._feed, name="piezohyst-figures", daemon=True)
        self._thread.start()

    def _take(self, at_least: int = 1) -> int | None:
        with self._lock:
            return self._pending.popleft() if len(self._pending) >= at_least else None

    def _feed(self) -> None:
        """The thread: one job at a time to the worker, until none is left or the worker fails."""
        proc = self._proc
        assert self._spec is not None
        out, fmts, force, who = self._spec
        while True:
            i = self._take()
            if i is None:
                return
            reply = None
            if proc is not None and proc.stdin is not None and proc.stdout is not None:
                try:
                    pickle.dump(([self._jobs[i]], out, fmts, force, who), proc.stdin)
                    proc.stdin.flush()
                    reply = pickle.load(proc.stdout)
                except Exception:  # the worker is gone
                    reply = None
            if reply is None:  # this job and the rest are drawn by result()
                with self._lock:
                    self._pending.appendleft(i)
                return
            self._warnings.extend(reply[2])
            if reply[0] == "ok":
                self._done[i] = dict(reply[1])
            else:  # drawn again by result(), which raises the real error
                with self._lock:
                    self._failed.append(i)

    def result(self) -> dict[str, Path]:
        """The files of the submitted jobs, ``{key: path}`` in the jobs' order (what the worker
        could not draw is drawn here)."""
        if self._spec is None or self._thread is None:
            raise RuntimeError("nothing was submitted")
        out, fmts, force, who = self._spec
        try:
            while (i := self._take(self.STEAL_FROM)) is not None:
                self._done[i] = render([self._jobs[i]], out, fmts, force=force, producer=who)
            self._thread.join()
            self._let_go()  # the worker's shutdown overlaps what the caller does next
            for message, category in self._warnings:
                warnings.warn(message, category, stacklevel=2)
            for i in [*self._pending, *self._failed]:
                self._done[i] = render([self._jobs[i]], out, fmts, force=force, producer=who)
            paths: dict[str, Path] = {}
            for i in range(len(self._jobs)):
                paths.update(self._done[i])
            return paths
        finally:
            self._spec = None

    def _let_go(self) -> None:
        """Tell the worker to stop, without waiting for it."""
        proc = self._proc
        if proc is not None and proc.stdin is not None and not proc.stdin.closed:
            try:
                pickle.dump(None, proc.stdin)
                proc.stdin.close()
            except (OSError, ValueError):
                pass

    def close(self, kill: bool = False) -> None:
        """Stop the worker (at once with ``kill``)."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        try:
            if not kill:
                self._proc = proc
                self._let_go()
                self._proc = None
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    pass
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            if self._thread is not None:
                self._thread.join(timeout=10)  # its pipe is closed: it returns
            for f in (proc.stdin, proc.stdout):
                if f is not None:
                    try:
                        f.close()
                    except OSError:
                        pass

    def __enter__(self) -> BackgroundFigures:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        self.close(kill=exc_type is not None or self._spec is not None)
