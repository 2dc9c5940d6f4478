"""Where a record shows a stage that is not monotone: the output goes on falling while the input
rises from the bottom of its range (or rising while it falls from the top) over a long stretch.

Every model kind here has rising branches, and every compensator and feedback loop assumes that
more command gives more displacement. A piezo stack driven too far negative (a bipolar drive
beyond its coercive field, where electrostriction and depolarisation give the "butterfly" loop)
is not monotone near that end: from the bottom reversal the displacement keeps falling for a
large part of the rise. There no inverse exists and integral feedback pushes the command further
the wrong way. This module finds such ends in a record so that identification can say so and
``commission`` can refuse the range, naming the part of it where the stage is monotone.

A short fall just after a reversal (the sensor's delay, the stage's own dynamics, a loop that
falls a little after each reversal, creep) is not counted: the fall must last for at least
:data:`MIN_TRAVEL` of the input's range and amount to :data:`MIN_FALL` of the output's span (and
well over the noise), after at least two of the reversals at that end, and after most of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .._numba import njit
from .._validation import FloatArray
from ..signals import sensor_resolution

IntArray = NDArray[np.int64]

#: the input's travel (fraction of its range) over which the output must go on the old way
MIN_TRAVEL = 0.15
#: how far (fraction of the output's span) it must go the old way meanwhile
MIN_FALL = 0.03
#: a reversal belongs to an end when it lies within this fraction of the range from it
END_SHARE = 0.2
#: reversals: running extremes the input then leaves by more than this fraction of its range
TURN_BAND = 0.05
#: the output is read through a running median of this many samples (glitches of up to two)
GLITCH_WIDTH = 5


class NotMonotoneWarning(UserWarning):
    """The stage is not monotone at an end of the range given (``commission`` narrowed it)."""


class DeadRangeWarning(UserWarning):
    """The stage does not move over a part of the range at one end (``commission`` narrowed it)."""


#: The input's range is read in this many bins for the slope of the output on it (:func:`dead_range`).
DEAD_BINS = 50
#: ... each read together with this many neighbours on each side (over the steps both ways).
DEAD_NEIGHBOURS = 1
#: A bin is dead when the output's slope on the input there is, with three standard errors to
#: spare, below this share of the record's mean slope (output span over input range) ...
DEAD_SLOPE = 0.1
#: ... and the dead bins from one end reach this share of the range: less is left alone (a stage
#: whose loop is flat at an end over a few volts loses little of the excitation there).
MIN_DEAD_SHARE = 0.1


@dataclass(frozen=True)
class MonotoneRange:
    """Where the record shows the stage monotone.

    ``low`` / ``high``: the input (V) from which the output follows the input again after the
    reversals at the bottom / top of the range (None where it does at once); ``falls``: how far
    (in the output's unit) it went the old way at most, per end; ``reversals``: how many of the
    reversals at each end showed it, of how many.
    """

    low: float | None
    high: float | None
    falls: tuple[float, float]
    reversals: tuple[tuple[int, int], tuple[int, int]]

    @property
    def monotone(self) -> bool:
        """True when neither end shows a long fall."""
        return self.low is None and self.high is None

    def describe(self, u_lo: float, u_hi: float) -> str:
        """One sentence: where the stage is not monotone and the range where it is."""
        parts = []
        if self.low is not None:
            parts.append(f"rising from the bottom reversals the output goes on falling (by up to {self.falls[0]:.3g} µm) "
                         f"until the input reaches {self.low:.4g} V ({self.reversals[0][0]} of "
                         f"{self.reversals[0][1]} reversals there)")
        if self.high is not None:
            parts.append(f"falling from the top reversals the output goes on rising (by up to {self.falls[1]:.3g} µm) "
                         f"until the input reaches {self.high:.4g} V ({self.reversals[1][0]} of "
                         f"{self.reversals[1][1]} reversals there)")
        lo = u_lo if self.low is None else self.low
        hi = u_hi if self.high is None else self.high
        return ("; ".join(parts) + ": the stage is not monotone there (a loop driven beyond its range, e.g. the "
                "butterfly loop of a stack driven too far negative), where no inverse or feedback can follow it; "
                f"it is monotone within {lo:.4g}..{hi:.4g} V")


@dataclass(frozen=True)
class DeadRange:
    """Where a record shows the stage not moving at an end of the input's range.

    ``low``: the input up to which, from the bottom of the range, the output does not follow it
    (None where it does within :data:`MIN_DEAD_SHARE` of the bottom); ``high``: the input from
    which to the top it does not (None likewise); ``share``: the part of the range they cover.
    """

    low: float | None
    high: float | None
    share: float = 0.0

    @property
    def found(self) -> bool:
        """True when either end is dead."""
        return self.low is not None or self.high is not None

    def describe(self, u_lo: float, u_hi: float) -> str:
        """One sentence: where the stage does not move."""
        parts = []
        if self.low is not None:
            parts.append(f"{u_lo:.4g}..{self.low:.4g} V")
        if self.high is not None:
            parts.append(f"{self.high:.4g}..{u_hi:.4g} V")
        return (f"the output does not follow the input in {' and '.join(parts)} ({100 * self.share:.0f} % of the "
                f"range: its slope there is below {100 * DEAD_SLOPE:g} % of the mean; a dead zone, a stage against "
                "its stop, a unipolar stack on a bipolar amplifier)")


def dead_range(u: FloatArray, y: FloatArray) -> DeadRange:
    """Where ``y`` does not follow ``u`` at an end of the input's range (:class:`DeadRange`).

    The range is cut into :data:`DEAD_BINS` bins; in each, the output's slope on the input is the
    least-squares ratio of the sample-to-sample changes, ``sum dy du / sum du^2`` over the steps
    that begin and end in the bin, with its standard error. It is read two ways:

    * over the steps both ways, each bin with its :data:`DEAD_NEIGHBOURS` neighbours each side: a
      drift of the output with time (creep relaxing after the input entered a dead zone, ringing,
      noise) moves ``y`` the same way whether ``u`` rises or falls and so adds nothing to the
      sum, where a level of ``y`` over the bin would say nothing of the input's effect;
    * over the steps of the branch that reaches the end alone (falling at the bottom, rising at
      the top), each bin alone: a stop shows there although the other branch, leaving it late,
      still moves; creep, still going the way the input went, only makes the part look alive.

    A bin is dead when its slope is below :data:`DEAD_SLOPE` of the record's mean slope with three
    standard errors to spare, alive when above it so; an end is dead up to its last dead bin before
    the first alive one (the bins at the very end, where the input turns and moves slowly, often
    cannot tell), as far as either reading says, if that is :data:`MIN_DEAD_SHARE` of the range. The output is read through a running
    median of :data:`GLITCH_WIDTH` samples (a glitch is not a slope).
    Records longer than 200,000 samples are read every k-th sample.
    """
    u = np.asarray(u, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    step = max(1, u.size // 200_000)
    u, y = u[::step], y[::step]
    none = DeadRange(None, None)
    if u.size < 3 * GLITCH_WIDTH or not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
        return none
    from scipy.ndimage import median_filter

    y = median_filter(y, size=GLITCH_WIDTH, mode="nearest")
    lo, hi = float(np.min(u)), float(np.max(u))
    span = float(np.ptp(y))
    if not (hi > lo and span > 0):
        return none
    width = (hi - lo) / DEAD_BINS
    du, dy = np.diff(u), np.diff(y)
    b0 = np.minimum((u[:-1] - lo) // width, DEAD_BINS - 1).astype(np.int64)
    b1 = np.minimum((u[1:] - lo) // width, DEAD_BINS - 1).astype(np.int64)
    same = b0 == b1
    limit = DEAD_SLOPE * span / (hi - lo)
    # the steps both ways (a drift with time cancels), and the steps of the branch that reaches
    # each end alone, falling at the bottom and rising at the top: it tells whether going further
    # does anything (on a Preisach-type stage a reversal anywhere in such a part gives the same
    # branch back; against a stop the rising branch is flat where the falling one, leaving the
    # stop late, is not); an end is dead as far as either says
    both = same & (du != 0.0)
    dead_both = _dead_bins(b0[both], du[both], dy[both], limit, DEAD_NEIGHBOURS)
    # one way, each bin alone: a bin read as alive only stops the dead part short, and the edge of
    # a stop is found to the bin (read with its neighbours, a bin beyond it: on P-I elements against
    # a stop at 80 % of the stroke, commissioned up to 80, 82 and 84 V, the feedforward missed by
    # 0.7, 2.6 and 4.6 % e_max at 1 Hz)
    dead_down, dead_up = (_dead_bins(b0[keep], du[keep], dy[keep], limit, 0)
                          for keep in (same & (du < 0.0), same & (du > 0.0)))

    n_lo = max(_dead_from_start(*dead_both), _dead_from_start(*dead_down))
    n_hi = max(_dead_from_start(*(m[::-1] for m in dead_both)), _dead_from_start(*(m[::-1] for m in dead_up)))
    need = int(math.ceil(MIN_DEAD_SHARE * DEAD_BINS - 1e-9))
    if n_lo + n_hi >= DEAD_BINS:
        return none  # the output follows the input nowhere: nothing to narrow to
    low = lo + n_lo * width if n_lo >= need else None
    high = hi - n_hi * width if n_hi >= need else None
    share = ((n_lo if low is not None else 0) + (n_hi if high is not None else 0)) / DEAD_BINS
    return DeadRange(low, high, share)


def _dead_bins(bins: NDArray[np.int64], du: FloatArray, dy: FloatArray, limit: float,
               neighbours: int) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Per bin of :func:`dead_range`, from the slope ``sum dy du / sum du^2`` over the steps in it
    and its ``neighbours`` each side: whether it is below ``limit`` with three standard errors to
    spare (dead), and whether it is above it so (alive). A bin with too few steps to tell is
    neither (at the ends of the range the input turns, and moves slowly)."""
    sums = [np.bincount(bins, w, DEAD_BINS).astype(np.float64) for w in (du * du, du * dy, dy * dy, np.ones(du.size))]
    # each bin read with its neighbours: ringing after the input enters a dead part moves the
    # output one way over one bin's passage and back over the next (measured: slopes of -0.36 to
    # +0.17 of the mean, alternating bin by bin, on a dead part behind a 550 Hz resonance)
    window = np.ones(2 * neighbours + 1)
    suu, suy, syy, count = (np.convolve(x, window, mode="same") for x in sums)
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = suy / suu
        resid = np.maximum(syy - slope * suy, 0.0) / np.maximum(count - 1, 1)  # the steps' scatter about it
        stderr = np.sqrt(resid / suu)
    enough = count >= 3
    return (np.asarray(enough & (slope + 3.0 * stderr < limit)),
            np.asarray(enough & (slope - 3.0 * stderr > limit)))


def _dead_from_start(dead: NDArray[np.bool_], alive: NDArray[np.bool_]) -> int:
    """How many bins from the start are dead: up to the last dead one before the first alive one
    (bins that cannot tell, between dead ones or before them, count with them)."""
    first_alive = int(np.argmax(alive)) if alive.any() else dead.size
    dead_before = np.flatnonzero(dead[:first_alive])
    return int(dead_before[-1]) + 1 if dead_before.size else 0


#: A clipped output (:func:`clipped_output`): at least this share of the samples (and
#: :data:`CLIPPED_MIN_SAMPLES`) sit exactly at the output's largest or smallest value while the
#: input moves over at least :data:`CLIPPED_INPUT_SHARE` of its span.
CLIPPED_SHARE = 0.01
CLIPPED_MIN_SAMPLES = 5
CLIPPED_INPUT_SHARE = 0.05


def clipped_output(u: FloatArray, y: FloatArray) -> list[tuple[str, float, int, float, float]]:
    """The ends at which the output is clipped: ``(end, value, samples, u_from, u_to)`` for each
    end (``"top"``, ``"bottom"``) where at least :data:`CLIPPED_SHARE` of the samples hold exactly
    the output's extreme value while the input moves over at least :data:`CLIPPED_INPUT_SHARE` of
    its span (a sensor or converter at the end of its range: the stage moved, the reading did not).
    A stage's own loop reaches its extreme at one turn, and noise makes it a single sample.

    >>> u = np.linspace(0.0, 10.0, 101)
    >>> clipped_output(u, np.minimum(u, 8.0))
    [('top', 8.0, 21, 8.0, 10.0)]
    """
    uu, yy = np.asarray(u, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if uu.size < 10 or not np.ptp(uu) > 0:
        return []
    out = []
    for end, value in (("top", float(yy.max())), ("bottom", float(yy.min()))):
        at = yy == value
        k = int(at.sum())
        if k >= max(CLIPPED_MIN_SAMPLES, CLIPPED_SHARE * yy.size):
            lo_u, hi_u = float(uu[at].min()), float(uu[at].max())
            if hi_u - lo_u >= CLIPPED_INPUT_SHARE * float(np.ptp(uu)):
                out.append((end, value, k, lo_u, hi_u))
    return out


#: A sensor whose step (:func:`~piezohyst.signals.sensor_resolution`) is at least this share of
#: the output's span (200 counts or fewer over it) is said to be coarse (:func:`range_warnings`).
COARSE_RESOLUTION_SHARE = 0.005


def range_warnings(u: FloatArray, y: FloatArray) -> list[str]:
    """What a record shows of its range that a model fitted over all of it cannot use: a sensor
    that reads in coarse steps (:data:`COARSE_RESOLUTION_SHARE`; then the clipping check, which
    such a sensor's held readings would fool, is not made), an output held at an end
    (:func:`clipped_output`), an end where the stage is not monotone (:func:`monotone_range`) and
    one where it does not move (:func:`dead_range`), one sentence each (``u`` and ``y`` paired, a
    delay taken out)."""
    out = []
    step = sensor_resolution(y)
    span = float(np.ptp(y))
    coarse = step is not None and span > 0 and step >= COARSE_RESOLUTION_SHARE * span
    if coarse:
        assert step is not None
        out.append(f"the output reads in steps of {step:.4g} ({int(round(span / step)) + 1} distinct values over its "
                   f"span of {span:.4g}: {100.0 * step / span:.2g} % of it): a sensor or converter coarser than the "
                   f"motion to be modelled. No model fits it better than about {step / math.sqrt(12.0):.3g} RMS, a "
                   f"tracking run shows its error no finer than {step / 2.0:.3g}, and the reading stands still at "
                   f"reversals and at the ends while the stage moves within a step (so neither a clipped sensor nor "
                   f"a loop flat after reversals can be told from it); measure with a finer resolution")
    for end, value, k, lo_u, hi_u in ([] if coarse else clipped_output(u, y)):
        out.append(f"the output stays at {value:.6g} ({'its largest' if end == 'top' else 'its smallest'} value) for "
                   f"{k} samples ({100.0 * k / len(y):.1f} %) while the input moves over {lo_u:.4g}..{hi_u:.4g} V: "
                   f"a sensor or converter clipped at the end of its range? Those samples say nothing of the "
                   f"stage; fit without them (a narrower input range, or --train / a slice of the record)")
    lo, hi = float(np.min(u)), float(np.max(u))
    mono = monotone_range(u, y)
    if not mono.monotone:
        out.append(f"{mono.describe(lo, hi)}: a model fitted over the whole range is fitted to what no compensator "
                   "can use; identify within that range")
    dead = dead_range(u, y)
    if dead.found:
        out.append(f"{dead.describe(lo, hi)}: what the record spends there identifies nothing, and its loops inside "
                   "the range may miss those the stage makes where it moves; identify within the range where it "
                   "moves (commission() narrows to it)")
    return out


#: Below this correlation of output with input (in magnitude) the output is said not to follow
#: the input at all (a wrong column, a sensor that does not see the stage, swings inside a dead
#: zone), rather than to fall as it rises (the messages of ``fit_pi``, ``fit_model``, ``commission``).
WEAK_CORRELATION = 0.3


def rises_with_input(u: FloatArray, y: FloatArray) -> bool:
    """False when the output falls as the input rises (negative correlation, e.g. a sensor mounted
    the other way round): every model kind here has a rising loop."""
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.corrcoef(u, y)[0, 1]
    return not r < 0


def butterfly_hint(rising: tuple[float, float] | None, what: str, unit: str, keep: str) -> str:
    """The sentence an error about a falling record adds where :func:`rising_part` found a part of
    the range that rises (``""`` where it found none): ``what`` rises over that part (``unit``
    after its end), and ``keep`` says how to keep to it."""
    if rising is None:
        return ""
    return (f". It does rise with the {what} over {rising[0]:.4g}..{rising[1]:.4g}{unit}: if its loop is a "
            f"butterfly (a stack driven past its coercive voltage, which depoles it), {keep}")


#: :func:`rising_part` names a part of the range only where the output follows the input over it
#: this well (correlation).
RISING_CORRELATION = 0.5


def rising_part(u: FloatArray, y: FloatArray, parts: int = 10) -> tuple[float, float] | None:
    """The widest run of adjacent tenths of the command's range, at its top or its bottom, over
    each of which the output rises with the command (least-squares slope over the samples there),
    where the run as a whole falls, and where over it the output follows the input (correlation at
    least :data:`RISING_CORRELATION`: a stage swung inside its dead band rises and falls by noise);
    None where no such run exists or every tenth rises. A butterfly loop (a bipolar stack driven
    past its coercive voltage) falls as the input rises below it and rises above.
    """
    lo, hi = float(np.min(u)), float(np.max(u))
    if not hi > lo:
        return None
    edges = np.linspace(lo, hi, parts + 1)
    which = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, parts - 1)
    rises = []
    for j in range(parts):
        uu, yy = u[which == j], y[which == j]
        du = uu - uu.mean() if uu.size > 2 else np.zeros(0)
        rises.append(bool(du.size and float(np.dot(du, yy - yy.mean())) > 0.0))
    if all(rises):
        return None
    top = next((j for j in range(parts - 1, -1, -1) if not rises[j]), -1) + 1  # rises from tenth `top` up
    bottom = next((j for j in range(parts) if not rises[j]), parts)  # rises below tenth `bottom`
    if top >= parts and bottom <= 0:
        return None
    part = (float(edges[top]), hi) if parts - top >= bottom else (lo, float(edges[bottom]))
    inside = (u >= part[0]) & (u <= part[1])
    if inside.sum() < 3 or not float(np.ptp(y[inside])) > 0.0:
        return None
    r = float(np.corrcoef(u[inside], y[inside])[0, 1])
    return part if r >= RISING_CORRELATION else None


def turn_indices(u: FloatArray, band: float) -> IntArray:
    """Indices of the input's reversals: running extremes the input then leaves by more than
    ``band`` (noise and dither smaller than that do not count)."""
    return _turn_indices(np.ascontiguousarray(u, dtype=np.float64), float(band))


@njit
def _turn_indices(u: FloatArray, band: float) -> IntArray:  # pragma: no cover - compiled
    out = np.empty(u.shape[0], dtype=np.int64)
    m = 0
    if not band > 0.0 or u.shape[0] < 3:
        return out[:0]
    ext_i, direction = 0, 0  # the running extreme, and the direction of motion since the last turn
    for i in range(1, u.shape[0]):
        x = u[i]
        if direction == 0:  # not yet left the start by the band
            if abs(x - u[ext_i]) > band:
                direction = 1 if x > u[ext_i] else -1
                ext_i = i
        elif (x - u[ext_i]) * direction > 0:
            ext_i = i
        elif abs(x - u[ext_i]) > band:
            out[m] = ext_i
            m += 1
            direction = -direction
            ext_i = i
    return out[:m]


def monotone_range(u: FloatArray, y: FloatArray) -> MonotoneRange:
    """Where ``y`` follows ``u`` the way every model here assumes (module docstring).

    ``u`` and ``y`` are paired samples (a delay of a few samples does not matter: the fall must
    last over :data:`MIN_TRAVEL` of the input's range). Records longer than 200,000 samples are
    read every k-th sample.
    """
    u = np.asarray(u, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    step = max(1, u.size // 200_000)
    u, y = u[::step], y[::step]
    if y.size >= GLITCH_WIDTH:  # a sensor's glitch (a sample or two) is not a fall
        from scipy.ndimage import median_filter

        y = median_filter(y, size=GLITCH_WIDTH, mode="nearest")
    lo, hi = float(np.min(u)), float(np.max(u))
    rng = hi - lo
    span = float(np.ptp(y))
    none = MonotoneRange(None, None, (0.0, 0.0), ((0, 0), (0, 0)))
    if not (rng > 0 and span > 0):
        return none
    noise = float(np.median(np.abs(np.diff(y, 2)))) if y.size > 3 else 0.0
    need = max(MIN_FALL * span, 8.0 * noise)
    turns = turn_indices(u, TURN_BAND * rng).tolist()
    ends: list[tuple[float | None, float, tuple[int, int]]] = []
    for sign in (1.0, -1.0):  # +1: reversals at the bottom (the input then rises), -1: at the top
        at_end = [(k, turns[j + 1] if j + 1 < len(turns) else u.size - 1) for j, k in enumerate(turns)
                  if (u[k] - lo if sign > 0 else hi - u[k]) <= END_SHARE * rng]
        hits: list[tuple[float, float]] = []
        for k, k_next in at_end:
            seg_y = sign * y[k:k_next + 1]
            j = int(np.argmin(seg_y))
            fall = float(seg_y[0] - seg_y[j])
            travel = sign * float(u[k + j] - u[k])
            if fall >= need and travel >= MIN_TRAVEL * rng:
                hits.append((float(u[k + j]), fall))
        counted = (len(hits), len(at_end))
        if len(hits) >= 2 and 2 * len(hits) > len(at_end):
            limit = max(h[0] for h in hits) if sign > 0 else min(h[0] for h in hits)
            ends.append((limit, max(h[1] for h in hits), counted))
        else:
            ends.append((None, 0.0, counted))
    return MonotoneRange(ends[0][0], ends[1][0], (ends[0][1], ends[1][1]), (ends[0][2], ends[1][2]))


__all__ = ["DeadRange", "DeadRangeWarning", "clipped_output", "dead_range", "range_warnings", "MonotoneRange", "NotMonotoneWarning", "monotone_range", "rises_with_input", "turn_indices", "MIN_TRAVEL", "MIN_FALL"]
