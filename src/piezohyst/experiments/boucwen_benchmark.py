"""The Bouc-Wen nonlinear system identification benchmark (Noel and Schoukens, 2016).

Data: doi 10.4121/12967592 (4TU.ResearchData); the MATLAB file in ``data/bouc-wen-benchmark/``.
A **grey-box** identification of the structural Bouc-Wen model
(:mod:`piezohyst.models.bouc_wen_structural`), i.e. with the true model structure given, from the
**training record only**, then simulation of the two official test records. (The published
results it is compared with are black-box models, which are given no structure.)

Identifiability: only ``beta gamma`` and ``beta delta`` enter the equations, so ``beta = 1`` is
fixed and ``gamma' = beta gamma``, ``delta' = beta delta`` are identified (the true values are
800 and -1100). The other parameters, m, c, k, alpha and nu, are identified.

Method, each stage reported with its own figures:

1. **Best linear approximation** (closed form): the training input is a periodic multisine, so
   averaging its periods after the first gives the frequency response ``G = Y/U`` at the excited
   lines; ``1/G = k_tot - m w^2 + j c w`` is linear in (m, c, k_tot), ``k_tot = k + alpha`` the
   small-signal stiffness.
2. **The search box, from the data** (:func:`derive_bounds`). The linear part from the BLA:

   * ``m`` within a factor 2 of the BLA mass, which the high-frequency lines fix (inertia
     dominates there whatever the stiffness does);
   * ``k_tot = k + alpha`` within a factor 3 of the BLA stiffness (the BLA is the best linear fit
     of the same force-displacement relation);
   * ``c`` from 1/100 to 3 times the BLA damping, which includes the hysteresis' dissipation, so
     the viscous part is at most of its order and possibly far below;
   * ``alpha / k_tot`` in [0, 1]: the hysteretic share of the small-signal stiffness, its whole
     physical range (k, alpha >= 0).

   The hysteresis parameters from scale arguments, with the output's RMS ``y_s`` as the
   displacement scale and ``z_s = k_tot,BLA y_s`` as the force scale: ``gamma'`` and ``delta'``
   have units 1/(m N^(nu-1)), so the search runs over the dimensionless
   ``gamma^ = gamma' y_s z_s^(nu-1)`` and ``delta^`` (the same). At ``|gamma^| = 1e-2`` the
   hysteresis bends the restoring force by ~1 % over a typical amplitude (less is invisible:
   ``z = alpha y``); at ``1e2`` it saturates within 1 % of it (more is the same Coulomb-like
   element). So ``gamma^`` in [1e-2, 1e2] (log) and ``delta^`` either sign with
   ``|delta^|`` in the same decades (searched as ``asinh(delta^ / 1e-2)``, a signed log). The
   exponent ``nu`` is dimensionless, so no data scale bounds it: [1/2, 2] (log), from a smooth to
   a sharp transition, the usual range.

   ``bounds_scale`` s widens every bound s times: log-searched ones by a factor s at each end
   (m, c, k_tot, gamma^, |delta^| from 1e-2/s to 1e2 s, nu); ``alpha / k_tot`` already spans its
   physical range.
3. **PSO** (eqs. 5-6; whole swarm per call, threads over particles) over those coordinates, on
   the first period of the training record, RK4 at the rate that puts 5 steps in a period of the
   highest excited frequency (750 Hz here). One particle starts at the BLA point with the
   hysteresis at its scale values (``alpha / k_tot = 1/2``, ``gamma^ = 1``, ``delta^ = 0``,
   ``nu = 1``); the rest are random, as in the paper.
4. **Multi-start**: the best points the swarm evaluated that lie at least 20 % of the box apart
   in some coordinate (up to 8, best first), each refined briefly by bounded least squares on the
   PSO window (exact Jacobian, below); the best result goes on. A gbest swarm collapses into one
   basin; its early positions still sample others, and with bounds 10x wider the right basin is
   sometimes found only from one of these.
5. **Local refinement**: bounded nonlinear least squares (``scipy.optimize.least_squares``) on
   the whole training record, RK4 at the rate that puts 20 steps in a period of the highest
   excited frequency (3 kHz here), with the exact Jacobian of the RK4 map by forward
   sensitivities (:func:`~piezohyst.models.bouc_wen_structural.structural_sensitivities`: one
   integration per Jacobian, not one per parameter).

The test records are simulated with RK4 at 15 kHz (20 substeps) from band-limited input
interpolation: the multisine over two periods, keeping the second (steady state, as the record
is); the sine sweep from rest.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ..models.bouc_wen_structural import (
    StructuralBoucWen,
    fine_input,
    structural_rk4,
    structural_sensitivities,
    structural_swarm_rmse,
)
from ..pso import ParticleSwarm

FS = 750.0
PERIOD = 8192
TRUE = StructuralBoucWen(m=2.0, c=10.0, k=5e4, alpha=5e4, beta=1e3, gamma=0.8, delta=-1.1, nu=1.0)

#: Published test RMS errors on the multisine record, m (shared/data/README.md); black-box models.
PUBLISHED = (
    ("state-space neural network, improved initialisation (M. Schoukens, ECC 2021)", 7.53e-6),
    ("decoupled polynomial nonlinear state-space (Esfahani et al., MSSP 104, 2018)", 1.34e-5),
    ("Koopman input-affine model (Iacob et al.)", 1.43e-5),
    ("PNLSS (Noel et al.)", 1.2e-5),
)
BEST_PUBLISHED = min(v for _, v in PUBLISHED)
#: The floor quoted with the data (RK4 at 15 kHz, two periods): 2.1e-6 m. With band-limited
#: input interpolation the true system reproduces the record far more closely; both are printed.
QUOTED_FLOOR = 2.1e-6

NAMES = ("m", "c", "k", "alpha", "gamma'", "delta'", "nu")
#: search coordinates, in the order of :meth:`SearchBox.natural`'s argument
COORDS = ("log10 m", "log10 c", "log10 k_tot", "alpha/k_tot", "log10 gamma^", "asinh(delta^/d0)", "log10 nu")
_D0 = 1e-2  # the smallest |delta^| resolved by the signed log, before widening
START_SEPARATION = 0.2  # multi-start points differ by this fraction of the box in some coordinate


@dataclass(frozen=True)
class SearchBox:
    """The search coordinates of stages 3-5 and their bounds (module docstring, stage 2).

    ``lo``, ``hi`` bound the coordinates ``COORDS``; :meth:`natural` maps them to the model's
    parameters ``NAMES`` (SI units) and :meth:`jacobian` gives that map's derivative.
    """

    lo: np.ndarray
    hi: np.ndarray
    y_scale: float
    z_scale: float
    d0: float
    bla: tuple[float, float, float]
    bounds_scale: float

    def _scale(self, nu: np.ndarray) -> np.ndarray:
        """1 / (y_s z_s^(nu - 1)): gamma' = gamma^ times this."""
        return 1.0 / (self.y_scale * self.z_scale ** (nu - 1.0))

    def natural(self, x: Any) -> np.ndarray:
        """(m, c, k, alpha, gamma', delta', nu) for each row of search coordinates ``x``."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        k_tot = 10 ** x[:, 2]
        nu = 10 ** x[:, 6]
        sc = self._scale(nu)
        return np.column_stack([10 ** x[:, 0], 10 ** x[:, 1], k_tot * (1.0 - x[:, 3]), k_tot * x[:, 3],
                                10 ** x[:, 4] * sc, self.d0 * np.sinh(x[:, 5]) * sc, nu])

    def jacobian(self, x: Any) -> np.ndarray:
        """d natural / d x (7 x 7) at one point ``x``."""
        x = np.asarray(x, dtype=np.float64)
        m, c, _, _, g, d, nu = self.natural(x)[0]
        ln10 = math.log(10.0)
        k_tot = 10 ** x[2]
        sc = float(self._scale(np.array([nu]))[0])
        dlnsc_dx6 = -math.log(self.z_scale) * nu * ln10  # d ln(scale) / d log10(nu)
        j = np.zeros((7, 7))
        j[0, 0] = m * ln10
        j[1, 1] = c * ln10
        j[2, 2], j[2, 3] = k_tot * (1.0 - x[3]) * ln10, -k_tot
        j[3, 2], j[3, 3] = k_tot * x[3] * ln10, k_tot
        j[4, 4], j[4, 6] = g * ln10, g * dlnsc_dx6
        j[5, 5], j[5, 6] = self.d0 * math.cosh(x[5]) * sc, d * dlnsc_dx6
        j[6, 6] = nu * ln10
        return j

    def bounds_natural(self) -> dict[str, list[float]]:
        """The box in readable units: m, c, k_tot (SI), alpha/k_tot, gamma^, |delta^|, nu."""
        lo, hi = self.lo, self.hi
        return {"m": [10 ** lo[0], 10 ** hi[0]], "c": [10 ** lo[1], 10 ** hi[1]],
                "k_tot": [10 ** lo[2], 10 ** hi[2]], "alpha/k_tot": [lo[3], hi[3]],
                "gamma^": [10 ** lo[4], 10 ** hi[4]], "|delta^|": [self.d0, self.d0 * math.sinh(hi[5])],
                "nu": [10 ** lo[6], 10 ** hi[6]], "y_scale_m": [self.y_scale] * 2, "z_scale_N": [self.z_scale] * 2}

    def start(self) -> np.ndarray:
        """The BLA point with the hysteresis at its scale values (the first particle)."""
        m0, c0, k0 = self.bla
        x = np.array([math.log10(m0), math.log10(c0), math.log10(k0), 0.5, 0.0, 0.0, 0.0])
        return np.clip(x, self.lo, self.hi)


def derive_bounds(u: np.ndarray, y: np.ndarray, fs: float, period: int, *, bounds_scale: float = 1.0) -> SearchBox:
    """The search box of stages 3-5 from the training record (module docstring, stage 2)."""
    if not (math.isfinite(bounds_scale) and bounds_scale >= 1.0):
        raise ValueError(f"bounds_scale must be a finite number >= 1, got {bounds_scale}")
    m0, c0, k0 = best_linear_approximation(u, y, fs, period)
    if not (m0 > 0 and k0 > 0 and c0 > 0):
        raise ValueError(f"the best linear approximation is not a damped mass-spring system (m {m0:.3g}, "
                         f"c {c0:.3g}, k {k0:.3g}): not a record of this benchmark's kind")
    y_s = float(np.std(y))
    z_s = k0 * y_s
    w = math.log10(bounds_scale)
    lg = math.log10
    lo = np.array([lg(m0 / 2) - w, lg(c0 / 100) - w, lg(k0 / 3) - w, 0.0, -2.0 - w,
                   -math.asinh(1e2 * bounds_scale / (_D0 / bounds_scale)), lg(0.5) - w])
    hi = np.array([lg(m0 * 2) + w, lg(c0 * 3) + w, lg(k0 * 3) + w, 1.0, 2.0 + w,
                   math.asinh(1e2 * bounds_scale / (_D0 / bounds_scale)), lg(2.0) + w])
    return SearchBox(lo=lo, hi=hi, y_scale=y_s, z_scale=z_s, d0=_D0 / bounds_scale, bla=(m0, c0, k0),
                     bounds_scale=float(bounds_scale))


def excited_band(u: np.ndarray, fs: float, period: int) -> tuple[float, float]:
    """Lowest and highest frequency (Hz) that carry the periodic input's power."""
    n_per = max(u.size // period, 1)
    spec = np.abs(np.fft.rfft(u[: n_per * period].reshape(n_per, period).mean(axis=0)))
    freqs = np.fft.rfftfreq(period, 1 / fs)
    lines = np.nonzero(spec[1:] > 1e-3 * spec[1:].max())[0] + 1
    return float(freqs[lines[0]]), float(freqs[lines[-1]])


def _model(p: Sequence[float]) -> StructuralBoucWen:
    return StructuralBoucWen(m=p[0], c=p[1], k=p[2], alpha=p[3], beta=1.0, gamma=p[4], delta=p[5], nu=p[6])


@dataclass
class BenchmarkResult:
    model: StructuralBoucWen
    stages: dict[str, dict[str, Any]]
    test_rmse: dict[str, float]
    true_model_test_rmse: dict[str, float]
    train_rmse: float
    time_s: float
    data: str
    seed: int = 0
    bounds_scale: float = 1.0
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        m = self.model
        ident = {"m": m.m, "c": m.c, "k": m.k, "alpha": m.alpha, "gamma'": m.beta * m.gamma,
                 "delta'": m.beta * m.delta, "nu": m.nu}
        true = {"m": TRUE.m, "c": TRUE.c, "k": TRUE.k, "alpha": TRUE.alpha, "gamma'": TRUE.beta * TRUE.gamma,
                "delta'": TRUE.beta * TRUE.delta, "nu": TRUE.nu}
        stages = {k: {kk: vv for kk, vv in v.items() if kk != "model"} for k, v in self.stages.items()}
        return {"data": self.data, "seed": self.seed, "bounds_scale": self.bounds_scale,
                "identified": ident, "true": true, "beta_fixed": 1.0, "grey_box": True,
                "test_rmse_m": self.test_rmse, "true_system_test_rmse_m": self.true_model_test_rmse,
                "quoted_floor_m": QUOTED_FLOOR, "published_multisine_rmse_m": [
                    {"method": n, "rmse_m": v} for n, v in PUBLISHED],
                "beats_best_published": bool(self.test_rmse["multisine"] < BEST_PUBLISHED),
                "train_rmse_m": self.train_rmse, "stages": stages, "identification_time_s": self.time_s}


def load_benchmark(path: str | Path) -> dict[str, np.ndarray]:
    """The benchmark's arrays from its MATLAB file, as flat float64 vectors."""
    from scipy.io import loadmat

    from ..data import DataError

    p = Path(path)
    if not p.exists():
        raise DataError(f"{p}: no such file")
    try:
        m = loadmat(p)
    except Exception as exc:
        raise DataError(f"{p}: not a readable MATLAB file ({exc})") from None
    need = ("u", "y", "uval_multisine", "yval_multisine", "uval_sinesweep", "yval_sinesweep")
    missing = [k for k in need if k not in m]
    if missing:
        raise DataError(f"{p}: not the Bouc-Wen benchmark file (missing {missing})")
    return {k: np.asarray(m[k], dtype=np.float64).ravel() for k in need}


def best_linear_approximation(u: np.ndarray, y: np.ndarray, fs: float, period: int) -> tuple[float, float, float]:
    """(m, c, k_tot) from the averaged frequency response of a periodic multisine (stage 1)."""
    n_per = u.size // period
    first = 1 if n_per > 1 else 0
    ub = u[first * period: n_per * period].reshape(-1, period).mean(axis=0)
    yb = y[first * period: n_per * period].reshape(-1, period).mean(axis=0)
    uf, yf = np.fft.rfft(ub), np.fft.rfft(yb)
    w = 2 * np.pi * np.fft.rfftfreq(period, 1 / fs)
    lines = np.abs(uf) > 1e-3 * np.abs(uf).max()
    inv = uf[lines] / yf[lines]  # 1/G = k_tot - m w^2 + j c w
    a_re = np.column_stack([np.ones(lines.sum()), -w[lines] ** 2])
    k_tot, mass = np.linalg.lstsq(a_re, inv.real, rcond=None)[0]
    c = float(np.linalg.lstsq(w[lines][:, None], inv.imag, rcond=None)[0][0])
    return float(mass), c, float(k_tot)


def _least_squares(box: SearchBox, x0: np.ndarray, u_fine: np.ndarray, y: np.ndarray, h: float, sub: int,
                   max_nfev: int) -> Any:
    """Bounded least squares of the RK4 simulation against ``y``, exact Jacobian (stage 4 and 5)."""
    from scipy.optimize import least_squares

    bad = np.full(y.size, 10.0 * float(np.abs(y).max()))  # a diverged simulation: far off, flat

    def resid(x: np.ndarray) -> np.ndarray:
        r = structural_rk4(box.natural(x)[0], u_fine, h, sub, np.zeros(3)) - y
        return r if np.all(np.isfinite(r)) else bad

    def jac(x: np.ndarray) -> np.ndarray:
        _, dy_dp = structural_sensitivities(box.natural(x)[0], u_fine, h, sub)
        with np.errstate(all="ignore"):
            j = dy_dp @ box.jacobian(x)
        return j if np.all(np.isfinite(j)) and np.abs(j).max() < 1e150 else np.zeros((y.size, 7))

    span = box.hi - box.lo
    x0 = np.clip(x0, box.lo + 1e-9 * span, box.hi - 1e-9 * span)
    # lsmr for the trust-region subproblem: 7 columns, so it is exact in a few products, where the
    # default SVD of the tall Jacobian costs more than the simulations themselves
    return least_squares(resid, x0, jac=jac, bounds=(box.lo, box.hi), x_scale="jac", max_nfev=max_nfev,
                         tr_solver="lsmr")


def _distinct(pbest: np.ndarray, pbest_f: np.ndarray, box: SearchBox, k: int, sep: float = 0.02) -> list[int]:
    """Up to ``k`` personal bests, best first, each at least ``sep`` of the box from the others."""
    span = box.hi - box.lo
    picked: list[int] = []
    for i in np.argsort(pbest_f):
        if not np.isfinite(pbest_f[i]):
            break
        xn = (pbest[i] - box.lo) / span
        if all(np.max(np.abs(xn - (pbest[j] - box.lo) / span)) > sep for j in picked):
            picked.append(int(i))
        if len(picked) >= k:
            break
    return picked


def identify(data: dict[str, np.ndarray], *, seed: int = 0, n_particles: int = 40, max_iter: int = 60,
             fs: float = FS, period: int = PERIOD, refine_nfev: int = 100, n_starts: int = 8,
             bounds_scale: float = 1.0, on_step: Callable[[str], None] | None = None,
             ) -> tuple[StructuralBoucWen, dict[str, dict[str, Any]], float]:
    """Stages 1-5 of the module docstring on ``data["u"], data["y"]`` (a periodic multisine of
    ``period`` samples at ``fs``, from rest); returns the model, each stage's figures, seconds."""
    say = on_step or (lambda s: None)
    t_all = time.perf_counter()
    u, y = data["u"], data["y"]
    stages: dict[str, dict[str, Any]] = {}

    t0 = time.perf_counter()
    say("best linear approximation and search box")
    box = derive_bounds(u, y, fs, period, bounds_scale=bounds_scale)
    _, f_hi = excited_band(u, fs, period)
    sub_pso = max(1, math.ceil(5 * f_hi / fs))  # 5 RK4 steps per period of the highest line
    sub_ref = max(1, math.ceil(20 * f_hi / fs))  # 20
    m0, c0, k0 = box.bla
    stages["bla"] = {"m": m0, "c": c0, "k_tot": k0, "f_max_hz": f_hi, "bounds_scale": bounds_scale,
                     "bounds": box.bounds_natural(), "time_s": time.perf_counter() - t0}

    n_fit = min(period, u.size)
    fine = fine_input(u[:n_fit], sub_pso, periodic=True)
    h = 1.0 / (fs * sub_pso)

    seen_x: list[np.ndarray] = []
    seen_f: list[np.ndarray] = []

    def fitness(xs: np.ndarray) -> np.ndarray:
        f = structural_swarm_rmse(np.ascontiguousarray(box.natural(xs)), fine, h, sub_pso, y[:n_fit], 0)
        seen_x.append(xs.copy())
        seen_f.append(f)
        return f

    t0 = time.perf_counter()
    say(f"PSO, {n_particles} particles x {max_iter} iterations")
    swarm = ParticleSwarm(fitness, list(zip(box.lo, box.hi)), n_particles=n_particles, seed=seed,
                          init=box.start()[None, :])
    for _ in range(max_iter):
        swarm.step()
    if not np.isfinite(swarm.gbest_f):
        raise RuntimeError("Bouc-Wen benchmark: every particle's simulation diverged")
    p_pso = box.natural(swarm.gbest)[0]
    stages["pso"] = {"model": _model(p_pso), "rmse_m": float(swarm.gbest_f), "nit": int(swarm.nit),
                     "nfev": int(swarm.nfev), "parameters": dict(zip(NAMES, p_pso.tolist())),
                     "time_s": time.perf_counter() - t0, "fit_samples": n_fit, "rk4_hz": fs * sub_pso}

    t0 = time.perf_counter()
    all_x, all_f = np.concatenate(seen_x), np.concatenate(seen_f)
    picked = _distinct(all_x, all_f, box, n_starts, sep=START_SEPARATION)
    say(f"multi-start: {len(picked)} distinct points of the search, refined on the PSO window")
    with ThreadPoolExecutor(max_workers=2) as pool:  # the compiled simulations release the GIL
        sols = list(pool.map(lambda i: _least_squares(box, all_x[i], fine, y[:n_fit], h, sub_pso, 15), picked))
    rms = [float(np.sqrt(np.mean(s.fun**2))) for s in sols]
    best = int(np.argmin(rms))
    x_start = sols[best].x
    stages["multistart"] = {"starts": len(picked), "start_rmse_m": [float(all_f[i]) for i in picked],
                            "refined_rmse_m": rms, "chosen": best, "time_s": time.perf_counter() - t0}

    t0 = time.perf_counter()
    say("local refinement (least squares, whole training record)")
    fine_all = fine_input(u, sub_ref, periodic=True)
    sol = _least_squares(box, x_start, fine_all, y, 1.0 / (fs * sub_ref), sub_ref, refine_nfev)
    p = box.natural(sol.x)[0]
    stages["refinement"] = {"rmse_m": float(np.sqrt(np.mean(sol.fun**2))), "nfev": int(sol.nfev),
                            "njev": int(sol.njev or 0), "parameters": dict(zip(NAMES, p.tolist())),
                            "time_s": time.perf_counter() - t0, "rk4_hz": fs * sub_ref}
    return _model(p), stages, time.perf_counter() - t_all


def _simulations(models: Sequence[StructuralBoucWen], data: dict[str, np.ndarray]) -> list[dict[str, float]]:
    """:func:`test_errors` of several models at once (the swarm kernel: same RK4, to rounding)."""
    theta = np.array([m.kernel_params() for m in models])
    sub = 20
    ums, yms = data["uval_multisine"], data["yval_multisine"]
    # two periods from rest, scored on the second (steady state, as the record is)
    ms = structural_swarm_rmse(theta, fine_input(np.tile(ums, 2), sub, periodic=True), 1.0 / (FS * sub), sub,
                               np.concatenate([np.zeros(ums.size), yms]), ums.size)
    sw = structural_swarm_rmse(theta, fine_input(data["uval_sinesweep"], sub, periodic=False), 1.0 / (FS * sub),
                               sub, data["yval_sinesweep"], 0)
    return [{"multisine": float(a), "sinesweep": float(b)} for a, b in zip(ms, sw)]


def test_errors(model: StructuralBoucWen, data: dict[str, np.ndarray]) -> dict[str, float]:
    """RMS error (m) on the two official test records, RK4 at 15 kHz."""
    return _simulations([model], data)[0]


def run_benchmark(path: str | Path, *, seed: int = 0, bounds_scale: float = 1.0,
                  on_step: Callable[[str], None] | None = None, data: dict[str, np.ndarray] | None = None,
                  true_errors: dict[str, float] | None = None, **options: Any) -> BenchmarkResult:
    """Identify from the training record (:func:`identify`) and score both test records."""
    data = load_benchmark(path) if data is None else data
    model, stages, t = identify(data, seed=seed, bounds_scale=bounds_scale, on_step=on_step, **options)
    say = on_step or (lambda s: None)
    say("simulating the test records")
    pso_model = stages["pso"].pop("model")
    if true_errors is None:
        tests, pso_tests, true_errors = _simulations([model, pso_model, TRUE], data)
    else:
        tests, pso_tests = _simulations([model, pso_model], data)
    stages["pso"]["test_rmse_m"] = pso_tests
    train = float(np.sqrt(np.mean((model.simulate(data["u"], FS) - data["y"]) ** 2)))
    return BenchmarkResult(model=model, stages=stages, test_rmse=tests, true_model_test_rmse=true_errors,
                           train_rmse=train, time_s=t, data=str(path), seed=int(seed),
                           bounds_scale=float(bounds_scale))


def run_benchmarks(path: str | Path, *, seeds: Sequence[int] = (0,), bounds_scales: Sequence[float] = (1.0,),
                   on_step: Callable[[str], None] | None = None, **options: Any) -> list[BenchmarkResult]:
    """:func:`run_benchmark` for every bounds scale and seed (the data read once)."""
    data = load_benchmark(path)
    say = on_step or (lambda s: None)
    out: list[BenchmarkResult] = []
    truth: dict[str, float] | None = None
    def tagged(tag: str) -> Callable[[str], None]:
        return lambda s: say(tag + s)

    for scale in bounds_scales:
        for seed in seeds:
            res = run_benchmark(path, seed=seed, bounds_scale=scale, data=data, true_errors=truth,
                                on_step=tagged(f"bounds x{scale:g}, seed {seed}: "), **options)
            truth = res.true_model_test_rmse
            out.append(res)
    return out


def summary(results: Sequence[BenchmarkResult]) -> list[dict[str, Any]]:
    """Per bounds scale: runs, how many beat the best published multisine error, worst and median."""
    out = []
    for scale in sorted({r.bounds_scale for r in results}):
        errs = [r.test_rmse["multisine"] for r in results if r.bounds_scale == scale]
        out.append({"bounds_scale": scale, "runs": len(errs), "below_best_published": int(sum(e < BEST_PUBLISHED for e in errs)),
                    "median_multisine_rmse_m": float(np.median(errs)), "worst_multisine_rmse_m": float(max(errs))})
    return out
