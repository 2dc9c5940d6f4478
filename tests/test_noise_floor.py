"""The sensor-noise floor under a tracking run's e_max: the noise's RMS estimated from a record
(:func:`piezohyst.signals.sensor_noise_rms`), the e_max that noise alone reaches
(:func:`piezohyst.signals.noise_e_max`), and what a commissioned controller reports of both."""

import json
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import piezohyst as ph
from piezohyst.signals import noise_e_max, sensor_noise_rms, sensor_resolution

from .plants.zoo import zoo
from .test_zoo import steady_range


@settings(max_examples=40, deadline=None)
@given(amplitude=st.floats(0.1, 100.0), freq=st.floats(0.2, 20.0), fs=st.sampled_from([2e3, 5e3, 1e4, 2e4]),
       sigma_share=st.floats(1e-4, 1e-2), seed=st.integers(0, 2**31 - 1))
def test_noise_rms_of_a_smooth_motion_plus_white_noise(amplitude, freq, fs, sigma_share, seed):
    """Law: on a motion that is smooth at the sample rate (second difference far below the
    noise's), the estimate is the noise's RMS to within the estimator's own scatter (20,000
    samples: about 1 %; 8 % allowed)."""
    rng = np.random.default_rng(seed)
    t = np.arange(20_000) / fs
    sigma = sigma_share * amplitude
    smooth_d2 = amplitude * (2 * np.pi * freq / fs) ** 2  # largest second difference of the motion
    if smooth_d2 > 0.05 * sigma:
        freq = freq * (0.05 * sigma / smooth_d2) ** 0.5  # slow it until the motion is smooth here
    y = amplitude * np.sin(2 * np.pi * freq * t) + sigma * rng.standard_normal(t.size)
    assert sensor_noise_rms(y) == pytest.approx(sigma, rel=0.08)


def test_noise_rms_ignores_a_few_glitches_and_reversal_kinks():
    rng = np.random.default_rng(3)
    t = np.arange(50_000) * 1e-4
    y = 10.0 * np.abs(((t * 2.0) % 2.0) - 1.0)  # a triangle: a kink at every reversal
    y = y + 0.004 * rng.standard_normal(t.size)
    y[rng.choice(t.size, 50, replace=False)] += 5.0  # sensor glitches
    assert sensor_noise_rms(y) == pytest.approx(0.004, rel=0.05)


def test_noise_rms_of_a_sensor_reading_in_counts():
    """Counts larger than the noise: most second differences are zero, so the median says
    nothing; the RMS of the second differences measures the quantisation's noise instead (a
    staircase has ``q^2 / 12``-ish variance per sample, never zero and never above a count)."""
    t = np.arange(20_000) * 1e-4
    q = 0.02
    y = np.round((3.0 * np.sin(2 * np.pi * t) + 0.001 * np.random.default_rng(0).standard_normal(t.size)) / q) * q
    est = sensor_noise_rms(y)
    assert 0.0 < est < q


def test_noise_e_max_is_the_median_of_the_largest_noise_sample():
    """Against Monte Carlo (seeded): the median over 4000 draws of max |n_k| over n samples."""
    rng = np.random.default_rng(11)
    for n in (1, 30, 3000):
        draws = np.abs(rng.standard_normal((4000, n))).max(axis=1)
        assert noise_e_max(2.0, n) == pytest.approx(2.0 * float(np.median(draws)), rel=0.03), n
    assert noise_e_max(0.0, 100) == 0.0


def test_noise_e_max_stays_finite_and_rising_for_any_count():
    """Beyond about 10^16 samples ``1 - p`` rounds to 1 and the normal quantile to inf (it did:
    ``noise_e_max(1, 1e17)`` was inf). Reference: for large n, ``(1 - 2 Q(t))^n = 1/2`` gives
    ``Q(t) = ln 2 / (2 n)`` to first order, t from scipy.stats.norm.isf."""
    from scipy.stats import norm

    counts = [10**k for k in range(0, 301, 10)]
    floors = [noise_e_max(1.0, n) for n in counts]
    assert all(np.isfinite(floors)) and all(b > a for a, b in zip(floors, floors[1:]))
    for n in (10**17, 10**40, 10**300):
        assert noise_e_max(1.0, n) == pytest.approx(float(norm.isf(np.log(2.0) / (2.0 * n))), rel=1e-9), n


@pytest.mark.parametrize("bad", [(-1.0, 10), (float("nan"), 10), (1.0, 0), (1.0, 2.5), (1.0, True)])
def test_noise_e_max_refuses_what_is_not_a_noise_and_a_count(bad):
    with pytest.raises(ValueError, match="sigma|samples"):
        noise_e_max(*bad)


@pytest.mark.slow
def test_commissioned_controller_reports_the_noise_floor():
    """On a zoo stage (asymmetric Maxwell-slip, sensor noise 0.01 µm RMS, known), the
    controller's estimate from its identification run, and every tracking run's floor, computed
    from it over the run's scored samples."""
    stage = zoo(seed=0)[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(stage, tune=False)
    assert ctl.sensor_noise_um == pytest.approx(stage.noise_um, rel=0.1)
    assert ctl.describe()["sensor_noise_um"] == ctl.sensor_noise_um
    a, b = steady_range(stage)
    period = int(round(1.0 / stage.dt))
    out = ctl.track(ph.sinusoid(1.0, 3, a, b, stage.dt), feedback=False, learning=False, period=period)
    floor = noise_e_max(ctl.sensor_noise_um, out.metrics.samples)
    assert out.info["sensor_noise_um"] == ctl.sensor_noise_um
    assert out.info["noise_floor_um"] == pytest.approx(floor)
    assert out.info["noise_floor_percent"] == pytest.approx(100.0 * floor / out.metrics.span)
    assert out.summary()["noise_floor_percent"] == out.info["noise_floor_percent"]
    # the measured error carries the noise: e_max cannot sit far below the floor
    assert out.e_max >= 0.8 * floor


def test_fit_residual_pairs_the_output_with_the_delayed_prediction():
    """A P-I stage whose sensor lags by 3 samples, read noise-free: the fit finds the delay, and its
    residual pairs y[k + 3] with the prediction at k (n - 3 samples; the loop is fitted closely)."""
    u = ph.sinusoid(2.0, 3, 0.0, 100.0, 1e-3) * np.linspace(1.0, 0.4, 1500)
    truth = ph.fit_pi(u, np.sqrt(u + 1.0)).model  # some monotone P-I loop
    y = np.concatenate([np.zeros(3), truth.simulate(u)[:-3]])
    fit = ph.fit_pi(u, y, delay="auto")
    assert fit.delay == 3
    r = fit.residual(u, y)
    assert r.size == u.size - 3
    np.testing.assert_array_equal(r, y[3:] - fit.predict(u)[:-3])
    assert np.abs(r).max() < 1e-4 * np.ptp(y)
    with pytest.raises(ValueError, match="same length"):
        fit.residual(u, y[:-1])


def test_identify_reports_the_noise_it_cannot_take_out(tmp_path, capsys):
    """`piezohyst identify` on a P-I record with 0.01 µm of white sensor noise (known): the white part
    of the residual is that noise, and what the model misses beyond it is small."""
    from piezohyst.cli import main

    dt = 1e-3
    u = 50.0 + 50.0 * np.sin(2 * np.pi * np.arange(8000) * dt - np.pi / 2) * np.linspace(1.0, 0.3, 8000)
    truth = ph.fit_pi(u, np.sqrt(u + 1.0)).model  # some monotone P-I loop
    y = truth.simulate(u) + 0.01 * np.random.default_rng(5).standard_normal(u.size)
    path = tmp_path / "rec.csv"
    np.savetxt(path, np.column_stack([np.arange(u.size) * dt, u, y]), delimiter=",", header="t,u,y", comments="")
    assert main(["identify", str(path), "--model", "pi", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["sensor_noise_rms"] == pytest.approx(0.01, rel=0.1)
    assert out["fit_rmse_beyond_noise"] < 0.5 * out["sensor_noise_rms"]
    assert main(["identify", str(path), "--model", "pi"]) == 0
    assert "sensor noise" in capsys.readouterr().out


# -- a sensor that reads in counts (found by a helper's stage with a 16-level sensor: the fit called
# the held counts a clipped sensor, the noise floor read 0.0001 % where half a count is 5 %, and
# commissioning ended at ki = 0 without a word)


@settings(max_examples=40, deadline=None)
@given(step=st.floats(1e-4, 10.0), offset=st.floats(-1e3, 1e3), levels=st.integers(3, 4000),
       seed=st.integers(0, 2**31 - 1))
def test_sensor_resolution_is_the_grid_of_a_scaled_count(step, offset, levels, seed):
    """Law: readings that are whole counts times a scale plus an offset (as a converter gives them,
    rounded by the scaling) have that scale as their resolution, to the scaling's rounding."""
    rng = np.random.default_rng(seed)
    n = 4 * levels * 5
    counts = np.round((levels - 1) * (0.5 + 0.5 * np.sin(np.linspace(0.0, 12.0, n) + rng.uniform(0, 6))))
    if np.unique(counts).size < 2:
        counts[0] = 0.0 if counts[1] else 1.0
    y = offset + counts * step
    assert sensor_resolution(y) == pytest.approx(step, rel=1e-6)


def test_sensor_resolution_of_continuous_readings_is_none():
    rng = np.random.default_rng(1)
    t = np.arange(20_000) * 1e-4
    y = 5.0 * np.sin(2 * np.pi * t) + 1e-3 * rng.standard_normal(t.size)
    assert sensor_resolution(y) is None
    assert sensor_resolution(np.round(y, 4)) is None  # a file's 4 decimals: too many levels to tell
    assert sensor_resolution(np.r_[0.0, 1.0, 1.5, 3.7].repeat(10)) is None  # no common step
    # a noise-free simulation of a periodic input repeats its values a period later, on a grid,
    # but not from one sample to the next as a held count does (found by a reviewer)
    triangle = 15.0 * np.abs(((np.arange(4000) / 200.0) % 2.0) - 1.0)
    assert sensor_resolution(triangle) is None


def test_sensor_resolution_through_a_files_decimals_and_float32():
    """Found by a reviewer: a 12-bit converter's counts written with "%.6g" or stored as float32
    lay off the float64 grid by more than the first tolerance, and no step was found."""
    t = np.linspace(0.0, 1.0, 20_000)
    counts = np.round((0.5 + 0.4 * np.sin(2 * np.pi * t)) * 4095)
    volts = counts * (10.0 / 4095)
    step = 10.0 / 4095
    assert sensor_resolution(volts) == pytest.approx(step, rel=1e-9)
    assert sensor_resolution(np.array([float(f"{v:.6g}") for v in volts])) == pytest.approx(step, rel=1e-5)
    assert sensor_resolution(volts.astype(np.float32)) == pytest.approx(step, rel=1e-5)


class _CountingPIStage:
    """A P-I stage (9 operators, about 9 um) whose sensor reads in counts of ``step_um``."""

    u_range = (0.0, 100.0)

    def __init__(self, step_um: float, dt: float = 2e-4):
        self.model = ph.PrandtlIshlinskii(np.arange(0.0, 90.0, 10.0),
                                          [0.05, 0.02, 0.012, 0.008, 0.006, 0.004, 0.003, 0.002, 0.002])
        self.dt, self.count = dt, step_um
        self.reset()

    def reset(self):
        self._s = self.model.stepper()

    def step(self, u):
        return self.count * round(self._s.step(min(max(float(u), 0.0), 100.0)) / self.count)


def test_a_coarse_sensor_is_named_not_taken_for_clipping():
    st_ = _CountingPIStage(0.6)
    u = ph.sinusoid(1.0, 3, 0.0, 100.0, st_.dt)
    y = np.array([st_.step(v) for v in u])
    fit = ph.fit_model(u, y, st_.dt, kind="pi")
    said = " ".join(fit.warnings)
    assert "reads in steps of 0.6 (16 distinct values" in said
    assert "clipped" not in said.replace("a clipped sensor nor", "")
    # a fine sensor: no such sentence
    fine = ph.fit_model(u, st_.model.simulate(u), st_.dt, kind="pi")
    assert not any("reads in steps" in w for w in fine.warnings)


def test_commissioning_a_coarse_sensor_says_why_there_is_no_feedback_and_floors_the_noise():
    stage = _CountingPIStage(0.6)
    with pytest.warns(ph.NoFeedbackWarning, match="never answered half of the .* probe") as rec:
        ctl = ph.commission(stage)
    assert ctl.tuning.ki == 0.0
    assert "coarser than the probe" in str(rec[0].message)
    assert ctl.describe()["feedback"].startswith("none (tuned to ki = 0: the stage never answered")
    assert ctl.sensor_resolution_um == pytest.approx(0.6)
    r = ctl.track(ph.sinusoid(1.0, 3, 2.0, 8.0, stage.dt), feedback=False, learning=False, period=5000)
    assert r.info["sensor_resolution_um"] == pytest.approx(0.6)
    assert r.info["noise_floor_um"] == pytest.approx(0.3)  # half a count; the noise alone says ~0
    assert r.info["noise_floor_percent"] == pytest.approx(5.0)
