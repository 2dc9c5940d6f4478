"""piezohyst: hysteresis modelling, identification and compensation of piezoelectric actuators.

Implements Prandtl-Ishlinskii and Bouc-Wen hysteresis models, their identification with particle
swarm optimisation (and, beyond the paper, constrained least squares), the inverse-P-I and
Bouc-Wen feedforward controllers with PID feedback, and a virtual piezo test rig, after
"Model-Based Control for Piezoelectric-Actuated Systems Using Inverse Prandtl-Ishlinskii Model
and Particle Swarm Optimization". Equation numbers in docstrings refer to that paper.
"""

from __future__ import annotations

from .analysis import LoopFigures, loop_figures
from .models import BoucWen, BoucWenStepper, PIStepper, PrandtlIshlinskii, equal_thresholds, play_operator
from .signals import estimate_period, sinusoid

__version__ = "0.1.0"

__all__ = [
    "BoucWen",
    "BoucWenStepper",
    "LoopFigures",
    "PIStepper",
    "PrandtlIshlinskii",
    "__version__",
    "equal_thresholds",
    "estimate_period",
    "loop_figures",
    "play_operator",
    "sinusoid",
]
