"""piezohyst: hysteresis modelling, identification and compensation of piezoelectric actuators.

Implements Prandtl-Ishlinskii and Bouc-Wen hysteresis models, their identification with particle
swarm optimisation (and, beyond the paper, constrained least squares), the inverse-P-I and
Bouc-Wen feedforward controllers with PID feedback, and a virtual piezo test rig, after
"Model-Based Control for Piezoelectric-Actuated Systems Using Inverse Prandtl-Ishlinskii Model
and Particle Swarm Optimization". Equation numbers in docstrings refer to that paper. Beyond it:
asymmetric P-I, Preisach and rate-dependent models behind one interface
(:mod:`piezohyst.models.base`), model selection on held-out data (:func:`fit_model`), and
commissioning of any stage (:func:`commission`).

The names below are imported on first use, so ``import piezohyst`` (and ``piezohyst --help``)
does not pay for numba and scipy until something needs them. No public function shares its name
with a submodule (importing the submodule would replace the function on the package): hence
``commission`` lives in :mod:`piezohyst.commissioning`.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

from ._version import __version__ as __version__  # re-exported

#: public name -> the module that defines it
_LAZY: dict[str, str] = {
    "LoopFigures": "analysis", "loop_figures": "analysis",
    "CommissionedController": "commissioning", "commission": "commissioning",
    "commissioning_excitation": "commissioning",
    "AmplifierSlewWarning": "commissioning", "NoFeedbackWarning": "commissioning",
    "NotMonotoneWarning": "identify.monotone", "DeadRangeWarning": "identify.monotone",
    "BoucWenFeedforward": "control", "InversePIFeedforward": "control", "PID": "control",
    "TrackingResult": "control", "UnstableLoopError": "control", "track": "control",
    "DataError": "data", "Dataset": "data", "load_dataset": "data", "load_piezo_dbo": "data",
    "save_dataset": "data",
    "ExtrapolationWarning": "identify", "FitResult": "identify", "fit_bouc_wen": "identify", "fit_pi": "identify",
    "fit_rate_pi": "identify",
    "fit_model": "identify", "fit_asymmetric_pi": "identify", "fit_preisach": "identify",
    "fit_rate_dependent": "identify",
    "AfterHistory": "models", "AsymmetricPI": "models", "BoucWen": "models", "BoucWenHysteresis": "models", "BoucWenStepper": "models", "Compensator": "models",
    "GeneralizedDuhem": "models",
    "HysteresisModel": "models", "OutputMap": "models", "PIStepper": "models", "Preisach": "models",
    "PrandtlIshlinskii": "models", "RateDependent": "models", "RateDependentPI": "models",
    "equal_thresholds": "models", "play_operator": "models", "kinds": "models",
    "ModelFileError": "modelio", "load_model": "modelio", "save_model": "modelio",
    "PSOResult": "pso", "pso_minimize": "pso",
    "Plant": "plant", "open_loop": "plant", "BufferedPlant": "plant", "CommandLimits": "plant",
    "GuardedPlant": "plant", "SensorDropoutError": "plant", "SensorDropoutWarning": "plant",
    "ClippingWarning": "rig", "RigSettings": "rig", "VirtualRig": "rig",
    "estimate_period": "signals", "sinusoid": "signals", "sensor_noise_rms": "signals", "noise_e_max": "signals",
    "Progress": "progress",
}
_SUBMODULES = ("signals", "models", "identify", "control", "data", "modelio", "plots", "experiments", "export",
               "fleet", "commissioning")

__all__ = sorted([*_LAZY, *_SUBMODULES, "__version__"])


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    elif name in _SUBMODULES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module 'piezohyst' has no attribute {name!r}")
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return __all__


class _Package(types.ModuleType):
    """The package module, so that importing a submodule cannot hide the public name it defines.

    Importing ``piezohyst.commission`` (the module) sets the package's attribute ``commission``
    to that module; ``ph.commission(plant)`` would then fail. The public name wins.
    """

    def __setattr__(self, name: str, value: Any) -> None:
        if (name in _LAZY and isinstance(value, types.ModuleType)
                and value.__name__ == f"{__name__}.{name}" and hasattr(value, name)):
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from . import control, data, experiments, export, fleet, identify, modelio, models, plots, signals  # noqa: F401
    from .analysis import LoopFigures, loop_figures  # noqa: F401
    from . import commissioning  # noqa: F401
    from .commissioning import (AmplifierSlewWarning, CommissionedController, NoFeedbackWarning,  # noqa: F401
                                commission, commissioning_excitation)
    from .identify.monotone import DeadRangeWarning, NotMonotoneWarning  # noqa: F401
    from .control import (BoucWenFeedforward, InversePIFeedforward, PID, TrackingResult,  # noqa: F401
                          UnstableLoopError, track)
    from .data import DataError, Dataset, load_dataset, load_piezo_dbo, save_dataset  # noqa: F401
    from .identify import (ExtrapolationWarning, FitResult, fit_asymmetric_pi, fit_bouc_wen,  # noqa: F401
                           fit_model, fit_pi, fit_preisach, fit_rate_dependent, fit_rate_pi)
    from .modelio import ModelFileError, load_model, save_model  # noqa: F401
    from .models import (AfterHistory, AsymmetricPI, BoucWen, BoucWenHysteresis, BoucWenStepper, Compensator,  # noqa: F401
                         GeneralizedDuhem, HysteresisModel,
                         OutputMap, PIStepper, PrandtlIshlinskii, Preisach, RateDependent, RateDependentPI,
                         equal_thresholds, kinds, play_operator)
    from .plant import (BufferedPlant, CommandLimits, GuardedPlant, Plant,  # noqa: F401
                        SensorDropoutError, SensorDropoutWarning, open_loop)
    from .pso import PSOResult, pso_minimize  # noqa: F401
    from .rig import ClippingWarning, RigSettings, VirtualRig  # noqa: F401
    from .signals import estimate_period, noise_e_max, sensor_noise_rms, sinusoid  # noqa: F401
    from .progress import Progress  # noqa: F401
