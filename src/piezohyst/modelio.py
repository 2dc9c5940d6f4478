"""Model files: versioned JSON, written atomically, never pickled.

A file looks like::

    {
      "schema": "piezohyst.model/1",
      "kind": "prandtl-ishlinskii" | "bouc-wen",
      "producer": "piezohyst 0.1.0; command: ...; at ...",
      "units": {...},
      "parameters": {...},
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
import os
from pathlib import Path
from typing import Any


from ._fileio import atomic_write_text, producer
from ._fileio import to_jsonable as _clean
from .models.bouc_wen import BoucWen
from .models.pi import PrandtlIshlinskii

SCHEMA_NAME = "piezohyst.model"
SCHEMA_VERSION = 1
KINDS = ("prandtl-ishlinskii", "bouc-wen")


class ModelFileError(ValueError):
    """A model file that cannot be read, with the file and the reason in the message."""


def model_to_dict(model: Any, *, fit: Any = None, dataset: Any = None,
                  units: dict[str, str] | None = None, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The JSON document for ``model`` (see the module docstring)."""
    if isinstance(model, PrandtlIshlinskii):
        kind = "prandtl-ishlinskii"
        params = {
            "thresholds": model.thresholds.tolist(), "weights": model.weights.tolist(),
            "initial_state": model.initial_state.tolist(), "offset": model.offset,
            "input_offset": model.input_offset,
        }
        unit = {"input": "V", "output": "um", "thresholds": "input unit", "weights": "output unit per input unit"}
    elif isinstance(model, BoucWen):
        kind = "bouc-wen"
        params = model.parameters()
        unit = {"input": "V", "output": "m", "m": "kg", "b": "N s/m", "k": "N/m", "d1": "m/V",
                "alpha": "1", "beta": "1/V", "gamma": "1/V", "offset": "m", "h0": "m"}
    else:
        raise TypeError(f"cannot save a {type(model).__name__}; expected PrandtlIshlinskii or BoucWen")
    if units:
        unit.update(units)
    doc: dict[str, Any] = {
        "schema": f"{SCHEMA_NAME}/{SCHEMA_VERSION}",
        "kind": kind,
        "producer": producer(),
        "units": unit,
        "parameters": params,
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


def save_model(model: Any, path: str | os.PathLike[str], *, fit: Any = None, dataset: Any = None,
               units: dict[str, str] | None = None, extra: dict[str, Any] | None = None,
               force: bool = False) -> Path:
    """Save ``model`` as a versioned JSON file, atomically; refuse to overwrite unless ``force``.

    Parameters
    ----------
    model : PrandtlIshlinskii or BoucWen
    path : path
    fit : FitResult, optional
        Its figures (RMSE, method, time, sensitivity) are stored with the model.
    dataset : Dataset, optional
        Its SHA-256 and source are stored, so the model says what it was identified on.
    """
    doc = model_to_dict(model, fit=fit, dataset=dataset, units=units, extra=extra)
    text = json.dumps(doc, indent=2, allow_nan=False) + "\n"
    return atomic_write_text(path, text, force=force)


def model_from_dict(doc: Any, *, source: str = "model") -> Any:
    """Rebuild a model from its JSON document, checking the schema."""
    if not isinstance(doc, dict):
        raise ModelFileError(f"{source}: not a piezohyst model (top level is not an object)")
    schema = doc.get("schema")
    if not isinstance(schema, str) or not schema.startswith(SCHEMA_NAME + "/"):
        raise ModelFileError(f"{source}: not a piezohyst model file (schema is {schema!r})")
    try:
        version = int(schema.split("/", 1)[1])
    except ValueError:
        raise ModelFileError(f"{source}: unreadable schema version in {schema!r}") from None
    if version > SCHEMA_VERSION:
        raise ModelFileError(f"{source}: written by a newer piezohyst (schema version {version}; "
                             f"this one reads up to {SCHEMA_VERSION}); upgrade piezohyst")
    kind = doc.get("kind")
    params = doc.get("parameters")
    if not isinstance(params, dict):
        raise ModelFileError(f"{source}: 'parameters' is missing or not an object")
    try:
        if kind == "prandtl-ishlinskii":
            return PrandtlIshlinskii(
                thresholds=params["thresholds"], weights=params["weights"],
                initial_state=params.get("initial_state"), offset=params.get("offset", 0.0),
                input_offset=params.get("input_offset", 0.0),
            )
        if kind == "bouc-wen":
            names = ("m", "b", "k", "d1", "alpha", "beta", "gamma", "offset", "h0")
            return BoucWen(**{n: params[n] for n in names if n in params})
    except KeyError as exc:
        raise ModelFileError(f"{source}: parameter {exc} is missing") from None
    except (ValueError, TypeError) as exc:
        raise ModelFileError(f"{source}: {exc}") from None
    raise ModelFileError(f"{source}: unknown model kind {kind!r}; known kinds are {list(KINDS)}")


def load_model_document(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The raw JSON document of a model file (model, fit figures, data hash)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ModelFileError(f"{p}: no such file") from None
    except (IsADirectoryError, UnicodeDecodeError) as exc:
        raise ModelFileError(f"{p}: cannot read it as a model file ({exc})") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"{p}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    return doc  # type: ignore[no-any-return]


def load_model(path: str | os.PathLike[str]) -> Any:
    """Load a model saved by :func:`save_model` (any schema version up to this one's)."""
    p = Path(path)
    return model_from_dict(load_model_document(p), source=str(p))
