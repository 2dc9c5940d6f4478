"""Identification: fit_pi (lsq, pso) and fit_bouc_wen."""

import numpy as np
import pytest

import piezohyst as ph
from piezohyst import paper_values as pv

DT = 1e-4


def rich_excitation(n=6000, u_max=100.0):
    """Sinusoids of decaying amplitude: minor loops that excite every threshold."""
    t = np.arange(n) / n
    return u_max * 0.5 * (1 - np.cos(2 * np.pi * 6 * t)) * (1 - 0.8 * t)


def test_lsq_recovers_known_weights():
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(8, 100.0), [0.7, 0.2, -0.1, 0.15, 0.05, -0.05, 0.1, 0.02])
    u = rich_excitation()
    fit = ph.fit_pi(u, true.simulate(u), n=8, u_max=100.0, fit_offset=False)
    np.testing.assert_allclose(fit.model.weights, true.weights, atol=1e-6)
    assert fit.rmse < 1e-9


def test_lsq_recovers_paper_weights_and_offset():
    true = pv.pi_model()
    u = rich_excitation(8000)
    y = true.simulate(u) + 3.0
    fit = ph.fit_pi(u, y, n=20, u_max=100.0)
    np.testing.assert_allclose(fit.model.weights, true.weights, atol=1e-6)
    assert fit.model.offset == pytest.approx(3.0, abs=1e-6)


def test_lsq_models_are_invertible_even_when_the_data_are_not():
    # data from a model whose 3rd partial sum is negative: the constrained fit stays invertible
    bad = ph.PrandtlIshlinskii(ph.equal_thresholds(4, 10.0), [1.0, -0.5, -0.7, 1.0])
    u = rich_excitation(3000, 10.0)
    fit = ph.fit_pi(u, bad.simulate(u), n=4, u_max=10.0)
    assert not bad.is_invertible
    assert fit.model.is_invertible
    assert np.all(fit.model.partial_sums >= fit.info["margin"] * (1 - 1e-9))


def test_lsq_is_the_optimum_pso_is_not_better(rng):
    bw = pv.bouc_wen_model()
    u = ph.sinusoid(1.0, 2, 0.0, 100.0, 5e-4)
    y = bw.simulate(u, 5e-4) * 1e6 + rng.normal(0, 0.002, u.size)
    lsq = ph.fit_pi(u, y, n=20, method="lsq")
    pso = ph.fit_pi(u, y, n=20, method="pso", seed=0)
    assert lsq.rmse <= pso.rmse * (1 + 1e-9)
    assert pso.model.is_invertible
    assert pso.nfev == 40 * 201


def test_pso_fit_is_repeatable():
    u = rich_excitation(2000)
    y = pv.pi_model().simulate(u)
    a = ph.fit_pi(u, y, method="pso", seed=3, max_iter=30)
    b = ph.fit_pi(u, y, method="pso", seed=3, max_iter=30)
    np.testing.assert_array_equal(a.model.weights, b.model.weights)


def test_delay_is_found():
    true = pv.pi_model()
    u = rich_excitation(4000)
    y = np.concatenate([[0.0, 0.0, 0.0], true.simulate(u)[:-3]])  # three samples of sensor lag
    fit = ph.fit_pi(u, y, n=20, u_max=100.0, delay="auto", max_auto_delay=6)
    assert fit.delay == 3
    assert fit.rmse < 1e-8



def test_stacked_bounded_least_squares_equal_one_by_one(rng):
    # the delay search solves its problems as one stack: each row is bounded_lstsq_gram's optimum,
    # whether the unconstrained optimum is feasible, violates a bound (active-set fallback), the
    # Gram matrix is singular (jitter fallback) or there are upper bounds (BVLS fallback)
    from piezohyst.identify.lsq import bounded_lstsq_gram, bounded_lstsq_gram_many

    a = rng.normal(size=(200, 6))
    grams, atbs = [], []
    for k in range(7):
        ak = a * rng.uniform(0.5, 2.0, 6)
        if k == 3:
            ak[:, 5] = ak[:, 4]  # collinear columns: singular
        grams.append(ak.T @ ak)
        atbs.append(ak.T @ (ak @ rng.normal(1.0, 2.0 if k % 2 else 0.1, 6)))  # odd k: some < 0
    lb = np.r_[np.zeros(5), -np.inf]
    at_bound = 0
    for ub in (np.full(6, np.inf), np.full(6, 3.0)):
        for ks in (range(7), [0, 1, 2, 4, 5, 6]):  # with the singular one, and without
            got = bounded_lstsq_gram_many(np.array(grams)[ks], np.array(atbs)[ks], lb, ub)
            for row, k in enumerate(ks):
                ref = bounded_lstsq_gram(grams[k], atbs[k], lb, ub)
                at_bound += int(np.any(ref[:5] < 1e-9))

                def cost(x, k=k):
                    return x @ grams[k] @ x - 2 * atbs[k] @ x
                assert cost(got[row]) == pytest.approx(cost(ref), rel=1e-9, abs=1e-9)
                if k != 3:  # a singular problem's optimum is not unique, its cost is
                    np.testing.assert_allclose(got[row], ref, rtol=1e-7, atol=1e-9)
                assert np.all(got[row] >= lb - 1e-12) and np.all(got[row] <= ub + 1e-12)
    assert at_bound >= 4  # the active-set fallback was needed


def test_a_schur_complement_lost_to_rounding_falls_back_to_the_full_factor(rng, monkeypatch):
    """Found on a record that starts mid-cycle: eliminating the free variables of a nearly
    collinear design left a Schur complement with a negative diagonal beyond the jitter's reach,
    and fit_model failed with "the regressors' Gram matrix is not positive definite even with
    jitter". The same problem is then solved with the full factor: the same optimum."""
    from scipy.optimize import lsq_linear

    import piezohyst.identify.lsq as lsq

    a = rng.normal(size=(300, 7))
    y = a @ rng.normal(0.0, 2.0, 7)
    lb = np.r_[np.zeros(5), -np.inf, -np.inf]
    want = lsq_linear(a, y, bounds=(lb, np.full(7, np.inf)), method="bvls", tol=1e-14).x
    calls = {"n": 0}
    real = lsq._cholesky

    def failing_schur(g):
        calls["n"] += 1
        if calls["n"] == 3:  # the full factor, the free block's, then the Schur complement's
            raise np.linalg.LinAlgError("the regressors' Gram matrix is not positive definite even with jitter")
        return real(g)

    monkeypatch.setattr(lsq, "_cholesky", failing_schur)
    got = lsq.bounded_lstsq_gram(a.T @ a, a.T @ y, lb, np.full(7, np.inf))
    assert calls["n"] >= 3
    np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-9)


def test_delay_search_scores_every_delay_as_one_fit_each():
    # the held-out RMSE of each delay, from the stacked solves, is that of the delay's own bounded
    # least-squares fit on the fitting part, evaluated on the held-out rows
    from piezohyst.identify.pi import _lsq_from_gram, _split_gram

    true = pv.pi_model()
    u = rich_excitation(5000)
    y = np.concatenate([[0.0, 0.0], true.simulate(u)[:-2]]) + np.random.default_rng(1).normal(0, 0.01, u.size)
    for offset in (True, False):
        fit = ph.fit_pi(u, y, n=12, u_max=100.0, delay="auto", max_auto_delay=5, fit_offset=offset)
        r = fit.model.thresholds
        delays = np.arange(6, dtype=np.int64)
        part, held = _split_gram(u, y, r, delays, int(round(0.7 * u.size)))
        margin = fit.info["margin"]
        for i, d in enumerate(delays):
            x = _lsq_from_gram(part, i, r.size, margin, offset)
            coef = np.diff(np.r_[0.0, x[: r.size]])
            g, b, c, m = held.normal_equations(i, offset=offset)
            if offset:
                coef = np.r_[coef, x[-1]]
            want = np.sqrt(max(c - 2 * coef @ b + coef @ g @ coef, 0.0) / m)
            assert fit.info["delay_holdout_rmse"][int(d)] == pytest.approx(want, rel=1e-7)
        assert fit.delay == 2

def test_fit_pi_refuses_bad_input():
    u = np.linspace(0, 1, 100)
    with pytest.raises(ValueError, match="same length"):
        ph.fit_pi(u, u[:-1])
    with pytest.raises(ValueError, match="method"):
        ph.fit_pi(u, u, method="magic")
    with pytest.raises(ValueError, match="constant"):
        ph.fit_pi(np.ones(100), u)
    with pytest.raises(ValueError, match="negate y"):
        ph.fit_pi(u, -u)
    with pytest.raises(ValueError, match="y contains"):
        ph.fit_pi(u, np.where(u > 0.5, np.nan, u))
    with pytest.raises(ValueError, match="delay"):
        ph.fit_pi(u, u, delay=-1)


def test_fit_bouc_wen_recovers_the_paper_model():
    # the paper's model, 1 Hz 0-100 V, 2 nm of sensor noise and a 0.5 um sensor zero: d1, alpha,
    # beta within 5 %, the zero in the returned model
    bw = pv.bouc_wen_model()
    u = ph.sinusoid(1.0, 2, 0.0, 100.0, DT)
    y = bw.simulate(u, DT) * 1e6 + np.random.default_rng(1).normal(0, 0.002, u.size) + 0.5
    fit = ph.fit_bouc_wen(u, y, DT, seed=0)
    for name in ("d1", "alpha", "beta"):
        assert getattr(fit.model, name) == pytest.approx(getattr(bw, name), rel=0.05), name
    assert fit.rmse < 0.0025  # at the noise floor, um
    # the offset is in metres: 0.5 um = 5e-7 m. Measured 5.0000058e-7; the noise alone moves a
    # mean over 20000 samples by 2 nm / sqrt(20000) = 1.4e-11 m, so 1 nm is a wide margin that
    # still refuses any offset more than a fifth of a noise sigma wrong
    assert fit.model.offset == pytest.approx(5e-7, abs=1e-9)
    # the returned model itself (not just the fitness) meets the data at the noise floor
    # (measured 0.0019878 um, the 2 nm noise's own RMS; a lost offset gives ~0.5 um)
    own = float(np.sqrt(np.mean((fit.model.predict(u, DT) - y) ** 2)))
    assert own < 0.0025
    assert own == pytest.approx(fit.rmse, rel=1e-6)  # the rmse reported is the returned model's
    assert fit.info["pso_rmse"] >= fit.rmse
    # m, b and k only shape a 1.7 kHz resonance that 1 Hz data cannot see
    assert {"m", "k"} <= set(fit.poorly_constrained)
    assert "d1" not in fit.poorly_constrained and "beta" not in fit.poorly_constrained


def test_fit_bouc_wen_same_seed_same_model():
    bw = pv.bouc_wen_model()
    u = ph.sinusoid(1.0, 1, 0.0, 100.0, 1e-3)
    y = bw.simulate(u, 1e-3) * 1e6
    a = ph.fit_bouc_wen(u, y, 1e-3, seed=5, max_iter=20, polish=False)
    b = ph.fit_bouc_wen(u, y, 1e-3, seed=5, max_iter=20, polish=False)
    assert a.model == b.model and a.nfev == b.nfev


def test_fit_bouc_wen_refuses_bad_bounds():
    u = ph.sinusoid(1.0, 1, 0.0, 100.0, 1e-3)
    y = u * 0.02
    with pytest.raises(ValueError, match="unknown Bouc-Wen parameter"):
        ph.fit_bouc_wen(u, y, 1e-3, bounds={"mass": (1, 2)})
    with pytest.raises(ValueError, match="low < high"):
        ph.fit_bouc_wen(u, y, 1e-3, bounds={"alpha": (1, 0)})
    with pytest.raises(ValueError, match="positive"):
        ph.fit_bouc_wen(u, y, 1e-3, bounds={"k": (0, 1e8)})
    with pytest.raises(ValueError, match="dt must be > 0"):
        ph.fit_bouc_wen(u, y, 0.0)


@pytest.mark.parametrize("knots, stride, delay", [(2, 1, 0), (4, 2, 3), (8, 3, 1)])
def test_output_map_normal_equations_equal_the_explicit_design(monkeypatch, knots, stride, delay):
    # fit_prepared forms the asymmetric P-I model's normal equations from the stored columns B
    # (B' [map columns, const], map columns' [map columns, y, const]); they are those of the
    # explicit design A = [B T | map columns], rhs = y - B shift - const
    from piezohyst.identify import linear as lin

    rig = ph.VirtualRig(seed=1)
    ds = rig.excite(ph.sinusoid(2.0, 3, 0.0, 100.0, rig.dt))
    st = lin.Structure("pi", 10, map_knots=knots, taus=(0.01, 0.1), delay=delay)
    pre = lin.prepare(ds.u, rig.dt, st, stride=stride)
    rows = ds.u.size - delay
    y = ds.y[delay:]
    margin = 0.02 * lin.mean_slope(ds.u, ds.y)
    seen = {}

    def capture(gram, atb, lb, ub, ridge=None):
        seen["gram"], seen["atb"] = gram, atb
        return np.zeros(atb.size)

    monkeypatch.setattr(lin, "bounded_lstsq_gram", capture)
    with np.errstate(all="ignore"):
        lin.fit_prepared(pre, y, rows, rig.dt, margin=margin)
    t, shift, *_ = lin._design(pre, margin, True)
    b = pre.base[: pre.n_rows(rows)]
    ys = y[::stride]
    knot_values, centre = lin.map_knots_for(ys, knots)
    mc, const, _ = lin._map_columns(ys, knot_values, centre)
    a = np.column_stack([b @ t, mc])
    rhs = ys - b @ shift - const
    scale = np.sqrt(np.outer(np.diag(a.T @ a), np.diag(a.T @ a)))
    np.testing.assert_allclose(seen["gram"] / scale, (a.T @ a) / scale, rtol=0, atol=1e-10)
    np.testing.assert_allclose(seen["atb"], a.T @ rhs, rtol=1e-9, atol=1e-9 * np.abs(a.T @ rhs).max())


@pytest.mark.parametrize("static", ["pi", "preisach", "bouc-wen"])
@pytest.mark.parametrize("stride", [2, 3])
def test_strided_regressors_are_the_full_ones_subsampled(static, stride):
    # a search keeps every stride-th row; its blocks are built at those rows only (the states
    # still run over every sample), so they equal the full regressors' rows, bit for bit
    from piezohyst.identify import linear as lin

    rig = ph.VirtualRig(seed=2)
    ds = rig.excite(ph.sinusoid(3.0, 2, 0.0, 100.0, rig.dt))
    shape = (0.03, 0.01) if static == "bouc-wen" else (0.0, 0.0)
    size = {"pi": 12, "preisach": 6, "bouc-wen": 1}[static]
    st = lin.Structure(static, size, taus=(0.002, 0.02), input_tau=0.0005, shape=shape)
    full = lin.prepare(ds.u, rig.dt, st)
    cache: dict = {}
    for _ in range(2):  # built, then from the cache
        sub = lin.prepare(ds.u, rig.dt, st, stride=stride, cache=cache)
        np.testing.assert_array_equal(sub.base, full.base[::stride])


@pytest.mark.parametrize("stride", [1, 3])
@pytest.mark.parametrize("static,size,shape", [("pi", 12, (0.0, 0.0)), ("preisach", 6, (0.0, 0.0)),
                                               ("bouc-wen", 1, (0.03, -0.01))])
def test_a_refits_design_written_in_place_is_the_searchs_design(static, size, shape, stride):
    """``prepare`` without a cache (a refit on all the data) writes the static part's columns
    straight into one design array (no second copy of a design that can be gigabytes); the design
    is bit for bit the one the search's cached path builds from its shared blocks
    (identify/linear.py)."""
    from piezohyst.identify.linear import Structure, prepare

    rng = np.random.default_rng(3)
    u = np.clip(50.0 + np.cumsum(rng.normal(0.0, 1.0, 5000)), 0.0, 100.0)
    st = Structure(static=static, size=size, taus=(0.002, 0.05), input_tau=3e-4, delay=2, shape=shape)
    direct = prepare(u, 1e-4, st, u_ref=u[:4000], stride=stride)
    cached = prepare(u, 1e-4, st, u_ref=u[:4000], cache={}, stride=stride)
    assert direct.base.shape == cached.base.shape
    assert np.array_equal(direct.base, cached.base)
    assert direct.whole is not None and np.shares_memory(direct.static, direct.whole)
    assert np.shares_memory(direct.extra, direct.whole) and np.shares_memory(direct.base, direct.whole)


def test_a_record_beyond_the_row_budget_is_fitted_on_every_kth_row():
    """``fit_structure`` with more fitting rows than ``max_rows`` fits on every k-th row (a long
    record's design matrix would not fit in memory) and reports its RMSE over every row from the
    model's own prediction: on a smooth record the model is as good as the fit on all rows."""
    from piezohyst.identify.linear import Structure, fit_structure

    rig = ph.VirtualRig()
    u = ph.sinusoid(2.0, 3, 0.0, 100.0, rig.dt) * np.linspace(1.0, 0.5, int(1.5 / rig.dt))
    y = rig.excite(u).y
    st = Structure(static="preisach", size=8, taus=(0.003, 0.05), delay=2)
    full, _ = fit_structure(u, y, rig.dt, st)
    thin, pred = fit_structure(u, y, rig.dt, st, max_rows=2000)
    k = -(-(u.size - 2) // 2000)
    assert "fit_every_kth_row" not in full.info and thin.info["fit_every_kth_row"] == k > 1
    assert pred.size == u.size
    assert thin.rmse == pytest.approx(float(np.sqrt(np.mean((y[2:] - pred[2:]) ** 2))), rel=1e-12)
    assert thin.rmse <= 1.1 * full.rmse


def test_fit_pi_warns_when_the_input_sits_on_fewer_levels_than_operators():
    # found by fuzzing: a square wave between 10 and 90 V fitted 20 weights "globally optimal"
    # without a word (that model predicted a 0..100 V sinusoid to 6.7 % of span, against 0.6 %)
    u = np.where(np.sin(np.linspace(0.0, 40.0, 4000)) > 0, 90.0, 10.0)
    y = pv.pi_model().simulate(u) * 0.02 + 0.001 * np.random.default_rng(0).standard_normal(u.size)
    assert any("takes only 2 values (10, 90 V)" in w for w in ph.fit_pi(u, y).warnings)
    s = ph.sinusoid(1.0, 2, 0.0, 100.0, 1e-3)
    assert not any("takes only" in w for w in ph.fit_pi(s, pv.pi_model().simulate(s) * 0.02).warnings)
