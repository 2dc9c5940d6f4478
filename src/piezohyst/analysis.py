"""Figures of a hysteresis loop: span and width at mid-range."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._validation import as_signal
from .signals import estimate_period


@dataclass(frozen=True)
class LoopFigures:
    """Span and mid-range width of one steady hysteresis loop.

    ``width`` is the distance between the descending and the ascending branch at the middle of
    the input range (in the units of y); ``width_percent`` is it as a percentage of ``span``,
    the "positioning error of 10-15 % of the span" of the paper's Section I.
    """

    span: float
    width: float
    u_mid: float

    @property
    def width_percent(self) -> float:
        """The width as a percentage of the span (the paper's 10-15 %)."""
        return 100.0 * self.width / self.span if self.span > 0 else float("nan")


def _branch_value(u: np.ndarray, y: np.ndarray, at: float, half_window: float) -> float:
    sel = np.abs(u - at) <= half_window
    if sel.sum() < 2:
        order = np.argsort(u)
        return float(np.interp(at, u[order], y[order]))
    slope, icpt = np.polyfit(u[sel] - at, y[sel], 1)
    return float(icpt)


def loop_figures(u: object, y: object, *, period: int | None = None) -> LoopFigures:
    """Span and mid-range width of the last whole loop of a periodic run.

    Parameters
    ----------
    u, y : array_like
        Input and output of a run under a periodic input (e.g. a sinusoid).
    period : int, optional
        The period in samples; estimated from ``u`` when omitted.

    Returns
    -------
    LoopFigures

    Notes
    -----
    Each branch is a local straight-line fit over +-2 % of the input range around mid-range, so
    sensor noise does not decide the figure.
    """
    us = as_signal("u", u, min_length=4)
    ys = as_signal("y", y, min_length=4)
    if us.size != ys.size:
        raise ValueError(f"u and y must have the same length, got {us.size} and {ys.size}")
    if period is None:
        period = estimate_period(us)
    if period is not None and us.size >= period:
        us, ys = us[-period:], ys[-period:]
    lo, hi = float(us.min()), float(us.max())
    mid = 0.5 * (lo + hi)
    du = np.gradient(us)
    up = du > 0
    down = du < 0
    if up.sum() < 2 or down.sum() < 2:
        raise ValueError("the input has no ascending and descending branch: not a loop")
    hw = 0.02 * (hi - lo)
    y_up = _branch_value(us[up], ys[up], mid, hw)
    y_down = _branch_value(us[down], ys[down], mid, hw)
    return LoopFigures(span=float(ys.max() - ys.min()), width=abs(y_down - y_up), u_mid=mid)
