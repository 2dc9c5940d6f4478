"""Identification of the Bouc-Wen model, eqs. (7)-(8), with PSO and fitness eq. (9) (paper Sec. III-B).

PSO over (m, b, k, d1, alpha, beta, gamma), the parameters that span decades searched in log
space, the whole swarm simulated in one compiled, parallel call; then (``polish=True``) a bounded
least-squares refinement, reported separately. Each fit says how strongly the data constrain
each parameter.
"""

from __future__ import annotations

import math
import time
from typing import Any, Callable

import numpy as np

from .._validation import FitError, FloatArray, as_scalar, as_signal
from ..models.bouc_wen import BoucWen, bw_swarm_rmse
from ..models.play import largest_loop_threshold
from ..pso import pso_minimize
from .result import FitResult, paired_signals as _pair, unpack_data

BW_NAMES = ("m", "b", "k", "d1", "alpha", "beta", "gamma")
_BW_LOG = (True, True, True, True, False, True, False)


def default_bouc_wen_bounds(u: Any, y_um: Any) -> dict[str, tuple[float, float]]:
    """The default search box of :func:`fit_bouc_wen`, from the data's scales.

    * m in [1e-3, 10] kg, b in [0.1, 1e5] N s/m, k in [1e5, 1e10] N/m: wide, because a
      low-frequency record barely constrains them (the sensitivity report says so);
    * d1 within a factor 10 of the data's mean slope ``ptp(y)/ptp(u)`` (m/V);
    * alpha in [0, 2];
    * beta in [0.01, 100] / ptp(u) (1/V): saturation of h over 1 % .. 100x of the input range;
    * gamma in [-10, 10] / ptp(u) (1/V): the paper keeps gamma >= 0; negative values are allowed
      so loops skewed either way can be fitted.
    m, b, k, d1 and beta are searched in log space.
    """
    us = as_signal("u", u, min_length=2)
    ys = as_signal("y", y_um, min_length=2)
    span_u = float(np.ptp(us))
    if span_u == 0:
        raise ValueError("u is constant: a constant input cannot identify a hysteresis model")
    slope = float(np.ptp(ys)) * 1e-6 / span_u
    if slope <= 0:
        raise ValueError("y is constant: nothing to identify")
    return {
        "m": (1e-3, 10.0), "b": (0.1, 1e5), "k": (1e5, 1e10),
        "d1": (slope / 10, slope * 10), "alpha": (0.0, 2.0),
        "beta": (0.01 / span_u, 100.0 / span_u), "gamma": (-10.0 / span_u, 10.0 / span_u),
    }


def _to_search(theta: FloatArray) -> FloatArray:
    out = np.array(theta, dtype=np.float64, copy=True)
    for j, lg in enumerate(_BW_LOG):
        if lg:
            out[..., j] = np.log10(out[..., j])
    return out


def _from_search(x: FloatArray) -> FloatArray:
    out = np.array(x, dtype=np.float64, copy=True)
    for j, lg in enumerate(_BW_LOG):
        if lg:
            out[..., j] = 10.0 ** out[..., j]
    return out


def fit_bouc_wen(
    u: Any, y: Any = None, dt: float | None = None, bounds: dict[str, tuple[float, float]] | None = None,
    seed: Any = 0, *, n_particles: int = 40, max_iter: int = 200, fit_offset: bool = True,
    delay: int = 0, polish: bool = True, stall_iter: int | None = None, progress: bool = False,
    callback: Callable[..., Any] | None = None, hold: str = "foh",
) -> FitResult:
    """Identify the Bouc-Wen model of eqs. (7)-(8) with PSO, fitness eq. (9) (paper Sec. III-B).

    Parameters
    ----------
    u : array_like
        Input voltage, V.
    y : array_like
        Measured displacement, **µm**. ``fit.rmse`` is in µm; the model keeps SI units.
    dt : float
        Sample period, s.
    bounds : dict, optional
        ``{name: (low, high)}`` for any of m, b, k, d1, alpha, beta, gamma (SI units);
        the rest come from :func:`default_bouc_wen_bounds`.
    seed : int or Generator
        PSO's randomness: the same seed gives the same model.
    n_particles, max_iter, stall_iter : int
        PSO budget (the paper's steps 1-6; defaults 40 x 200).
    fit_offset : bool
        Remove the best constant offset (a sensor's zero) inside the fitness.
    delay : int
        Samples by which y lags u.
    polish : bool
        Refine PSO's best with bounded least squares (``scipy.optimize.least_squares``);
        ``fit.info["pso_rmse"]`` keeps PSO's own figure.
    hold : {"foh", "zoh"}
        How the simulator interpolates the input between samples.

    Returns
    -------
    FitResult
        With ``sensitivity`` per parameter and ``poorly_constrained``.
    """
    t0 = time.perf_counter()
    u, y, dt = unpack_data(u, y, dt, need_dt=True)
    dt = as_scalar("dt", dt, positive=True)
    if hold not in ("foh", "zoh"):
        raise ValueError(f"hold must be 'foh' or 'zoh', got {hold!r}")
    us, ys_um = _pair(u, y, delay)
    box = default_bouc_wen_bounds(us, ys_um)
    if bounds is not None:
        unknown = set(bounds) - set(BW_NAMES)
        if unknown:
            raise ValueError(f"unknown Bouc-Wen parameter(s) in bounds: {sorted(unknown)}; "
                             f"the parameters are {list(BW_NAMES)}")
        for name, (lo, hi) in bounds.items():
            if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                raise ValueError(f"bounds[{name!r}] must be finite with low < high, got ({lo}, {hi})")
            if _BW_LOG[BW_NAMES.index(name)] and lo <= 0:
                raise ValueError(f"bounds[{name!r}] must be positive (searched in log space), got ({lo}, {hi})")
            box[name] = (float(lo), float(hi))
    nat_lo = np.array([box[n][0] for n in BW_NAMES])
    nat_hi = np.array([box[n][1] for n in BW_NAMES])
    s_lo, s_hi = _to_search(nat_lo), _to_search(nat_hi)
    y_m = ys_um * 1e-6
    foh = hold == "foh"

    def swarm_fitness(xs: FloatArray) -> FloatArray:
        theta = np.ascontiguousarray(_from_search(xs))
        return bw_swarm_rmse(theta, us, y_m, dt, foh, fit_offset, 1e6)

    res = pso_minimize(swarm_fitness, list(zip(s_lo, s_hi)), n_particles=n_particles,
                       max_iter=max_iter, seed=seed, stall_iter=stall_iter, progress=progress,
                       callback=callback, description="PSO, Bouc-Wen (7 parameters)")
    if not res.success:
        raise FitError("Bouc-Wen identification failed: every particle's simulation diverged; "
                           "check the data's units (u in V, y in um) and the bounds")
    best = res.x
    info: dict[str, Any] = {"pso_rmse": float(res.fun), "pso_nit": int(res.nit),
                            "bounds": {n: list(box[n]) for n in BW_NAMES}}
    nfev = int(res.nfev)
    method = "pso"
    if polish:
        best, extra = _polish_bouc_wen(best, s_lo, s_hi, us, y_m, dt, foh, fit_offset)
        nfev += extra
        method = "pso+polish"
    theta = _from_search(best)
    rmse = float(swarm_fitness(best[None, :])[0])
    # the offset that eq. (9) was minimised over
    params = dict(zip(BW_NAMES, (float(v) for v in theta)))
    model0 = BoucWen(**params)
    offset = float(np.mean(y_m - model0.simulate(us, dt, hold=hold))) if fit_offset else 0.0  # type: ignore[arg-type, operator]
    model = BoucWen(**params, offset=offset)
    sens = _bw_sensitivity(theta, rmse, nat_lo, nat_hi, us, y_m, dt, foh, fit_offset)
    info["polished_rmse"] = rmse if polish else None
    said = []
    if not model.is_invertible:
        # (returned without a word, then refused by model.compensator(): found by a helper)
        said.append(f"the identified Bouc-Wen loop is not invertible (alpha max(1, 2 beta / (beta + gamma)) = "
                    f"{model.steepest_hysteresis_slope:.4g} >= 1: its output falls along part of a branch after a "
                    f"reversal), so eq. (10) has no unique command: its compensator is refused; identify on a "
                    f"record with full-range loops, or use another model kind (fit_model)")
    return FitResult(model=model, rmse=rmse, method=method, n_samples=int(us.size),
                     time_s=time.perf_counter() - t0, nit=int(res.nit), nfev=nfev,
                     history=res.history, message=res.message, delay=int(delay),
                     sensitivity=sens, info=info, input_range=(float(us.min()), float(us.max())),
                     largest_loop=2.0 * largest_loop_threshold(us), warnings=said)


def _polish_bouc_wen(x0: FloatArray, lo: FloatArray, hi: FloatArray, u: FloatArray, y_m: FloatArray,
                     dt: float, foh: bool, fit_offset: bool) -> tuple[FloatArray, int]:
    """Bounded least squares from PSO's best, on the residual vector (in search space)."""
    from scipy.optimize import least_squares

    from ..models.bouc_wen import bw_initial_state, bw_params, bw_simulate

    def residuals(x: FloatArray) -> FloatArray:
        th = _from_search(x)
        p = bw_params(th[0], th[1], th[2], th[3], th[4], th[5], th[6], 0.0, dt, foh)
        r = (y_m - bw_simulate(p, bw_initial_state(0.0), u)) * 1e6
        if fit_offset:
            r = r - r.mean()
        if not np.all(np.isfinite(r)):
            return np.full(r.size, 1e6)
        return r

    x_start = np.clip(x0, lo + 1e-12 * (hi - lo), hi - 1e-12 * (hi - lo))
    sol = least_squares(residuals, x_start, bounds=(lo, hi), x_scale="jac", method="trf",
                        diff_step=1e-7, max_nfev=200)
    before = float(np.sqrt(np.mean(residuals(x0) ** 2)))
    after = float(np.sqrt(np.mean(sol.fun**2)))
    return (sol.x if after < before else x0), int(sol.nfev) * (x0.size + 1)


def _bw_sensitivity(theta: FloatArray, rmse: float, lo: FloatArray, hi: FloatArray, u: FloatArray,
                    y_m: FloatArray, dt: float, foh: bool, fit_offset: bool) -> dict[str, float]:
    """Relative RMSE rise for a 10 % change of each parameter alone (both directions, the larger)."""
    trials = []
    for j in range(theta.size):
        for sign in (+1, -1):
            t = theta.copy()
            if _BW_LOG[j]:
                t[j] = theta[j] * (1.1 if sign > 0 else 1 / 1.1)
            else:  # searched linearly, may sit at or near 0: 10 % of itself or 1 % of its range
                t[j] = theta[j] + sign * max(0.1 * abs(theta[j]), 0.01 * (hi[j] - lo[j]))
            trials.append(t)
    vals = bw_swarm_rmse(np.ascontiguousarray(np.array(trials)), u, y_m, dt, foh, fit_offset, 1e6)
    out = {}
    base = max(rmse, 1e-300)
    for j, name in enumerate(BW_NAMES):
        worst = max(vals[2 * j], vals[2 * j + 1])
        out[name] = float((worst - rmse) / base) if math.isfinite(worst) else float("inf")
    return out

