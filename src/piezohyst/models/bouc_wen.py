"""The Bouc-Wen model of the paper's PSA-driven system, eqs. (7)-(8).

    m x'' + b x' + k x = k (d1 u - h)                                        (7)
    h'  = alpha d1 u' - beta |u'| h - gamma u' |h|                           (8)

Units are the paper's SI units: u in volts, x and h in metres, d1 in m/V, m in kg, b in N s/m,
k in N/m. Conversions to micrometres happen at the plant and data-set boundary, not here.

How it is computed, exactly and without an ODE solver:

* **h is rate independent.** Eq. (8) divided by u' gives dh/du, which on a monotone input
  increment of size ``lam = |du|`` and direction ``s = sign(du)`` is the *linear* ODE
  ``dh/dlam = s alpha d1 - (beta + gamma s sign(h)) h``. It is solved in closed form over the
  increment; if h changes sign inside it, the solution is continued from h = 0 with the other
  regime (:func:`bw_h_update`). No Euler step, no step-size error.
* **The linear part is discretised exactly** with the matrix exponential of the augmented
  system. The default hold is first-order (``hold="foh"``): the input is taken as linear between
  samples, which the exact discretisation integrates without error, and ``x[k]`` is the
  displacement at the instant ``u[k]`` is reached, so output sample k lines up with input
  sample k as in the P-I model. ``hold="zoh"`` holds each sample for one period (a staircase
  D/A) and reports the displacement at the end of it. The two differ by about half a sample of
  delay (0.3 nm at 1 Hz, 0-100 V, 10 kHz). The paper's parameters put a lightly damped
  (zeta = 0.0017) resonance at 1.70 kHz, which any explicit scheme at 10 kHz would get wrong.

The model starts at rest and de-energised: ``u = 0``, ``h = h0`` (default 0), x at equilibrium.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np

from .._numba import njit
from .._validation import FloatArray, as_scalar, as_signal
from .base import need_dt, register_kind

Hold = Literal["foh", "zoh"]

# layout of the parameter vector shared by the kernels
_P_D1, _P_AD1, _P_BETA, _P_GAMMA = 0, 1, 2, 3
_P_LEN = 13
# layout of the state vector: previous input, h, x, scaled velocity, previous forcing
_S_LEN = 5


@njit
def _phi1(x: float) -> float:  # pragma: no cover - compiled
    """(1 - exp(-x)) / x, accurate near 0."""
    if abs(x) < 1e-9:
        return 1.0 - 0.5 * x
    return -math.expm1(-x) / x


@njit
def bw_h_update(h: float, du: float, ad1: float, beta: float, gamma: float) -> float:  # pragma: no cover
    """Exact solution of eq. (8) over one input increment ``du`` (rate independent).

    ``ad1`` is ``alpha * d1``. With ``lam = |du|``, ``s = sign(du)``, ``sig = sign(h)``:
    ``dh/dlam = a - c h``, ``a = s * ad1``, ``c = beta + gamma * s * sig``, whose solution is
    ``h(lam) = h0 exp(-c lam) + a lam (1 - exp(-c lam)) / (c lam)``. If h reaches 0 within the
    increment the rest of it is solved in the other regime.
    """
    if du == 0.0:
        return h
    s = 1.0 if du > 0.0 else -1.0
    lam = abs(du)
    a = s * ad1
    for _ in range(2):
        if h > 0.0:
            sig = 1.0
        elif h < 0.0:
            sig = -1.0
        else:
            sig = 1.0 if a >= 0.0 else -1.0
        c = beta + gamma * s * sig
        # does h reach zero inside this increment? only if the drive a points across zero
        if h != 0.0 and a * sig < 0.0:
            lam0 = -1.0
            if c == 0.0:
                lam0 = -h / a
            else:
                ratio = a / (a - c * h)
                if ratio > 0.0:
                    lam0 = -math.log(ratio) / c
            if 0.0 < lam0 < lam:
                h = 0.0
                lam -= lam0
                continue
        return h * math.exp(-c * lam) + a * lam * _phi1(c * lam)
    return h  # not reached: at most one sign change per monotone increment


@njit
def expm_small(a: FloatArray) -> FloatArray:  # pragma: no cover - compiled
    """Matrix exponential of a small square matrix (scaling and squaring, Taylor series).

    Checked against ``scipy.linalg.expm`` in the tests; used where a kernel must discretise a
    model per particle without leaving compiled code.
    """
    n = a.shape[0]
    norm = 0.0
    for i in range(n):
        row = 0.0
        for j in range(n):
            row += abs(a[i, j])
        norm = max(norm, row)
    s = 0
    if norm > 0.5:
        s = int(math.ceil(math.log2(norm / 0.5)))
    x = a / (2.0**s)
    result = np.eye(n)
    term = np.eye(n)
    for p in range(1, 24):
        term = term @ x / p
        result = result + term
    for _ in range(s):
        result = result @ result
    return result


@njit
def bw_params(
    m: float, b: float, k: float, d1: float, alpha: float, beta: float, gamma: float,
    offset: float, dt: float, foh: bool,
) -> FloatArray:  # pragma: no cover - compiled
    """Pack eqs. (7)-(8) into the kernel parameter vector, discretising the linear part.

    The state is ``(x, v / w0)`` with ``w0 = sqrt(k/m)``, which keeps the matrix well scaled.
    The augmented matrix ``[[A dt, B dt, 0], [0, 0, 1], [0, 0, 0]]`` gives, through one matrix
    exponential, the transition matrix and the zero- and first-order hold input terms.
    """
    w0 = math.sqrt(k / m)
    big = np.zeros((4, 4))
    big[0, 1] = w0 * dt
    big[1, 0] = -w0 * dt
    big[1, 1] = -(b / m) * dt
    big[1, 2] = w0 * dt
    big[2, 3] = 1.0
    e = expm_small(big)
    p = np.empty(_P_LEN)
    p[0] = d1
    p[1] = alpha * d1
    p[2] = beta
    p[3] = gamma
    p[4] = e[0, 0]
    p[5] = e[0, 1]
    p[6] = e[1, 0]
    p[7] = e[1, 1]
    if foh:
        p[8] = e[0, 2] - e[0, 3]
        p[9] = e[1, 2] - e[1, 3]
        p[10] = e[0, 3]
        p[11] = e[1, 3]
    else:
        p[8] = 0.0
        p[9] = 0.0
        p[10] = e[0, 2]
        p[11] = e[1, 2]
    p[12] = offset
    return p


@njit
def bw_initial_state(h0: float) -> FloatArray:  # pragma: no cover - compiled
    """At rest, de-energised: u = 0, h = h0, x at its equilibrium -h0, no velocity."""
    st = np.empty(_S_LEN)
    st[0] = 0.0
    st[1] = h0
    st[2] = -h0
    st[3] = 0.0
    st[4] = -h0
    return st


@njit
def mech_step(p: FloatArray, st: FloatArray, f: float) -> float:  # pragma: no cover - compiled
    """The linear part of eq. (7) over one sample, driven by ``f = d1 u - h`` (metres).

    Updates ``st[2:5]`` (x, scaled velocity, previous forcing) and returns x without offset.
    Shared by :func:`bw_step` and the virtual rig, so both integrate the same dynamics.
    """
    x = st[2]
    v = st[3]
    fp = st[4]
    xn = p[4] * x + p[5] * v + p[8] * fp + p[10] * f
    st[3] = p[6] * x + p[7] * v + p[9] * fp + p[11] * f
    st[2] = xn
    st[4] = f
    return xn


@njit
def bw_step(p: FloatArray, st: FloatArray, u: float) -> float:  # pragma: no cover - compiled
    """One sample of eqs. (7)-(8): update the state ``st`` in place, return x (m) + offset."""
    h = bw_h_update(st[1], u - st[0], p[1], p[2], p[3])
    st[0] = u
    st[1] = h
    return mech_step(p, st, p[0] * u - h) + p[12]


@njit
def bw_simulate(p: FloatArray, st: FloatArray, u: FloatArray) -> FloatArray:  # pragma: no cover
    """:func:`bw_step` over a whole signal."""
    out = np.empty(u.shape[0])
    for k in range(u.shape[0]):
        out[k] = bw_step(p, st, u[k])
    return out


@njit
def bw_hysteresis(u: FloatArray, h0: float, ad1: float, beta: float, gamma: float) -> FloatArray:  # pragma: no cover
    """h alone (eq. 8) over a signal, from the de-energised state ``u = 0, h = h0``."""
    out = np.empty(u.shape[0])
    h = h0
    up = 0.0
    for k in range(u.shape[0]):
        h = bw_h_update(h, u[k] - up, ad1, beta, gamma)
        up = u[k]
        out[k] = h
    return out


def _check_hold(hold: str) -> bool:
    if hold not in ("foh", "zoh"):
        raise ValueError(f"hold must be 'foh' or 'zoh', got {hold!r}")
    return hold == "foh"


@register_kind("bouc-wen", "bw", "boucwen")
@dataclass(frozen=True)
class BoucWen:
    """The paper's Bouc-Wen model of a piezo stack driving a flexure, eqs. (7)-(8).

    Parameters
    ----------
    m : float
        Inertia, kg (> 0). Paper: 0.75.
    b : float
        Damping, N s/m (>= 0). Paper: 27.96.
    k : float
        Stiffness, N/m (> 0). Paper: 8.54e7.
    d1 : float
        Piezoelectric constant, m/V (> 0). Paper: 2.15e-8.
    alpha, beta, gamma : float
        Loop magnitude and shape. Paper: 0.472, 0.072, 0. ``beta`` and ``gamma`` are in 1/V.
    offset : float
        Added to the displacement, m (a sensor zero; 0 in the paper).
    h0 : float
        Initial hysteresis state, m (0: de-energised).

    Examples
    --------
    >>> import piezohyst as ph, numpy as np
    >>> bw = ph.BoucWen(m=0.75, b=27.96, k=8.54e7, d1=2.15e-8, alpha=0.472, beta=0.072, gamma=0.0)
    >>> round(bw.natural_frequency_hz)  # sqrt(8.54e7 / 0.75) / (2 pi): the paper's "1.7 kHz"
    1698
    """

    m: float
    b: float
    k: float
    d1: float
    alpha: float
    beta: float
    gamma: float = 0.0
    offset: float = 0.0
    h0: float = 0.0

    def __post_init__(self) -> None:
        for name in ("m", "k", "d1"):
            object.__setattr__(self, name, as_scalar(name, getattr(self, name), positive=True))
        object.__setattr__(self, "b", as_scalar("b", self.b, nonnegative=True))
        for name in ("alpha", "beta", "gamma", "offset", "h0"):
            object.__setattr__(self, name, as_scalar(name, getattr(self, name)))

    # -- derived figures ------------------------------------------------------------------
    @property
    def natural_frequency_hz(self) -> float:
        """Undamped natural frequency sqrt(k/m) / 2 pi, Hz."""
        return math.sqrt(self.k / self.m) / (2 * math.pi)

    @property
    def damping_ratio(self) -> float:
        """b / (2 sqrt(k m))."""
        return self.b / (2 * math.sqrt(self.k * self.m))

    def parameters(self) -> dict[str, float]:
        """The seven parameters of eqs. (7)-(8) (plus offset and h0) as a dict."""
        return {
            "m": self.m, "b": self.b, "k": self.k, "d1": self.d1, "alpha": self.alpha,
            "beta": self.beta, "gamma": self.gamma, "offset": self.offset, "h0": self.h0,
        }

    def kernel_params(self, dt: float, hold: Hold = "foh") -> FloatArray:
        """The packed, discretised parameter vector the compiled kernels take."""
        dt = as_scalar("dt", dt, positive=True)
        foh = _check_hold(hold)
        return bw_params(self.m, self.b, self.k, self.d1, self.alpha, self.beta, self.gamma,
                         self.offset, dt, foh)

    # -- simulation -----------------------------------------------------------------------
    def simulate(self, u: Any, dt: float, *, hold: Hold = "foh") -> FloatArray:
        """Displacement x (metres, plus ``offset``) for the voltage signal ``u`` sampled every ``dt`` s."""
        x = as_signal("u", u)
        p = self.kernel_params(dt, hold)
        return bw_simulate(p, bw_initial_state(self.h0), x)

    def hysteresis(self, u: Any) -> FloatArray:
        """The hysteresis state h of eq. (8), metres. Rate independent: no ``dt``."""
        x = as_signal("u", u)
        return bw_hysteresis(x, self.h0, self.alpha * self.d1, self.beta, self.gamma)

    def quasi_static(self, u: Any) -> FloatArray:
        """``d1 u - h + offset``, metres: eq. (7) with the dynamics settled."""
        x = as_signal("u", u)
        return self.d1 * x - self.hysteresis(x) + self.offset

    def stepper(self, dt: float, *, hold: Hold = "foh") -> "BoucWenStepper":
        """A streaming simulator on the same kernel as :meth:`simulate`."""
        return BoucWenStepper(self, dt, hold=hold)

    # -- the model protocol (piezohyst.models.base) ---------------------------------------------
    kind: ClassVar[str]
    output_unit: ClassVar[str] = "m"
    dynamic: ClassVar[bool] = True
    is_invertible: ClassVar[bool] = True  # eq. (10) solves for the command at every sample

    def predict(self, u: Any, dt: float | None = None) -> FloatArray:
        """The displacement in µm (the protocol's common unit): ``simulate(u, dt) * 1e6``."""
        return self.simulate(u, need_dt(dt, self.kind)) * 1e6

    def compensator(self, dt: float | None = None, *, u_range: Any = None,
                    max_slew: float | None = None) -> Any:
        """The hysteresis-estimate feedforward of eq. (10) (rate independent: ``dt`` unused)."""
        from .bouc_wen_inverse import BoucWenFeedforward

        return BoucWenFeedforward(self, u_range=u_range, max_slew=max_slew)

    def to_dict(self) -> dict[str, float]:
        """The seven parameters of eqs. (7)-(8), the offset and h0, in SI units (plain data)."""
        return self.parameters()

    @classmethod
    def from_dict(cls, params: dict[str, Any]) -> "BoucWen":
        """Rebuild the model from :meth:`to_dict`'s data; unknown names are refused."""
        names = ("m", "b", "k", "d1", "alpha", "beta", "gamma", "offset", "h0")
        missing = [n for n in names[:6] if n not in params]
        if missing:
            raise KeyError(missing[0])
        unknown = set(params) - set(names)
        if unknown:
            raise ValueError(f"unknown Bouc-Wen parameter(s) {sorted(unknown)}")
        return cls(**{n: params[n] for n in names if n in params})

    def _repr_html_(self) -> str:
        """An HTML summary for Jupyter: kind, units, invertibility, parameters."""
        from .._html import model_html

        return model_html(self)


def solve_ivp_reference(model: BoucWen, u: Any, dt: float, *, method: str = "LSODA", rtol: float = 1e-10) -> tuple[FloatArray, FloatArray]:
    """An independent, slow reference for eqs. (7)-(8): (x, h) in metres at the sample instants.

    One ODE in (x, v, h) with the input linear between samples, integrated by
    ``scipy.integrate.solve_ivp`` (never faster than one step per sample). For checks and
    benchmarks, not for work: :meth:`BoucWen.simulate` computes the same thousands of times faster.
    """
    from scipy.integrate import solve_ivp

    x = as_signal("u", u, min_length=2)
    t = np.arange(x.size) * dt
    slopes = np.diff(x) / dt
    m = model

    def rhs(tt: float, s: FloatArray) -> list[float]:
        _, v, h = s
        i = min(int(tt / dt), x.size - 2)
        du = slopes[i]
        uu = x[i] + du * (tt - t[i])
        dh = m.alpha * m.d1 * du - m.beta * abs(du) * h - m.gamma * du * abs(h)
        return [v, (m.k * (m.d1 * uu - h) - m.b * v - m.k * s[0]) / m.m, dh]

    sol = solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0, 0.0], method=method, t_eval=t, rtol=rtol,
                    atol=[1e-16, 1e-12, 1e-16], max_step=dt)
    if not sol.success:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    return sol.y[0] + m.offset, sol.y[2]


class BoucWenStepper:
    """Streaming Bouc-Wen simulation: ``step(u_k)`` returns x (metres) at sample k."""

    __slots__ = ("model", "dt", "_p", "_st")

    def __init__(self, model: BoucWen, dt: float, *, hold: Hold = "foh"):
        self.model = model
        self.dt = as_scalar("dt", dt, positive=True)
        self._p = model.kernel_params(self.dt, hold)
        self._st = bw_initial_state(model.h0)

    def reset(self) -> None:
        """Back to rest, de-energised."""
        self._st[:] = bw_initial_state(self.model.h0)

    @property
    def h(self) -> float:
        """Current hysteresis state, metres."""
        return float(self._st[1])

    def step(self, u_k: float) -> float:
        """Apply ``u_k`` (V) for one sample; return the displacement (m)."""
        x = float(u_k)
        if not math.isfinite(x):
            raise ValueError(f"u_k must be finite, got {u_k!r}")
        return float(bw_step(self._p, self._st, x))


# ------------------------------------------------------------------------------------------------
# whole-swarm evaluation for identification (paper eq. 9), one compiled call, parallel over particles
from .._numba import njit_parallel, prange  # noqa: E402


@njit_parallel
def bw_swarm_rmse(
    theta: FloatArray, u: FloatArray, y: FloatArray, dt: float, foh: bool, fit_offset: bool,
    scale: float,
) -> FloatArray:  # pragma: no cover - compiled
    """RMSE (eq. 9) of every particle ``theta[i] = (m, b, k, d1, alpha, beta, gamma)``.

    Residuals are multiplied by ``scale`` (1e6: metres to micrometres) before they are summed.
    With ``fit_offset`` the best constant offset is removed analytically (the RMSE is then the
    residual's standard deviation). Invalid or diverging particles get +inf.
    """
    n_p = theta.shape[0]
    n = u.shape[0]
    out = np.empty(n_p)
    for i in prange(n_p):
        m = theta[i, 0]
        b = theta[i, 1]
        k = theta[i, 2]
        d1 = theta[i, 3]
        if not (m > 0.0 and k > 0.0 and b >= 0.0 and d1 > 0.0):
            out[i] = np.inf
            continue
        p = bw_params(m, b, k, d1, theta[i, 4], theta[i, 5], theta[i, 6], 0.0, dt, foh)
        st = bw_initial_state(0.0)
        s1 = 0.0
        s2 = 0.0
        for j in range(n):
            r = (y[j] - bw_step(p, st, u[j])) * scale
            s1 += r
            s2 += r * r
        mean = s1 / n
        var = s2 / n - mean * mean if fit_offset else s2 / n
        val = math.sqrt(max(var, 0.0))
        out[i] = val if math.isfinite(val) else np.inf
    return out
