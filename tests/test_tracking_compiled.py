"""The compiled closed loop of track() (piezohyst.control.compiled_loop) equals the Python loop."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import piezohyst as ph
from piezohyst.control import compiled_loop


@pytest.fixture(scope="module")
def models():
    rig = ph.VirtualRig(seed=0)
    ds = rig.excite(ph.sinusoid(1.0, 2, 0.0, 100.0, rig.dt))
    pi = ph.fit_pi(ds.u, ds.y, n=12, method="lsq").model
    bw = ph.BoucWen(m=0.75, b=27.96, k=8.54e7, d1=2.15e-8, alpha=0.472, beta=0.072, gamma=0.0)
    return pi, bw


def _python_loop(monkeypatch, *args, **kw):
    with monkeypatch.context() as m:
        m.setattr(compiled_loop, "has_kernels", lambda *a: False)
        return ph.track(*args, **kw)


def _feedforward(kind, models, limited=False):
    pi, bw = models
    lim = {"u_range": (0.0, 100.0), "max_slew": 0.3} if limited else {}
    return {"none": None, "pi": ph.InversePIFeedforward(pi, **lim), "bw": ph.BoucWenFeedforward(bw, **lim)}[kind]


def _state(rig, ff, pid):
    out = {"rig": rig._st.copy(), "line": rig._line.copy(), "n": rig.samples, "noise": rig._rng.standard_normal()}
    if ff is not None:
        out["ff"] = (ff._u_last, ff.limited, ff.step(1.0))
    if pid is not None:
        out["pid"] = (pid.integral, pid._d, pid._e_prev, pid._first)
    return out


# every feedforward with and without feedback, and feedback alone (neither: nothing drives the plant)
@pytest.mark.parametrize("kind, feedback", [("none", True), ("pi", False), ("pi", True), ("bw", False), ("bw", True)])
@pytest.mark.parametrize("feedback_at", ["reference", "command"])
@pytest.mark.parametrize("limited", [False, True])
def test_compiled_loop_equals_python_loop(monkeypatch, models, kind, feedback, feedback_at, limited):
    rig = ph.VirtualRig(seed=3)
    ref = ph.sinusoid(5.0, 3, 0.25, 2.25, rig.dt)
    ff = _feedforward(kind, models, limited)
    ki = 200.0 if (kind != "none" and feedback_at == "reference") else 2000.0
    pid = ph.PID(0.05 if kind != "none" else 0.0, ki, 0.0, rig.dt) if feedback else None
    assert compiled_loop.has_kernels(rig, ff, pid)
    fast = ph.track(rig, ref, ff, pid, feedback_at=feedback_at)
    after_fast = _state(rig, ff, pid)
    slow = _python_loop(monkeypatch, rig, ref, ff, pid, feedback_at=feedback_at)
    after_slow = _state(rig, ff, pid)
    np.testing.assert_array_equal(fast.output, slow.output)
    np.testing.assert_array_equal(fast.command, slow.command)
    assert fast.clipped == slow.clipped and fast.rmse == slow.rmse and fast.info == slow.info
    for key in after_slow:
        np.testing.assert_equal(after_fast[key], after_slow[key])


@settings(max_examples=15, deadline=None)
@given(ki=st.floats(0.0, 3000.0), kp=st.floats(0.0, 0.5), freq=st.sampled_from([1.0, 7.0, 20.0]),
       low=st.floats(0.0, 1.0), span=st.floats(0.1, 2.0), seed=st.integers(0, 5))
def test_compiled_loop_property(models, ki, kp, freq, low, span, seed):
    rig = ph.VirtualRig(seed=seed)
    ref = ph.sinusoid(freq, 2, low, low + span, rig.dt)[:3000]
    ff = ph.InversePIFeedforward(models[0])
    pid = ph.PID(kp, ki, 0.0, rig.dt)
    outcome = {}
    for name in ("compiled", "python"):
        orig = compiled_loop.has_kernels
        if name == "python":
            compiled_loop.has_kernels = lambda *a: False
        try:
            res = ph.track(rig, ref, ff, pid)
            outcome[name] = ("ok", res.output, res.command)
        except ph.UnstableLoopError as exc:
            outcome[name] = ("unstable", str(exc), exc.sample)
        finally:
            compiled_loop.has_kernels = orig
    a, b = outcome["compiled"], outcome["python"]
    assert a[0] == b[0]
    if a[0] == "ok":
        np.testing.assert_array_equal(a[1], b[1])
        np.testing.assert_array_equal(a[2], b[2])
    else:
        assert a[1:] == b[1:]


def test_an_unstable_loop_raises_the_python_loops_error(monkeypatch, models):
    rig = ph.VirtualRig(seed=0)
    ref = ph.sinusoid(1.0, 2, 0.25, 2.25, rig.dt)
    ff = ph.InversePIFeedforward(models[0])
    errors = []
    for compiled in (True, False):
        with monkeypatch.context() as m:
            if not compiled:
                m.setattr(compiled_loop, "has_kernels", lambda *a: False)
            with pytest.raises(ph.UnstableLoopError) as exc:
                ph.track(rig, ref, ff, ph.PID(0.0, 1e6, 0.0, rig.dt))
            errors.append((str(exc.value), exc.value.sample))
    assert errors[0] == errors[1]


def test_other_parts_take_the_python_loop(models):
    class Subclass(ph.InversePIFeedforward):
        pass

    class Plant:
        dt = 1e-4

        def reset(self):
            pass

        def step(self, u):
            return 0.0

    rig = ph.VirtualRig(seed=0)
    assert not compiled_loop.has_kernels(rig, Subclass(models[0]), None)
    assert not compiled_loop.has_kernels(Plant(), ph.InversePIFeedforward(models[0]), None)
    assert not compiled_loop.has_kernels(rig, None, object())


@settings(max_examples=30, deadline=None)
@given(input_tau=st.sampled_from([0.0, 2e-4, 8e-4]), n_lags=st.integers(0, 4), seed=st.integers(0, 100),
       freq=st.sampled_from([1.0, 5.0, 40.0]), static=st.sampled_from(["pi", "preisach"]))
def test_rate_compensator_kernel_equals_python_recursion(input_tau, n_lags, seed, freq, static):
    """The compiled recursion of RateCompensator (P-I or Preisach static part) equals its Python
    loop, in ``step`` and ``command``, sample for sample."""
    from piezohyst.models import rate

    g = np.random.default_rng(seed)
    if static == "pi":
        inner = ph.PrandtlIshlinskii(ph.equal_thresholds(8, 100.0), g.uniform(0.002, 0.02, 8))
    else:
        inner = ph.Preisach(lo=0.0, hi=100.0, weights=g.uniform(0.0, 0.002, 6 * 7 // 2 + 12), slope=0.004)
    taus = np.geomspace(1e-3, 1.0, n_lags) if n_lags else np.zeros(0)
    model = rate.RateDependent(inner, taus, g.uniform(0.0, 0.002, n_lags), 1e-4, input_tau=input_tau)
    comp = rate.RateCompensator(model)
    assert comp._kernel_args() is not None
    x = np.resize(ph.sinusoid(freq, 1, 0.1, 1.5, 1e-4), 4000) + g.normal(0.0, 1e-3, 4000)
    fast_cmd = comp.command(x)
    comp.reset()
    fast_steps = np.array([comp.step(v) for v in x])
    with pytest.MonkeyPatch.context() as m:
        m.setattr(rate.RateCompensator, "_kernel_args", lambda self: None)
        slow_cmd = comp.command(x)
        comp.reset()
        slow_steps = np.array([comp.step(v) for v in x])
    np.testing.assert_array_equal(fast_cmd, slow_cmd)
    np.testing.assert_array_equal(fast_steps, slow_steps)
    np.testing.assert_array_equal(fast_cmd, fast_steps)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 1000), scale=st.floats(0.1, 300.0), start=st.floats(-20.0, 120.0))
def test_guard_table_equals_the_per_sample_guard(seed, scale, start):
    from piezohyst.plant import CommandLimits, GuardedPlant

    g = np.random.default_rng(seed)
    x = start + np.cumsum(g.normal(0.0, scale / 50, 2000)) + g.choice([0.0, scale], 2000, p=[0.97, 0.03])
    lim = CommandLimits.for_range((0.0, 100.0))
    a = GuardedPlant(ph.VirtualRig(seed=0), lim, last=float(np.clip(start, 0.0, 100.0)))
    b = GuardedPlant(ph.VirtualRig(seed=0), lim, last=float(np.clip(start, 0.0, 100.0)))
    table = a.guard_table(x)
    steps = np.array([b._guard(v) for v in x])
    np.testing.assert_array_equal(table, steps)
    assert a.counts() == b.counts() and a.last == b.last and a.last_saturation == b.last_saturation
