"""From a model to a stage's controller: C99 compensators, MATLAB files and wave tables.

* :func:`export_c` / :func:`generate_c` - ``compensator.h`` and ``compensator.c``
  (:mod:`piezohyst.export.c`), equal to ``piezohyst compensate`` sample for sample;
* :func:`export_matlab` - a ``.mat`` with the model, its inverse and a reference command table
  (:mod:`piezohyst.export.matlab`);
* :func:`write_table`, :func:`periodic_table`, :func:`resample_reference` - wave tables
  (:mod:`piezohyst.export.tables`);
* :mod:`piezohyst.export.pycontrol` - the bridge to python-control (optional extra ``control``).

Everything goes through the model protocol (:mod:`piezohyst.models.base`): each kind's compensator
emits its own C piece and says what its inverse's parameters are.
"""

from .c import CEmitter, export_c, generate_c
from .matlab import export_matlab
from .tables import TABLE_FORMATS, periodic_table, resample_reference, write_table

__all__ = ["CEmitter", "TABLE_FORMATS", "export_c", "export_matlab", "generate_c", "periodic_table",
           "resample_reference", "write_table"]
