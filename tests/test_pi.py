"""Prandtl-Ishlinskii model, eqs. (3)-(4), and its inverse, eqs. (12)-(15)."""

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

import piezohyst as ph
from piezohyst import paper_values as pv
from piezohyst.models.play import pi_simulate_dense


def test_equal_thresholds_eq4():
    # eq. (4): r_i = (i - 1) / (n + 1) * max|x|
    r = ph.equal_thresholds(20, 100.0)
    assert r.shape == (20,)
    assert r[0] == 0.0
    assert r[1] == pytest.approx(100 / 21)
    assert r[-1] == pytest.approx(19 / 21 * 100)


def test_simulate_is_weighted_sum_of_play_operators(rng):
    r = ph.equal_thresholds(5, 10.0)
    w = rng.normal(size=5)
    u = rng.uniform(-10, 10, 200)
    y = ph.PrandtlIshlinskii(r, w).simulate(u)
    expected = sum(wi * ph.play_operator(u, ri) for wi, ri in zip(w, r))
    np.testing.assert_allclose(y, expected, atol=1e-12)


@pytest.mark.parametrize("kind", ["noise", "smooth"])
def test_streaming_equals_batch(rng, kind):
    model = pv.pi_model()
    u = rng.uniform(0, 100, 500) if kind == "noise" else ph.sinusoid(2.0, 1, 0.0, 100.0, 1e-3)
    s = model.stepper()
    streamed = np.array([s.step(v) for v in u])
    # the stepper is the dense loop's own step, sample for sample ...
    dense = pi_simulate_dense(u, model.thresholds, model.weights, np.zeros(model.n), 0.0, 0.0)
    np.testing.assert_array_equal(streamed, dense)
    # ... and simulate (event-driven on the sinusoid, dense on the noise) agrees to rounding
    np.testing.assert_allclose(model.simulate(u), streamed, rtol=0, atol=1e-12 * np.abs(streamed).max())
    s.reset()
    assert s.step(u[0]) == pytest.approx(model.simulate(u[:1])[0], rel=1e-12, abs=1e-12)


@st.composite
def invertible_models(draw):
    n = draw(st.integers(1, 12))
    u_max = draw(st.floats(1.0, 200.0))
    r = ph.equal_thresholds(n, u_max)
    # weights with every partial sum >= 0.05, negative weights allowed
    sums = draw(st.lists(st.floats(0.05, 3.0), min_size=n, max_size=n))
    w = np.diff(np.concatenate([[0.0], sums]))
    return ph.PrandtlIshlinskii(r, w), u_max


@given(data=invertible_models(), seed=st.integers(0, 2**31))
def test_inverse_of_forward_is_identity(data, seed):
    model, u_max = data
    rng = np.random.default_rng(seed)
    # a random piecewise-monotone signal with reversals of every size
    u = np.cumsum(rng.normal(0, u_max / 10, 300))
    y = model.simulate(u)
    np.testing.assert_allclose(model.inverse().simulate(y), u, atol=1e-9 * max(1.0, np.abs(u).max()))


@given(data=invertible_models(), seed=st.integers(0, 2**31))
def test_forward_of_inverse_is_identity(data, seed):
    model, u_max = data
    rng = np.random.default_rng(seed)
    y = np.cumsum(rng.normal(0, u_max / 10, 300))
    u = model.inverse().simulate(y)
    np.testing.assert_allclose(model.simulate(u), y, atol=1e-9 * max(1.0, np.abs(y).max()))


@given(data=invertible_models(), seed=st.integers(0, 2**31))
def test_inverse_from_a_non_zero_state_eq14(data, seed):
    # run the model on a prefix, so its operator states are an admissible memory; the inverse
    # built from that state by eq. (14) must continue exactly where the forward one stands
    model, u_max = data
    rng = np.random.default_rng(seed)
    u = np.cumsum(rng.normal(0, u_max / 10, 200))
    stepper = model.stepper()
    y_prefix = [stepper.step(v) for v in u[:100]]
    assume(len(y_prefix) == 100)
    later = model.with_state(stepper.state)
    y = later.simulate(u[100:])
    np.testing.assert_allclose(later.inverse().simulate(y), u[100:], atol=1e-9 * max(1.0, np.abs(u).max()))


def test_inverse_of_inverse_is_the_model(rng):
    model = ph.PrandtlIshlinskii(ph.equal_thresholds(6, 10.0), [1.0, 0.3, -0.2, 0.4, 0.1, -0.3], offset=2.0)
    back = model.inverse().inverse()
    np.testing.assert_allclose(back.thresholds, model.thresholds, atol=1e-12)
    np.testing.assert_allclose(back.weights, model.weights, atol=1e-12)
    assert back.offset == pytest.approx(2.0)


def test_paper_weights_invert_exactly():
    # Section III-C weights, thresholds by eq. (4) over [0, 100] V
    model = pv.pi_model()
    assert model.is_invertible
    u = ph.sinusoid(1.0, 2, 0.0, 100.0, 1e-3)
    np.testing.assert_allclose(model.inverse().simulate(model.simulate(u)), u, atol=1e-9)


def test_paper_printed_inverse_weights_do_not_follow_from_eqs_13_15():
    # Section IV-B prints w'_1 = 1.834; eq. (15) gives w'_1 = 1 / w_1 = 1 / 0.616 = 1.623
    inv = pv.pi_model().inverse()
    assert inv.weights[0] == pytest.approx(1 / 0.616)
    assert inv.weights[0] == pytest.approx(1.623, abs=5e-4)
    assert abs(inv.weights[0] - pv.PI_INVERSE_WEIGHTS_PRINTED[0]) > 0.2
    # and the printed inverse, used as a compensator, leaves ~21 V of error on a 0-100 V sinusoid
    u = ph.sinusoid(1.0, 2, 0.0, 100.0, 1e-3)
    y = pv.pi_model().simulate(u)
    printed = ph.PrandtlIshlinskii(inv.thresholds, pv.PI_INVERSE_WEIGHTS_PRINTED)
    err = np.abs(printed.simulate(y) - u).max()
    assert 19.0 < err < 23.0


def test_non_invertible_names_the_failing_partial_sum():
    model = ph.PrandtlIshlinskii(ph.equal_thresholds(4, 4.0), [1.0, -0.5, -0.6, 0.2])
    assert not model.is_invertible
    with pytest.raises(ValueError, match=r"w_1 \+ \.\.\. \+ w_3 = -0\.1"):
        model.inverse()


def test_weights_whose_inverse_overflows_are_not_invertible():
    """Weights of 1e-300 have positive partial sums, but eq. (15)'s inverse weights overflow: the
    model said "invertible" and its compensator failed on "non-finite weights" of the inverse,
    named as if they were the model's (found by fuzzing)."""
    model = ph.PrandtlIshlinskii(ph.equal_thresholds(4, 4.0), [1e-300] * 4)
    assert not model.is_invertible
    with pytest.raises(ValueError, match=r"not invertible in floating point: the inverse's weight w'_2"):
        model.compensator()
    assert ph.PrandtlIshlinskii(ph.equal_thresholds(4, 4.0), [1e-3] * 4).is_invertible


def test_offsets_round_trip(rng):
    model = ph.PrandtlIshlinskii(ph.equal_thresholds(5, 10.0), [0.8, 0.2, 0.1, -0.1, 0.05], offset=-120.0)
    u = rng.uniform(0, 10, 300)
    y = model.simulate(u)
    assert y.min() < -100
    np.testing.assert_allclose(model.inverse().simulate(y), u, atol=1e-9)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(thresholds=[1.0, 2.0], weights=[1.0, 1.0]), "thresholds must start at 0"),
        (dict(thresholds=[0.0, 2.0, 2.0], weights=[1.0, 1.0, 1.0]), "strictly increasing"),
        (dict(thresholds=[0.0, 1.0], weights=[1.0]), "weights must have one entry per threshold"),
        (dict(thresholds=[0.0, 1.0], weights=[1.0, np.nan]), "weights contains"),
        (dict(thresholds=[0.0, 1.0], weights=[1.0, 1.0], initial_state=[0.0]), "initial_state"),
        (dict(thresholds=[[0.0, 1.0]], weights=[1.0, 1.0]), "thresholds must be 1-D"),
    ],
)
def test_refuses_bad_parameters(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ph.PrandtlIshlinskii(**kwargs)


def test_refuses_bad_signals():
    model = pv.pi_model()
    with pytest.raises(ValueError, match="u contains"):
        model.simulate([0.0, np.inf])
    with pytest.raises(ValueError, match="u must be 1-D"):
        model.simulate(np.zeros((2, 2)))
    with pytest.raises(TypeError, match="u must be"):
        model.simulate("abc")
    with pytest.raises(ValueError, match="u_k must be finite"):
        model.stepper().step(float("nan"))


def test_equal_thresholds_refuses_bad_n():
    with pytest.raises(ValueError, match="n must be"):
        ph.equal_thresholds(0, 100.0)
    with pytest.raises(ValueError, match="u_max must be > 0"):
        ph.equal_thresholds(5, 0.0)


def test_parameters_are_read_only():
    model = pv.pi_model()
    with pytest.raises(ValueError):
        model.weights[0] = 3.0


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_simulate_refuses_non_finite_input(bad):
    model = pv.pi_model()
    u = np.linspace(0, 100, 50)
    u[17] = bad
    with pytest.raises(ValueError, match="u contains 1 non-finite value.*first at index 17"):
        model.simulate(u)


def test_simulate_takes_any_array_like():
    # lists, integers, strided views: the same output as the float64 array
    model = pv.pi_model()
    u = np.arange(0, 100, 3)
    ref = model.simulate(u.astype(float))
    np.testing.assert_array_equal(model.simulate(list(u)), ref)
    np.testing.assert_array_equal(model.simulate(np.repeat(u.astype(float), 2)[::2]), ref)
    with pytest.raises(ValueError, match="u must be 1-D"):
        model.simulate(np.zeros((3, 2)))
