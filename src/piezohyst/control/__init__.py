"""Feedforward compensation, PID feedback and closed-loop tracking (paper Section IV, Fig. 5)."""

from .feedforward import BoucWenFeedforward, InversePIFeedforward
from .pid import PID
from .tracking import TrackingResult, UnstableLoopError, track

__all__ = ["BoucWenFeedforward", "InversePIFeedforward", "PID", "TrackingResult", "UnstableLoopError", "track"]
