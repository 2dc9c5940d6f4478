"""Identification of hysteresis models from measured data (paper Sections III-B and III-C, and beyond).

* :func:`fit_pi` - the paper's P-I model: PSO (eqs. 5-6, fitness eq. 9) or bounded least squares
  (the global optimum); :func:`fit_bouc_wen` - the paper's Bouc-Wen model, PSO plus refinement.
* :func:`fit_rate_pi`, :func:`fit_asymmetric_pi`, :func:`fit_preisach`,
  :func:`fit_rate_dependent` - every other kind, each one bounded linear least-squares problem
  per structure (:mod:`piezohyst.identify.linear`), invertible with a stable inverse by
  construction.
* :func:`fit_model` - every kind and structure, fitted on one part of the data and chosen on
  another (:mod:`piezohyst.identify.select`).

Every ``fit_*`` takes either ``u, y`` (and ``dt``) or one :class:`~piezohyst.data.Dataset`, and
returns a :class:`FitResult`.
"""

from .bouc_wen import BW_NAMES, default_bouc_wen_bounds, fit_bouc_wen
from .linear import DEFAULT_MARGIN, Structure, fit_structure
from .lsq import bounded_lstsq
from .pi import fit_pi, pi_regressors
from .rate import fit_asymmetric_pi, fit_preisach, fit_rate_dependent, fit_rate_pi
from .result import ExtrapolationWarning, FitResult, paired_signals, simulate_fit
from .select import fit_model, search_ranges

__all__ = [
    "BW_NAMES",
    "DEFAULT_MARGIN",
    "ExtrapolationWarning",
    "FitResult",
    "Structure",
    "bounded_lstsq",
    "default_bouc_wen_bounds",
    "fit_asymmetric_pi",
    "fit_bouc_wen",
    "fit_model",
    "fit_pi",
    "fit_preisach",
    "fit_rate_dependent",
    "fit_rate_pi",
    "fit_structure",
    "paired_signals",
    "pi_regressors",
    "search_ranges",
    "simulate_fit",
]
