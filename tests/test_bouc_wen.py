"""Bouc-Wen model, paper eqs. (7)-(8)."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

import piezohyst as ph
from piezohyst import paper_values as pv
from piezohyst.models.bouc_wen import bw_h_update, expm_small, solve_ivp_reference

DT = 1e-4


def test_paper_model_loop_at_1hz():
    # Section III-B parameters, 1 Hz, 0-100 V: span about 2 um and a loop width of 10-15 % of
    # the span (Section I: "as high as 10-15% of the span of the motion")
    bw = pv.bouc_wen_model()
    u = ph.sinusoid(1.0, 2, 0.0, 100.0, DT)
    x_um = bw.simulate(u, DT) * 1e6
    figs = ph.loop_figures(u, x_um)
    assert 1.8 < figs.span < 2.2
    assert 12.0 < figs.width_percent < 15.0


def test_resonance_of_paper_parameters():
    bw = pv.bouc_wen_model()
    assert bw.natural_frequency_hz == pytest.approx(1698.3, abs=0.5)  # sqrt(8.54e7/0.75)/2pi
    assert bw.damping_ratio == pytest.approx(27.96 / (2 * np.sqrt(8.54e7 * 0.75)))


@pytest.mark.parametrize("gamma", [0.0, 0.03])
def test_simulate_matches_solve_ivp_within_1nm(gamma):
    bw = ph.BoucWen(**{**pv.BOUC_WEN, "gamma": gamma})
    u = ph.sinusoid(2.0, 1, 0.0, 100.0, DT)
    x_ref, h_ref = solve_ivp_reference(bw, u, DT)
    x = bw.simulate(u, DT)
    assert np.abs(x - x_ref).max() < 1e-9  # metres: 1 nm
    assert np.abs(bw.hysteresis(u) - h_ref).max() < 1e-11


@pytest.mark.parametrize("h0, du, gamma", [(-5e-8, 40.0, 0.05), (5e-8, -40.0, 0.05), (-5e-8, 40.0, 0.1), (1e-8, 10.0, -0.03)])
def test_hysteresis_increment_is_exact_across_sign_change(h0, du, gamma):
    # dh/du = alpha d1 - beta s h - gamma |h|, integrated over u with solve_ivp (tight tolerances)
    ad1, beta = 0.472 * 2.15e-8, 0.072
    s = np.sign(du)

    def rhs(uu, h):
        return [ad1 - beta * s * h[0] - gamma * abs(h[0])]

    sol = solve_ivp(rhs, (0.0, du), [h0], rtol=1e-12, atol=1e-20, method="DOP853")
    assert bw_h_update(h0, du, ad1, beta, gamma) == pytest.approx(sol.y[0, -1], rel=1e-8, abs=1e-18)


def test_hysteresis_is_rate_independent():
    bw = pv.bouc_wen_model()
    slow = ph.sinusoid(1.0, 1, 0.0, 100.0, 1e-4)
    fast = slow[::10]  # the same path, fewer samples: h at shared samples must agree
    np.testing.assert_allclose(bw.hysteresis(slow)[::10], bw.hysteresis(fast), atol=1e-15)


def test_streaming_equals_batch():
    bw = pv.bouc_wen_model()
    u = ph.sinusoid(3.0, 1, 0.0, 100.0, DT)
    s = bw.stepper(DT)
    np.testing.assert_array_equal(np.array([s.step(v) for v in u]), bw.simulate(u, DT))
    s.reset()
    assert s.step(u[1]) == bw.simulate(u[1:2], DT)[0]


def test_zoh_and_foh_differ_by_about_half_a_sample():
    bw = pv.bouc_wen_model()
    u = ph.sinusoid(1.0, 1, 0.0, 100.0, DT)
    diff = np.abs(bw.simulate(u, DT, hold="zoh") - bw.simulate(u, DT, hold="foh")).max()
    # half a sample of the fastest slope: pi * f * 2.15 um * dt / 2 ~ 0.34 nm
    assert 0.1e-9 < diff < 1e-9


def test_expm_small_matches_scipy(rng):
    for scale in (1e-3, 1.0, 30.0):
        a = rng.normal(size=(4, 4)) * scale
        np.testing.assert_allclose(expm_small(a), expm(a), rtol=1e-10, atol=1e-12)


def test_quasi_static_is_d1_u_minus_h():
    bw = pv.bouc_wen_model()
    u = ph.sinusoid(1.0, 1, 0.0, 100.0, 1e-3)
    np.testing.assert_allclose(bw.quasi_static(u), bw.d1 * u - bw.hysteresis(u))


@pytest.mark.parametrize("name, value", [("m", 0.0), ("k", -1.0), ("d1", 0.0), ("b", -1.0), ("alpha", np.nan)])
def test_refuses_bad_parameters(name, value):
    params = {**pv.BOUC_WEN, name: value}
    with pytest.raises(ValueError, match=name):
        ph.BoucWen(**params)


def test_refuses_bad_dt_and_signal():
    bw = pv.bouc_wen_model()
    with pytest.raises(ValueError, match="dt must be > 0"):
        bw.simulate([0.0, 1.0], 0.0)
    with pytest.raises(ValueError, match="u contains"):
        bw.simulate([0.0, np.nan], DT)
    with pytest.raises(ValueError, match="hold"):
        bw.simulate([0.0, 1.0], DT, hold="cubic")
    with pytest.raises(TypeError, match="m must be a real number"):
        ph.BoucWen(**{**pv.BOUC_WEN, "m": "heavy"})
