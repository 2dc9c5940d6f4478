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


#: :func:`sensor_resolution` looks for a count only where each distinct reading recurs, on average,
#: at least this often (a continuous reading, noise included, repeats almost no value) ...
RESOLUTION_MIN_REPEATS = 4
#: ... and at least this share of the readings repeat the one before (a count held while the stage
#: moves within it; a noise-free simulation of a periodic input repeats its values a period later,
#: not from one sample to the next: found by a reviewer, a sampled triangle read as "steps").
RESOLUTION_MIN_HELD = 0.25
#: Readings off the grid by up to this share of a step still lie on it (a file's decimals, float32
#: storage: a 12-bit converter's counts written with "%.6g" were not found on their grid).
RESOLUTION_TOLERANCE = 1e-3


def sensor_resolution(y: Any) -> float | None:
    """The step of a sensor that reads in counts: the spacing of the grid that every distinct
    value of ``y`` lies on, or None where the values do not lie on one (or recur too seldom,
    :data:`RESOLUTION_MIN_REPEATS`, for a grid to be told from a continuous reading).

    Every reading of a converter is a whole number of counts (times a scale, plus an offset): the
    differences between the sorted distinct values are whole multiples of the smallest, within
    the rounding of the scaling. A step that is a large share of the span (a 12-bit converter of
    which the stage uses a sliver, a coarse encoder) bounds what any model can fit (an RMS of
    ``step / sqrt(12)``) and what a tracking run can show (``step / 2``); it also holds the
    reading still at a reversal and at the ends, where a finer sensor would show motion.

    >>> sensor_resolution(np.round(np.sin(np.linspace(0.0, 20.0, 4000)) * 8.0) / 8.0 * 3.0)
    0.375
    >>> sensor_resolution(np.sin(np.linspace(0.0, 20.0, 4000))) is None
    True
    """
    x = as_signal("y", y, min_length=2)
    if np.mean(x[1:] == x[:-1]) < RESOLUTION_MIN_HELD:
        return None
    levels = np.unique(x)
    if levels.size < 2 or levels.size * RESOLUTION_MIN_REPEATS > x.size:
        return None
    with np.errstate(over="ignore", invalid="ignore"):
        gaps = np.diff(levels)
        if not np.all(np.isfinite(gaps)):
            return None  # (a span beyond the float range)
        step = float(gaps.min())
        # the values' own rounding (their decimals in a file, float32): a share of the step, and a
        # few units in the last place of the largest value
        tol = RESOLUTION_TOLERANCE * step + 16.0 * np.finfo(np.float32).eps * float(np.max(np.abs(levels)))
        counts = np.round(gaps / step)
        if not np.all(np.abs(gaps - counts * step) <= tol * np.maximum(counts, 1.0)):
            return None
        return float((levels[-1] - levels[0]) / float(counts.sum()))  # the mean step: rounding averaged out


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
    # ndtri(1 - p) = -ndtri(p): taken from the small tail, since 1 - p rounds to 1 (and the
    # quantile to inf) once p < 1e-16, i.e. beyond about 10^16 samples
    return s * float(-ndtri(0.5 * tail))


#: Damping ratios :func:`lightly_damped_mode` tries: lightly damped modes only (a mode damped
#: more than 0.2 has a resonant peak of at most 2.5 and does not ring).
MODE_DAMPINGS = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2)
#: Ratio between neighbouring natural frequencies of its grid (6 %).
MODE_FREQUENCY_STEP = 1.06
#: Peaks of each spectrum (the transfer function's, the residual's) that
#: :func:`lightly_damped_mode` fits a mode at.
MODE_CANDIDATES = 3
#: Share of what the model leaves of a record that a mode must explain to be reported: fitting
#: two parameters to noise explains about 2 / N of it.
MODE_MIN_SHARE = 0.02


def second_order_filter(f_hz: float, zeta: float, dt: float) -> tuple[FloatArray, FloatArray]:
    """``(b, a)`` of ``w^2 / (s^2 + 2 zeta w s + w^2)``, ``w = 2 pi f_hz``, discretised with a
    zero-order hold at ``dt`` (unit gain at DC): for :func:`scipy.signal.lfilter`."""
    # the hold's closed form for an underdamped pair of poles s = -sigma +- j wd:
    # a = [1, -2 e^(-sigma dt) cos(wd dt), e^(-2 sigma dt)], b = [0, b1, b2] with b1 + b2 = sum(a)
    if not 0.0 < zeta < 1.0:
        raise ValueError(f"zeta must lie strictly between 0 and 1 (an underdamped mode), got {zeta!r}")
    w = 2.0 * np.pi * float(f_hz)
    sigma = zeta * w
    wd = w * np.sqrt(1.0 - zeta * zeta)
    e = np.exp(-sigma * dt)
    c, s = np.cos(wd * dt), np.sin(wd * dt)
    b1 = 1.0 - e * (c + sigma / wd * s)
    b2 = e * e + e * (sigma / wd * s - c)
    return np.array([0.0, b1, b2]), np.array([1.0, -2.0 * e * c, e * e])


def mode_inverse(y: Any, dt: float, f_hz: float, zeta: float, *, band_hz: float,
                 period: int | None = None) -> FloatArray:
    """``y`` through the inverse of the mode ``w^2 / (s^2 + 2 zeta w s + w^2)`` (``w = 2 pi
    f_hz``) below ``band_hz``, and unchanged above it:
    ``y + (2 zeta / w) y_s' + y_s'' / w^2``, where ``y_s`` is ``y`` low-passed at ``band_hz``
    without phase (a second-order Butterworth filter run forwards and backwards) and the
    derivatives are central differences. Non-causal: for a whole record or a reference known in
    advance. Beyond its ends the signal is taken to go on as it would: one ``period`` (samples)
    earlier and later where it repeats, else mirrored about each end (right for a record or a
    reference that starts and ends at rest or at a turn; one that ends moving gets a kink there,
    felt over two periods of ``band_hz``).

    Two uses: what a hysteresis element ahead of the mode puts out, from a record measured after
    it (``band_hz`` a few times ``f_hz``: the record's noise is amplified by ``(f / f_hz)^2`` up
    to there); and the target a feedforward gives that element so that the mode's output follows
    a reference (``band_hz`` below ``f_hz``: a step in the reference is not turned into a spike).

    >>> import numpy as np
    >>> from scipy.signal import lfilter
    >>> dt = 1e-4
    >>> t = np.arange(20000) * dt
    >>> x = np.sin(2 * np.pi * 5.0 * t) ** 3
    >>> b, a = second_order_filter(60.0, 0.01, dt)
    >>> y = lfilter(b, a, x)  # x rings the mode; its inverse gives x back (half a sample late)
    >>> back = mode_inverse(y, dt, 60.0, 0.01, band_hz=300.0)
    >>> bool(np.max(np.abs(back - x)[5000:-100]) < 0.01)  # (y ends ringing: mirrored, a kink)
    True
    """
    from scipy.signal import butter, sosfiltfilt

    x = as_signal("y", y, min_length=3)
    if not dt > 0.0 or not f_hz > 0.0 or not 0.0 < zeta < 1.0 or not band_hz > 0.0:
        raise ValueError(f"mode_inverse needs dt, f_hz, band_hz > 0 and 0 < zeta < 1, got dt={dt!r}, "
                         f"f_hz={f_hz!r}, zeta={zeta!r}, band_hz={band_hz!r}")
    w = 2.0 * np.pi * float(f_hz)
    fc = min(float(band_hz), 0.4 / dt)
    sos = butter(2, fc, fs=1.0 / dt, output="sos")
    # extended (docstring) by two periods of the cut-off, so that the filter has settled where
    # the signal starts and ends
    pad = max(9, int(np.ceil(2.0 / (fc * dt))))
    n = x.size
    if period is not None and 2 <= int(period) <= n:
        p, i = int(period), np.arange(pad)
        xp = np.concatenate([x[(i - pad) % p], x, x[n - p + i % p]])
    else:
        xp = np.pad(x, pad, mode="reflect")
    xs = sosfiltfilt(sos, xp, padtype=None)
    d1 = np.gradient(xs, dt)[pad:pad + n]
    d2 = (xs[pad + 1:pad + n + 1] - 2.0 * xs[pad:pad + n] + xs[pad - 1:pad + n - 1]) / (dt * dt)
    return x + (2.0 * zeta / w) * d1 + d2 / (w * w)


#: :func:`transfer_peak_mode` takes a peak only where the command explains the output this well
#: (magnitude-squared coherence): elsewhere the ratio of spectra is noise.
MODE_COHERENCE = 0.8
#: ... and only a peak this many times the gain at low frequencies.
MODE_PEAK_RATIO = 3.0
#: ... and only where the command has power: at least this share of the geometric mean of its
#: power a fifth of the frequency below and above (:data:`MODE_INPUT_SPREAD`). At a null of the
#: command's spectrum (a ramp's or a triangle's) the ratio of spectra is the hysteresis's
#: distortion over almost no command: rising to false "peaks" (146.6 Hz on three probe stages
#: with no mode there, where the command's power fell to 1e-4 of its low-frequency level while it
#: was 10 times that at 120 and 180 Hz). A smooth spectrum falling as any power of the frequency
#: passes at a ratio of one.
MODE_INPUT_SHARE = 0.25
#: The factor above and below a frequency where :data:`MODE_INPUT_SHARE` reads the command's power.
MODE_INPUT_SPREAD = 1.2
#: ... and the factor within which the command's least power counts (a null beside a peak).
MODE_INPUT_NEAR = 1.1


def _command_has_power(f: FloatArray, puu: FloatArray, bins: Any) -> Any:
    """Which of ``bins`` (indices into the spectrum ``puu`` at frequencies ``f``) are not at or
    beside a null of it: its least power within a factor :data:`MODE_INPUT_NEAR` is at least
    :data:`MODE_INPUT_SHARE` of the geometric mean of its power (a median over five bins) a factor
    :data:`MODE_INPUT_SPREAD` below and above."""
    idx = np.asarray(bins, dtype=np.intp)
    if idx.size == 0:
        return np.zeros(0, dtype=bool)

    def around(freqs: FloatArray) -> FloatArray:
        at = np.clip(np.searchsorted(f, freqs), 2, f.size - 3)
        return np.median(np.stack([puu[at + j] for j in range(-2, 3)]), axis=0)

    lo, hi = around(f[idx] / MODE_INPUT_SPREAD), around(f[idx] * MODE_INPUT_SPREAD)
    # the least power within MODE_INPUT_NEAR of the bin: a peak on a null's shoulder (138 Hz, the
    # null at 146) is as false as one at its bottom
    a = np.searchsorted(f, f[idx] / MODE_INPUT_NEAR)
    b = np.searchsorted(f, f[idx] * MODE_INPUT_NEAR, side="right")
    least = np.array([puu[i:j].min() if j > i else puu[k] for i, j, k in zip(a, b, idx)])
    return least >= MODE_INPUT_SHARE * np.sqrt(lo * hi)


def transfer_peak_mode(u: Any, y: Any, dt: float, *, f_min: float, f_max: float) -> dict[str, float] | None:
    """A lightly damped mode read off a record's command-to-output transfer function, without any
    model: the highest peak of ``|P_uy| / P_uu`` (Welch, at a resolution of a twentieth of
    ``f_min``) between ``f_min`` and ``f_max`` where the coherence is at least
    :data:`MODE_COHERENCE` and the command has power (not at a null of its spectrum:
    :data:`MODE_INPUT_SHARE`), if it stands :data:`MODE_PEAK_RATIO` times above the median gain below
    ``f_min / 2``; its damping ratio from the half-power width (at least half the resolution over
    the frequency, at most 0.2). None where there is no such peak.

    Where a model's delay and lags have taken up a well-damped mode's effect on a record, the mode
    no longer shows in what the model leaves (:func:`lightly_damped_mode` finds nothing), but the
    transfer function still peaks at it: on four stages with modes damped 4.7-9.3 % at 51-69 Hz,
    peaks at 50.2, 54.5, 58.8 and 71.6 Hz, damping 4.4-8.7 %.

    Returns ``{"f_hz", "zeta", "peak_ratio", "coherence"}``.
    """
    from scipy.signal import csd, welch

    uu = as_signal("u", u, min_length=3)
    yy = as_signal("y", y, min_length=3)
    if uu.size != yy.size:
        raise ValueError(f"u and y must have the same length, got {uu.size} and {yy.size}")
    if not (dt > 0.0 and 0.0 < f_min < f_max):
        return None
    nper = int(min(uu.size, max(16, round(20.0 / (f_min * dt)))))
    f, puy = csd(uu - uu.mean(), yy - yy.mean(), fs=1.0 / dt, nperseg=nper)
    _, puu = welch(uu - uu.mean(), fs=1.0 / dt, nperseg=nper)
    _, pyy = welch(yy - yy.mean(), fs=1.0 / dt, nperseg=nper)
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = np.where(puu > 0.0, np.abs(puy) / puu, 0.0)
        coh = np.where(puu * pyy > 0.0, np.abs(puy) ** 2 / (puu * pyy), 0.0)
    low = (f > 0.0) & (f <= 0.5 * f_min)
    band = np.flatnonzero((f >= f_min) & (f <= min(f_max, 0.45 / dt)) & (coh >= MODE_COHERENCE))
    band = band[_command_has_power(f, puu, band)]
    if not low.any() or band.size < 3:
        return None
    g0 = float(np.median(gain[low]))
    k = int(band[np.argmax(gain[band])])
    if not (g0 > 0.0 and gain[k] >= MODE_PEAK_RATIO * g0) or k in (0, f.size - 1):
        return None
    half = gain[k] / np.sqrt(2.0)
    i, j = k, k
    while i > 0 and gain[i] > half:
        i -= 1
    while j < f.size - 1 and gain[j] > half:
        j += 1

    def crossing(a: int, b: int) -> float:  # where the gain passes half power between bins a and b
        if gain[b] == gain[a]:
            return float(f[a])
        return float(f[a] + (half - gain[a]) * (f[b] - f[a]) / (gain[b] - gain[a]))

    width = crossing(j - 1, j) - crossing(i, i + 1)
    zeta = min(max(width, float(f[1] - f[0])) / (2.0 * float(f[k])), 0.2)
    return {"f_hz": float(f[k]), "zeta": float(zeta), "peak_ratio": float(gain[k] / g0), "coherence": float(coh[k])}


def lightly_damped_mode(y: Any, prediction: Any, dt: float, *, f_min: float,
                        f_max: float) -> dict[str, float] | None:
    """A lightly damped structural mode between ``f_min`` and ``f_max`` (Hz) that a hysteresis
    model's ``prediction`` of a measured ``y`` leaves out, or None.

    Output-error identification of one second-order mode after the model: the measured record is
    compared with the prediction passed through ``w^2 / (s^2 + 2 zeta w s + w^2)``
    (:func:`second_order_filter`). Where to look: the :data:`MODE_CANDIDATES` highest peaks of
    the empirical transfer function from the prediction to what it leaves (``R - 1``: Welch
    cross-spectrum over auto-spectrum, at a resolution of a twentieth of ``f_min``), as many of
    what it leaves (where a mode rings after every sharp turn, whether or not the motion has
    power there), and the best of a grid of steps of :data:`MODE_FREQUENCY_STEP` squared; at
    each, the damping ratios :data:`MODE_DAMPINGS`, the best pair then refined (Nelder-Mead on
    their logarithms, within 10 %: a mode damped 1 % rings within 1 % of its frequency, finer
    than any grid worth searching blindly). The pair that leaves
    the least mean-square error is reported if it explains at least :data:`MODE_MIN_SHARE` of what
    the prediction alone leaves (``explained``). An output-error fit is used, not an equation-error
    (ARX) one: on a record sampled far faster than it moves, an ARX model's autoregressive part
    fits the record's smoothness (``y[k] ~ 2 y[k-1] - y[k-2]``) rather than the mode, and sensor
    noise biases it. A mode the record's motion does not excite (a resonance far above the
    excitation's harmonics) is not found; nor is one the model's own lags already follow.

    Returns ``{"f_hz", "zeta", "explained"}`` (the natural frequency, the damping ratio, the share).

    >>> import numpy as np
    >>> from scipy.signal import lfilter
    >>> dt = 1e-4
    >>> t = np.arange(20000) * dt
    >>> p = np.abs((t * 7.0) % 2.0 - 1.0)  # a triangle wave: corners ring a mode
    >>> b, a = second_order_filter(90.0, 0.02, dt)
    >>> y = lfilter(b, a, p - p[0]) + p[0]
    >>> m = lightly_damped_mode(y, p, dt, f_min=20.0, f_max=1000.0)
    >>> round(m["f_hz"], 1), round(m["zeta"], 3)
    (90.0, 0.02)
    """
    from scipy.signal import lfilter

    yy = as_signal("y", y, min_length=3)
    pp = as_signal("prediction", prediction, min_length=3)
    if yy.size != pp.size:
        raise ValueError(f"y and prediction must have the same length, got {yy.size} and {pp.size}")
    ok = np.isfinite(yy) & np.isfinite(pp)
    yy, pp = yy[ok], pp[ok]
    if yy.size < 3 or not (0.0 < f_min < f_max) or not dt > 0.0:
        return None
    f_max = min(float(f_max), 0.45 / dt)  # below Nyquist, where the hold's discretisation holds
    if not f_min < f_max:
        return None
    j0 = float(np.mean((yy - pp) ** 2))
    if not j0 > 0.0:
        return None
    start = pp[0]
    moved = pp - start
    target = yy - start

    def cost(f: float, zeta: float) -> float:
        b, a = second_order_filter(f, zeta, dt)
        d = target - lfilter(b, a, moved)
        return float(np.dot(d, d)) / d.size

    # where to look (docstring)
    from scipy.optimize import minimize
    from scipy.signal import csd, find_peaks, welch

    nper = int(min(yy.size, max(16, round(20.0 / (f_min * dt)))))
    freqs, pxy = csd(pp, yy - pp, fs=1.0 / dt, nperseg=nper)
    _, pxx = welch(pp, fs=1.0 / dt, nperseg=nper)
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = np.where(pxx > 0.0, np.abs(pxy) / pxx, 0.0)
    inside = np.flatnonzero((freqs >= f_min) & (freqs <= f_max))
    if inside.size < 3:
        return None
    _, pee = welch(yy - pp, fs=1.0 / dt, nperseg=nper)

    def highest_peaks(curve: FloatArray) -> list[float]:
        found, _ = find_peaks(np.concatenate([[0.0], curve[inside], [0.0]]))
        found = inside[found - 1]
        return [float(freqs[k]) for k in found[np.argsort(curve[found])[::-1][:MODE_CANDIDATES]]]

    candidates = highest_peaks(gain) + highest_peaks(pee)
    # and a blind grid's best (every other damping ratio): where the motion has little power near
    # the mode and it rings little, the spectra say little
    coarse = MODE_FREQUENCY_STEP ** 2
    grid = np.geomspace(f_min, f_max, int(np.ceil(np.log(f_max / f_min) / np.log(coarse))) + 1)
    candidates.append(min((cost(float(f), z), float(f)) for z in MODE_DAMPINGS[1::2] for f in grid)[1])
    best = (j0, 0.0, 0.0)
    lo_z, hi_z = 0.5 * MODE_DAMPINGS[0], MODE_DAMPINGS[-1]
    for fc in candidates:
        lo_f, hi_f = max(f_min, fc / 1.1), min(f_max, fc * 1.1)
        j, z0 = min((cost(fc, z), z) for z in MODE_DAMPINGS)

        def bounded(x: FloatArray, lo_f: float = lo_f, hi_f: float = hi_f) -> tuple[float, float]:
            return min(max(float(np.exp(x[0])), lo_f), hi_f), min(max(float(np.exp(x[1])), lo_z), hi_z)

        res = minimize(lambda x, b=bounded: cost(*b(x)), np.log([fc, z0]), method="Nelder-Mead",
                       options={"xatol": 1e-3, "fatol": 1e-6 * j0, "maxfev": 40, "initial_simplex":
                                np.log([[fc, z0], [fc * 1.02, z0], [fc, z0 * 1.5]])})
        here = (float(res.fun), *bounded(res.x)) if res.fun < j else (j, fc, z0)
        if here[0] < best[0]:
            best = here
    explained = 1.0 - best[0] / j0
    if explained < MODE_MIN_SHARE:
        return None
    return {"f_hz": best[1], "zeta": best[2], "explained": explained}
