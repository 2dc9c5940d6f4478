"""Input checks shared by the public API: refuse bad input up front, naming the parameter."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


class FitError(RuntimeError):
    """An identification that found no model in the data it was given (e.g. every candidate's
    simulation diverged): the data's fault (units, scale), not a bug. A ``RuntimeError``."""


def as_signal(name: str, value: Any, *, min_length: int = 1) -> FloatArray:
    """Return ``value`` as a 1-D, finite float64 array or raise naming ``name``."""
    if isinstance(value, (str, bytes)):
        raise TypeError(f"{name} must be a 1-D array of numbers, got {type(value).__name__}")
    if np.iscomplexobj(value):  # (a cast to float would drop the imaginary part with only a warning)
        raise TypeError(f"{name} must be real numbers, got complex values")
    if isinstance(value, np.ma.MaskedArray) and np.ma.getmaskarray(value).any():
        # (the masked samples were fitted as if valid: found by a helper)
        first = int(np.argmax(np.ma.getmaskarray(value).ravel()))
        raise ValueError(f"{name} has {int(np.ma.count_masked(value))} masked sample(s), first at index {first}: "
                         f"fill them (.filled(...)) or leave them out")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a 1-D array of numbers ({exc})") from None
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got an array of shape {arr.shape}")
    if arr.size < min_length:
        raise ValueError(f"{name} needs at least {min_length} sample(s), got {arr.size}")
    bad = ~np.isfinite(arr)
    if bad.any():
        first = int(np.argmax(bad))
        raise ValueError(
            f"{name} contains {int(bad.sum())} non-finite value(s) (NaN or inf), "
            f"first at index {first}"
        )
    return np.ascontiguousarray(arr)


def as_scalar(name: str, value: Any, *, positive: bool = False, nonnegative: bool = False) -> float:
    """Return ``value`` as a finite float or raise naming ``name``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v}")
    if positive and v <= 0:
        raise ValueError(f"{name} must be > 0, got {v}")
    if nonnegative and v < 0:
        raise ValueError(f"{name} must be >= 0, got {v}")
    return v


def as_count(name: str, value: Any, *, minimum: int = 0, maximum: int | None = None,
             why: str = "") -> int:
    """Return ``value`` as a whole number in ``minimum..maximum`` or raise naming ``name``
    (``why`` says what the upper limit is, e.g. "leaves too few samples to fit on")."""
    if isinstance(value, (float, np.floating)) and math.isfinite(value) and float(value).is_integer():
        value = int(value)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be a whole number, got {value!r}")
    v = int(value)
    if v < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {v}")
    if maximum is not None and v > maximum:
        raise ValueError(f"{name} of {v} {why or f'is more than the largest allowed, {maximum}'}")
    return v


def as_flag(name: str, value: Any, *, default_ok: bool = False) -> Any:
    """``value`` if it is a bool (or, with ``default_ok``, None for the default), else a TypeError
    naming ``name``: a string such as ``"no"`` is true in Python and ran as if it said yes."""
    if (value is None and default_ok) or isinstance(value, (bool, np.bool_)):
        return value
    raise TypeError(f"{name} must be True or False{' (or None for the default)' if default_ok else ''}, "
                    f"got {value!r}")


def frozen(arr: FloatArray) -> FloatArray:
    """A read-only copy, so a model's parameters cannot change under it."""
    out = np.array(arr, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out
