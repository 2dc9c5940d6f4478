"""Bounded linear least squares: the global optimum of the convex problems every linear fit is.

``min ||A x - y||^2`` subject to ``x_j >= lb_j`` (``lb_j`` finite or ``-inf``), optionally plus a
Tikhonov term ``sum_j ridge_j x_j^2``. The tall problem is reduced to its normal equations
``G = A'A``, ``b = A'y`` (columns scaled to unit norm), which is all that depends on the record's
length: a fit of 10^7 samples can accumulate them in chunks (:func:`bounded_lstsq_gram`). The
free variables (``lb = -inf``, e.g. an offset) are eliminated exactly through the Schur
complement, the bounded ones shifted to ``x >= 0``, and the remaining non-negative least-squares
problem is solved on the Cholesky factor ``R`` of that complement (``||R x - R^-T b'||``) by
Lawson and Hanson's active-set NNLS (``scipy.optimize.nnls``): its global optimum, with work
depending on the number of parameters only. Problems with finite upper bounds go to BVLS
(``scipy.optimize.lsq_linear``) on the same square system.
"""

from __future__ import annotations

import numpy as np

from .._validation import FloatArray

#: Relative jitter added to the diagonal before a Cholesky factorisation, so a Gram matrix that
#: is singular in floating point (collinear regressors) still factors; it changes the optimum's
#: residual by far less than the data's own rounding.
_JITTER = 1e-12


def bounded_lstsq(a: FloatArray, y: FloatArray, lb: FloatArray, ub: FloatArray, *,
                  ridge: FloatArray | None = None) -> FloatArray:
    """``argmin ||a x - y||^2 (+ sum ridge_j x_j^2)`` subject to ``lb <= x <= ub`` (module docstring)."""
    a = np.asarray(a, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    return bounded_lstsq_gram(a.T @ a, a.T @ y, lb, ub, ridge=ridge)


def bounded_lstsq_gram(gram: FloatArray, atb: FloatArray, lb: FloatArray, ub: FloatArray, *,
                       ridge: FloatArray | None = None) -> FloatArray:
    """The same from the normal equations ``gram = A'A`` and ``atb = A'y`` (module docstring)."""
    from scipy.optimize import lsq_linear

    g = np.array(gram, dtype=np.float64)
    b = np.array(atb, dtype=np.float64)
    p = b.size
    lb = np.broadcast_to(np.asarray(lb, dtype=np.float64), (p,)).copy()
    ub = np.broadcast_to(np.asarray(ub, dtype=np.float64), (p,)).copy()
    if ridge is not None:
        g[np.diag_indices(p)] += np.asarray(ridge, dtype=np.float64)
    # scale the columns to unit norm (the solvers' tolerances are then relative)
    norms = np.sqrt(np.maximum(np.diag(g), 0.0))
    norms[norms == 0] = 1.0
    g = g / np.outer(norms, norms)
    b = b / norms
    lbs, ubs = lb * norms, ub * norms
    # a convex problem: when the unconstrained optimum lies within the bounds it is the bounded
    # one, found with one factorisation instead of the active-set iterations
    rg = _cholesky(g)
    x0 = np.linalg.solve(rg, np.linalg.solve(rg.T, b))
    if np.all(np.isfinite(x0)) and np.all(x0 >= lbs) and np.all(x0 <= ubs):
        return np.asarray(x0 / norms)
    if np.any(np.isfinite(ubs)):
        rhs = np.linalg.solve(rg.T, b)
        res = lsq_linear(rg, rhs, bounds=(lbs, ubs), method="bvls", tol=1e-12)
        return np.asarray(res.x / norms)
    try:
        return _lower_bounded(g, b, lbs, norms)
    except np.linalg.LinAlgError:
        # eliminating the free variables lost the Schur complement's definiteness to rounding
        # (a nearly collinear design: its diagonal came out at -2x the jitter's reach, found on
        # a record that starts mid-cycle); the full factor solves the same problem directly
        rhs = np.linalg.solve(rg.T, b)
        res = lsq_linear(rg, rhs, bounds=(lbs, ubs), method="bvls", tol=1e-12)
        return np.asarray(res.x / norms)


def _lower_bounded(g: FloatArray, b: FloatArray, lbs: FloatArray, norms: FloatArray) -> FloatArray:
    """The scaled problem with lower bounds only (or none) by NNLS on the bounded variables,
    the free ones eliminated (Schur complement)."""
    from scipy.optimize import nnls

    p = b.size
    free = ~np.isfinite(lbs)
    bnd = ~free
    shift = np.where(bnd, lbs, 0.0)
    b = b - g @ shift  # x = shift + x', x' >= 0 on the bounded variables
    x = np.zeros(p)
    if bnd.any():
        gbb = g[np.ix_(bnd, bnd)]
        bb = b[bnd]
        if free.any():  # eliminate the free variables: Schur complement of G_ff
            gff = g[np.ix_(free, free)]
            gfb = g[np.ix_(free, bnd)]
            rf = _cholesky(gff)
            sol_g = np.linalg.solve(rf, np.linalg.solve(rf.T, gfb))
            sol_b = np.linalg.solve(rf, np.linalg.solve(rf.T, b[free]))
            gbb = gbb - gfb.T @ sol_g
            bb = bb - gfb.T @ sol_b
        r = _cholesky(0.5 * (gbb + gbb.T))
        rhs = np.linalg.solve(r.T, bb)
        xb, _ = nnls(r, rhs, maxiter=50 * r.shape[1])
        x[bnd] = xb
    if free.any():
        gff = g[np.ix_(free, free)]
        rf = _cholesky(gff)
        rest = b[free] - g[np.ix_(free, bnd)] @ x[bnd]
        x[free] = np.linalg.solve(rf, np.linalg.solve(rf.T, rest))
    return np.asarray((x + shift) / norms)



def bounded_lstsq_gram_many(grams: FloatArray, atbs: FloatArray, lb: FloatArray, ub: FloatArray) -> FloatArray:
    """:func:`bounded_lstsq_gram` for a stack of problems ``grams[i], atbs[i]`` with the same
    bounds, e.g. one per candidate delay: the first step (scaling, Cholesky factor, unconstrained
    optimum) for all of them in a few stacked numpy calls, and :func:`bounded_lstsq_gram` for each
    one whose unconstrained optimum violates a bound or whose factorisation fails. Each row of the
    result is that problem's optimum (the same convex problem, so the same optimum up to rounding;
    the per-problem Python overhead of a small problem is paid once instead of once each)."""
    g = np.asarray(grams, dtype=np.float64)
    b = np.asarray(atbs, dtype=np.float64)
    k, p = b.shape
    lb = np.broadcast_to(np.asarray(lb, dtype=np.float64), (p,))
    ub = np.broadcast_to(np.asarray(ub, dtype=np.float64), (p,))
    norms = np.sqrt(np.maximum(np.diagonal(g, axis1=1, axis2=2), 0.0))
    norms[norms == 0] = 1.0
    gs = g / (norms[:, :, None] * norms[:, None, :])
    bs = b / norms
    out = np.empty((k, p))
    done = np.zeros(k, dtype=bool)
    with np.errstate(all="ignore"):
        try:
            low = np.linalg.cholesky(gs)  # G = L L'
        except np.linalg.LinAlgError:
            low = None  # one of them needs the jitter: each on its own below
        if low is not None:
            x0 = np.linalg.solve(np.swapaxes(low, 1, 2), np.linalg.solve(low, bs[:, :, None]))[:, :, 0]
            done = np.all(np.isfinite(x0), axis=1) & np.all(x0 >= lb * norms, axis=1) & np.all(x0 <= ub * norms, axis=1)
            out[done] = x0[done] / norms[done]
    for i in np.flatnonzero(~done):
        out[i] = bounded_lstsq_gram(g[i], b[i], lb, ub)
    return out

def _cholesky(g: FloatArray) -> FloatArray:
    """Upper Cholesky factor of a (scaled) Gram matrix, with a tiny jitter when it is singular."""
    import scipy.linalg as sl

    n = g.shape[0]
    scale = float(np.trace(g)) / max(n, 1) or 1.0
    jitter = 0.0
    for _ in range(8):
        try:
            return np.asarray(sl.cholesky(g + jitter * scale * np.eye(n), lower=False))
        except np.linalg.LinAlgError:
            jitter = _JITTER if jitter == 0.0 else jitter * 100.0
    raise np.linalg.LinAlgError("the regressors' Gram matrix is not positive definite even with jitter")
