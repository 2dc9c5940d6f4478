"""Backlash (play) operator, paper eqs. (1)-(2)."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import piezohyst as ph


def reference_play(x, r, y0):
    """Eqs. (1)-(2) written out literally in plain Python."""
    out = []
    y_prev = y0
    for xk in x:
        y_prev = max(xk - r, min(xk + r, y_prev))
        out.append(y_prev)
    return np.array(out)


signals = arrays(np.float64, st.integers(1, 60), elements=st.floats(-100, 100))


@given(x=signals, r=st.floats(0, 50), y0=st.floats(-50, 50))
def test_play_matches_the_equations(x, r, y0):
    np.testing.assert_array_equal(ph.play_operator(x, r, y0), reference_play(x, r, y0))


def test_initial_consistency_eq2():
    # eq. (2): y(0) = max{x(0) - r, min{x(0) + r, y0}}
    assert ph.play_operator([10.0], 2.0, 0.0)[0] == 8.0
    assert ph.play_operator([-10.0], 2.0, 0.0)[0] == -8.0
    assert ph.play_operator([1.0], 2.0, 0.5)[0] == 0.5


def test_zero_threshold_is_identity():
    x = np.linspace(-3, 5, 50) ** 2
    np.testing.assert_array_equal(ph.play_operator(x, 0.0), x)


def test_backlash_loop_width_is_2r():
    x = np.concatenate([np.linspace(0, 10, 101), np.linspace(10, 0, 101)])
    y = ph.play_operator(x, 1.0)
    # on the way up the output trails by r, on the way down it leads by r
    assert y[100] == pytest.approx(9.0)
    i5_up, i5_down = 50, 151
    assert y[i5_down] - y[i5_up] == pytest.approx(2.0)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_refuses_non_finite(bad):
    with pytest.raises(ValueError, match="x contains"):
        ph.play_operator([0.0, bad], 1.0)


def test_refuses_negative_threshold():
    with pytest.raises(ValueError, match="r must be"):
        ph.play_operator([0.0, 1.0], -1.0)


def test_refuses_2d():
    with pytest.raises(ValueError, match="x must be 1-D"):
        ph.play_operator(np.zeros((3, 2)), 1.0)
