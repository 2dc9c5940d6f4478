"""Reference trajectories and excitations, as in the paper's experiments."""

from __future__ import annotations

import numpy as np

from ._validation import FloatArray, as_scalar, as_signal


def n_samples(freq: float, cycles: float, dt: float) -> int:
    """Samples in ``cycles`` periods of ``freq`` Hz at step ``dt`` (rounded to the nearest)."""
    return int(round(cycles / (freq * dt)))


def sinusoid(
    freq: float, cycles: float = 3, low: float = 0.0, high: float = 1.0, dt: float = 1e-4,
    *, start: str = "low",
) -> FloatArray:
    """A sinusoid between ``low`` and ``high``, ``cycles`` periods of ``freq`` Hz at step ``dt``.

    It starts at ``low`` with zero slope (``low + (high - low) (1 - cos 2 pi f t) / 2``), the way
    a de-energised actuator is started in the paper's experiments, so no step is applied at t = 0.
    Used both as a voltage excitation (``low=0, high=100`` V) and as a desired displacement (µm).

    Examples
    --------
    >>> import piezohyst as ph
    >>> ref = ph.sinusoid(freq=1.0, cycles=3, low=0.1, high=1.9, dt=1e-4)
    >>> ref.shape, float(ref[0]), round(float(ref.max()), 6)
    ((30000,), 0.1, 1.9)
    """
    freq = as_scalar("freq", freq, positive=True)
    cycles = as_scalar("cycles", cycles, positive=True)
    dt = as_scalar("dt", dt, positive=True)
    low = as_scalar("low", low)
    high = as_scalar("high", high)
    if high <= low:
        raise ValueError(f"high must be greater than low, got low={low}, high={high}")
    if freq * dt >= 0.5:
        raise ValueError(f"freq={freq} Hz is not below the Nyquist frequency 1/(2 dt) = {0.5 / dt} Hz")
    n = n_samples(freq, cycles, dt)
    if n < 2:
        raise ValueError(f"{cycles} cycle(s) of {freq} Hz at dt={dt} s is fewer than 2 samples")
    t = np.arange(n) * dt
    if start == "low":
        shape = 0.5 * (1.0 - np.cos(2 * np.pi * freq * t))
    elif start == "mid":
        shape = 0.5 * (1.0 + np.sin(2 * np.pi * freq * t))
    else:
        raise ValueError(f"start must be 'low' or 'mid', got {start!r}")
    return low + (high - low) * shape


def time_vector(n: int, dt: float) -> FloatArray:
    """``t_k = k dt`` for ``k = 0..n-1``."""
    return np.arange(int(n)) * float(dt)


def estimate_period(x: object, *, min_corr: float = 0.95) -> int | None:
    """The fundamental period of a repeating signal, in samples, or None if it does not repeat.

    Uses the normalised autocorrelation of the mean-removed signal: the first lag at which it
    has a local maximum above ``min_corr``.
    """
    s = as_signal("x", x)
    s = s - s.mean()
    n = s.size
    if n < 4 or not np.any(s):
        return None
    size = 1 << (2 * n - 1).bit_length()
    spec = np.fft.rfft(s, size)
    ac = np.fft.irfft(spec * np.conj(spec), size)[:n]
    # unbiased normalisation, so later lags are not penalised for having fewer terms
    ac = ac / (ac[0] * (n - np.arange(n)) / n)
    for lag in range(1, n // 2 + 1):
        if ac[lag] >= min_corr and ac[lag] >= ac[lag - 1] and ac[lag] >= ac[lag + 1]:
            return lag
    return None


def cycles_after_first(n: int, period: int | None) -> slice:
    """The samples of the whole cycles after the first (all samples if no period is known)."""
    if period is None or period <= 0 or n < 2 * period:
        return slice(0, n)
    whole = (n // period) * period
    return slice(period, whole)

