"""Closed-loop tracking (the paper's Fig. 5) and its figures of merit (Tables I and II).

``track`` drives any object that follows the Plant protocol (``dt``, ``reset()``,
``step(u) -> y``) sample by sample (a plant that only plays tables, the BufferedPlant protocol,
gets the feedforward's command table in one play, and no feedback)::

    e_k   = r_k - y_{k-1}                  (the latest measurement before u_k is chosen)
    fb_k  = PID(e_k)                       (0 without feedback)
    u_k   = FF(r_k + fb_k)                 feedback_at="reference" (default)
          = FF(r_k) + fb_k                 feedback_at="command"
          = fb_k                           no feedforward
    y_k   = plant.step(u_k)

The figures of merit are those of the paper's tables: ``e_max`` (µm), ``e_max`` as a percentage
of the reference's span, and the RMSE (µm) of ``y - r``, computed over the whole cycles after
the first (the first is the start-up transient) when the reference repeats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from .._validation import FloatArray, as_scalar, as_signal
from ..signals import cycles_after_first, estimate_period
from ..plant import SensorDropouts, measured


class UnstableLoopError(RuntimeError):
    """The loop diverged: non-finite output, or output far outside any plausible range.

    ``reason`` is the short cause (without the controller settings), ``sample`` where it was seen.
    """

    def __init__(self, message: str, *, reason: str | None = None, sample: int | None = None):
        super().__init__(message)
        self.reason = reason or message
        self.sample = sample


def _check_period(period: Any, n: int) -> int | None:
    """``period`` (samples) as given to the metrics: None, or a whole number of samples with at
    least one whole cycle after the first (else the start-up would be scored)."""
    if period is None:
        return None
    if isinstance(period, (bool, np.bool_)) or not isinstance(period, (int, np.integer)):
        raise TypeError(f"period must be a whole number of samples or None, got {type(period).__name__}")
    p = int(period)
    if p < 1:
        raise ValueError(f"period must be >= 1 sample, got {p}")
    if n < 2 * p:
        raise ValueError(f"period={p} samples leaves no whole cycle after the first in {n} samples "
                         f"(the first cycle is the start-up and is not scored); give a longer reference")
    return p


class _Stepper(Protocol):
    def reset(self) -> None: ...

    def step(self, x: float) -> float: ...  # noqa: E704


@dataclass(frozen=True)
class Metrics:
    """e_max (µm), e_max % of span, RMSE (µm), over ``samples`` samples."""

    e_max: float
    e_max_percent: float
    rmse: float
    span: float
    samples: int

    @property
    def rmse_percent(self) -> float:
        return 100.0 * self.rmse / self.span if self.span > 0 else float("nan")


def tracking_metrics(reference: Any, output: Any, *, period: int | None = None) -> Metrics:
    """The paper's figures of merit of ``output - reference`` over the cycles after the first."""
    r = as_signal("reference", reference)
    y = as_signal("output", output)
    if r.size != y.size:
        raise ValueError(f"reference and output must have the same length, got {r.size} and {y.size}")
    period = _check_period(period, r.size)
    sl = cycles_after_first(r.size, period if period is not None else estimate_period(r))
    e = y[sl] - r[sl]
    span = float(np.ptp(r))
    e_max = float(np.max(np.abs(e)))
    return Metrics(e_max=e_max, e_max_percent=100.0 * e_max / span if span > 0 else float("nan"),
                   rmse=float(np.sqrt(np.mean(e**2))), span=span, samples=int(e.size))


@dataclass
class TrackingResult:
    """A tracking run: time series and the paper's figures of merit.

    Attributes
    ----------
    t, reference, output, command, error : ndarray
        Time (s), desired displacement (µm), measured displacement (µm), command (V) and
        ``output - reference`` (µm).
    e_max, e_max_percent, rmse : float
        Over the whole cycles after the first (see :func:`tracking_metrics`).
    period : int or None
        The reference's period in samples, if it repeats.
    clipped : int or None
        Commands the plant clipped (if it reports it).
    """

    t: FloatArray
    reference: FloatArray
    output: FloatArray
    command: FloatArray
    period: int | None
    clipped: int | None = None
    label: str = ""
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.metrics = tracking_metrics(self.reference, self.output, period=self.period)

    @property
    def error(self) -> FloatArray:
        """``output - reference``, µm, every sample."""
        return self.output - self.reference

    @property
    def e_max(self) -> float:
        """The largest absolute error over the scored samples, µm."""
        return self.metrics.e_max

    @property
    def e_max_percent(self) -> float:
        """``e_max`` as a percentage of the reference's span."""
        return self.metrics.e_max_percent

    @property
    def rmse(self) -> float:
        """The RMS error over the scored samples, µm."""
        return self.metrics.rmse

    @property
    def rmse_percent(self) -> float:
        """``rmse`` as a percentage of the reference's span."""
        return self.metrics.rmse_percent

    def summary(self) -> dict[str, Any]:
        """The figures of merit and the run's settings as plain data (JSON-ready)."""
        return {"label": self.label, "e_max_um": self.e_max, "e_max_percent": self.e_max_percent,
                "rmse_um": self.rmse, "rmse_percent": self.rmse_percent, "span_um": self.metrics.span,
                "evaluated_samples": self.metrics.samples, "clipped_samples": self.clipped, **{
                    k: v for k, v in self.info.items() if isinstance(v, (int, float, str, bool)) or v is None}}

    def __repr__(self) -> str:
        """One line: the figures of merit (the dataclass's repr printed every array)."""
        m = self.metrics
        return (f"TrackingResult({(self.label + ', ') if self.label else ''}{int(self.reference.size)} samples, "
                f"e_max {m.e_max:.4g} um ({m.e_max_percent:.3g} % of span), rmse {m.rmse:.4g} um"
                + (f", {self.clipped} commands clipped" if self.clipped else "") + ")")

    def plot(self, axes: Any = None, title: str | None = None, *, u_range: Any = None, ax: Any = None) -> Any:
        """The run as a figure (cf. the paper's Figs. 6-9): desired and measured displacement,
        the error on the scale of the scored window (shaded), the command, and measured against
        desired (:func:`piezohyst.plots.plot_tracking`).

        Parameters
        ----------
        axes : sequence of Axes, optional
            As for :func:`~piezohyst.plots.plot_tracking`; a new figure when omitted.
        title : str, optional
            Default: the run's label and its figures of merit.
        u_range : (low, high), optional
            The actuator's range (V) to draw on the command panel.
        ax : Axes or sequence of Axes, optional
            Another name for ``axes`` (as :func:`~piezohyst.plots.plot_loops` calls it).

        Returns
        -------
        matplotlib.figure.Figure
            Shown once when it is a Jupyter cell's value; ``fig.savefig(...)`` saves it.
        """
        from ..plots import figure_result, plot_tracking

        if ax is not None:  # (out.plot(ax=ax) was a TypeError: found by a helper)
            if axes is not None:
                raise TypeError("give axes= or ax=, not both")
            axes = ax

        period = self.period if self.period is not None else estimate_period(self.reference)
        scored = cycles_after_first(self.reference.size, period)
        m = self.metrics
        head = title or (f"{self.label + ': ' if self.label else ''}e_max {m.e_max * 1e3:.3g} nm "
                         f"({m.e_max_percent:.2f} % of span), RMSE {m.rmse * 1e3:.3g} nm")
        arts = plot_tracking(self.t, self.reference, self.output, command=self.command, scored=scored,
                             u_range=u_range, axes=axes, title=head)
        fig = arts[0].axes.figure
        return figure_result(fig) if axes is None else fig

    def _repr_html_(self) -> str:
        """An HTML summary for Jupyter: the figures of merit and the window they are taken on."""
        from .. import _html

        m = self.metrics
        n = self.reference.size
        period = self.period if self.period is not None else estimate_period(self.reference)
        sl = cycles_after_first(n, period)
        window = (f"samples {sl.start}..{sl.stop - 1} of {n} (the whole cycles after the first)"
                  if sl.stop - sl.start < n else f"all {n} samples")
        dt = float(self.t[1] - self.t[0]) if n > 1 else float("nan")
        rows: list[tuple[str, Any]] = [
            ("e_max", f"{m.e_max:.4g} µm ({m.e_max_percent:.3g} % of span)"),
            ("RMSE", f"{m.rmse:.4g} µm ({m.rmse_percent:.3g} % of span)"),
            ("reference span", f"{m.span:.4g} µm"),
            ("scored", window),
            ("period", f"{period} samples ({period * dt:.4g} s)" if period else "does not repeat"),
            ("duration", f"{n * dt:.4g} s at {1 / dt:.5g} Hz" if n > 1 else "-"),
            ("clipped commands", self.clipped),
        ]
        rows += [(k.replace("_", " "), v) for k, v in self.info.items()
                 if isinstance(v, (int, float, str, bool)) and not isinstance(v, type)]
        return _html.block(f"TrackingResult{': ' + self.label if self.label else ''}", _html.table(rows))


class LoopWatch:
    """The checks that stop a closed-loop run that has gone unstable, shared by every loop.

    * the output is not finite, or ``|y - r|`` exceeds ``limit``;
    * with feedback on and the plant's ``u_range`` known: ten or more commands below *and* ten
      or more above the range within 200 samples (an unstable loop on a saturating amplifier does
      not diverge, it oscillates between the limits);
    * with feedback on, after the first fifth of the run: the error's RMS over 500 samples
      exceeds the reference's span (the loop is not following at all), or, where the sensor's
      noise RMS ``noise`` (µm) is known, :data:`FOLLOW_NOISE_FACTOR` times it if that is more: a
      reference that holds a position (a span below the noise) is followed when the error is the
      sensor's noise (the span alone stopped such a hold, followed to the noise, as unstable).

    ``describe()`` names the controller settings in the error message.
    """

    WINDOW = 500
    CHATTER = 200
    #: The window's error RMS, in sensor-noise RMS, below which a loop counts as following.
    FOLLOW_NOISE_FACTOR = 5.0

    def __init__(self, r: FloatArray, *, u_range: Any, feedback_on: bool, limit: float, dt: float,
                 describe: Any, noise: float | None = None):
        self.r = r
        self.dt = dt
        self.limit = limit
        self.describe = describe
        self.span = float(np.ptp(r))
        self.noise = float(noise) if noise is not None and math.isfinite(noise) and noise > 0 else None
        #: the window check's threshold (µm): the span, or FOLLOW_NOISE_FACTOR noise RMS if more
        self.follow_rms = max(self.span, self.FOLLOW_NOISE_FACTOR * self.noise if self.noise else 0.0)
        self.settle = max(r.size // 5, self.WINDOW)
        self.watch_window = feedback_on and self.follow_rms > 0 and r.size >= 2 * self.settle
        self.lo_u, self.hi_u = (float(u_range[0]), float(u_range[1])) if u_range is not None else (-math.inf, math.inf)
        self.watch_chatter = feedback_on and u_range is not None
        self.n_lo = self.n_hi = 0
        #: the run's commands so far (the caller's array, filled as it goes), for the advice of a stop
        self.commands: FloatArray | None = None
        #: the run's outputs so far (likewise) and the feedback's gains (kp, ki, kd), for the same
        self.outputs: FloatArray | None = None
        self.gains: tuple[float, float, float] | None = None

    def advice(self, k: int, y: FloatArray | None) -> str:
        """What to do about a loop that stopped at sample k: lower the gains, unless the run shows
        another cause (it said "lower the feedback gains" for an inverted sensor and for negative
        gains: found by fuzzing)."""
        if self.gains is not None and any(g < 0 for g in self.gains):
            return "a negative gain is positive feedback on a stage that rises with its command: give gains >= 0"
        if self.commands is not None and y is not None and k >= 20:
            still = output_still(y[: k], self.commands[: k])
            if still:
                return (f"the output did not move {still}: a dead sensor, an amplifier off, or commands held beyond "
                        "the range's end (a sensor that reads the other way round drives them there); not the gains")
        return "lower the feedback gains"

    def command(self, k: int, uk: float) -> int:
        """Check command k; return +1/-1 when it is above/below the actuator's range, else 0."""
        sat = 1 if uk > self.hi_u else (-1 if uk < self.lo_u else 0)
        if self.watch_chatter:
            if sat > 0:
                self.n_hi += 1
            elif sat < 0:
                self.n_lo += 1
            if k % self.CHATTER == self.CHATTER - 1:
                if self.n_hi >= 10 and self.n_lo >= 10:
                    reason = (f"the loop oscillates between the amplifier's limits ({self.n_lo} commands below "
                              f"{self.lo_u:g} V and {self.n_hi} above {self.hi_u:g} V within samples "
                              f"{k - self.CHATTER + 1}..{k})")
                    raise UnstableLoopError(f"{reason} with {self.describe()}; {self.advice(k, self.outputs)}",
                                            reason=reason, sample=k)
                self.n_lo = self.n_hi = 0
        return sat

    def output(self, k: int, yk: float, y: FloatArray) -> None:
        """Check output k (``y[:k+1]`` holds the outputs so far, ``y[k] == yk``)."""
        rk = self.r[k]
        if not math.isfinite(yk) or abs(yk - rk) > self.limit:
            reason = (f"the loop went unstable at sample {k} (t = {k * self.dt:.4g} s): output {yk!r} um against "
                      f"reference {rk:.4g} um")
            raise UnstableLoopError(f"{reason}, with {self.describe()}; {self.advice(k, y)}",
                                    reason=reason, sample=k)
        w = self.WINDOW
        if self.watch_window and k >= self.settle and k % w == w - 1:
            ew = y[k - w + 1: k + 1] - self.r[k - w + 1: k + 1]
            rms = float(np.sqrt(np.mean(ew * ew)))
            if rms > self.follow_rms:
                scale = (f"the reference's whole span ({self.span:.4g} um)" if self.follow_rms == self.span else
                         f"{self.FOLLOW_NOISE_FACTOR:g} times the sensor's noise RMS ({self.follow_rms:.4g} um; "
                         f"the reference spans {self.span:.4g} um)")
                reason = (f"the loop stopped following: the error's RMS over samples {k - w + 1}..{k} "
                          f"is {rms:.4g} um, more than {scale}")
                raise UnstableLoopError(f"{reason}, with {self.describe()}; {self.advice(k, y)}",
                                        reason=reason, sample=k)


def _describe(feedforward: Any, feedback: Any, feedback_at: str) -> str:
    parts = [f"feedforward={feedforward!r}" if feedforward is not None else "no feedforward"]
    if feedback is not None:
        s = feedback.settings() if hasattr(feedback, "settings") else repr(feedback)
        parts.append(f"feedback={s} at the {feedback_at}")
    return ", ".join(parts)


def lead_in(feedforward: Any, y_from: float, y_to: float, limits: Any, dt: float, *,
            share: float = 0.5, before: FloatArray | None = None,
            min_seconds: float = 0.01, max_samples: int = 2**22) -> tuple[FloatArray, FloatArray]:
    """A desired trajectory from ``y_from`` to ``y_to`` µm (raised cosine, both ends included) whose
    commands, from the feedforward's initial state, change by at most ``share * limits.max_step``
    per sample (within the range). Returns (desired µm, commands V); the caller ramps the command
    from where the plant holds it to the first of them.

    ``before`` (µm, ending at ``y_from``) is a desired trajectory the ramp follows, such as a
    conditioning sweep: it is returned in front of the ramp, and the commands are computed over
    both, the ramp's from the state the sweep leaves. The ramp lasts at least ``min_seconds``.

    The ramp's length starts at the safe layer's shortest ramp and doubles until the commands,
    computed offline with ``feedforward.command``, are that smooth (the inverse of an input lag is
    a lead: a fast ramp in displacement asks for a much faster one in volts), until
    :data:`LEAD_IN_STUCK_DOUBLINGS` doublings in a row leave the largest step as it was (a step the
    ramp's speed does not make: where the commands at the end of ``before`` were clipped to the
    range, the first of the ramp's steps back into it is the same whatever its length, and the
    ramp doubled to 5 million samples, 80 s of a stage driven sample by sample, on every run; a
    backlash's gap, crossed at the ramp's start, shrinks unevenly but shrinks), or until it passes
    ``max_samples`` (the commands are then returned as they are; the safe layer limits their steps).
    """
    n = max(int(math.ceil(min_seconds / dt)), 2)
    head = np.empty(0) if before is None else np.asarray(before, dtype=np.float64)[:-1]
    largest, stuck = math.inf, 0
    while True:
        k = np.arange(1, n + 1) / n
        desired = y_from + (y_to - y_from) * 0.5 * (1.0 - np.cos(np.pi * k))
        desired = np.concatenate([head, [y_from], desired])
        cmd = feedforward.command(desired)
        ramp = cmd[head.size:]
        if _smooth_enough(ramp, limits, share) or n > max_samples:
            return desired, cmd
        step = _largest_step(ramp, limits)
        stuck = stuck + 1 if step >= LEAD_IN_SAME_STEP * largest else 0
        if stuck >= LEAD_IN_STUCK_DOUBLINGS:
            return desired, cmd
        largest = step
        n *= 2


#: :func:`lead_in` stops doubling its ramp after this many doublings in a row each left the
#: largest step at least :data:`LEAD_IN_SAME_STEP` of the one before (a smooth ramp's steps halve).
LEAD_IN_STUCK_DOUBLINGS = 3
LEAD_IN_SAME_STEP = 0.99


def _largest_step(cmd: FloatArray, limits: Any) -> float:
    """The largest change per sample of commands clipped to the range (0 for fewer than two)."""
    steps = np.abs(np.diff(np.clip(cmd, limits.low, limits.high)))
    return float(steps.max()) if steps.size else 0.0


def _smooth_enough(cmd: FloatArray, limits: Any, share: float) -> bool:
    """Whether commands (clipped to the range) change by at most ``share * limits.max_step`` per sample."""
    return _largest_step(cmd, limits) <= share * limits.max_step


#: The longest lead-in from rest (:func:`lead_in_from_rest`) tried straight from the model's
#: settled rest output, seconds.
LEAD_IN_MAX_S = 10.0


def lead_in_from_rest(feedforward: Any, model: Any, y_to: float, limits: Any, dt: float,
                      *, share: float = 0.5) -> tuple[FloatArray, FloatArray]:
    """:func:`lead_in` from the model's output at the rest command to ``y_to``.

    The model's initial state is the de-energised one at 0 V. Where the stage rests elsewhere (a
    range that excludes 0 V) a model with lags starts off their equilibrium, and the inverse, asked
    for the rest output from that state at once, jumps (-15.8 then -6.6 V on a stage resting at
    -10 V): no ramp is then smooth enough, and the ramp doubled to 6.5 million samples. When the
    straight ramp is not smooth within :data:`LEAD_IN_MAX_S`, the lead-in follows the model's own
    output along the rest command first (:func:`lead_in_after`), which the inverse maps back to the
    rest command exactly, then rises."""
    y_rest = float(np.asarray(model.predict(np.full(2, limits.rest), dt if model.dynamic else None))[-1])
    desired, cmd = lead_in(feedforward, y_rest, y_to, limits, dt, share=share,
                           max_samples=max(int(LEAD_IN_MAX_S / dt), 2))
    if _smooth_enough(cmd, limits, share):
        return desired, cmd
    return lead_in_after(feedforward, model, np.full(2, limits.rest), y_to, limits, dt, rise_s=0.01)


def lead_in_after(feedforward: Any, model: Any, sweep: Any, y_to: float, limits: Any, dt: float, *,
                  rise_s: float) -> tuple[FloatArray, FloatArray]:
    """:func:`lead_in` after a conditioning sweep (``sweep``, V, from the model's initial state):
    the desired trajectory is the model's output along the sweep, which the feedforward then
    follows back to those commands, and a rise of at least ``rise_s`` seconds to ``y_to``."""
    ys = np.asarray(model.predict(np.asarray(sweep, dtype=np.float64), dt if model.dynamic else None), dtype=np.float64)
    return lead_in(feedforward, float(ys[-1]), y_to, limits, dt, before=ys, min_seconds=rise_s)


def _check_controllers(feedforward: Any, feedback: Any) -> None:
    """A clear TypeError for what is not a feedforward (a compensator: ``reset`` and ``step``)
    or a feedback controller (``reset``, ``step`` and ``dt``, as :class:`~piezohyst.PID`); a
    model passed where its compensator belongs says so (an AttributeError on ``reset`` before)."""
    if feedforward is not None and not (hasattr(feedforward, "reset") and hasattr(feedforward, "step")) and not (
            hasattr(feedforward, "command") and not hasattr(feedforward, "compensator")):
        hint = (" (that is a model: pass its feedforward, model.compensator(...))"
                if hasattr(feedforward, "compensator") else "")
        raise TypeError(f"feedforward must be a compensator with reset() and step(), such as "
                        f"model.compensator(...), or None; got {type(feedforward).__name__}{hint}")
    if feedback is not None and not all(hasattr(feedback, a) for a in ("reset", "step", "dt")):
        raise TypeError(f"feedback must be a controller with reset(), step() and dt, such as "
                        f"piezohyst.PID(kp, ki, kd, dt), or None; got {type(feedback).__name__}")


def track(
    plant: Any, reference: Any, feedforward: _Stepper | None = None, feedback: Any = None, *,
    feedback_at: str = "reference", period: int | None = None, reset: bool = True,
    divergence_limit: float | None = None, label: str = "",
) -> TrackingResult:
    """Make ``plant`` follow ``reference`` with feedforward and/or PID feedback (paper Fig. 5).

    Parameters
    ----------
    plant : Plant or BufferedPlant
        Anything with ``dt``, ``reset()`` and ``step(u) -> y`` (V in, µm out); or a plant that
        only plays tables (``dt``, ``play(u) -> y``): then the feedforward's command table for the
        whole reference is played once, from the plant's present state, and there is no feedback
        (no per-sample loop exists; asking for it is an error).
    reference : array_like
        Desired displacement, µm, one sample per ``plant.dt``.
    feedforward : InversePIFeedforward or BoucWenFeedforward, optional
    feedback : PID, optional
        Its ``dt`` must equal the plant's.
    feedback_at : {"reference", "command"}
        Where the PID's output enters (see :mod:`piezohyst.control.pid`).
    period : int, optional
        The reference's period in samples (estimated when omitted). Given, it must leave at
        least one whole cycle after the first (the start-up, which is not scored).
    divergence_limit : float, optional
        Stop with :class:`UnstableLoopError` when |y - r| exceeds this (µm); default ten times
        the reference's span plus 10 µm. With feedback on, the run also stops when, after the
        first fifth of it, the error's RMS over 500 samples exceeds the reference's span: an
        unstable loop on a saturating amplifier does not diverge, it oscillates between the
        limits.

    Notes
    -----
    A plant may also tell its actuator's limits as ``u_range = (low, high)`` volts (VirtualRig
    does); the PID then stops integrating in the direction of a clipped command (anti-windup
    on the real saturation, wherever the PID's output enters), and no command beyond it is sent:
    a plant that does not clip and count (``clipped``) itself gets the command clipped here, and
    ``clipped`` counts those. This is the paper's loop (Fig. 5) as it is: no limit on the
    command's step, no ramp from rest; :func:`~piezohyst.commission` and its controller's
    ``track`` add the safe layer (step limit, lead-in, back to rest after a fault) for a stage.

    Returns
    -------
    TrackingResult
        ``info["mode"]`` says how the plant was driven (``"step"`` or ``"buffered"``).
    """
    from ..plant import check_plant, plant_mode, plant_u_range, play_checked

    r = as_signal("reference", reference, min_length=2)
    period = _check_period(period, r.size)
    if divergence_limit is not None:
        divergence_limit = as_scalar("divergence_limit", divergence_limit, positive=True)
    dt = check_plant(plant)
    try:
        rng = plant_u_range(plant)
    except ValueError as exc:  # ("0,100" failed on float(',') deep inside: found by fuzzing)
        raise ValueError(f"the plant's u_range ({type(plant).__name__}.u_range): {exc}") from None
    # a plant that states its range but does not clip to it itself (the VirtualRig does, and counts
    # what it clipped): the commands are clipped here, never sent beyond it (-39..161 V, and 4e6 V
    # from a large gain, reached a 0..100 V plant: found by fuzzing)
    clip_here = rng is not None and getattr(plant, "clipped", None) is None
    if feedback_at not in ("reference", "command"):
        raise ValueError(f"feedback_at must be 'reference' or 'command', got {feedback_at!r}")
    _check_controllers(feedforward, feedback)
    if plant_mode(plant) == "buffered":
        if feedback is not None:
            raise ValueError("this plant only plays tables (BufferedPlant): there is no per-sample loop to "
                             "close, so no feedback; track with feedforward alone, or commission() it and "
                             "use learning across plays")
        if feedforward is None:
            raise ValueError("a plant that plays tables needs a feedforward to compute its command table")
        u = feedforward.command(r) if hasattr(feedforward, "command") else _stream(feedforward, r)
        n_clip = None
        if clip_here:
            assert rng is not None
            n_clip = int(np.sum((u < rng[0]) | (u > rng[1])))
            u = np.clip(u, rng[0], rng[1])
        y = play_checked(plant, u)
        _check_the_output_moved(y, u, plant)
        return TrackingResult(t=np.arange(r.size, dtype=np.float64) * dt, reference=r, output=y, command=u,
                              period=period if period is not None else estimate_period(r), clipped=n_clip,
                              label=label, info={"mode": "buffered", "feedback_at": None, "feedback": False})
    if feedback is not None:
        fdt = getattr(feedback, "dt", None)
        # (a plant's float32 dt, 0.0010000000474974513, was refused against 1e-3: found by fuzzing)
        if fdt is None or not math.isclose(float(fdt), float(dt), rel_tol=1e-6):
            raise ValueError(f"the feedback controller's dt ({fdt}) does not match the plant's dt ({dt})")
        feedback.reset()
    if feedforward is not None:
        feedforward.reset()
    if reset:
        plant.reset()
    clipped0 = getattr(plant, "clipped", None)
    limit = divergence_limit if divergence_limit is not None else 10.0 * float(np.ptp(r)) + 10.0
    n = r.size
    y = np.empty(n)
    u = np.empty(n)
    y_prev = 0.0  # the plant starts at rest
    # the plant's actuator limits, if it tells them, drive the PID's anti-windup
    watch = LoopWatch(r, u_range=rng, feedback_on=feedback is not None,
                      limit=limit, dt=dt, describe=lambda: _describe(feedforward, feedback, feedback_at))
    watch.commands, watch.outputs = u, y
    if feedback is not None:
        watch.gains = tuple(float(getattr(feedback, g, 0.0)) for g in ("kp", "ki", "kd"))  # type: ignore[assignment]
    sat = 0
    at_ref = feedback_at == "reference"
    compiled = False
    if reset:  # the whole loop in one compiled call when every part has a kernel (compiled_loop)
        from .compiled_loop import has_kernels, run_compiled

        if has_kernels(plant, feedforward, feedback):
            done = run_compiled(plant, r, feedforward, feedback, at_ref=at_ref, watch=watch)
            compiled = done is not None
            if compiled:
                y, u = done  # type: ignore[misc]
            else:  # it gave up where a check stops the run: the Python loop, from the start, says why
                for part in (feedback, feedforward, plant):
                    if part is not None:
                        part.reset()
    ff_step = feedforward.step if feedforward is not None else None
    fb_step = feedback.step if feedback is not None else None
    pstep = plant.step
    dropouts = SensorDropouts(dt, f"the plant ({type(plant).__name__})",
                              u_span=(rng[1] - rng[0]) if rng is not None else None)
    lo_u, hi_u = rng if (clip_here and rng is not None) else (-math.inf, math.inf)
    rng_lo, rng_hi = rng if rng is not None else (-math.inf, math.inf)
    n_clip = 0
    for k in range(0 if not compiled else n, n):
        rk = r[k]
        fb = fb_step(rk - y_prev, sat) if fb_step is not None else 0.0
        if ff_step is None:
            uk = fb
        elif at_ref:
            uk = ff_step(rk + fb)
        else:
            uk = ff_step(rk) + fb
        sat = watch.command(k, uk)
        sent = lo_u if uk < lo_u else hi_u if uk > hi_u else uk
        n_clip += sent != uk
        # (the stuck-sensor check takes the command the stage can follow: a plant that clips
        # itself holds its end however far beyond it a diverging loop's commands go)
        yk = dropouts.take(measured(pstep(sent)), min(max(sent, rng_lo), rng_hi))
        u[k] = uk
        y[k] = yk
        watch.output(k, yk, y)
        y_prev = yk
    _check_the_output_moved(y, u, plant)
    clipped = n_clip if clip_here else None
    if clipped0 is not None:
        clipped = int(plant.clipped) - (0 if reset else int(clipped0))
    return TrackingResult(t=np.arange(n, dtype=np.float64) * dt, reference=r, output=y, command=u,
                          period=period if period is not None else estimate_period(r),
                          clipped=clipped, label=label,
                          info={"mode": "step", "feedback_at": feedback_at if feedback is not None else None,
                                "feedback": feedback is not None, "sensor_dropouts": dropouts.count})


def output_still(y: FloatArray, u: FloatArray) -> str | None:
    """Where the output ``y`` read one value throughout (a real sensor's noise moves it), what it
    read and what the command ``u`` did meanwhile: ``"(it read 3 um throughout) while the command
    went 0..100 V"``; None where it moved."""
    if y.size < 1 or float(np.ptp(y)) > 0.0:
        return None
    went = (f"went {float(np.min(u)):.4g}..{float(np.max(u)):.4g} V" if u.size and float(np.ptp(u)) > 0.0 else
            f"stayed at {float(u[0]):.4g} V" if u.size else "was sent")
    return f"(it read {float(y[0]):.6g} um throughout) while the command {went}"


def _check_the_output_moved(y: FloatArray, u: FloatArray, plant: Any) -> None:
    """Refuse a run whose output read one value throughout while the command moved: a dead sensor
    or an amplifier switched off (with integral feedback the command ran to the range's end and the
    run returned as if it had tracked: found by fuzzing)."""
    still = output_still(y, u) if y.size >= 2 and float(np.ptp(u)) > 0.0 else None
    if still:
        raise ValueError(f"the plant's output did not move over the run {still}: is {type(plant).__name__}'s sensor "
                         "reading and its amplifier on?")


def _stream(stepper: Any, r: FloatArray) -> FloatArray:
    stepper.reset()
    return np.array([float(stepper.step(v)) for v in r])
