"""Measured (or simulated) voltage/displacement records: :class:`Dataset`, reading lab files, saving.

Units at this boundary: time in seconds, input ``u`` in volts, output ``y`` in micrometres.
Values in other units are converted when the file says so (``Displacement [nm]``, ``Time (ms)``,
``u_mV``, a line of units under the header, a dSPACE ``Unit`` field) and ``meta["units"]``
records every conversion.

Formats (found from the file's first bytes, then its name)
-----------------------------------------------------------
* Text tables (``.csv``, ``.tsv``, ``.txt``, ``.dat``, ``.asc``, ``.lvm``, any name): comma,
  semicolon, tab, bar or whitespace delimiters; decimal point or decimal comma
  (``0,001;1,5;12,3``); UTF-8 with or without a byte-order mark, UTF-16 with one, cp1252 or
  latin-1; ``#`` comments; lines of preamble before the table (skipped, counted in
  ``meta["skipped_lines"]``); an optional header and an optional line of units under it; an
  unnamed first column as pandas writes its index (dropped; column numbers count the columns
  after it); a header written as a ``#`` comment (``numpy.savetxt``); clock times
  (``2024-03-05 14:00:00.000``) as seconds from the first sample. Parsed by pandas, only the
  columns needed.
* LabVIEW measurement files (``LabVIEW Measurement`` on the first line, usually ``.lvm``): the
  delimiter and decimal mark its header states, the units of ``Y_Unit_Label``, the time from
  ``X_Value`` or ``X0 + k Delta_X`` (``X_Columns No``), segments that continue in time joined
  (a segment whose time restarts is refused: split the file).
* MATLAB ``.mat`` v4, v5 and v7 (scipy) and v7.3 (HDF5, h5py): variables, or paths into
  structs: ``x.signals.values``, ``logsout.signals[0].values`` (``[i]`` from 0; MATLAB's
  ``(i)``/``{i}`` from 1), ``data[:, 2]`` for one column. A Simulink "structure with time"
  brings its ``time``; a dSPACE ControlDesk struct (``X``/``Y`` arrays of structs with ``Data``,
  ``Name`` and ``Unit``) its ``X.Data``, and its signals answer to their names.
* NumPy ``.npz`` (never with pickles: a data file cannot run code) and ``.npy``; HDF5
  ``.h5``/``.hdf5``.
* Parquet and Excel/OpenDocument through pandas, when its engine (pyarrow, openpyxl, xlrd,
  odfpy) is installed.

What is refused, with a one-line :class:`DataError` naming the file: a matrix where a signal
is expected (N x 2 is never flattened into 2N samples), NaN or inf (with the line or sample and
the column), text in a numeric column, ragged rows, fewer than two samples, a time column that
does not increase or is not uniform (unless ``resample=True``), a sample rate that disagrees
with the time column, a unit of the wrong kind, a file larger than the memory limit
(``max_memory=`` or ``PIEZOHYST_MAX_MEMORY``), and formats it does not read (the message lists
the ones it does).
"""

from __future__ import annotations

from ._bundled import data_dir, load_piezo_dbo
from ._dataset import DataError, Dataset
from ._load import load_dataset, save_dataset, supported
from ._text import read_table

__all__ = ["DataError", "Dataset", "data_dir", "load_dataset", "load_piezo_dbo", "read_table",
           "save_dataset", "supported"]
