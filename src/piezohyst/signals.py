"""Reference trajectories and excitations, as in the paper's experiments."""

from __future__ import annotations

from typing import Any

import numpy as np

from ._validation import FloatArray, as_scalar, as_signal

#: The longest signal these generators build (samples): 400 MB of float64. Beyond it a request is
#: almost surely a unit mistake (a frequency in kHz given as Hz, a dt in ms given as s), and would
#: exhaust memory before failing.
MAX_SAMPLES = 50_000_000


def n_samples(freq: float, cycles: float, dt: float) -> int:
    """Samples in ``cycles`` periods of ``freq`` Hz at step ``dt`` (rounded to the nearest).

    Raises ValueError (naming the parameters) when that is more than :data:`MAX_SAMPLES`.
    """
    n = cycles / (freq * dt)
    if not n <= MAX_SAMPLES:
        raise ValueError(f"cycles={cycles:g} of freq={freq:g} Hz at dt={dt:g} s is {n:.3g} samples; the limit is "
                         f"{MAX_SAMPLES:.3g} (piezohyst.signals.MAX_SAMPLES)")
    return int(round(n))


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
    if not freq * dt < 0.5:
        raise ValueError(f"freq={freq} Hz is not below the Nyquist frequency 1/(2 dt) = {0.5 / dt} Hz")
    if start not in ("low", "mid"):
        raise ValueError(f"start must be 'low' or 'mid', got {start!r}")
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
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)):
        raise TypeError(f"n must be a whole number of samples, got {type(n).__name__}")
    if not 0 <= n <= MAX_SAMPLES:
        raise ValueError(f"n must be in 0..{MAX_SAMPLES} samples, got {n}")
    return np.arange(int(n), dtype=np.float64) * float(as_scalar("dt", dt, positive=True))


def estimate_period(x: object, *, min_corr: float = 0.95) -> int | None:
    """The fundamental period of a repeating signal, in samples, or None if it does not repeat.

    The normalised autocorrelation of the mean-removed signal finds the first lag at which it
    has a local maximum above ``min_corr``; that lag is then refined, within 3 % of it, to the
    lag at which the signal best matches itself shifted (least mean squared difference), since
    the correlation's first maximum can sit a little early (1 % for a sinusoid of four cycles).
    Any periodic shape works: sinusoids, triangles (an AFM raster), squares.

    Examples
    --------
    >>> import numpy as np, piezohyst as ph
    >>> t = np.arange(40000) * 1e-4
    >>> ph.estimate_period(1 + 2 * np.abs((2 * t) % 1.0 - 0.5))   # a 2 Hz triangle at 10 kHz
    5000
    """
    s = as_signal("x", x)
    min_corr = as_scalar("min_corr", min_corr)
    if not 0 < min_corr <= 1:
        raise ValueError(f"min_corr must be in (0, 1], got {min_corr}")
    s = s - s.mean()
    n = s.size
    if n < 4 or not np.any(s):
        return None
    size = 1 << (2 * n - 1).bit_length()
    spec = np.fft.rfft(s, size)
    ac = np.fft.irfft(spec * np.conj(spec), size)[:n]
    # unbiased normalisation, so later lags are not penalised for having fewer terms
    raw = ac.copy()
    ac = ac / (ac[0] * (n - np.arange(n)) / n)
    # the correlation must first fall (below 1/2) away from lag 0 before it can peak again: near
    # lag 0 a smooth signal's correlation is flat to rounding and shows spurious local maxima
    fallen = np.flatnonzero(ac[: n // 2 + 1] < 0.5)
    if fallen.size == 0:
        return None
    for lag in range(int(fallen[0]), n // 2 + 1):
        if ac[lag] >= min_corr and ac[lag] >= ac[lag - 1] and ac[lag] >= ac[lag + 1]:
            return _refine_period(s, raw, lag)
    return None


def _refine_period(s: FloatArray, raw_ac: FloatArray, p0: int) -> int:
    """The lag within 3 % of ``p0`` minimising ``mean((s[L:] - s[:-L])^2)``, from the raw
    autocorrelation and cumulative sums of squares (no loop over the record)."""
    n = s.size
    lo = max(1, int(np.floor(0.97 * p0)))
    hi = min(int(np.ceil(1.03 * p0)), n // 2)
    lags = np.arange(lo, hi + 1)
    sq = np.concatenate([[0.0], np.cumsum(s * s)])
    head = sq[n - lags]  # sum of s[:n-L]^2
    tail = sq[n] - sq[lags]  # sum of s[L:]^2
    msd = (head + tail - 2.0 * raw_ac[lags]) / (n - lags)
    return int(lags[int(np.argmin(msd))])


def cycles_after_first(n: int, period: int | None) -> slice:
    """The samples of the whole cycles after the first (all samples if no period is known)."""
    if period is None or period <= 0 or n < 2 * period:
        return slice(0, n)
    whole = (n // period) * period
    return slice(period, whole)


def interpolate_over(y: FloatArray, bad: Any) -> FloatArray:
    """``y`` with the samples where ``bad`` is True replaced by linear interpolation between the
    others (held at the ends); ``y`` itself is left as it is. At least one sample must be good.

    >>> interpolate_over(np.array([0.0, 9.0, 2.0, 3.0, 9.0]), np.array([False, True, False, False, True]))
    array([0., 1., 2., 3., 3.])
    """
    out = np.array(y, dtype=np.float64, copy=True)
    mask = np.asarray(bad, dtype=bool)
    if mask.any():
        i = np.arange(out.size)
        out[mask] = np.interp(i[mask], i[~mask], out[~mask])
    return out


#: ``sqrt(6)``: the standard deviation of the second difference ``e[k+1] - 2 e[k] + e[k-1]`` of
#: white noise of unit standard deviation (variance 1 + 4 + 1).
_SECOND_DIFFERENCE_GAIN = 6.0 ** 0.5
#: The median absolute deviation of a normal variable, in standard deviations (``ndtri(0.75)``).
_MAD_PER_SIGMA = 0.6744897501960817


def sensor_noise_rms(y: Any) -> float:
    """The RMS of the white noise on a measured signal, from the median absolute value of its
    second differences (a difference-based variance estimator, cf. Gasser, Sroka and
    Jennen-Steinmetz, Biometrika 73 (1986) 625-633, made robust with the median):

        sigma = median(|y[k+1] - 2 y[k] + y[k-1]|) / (0.6745 sqrt(6))

    The second difference of white noise has a standard deviation of ``sqrt(6) sigma``; that of a
    smooth motion sampled fast is far smaller, and the median ignores what is not (reversals,
    ringing, glitches: a minority of samples). Pass what is left after a model's prediction when
    the motion is fast at this sample rate, so that little but the noise remains. Where more than
    half the second differences are exactly zero (a sensor that reads in counts larger than its
    noise), the median says nothing and their RMS is used: the quantisation's own noise.

    >>> rng = np.random.default_rng(0)
    >>> t = np.arange(20000) * 1e-4
    >>> round(sensor_noise_rms(5.0 * np.sin(2 * np.pi * t) + 0.003 * rng.standard_normal(t.size)), 4)
    0.003
    """
    x = as_signal("y", y, min_length=3)
    d2 = x[2:] - 2.0 * x[1:-1] + x[:-2]
    mad = float(np.median(np.abs(d2)))
    if mad > 0.0:
        return mad / (_MAD_PER_SIGMA * _SECOND_DIFFERENCE_GAIN)
    return float(np.sqrt(np.mean(d2 * d2))) / _SECOND_DIFFERENCE_GAIN


def noise_e_max(sigma: float, samples: int) -> float:
    """The largest magnitude that ``samples`` independent samples of normal noise of RMS ``sigma``
    reach with probability one half (the median of their maximum): the floor that sensor noise
    alone puts under a measured e_max over that many samples.

    ``P(max |n_k| < t) = (1 - 2 Q(t / sigma))^samples = 1/2`` gives
    ``t = sigma ndtri(1 - (1 - 2^(-1/samples)) / 2)``.

    >>> round(noise_e_max(1.0, 1), 3), round(noise_e_max(1.0, 10000), 2)
    (0.674, 3.98)
    """
    from scipy.special import ndtri

    s = as_scalar("sigma", sigma)
    if not s >= 0.0:
        raise ValueError(f"sigma must be >= 0, got {sigma!r}")
    if isinstance(samples, bool) or int(samples) != samples or samples < 1:
        raise ValueError(f"samples must be a positive whole number, got {samples!r}")
    tail = -np.expm1(-np.log(2.0) / float(samples))  # 1 - 2^(-1/samples), exact for large samples
    return s * float(ndtri(1.0 - 0.5 * tail))
