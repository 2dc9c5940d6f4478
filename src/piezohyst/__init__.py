"""piezohyst: hysteresis modelling, identification and compensation of piezoelectric actuators.

Implements Prandtl-Ishlinskii and Bouc-Wen hysteresis models, their identification with particle
swarm optimisation (and, beyond the paper, constrained least squares), the inverse-P-I and
Bouc-Wen feedforward controllers with PID feedback, and a virtual piezo test rig, after
"Model-Based Control for Piezoelectric-Actuated Systems Using Inverse Prandtl-Ishlinskii Model
and Particle Swarm Optimization". Equation numbers in docstrings refer to that paper.
"""

from __future__ import annotations

from .analysis import LoopFigures, loop_figures
from .commission import CommissionedController, commission
from .control import BoucWenFeedforward, InversePIFeedforward, PID, TrackingResult, UnstableLoopError, track
from .data import DataError, Dataset, load_dataset, load_piezo_dbo, save_dataset
from .identify import FitResult, fit_bouc_wen, fit_pi, fit_rate_pi
from .models.rate_pi import RateDependentPI
from .models import BoucWen, BoucWenStepper, PIStepper, PrandtlIshlinskii, equal_thresholds, play_operator
from .modelio import ModelFileError, load_model, save_model
from .pso import PSOResult, pso_minimize
from .rig import ClippingWarning, Plant, RigSettings, VirtualRig
from . import signals
from .signals import estimate_period, sinusoid

__version__ = "0.1.0"

__all__ = [
    "CommissionedController",
    "RateDependentPI",
    "commission",
    "fit_rate_pi",
    "BoucWenFeedforward",
    "InversePIFeedforward",
    "PID",
    "TrackingResult",
    "UnstableLoopError",
    "track",
    "ClippingWarning",
    "signals",
    "Plant",
    "RigSettings",
    "VirtualRig",
    "DataError",
    "Dataset",
    "FitResult",
    "ModelFileError",
    "PSOResult",
    "fit_bouc_wen",
    "fit_pi",
    "load_dataset",
    "load_model",
    "load_piezo_dbo",
    "pso_minimize",
    "save_dataset",
    "save_model",
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
