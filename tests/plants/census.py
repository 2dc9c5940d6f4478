"""A census of piezo-like stages of yet other structures, written after the zoo (issue 11).

The zoo (:mod:`tests.plants.zoo`) is what the tests commission; these stages were written on
2026-11-27 to see whether what the zoo shows carries over to structures nobody here had tried,
and their figures are printed by ``python benchmarks/census_table.py`` (the README's second zoo
table). Each stage is the zoo's chain (:class:`~tests.plants.zoo.Stage`: amplifier lag,
Kelvin-Voigt rate and creep elements, a resonance, noise, delay) around one of these elements:

* :class:`KrasnoselskiiPokrovskii` - a 30-level grid of ramp hysterons of finite width (6 % of the
  range), a density centred on the range, plus a reversible slope;
* :class:`BoucWenExponent` - Bouc-Wen with an exponent ``n`` other than one (sharper or softer
  saturation of the hysteretic state than the paper's, sub-stepped);
* :class:`QuadraticOutput` - play operators into a stiffening quadratic output (an
  electrostrictive-like curvature over a unipolar range);
* :class:`DahlLoop` - Dahl's model, ``dz = c dv (1 - z sgn dv)^alpha``, entering the output with
  a minus sign (a counterclockwise loop, flat just after each reversal, as a piezo's);
* :class:`SaturatedPI` - play operators through an exponential output saturation (Kuhnen's
  structure; a top slope 35 % of the bottom's).

The numbers were chosen once, as plausible stages, before any of them was commissioned; nothing
in the project is tuned on them. Two elements written at the same time are not here: a Dahl loop
with the hysteretic part added (a clockwise loop, the output leading the input: not a piezo's),
and P-I operators with weights linear in the input's rate (Ang et al.), whose output goes on
rising after the top reversals (``commission`` reports it as not monotone there, with the range
where it is).
"""

from __future__ import annotations

import math

import numpy as np

from .zoo import Stage


class KrasnoselskiiPokrovskii:
    """Ramp hysterons (width ``a_frac`` of the range) on an ``n``-level grid over 0..v_max."""

    def __init__(self, v_max: float, stroke_um: float, n: int = 30, a_frac: float = 0.06):
        g = np.linspace(0.0, v_max, n)
        ai, bi = np.tril_indices(n)
        keep = ai > bi
        self.alpha, self.beta = g[ai][keep], g[bi][keep]
        self.a = a_frac * v_max
        centre, half = 0.5 * (self.alpha + self.beta), 0.5 * (self.alpha - self.beta)
        dens = np.exp(-((centre - 0.5 * v_max) / (0.4 * v_max)) ** 2) * np.exp(-half / (0.15 * v_max))
        self.mu = dens / dens.sum() * 0.5 * stroke_um
        self.slope = 0.5 * stroke_um / v_max
        self.reset()

    def reset(self) -> None:
        self.z = -np.ones(self.alpha.size)

    def step(self, v: float) -> float:
        up = np.clip(2.0 * (v - self.alpha) / self.a + 1.0, -1.0, 1.0)
        down = np.clip(2.0 * (v - self.beta) / self.a - 1.0, -1.0, 1.0)
        self.z = np.minimum(np.maximum(self.z, up), down)
        return float(self.mu @ self.z) + self.slope * v


class BoucWenExponent:
    """``y = d v - h``, ``dh = alpha d dv - beta |dv| sgn(h) |h|^n d^(1-n) - gamma dv |h|^n d^(1-n)``
    (h in µm, v in V), sub-stepped at 0.05 V."""

    def __init__(self, v_max: float, stroke_um: float, n: float = 2.0, alpha: float = 0.4,
                 beta_v: float = 3.0, gamma_v: float = 1.0):
        self.d = stroke_um / v_max
        self.n, self.alpha = n, alpha
        self.beta, self.gamma = beta_v / v_max, gamma_v / v_max
        self.reset()

    def reset(self) -> None:
        self.h, self.v = 0.0, 0.0

    def step(self, v: float) -> float:
        dv = v - self.v
        k = max(1, int(abs(dv) / 0.05) + 1)
        s = dv / k
        for _ in range(k):
            hn = (abs(self.h) / self.d) ** self.n * self.d
            self.h += self.alpha * self.d * s - self.beta * abs(s) * math.copysign(hn, self.h) - self.gamma * s * hn
        self.v = v
        return self.d * v - self.h


class QuadraticOutput:
    """Play operators (thresholds up to 30 % of the range) into ``p + c p^2 (1 + c) / stroke``."""

    def __init__(self, v_max: float, stroke_um: float, n: int = 8, c: float = 0.8):
        self.r = np.linspace(0.0, 0.3 * v_max, n)
        w = np.linspace(1.0, 0.3, n)
        self.w = w / w.sum() * stroke_um / v_max / (1.0 + c)
        self.c, self.stroke = c, stroke_um
        self.reset()

    def reset(self) -> None:
        self.z = np.zeros(self.r.size)

    def step(self, v: float) -> float:
        self.z = np.minimum(np.maximum(self.z, v - self.r), v + self.r)
        p = float(self.w @ self.z)
        return p + self.c * p * p * (1.0 + self.c) / self.stroke


class DahlLoop:
    """``y = stroke (x - share z) / (1 + share)``, ``x = v / v_max``, ``dz = c dx (1 - z sgn dx)^alpha``."""

    def __init__(self, v_max: float, stroke_um: float, alpha: float = 2.0, share: float = 0.3, c: float = 1.4):
        self.v_max, self.stroke, self.alpha, self.share, self.c = v_max, stroke_um, alpha, share, c
        self.reset()

    def reset(self) -> None:
        self.z, self.v = 0.0, 0.0

    def step(self, v: float) -> float:
        dx = (v - self.v) / self.v_max
        self.v = v
        if dx:
            s = 1.0 if dx > 0 else -1.0
            self.z = min(max(self.z + self.c * dx * max(1.0 - s * self.z, 0.0) ** self.alpha, -1.0), 1.0)
        return self.stroke * (v / self.v_max - self.share * self.z) / (1.0 + self.share)


class SaturatedPI:
    """Play operators (thresholds up to half the range) through ``(1 - exp(-k p)) / (1 - exp(-k))``,
    ``k = -ln(top)``: the top of the range ``top`` times as steep as the bottom."""

    def __init__(self, v_max: float, stroke_um: float, n: int = 8, top: float = 0.35):
        self.v_max, self.stroke = v_max, stroke_um
        self.r = np.linspace(0.0, 0.5, n, endpoint=False) * v_max
        w = np.linspace(1.0, 0.3, n)
        self.w = w / w.sum()
        self.k = -math.log(top)
        self.reset()

    def reset(self) -> None:
        self.z = np.zeros(self.r.size)

    def step(self, v: float) -> float:
        self.z = np.maximum(v - self.r, np.minimum(v + self.r, self.z))
        p = float(self.w @ self.z) / self.v_max
        return self.stroke * (1.0 - math.exp(-self.k * p)) / (1.0 - math.exp(-self.k))


class JilesAthertonLike:
    """The Jiles-Atherton structure (with its mean-field coupling left out, ``alpha = 0``): an
    irreversible part ``z`` that moves towards the anhysteretic curve ``an(v)`` (a ``tanh`` of
    steepness ``b`` over the range) only while the input moves that way,
    ``dz = (an(v) - z) |dx| / k`` if ``(an(v) - z) dx > 0`` else 0 (``x = v`` over the range:
    the usual fix that keeps the susceptibility positive), plus a reversible share ``c``:
    ``y = stroke (c an(v) + (1 - c) z)``. Its minor loops do not close: cycled between two inputs
    inside the range, the loop climbs from cycle to cycle (accommodation) instead of returning to
    its turning points, which neither a Preisach nor a P-I model can do. Written after the zoo,
    the census and every default, for ``tests/test_accommodation.py``."""

    def __init__(self, v_lo: float, v_hi: float, stroke_um: float, k: float = 0.2, c: float = 0.4, b: float = 1.8):
        self.lo, self.hi, self.stroke, self.k, self.c, self.b = v_lo, v_hi, stroke_um, k, c, b
        self.reset()

    def anhysteretic(self, v: float) -> float:
        x = 2.0 * (v - self.lo) / (self.hi - self.lo) - 1.0
        return 0.5 * (1.0 + math.tanh(self.b * x) / math.tanh(self.b))

    def reset(self) -> None:
        self.v = min(max(0.0, self.lo), self.hi)
        self.z = self.anhysteretic(self.v)

    def step(self, v: float) -> float:
        dx = (v - self.v) / (self.hi - self.lo)
        self.v = v
        an = self.anhysteretic(v)
        if (an - self.z) * dx > 0.0:
            self.z += (an - self.z) * abs(dx) / self.k
        return self.stroke * (self.c * an + (1.0 - self.c) * self.z)


def jiles_atherton_stage(seed: int = 0) -> Stage:
    """A stage around :class:`JilesAthertonLike`, in the census's chain (not one of its seven)."""
    return Stage("Jiles-Atherton (no return-point memory), 10 kHz, 0..150 V, 10 um, delay 2",
                 JilesAthertonLike(0.0, 150.0, 10.0), 1e-4, (0.0, 150.0), tau_amp=2e-4, kv=((0.05, 0.01),),
                 fn_hz=2500.0, zeta=0.05, noise_um=0.003, delay_samples=2, seed=21 + seed)


def census(seed: int = 0) -> list[Stage]:
    """The seven census stages (module docstring); ``seed`` adds to each stage's noise seed."""
    return [
        Stage("Krasnosel'skii-Pokrovskii, 10 kHz, 0..100 V, 20 um, delay 1", KrasnoselskiiPokrovskii(100.0, 20.0),
              1e-4, (0.0, 100.0), tau_amp=2e-4, kv=((0.05, 0.02), (0.02, 2.0)), fn_hz=2000.0, zeta=0.05,
              noise_um=0.005, delay_samples=1, seed=11 + seed),
        Stage("Bouc-Wen n = 2, 5 kHz, 0..150 V, 60 um, delay 3", BoucWenExponent(150.0, 60.0, n=2.0), 2e-4,
              (0.0, 150.0), tau_amp=3e-4, kv=((0.06, 0.01),), fn_hz=1200.0, zeta=0.04, noise_um=0.015,
              delay_samples=3, seed=12 + seed),
        Stage("Bouc-Wen n = 0.5, 20 kHz, -50..50 V, 8 um, delay 4",
              BoucWenExponent(100.0, 8.0, n=0.5, beta_v=1.5, gamma_v=0.5), 5e-5, (-50.0, 50.0), tau_amp=1e-4,
              kv=((0.04, 0.005),), fn_hz=5000.0, zeta=0.05, noise_um=0.002, delay_samples=4, seed=13 + seed),
        Stage("quadratic output, 2 kHz, 0..120 V, 15 um, delay 0", QuadraticOutput(120.0, 15.0), 5e-4, (0.0, 120.0),
              kv=((0.08, 0.05),), fn_hz=700.0, zeta=0.08, noise_um=0.004, delay_samples=0, seed=14 + seed),
        Stage("Dahl exponent 2, 5 kHz, -50..100 V, 25 um, delay 2", DahlLoop(100.0, 25.0, alpha=2.0), 2e-4,
              (-50.0, 100.0), tau_amp=2e-4, kv=((0.05, 0.02),), fn_hz=1500.0, zeta=0.06, noise_um=0.005,
              delay_samples=2, seed=5 + seed),
        Stage("Dahl exponent 0.5, 10 kHz, 0..150 V, 40 um, delay 1",
              DahlLoop(150.0, 40.0, alpha=0.5, share=0.5, c=0.9), 1e-4, (0.0, 150.0), tau_amp=3e-4,
              kv=((0.05, 0.05),), fn_hz=2500.0, zeta=0.05, noise_um=0.008, delay_samples=1, seed=6 + seed),
        Stage("saturated P-I, 10 kHz, 0..100 V, 12 um, delay 3", SaturatedPI(100.0, 12.0), 1e-4, (0.0, 100.0),
              tau_amp=3e-4, kv=((0.04, 0.05),), fn_hz=2200.0, zeta=0.05, noise_um=0.003, delay_samples=3,
              seed=4 + seed),
    ]
