"""Model files: versioned JSON, written atomically, never pickled.

A file looks like::

    {
      "schema": "piezohyst.model/3",
      "kind": "prandtl-ishlinskii" | "bouc-wen" | "rate-dependent" | "asymmetric-pi" | "preisach",
      "producer": "piezohyst 0.1.0; command: ...; at ...",
      "units": {...},
      "parameters": {...},          # the kind's to_dict(); wrappers nest {"kind", "parameters"}
      "fit": {"method": ..., "rmse": ..., ...} | null,
      "data": {"sha256": ..., "n_samples": ..., "source": ...} | null
    }

``schema`` carries a major version: a reader accepts every version up to its own and refuses a
newer one with a message, so a model identified today loads next year, and a file from a newer
piezohyst is not silently misread. JSON holds only numbers and strings: a model file from a
colleague cannot run code.
"""

from __future__ import annotations

import json
import math
import os
import stat
from pathlib import Path
from typing import Any, Callable


from ._fileio import atomic_write_text, producer
from ._fileio import to_jsonable as _clean
from .models.base import kind_class, kind_of, kinds
from .models.base import model_from_dict as registry_from_dict

#: Largest model file read (a model is kilobytes; this refuses a mistaken or hostile input).
MAX_FILE_BYTES = 64 * 1024 * 1024

SCHEMA_NAME = "piezohyst.model"
#: Version 2 added the kinds beyond the paper (nested models in "parameters"); version 1 files
#: (prandtl-ishlinskii, bouc-wen) have the same layout and load unchanged. Version 3: a Bouc-Wen
#: hysteresis may carry its operating range (``v_range``), which its inverse keeps to; a reader
#: that dropped it would invert a model that is invertible only within it, so older readers refuse
#: version 3 files. Versions 1 and 2 load unchanged. A file is written with the oldest version
#: that holds what it carries (:func:`schema_version_for`): a model without an operating range is
#: a version 2 file, which piezohyst 0.2 reads too. Version 4: the generalized Duhem kind (a
#: version 3 reader would call it an unknown kind; it says "written by a newer piezohyst" instead).
#: Version 5: a rate-dependent model may carry the limit of its compensator's input-lag lead
#: (``input_lead_gain``); a reader that dropped it would send the exact lead's steps (dozens of
#: times the reference's behind a long amplifier lag), so older readers refuse such a file.
#: Version 6: the after-history kind (a model started from the state a known input history
#: leaves; a version 5 reader would call it an unknown kind).
SCHEMA_VERSION = 6
#: The schema version that introduced each kind after version 2 (a file holding one, at any depth,
#: carries at least that version).
KIND_SINCE = {"generalized-duhem": 4, "after-history": 6}
#: Deepest nesting a model file may have (wrappers hold models; nothing legitimate nests deeper).
MAX_DEPTH = 32


class ModelFileError(ValueError):
    """A model file that cannot be read, with the file and the reason in the message."""


_UNITS = {"input": "V", "output": "um"}


def model_units(model: Any) -> dict[str, str]:
    """The units a model's file records (SI parameters for Bouc-Wen, µm otherwise)."""
    if getattr(model, "output_unit", "um") == "m":
        return {"input": "V", "output": "m", "m": "kg", "b": "N s/m", "k": "N/m", "d1": "m/V",
                "alpha": "1", "beta": "1/V", "gamma": "1/V", "offset": "m", "h0": "m"}
    return {**_UNITS, "time": "s", "note": "thresholds and lags act on the input (V); weights are um per V"}


def model_to_dict(model: Any, *, fit: Any = None, dataset: Any = None,
                  units: dict[str, str] | None = None, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The JSON document for ``model`` (see the module docstring)."""
    try:
        kind = kind_of(model)
    except TypeError as exc:
        raise TypeError(f"cannot save a {type(model).__name__}: {exc}") from None
    _check_finite(model.to_dict(), f"cannot save the {kind} model: parameter")
    # (a string or an array here raised AttributeError on .summary / .sha256: found by fuzzing)
    if fit is not None and not callable(getattr(fit, "summary", None)):
        raise TypeError(f"fit must be the FitResult the model came from (it has .summary()), or None; "
                        f"got {type(fit).__name__}")
    if dataset is not None and not all(hasattr(dataset, a) for a in ("sha256", "fs", "meta")):
        raise TypeError(f"dataset must be the piezohyst Dataset the model was fitted on (load_dataset, "
                        f"Dataset(t, u, y)), or None; got {type(dataset).__name__}")
    unit = model_units(model)
    if units:
        unit.update(units)
    doc: dict[str, Any] = {
        "schema": f"{SCHEMA_NAME}/{schema_version_for(model.to_dict(), kind)}",
        "kind": kind,
        "producer": producer(),
        "units": unit,
        "parameters": model.to_dict(),
        "fit": fit.summary() if fit is not None else None,
        "data": None,
    }
    if dataset is not None:
        doc["data"] = {"sha256": dataset.sha256, "n_samples": len(dataset), "fs_hz": dataset.fs,
                       "source": dataset.meta.get("source"),
                       "source_sha256": dataset.meta.get("source_sha256")}
    if extra:
        doc["extra"] = extra
    return _clean(doc)


def schema_version_for(params: Any, kind: str | None = None) -> int:
    """The oldest schema version that holds ``params`` (a model's ``to_dict()``, of ``kind``): the
    version that introduced a kind it holds (:data:`KIND_SINCE`, nested ones too), 5 where some
    part limits its input-lag lead (``input_lead_gain``), 3 where some part carries an operating
    range (``v_range``), else 2."""
    since = KIND_SINCE.get(kind, 2) if kind is not None else 2
    if isinstance(params, dict):
        nested = params.get("kind")
        if isinstance(nested, str):
            since = max(since, KIND_SINCE.get(nested, 2))
        if params.get("v_range") is not None:
            since = max(since, 3)
        if params.get("input_lead_gain"):
            since = max(since, 5)
        return max([since, *(schema_version_for(v) for v in params.values())])
    if isinstance(params, (list, tuple)):
        return max((schema_version_for(v) for v in params), default=2)
    return 2


def _check_finite(obj: Any, what: str, where: str = "") -> None:
    """Refuse NaN/inf anywhere in a model's parameters (they would be written as null, and the
    file would not load back)."""
    import numpy as np

    if isinstance(obj, dict):
        for k, v in obj.items():
            _check_finite(v, what, f"{where}.{k}" if where else str(k))
    elif isinstance(obj, np.ndarray) and obj.dtype.kind in "fc":
        bad = ~np.isfinite(obj)
        if bad.any():
            i = int(np.argmax(bad.ravel()))
            raise ValueError(f"{what} {where}[{i}] is {obj.ravel()[i]}; a model file holds finite numbers only")
    elif isinstance(obj, (list, tuple, np.ndarray)):
        for i, v in enumerate(obj):
            _check_finite(v, what, f"{where}[{i}]")
    elif isinstance(obj, (float, np.floating)) and not math.isfinite(float(obj)):
        raise ValueError(f"{what} {where} is {float(obj)}; a model file holds finite numbers only")


def save_model(model: Any, path: str | os.PathLike[str], *, fit: Any = None, dataset: Any = None,
               units: dict[str, str] | None = None, extra: dict[str, Any] | None = None,
               force: bool = False) -> Path:
    """Save ``model`` (any registered kind) as a versioned JSON file, atomically; refuse to
    overwrite unless ``force``.

    Parameters
    ----------
    model : any kind of :mod:`piezohyst.models`
    path : path
    fit : FitResult, optional
        Its figures (RMSE, method, time, hold-out errors, warnings) are stored with the model.
    dataset : Dataset, optional
        Its SHA-256 and source are stored, so the model says what it was identified on.
    """
    if isinstance(model, (str, os.PathLike)) and not isinstance(path, (str, os.PathLike)):
        # (save_model("m.json", model) failed inside pathlib: found by a helper; save_dataset
        # takes the path first, which is how the swap happens)
        raise TypeError(f"save_model(model, path): the model comes first, then the file name; got the name "
                        f"{os.fspath(model)!r} first")
    _check_path("path", path)
    check_model_file_name(path)
    doc = model_to_dict(model, fit=fit, dataset=dataset, units=units, extra=extra)
    text = json.dumps(doc, indent=2, allow_nan=False) + "\n"
    return atomic_write_text(path, text, force=force)


def check_model_file_name(path: str | os.PathLike[str]) -> None:
    """Refuse a model file name whose ending says another format (:data:`NOT_JSON_SUFFIXES`):
    it wrote JSON under the name ``m.mat``, which MATLAB then cannot open (found by fuzzing)."""
    if Path(path).suffix.lower() in NOT_JSON_SUFFIXES:
        raise ValueError(f"{path}: a model file is JSON; give it a .json name (for MATLAB, export the model "
                         f"and its inverse as a .mat file: piezohyst export --to matlab, "
                         f"piezohyst.export.export_matlab)")


#: File name endings :func:`save_model` refuses: formats a model file is not (it is JSON).
NOT_JSON_SUFFIXES = frozenset({".mat", ".npz", ".npy", ".csv", ".tsv", ".h5", ".hdf5", ".xlsx", ".xls", ".ods",
                               ".parquet", ".pkl", ".pickle", ".c", ".h"})


def schema_version(doc: Any, source: str, name: str = SCHEMA_NAME, newest: int = SCHEMA_VERSION) -> int:
    """The schema version of a document, checked: a positive integer no newer than ``newest``."""
    if not isinstance(doc, dict):
        raise ModelFileError(f"{source}: not a piezohyst file (top level is not an object)")
    schema = doc.get("schema")
    if not isinstance(schema, str) or not schema.startswith(name + "/"):
        raise ModelFileError(f"{source}: not a {name} file (schema is {schema!r})")
    text = schema.split("/", 1)[1]
    if not text.isdigit() or int(text) < 1:
        raise ModelFileError(f"{source}: unreadable schema version {text!r} in {schema!r} (expected a positive integer)")
    version = int(text)
    if version > newest:
        raise ModelFileError(f"{source}: written by a newer piezohyst (schema version {version}; "
                             f"this one reads up to {newest}); upgrade piezohyst")
    return version


def _depth(obj: Any, limit: int) -> int:
    """Nesting depth of plain JSON data, without recursion (a hostile file cannot overflow the stack)."""
    stack = [(obj, 1)]
    deepest = 0
    while stack:
        o, d = stack.pop()
        deepest = max(deepest, d)
        if deepest > limit:
            return deepest
        if isinstance(o, dict):
            stack.extend((v, d + 1) for v in o.values())
        elif isinstance(o, list):
            stack.extend((v, d + 1) for v in o)
    return deepest


def model_from_dict(doc: Any, *, source: str = "model") -> Any:
    """Rebuild a model from its JSON document, checking the schema."""
    schema_version(doc, source)
    if _depth(doc, MAX_DEPTH) > MAX_DEPTH:
        raise ModelFileError(f"{source}: nested deeper than {MAX_DEPTH} levels; not a model document")
    kind = doc.get("kind")
    params = doc.get("parameters")
    if not isinstance(kind, str):
        raise ModelFileError(f"{source}: 'kind' is missing or not a string; the kinds are {kinds()}")
    if not isinstance(params, dict):
        raise ModelFileError(f"{source}: 'parameters' is missing or not an object")
    try:
        kind_class(kind)
    except ValueError:
        raise ModelFileError(f"{source}: unknown model kind {kind!r}; known kinds are {kinds()}") from None
    text = _text_in_arrays(params, "parameters")
    if text:
        what = "a boolean" if isinstance(text[1], bool) else "text"
        raise ModelFileError(f"{source}: {text[0]} holds {what} ({json.dumps(text[1])[:40]}) where a number belongs; "
                             "a model file's numbers are JSON numbers, not strings or true/false")
    huge = _huge_number(params, "parameters")
    if huge:
        # (found by fuzzing: weights of 1e308 loaded, summed to inf and simulated to NaN, silently)
        raise ModelFileError(f"{source}: {huge[0]} is {huge[1]:g}, beyond any physical parameter (a model file's "
                             f"numbers stay below {HUGE_PARAMETER:g} in magnitude, where sums and products of "
                             "them cannot overflow)")
    read = _ReadKeys(params)
    try:
        # (a missing parameter is a ValueError naming it: every kind's from_dict is wrapped so at
        # registration, models.base._checked_from_dict)
        model = registry_from_dict(kind, read)
    except (ValueError, TypeError) as exc:
        raise ModelFileError(f"{source}: {exc}") from None
    unread = read.unread("parameters")
    if unread:
        # a typo ("ofset") was ignored and the model built without it (found by fuzzing)
        raise ModelFileError(f"{source}: unknown parameter{'s' if len(unread) > 1 else ''} {', '.join(unread)} for a "
                             f"{kind} model (misspelt? a {kind} model file holds {', '.join(sorted(read.read))})")
    return model


class _ReadKeys(dict):  # type: ignore[type-arg]
    """A model file's ``parameters`` that record which names the kind's ``from_dict`` read (by
    name, by a membership test, or all of them by iterating), nested objects alike: what it did
    not read it would have ignored."""

    def __init__(self, d: dict[str, Any]) -> None:
        super().__init__({k: _ReadKeys(v) if isinstance(v, dict) else v for k, v in d.items()})
        self.read: set[Any] = set()

    def __getitem__(self, key: Any) -> Any:
        self.read.add(key)
        return super().__getitem__(key)

    def get(self, key: Any, default: Any = None) -> Any:
        self.read.add(key)
        return super().get(key, default)

    def __contains__(self, key: Any) -> bool:
        self.read.add(key)
        return super().__contains__(key)

    def pop(self, key: Any, *default: Any) -> Any:
        self.read.add(key)
        return super().pop(key, *default)

    def _all(self) -> None:
        self.read.update(super().keys())

    def __iter__(self) -> Any:
        self._all()
        return super().__iter__()

    def keys(self) -> Any:
        self._all()
        return super().keys()

    def items(self) -> Any:
        self._all()
        return super().items()

    def values(self) -> Any:
        self._all()
        return super().values()

    def unread(self, path: str) -> list[str]:
        out = []
        for k in dict.keys(self):
            v = dict.__getitem__(self, k)
            if k not in self.read:
                out.append(f"{path}.{k}")
            elif isinstance(v, _ReadKeys):
                out += v.unread(f"{path}.{k}")
        return out


def _first_value(obj: Any, path: str, bad: Callable[[Any, bool], bool]) -> tuple[str, Any] | None:
    """The path and value of the first value in the JSON data ``obj`` (depth first, ``path`` its
    name) for which ``bad(value, in_a_list)`` holds, or None."""
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, list) else ()
    for k, v in items:
        where = f"{path}.{k}" if isinstance(obj, dict) else f"{path}[{k}]"
        if bad(v, isinstance(obj, list)):
            return where, v
        found = _first_value(v, where, bad) if isinstance(v, (dict, list)) else None
        if found:
            return found
    return None


def _text_in_arrays(obj: Any, path: str) -> tuple[str, str] | None:
    """The path of the first list item that is a string (``"0.0307"`` for a weight) or a boolean
    (``true`` was read as 1.0: found by fuzzing), and the item, or None."""
    return _first_value(obj, path, lambda v, in_list: in_list and isinstance(v, (str, bool)))


#: The largest magnitude a model file's parameter may have: far beyond any physical value in any
#: unit, and small enough that a model's sums and products of its parameters stay finite.
HUGE_PARAMETER = 1e100


def _huge_number(obj: Any, path: str) -> tuple[str, float] | None:
    """The path and value of the first number in ``obj`` beyond :data:`HUGE_PARAMETER` in
    magnitude, or None."""
    found = _first_value(obj, path, lambda v, in_list: isinstance(v, (int, float)) and not isinstance(v, bool)
                         and abs(v) > HUGE_PARAMETER)
    return (found[0], float(found[1])) if found else None


def _strict_loads(text: str, source: str) -> Any:
    """JSON as the standard defines it: NaN, Infinity and numbers beyond float range are refused."""
    from ._fileio import loads_strict

    def unique(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        # (a second "offset" silently won over the first; a second "kind" gave a puzzling message:
        # found by fuzzing)
        out: dict[str, Any] = {}
        for k, v in pairs:
            if k in out:
                raise ModelFileError(f"{source}: the key {k!r} appears twice in one object; which one is meant "
                                     "cannot be told: keep one")
            out[k] = v
        return out

    return loads_strict(
        text,
        bad_constant=lambda name: ModelFileError(f"{source}: {name} is not a JSON number; a model file holds "
                                                 "finite numbers only"),
        bad_number=lambda num: ModelFileError(f"{source}: the number {num[:40]} is beyond double precision"),
        object_pairs_hook=unique)


def load_model_document(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The raw JSON document of a model file (model, fit figures, data hash).

    Every problem is a :class:`ModelFileError` naming the file: missing, a folder, not a regular
    file, larger than :data:`MAX_FILE_BYTES`, not UTF-8, not strict JSON (NaN and Infinity are
    not JSON), nested deeper than :data:`MAX_DEPTH`.
    """
    p = Path(path).expanduser()
    try:
        st = p.stat()
        if stat.S_ISDIR(st.st_mode):
            raise ModelFileError(f"{p}: is a folder, not a model file")
        if not stat.S_ISREG(st.st_mode):
            raise ModelFileError(f"{p}: not a regular file (a device or a pipe is not a model file)")
        if st.st_size > MAX_FILE_BYTES:
            raise ModelFileError(f"{p}: {st.st_size} bytes is too large for a model file "
                                 f"(the limit is {MAX_FILE_BYTES} bytes)")
        with open(p, "rb") as fh:
            raw = fh.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        raise ModelFileError(f"{p}: no such file") from None
    except OSError as exc:
        raise ModelFileError(f"{p}: cannot read it ({exc.strerror or exc})") from None
    if len(raw) > MAX_FILE_BYTES:
        raise ModelFileError(f"{p}: too large for a model file (the limit is {MAX_FILE_BYTES} bytes)")
    if not raw.strip():
        raise ModelFileError(f"{p}: the file is empty")
    try:
        text = raw.decode("utf-8-sig")  # (a byte-order mark, as some Windows editors save: found by fuzzing)
    except UnicodeDecodeError:
        raise ModelFileError(f"{p}: not a text file (cannot decode it as UTF-8); a model file is JSON") from None
    try:
        doc = _strict_loads(text, str(p))
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"{p}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except RecursionError:
        raise ModelFileError(f"{p}: nested too deeply to be a model file") from None
    if _depth(doc, MAX_DEPTH) > MAX_DEPTH:
        raise ModelFileError(f"{p}: nested deeper than {MAX_DEPTH} levels; not a model file")
    if isinstance(doc, dict):
        _check_fit_block(doc.get("fit"), str(p))
    return doc  # type: ignore[no-any-return]


#: The largest voltage a model file's ``fit`` block may state (its record's input range, its
#: largest loop): far beyond any piezo amplifier (they reach about 1.5 kV), so a hand-edited range
#: of 1e99 V, which compensate and export take for the amplifier's range, is refused.
MAX_RECORD_VOLTS = 1e5


def _check_fit_block(fit: Any, source: str) -> None:
    """The ``fit`` block's figures that the command line reads (the input range the model was
    identified on sets the amplifier's default range; its largest loop, the extrapolation warning):
    a hand-edited one was an internal error in ``compensate`` ("0..100", one number, text, a
    string for the block: found by fuzzing) or a range of 1e99 V that the C code never clipped to."""
    if fit is None:
        return
    if not isinstance(fit, dict):
        raise ModelFileError(f"{source}: 'fit' is {type(fit).__name__}, not an object of the fit's figures")
    rng = fit.get("input_range_V")
    if rng is not None:
        ok = (isinstance(rng, list) and len(rng) == 2
              and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in rng))
        if not ok or not rng[0] < rng[1] or max(abs(rng[0]), abs(rng[1])) > MAX_RECORD_VOLTS:
            raise ModelFileError(f"{source}: fit.input_range_V must be [low, high] in volts, low < high, within "
                                 f"{MAX_RECORD_VOLTS:g} V of 0 (the record's input range), got {json.dumps(rng)[:60]}")
    loop = fit.get("largest_loop_V")
    if loop is not None and not (isinstance(loop, (int, float)) and not isinstance(loop, bool)
                                 and 0.0 <= loop <= 2.0 * MAX_RECORD_VOLTS):
        raise ModelFileError(f"{source}: fit.largest_loop_V must be a number of volts >= 0, got {json.dumps(loop)[:60]}")


def _check_path(name: str, path: Any) -> None:
    if not isinstance(path, (str, os.PathLike)):
        hint = " (a model document as a dict: piezohyst.modelio.model_from_dict)" if isinstance(path, dict) else ""
        raise TypeError(f"{name} must be a file name (str or os.PathLike), got {type(path).__name__}{hint}")


def load_model(path: str | os.PathLike[str]) -> Any:
    """Load a model saved by :func:`save_model` (any kind, any schema version up to this one's)."""
    _check_path("path", path)
    p = Path(path).expanduser()
    return model_from_dict(load_model_document(p), source=str(p))
