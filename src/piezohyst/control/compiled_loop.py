"""The closed loop of :func:`~piezohyst.control.tracking.track` compiled, for the parts that have kernels.

``track`` drives any Plant sample by sample in Python: one call into the feedforward, the PID
and the plant per sample, which costs microseconds each. When every part of the loop is one
whose arithmetic is already a compiled kernel, the whole loop runs in one compiled call instead:

* the plant is a :class:`~piezohyst.rig.VirtualRig` (its ``_rig_step``; the sensor noise drawn
  from the rig's own generator in one block, the same numbers ``step`` draws one at a time);
* the feedforward is none, an :class:`~piezohyst.models.pi.InversePIFeedforward` (``pi_step`` on
  the inverse model, eqs. 12-15) or a :class:`~piezohyst.models.bouc_wen_inverse.BoucWenFeedforward`
  (``bw_ff_step``, eq. 10), with the output limits of
  :class:`~piezohyst.models.base.Compensator`;
* the feedback is none or a :class:`~piezohyst.control.pid.PID`.

The loop is the one ``track`` documents, operation for operation, with the checks of
:class:`~piezohyst.control.tracking.LoopWatch`. It only ever runs a loop that completes: at the
first sample where anything unusual happens (a check that would stop the run, a non-finite
value) it gives up, and ``track`` runs the generic Python loop from the start, which raises the
error it always raised. So the compiled path changes nothing a caller can see but the time:
the states of the plant, the feedforward and the PID after the run are those the Python loop
leaves (``tests/test_tracking_compiled.py`` checks it sample for sample).

Any other plant, feedforward or feedback (a user's own hardware adapter, another model kind's
compensator, a subclass that may override a step) takes the generic loop.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .._numba import njit
from .._validation import FloatArray
from ..models.bouc_wen_inverse import BoucWenFeedforward, bw_ff_step
from ..models.pi import InversePIFeedforward
from ..models.play import pi_step
from ..models.rate import rate_inverse_step
from ..plant import guard_step
from ..rig import VirtualRig, _rig_step
from .pid import PID

# feedforward kinds of the kernel
_FF_NONE, _FF_PI, _FF_BW = 0, 1, 2
#: what the kernel returns when the loop ran to its end (else: the sample where it gave up)
COMPLETED = -1


@njit
def pid_step(e: float, sat: int, pid_g: FloatArray, pid_state: FloatArray) -> float:  # pragma: no cover
    """:meth:`PID.step` operation for operation: ``pid_g`` is ``[kp, ki, dt, a, b, u_min, u_max]``,
    ``pid_state`` ``[integral, derivative, previous error, first]`` (updated); the integral stops
    where the output, or the actuator (``sat``), is at its limit."""
    if pid_state[3] != 0.0:
        pid_state[2] = e
        pid_state[3] = 0.0
    pid_state[1] = pid_g[3] * pid_state[1] + pid_g[4] * (e - pid_state[2])
    pid_state[2] = e
    inc = pid_g[1] * pid_g[2] * e
    u_try = pid_g[0] * e + pid_state[0] + inc + pid_state[1]
    if inc > 0:
        blocked = u_try > pid_g[6] or sat > 0
    else:
        blocked = u_try < pid_g[5] or sat < 0
    if not blocked:
        pid_state[0] += inc
    out = pid_g[0] * e + pid_state[0] + pid_state[1]
    return min(max(out, pid_g[5]), pid_g[6])


@njit
def output_limits(raw: float, ff_lim: FloatArray, ff_lim_state: FloatArray) -> float:  # pragma: no cover
    """The compensator's output limits (``Compensator.step``): within ``ff_lim[2]`` of the last
    command, then within ``ff_lim[0] .. ff_lim[1]``; ``ff_lim_state`` is ``[has last, last,
    limited]``, updated."""
    v = raw
    if ff_lim_state[0] != 0.0 and ff_lim[2] < math.inf:
        v = min(max(v, ff_lim_state[1] - ff_lim[2]), ff_lim_state[1] + ff_lim[2])
    v = min(max(v, ff_lim[0]), ff_lim[1])
    if v != raw:
        ff_lim_state[2] += 1.0
    ff_lim_state[0] = 1.0
    ff_lim_state[1] = v
    return v


@njit
def watch_output_stops(y: FloatArray, r: FloatArray, k: int, limit: float, watch_window: bool, settle: int,
                       w: int, span: float) -> bool:  # pragma: no cover
    """:meth:`LoopWatch.output` for sample k: the output is not finite or further than ``limit``
    from the reference, or the RMS error of the window ending at k exceeds ``span`` (the watch's
    ``follow_rms``: the reference's span, or a multiple of the sensor's noise if more; with a hair
    of margin: at the threshold the Python loop, summing differently, decides)."""
    yk = y[k]
    if not math.isfinite(yk) or abs(yk - r[k]) > limit:
        return True
    if watch_window and k >= settle and k % w == w - 1:
        acc = 0.0
        for i in range(k - w + 1, k + 1):
            d = y[i] - r[i]
            acc += d * d
        if math.sqrt(acc / w) > span * (1.0 - 1e-9):
            return True
    return False


@njit
def _closed_loop(r: FloatArray, y: FloatArray, u: FloatArray,
                 # the rig (VirtualRig._rig_step's arguments) and its noise, one value per sample
                 p: FloatArray, kv_a: FloatArray, kv_g: FloatArray, amp_a: float, st: FloatArray,
                 line: FloatArray, consts: FloatArray, noise: FloatArray,
                 # the feedforward: kind, arrays (P-I: thresholds, weights, state; Bouc-Wen: the
                 # constants of eq. 10, unused, state [u_prev, h]), scalars (P-I: input and output
                 # offsets; Bouc-Wen: offset), limits [u_lo, u_hi, max_slew] (inf: none) and
                 # their state [has_last, u_last, limited]
                 ff_kind: int, ff_a: FloatArray, ff_b: FloatArray, ff_state: FloatArray, ff_s: FloatArray,
                 ff_lim: FloatArray, ff_lim_state: FloatArray,
                 # the PID: on, gains [kp, ki, dt, a, b, u_min, u_max], state [integral, d, e_prev, first]
                 fb_on: bool, pid_g: FloatArray, pid_state: FloatArray, at_ref: bool,
                 # LoopWatch: [lo_u, hi_u, limit, span, settle, window, chatter], switches
                 watch: FloatArray, watch_chatter: bool, watch_window: bool) -> int:  # pragma: no cover
    """The loop of :func:`~piezohyst.control.tracking.track` (module docstring); the sample where
    it gave up, or :data:`COMPLETED`."""
    n = r.shape[0]
    lo_u, hi_u, limit, span = watch[0], watch[1], watch[2], watch[3]
    settle, w, chatter = int(watch[4]), int(watch[5]), int(watch[6])
    n_lo = 0
    n_hi = 0
    sat = 0
    y_prev = 0.0
    for k in range(n):
        rk = r[k]
        # -- PID.step(rk - y_prev, sat)
        fb = 0.0
        if fb_on:
            e = rk - y_prev
            if not math.isfinite(e):
                return k
            fb = pid_step(e, sat, pid_g, pid_state)
        # -- the feedforward (Compensator.step: the inverse, then the output limits)
        if ff_kind == _FF_NONE:
            uk = fb
        else:
            x = rk + fb if at_ref else rk
            if not math.isfinite(x):
                return k
            if ff_kind == _FF_PI:
                raw = pi_step(x, ff_a, ff_b, ff_state, ff_s[0], ff_s[1])
            else:
                raw = bw_ff_step(ff_a[0], ff_a[1], ff_a[2], ff_a[3], ff_state, x * 1e-6 - ff_s[0])
            v = output_limits(raw, ff_lim, ff_lim_state)
            uk = v if at_ref else v + fb
        # -- LoopWatch.command
        if not math.isfinite(uk):
            return k
        sat = 1 if uk > hi_u else (-1 if uk < lo_u else 0)
        if watch_chatter:
            if sat > 0:
                n_hi += 1
            elif sat < 0:
                n_lo += 1
            if k % chatter == chatter - 1:
                if n_hi >= 10 and n_lo >= 10:
                    return k
                n_lo = 0
                n_hi = 0
        # -- the plant
        yk = _rig_step(p, kv_a, kv_g, amp_a, st, line, consts, uk, noise[k])
        u[k] = uk
        y[k] = yk
        # -- LoopWatch.output
        if watch_output_stops(y, r, k, limit, watch_window, settle, w, span):
            return k
        y_prev = yk
    return COMPLETED


def limits_arrays(ff: Any) -> tuple[FloatArray, FloatArray]:
    """A compensator's output limits as :func:`output_limits` takes them (none for ``None``)."""
    if ff is None:
        return np.array([-math.inf, math.inf, math.inf]), np.zeros(3)
    lo, hi = ff.u_range if ff.u_range is not None else (-math.inf, math.inf)
    last = ff._u_last
    return (np.array([lo, hi, ff.max_slew if ff.max_slew is not None else math.inf]),
            np.array([0.0 if last is None else 1.0, 0.0 if last is None else last, float(ff.limited)]))


def limits_back(ff: Any, state: FloatArray) -> None:
    """Take back the limits' state of :func:`limits_arrays` after a kernel ran."""
    if ff is not None:
        ff._u_last = float(state[1]) if state[0] != 0.0 else None
        ff.limited = int(state[2])


def pid_arrays(pid: Any) -> tuple[FloatArray, FloatArray]:
    """A :class:`PID` as :func:`pid_step` takes it (zeros for ``None``)."""
    if pid is None:
        return np.zeros(7), np.zeros(4)
    return (np.array([pid.kp, pid.ki, pid.dt, pid._a, pid._b, pid.u_min, pid.u_max]),
            np.array([pid.integral, pid._d, pid._e_prev, 1.0 if pid._first else 0.0]))


def pid_back(pid: Any, state: FloatArray) -> None:
    """Take back the PID's state of :func:`pid_arrays` after a kernel ran."""
    if pid is not None:
        pid.integral, pid._d, pid._e_prev = (float(v) for v in state[:3])
        pid._first = bool(state[3] != 0.0)


def _ff_spec(ff: Any) -> tuple[int, FloatArray, FloatArray, FloatArray, FloatArray] | None:
    """The kernel's view of a feedforward it knows (exact types: a subclass may override a step)."""
    if ff is None:
        e = np.zeros(1)
        return _FF_NONE, e, e, e, e
    if type(ff) is InversePIFeedforward:
        s = ff._stepper
        return _FF_PI, s._r, s._w, s._z, np.array([s._in, s._out])
    if type(ff) is BoucWenFeedforward:
        return _FF_BW, np.array(ff._consts, dtype=np.float64), np.zeros(1), ff._st, np.array([ff.model.offset])
    return None


def has_kernels(plant: Any, feedforward: Any, feedback: Any) -> bool:
    """Whether the loop of these parts can run compiled (module docstring)."""
    return (type(plant) is VirtualRig and (feedback is None or type(feedback) is PID)
            and _ff_spec(feedforward) is not None)


def run_compiled(plant: Any, r: FloatArray, feedforward: Any, feedback: Any, *, at_ref: bool,
                 watch: Any) -> tuple[FloatArray, FloatArray] | None:
    """Run the loop of ``track`` compiled (the parts must pass :func:`has_kernels`), from the state
    ``track`` has just reset everything to; ``(y, u)``, or None when the run gave up: then the
    plant, the feedforward and the feedback must be reset and the Python loop run."""
    spec = _ff_spec(feedforward)
    assert spec is not None
    kind, ff_a, ff_b, ff_state, ff_s = spec
    ff_lim, ff_lim_state = limits_arrays(feedforward)
    pid_g, pid_state = pid_arrays(feedback)
    wv = np.array([watch.lo_u, watch.hi_u, watch.limit, watch.follow_rms, watch.settle, watch.WINDOW, watch.CHATTER],
                  dtype=np.float64)
    n = r.size
    y = np.empty(n)
    u = np.empty(n)
    noise = plant._rng.standard_normal(n)
    k = _closed_loop(r, y, u, plant._p, plant._kv_a, plant._kv_g, plant._amp_a, plant._st, plant._line,
                     plant._consts, noise, kind, ff_a, ff_b, ff_state, ff_s, ff_lim, ff_lim_state,
                     feedback is not None, pid_g, pid_state, at_ref, wv, bool(watch.watch_chatter),
                     bool(watch.watch_window))
    if k != COMPLETED:
        return None
    plant._n += n
    limits_back(feedforward, ff_lim_state)
    pid_back(feedback, pid_state)
    return y, u


# -- the commissioned controller's loop ----------------------------------------------------------
@njit
def _guarded_loop(k0: int, k1: int, r: FloatArray, y: FloatArray, u: FloatArray, clipped_at: Any,
                  corr: FloatArray, has_corr: bool, c_of: FloatArray, c_to_feedback: bool, d: int, vpu: float,
                  # the rig and its noise for samples k0..k1-1
                  p: FloatArray, kv_a: FloatArray, kv_g: FloatArray, amp_a: float, st: FloatArray,
                  line: FloatArray, consts: FloatArray, noise: FloatArray,
                  # the rate-dependent inverse (RateCompensator._kernel_args: P-I or Preisach) and the
                  # compensator's limits [u_lo, u_hi, max_slew] and their state [has_last, u_last, limited]
                  ff_kind: int, ff_f: FloatArray, ff_i1: FloatArray, ff_i2: FloatArray, ff_i3: FloatArray,
                  ff_i4: FloatArray, ff_vlast: FloatArray, ff_a: FloatArray, ff_c: FloatArray, ff_s: FloatArray,
                  ff_b: float, ff_vprev: FloatArray, ff_lim: FloatArray, ff_lim_state: FloatArray,
                  # the PID (as in _closed_loop)
                  fb_on: bool, pid_g: FloatArray, pid_state: FloatArray,
                  # GuardedPlant: [low, high, max_step, tol], state [last, clipped, slew_limited,
                  # largest_step, last_saturation, sent]
                  guard: FloatArray, guard_state: FloatArray,
                  # LoopWatch (as in _closed_loop), its chatter counts [n_lo, n_hi]
                  watch: FloatArray, watch_chatter: bool, watch_window: bool, watch_state: FloatArray,
                  # [y_prev, sat] carried from one call to the next
                  loop_state: FloatArray) -> int:  # pragma: no cover
    """Samples ``k0..k1-1`` of the loop of :meth:`CommissionedController._track_step
    <piezohyst.commissioning.CommissionedController._track_step>`: integral feedback on the command,
    the rate-dependent inverse (P-I or Preisach) fed ``d`` samples ahead (plus the learned correction, which the
    feedback's reference carries too with ``c_to_feedback``: ``c_of``), the
    safe layer, the rig, the checks of LoopWatch. The sample where it gave up (anything a check
    or a step would raise on), or :data:`COMPLETED`."""
    n = r.shape[0]
    p_len = corr.shape[0]
    lo_u, hi_u, limit, span = watch[0], watch[1], watch[2], watch[3]
    settle, w, chatter = int(watch[4]), int(watch[5]), int(watch[6])
    g_lo, g_hi, g_step, g_tol = guard[0], guard[1], guard[2], guard[3]
    y_prev = loop_state[0]
    sat = int(loop_state[1])
    for k in range(k0, k1):
        # -- PID.step(r[k - 1] + c_of[k - 1] - y_prev, sat) * volts_per_um: the corrected reference
        fb = 0.0
        if fb_on and k > 0:
            e = r[k - 1] + c_of[k - 1] - y_prev
            if not math.isfinite(e):
                return k
            fb = pid_step(e, sat, pid_g, pid_state) * vpu
        # -- the feedforward, d samples ahead (Compensator.step: the inverse, then its limits)
        j = min(k + d, n - 1)
        c = corr[j % p_len] if has_corr else 0.0
        if c_to_feedback:
            c_of[j] = c
        target = r[j] + c
        if not math.isfinite(target):
            return k
        raw = rate_inverse_step(target, ff_kind, ff_f, ff_i1, ff_i2, ff_i3, ff_i4, ff_vlast, ff_a, ff_c, ff_s, ff_b,
                                ff_vprev)
        if math.isnan(raw):
            return k
        v = output_limits(raw, ff_lim, ff_lim_state)
        uk = v + fb
        # -- LoopWatch.command
        if not math.isfinite(uk):
            return k
        if watch_chatter:
            if uk > hi_u:
                watch_state[1] += 1.0
            elif uk < lo_u:
                watch_state[0] += 1.0
            if k % chatter == chatter - 1:
                if watch_state[1] >= 10 and watch_state[0] >= 10:
                    return k
                watch_state[0] = 0.0
                watch_state[1] = 0.0
        # -- GuardedPlant._guard
        gv = guard_step(uk, g_lo, g_hi, g_step, g_tol, guard_state)
        sat = int(guard_state[4])
        guard_state[5] += 1.0
        # -- the rig
        yk = _rig_step(p, kv_a, kv_g, amp_a, st, line, consts, gv, noise[k - k0])
        clipped_at[k + d] = sat != 0
        u[k] = gv
        y[k] = yk
        # -- LoopWatch.output
        if watch_output_stops(y, r, k, limit, watch_window, settle, w, span):
            return k
        y_prev = yk
        loop_state[0] = y_prev
        loop_state[1] = sat
    return COMPLETED


# -- the safe tuning's hold at a level (tune_integral_safely) ------------------------------------
#: why :func:`_hold_loop` stopped before the end: a trial's check (sample k done), the inverse
#: refused its input (the PID stepped, nothing else), the command is not finite (the feedforward
#: stepped too, nothing sent)
HOLD_CHECK, HOLD_FF, HOLD_COMMAND = 1, 2, 3


@njit
def _hold_loop(n: int, level: float, add: float, check: bool, e0: float, fb0: float, tol_e: float, tol_fb: float,
               fbs: FloatArray, vpu: float,
               # the rate-dependent inverse (RateCompensator._kernel_args), its limits and their state
               ff_kind: int, ff_f: FloatArray, ff_i1: FloatArray, ff_i2: FloatArray, ff_i3: FloatArray,
               ff_i4: FloatArray, ff_vlast: FloatArray, ff_a: FloatArray, ff_c: FloatArray, ff_s: FloatArray,
               ff_b: float, ff_vprev: FloatArray, ff_lim: FloatArray, ff_lim_state: FloatArray,
               pid_g: FloatArray, pid_state: FloatArray,
               # GuardedPlant (as in _guarded_loop)
               guard: FloatArray, guard_state: FloatArray,
               # the rig and its generator (one normal draw per sample, as VirtualRig.step)
               p: FloatArray, kv_a: FloatArray, kv_g: FloatArray, amp_a: float, st: FloatArray,
               line: FloatArray, consts: FloatArray, rng: Any,
               # [y, sat, u_lo, u_hi, why stopped, the command that was not finite]
               loop_state: FloatArray) -> int:  # pragma: no cover
    """``n`` samples of the safe tuning's hold (the ``run`` of
    :func:`~piezohyst.control.tuning.tune_integral_safely`), operation for operation: integral
    feedback on the error to ``level``, the feedforward of ``level``, plus ``add`` (the probe),
    through the guard to the rig; the feedback's outputs in ``fbs``. With ``check``, it stops
    after the first sample whose error or feedback moved further than ``tol_e`` / ``tol_fb`` from
    ``e0`` / ``fb0``. Returns :data:`COMPLETED` or the sample where it stopped (why: ``loop_state[4]``)."""
    y = loop_state[0]
    sat = int(loop_state[1])
    u_lo, u_hi = loop_state[2], loop_state[3]
    g_lo, g_hi, g_step, g_tol = guard[0], guard[1], guard[2], guard[3]
    for k in range(n):
        fb = pid_step(level - y, sat, pid_g, pid_state) * vpu
        fbs[k] = fb
        raw = rate_inverse_step(level, ff_kind, ff_f, ff_i1, ff_i2, ff_i3, ff_i4, ff_vlast, ff_a, ff_c, ff_s, ff_b,
                                ff_vprev)
        if math.isnan(raw):
            loop_state[4] = HOLD_FF
            return k
        u = output_limits(raw, ff_lim, ff_lim_state) + fb + add
        if not math.isfinite(u):
            loop_state[4] = HOLD_COMMAND
            loop_state[5] = u
            return k
        gv = guard_step(u, g_lo, g_hi, g_step, g_tol, guard_state)
        guard_state[5] += 1.0
        sat = int(guard_state[4])
        y = _rig_step(p, kv_a, kv_g, amp_a, st, line, consts, gv, rng.standard_normal())
        u_lo = min(u_lo, gv)
        u_hi = max(u_hi, gv)
        loop_state[0], loop_state[1], loop_state[2], loop_state[3] = y, sat, u_lo, u_hi
        if check and (abs((level - y) - e0) > tol_e or abs(fb - fb0) > tol_fb):
            loop_state[4] = HOLD_CHECK
            return k
    return COMPLETED


def run_hold(guard: Any, ff: Any, pid: Any, *, n: int, level: float, add: float, check: bool, e0: float,
             fb0: float, tol_e: float, tol_fb: float, vpu: float, state: dict[str, Any]) -> Any:
    """The safe tuning's hold compiled (:func:`_hold_loop`) when the parts have kernels: a
    :class:`~piezohyst.plant.GuardedPlant` around a :class:`~piezohyst.rig.VirtualRig`, a
    rate-dependent compensator of a P-I or Preisach model, a :class:`PID` (exact types). Returns the feedback's outputs,
    None when the check stopped the hold, or ``NotImplemented`` (the parts have no kernels: the
    caller runs its Python loop). ``state`` (``y``, ``sat``, ``u_lo``, ``u_hi``) and the objects'
    states are left as the Python loop leaves them; where that loop would raise (a value that is
    not finite), the same call raises here, from the same state."""
    from ..models.rate import RateCompensator
    from ..plant import GuardedPlant

    rig = getattr(guard, "plant", None)
    if (type(guard) is not GuardedPlant or type(rig) is not VirtualRig or type(pid) is not PID
            or type(ff) is not RateCompensator):
        return NotImplemented
    ff_args = ff._kernel_args()
    if ff_args is None:
        return NotImplemented
    ff_lim, ff_lim_state = limits_arrays(ff)
    pid_g, pid_state = pid_arrays(pid)
    g, g_state = guard.kernel_arrays()
    loop_state = np.array([state["y"], state["sat"], state["u_lo"], state["u_hi"], 0.0, 0.0])
    fbs = np.empty(n)
    args: tuple[Any, ...] = (n, float(level), float(add), bool(check), float(e0), float(fb0), float(tol_e),
                             float(tol_fb), fbs, float(vpu), *ff_args, ff_lim, ff_lim_state, pid_g, pid_state, g,
                             g_state, rig._p, rig._kv_a, rig._kv_g, rig._amp_a, rig._st, rig._line, rig._consts,
                             rig._rng, loop_state)
    k = _hold_loop(*args)
    # the objects' states as the Python loop leaves them
    why = int(loop_state[4]) if k != COMPLETED else 0
    rig._n += int(g_state[5]) - guard.sent
    guard.set_kernel_state(g_state)
    ff._kernel_back(ff_args)
    limits_back(ff, ff_lim_state)
    pid_back(pid, pid_state)
    state["y"], state["sat"] = float(loop_state[0]), int(loop_state[1])
    state["u_lo"], state["u_hi"] = float(loop_state[2]), float(loop_state[3])
    if k == COMPLETED:
        return fbs
    if why == HOLD_CHECK:
        return None
    # what the Python loop raises at this sample, from the state it would raise in
    if why == HOLD_FF:
        ff.step(level)
    else:
        guard.step(float(loop_state[5]))
    raise RuntimeError(f"the compiled hold stopped at sample {k} where the Python loop goes on")  # pragma: no cover
