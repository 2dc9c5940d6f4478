"""The output limits of a compensator (``u_range``, ``max_slew``) over a whole command, compiled.

:meth:`~piezohyst.models.base.Compensator.command` applied them sample by sample in Python: a
million samples took 256 ms with ``u_range`` against 1.3 ms without (found by a helper timing
records the benchmarks do not use). The same recursion, compiled: the slew limit against the
last limited command, then the range, each change counted, as ``Compensator._limit`` does per
sample.
"""

from __future__ import annotations

import numpy as np

from .._numba import njit
from .._validation import FloatArray


@njit
def limit_run(raw: FloatArray, lo: float, hi: float, slew: float) -> tuple[FloatArray, int]:  # pragma: no cover
    """``(limited commands, how many the limits changed)`` from a reset compensator (no command
    before ``raw[0]``); ``lo``/``hi`` are -inf/inf without a range."""
    out = np.empty(raw.shape[0])
    changed = 0
    prev = 0.0
    have = False
    for k in range(raw.shape[0]):
        u = raw[k]
        v = u
        if have:
            if v < prev - slew:
                v = prev - slew
            elif v > prev + slew:
                v = prev + slew
        if v < lo:
            v = lo
        elif v > hi:
            v = hi
        if v != u:
            changed += 1
        out[k] = v
        prev = v
        have = True
    return out, changed
