"""Identification of P-I and Bouc-Wen models from measured data (paper Sections III-B, III-C).

* :func:`fit_pi` - the P-I weights, thresholds by eq. (4):
  - ``method="pso"``, the paper's way: PSO (eqs. 5-6) minimising the RMSE of eq. (9);
  - ``method="lsq"``, beyond the paper: with the thresholds fixed the output is *linear* in the
    weights, so the best weights solve a bounded linear least-squares problem. Writing the
    weights through their partial sums ``S_i = w_1 + ... + w_i`` turns the invertibility
    condition ``S_i > 0`` into simple bounds ``S_i >= margin``; the problem is convex and
    ``scipy.optimize.lsq_linear`` (BVLS) returns its global optimum, every time, in
    milliseconds. The model is invertible by construction.
* :func:`fit_bouc_wen` - PSO over (m, b, k, d1, alpha, beta, gamma) of eqs. (7)-(8) with the
  fitness of eq. (9), the parameters that span decades searched in log space, the whole swarm
  simulated in one compiled, parallel call; then (``polish=True``) a bounded least-squares
  refinement, reported separately. Each fit says how strongly the data constrain each parameter.

How far PSO is from the optimum (measured by ``make bench`` row 5 and ``piezohyst reproduce``): on
a 20,000-sample 1 Hz record of the virtual rig, PSO over the paper's 20 weights with 40 particles
x 200 iterations ends at an RMSE of 49 nm against 7.7 nm for the least-squares optimum on the same
data (6x); with 100 x 3000 (what ``reproduce`` uses, 0.5 s) it reaches 20 nm against 7.5 nm.
``tests/test_identify.py`` checks that PSO never beats the least-squares optimum.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from ._validation import FloatArray, as_scalar, as_signal
from .models.bouc_wen import BoucWen, bw_swarm_rmse
from .models.pi import PrandtlIshlinskii, equal_thresholds
from .models.play import play_outputs
from .pso import pso_minimize


@dataclass
class FitResult:
    """What an identification produced.

    Attributes
    ----------
    model : PrandtlIshlinskii or BoucWen
        The identified model.
    rmse : float
        RMSE of eq. (9) on the fitting data, in the units of ``y``.
    method : str
        ``"lsq"`` or ``"pso"`` (+ ``"+polish"``).
    time_s : float
        Wall-clock time of the fit.
    nit, nfev : int or None
        The optimiser's iterations and fitness evaluations.
    history : ndarray or None
        PSO's best fitness per iteration.
    delay : int
        Samples by which the output was taken to lag the input.
    sensitivity : dict or None
        Per parameter: relative rise of the RMSE when that parameter alone moves by 10 %
        (for alpha and gamma, which may sit at 0: by 10 % of itself or 1 % of its search range,
        whichever is larger). Below 1 %: barely constrained.
    info : dict
        Anything else worth keeping (PSO RMSE before polishing, bounds, messages).
    """

    model: Any
    rmse: float
    method: str
    n_samples: int
    time_s: float
    nit: int | None = None
    nfev: int | None = None
    history: FloatArray | None = None
    message: str = ""
    delay: int = 0
    sensitivity: dict[str, float] | None = None
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def poorly_constrained(self) -> list[str]:
        """Parameters whose 10 % change moves the RMSE by less than 1 %."""
        if not self.sensitivity:
            return []
        return [k for k, v in self.sensitivity.items() if v < 0.01]

    def summary(self) -> dict[str, Any]:
        """The fit's figures as plain data (JSON-ready)."""
        out: dict[str, Any] = {
            "method": self.method, "rmse": self.rmse, "n_samples": self.n_samples,
            "time_s": self.time_s, "nit": self.nit, "nfev": self.nfev, "delay": self.delay,
            "message": self.message,
        }
        if self.sensitivity is not None:
            out["sensitivity"] = dict(self.sensitivity)
            out["poorly_constrained"] = self.poorly_constrained
        for k, v in self.info.items():
            if isinstance(v, (int, float, str, bool)) or v is None:
                out[k] = v
        return out


def _pair(u: Any, y: Any, delay: int) -> tuple[FloatArray, FloatArray]:
    us = as_signal("u", u, min_length=2)
    ys = as_signal("y", y, min_length=2)
    if us.size != ys.size:
        raise ValueError(f"u and y must have the same length, got {us.size} and {ys.size}")
    if isinstance(delay, bool) or not isinstance(delay, (int, np.integer)) or delay < 0:
        raise ValueError(f"delay must be an integer number of samples >= 0, got {delay!r}")
    if delay:
        if delay >= us.size - 1:
            raise ValueError(f"delay={delay} leaves fewer than 2 samples of {us.size}")
        us, ys = us[: us.size - delay], ys[delay:]
    if np.ptp(us) == 0:
        raise ValueError("u is constant: a constant input cannot identify a hysteresis model")
    return np.ascontiguousarray(us), np.ascontiguousarray(ys)


def bounded_lstsq(a: FloatArray, y: FloatArray, lb: FloatArray, ub: FloatArray) -> FloatArray:
    """``argmin ||a x - y||`` subject to ``lb <= x <= ub``: the global optimum of a convex problem.

    The tall problem is reduced to a square one of the same optimum,
    ``||a x - y||^2 = ||R x - R^-T a'y||^2 + const`` with ``a'a = R'R`` (Cholesky of the Gram
    matrix of the unit-norm columns; a QR factorisation instead when that Gram matrix is too
    ill-conditioned to trust), and the bounded solver (BVLS) works on that square system: tens
    of times faster for long records than BVLS on the tall one.
    """
    import scipy.linalg as sl
    from scipy.optimize import lsq_linear

    norms = np.linalg.norm(a, axis=0)
    norms[norms == 0] = 1.0
    an = a / norms
    gram = an.T @ an
    rmat = None
    try:
        rmat = sl.cholesky(gram, lower=False)
        d = np.abs(np.diag(rmat))
        if d.min() < 1e-7 * d.max():  # cond(gram) beyond ~1e14: precision would be lost
            rmat = None
    except np.linalg.LinAlgError:
        rmat = None
    if rmat is not None:
        rhs = sl.solve_triangular(rmat, an.T @ y, trans="T")
    else:
        q, rmat = np.linalg.qr(an, mode="reduced")
        rhs = q.T @ y
    res = lsq_linear(rmat, rhs, bounds=(lb * norms, ub * norms), method="bvls", tol=1e-12)
    return np.asarray(res.x / norms)


def pi_regressors(u: FloatArray, thresholds: FloatArray) -> FloatArray:
    """The play-operator outputs from the de-energised state: the columns of the linear P-I fit."""
    return play_outputs(u, thresholds, np.zeros(thresholds.size))


def fit_pi(
    u: Any, y: Any, n: int = 20, method: str = "lsq", *,
    thresholds: Any = None, u_max: float | None = None, fit_offset: bool = True,
    delay: int | str = 0, max_auto_delay: int = 10, margin: float | None = None, seed: Any = None, n_particles: int = 40, max_iter: int = 200,
    weight_bounds: tuple[float, float] | None = None, progress: bool = False,
    callback: Callable[..., Any] | None = None,
) -> FitResult:
    """Identify P-I weights from an input ``u`` and a measured output ``y`` (paper Sec. III-C).

    Parameters
    ----------
    u, y : array_like
        Input (V) and output (any unit; ``rmse`` is in it). The model starts de-energised.
    n : int
        Number of play operators, thresholds by eq. (4) over ``u_max`` (default ``max|u|``).
    method : {"lsq", "pso"}
        ``"lsq"``: constrained linear least squares, the global optimum; ``"pso"``: the paper's
        particle swarm search over the weights.
    thresholds : array_like, optional
        Your own thresholds (``0 = r_1 < ... < r_n``) instead of eq. (4).
    fit_offset : bool
        Fit a constant output offset too (sensors rarely read 0 at 0 V).
    delay : int or "auto"
        Samples by which ``y`` lags ``u`` (a sensor's delay); the fit pairs ``u[k]`` with
        ``y[k + delay]``. ``"auto"`` tries 0..``max_auto_delay`` and keeps the one with the
        lowest RMSE on the fitting data itself.
    margin : float, optional
        Smallest allowed partial sum of the weights (default 1e-3 of the data's mean slope):
        keeps the model invertible with a bounded inverse slope.
    seed, n_particles, max_iter, progress, callback
        PSO settings (``method="pso"``).
    weight_bounds : (low, high), optional
        PSO search box for each weight (default +-2x the data's mean slope).

    Returns
    -------
    FitResult
        ``fit.model`` is a :class:`PrandtlIshlinskii`; ``fit.rmse`` is eq. (9) in y's unit.

    Examples
    --------
    >>> import numpy as np, piezohyst as ph
    >>> true = ph.PrandtlIshlinskii(ph.equal_thresholds(5, 10.0), [0.6, 0.2, 0.1, -0.05, 0.1])
    >>> u = ph.sinusoid(1.0, 3, 0.0, 10.0, 1e-3) * np.linspace(0.4, 1.0, 3000)
    >>> fit = ph.fit_pi(u, true.simulate(u), n=5, u_max=10.0, fit_offset=False)
    >>> bool(np.allclose(fit.model.weights, true.weights, atol=1e-6))
    True
    """
    t0 = time.perf_counter()
    if method not in ("lsq", "pso"):
        raise ValueError(f"method must be 'lsq' or 'pso', got {method!r}")
    if isinstance(delay, str):
        if delay != "auto":
            raise ValueError(f"delay must be a number of samples or 'auto', got {delay!r}")
        # the lag that fits the *fitting* data best (no peeking at validation data)
        kw = dict(thresholds=thresholds, u_max=u_max, fit_offset=fit_offset, margin=margin, seed=seed,
                  n_particles=n_particles, max_iter=max_iter, weight_bounds=weight_bounds)
        trials = [fit_pi(u, y, n, method, delay=d, **kw) for d in range(0, max_auto_delay + 1)]  # type: ignore[arg-type]
        best = min(trials, key=lambda f: f.rmse)
        best.info["delay_rmse"] = {f.delay: f.rmse for f in trials}
        best.time_s = time.perf_counter() - t0
        return best
    us, ys = _pair(u, y, delay)
    if thresholds is None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"n must be a positive integer, got {n!r}")
        um = as_scalar("u_max", u_max, positive=True) if u_max is not None else float(np.abs(us).max())
        r = equal_thresholds(int(n), um)
    else:
        r = PrandtlIshlinskii(thresholds, np.ones(len(np.atleast_1d(thresholds)))).thresholds
    nr = r.size
    if us.size < nr + 2:
        raise ValueError(f"{us.size} samples are too few to fit {nr} weights")
    slope = float(np.ptp(ys) / np.ptp(us))
    if np.corrcoef(us, ys)[0, 1] < 0:
        raise ValueError(
            "the output falls as the input rises (negative correlation): a P-I model with an "
            "invertible (increasing) loading curve cannot fit it; negate y first"
        )
    if margin is None:
        margin = 1e-3 * slope
    z = pi_regressors(us, r)
    info: dict[str, Any] = {"n_operators": nr, "margin": margin}

    if method == "lsq":
        # y = Z w + c with w = D s, s the partial sums: column i of Z D is z_i - z_{i+1}
        zd = z.copy()
        zd[:, :-1] -= z[:, 1:]
        cols = [zd] + ([np.ones((us.size, 1))] if fit_offset else [])
        a = np.hstack(cols)
        lb = np.full(a.shape[1], -np.inf)
        lb[:nr] = margin
        sol = bounded_lstsq(a, ys, lb, np.full(a.shape[1], np.inf))
        s = sol[:nr]
        w = np.diff(np.concatenate([[0.0], s]))
        offset = float(sol[nr]) if fit_offset else 0.0
        nit, nfev, history, message = None, None, None, "bounded least squares (BVLS after QR): global optimum"
        info["active_constraints"] = int(np.sum(s <= margin * (1 + 1e-9)))
    else:
        # eq. (9) for the whole swarm from the Gram matrix: RMSE^2 = w'Gw - 2b'w + c
        if fit_offset:
            zc = z - z.mean(axis=0)
            yc = ys - ys.mean()
        else:
            zc, yc = z, ys
        gram = zc.T @ zc / us.size
        bvec = zc.T @ yc / us.size
        cval = float(yc @ yc / us.size)
        span_u = float(np.ptp(us))

        def fitness(wmat: FloatArray) -> FloatArray:
            mse = np.einsum("pi,ij,pj->p", wmat, gram, wmat) - 2 * wmat @ bvec + cval
            rmse = np.sqrt(np.maximum(mse, 0.0))
            # inequality constraints (invertibility): penalise partial sums below the margin
            short = np.maximum(margin - np.cumsum(wmat, axis=1), 0.0).sum(axis=1)
            return rmse + 10.0 * span_u * short

        lo, hi = weight_bounds if weight_bounds is not None else (-2 * abs(slope), 2 * abs(slope))
        res = pso_minimize(fitness, [(lo, hi)] * nr, n_particles=n_particles, max_iter=max_iter,
                           seed=seed, progress=progress, callback=callback,
                           description=f"PSO, P-I weights ({nr})")
        w = res.x
        offset = float(ys.mean() - z.mean(axis=0) @ w) if fit_offset else 0.0
        nit, nfev, history, message = int(res.nit), int(res.nfev), res.history, res.message
        info["weight_bounds"] = [float(lo), float(hi)]

    model = PrandtlIshlinskii(r, w, offset=offset)
    resid = ys - (z @ w + offset)
    rmse = float(np.sqrt(np.mean(resid**2)))
    return FitResult(model=model, rmse=rmse, method=method, n_samples=int(us.size),
                     time_s=time.perf_counter() - t0, nit=nit, nfev=nfev, history=history,
                     message=message, delay=int(delay), info=info)


# ------------------------------------------------------------------------------------------------
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
    u: Any, y: Any, dt: float, bounds: dict[str, tuple[float, float]] | None = None,
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
        raise RuntimeError("Bouc-Wen identification failed: every particle's simulation diverged; "
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
    offset = float(np.mean(y_m - model0.simulate(us, dt, hold=hold))) if fit_offset else 0.0  # type: ignore[arg-type]
    model = BoucWen(**params, offset=offset)
    sens = _bw_sensitivity(theta, rmse, nat_lo, nat_hi, us, y_m, dt, foh, fit_offset)
    info["polished_rmse"] = rmse if polish else None
    return FitResult(model=model, rmse=rmse, method=method, n_samples=int(us.size),
                     time_s=time.perf_counter() - t0, nit=int(res.nit), nfev=nfev,
                     history=res.history, message=res.message, delay=int(delay),
                     sensitivity=sens, info=info)


def _polish_bouc_wen(x0: FloatArray, lo: FloatArray, hi: FloatArray, u: FloatArray, y_m: FloatArray,
                     dt: float, foh: bool, fit_offset: bool) -> tuple[FloatArray, int]:
    """Bounded least squares from PSO's best, on the residual vector (in search space)."""
    from scipy.optimize import least_squares

    from .models.bouc_wen import bw_initial_state, bw_params, bw_simulate

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


def simulate_fit(fit: FitResult, u: Any, dt: float | None = None) -> FloatArray:
    """The fitted model's output for ``u`` in the units the fit was made in (µm for Bouc-Wen)."""
    if isinstance(fit.model, PrandtlIshlinskii):
        return fit.model.simulate(u)
    if dt is None:
        raise ValueError("dt is needed to simulate a Bouc-Wen model")
    return fit.model.simulate(u, dt) * 1e6


__all__: Sequence[str] = ("FitResult", "fit_pi", "fit_bouc_wen", "default_bouc_wen_bounds", "pi_regressors")


# ------------------------------------------------------------------------------------------------
def _lsq_pi_with_lags(v: FloatArray, y: FloatArray, r: FloatArray, lags: FloatArray, margin: float,
                      fit_offset: bool) -> tuple[FloatArray, FloatArray, float, float]:
    """Bounded least squares for [partial sums of w | lag weights | offset]; returns w, c, offset, rmse."""
    z = pi_regressors(v, r)
    nr = r.size
    zd = z.copy()
    zd[:, :-1] -= z[:, 1:]
    cols = [zd, lags] + ([np.ones((v.size, 1))] if fit_offset else [])
    a = np.hstack(cols)
    lb = np.full(a.shape[1], -np.inf)
    lb[:nr] = margin
    sol = bounded_lstsq(a, y, lb, np.full(a.shape[1], np.inf))
    w = np.diff(np.concatenate([[0.0], sol[:nr]]))
    c = sol[nr:nr + lags.shape[1]]
    offset = float(sol[-1]) if fit_offset else 0.0
    rmse = float(np.sqrt(np.mean((a @ sol - y) ** 2)))
    return w, c, offset, rmse


def fit_rate_pi(
    u: Any, y: Any, dt: float, *, n: int = 20, u_max: float | None = None, taus: Sequence[float] | None = None,
    input_taus: Sequence[float] | None = None, delay: int | str = "auto", max_auto_delay: int = 3,
    fit_offset: bool = True, margin: float | None = None,
) -> FitResult:
    """Identify a :class:`~piezohyst.models.rate_pi.RateDependentPI` (beyond the paper).

    The P-I weights (thresholds by eq. 4, invertibility as bounds) and the output-lag weights are
    one bounded linear least-squares problem, solved to its global optimum for each candidate input
    lag and sensor delay; the pair with the lowest RMSE on the fitting data is kept.

    Parameters
    ----------
    u, y : array_like
        Input (V) and output (µm) of an identification run that starts at rest.
    dt : float
        Sample period, s.
    n : int
        Play operators (eq. 4 thresholds over ``u_max``, default ``max|u|``).
    taus, input_taus : sequence of float, optional
        Output-lag and candidate input-lag time constants (s); defaults in
        :mod:`piezohyst.models.rate_pi`.
    delay : int or "auto"
        Samples by which y lags u; "auto" tries 0..``max_auto_delay``.
    """
    from .models.rate_pi import DEFAULT_INPUT_TAUS, DEFAULT_TAUS, RateDependentPI, input_lag, lag_outputs

    t0 = time.perf_counter()
    dt = as_scalar("dt", dt, positive=True)
    taus_arr = np.asarray(DEFAULT_TAUS if taus is None else taus, dtype=np.float64)
    itaus = list(DEFAULT_INPUT_TAUS if input_taus is None else input_taus)
    us0, ys0 = _pair(u, y, 0)
    if np.corrcoef(us0, ys0)[0, 1] < 0:
        raise ValueError("the output falls as the input rises (negative correlation): negate y first")
    um = as_scalar("u_max", u_max, positive=True) if u_max is not None else float(np.abs(us0).max())
    r = equal_thresholds(int(n), um)
    slope = float(np.ptp(ys0) / np.ptp(us0))
    margin = 1e-3 * slope if margin is None else margin
    a_lag = np.exp(-dt / taus_arr)

    def attempt(d: int, itau: float) -> tuple[float, Any]:
        us, ys = _pair(u, y, d)
        b = float(np.exp(-dt / itau)) if itau > 0 else 0.0
        v = input_lag(us, b)
        w, c, off, rmse = _lsq_pi_with_lags(v, ys, r, lag_outputs(v, a_lag), margin, fit_offset)
        return rmse, (d, itau, w, c, off)

    delays = range(max_auto_delay + 1) if delay == "auto" else [delay]
    # delay and input lag trade against each other: search them jointly
    results = [attempt(int(d), it) for d in delays for it in itaus]  # type: ignore[call-overload]
    rmse, (d, itau, w, c, off) = min(results, key=lambda t: t[0])
    model = RateDependentPI(PrandtlIshlinskii(r, w, offset=off), taus_arr, c, dt, input_tau=itau)
    info = {"input_tau_s": itau, "margin": margin,
            "grid_rmse": {f"delay={t[1][0]},input_tau={t[1][1]:g}": t[0] for t in results}}
    return FitResult(model=model, rmse=rmse, method="lsq (rate-dependent P-I)", n_samples=int(us0.size - d),
                     time_s=time.perf_counter() - t0, delay=int(d), info=info)
