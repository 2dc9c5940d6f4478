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



def test_a_held_position_is_followed_to_the_sensor_noise_in_both_loops(controller):
    # a reference that holds 1.2 um with a dither far below the sensor's noise: the error is the
    # noise, and the loop follows it (the watch's window compared the error's RMS with the
    # reference's span alone, 2e-4 um here, and stopped this hold as "not following")
    ctl = controller
    noise = ctl.sensor_noise_um
    assert noise is not None and noise > 0
    ref = 1.2 + 1e-4 * np.sin(np.linspace(0.0, 20.0, 6000))
    fast, _, slow, _ = _both(ctl, ref, learning=False)
    assert fast is not None
    np.testing.assert_array_equal(fast.output, slow.output)
    settled = slow.error[slow.error.size // 5:]
    assert float(np.sqrt(np.mean(settled ** 2))) < 2.0 * noise, (float(np.sqrt(np.mean(settled ** 2))), noise)


def test_the_watch_stops_a_hold_left_far_from_its_position_when_the_noise_is_known():
    from piezohyst.control.tracking import LoopWatch

    rng = np.random.default_rng(0)
    r = np.full(3000, 1.0)
    follow = r + 0.003 * rng.standard_normal(r.size)  # the sensor's noise alone: followed
    away = follow + 0.05  # 17 noise RMS away from the held position: not followed

    def run(y, noise):
        w = LoopWatch(r, u_range=None, feedback_on=True, limit=10.0, dt=1e-4, describe=lambda: "test", noise=noise)
        for k in range(r.size):
            w.output(k, float(y[k]), y)

    run(follow, 0.003)
    with pytest.raises(UnstableLoopError, match="5 times the sensor's noise RMS"):
        run(away, 0.003)
    run(away, None)  # without the noise a constant reference has no scale: only the limit watches it
