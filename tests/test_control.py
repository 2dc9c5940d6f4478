"""Feedforward (eqs. 10, 12-15), PID and track() (Fig. 5)."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import piezohyst as ph
from piezohyst import paper_values as pv
from piezohyst.control.tracking import tracking_metrics

from .plants import FirstOrderPlant, PIPlant, QuasiStaticBoucWenPlant, UnboundedIntegrator


def test_inverse_pi_feedforward_tracks_a_pi_plant_exactly():
    model = ph.PrandtlIshlinskii(ph.equal_thresholds(20, 100.0), np.array(pv.PI_WEIGHTS) * 0.02)
    plant = PIPlant(model, dt=1e-3)
    ref = ph.sinusoid(1.0, 3, 0.1, 1.9, plant.dt)
    out = ph.track(plant, ref, ph.InversePIFeedforward(model))
    assert out.e_max < 1e-9
    np.testing.assert_allclose(out.output, ref, atol=1e-9)


def test_bouc_wen_feedforward_cancels_the_quasi_static_model():
    # eq. (10) with h_hat from eq. (8) solved as the command is produced: exact on d1 u - h
    bw = ph.BoucWen(**{**pv.BOUC_WEN, "gamma": 0.02})
    plant = QuasiStaticBoucWenPlant(bw, dt=1e-3)
    ref = ph.sinusoid(2.0, 3, 0.2, 1.8, plant.dt)
    out = ph.track(plant, ref, ph.BoucWenFeedforward(bw))
    assert out.e_max < 1e-9


def test_feedforward_streaming_equals_whole_signal():
    bw = pv.bouc_wen_model()
    ref = ph.sinusoid(3.0, 1, 0.1, 1.9, 1e-4)
    for ff in (ph.BoucWenFeedforward(bw), ph.InversePIFeedforward(ph.fit_pi(*_rig_record()).model)):
        whole = ff.command(ref)
        ff.reset()
        streamed = np.array([ff.step(v) for v in ref])
        if isinstance(ff, ph.InversePIFeedforward):  # simulate may go event-driven: same to rounding
            np.testing.assert_allclose(streamed, whole, rtol=0, atol=1e-12 * np.abs(whole).max())
        else:
            np.testing.assert_array_equal(streamed, whole)


def _rig_record():
    rig = ph.VirtualRig(seed=0)
    ds = rig.excite(ph.sinusoid(1.0, 2, 0.0, 100.0, 1e-3 if False else rig.dt))
    return ds.u, ds.y


def test_pid_drives_first_order_plant_to_step_with_zero_steady_state_error():
    plant = FirstOrderPlant(gain=2.0, tau=0.05, dt=1e-3, disturbance=0.3)
    ref = np.ones(3000)
    out = ph.track(plant, ref, feedback=ph.PID(kp=0.5, ki=20.0, kd=0.0, dt=plant.dt))
    assert abs(out.output[-1] - 1.0) < 1e-6
    # P alone leaves a steady-state error: the integral is what removes it
    p_only = ph.track(plant, ref, feedback=ph.PID(kp=0.5, dt=plant.dt))
    assert abs(p_only.output[-1] - 1.0) > 0.05


def test_pid_output_limits_and_anti_windup():
    pid = ph.PID(kp=1.0, ki=100.0, dt=1e-3, u_min=-1.0, u_max=1.0)
    outs = [pid.step(10.0) for _ in range(1000)]
    assert max(outs) == 1.0
    # conditional integration: the integral did not wind up while saturated, so the output
    # leaves the limit as soon as the error changes sign
    assert pid.integral <= 1.0 + 1e-12
    assert pid.step(-2.0) < 1.0


def test_pid_derivative_is_filtered_and_has_no_kick():
    pid = ph.PID(kd=1.0, dt=1e-3, tf=1e-2)
    assert pid.step(5.0) == 0.0  # first sample: no derivative kick
    d1 = pid.step(6.0)
    # the filter of pid.py, D = tf/(tf+dt) D + kd/(tf+dt) (e - e_prev), from D = 0 with a unit
    # step of e: kd / (tf + dt) = 1 / 0.011 = 90.909 (the raw quotient kd/dt would be 1000)
    assert d1 == pytest.approx(1.0 / (1e-2 + 1e-3), rel=1e-12)
    # e held: the derivative decays by the pole tf / (tf + dt) = 10/11 each sample
    assert pid.step(6.0) == pytest.approx(d1 * 1e-2 / (1e-2 + 1e-3), rel=1e-12)
    assert pid.step(6.0) == pytest.approx(d1 * (1e-2 / (1e-2 + 1e-3)) ** 2, rel=1e-12)


def test_pid_integral_is_backward_euler_with_conditional_anti_windup():
    # pid.py: I += ki dt e, the current sample's error included (backward Euler), so the first
    # output is ki dt e = 10 * 1e-3 * 2 = 0.02 (forward Euler would give 0 and lag one sample)
    pid = ph.PID(ki=10, dt=1e-3)
    assert pid.step(2.0) == pytest.approx(0.02, rel=1e-12)
    assert pid.integral == pytest.approx(0.02, rel=1e-12)
    outs = [pid.step(e) for e in (1.0, -3.0, 0.5, 4.0)]
    # running sums of ki dt e: 0.02 + 0.01, - 0.03, + 0.005, + 0.04
    assert outs == pytest.approx([0.03, 0.0, 0.005, 0.045], abs=1e-15)
    assert pid.integral == pytest.approx(0.045, abs=1e-15)
    # a sample the actuator clipped (saturated=+1) does not integrate further up, but down it does
    assert pid.step(2.0, saturated=1) == pytest.approx(0.045, abs=1e-15)
    assert pid.step(-1.0, saturated=1) == pytest.approx(0.035, abs=1e-15)
    # its own limit: an increment that would take the output past u_max is not taken (the
    # integral stays at 0.04 after 0.02 + 0.02, as 0.06 > 0.05), and the output is not pinned
    # to the limit
    lim = ph.PID(ki=10, dt=1e-3, u_max=0.05)
    assert [lim.step(2.0) for _ in range(4)] == pytest.approx([0.02, 0.04, 0.04, 0.04], abs=1e-15)
    assert lim.integral == pytest.approx(0.04, abs=1e-15)
    assert lim.step(-1.0) == pytest.approx(0.03, abs=1e-15)  # unwinds at once: no stored excess


@given(kp=st.floats(0, 5), ki=st.floats(0, 50), e=st.lists(st.floats(-10, 10), min_size=1, max_size=50))
def test_pid_respects_limits(kp, ki, e):
    pid = ph.PID(kp=kp, ki=ki, dt=1e-2, u_min=-2.0, u_max=3.0)
    assert all(-2.0 <= pid.step(v) <= 3.0 for v in e)


def test_track_refuses_mismatched_dt():
    plant = FirstOrderPlant(dt=1e-3)
    with pytest.raises(ValueError, match="dt"):
        ph.track(plant, np.ones(10), feedback=ph.PID(ki=1.0, dt=1e-4))


def test_track_refuses_a_non_plant():
    with pytest.raises(TypeError, match="Plant protocol"):
        ph.track(object(), np.ones(10))


class _OneSampleReads:
    """A first-order plant whose ``step`` answers as a data-acquisition read of one sample does:
    a one-element array (or what ``answer`` makes of the value)."""

    def __init__(self, answer=lambda y: np.array([y])):
        self.dt = 1e-3
        self.answer = answer
        self.reset()

    def reset(self):
        self.y = 0.0

    def step(self, u):
        self.y += 0.2 * (0.1 * u - self.y)
        return self.answer(self.y)


def test_a_plant_may_answer_with_a_one_sample_array():
    ref = np.full(300, 2.0)
    got = ph.track(_OneSampleReads(), ref, feedback=ph.PID(ki=20.0, dt=1e-3))
    want = ph.track(_OneSampleReads(float), ref, feedback=ph.PID(ki=20.0, dt=1e-3))
    assert np.array_equal(got.output, want.output)
    assert ph.open_loop(_OneSampleReads(), np.ones(5)).y.dtype == np.float64


@pytest.mark.parametrize("answer, what", [(lambda y: None, "None"), (lambda y: np.array([y, y]), r"an array of shape \(2,\)"),
                                          (lambda y: "1.0", "'1.0'")])
def test_a_plant_that_answers_with_no_number_is_told_what_it_returned(answer, what):
    with pytest.raises(TypeError, match=r"plant\.step\(u\) must return the measured displacement as one "
                                        r"number .* returned .*" + what):
        ph.track(_OneSampleReads(answer), np.ones(10), feedback=ph.PID(ki=1.0, dt=1e-3))


def test_unstable_loop_stops_with_the_settings_in_the_message():
    plant = UnboundedIntegrator(dt=1e-3)
    with pytest.raises(ph.UnstableLoopError, match=r"'kp': 50\.0"):
        ph.track(plant, np.ones(2000), feedback=ph.PID(kp=50.0, dt=plant.dt))


def test_unstable_loop_on_the_saturating_rig_is_caught():
    rig = ph.VirtualRig(seed=0)
    ref = ph.sinusoid(5.0, 3, 0.25, 2.25, rig.dt)
    with pytest.raises(ph.UnstableLoopError, match="ki"):
        ph.track(rig, ref, feedback=ph.PID(kp=0.0, ki=1e6, dt=rig.dt))


def test_metrics_are_the_papers_over_cycles_after_the_first():
    period = 100
    ref = np.tile(np.sin(np.linspace(0, 2 * np.pi, period, endpoint=False)), 4) + 1.0
    out = ref.copy()
    out[10] += 5.0  # a start-up transient in the first cycle: not counted
    out[250] += 0.2
    m = tracking_metrics(ref, out, period=period)
    assert m.e_max == pytest.approx(0.2)
    assert m.e_max_percent == pytest.approx(100 * 0.2 / np.ptp(ref))
    assert m.rmse == pytest.approx(np.sqrt(0.2**2 / 300))
    assert m.samples == 300


def test_feedback_improves_tracking_on_the_rig():
    rig = ph.VirtualRig(seed=0)
    ds = rig.excite(ph.sinusoid(1.0, 2, 0.0, 100.0, rig.dt))
    ff = ph.InversePIFeedforward(ph.fit_pi(ds.u, ds.y).model)
    ref = ph.sinusoid(3.0, 3, 0.25, 2.25, rig.dt)
    alone = ph.track(rig, ref, ff)
    with_pid = ph.track(rig, ref, ff, ph.PID(ki=500.0, dt=rig.dt))
    assert with_pid.rmse < alone.rmse and with_pid.e_max < alone.e_max
    assert alone.clipped == 0


def test_non_invertible_model_is_refused_by_the_feedforward():
    bad = ph.PrandtlIshlinskii(ph.equal_thresholds(3, 10.0), [1.0, -2.0, 0.5])
    with pytest.raises(ValueError, match="not invertible"):
        ph.InversePIFeedforward(bad)
    with pytest.raises(TypeError):
        ph.BoucWenFeedforward(bad)


@pytest.mark.parametrize("shape", ["sine", "triangle", "square", "raster"])
def test_estimate_period_is_exact_for_any_periodic_shape(shape):
    from piezohyst.signals import estimate_period

    t = np.arange(40000) * 1e-4
    x = {"sine": np.sin(2 * np.pi * 2.5 * t), "triangle": np.abs((2.5 * t) % 1.0 - 0.5),
         "square": np.sign(np.sin(2 * np.pi * 2.5 * t) + 1e-9),
         "raster": np.concatenate([np.linspace(0, 1, 3000), np.linspace(1, 0, 1000)] * 10)}[shape]
    assert estimate_period(x) == 4000
    assert estimate_period(ph.sinusoid(1.0, 4, 0.25, 2.25, 1e-4)) == 10000  # was 9916


class _JumpAtStart:
    """A feedforward whose first command sits a fixed 0.6 V below the rest (the command there was
    clipped to the range, as behind an input lag's lead at the end of a conditioning sweep): a
    step no ramp's speed changes."""

    def __init__(self, jump):
        self.jump = jump

    def command(self, desired):
        cmd = 10.0 * np.asarray(desired, dtype=float)
        cmd[0] -= self.jump
        return cmd


def test_a_lead_in_stops_doubling_when_that_no_longer_smooths_it():
    """The lead-in's ramp doubles until its commands step by at most half the step limit. A step
    that the ramp's speed does not make never shrinks: the ramp doubled to 5 million samples
    (80 s of a stage driven sample by sample, on every tracking run of a stage behind a 6 ms
    amplifier lag). It now stops once doubling no longer shrinks the largest step; a ramp that
    is merely too fast still doubles until smooth."""
    from piezohyst.control.tracking import lead_in
    from piezohyst.plant import CommandLimits

    limits = CommandLimits.for_range((0.0, 100.0), max_step_fraction=0.01, rest=0.0)  # 1 V per sample
    dt = 1e-4
    desired, cmd = lead_in(_JumpAtStart(0.6), 1.0, 9.0, limits, dt)
    assert desired.size < 10_000, desired.size  # 6.6 million before
    desired, cmd = lead_in(_JumpAtStart(0.0), 1.0, 9.0, limits, dt)  # 80 V up: at least 160 samples
    assert np.abs(np.diff(cmd)).max() <= 0.5 and desired.size >= 160


def test_pid_settings_changed_after_construction_take_effect():
    # found by fuzzing: kd set to 0 after construction kept its derivative (the coefficients were
    # computed once), while settings() showed the new kd
    p = ph.PID(1.0, 0.0, 3.0, 1e-3)
    p.kd = 0.0
    assert p.step(0.0) == 0.0 and p.step(1.0) == 1.0 and p.settings()["kd"] == 0.0
    q = ph.PID(0.0, 0.0, 1.0, 1e-3, tf=1e-3, u_min=None)  # None: no limit
    q.tf = 3e-3
    q.step(0.0)
    assert q.step(1.0) == pytest.approx(1.0 / (3e-3 + 1e-3))
    assert q.u_min == -np.inf
