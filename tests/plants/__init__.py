"""Plants for the tests: small ones (:mod:`.simple`) and the zoo of piezo-like stages (:mod:`.zoo`).

Every plant follows the Plant protocol (``dt``, ``reset()``, ``step(u) -> y``) and most state
their ``u_range``. The zoo's stages are of structures the project's models do not share; nothing
in the project is tuned on them (they are the test).
"""

from .simple import FirstOrderPlant, PIPlant, QuasiStaticBoucWenPlant, UnboundedIntegrator

__all__ = ["FirstOrderPlant", "PIPlant", "QuasiStaticBoucWenPlant", "UnboundedIntegrator", "error_below"]


def error_below(result, f_hz=100.0):
    """RMS of a tracking result's error in its scored cycles (the first left out), below ``f_hz``:
    the band integral feedback and learning act in. The VirtualRig's sensor noise (3 nm RMS,
    white to 5 kHz) sets a floor under the whole RMSE that a feedforward as good as the
    commissioned one already reaches, so feedback shows in this band, not in the RMSE."""
    import numpy as np

    per = result.period or 0
    e = np.asarray(result.error[per:], dtype=np.float64)
    dt = float(result.t[1] - result.t[0])
    spec = np.fft.rfft(e)
    spec[np.fft.rfftfreq(e.size, dt) > f_hz] = 0.0
    return float(np.sqrt(np.mean(np.fft.irfft(spec, e.size) ** 2)))

