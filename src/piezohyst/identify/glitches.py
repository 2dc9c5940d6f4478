"""Isolated gross glitches in a measured output: one or two samples far off their neighbours.

A displacement sensor glitches now and then: an interferometer miscounts a fringe or its beam is
cut for a moment, a capacitive sensor's converter returns a wild value, a packet arrives
corrupted. Such a sample is off by a large part of the stroke while its neighbours are not. Least
squares weighs it by its square, and the model search scores candidates on held-out samples that
contain some of them: measured on the zoo's Maxwell-slip stage, one glitch of the whole span per
5000 samples made the chosen model predict a clean record 9x worse (0.039 -> 0.37 % of span RMS,
and a delay of 9 samples where there is 1), one of 30 % per 1000 samples 16x worse.

A sample is a glitch when it lies further from the running median of :data:`WIDTH` samples
around it than both :data:`NOISE_FACTOR` times the record's robust noise level (the median
absolute deviation of that difference) and :data:`SPAN_SHARE` of the output's span (between its
0.5th and 99.5th percentiles), in a run of at most ``WIDTH // 2`` such samples with at least
:data:`CLEAR` ordinary samples on either side (and so not among the record's first or last
:data:`CLEAR`). What a stage does is never that: a step keeps its
edge through the median, ringing and stairs fall within the span share or come in runs.
:func:`bridge_glitches` replaces them by linear interpolation between their neighbours.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..signals import interpolate_over

IntArray = NDArray[np.int64]

#: samples in the running median a sample is compared with (glitches of up to WIDTH // 2 samples)
WIDTH = 5
#: how many times the robust noise level a glitch lies off the running median, at least
NOISE_FACTOR = 10.0
#: what share of the output's span a glitch lies off the running median, at least
SPAN_SHARE = 0.05
#: ordinary samples a glitch has on either side (so that ringing or a burst is not one)
CLEAR = 10


def find_glitches(y: FloatArray) -> IntArray:
    """The indices of the isolated gross glitches of ``y`` (module docstring); empty when none."""
    from scipy.ndimage import median_filter

    y = np.asarray(y, dtype=np.float64)
    if y.size < 4 * WIDTH or not np.all(np.isfinite(y)):
        return np.empty(0, dtype=np.int64)
    r = y - median_filter(y, size=WIDTH, mode="nearest")
    lo, hi = np.percentile(y, [0.5, 99.5])
    noise = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    threshold = max(NOISE_FACTOR * noise, SPAN_SHARE * float(hi - lo))
    if not threshold > 0.0:
        return np.empty(0, dtype=np.int64)
    idx = np.flatnonzero(np.abs(r) > threshold)
    if idx.size == 0:
        return idx.astype(np.int64)
    # runs of neighbouring flagged samples: (first, last) index into idx
    breaks = np.flatnonzero(np.diff(idx) > 1)
    first = np.concatenate([[0], breaks + 1])
    last = np.concatenate([breaks, [idx.size - 1]])
    short = (idx[last] - idx[first] + 1) <= WIDTH // 2
    # ordinary samples between runs, and before the first and after the last (a record's first
    # or last few samples cannot be judged: a transient as the record starts is no glitch)
    between = idx[first[1:]] - idx[last[:-1]] - 1
    before = np.concatenate([[idx[0]], between])
    after = np.concatenate([between, [y.size - 1 - idx[-1]]])
    keep = short & (before >= CLEAR) & (after >= CLEAR)
    out = [idx[a:b + 1] for a, b, k in zip(first, last, keep) if k]
    return np.concatenate(out).astype(np.int64) if out else np.empty(0, dtype=np.int64)


def bridge_glitches(y: FloatArray, where: IntArray) -> FloatArray:
    """``y`` with the samples ``where`` replaced by linear interpolation between the others."""
    bad = np.zeros(np.shape(y)[0], dtype=bool)
    bad[where] = True
    return interpolate_over(y, bad)
