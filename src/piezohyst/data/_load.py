"""``load_dataset``: what kind of file it is (by its first bytes, then its name), and reading it."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np

from .._fileio import atomic_write, producer
from .._fileio import to_jsonable as _jsonable
from ._columns import assemble, check_size, default_limit, parse_size
from ._dataset import DataError, Dataset
from ._text import HEAD_BYTES, NotText, TextSource

_HDF5 = b"\x89HDF\r\n\x1a\n"
_OLE2 = b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1"
_TEXT_SUFFIXES = ".csv .tsv .txt .dat .asc .lvm"
#: The file name endings of the formats :func:`load_dataset` reads (it tells them by content; these
#: are what a folder of records is searched for, e.g. by :func:`piezohyst.fleet.find_records`).
READ_SUFFIXES = (*_TEXT_SUFFIXES.split(), ".mat", ".npz", ".npy", ".h5", ".hdf5", ".parquet", ".xlsx", ".xls", ".ods")
_HASH_BESIDE = 4 << 20  # files from this size on are hashed in a thread while they are parsed

#: format -> (what to install, the module that provides it); None when always available
_ENGINES = {"parquet": ("pyarrow", "pyarrow"), "xlsx": ("openpyxl", "openpyxl"),
            "xls": ("xlrd", "xlrd"), "ods": ("odfpy", "odf")}


def _has(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def supported() -> str:
    """One line listing the formats :func:`load_dataset` reads (and what the optional ones need)."""
    def opt(fmt: str, text: str) -> str:
        pkg, mod = _ENGINES[fmt]
        return text if _has(mod) else f"{text} (needs {pkg}: pip install {pkg})"

    return ("supported formats: text tables (" + _TEXT_SUFFIXES + " or any name; comma, semicolon, tab or "
            "whitespace separated, decimal point or comma, UTF-8/UTF-16/cp1252), LabVIEW measurement files "
            ".lvm (units and segments from their headers), MATLAB .mat (v4, v5, v7 "
            "and v7.3), NumPy .npz and .npy, HDF5 .h5/.hdf5, " + opt("parquet", "Parquet .parquet") + ", "
            + opt("xlsx", "Excel .xlsx") + ", " + opt("xls", "Excel 97 .xls") + ", "
            + opt("ods", "OpenDocument .ods"))


def open_checked(path: Any) -> tuple[Path, bytes, int]:
    """(path, its first bytes, its size), or a DataError saying why the file cannot be read."""
    try:
        p = Path(os.fspath(path)).expanduser()
    except TypeError:
        raise DataError(f"a data file is given by its path (a str or os.PathLike), got {type(path).__name__}") from None
    try:
        if not p.exists():
            raise DataError(f"{p}: no such file")
        if p.is_dir():
            raise DataError(f"{p}: is a directory, not a data file")
        size = p.stat().st_size
        with open(p, "rb") as fh:
            head = fh.read(HEAD_BYTES)
    except PermissionError:
        raise DataError(f"{p}: cannot read it (permission denied)") from None
    except OSError as exc:
        raise DataError(f"{p}: cannot read it ({exc.strerror or exc})") from None
    if size == 0 or not head:
        raise DataError(f"{p}: the file is empty")
    return p, head, size


def detect_format(p: Path, head: bytes) -> str:
    """The format from the first bytes (magic numbers), then the name."""
    if head.startswith(b"MATLAB 5.0 MAT-file"):
        return "mat-v5"
    if head.startswith(b"MATLAB 7.3 MAT-file") or (head.startswith(b"MATLAB") and head[512:520] == _HDF5):
        return "mat-v7.3"
    if any(head[o:o + 8] == _HDF5 for o in (0, 512, 1024, 2048)):
        return "hdf5"
    if head.startswith(b"\x93NUMPY"):
        return "npy"
    if head.startswith((b"PK\x03\x04", b"PK\x05\x06")):
        return _zip_kind(p)
    if head.startswith(b"PAR1"):
        return "parquet"
    if head.startswith(b"TDSm"):
        return "tdms"
    from ._lvm import is_lvm

    if is_lvm(head):
        return "lvm"
    if head.startswith((b"\x1f\x8b", b"BZh", b"\xfd7zXZ\x00", b"\x28\xb5\x2f\xfd")):
        return "compressed"  # gzip, bzip2, xz, zstd ("not a text file (it contains NUL bytes)" before)
    if head.startswith(_OLE2):
        return "xls"
    suffix = p.suffix.lower()
    if suffix == ".mat" and (b"\x00" in head[:128]):
        return "mat-v4"  # v4 files have no magic number; scipy reads them
    return "text"


def _zip_kind(p: Path) -> str:
    import zipfile

    try:
        with zipfile.ZipFile(p) as z:
            names = z.namelist()
            if "mimetype" in names and b"opendocument.spreadsheet" in z.read("mimetype"):
                return "ods"
    except (zipfile.BadZipFile, OSError, KeyError, ValueError, EOFError):
        return "zip?"
    if any(n.startswith("xl/") for n in names):
        return "xlsx"
    if names and all(n.endswith(".npy") for n in names):
        return "npz"
    if not names and p.suffix.lower() == ".npz":
        return "npz"
    return "zip"


def file_sha256(path: Path, stop: threading.Event | None = None) -> str | None:
    """SHA-256 of the file's bytes (provenance in ``meta``); None if ``stop`` was set first."""
    h = hashlib.sha256()
    buf = bytearray(1 << 20)
    view = memoryview(buf)
    with open(path, "rb", buffering=0) as fh:
        while n := fh.readinto(buf):
            h.update(view[:n])
            if stop is not None and stop.is_set():
                return None
    return h.hexdigest()


def load_dataset(
    path: str | os.PathLike[str], *, u_col: Any = None, y_col: Any = None, t_col: Any = None,
    fs: float | None = None, units: dict[str, Any] | None = None, resample: bool = False,
    delimiter: str | None = None, decimal: str | None = None, encoding: str | None = None,
    max_memory: int | str | None = None,
) -> Dataset:
    """Load a record (time, input voltage, output displacement) from a lab file.

    The format is found from the file's first bytes (then its name): text tables (any common
    delimiter, decimal comma, UTF-8/UTF-16/cp1252/latin-1), LabVIEW measurement files (``.lvm``:
    units, time and segments from their headers), MATLAB ``.mat`` v4 to v7.3, NumPy
    ``.npz``/``.npy``, HDF5, Parquet and Excel/OpenDocument (when pandas' engine for them is
    installed). Values are converted to seconds, volts and micrometres from the units in the
    names (``Displacement [nm]``, ``Time (ms)``, ``u_mV``, ``time.s``) or stated by the file (a line of units
    under the header, a dSPACE ``Unit`` field); ``meta["units"]`` records each conversion.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    u_col, y_col, t_col : str or int, optional
        The input, output and time columns: a header name (with or without its unit), a 0-based
        column number, a MATLAB/HDF5/npz variable or a path into a struct such as
        ``"logsout.signals[0].values"``, ``"rec.Y(2).Data"`` (MATLAB's 1-based ``(i)``) or
        ``"data[:, 1]"``, or a signal's name (a dSPACE ``Name``, a Simulink ``label``). By
        default they are found by name: ``t``/``time``, ``u``/``voltage``/``input``,
        ``y``/``displacement``/``position``, ... A struct's own time vector (Simulink
        ``x.time``, dSPACE ``X.Data``) comes with its signals.
    fs : float, optional
        Sample rate in Hz, for files without a time column (checked against one if present).
    units : dict, optional
        Units that override the file's, e.g. ``{"y": "nm"}``, or factors to the canonical unit
        (``{"y": 10.0}``: 10 µm per unit of the file).
    resample : bool
        A time column with a step more than 1 % away from the mean step and from the median
        step (a gap, a change of rate) is refused: one sample period would misstate the timing.
        Smaller jitter, and times printed with limited digits, pass. With ``resample=True`` such a
        record is linearly interpolated onto a uniform grid at the median step (or ``1/fs``)
        instead, and ``meta["resampled"]`` says so.
    delimiter, decimal, encoding : str, optional
        Override what is sniffed from a text file.
    max_memory : int or str, optional
        The most memory reading may take (``"2G"``); by default ``PIEZOHYST_MAX_MEMORY`` or half
        the machine's memory. Larger files are refused before anything is allocated.

    Returns
    -------
    Dataset
        With ``meta``: ``source``, ``source_sha256``, ``format``, ``columns``, ``units`` and what
        the reader found (encoding, delimiter, ...).

    Raises
    ------
    DataError
        (a ``ValueError``) one line naming the file and the problem: the line and column of a
        value that is not a number, NaN or inf; a matrix where a signal was expected (never
        flattened); a non-uniform time column; a unit of the wrong kind; a file too large for
        the memory limit; an unsupported format (with the list of supported ones).

    Examples
    --------
    ``load_dataset("Model_Vi_Do.dat", u_col=0, y_col=4, fs=200)`` reads a headerless
    whitespace-separated file sampled at 200 Hz; ``load_dataset("run.mat",
    u_col="logsout.signals[0].values", y_col="logsout.signals[1].values")`` two signals of a
    Simulink structure with time.
    """
    p, head, size = open_checked(path)
    limit = default_limit() if max_memory is None else parse_size(max_memory, "max_memory")
    fmt = detect_format(p, head)
    opts = {"t_col": t_col, "u_col": u_col, "y_col": y_col, "fs": fs, "units": units, "resample": resample,
            "max_memory": limit}
    if fmt != "text" and (delimiter, decimal, encoding) != (None, None, None):
        raise DataError(f"{p}: delimiter=, decimal= and encoding= apply to text files; this is {fmt}")
    if size < _HASH_BESIDE:
        ds = _load(p, head, size, fmt, opts, delimiter, decimal, encoding)
        sha = file_sha256(p)
    else:  # a big file's hash runs beside the parse (both release the GIL): no extra wait
        from concurrent.futures import ThreadPoolExecutor

        stop = threading.Event()
        with ThreadPoolExecutor(max_workers=1) as pool:
            digest = pool.submit(file_sha256, p, stop)
            try:
                ds = _load(p, head, size, fmt, opts, delimiter, decimal, encoding)
            except BaseException:
                stop.set()  # a refused file (too large, say) is not hashed to the end
                raise
            try:
                sha = digest.result()
            except OSError as exc:
                raise DataError(f"{p}: cannot read it ({exc.strerror or exc})") from None
    ds.meta["source"] = str(p)
    ds.meta["source_sha256"] = sha
    return ds


def _load(p: Path, head: bytes, size: int, fmt: str, opts: dict[str, Any],
          delimiter: str | None, decimal: str | None, encoding: str | None) -> Dataset:
    from . import _containers as c
    from ._tree import TreeSource

    where = str(p)
    if fmt == "text":
        try:
            src = TextSource(p, head, size, delimiter=delimiter, decimal=decimal, encoding=encoding)
        except NotText as exc:
            raise DataError(f"{where}: not a text file ({exc}) nor another format piezohyst reads; "
                            f"{supported()}") from None
        return assemble(src, extra_meta=src.lay.saved_meta, **opts)
    if fmt == "lvm":
        from ._frame import FrameSource
        from ._lvm import read_lvm

        from ._columns import check_size

        # the rows are split into Python strings first: about 10 times the file's size
        check_size(where, 10.0 * size, opts["max_memory"], "reading this LabVIEW file")
        df = read_lvm(p)
        return assemble(FrameSource(df, where=where, fmt="lvm"), extra_meta={"lvm": df.attrs["lvm"]}, **opts)
    if fmt == "npz":
        with c.npz(p) as (root, saved):
            return assemble(TreeSource(root, where=where, fmt="npz", kind="array"), extra_meta=saved, **opts)
    if fmt == "npy":
        return assemble(TreeSource(c.npy(p), where=where, fmt="npy", kind="array"), **opts)
    if fmt in ("mat-v5", "mat-v4"):
        root = c.mat_v5(p, opts["max_memory"], v4=fmt == "mat-v4")
        return assemble(TreeSource(root, where=where, fmt=fmt), **opts)
    if fmt in ("mat-v7.3", "hdf5"):
        with c.hdf5(p, matlab=fmt == "mat-v7.3") as root:
            kind = "variable" if fmt == "mat-v7.3" else "dataset"
            return assemble(TreeSource(root, where=where, fmt=fmt, kind=kind), **opts)
    if fmt in _ENGINES:
        from ._frame import FrameSource

        df = _read_frame(p, fmt, size, opts["max_memory"])
        return assemble(FrameSource(df, where=where, fmt=fmt), **opts)
    what = {"tdms": "a LabVIEW TDMS file (export it as text or read it with npTDMS and use "
                    "Dataset.from_dataframe)",
            "zip": "a zip archive that is neither .npz nor a spreadsheet",
            "zip?": "a damaged zip archive",
            "compressed": "a compressed file (gzip, bzip2, xz or zstd); decompress it first (e.g. gunzip)"}.get(fmt, fmt)
    raise DataError(f"{where}: {what}; {supported()}")


def _read_frame(p: Path, fmt: str, size: int, limit: int) -> Any:
    import pandas as pd

    from ._units import is_unit

    where = str(p)
    pkg, mod = _ENGINES[fmt]
    if not _has(mod):
        raise DataError(f"{where}: reading {fmt} files needs {pkg} (pip install {pkg}); {supported()}")
    # a compressed spreadsheet or Parquet file unpacks to far more than its size
    check_size(where, size * (40 if fmt != "parquet" else 12), limit, f"reading this {fmt} file")
    try:
        if fmt == "parquet":
            df = pd.read_parquet(p)
        else:
            df = pd.read_excel(p, sheet_name=0)
    except Exception as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DataError(f"{where}: cannot read it as {fmt} ({first[:200]})") from None
    if fmt != "parquet" and len(df) >= 1:
        first_row = df.iloc[0].tolist()
        if all(isinstance(v, str) and is_unit(v) for v in first_row if not (isinstance(v, float) and np.isnan(v))) \
                and any(isinstance(v, str) for v in first_row):
            df.attrs["units"] = {col: v for col, v in zip(df.columns, first_row) if isinstance(v, str)}
            df = df.iloc[1:].reset_index(drop=True)
    return df


# ------------------------------------------------------------------------------------------------
def save_dataset(path: str | os.PathLike[str], ds: Dataset, *, force: bool = False) -> Path:
    """Write ``ds`` as CSV (``t_s,u_V,y_um`` with a provenance comment) or ``.npz``; atomic.

    The CSV is the canonical form: every reader returns the same data as loading it.
    """
    if not isinstance(ds, Dataset):
        raise TypeError(f"save_dataset writes a Dataset, got {type(ds).__name__}")
    p = Path(path)
    if p.suffix.lower() not in (".npz", ".csv", ".txt", ".dat", ".tsv", ""):
        # (s.mat, s.xlsx and s.h5 were written as CSV text: found by fuzzing)
        raise ValueError(f"{p}: save_dataset writes CSV (.csv, .txt, .dat) or NumPy .npz; give one of those names")
    if p.suffix.lower() == ".npz":
        def write_npz(tmp: Path) -> None:
            with open(tmp, "wb") as fh:
                np.savez(fh, t=ds.t, u=ds.u, y=ds.y,
                         meta=np.array(json.dumps({**_jsonable(ds.meta), "producer": producer()})))
        return atomic_write(p, write_npz, force=force)

    def write_csv(tmp: Path) -> None:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(f"# {producer()}\n")
            fh.write("# units: t in s, u in V, y in um\n")
            if ds.meta:
                fh.write(f"# meta: {json.dumps(_jsonable(ds.meta))}\n")
            fh.write("t_s,u_V,y_um\n")
            np.savetxt(fh, np.column_stack([ds.t, ds.u, ds.y]), delimiter=",", fmt="%.10g")
    return atomic_write(p, write_csv, force=force)
