"""Hysteresis models: backlash (play) operator, Prandtl-Ishlinskii, Bouc-Wen."""

from .bouc_wen import BoucWen, BoucWenStepper
from .pi import PIStepper, PrandtlIshlinskii, equal_thresholds
from .play import play_operator

__all__ = [
    "BoucWen",
    "BoucWenStepper",
    "PIStepper",
    "PrandtlIshlinskii",
    "equal_thresholds",
    "play_operator",
]
