"""The commissioned controller's loop compiled (compiled_loop._guarded_loop) equals its Python loop."""

import dataclasses
import warnings

import numpy as np
import pytest

import piezohyst as ph
from piezohyst import commissioning
from piezohyst.models import rate
from piezohyst.control.tracking import UnstableLoopError

from .plants import PIPlant


@pytest.fixture(scope="module", params=["pi", "preisach"])
def controller(request):
    """The VirtualRig commissioned, its model refitted as a rate-dependent model of each static part
    the compiled loops take (a P-I model or a Preisach grid), and its feedback tuned."""
    rig = ph.VirtualRig(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ph.ClippingWarning)
        ctl = ph.commission(rig, tune=False)
        ds = ctl.identification
        n_id = commissioning.identification_length(rig.dt, rig.u_range)
        fit = ph.fit_model(ds.u, ds.y, rig.dt, "rate-dependent", statics=(request.param,), holdout=int(ds.u.size - n_id))
        ctl = dataclasses.replace(ctl, fit=fit)
        ctl.tune()
    args = ctl.feedforward()._kernel_args()
    assert args is not None and args[0] == {"pi": rate.RATE_PI, "preisach": rate.RATE_PREISACH}[request.param]
    return ctl


def _state(rig):
    return {"st": rig._st.copy(), "line": rig._line.copy(), "n": rig.samples, "noise": rig._rng.standard_normal()}


def _both(ctl, ref, **kw):
    kw = {"feedback": True, "learning": True, "period": None, "label": "x", **kw}
    fast = ctl._track_step_run(ref, compiled=True, **kw)
    after_fast = _state(ctl.plant)
    slow = ctl._track_step_run(ref, compiled=False, **kw)
    after_slow = _state(ctl.plant)
    return fast, after_fast, slow, after_slow


@pytest.mark.parametrize("freq, cycles", [(5.0, 6), (2.0, 3)])
@pytest.mark.parametrize("feedback, learning", [(False, False), (True, False), (True, True), (False, True)])
def test_compiled_loop_equals_python_loop(controller, freq, cycles, feedback, learning):
    ctl = controller
    assert commissioning._loop_kernel_args(ctl.plant, ctl.feedforward(), None) is not None
    ref = ph.sinusoid(freq, cycles, 0.25, 2.25, ctl.plant.dt)
    per = int(round(1 / (freq * ctl.plant.dt)))
    fast, after_fast, slow, after_slow = _both(ctl, ref, feedback=feedback, learning=learning, period=per)
    assert fast is not None
    np.testing.assert_array_equal(fast.output, slow.output)
    np.testing.assert_array_equal(fast.command, slow.command)
    assert fast.info == slow.info and fast.clipped == slow.clipped
    assert fast.info["learning"] == learning and fast.info["feedback"] == feedback
    if learning:
        assert len(fast.info["cycle_rms_um"]) == cycles
    for key in after_slow:
        np.testing.assert_array_equal(after_fast[key], after_slow[key])


def test_track_uses_the_compiled_loop_and_gives_the_same_result(controller, monkeypatch):
    ctl = controller
    ref = ph.sinusoid(5.0, 4, 0.25, 2.25, ctl.plant.dt)
    fast = ctl.track(ref, period=2000)
    calls = []
    with monkeypatch.context() as m:
        m.setattr(commissioning, "_run_loop_compiled", lambda *a, **k: calls.append(1) or False)
        slow = ctl.track(ref, period=2000)  # the kernel "gave up": the run is made again in Python
    assert calls == [1]
    np.testing.assert_array_equal(fast.output, slow.output)
    assert fast.info == slow.info


def test_an_unstable_loop_gives_up_and_raises_the_python_loops_error(controller):
    ctl = dataclasses.replace(controller, tuning=dataclasses.replace(controller.tuning, ki=80 * controller.tuning.ki))
    ref = ph.sinusoid(5.0, 4, 0.25, 2.25, ctl.plant.dt)
    assert ctl._track_step_run(ref, feedback=True, learning=False, period=2000, label="", compiled=True) is None
    with pytest.raises(UnstableLoopError) as fast:
        ctl.track(ref, learning=False, period=2000)
    with pytest.raises(UnstableLoopError) as slow:
        ctl._track_step_run(ref, feedback=True, learning=False, period=2000, label="", compiled=False)
    assert str(fast.value) == str(slow.value)


def test_other_plants_take_the_python_loop():
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(20, 100.0), np.linspace(0.03, -0.0005, 20))
    plant = PIPlant(true, dt=1e-3)
    ctl = ph.commission(plant, u_range=(-50.0, 100.0), tune=False)
    assert commissioning._loop_kernel_args(plant, ctl.feedforward(), None) is None
    ref = ph.sinusoid(2.0, 3, 0.5, 2.5, plant.dt)
    assert ctl._track_step_run(ref, feedback=False, learning=False, period=None, label="", compiled=True) is None
    assert ctl.track(ref, feedback=False, learning=False).rmse < 1e-3


def _tune_once(ctl, compiled, monkeypatch):
    """ctl.tune() from a reset rig, with the safe tuning's hold compiled or forced to Python."""
    from piezohyst.control import compiled_loop

    with monkeypatch.context() as m:
        if not compiled:
            m.setattr(compiled_loop, "run_hold", lambda *a, **k: NotImplemented)
        ctl.plant.reset()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ph.ClippingWarning)
            counts = ctl.tune()
    return ctl.tuning, counts, _state(ctl.plant)


def test_safe_tuning_hold_compiled_equals_python(controller, monkeypatch):
    """The bounded experiments of tune_integral_safely run compiled on the VirtualRig; every trial
    (gains, overshoots, aborts, command bands), the gain chosen and the rig afterwards are those
    of the Python loop."""
    ctl = dataclasses.replace(controller)
    fast, counts_fast, after_fast = _tune_once(ctl, True, monkeypatch)
    slow, counts_slow, after_slow = _tune_once(ctl, False, monkeypatch)
    assert counts_fast == counts_slow and counts_fast["commands_sent"] > 1000
    assert fast.ki == slow.ki > 0 and fast.trials == slow.trials
    assert fast.experiments == slow.experiments and len(fast.experiments) >= 3
    for key in after_slow:
        np.testing.assert_array_equal(after_fast[key], after_slow[key])


def test_safe_tuning_hold_stops_on_its_check_as_python(controller, monkeypatch):
    """A hold whose check trips (here: a far too strict tolerance) stops at the same sample, with
    the same states, compiled or not."""
    from piezohyst.control import compiled_loop
    from piezohyst.control.pid import PID
    from piezohyst.control.tuning import hold_at_level
    from piezohyst.plant import GuardedPlant

    ctl = controller
    limits = ctl._limits()
    outs = []
    for compiled in (True, False):
        rig = ph.VirtualRig(seed=3)
        guard = GuardedPlant(rig, limits)
        ff = ctl.feedforward()
        pid = PID(0.0, 50.0, 0.0, rig.dt)
        state = {"y": 0.0, "sat": 0, "u_lo": np.inf, "u_hi": -np.inf}
        kw = dict(n=400, level=1.0, add=0.3, check=True, e0=1.0, fb0=0.0, tol_e=0.2, tol_fb=10.0,
                  vpu=40.0, state=state)
        if compiled:
            res = compiled_loop.run_hold(guard, ff, pid, **kw)
        else:
            res = hold_at_level(guard, ff, pid, **kw)
        outs.append((res, dict(state), guard.sent, guard.last, pid.integral, _state(rig)))
    (a, sa, na, la, ia, ra), (b, sb, nb, lb, ib, rb) = outs
    assert a is None and b is None and sa == sb and na == nb and 0 < na < 400 and la == lb and ia == ib
    for key in ra:
        np.testing.assert_array_equal(ra[key], rb[key])

