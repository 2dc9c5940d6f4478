"""What a plant is: the protocol every closed loop, commissioning and identification run talks to.

A plant is the stage as the software sees it, real or simulated: commands in volts, measured
displacement in micrometres, one sample every ``dt`` seconds. The :class:`~piezohyst.rig.VirtualRig`
is one; a user's hardware adapter with the same three members is another, and works everywhere
the rig does.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from ._validation import as_signal
from .data import Dataset


@runtime_checkable
class Plant(Protocol):
    """What ``track`` and ``commission`` need from a plant, real or simulated.

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


def check_plant(plant: Any) -> float:
    """The plant's ``dt``, or a TypeError that says what the Plant protocol needs."""
    dt = getattr(plant, "dt", None)
    if isinstance(dt, bool) or not isinstance(dt, (int, float, np.floating)) or not dt > 0 or not np.isfinite(dt):
        raise TypeError("plant must follow the Plant protocol: a positive float 'dt', reset() and step(u)")
    return float(dt)


def open_loop(plant: Any, u: Any) -> Dataset:
    """An open-loop run of any Plant from rest: ``plant.excite(u)`` when it has one (compiled for
    the VirtualRig), else ``reset()`` and one ``step`` per sample."""
    if hasattr(plant, "excite"):
        return plant.excite(u)  # type: ignore[no-any-return]
    dt = check_plant(plant)
    x = as_signal("u", u)
    plant.reset()
    y = np.array([float(plant.step(v)) for v in x])
    return Dataset(np.arange(x.size) * dt, x, y, {"source": type(plant).__name__})
