"""Trees (see :mod:`._tree`) from MATLAB files (v4/v5/v7 via scipy, v7.3 via h5py), HDF5, .npz, .npy.

MATLAB v7.3 files are HDF5 files with a 512-byte user block; MATLAB writes arrays column-major,
so an HDF5 dataset of shape (2, N) is MATLAB's N x 2 and is read transposed. Scalar structs are
groups; struct arrays are groups whose fields are arrays of object references (one per element)
into ``#refs#``; cells are datasets of references; text is ``char`` (UTF-16 code units).
"""

from __future__ import annotations

import contextlib
import json
import math
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ._columns import check_size
from ._dataset import DataError
from ._tree import Leaf, Opaque, eager

MAX_NODES = 200_000  # arrays, structs and cells listed from one file
MAX_DEPTH = 64
_MATLAB_NUMERIC = {"double": 8, "single": 4, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2,
                   "int32": 4, "uint32": 4, "int64": 8, "uint64": 8}


class _Budget:
    def __init__(self, where: str) -> None:
        self.where = where
        self.nodes = 0

    def tick(self, depth: int) -> None:
        self.nodes += 1
        if self.nodes > MAX_NODES:
            raise DataError(f"{self.where}: holds more than {MAX_NODES} arrays, structs and cells; "
                            f"save the signals as plain arrays")
        if depth > MAX_DEPTH:
            raise DataError(f"{self.where}: structs nested more than {MAX_DEPTH} deep")


def _check_tree(where: str, node: Any, budget: _Budget | None = None, depth: int = 0) -> None:
    budget = budget or _Budget(where)
    budget.tick(depth)
    if isinstance(node, dict):
        for v in node.values():
            _check_tree(where, v, budget, depth + 1)
    elif isinstance(node, list):
        for v in node:
            _check_tree(where, v, budget, depth + 1)


# ------------------------------------------------------------------------------------------------
def mat_v5(path: Path, limit: int, *, v4: bool = False) -> dict[str, Any]:
    """Variables of a MATLAB v4/v5/v7 file (scipy), as a tree; v5/v7 files are checked first."""
    import io

    from scipy.io import loadmat, whosmat

    from ._mat5 import Malformed, check

    where = str(path)
    check_size(where, path.stat().st_size, limit, "reading this MATLAB file")
    data = path.read_bytes()
    # scipy picks the reader by its own reading of the header, not by ours: a v5 file with a damaged
    # text header still goes to the v5 reader, so ask scipy which one it will use.
    try:
        from scipy.io.matlab import matfile_version

        major = matfile_version(io.BytesIO(data))[0]
    except Exception as exc:  # scipy raises several kinds for headers it cannot place
        raise DataError(f"{where}: not a readable MATLAB file ({_first_line(exc)})") from None
    if major == 2:
        raise DataError(f"{where}: a MATLAB v7.3 file that is not valid HDF5")
    v4 = major == 0
    if not v4:  # scipy's compiled reader can crash on a damaged file: check its structure first
        try:
            need = check(data, limit)
        except Malformed as exc:
            raise DataError(f"{where}: a damaged MATLAB file ({exc})") from None
        check_size(where, need + len(data), limit, "loading its variables")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if v4:
            try:
                info = whosmat(io.BytesIO(data))
            except Exception as exc:  # scipy raises many kinds for damaged files
                raise DataError(f"{where}: not a readable MATLAB file ({_first_line(exc)})") from None
            need = sum(math.prod(shape) * (8 + _MATLAB_NUMERIC.get(cls, 8)) for _n, shape, cls in info)
            check_size(where, need, limit, f"loading its {len(info)} variables")
        try:
            m = loadmat(io.BytesIO(data), simplify_cells=True)
        except NotImplementedError:  # a v7.3 file that got here by its name
            raise DataError(f"{where}: a MATLAB v7.3 file that is not valid HDF5") from None
        except Exception as exc:
            raise DataError(f"{where}: not a readable MATLAB file ({_first_line(exc)})") from None
    root = {k: eager(v) for k, v in m.items() if not k.startswith("__")}
    _check_tree(where, root)
    return root


# ------------------------------------------------------------------------------------------------
def _attr(obj: Any, name: str) -> str | None:
    v = obj.attrs.get(name)
    if v is None:
        return None
    if isinstance(v, bytes):
        return v.decode("latin-1")
    if isinstance(v, np.ndarray) and v.dtype.kind == "S":
        return b"".join(v.ravel().tolist()).decode("latin-1")
    return str(v)


@contextlib.contextmanager
def hdf5(path: Path, *, matlab: bool) -> Iterator[dict[str, Any]]:
    """The tree of an HDF5 file (MATLAB v7.3 semantics when ``matlab``); open while in use."""
    import h5py

    where = str(path)
    try:
        f = h5py.File(str(path), "r")
    except Exception as exc:
        raise DataError(f"{where}: not a readable {'MATLAB v7.3' if matlab else 'HDF5'} file "
                        f"({_first_line(exc)})") from None
    budget = _Budget(where)
    try:
        root: dict[str, Any] = {}
        try:
            for k in f:
                if k.startswith("#"):  # "#refs#", "#subsystem#"
                    continue
                root[k] = _h5_node(f, f[k], matlab, budget, 1)
        except DataError:
            raise
        except Exception as exc:  # h5py reports damage as KeyError, OSError, ValueError, ...
            raise DataError(f"{where}: a damaged {'MATLAB v7.3' if matlab else 'HDF5'} file "
                            f"({_first_line(exc)})") from None
        yield root
    finally:
        f.close()


def _h5_node(f: Any, obj: Any, matlab: bool, budget: _Budget, depth: int) -> Any:
    import h5py

    budget.tick(depth)
    if isinstance(obj, h5py.Group):
        if matlab:
            cls = _attr(obj, "MATLAB_class")
            if obj.attrs.get("MATLAB_sparse") is not None:
                return Opaque("a sparse matrix (save it as full(x))")
            if cls not in (None, "struct"):
                return Opaque(f"a MATLAB object of class {cls!r} that can only be read in MATLAB")
            names = list(obj.keys())
            fields = {k: obj[k] for k in names}
            if names and all(isinstance(v, h5py.Dataset) and v.dtype == h5py.ref_dtype
                             and _attr(v, "MATLAB_class") is None for v in fields.values()):
                refs = {k: v[()].ravel() for k, v in fields.items()}  # MATLAB's element order
                count = len(next(iter(refs.values())))
                if any(len(r) != count for r in refs.values()):
                    return Opaque("a struct array with fields of different sizes")
                return [{k: _h5_node(f, f[refs[k][i]], matlab, budget, depth + 1) for k in names}
                        for i in range(count)]
            return {k: _h5_node(f, v, matlab, budget, depth + 1) for k, v in fields.items()}
        return {k: _h5_node(f, obj[k], matlab, budget, depth + 1) for k in obj}
    if not isinstance(obj, h5py.Dataset):
        return Opaque(f"an HDF5 {type(obj).__name__}")
    if matlab:
        cls = _attr(obj, "MATLAB_class")
        if obj.attrs.get("MATLAB_empty") not in (None, 0):
            return "" if cls == "char" else [] if cls == "cell" else {} if cls == "struct" else \
                Leaf((0,), np.dtype(np.float64), lambda: np.zeros(0))
        if cls == "char":
            codes = np.asarray(obj[()]).T.ravel() if obj.size < 100_000 else np.zeros(0, np.uint16)
            return "".join(chr(int(c)) for c in codes if 0 < int(c) < 0x110000)
        if cls == "cell":
            refs = obj[()].T.ravel()
            return [_h5_node(f, f[r], matlab, budget, depth + 1) for r in refs]
        if cls == "logical":
            return Opaque("logical values")
        if cls in _MATLAB_NUMERIC:
            if obj.dtype.names:
                return Opaque(f"complex numbers ({cls})")
            shape = tuple(int(d) for d in reversed(obj.shape))
            return Leaf(shape, obj.dtype, _h5_reader(obj, transpose=True))
        if cls is None and obj.dtype == h5py.ref_dtype:
            refs = obj[()].ravel()
            return [_h5_node(f, f[r], matlab, budget, depth + 1) for r in refs]
        return Opaque(f"a MATLAB object of class {cls!r} that can only be read in MATLAB")
    kind = obj.dtype.kind
    if kind in "fiu" and not obj.dtype.names:
        stated = next((u.strip() for u in (_attr(obj, a) for a in ("units", "unit", "Units", "Unit"))
                       if u is not None and u.strip()), None)
        return Leaf(tuple(int(d) for d in obj.shape), obj.dtype, _h5_reader(obj, transpose=False), stated)
    if kind in "SUO" and obj.shape == ():
        v = obj[()]
        return v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)
    if obj.dtype.names:
        return Opaque(f"a table of records with fields {list(obj.dtype.names)[:8]}")
    return Opaque(f"values of type {obj.dtype}")


# ------------------------------------------------------------------------------------------------
@contextlib.contextmanager
def npz(path: Path) -> Iterator[tuple[dict[str, Any], dict[str, Any]]]:
    """(tree, saved meta) of a .npz archive; arrays read lazily, never with pickles."""
    where = str(path)
    try:
        z = np.load(str(path), allow_pickle=False)
    except Exception as exc:
        raise DataError(f"{where}: not a readable .npz file ({_first_line(exc)})") from None
    try:
        if not hasattr(z, "files"):
            raise DataError(f"{where}: holds a single array, not a .npz archive")
        root: dict[str, Any] = {}
        meta: dict[str, Any] = {}
        budget = _Budget(where)
        for name in z.files:
            budget.tick(1)
            try:
                with z.zip.open(name + ".npy") as fh:
                    shape, dtype = _npy_header(fh)
            except Exception as exc:  # zipfile, zlib and format errors of a damaged archive
                root[name] = Opaque(f"an unreadable member ({_first_line(exc)})")
                continue
            if dtype.hasobject:
                root[name] = Opaque("Python objects, which are never loaded (they would need pickles)")
            elif name == "meta" and dtype.kind == "U" and shape == ():
                try:
                    m = json.loads(str(z["meta"]))
                    meta = m if isinstance(m, dict) else {}
                except ValueError:
                    pass
            elif dtype.kind in "fiu" and not dtype.names:
                root[name] = Leaf(shape, dtype, _npz_reader(z, name))
            else:
                root[name] = Opaque(f"values of type {dtype}")
        yield root, meta
    finally:
        z.close()


def _h5_reader(obj: Any, *, transpose: bool) -> Callable[[], np.ndarray]:
    """Read an HDF5 dataset when asked (MATLAB's are column-major: transposed)."""
    def read() -> np.ndarray:
        a = np.asarray(obj[()])
        return a.T if transpose else a
    return read


def _npz_reader(z: Any, name: str) -> Callable[[], np.ndarray]:
    return lambda: np.asarray(z[name])


def _npy_header(fh: Any) -> tuple[tuple[int, ...], np.dtype]:
    fmt = np.lib.format
    version = fmt.read_magic(fh)
    if version == (1, 0):
        shape, _fortran, dtype = fmt.read_array_header_1_0(fh)
    elif version == (2, 0):
        shape, _fortran, dtype = fmt.read_array_header_2_0(fh)
    else:
        raise ValueError(f"unsupported .npy format version {version}")
    return tuple(int(d) for d in shape), dtype


def npy(path: Path) -> dict[str, Any]:
    """A single .npy array (memory-mapped until read) as a tree of one variable."""
    where = str(path)
    try:
        with open(path, "rb") as fh:
            shape, dtype = _npy_header(fh)
    except Exception as exc:
        raise DataError(f"{where}: not a readable .npy file ({_first_line(exc)})") from None
    if dtype.hasobject:
        raise DataError(f"{where}: holds Python objects, which are never loaded (they would need pickles)")
    name = path.stem or "array"
    if dtype.kind not in "fiu" or dtype.names:
        return {name: Opaque(f"values of type {dtype}")}
    return {name: Leaf(shape, dtype, lambda: np.load(str(path), allow_pickle=False))}


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return (text.splitlines()[0] if text else type(exc).__name__)[:200]
