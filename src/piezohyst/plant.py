"""What a plant is: the protocols every closed loop, commissioning and identification run talks to,
and the safe layer between them and the stage.

A plant is the stage as the software sees it, real or simulated: commands in volts, measured
displacement in micrometres, one sample every ``dt`` seconds. There are two ways a stage is driven:

* :class:`Plant` - sample by sample, ``reset()`` and ``step(u) -> y``: a real-time loop (the
  :class:`~piezohyst.rig.VirtualRig`, a hardware adapter with a per-sample callback);
* :class:`BufferedPlant` - table by table, ``play(u) -> y``: a piezo controller's wave generator
  and data recorder, or buffered analog output and input on a DAQ card. The whole command table is
  applied, one value per ``dt``, and the record comes back; the stage's state carries over from
  one play to the next (there is no ``reset``).

The VirtualRig offers both. :func:`plant_mode` tells which one an object offers (a plant with both
is driven sample by sample, where feedback is possible). :func:`open_loop` runs an excitation on
either.

**The safe layer** (:class:`CommandLimits`, :class:`GuardedPlant`). Whatever a controller computes,
what reaches the stage passes through a guard that knows the amplifier's range and the largest
change of the command from one sample to the next. A command outside the range is clipped to it,
a change larger than the limit is cut to it, *before* ``step`` or ``play``; both are counted, so a
run can say how often the guard had to act (for the excitations and experiments of
:func:`~piezohyst.commission` it never has to: they are designed inside the limits). The limit is
relative to the range, ``max_step = max_step_fraction * (high - low)`` volts per sample (default
2 %: 2 V on a 0-100 V amplifier, 6 V on a +-150 V one); ramps (:meth:`GuardedPlant.ramp_to`)
take as many samples as that limit requires. At sample rates below 2 kHz the default
(:func:`default_step_fraction`) grows with the sample period, so that a full-range sinusoid of
:data:`STEP_LIMIT_SINE_HZ` still passes: at 500 Hz, 2 % per sample is 10 ranges per second, and
the guard slowed a 5 Hz tracking run over 80 % of the range (8.7 % e_max with the feedforward
alone, and with feedback the loop wound up against the slowed command until it oscillated
between the amplifier's limits).

**Missing measurements.** A sensor drops a sample now and then (an over-range reading, a lost
packet), and the plant then answers NaN or inf. A run rides through such dropouts: a loop holds
the last measurement (:class:`SensorDropouts`), an offline record (an identification run, a
played table) is bridged by linear interpolation (:func:`bridge_dropouts`); either is counted
(``sensor_dropouts`` in :meth:`GuardedPlant.counts`) and warned about once
(:class:`SensorDropoutWarning`). A gap longer than :data:`SENSOR_GAP_S` (and
:data:`SENSOR_GAP_MIN_SAMPLES`), or more than :data:`SENSOR_DROPOUT_SHARE` of the samples missing,
is a failing sensor: the run stops with a :class:`SensorDropoutError` that says where. Given the
most the stage moves in one sample (``max_jump``, which ``commission`` takes from its
identification run), a loop also holds a measurement that jumps further, for at most
:data:`GLITCH_HOLD_SAMPLES` samples (a sensor glitch: counted as ``sensor_glitches``).
"""

from __future__ import annotations

import math
import sys
import warnings
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from ._numba import njit
from ._validation import FloatArray, as_scalar, as_signal
from .data import Dataset
from .signals import interpolate_over

#: Default largest command change per sample, as a fraction of the amplifier's range.
MAX_STEP_FRACTION = 0.02
#: The fastest full-range sinusoid (Hz) the default step limit lets through at any sample rate.
STEP_LIMIT_SINE_HZ = 10.0


def default_step_fraction(dt: float) -> float:
    """The default step limit at sample period ``dt`` (s), as a fraction of the range:
    :data:`MAX_STEP_FRACTION`, or what a full-range sinusoid of :data:`STEP_LIMIT_SINE_HZ` changes
    by per sample (``pi f dt`` of the range) with a quarter to spare, whichever is larger (from
    2 kHz down: 3.9 % at 1 kHz, 7.9 % at 500 Hz).

    >>> default_step_fraction(1e-4), round(default_step_fraction(2e-3), 4)
    (0.02, 0.0785)
    """
    return min(1.0, max(MAX_STEP_FRACTION, 1.25 * math.pi * STEP_LIMIT_SINE_HZ * float(dt)))
#: Shortest ramp the safe layer plays, seconds (a ramp is never faster than this, whatever dt).
MIN_RAMP_S = 0.01


@runtime_checkable
class Plant(Protocol):
    """What ``track`` and ``commission`` need from a plant driven sample by sample.

    ``dt`` is the sample period in seconds; ``reset()`` brings the plant to rest; ``step(u)``
    applies the command ``u`` (volts) for one sample and returns the measured displacement (µm).
    An optional ``u_range = (low, high)`` tells the amplifier's range in volts.
    A hardware adapter that does these three things works everywhere a VirtualRig does.
    """

    dt: float

    def reset(self) -> None:
        """Bring the plant to rest (the start of a run)."""

    def step(self, u: float) -> float:
        """Apply the command ``u`` (V) for one sample; return the measured displacement (µm)."""


@runtime_checkable
class BufferedPlant(Protocol):
    """What ``track`` and ``commission`` need from a plant that plays command tables.

    ``dt`` is the table's sample period in seconds; ``play(u)`` applies the whole table ``u``
    (volts, one value per ``dt``) and returns the measured displacement (µm), one value per command,
    the same length. The plant's state carries over between plays: the first command of a table
    follows the last command of the previous one. An optional ``u_range = (low, high)`` tells the
    amplifier's range in volts.
    """

    dt: float

    def play(self, u: FloatArray) -> FloatArray:
        """Apply the command table ``u`` (V, one value per ``dt``); return the measured displacement (µm)."""
        ...


def plant_mode(plant: Any) -> str:
    """``"step"`` for a :class:`Plant` (also when it can play tables), ``"buffered"`` for a plant
    that only plays tables; a TypeError naming both protocols otherwise."""
    check_plant(plant)
    if callable(getattr(plant, "step", None)) and callable(getattr(plant, "reset", None)):
        return "step"
    return "buffered"


def check_plant(plant: Any) -> float:
    """The plant's ``dt``, or a TypeError that says what the Plant and BufferedPlant protocols need."""
    dt = getattr(plant, "dt", None)
    ok_dt = (not isinstance(dt, (bool, np.bool_)) and isinstance(dt, (int, float, np.integer, np.floating))
             and dt > 0 and np.isfinite(dt))
    stepper = callable(getattr(plant, "step", None)) and callable(getattr(plant, "reset", None))
    player = callable(getattr(plant, "play", None))
    if not ok_dt or not (stepper or player):
        why = "" if ok_dt else f" ({type(plant).__name__}.dt is {dt!r})"
        raise TypeError("plant must follow the Plant protocol (a positive float 'dt', reset() and step(u)) "
                        f"or the BufferedPlant protocol (a positive float 'dt' and play(u_table)){why}")
    return float(dt)  # type: ignore[arg-type]


def plant_u_range(plant: Any, u_range: Any = None) -> tuple[float, float] | None:
    """``u_range`` if given, else the plant's ``u_range`` attribute, checked; None if neither. A
    ``u_range`` given must lie within the plant's own: that is its amplifier's range (a wider one
    was sent to the plant as it was, -50..150 V to a 0..100 V plant: found by fuzzing)."""
    from .models.base import check_u_range

    own_given = getattr(plant, "u_range", None)
    own = check_u_range(own_given) if own_given is not None else None
    if u_range is None:
        return own
    rng = check_u_range(u_range)
    if own is not None and rng is not None and (rng[0] < own[0] or rng[1] > own[1]):
        raise ValueError(f"u_range={rng[0]:g}..{rng[1]:g} V goes beyond the plant's own u_range {own[0]:g}..{own[1]:g} V "
                         f"(its amplifier's range): give one within it")
    return rng


def measured(y: Any) -> float:
    """One answer of a plant's ``step`` as a float: a number, or the one value of a size-1 array
    or sequence (what a data-acquisition read of one sample often returns). Anything else is a
    TypeError that says what ``step`` returned."""
    if isinstance(y, (float, int, np.floating, np.integer)) and not isinstance(y, bool):
        return float(y)
    a = None
    if y is not None and not isinstance(y, (bool, np.bool_, str, bytes)):
        try:
            a = np.asarray(y, dtype=np.float64)
        except (TypeError, ValueError):
            a = None
    if a is None or a.size != 1:
        what = f"an array of shape {a.shape}" if a is not None else repr(y)[:60]
        raise TypeError(f"plant.step(u) must return the measured displacement as one number (µm); it "
                        f"returned {what} ({type(y).__name__})")
    return float(a.reshape(()))


#: The longest run of missing measurements (seconds) a run rides through; longer is a lost sensor.
SENSOR_GAP_S = 1e-3
#: ... but never fewer samples than this (at low sample rates).
SENSOR_GAP_MIN_SAMPLES = 2
#: The share of a run's samples that may be missing (past the first few); more is a failing sensor.
SENSOR_DROPOUT_SHARE = 0.01
#: Missing samples always allowed before the share counts (a run's first samples).
SENSOR_DROPOUT_ALLOWANCE = 10
#: A measurement that jumps further than a loop's ``max_jump`` in one sample is held for at most
#: this many samples (a glitch); one still there after them is a new level, taken.
GLITCH_HOLD_SAMPLES = 2
#: A measurement that stays at exactly one value while the command moves over at least this share
#: of the guarded range is a stuck (or saturated, or disconnected) sensor: no stage whose command
#: sweeps half its range stands still, and a sensor with noise never repeats a value exactly
#: (a coarse one does, but its count changes well within half the range). Found by a helper: a
#: sensor stuck mid-run gave a tracking "result" of 93.8 % e_max, the command at its limit for
#: 720 samples, with only a clipping warning; stuck during tuning, a verified gain.
STUCK_COMMAND_SHARE = 0.5
#: ... and it must stay so this long after the command got that far (s; at least
#: :data:`STUCK_MIN_SAMPLES`): a stage read late (a buffered acquisition, a slow link) shows the
#: old reading while the command moves on, for as long as it is late (found in the tests: a
#: noise-free stage read 150 samples late).
STUCK_AFTER_S = 0.25
STUCK_MIN_SAMPLES = 250


def _stuck_after(dt: float) -> int:
    return max(STUCK_MIN_SAMPLES, int(round(STUCK_AFTER_S / dt)))


class SensorDropoutError(RuntimeError):
    """The plant's measurements went missing (NaN or inf) for too long or too often to go on, or
    stayed at one value while the command swept half the range (a stuck sensor)."""


class SensorDropoutWarning(UserWarning):
    """The plant answered NaN or inf for some samples; they were held or bridged (module docstring)."""


def _max_gap(dt: float) -> int:
    return max(SENSOR_GAP_MIN_SAMPLES, int(round(SENSOR_GAP_S / dt)))


def _too_many(count: int, samples: int) -> bool:
    return count > max(SENSOR_DROPOUT_ALLOWANCE, SENSOR_DROPOUT_SHARE * samples)


class SensorDropouts:
    """Missing measurements of a per-sample run: each one is replaced by the last measurement
    (what a sample-and-hold gives a loop), counted, and warned about once; a gap longer than
    :data:`SENSOR_GAP_S` or too many of them raise :class:`SensorDropoutError`.

    >>> import warnings
    >>> d = SensorDropouts(1e-4, "the plant")
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore", SensorDropoutWarning)
    ...     d.take(1.0), d.take(float("nan")), d.take(2.0), d.count
    (1.0, 1.0, 2.0, 1)
    """

    def __init__(self, dt: float, who: str, max_jump: float | None = None, u_span: float | None = None):
        self.dt = float(dt)
        self.who = who
        # the stuck-sensor check (STUCK_COMMAND_SHARE), where the commands and their range are known
        self._stuck_over = STUCK_COMMAND_SHARE * u_span if u_span is not None and u_span > 0 else None
        self._stuck_wait = _stuck_after(self.dt)
        self.restart_stuck()
        self.max_gap = _max_gap(self.dt)
        self.max_jump = max_jump if max_jump is not None and max_jump > 0 and math.isfinite(max_jump) else None
        self.count = 0
        self.samples = 0
        self.first: int | None = None
        self.glitches = 0
        self._gap = 0
        self._jumped = 0
        self._held: float | None = None
        self._warned_glitch = False

    def hold(self, y: float) -> None:
        """The last valid measurement is ``y`` (taken outside :meth:`take`, e.g. from a played table)."""
        if math.isfinite(y):
            self._held = float(y)
            self._gap = 0

    def take(self, y: float, u: float | None = None) -> float:
        """The measurement to use for sample ``y`` (the plant's answer, already a float); ``u``
        the command it answered (for the stuck-sensor check, where the range was given)."""
        k = self.samples
        self.samples += 1
        if u is not None and self._stuck_over is not None:
            self._stuck(k, y, u)
        if math.isfinite(y):
            self._gap = 0
            if (self.max_jump is not None and self._held is not None and abs(y - self._held) > self.max_jump
                    and self._jumped < GLITCH_HOLD_SAMPLES):
                # a jump no stage makes in one sample: held while it lasts at most GLITCH_HOLD_SAMPLES
                # (a glitch); a new level that stays is taken (the stage did move)
                self._jumped += 1
                self.glitches += 1
                if not self._warned_glitch:
                    self._warned_glitch = True
                    warnings.warn(f"{self.who}'s measurement jumped by {y - self._held:.4g} um in one sample at "
                                  f"sample {k} (t = {k * self.dt:.6g} s of this run), more than the "
                                  f"{self.max_jump:.4g} um the stage moves in one: a sensor glitch? It is held at the "
                                  "last measurement; sensor_glitches in the run's safety counts says how many there "
                                  "were", SensorDropoutWarning, stacklevel=4)
                return self._held
            self._jumped = 0
            self._held = y
            return y
        self.count += 1
        self._gap += 1
        if self.first is None:
            self.first = k
            warnings.warn(f"{self.who} returned {y} instead of a measurement at sample {k} "
                          f"(t = {k * self.dt:.6g} s of this run): a sensor dropout? It is held at the last "
                          "measurement; sensor_dropouts in the run's safety counts says how many there were",
                          SensorDropoutWarning, stacklevel=4)
        if self._held is None:
            raise SensorDropoutError(f"{self.who} returned {y} instead of a measurement at sample {k}, before "
                                     "any valid one: check the sensor and its range")
        if self._gap > self.max_gap:
            raise SensorDropoutError(
                f"{self.who} returned no valid measurement (NaN or inf) for {self._gap} samples in a row, "
                f"from sample {k - self._gap + 1} (t = {(k - self._gap + 1) * self.dt:.6g} s of this run): more "
                f"than the {self.max_gap} samples ({SENSOR_GAP_S * 1e3:g} ms) a run rides through. Is the "
                "sensor connected and within its range? The run stopped")
        if _too_many(self.count, self.samples):
            raise SensorDropoutError(
                f"{self.who} returned no valid measurement at {self.count} of {self.samples} samples (first at "
                f"sample {self.first}): more than {SENSOR_DROPOUT_SHARE:.0%} missing is a failing sensor. The run "
                "stopped")
        return self._held

    def restart_stuck(self) -> None:
        """Forget the readings so far for the stuck-sensor check (the plant was reset)."""
        self._same: float | None = None
        self._same_since = 0
        self._same_lo = self._same_hi = 0.0
        self._armed: int | None = None

    def _stuck(self, k: int, y: float, u: float) -> None:
        """Raise :class:`SensorDropoutError` where ``y`` has stayed at one value while the commands
        since it first read so moved over :data:`STUCK_COMMAND_SHARE` of the range, and for
        :data:`STUCK_AFTER_S` since."""
        if y != self._same:  # (NaN never equals: a dropout is not a stuck reading)
            self._same, self._same_since, self._same_lo, self._same_hi, self._armed = y, k, u, u, None
            return
        self._same_lo, self._same_hi = min(self._same_lo, u), max(self._same_hi, u)
        assert self._stuck_over is not None
        if self._armed is None and self._same_hi - self._same_lo >= self._stuck_over:
            self._armed = k
        if self._armed is not None and k - self._armed >= self._stuck_wait:
            raise SensorDropoutError(
                f"{self.who}'s measurement has stayed at exactly {y:.6g} um since sample {self._same_since} "
                f"(t = {self._same_since * self.dt:.6g} s of this run), {k - self._same_since + 1} samples, while the "
                f"command moved over {self._same_lo:.4g}..{self._same_hi:.4g} V: a sensor stuck, saturated at the "
                "end of its range, or disconnected? The run stopped")


def stuck_reading(u: FloatArray, y: FloatArray, u_span: float, dt: float, who: str) -> None:
    """Raise :class:`SensorDropoutError` where a played record's measurement stays at exactly one
    value while its commands sweep :data:`STUCK_COMMAND_SHARE` of ``u_span`` (as
    :class:`SensorDropouts` does sample by sample; a stuck sensor in an identification run was
    taken for a slow amplifier and the run played again for 50 s: found by a helper)."""
    if y.size < 2 or not u_span > 0:
        return
    starts = np.concatenate([[0], np.flatnonzero(np.diff(y) != 0) + 1])
    if starts.size == 1:
        return  # one value throughout: a constant output, which the callers name as such
    ends = np.concatenate([starts[1:], [y.size]])
    hi = np.maximum.reduceat(u, starts)
    lo = np.minimum.reduceat(u, starts)
    top, bottom = float(np.max(y)), float(np.min(y))
    wait = _stuck_after(dt)
    for i in np.flatnonzero((hi - lo >= STUCK_COMMAND_SHARE * u_span) & (ends - starts > wait)):
        k0, k1 = int(starts[i]), int(ends[i])
        if y[k0] in (top, bottom):
            continue  # held at the record's end: a clipped sensor or a dead range, which fit and commission name
        seg = u[k0:k1]
        far = np.maximum.accumulate(seg) - np.minimum.accumulate(seg) >= STUCK_COMMAND_SHARE * u_span
        armed = int(np.argmax(far))
        if k1 - k0 - armed <= wait:
            continue  # still within the time a late reading takes to catch up
        raise SensorDropoutError(
            f"{who}'s measurement stayed at exactly {float(y[k0]):.6g} um over samples {k0}..{k1 - 1} (t = "
            f"{k0 * dt:.6g} s of this run on), while the command moved over {float(lo[i]):.4g}..{float(hi[i]):.4g} V: "
            "a sensor stuck, saturated at the end of its range, or disconnected? The run stopped")


def bridge_dropouts(y: FloatArray, dt: float, who: str) -> tuple[FloatArray, int]:
    """A recorded run with its missing samples (NaN or inf) filled by linear interpolation
    between their neighbours (the ends held), and how many there were; warned about once
    (:class:`SensorDropoutWarning`). A gap longer than :data:`SENSOR_GAP_S` or too many of them
    raise :class:`SensorDropoutError`."""
    bad = ~np.isfinite(y)
    count = int(bad.sum())
    if count == 0:
        return y, 0
    if count == y.size:
        raise SensorDropoutError(f"{who} returned no valid measurement at all ({y.size} samples of NaN or inf)")
    edges = np.diff(np.concatenate([[0], bad.view(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    longest = int(np.argmax(ends - starts))
    gap = int(ends[longest] - starts[longest])
    limit = _max_gap(dt)
    if gap > limit:
        raise SensorDropoutError(
            f"{who} returned no valid measurement (NaN or inf) for {gap} samples in a row, from sample "
            f"{int(starts[longest])} (t = {starts[longest] * dt:.6g} s of the run): more than the {limit} samples "
            f"({SENSOR_GAP_S * 1e3:g} ms) a run rides through. Is the sensor connected and within its range?")
    if _too_many(count, y.size):
        raise SensorDropoutError(
            f"{who} returned no valid measurement at {count} of {y.size} samples (first at sample "
            f"{int(starts[0])}): more than {SENSOR_DROPOUT_SHARE:.0%} missing is a failing sensor")
    warnings.warn(f"{who} returned NaN or inf instead of a measurement at {count} of {y.size} samples (first at "
                  f"sample {int(starts[0])}, t = {starts[0] * dt:.6g} s): sensor dropouts? They are bridged by "
                  "linear interpolation", SensorDropoutWarning, stacklevel=3)
    return interpolate_over(y, bad), count


def _recorded(plant: Any, u: FloatArray, mode: str, progress: list[int] | None = None) -> FloatArray:
    """The plant's answer to the table ``u`` as it came (dropouts not bridged): one ``play`` of it
    (``mode`` ``"buffered"``, checked for one value per command) or one ``step`` per command.
    ``progress`` (a one-element list), when given, holds the index of the command being sent: where
    a step that raised (an interrupt, a fault of the plant) left the table."""
    if mode == "buffered":
        got = plant.play(np.ascontiguousarray(u, dtype=np.float64))
        # as strictly as step()'s answers (found by fuzzing: None was "1 values", complex values lost
        # their imaginary part with only numpy's warning, an (n, 2) array was "2n values")
        what = f"the plant's play() ({type(plant).__name__})"
        if got is None or isinstance(got, (str, bytes)):
            raise TypeError(f"{what} returned {type(got).__name__}, not one measurement (um) per command")
        if np.iscomplexobj(got):
            raise TypeError(f"{what} returned complex values; a measurement is a real number (um)")
        try:
            arr = np.asarray(got, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise TypeError(f"{what} returned something that is not numbers ({exc})") from None
        if arr.ndim > 1 and arr.size != max(arr.shape):
            raise ValueError(f"{what} returned an array of shape {arr.shape}; one measurement per command, "
                             f"{u.size} of them, is needed")
        y = arr.ravel()
        if y.size != u.size:
            raise ValueError(f"{what} returned {y.size} values for a table of {u.size} commands")
        return y
    at = progress if progress is not None else [0]
    out = np.empty(u.size)
    for k, v in enumerate(u):
        at[0] = k
        out[k] = measured(plant.step(v))
    return out


def play_checked(plant: Any, u: FloatArray) -> FloatArray:
    """``plant.play(u)`` with its answer checked: one value per command, sensor dropouts
    bridged (:func:`bridge_dropouts`)."""
    return bridge_dropouts(_recorded(plant, u, "buffered"), float(plant.dt),
                           f"the plant's play() ({type(plant).__name__})")[0]


def checked_excitation(plant: Any, x: FloatArray) -> Dataset:
    """``plant.excite(x)``, which must return a :class:`Dataset` of ``x.size`` samples (an open-loop
    run from rest: the plant protocol's optional fast path)."""
    ds = plant.excite(x)
    if not isinstance(ds, Dataset) or len(ds) != x.size:
        what = f"a Dataset of {len(ds)} samples" if isinstance(ds, Dataset) else type(ds).__name__
        raise TypeError(f"{type(plant).__name__}.excite(u) must return a piezohyst Dataset of the run, one sample "
                        f"per command ({x.size}), got {what}; drop excite and piezohyst drives the plant with "
                        "reset() and step()")
    return ds


def open_loop(plant: Any, u: Any) -> Dataset:
    """An open-loop run of any plant: ``plant.excite(u)`` when it has one (compiled for the
    VirtualRig, from rest), else ``reset()`` and one ``step`` per sample, else one ``play`` of the
    whole table (from the buffered plant's present state). Commands beyond the range the plant
    states (``u_range``) are refused, not sent."""
    dt = check_plant(plant)
    x = as_signal("u", u)
    rng = plant_u_range(plant, None)
    if rng is not None:  # sent as given, so never beyond the range the plant states (found by fuzzing)
        outside = (x < rng[0]) | (x > rng[1])
        if outside.any():
            i = int(np.argmax(outside))
            raise ValueError(f"u[{i}] = {x[i]:.6g} V is outside the plant's u_range {rng[0]:g}..{rng[1]:g} V "
                             f"({int(outside.sum())} of {x.size} commands): open_loop sends the commands as given; "
                             "keep them inside the range (np.clip) or state the amplifier's range in u_range")
    if callable(getattr(plant, "excite", None)):
        # (the range was not checked for a plant with excite, -50..150 V reached a 0..100 V plant,
        # and whatever excite returned was passed on: found by fuzzing)
        return checked_excitation(plant, x)
    if plant_mode(plant) == "step":
        plant.reset()
        y = bridge_dropouts(_recorded(plant, x, "step"), dt, f"the plant's step() ({type(plant).__name__})")[0]
        how = "step"
    else:
        y = play_checked(plant, x)
        how = "play"
    return Dataset(np.arange(x.size, dtype=np.float64) * dt, x, y, {"source": type(plant).__name__, "driven_by": how})


# -- the safe layer ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class CommandLimits:
    """What the safe layer lets through to a stage.

    Parameters
    ----------
    low, high : float
        The amplifier's range, V.
    max_step : float
        Largest change of the command from one sample to the next, V.
    rest : float
        The command a stage at rest holds (0 V, or the nearest end of a range without 0).
    """

    low: float
    high: float
    max_step: float
    rest: float

    def __post_init__(self) -> None:
        lo = as_scalar("low", self.low)
        hi = as_scalar("high", self.high)
        if not lo < hi:
            raise ValueError(f"the command range must have low < high, got ({lo:g}, {hi:g})")
        step = as_scalar("max_step", self.max_step, positive=True)
        rest = as_scalar("rest", self.rest)
        if not lo <= rest <= hi:
            raise ValueError(f"the rest command {rest:g} V is outside the range {lo:g}..{hi:g} V")
        object.__setattr__(self, "low", lo)
        object.__setattr__(self, "high", hi)
        object.__setattr__(self, "max_step", step)
        object.__setattr__(self, "rest", rest)

    @classmethod
    def for_range(cls, u_range: Any, *, max_step_fraction: float = MAX_STEP_FRACTION,
                  rest: float | None = None) -> "CommandLimits":
        """Limits for the range ``(low, high)``: ``max_step = max_step_fraction * (high - low)``."""
        from .models.base import check_u_range

        rng = check_u_range(u_range)
        if rng is None:
            raise ValueError("u_range must be (low, high) in volts, got None")
        frac = as_scalar("max_step_fraction", max_step_fraction, positive=True)
        if frac > 1:
            raise ValueError(f"max_step_fraction is a fraction of the range (0 < f <= 1), got {frac}")
        lo, hi = rng
        r = min(max(0.0, lo), hi) if rest is None else as_scalar("u_rest", rest)
        return cls(lo, hi, frac * (hi - lo), r)

    @property
    def span(self) -> float:
        """The width of the range, ``high - low``, V."""
        return self.high - self.low

    def ramp_length(self, delta: float, dt: float, *, share: float = 0.5) -> int:
        """Samples of a raised-cosine ramp over ``delta`` volts whose largest step is ``share`` of
        ``max_step`` (and that lasts at least :data:`MIN_RAMP_S`)."""
        n = math.ceil(math.pi * abs(delta) / (2.0 * share * self.max_step))
        return max(n, int(math.ceil(MIN_RAMP_S / dt)), 2) if delta != 0 else 0

    def ramp(self, start: float, end: float, dt: float, *, share: float = 0.5) -> FloatArray:
        """A raised-cosine ramp from ``start`` (excluded) to ``end`` (included), V."""
        n = self.ramp_length(end - start, dt, share=share)
        if n == 0:
            return np.empty(0)
        k = np.arange(1, n + 1) / n
        return start + (end - start) * 0.5 * (1.0 - np.cos(np.pi * k))

    def to_dict(self) -> dict[str, float]:
        """The limits as plain data (V)."""
        return {"u_low_V": self.low, "u_high_V": self.high, "max_step_V": self.max_step,
                "max_step_fraction": self.max_step / self.span, "u_rest_V": self.rest}


@njit
def guard_step(x: float, low: float, high: float, max_step: float, tol: float,
               state: FloatArray) -> float:  # pragma: no cover - compiled
    """:meth:`GuardedPlant._guard` for one command, operation for operation: the command within
    the range, then within ``max_step`` of the last one sent; ``state`` is ``[last, clipped,
    slew_limited, largest_step, last_saturation, sent]``, updated but for ``sent``."""
    last = state[0]
    sat = 1.0 if x > high else (-1.0 if x < low else 0.0)
    v = min(max(x, low), high)
    if abs(v - x) > tol:
        state[1] += 1.0
    if abs(v - last) > max_step:
        v = min(max(v, last - max_step), last + max_step)
        state[2] += 1.0
    state[4] = sat
    state[3] = max(state[3], abs(v - last))
    state[0] = v
    return v


@njit
def _guard_table(x: FloatArray, low: float, high: float, max_step: float, tol: float,
                 state: FloatArray) -> FloatArray:  # pragma: no cover - compiled
    """:func:`guard_step` over a table (``state`` as there, ``sent`` counted too)."""
    out = np.empty(x.shape[0])
    for k in range(x.shape[0]):
        out[k] = guard_step(x[k], low, high, max_step, tol, state)
    state[5] += x.shape[0]
    return out


@njit
def rate_limited(x: FloatArray, max_step: float) -> FloatArray:  # pragma: no cover - compiled
    """``x`` as an amplifier that changes its output by at most ``max_step`` per sample (a slew
    rate, ``max_step / dt``: a current limit into the stack's capacitance) delivers it, from
    ``x[0]``.

    >>> rate_limited(np.array([0.0, 5.0, 5.0, 5.0, 0.0]), 2.0).tolist()
    [0.0, 2.0, 4.0, 5.0, 3.0]
    """
    out = np.empty(x.shape[0])
    if x.shape[0] == 0:
        return out
    v = x[0]
    for k in range(x.shape[0]):
        v += min(max(x[k] - v, -max_step), max_step)
        out[k] = v
    return out


class GuardedPlant:
    """A plant (either protocol) behind the safe layer (module docstring).

    It offers the protocol of the plant it wraps: ``step``/``reset`` for a :class:`Plant`,
    ``play`` for a :class:`BufferedPlant`. Every command is clipped to ``limits`` and its change
    from the previous command cut to ``limits.max_step`` before the plant sees it; ``clipped`` and
    ``slew_limited`` count what the guard changed (a command beyond the range by less than 1e-9 of
    it, a rounding at a bound, is clipped but not counted), ``sent`` every command,
    ``largest_step`` the largest change actually sent, ``last_saturation`` whether the last command
    asked for was above (+1) or below (-1) the range (for a loop's anti-windup).

    Parameters
    ----------
    plant : Plant or BufferedPlant
    limits : CommandLimits
    last : float, optional
        The command the plant holds now (default ``limits.rest``: a plant not driven yet).
    max_jump : float, optional
        The most (µm) the stage's measurement can change in one sample: a larger jump in a
        per-sample run is held as a glitch (:class:`SensorDropouts`). Default: no such check.
    """

    def __init__(self, plant: Any, limits: CommandLimits, *, last: float | None = None,
                 max_jump: float | None = None):
        self.dt = check_plant(plant)
        self.plant = plant
        self.mode = plant_mode(plant)
        self.limits = limits
        self.last = float(limits.rest if last is None else last)
        self.clipped = 0
        self.slew_limited = 0
        self.sent = 0
        self.largest_step = 0.0
        self.last_saturation = 0
        self._tol = 1e-9 * limits.span
        self.dropouts = SensorDropouts(self.dt, f"the plant ({type(plant).__name__})", max_jump, limits.span)
        self.bridged = 0  # missing samples filled in played records

    @property
    def u_range(self) -> tuple[float, float]:
        """The guarded range ``(low, high)``, V."""
        return (self.limits.low, self.limits.high)

    def reset(self) -> None:
        """Reset the plant (a :class:`Plant`): it is at rest, holding ``limits.rest``."""
        if self.mode != "step":
            raise TypeError("a plant that plays tables (BufferedPlant) cannot be reset; it keeps its state")
        self.plant.reset()
        self.last = self.limits.rest
        self.dropouts.restart_stuck()

    def _guard(self, u: float) -> float:
        x = float(u)
        if not math.isfinite(x):
            raise ValueError(f"the command must be finite, got {u!r}; not sent to the plant")
        lim = self.limits
        # clip to the range first: the previous command is inside it, so cutting the step towards
        # the clipped value keeps the result inside too
        sat = 1 if x > lim.high else (-1 if x < lim.low else 0)
        v = min(max(x, lim.low), lim.high)
        if abs(v - x) > self._tol:  # rounding at a bound (1e-9 of the range) is not counted
            self.clipped += 1
        if abs(v - self.last) > lim.max_step:
            v = min(max(v, self.last - lim.max_step), self.last + lim.max_step)
            self.slew_limited += 1
        self.last_saturation = sat
        self.largest_step = max(self.largest_step, abs(v - self.last))
        self.last = v
        self.sent += 1
        return v

    def guard_table(self, u: Any) -> FloatArray:
        """The table the guard would send for ``u`` (and its counts updated as if sent)."""
        x = as_signal("u", u)  # finite, so _guard would raise for none of it: compiled, the same
        g, state = self.kernel_arrays()
        out = _guard_table(x, g[0], g[1], g[2], g[3], state)
        self.set_kernel_state(state)
        return out

    def kernel_arrays(self) -> tuple[FloatArray, FloatArray]:
        """The guard as compiled kernels take it (:func:`guard_step`): ``[low, high, max_step,
        tol]`` and the state ``[last, clipped, slew_limited, largest_step, last_saturation, sent]``."""
        lim = self.limits
        return (np.array([lim.low, lim.high, lim.max_step, self._tol]),
                np.array([self.last, self.clipped, self.slew_limited, self.largest_step, self.last_saturation,
                          self.sent], dtype=np.float64))

    def set_kernel_state(self, state: FloatArray) -> None:
        """Take back the state of :meth:`kernel_arrays` after a kernel ran."""
        self.last, self.largest_step = float(state[0]), float(state[3])
        self.clipped, self.slew_limited = int(state[1]), int(state[2])
        self.last_saturation, self.sent = int(state[4]), int(state[5])

    def step(self, u: float) -> float:
        """Guard ``u`` and apply it for one sample (a :class:`Plant`); the measured µm."""
        if self.mode != "step":
            raise TypeError("this plant plays tables (BufferedPlant): it has no per-sample step")
        v = self._guard(u)
        return self.dropouts.take(measured(self.plant.step(v)), v)

    def play(self, u: Any) -> FloatArray:
        """Guard the table ``u`` and play it (either protocol: a Plant steps through it); missing
        measurements bridged (:func:`bridge_dropouts`)."""
        sent = self.guard_table(u)
        at = [0]
        try:
            raw = _recorded(self.plant, sent, self.mode, at)
        except BaseException:
            if self.mode == "step" and sent.size:
                # the table stopped part-way (an interrupt, a fault of the plant): the command in
                # flight is where the stage is (or one step short of it), not the table's end
                self.last = float(sent[at[0]])
            raise
        y, missing = bridge_dropouts(raw, self.dt, f"the plant ({type(self.plant).__name__})")
        self.bridged += missing
        stuck_reading(sent, y, self.limits.span, self.dt, f"the plant ({type(self.plant).__name__})")
        if y.size:
            self.dropouts.hold(float(y[-1]))
        return y

    def back_to_rest(self) -> None:
        """After a run stopped part-way (an interrupt, a fault of the plant): ramp the command back
        to the rest command, as every finished run ends, if the plant still takes commands. The
        error that stopped the run is the one reported; where the stage could not be brought to
        rest, a note on it says where it was left (found by a helper: a plant failing at every
        call, or a second Ctrl-C during the ramp, left the stage at 12-63 V without a word).

        A plant whose readings fail (``step`` returning None, a string) still takes commands: the
        ramp goes on without reading (its readings are not needed), so the stage comes to rest."""
        if self.mode != "step":
            return
        stopped = sys.exception()  # (called while the error that stopped the run propagates)
        start, rest = self.last, self.limits.rest
        why = ""
        try:
            try:
                self.ramp_to(rest)
                return
            except Exception:  # noqa: BLE001 - the ramp through the guard failed: on without reading
                pass
            for v in self.limits.ramp(self.last, rest, self.dt, share=0.5):
                try:
                    self.plant.step(float(v))
                except Exception as exc:  # noqa: BLE001 - the plant takes no more commands: it stays here
                    said = " ".join(str(exc).split())[:120]
                    why = f"the plant failed again ({type(exc).__name__}{': ' + said if said else ''})"
                    break
                self.last = float(v)
                self.sent += 1
        except Exception:
            raise
        except BaseException as again:  # a second Ctrl-C: stop here, and say where the stage is
            again.add_note(self._left_at(start, rest, "the ramp back to rest was interrupted"))
            raise
        if why:
            if stopped is None:  # called on its own: the failure is the error
                raise RuntimeError(self._left_at(start, rest, why))
            stopped.add_note(self._left_at(start, rest, why))

    def _left_at(self, start: float, rest: float, why: str) -> str:
        return (f"the stage was NOT brought back to rest: the ramp from {start:.4g} V to the rest command "
                f"{rest:.4g} V stopped at the command {self.last:.4g} V ({why}); the amplifier holds it, or the "
                f"command before it (within {self.limits.max_step:.3g} V)")

    def ramp_to(self, target: float, *, share: float = 0.5) -> FloatArray:
        """Move the command smoothly from where it is to ``target`` (clipped to the range): a
        raised-cosine ramp whose largest step is ``share`` of the limit. Returns the record."""
        end = min(max(float(target), self.limits.low), self.limits.high)
        table = self.limits.ramp(self.last, end, self.dt, share=share)
        return self.play(table) if table.size else np.empty(0)

    def counts(self) -> dict[str, Any]:
        """What the guard counted: commands sent, clipped to the range, slowed to the step limit, the largest step sent (V)."""
        return {"commands_sent": self.sent, "clipped": self.clipped, "slew_limited": self.slew_limited,
                "largest_step_V": self.largest_step, "sensor_dropouts": self.dropouts.count + self.bridged,
                "sensor_glitches": self.dropouts.glitches,
                **self.limits.to_dict()}


def check_table(u: Any, limits: CommandLimits, *, start: float | None = None) -> dict[str, float]:
    """How a command table sits against ``limits``: commands outside the range and the largest
    step (from ``start`` when given)."""
    x = as_signal("u", u)
    steps = np.abs(np.diff(x if start is None else np.concatenate([[start], x])))
    return {"outside": int(np.sum((x < limits.low) | (x > limits.high))),
            "largest_step_V": float(steps.max()) if steps.size else 0.0}
