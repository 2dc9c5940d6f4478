"""The data sets shipped with piezohyst (inside the package, so an installed wheel has them)."""

from __future__ import annotations

import atexit
import contextlib
import os
from pathlib import Path

import numpy as np

from ._dataset import DataError, Dataset

_extracted: contextlib.ExitStack | None = None


def data_dir() -> Path:
    """The folder of the bundled data sets (``piezo-dbo/``, ``bouc-wen-benchmark/``).

    ``PIEZOHYST_DATA`` overrides it. Otherwise it is ``piezohyst/datasets`` inside the installed
    package, found through :mod:`importlib.resources` (in a source checkout the top-level
    ``data`` folder is a link to it).
    """
    env = os.environ.get("PIEZOHYST_DATA")
    if env:
        return Path(env)
    from importlib.resources import as_file, files

    res = files("piezohyst") / "datasets"
    if isinstance(res, Path):
        return res
    global _extracted
    if _extracted is None:  # a zipped install: unpack once, for this process
        _extracted = contextlib.ExitStack()
        atexit.register(_extracted.close)
    return Path(_extracted.enter_context(as_file(res)))


def load_piezo_dbo(which: str = "model", *, root: str | os.PathLike[str] | None = None) -> Dataset:
    """The measured piezoelectric micromanipulator records of Aye and Ang (ICSTSD 2018).

    ``which="model"``: ``Model_Vi_Do.dat``, the open-loop identification run (1 Hz, 0-3.6 V,
    about 40 cycles); ``which="test"``: ``Test_Vi_Do_Di.dat`` (open-loop and compensated runs;
    column 8, the desired trajectory, is in ``meta["desired"]``). Input column 0 (V), output
    column 4 (the capacitive sensor reading, treated as µm as in the authors' scripts), 200 Hz.
    MIT licence; see ``datasets/piezo-dbo/README.md`` for provenance.
    """
    from ._load import load_dataset
    from ._text import read_table

    files = {"model": "Model_Vi_Do.dat", "test": "Test_Vi_Do_Di.dat"}
    if which not in files:
        raise ValueError(f"which must be 'model' or 'test', got {which!r}")
    base = Path(root) if root is not None else data_dir() / "piezo-dbo"
    path = base / files[which]
    if not path.exists():
        raise DataError(f"{path}: no such file (the bundled data set is missing; reinstall piezohyst or "
                        f"set PIEZOHYST_DATA to a folder holding piezo-dbo/)")
    ds = load_dataset(path, u_col=0, y_col=4, fs=200.0)
    meta = {**ds.meta, "name": f"piezo-dbo/{files[which]}", "licence": "MIT (c) 2019 Yan Naing Aye"}
    if which == "test":
        _names, raw, _header = read_table(path)
        meta["desired"] = np.array(raw[:, 8])
    return Dataset(ds.t, ds.u, ds.y, meta)
