"""VirtualRig: the figures issue #4 asks of it, with the paper's sections quoted."""

import warnings

import numpy as np
import pytest

import piezohyst as ph
from piezohyst.rig import RigSettings

DT = 1e-4


def loop(rig, freq):
    u = ph.sinusoid(freq, 3, 0.0, 100.0, rig.dt)
    ds = rig.excite(u)
    return ph.loop_figures(ds.u, ds.y, period=int(round(1 / (freq * rig.dt))))


def test_is_a_plant():
    assert isinstance(ph.VirtualRig(), ph.Plant)


def test_span_and_loop_width_at_1hz():
    # Section I: open-loop hysteresis error "as high as 10-15% of the span of the motion"
    f1 = loop(ph.VirtualRig(seed=0), 1.0)
    assert 1.9 < f1.span < 2.4
    assert 10.0 < f1.width_percent < 15.0


def test_loop_widens_with_frequency():
    # Section III-A / Fig. 2: "the width of the hysteretic loop increases as the excitation
    # frequency increases"
    rig = ph.VirtualRig(seed=0)
    w1, w3, w5 = (loop(rig, f).width for f in (1.0, 3.0, 5.0))
    assert w1 < w3 < w5
    assert w5 >= 1.3 * w1


def test_creep_after_a_step():
    rig = ph.VirtualRig(seed=0)
    ds = rig.excite(np.full(int(10.05 / DT), 50.0))

    def around(t):  # 20 ms average: the step rings the 1.7 kHz resonance for a while
        return ds.y[int((t - 0.01) / DT): int((t + 0.01) / DT)].mean()

    drift = (around(10.0) - around(0.1)) / around(0.1)
    assert 0.01 <= drift <= 0.05


def test_noise_rms_at_rest_matches_setting():
    for noise in (0.003, 0.01):
        rig = ph.VirtualRig(seed=3, noise_rms_um=noise)
        y = rig.excite(np.zeros(20000)).y
        assert np.std(y) == pytest.approx(noise, rel=0.2)


def test_same_seed_same_run_other_seed_only_noise():
    u = ph.sinusoid(3.0, 1, 0.0, 100.0, DT)
    a = ph.VirtualRig(seed=1).excite(u).y
    b = ph.VirtualRig(seed=1).excite(u).y
    c = ph.VirtualRig(seed=2).excite(u).y
    np.testing.assert_array_equal(a, b)
    diff = a - c
    assert 0 < np.std(diff) < 3 * 0.003 * np.sqrt(2)  # noise only: a few nm, no systematic part
    assert abs(np.mean(diff)) < 0.001


def test_step_and_excite_are_the_same_kernel():
    u = ph.sinusoid(5.0, 1, 0.0, 100.0, DT)
    rig = ph.VirtualRig(seed=4)
    batch = rig.excite(u).y
    rig.reset()
    stream = np.array([rig.step(v) for v in u])
    np.testing.assert_array_equal(stream, batch)


def test_one_sample_delay():
    rig = ph.VirtualRig(seed=0, noise_rms_um=0.0)
    u = np.concatenate([np.zeros(10), np.full(10, 50.0)])
    y = rig.excite(u).y
    rig0 = ph.VirtualRig(seed=0, noise_rms_um=0.0, delay_samples=0)
    y0 = rig0.excite(u).y
    np.testing.assert_array_equal(y[1:], y0[:-1])
    assert abs(y[0]) < 5.0 / 2**16  # the reading at rest, quantised


def test_clipping_is_counted_and_reported():
    rig = ph.VirtualRig(seed=0)
    u = np.array([0.0, 50.0, 120.0, 130.0, -5.0, 10.0])
    with pytest.warns(ph.ClippingWarning, match="3 of 6 commands"):
        ds = rig.excite(u)
    assert ds.meta["clipped_samples"] == 3
    assert rig.clipped == 3
    # clipped means the amplifier delivered at most 100 V: same output as asking 100 V
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        a = ph.VirtualRig(seed=0, noise_rms_um=0).excite([0.0, 150.0, 150.0]).y
    b = ph.VirtualRig(seed=0, noise_rms_um=0).excite([0.0, 100.0, 100.0]).y
    np.testing.assert_array_equal(a, b)


def test_quantisation_step():
    rig = ph.VirtualRig(seed=0, adc_bits=8, noise_rms_um=0.0)
    y = rig.excite(ph.sinusoid(1.0, 1, 0.0, 100.0, 1e-3)).y
    q = 5.0 / 256
    np.testing.assert_allclose((y + 1.0) / q, np.round((y + 1.0) / q), atol=1e-9)


def test_variants_are_settable():
    base = loop(ph.VirtualRig(seed=0), 1.0)
    skew = ph.VirtualRig(seed=0, gamma=0.03)
    assert skew.settings.gamma == 0.03
    assert loop(skew, 1.0).width != pytest.approx(base.width, rel=0.01)
    s = RigSettings(creep_scale=2.0)
    np.testing.assert_allclose(s.effective_gains()[1:], 2 * np.array(RigSettings().kv_gain[1:]))
    assert RigSettings.from_dict(s.to_dict()) == s


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(dt=0.0), "dt must be > 0"),
        (dict(u_min=100.0, u_max=0.0), "u_max must be greater"),
        (dict(kv_tau=(1.0,), kv_gain=(0.1, 0.2)), "same length"),
        (dict(delay_samples=-1), "delay_samples"),
        (dict(noise_rms_um=-1.0), "noise_rms_um"),
    ],
)
def test_refuses_bad_settings(kw, match):
    with pytest.raises(ValueError, match=match):
        ph.VirtualRig(**kw)


def test_refuses_unknown_setting_in_dict():
    with pytest.raises(ValueError, match="unknown rig setting"):
        RigSettings.from_dict({"colour": "red"})


def test_refuses_non_finite_command():
    with pytest.raises(ValueError, match="finite"):
        ph.VirtualRig().step(float("nan"))
