"""Files that hold named arrays, possibly nested: MATLAB structs, ``.npz``, ``.npy``, HDF5.

The file becomes a tree of dicts (structs, groups), lists (struct arrays, cells), :class:`Leaf`
arrays (read lazily where the format allows, so sizes are checked first), strings and
:class:`Opaque` things that cannot be read (MATLAB objects, sparse or complex arrays). A signal is
addressed by a path: ``u``, ``x.signals.values``, ``logsout.signals[0].values`` (``[i]`` counts
from 0, MATLAB's ``(i)`` and ``{i}`` from 1), ``data[:, 2]`` for one column of a matrix; or by
a name: a variable's, a field's, or a signal's ``Name``/``label`` (dSPACE ControlDesk,
Simulink). A matrix is never flattened: a variable of shape N x 2 is refused unless one column
is picked.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._columns import ALIASES, ROLE_WORDS, Key, check_size, flag, match_name
from ._dataset import DataError
from ._units import normal_name

NAME_FIELDS = ("Name", "name", "label", "Label", "signalName", "SignalName")
UNIT_FIELDS = ("Unit", "unit", "Units", "units")
DATA_FIELDS = ("Data", "data", "values", "Values")
TIME_FIELDS = ("time", "Time", "t", "tout")


@dataclass
class Leaf:
    """A numeric array in the user's orientation (MATLAB's for .mat files), read on demand."""

    shape: tuple[int, ...]
    dtype: np.dtype
    _read: Callable[[], np.ndarray]
    #: the unit the file states on the array itself (an HDF5 dataset's ``units`` attribute)
    unit: str | None = None

    def read(self) -> np.ndarray:
        return np.asarray(self._read())

    @property
    def size(self) -> int:
        return int(math.prod(self.shape))

    def is_vector(self) -> bool:
        return sum(1 for d in self.shape if d > 1) <= 1 and len(self.shape) >= 1

    def describe(self) -> str:
        return "x".join(str(d) for d in self.shape) if self.shape else "scalar"


@dataclass
class Opaque:
    """Something in the file that is not an array of numbers (say what it is)."""

    what: str


@dataclass
class Entry:
    """A numeric leaf with the names it can be found by."""

    path: str
    leaf: Leaf
    labels: list[str]
    unit: str | None
    unit_name: str
    time: str | None  # path of a companion time vector


@dataclass(frozen=True)
class Selection:
    """A leaf, or one row/column of it."""

    path: str
    axis: int | None = None
    index: int | None = None


# ------------------------------------------------------------------------------------------------
def constant(a: np.ndarray) -> Callable[[], np.ndarray]:
    """A reader of an array already in memory."""
    return lambda: a


def eager(arr: Any) -> Any:
    """A node from an in-memory numpy value (scipy.io.loadmat with simplify_cells, .npz)."""
    if isinstance(arr, dict):
        return {str(k): eager(v) for k, v in arr.items()}
    if isinstance(arr, (list, tuple)):
        return [eager(v) for v in arr]
    if isinstance(arr, str):
        return arr
    if isinstance(arr, bytes):
        return arr.decode("latin-1")
    if isinstance(arr, (bool, np.bool_)):
        return Opaque("a logical value")
    if isinstance(arr, (int, float, np.integer, np.floating)):
        a = np.asarray(arr, dtype=np.float64)
        return Leaf((), a.dtype, constant(a))
    if isinstance(arr, np.ndarray):
        if arr.dtype.hasobject:
            return [eager(v) for v in arr.ravel().tolist()] if arr.ndim else eager(arr.item())
        if arr.dtype.names:
            return Opaque("a structured array")
        if arr.dtype.kind in "US":
            return "".join(str(x) for x in arr.ravel().tolist())
        if arr.dtype.kind == "c":
            return Opaque(f"complex numbers ({arr.dtype})")
        if arr.dtype.kind == "b":
            return Opaque(f"logical values, shape {arr.shape}")
        if arr.dtype.kind in "fiu":
            return Leaf(tuple(int(d) for d in arr.shape), arr.dtype, constant(arr))
        return Opaque(f"values of type {arr.dtype}")
    name = type(arr).__name__
    if "sparse" in type(arr).__module__ or "sparse" in name.lower():
        return Opaque("a sparse matrix (save it as full(x))")
    if "Function" in name:
        return Opaque("a MATLAB function handle")
    return Opaque(f"a MATLAB object ({name}) that can only be read in MATLAB; save it as a struct or arrays")


# ------------------------------------------------------------------------------------------------
_TOKEN = re.compile(r"\s*(?:(?P<sep>[./])|\[(?P<br>[^\]]*)\]|\((?P<par>[^)]*)\)|\{(?P<cur>[^}]*)\}"
                    r"|(?P<name>[^./\[\](){}]+))")


class PathError(ValueError):
    pass


def parse_path(text: str) -> list[tuple]:
    """``"a.b(2).c[:, 1]"`` -> [("key", "a"), ("key", "b"), ("index", 1), ("key", "c"), ("slice", 1, 1)]."""
    steps: list[tuple] = []
    pos = 0
    text = text.strip()
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if not m or m.end() == pos:
            raise PathError(f"cannot read the path at {text[pos:]!r}")
        pos = m.end()
        if m.group("sep"):
            continue
        if m.group("name") is not None:
            name = m.group("name").strip()
            if name:
                steps.append(("key", name))
            continue
        inner, base = ((m.group("br"), 0) if m.group("br") is not None else
                       (m.group("par"), 1) if m.group("par") is not None else (m.group("cur"), 1))
        parts = [p.strip() for p in inner.split(",")]
        try:
            if len(parts) == 1:
                steps.append(("index", int(parts[0]) - base))
            elif len(parts) == 2 and parts[0] == ":":
                steps.append(("slice", 1, int(parts[1]) - base))
            elif len(parts) == 2 and parts[1] == ":":
                steps.append(("slice", 0, int(parts[0]) - base))
            else:
                raise ValueError
        except ValueError:
            raise PathError(f"cannot read the index {inner!r} (use [i], [:, j] or [i, :], counting from 0)") from None
    if not steps:
        raise PathError("the path is empty")
    return steps


def _last_component(name: str) -> str:
    return re.split(r"[/\\]", name.strip().strip('"'))[-1].strip().strip('"')


class TreeSource:
    """A tree of named arrays as a :class:`~piezohyst.data._columns.Source`; keys are Selections."""

    def __init__(self, root: dict[str, Any], *, where: str, fmt: str, kind: str = "variable") -> None:
        self.root = root
        self.where = where
        self.kind = kind
        self.meta: dict[str, Any] = {"format": fmt}
        self.entries = list(self._walk(root, "", [], []))
        self.by_path = {e.path: e for e in self.entries}

    # -- walking ---------------------------------------------------------------------------------
    def _walk(self, node: Any, path: str, keys: list[Any], ancestors: list[Any]) -> Iterator[Entry]:
        if isinstance(node, dict):
            for k, child in node.items():
                p = f"{path}.{k}" if path else str(k)
                yield from self._walk(child, p, keys + [k], ancestors + [node])
        elif isinstance(node, list):
            for i, child in enumerate(node):
                yield from self._walk(child, f"{path}[{i}]", keys + [i], ancestors + [node])
        elif isinstance(node, Leaf) and node.size >= 2:
            labels = [str(keys[-1])] if keys and isinstance(keys[-1], str) else []
            unit_name = labels[0] if labels else path
            parent = ancestors[-1] if ancestors else None
            unit = node.unit  # (an HDF5 dataset's units attribute was ignored: found by fuzzing)
            if isinstance(parent, dict):
                for f in NAME_FIELDS:
                    v = parent.get(f)
                    if isinstance(v, str) and v.strip():
                        labels += [v.strip(), _last_component(v)]
                        unit_name = _last_component(v)
                        break
                for f in UNIT_FIELDS if unit is None else ():
                    v = parent.get(f)
                    if isinstance(v, str) and v.strip():
                        unit = v.strip()
                        break
            # a variable that is a Simulink "structure (with time)" of one signal, or a struct
            # with a Data field, answers to the variable's name: u.signals.values is "u"
            ks = [k for k in keys if isinstance(k, str)]
            if len(ks) >= 2 and ks[-1] in DATA_FIELDS and (
                    len(ks) == 2 or (len(ks) == 3 and ks[1] == "signals" and self._single(ancestors[1]))):
                labels.append(ks[0])
                if unit_name in DATA_FIELDS:
                    unit_name = ks[0]
            yield Entry(path, node, list(dict.fromkeys(labels)), unit, unit_name,
                        self._time_for(path, keys, ancestors, node))

    @staticmethod
    def _single(signals: Any) -> bool:
        return isinstance(signals, dict) or (isinstance(signals, list) and len(signals) == 1)

    def _time_for(self, path: str, keys: list[Any], ancestors: list[Any], leaf: Leaf) -> str | None:
        """A time vector that goes with a signal: the nearest struct's time field, or dSPACE's X."""
        for depth in range(len(ancestors) - 1, 0, -1):  # not the root: top-level t is found by name
            anc = ancestors[depth]
            prefix = self._path_of(keys[:depth])
            if not isinstance(anc, dict):
                continue
            for f in TIME_FIELDS:
                v = anc.get(f)
                if isinstance(v, Leaf) and v is not leaf and v.size >= 2:
                    return f"{prefix}.{f}"
            if "X" in anc and "Y" in anc and depth < len(keys) and keys[depth] == "Y":
                x = anc["X"]
                xi = 0
                elem = ancestors[depth + 2] if depth + 2 < len(ancestors) else None
                if isinstance(elem, dict):
                    idx = elem.get("XIndex")
                    if isinstance(idx, Leaf) and idx.size == 1:
                        xi = int(np.asarray(idx.read()).ravel()[0]) - 1
                if isinstance(x, list) and 0 <= xi < len(x) and isinstance(x[xi], dict):
                    return f"{prefix}.X[{xi}].Data" if isinstance(x[xi].get("Data"), Leaf) else None
                if isinstance(x, dict) and isinstance(x.get("Data"), Leaf):
                    return f"{prefix}.X.Data"
        return None

    @staticmethod
    def _path_of(keys: Sequence[Any]) -> str:
        out = ""
        for k in keys:
            out = f"{out}[{k}]" if isinstance(k, int) else (f"{out}.{k}" if out else str(k))
        return out

    # -- naming ----------------------------------------------------------------------------------
    def listing(self) -> str:
        if not self.entries:
            return f"the file holds no numeric arrays ({self._top()})"
        shown = []
        for e in self.entries[:10]:
            extra = f" {e.labels[1]!r}" if len(e.labels) > 1 and e.labels[1] != e.path else ""
            shown.append(f"{e.path} ({e.leaf.describe()}){extra}")
        more = f", ... ({len(self.entries)} in all)" if len(self.entries) > 10 else ""
        others = [f"{k} ({self._what(v)})" for k, v in self.root.items() if isinstance(v, Opaque)][:5]
        also = f"; also {', '.join(others)}" if others else ""
        return f"the file holds {', '.join(shown)}{more}{also}"

    def _top(self) -> str:
        return ", ".join(f"{k}: {self._what(v)}" for k, v in list(self.root.items())[:10]) or "nothing"

    @staticmethod
    def _what(node: Any) -> str:
        if isinstance(node, Leaf):
            return f"{node.describe()} array"
        if isinstance(node, dict):
            return "struct"
        if isinstance(node, list):
            return f"list of {len(node)}"
        if isinstance(node, str):
            return "text"
        if isinstance(node, Opaque):
            return node.what
        return type(node).__name__

    def find(self, given: Any, role: str) -> Key:
        if isinstance(given, (int, np.integer)) and not isinstance(given, bool):
            return self._column_of_matrix(int(given), role)
        if not isinstance(given, str):
            raise DataError(f"{self.where}: a {self.kind} is named by a string (a name or a path such as "
                            f"'x.signals.values') or a 0-based column number, got {given!r} ({flag(role)})")
        sel: Selection | None
        path_problem: str | None
        try:
            sel = self._resolve(parse_path(given))
        except PathError as exc:
            sel = None
            path_problem = str(exc)
        else:
            path_problem = None
        if sel is not None:
            return sel
        hits = match_name(given, [(e.path, [e.path] + e.labels) for e in self.entries])
        if len(hits) > 1:
            which = ", ".join(repr(h) for h in hits[:6])
            raise DataError(f"{self.where}: {given!r} ({ROLE_WORDS[role]}) matches several signals ({which}); "
                            f"give the path of one ({flag(role)})")
        if hits:
            return Selection(str(hits[0]))
        why = f" ({path_problem})" if path_problem else ""
        raise DataError(f"{self.where}: no {self.kind} or signal {given!r}{why} ({ROLE_WORDS[role]}); "
                        f"{self.listing()}")

    def _resolve(self, steps: list[tuple]) -> Selection | None:
        node: Any = self.root
        keys: list[Any] = []
        for n, step in enumerate(steps):
            if step[0] == "key":
                if isinstance(node, list) and len(node) == 1:  # s.signals.values on a 1x1 struct array
                    node = node[0]
                    keys.append(0)
                if not isinstance(node, dict):
                    return None
                name = step[1]
                if name not in node:
                    low = {str(k).lower(): k for k in node}
                    if name.lower() not in low:
                        return None
                    name = low[name.lower()]
                node = node[name]
                keys.append(name)
            elif step[0] == "index":
                i = step[1]
                if isinstance(node, list):
                    if not 0 <= i < len(node):
                        raise DataError(f"{self.where}: index {i} is out of range in "
                                        f"{self._path_of(keys)!r}, which has {len(node)} elements (counting from 0)")
                    node = node[i]
                    keys.append(i)
                elif i != 0 or isinstance(node, Leaf):
                    return None
            else:  # slice
                if not isinstance(node, Leaf) or n != len(steps) - 1:
                    return None
                axis, i = step[1], step[2]
                if len(node.shape) != 2:
                    raise DataError(f"{self.where}: {self._path_of(keys)!r} has shape {node.describe()}; "
                                    f"a row or column can be picked only from a matrix")
                if not 0 <= i < node.shape[axis]:
                    what = "column" if axis == 1 else "row"
                    raise DataError(f"{self.where}: {what} {i} of {self._path_of(keys)!r} does not exist "
                                    f"(shape {node.describe()}, counting from 0)")
                return Selection(self._path_of(keys), axis, i)
        path = self._path_of(keys)
        if isinstance(node, Leaf):
            return Selection(path)
        if isinstance(node, dict):
            # a Simulink structure of one signal, or a struct with one Data field: take its values
            sig = node.get("signals")
            if sig is not None and self._single(sig):
                s = sig if isinstance(sig, dict) else sig[0]
                if isinstance(s, dict) and isinstance(s.get("values"), Leaf):
                    return Selection(self._path_of(keys + (["signals"] if isinstance(sig, dict) else ["signals", 0])
                                                   + ["values"]))
            for f in DATA_FIELDS:
                if isinstance(node.get(f), Leaf):
                    return Selection(self._path_of(keys + [f]))
        what = self._what(node)
        raise DataError(f"{self.where}: {path!r} is {what}, not an array of numbers; {self.listing()}")

    def _column_of_matrix(self, i: int, role: str) -> Selection:
        mats = [e for e in self.entries if len(e.leaf.shape) == 2 and min(e.leaf.shape) > 1]
        if len(mats) != 1:
            raise DataError(f"{self.where}: a column number ({i}) picks from the one matrix in a file; "
                            f"name the {self.kind} instead ({flag(role)}); {self.listing()}")
        e = mats[0]
        rows, cols = e.leaf.shape
        axis = 1 if rows >= cols else 0  # signals run along the long side
        if not 0 <= i < e.leaf.shape[axis]:
            raise DataError(f"{self.where}: column {i} does not exist: {e.path!r} ({e.leaf.describe()}) holds "
                            f"{e.leaf.shape[axis]} signals, numbered from 0")
        return Selection(e.path, axis, i)

    def guess(self, role: str) -> Key | None:
        pool = self.entries
        if role == "t":  # a struct's own time comes with its signals; guess only top-level vectors
            # (by the root's own keys: a key such as "Time [ms]" is top-level too, and was passed
            # over for its bracket: found by fuzzing)
            top = self.root if isinstance(self.root, dict) else {}
            pool = [e for e in self.entries if e.path in top]
        normed = [(e, {normal_name(x) for x in [e.path] + e.labels}) for e in pool]
        unreadable = {normal_name(k): (k, v) for k, v in self.root.items() if isinstance(v, (Opaque, str))}
        for alias in ALIASES[role]:
            hits = [e for e, ns in normed if alias in ns]
            if not hits and alias in unreadable:
                k, v = unreadable[alias]
                what = v.what if isinstance(v, Opaque) else "text"
                raise DataError(f"{self.where}: {k!r} ({ROLE_WORDS[role]}) is {what}, not an array of numbers")
            if len(hits) == 1:
                return Selection(hits[0].path)
            if len(hits) > 1:
                which = ", ".join(repr(e.path) for e in hits[:6])
                raise DataError(f"{self.where}: several signals could be {ROLE_WORDS[role]} ({which}); name one "
                                f"({flag(role)})")
        return None

    def companion_time(self, key: Key) -> Key | None:
        e = self.by_path.get(key.path)  # type: ignore[attr-defined]
        if e is None or e.time is None:
            return None
        return Selection(e.time)

    def label(self, key: Key) -> str:
        sel: Selection = key  # type: ignore[assignment]
        if sel.axis is None:
            return sel.path
        return f"{sel.path}[:, {sel.index}]" if sel.axis == 1 else f"{sel.path}[{sel.index}, :]"

    def unit_name(self, key: Key) -> str:
        e = self.by_path.get(key.path)  # type: ignore[attr-defined]
        return e.unit_name if e is not None else self.label(key)

    def stated_unit(self, key: Key) -> str | None:
        e = self.by_path.get(key.path)  # type: ignore[attr-defined]
        return e.unit if e is not None else None

    # -- values ----------------------------------------------------------------------------------
    def read(self, keys: Sequence[Key], limit: int) -> list[np.ndarray]:
        sels: list[Selection] = list(keys)  # type: ignore[arg-type]
        leaves = []
        for sel in sels:
            e = self.by_path.get(sel.path)
            if e is None:
                raise DataError(f"{self.where}: {sel.path!r} is not an array of numbers of 2 or more values; "
                                f"{self.listing()}")
            leaf = e.leaf
            if sel.axis is None and not leaf.is_vector():
                axis_long = int(np.argmax(leaf.shape))
                example = f"{sel.path}[:, 0]" if axis_long == 0 else f"{sel.path}[0, :]"
                if len(leaf.shape) == 2:
                    raise DataError(f"{self.where}: {sel.path!r} has shape {leaf.describe()}: it holds "
                                    f"{min(leaf.shape)} signals, not one, and is not flattened; pick one, e.g. "
                                    f"{example!r} (u_col=/y_col= in Python, --u-col/--y-col at the command line)")
                raise DataError(f"{self.where}: {sel.path!r} has shape {leaf.describe()}; a signal is a vector")
            leaves.append(leaf)
        distinct = {sel.path: leaf for sel, leaf in zip(sels, leaves)}  # columns of one matrix: read once
        need = sum(leaf.size * (8 + leaf.dtype.itemsize) for leaf in distinct.values())
        count = len(distinct)
        check_size(self.where, need, limit, f"reading {count} array{'s' if count > 1 else ''} of up to "
                                            f"{max(x.size for x in distinct.values()):,} values")
        cache: dict[str, np.ndarray] = {}
        out = []
        for sel, leaf in zip(sels, leaves):
            try:
                a = cache[sel.path] if sel.path in cache else leaf.read()
            except DataError:
                raise
            except Exception as exc:  # a damaged file
                raise DataError(f"{self.where}: cannot read {sel.path!r} ({type(exc).__name__}: "
                                f"{str(exc).splitlines()[0] if str(exc) else ''})") from None
            cache[sel.path] = a
            if a.shape != leaf.shape and a.size == leaf.size:
                a = a.reshape(leaf.shape)
            if a.shape != leaf.shape:
                raise DataError(f"{self.where}: {sel.path!r} holds {a.shape} values where its header says "
                                f"{leaf.shape}; the file is damaged")
            if sel.axis is not None:
                a = a[:, sel.index] if sel.axis == 1 else a[sel.index, :]
            out.append(np.array(a, dtype=np.float64).ravel())
        return out

    def locate(self, key: Key, row: int) -> str:
        return f"sample {row} of {self.label(key)!r}"

    def explain(self, key: Key, row: int, value: float) -> str:
        return f"sample {row} of {self.label(key)!r} is {value}, not a finite number"
