"""Fleets of actuators: identify every record of a production batch, on Dask, and compare them.

A manufacturer or a lab characterises every actuator of a batch: hundreds to thousands of
voltage/displacement records, each to be identified, filed and compared with its siblings. This
module runs one task per record on a Dask cluster (a ``LocalCluster`` on this machine by
default, or any scheduler you already run) and gathers one table; records that take only
milliseconds (P-I fits) go out in small groups, so that Dask's cost per task does not eat the
speed-up.

* :func:`identify_many` - every record identified (P-I by default), the models written to
  ``out/models/<record>.json`` and one row per record returned as a ``pandas.DataFrame`` (and
  written to ``out/summary.csv``, and ``summary.parquet`` when pyarrow is installed);
* :func:`batch_statistics` - the batch's distributions of gain, loop width and fit error, and
  the actuators that differ (beyond 5 median absolute deviations);
* :func:`plot_histograms` - those distributions as histograms, the outliers marked;
* :func:`identify_record` - the task itself, for one record (what each worker runs);
* :func:`write_simulated_batch` - a simulated batch to try all this on.

The command line does the same: ``piezohyst fleet identify PATHS... --model pi --out DIR``.

Each row
--------
``record`` (the file's name without its suffix, made unique), ``file``, ``status`` (``"ok"`` or
``"error"``), ``error`` (why a record failed: an unreadable or corrupt file is a row with its
error, never a failed batch), ``kind``, ``method``, ``n_samples``, ``fs_hz``,
``delay_samples``, ``fit_rmse_um`` and ``fit_rmse_percent_of_span`` (eq. 9 on the fitting data),
``holdout_rmse_um`` and ``holdout_percent_of_span`` (the chosen model's error on held-out data,
``fit.info["holdout"]``, when the kind is chosen by :func:`~piezohyst.fit_model`; empty for
``kind="pi"`` and ``"bouc-wen"``, which the paper's way fits on the whole record), ``span_um``,
``gain_um_per_v`` (the mean slope, ``ptp(y) / ptp(u)``), ``loop_width_um`` and
``loop_width_percent`` (the width of the last whole loop at mid-range,
:func:`~piezohyst.loop_figures`, when the input is periodic), ``n_warnings`` and ``warnings``
(the fit's, and any Python warning raised while it ran), ``fit_time_s``, ``elapsed_s`` (load +
fit + figures, on the worker), ``resumed``, ``model_file``, ``outlier`` and ``outlier_reason``.
These figures are of the *measured* record (gain, width) and of the fit (errors), so an actuator
that differs shows in both.

Which fit
---------
``kind="pi"`` is :func:`~piezohyst.fit_pi` with the ``piezohyst identify --model pi`` defaults
(20 play operators, bounded least squares, no delay): the fleet's RMSE of a record is exactly
``ph.fit_pi(u, y).rmse`` on it. ``kind="bouc-wen"`` is :func:`~piezohyst.fit_bouc_wen` (PSO and
polish, the paper's). ``"auto"`` and every other kind go through :func:`~piezohyst.fit_model`
(structure chosen on held-out data). The options (:class:`FitOptions`) are those of
``piezohyst identify``: ``method``, ``n``, ``seed``, ``max_iter``, ``polish``, ``delay`` and the
data options ``u_col``, ``y_col``, ``t_col``, ``fs``.

Resuming
--------
Records whose model file is already in ``out/models`` are not fitted again (unless ``force``):
their rows are read back from the model files, which carry them. A model file made with other
options, or from another version of its data file (its SHA-256), is reported as an error row
rather than silently reused; ``force`` refits it. ``summary.*`` and the histogram describe the
latest run and are replaced by it (atomically), but a file of those names that no batch wrote
(a user's own ``summary.csv``) is refused before any fit unless ``force``; model files are never
overwritten without ``force``. The summary files add a column ``written_by`` (package, version,
command line, time) in place of a comment line, which spreadsheets would read as data.

One numba thread per worker
---------------------------
Process parallelism and numba's own threads do not mix: :func:`~piezohyst.fit_bouc_wen`
simulates the whole swarm in a ``prange`` loop that starts one thread per core, so two worker
processes on two cores would run four busy threads and slow each other down (the issue that
asked for this module measured it). The local cluster's workers therefore start with
``NUMBA_NUM_THREADS=1`` (and distributed's own ``OMP_NUM_THREADS=1`` etc. for BLAS), one thread
each, and every task calls ``numba.set_num_threads(1)`` (per thread), so workers you started
yourself behave the same. Parallelism comes from the records, which are independent.

Running it on a real cluster
----------------------------
No cluster exists where this was written; these are pointers, not tested recipes. Any
``distributed.Client`` works: pass it as ``client=``, or give the scheduler's address to the
command (``--scheduler tcp://host:8786``). What every deployment needs:

* the workers run the same Python environment (``pip install "piezohyst[fleet]"``);
* the data files are readable by the workers *at the same paths* (a shared filesystem, as on
  most HPC clusters): the workers read the records; the client writes the model files and the
  summary, so ``out`` only needs to be writable where the command runs;
* one thread per worker process (``--nthreads 1``), for the reason above; with ``dask worker``
  set ``NUMBA_NUM_THREADS=1`` in its environment (the tasks also lower it per thread); for
  quick fits, ``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False`` saves the workers' profiler
  thread (see :data:`LOCAL_CLUSTER_CONFIG`).

By hand: ``dask scheduler`` on one machine, ``dask worker tcp://SCHEDULER:8786 --nthreads 1
--nworkers N`` on each of the others (https://docs.dask.org/en/stable/deploying-cli.html).
On SLURM, PBS, SGE or LSF, dask-jobqueue (https://jobqueue.dask.org) starts the workers as batch
jobs::

    from dask_jobqueue import SLURMCluster          # or PBSCluster, SGECluster, LSFCluster
    from distributed import Client
    cluster = SLURMCluster(cores=1, processes=1, memory="2GB", walltime="01:00:00",
                           job_script_prologue=["export NUMBA_NUM_THREADS=1"])
    cluster.scale(jobs=50)                          # or cluster.adapt(maximum_jobs=200)
    df = ph.fleet.identify_many("batch-07/", kind="pi", client=Client(cluster), out="fleet-07")

On Kubernetes, dask-kubernetes' operator (https://kubernetes.dask.org) gives a ``KubeCluster``
(an image with ``piezohyst[fleet]`` installed, the data on a shared volume), used the same way;
Dask Gateway (https://gateway.dask.org) and Coiled work alike. The command line takes the
scheduler's address from any of them (``cluster.scheduler_address``).

Dask and pandas are the optional extra ``piezohyst[fleet]``; ``import piezohyst`` never imports
them, and :class:`MissingExtraError` says how to install them when they are missing.
"""

from __future__ import annotations

import contextlib
import errno
import glob
import hashlib
import json
import math
import os
import re
import time
import uuid
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from ._validation import as_flag, as_scalar
from .data._load import READ_SUFFIXES

#: Suffixes of the data files a folder given as a path contributes (what load_dataset reads).
DATA_SUFFIXES = READ_SUFFIXES

#: The summary's columns, in order (see the module docstring).
COLUMNS = (
    "record", "file", "status", "error", "kind", "method", "n_samples", "fs_hz", "delay_samples",
    "fit_rmse_um", "fit_rmse_percent_of_span", "holdout_rmse_um", "holdout_percent_of_span",
    "span_um", "gain_um_per_v", "loop_width_um", "loop_width_percent", "n_warnings", "warnings",
    "fit_time_s", "elapsed_s", "resumed", "model_file", "outlier", "outlier_reason",
)

#: The batch figures compared between actuators: column -> (label, unit). Loop width and fit
#: error are taken relative to each actuator's own span, so an actuator with a larger stroke is
#: not also flagged for a wider loop or a larger error in µm; its gain flags it.
FIGURES: dict[str, tuple[str, str]] = {
    "gain_um_per_v": ("gain", "µm/V"),
    "loop_width_percent": ("loop width", "% of span"),
    "fit_rmse_percent_of_span": ("fit RMSE", "% of span"),
}

#: Flag an actuator whose figure is further than this many median absolute deviations from the
#: batch's median (raw MAD, not scaled to a standard deviation: 5 MADs is about 3.4 sigma of a
#: normal distribution).
OUTLIER_MADS = 5.0

_INSTALL = 'pip install "piezohyst[fleet]"  (dask[distributed] and pandas)'


class MissingExtraError(ImportError):
    """Dask or pandas is not installed; the message says how to install the ``fleet`` extra."""


def _require(module: str) -> Any:
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingExtraError(f"piezohyst.fleet needs {module.split('.')[0]}, which is not installed "
                                f"({exc}); install the fleet extra: {_INSTALL}") from None


# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FitOptions:
    """How each record is read and identified: the options of ``piezohyst identify``.

    Parameters
    ----------
    kind : str
        ``"auto"`` or a kind name or alias (``"pi"``, ``"bouc-wen"``, ``"rate-dependent"``,
        ``"asymmetric-pi"``, ``"preisach"``); stored as the kind's canonical name.
    method : {"lsq", "pso", "select"}, optional
        ``lsq`` (P-I default): :func:`~piezohyst.fit_pi` by least squares; ``pso``: the paper's
        swarm (``bouc-wen`` default, or P-I); ``select``: :func:`~piezohyst.fit_model` (every
        other kind, and ``auto``).
    n : int, optional
        Play operators (P-I; 20 with ``lsq``/``pso``) or grid levels; default chosen on
        held-out data with ``select``.
    seed, max_iter, polish
        PSO's seed and iterations, and the Bouc-Wen local refinement.
    delay : int or "auto", optional
        Samples by which the output lags the input (default ``"auto"`` with ``select``, 0
        otherwise).
    u_col, y_col, t_col, fs, resample, units, delimiter, decimal, encoding
        How to read each file (:func:`~piezohyst.load_dataset`; ``resample``: a time column that
        is not uniformly sampled is interpolated onto a uniform grid; ``units``: a unit or factor
        per column role, over what the names say, e.g. ``{"y": 10.0}`` for a sensor of 10 um/V).
    history : {"auto", "none"}, optional
        With ``select``: where each actuator's state at the record's start came from
        (:func:`~piezohyst.fit_model`'s ``history``; default ``"auto"`` for ``kind="auto"``).
    """

    kind: str = "pi"
    method: str | None = None
    n: int | None = None
    seed: int = 0
    max_iter: int = 200
    polish: bool = True
    delay: int | str | None = None
    u_col: Any = None
    y_col: Any = None
    t_col: Any = None
    fs: float | None = None
    history: str | None = None
    resample: bool = False
    units: dict[str, Any] | None = None
    delimiter: str | None = None
    decimal: str | None = None
    encoding: str | None = None

    def __post_init__(self) -> None:
        from .models.base import kind_class

        as_flag("resample", self.resample)  # ("no" was taken as true: found by fuzzing)
        if self.decimal not in (None, ".", ","):
            raise ValueError(f"decimal must be '.' or ',', got {self.decimal!r}")
        for name in ("delimiter", "encoding"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, str) and v and (name == "encoding" or len(v) == 1)):
                raise ValueError(f"{name} must be {'one character' if name == 'delimiter' else 'an encoding name'}, "
                                 f"got {v!r}")
        if self.units is not None:
            from .data._columns import check_units_arg

            object.__setattr__(self, "units", check_units_arg(self.units, "units") or None)
        as_flag("polish", self.polish)
        kind = self.kind
        if not isinstance(kind, str):
            raise TypeError(f"kind must be a string, got {type(kind).__name__}")
        if kind != "auto":
            kind = str(kind_class(kind).kind)  # type: ignore[attr-defined]
        method = self.method
        if method is None:
            method = "pso" if kind == "bouc-wen" else "lsq" if kind == "prandtl-ishlinskii" else "select"
        if method not in ("select", "lsq", "pso"):
            raise ValueError(f"method must be 'select', 'lsq' or 'pso', got {method!r}")
        if method == "pso" and kind not in ("bouc-wen", "prandtl-ishlinskii"):
            raise ValueError(f"method 'pso' is for kind 'pi' or 'bouc-wen' (the paper's); {kind} is fitted "
                             "by least squares with its structure chosen on held-out data (method 'select')")
        if method == "lsq" and kind != "prandtl-ishlinskii":
            raise ValueError("method 'lsq' is for kind 'pi'; the other kinds choose their structure on held-out "
                             "data (method 'select', their default)")
        if self.history not in (None, "auto", "none"):
            raise ValueError(f"history must be 'auto' or 'none', got {self.history!r}")
        if self.history is not None and method != "select":
            raise ValueError(f"history is for the structure search (method 'select'); method {method!r} fits "
                             "from the de-energised state")
        for name, least in (("n", 1), ("seed", 0), ("max_iter", 1)):
            v = getattr(self, name)
            if v is None and name == "n":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < least:
                raise ValueError(f"{name} must be an integer >= {least}, got {v!r}")
        delay = self.delay
        if delay is None:
            delay = "auto" if method == "select" else 0
        if isinstance(delay, str):
            if delay != "auto":
                raise ValueError(f"delay must be a number of samples >= 0 or 'auto', got {delay!r}")
            if method == "pso" and kind == "bouc-wen":
                raise ValueError("delay 'auto' is not available for kind 'bouc-wen' with method 'pso'; "
                                 "give the delay in samples")
        elif isinstance(delay, bool) or not isinstance(delay, (int, np.integer)) or delay < 0:
            raise ValueError(f"delay must be a number of samples >= 0 or 'auto', got {delay!r}")
        if self.fs is not None and not (isinstance(self.fs, (int, float)) and np.isfinite(self.fs) and self.fs > 0):
            raise ValueError(f"fs must be a positive sample rate in Hz, got {self.fs!r}")
        object.__setattr__(self, "kind", kind)
        object.__setattr__(self, "method", method)
        object.__setattr__(self, "delay", delay if isinstance(delay, str) else int(delay))

    def data_options(self) -> dict[str, Any]:
        """The keyword arguments of :func:`~piezohyst.load_dataset`."""
        return {"u_col": self.u_col, "y_col": self.y_col, "t_col": self.t_col, "fs": self.fs,
                "resample": bool(self.resample), "units": self.units, "delimiter": self.delimiter,
                "decimal": self.decimal, "encoding": self.encoding}

    def to_dict(self) -> dict[str, Any]:
        """The options as plain data (the fleet's result records them)."""
        return asdict(self)


def fit_record(ds: Any, options: FitOptions | None = None) -> Any:
    """Identify one :class:`~piezohyst.data.Dataset` as ``piezohyst identify`` would.

    ``kind="pi"`` with ``method="lsq"`` (the default) is ``fit_pi(ds.u, ds.y, n=20)``, i.e.
    exactly ``ph.fit_pi(ds.u, ds.y)``.
    """
    from .identify import fit_bouc_wen, fit_model, fit_pi

    o = options or FitOptions()
    if o.kind == "bouc-wen" and o.method == "pso":
        return fit_bouc_wen(ds.u, ds.y, ds.dt, seed=o.seed, delay=o.delay, max_iter=o.max_iter,  # type: ignore[arg-type]
                            polish=o.polish)
    if o.kind == "prandtl-ishlinskii" and o.method in ("lsq", "pso"):
        return fit_pi(ds.u, ds.y, n=o.n or 20, method=o.method, seed=o.seed, delay=o.delay,  # type: ignore[arg-type]
                      max_iter=o.max_iter)
    return fit_model(ds.u, ds.y, ds.dt, o.kind, delay=o.delay, n=o.n, seed=o.seed,  # type: ignore[arg-type]
                     bouc_wen_options={"max_iter": o.max_iter, "polish": o.polish}, history=o.history)


# ------------------------------------------------------------------------------------------------
def find_records(paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]]) -> list[tuple[str, Path]]:
    """The records named by ``paths``: ``(record name, file)`` pairs, in the order given.

    Each path is a file (taken as it is), a folder (its data files, :data:`DATA_SUFFIXES`, not
    recursing: give ``"folder/**/*.csv"`` for that) or a glob pattern. Record names are the
    file names without suffix, with characters other than letters (of any script), digits, ``.``,
    ``_`` and ``-`` replaced by ``_``; two files with the same name get their folders prefixed
    (``lot1__a001``); names still alike (``act 01`` and ``act_01``), or longer than 200 bytes, end
    in a short hash of the file's path.

    Raises
    ------
    FileNotFoundError
        A path that is neither a file nor a folder and matches nothing.
    ValueError
        No records at all, or a folder without data files.
    """
    items = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    if not items:
        raise ValueError("paths is empty: give data files, folders or glob patterns")
    files: list[Path] = []
    seen: set[Path] = set()

    def add(p: Path) -> None:
        key = p.resolve()
        if key not in seen:
            seen.add(key)
            files.append(p)

    for item in items:
        if not isinstance(item, (str, os.PathLike)):
            raise TypeError(f"paths must be file names, folders or glob patterns, got {type(item).__name__}")
        text = os.fspath(item)
        p = Path(text)
        if p.is_dir():
            found = _folder_records(p)
            if not found:
                raise ValueError(f"{p}: no data files ({', '.join(DATA_SUFFIXES)}) in this folder")
            for f in found:
                add(f)
        elif p.is_file():
            add(p)
        elif glob.has_magic(text):
            matches = sorted(glob.glob(text, recursive=True))
            if not matches:
                raise FileNotFoundError(f"{text}: no file matches this pattern")
            for m in matches:
                mp = Path(m)
                if mp.is_dir():
                    for f in _folder_records(mp):
                        add(f)
                elif mp.is_file() or mp.is_symlink():
                    add(mp)
        else:
            raise FileNotFoundError(f"{text}: no such file or folder")
    if not files:
        raise ValueError(f"no data files found in {[os.fspath(i) for i in items]}")
    return list(zip(_record_names(files), files))


def _folder_records(folder: Path) -> list[Path]:
    # a link to a file that is gone is a record too (its row says it cannot be read): it was
    # left out of the batch without a word (found by fuzzing)
    return sorted(f for f in folder.iterdir()
                  if (f.is_file() or f.is_symlink() and not f.is_dir()) and not f.name.startswith(".")
                  and f.suffix.lower() in DATA_SUFFIXES)


#: bytes of a record name at most (its model file adds ".json"; file systems allow 255)
_NAME_BYTES = 200


def _safe(text: str) -> str:
    # letters and digits of any script stay (压电1, Ω1 and µ1 all became "_1", and the batch was
    # refused as not unique: found by a helper)
    return re.sub(r"[^\w.-]+", "_", text).lstrip("._") or "record"


def _tagged(name: str, f: Path) -> str:
    """``name`` made unique by a short hash of the file's full path (stable from run to run),
    and cut to :data:`_NAME_BYTES` (a 251-character file name was fitted, then its model file
    could not be written, on every run: found by a helper)."""
    tag = "-" + hashlib.sha256(str(f.resolve()).encode("utf-8", "surrogateescape")).hexdigest()[:8]
    room = _NAME_BYTES - len(tag)
    cut = name.encode("utf-8", "surrogateescape")[:room].decode("utf-8", "ignore")
    return cut + tag


def _record_names(files: Sequence[Path]) -> list[str]:
    """Unique, file-system-safe names: the stem, or more of the path where names collide.

    A colliding name takes one more folder in front (``lot1__a001``), then the suffix too
    (``a001_csv``), until it is unique (ignoring case, for case-insensitive file systems).
    """
    from collections import Counter

    parts = [f.resolve().parts[:-1] for f in files]
    deepest = max(len(p) for p in parts)
    levels = [(d, False) for d in range(deepest + 1)] + [(d, True) for d in range(deepest + 1)]

    def name(i: int, level: int) -> str:
        depth, suffix = levels[level]
        f = files[i]
        stem = f.stem + ("_" + f.suffix.lstrip(".") if suffix and f.suffix else "")
        text = _safe("__".join([*parts[i][len(parts[i]) - depth:], stem] if depth else [stem]))
        return text if len(text.encode("utf-8", "surrogateescape")) <= _NAME_BYTES else _tagged(text, f)

    level = [0] * len(files)
    while True:
        names = [name(i, lv) for i, lv in enumerate(level)]
        count = Counter(n.casefold() for n in names)
        clash = [i for i, n in enumerate(names) if count[n.casefold()] > 1]
        if not clash:
            return names
        if any(level[i] == len(levels) - 1 for i in clash):
            # names that stay alike whatever is added ("act 01", "act_01", "Act_01"): each its
            # own hash, where the batch was refused
            names = [_tagged(name(i, 0), files[i]) if i in clash else n for i, n in enumerate(names)]
            return names
        for i in clash:
            level[i] += 1


# ------------------------------------------------------------------------------------------------
def _empty_row(record: str, path: str, options: FitOptions) -> dict[str, Any]:
    row: dict[str, Any] = dict.fromkeys(COLUMNS, float("nan"))
    row.update(record=record, file=path, status="error", error="", kind=options.kind, method=options.method,
               n_samples=0, delay_samples=0, n_warnings=0, warnings="", resumed=False, model_file="",
               outlier=False, outlier_reason="")
    return row


def _one_numba_thread() -> None:
    """This thread's numba parallel regions run on one thread (see the module docstring)."""
    import numba

    if numba.get_num_threads() != 1:
        numba.set_num_threads(1)


def _loop_row(u: Any, y: Any) -> tuple[dict[str, Any], list[str]]:
    from .analysis import loop_figures
    from .signals import estimate_period

    span = float(np.ptp(y))
    out: dict[str, Any] = {"span_um": span, "gain_um_per_v": span / float(np.ptp(u))}
    notes = []
    period = estimate_period(u)
    if period is None:
        notes.append("the input is not periodic: no loop width")
    else:
        try:
            lf = loop_figures(u, y, period=period)
            out.update(loop_width_um=lf.width, loop_width_percent=lf.width_percent)
        except ValueError as exc:
            notes.append(f"no loop width: {exc}")
    return out, notes


def identify_record(path: str | os.PathLike[str], options: FitOptions | None = None, *,
                    record: str | None = None, single_thread: bool = False, document: bool = True) -> dict[str, Any]:
    """Load one record, identify it and measure its loop: what each task of the fleet runs.

    Never raises for a bad record: a file that cannot be read or fitted gives a row with
    ``status="error"`` and the reason in ``error``.

    Parameters
    ----------
    path : path
        The data file (read with :func:`~piezohyst.load_dataset` and ``options``' data options).
    options : FitOptions, optional
        Default: ``FitOptions()`` (P-I by least squares).
    record : str, optional
        The record's name in the row (default: the file's stem).
    single_thread : bool
        Run numba's parallel regions on one thread (on a cluster's workers).
    document : bool
        Build the model file's document (``False`` where no file is written: a batch without
        ``out``, whose workers then neither build nor send it).

    Returns
    -------
    dict
        ``{"row": {...}, "document": model file document or None}``; the document (what
        :func:`~piezohyst.save_model` writes) carries the row and the options in
        ``extra["fleet"]``.
    """
    from ._blas import single_threaded_blas
    from ._fileio import to_jsonable
    from .data import load_dataset
    from .modelio import model_to_dict

    t0 = time.perf_counter()
    opts = options or FitOptions()
    p = os.fspath(path)
    row = _empty_row(record or _safe(Path(p).stem), p, opts)
    doc = None
    try:
        if single_thread:
            _one_numba_thread()
        # one record's products are small: a second BLAS thread only contends (piezohyst._blas)
        with single_threaded_blas(), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            ds = load_dataset(p, **opts.data_options())
            fit = fit_record(ds, opts)
            loop, notes = _loop_row(ds.u, ds.y)
        span = loop["span_um"]
        hold = fit.info.get("holdout") or {}
        said = list(fit.warnings) + [f"{w.category.__name__}: {w.message}" for w in caught] + notes
        row.update(loop)
        row.update(status="ok", kind=fit.model.kind, method=fit.method, n_samples=len(ds), fs_hz=ds.fs,
                   delay_samples=int(fit.delay), fit_rmse_um=float(fit.rmse),
                   fit_rmse_percent_of_span=100.0 * float(fit.rmse) / span if span > 0 else float("nan"),
                   holdout_rmse_um=float(hold["rmse"]) if hold.get("rmse") is not None else float("nan"),
                   holdout_percent_of_span=(float(hold["percent_of_span"]) if hold.get("percent_of_span")
                                            is not None else float("nan")),
                   n_warnings=len(said), warnings=" | ".join(said), fit_time_s=float(fit.time_s))
        if document:
            doc = model_to_dict(fit.model, fit=fit, dataset=ds)
    except Exception as exc:  # noqa: BLE001 - one bad record is a row, never a failed batch
        row.update(status="error", error=f"{type(exc).__name__}: {exc}")
    row["elapsed_s"] = time.perf_counter() - t0
    if doc is not None:
        doc["extra"] = to_jsonable({"fleet": {"row": row, "options": opts.to_dict()}})
    return {"row": row, "document": doc}


# ------------------------------------------------------------------------------------------------
def _file_sha256(path: Path) -> str | None:
    try:
        h = hashlib.sha256()
        with open(path, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
        return h.hexdigest()
    except OSError:
        return None  # not readable here (only on the workers): not checked


def _effective_options(d: dict[str, Any]) -> dict[str, Any]:
    """The options as they act on the fit: the P-I default size written out (``n`` None is 20 for
    ``lsq`` and ``pso``), and what least squares does not use (``seed``, ``max_iter``, ``polish``)
    left out. ``--n 20`` and ``--seed 5`` with ``lsq`` were "other options" than a default run's,
    and every record was refused for a refit that would change nothing (found by fuzzing)."""
    out = dict(d)
    if out.get("kind") == "prandtl-ishlinskii" and out.get("method") in ("lsq", "pso") and out.get("n") is None:
        out["n"] = 20
    if out.get("method") == "lsq":
        for k in ("seed", "max_iter", "polish"):
            out.pop(k, None)
    return out


def _option_changes(before: Any, now: FitOptions, path: Path, samples_sha256: Any) -> str:
    """What differs between the options a model file records and this run's, as they act on the
    fit (:func:`_effective_options`; "" if nothing). Options that say how to read the file
    (``u_col``, ``delimiter``, ...) count only where they read other samples from ``path`` than
    the model was fitted on (their SHA-256): ``--u-col u_V`` naming the column found without it,
    or ``--delimiter ,`` for a comma file, refused the whole batch (found by a helper)."""
    if not isinstance(before, dict):
        return "no options recorded"
    now_d = _effective_options(json.loads(json.dumps(now.to_dict())))
    then = _effective_options(before)
    keys = [k for k, v in now_d.items() if then.get(k) != v]
    reading = set(now.data_options())
    if keys and all(k in reading for k in keys) and _same_samples(path, now, samples_sha256):
        return ""
    return "; ".join(f"{k} {then.get(k)!r} there, {now_d[k]!r} now" for k in keys)


def _resumed_row(model_path: Path, record: str, path: Path, opts: FitOptions) -> tuple[dict[str, Any], str]:
    """The row of a record whose model file exists, read back from that file (checked), and
    how the options it was made with differ from ``opts`` ("" when they do not)."""
    from .modelio import MAX_FILE_BYTES, schema_version

    row = _empty_row(record, str(path), opts)
    row.update(resumed=True, model_file=str(model_path))
    # (summary.csv of a command-line run said only "force=True": found by fuzzing)
    redo = "; refit it with force=True (--force at the command line)"
    try:
        if model_path.stat().st_size > MAX_FILE_BYTES:
            raise ValueError(f"larger than {MAX_FILE_BYTES} bytes")
        doc = json.loads(model_path.read_text(encoding="utf-8"))
        schema_version(doc, str(model_path))
    except (OSError, ValueError, RecursionError) as exc:
        row["error"] = f"cannot read the existing model file {model_path} ({exc}){redo}"
        return row, ""
    fleet = doc["extra"].get("fleet") if isinstance(doc.get("extra"), dict) else None
    if not isinstance(fleet, dict) or not isinstance(fleet.get("row"), dict):
        row["error"] = f"{model_path} exists but was not written by piezohyst fleet{redo}"
        return row, ""
    changes = _option_changes(fleet.get("options"), opts, path, (doc.get("data") or {}).get("sha256"))
    if changes:
        row["error"] = f"{model_path} was identified with other options ({changes}){redo}"
        return row, changes
    recorded = (doc.get("data") or {}).get("source_sha256")
    now = _file_sha256(path)
    if recorded and now and recorded != now and not _same_samples(path, opts, (doc.get("data") or {}).get("sha256")):
        source = fleet["row"].get("file")
        if isinstance(source, str) and not _same_path(source, path):
            # (another lot's actuator-001 in the same out folder was "changed", and the advice,
            # force, replaced the other lot's model files: found by a helper)
            row["error"] = (f"{model_path} was identified from another file, {source}, not from {path} (a record "
                            f"of the same name: another lot?); give this batch another out folder")
        else:
            row["error"] = f"{path} changed since {model_path} was identified from it (its samples differ){redo}"
        return row, ""
    for k, v in fleet["row"].items():
        if k in row and k not in ("record", "file", "resumed", "model_file", "outlier", "outlier_reason"):
            row[k] = float("nan") if v is None and isinstance(row[k], float) else v
    return row, ""


def _same_path(recorded: str, path: Path) -> bool:
    """Whether a path a model file records names ``path`` (as given then, or resolved)."""
    try:
        return recorded == str(path) or Path(recorded).resolve() == path.resolve()
    except (OSError, ValueError, RuntimeError):
        return False


def _same_samples(path: Path, opts: FitOptions, samples_sha256: Any) -> bool:
    """Whether a record whose file's bytes changed still holds the samples its model was fitted on
    (their own SHA-256, as the model file records it): an edited comment line or other line endings
    made a record "changed" and dropped it from the batch until a refit (found by fuzzing)."""
    if not isinstance(samples_sha256, str):
        return False
    from .data import load_dataset

    try:
        return bool(load_dataset(path, **opts.data_options()).sha256 == samples_sha256)
    except (OSError, ValueError):
        return False


def _write_model(doc: dict[str, Any], path: Path, force: bool) -> Path:
    """Write a model document as :func:`~piezohyst.save_model` does (atomic; refuses to overwrite)."""
    from ._fileio import atomic_write_text, producer

    doc = dict(doc)
    doc["producer"] = producer()  # the client's command line, not the worker's
    return atomic_write_text(path, json.dumps(doc, indent=2, allow_nan=False) + "\n", force=force)


#: Seconds between a batch's progress lines at most, where standard error is not a terminal.
LOG_EVERY_S = 30.0


class _Progress:
    """A rich progress bar on stderr where it is a terminal, plain lines where it is not (a log),
    or a user's callback, or nothing."""

    def __init__(self, progress: Any, total: int, where: str) -> None:
        self.callback = progress if callable(progress) else None
        self.bar = None
        self.done = 0
        self.total = total
        self.failed = 0
        from .progress import detect_mode

        # a batch's log (nohup, SLURM, CI) got no progress until the end, then one line cut at 80
        # columns (found by a helper): plain lines there, each tenth of the batch and at least
        # every LOG_EVERY_S; the bar on a terminal
        self.lines = progress is True and detect_mode() != "terminal"
        self.where = where
        self.started = self.last_line = time.monotonic()
        if progress is True and not self.lines:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            self.bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                                TextColumn("{task.fields[failed]} failed"), TimeElapsedColumn(),
                                TimeRemainingColumn(), console=Console(stderr=True), transient=False)
            self.task = self.bar.add_task(f"identifying on {where}", total=total, failed=0)

    def __enter__(self) -> _Progress:  # noqa: PYI034
        if self.bar is not None:
            self.bar.start()
        if self.lines:
            self._line(f"identifying {self.total} record{'s' if self.total != 1 else ''} on {self.where}")
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.stop()

    def _line(self, text: str) -> None:
        import sys

        stamp = time.strftime("%H:%M:%S")
        print(f"[{stamp}] {text}", file=sys.stderr, flush=True)
        self.last_line = time.monotonic()

    def advance(self, row: dict[str, Any]) -> None:
        self.done += 1
        self.failed += row["status"] != "ok"
        if self.bar is not None:
            self.bar.update(self.task, advance=1, failed=self.failed)
        if self.lines:
            now = time.monotonic()
            tenth = max(1, self.total // 10)
            if self.done == self.total or self.done % tenth == 0 or now - self.last_line >= LOG_EVERY_S:
                spent = now - self.started
                left = spent / self.done * (self.total - self.done)
                self._line(f"{self.done}/{self.total} records ({self.failed} failed), {spent:.0f} s"
                           + (f", about {left:.0f} s left" if self.done < self.total else ""))
        if self.callback is not None:
            self.callback(self.done, self.total, row)


#: Dask settings of the local cluster: its servers' periodic diagnostics run less often. With
#: distributed's defaults (event-loop tick every 20 ms, system monitor every 0.5 s, the nanny
#: polling worker memory every 0.1 s) an idle 2-worker cluster used 1.3 CPU-seconds per 5 s
#: (a quarter of a core, taken from the fits on a 2-core machine); with these, 0.4 (measured
#: here, same method). The tick only detects blocked event loops and the system monitor feeds the
#: dashboard (off by default); a runaway worker's memory is still checked twice a second.
#: The workers also start without distributed's ``MALLOC_TRIM_THRESHOLD_=65536`` (which hands
#: freed memory back to the system at once, so every record's arrays are page-faulted in anew):
#: it cost a serial loop of 40 records 16-25 % more CPU here; the thread limits stay.
#: And the workers' statistical profiler (a thread that samples every task's stack each 10 ms,
#: for the dashboard's profile page) is off: the workers of a 2-worker cluster spent 0.21
#: CPU-seconds per 3 s idle with it and 0.02 without, and 20 % of a batch's CPU went outside
#: the tasks with it against 7 % without (40 P-I records, measured here).
LOCAL_CLUSTER_CONFIG = {
    "distributed.nanny.pre-spawn-environ": {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1},
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.memory.monitor-interval": "500ms",
    "distributed.worker.profile.enabled": False,
}


def _check_workers(n: Any) -> None:
    """Refuse a number of local workers that is no positive integer, or more than the machine
    carries (:func:`~piezohyst._blas.too_many_workers`)."""
    from ._blas import too_many_workers

    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"workers must be a positive integer, got {n!r}")
    why = too_many_workers(int(n))
    if why is not None:
        raise ValueError(f"workers: {why.replace('pass its address', 'pass its address as client=')}")


def local_cluster(workers: int | None = None, *, dashboard_address: str | None = None) -> Any:
    """A ``distributed.Client`` on a new ``LocalCluster``: ``workers`` processes (default: the
    cores) of one thread each, on the loopback interface, started with ``NUMBA_NUM_THREADS=1``
    and :data:`LOCAL_CLUSTER_CONFIG`.

    Close it with ``client.close(); client.cluster.close()`` (or use it in a ``with`` block and
    close the cluster after).
    """
    import logging

    distributed = _require("distributed")
    import dask
    from dask.system import CPU_COUNT

    n = CPU_COUNT if workers is None else workers
    _check_workers(n)
    from distributed.deploy.spec import SpecCluster

    before = {id(c) for c in SpecCluster._instances}
    try:
        with dask.config.set(LOCAL_CLUSTER_CONFIG):  # read by the servers as they start; the nannies pass it on
            cluster = distributed.LocalCluster(
                n_workers=int(n), threads_per_worker=1, processes=True, host="127.0.0.1",
                dashboard_address=dashboard_address, silence_logs=logging.ERROR,
                # without a dashboard the scheduler still serves HTTP (health, metrics), on 8787 by
                # default: on a shared machine that port is often taken, and distributed then warns
                # and moves; any free loopback port says the same without the warning
                scheduler_kwargs=None if dashboard_address is not None else {"dashboard_address": "127.0.0.1:0"},
                env={"NUMBA_NUM_THREADS": "1"})
        return distributed.Client(cluster)
    except BaseException:
        # interrupted (Ctrl-C, SIGTERM) or failed while starting: close what was started here, quietly
        _close_quietly([c for c in list(SpecCluster._instances) if id(c) not in before])
        raise


def _close_quietly(clusters: list[Any]) -> None:
    """Close clusters whose start was interrupted, and keep distributed's exit hook from trying
    again: a Ctrl-C or SIGTERM 2-3 s into ``fleet identify`` gave its one-line message, then 25
    lines of traceback from that hook (``close_clusters``: ``AssertionError: Status.init``, or
    ``RuntimeError: Nanny failed to start``: found by a helper). Their workers' processes are
    ended by the close, or else by multiprocessing as this process exits."""
    import logging

    from distributed.deploy.spec import SpecCluster

    for cluster in clusters:
        _drop_unretrieved_start_failures(getattr(getattr(cluster, "loop", None), "asyncio_loop", None))
        try:
            # a half-started cluster's close may fail, and say so in distributed's log: both quiet
            with _quiet_logs("distributed"):
                cluster.close(timeout=10)
        except Exception:  # noqa: BLE001, S110 - what a half-started cluster's close can raise; it is going anyway
            pass
        finally:
            SpecCluster._instances.discard(cluster)
            logging.getLogger("distributed").debug("closed a cluster whose start was interrupted")


def _drop_unretrieved_start_failures(loop: Any) -> None:
    """Keep ``loop`` from logging, as its tasks are collected, the start-up failures of workers
    whose start was interrupted ("Task exception was never retrieved ... RuntimeError: Nanny
    failed to start.", 20 lines); every other message goes where it went."""
    if loop is None or getattr(loop.get_exception_handler(), "_piezohyst_filter", False):
        return
    previous = loop.get_exception_handler()

    def handler(lp: Any, context: dict[str, Any]) -> None:
        exc = context.get("exception")
        if (str(context.get("message", "")).startswith("Task exception was never retrieved")
                and isinstance(exc, (RuntimeError, TimeoutError))
                and ("failed to start" in str(exc) or "start timed out" in str(exc))):
            return
        if previous is not None:
            previous(lp, context)
        else:
            lp.default_exception_handler(context)

    handler._piezohyst_filter = True  # type: ignore[attr-defined]
    loop.set_exception_handler(handler)


@contextlib.contextmanager
def _quiet_logs(name: str) -> Any:
    import logging

    log = logging.getLogger(name)
    level = log.level
    log.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        log.setLevel(level)


def _speaks_first(address: str, timeout: float) -> None:
    """Refuse a plain-TCP address whose listener is not a Dask scheduler, within ``timeout``.

    A scheduler writes its handshake as soon as a connection is accepted; a dashboard, a web
    server or a silent listener writes nothing, and ``distributed.Client`` then waited past its
    own timeout without end (found by a helper: the dashboard's port given, killed after 60 s).
    Addresses of other schemes (tls://, inproc://) go to distributed as they are."""
    import socket
    from urllib.parse import urlsplit

    text = address if "://" in address else f"tcp://{address}"
    parts = urlsplit(text)
    if parts.scheme != "tcp" or not parts.hostname:
        return
    try:
        port = parts.port
    except ValueError:
        return  # distributed names a bad port itself
    if port is None:
        return
    try:
        with socket.create_connection((parts.hostname, port), timeout=timeout) as sock:
            sock.settimeout(timeout)
            first = sock.recv(8)
    except socket.timeout:
        first = b""
    except OSError as exc:
        raise ConnectionError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s "
                              f"({type(exc).__name__}: {exc})") from None
    if not first:
        raise ConnectionError(f"{address} answers but is not a Dask scheduler: it sent no handshake within {timeout:g} s "
                              f"(a dashboard's port? a scheduler listens on 8786 unless told otherwise)")


def _connect(address: str, timeout: float) -> Any:
    distributed = _require("distributed")
    _speaks_first(address, timeout)
    try:
        return distributed.Client(address, timeout=timeout)
    except ValueError as exc:
        raise ValueError(f"{address!r} is not a Dask scheduler address such as tcp://host:8786 ({exc})") from None
    except (OSError, TimeoutError) as exc:
        raise ConnectionError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s "
                              f"({type(exc).__name__}: {exc})") from None
    except (MemoryError, OverflowError, TypeError, KeyError) as exc:
        # (a listener that wrote something else: its bytes read as Dask frames, "not enough memory
        # for this run (Unable to allocate 3.07 EiB)": found by a helper)
        raise ConnectionError(f"{address} answers but does not speak Dask's protocol ({type(exc).__name__}); "
                              f"is it a Dask scheduler's address?") from None


def _describe(client: Any) -> str:
    try:
        info = client.scheduler_info()
        n = len(info.get("workers", {}))
        return f"{n} Dask worker{'s' if n != 1 else ''} ({info.get('address', '?')})"
    except Exception:  # noqa: BLE001  # pragma: no cover - only a description
        return "a Dask cluster"


def _cluster_task(path: str, options: FitOptions, record: str, document: bool = True) -> dict[str, Any]:
    """What a worker runs for one record: :func:`identify_record` on one numba thread."""
    return identify_record(path, options, record=record, single_thread=True, document=document)


def _cluster_group(paths: list[str], options: FitOptions, records: list[str],
                   document: bool = True) -> list[dict[str, Any]]:
    """What a worker runs for a group of quick records: :func:`identify_record` for each, in turn."""
    return [identify_record(p, options, record=r, single_thread=True, document=document)
            for p, r in zip(paths, records)]


#: Work a task should carry, in seconds. distributed spends about a millisecond of scheduler,
#: worker and client time on every task (its documentation advises tasks of 100 ms or more);
#: a P-I record of 20,000 samples takes about 20 ms, so one task per record spent a fifth of the
#: cores on the bookkeeping (measured: 40 records on 2 local workers, 1.1-1.3x serial).
TASK_SECONDS = 0.1
#: Tasks per worker that a batch keeps at least, so that a slow worker or a slow record cannot
#: leave the others idle at the end.
TASKS_PER_WORKER = 4


def group_size(record_seconds: float, records: int, workers: int) -> int:
    """How many records one task carries: enough for :data:`TASK_SECONDS` of work, but never so
    many that the ``records`` leave fewer than :data:`TASKS_PER_WORKER` tasks per worker.

    >>> group_size(0.02, 36, 2), group_size(2.0, 36, 2), group_size(0.001, 10, 2)
    (5, 1, 2)
    """
    if not record_seconds > 0.0:  # nothing measured (or a clock that did not move): one per task
        return 1
    most = max(1, math.ceil(records / (TASKS_PER_WORKER * max(workers, 1))))
    if most * record_seconds < TASK_SECONDS:  # (also keeps the division below finite)
        return most
    return min(most, math.ceil(TASK_SECONDS / record_seconds))


def group_sizes(records: int, size: int, workers: int) -> list[int]:
    """The sizes of the successive groups of ``records`` records, at most ``size`` each: each
    takes a ``2 * workers``-th of the records still left (guided self-scheduling), so the groups
    shrink towards single records at the end and no worker waits long for the last one.

    >>> group_sizes(37, 5, 2)
    [5, 5, 5, 5, 5, 3, 3, 2, 1, 1, 1, 1]
    """
    sizes = []
    left = records
    while left > 0:
        k = max(1, min(size, math.ceil(left / (2 * max(workers, 1)))))
        sizes.append(k)
        left -= k
    return sizes


def _workers_of(client: Any) -> int:
    try:
        return max(1, sum(client.nthreads().values()))
    except Exception:  # noqa: BLE001 - only a sizing hint
        return 1


#: Seconds a finished task's result may wait to be fetched together with others (see
#: :func:`_run_on_client`): at most this much work is lost to an interrupted batch.
FETCH_EVERY_S = 0.5


def _run_on_client(client: Any, jobs: list[tuple[str, Path]], opts: FitOptions,
                   done: Callable[[str, dict[str, Any]], None], document: bool = True) -> None:
    """One task per record, or per group of records when a record is quick; gathered as they finish.

    The first records (two per worker, at most) go out one per task; what the first of them to
    come back took sizes the groups of the rest, sent while the workers fit the others
    (:func:`group_size`, :func:`group_sizes`: shrinking towards single records at the end): a
    batch of Bouc-Wen fits (seconds each) stays one task per record; a batch of P-I fits
    (milliseconds) goes out in groups, so that distributed's per-task cost does not eat the
    speed-up. Each batch is one ``client.map``. Finished tasks are announced by the scheduler;
    their results are fetched together, one ``gather`` for all that finished since the last one,
    as soon as two per worker have finished or :data:`FETCH_EVERY_S` has passed (and at once
    while the first records size the groups): a fetch per task cost the client and the scheduler
    about as much CPU again as the rest of the batch (measured: 16 tasks on 2 local workers, 55
    against 30 ms), and on two cores that CPU is the workers'.
    """
    from distributed import as_completed

    token = uuid.uuid4().hex[:8]
    n_jobs, n_done = len(jobs), 0
    workers = _workers_of(client)
    n_probe = min(len(jobs), 2 * workers)
    probe, rest = jobs[:n_probe], jobs[n_probe:]
    keys = [f"piezohyst-fleet-{token}-{i}-{name}" for i, (name, _) in enumerate(probe)]
    futures = client.map(_cluster_task, [str(path) for _, path in probe], [opts] * len(probe),
                         [name for name, _ in probe], [document] * len(probe), pure=False, key=keys)
    #: future key -> (future, the records it carries)
    pending: dict[str, tuple[Any, list[tuple[str, Path]]]] = {
        fut.key: (fut, [job]) for fut, job in zip(futures, probe)}
    seen: list[float] = []
    queue = as_completed(futures)
    finished: list[Any] = []  # announced, result not fetched yet
    last_fetch = time.monotonic()

    def send_rest() -> None:
        size = group_size(min(seen) if seen else 0.0, len(rest), workers)
        groups, start = [], 0
        for k in group_sizes(len(rest), size, workers):
            groups.append(rest[start:start + k])
            start += k
        keys = [f"piezohyst-fleet-{token}-{i}-{g[0][0]}-x{len(g)}" for i, g in enumerate(groups, n_probe)]
        if size == 1:
            futs = client.map(_cluster_task, [str(g[0][1]) for g in groups], [opts] * len(groups),
                              [g[0][0] for g in groups], [document] * len(groups), pure=False, key=keys)
        else:
            futs = client.map(_cluster_group, [[str(p) for _, p in g] for g in groups], [opts] * len(groups),
                              [[n for n, _ in g] for g in groups], [document] * len(groups), pure=False, key=keys)
        pending.update({fut.key: (fut, g) for fut, g in zip(futs, groups)})
        queue.update(futs)
        rest.clear()

    def results_of(futs: list[Any]) -> list[Any]:
        """Each future's result, or the exception it ended with; one gather for the finished ones."""
        ok = [f for f in futs if f.status == "finished"]
        got: dict[str, Any] = {}
        if ok:
            try:
                got = dict(zip([f.key for f in ok], client.gather(ok, errors="raise")))
            except Exception:  # noqa: BLE001 - a worker lost meanwhile: each one on its own
                got = {}
        out = []
        for f in futs:
            if f.key in got:
                out.append(got[f.key])
                continue
            try:
                out.append(f.result())
            except BaseException as exc:  # noqa: BLE001 - the task's error becomes its records' rows
                out.append(exc)
        return out

    def retry_one_by_one(carried: list[tuple[str, Path]]) -> None:
        """A group's records again, each a task of its own: one record that kills its worker
        failed the records grouped with it (KilledWorker on all six: found by a helper)."""
        keys = [f"piezohyst-fleet-{token}-again-{name}" for name, _ in carried]
        futs = client.map(_cluster_task, [str(p) for _, p in carried], [opts] * len(carried),
                          [n for n, _ in carried], [document] * len(carried), pure=False, key=keys)
        pending.update({fut.key: (fut, [job]) for fut, job in zip(futs, carried)})
        queue.update(futs)

    def fetch() -> None:
        nonlocal last_fetch, n_done
        batch = finished[:]
        finished.clear()
        last_fetch = time.monotonic()
        for fut, res in zip(batch, results_of(batch)):
            if isinstance(res, BaseException) and _cluster_lost(client, res):
                raise ConnectionError(
                    f"lost the Dask scheduler after {n_done} of {n_jobs} records ({type(res).__name__}: "
                    f"{' '.join(str(res).split())}); the "
                    f"model files of those identified are written: run the same command again to resume") from None
            _, carried = pending.pop(fut.key)
            if isinstance(res, BaseException) and len(carried) > 1:
                retry_one_by_one(carried)
                fut.release()
                continue
            n_done += len(carried)
            if isinstance(res, list) and len(res) == len(carried):
                results = res
            else:  # one record's result, or the exception that a whole task ended with
                results = [res] * len(carried)
            for (name, path), one in zip(carried, results):
                if isinstance(one, BaseException) or not isinstance(one, dict):
                    row = _empty_row(name, str(path), opts)  # the worker died (KilledWorker), was cancelled, ...
                    row["error"] = f"the task failed on the cluster: {type(one).__name__}: {one}"
                    one = {"row": row, "document": None}
                elif one["row"]["status"] == "ok":
                    seen.append(float(one["row"]["elapsed_s"]))
                done(name, one)
            fut.release()

    probes_out = len(probe)
    try:
        for fut in queue:
            finished.append(fut)
            probes_out -= fut.key in keys
            if (rest or queue.count() == 0 or len(finished) >= 2 * workers
                    or time.monotonic() - last_fetch >= FETCH_EVERY_S):
                fetch()
            # the rest goes out with the first record back, while every worker still has a second
            # one to fit (waiting for more left both workers idle for a round trip, 20 ms of 0.8 s
            # here); a cold first record only makes the groups smaller
            if rest and (seen or probes_out == 0):
                send_rest()
        if finished:
            fetch()
    finally:
        if pending:  # interrupted: do not leave the scheduler running the rest
            try:
                client.cancel([fut for fut, _ in pending.values()])
            except Exception:  # noqa: BLE001, S110 - a scheduler already gone has nothing left to run
                pass


def _cluster_lost(client: Any, exc: BaseException) -> bool:
    """Whether a task's error is the client's lost connection to its scheduler, not the record's:
    every task then ends cancelled, and the batch was reported as 30 records that "failed on the
    cluster", with exit code 0 (found by a helper: the scheduler killed mid-batch)."""
    text = f"{type(exc).__name__}: {exc}"
    if "scheduler-connection-lost" in text:
        return True
    return type(exc).__name__ in ("CancelledError", "FutureCancelledError", "CommClosedError") and \
        getattr(client, "status", "running") != "running"


def identify_many(
    paths: Any, *, kind: str = "pi", client: Any = None, out: str | os.PathLike[str] | None = None,
    force: bool = False, workers: int | None = None, progress: bool | Callable[..., Any] = False,
    outlier_mads: float = OUTLIER_MADS, timeout: float = 30.0, histograms: bool = False, **options: Any,
) -> Any:
    """Identify every record of a batch, one Dask task per record (quick records in small groups); one row per record.

    Parameters
    ----------
    paths : path, glob or sequence of them
        Data files, folders (their data files) or glob patterns (:func:`find_records`).
    kind : str
        ``"pi"`` (``ph.fit_pi``), ``"bouc-wen"`` (``ph.fit_bouc_wen``), ``"auto"`` or any other
        kind (``ph.fit_model``); see the module docstring.
    client : None, "serial", str or distributed.Client
        ``None``: a ``LocalCluster`` (``workers`` processes, one thread each) made and closed for
        this call; ``"serial"``: no Dask, a loop in this process; a scheduler address
        (``"tcp://host:8786"``); or your own ``distributed.Client`` (left open).
    out : path, optional
        Folder for ``models/<record>.json`` and ``summary.csv`` (+ ``.parquet`` with pyarrow).
        Records whose model file is already there are not fitted again (see Resuming).
    force : bool
        Refit and overwrite existing model files.
    workers : int, optional
        Workers of the local cluster (default: the cores).
    progress : bool or callable
        ``True``: a progress bar on stderr; a callable is called as ``progress(done, total, row)``
        after each record.
    outlier_mads : float
        Flag actuators further than this many MADs from the median (:func:`batch_statistics`).
    timeout : float
        Seconds to wait for the scheduler when ``client`` is an address.
    histograms : bool
        Also write ``out/fleet_histograms.png`` (:func:`plot_histograms`, as the command line
        does), published together with the summary files: an interrupted run leaves the previous
        set or the new one, never files of two runs (:func:`write_summary`).
    **options
        :class:`FitOptions` (``method``, ``n``, ``seed``, ``max_iter``, ``polish``, ``delay``,
        ``u_col``, ``y_col``, ``t_col``, ``fs``).

    Returns
    -------
    pandas.DataFrame
        One row per record, in the order of ``paths``, with the columns :data:`COLUMNS`.

    Raises
    ------
    piezohyst._fileio.FolderBusy
        Another run is writing in ``out`` (it holds the folder's lock, :data:`LOCK_FILE`): refused
        at once, naming the folder and that run's process id.
    piezohyst._fileio.OutputError
        A model file could not be written for want of space (``ENOSPC``, ``EDQUOT``) or on a
        read-only file system: the batch stops there, naming the folder; the model files written
        so far stay, and a rerun resumes from them.

    Examples
    --------
    >>> df = ph.fleet.identify_many("batch/", kind="pi", out="fleet-out")      # doctest: +SKIP
    >>> df[df.outlier][["record", "gain_um_per_v", "outlier_reason"]]          # doctest: +SKIP
    """
    pd = _require("pandas")
    unknown = sorted(set(options) - {f.name for f in fields(FitOptions)} - {"kind"})
    if unknown or "kind" in options:
        raise TypeError(f"identify_many() got unknown option(s) {unknown or ['kind (twice)']}; the options are "
                        f"{[f.name for f in fields(FitOptions) if f.name != 'kind']}")
    opts = FitOptions(kind=kind, **options)
    # checked before any record is fitted (found by fuzzing: a NaN threshold failed at the end, in
    # batch_statistics, after every fit, under another name)
    outlier_mads = as_scalar("outlier_mads", outlier_mads, positive=True)
    if not isinstance(paths, (str, os.PathLike)) and not hasattr(paths, "__iter__"):
        raise TypeError(f"paths must be a file, a folder, a glob or a list of them, got {type(paths).__name__}")
    as_flag("force", force)  # (force="no" refitted everything: found by fuzzing)
    as_flag("histograms", histograms)
    if not (isinstance(client, str) or client is None or hasattr(client, "submit")):
        raise TypeError(f"client must be None, 'serial', a scheduler address or a distributed.Client, "
                        f"got {type(client).__name__}")
    if workers is not None and client is not None:
        raise ValueError("workers sizes the local cluster made when client is None; with a client or a scheduler, "
                         "the cluster has the workers it has")
    if workers is not None:  # up front, not after the records are read
        _check_workers(workers)
    records = find_records(paths)
    out_dir = Path(out) if out is not None else None
    if out_dir is not None and out_dir.exists() and not out_dir.is_dir():
        raise NotADirectoryError(f"{out_dir}: exists and is not a folder: a batch writes into a folder (out= in "
                                 f"Python, --out at the command line)")
    with contextlib.ExitStack() as held:
        if out_dir is not None:
            # one run at a time per out folder: two at once each took the other's new model files
            # for files that "appeared while this run worked", and their summaries marked records
            # as errors whose model files were there (found by a helper)
            from ._fileio import folder_lock

            if not out_dir.exists():  # the folder the lock makes, removed if the run leaves it empty
                held.callback(_remove_empty_folder, out_dir)
            held.enter_context(folder_lock(out_dir, LOCK_FILE, "another piezohyst fleet run"))
        return _identify_locked(pd, records, out_dir, opts, client, force, workers, progress, outlier_mads,
                                timeout, histograms)


def _remove_empty_folder(folder: Path) -> None:
    with contextlib.suppress(OSError):
        folder.rmdir()  # (fails, as it should, where anything is in it)


#: The lock file of an out folder while a batch writes there (:func:`~piezohyst._fileio.folder_lock`):
#: hidden, no data suffix, outside ``models/``; removed at the end.
LOCK_FILE = ".piezohyst-fleet.lock"

#: Errors of a model file that no other record's could escape (the disk, not the record): the
#: batch stops at the first (it fitted all 20 records of a full disk, each an error row, then
#: failed on the summary: found by a helper).
DISK_ERRNOS = frozenset(e for e in (getattr(errno, n, None) for n in ("ENOSPC", "EDQUOT", "EROFS")) if e is not None)


def _disk_errno(exc: BaseException) -> int | None:
    """The errno of :data:`DISK_ERRNOS` behind ``exc`` (itself or what it was raised from), if any."""
    seen: set[int] = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:
        if isinstance(cur, OSError) and cur.errno in DISK_ERRNOS:
            return cur.errno
        seen.add(id(cur))
        cur = cur.__cause__ or cur.__context__
    return None


def _identify_locked(pd: Any, records: list[tuple[str, Path]], out_dir: Path | None, opts: FitOptions,
                     client: Any, force: bool, workers: int | None, progress: Any, outlier_mads: float,
                     timeout: float, histograms: bool) -> Any:
    """:func:`identify_many` from the out folder's checks on, its lock held."""
    models_dir = None
    if out_dir is not None:
        check_batch_files(out_dir, force)  # before the fits, not after an hour of them
        models_dir = out_dir / "models"
        inside = out_dir.resolve()
        records = [(n, p) for n, p in records if inside not in p.resolve().parents]  # not our own summary
        if not records:
            raise ValueError(f"every file given is inside out={out_dir}; nothing to identify")
    rows: dict[str, dict[str, Any]] = {}
    jobs: list[tuple[str, Path]] = []
    stale = []
    for name, path in records:
        mp = models_dir / f"{name}.json" if models_dir is not None else None
        if mp is not None and mp.exists() and not force:
            rows[name], changes = _resumed_row(mp, name, path, opts)
            if changes:
                stale.append((mp, changes))
        else:
            jobs.append((name, path))
    if stale:  # one mistake, one message (not a thousand error rows)
        raise ValueError(f"{models_dir} holds {len(stale)} model file(s) identified with other options than this "
                         f"run's ({stale[0][0].name}: {stale[0][1]}); give another out folder, or force=True "
                         "to refit them")

    def done(name: str, res: dict[str, Any]) -> None:
        row = res["row"]
        if res["document"] is not None and models_dir is not None:
            try:
                row["model_file"] = str(_write_model(res["document"], models_dir / f"{name}.json", force))
            except OSError as exc:
                code = _disk_errno(exc)
                if code is not None:  # every record after it would fail alike: stop here
                    from ._fileio import OutputError

                    kept = sum(1 for r in rows.values() if r["model_file"] and not r["resumed"])
                    err = OutputError(
                        f"cannot write model files in {models_dir}: {os.strerror(code)} (at record {name}); the "
                        f"batch stopped there, the {kept} model file(s) this run wrote are kept: make room (or "
                        f"give another out folder) and run the same command again to resume")
                    err.errno = code
                    raise err from exc
                row.update(status="error", error=f"fitted, but the model file could not be written: {exc}")
        rows[name] = row
        bar.advance(row)

    own = None
    try:
        if client == "serial" or not jobs:  # nothing to fit: no cluster to start
            where = "this process (serial)" if client == "serial" else "no cluster (every record read back)"
        elif client is None or isinstance(client, str):
            own = local_cluster(workers) if client is None else _connect(client, timeout)
            where = _describe(own)
        else:
            where = _describe(client)
        if models_dir is not None and jobs:
            models_dir.mkdir(parents=True, exist_ok=True)
        with _Progress(progress, len(jobs), where) as bar:
            if client == "serial" or not jobs:
                for name, path in jobs:
                    done(name, identify_record(path, opts, record=name, document=models_dir is not None))
            else:
                _run_on_client(own if own is not None else client, jobs, opts, done, document=models_dir is not None)
    finally:
        if own is not None:
            cluster = own.cluster if client is None else None
            own.close()
            if cluster is not None:
                cluster.close()
    df = pd.DataFrame.from_records([rows[n] for n, _ in records], columns=list(COLUMNS))
    stats = batch_statistics(df, threshold=outlier_mads)
    df = stats.table
    if out_dir is not None:
        figure = _histogram_figure(stats, outlier_mads) if histograms else None
        try:
            write_summary(df, out_dir, force=force, figure=figure)
        finally:
            if figure is not None:
                import matplotlib.pyplot as plt

                plt.close(figure)
    if models_dir is not None and models_dir.is_dir():
        # model files of records no longer in the batch (renamed, removed) stayed without a word
        # (found by fuzzing): named, not removed (they are the user's results)
        names = {n for n, _ in records}
        df.attrs["orphaned_model_files"] = sorted(str(q) for q in models_dir.glob("*.json") if q.stem not in names)
    return df


#: The files a batch writes in its out folder besides ``models/``, which a later run of the same
#: batch replaces (the command line writes the histograms)
BATCH_FILES = ("summary.csv", "summary.parquet", "fleet_histograms.png")
#: The histograms' file name in the out folder.
HISTOGRAMS = BATCH_FILES[2]


def _written_by_a_fleet(path: Path) -> bool:
    """Whether ``path`` is a file a batch wrote: a summary whose columns start as this module's
    (of any version), or a PNG whose metadata name piezohyst."""
    try:
        if path.suffix == ".csv":
            with open(path, encoding="utf-8", errors="replace", newline="") as fh:
                first = fh.readline()
            return first.split(",")[:3] == list(COLUMNS[:3])
        if path.suffix == ".parquet":
            import pyarrow.parquet as pq

            return list(pq.read_schema(path).names[:3]) == list(COLUMNS[:3])
        if path.suffix == ".png":
            with open(path, "rb") as fh:
                head = fh.read(1 << 16)
            return head.startswith(b"\x89PNG") and b"piezohyst" in head
    except Exception:  # noqa: BLE001 - unreadable, or not what its name says: not ours
        return False
    return False


def check_batch_files(out: str | os.PathLike[str], force: bool) -> None:
    """Refuse (OverwriteRefused) where ``out`` holds a ``summary.csv``, ``summary.parquet`` or
    ``fleet_histograms.png`` that no batch wrote, unless ``force``: a rerun of a batch replaces
    its own summary (that is how it resumes), but a user's own file of that name was replaced
    without a word (found by a helper)."""
    from ._fileio import OverwriteRefused

    if force:
        return
    for name in BATCH_FILES:
        p = Path(out) / name
        if os.path.lexists(p) and not _written_by_a_fleet(p):
            raise OverwriteRefused(
                f"{p} exists and is not a file a piezohyst fleet wrote; not replacing it: give another out folder, "
                f"or replace it and refit every record (force=True in Python, --force at the command line)")


def write_summary(df: Any, out: str | os.PathLike[str], *, force: bool = False, figure: Any = None) -> list[Path]:
    """Write ``out/summary.csv`` (and ``summary.parquet`` when pyarrow is installed), and
    ``figure`` (a matplotlib figure, optional) as ``out/fleet_histograms.png``, replacing a
    previous batch's; a file of those names that no batch wrote is refused unless ``force``
    (:func:`check_batch_files`). The files are written to temporary names first and published
    together (:func:`~piezohyst._fileio.atomic_write_files`): an interrupted run leaves the
    previous set or this one, never files of two runs (summary.csv of one run beside the
    histograms of another, after a Ctrl-C between them: found by a helper). Each row's
    ``written_by`` says what wrote the file (package, version, command line, time: the summary
    keeps no comment line, so that every spreadsheet and ``pandas.read_csv`` reads it as it is).
    Returns the files written."""
    import importlib.util

    from ._fileio import atomic_write_files, producer

    out_dir = Path(out)
    check_batch_files(out_dir, force)
    table = df.assign(written_by=producer())
    writes: dict[Path, Callable[[Path], object]] = {out_dir / "summary.csv": lambda tmp: table.to_csv(tmp, index=False)}
    if importlib.util.find_spec("pyarrow") is not None:
        writes[out_dir / "summary.parquet"] = lambda tmp: table.to_parquet(tmp, index=False)
    if figure is not None:
        from .plots import figure_writer

        writes[out_dir / HISTOGRAMS] = figure_writer(figure, out_dir / HISTOGRAMS, note="piezohyst fleet: batch histograms")
    return atomic_write_files(writes, force=True)


def _histogram_figure(stats: "BatchStatistics", outlier_mads: float) -> Any:
    """The batch's histograms (:func:`plot_histograms`) under a title saying what they show."""
    df = stats.table
    drawn = stats.plot()
    figure = next(iter(drawn.values()))["ax"].figure
    figure.suptitle(f"{int((df['status'] == 'ok').sum())} actuators identified ({df['kind'].iloc[0]}); "
                    f"outliers beyond {outlier_mads:g} MADs marked", fontsize=10)
    return figure


# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BatchStatistics:
    """The distributions of a batch's figures and its outliers (from :func:`batch_statistics`).

    Attributes
    ----------
    distributions : pandas.DataFrame
        One row per figure (:data:`FIGURES`): ``label``, ``unit``, ``n``, ``median``, ``mad``,
        ``q05``, ``q25``, ``q75``, ``q95``, ``min``, ``max`` over the records that were identified.
    table : pandas.DataFrame
        The input rows with ``outlier`` (bool) and ``outlier_reason`` set.
    threshold : float
        Median absolute deviations beyond which a record is flagged.
    """

    distributions: Any
    table: Any
    threshold: float = OUTLIER_MADS
    values: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def outliers(self) -> Any:
        """The flagged rows."""
        return self.table[self.table["outlier"]]

    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON-ready): the distributions and the outliers with their reasons."""
        dist = {name: {k: (v.item() if hasattr(v, "item") else v) for k, v in r.items()}
                for name, r in self.distributions.to_dict(orient="index").items()}
        return {"threshold_mads": self.threshold, "distributions": dist,
                "outliers": [{"record": r, "reason": why} for r, why in
                             zip(self.outliers["record"], self.outliers["outlier_reason"])]}

    def plot(self, *, ax: Any = None, bins: Any = "auto") -> dict[str, dict[str, Any]]:
        """:func:`plot_histograms` of these statistics."""
        return plot_histograms(self, ax=ax, bins=bins)


def batch_statistics(df: Any, *, threshold: float = OUTLIER_MADS) -> BatchStatistics:
    """Distributions of gain, loop width and fit error over a batch, and its outliers.

    For each figure of :data:`FIGURES`, over the rows with ``status == "ok"`` and a finite
    value: the median, the median absolute deviation ``MAD = median(|x - median|)`` and
    quantiles. A record is an outlier when one of its figures lies more than ``threshold`` MADs
    from the median (when more than half of the batch shares one value, MAD is 0 and any record
    that differs from it is flagged); the reason names each figure, its value and how far out it
    is. Records that failed are not flagged (their ``error`` says why).

    Parameters
    ----------
    df : pandas.DataFrame
        Rows as :func:`identify_many` returns them (at least ``record``, ``status`` and the
        figures' columns).
    threshold : float
        In median absolute deviations (default 5).

    Returns
    -------
    BatchStatistics
    """
    pd = _require("pandas")
    # (np.int64(3) was refused and True taken as 1; a list failed on .columns: found by fuzzing)
    if isinstance(threshold, (bool, np.bool_)) or not (
            isinstance(threshold, (int, float, np.integer, np.floating)) and np.isfinite(threshold) and threshold > 0):
        raise ValueError(f"threshold must be a positive number of MADs, got {threshold!r}")
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"df must be the pandas DataFrame identify_many returns, got {type(df).__name__}")
    missing = [c for c in ("record", "status", *FIGURES) if c not in df.columns]
    if missing:
        raise ValueError(f"df lacks the column(s) {missing}; give the table identify_many returns")
    table = df.copy()
    ok = (table["status"] == "ok").to_numpy()
    reasons: list[list[str]] = [[] for _ in range(len(table))]
    dist = {}
    values = {}
    for col, (label, unit) in FIGURES.items():
        x = pd.to_numeric(table[col], errors="coerce").to_numpy(dtype=float)
        use = ok & np.isfinite(x)
        v = x[use]
        values[col] = v
        if v.size == 0:
            dist[col] = {"label": label, "unit": unit, "n": 0, **dict.fromkeys(
                ("median", "mad", "q05", "q25", "q75", "q95", "min", "max"), float("nan"))}
            continue
        med = float(np.median(v))
        mad = float(np.median(np.abs(v - med)))
        q = np.quantile(v, [0.05, 0.25, 0.75, 0.95])
        dist[col] = {"label": label, "unit": unit, "n": int(v.size), "median": med, "mad": mad,
                     "q05": float(q[0]), "q25": float(q[1]), "q75": float(q[2]), "q95": float(q[3]),
                     "min": float(v.min()), "max": float(v.max())}
        if v.size < 3:
            continue  # no batch to differ from
        for i in np.flatnonzero(use):
            d = abs(x[i] - med)
            where = "above" if x[i] > med else "below"
            if mad > 0 and d > threshold * mad:
                reasons[i].append(f"{label} {x[i]:.4g} {unit} is {d / mad:.1f} MADs {where} the batch median "
                                  f"{med:.4g}")
            elif mad == 0 and not np.isclose(x[i], med, rtol=1e-6, atol=0.0):
                # (a difference of 1e-8 was flagged as "gain 1 µm/V differs from the median 1":
                # found by a helper; now beyond a part in a million, with the digits that show it)
                reasons[i].append(f"{label} {x[i]:.10g} {unit} differs from the median {med:.10g} that most of "
                                  "the batch shares exactly")
    table["outlier"] = [bool(r) for r in reasons]
    table["outlier_reason"] = ["; ".join(r) for r in reasons]
    distributions = pd.DataFrame.from_dict(dist, orient="index")
    return BatchStatistics(distributions=distributions, table=table, threshold=float(threshold), values=values)


def plot_histograms(stats: BatchStatistics | Any, *, ax: Any = None, bins: Any = "auto") -> dict[str, dict[str, Any]]:
    """Histograms of the batch's gain, loop width and fit error, outliers marked.

    Parameters
    ----------
    stats : BatchStatistics or pandas.DataFrame
        Statistics, or a table to compute them from.
    ax : sequence of 3 matplotlib Axes, optional
        One per figure of :data:`FIGURES`; a new figure when omitted.
    bins
        As ``numpy.histogram``.

    Returns
    -------
    dict
        Per figure: ``{"ax", "patches", "median", "limits", "outliers"}`` (what was drawn; ``None``
        where there was nothing to draw).
    """
    if not isinstance(stats, BatchStatistics):
        stats = batch_statistics(stats)
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(1, len(FIGURES), figsize=(4.2 * len(FIGURES), 3.6), layout="constrained")
    axes = list(np.ravel(np.asarray(ax, dtype=object)))
    if len(axes) != len(FIGURES):
        raise ValueError(f"ax must hold {len(FIGURES)} Axes (one per figure: {list(FIGURES)}), got {len(axes)}")
    drawn: dict[str, dict[str, Any]] = {}
    ok = (stats.table["status"] == "ok").to_numpy()
    flagged = stats.table["outlier"].to_numpy(dtype=bool)
    for a, (col, (label, unit)) in zip(axes, FIGURES.items()):
        v = stats.values.get(col, np.array([]))
        d = stats.distributions.loc[col]
        entry: dict[str, Any] = {"ax": a, "patches": None, "median": None, "limits": [], "outliers": None}
        a.set_xlabel(f"{label} ({unit})")
        a.set_ylabel("actuators")
        if v.size == 0:
            a.text(0.5, 0.5, "no identified records", ha="center", va="center", transform=a.transAxes)
            drawn[col] = entry
            continue
        _, _, entry["patches"] = a.hist(v, bins=bins, color="C0", alpha=0.8)
        entry["median"] = a.axvline(d["median"], color="k", lw=1.2, label=f"median {d['median']:.4g}")
        if d["mad"] > 0:
            for s in (-1, 1):
                entry["limits"].append(a.axvline(d["median"] + s * stats.threshold * d["mad"], color="C3", ls="--",
                                                 lw=1.0, label=f"±{stats.threshold:g} MAD" if s > 0 else None))
        x = _numeric(stats.table[col])
        out = ok & flagged & np.isfinite(x)
        if out.any():
            entry["outliers"] = a.plot(x[out], np.zeros(int(out.sum())), "v", color="C3", ms=8, clip_on=False,
                                       label="flagged actuator")[0]
        a.set_title(f"{label}: n = {int(d['n'])}", fontsize=10)
        a.grid(True, alpha=0.3)
        a.legend(fontsize=8)
        drawn[col] = entry
    return drawn


def _numeric(series: Any) -> Any:
    pd = _require("pandas")
    return pd.to_numeric(series, errors="coerce").to_numpy(dtype=float)


# ------------------------------------------------------------------------------------------------
def write_simulated_batch(
    directory: str | os.PathLike[str], n: int = 40, *, seed: Any = 0, fs: float = 1000.0,
    freq: float = 1.0, cycles: float = 3, u_max: float = 100.0, spread: float = 0.05,
    noise_percent: float = 0.2, outliers: int = 0, outlier_gain: float = 1.5, force: bool = False,
) -> list[Path]:
    """Write a simulated production batch: ``n`` P-I actuators as CSV records, to try the fleet on.

    Each actuator is the paper's P-I model (its twenty weights on eq. (4)'s thresholds over
    ``u_max``) with every weight scaled by ``1 + spread * N(0, 1)`` and the whole by a common
    gain ``exp(spread * N(0, 1))`` (the spread of a production batch), driven by a
    ``freq`` Hz sinusoid from 0 to ``u_max`` V for ``cycles`` periods at ``fs`` Hz, plus white
    sensor noise of ``noise_percent`` % of the span (RMS). ``outliers`` of them (chosen at
    random) get their gain multiplied by ``outlier_gain``: the actuator that differs.

    Files are ``actuator-001.csv``... (``t_s,u_V,y_um``); each one's ``meta`` (in its header)
    records its gain and whether it is an outlier. Returns the files, in order.
    """
    from . import paper_values as pv
    from .data import Dataset, save_dataset
    from .models.pi import PrandtlIshlinskii, equal_thresholds
    from .signals import sinusoid

    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    if isinstance(outliers, bool) or not isinstance(outliers, (int, np.integer)) or not 0 <= outliers <= n:
        raise ValueError(f"outliers must be an integer between 0 and n={n}, got {outliers!r}")
    for name, v in (("spread", spread), ("noise_percent", noise_percent)):
        if not (np.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be >= 0, got {v!r}")
    if not (np.isfinite(outlier_gain) and outlier_gain > 0):
        raise ValueError(f"outlier_gain must be positive, got {outlier_gain!r}")
    rng = np.random.default_rng(seed)
    u = sinusoid(freq, cycles, 0.0, u_max, 1.0 / fs)
    t = np.arange(u.size) / fs
    r = equal_thresholds(pv.PI_N, u_max)
    w0 = np.asarray(pv.PI_WEIGHTS)
    odd = set(rng.choice(n, size=outliers, replace=False).tolist()) if outliers else set()
    folder = Path(directory)
    files = []
    width = max(3, len(str(n)))
    for i in range(n):
        gain = float(np.exp(spread * rng.standard_normal())) * (outlier_gain if i in odd else 1.0)
        w = gain * w0 * (1.0 + spread * rng.standard_normal(w0.size))
        y = PrandtlIshlinskii(r, w).simulate(u)
        y = y + rng.normal(0.0, noise_percent / 100.0 * float(np.ptp(y)), y.size)
        ds = Dataset(t, u, y, {"simulated": {"gain": gain, "outlier": i in odd, "seed": str(seed)}})
        files.append(save_dataset(folder / f"actuator-{i + 1:0{width}d}.csv", ds, force=force))
    return files


__all__ = [
    "COLUMNS", "DATA_SUFFIXES", "FIGURES", "OUTLIER_MADS", "BatchStatistics", "FitOptions", "MissingExtraError",
    "batch_statistics", "find_records", "fit_record", "identify_many", "identify_record", "local_cluster",
    "plot_histograms", "write_simulated_batch", "write_summary", "check_batch_files",
]
