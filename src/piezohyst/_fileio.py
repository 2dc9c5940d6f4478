"""Writing files safely: atomically, never over a user's file unless asked, saying who wrote it."""

from __future__ import annotations

import datetime as _dt
import math
import os
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable


def to_jsonable(obj: Any) -> Any:
    """Plain JSON data from nested dicts/lists with numpy arrays and scalars; NaN and inf become None."""
    import numpy as np

    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


class OverwriteRefused(FileExistsError):
    """The output file exists and ``force`` was not given."""


def producer() -> str:
    """One line saying what wrote a file: package, version, command line, UTC time."""
    from . import __version__

    argv = " ".join(os.path.basename(a) if i == 0 else a for i, a in enumerate(sys.argv))
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    return f"piezohyst {__version__}; command: {argv}; at {now}"


def check_writable(path: str | os.PathLike[str], force: bool) -> Path:
    """Refuse to overwrite an existing file unless ``force``; return the path."""
    p = Path(path)
    if p.exists() and not force:
        raise OverwriteRefused(f"{p} exists; not overwriting it (pass force=True / --force)")
    if p.exists() and p.is_dir():
        raise IsADirectoryError(f"{p} is a directory, not a file")
    return p


def atomic_write(path: str | os.PathLike[str], write: Callable[[Path], None], *, force: bool = False) -> Path:
    """Call ``write(tmp_path)`` then rename the temporary file onto ``path`` in one step.

    A crash or error part-way leaves the old file (or no file) in place, never half a file.
    """
    p = check_writable(path, force)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        write(tmp_path)
        os.replace(tmp_path, p)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise
    return p


def atomic_write_text(path: str | os.PathLike[str], text: str, *, force: bool = False) -> Path:
    """Write ``text`` (UTF-8) atomically."""
    return atomic_write(path, lambda t: t.write_text(text, encoding="utf-8"), force=force)
