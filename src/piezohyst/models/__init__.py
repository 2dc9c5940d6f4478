"""Hysteresis model kinds, all behind one protocol (:mod:`piezohyst.models.base`).

Importing this package registers every kind: a new kind is one module here and one line below.
"""

from .base import Compensator, HysteresisModel, kind_class, kind_of, kinds, register_kind
from .bouc_wen import BoucWen, BoucWenStepper
from .pi import InversePIFeedforward, PIStepper, PrandtlIshlinskii, equal_thresholds
from .play import play_operator
from .rate import RateDependent, RateDependentPI
from .preisach import Preisach
from .asymmetric_pi import AsymmetricPI, OutputMap
from .bouc_wen_hysteresis import BoucWenHysteresis
from .duhem import GeneralizedDuhem
from .history import AfterHistory

__all__ = [
    "AfterHistory",
    "AsymmetricPI",
    "BoucWen",
    "BoucWenHysteresis",
    "BoucWenStepper",
    "Compensator",
    "GeneralizedDuhem",
    "HysteresisModel",
    "InversePIFeedforward",
    "OutputMap",
    "PIStepper",
    "Preisach",
    "PrandtlIshlinskii",
    "RateDependent",
    "RateDependentPI",
    "equal_thresholds",
    "kind_class",
    "kind_of",
    "kinds",
    "play_operator",
    "register_kind",
]
