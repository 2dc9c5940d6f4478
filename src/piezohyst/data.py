"""Measured (or simulated) voltage/displacement records: :class:`Dataset`, loading and saving.

Units at this boundary: time in seconds, input ``u`` in volts, output ``y`` in micrometres.

Formats
-------
* CSV or whitespace-separated text (``.csv``, ``.txt``, ``.dat``, ``.tsv``). Lines starting with
  ``#`` are comments. A first non-comment line with words in it is a header naming the columns;
  ``t``/``time``, ``u``/``voltage`` and ``y``/``displacement`` (unit suffixes such as ``u_V`` or
  ``y [um]`` allowed) are found by name, or pick columns with ``t_col=``, ``u_col=``, ``y_col=``
  (a name or a 0-based index). Without a time column, give the sample rate ``fs`` (Hz).
* MATLAB ``.mat`` (v5, via scipy): variables ``t``, ``u``, ``y`` or the names given.
* NumPy ``.npz``: arrays ``t``, ``u``, ``y`` (loaded with ``allow_pickle=False``: a data file
  can never run code).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._fileio import atomic_write, producer
from ._fileio import to_jsonable as _jsonable
from ._validation import FloatArray, as_signal


class DataError(ValueError):
    """A data file or array that cannot be used, with the reason (and the file) in the message."""


@dataclass(frozen=True, eq=False)
class Dataset:
    """One record: time ``t`` (s), input ``u`` (V), output ``y`` (µm) and free-form ``meta``.

    Examples
    --------
    >>> import numpy as np, piezohyst as ph
    >>> ds = ph.Dataset(t=np.arange(3) * 1e-3, u=[0.0, 1.0, 2.0], y=[0.0, 0.02, 0.04])
    >>> ds.fs, len(ds)
    (1000.0, 3)
    """

    t: FloatArray
    u: FloatArray
    y: FloatArray
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = as_signal("t", self.t, min_length=2)
        u = as_signal("u", self.u, min_length=2)
        y = as_signal("y", self.y, min_length=2)
        if not (t.size == u.size == y.size):
            raise DataError(f"t, u and y must have the same length, got {t.size}, {u.size} and {y.size}")
        steps = np.diff(t)
        if np.any(steps <= 0):
            i = int(np.argmax(steps <= 0))
            raise DataError(f"time must be strictly increasing, but t[{i + 1}] = {t[i + 1]} <= t[{i}] = {t[i]}")
        for name, arr in (("t", t), ("u", u), ("y", y)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "meta", dict(self.meta))

    def __len__(self) -> int:
        return int(self.u.size)

    @property
    def dt(self) -> float:
        """The (median) sample period, s."""
        return float(np.median(np.diff(self.t)))

    @property
    def fs(self) -> float:
        """The sample rate, Hz."""
        return 1.0 / self.dt

    @property
    def is_uniform(self) -> bool:
        """True when every sample period is within 1e-6 relative of the median."""
        d = np.diff(self.t)
        return bool(np.all(np.abs(d - self.dt) <= 1e-6 * self.dt))

    def slice(self, start: int | None = None, stop: int | None = None) -> "Dataset":
        """Samples ``start:stop`` as a new data set (meta says which)."""
        sl = slice(start, stop)
        meta = {**self.meta, "slice": [start, stop]}
        return Dataset(self.t[sl], self.u[sl], self.y[sl], meta)

    @property
    def sha256(self) -> str:
        """SHA-256 of the samples (t, u, y as little-endian float64): identifies the data, not the file."""
        h = hashlib.sha256()
        for arr in (self.t, self.u, self.y):
            h.update(np.ascontiguousarray(arr, dtype="<f8").tobytes())
        return h.hexdigest()


# ------------------------------------------------------------------------------------------------
_ALIASES = {
    "t": ("t", "time", "times", "t_s", "time_s"),
    "u": ("u", "v", "voltage", "input", "volt", "volts", "command"),
    "y": ("y", "x", "displacement", "output", "position", "disp"),
}


def _norm(name: str) -> str:
    n = name.strip().strip('"').strip("'").lower()
    n = re.sub(r"\s*[\[(].*$", "", n)  # "y [um]" -> "y"
    base = re.split(r"[_\s]", n, maxsplit=1)[0] if "_" in n or " " in n else n
    return base


def _pick(names: list[str], key: str, given: Any, path: Path) -> int | None:
    if given is not None:
        if isinstance(given, (int, np.integer)) and not isinstance(given, bool):
            if not 0 <= int(given) < len(names):
                raise DataError(f"{path}: column {given} does not exist (the file has {len(names)} columns)")
            return int(given)
        lowered = [n.strip().lower() for n in names]
        g = str(given).strip().lower()
        if g in lowered:
            return lowered.index(g)
        normed = [_norm(n) for n in names]
        if _norm(g) in normed:
            return normed.index(_norm(g))
        raise DataError(f"{path}: unknown column {given!r}; the columns are {names}")
    normed = [_norm(n) for n in names]
    for alias in _ALIASES[key]:
        if alias in normed:
            return normed.index(alias)
    return None


def read_table(path: Path, delimiter: str | None = None) -> tuple[list[str], np.ndarray, bool]:
    """A numeric text table: (column names, rows x columns array, whether it had a header).

    ``#`` lines are comments; the delimiter (comma, tab, semicolon or whitespace) is detected
    from the first data line unless given. Every problem is a :class:`DataError` naming the file
    and the line.
    """
    try:
        with open(path, encoding="utf-8") as fh:
            lines = [ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")]
    except UnicodeDecodeError:
        raise DataError(f"{path}: not a text file (cannot decode it as UTF-8)") from None
    if not lines:
        raise DataError(f"{path}: no data (the file is empty or only comments)")
    if delimiter is None:
        first_line = lines[0]
        delimiter = ("," if "," in first_line else ";" if ";" in first_line else "\t" if "\t" in first_line else None)

    def split(line: str) -> list[str]:
        return line.split(delimiter) if delimiter else line.split()

    def is_number(text: str) -> bool:
        try:
            float(text)
            return True
        except ValueError:
            return False

    first = split(lines[0])
    has_header = not all(is_number(c) for c in first if c.strip())
    body = lines[1:] if has_header else lines
    names = [c.strip() for c in first] if has_header else [str(i) for i in range(len(first))]
    rows = []
    for lineno, line in enumerate(body, start=2 if has_header else 1):
        cells = split(line)
        if len(cells) != len(names):
            raise DataError(f"{path}: line {lineno} has {len(cells)} columns, expected {len(names)}")
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            raise DataError(f"{path}: line {lineno} has a value that is not a number: {line.strip()[:60]!r}") from None
    if len(rows) < 2:
        raise DataError(f"{path}: needs at least 2 samples, found {len(rows)}")
    return names, np.array(rows), has_header


def _read_text(path: Path, t_col: Any, u_col: Any, y_col: Any, fs: float | None,
               delimiter: str | None) -> Dataset:
    names, arr, has_header = read_table(path, delimiter)
    if not has_header and (u_col is None or y_col is None):
        raise DataError(
            f"{path}: the file has no header; say which columns hold the input and the "
            f"output (u_col=, y_col=, 0-based; {arr.shape[1]} columns) and give fs= or t_col="
        )
    iu = _pick(names, "u", u_col, path)
    iy = _pick(names, "y", y_col, path)
    it = _pick(names, "t", t_col, path) if (t_col is not None or has_header) else None
    if iu is None or iy is None:
        raise DataError(f"{path}: cannot tell which columns are u and y from the header {names}; "
                        f"give u_col= and y_col=")
    return _assemble(path, arr[:, it] if it is not None else None, arr[:, iu], arr[:, iy], fs,
                     {"columns": {"u": names[iu], "y": names[iy], "t": names[it] if it is not None else None}})


def _assemble(path: Path, t: Any, u: Any, y: Any, fs: float | None, meta: dict[str, Any]) -> Dataset:
    u = np.asarray(u, dtype=np.float64).ravel()
    y = np.asarray(y, dtype=np.float64).ravel()
    if t is None:
        if fs is None:
            raise DataError(f"{path}: no time column; give the sample rate fs= (Hz)")
        if not np.isfinite(fs) or fs <= 0:
            raise DataError(f"{path}: fs must be a positive sample rate in Hz, got {fs}")
        t = np.arange(u.size) / float(fs)
    t = np.asarray(t, dtype=np.float64).ravel()
    meta = {**meta, "source": str(path), "source_sha256": _file_sha256(path)}
    try:
        return Dataset(t, u, y, meta)
    except (ValueError, TypeError) as exc:
        raise DataError(f"{path}: {exc}") from None


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _arrays(path: Path, store: Any, what: str, t_col: Any, u_col: Any, y_col: Any) -> tuple[Any, Any, Any]:
    """t (None if absent and not asked for), u and y from a mapping of named arrays (.npz, .mat)."""
    keys = list(store.keys())

    def get(name: Any, default: str) -> Any:
        k = name if name is not None else default
        if k not in keys:
            if name is None and default == "t":
                return None
            raise DataError(f"{path}: no {what} {k!r}; the file has {keys}")
        return store[k]

    return get(t_col, "t"), get(u_col, "u"), get(y_col, "y")


def load_dataset(
    path: str | os.PathLike[str], *, u_col: Any = None, y_col: Any = None, t_col: Any = None,
    fs: float | None = None, delimiter: str | None = None,
) -> Dataset:
    """Load a record from CSV/text, ``.mat`` or ``.npz`` (see the module docstring).

    Raises
    ------
    DataError
        (a ``ValueError``) naming the file and what is wrong with it.

    Examples
    --------
    ``load_dataset("Model_Vi_Do.dat", u_col=0, y_col=4, fs=200)`` reads a headerless
    whitespace-separated file sampled at 200 Hz.
    """
    p = Path(path)
    if not p.exists():
        raise DataError(f"{p}: no such file")
    if p.is_dir():
        raise DataError(f"{p}: is a directory, not a data file")
    suffix = p.suffix.lower()
    if suffix == ".npz":
        try:
            with np.load(p, allow_pickle=False) as z:
                t, u, y = _arrays(p, z, "array", t_col, u_col, y_col)
                meta = json.loads(str(z["meta"])) if "meta" in z.files else {}
        except DataError:
            raise
        except ValueError as exc:
            raise DataError(f"{p}: cannot read as .npz without pickles ({exc})") from None
        except Exception as exc:  # zipfile / format errors
            raise DataError(f"{p}: not a readable .npz file ({exc})") from None
        return _assemble(p, t, u, y, fs, meta)
    if suffix == ".mat":
        from scipy.io import loadmat

        try:
            m = loadmat(p)
        except Exception as exc:
            raise DataError(f"{p}: not a readable MATLAB file ({exc})") from None
        variables = {k: v for k, v in m.items() if not k.startswith("__")}
        return _assemble(p, *_arrays(p, variables, "variable", t_col, u_col, y_col), fs, {})
    return _read_text(p, t_col, u_col, y_col, fs, delimiter)


def save_dataset(path: str | os.PathLike[str], ds: Dataset, *, force: bool = False) -> Path:
    """Write ``ds`` as CSV (``t_s,u_V,y_um`` with a provenance comment) or ``.npz``; atomic."""
    p = Path(path)
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


# ------------------------------------------------------------------------------------------------
def data_dir() -> Path:
    """The project's ``data/`` folder (next to ``src/`` in a source checkout)."""
    env = os.environ.get("PIEZOHYST_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "data"


def load_piezo_dbo(which: str = "model", *, root: str | os.PathLike[str] | None = None) -> Dataset:
    """The measured piezoelectric micromanipulator records of Aye and Ang (ICSTSD 2018).

    ``which="model"``: ``Model_Vi_Do.dat``, the open-loop identification run (1 Hz, 0-3.6 V,
    about 40 cycles); ``which="test"``: ``Test_Vi_Do_Di.dat`` (open-loop and compensated runs;
    column 8, the desired trajectory, is in ``meta["desired"]``). Input column 0 (V), output
    column 4 (the capacitive sensor reading, treated as µm as in the authors' scripts), 200 Hz.
    MIT licence; see ``data/piezo-dbo/README.md`` for provenance.
    """
    base = Path(root) if root is not None else data_dir() / "piezo-dbo"
    files = {"model": "Model_Vi_Do.dat", "test": "Test_Vi_Do_Di.dat"}
    if which not in files:
        raise ValueError(f"which must be 'model' or 'test', got {which!r}")
    path = base / files[which]
    ds = load_dataset(path, u_col=0, y_col=4, fs=200.0)
    meta = {**ds.meta, "name": f"piezo-dbo/{files[which]}", "licence": "MIT (c) 2019 Yan Naing Aye"}
    if which == "test":
        raw = np.loadtxt(path)
        meta["desired"] = raw[:, 8]
    return Dataset(ds.t, ds.u, ds.y, meta)
