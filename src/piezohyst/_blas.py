"""One BLAS thread for the model search's small products, where more threads only contend.

The model selection (:func:`piezohyst.identify.fit_model`) forms hundreds of Gram matrices and
products of tall, narrow design matrices (30 000 x ~40). OpenBLAS splits each over every core;
on a machine whose cores are busy with anything else (a shared 2-core machine, a CI runner, a
Dask worker beside others) each product then waits for a descheduled thread: measured here,
``B'B`` of a 30 000 x 36 matrix took 96 ms with two threads on a loaded 2-core machine and 2.6 ms
with one. :func:`single_threaded_blas` sets OpenBLAS (numpy's and scipy's bundled copies, found
among the process's loaded libraries) to one thread for a block and restores the count after.

It changes the thread count of the whole process for the block (BLAS has no per-thread setting
in the builds numpy ships), and it does nothing where it cannot find OpenBLAS (another BLAS,
another platform): the numbers are the same either way, only the time differs.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import os
import sys
import threading
from typing import Any, Callable, Iterator, TypeVar

def usable_cores() -> int:
    """The CPUs this process may run on (its affinity mask where the platform has one, else the
    machine's count), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not Linux
        return max(1, os.cpu_count() or 1)


#: A local cluster may have up to this many worker processes per core: a local cluster of
#: hundreds of processes on a few cores starved itself into CommClosedErrors and hung (found by
#: fuzzing: 200 and 100000 workers on 2 cores; 1000 from Python, a load of 53 and 1614 leaked
#: semaphores: found by a helper)
MAX_WORKERS_PER_CORE = 4


def too_many_workers(n: int) -> str | None:
    """Why ``n`` worker processes are too many for a cluster on this machine, or None."""
    cores = usable_cores()
    if n > MAX_WORKERS_PER_CORE * cores:
        return (f"{n} workers is more than {MAX_WORKERS_PER_CORE}x this machine's {cores} cores: each worker is a "
                "process of its own; for more, start a cluster (dask-jobqueue, a dask scheduler) and pass its address")
    return None


# (set, get) function names, newest builds first
_NAMES = (("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
          ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
          ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
          ("openblas_set_num_threads", "openblas_get_num_threads"))
_lock = threading.Lock()
_depth = 0
_saved: list[tuple[Any, int]] = []


_found: tuple[int, list[tuple[Any, Any]]] | None = None


def _openblas_controls() -> list[tuple[Any, Any]]:
    """``(set, get)`` of each OpenBLAS loaded in this process (Linux: from /proc/self/maps).

    Reading the maps of a process that has loaded numba and scipy costs milliseconds (thousands of
    lines), as much as a small fit: the answer is kept until a module is imported (a library such as
    scipy's OpenBLAS is loaded by an import)."""
    global _found
    key = len(sys.modules)
    if _found is not None and _found[0] == key:
        return _found[1]
    out = _scan_openblas()
    _found = (key, out)
    return out


def _scan_openblas() -> list[tuple[Any, Any]]:
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            paths = {line.split()[-1] for line in f if "openblas" in line.lower() and "/" in line}
    except OSError:
        return []
    out = []
    for path in sorted(paths):
        if "openblas" not in os.path.basename(path).lower():
            continue
        try:
            lib = ctypes.CDLL(path)  # already loaded: the same handle
        except OSError:
            continue
        for set_name, get_name in _NAMES:
            if hasattr(lib, set_name) and hasattr(lib, get_name):
                setter, getter = getattr(lib, set_name), getattr(lib, get_name)
                setter.argtypes, setter.restype = [ctypes.c_int], None
                getter.argtypes, getter.restype = [], ctypes.c_int
                out.append((setter, getter))
                break
    return out


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """OpenBLAS on one thread inside the block (module docstring); nested blocks are one."""
    global _depth
    with _lock:
        _depth += 1
        if _depth == 1:
            try:
                for setter, getter in _openblas_controls():
                    n = int(getter())
                    if n > 1:
                        setter(1)
                        _saved.append((setter, n))
            except Exception:  # pragma: no cover - a BLAS that does not behave: leave it as it is
                pass
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                while _saved:
                    setter, n = _saved.pop()
                    setter(n)


F = TypeVar("F", bound=Callable[..., Any])


def with_single_threaded_blas(func: F) -> F:
    """Run ``func`` inside :func:`single_threaded_blas`."""
    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with single_threaded_blas():
            return func(*args, **kwargs)
    return wrapper  # type: ignore[return-value]
