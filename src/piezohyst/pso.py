"""Particle swarm optimisation, global-best version, paper Section II-B, eqs. (5)-(6).

    v_ij(k+1) = w v_ij(k) + c1 r1 [p_ij(k) - x_ij(k)] + c2 r2 [g_j(k) - x_ij(k)]     (5)
    x_ij(k+1) = x_ij(k) + v_ij(k+1)                                                (6)

The loop follows the paper's steps 1-6: random initial positions and velocities (1), evaluate
the fitness of every particle (2), update each particle's best (3) and the swarm's best (4),
move (5), repeat until a termination criterion is met (6): a target fitness, the maximum number
of iterations, or a stall (no improvement of the best fitness for ``stall_iter`` iterations).

Constraints are box bounds, as in scipy: a particle that would leave the box is put back on the
bound and the outward component of its velocity is zeroed (no wrap-around); velocities are
clamped to ``velocity_clamp`` times the width of the box in each dimension. r1 and r2 are drawn
independently per particle and per dimension at every iteration.

The objective receives the whole swarm, ``f(X) -> (n_particles,)`` with ``X`` of shape
``(n_particles, d)`` (``vectorized=False`` wraps a scalar ``f(x) -> float``). A non-finite fitness
counts as +inf, so a particle whose model blows up is simply never a best.

The small pure functions :func:`compute_velocity` and :func:`apply_bounds` are the backend;
:class:`ParticleSwarm` holds the state; :func:`pso_minimize` is the one-call interface.

An objective whose fitness is itself a compiled kernel can let the whole run go compiled: it
offers ``swarm_kernel() -> (kernel, args)``, a numba function that runs iterations of the loop
with :func:`swarm_move` and :func:`swarm_best_update` (the same operations as ``step``, in the
same order, on the same random numbers; :meth:`ParticleSwarm.run_compiled`). ``pso_minimize``
then runs it in blocks of iterations when nothing needs to see every iteration (no callback, no
target, no stall test). A run of hundreds of thousands of small evaluations (the paper's P-I fit,
100 particles x 3000 iterations) then costs what its arithmetic costs, not an interpreter's
round per iteration; the result is bit for bit the one ``step`` gives (``tests/test_pso.py``).
"""

from __future__ import annotations

import time
from typing import Any, Callable, Sequence

import numpy as np
from scipy.optimize import OptimizeResult

from ._numba import njit
from ._validation import FloatArray


#: iterations per compiled call between progress updates (:meth:`ParticleSwarm.run_compiled`)
COMPILED_BLOCK = 100


class PSOResult(OptimizeResult):
    """Result of :func:`pso_minimize`.

    Attributes
    ----------
    x : ndarray
        Best position found (gbest).
    fun : float
        Its fitness.
    nit : int
        Iterations performed (velocity/position updates).
    nfev : int
        Fitness evaluations (particles x (iterations + 1)).
    history : ndarray
        Best fitness after the initial evaluation and after each iteration (length nit + 1).
    message : str
        Why the run stopped.
    success : bool
        True unless the run stopped because every fitness was non-finite.
    time_s : float
        Wall-clock time of the run.
    """


def _bounds_array(bounds: Any) -> tuple[FloatArray, FloatArray]:
    try:
        b = np.asarray(bounds, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("bounds must be a sequence of (low, high) pairs of numbers") from None
    if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] < 1:
        raise ValueError(f"bounds must be a sequence of (low, high) pairs, got shape {b.shape}")
    if not np.all(np.isfinite(b)):
        raise ValueError("bounds must be finite")
    lb, ub = b[:, 0].copy(), b[:, 1].copy()
    if np.any(lb >= ub):
        i = int(np.argmax(lb >= ub))
        raise ValueError(
            f"Each lower bound must be strictly less than each upper bound "
            f"(dimension {i}: low={lb[i]}, high={ub[i]})."
        )
    return lb, ub


def compute_velocity(
    v: FloatArray, x: FloatArray, pbest: FloatArray, gbest: FloatArray, *,
    inertia: float, c1: float, c2: float, vmax: FloatArray, rng: np.random.Generator,
) -> FloatArray:
    """Eq. (5) for the whole swarm, then clamped to ``[-vmax, vmax]`` per dimension."""
    r = rng.random((2, *x.shape))  # r1 then r2: the same stream as two separate draws
    new = inertia * v
    new += c1 * r[0] * (pbest - x)
    new += c2 * r[1] * (gbest - x)
    np.minimum(new, vmax, out=new)
    np.maximum(new, -vmax, out=new)
    return new


def apply_bounds(x: FloatArray, v: FloatArray, lb: FloatArray, ub: FloatArray) -> None:
    """Put particles that left the box back on the bound and zero their outward velocity (in place)."""
    low = x < lb
    if low.any():
        np.copyto(x, np.broadcast_to(lb, x.shape), where=low)
        v[low & (v < 0)] = 0.0
    high = x > ub
    if high.any():
        np.copyto(x, np.broadcast_to(ub, x.shape), where=high)
        v[high & (v > 0)] = 0.0


@njit
def swarm_move(x: FloatArray, v: FloatArray, pbest: FloatArray, gbest: FloatArray, r: FloatArray, inertia: float,
               c1: float, c2: float, vmax: FloatArray, lb: FloatArray, ub: FloatArray) -> None:  # pragma: no cover
    """Eqs. (5)-(6) with the bounds, in place: :func:`compute_velocity` with the random numbers
    ``r`` (shape ``(2, n, d)``), then ``x + v``, then :func:`apply_bounds`, operation for operation."""
    n, d = x.shape
    for i in range(n):
        for j in range(d):
            xv = x[i, j]
            nv = inertia * v[i, j]
            nv = nv + c1 * r[0, i, j] * (pbest[i, j] - xv)
            nv = nv + c2 * r[1, i, j] * (gbest[j] - xv)
            if nv > vmax[j]:
                nv = vmax[j]
            if nv < -vmax[j]:
                nv = -vmax[j]
            xv = xv + nv
            if xv < lb[j]:
                xv = lb[j]
                if nv < 0:
                    nv = 0.0
            if xv > ub[j]:
                xv = ub[j]
                if nv > 0:
                    nv = 0.0
            x[i, j] = xv
            v[i, j] = nv


@njit
def swarm_best_update(x: FloatArray, f: FloatArray, pbest: FloatArray, pbest_f: FloatArray, gbest: FloatArray,
                      gbest_f: FloatArray) -> None:  # pragma: no cover
    """Steps 3-4 of :meth:`ParticleSwarm.step`, in place: a non-finite fitness counts as +inf,
    each particle's best, then the swarm's (``gbest_f`` is a one-element array)."""
    n, d = x.shape
    for i in range(n):
        fi = f[i]
        if not np.isfinite(fi):
            fi = np.inf
        if fi < pbest_f[i]:
            pbest_f[i] = fi
            for j in range(d):
                pbest[i, j] = x[i, j]
    k = 0
    for i in range(1, n):
        if pbest_f[i] < pbest_f[k]:
            k = i
    if pbest_f[k] < gbest_f[0]:
        gbest_f[0] = pbest_f[k]
        for j in range(d):
            gbest[j] = pbest[k, j]


class ParticleSwarm:
    """The state of a global-best swarm; :meth:`step` performs one iteration of steps 2-5."""

    def __init__(
        self, fun: Callable[[FloatArray], Any], bounds: Any, *, n_particles: int = 40,
        inertia: float = 0.7298, c1: float = 1.49618, c2: float = 1.49618,
        velocity_clamp: float = 0.5, seed: Any = None, vectorized: bool = True,
        init: Any = None,
    ):
        if isinstance(n_particles, bool) or not isinstance(n_particles, (int, np.integer)) or n_particles < 1:
            raise ValueError(f"n_particles must be a positive integer, got {n_particles!r}")
        for name, val in (("inertia", inertia), ("c1", c1), ("c2", c2)):
            if not np.isfinite(val) or val < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {val}")
        if not (0 < velocity_clamp <= 1):
            raise ValueError(f"velocity_clamp must be in (0, 1], got {velocity_clamp}")
        if not callable(fun):
            raise TypeError("fun must be callable")
        self.lb, self.ub = _bounds_array(bounds)
        self.d = self.lb.size
        self.n = int(n_particles)
        self.inertia, self.c1, self.c2 = float(inertia), float(c1), float(c2)
        self.vmax = velocity_clamp * (self.ub - self.lb)
        self.rng = np.random.default_rng(seed)
        self._fun = fun
        self._vectorized = vectorized
        self.nfev = 0
        self.nit = 0
        # step 1: random positions and velocities
        self.x = self.lb + self.rng.random((self.n, self.d)) * (self.ub - self.lb)
        if init is not None:
            x0 = np.atleast_2d(np.asarray(init, dtype=np.float64))
            if x0.shape[1] != self.d:
                raise ValueError(f"init must have {self.d} columns, got shape {x0.shape}")
            k = min(len(x0), self.n)
            self.x[:k] = np.clip(x0[:k], self.lb, self.ub)
        self.v = (2 * self.rng.random((self.n, self.d)) - 1) * self.vmax
        # steps 2-4 for the initial swarm
        f = self._evaluate(self.x)
        self.pbest = self.x.copy()
        self.pbest_f = f
        i = int(np.argmin(f))
        self.gbest = self.x[i].copy()
        self.gbest_f = float(f[i])
        self.history = [self.gbest_f]

    def _evaluate(self, x: FloatArray) -> FloatArray:
        if self._vectorized:
            f = np.asarray(self._fun(x), dtype=np.float64)
            if f.shape != (self.n,):
                raise ValueError(
                    f"the objective must return one fitness per particle, shape ({self.n},), "
                    f"got shape {f.shape} (pass vectorized=False for a scalar objective)"
                )
        else:
            f = np.array([float(self._fun(row)) for row in x])
        self.nfev += self.n
        if not np.isfinite(f).all():
            f = np.where(np.isfinite(f), f, np.inf)
        return f

    def step(self) -> None:
        """One iteration: move (eqs. 5-6, with bounds), evaluate (2), update pbest (3), gbest (4)."""
        self.v = compute_velocity(
            self.v, self.x, self.pbest, self.gbest, inertia=self.inertia, c1=self.c1, c2=self.c2,
            vmax=self.vmax, rng=self.rng,
        )
        self.x = self.x + self.v
        apply_bounds(self.x, self.v, self.lb, self.ub)
        f = self._evaluate(self.x)
        better = f < self.pbest_f
        np.copyto(self.pbest, self.x, where=better[:, None])
        np.copyto(self.pbest_f, f, where=better)
        i = int(self.pbest_f.argmin())
        if self.pbest_f[i] < self.gbest_f:
            self.gbest_f = float(self.pbest_f[i])
            self.gbest = self.pbest[i].copy()
        self.nit += 1
        self.history.append(self.gbest_f)

    def run_compiled(self, iterations: int, kernel: Callable[..., Any], args: tuple[Any, ...]) -> None:
        """``iterations`` calls of :meth:`step` in one call of a compiled ``kernel`` (module docstring):
        ``kernel(iterations, x, v, pbest, pbest_f, gbest, gbest_f, lb, ub, vmax, inertia, c1, c2, rng,
        history, *args)`` updates the swarm's arrays in place and writes the best fitness after each
        iteration into ``history``; this keeps the counts."""
        if iterations <= 0:
            return
        for name in ("x", "v", "pbest", "pbest_f", "gbest"):
            setattr(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float64))
        best = np.array([self.gbest_f])
        hist = np.empty(iterations)
        kernel(iterations, self.x, self.v, self.pbest, self.pbest_f, self.gbest, best, self.lb, self.ub, self.vmax,
               self.inertia, self.c1, self.c2, self.rng, hist, *args)
        self.gbest_f = float(best[0])
        self.nit += iterations
        self.nfev += iterations * self.n
        self.history.extend(hist.tolist())


def pso_minimize(
    fun: Callable[[FloatArray], Any],
    bounds: Sequence[tuple[float, float]] | FloatArray,
    *,
    n_particles: int = 40,
    max_iter: int = 200,
    inertia: float = 0.7298,
    c1: float = 1.49618,
    c2: float = 1.49618,
    target: float | None = None,
    seed: Any = None,
    vectorized: bool = True,
    callback: Callable[[OptimizeResult], Any] | None = None,
    stall_iter: int | None = None,
    ftol: float = 0.0,
    velocity_clamp: float = 0.5,
    init: Any = None,
    progress: Any = False,
    description: str = "PSO",
    polish: bool = False,
) -> PSOResult:
    """Minimise ``fun`` over a box with global-best particle swarm optimisation, eqs. (5)-(6).

    Parameters
    ----------
    fun : callable
        ``fun(X) -> (n_particles,)`` for ``X`` of shape ``(n_particles, d)``; with
        ``vectorized=False``, ``fun(x) -> float``.
    bounds : sequence of (low, high)
        One pair per dimension; every particle stays inside.
    n_particles, max_iter : int
        Swarm size and the maximum number of iterations.
    inertia, c1, c2 : float
        ``w``, ``c1``, ``c2`` of eq. (5). Defaults: the constriction-equivalent values of
        Clerc and Kennedy (0.7298, 1.49618, 1.49618).
    target : float, optional
        Stop as soon as the best fitness is <= target ("a sufficiently good fitness value").
    seed : int or numpy Generator, optional
        The only source of randomness: the same seed gives the same x and the same nfev.
    callback : callable, optional
        Called after every iteration with an ``OptimizeResult`` (x, fun, nit, nfev); returning
        True or raising ``StopIteration`` stops the run.
    stall_iter : int, optional
        Stop when the best fitness has not improved by more than ``ftol`` (relative) for this
        many iterations.
    velocity_clamp : float
        Velocities are limited to this fraction of each dimension's range.
    init : array_like, optional
        Positions for the first particles (e.g. a previous solution); the rest are random.
    progress : bool or Progress
        True: show the iterations and the best fitness in a :class:`~piezohyst.Progress` display
        (a Jupyter cell's output, or a line on a terminal's standard error). A ``Progress``:
        show them in that display. Either way, while another ``Progress`` is open (say, the one
        given to :func:`~piezohyst.identify.fit_model`), the iterations show in it.
    polish : bool
        After the swarm stops, refine its best position with a bounded local optimiser
        (``scipy.optimize.minimize``, L-BFGS-B), as ``scipy.optimize.differential_evolution``
        does. The swarm's own result stays in ``pso_x`` / ``pso_fun``; ``nfev`` counts both.

    Returns
    -------
    PSOResult

    Examples
    --------
    >>> import numpy as np, piezohyst as ph
    >>> res = ph.pso_minimize(lambda X: (X**2).sum(axis=1), [(-5, 5)] * 3, seed=0)
    >>> bool(res.fun < 1e-6), res.nfev == 40 * (res.nit + 1)
    (True, True)
    """
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 0:
        raise ValueError(f"max_iter must be an integer >= 0, got {max_iter!r}")
    if stall_iter is not None and (not isinstance(stall_iter, (int, np.integer)) or stall_iter < 1):
        raise ValueError(f"stall_iter must be a positive integer or None, got {stall_iter!r}")
    t0 = time.perf_counter()
    swarm = ParticleSwarm(
        fun, bounds, n_particles=n_particles, inertia=inertia, c1=c1, c2=c2,
        velocity_clamp=velocity_clamp, seed=seed, vectorized=vectorized, init=init,
    )
    message = f"maximum number of iterations ({max_iter}) reached"
    last_improvement = 0
    best_seen = swarm.gbest_f

    from . import progress as _progress

    # a display of our own when asked; else the iterations go to an open one (e.g. fit_model's)
    outer = progress if isinstance(progress, _progress.Progress) else _progress.active()
    bar: _progress.Progress | None = None
    if outer is not None and not outer.closed:
        outer.start_sub(description, total=max_iter)
        tick = outer.advance_sub
    elif progress:
        outer = None
        bar = _progress.Progress(description, total=max_iter)
        tick = bar.advance
    else:
        outer = None
        tick = None
    # the whole run compiled, in blocks (progress between them), when the objective offers it and
    # nothing has to see every iteration
    compiled = getattr(fun, "swarm_kernel", None)
    compiled = compiled() if (compiled is not None and vectorized and callback is None and target is None
                              and stall_iter is None) else None
    try:
        if target is not None and swarm.gbest_f <= target:
            message = f"target fitness {target} reached"
            max_iter = 0
        while compiled is not None and swarm.nit < max_iter:
            k = min(COMPILED_BLOCK, max_iter - swarm.nit)
            swarm.run_compiled(k, *compiled)
            if tick is not None:
                tick(k, best=swarm.gbest_f)
        while swarm.nit < max_iter:
            swarm.step()
            if tick is not None:
                tick(1, best=swarm.gbest_f)
            if swarm.gbest_f < best_seen - ftol * abs(best_seen):
                best_seen = swarm.gbest_f
                last_improvement = swarm.nit
            if target is not None and swarm.gbest_f <= target:
                message = f"target fitness {target} reached"
                break
            if stall_iter is not None and swarm.nit - last_improvement >= stall_iter:
                message = f"no improvement for {stall_iter} iterations (stall)"
                break
            if callback is not None:
                state = OptimizeResult(x=swarm.gbest.copy(), fun=swarm.gbest_f, nit=swarm.nit, nfev=swarm.nfev)
                try:
                    stop = callback(state)
                except StopIteration:
                    stop = True
                if stop is True:
                    message = "stopped by the callback"
                    break
    finally:
        if bar is not None:
            bar.close()
        elif outer is not None:
            outer.end_sub()
    success = bool(np.isfinite(swarm.gbest_f))
    if not success:
        message = "every evaluated fitness was non-finite"
    result = PSOResult(
        x=swarm.gbest.copy(), fun=swarm.gbest_f, nit=swarm.nit, nfev=swarm.nfev,
        history=np.array(swarm.history), message=message, success=success,
        pso_x=swarm.gbest.copy(), pso_fun=swarm.gbest_f,
    )
    if polish and success:
        from scipy.optimize import minimize

        def scalar(x: FloatArray) -> float:
            if vectorized:
                val = float(np.asarray(fun(x[None, :]), dtype=np.float64).reshape(-1)[0])
            else:
                val = float(fun(x))
            return val if np.isfinite(val) else np.inf

        loc = minimize(scalar, swarm.gbest, method="L-BFGS-B", bounds=list(zip(swarm.lb, swarm.ub)))
        result.nfev += int(loc.nfev)
        if np.isfinite(loc.fun) and loc.fun < result.fun:
            result.x = np.clip(loc.x, swarm.lb, swarm.ub)
            result.fun = float(loc.fun)
        result.message += "; polished with L-BFGS-B"
    result.time_s = time.perf_counter() - t0
    return result
