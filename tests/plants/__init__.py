"""Plants for the tests: small ones (:mod:`.simple`) and the zoo of piezo-like stages (:mod:`.zoo`).

Every plant follows the Plant protocol (``dt``, ``reset()``, ``step(u) -> y``) and most state
their ``u_range``. The zoo's stages are of structures the project's models do not share; nothing
in the project is tuned on them (they are the test).
"""

from .simple import FirstOrderPlant, PIPlant, QuasiStaticBoucWenPlant, UnboundedIntegrator

__all__ = ["FirstOrderPlant", "PIPlant", "QuasiStaticBoucWenPlant", "UnboundedIntegrator"]
