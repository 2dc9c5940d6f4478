"""Identification of the P-I weights (paper Section III-C): PSO, as the paper, or least squares.

* ``method="pso"``, the paper's way: PSO (eqs. 5-6) minimising the RMSE of eq. (9);
* ``method="lsq"``, beyond the paper: with the thresholds fixed the output is *linear* in the
  weights, so the best weights solve a bounded linear least-squares problem. Writing the
  weights through their partial sums ``S_i = w_1 + ... + w_i`` turns the invertibility
  condition ``S_i > 0`` into simple bounds ``S_i >= margin``; the problem is convex and
  ``scipy.optimize.lsq_linear`` (BVLS) returns its global optimum, every time, in
  milliseconds. The model is invertible by construction.

How far PSO is from the optimum (measured by ``make bench`` and ``piezohyst reproduce``): on
a 20,000-sample 1 Hz record of the virtual rig, PSO over the paper's 20 weights with 40 particles
x 200 iterations ends at an RMSE of 49 nm against 7.7 nm for the least-squares optimum on the same
data (6x); with 100 x 3000 (what ``reproduce`` uses; 0.15 s, the whole swarm loop compiled) it reaches
20 nm against 7.5 nm.
``tests/test_identify.py`` checks that PSO never beats the least-squares optimum.
"""

from __future__ import annotations

import time
from typing import Any, Callable

import numpy as np

from .._numba import njit
from .._validation import FloatArray, as_scalar
from ..models.pi import PrandtlIshlinskii, equal_thresholds
from ..models.play import (GramStats, _gram_stats, default_chunk_rows, largest_loop_threshold, pi_gram,
                           pi_simulate_strict, play_outputs)
from ..pso import pso_minimize, swarm_best_update, swarm_move
from .lsq import bounded_lstsq_gram, bounded_lstsq_gram_many
from .monotone import WEAK_CORRELATION
from .linear import unreversed_thresholds
from .result import FitResult, check_output_scale, unpack_data
from .result import paired_signals as _pair


@njit
def _weights_fitness(wmat: FloatArray, gram: FloatArray, bvec: FloatArray, cval: float, margin: float,
                     penalty: float, out: FloatArray) -> None:  # pragma: no cover - compiled
    """Eq. (9) for every particle (row of ``wmat``) from the normal equations, ``RMSE^2 = w'Gw -
    2 b'w + c``, plus ``penalty`` times the partial sums' shortfall below ``margin`` (the
    invertibility constraint)."""
    n, d = wmat.shape
    for p in range(n):
        quad = 0.0
        lin = 0.0
        short = 0.0
        s = 0.0
        for i in range(d):
            wi = wmat[p, i]
            acc = 0.0
            for j in range(d):
                acc += gram[i, j] * wmat[p, j]
            quad += wi * acc
            lin += wi * bvec[i]
            s += wi
            if s < margin:
                short += margin - s
        mse = quad - 2.0 * lin + cval
        out[p] = np.sqrt(max(mse, 0.0)) + penalty * short


@njit
def _weights_swarm(iterations: int, x: FloatArray, v: FloatArray, pbest: FloatArray, pbest_f: FloatArray,
                   gbest: FloatArray, gbest_f: FloatArray, lb: FloatArray, ub: FloatArray, vmax: FloatArray,
                   inertia: float, c1: float, c2: float, rng: Any, history: FloatArray, gram: FloatArray,
                   bvec: FloatArray, cval: float, margin: float, penalty: float) -> None:  # pragma: no cover
    """Iterations of :meth:`piezohyst.pso.ParticleSwarm.step` with :func:`_weights_fitness`, compiled."""
    n, d = x.shape
    f = np.empty(n)
    for it in range(iterations):
        r = rng.random((2, n, d))
        swarm_move(x, v, pbest, gbest, r, inertia, c1, c2, vmax, lb, ub)
        _weights_fitness(x, gram, bvec, cval, margin, penalty, f)
        swarm_best_update(x, f, pbest, pbest_f, gbest, gbest_f)
        history[it] = gbest_f[0]


class WeightsFitness:
    """The PSO fitness of the P-I weights, eq. (9), for the whole swarm from the normal equations
    (centred when the offset is fitted: the best offset for every particle analytically), with a
    penalty on partial sums below the margin. Compiled, and offers the whole swarm loop compiled
    (``swarm_kernel``, :mod:`piezohyst.pso`)."""

    def __init__(self, gram: FloatArray, bvec: FloatArray, cval: float, margin: float, penalty: float):
        self.gram = np.ascontiguousarray(gram, dtype=np.float64)
        self.bvec = np.ascontiguousarray(bvec, dtype=np.float64)
        self.cval, self.margin, self.penalty = float(cval), float(margin), float(penalty)

    def __call__(self, wmat: FloatArray) -> FloatArray:
        w = np.ascontiguousarray(wmat, dtype=np.float64)
        out = np.empty(w.shape[0])
        _weights_fitness(w, self.gram, self.bvec, self.cval, self.margin, self.penalty, out)
        return out

    def swarm_kernel(self) -> tuple[Callable[..., Any], tuple[Any, ...]]:
        return _weights_swarm, (self.gram, self.bvec, self.cval, self.margin, self.penalty)


def _partial_sum_map(nr: int, fit_offset: bool) -> FloatArray:
    """``M`` with ``[Z, 1] M = [z_1 - z_2, ..., z_{n-1} - z_n, z_n, 1]``: the columns of the partial
    sums ``S_i = w_1 + ... + w_i`` (the weights' invertibility becomes the bounds ``S_i >= margin``)."""
    q = nr + (1 if fit_offset else 0)
    m = np.eye(q)
    for i in range(nr - 1):
        m[i + 1, i] = -1.0
    return m


def _lsq_from_gram(stats: Any, i: int, nr: int, margin: float, fit_offset: bool) -> FloatArray:
    """Partial sums (and offset) of the bounded least-squares P-I fit from streamed normal equations."""
    ata, aty, _, _ = stats.normal_equations(i, offset=fit_offset)
    m = _partial_sum_map(nr, fit_offset)
    lb = np.full(m.shape[1], -np.inf)
    lb[:nr] = margin
    return bounded_lstsq_gram(m.T @ ata @ m, m.T @ aty, lb, np.full(m.shape[1], np.inf))


def _lsq_from_gram_many(stats: Any, nr: int, margin: float, fit_offset: bool) -> FloatArray:
    """:func:`_lsq_from_gram` for every delay of ``stats`` (rows), as one stack of problems."""
    ata, aty, _, _ = stats.normal_equations_all(offset=fit_offset)
    m = _partial_sum_map(nr, fit_offset)
    lb = np.full(m.shape[1], -np.inf)
    lb[:nr] = margin
    return bounded_lstsq_gram_many(m.T @ ata @ m, aty @ m, lb, np.full(m.shape[1], np.inf))


def _coefficients_many(x: FloatArray, nr: int) -> FloatArray:
    """Weights (and offset) from partial sums (and offset), a row per problem."""
    out = np.array(x, dtype=np.float64, copy=True)
    out[:, :nr] = np.diff(x[:, :nr], axis=1, prepend=0.0)
    return out


def _split_gram(us: FloatArray, ys: FloatArray, r: FloatArray, delays: Any, n_fit: int) -> tuple[Any, Any]:
    """Streamed normal equations, for every delay ``d``, of the rows ``u[k]`` paired with
    ``y[k + d]`` whose output lies before ``n_fit`` (the fitting part: ``k < n_fit - d``) and
    of the rest (held out: ``y[n_fit:]``), in one pass over the record.

    The part's pass stops with the operators' states at ``K = n_fit - max(delays)``; the
    held-out pass continues from there over ``u[K:]``, so each delay's first ``max(delays) - d``
    rows of it belong to the part and are taken off again (a few rows, outputs recomputed).
    """
    dmax = int(delays.max())
    cut = n_fit - dmax
    part, at_cut = _gram_stats(us[:n_fit], r, ys[:n_fit], delays, np.zeros(r.size), default_chunk_rows(r.size))
    rest, _ = _gram_stats(us[cut:], r, ys[cut:], delays, at_cut.copy(), default_chunk_rows(r.size))
    overlap = play_outputs(us[cut:n_fit], r, at_cut.copy())  # the rows k = cut .. n_fit - 1
    gram, zty, zsum = rest.gram.copy(), rest.zty.copy(), rest.zsum.copy()
    ysum, yty = rest.ysum.copy(), rest.yty.copy()
    for i, d in enumerate(delays):
        e, ye = overlap[: dmax - d], ys[cut + d: n_fit]
        gram[i] -= e.T @ e
        zty[i] -= e.T @ ye
        zsum[i] -= e.sum(axis=0)
        ysum[i] -= ye.sum()
        yty[i] -= ye @ ye
    held = GramStats(delays=delays, n_samples=np.full(delays.size, us.size - n_fit), gram=gram, zty=zty,
                     zsum=zsum, ysum=ysum, yty=yty)
    return part, held


def _sum_gram(a: Any, b: Any) -> Any:
    """The normal equations of two disjoint sets of rows together (they add)."""
    return GramStats(delays=a.delays, n_samples=a.n_samples + b.n_samples, gram=a.gram + b.gram,
                     zty=a.zty + b.zty, zsum=a.zsum + b.zsum, ysum=a.ysum + b.ysum, yty=a.yty + b.yty)


def pi_regressors(u: FloatArray, thresholds: FloatArray) -> FloatArray:
    """The play-operator outputs from the de-energised state: the columns of the linear P-I fit."""
    return play_outputs(u, thresholds, np.zeros(thresholds.size))



def fit_pi(
    u: Any, y: Any = None, n: int = 20, method: str = "lsq", *,
    thresholds: Any = None, u_max: float | None = None, fit_offset: bool = True,
    delay: int | str = 0, max_auto_delay: int = 10, margin: float | None = None, seed: Any = None, n_particles: int = 40, max_iter: int = 200,
    weight_bounds: tuple[float, float] | None = None, progress: bool = False,
    callback: Callable[..., Any] | None = None,
) -> FitResult:
    """Identify P-I weights from an input ``u`` and a measured output ``y`` (paper Sec. III-C).

    Parameters
    ----------
    u, y : array_like, or a Dataset as ``u``
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
        ``y[k + delay]``. ``"auto"`` tries 0..``max_auto_delay``: each delay is fitted (least
        squares) on the first 70 % of the record, the one that predicts the last 30 % best is
        kept (a delay chosen on the fitting data itself absorbs dynamics and predicts new data
        worse), and the fit is redone on the whole record with it. The normal equations of every
        delay come from one streamed pass and their small least-squares problems are solved as one
        stack, so this costs at most about two fits.
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
    u, y, _ = unpack_data(u, y)
    if method not in ("lsq", "pso"):
        raise ValueError(f"method must be 'lsq' or 'pso', got {method!r}")
    auto = isinstance(delay, str)
    if auto and delay != "auto":
        raise ValueError(f"delay must be a number of samples or 'auto', got {delay!r}")
    if auto:
        if isinstance(max_auto_delay, bool) or not isinstance(max_auto_delay, (int, np.integer)) or max_auto_delay < 0:
            raise ValueError(f"max_auto_delay must be an integer >= 0, got {max_auto_delay!r}")
        delays = list(range(0, int(max_auto_delay) + 1))
        us, ys = _pair(u, y, 0)
        if delays[-1] >= us.size // 2:
            raise ValueError(f"max_auto_delay={max_auto_delay} is too long for {us.size} samples")
    else:
        us, ys = _pair(u, y, delay)  # type: ignore[arg-type]
        delays = [0]
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
    if not float(np.ptp(ys)) > 0.0:
        raise ValueError(f"y is constant ({float(ys[0]):.6g}): the output never moves, so no model of how it follows "
                         "the input can be identified")
    check_output_scale(us, ys)
    slope = float(np.ptp(ys) / np.ptp(us))
    corr = float(np.corrcoef(us, ys)[0, 1])
    if not abs(corr) >= WEAK_CORRELATION:
        # (an output of noise fitted "globally optimal" without a word, or was told to be negated,
        # as its correlation came out at +0.002 or -0.002: found by fuzzing)
        raise ValueError(
            f"the output hardly follows the input (correlation {corr:.2f}; input {float(np.min(us)):.4g} to "
            f"{float(np.max(us)):.4g}, output span {float(np.ptp(ys)):.3g}): is y the stage's displacement (the "
            "right column), does the sensor see the stage, does the input span more than its dead band?")
    if corr < 0:
        raise ValueError(
            f"the output falls as the input rises (correlation {corr:.2f}): a P-I model with an "
            "invertible (increasing) loading curve cannot fit it; negate y first"
        )
    if margin is None:
        margin = 1e-3 * slope
    else:
        margin = as_scalar("margin", margin, nonnegative=True)
    if weight_bounds is not None:
        if not (isinstance(weight_bounds, (tuple, list)) and len(weight_bounds) == 2):
            raise TypeError(f"weight_bounds must be a (low, high) pair, got {weight_bounds!r}")
        wlo = as_scalar("weight_bounds[0]", weight_bounds[0])
        whi = as_scalar("weight_bounds[1]", weight_bounds[1])
        if not wlo < whi:
            raise ValueError(f"weight_bounds must have low < high, got {weight_bounds!r}")
        weight_bounds = (wlo, whi)
    info: dict[str, Any] = {"n_operators": nr, "margin": margin}
    if auto:
        # the delay that predicts held-out data best (the last 30 %), from one pass of streamed
        # normal equations for every delay at once, split into the fitting part's and the
        # held-out rows' (the whole record's are their sum)
        part, held = _split_gram(us, ys, r, np.asarray(delays, dtype=np.int64), int(round(0.7 * us.size)))
        whole = _sum_gram(part, held)
        # every delay's bounded least squares at once (a stack of small problems), and its
        # held-out residual x'A'Ax - 2 x'A'y + y'y from the held-out rows' normal equations
        coef = _coefficients_many(_lsq_from_gram_many(part, nr, margin, fit_offset), nr)
        g, b, c, m = held.normal_equations_all(offset=fit_offset)
        res = c - 2 * np.einsum("ki,ki->k", coef, b) + np.einsum("ki,kij,kj->k", coef, g, coef)
        hold = {d: float(np.sqrt(max(float(res[i]), 0.0) / m[i])) for i, d in enumerate(delays)}
        delay = min(hold, key=lambda d: hold[d])
        info["delay_holdout_rmse"] = hold
        stats, i_d = whole, delays.index(delay)
        us, ys = us[: us.size - delay], ys[delay:]
    else:
        stats, i_d = pi_gram(us, r, ys, delays=[0]), 0

    if method == "lsq":
        x = _lsq_from_gram(stats, i_d, nr, margin, fit_offset)
        s = x[:nr]
        w = np.diff(np.concatenate([[0.0], s]))
        offset = float(x[nr]) if fit_offset else 0.0
        nit, nfev, history, message = None, None, None, "bounded least squares (NNLS on the normal equations): global optimum"
        info["active_constraints"] = int(np.sum(s <= margin * (1 + 1e-9)))
    else:
        # eq. (9) for the whole swarm from the Gram matrix: RMSE^2 = w'Gw - 2b'w + c
        gram_z, zty, zsum, ysum, yty, m_rows = (stats.gram[i_d], stats.zty[i_d], stats.zsum[i_d], float(stats.ysum[i_d]),
                                                 float(stats.yty[i_d]), float(stats.n_samples[i_d]))
        if fit_offset:  # centred: the best offset for every particle analytically
            gram = (gram_z - np.outer(zsum, zsum) / m_rows) / m_rows
            bvec = (zty - zsum * ysum / m_rows) / m_rows
            cval = (yty - ysum * ysum / m_rows) / m_rows
        else:
            gram, bvec, cval = gram_z / m_rows, zty / m_rows, yty / m_rows
        fitness = WeightsFitness(gram, bvec, cval, margin, 10.0 * float(np.ptp(us)))
        lo, hi = weight_bounds if weight_bounds is not None else (-2 * abs(slope), 2 * abs(slope))
        res = pso_minimize(fitness, [(lo, hi)] * nr, n_particles=n_particles, max_iter=max_iter,
                           seed=seed, progress=progress, callback=callback,
                           description=f"PSO, P-I weights ({nr})")
        w = res.x
        offset = float((ysum - zsum @ w) / m_rows) if fit_offset else 0.0
        nit, nfev, history, message = int(res.nit), int(res.nfev), res.history, res.message
        info["weight_bounds"] = [float(lo), float(hi)]

    model = PrandtlIshlinskii(r, w, offset=offset)
    # no (N, n) matrix, and the same residual in every process (a fleet's workers, this one)
    resid = ys - pi_simulate_strict(np.ascontiguousarray(us, dtype=np.float64), model.thresholds, model.weights,
                                    np.array(model.initial_state), model.input_offset, model.offset)
    rmse = float(np.sqrt(np.mean(resid**2)))
    notes = []
    loop = 2.0 * largest_loop_threshold(us)
    unreversed = unreversed_thresholds(model.thresholds, us)
    if unreversed.size:
        notes.append(f"{unreversed.size} operator{'s' if unreversed.size > 1 else ''} (threshold "
                     f"{unreversed.min():.4g}{'..' + format(unreversed.max(), '.4g') if unreversed.size > 1 else ''}) "
                     f"{'are' if unreversed.size > 1 else 'is'} never reversed by this record (its largest loop is "
                     f"{loop:.4g} of its {float(np.ptp(us)):.4g} range), yet a cycle over "
                     f"the range reverses {'them' if unreversed.size > 1 else 'it'}: only the way from rest sets "
                     f"{'their weights' if unreversed.size > 1 else 'its weight'}, and such a cycle may be predicted "
                     f"poorly. Identify on a record with a cycle over the whole range, or with fit_model, which "
                     f"spreads the thresholds over the loops a record holds")
    levels = np.unique(us[:4096])  # (a record that moves has more values than operators in its start)
    if levels.size <= nr:
        levels = np.unique(us[: min(us.size, 1_000_000)])
    if levels.size <= nr:
        # (a square wave between 10 and 90 V fitted 20 weights "globally optimal" without a word, and
        # predicted a 0..100 V sinusoid to 6.7 % of span against 0.6 % from a sinusoid: found by fuzzing)
        notes.append(f"the input takes only {levels.size} value{'s' if levels.size > 1 else ''} "
                     f"({', '.join(format(float(v), '.4g') for v in levels[:6])}{', ...' if levels.size > 6 else ''} V), "
                     f"fewer than the {nr} operators: the loop between them is not observed, and the weights that "
                     "shape it are a guess. Identify on a record that moves through the range (a sinusoid, "
                     "commissioning_excitation)")
    return FitResult(model=model, rmse=rmse, method=method, n_samples=int(us.size),
                     time_s=time.perf_counter() - t0, nit=nit, nfev=nfev, history=history,
                     message=message, delay=int(delay), info=info, warnings=notes,
                     input_range=(float(us.min()), float(us.max())),
                     largest_loop=loop)

