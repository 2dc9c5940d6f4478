"""Particle swarm optimisation, eqs. (5)-(6)."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import piezohyst as ph
from piezohyst.pso import apply_bounds, compute_velocity


def sphere(x):
    return (x**2).sum(axis=1)


def rosenbrock(x):
    return (100 * (x[:, 1:] - x[:, :-1] ** 2) ** 2 + (1 - x[:, :-1]) ** 2).sum(axis=1)


def rastrigin(x):
    return 10 * x.shape[1] + (x**2 - 10 * np.cos(2 * np.pi * x)).sum(axis=1)


# Tolerances at stated budgets, 10-D, seeds 0..2. Global-best PSO is known to converge slowly on
# Rosenbrock's valley and to stall in one of Rastrigin's local minima (each ~1 apart); the
# tolerances say what this implementation reaches, and polish=True shows the local refinement.
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sphere_10d(seed):
    res = ph.pso_minimize(sphere, [(-5.12, 5.12)] * 10, n_particles=40, max_iter=300, seed=seed)
    assert res.fun < 1e-8
    np.testing.assert_allclose(res.x, 0.0, atol=1e-4)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rosenbrock_10d(seed):
    res = ph.pso_minimize(rosenbrock, [(-5.0, 5.0)] * 10, n_particles=100, max_iter=2000, seed=seed)
    assert res.fun < 0.1
    polished = ph.pso_minimize(rosenbrock, [(-5.0, 5.0)] * 10, n_particles=100, max_iter=2000,
                               seed=seed, polish=True)
    assert polished.fun < 1e-6
    np.testing.assert_allclose(polished.x, 1.0, atol=1e-2)
    assert polished.pso_fun == res.fun  # the swarm's own figure is kept


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rastrigin_10d(seed):
    res = ph.pso_minimize(rastrigin, [(-5.12, 5.12)] * 10, n_particles=200, max_iter=2000, seed=seed)
    # within a few local minima of the global optimum 0 (start: ~100 on average)
    assert res.fun < 6.0
    # every coordinate in or next to the global basin
    assert np.all(np.abs(res.x) < 2.1)


def test_same_seed_same_result():
    a = ph.pso_minimize(rastrigin, [(-5.12, 5.12)] * 4, seed=7, max_iter=50, stall_iter=10)
    b = ph.pso_minimize(rastrigin, [(-5.12, 5.12)] * 4, seed=7, max_iter=50, stall_iter=10)
    np.testing.assert_array_equal(a.x, b.x)
    assert a.nfev == b.nfev and a.fun == b.fun
    c = ph.pso_minimize(rastrigin, [(-5.12, 5.12)] * 4, seed=8, max_iter=50, stall_iter=10)
    assert not np.array_equal(a.x, c.x)


@given(seed=st.integers(0, 1000), lo=st.floats(-10, 0), width=st.floats(0.1, 10))
def test_bounds_are_never_left(seed, lo, width):
    hi = lo + width
    seen = []

    def f(x):
        seen.append(x.copy())
        return ((x - (hi + 5)) ** 2).sum(axis=1)  # optimum outside the box: pushes on the bound

    res = ph.pso_minimize(f, [(lo, hi)] * 3, n_particles=10, max_iter=30, seed=seed)
    allx = np.concatenate(seen)
    assert np.all(allx >= lo) and np.all(allx <= hi)
    np.testing.assert_allclose(res.x, hi)


def test_nfev_and_history():
    res = ph.pso_minimize(sphere, [(-1, 1)] * 2, n_particles=12, max_iter=25, seed=0)
    assert res.nit == 25
    assert res.nfev == 12 * 26
    assert res.history.shape == (26,)
    assert np.all(np.diff(res.history) <= 0)  # the global best never gets worse
    assert res.history[-1] == res.fun


def test_target_stops_early():
    res = ph.pso_minimize(sphere, [(-5, 5)] * 2, seed=0, max_iter=1000, target=1e-3)
    assert res.fun <= 1e-3 and res.nit < 1000
    assert "target" in res.message


def test_stall_stops_early():
    res = ph.pso_minimize(lambda x: np.ones(len(x)), [(-5, 5)] * 2, seed=0, max_iter=1000, stall_iter=5)
    assert res.nit == 5 and "stall" in res.message


def test_callback_can_stop():
    calls = []

    def cb(state):
        calls.append(state.nit)
        return state.nit >= 3

    res = ph.pso_minimize(sphere, [(-5, 5)] * 2, seed=0, max_iter=100, callback=cb)
    assert res.nit == 3 and calls == [1, 2, 3] and "callback" in res.message

    def cb2(state):
        raise StopIteration

    assert ph.pso_minimize(sphere, [(-5, 5)] * 2, seed=0, callback=cb2).nit == 1


def test_scalar_objective():
    res = ph.pso_minimize(lambda x: float((x**2).sum()), [(-3, 3)] * 2, vectorized=False, seed=1)
    assert res.fun < 1e-8


def test_non_finite_fitness_is_never_best():
    def f(x):
        out = (x**2).sum(axis=1)
        out[x[:, 0] < 0] = np.nan
        return out

    res = ph.pso_minimize(f, [(-1, 1)] * 2, seed=0, max_iter=50)
    assert np.isfinite(res.fun) and res.x[0] >= 0


def test_velocity_update_eq5_and_clamp():
    rng = np.random.default_rng(0)
    x = np.zeros((2, 3))
    v = np.ones((2, 3))
    p = np.full((2, 3), 2.0)
    g = np.full(3, 4.0)
    # r1, r2 are the next draws of the same generator
    r1 = np.random.default_rng(0).random((2, 3))
    r2_rng = np.random.default_rng(0)
    r2_rng.random((2, 3))
    r2 = r2_rng.random((2, 3))
    new = compute_velocity(v, x, p, g, inertia=0.5, c1=1.0, c2=2.0, vmax=np.full(3, 100.0), rng=rng)
    np.testing.assert_allclose(new, 0.5 * v + 1.0 * r1 * (p - x) + 2.0 * r2 * (g - x))
    clamped = compute_velocity(v, x, p, g, inertia=0.5, c1=1.0, c2=2.0, vmax=np.full(3, 0.1),
                               rng=np.random.default_rng(0))
    assert np.all(np.abs(clamped) <= 0.1)


def test_apply_bounds_zeroes_outward_velocity():
    x = np.array([[-2.0, 0.5, 3.0]])
    v = np.array([[-1.0, 1.0, 1.0]])
    apply_bounds(x, v, np.full(3, -1.0), np.full(3, 1.0))
    np.testing.assert_array_equal(x, [[-1.0, 0.5, 1.0]])
    np.testing.assert_array_equal(v, [[0.0, 1.0, 0.0]])


@pytest.mark.parametrize(
    "bounds, match",
    [([(1, 1)], "strictly less"), ([(2, 1)], "strictly less"), ([1, 2], "pairs"), ([(0, np.inf)], "finite")],
)
def test_refuses_bad_bounds(bounds, match):
    with pytest.raises(ValueError, match=match):
        ph.pso_minimize(sphere, bounds)


def test_refuses_bad_options():
    with pytest.raises(ValueError, match="n_particles"):
        ph.pso_minimize(sphere, [(-1, 1)], n_particles=0)
    with pytest.raises(ValueError, match="max_iter"):
        ph.pso_minimize(sphere, [(-1, 1)], max_iter=-1)
    with pytest.raises(ValueError, match="one fitness per particle"):
        ph.pso_minimize(lambda x: 1.0, [(-1, 1)])
    with pytest.raises(ValueError, match="inertia"):
        ph.pso_minimize(sphere, [(-1, 1)], inertia=-0.1)


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 12), d=st.integers(1, 6), spread=st.floats(0.01, 10.0))
def test_compiled_move_is_compute_velocity_then_apply_bounds(seed, n, d, spread):
    """swarm_move (the compiled runs' eqs. 5-6) is the NumPy backend operation for operation."""
    from piezohyst.pso import swarm_move

    rng = np.random.default_rng(seed)
    lb, ub = -rng.random(d), rng.random(d) + 0.01
    vmax = 0.5 * (ub - lb)
    x = rng.uniform(lb, ub, (n, d))
    v = rng.normal(0, spread, (n, d))  # large: many particles hit the clamp and the bounds
    pbest, gbest = rng.uniform(lb, ub, (n, d)), rng.uniform(lb, ub, d)
    r = rng.random((2, n, d))
    ref_v = compute_velocity(v, x, pbest, gbest, inertia=0.73, c1=1.5, c2=1.4, vmax=vmax,
                             rng=_FixedDraw(r))
    ref_x = x + ref_v
    apply_bounds(ref_x, ref_v, lb, ub)
    swarm_move(x, v, pbest, gbest, r, 0.73, 1.5, 1.4, vmax, lb, ub)
    np.testing.assert_array_equal(x, ref_x)
    np.testing.assert_array_equal(v, ref_v)


class _FixedDraw:
    """A generator stand-in that returns given random numbers."""

    def __init__(self, r):
        self.r = r

    def random(self, shape):
        assert tuple(shape) == self.r.shape
        return self.r


@pytest.mark.parametrize("seed", [0, 1, 7])
def test_compiled_run_equals_step_by_step(seed):
    """An objective that offers the whole loop compiled (the P-I weights' fitness) gives, bit for
    bit, what the Python loop gives (forced here by a callback): positions, history, counts."""
    rng = np.random.default_rng(seed)
    u = np.concatenate([np.linspace(0, 1, 200), np.linspace(1, 0.2, 150), np.linspace(0.2, 0.8, 100)]) * 100
    y = ph.PrandtlIshlinskii(ph.equal_thresholds(6, 100.0), rng.uniform(0.01, 0.1, 6)).simulate(u)
    y = y + 1e-3 * rng.standard_normal(u.size)
    fast = ph.fit_pi(u, y, n=6, method="pso", seed=seed, n_particles=15, max_iter=250)
    slow = ph.fit_pi(u, y, n=6, method="pso", seed=seed, n_particles=15, max_iter=250, callback=lambda s: None)
    np.testing.assert_array_equal(fast.model.weights, slow.model.weights)
    np.testing.assert_array_equal(fast.history, slow.history)
    assert fast.nfev == slow.nfev == 15 * 251 and fast.rmse == slow.rmse
