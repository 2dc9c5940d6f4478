"""Known answers for the loop figures (piezohyst.analysis)."""

import math

import numpy as np
import pytest

import piezohyst as ph


@pytest.mark.parametrize("period", [2000, None])
def test_loop_figures_of_an_ellipse(period):
    """u = 50 + 50 cos t, y = cos(t - phi): an elliptic loop with every figure in closed form.

    At mid-range (u = 50, cos t = 0) the descending branch (t = pi/2) has y = sin(phi) and the
    ascending one (t = 3 pi/2) has y = -sin(phi): width = 2 sin(phi), in the units of y; the
    span is max y - min y = 2, so width_percent = 100 sin(phi).

    loop_figures fits a straight line to each branch over +-2 % of the input range about
    mid-range: x = (u - 50) / 50 within +-h, h = 0.04. On a branch y = x cos(phi) + sqrt(1 - x^2)
    sin(phi) ~ x cos(phi) + (1 - x^2 / 2) sin(phi); the fitted line's intercept over x spread
    evenly on [-h, h] (mean x^2 = h^2 / 3) is sin(phi) (1 - h^2 / 6), a bias of -2.7e-4 relative
    (0.59088 for 0.59104; measured 0.59089). The tolerance, 1e-3 relative, is four times that
    bias; a window of +-10 % (bias h^2 / 6 = 6.7e-3) or wider fails it.
    """
    phi = 0.3
    n = 2000  # samples per period (even, so u = 0 and u = 100 are both sampled exactly)
    t = 2 * np.pi * np.arange(3 * n) / n
    u = 50.0 + 50.0 * np.cos(t)
    y = np.cos(t - phi)
    lf = ph.loop_figures(u, y, period=period)
    assert lf.u_mid == pytest.approx(50.0, abs=1e-9)
    # sampled extremes of cos miss the true ones by at most (pi / n)^2 / 2 = 1.2e-6
    assert lf.span == pytest.approx(2.0, abs=2 * (np.pi / n) ** 2)
    assert lf.width == pytest.approx(2 * math.sin(phi), rel=1e-3)
    # and closer still to the window-biased value derived above. The window holds ~25 samples
    # (spacing 50 * 2 pi / n = 0.16 V in +-2 V), so their mean x^2 differs from h^2 / 3 by up to
    # ~ spacing / window = 8 % of the 2.7e-4 bias, ~2e-5 (measured 1.0e-5): 5e-5 allows that,
    # while a window of +-3 % already moves the bias by 3.3e-4
    h = 0.02 * 100.0 / 50.0
    assert lf.width == pytest.approx(2 * math.sin(phi) * (1 - h * h / 6), rel=5e-5)
    assert lf.width_percent == pytest.approx(100 * math.sin(phi), rel=1e-3)
