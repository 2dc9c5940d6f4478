"""Backlash (play) operator, paper eqs. (1)-(2)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import piezohyst as ph
from piezohyst.models import play as P


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


# -- the event-driven P-I kernel against the dense loop ------------------------------------------


@st.composite
def piecewise_signals(draw, max_len=400):
    """Ramps, constant stretches, noise, steps and integer-valued runs (exact ties), joined."""
    out = [draw(st.floats(-50, 50))]
    for _ in range(draw(st.integers(0, 12))):
        kind = draw(st.sampled_from(["hold", "ramp", "noise", "step", "integers"]))
        n = draw(st.integers(1, 60))
        if kind == "ramp":
            out.extend(np.linspace(out[-1], draw(st.floats(-50, 50)), n + 1)[1:])
        elif kind == "hold":
            out.extend([out[-1]] * n)
        elif kind == "noise":
            scale = draw(st.sampled_from([1e-3, 0.1, 5.0, 50.0]))
            seed = draw(st.integers(0, 2**32 - 1))
            out.extend(out[-1] + np.random.default_rng(seed).uniform(-scale, scale, n))
        elif kind == "step":
            out.append(draw(st.floats(-50, 50)))
        else:
            out.extend(float(v) for v in draw(st.lists(st.integers(-6, 6), min_size=1, max_size=n)))
    return np.array(out[:max_len])


@st.composite
def pi_setups(draw):
    m = draw(st.integers(1, 25))
    kind = draw(st.sampled_from(["equal", "integer", "random", "with ties"]))
    if kind == "equal":
        r = np.arange(m) / (m + 1) * draw(st.floats(1.0, 100.0))
    elif kind == "integer":  # integer thresholds meet integer inputs in exact ties
        r = np.arange(m, dtype=float)
    elif kind == "random":
        r = np.sort(np.array(draw(st.lists(st.floats(0, 40), min_size=m, max_size=m))))
    else:
        r = np.sort(np.array(draw(st.lists(st.sampled_from([0.0, 0.5, 1.0, 3.0]), min_size=m, max_size=m))))
    w = np.array(draw(st.lists(st.floats(-2, 2), min_size=m, max_size=m)))
    state = draw(st.sampled_from(["rest", "constant", "reached", "arbitrary"]))
    if state == "rest":
        z0 = np.zeros(m)
    elif state == "constant":
        z0 = np.full(m, draw(st.floats(-50, 50)))
    elif state == "reached":  # a state the model can be in: where a run ended
        z0 = np.zeros(m)
        P.pi_simulate_dense(draw(piecewise_signals(max_len=40)), r, w, z0, 0.0, 0.0)
    else:  # any state at all (the kernel runs dense until the state is consistent)
        z0 = np.array(draw(st.lists(st.floats(-60, 60), min_size=m, max_size=m)))
    return r, w, z0


def _scale(u, r, w, z0, out_off=0.0):
    # the size of the terms of eq. (3): rounding differences are relative to it
    return float(np.abs(w).sum() * (np.abs(u).max() + r.max() + np.abs(z0).max()) + abs(out_off) + 1.0)


@given(setup=pi_setups(), u=piecewise_signals(), in_off=st.sampled_from([0.0, 3.25]),
       out_off=st.sampled_from([0.0, -7.5]))
def test_event_driven_kernel_equals_the_dense_loop(setup, u, in_off, out_off):
    r, w, z0 = setup
    zd, ze = z0.copy(), z0.copy()
    yd = P.pi_simulate_dense(u, r, w, zd, in_off, out_off)
    ye = P.pi_simulate_events(u, r, w, ze, in_off, out_off)
    tol = 1e-12 * r.size * _scale(u - in_off, r, w, z0, out_off)
    np.testing.assert_allclose(ye, yd, rtol=0, atol=tol)
    # the final operator states too (where the next call starts)
    np.testing.assert_allclose(ze, zd, rtol=0, atol=1e-12 * (np.abs(u).max() + r.max() + np.abs(z0).max() + 5))


@given(setup=pi_setups(), u=piecewise_signals())
def test_automatic_choice_equals_the_dense_loop(setup, u):
    r, w, z0 = setup
    zd, za = z0.copy(), z0.copy()
    yd = P.pi_simulate_dense(u, r, w, zd, 0.0, 0.0)
    ya = P.pi_simulate(u, r, w, za, 0.0, 0.0)
    np.testing.assert_allclose(ya, yd, rtol=0, atol=1e-12 * r.size * _scale(u, r, w, z0))
    np.testing.assert_allclose(za, zd, rtol=0, atol=1e-12 * (np.abs(u).max() + r.max() + np.abs(z0).max() + 5))


@given(setup=pi_setups(), u=piecewise_signals(), extra=st.integers(0, 40), k0=st.integers(0, 5))
def test_four_samples_at_once_equals_the_dense_loop(setup, u, extra, k0):
    # the dense loop of the automatic choice composes four clamps into one: the states must come
    # out bit for bit (only min and max), the outputs to rounding; also past 32 operators
    r, w, z0 = setup
    if extra:
        r = np.concatenate([r, r.max() + np.arange(1, extra + 1)])
        w = np.concatenate([w, np.linspace(-1, 1, extra)])
        z0 = np.concatenate([z0, np.full(extra, z0[-1])])
    k0 = min(k0, u.size)
    zd, zf = z0.copy(), z0.copy()
    yd = P.pi_simulate_dense(u[k0:], r, w, zd, 1.5, -2.0)
    yf = np.full(u.size, np.nan)
    P._pi_dense_fast_into(u, r, w, zf, 1.5, -2.0, yf, k0, u.size)
    np.testing.assert_array_equal(zf, zd)
    np.testing.assert_allclose(yf[k0:], yd, rtol=0, atol=1e-12 * r.size * _scale(u - 1.5, r, w, z0, -2.0))
    assert np.isnan(yf[:k0]).all()  # samples before k0 untouched


def test_event_driven_kernel_unsorted_thresholds_and_long_records(rng):
    # unsorted thresholds: no prefix structure, so the kernel must stay on the dense loop
    r = rng.permutation(np.arange(8.0))
    w = rng.normal(size=8)
    u = np.cumsum(rng.normal(0, 2, 5000))
    np.testing.assert_allclose(P.pi_simulate_events(u, r, w, np.zeros(8), 0.0, 0.0),
                               P.pi_simulate_dense(u, r, w, np.zeros(8), 0.0, 0.0), atol=1e-9)
    # a long smooth record with noise: many reversals, a deep stack of frozen segments
    m = 60
    r = np.arange(m) / (m + 1) * 100.0
    w = rng.uniform(-0.2, 1.0, m)
    t = np.arange(200_000) * 1e-4
    u = 50 + 45 * np.sin(2 * np.pi * t) * np.exp(-0.1 * t) + rng.normal(0, 0.5, t.size)
    yd = P.pi_simulate_dense(u, r, w, np.zeros(m), 0.0, 0.0)
    ye = P.pi_simulate_events(u, r, w, np.zeros(m), 0.0, 0.0)
    np.testing.assert_allclose(ye, yd, rtol=0, atol=1e-12 * m * _scale(u, r, w, np.zeros(1)))


def test_the_choice_follows_the_input():
    # a smooth record moves a few operators per reversal: event-driven; white noise reverses at
    # nearly every sample and moves many: dense
    r = np.arange(20) / 21 * 100.0
    smooth = 50 + 45 * np.sin(2 * np.pi * np.arange(100_000) * 1e-4)
    noise = np.random.default_rng(0).uniform(0, 100, 100_000)
    assert P.prefers_events(smooth, r)
    assert not P.prefers_events(noise, r)
    turns, moves = P.event_work(noise, r)
    # uniform white noise: 2/3 of the samples are reversals (a middle one of three)
    assert turns == pytest.approx(2 / 3, abs=0.03)
    assert moves > 1.0
    turns, moves = P.event_work(smooth, r)
    assert turns < 1e-3 and moves < 0.01


def test_consistent_states():
    r = np.arange(5.0)
    assert P.state_is_consistent(r, np.zeros(5))
    z = np.zeros(5)
    P.pi_simulate_dense(np.array([3.0, -2.5, 7.0, 1.0]), r, np.ones(5), z, 0.0, 0.0)
    assert P.state_is_consistent(r, z)  # any state the model reaches
    assert not P.state_is_consistent(r, np.array([0.0, 0.0, 5.0, 0.0, 0.0]))
    assert not P.state_is_consistent(r[::-1].copy(), np.zeros(5))  # unsorted thresholds


# -- streamed normal equations -------------------------------------------------------------------
@given(setup=pi_setups(), u=piecewise_signals(), chunk=st.integers(1, 50),
       delays=st.lists(st.integers(0, 5), min_size=1, max_size=4))
def test_pi_gram_equals_the_dense_matrix(setup, u, chunk, delays):
    r, _, z0 = setup
    r = np.abs(r)
    n = u.size
    if n < 8:
        u = np.concatenate([u, np.linspace(u[-1], 0.0, 8)])
        n = u.size
    y = np.sin(np.arange(n)) * 3 + u
    g = P.pi_gram(u, r, y, delays=delays, initial_state=z0, chunk_rows=chunk)
    z = P.play_outputs(u, r, z0.copy())
    for i, d in enumerate(delays):
        zd, yd = z[: n - d], y[d:]
        scale = (np.abs(zd).max() + 1) * (np.abs(yd).max() + np.abs(zd).max() + 1) * n
        np.testing.assert_allclose(g.gram[i], zd.T @ zd, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(g.zty[i], zd.T @ yd, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(g.zsum[i], zd.sum(axis=0), rtol=0, atol=1e-12 * scale)
        assert g.ysum[i] == pytest.approx(yd.sum(), abs=1e-12 * scale)
        assert g.yty[i] == pytest.approx(yd @ yd, abs=1e-12 * scale)
        assert g.n_samples[i] == n - d
        ata, aty, yty, nn = g.normal_equations(i)
        a = np.hstack([zd, np.ones((n - d, 1))])
        np.testing.assert_allclose(ata, a.T @ a, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(aty, a.T @ yd, rtol=0, atol=1e-12 * scale)
        assert nn == n - d and yty == g.yty[i]


def _gram_sums(kernel, u, r, z, y, delays, *args):
    """A Gram kernel's accumulators over the rows u[:N - max(delays)] from the states z."""
    m, d = r.size, np.asarray(delays, dtype=np.int64)
    g, b, s, zz = np.zeros((m, m)), np.zeros((m, d.size)), np.zeros(m), z.copy()
    kernel(u[: u.size - int(d.max())], r, zz, y, d, g, b, s, *args)
    return np.triu(g), b, s, zz


@st.composite
def gram_inputs(draw):
    """Input records for the Gram kernels: joined pieces, smooth sines (long runs, cut every
    _GRAM_RUN rows), sines with noise, white noise."""
    kind = draw(st.sampled_from(["pieces", "sine", "noisy sine", "white"]))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    if kind == "pieces":
        u = draw(piecewise_signals())
    else:
        n = draw(st.integers(2, 6000))
        t = np.arange(n) / draw(st.sampled_from([50.0, 500.0, 3000.0]))
        u = draw(st.floats(-20, 20)) + draw(st.floats(1, 60)) * np.sin(2 * np.pi * t + draw(st.floats(0, 6)))
        if kind == "noisy sine":
            u += rng.normal(0, draw(st.sampled_from([1e-3, 0.05, 1.0])), n)
        elif kind == "white":
            u = rng.uniform(-50, 50, n)
    if u.size < 12:
        u = np.concatenate([u, np.linspace(u[-1], 0.0, 12)])
    y = np.sin(np.arange(u.size) * 0.37) * 3 + 0.5 * u + rng.normal(0, 0.1, u.size)
    return u, y


@given(setup=pi_setups(), data=gram_inputs(), delays=st.lists(st.integers(0, 10), min_size=1, max_size=11),
       chunk=st.sampled_from([7, 64, 500, 4096]), event_rows=st.sampled_from([0, 1, 6]))
def test_event_driven_normal_equations_equal_the_dense_ones(setup, data, delays, chunk, event_rows):
    # Z'Z, Z'y_d, Z'1 run by run (event-driven) are the dense pass's sums to rounding, on any
    # input (white noise included: event_rows=0 never hands over to the dense pass), thresholds
    # (unsorted ones and inconsistent states go dense) and delays; the final states too
    r, _, z0 = setup
    u, y = data
    delays = [d for d in delays if d <= u.size - 2] or [0]
    if setup[0].size > 1 and chunk == 7:
        r = r[::-1].copy()  # unsorted thresholds too
    ref = _gram_sums(P._gram_into, u, r, z0, y, delays)
    got = _gram_sums(P._gram_auto_into, u, r, z0, y, delays, chunk, event_rows)
    zmax = np.abs(u).max() + r.max() + np.abs(z0).max() + 1
    tol = 1e-13 * u.size * zmax * (zmax + np.abs(y).max())
    for a, b in zip(got[:3], ref[:3]):
        np.testing.assert_allclose(a, b, rtol=0, atol=tol)
    np.testing.assert_allclose(got[3], ref[3], rtol=0, atol=1e-12 * zmax)
    if np.all(np.diff(r) >= 0) and P.state_is_consistent(r, z0):  # and run by run throughout
        ev = _gram_sums(lambda *a: P._gram_events_into(*a, 0, u.size - max(delays), 0), u, r, z0, y, delays)
        for a, b in zip(ev[:3], ref[:3]):
            np.testing.assert_allclose(a, b, rtol=0, atol=tol)
        np.testing.assert_allclose(ev[3], ref[3], rtol=0, atol=1e-12 * zmax)


def test_event_driven_normal_equations_choose_by_the_input(rng):
    # a smooth record goes run by run, white noise hands over to the dense pass within _GRAM_TRY
    # rows of a chunk: the two give the same sums either way
    r = ph.equal_thresholds(20, 100.0)
    t = np.arange(30_000) * 1e-4
    smooth = 50 + 50 * np.sin(2 * np.pi * t)
    noise = rng.uniform(0, 100, t.size)
    y = rng.normal(size=t.size)
    d = np.arange(4, dtype=np.int64)
    for u, done in ((smooth, 4096), (noise, P._GRAM_TRY)):
        z = np.zeros(20)
        stop = P._gram_events_into(u, r, z, y, d, np.zeros((20, 20)), np.zeros((20, 4)), np.zeros(20), 0, 4096,
                                   P._GRAM_EVENT_ROWS)
        assert stop == done if u is smooth else stop <= 2 * done
        ref = _gram_sums(P._gram_into, u, r, np.zeros(20), y, d)
        got = _gram_sums(P._gram_auto_into, u, r, np.zeros(20), y, d, P._GRAM_CHUNK, P._GRAM_EVENT_ROWS)
        for a, b in zip(got[:3], ref[:3]):
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())
        np.testing.assert_array_equal(got[3], ref[3])


@pytest.mark.parametrize("m, chunk", [(70, 100), (70, None), (64, None)])
def test_pi_gram_with_many_operators(rng, m, chunk):
    # past 64 operators pi_gram goes through BLAS chunk by chunk: the same sums
    u = np.cumsum(rng.normal(0, 2, 3000))
    y = rng.normal(size=u.size)
    r = np.sort(rng.uniform(0, 30, m))
    z0 = np.zeros(m)
    g = P.pi_gram(u, r, y, delays=[0, 3], chunk_rows=chunk)
    z = P.play_outputs(u, r, z0.copy())
    for i, d in enumerate([0, 3]):
        zd, yd = z[: u.size - d], y[d:]
        scale = (np.abs(zd).max() + 1) ** 2 * u.size
        np.testing.assert_allclose(g.gram[i], zd.T @ zd, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(g.zty[i], zd.T @ yd, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(g.zsum[i], zd.sum(axis=0), rtol=0, atol=1e-12 * scale)


def test_pi_gram_gives_the_least_squares_fit(rng):
    # the weights solved from the streamed normal equations are those of the dense problem
    r = np.arange(6) / 7 * 5.0  # every operator moves both ways over the 0-10 input
    w = np.array([0.9, 0.3, -0.1, 0.2, 0.05, 0.1])
    t = np.arange(20_000) * 1e-3
    u = 5 + 5 * np.sin(2 * np.pi * t) * (0.2 + 0.8 * (t % 4) / 4)
    y = P.pi_simulate_dense(u, r, w, np.zeros(6), 0.0, 1.5) + rng.normal(0, 0.01, u.size)
    y_lag = np.concatenate([np.zeros(2), y[:-2]])  # a sensor two samples late
    g = P.pi_gram(u, r, y_lag, delays=[0, 1, 2, 3], chunk_rows=1000)
    ata, aty, yty, nn = g.normal_equations(2)
    x = np.linalg.solve(ata, aty)
    z = P.play_outputs(u, r, np.zeros(6))
    a = np.hstack([z[:-2], np.ones((u.size - 2, 1))])
    x_dense = np.linalg.lstsq(a, y_lag[2:], rcond=None)[0]
    np.testing.assert_allclose(x, x_dense, atol=1e-8)
    np.testing.assert_allclose(x[:6], w, atol=5e-3)
    rmse = np.sqrt((x @ ata @ x - 2 * x @ aty + yty) / nn)
    assert rmse == pytest.approx(np.sqrt(np.mean((a @ x_dense - y_lag[2:]) ** 2)), rel=1e-6)
    # and the right delay has the smallest residual
    rmses = []
    for i in range(4):
        ata, aty, yty, nn = g.normal_equations(i)
        xi = np.linalg.solve(ata, aty)
        rmses.append((xi @ ata @ xi - 2 * xi @ aty + yty) / nn)
    assert int(np.argmin(rmses)) == 2


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(y=np.zeros(5)), "same length"),
        (dict(delays=[-1]), "delays must lie"),
        (dict(delays=[9]), "delays must lie"),
        (dict(delays=[0.5]), "integers"),
        (dict(delays=[]), "non-empty"),
        (dict(initial_state=[0.0]), "initial_state"),
        (dict(chunk_rows=0), "chunk_rows"),
        (dict(thresholds=[-1.0, 1.0]), "thresholds must be >= 0"),
    ],
)
def test_pi_gram_refuses_bad_input(kwargs, match):
    args = dict(u=np.arange(10.0), thresholds=[0.0, 1.0], y=np.arange(10.0))
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        P.pi_gram(args.pop("u"), args.pop("thresholds"), args.pop("y"), **args)


@given(u=piecewise_signals(), dmax=st.integers(0, 6), frac=st.floats(0.3, 0.9), m=st.integers(1, 70))
def test_split_normal_equations_add_up_to_the_whole_record(u, dmax, frac, m):
    # fit_pi(delay="auto") takes the fitting part's and the held-out rows' normal equations
    # from one pass: the part's are pi_gram's of the first n_fit samples, and part + held out
    # are pi_gram's of the whole record, for every delay
    from piezohyst.identify.pi import _split_gram

    if u.size < 4 * dmax + 16:
        u = np.concatenate([u, np.linspace(u[-1], -u[-1], 4 * dmax + 16)])
    n = u.size
    y = np.cos(np.arange(n) * 0.7) + u
    r = np.linspace(0.0, np.ptp(u) / 2 + 1.0, m)
    delays = np.arange(dmax + 1, dtype=np.int64)
    n_fit = int(round(frac * n))
    part, held = _split_gram(u, y, r, delays, n_fit)
    ref_part = P.pi_gram(u[:n_fit], r, y[:n_fit], delays=delays)
    whole = P.pi_gram(u, r, y, delays=delays)
    scale = (np.abs(u).max() + r.max() + 1) * (np.abs(y).max() + np.abs(u).max() + r.max() + 1) * n
    for name in ("gram", "zty", "zsum", "ysum", "yty"):
        np.testing.assert_allclose(getattr(part, name), getattr(ref_part, name), rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(getattr(part, name) + getattr(held, name), getattr(whole, name),
                                   rtol=0, atol=1e-11 * scale)
    np.testing.assert_array_equal(held.n_samples, n - n_fit)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), stride=st.integers(1, 40), n=st.integers(1, 3000), levels=st.integers(1, 8),
       shape=st.sampled_from(["walk", "smooth", "quantised"]))
def test_strided_regressors_are_every_strideth_row(seed, stride, n, levels, shape):
    """The model search's strided regressors (identify/linear.py, records longer than its row
    budget) are exactly every stride-th row of the full matrices, for P-I and Preisach alike;
    the Preisach kernel steps only kept rows and turning points, and its hysterons end in the
    state that stepping every sample leaves (inputs with many turns, smooth ones, and quantised
    ones that hold a value for several samples)."""
    from piezohyst.models.play import play_outputs, play_outputs_strided_into
    from piezohyst.models.preisach import demagnetised_state, grid_thresholds, preisach_outputs, preisach_outputs_into

    rng = np.random.default_rng(seed)
    if shape == "walk":
        u = np.cumsum(rng.normal(0.0, 1.0, n))
    else:
        t = np.arange(n) / 500.0
        u = 5.0 * np.sin(2 * np.pi * (1.0 + rng.uniform(0, 3)) * t) * np.exp(-t * rng.uniform(0, 2)) + rng.normal()
        if shape == "quantised":
            u = np.round(u * 4.0) / 4.0
    r = np.linspace(0.0, 3.0, 6)
    rows = -(-n // stride)
    got = np.empty((rows, 6))
    z_strided, z_every = np.zeros(6), np.zeros(6)
    play_outputs_strided_into(u, r, z_strided, stride, got)
    assert np.array_equal(play_outputs(u, r, z_every)[::stride], got)
    assert np.array_equal(z_strided, z_every)
    lo, hi = float(u.min()) - 1.0, float(u.max()) + 1.0
    a, b, d = grid_thresholds(lo, hi, levels)
    z0 = demagnetised_state(a, b, d, 0.0)
    got = np.empty((rows, a.size))
    z_strided, z_every = z0.copy(), z0.copy()
    preisach_outputs_into(u, a, b, 1.0 / d, z_strided, got, stride)
    assert np.array_equal(preisach_outputs(u, a, b, 1.0 / d, z_every)[::stride], got)
    assert np.array_equal(z_strided, z_every)
