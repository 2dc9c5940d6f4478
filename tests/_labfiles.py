"""Writers of lab files as other programs lay them out, for the reader tests.

MATLAB v7.3 (``save -v7.3``) files are HDF5 files with a 512-byte user block whose first 128
bytes are MATLAB's text header, version 0x0200 and the endian mark "IM"; arrays are stored
column-major, so MATLAB's N x 1 column is an HDF5 dataset of shape (1, N); every object carries
a ``MATLAB_class`` attribute; a scalar struct is a group; a 1 x K struct array is a group whose
fields are K x 1 datasets of object references into ``#refs#``; text is ``char`` (uint16).
(Layout as documented by hdf5storage's "Storage Format" page and read by MATLAB's own files.)
"""

from __future__ import annotations

from typing import Any

import numpy as np

MAT73_HEADER = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Sun Nov 22 01:00:00 2026 HDF5 schema 1.00 ."


def savemat73(path: Any, variables: dict[str, Any]) -> None:
    """Write ``variables`` as MATLAB's ``save(path, ..., "-v7.3")`` would.

    dict -> scalar struct; list of dicts -> 1 x K struct array; str -> char; anything else a
    double array in MATLAB's orientation (a 1-D array is a 1 x N row, as MATLAB's vectors
    built with ``linspace``).
    """
    import h5py

    with h5py.File(path, "w", userblock_size=512) as f:
        refs = f.create_group("#refs#")
        counter = [0]
        for name, value in variables.items():
            _write(f, refs, name, value, counter)
    head = MAT73_HEADER.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM"
    with open(path, "r+b") as fh:
        fh.write(head)


def _fields_attr(names: list[str]) -> Any:
    import h5py

    dt = h5py.vlen_dtype(np.dtype("S1"))
    out = np.empty(len(names), dtype=dt)
    for i, n in enumerate(names):
        out[i] = np.array([c.encode("ascii") for c in n], dtype="S1")
    return out


def _write(group: Any, refs: Any, name: str, value: Any, counter: list[int]) -> None:
    import h5py

    if isinstance(value, dict):
        g = group.create_group(name)
        g.attrs["MATLAB_class"] = np.bytes_("struct")
        g.attrs["MATLAB_fields"] = _fields_attr(list(value))
        for k, v in value.items():
            _write(g, refs, k, v, counter)
    elif isinstance(value, list):
        g = group.create_group(name)
        g.attrs["MATLAB_class"] = np.bytes_("struct")
        fields = list(value[0])
        g.attrs["MATLAB_fields"] = _fields_attr(fields)
        for k in fields:
            rs = []
            for elem in value:
                counter[0] += 1
                key = f"r{counter[0]:04x}"
                _write(refs, refs, key, elem[k], counter)
                rs.append(refs[key].ref)
            g.create_dataset(k, data=np.array(rs, dtype=h5py.ref_dtype).reshape(len(rs), 1))
    elif isinstance(value, str) and not value:  # MATLAB stores an empty array's dimensions
        ds = group.create_dataset(name, data=np.array([0, 0], dtype=np.uint64))
        ds.attrs["MATLAB_class"] = np.bytes_("char")
        ds.attrs["MATLAB_empty"] = np.uint8(1)
    elif isinstance(value, str):
        codes = np.array([ord(c) for c in value], dtype=np.uint16).reshape(-1, 1)
        ds = group.create_dataset(name, data=codes)
        ds.attrs["MATLAB_class"] = np.bytes_("char")
        ds.attrs["MATLAB_int_decode"] = np.int32(2)
    else:
        arr = np.asarray(value, dtype=np.float64)
        if arr.ndim < 2:
            arr = arr.reshape(1, -1)
        ds = group.create_dataset(name, data=arr.T)
        ds.attrs["MATLAB_class"] = np.bytes_("double")


def v5_struct_array(elements: list[dict[str, Any]]) -> np.ndarray:
    """A 1 x K MATLAB struct array for ``scipy.io.savemat`` (a record array of objects)."""
    names = list(elements[0])
    arr = np.zeros((1, len(elements)), dtype=[(n, "O") for n in names])
    for i, e in enumerate(elements):
        arr[0, i] = tuple(e[n] for n in names)
    return arr


def dspace(t: np.ndarray, signals: list[tuple[str, np.ndarray, str]], *, v73: bool = False) -> dict[str, Any]:
    """A dSPACE ControlDesk recording: X (time) and Y (signals) with Name, Type, Data, Unit.

    Data are 1 x N rows as ControlDesk writes them; signal names are block paths.
    """
    x = {"Name": "Time", "Type": "Time", "Data": np.asarray(t)[None, :], "Unit": "s"}
    ys = [{"Name": name, "Type": "Output", "Raster": "Host Service", "Data": np.asarray(v)[None, :],
           "Unit": unit, "XIndex": 1.0} for name, v, unit in signals]
    if v73:
        return {"X": [x], "Y": ys, "Description": "piezo stage run", "Capture": {"Name": "recorder 1"}}
    return {"X": v5_struct_array([x]), "Y": v5_struct_array(ys), "Description": "piezo stage run",
            "Capture": {"Name": "recorder 1"}}


def simulink_structure_with_time(t: np.ndarray, columns: list[tuple[str, np.ndarray]], *,
                                 v73: bool = False) -> dict[str, Any]:
    """A Simulink "Structure With Time" (To Workspace / logging): time, signals(k).values/label."""
    sigs = [{"values": np.asarray(v)[:, None], "dimensions": 1.0, "label": label,
             "blockName": "piezo_rig/To Workspace"} for label, v in columns]
    time = np.asarray(t)[:, None]
    if v73:
        return {"time": time, "signals": sigs, "blockName": "piezo_rig/To Workspace"}
    return {"time": time, "signals": v5_struct_array(sigs), "blockName": "piezo_rig/To Workspace"}
