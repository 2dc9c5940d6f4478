"""Model selection on held-out data: :func:`fit_model` (beyond the paper).

Every candidate - a kind (P-I, asymmetric P-I, Preisach, Bouc-Wen hysteresis, generalised Duhem,
rate-dependent wrappers, Bouc-Wen) and a
structure (operators or grid levels, output-map knots, output lags, input lag, sensor delay) - is
fitted on the earlier part of the training record and scored on what it never saw: the later
part of the record (simulated from the record's start, so every model carries its memory into
it), or the validation sets the user gives. The winner is refitted on the whole training record.

The search is staged, each stage keeping the best so far (a more complex candidate must lower
the hold-out error by :data:`MIN_GAIN` to replace a simpler one):

1. P-I thresholds (over half the input's span, or by the paper's eq. 4), then the sensor delay
   (coarse, then fine) jointly with the input lag (amplifier and stack), with a plain P-I model;
2. (after the lags) the delay and the input lag again around the best, since lags take part of
   what looked like delay;
3. output lags: none, the rate-dependence band, rate and creep (then stage 2);
4. the static kind and its size: P-I operators, asymmetric P-I output-map knots, the Bouc-Wen
   hysteresis's shape, the generalised Duhem model's relaxation rate and knots (a candidate whose
   branches could rise by less than the margin over the states its range reaches is refused; where
   stage 3 chose no lags, the Duhem model is also tried with each lag set and the delay searched
   again, kept where it wins by ``MIN_GAIN`` per lag), Preisach levels;
   when another kind or size won, the delay over its whole range again with it, with and without
   the lags (a plain P-I model that cannot follow the loop can pick a long delay for its misfit);
5. Bouc-Wen (PSO) when the kind allows it and a sample period is known;
6. the winner, refitted on the whole record, must have a compensator that stays smooth: on
   sinusoids at both ends of the excitation band its command turns only where the reference
   turns (:func:`_chatters`); one that chatters (an inverse slope at the margin, amplified by an
   input lag's lead) is passed over for the next best, and ``info["refused_for_chatter"]`` names it;
   when the first runners-up all chatter, the best rate-independent candidate (no lags: its
   inverse is monotone between the reference's turns) is taken, checked the same way.
7. (``history="auto"``, before the refit) the stage's initial state: every kind starts from its
   de-energised state, but a stage at rest keeps the branch it last came down or up on. The
   chosen structure is fitted again after a history from the record's first value (rest) down
   to the least input and back, and after one up to the greatest and back, each followed by
   local moves (a wrong start bends the delay and the size the search chose), and scored on the
   same hold-out; one that lowers the error by :data:`MIN_GAIN` is kept, and the model is
   returned as an :class:`~piezohyst.models.AfterHistory` (its compensator replays the history).
   On random stages resting above the bottom of their range after coming up from it, the
   feedforward alone went from 0.82 / 0.70 / 0.72 to 0.50 / 0.37 / 0.46 % e_max at 1 / 3 / 5 Hz
   and from 4.10 / 2.94 / 2.77 to 2.02 / 1.48 / 1.57 %; on the zoo and the census, whose stages
   start demagnetised, no history is kept and nothing changed.

Every range follows from the data, nothing from any particular stage (:func:`search_ranges`):
the excitation's frequency band ``f_lo .. f_hi`` (between 1 % and 98 % of the input's power) and
the record's length and sample rate. Delays up to 5 % of the fastest period (at least 5
samples); input lags from two samples to ``1 / (2 pi f_hi)`` (a lag whose corner is the fastest
frequency the record shows: 45 degrees there, which the record identifies; below ``0.2 / (2 pi
f_hi)``, as before, stages behind 8 and 15 ms amplifier lags missed by 1.0-1.4 and 1.9-2.5 % with
the feedforward alone, 0.42-0.56 and 0.47-0.74 % now), searched jointly with the delay
(the two trade against each other); output lags two per decade from ``0.016 / f_hi`` (or two
samples), and half the fitting part of the record as the last one where the decades stop more
than a quarter decade short of it (creep; a lag longer than the record can tell from a constant
overfits: it drifts on new data, and the hold-out shows it), tried as two sets:
rate dependence (``tau <= 1 / (2 pi f_lo)``) and rate dependence with creep (all).

**A record of one rate** (:func:`single_rate`: 75 % of the input's power within half an octave
of its strongest frequency, such as cycles of one sinusoid, also of decaying amplitude) cannot
tell a sensor delay from the loop's own phase lag, nor rate dependence from a misfit of the
loop's shape: a later part of the same record rewards both, and the model then fails at other
rates. Fitted on a 1 Hz sinusoid and predicting a 5 Hz one, the model chosen on the seven
zoo stages was worse than a plain P-I model without delay on four of them (1.34 / 0.84 / 16.1 /
2.73 % of span against 0.97 / 0.33 / 1.79 / 0.52 %: a P-I delay of 191 samples, lags that made
up the loop's shape at 1 Hz and amplified it at 5 Hz). On such a record the search keeps a delay
only where it halves the hold-out error of the same structure without it
(:data:`ONE_RATE_DELAY_GAIN`: a delay the data show beyond doubt, such as that of a model exact
with it), tries no input lag and no lag within a decade of the excitation (``tau < 10 / (2 pi
f_peak)``: such a lag's weight is fitted to one rate and acts differently at any other; slower
ones act as creep at every rate in use; a rate-dependent model asked for by name keeps the lags
slower than the excitation, ``1 / (2 pi f_peak)``), and the result warns that it was fitted on one
rate.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence

import numpy as np

from .._blas import with_single_threaded_blas
from .._validation import FloatArray, as_count, as_scalar
from ..models.base import kind_class
from ..models.duhem import MAX_RANGE_SPANS, reaches_beyond_knots
from ..models.history import AfterHistory
from ..models.play import largest_loop_threshold, play_operator
from ..models.rate import first_order_lag
from .glitches import SPAN_SHARE as GLITCH_SPAN_SHARE
from .glitches import bridge_glitches, find_glitches
from .monotone import (WEAK_CORRELATION, butterfly_hint, range_warnings, rises_with_input, rising_part,
                       turn_indices)
from .linear import (DEFAULT_MARGIN, FewOutputLevelsError, Prepared, Structure, fit_prepared, fit_structure, mean_slope,
                     prepare)
from .result import FitResult, check_output_scale, paired_signals, unpack_data

#: Relative drop of the hold-out error a more complex candidate must bring to be preferred.
MIN_GAIN = 0.02
#: Fraction of the training record held out when no validation data are given.
HOLDOUT = 0.3
#: The initial-state histories (:func:`_histories`): each leg lasts this long (s) with a sample
#: period, else this many samples (a rate-independent model's state depends on the turning
#: points only); a side of rest closer than this share of the input's span is not tried.
HISTORY_LEG_S = 0.25
HISTORY_LEG_SAMPLES = 200
HISTORY_MIN_SHARE = 0.05
#: Run the two P-I threshold rules' searches on two threads (:func:`_searches`), unless numba's
#: parallel regions were set to one thread; False runs them one after the other, with the same
#: result.
PARALLEL_SEARCHES = True
#: Designs (one per structure) the search keeps at once (:meth:`_Scorer._prepared`).
PREPARED_KEPT = 4
#: Static parts' columns the search keeps at once (:class:`_Blocks`).
STATIC_KEPT = 4
#: Rows the search fits each candidate on (every k-th of a longer record; the winner is refitted
#: on every row).
SEARCH_ROWS = 30000

_LINEAR_KINDS = ("prandtl-ishlinskii", "rate-dependent", "asymmetric-pi", "preisach", "bouc-wen-hysteresis",
                 "generalized-duhem")


@dataclass(frozen=True)
class SearchRanges:
    """The data-derived ranges of the search (module docstring)."""

    f_lo: float | None
    f_hi: float | None
    max_delay: int
    input_taus: tuple[float, ...]
    rate_taus: tuple[float, ...]
    creep_taus: tuple[float, ...]
    #: the strongest frequency of a record of one rate (module docstring), else None
    single_rate_hz: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"f_lo_hz": self.f_lo, "f_hi_hz": self.f_hi, "max_delay": self.max_delay,
                "input_taus_s": list(self.input_taus), "rate_taus_s": list(self.rate_taus),
                "creep_taus_s": list(self.creep_taus), "single_rate_hz": self.single_rate_hz}


#: Share of a record's input power within half an octave of its strongest frequency above which the
#: record is of one rate (module docstring).
SINGLE_RATE_SHARE = 0.75
#: On a record of one rate, a delay is kept only when it brings the hold-out error below this
#: fraction of the same structure's without it (module docstring).
ONE_RATE_DELAY_GAIN = 0.5
#: On a record of one rate, the automatic choice tries no lag shorter than this over ``2 pi f_peak``
#: (a decade slower than the excitation); a rate-dependent model asked for by name, none shorter
#: than ``1 / (2 pi f_peak)`` (slower than the excitation: what the issue's 20 Hz record identified).
ONE_RATE_LAGS = 10.0


def _input_power(u: FloatArray, dt: float) -> tuple[FloatArray, FloatArray, float]:
    """Frequencies (Hz), power spectrum of the mean-removed input (0 at DC) and its total."""
    x = np.asarray(u, dtype=np.float64) - float(np.mean(u))
    spec: FloatArray = np.abs(np.fft.rfft(x)) ** 2
    spec[0] = 0.0
    freqs = np.asarray(np.fft.rfftfreq(x.size, dt), dtype=np.float64)
    return freqs, spec, float(spec.sum())


def single_rate(u: FloatArray, dt: float) -> float | None:
    """The strongest frequency (Hz) of ``u`` when :data:`SINGLE_RATE_SHARE` of its mean-removed
    power lies within half an octave of it (``f / sqrt 2`` to ``f sqrt 2``), else None: a record
    of one rate (a sinusoid, also of varying amplitude; one of 1 Hz then 2 Hz has two)."""
    freqs, spec, total = _input_power(u, dt)
    if total <= 0:
        return None
    f_peak = float(freqs[int(np.argmax(spec))])
    near = (freqs >= f_peak / math.sqrt(2.0)) & (freqs <= f_peak * math.sqrt(2.0))
    return f_peak if float(spec[near].sum()) >= SINGLE_RATE_SHARE * total else None


def excitation_band(u: FloatArray, dt: float) -> tuple[float, float]:
    """``(f_lo, f_hi)``: where 1 % and 98 % of the input's (mean-removed) power has accumulated."""
    freqs, spec, total = _input_power(u, dt)
    if total <= 0:
        raise ValueError("u is constant: a constant input cannot identify a hysteresis model")
    cum = np.cumsum(spec) / total
    f_lo = float(freqs[int(np.searchsorted(cum, 0.01))])
    f_hi = float(freqs[min(int(np.searchsorted(cum, 0.98)), freqs.size - 1)])
    f_min = 1.0 / (np.size(u) * dt)
    return max(f_lo, f_min), max(f_hi, f_lo, f_min)


def _geometric(lo: float, hi: float, ratio: float) -> tuple[float, ...]:
    if not (lo > 0 and hi >= lo):
        return ()
    k = int(math.floor(math.log(hi / lo) / math.log(ratio) + 1e-9))
    return tuple(float(lo * ratio**i) for i in range(k + 1))


def search_ranges(u: FloatArray, dt: float | None, n_fit: int, *, one_rate_rule: bool = True,
                  one_rate_lags: float = ONE_RATE_LAGS) -> SearchRanges:
    """The search's ranges from the data alone (module docstring); with ``one_rate_rule`` (the
    choice is made on a later part of the same record) those of a record of one rate: no input
    lag, no lag shorter than ``one_rate_lags / (2 pi f_peak)`` (with ``one_rate_lags <= 1``, what a
    rate-dependent model asked for by name uses, at least the slowest lag)."""
    if dt is None:
        return SearchRanges(None, None, max(5, min(n_fit // 50, 50)), (), (), ())
    f_lo, f_hi = excitation_band(u[:n_fit], dt)
    t_fit = n_fit * dt
    max_delay = int(max(5, min(round(0.05 / (f_hi * dt)), n_fit // 20)))
    itau_hi = min(1.0 / (2 * math.pi * f_hi), t_fit / 20)
    input_taus = _geometric(2 * dt, itau_hi, 2.0)
    tau_lo = max(0.016 / f_hi, 2 * dt)
    tau_hi = t_fit / 2
    taus = _geometric(tau_lo, tau_hi, math.sqrt(10.0))
    if taus and tau_hi > taus[-1] * 10 ** 0.25:
        # the grid's last step can fall up to half a decade short of the longest lag the record
        # identifies: a creep of a few seconds, fitted with lags that end below it, drifts
        taus = (*taus, tau_hi)
    # rate dependence: lags within the excitation's band (tau <= 1 / (2 pi f_lo)); creep: longer ones
    rate = tuple(t for t in taus if t <= 1.0 / (2 * math.pi * f_lo)) or taus[:1]
    f_one = single_rate(u[:n_fit], dt) if one_rate_rule else None
    if f_one is not None:  # one rate: no input lag, no lag the one rate cannot tell (module docstring)
        slow = one_rate_lags / (2 * math.pi * f_one)
        kept = tuple(t for t in taus if t >= slow)
        if not kept and one_rate_lags <= 1.0:  # a rate-dependent model asked for: at least the slowest lag
            kept = taus[-1:]
        return SearchRanges(f_lo, f_hi, max_delay, (), tuple(t for t in rate if t >= slow) or kept[:1], kept,
                            single_rate_hz=f_one)
    return SearchRanges(f_lo, f_hi, max_delay, input_taus, rate, taus)


@dataclass
class _Candidate:
    structure: Any  # Structure, or ("bouc-wen", delay)
    label: str
    kind: str
    score: float
    fit_rmse: float
    n_parameters: int
    time_s: float
    per_set: list[float] = field(default_factory=list)
    #: the hold-out error before a candidate was ruled out (``score`` is then inf): how close it came
    unmasked: float = math.nan
    #: the history it was fitted after (fit_model's ``history``; "": the de-energised start)
    start: str = ""


class _SearchCancelled(Exception):
    """A search in another thread was told to stop (:func:`_searches`)."""


class _Scorer:
    """Fits a structure on the fitting rows and scores it on the hold-out or validation sets."""

    def __init__(self, u: FloatArray, y: FloatArray, dt: float | None, n_fit: int,
                 validation: list[tuple[FloatArray, FloatArray, int]], margin: float, *,
                 warmup: FloatArray | None = None, stride: int | None = None):
        self.u, self.y, self.dt, self.n_fit = u, y, dt, n_fit
        self.validation = validation
        self.margin = margin
        #: the samples before the record that only set the operators' states (fit_model's warmup)
        self.warmup = np.empty(0) if warmup is None else warmup
        #: the warm-up is a history the stage's state at rest comes from (fit_model's ``history``):
        #: the validation sets, which also start at rest, are simulated after it too
        self.history = False
        self._u_states = np.concatenate([self.warmup, u]) if self.warmup.size else u
        #: the search fits on every stride-th row (at most SEARCH_ROWS rows); the refit uses all
        self.stride = max(1, n_fit // SEARCH_ROWS) if stride is None else int(stride)
        self.tried: list[_Candidate] = []
        #: the prepared structures (design matrices), the most recently used last; at most
        #: PREPARED_KEPT of them, an evicted one's Gram matrices kept in _grams
        self._prep: OrderedDict[Any, Prepared] = OrderedDict()
        self._grams: dict[Any, tuple[dict[int, FloatArray], dict[int, FloatArray]]] = {}
        self._done: dict[Structure, _Candidate] = {}
        self._blocks = _Blocks()
        #: set from another thread to stop a search at its next candidate (:func:`_searches`)
        self.cancelled = False

    def score_model(self, model: Any, delay: int, pred_train: FloatArray | None) -> tuple[float, list[float]]:
        if not self.validation:
            assert pred_train is not None
            e = self.y[self.n_fit:] - pred_train[self.n_fit:]
            r = float(np.sqrt(np.mean(e**2)))
            return r, [r]
        out = []
        for uv, yv, first in self.validation:
            if self.history:  # each set starts after the same history as the record
                p = model.predict(np.concatenate([self.warmup, uv]), self.dt)[self.warmup.size:]
            else:
                p = model.predict(uv, self.dt)
            resid = (yv[delay:] - p[: p.size - delay] if delay else yv - p)[max(first - delay, 0):]
            out.append(float(np.sqrt(np.mean(resid**2))))
        return float(np.mean(out)), out

    def sibling(self) -> _Scorer:
        """A scorer of the same data and settings with caches of its own (for a search in
        another thread)."""
        twin = _Scorer(self.u, self.y, self.dt, self.n_fit, self.validation, self.margin,
                       warmup=self.warmup, stride=self.stride)
        twin.history = self.history
        return twin

    def adopt(self, other: _Scorer) -> None:
        """The candidates ``other`` tried that this one has not, appended in ``other``'s order."""
        for c in other.tried:
            if c.structure not in self._done:
                self._done[c.structure] = c
                self.tried.append(c)

    def _prepared(self, key: Structure) -> Prepared:
        """The design of ``key`` (a structure without its delay: every delay fits the same rows).

        Only the last :data:`PREPARED_KEPT` designs used are kept (their own columns and the
        static block they hold on to, :class:`_Blocks`): a search tries dozens of structures,
        mostly one after the other (a delay search, then the next input lag), and keeping every
        one held 1.3 GB on a 10^5-sample record. An evicted design's Gram matrices are kept: built
        again, it computes exactly what it would have (its columns are recomputed bit for bit, and
        its Gram cache is as it was).
        """
        pre = self._prep.get(key)
        if pre is not None:
            self._prep.move_to_end(key)
            return pre
        pre = prepare(self._u_states, self.dt, key, u_ref=self.u[: self.n_fit], cache=self._blocks, stride=self.stride,
                      first=self.warmup.size)
        pre._gram, pre._extra = self._grams.pop(key, (pre._gram, pre._extra))
        self._prep[key] = pre
        if len(self._prep) > PREPARED_KEPT:
            old_key, old = self._prep.popitem(last=False)
            self._grams[old_key] = (old._gram, old._extra)
        return pre

    def linear(self, st: Structure) -> _Candidate:
        if self.cancelled:
            raise _SearchCancelled
        done = self._done.get(st)
        if done is not None:
            return done
        pre = self._prepared(replace(st, delay=0))
        t0 = time.perf_counter()
        d, n = st.delay, self.u.size
        try:
            c = self._fitted(st, pre, d, n, t0)
        except FewOutputLevelsError:
            # an output on a few levels has no map to fit: that structure is out (asked for by
            # name, the refit of the best says why)
            c = _Candidate(st, st.label(), st.kind, math.inf, math.nan, 0, time.perf_counter() - t0,
                           [math.inf] * max(len(self.validation), 1))
        self.tried.append(c)
        self._done[st] = c
        return c

    def _fitted(self, st: Structure, pre: Prepared, d: int, n: int, t0: float) -> _Candidate:
        """:meth:`linear`'s fit of ``st`` (``pre``: its design without the delay ``d``)."""
        if self.validation:
            model, info, _ = fit_prepared(pre, self.y[d:self.n_fit], self.n_fit - d, self.dt, margin=self.margin,
                                          predict=(0, 1))
            score, per = self.score_model(model, d, None)
            fit_rmse = float("nan")
        else:
            # prediction of sample k is row k - d: rows [n_fit - d, n - d) score the held-out samples
            model, info, pred = fit_prepared(pre, self.y[d:self.n_fit], self.n_fit - d, self.dt, margin=self.margin,
                                             predict=(self.n_fit - d, n - d))
            first = pre.n_rows(self.n_fit - d) * pre.stride  # the stored rows' record indices
            e = self.y[first + d::pre.stride][: pred.size] - pred
            score = float(np.sqrt(np.mean(e**2)))
            per = [score]
            fit_rmse = float("nan")
        unmasked = score
        if st.static == "duhem" and not _duhem_invertible(model, self.margin):
            score, per = math.inf, [math.inf] * len(per)  # its inverse's gain could exceed 1 / margin
        c = _Candidate(st, st.label(), st.kind, score, fit_rmse, int(info["n_parameters"]),
                       time.perf_counter() - t0, per, unmasked)
        return c


def _duhem_invertible(model: Any, margin: float) -> bool:
    """A generalised Duhem candidate (the least squares bound only ``G``): every branch over the
    states its range reaches rises by at least ``margin`` (the other kinds hold it by construction)."""
    static = getattr(model, "static", model)
    return bool(model.is_invertible and static.min_slope >= margin)


class _Blocks(OrderedDict):  # type: ignore[type-arg]
    """The regressor blocks structures share (:func:`~piezohyst.identify.linear.prepare`'s
    ``cache``), keeping only the last :data:`STATIC_KEPT` static parts used: each is the
    search's rows by the static part's columns (8 MB for 20 P-I operators, 70 MB for a 16-level
    Preisach grid), a search makes dozens, and one dropped is computed again bit for bit."""

    def __getitem__(self, key: Any) -> Any:
        value = super().__getitem__(key)
        self.move_to_end(key)
        return value

    def __setitem__(self, key: Any, value: Any) -> None:
        super().__setitem__(key, value)
        self.move_to_end(key)
        statics = [k for k in self if k[0] == "static"]
        for k in statics[:max(len(statics) - STATIC_KEPT, 0)]:
            del self[k]


def _best(cands: Sequence[_Candidate]) -> _Candidate:
    return min(cands, key=lambda c: c.score)


def _prefer(incumbent: _Candidate, challenger: _Candidate) -> _Candidate:
    """The challenger (more complex) wins only by a margin (module docstring)."""
    return challenger if challenger.score < (1.0 - MIN_GAIN) * incumbent.score else incumbent


def _delay_search(sc: _Scorer, base: Structure, lo: int, hi: int) -> _Candidate:
    """The delay in ``lo..hi`` with the lowest hold-out error: a coarse, roughly geometric grid
    (short delays are the common ones), then halving the gap around the best point."""
    grid = sorted({lo, hi, *[d for d in (1, 2, 3, 4, 6, 8, 11, 16, 22, 32, 45, 64, 90, 128, 181, 256)
                             if lo < d < hi]})
    cands = {d: sc.linear(replace(base, delay=d)) for d in grid}
    while True:
        order = sorted(cands)
        d0 = min(cands, key=lambda d: cands[d].score)
        i = order.index(d0)
        gaps = [(order[i - 1], d0)] if i > 0 else []
        gaps += [(d0, order[i + 1])] if i + 1 < len(order) else []
        new = [(a + b) // 2 for a, b in gaps if b - a > 1]
        if not new:
            return cands[d0]
        for d in new:
            cands[d] = sc.linear(replace(base, delay=d))


@with_single_threaded_blas  # hundreds of small products: more threads only contend (piezohyst._blas)
def fit_model(
    u: Any, y: Any = None, dt: float | None = None, kind: str = "auto", *,
    validation: Sequence[Any] | None = None, holdout: float | int = HOLDOUT, delay: int | str = "auto",
    n: int | None = None, kinds: Sequence[str] | None = None, margin: float | None = None,
    taus: Sequence[float] | None = None, input_taus: Sequence[float] | None = None,
    max_delay: int | None = None, statics: Sequence[str] = ("pi", "preisach", "bouc-wen", "duhem"),
    seed: Any = 0, bouc_wen_options: dict[str, Any] | None = None,
    progress: Callable[[str], None] | bool | None = None, warmup: int = 0, glitches: str = "bridge",
    history: str | None = None,
) -> FitResult:
    """Identify the model that predicts held-out data best (module docstring).

    Parameters
    ----------
    u, y : array_like or Dataset
        Input (V) and output (µm) of the training record, starting at rest; or one
        :class:`~piezohyst.data.Dataset` as ``u`` (its ``dt`` is used).
    dt : float, optional
        Sample period, s. Without it no rate-dependent kind is tried.
    kind : str
        ``"auto"`` (every kind), or one kind name or alias: ``"pi"``, ``"rate-dependent"``,
        ``"asymmetric-pi"``, ``"preisach"``, ``"bouc-wen"``; the structure is still chosen on
        held-out data.
    validation : sequence, optional
        Held-out sets to choose on instead of the later part of the training record: each a
        Dataset, a ``(u, y)`` pair, or ``(u, y, first)`` with ``first`` the first sample scored
        (the set is simulated from its start). The score is the mean of their RMSEs.
    holdout : float or int
        What of the training record is held out when ``validation`` is not given: a fraction of
        it (its end), or, as an integer, the number of samples at its end (an experiment made
        of an identification part and a validation part, as ``commission`` runs).
    delay : int or "auto"
        Samples by which y lags u, or searched.
    n : int, optional
        Fix the P-I operators / Preisach levels instead of choosing them.
    kinds : sequence of str, optional
        Restrict ``"auto"`` to these kinds (``commission`` uses the linear ones).
    margin : float, optional
        Smallest branch slope (see :mod:`piezohyst.identify.linear`).
    taus, input_taus, max_delay : optional
        Replace the data-derived output lags (one set, used as given), input-lag candidates and
        largest delay of the search.
    statics : sequence of {"pi", "preisach", "bouc-wen", "duhem"}
        The static parts the linear kinds may use.
    seed, bouc_wen_options
        For the Bouc-Wen candidate (PSO).
    progress : callable or bool, optional
        Called with a short description before each stage; True shows a
        :class:`~piezohyst.Progress` display (in a notebook, or on a terminal's standard error).
    warmup : int
        Samples at the record's start that only set the model's state: the candidates' operators
        and lags run through them, but they are neither fitted nor scored (a conditioning sweep
        that wipes out a stage's unknown past, so the model's initial state need not be the
        stage's). The hold-out part and ``n_fit`` count from after them; the Bouc-Wen (PSO)
        candidate starts from rest after them. Rounded up to the search's row stride;
        ``info["warmup"]`` says what was used.
    glitches : {"bridge", "keep"}
        Isolated gross glitches of y (one or two samples off their neighbours by more than 5 %
        of the span and 10x the noise: :mod:`piezohyst.identify.glitches`) are bridged by
        interpolation before anything is fitted, and a warning says how many (``"bridge"``,
        the default); ``"keep"`` fits y as it is. ``info["glitches_bridged"]`` counts them.
    history : {"auto", "none"}, optional
        Where the stage's state at the record's start came from. Every model kind starts from its
        de-energised state; a stage at rest need not be there (one that last came down from the
        top of its range keeps that branch's remanence). With ``"auto"`` the chosen structure is
        also fitted after each of two histories, down to the bottom of the record's input and back
        to its first value, and up to its top and back (:class:`~piezohyst.models.AfterHistory`),
        and one is kept where it lowers the hold-out error by :data:`MIN_GAIN` (module docstring,
        stage 7); ``"none"`` fits from the de-energised state. Default: ``"auto"`` for
        ``kind="auto"``, ``"none"`` for a kind asked for by name (its model is returned as that
        kind); ``kind="after-history"`` chooses the better of the two histories whatever the
        de-energised start scores (among the linear kinds). With ``validation`` sets each set is
        simulated after the history too (it starts at rest, as the record does). Not with
        ``warmup`` (the warm-up sets the state), where ``"auto"`` fits from the de-energised state.

    Returns
    -------
    FitResult
        The chosen model refitted on the whole training record; ``info["candidates"]`` lists
        every candidate with its hold-out error (µm and % of span), ``info["holdout"]`` the
        winner's, ``info["search"]`` the ranges; ``warnings`` what deserves attention.
    """
    # the display opened before anything is checked or changed, so the arguments go on as given
    # (it failed deep in the search, "'bool' object is not callable": found by a helper)
    if progress is True:
        from ..progress import Progress

        with Progress("identifying") as shown:
            return fit_model(u, y, dt, kind, validation=validation, holdout=holdout, delay=delay, n=n, kinds=kinds,
                             margin=margin, taus=taus, input_taus=input_taus, max_delay=max_delay, statics=statics,
                             seed=seed, bouc_wen_options=bouc_wen_options, progress=shown, warmup=warmup,
                             glitches=glitches, history=history)
    if not (progress is None or progress is False or callable(progress)):
        raise TypeError(f"progress must be True, False, None or a function of one str, got {type(progress).__name__}")
    t0 = time.perf_counter()
    if isinstance(kind, str) and kind.strip().lower() == "auto":  # spelt as kind names may be ("PI", "Preisach")
        kind = "auto"
    u, y, dt = unpack_data(u, y, dt)
    us, ys = paired_signals(u, y, 0)
    if history not in (None, "auto", "none"):
        raise ValueError(f"history must be 'auto' or 'none', got {history!r}")
    if kind != "auto" and kinds is not None and kind_class(kind) is not AfterHistory:
        # (kind="pi", kinds=("preisach",) fitted a P-I model, kinds ignored: found by fuzzing)
        raise ValueError(f"kinds= chooses among kinds for kind='auto'; kind={kind!r} fits that kind alone: drop "
                         f"kinds, or pass kind='auto'")
    if kind != "auto" and kind_class(kind) is AfterHistory:
        if warmup:
            raise ValueError("kind='after-history' fits the stage's start: not with a warmup, which sets the state")
        kind, kinds, history = "auto", list(kinds or _LINEAR_KINDS), "force"
    elif history is None:
        history = "auto" if kind == "auto" else "none"
    if isinstance(kinds, str):  # one kind given as a string, not a list of them
        kinds = [kinds]
    if kinds is not None:  # "after-history" among the kinds: the start is chosen anyway (history)
        kinds = [k for k in kinds if kind_class(k) is not AfterHistory]
    if glitches not in ("bridge", "keep"):
        raise ValueError(f"glitches must be 'bridge' or 'keep', got {glitches!r}")
    spikes = find_glitches(ys) if glitches == "bridge" else np.empty(0, dtype=np.int64)
    if spikes.size:
        ys = bridge_glitches(ys, spikes)
    if not float(np.ptp(ys)) > 0:
        raise ValueError(f"y is constant ({float(ys[0]):.6g}): the output never moves, so no model of how it "
                         "follows the input can be identified (a sensor that is not connected or not reading, a "
                         "stage that is not driven?)")
    check_output_scale(us, ys)
    if not rises_with_input(us, ys):
        r = float(np.corrcoef(us, ys)[0, 1])
        seen = (f"correlation {r:.2f}; input {float(np.min(us)):.4g} to {float(np.max(us)):.4g}, output span "
                f"{float(np.ptp(ys)):.3g}")
        rising = rising_part(us, ys)
        butterfly = butterfly_hint(rising, "input", "", "record it with the input kept there")
        if r > -WEAK_CORRELATION:  # found by fuzzing: swings inside a dead zone gave r = -0.01 to -0.26
            raise ValueError(
                f"the output hardly follows the input over this record ({seen}): swings within the stage's dead "
                "band or play, or a sensor that does not see the stage? Excite a wider range of the input"
                + butterfly)
        raise ValueError(
            f"the output falls as the input rises over this record ({seen}): every model kind here has a "
            "rising loop. A sensor that reads the other way round: negate y first; a stage whose loop falls "
            "after each reversal for longer than these swings: excite a wider range" + butterfly)
    dt = as_scalar("dt", dt, positive=True) if dt is not None else None
    say = progress if callable(progress) else (lambda s: None)
    allowed = _allowed_kinds(kind, kinds, dt)
    kind_name = allowed[0] if kind != "auto" else None
    vsets = [_as_validation(v, i) for i, v in enumerate(validation or [])]
    n_total = us.size
    if isinstance(holdout, (int, np.integer)) and not isinstance(holdout, bool):
        if not 20 <= holdout <= n_total - 50:
            raise ValueError(f"holdout of {holdout} samples leaves too little to fit on or to choose on "
                             f"({n_total} samples)")
        n_fit = n_total if vsets else n_total - int(holdout)
    else:
        if not vsets and not (0.05 <= holdout <= 0.5):
            raise ValueError(f"holdout must be between 0.05 and 0.5 of the record, got {holdout}")
        n_fit = n_total if vsets else int(round((1.0 - holdout) * n_total))
    if n_fit < 50 or (not vsets and n_total - n_fit < 20):
        raise ValueError(f"{n_total} samples are too few to fit on one part and choose on another")
    w = as_count("warmup", warmup, maximum=n_fit - 50,
                 why=f"samples leaves too little to fit on ({n_fit} samples to fit on)")
    if n is not None:
        n = as_count("n", n, minimum=1)
    if margin is not None:
        margin = as_scalar("margin", margin, nonnegative=True)
    # a delay as long as the part fitted on leaves nothing to fit (and ran the kernels past the
    # record's end: found by fuzzing, a segmentation fault for max_delay=10000 on 1500 samples)
    room = n_fit - w - 50
    if delay != "auto":
        if isinstance(delay, str):
            raise ValueError(f"delay must be a whole number of samples or 'auto', got {delay!r}")
        delay = as_count("delay", delay, maximum=room,
                         why=f"samples (delay= in Python, --delay at the command line) leaves too few samples to "
                             f"fit on ({n_fit - w} samples to fit on)")
    if max_delay is not None:
        max_delay = as_count("max_delay", max_delay, maximum=room,
                             why=f"samples leaves too few samples to fit on ({n_fit - w} samples to fit on)")
    for name, lags, least in (("taus", taus, "> 0"), ("input_taus", input_taus, ">= 0: 0 is no input lag")):
        if lags is not None and not all(isinstance(t, (int, float, np.integer, np.floating))
                                        and not isinstance(t, (bool, np.bool_)) and math.isfinite(t)
                                        and (t > 0 if name == "taus" else t >= 0) for t in lags):
            raise ValueError(f"{name} must be time constants in seconds (finite, {least}), got {list(lags)!r}")
    stride = max(1, (n_fit - w) // SEARCH_ROWS)
    w = -(-w // stride) * stride
    prefix = us[:w]
    if w:
        us, ys, n_total, n_fit = us[w:], ys[w:], n_total - w, n_fit - w
    if margin is None:
        margin = DEFAULT_MARGIN * mean_slope(us[:n_fit], ys[:n_fit])
    # validation sets of other rates would show what a record of one rate cannot: the rule is for
    # a choice made on the record's own later part; a rate-dependent model asked for by name keeps
    # the lags slower than the excitation (its lags are what the caller wants)
    one_rate_lags = 1.0 if kind_name == "rate-dependent" else ONE_RATE_LAGS
    ranges = search_ranges(us, dt, n_fit, one_rate_rule=not vsets, one_rate_lags=one_rate_lags)
    if taus is not None or input_taus is not None or max_delay is not None:
        ranges = replace(
            ranges, max_delay=ranges.max_delay if max_delay is None else int(max_delay),
            input_taus=ranges.input_taus if input_taus is None else tuple(float(t) for t in input_taus if t > 0),
            rate_taus=ranges.rate_taus if taus is None else tuple(float(t) for t in taus),
            creep_taus=ranges.creep_taus if taus is None else ())
    bad = set(statics) - {"pi", "preisach", "bouc-wen", "duhem"}
    if bad or not statics:
        raise ValueError(f"statics must be a non-empty selection of 'pi', 'preisach', 'bouc-wen' and 'duhem', "
                         f"got {list(statics)}")
    far = _far_from_rest(us[:n_fit])
    if far and "duhem" in statics:
        # a Duhem model's memory runs from rest (0 V): from a record this narrow this far from it,
        # its branches on the way there cannot be judged (GeneralizedDuhem's v_range)
        if kind_name == "generalized-duhem" or set(statics) == {"duhem"}:
            raise ValueError(f"{far}: a generalized Duhem model's state runs from rest, and from this record its "
                             "branches cannot be judged on the way; give a record that also covers the way from "
                             "rest, or try kind='auto'")
        statics = [s for s in statics if s != "duhem"]
    sc = _Scorer(us, ys, dt, n_fit, vsets, margin, warmup=prefix, stride=stride)
    start: AfterHistory | None = None  # the history chosen for the stage's initial state (stage 7)
    starts: list[dict[str, Any]] = []
    linear = [k for k in allowed if k in _LINEAR_KINDS]
    best: _Candidate | None = None
    if linear:
        pi_static = "pi" in statics and any(k in ("prandtl-ishlinskii", "rate-dependent", "asymmetric-pi")
                                            for k in linear)
        if pi_static:
            base = Structure("pi", n or 20)
        elif "preisach" in statics and any(k in ("preisach", "rate-dependent") for k in linear):
            base = Structure("preisach", n or 12)
        elif "generalized-duhem" in linear and "bouc-wen-hysteresis" not in linear:  # align with a mid-range rate
            base = Structure("duhem", n or 8, shape=(2.0 / float(np.ptp(us[:n_fit])), 0.0))
        else:  # the Bouc-Wen hysteresis alone: align with a mid-range shape
            base = Structure("bouc-wen", 1, shape=(1.5 / float(np.ptp(us[:n_fit])), 0.0))
        # P-I thresholds over half the input's span (the operators that move in steady loops) or by
        # the paper's eq. (4) (the initial loading too): the whole search runs for each, since which
        # one wins can change once lags take part of the error
        rules = ("span", "eq4") if pi_static else ("span",)
        # the generalized Duhem model does not depend on the P-I thresholds: its stage runs once,
        # from the better of the two searches' lags and delay, rather than in each
        once = len(rules) > 1 and "duhem" in statics and len(statics) > 1
        per_rule = [s for s in statics if s != "duhem"] if once else list(statics)
        ends = _searches(sc, [replace(base, thresholds=r) for r in rules], ranges, delay, linear, n, n_fit,
                         kind_name, per_rule, dt, say)
        best = min(ends, key=lambda c: c.score)
        if once and ("generalized-duhem" in linear or ("rate-dependent" in linear and best.structure.rate_dependent)):
            say("generalized Duhem model")
            c = _duhem_shapes(sc, best, best.structure, "generalized-duhem" in linear, "rate-dependent" in linear,
                              kind_name == "generalized-duhem", n, ranges.max_delay if delay == "auto" else None,
                              _lag_sets(ranges, dt))
            if c is not best and delay == "auto":
                c = _realign(sc, c, ranges, _input_lags(ranges, dt, linear), linear, kind_name)
            best = c
        say("local moves around the best")
        best = _one_rate_delay(sc, _polish(sc, best, ranges, delay, linear, n, kind_name), ranges,
                               delay == "auto" and max_delay is None)
    if "bouc-wen" in allowed and dt is not None:
        say("Bouc-Wen (PSO)")
        bw = _bouc_wen_candidate(sc, best.structure.delay if best else (0 if delay == "auto" else int(delay)),
                                 seed, bouc_wen_options)
        best = bw if best is None else _prefer(best, bw) if bw.score < best.score else best
    assert best is not None
    if history != "none" and not w and isinstance(best.structure, Structure):
        say("initial state")
        best, start, starts = _initial_state(sc, best, ranges, delay, linear, n, kind_name, history == "force",
                                             searched=delay == "auto" and max_delay is None)
        if start is not None:
            prefix = start.history()
    # refit the winner on the whole training record
    say("refit on the whole record")
    refused: list[str] = []
    flat: list[str] = []
    if isinstance(best.structure, Structure):
        final, _ = _refit(prefix, us, ys, dt, best.structure, margin)
        # the compensator must exist and stay smooth: a refitted generalized Duhem model whose
        # branches could rise by less than the margin, or a candidate whose inverse chatters, is
        # passed over for the next best (module docstring, "inverses that never chatter")
        # (the runners-up fitted from the same start as the winner: the refit runs after its history)
        order = sorted((c for c in sc.tried if isinstance(c.structure, Structure) and c is not best
                        and math.isfinite(c.score) and c.start == best.start), key=lambda c: c.score)
        # after the runners-up, the best rate-independent candidate: with no lags to invert,
        # its command follows the reference's turns and no others (a monotone inverse)
        static = [c for c in order if not c.structure.taus and not c.structure.input_tau]
        queue = order[:CHATTER_RETRIES] + [c for c in static if c not in order[:CHATTER_RETRIES]][:1]
        while queue:
            if best.structure.static == "duhem" and not _duhem_invertible(final.model, margin):
                flat.append(best.label)
            elif dt is not None and _chatters(final.model, dt, ys, ranges):
                limited = _with_limited_lead(final.model, dt, ys, ranges)
                if limited is None:
                    refused.append(best.label)
                else:  # only the input lag's lead stepped too far: the same model, its lead limited
                    final.model = limited
                    final.info["input_lead_gain"] = _input_lead_gain(limited)
                    break
            else:
                break
            best = queue.pop(0)
            final, _ = _refit(prefix, us, ys, dt, best.structure, margin)
        if best.structure.static == "duhem" and not _duhem_invertible(final.model, margin):
            raise ValueError(f"no generalized Duhem model with rising branches fits these data: the best one's "
                             f"smallest branch slope is {getattr(final.model, 'static', final.model).min_slope:.3g} "
                             f"(margin {margin:.3g}); its loop saturates or falls after reversals where this kind "
                             f"cannot follow it. Try kind='auto' (--model auto)")
        if start is not None:
            final.model = AfterHistory(final.model, start.waypoints, start.leg_samples, start.hold_samples)
            final.info["history"] = {k: v for k, v in start.describe().items() if k != "model"}
    else:
        final = _fit_bouc_wen(us, ys, dt, best.structure[1], seed, bouc_wen_options)  # type: ignore[arg-type]
    span = float(np.ptp(ys))
    final.info["candidates"] = [
        {"label": c.label, "kind": c.kind, "holdout_rmse": c.score,
         "holdout_percent_of_span": 100.0 * c.score / span if span > 0 else None,
         "fit_rmse": c.fit_rmse, "n_parameters": c.n_parameters, "per_set_rmse": c.per_set,
         "chosen": c is best} for c in sc.tried]
    final.info["holdout"] = {"rmse": best.score, "percent_of_span": 100.0 * best.score / span if span > 0 else None,
                             "on": "validation data" if vsets else f"the last {n_total - n_fit} samples "
                             f"({100 * (1 - n_fit / n_total):.0f} %) of the training record", "per_set_rmse": best.per_set}
    final.info["search"] = ranges.to_dict()
    if refused:
        final.info["refused_for_chatter"] = refused
    if flat:
        final.info["refused_not_invertible"] = flat
    final.info["chosen"] = best.label
    if starts:
        final.info["initial_state"] = starts
    final.info["glitches_bridged"] = int(spikes.size)
    final.method = f"selection on held-out data: {best.label}"
    final.warnings = _quality_warnings(final, us, ys, dt, best, span, vsets, n_fit, sc) + final.warnings
    if spikes.size:
        final.warnings.append(
            f"y has {spikes.size} isolated glitch{'es' if spikes.size > 1 else ''} (one or two samples more than "
            f"{100 * GLITCH_SPAN_SHARE:g} % of the span off their neighbours, first at sample {int(spikes[0])}): a "
            "sensor's miscounts or dropouts? Bridged by interpolation before fitting (glitches='keep' fits them)")
    if ranges.single_rate_hz is not None:
        final.warnings.append(
            f"the training record has one rate ({ranges.single_rate_hz:.3g} Hz: at least {SINGLE_RATE_SHARE:.0%} of "
            f"the input's power within half an octave of it), which cannot tell a sensor delay from the loop's own "
            f"phase lag, nor rate dependence from the loop's shape: the search kept "
            f"{'a delay only where it halves the error, ' if delay == 'auto' and max_delay is None else ''}"
            f"no input lag and no lag {'within a decade of' if one_rate_lags > 1 else 'faster than'} the "
            f"excitation; the lags and delay kept are fitted to that rate. Give the delay (delay=N, --delay N), "
            f"or identify on a record with several rates and amplitudes (commissioning_excitation), or choose on "
            f"validation data of other rates")
    if w:
        final.info["warmup"] = w
    final.time_s = time.perf_counter() - t0
    return final


def _histories(u: FloatArray, n_fit: int, dt: float | None, stride: int) -> list[AfterHistory]:
    """The histories :func:`_initial_state` tries, each as an :class:`AfterHistory` around a
    placeholder (only its waypoints and lengths are used): from the record's first value (rest)
    down to the least input of the fitting part and back, and up to the greatest and back; a
    side within :data:`HISTORY_MIN_SHARE` of the input's span of rest is left out (the stage
    rests at that end: the history would barely move it). Legs of :data:`HISTORY_LEG_S` and as
    long again held at rest, so that lags settle (with ``dt``; else legs of
    :data:`HISTORY_LEG_SAMPLES`: a rate-independent model's state depends on the turning points
    only); the whole a multiple of ``stride`` (the search's rows)."""
    from ..models.pi import PrandtlIshlinskii

    rest, lo, hi = float(u[0]), float(np.min(u[:n_fit])), float(np.max(u[:n_fit]))
    span = hi - lo
    leg = max(int(round(HISTORY_LEG_S / dt)), HISTORY_LEG_SAMPLES) if dt is not None else HISTORY_LEG_SAMPLES
    hold = leg if dt is not None else 0
    hold += -(2 * leg + hold + 1) % stride
    placeholder = PrandtlIshlinskii(np.zeros(1), np.ones(1))
    return [AfterHistory(placeholder, (rest, end, rest), leg, hold) for end in (lo, hi)
            if abs(end - rest) > HISTORY_MIN_SHARE * span]


def _initial_state(sc: _Scorer, best: _Candidate, ranges: SearchRanges, delay: Any, linear: list[str],
                   n: int | None, kind_name: str | None,
                   force: bool = False, *, searched: bool = True
                   ) -> tuple[_Candidate, AfterHistory | None, list[dict[str, Any]]]:
    """Stage 7 (``fit_model``'s ``history``): the chosen structure fitted after each history of
    :func:`_histories`, then moved locally (:func:`_polish`: a wrong start can bend the delay and
    size the search chose), scored on the same hold-out; a history is kept where it lowers the
    hold-out error by :data:`MIN_GAIN` (with ``force``, the better history whatever the
    de-energised start scores). Its candidates join ``sc.tried``, labelled with it.
    Returns the best candidate, its history (None: the de-energised start) and what each start
    scored (``info["initial_state"]``)."""
    table = [{"start": "de-energised", "label": best.label, "holdout_rmse": best.score}]
    chosen: tuple[_Candidate, AfterHistory | None] = (best, None)
    row = 0
    for h in _histories(sc.u, sc.n_fit, sc.dt, sc.stride):
        s = _Scorer(sc.u, sc.y, sc.dt, sc.n_fit, sc.validation, sc.margin, warmup=h.history(), stride=sc.stride)
        s.history = True
        c = _one_rate_delay(s, _polish(s, s.linear(best.structure), ranges, delay, linear, n, kind_name), ranges,
                            searched)
        for t in s.tried:
            t.start = _history_label(h)
            t.label, t.kind = f"{t.label}, {t.start}", AfterHistory.kind
            sc.tried.append(t)
        table.append({"start": _history_label(h), "label": c.label, "holdout_rmse": c.score})
        if c.score < (1.0 - MIN_GAIN) * chosen[0].score or (force and (chosen[1] is None or c.score < chosen[0].score)):
            chosen, row = (c, h), len(table) - 1
    for i, entry in enumerate(table):
        entry["chosen"] = i == row
    return chosen[0], chosen[1], table


def _one_rate_delay(sc: _Scorer, best: _Candidate, ranges: SearchRanges, searched: bool) -> _Candidate:
    """On a record of one rate a searched delay stays only where the data show it beyond doubt
    (module docstring): where it does not lower the hold-out error by the factor
    :data:`ONE_RATE_DELAY_GAIN`, the same structure without it.

    Where the same structure without the delay is ruled out (a generalized Duhem candidate whose
    branches would not rise), the best candidate without a delay that the search tried stands in
    for it: the ruled-out one's infinite error was "halved" by any delay (on a 1 Hz record of the
    VirtualRig a Duhem model kept 350 samples, 35 ms, of delay where the rig has one, and its
    feedforward missed a 2 Hz reference by 21 % of span)."""
    if ranges.single_rate_hz is None or not searched or not best.structure.delay:
        return best
    at_zero = sc.linear(replace(best.structure, delay=0))
    if not math.isfinite(at_zero.score):
        undelayed = [c for c in sc.tried if isinstance(c.structure, Structure) and not c.structure.delay
                     and math.isfinite(c.score)]
        if not undelayed:
            return best
        at_zero = min(undelayed, key=lambda c: c.score)
    return best if best.score < ONE_RATE_DELAY_GAIN * at_zero.score else at_zero


def _history_label(h: AfterHistory) -> str:
    side = "below" if h.waypoints[1] < h.waypoints[0] else "above"
    return f"after a history from {side} ({h.waypoints[1]:.4g} V and back)"


def _refit(prefix: FloatArray, u: FloatArray, y: FloatArray, dt: float | None, st: Structure,
           margin: float) -> tuple[FitResult, FloatArray]:
    """The chosen structure on the whole training record (after the warm-up ``prefix``)."""
    if not prefix.size:
        return fit_structure(u, y, dt, st, margin=margin)
    return fit_structure(np.concatenate([prefix, u]), np.concatenate([np.full(prefix.size, y[0]), y]), dt, st,
                         margin=margin, warmup=prefix.size)


def _complexity(st: Structure) -> int:
    """Number of free parameters a structure adds (to prefer the simpler of two close candidates)."""
    size = {"pi": st.size, "preisach": st.size * (st.size + 1) // 2 + 2 * st.size, "bouc-wen": 3,
            "duhem": 2 * st.size + 1}[st.static]
    return size + st.map_knots + len(st.taus) + (1 if st.input_tau else 0)


def _polish(sc: _Scorer, best: _Candidate, ranges: SearchRanges, delay: Any, linear: list[str],
            n: int | None, kind_name: str | None, rounds: int = 6) -> _Candidate:
    """Coordinate moves from the staged search's result until none helps: the delay by one or
    two samples, the neighbouring input lags or none, the lags' sets, the size and the map's knots.
    A simpler structure replaces a more complex one unless that one is better by MIN_GAIN; the
    staged search decides each dimension with the others fixed, and this undoes what an early,
    simplified stage got wrong (e.g. a delay chosen before the right operators were there)."""
    if not isinstance(best.structure, Structure):
        return best
    itaus = (0.0, *ranges.input_taus)
    lag_sets = [(), ranges.rate_taus, ranges.creep_taus]
    for _ in range(rounds):
        st = best.structure
        moves: list[Structure] = []
        if delay == "auto":
            moves += [replace(st, delay=d) for d in (st.delay - 2, st.delay - 1, st.delay + 1, st.delay + 2)
                      if 0 <= d <= ranges.max_delay]
        if sc.dt is not None and len(itaus) > 1:
            i0 = min(range(len(itaus)), key=lambda i: abs(itaus[i] - st.input_tau))
            moves += [replace(st, input_tau=itaus[i]) for i in {0, max(i0 - 1, 0), min(i0 + 1, len(itaus) - 1)}
                      if itaus[i] != st.input_tau]
            if kind_name != "rate-dependent" or st.static != "pi":
                moves += [replace(st, taus=t) for t in lag_sets if t != st.taus and (t or st.input_tau or st.map_knots
                                                                                       or kind_name != "rate-dependent")]
            else:
                moves += [replace(st, taus=t) for t in lag_sets if t and t != st.taus]
        if st.static == "pi" and not n:
            moves += [replace(st, size=s) for s in (10, 20, 40) if s != st.size and sc.n_fit >= 25 * s]
        if st.static == "pi" and "asymmetric-pi" in linear:
            moves += [replace(st, map_knots=k) for k in (0, 2, 4, 8) if k != st.map_knots
                      and (k or kind_name != "asymmetric-pi")]
        if st.static == "preisach" and not n:
            moves += [replace(st, size=s) for s in (8, 12, 16) if s != st.size]
        if st.static == "duhem" and not n:
            moves += [replace(st, size=s) for s in DUHEM_KNOTS if s != st.size and sc.n_fit >= 100 * s]
        improved = False
        for mv in moves:
            if not _allowed_structure(mv, linear, kind_name):
                continue
            c = sc.linear(mv)
            if _choose(best, c) is c:
                best, improved = c, True
        if not improved:
            break
    return best


def _allowed_structure(st: Structure, linear: list[str], kind_name: str | None) -> bool:
    """Whether the kinds the caller allows include the one ``st`` makes."""
    if kind_name is not None:
        return st.kind == kind_name or (kind_name == "rate-dependent" and st.rate_dependent and not st.map_knots)
    return st.kind in linear


def _delays_near(d0: int, max_delay: int) -> list[int]:
    """Delays around ``d0``: its neighbours and a few steps either side (log-spaced)."""
    out = {d0}
    for k in (1, 2, 4):
        if k <= max(2, max_delay // 8):
            out |= {max(d0 - k, 0), min(d0 + k, max_delay)}
    return sorted(out)


def _input_lags(ranges: SearchRanges, dt: float | None, linear: list[str]) -> tuple[float, ...]:
    """The input lags a search tries: none, and the data's range where a kind with lags is allowed."""
    rate_ok = dt is not None and any(k in ("rate-dependent", "asymmetric-pi") for k in linear)
    return (0.0, *ranges.input_taus) if rate_ok else (0.0,)


def _more_threads_wanted() -> bool:
    """Whether this thread may start another: not where numba's parallel regions were set to one
    thread (a fleet's workers, one per core, :mod:`piezohyst.fleet`; ``NUMBA_NUM_THREADS=1``)."""
    import numba

    return bool(numba.get_num_threads() > 1)


def _searches(sc: _Scorer, bases: list[Structure], ranges: SearchRanges, delay: Any, linear: list[str],
              n: int | None, n_fit: int, kind_name: str | None, statics: Sequence[str], dt: float | None,
              say: Callable[[str], None]) -> list[_Candidate]:
    """:func:`_linear_search` from each static part, the first on ``sc`` and each other one on a
    scorer of its own in a thread of its own (the searches are independent, and their kernels and
    BLAS products release the GIL); the others' candidates then join ``sc``'s, in order, each
    structure once. The candidates are those of the searches run one after the other, bit for bit
    (each fit depends only on its structure and the data)."""
    if len(bases) == 1 or not PARALLEL_SEARCHES or not _more_threads_wanted():
        return [_linear_search(sc, b, ranges, delay, linear, n, n_fit, kind_name, statics, dt, say) for b in bases]
    from concurrent.futures import ThreadPoolExecutor

    others = [sc.sibling() for _ in bases[1:]]
    quiet: Callable[[str], None] = lambda text: None  # noqa: E731 - progress is said by the first search
    with ThreadPoolExecutor(len(others)) as pool:
        futures = [pool.submit(_linear_search, o, b, ranges, delay, linear, n, n_fit, kind_name, statics, dt, quiet)
                   for o, b in zip(others, bases[1:])]
        try:
            ends = [_linear_search(sc, bases[0], ranges, delay, linear, n, n_fit, kind_name, statics, dt, say)]
        except BaseException:
            # (Ctrl-C, an error): the other searches stop at their next candidate, not at their end
            for o in others:
                o.cancelled = True
            raise
        ends += [f.result() for f in futures]
    for o in others:
        sc.adopt(o)
    return ends


def _linear_search(sc: _Scorer, base: Structure, ranges: SearchRanges, delay: Any, linear: list[str],
                   n: int | None, n_fit: int, kind_name: str | None, statics: Sequence[str],
                   dt: float | None, say: Callable[[str], None]) -> _Candidate:
    """Stages 1-4 of the module docstring from the static part ``base``."""
    rule = "" if base.static != "pi" else f" ({base.thresholds} thresholds)"
    rate_ok = dt is not None and any(k in ("rate-dependent", "asymmetric-pi") for k in linear)
    itaus = _input_lags(ranges, dt, linear)
    say("sensor delay and input lag" + rule)
    if delay == "auto":
        # delay and input lag trade against each other: search them jointly. An input lag of tau
        # stands for about tau / dt of the delay found without one, so each lag's delays are
        # searched around what is left of that delay.
        first = _delay_search(sc, base, 0, ranges.max_delay)
        per_tau = [first]
        for it in itaus[1:]:
            left = max(first.structure.delay - int(round(it / dt)), 0) if dt else first.structure.delay
            per_tau.append(min((sc.linear(replace(base, input_tau=it, delay=d))
                                for d in _delays_near(left, ranges.max_delay)), key=lambda c: c.score))
    else:
        per_tau = [sc.linear(replace(base, input_tau=it, delay=int(delay))) for it in itaus]
    best = per_tau[0]
    for c in per_tau[1:]:
        best = _prefer(best, c)
    if rate_ok:
        say("output lags" + rule)
        st0 = best.structure
        lagged = [sc.linear(replace(st0, taus=taus)) for taus in (ranges.rate_taus, ranges.creep_taus)
                  if taus and taus != st0.taus]
        if kind_name == "rate-dependent" and lagged and not st0.rate_dependent:
            best = _best(lagged)  # asked for: the best lagged structure, not the plain one
        for c in lagged:
            best = _prefer(best, c)
        if best.structure.rate_dependent and len(itaus) > 1:
            # the lags take part of what looked like delay and input lag: align again with them
            say("sensor delay and input lag, with the lags" + rule)
            st0 = best.structure
            i0 = itaus.index(st0.input_tau) if st0.input_tau in itaus else 0
            near_taus = {itaus[0], *itaus[max(i0 - 1, 0):i0 + 2]}
            ds = _delays_near(st0.delay, ranges.max_delay) if delay == "auto" else [st0.delay]
            for it in sorted(near_taus):
                for d in ds:
                    c = sc.linear(replace(st0, input_tau=it, delay=d))
                    best = c if c.score < best.score else best
    say("model kind and size" + rule)
    chosen = _kind_stage(sc, best, linear, n, n_fit, kind_name, statics,
                         max_delay=ranges.max_delay if delay == "auto" else None, lag_sets=_lag_sets(ranges, dt))
    if delay == "auto" and (chosen.structure.static, chosen.structure.size, chosen.structure.map_knots) != \
            (best.structure.static, best.structure.size, best.structure.map_knots):
        say("sensor delay and lags again, with the chosen kind" + rule)
        chosen = _realign(sc, chosen, ranges, itaus, linear, kind_name)
    return chosen


def _realign(sc: _Scorer, best: _Candidate, ranges: SearchRanges, itaus: tuple[float, ...], linear: list[str],
             kind_name: str | None) -> _Candidate:
    """The delay over its whole range again, with and without the output lags, once the static kind
    is chosen: stages 1-3 decided the delay with a plain P-I model, and where that model cannot
    follow the stage (a saturating or asymmetric loop) the delay that fits it best is not the
    stage's (a long delay stands in for the misfit); the lags chosen with it may be wrong too."""
    st0 = best.structure
    for taus in sorted({st0.taus, ()}, key=len):
        base = replace(st0, taus=taus, input_tau=0.0)
        if not _allowed_structure(base, linear, kind_name):
            continue
        c = _delay_search(sc, base, 0, ranges.max_delay)
        near = [c] + [sc.linear(replace(base, input_tau=it, delay=d)) for it in itaus[1:3]
                      for d in _delays_near(c.structure.delay, ranges.max_delay)]
        best = _choose(best, min(near, key=lambda x: x.score))
    return best


def _choose(best: _Candidate, c: _Candidate) -> _Candidate:
    """``c`` or ``best``: a simpler structure wins unless worse by more than :data:`MIN_GAIN`, a more
    complex one only by more than it, one as complex by any margin."""
    cx, bx = _complexity(c.structure), _complexity(best.structure)
    if cx < bx:
        return c if c.score <= best.score / (1.0 - MIN_GAIN) else best
    if cx > bx:
        return _prefer(best, c)
    return c if c.score < best.score else best


def _lag_sets(ranges: SearchRanges, dt: float | None) -> list[tuple[float, ...]]:
    """The output-lag sets the search tries (the ranges' rate and creep lags), each once; none without ``dt``."""
    sets: list[tuple[float, ...]] = []
    for taus in (ranges.rate_taus, ranges.creep_taus) if dt is not None else ():
        if taus and taus not in sets:
            sets.append(taus)
    return sets


def _kind_stage(sc: _Scorer, best: _Candidate, linear: list[str], n: int | None, n_fit: int,
                force: str | None, statics: Sequence[str], max_delay: int | None = None,
                lag_sets: Sequence[tuple[float, ...]] = ()) -> _Candidate:
    """Stage 4: the static kind and its size (smaller first; larger ones must win by MIN_GAIN)."""
    st0 = best.structure
    inc: _Candidate | None = None
    if st0.static == "pi":
        sizes = [n] if n else [s for s in (10, 20, 40) if n_fit >= 25 * s] or [st0.size]
        for s in sorted(sizes):
            c = best if s == st0.size else sc.linear(replace(st0, size=s))
            inc = c if inc is None else _prefer(inc, c)
        assert inc is not None
        if "asymmetric-pi" in linear:
            maps = [sc.linear(replace(inc.structure, map_knots=k)) for k in (2, 4, 8)
                    if n_fit >= 50 * (inc.structure.size + k)]
            if force == "asymmetric-pi" and maps:
                inc = _best(maps)
            for c in maps:
                inc = _prefer(inc, c)
    if "bouc-wen" in statics and ("bouc-wen-hysteresis" in linear or ("rate-dependent" in linear and st0.rate_dependent)):
        inc = _bouc_wen_shapes(sc, inc, st0, "bouc-wen-hysteresis" in linear, "rate-dependent" in linear,
                               force == "bouc-wen-hysteresis")
    if "duhem" in statics and ("generalized-duhem" in linear or ("rate-dependent" in linear and st0.rate_dependent)):
        inc = _duhem_shapes(sc, inc, st0, "generalized-duhem" in linear, "rate-dependent" in linear,
                            force == "generalized-duhem", n, max_delay, lag_sets)
    want_plain = "preisach" in linear and "preisach" in statics
    want_rate = "rate-dependent" in linear and st0.rate_dependent and "preisach" in statics
    if want_plain or want_rate:
        levels = [n] if (n and st0.static == "preisach") else [s for s in (8, 12, 16) if n_fit >= 10 * s * (s + 1) // 2]
        if not levels and inc is None:  # the Preisach model alone, on a short record: as many levels as it carries
            most = int((math.sqrt(1.0 + 0.8 * n_fit) - 1.0) / 2.0)  # 10 samples per weight
            if most < 2:
                raise ValueError(f"{n_fit} samples to fit on are too few for a Preisach model (at least 30: 10 per "
                                 "weight of 2 levels); give a longer record")
            levels = [most]
        # each size also without the delay the P-I stages chose when the delay is the search's: a P-I
        # model that cannot follow the loop picks a long delay for its misfit, which a Preisach model
        # that can follow it does not need (a small-signal record around 126 V of a P-I stage: P-I chose
        # a delay of 61 samples, and a Preisach model at 61 lost to a Bouc-Wen one, 0.66 % of span,
        # where at delay 0 it scores 0.006 %)
        delays = [st0.delay] + ([0] if max_delay is not None and st0.delay > 0 else [])
        for s in levels:
            taus, itau = (st0.taus, st0.input_tau) if want_rate else ((), 0.0)
            c = _best([sc.linear(Structure("preisach", s, 0, taus, itau, d)) for d in delays])
            inc = c if inc is None else (_prefer(inc, c) if inc.structure.static == "pi" else
                                         (c if c.score < (1.0 - MIN_GAIN) * inc.score else inc))
    assert inc is not None
    return inc


def _bouc_wen_shapes(sc: _Scorer, inc: _Candidate | None, st0: Structure, plain: bool, lagged: bool,
                     force: bool) -> _Candidate:
    """The Bouc-Wen hysteresis with the stage's lags (or none): its shape (beta, gamma) on a grid
    over the input's span (``beta span`` from 0.5 to 15: loops that saturate little to much;
    ``gamma / beta`` -0.5, 0, 0.5: skewed either way or not), then refined around the best by a
    pattern search whose steps shrink (``beta`` by a factor 1.7, 1.3, 1.14; ``gamma / beta`` by
    0.25, 0.125, 0.0625): the shape is a nonlinear parameter, and the loop's skew matters to the
    compensator more than a coarse grid resolves."""
    span = float(np.ptp(sc.u[: sc.n_fit]))
    keep_rate = lagged and st0.rate_dependent
    taus, itau = (st0.taus, st0.input_tau) if keep_rate else ((), 0.0)
    if not keep_rate and not plain:
        assert inc is not None
        return inc

    def cand(b: float, g_ratio: float) -> _Candidate:
        b, g_ratio = float(f"{b:.9g}"), round(g_ratio, 9)  # one key per point however it was reached
        st = Structure("bouc-wen", 1, 0, taus, itau, st0.delay, shape=(b / span, g_ratio * b / span))
        return sc.linear(st)

    grid = [cand(b, g) for b in (0.5, 1.5, 5.0, 15.0) for g in (-0.5, 0.0, 0.5)]
    best = _best(grid)
    factor, step = 1.7, 0.25
    for _ in range(3):
        for _move in range(4):  # to the best of the four neighbours until none is better (at most 4 moves)
            b0 = best.structure.shape[0] * span
            g0 = best.structure.shape[1] / best.structure.shape[0]
            around = [cand(b, g) for b, g in ((b0 / factor, g0), (b0 * factor, g0), (b0, g0 - step), (b0, g0 + step))
                      if -0.9 < g < 0.9]
            nxt = _best([best, *around])
            if nxt is best:
                break
            best = nxt
        factor, step = math.sqrt(factor), 0.5 * step
    if inc is None or force:
        return best
    return _prefer(inc, best)


#: Knots of the generalised Duhem model's F and G the search tries (fewer first).
DUHEM_KNOTS = (4, 8, 12)
#: Factors by which the search refines the Duhem model's rate around the best, in turn: down to
#: 2 % (a rate between grid points shifts every branch's slope, and the least squares then bends F
#: and G to make up for it, down to branches as flat as the margin allows).
DUHEM_RATE_STEPS = tuple(2.0 ** (1.0 / 2 ** k) for k in range(1, 6))


def _far_from_rest(u: FloatArray) -> str | None:
    """Why a record is too narrow and too far from 0 V for a generalized Duhem model (its span more
    than :data:`~piezohyst.models.duhem.MAX_RANGE_SPANS` times smaller than its distance from
    rest), or None."""
    lo, hi = float(np.min(u)), float(np.max(u))
    if reaches_beyond_knots(min(lo, 0.0), max(hi, 0.0), lo, hi):  # the v_range a fit gives it
        return f"the input covers only {lo:.4g} .. {hi:.4g} V, more than {MAX_RANGE_SPANS} times its span from 0 V (rest)"
    return None


def _duhem_shapes(sc: _Scorer, inc: _Candidate | None, st0: Structure, plain: bool, lagged: bool,
                  force: bool, n: int | None, max_delay: int | None = None,
                  lag_sets: Sequence[tuple[float, ...]] = ()) -> _Candidate:
    """The generalised Duhem model with the stage's lags (or none): its relaxation rate on a grid
    over the input's span (``lam span`` from 0.5 to 32 by factors of 2: a loop that relaxes over
    twice the span to one that relaxes over 3 % of it) with 8 knots; with ``max_delay``, the delay
    over ``0..max_delay`` again for the best (the stages before aligned it with a P-I model, and
    where that model cannot follow a Duhem loop a long delay stands in for its misfit: measured 31
    samples against 22 for the Duhem model on a bipolar Coleman-Hodgdon stage); then the rate
    refined around the best by factors of 1.41, 1.19, ..., 1.02 (:data:`DUHEM_RATE_STEPS`), and
    the knots (4, 8, 12; fewer must lose
    by :data:`MIN_GAIN`). The rate and the delay trade against each other, so the delay search
    and the grid of rates alternate until neither moves (twice at most)."""
    span = float(np.ptp(sc.u[: sc.n_fit]))
    keep_rate = lagged and st0.rate_dependent
    taus, itau = (st0.taus, st0.input_tau) if keep_rate else ((), 0.0)
    if (not keep_rate and not plain) or not span > 0:
        assert inc is not None
        return inc
    sizes = [n] if n else [k for k in DUHEM_KNOTS if sc.n_fit >= 100 * k]
    if not sizes:
        if inc is None:  # the Duhem model alone was asked for
            raise ValueError(f"{sc.n_fit} samples to fit on are too few to choose a generalized Duhem model's knots "
                             f"(at least {100 * min(DUHEM_KNOTS)}: 100 per knot, {min(DUHEM_KNOTS)} knots or more); "
                             "give a longer record, fix the knots with n=, or try kind='auto'")
        return inc
    k0 = 8 if 8 in sizes else sizes[0]

    def cand(ls: float, k: int, delay: int, lags: tuple[tuple[float, ...], float] | None = None) -> _Candidate:
        ts, it = (taus, itau) if lags is None else lags
        st = Structure("duhem", k, 0, ts, it, delay, shape=(float(f"{ls:.9g}") / span, 0.0))
        return sc.linear(st)

    grid = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
    start = len(sc.tried)
    best = _best([cand(ls, k0, st0.delay) for ls in grid])

    def closest() -> _Candidate:
        """The best candidate, or where every one so far was ruled out (not invertible), the one
        whose hold-out error came closest before it was."""
        if math.isfinite(best.score):
            return best
        mine = [c for c in sc.tried[start:] if isinstance(c.structure, Structure)
                and c.structure.static == "duhem" and math.isfinite(c.unmasked)]
        return min(mine, key=lambda c: c.unmasked, default=best)

    if max_delay is not None:
        if not math.isfinite(best.score):
            # no rate invertible at the stages' delay: fitted at a delay that is not its own, a
            # Duhem model bends its branches to follow the misalignment, so the delay is searched
            # from the rate that came closest
            best = _delay_search(sc, closest().structure, 0, max_delay)
        # the rate and the delay trade against each other: each searched with the other fixed,
        # until neither moves (twice at most)
        for _ in range(2):
            if not math.isfinite(best.score):
                break
            d0 = best.structure.delay
            best = _best([best, _delay_search(sc, best.structure, 0, max_delay)])
            if best.structure.delay == d0:
                break
            ls0 = best.structure.shape[0]
            best = _best([best, *(cand(ls, k0, best.structure.delay) for ls in grid)])
            if best.structure.shape[0] == ls0:
                break
    if lagged and lag_sets and not best.structure.taus:
        # the stages before chose the output lags with a P-I model (here: none); where that model
        # cannot follow the loop, its misfit hides the creep the lags would take, and a Duhem model
        # that follows the loop may need them (Jiles-Atherton-like stages behind a slow amplifier:
        # every Duhem model without lags ruled out or behind a Preisach model, with them the best
        # by half). Each of the ranges' lag sets, from the best (or closest) rate, with the delay
        # searched again (the lags take part of it). It overturns what the lag stage decided, so it
        # must beat the best so far (of any kind) by MIN_GAIN per lag it adds: on a record whose
        # unmodelled 84 Hz mode dominated what every model left (3.3 % of span), lags and a long
        # delay let a Duhem model win by 2 % by following part of the ringing, and the mode no
        # longer showed in what it left
        base0 = closest().structure
        bar = min(best.score, inc.score if inc is not None else math.inf)
        for lag_set in lag_sets:
            base = replace(base0, taus=tuple(lag_set))
            c = _delay_search(sc, base, 0, max_delay) if max_delay is not None else sc.linear(base)
            if c.score < (1.0 - MIN_GAIN) ** len(lag_set) * bar and c.score < best.score:
                best = c
    if math.isfinite(best.score):
        lags = (best.structure.taus, best.structure.input_tau)
        for factor in DUHEM_RATE_STEPS:
            ls0, d0 = best.structure.shape[0] * span, best.structure.delay
            best = _best([best, cand(ls0 / factor, k0, d0, lags), cand(ls0 * factor, k0, d0, lags)])
        ls0 = best.structure.shape[0] * span
        for k in sorted(sizes):
            if k != k0:
                c = cand(ls0, k, best.structure.delay, lags)
                best = _prefer(best, c) if k > k0 else _choose(best, c)
    if not math.isfinite(best.score):
        return best if inc is None else inc
    if inc is None or force:
        return best
    return _prefer(inc, best)


#: Samples the Bouc-Wen candidate is fitted on at most (the first of the training part): its
#: swarm simulates the whole record 8040 times, and on 3 million samples (5 minutes at 10 kHz)
#: the candidate took 129 of fit_model's 146 s, 10 million 568 s and 5.6 GiB (found by a
#: helper timing records the benchmarks do not use); ten times the rows the linear candidates are
#: searched on, tens of seconds of loops at any rate a stage is excited at.
BOUC_WEN_SAMPLES = 10 * SEARCH_ROWS


def _fit_bouc_wen(u: FloatArray, y: FloatArray, dt: float, d: int, seed: Any,
                  options: dict[str, Any] | None) -> FitResult:
    from .bouc_wen import fit_bouc_wen

    n = min(u.size, BOUC_WEN_SAMPLES)
    fit = fit_bouc_wen(u[:n], y[:n], dt, seed=seed, delay=d, **(options or {}))
    if n < u.size:
        fit.info["fitted_samples"] = f"the first {n} of {u.size} samples (BOUC_WEN_SAMPLES)"
    return fit


def _bouc_wen_candidate(sc: _Scorer, d: int, seed: Any, options: dict[str, Any] | None) -> _Candidate:
    t0 = time.perf_counter()
    fit = _fit_bouc_wen(sc.u[: sc.n_fit], sc.y[: sc.n_fit], sc.dt, d, seed, options)  # type: ignore[arg-type]
    pred_u = fit.model.predict(sc.u, sc.dt)
    pred = np.concatenate([np.full(d, pred_u[0]), pred_u[: pred_u.size - d]]) if d else pred_u
    score, per = sc.score_model(fit.model, d, pred)
    unmasked = score
    if not fit.model.is_invertible:  # its output falls along a branch: eq. (10) has no unique command
        score, per = math.inf, [math.inf] * len(per)
    c = _Candidate(("bouc-wen", d), f"Bouc-Wen (PSO + refinement); delay {d}", "bouc-wen", score, fit.rmse, 7,
                   time.perf_counter() - t0, per, unmasked)
    sc.tried.append(c)
    return c


def _allowed_kinds(kind: str, kinds: Sequence[str] | None, dt: float | None) -> list[str]:
    if kind == "auto":
        allowed = list(kinds) if kinds is not None else [*_LINEAR_KINDS, "bouc-wen"]
        allowed = [kind_class(k).kind for k in allowed]  # type: ignore[attr-defined]
    else:
        allowed = [kind_class(kind).kind]  # type: ignore[attr-defined]
    if dt is None:
        if any(k in ("rate-dependent", "bouc-wen") for k in allowed) and kind != "auto":
            raise ValueError(f"a {allowed[0]} model has dynamics: give the sample period (dt= in Python, "
                             f"--fs or a time column at the command line)")
        allowed = [k for k in allowed if k not in ("rate-dependent", "bouc-wen")]
    if not allowed:
        raise ValueError("no model kind to fit")
    return allowed


def _as_validation(v: Any, i: int) -> tuple[FloatArray, FloatArray, int]:
    from ..data import Dataset

    if isinstance(v, Dataset):
        return v.u, v.y, 0
    if isinstance(v, (tuple, list)) and len(v) in (2, 3):
        uu, yy = paired_signals(v[0], v[1], 0)
        if uu.size < 20:  # (3 samples ended in numpy's "operands could not be broadcast": fuzzing)
            raise ValueError(f"validation set {i} has {uu.size} samples; at least 20 are needed to judge a model on")
        first = int(v[2]) if len(v) == 3 else 0
        if not 0 <= first < uu.size - 1:
            raise ValueError(f"validation set {i}: the first scored sample {first} is outside its {uu.size} samples")
        return uu, yy, first
    raise TypeError(f"validation set {i} must be a Dataset or a (u, y[, first]) tuple")


#: How many runners-up the chatter check may try before it keeps the best candidate anyway.
CHATTER_RETRIES = 8


#: A command's turn counts (:func:`_chatters`) when it goes back by more than this fraction of its
#: range: a smaller excursion (a wiggle of 10^-7 to 10^-5 of the range where a Preisach inverse's
#: kinks meet the lags' recursion) changes no displacement a stage can show, while chatter swings
#: the command by a good part of its range (the case that made this check: -40 to +110 V at the
#: Nyquist frequency after every reversal).
CHATTER_TURN = 1e-3
#: ... and (for a model with an input lag, whose turns are judged after that lag) the largest step
#: of the raw command, at most this many times the reference's scaled by the mean gain: an inverse
#: whose input is barely oscillating, led by a long lag's lead (gain tau / dt), swings the
#: command itself
CHATTER_STEP = 20.0


def _turns(x: FloatArray, tol: float) -> int:
    """How often ``x`` changes direction by more than ``tol``: the reversals of a play operator of
    threshold ``tol / 2`` driven by it (eqs. 1-2), which ignores excursions smaller than ``tol``."""
    p = play_operator(x, 0.5 * tol, float(x[0]))
    d = np.diff(p)
    d = d[d != 0.0]
    return int(np.count_nonzero(np.diff(np.sign(d)) != 0))


def _lag_part(model: Any) -> Any:
    """The part of ``model`` that carries its input lag: an asymmetric P-I model's inner model (as
    linear._instantaneous_min_slope unwraps it), else the model itself."""
    return getattr(model, "inner", model)


def _input_lag_factor(model: Any) -> float:
    """The model's input lag factor ``b`` (:attr:`~piezohyst.models.rate.RateDependent.input_lag_factor`),
    also inside an asymmetric P-I model; 0 without an input lag."""
    return float(getattr(_lag_part(model), "input_lag_factor", 0.0))


def _input_lead_gain(model: Any) -> float:
    """The limit on the gain of the model's input-lag lead (0: none), also inside an asymmetric P-I model."""
    return float(getattr(_lag_part(model), "input_lead_gain", 0.0))


def _with_input_lead_gain(model: Any, gain: float) -> Any:
    """The same model with its compensator's input-lag lead limited to ``gain``."""
    part = _lag_part(model)
    limited = replace(part, input_lead_gain=gain)
    return limited if part is model else replace(model, inner=limited)


def _with_limited_lead(model: Any, dt: float, y: FloatArray, ranges: SearchRanges) -> Any:
    """Where a model with an input lag is refused only for the raw command's steps (its inverse
    follows the reference's turns, but the lead, of gain about ``input_tau / dt``, turns each kink
    of the static inverse into a step beyond :data:`CHATTER_STEP`: at 20 kHz behind a 6.4 ms
    amplifier lag, 29-49 times the reference's), the same model with the lead's gain limited
    (:class:`~piezohyst.models.rate.RateDependent`, ``input_lead_gain``) as far as the steps ask
    and no further; None where that does not make it pass (or it oscillates whatever the lead).
    The stage then receives the static inverse's command ``input_tau / G`` late, where the
    rate-independent fallback missed by 3-4 % of span with the feedforward alone (that stage:
    0.54 / 0.61 / 0.65 % at 1 / 3 / 5 Hz with the lead unlimited)."""
    b = _input_lag_factor(model)
    if not b > 0.0 or _chatters(model, dt, y, ranges, raw_steps=False):
        return None
    excess = _raw_step_excess(model, dt, y, ranges)
    if not (math.isfinite(excess) and excess > 1.0):
        return None
    gain = 0.9 / ((1.0 - b) * excess)  # the exact lead's gain is 1 / (1 - b); its steps scale with it
    for _ in range(4):
        if gain < 1.0:
            return None
        limited = _with_input_lead_gain(model, gain)
        if not _chatters(limited, dt, y, ranges):
            return limited
        gain *= 0.5
    return None


def _test_references(dt: float, y: FloatArray, ranges: SearchRanges) -> list[tuple[int, FloatArray]]:
    """The smooth references :func:`_chatters` tries: three cycles of a sinusoid over the middle
    70 % of ``y`` at the low and high ends of the excitation band, with each one's period."""
    lo, hi = (float(v) for v in np.percentile(y, [15.0, 85.0]))
    if not hi > lo:
        return []
    out = []
    for f in sorted({ranges.f_lo or 1.0 / (1000 * dt), ranges.f_hi or 1.0 / (1000 * dt)}):
        per = max(int(round(1.0 / (f * dt))), 8)
        if per > 200_000:  # a very slow band: a shorter cycle shows the same reversals
            per = 200_000
        k = np.arange(3 * per, dtype=np.float64)
        out.append((per, lo + 0.5 * (hi - lo) * (1.0 - np.cos(2.0 * np.pi * k / per))))
    return out


def _raw_step_excess(model: Any, dt: float, y: FloatArray, ranges: SearchRanges) -> float:
    """The raw command's largest step over :data:`CHATTER_STEP` times the reference's (scaled by
    the mean gain), the worst of :func:`_test_references` (NaN without a compensator)."""
    try:
        comp = model.compensator(dt)
    except (ValueError, TypeError, AttributeError):
        return math.nan
    worst = 0.0
    for per, x in _test_references(dt, y, ranges):
        cmd = np.asarray(comp.command(x), dtype=np.float64)
        if not np.all(np.isfinite(cmd)):
            return math.inf
        worst = max(worst, _raw_step_ratio(cmd[per:], x[per:]))
    return worst


def _raw_step_ratio(raw: FloatArray, ref: FloatArray) -> float:
    """The command's largest step over :data:`CHATTER_STEP` times the reference's, scaled by the
    mean gain (0 where the reference does not move)."""
    gain = float(np.ptp(raw)) / float(np.ptp(ref)) if np.ptp(ref) > 0 else 0.0
    bound = CHATTER_STEP * gain * float(np.abs(np.diff(ref)).max())
    return float(np.abs(np.diff(raw)).max()) / bound if bound > 0 else 0.0


def _chatters(model: Any, dt: float, y: FloatArray, ranges: SearchRanges, *, raw_steps: bool = True) -> bool:
    """Whether the model's compensator chatters on smooth references: sinusoids over the middle
    70 % of the record's output at the low and high ends of its excitation band, the command
    turning more often than the reference (beyond one spare turn), after the first cycle; a turn
    of the command counts when it goes back by more than :data:`CHATTER_TURN` of its range. A
    hysteresis inverse turns where the reference turns and nowhere else.

    A model with an input lag (amplifier and stack) is judged on the command as that lag passes
    it on: its exact inverse is a lead of gain ``tau / dt``, which turns each kink of a Preisach
    inverse into a wiggle of a sample or two (1 V of 100 behind an 8 ms lag) that the lag smooths
    away; judged on the raw command, every candidate with an input lag was refused on such a
    stage and the rate-independent fallback missed by 4-5 % of span. An oscillating inverse still
    shows: the lag passes ``(1 - b) / (1 + b)`` of a swing at the Nyquist frequency; and the raw
    command's largest step may be at most :data:`CHATTER_STEP` times the reference's (scaled by
    the mean gain), so that a swing the lag would hide cannot reach the amplifier either
    (``raw_steps=False``: that bound left out)."""
    try:
        comp = model.compensator(dt)
    except (ValueError, TypeError, AttributeError):
        return False  # no compensator: nothing to chatter
    b = _input_lag_factor(model)
    for per, x in _test_references(dt, y, ranges):
        cmd = np.asarray(comp.command(x), dtype=np.float64)  # from the initial state
        if not np.all(np.isfinite(cmd)):
            return True
        if b > 0.0:
            # the raw command's steps: at most CHATTER_STEP times the reference's, scaled by the
            # mean gain (what the zoo's tests ask of a command); its turns: as the model's own
            # input lag passes it on to the stage
            if raw_steps and _raw_step_ratio(cmd[per:], x[per:]) > 1.0:
                return True
            cmd = first_order_lag(cmd, b)
        dx = np.diff(x[per:])
        flips_u = _turns(cmd[per:], CHATTER_TURN * max(float(np.ptp(cmd)), 1e-300))
        flips_x = int(np.count_nonzero(np.diff(np.sign(dx[np.abs(dx) > 0])) != 0))
        if flips_u > flips_x + 1:
            return True
    return False


def _quality_warnings(fit: FitResult, u: FloatArray, y: FloatArray, dt: float | None, best: _Candidate,
                      span: float, vsets: list[Any], n_fit: int, sc: _Scorer) -> list[str]:
    """Warnings about the chosen model (module docstring of :mod:`piezohyst.identify`)."""
    out = []
    pct = 100.0 * best.score / span if span > 0 else float("nan")
    if pct > 5.0:
        out.append(f"the hold-out error is {pct:.1f} % of the output's span: the model predicts new data "
                   f"poorly; a compensator built from it needs feedback")
    d = fit.delay
    w = sc.warmup.size
    pred = fit.model.predict(np.concatenate([sc.warmup, u]), dt)[w:] if w else fit.model.predict(u, dt)
    resid = y[d:] - pred[: pred.size - d] if d else y - pred
    uu = u[: u.size - d] if d else u
    du = np.diff(uu)
    rr = resid[1:]
    up, down = du > 0, du < 0
    if up.sum() > 20 and down.sum() > 20 and span > 0:
        diff = float(rr[up].mean() - rr[down].mean())
        sd = float(np.std(rr))
        if abs(diff) > max(0.01 * span, 0.5 * sd):
            out.append(f"the residual depends on the direction of motion (mean {diff:+.3g} between rising and "
                       f"falling input): the model misses part of the loop's shape")
    fast_pct, slow_pct = _residual_by_rate(du, rr, span)
    by_rate: dict[str, Any] = {"fastest_tenth_percent_of_span": fast_pct, "slower_half_percent_of_span": slow_pct,
                               "amplifier_may_not_follow": fast_pct > max(RATE_RESIDUAL_RATIO * slow_pct,
                                                                          RATE_RESIDUAL_PERCENT)}
    if by_rate["amplifier_may_not_follow"]:
        by_rate["warning"] = (
            f"the model misses where the input moves fastest: residual RMS {fast_pct:.2g} % of the span over the "
            f"fastest tenth of the record, {slow_pct:.2g} % over its slower half. An amplifier that cannot follow the "
            f"fastest commands (a slew-rate or current limit with the stack's capacitance)? Declare it (commission's "
            f"max_step_fraction: the largest step per sample as a fraction of the range) or identify on a slower "
            f"record")
        out.append(by_rate["warning"])
    fit.info["residual_by_rate"] = by_rate
    mode = structural_mode_search(fit, y[d:] if d else y, pred[: pred.size - d] if d else pred, dt)
    if mode is not None and mode["explained"] >= MODE_WARN_SHARE:
        out.append(f"what the model leaves rings at {mode['f_hz']:.4g} Hz: a lightly damped mode ({100 * mode['zeta']:.2g} % "
                   f"damping; {100 * mode['explained']:.0f} % of the residual) that no model kind here has, and the fitted "
                   "delay and lags bend towards it. commission() fits its model ahead of such a mode and inverts it "
                   "(CommissionedController.output_mode); a record that turns more gently rings it less")
    out += range_warnings(uu, y[d:] if d else y)
    turns, lo, hi, band = _input_reversals(uu)
    if not turns:
        out.append(f"the input never reverses (by more than {100 * END_BAND:g} % of its range): a record that only "
                   "rises or only falls shows no branch the other way, so the model's hysteresis (the width of its "
                   "loop) is a guess; identify on cycles up and down (a sinusoid, commissioning_excitation)")
    ends = len(turns) if len(turns) >= 2 and all(not lo + band < t < hi - band for t in turns) else 0
    if ends:  # major loops only
        out.append(f"the input reverses only at the ends of its range ({ends} reversals): loops inside it (partial "
                   f"strokes) are not identified and the model may follow them poorly; a record that also reverses "
                   f"at smaller amplitudes (a decaying sinusoid, commissioning_excitation) identifies them")
    loop = fit.largest_loop if fit.largest_loop is not None else 2.0 * largest_loop_threshold(uu)
    if turns and loop < SMALL_LOOPS * (hi - lo):
        out.append(f"the input's largest loop spans {loop:.4g} V of its {hi - lo:.4g} V range (it never travels further "
                   f"against its last direction): loops larger than that (a cycle over the whole range) are "
                   f"extrapolated, and the model may follow them poorly; a record with a cycle over the whole "
                   f"range (a decaying sinusoid, commissioning_excitation) identifies them")
    falls, reversals = _falling_after_reversal(uu, y[d:] if d else y, pred[: pred.size - d] if d else pred, span)
    if falls >= max(3, 0.1 * reversals):
        out.append(f"after {falls} input reversals the output keeps moving the old way where the model (with its "
                   f"delay and lags) turns: no monotone model represents that; the compensator cannot cancel it, "
                   f"feedback must")
    return out


#: The structural-mode search (:func:`structural_mode_search`) looks up to this fraction of the sample
#: rate (twice the widest band commissioning's learning may use) ...
MODE_SEARCH_TOP = 0.1
#: ... and a mode that explains at least this share of the residual is a fit warning.
MODE_WARN_SHARE = 0.1


def structural_mode_search(fit: FitResult, y: FloatArray, pred: FloatArray,
                           dt: float | None) -> dict[str, float] | None:
    """A lightly damped structural mode that the chosen model's prediction ``pred`` of ``y`` (paired
    as the fit pairs them) leaves out (:func:`~piezohyst.signals.lightly_damped_mode`), searched
    from twice the excitation's fastest frequency (``fit.info["search"]``) up to
    :data:`MODE_SEARCH_TOP` of the sample rate; kept as ``fit.info["structural_mode"]`` (None where
    none is found or the fit has no sample period)."""
    from ..signals import lightly_damped_mode

    f_hi = (fit.info.get("search") or {}).get("f_hi_hz")
    mode = None
    if dt is not None and f_hi and y.size == pred.size:
        mode = lightly_damped_mode(y, pred, dt, f_min=2.0 * float(f_hi), f_max=MODE_SEARCH_TOP / dt)
    fit.info["structural_mode"] = mode
    return mode


#: The rate warning (:func:`_quality_warnings`): the residual over the fastest tenth of the record
#: (by the input's step per sample) above this many times that over its slower half, and above
#: this percentage of the output's span. A stage behind an amplifier limited to 2000 V/s, fitted on
#: commissioning_excitation (up to 7850 V/s on 0-100 V), showed 3.6 times and 7.2 %; the
#: commissioning fits of the rig, the zoo and 12 probe stages of other structures 0.76-4.3 times
#: (the one above 3, a non-collocated stage, fitted to 0.04 % of the span overall).
RATE_RESIDUAL_RATIO = 3.0
RATE_RESIDUAL_PERCENT = 1.0


def _residual_by_rate(du: FloatArray, resid: FloatArray, span: float) -> tuple[float, float]:
    """The residual's RMS (% of ``span``) over the samples where the input moves fastest (its
    largest tenth of ``|du|``) and over its slower half; zeros where they cannot be told apart."""
    sp = np.abs(du)
    if sp.size < 200 or not span > 0:
        return 0.0, 0.0
    q90, q50 = np.quantile(sp, 0.9), np.quantile(sp, 0.5)
    if not q90 > q50:  # one rate throughout (a triangle wave): no fast part to speak of
        return 0.0, 0.0
    fast, slow = resid[sp >= q90], resid[sp <= q50]
    return (100.0 * float(np.sqrt(np.mean(fast**2))) / span, 100.0 * float(np.sqrt(np.mean(slow**2))) / span)


#: The small-loops warning (:func:`_quality_warnings`): the input's largest loop
#: (:func:`~piezohyst.models.play.largest_loop_threshold`, twice) below this share of its range.
SMALL_LOOPS = 0.9

#: Share of the input's range a turning point may lie from its end and still count as at the end
#: (the major-loops warning); also the dead band that tells a reversal from noise.
END_BAND = 0.05


def _input_reversals(u: FloatArray) -> tuple[list[float], float, float, float]:
    """The reversals of ``u`` (running extremes the input then leaves by more than
    :data:`END_BAND` of its range: noise and dither do not count), the range's ends and the band."""
    lo, hi = float(np.min(u)), float(np.max(u))
    band = END_BAND * (hi - lo)
    return u[turn_indices(u, band)].tolist(), lo, hi, band


def _falling_after_reversal(u: FloatArray, y: FloatArray, model: FloatArray, span: float) -> tuple[int, int]:
    """Reversals of u after which the data move against u by more than 1 % of the span (and the
    noise) while the model, delay and lags included, moves with it; and the number of reversals."""
    if span <= 0 or u.size < 10:
        return 0, 0
    du = np.diff(u)
    sgn = np.sign(du)
    nz = np.flatnonzero(sgn)
    if nz.size < 3:
        return 0, 0
    s = sgn[nz]
    rev = nz[1:][s[1:] != s[:-1]]
    noise = float(np.median(np.abs(np.diff(y, 2)))) * 3.0
    travel = 0.02 * float(np.ptp(u))
    count = 0
    for k in rev:
        direction = np.sign(du[k])
        j = k + 1
        while j < u.size and abs(u[j] - u[k]) < travel:
            j += 1
        if j >= u.size:
            break
        if (y[j] - y[k]) * direction < -max(0.01 * span, noise) and (model[j] - model[k]) * direction > 0:
            count += 1
    return count, int(rev.size)


def fit_summary_table(fit: FitResult) -> list[dict[str, Any]]:
    """The candidates of a :func:`fit_model` result, best first."""
    return sorted(fit.info.get("candidates", []), key=lambda c: c["holdout_rmse"])


__all__ = ["HOLDOUT", "MIN_GAIN", "SearchRanges", "excitation_band", "fit_model", "fit_summary_table",
           "search_ranges"]
