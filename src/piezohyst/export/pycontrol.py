"""The bridge to python-control (optional extra ``control``: ``pip install 'piezohyst[control]'``).

So a user can read the margins of the loop they commission with the tools they know:

* :func:`bouc_wen_linear_part` - the linear part of the paper's eq. (7) as a continuous
  ``control.TransferFunction``: ``k / (m s^2 + b s + k)`` from the forcing ``d1 u - h`` to x, or,
  with ``input="u"``, from the command (V) to x (µm) with the hysteresis held;
* :func:`pid_transfer_function` - a :class:`~piezohyst.control.pid.PID` as the discrete transfer
  function it implements: ``kp + ki dt z/(z-1) + kd/(tf+dt) (z-1)/(z-a)``, ``a = tf/(tf+dt)``;
* :func:`commissioned_loop` - the commissioned controller's loop as ``control.FrequencyResponseData``,
  one per branch of the identified model's small-signal response (rising and reversing: a
  hysteretic stage's slope differs between them), with the integral feedback, the output scale
  (V per µm), the measured delay and the sample the loop waits for its measurement; and
  :func:`loop_margins`, ``control.stability_margins`` of each. The model's linear part is obtained
  through the model protocol (:func:`~piezohyst.control.tuning.small_signal_responses`), so this
  works for every kind; for a Bouc-Wen model it is the exact response of eq. (7).

python-control is imported only when one of these is called; without it they raise ImportError
with the command that installs it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def _control() -> Any:
    try:
        import control
    except ImportError:
        raise ImportError("the python-control bridge needs the optional package 'control': "
                          "pip install 'piezohyst[control]' (or pip install control)") from None
    return control


def bouc_wen_linear_part(model: Any, *, input: str = "w") -> Any:
    """The linear part of eq. (7) as a continuous ``control.TransferFunction``.

    ``input="w"``: from the forcing ``w = d1 u - h`` (m) to the displacement x (m),
    ``k / (m s^2 + b s + k)``; ``input="u"``: from the command (V) to x in µm with h held,
    ``1e6 d1 k / (m s^2 + b s + k)``.
    """
    ct = _control()
    if input not in ("w", "u"):
        raise ValueError(f"input must be 'w' (the forcing d1 u - h) or 'u' (the command), got {input!r}")
    for name in ("m", "b", "k", "d1"):
        if not hasattr(model, name):
            raise TypeError(f"a Bouc-Wen model is needed (with m, b, k, d1), got {type(model).__name__}")
    gain = model.k * (1e6 * model.d1 if input == "u" else 1.0)
    return ct.tf([gain], [model.m, model.b, model.k])


def pid_transfer_function(pid: Any) -> Any:
    """The discrete transfer function (sample period ``pid.dt``) that :class:`PID` implements
    (without its limits): ``kp + ki dt z/(z-1) + kd/(tf+dt) (z-1)/(z-a)``."""
    ct = _control()
    dt = float(pid.dt)
    a = pid.tf / (pid.tf + dt)
    b = pid.kd / (pid.tf + dt)
    c = ct.tf([pid.kp], [1.0], dt)
    if pid.ki:
        c = c + ct.tf([pid.ki * dt, 0.0], [1.0, -1.0], dt)
    if pid.kd:
        c = c + ct.tf([b, -b], [1.0, -a], dt)
    return c


def commissioned_loop(ctl: Any, *, n_freqs: int = 600) -> dict[str, Any]:
    """The commissioned controller's open loop, one ``control.FrequencyResponseData`` per branch
    (module docstring). Needs tuned feedback (a plant with a per-sample loop)."""
    ct = _control()
    from ..control.tuning import integral_loop_response, small_signal_responses

    if ctl.tuning is None:
        raise ValueError("the controller has no feedback (not tuned, or the plant only plays tables): no loop")
    dt = ctl.plant.dt
    limits = ctl._limits()
    ff = ctl.feedforward()
    level = float(np.median(ctl.identification.y))
    u_level = float(ff.command(np.full(max(int(round(0.05 / dt)), 20), level))[-1])
    u_level = min(max(u_level, limits.low), limits.high)
    resp = integral_loop_response(small_signal_responses(ctl.model, dt, u_level=u_level,
                                                         u_range=(limits.low, limits.high)),
                                  dt, delay=ctl.delay, scale=ctl.volts_per_um, n_freqs=n_freqs)
    omega = 2 * math.pi * resp.freqs_hz
    return {name: ct.frd(ctl.tuning.ki * lp, omega) for name, lp in resp.loops.items()}


def loop_margins(ctl: Any) -> dict[str, dict[str, float]]:
    """``control.stability_margins`` of each branch's loop: gain margin, phase margin (degrees) and
    their frequencies (rad/s)."""
    ct = _control()
    out = {}
    for name, sys in commissioned_loop(ctl).items():
        gm, pm, _sm, wpc, wgc, _wms = ct.stability_margins(sys)
        out[name] = {"gain_margin": float(gm), "phase_margin_deg": float(pm), "phase_crossover_rad_s": float(wpc),
                     "gain_crossover_rad_s": float(wgc)}
    return out
