"""Stages for the tests of wave-table plants, safe commissioning and export; none of them is
the VirtualRig, and nothing in piezohyst was tuned on them.

* :class:`MaxwellSlipStage` - hysteresis of Maxwell-slip elements (elastic-slide elements with
  asymmetric slip limits) and a constant stiffness, through an amplifier lag, a smooth asymmetric
  saturation of the output, a slow creep lag, sensor noise and a delay of 5 samples; 5 kHz, a
  -20..150 V amplifier. ``buffered=True`` gives an object with only ``dt``, ``u_range`` and
  ``play(u)`` (a wave-table controller: the state carries over between plays).
* :class:`ResonantStage` - a per-sample stage whose mechanics have a resonance the slow
  identification experiment cannot see (second order, exact discretisation), after play-operator
  hysteresis of its own thresholds; 10 kHz, 0..100 V, delay 2 samples.
* :class:`ButterflyStage` - play operators plus electrostriction on a bipolar range, not monotone
  near its negative end (5 kHz, -60..60 V).
* :class:`Recorder` - wraps either protocol and records every command the stage receives.
"""

import math

import numpy as np


class _MaxwellSlipCore:
    def __init__(self, dt, seed, delay=5, noise_um=0.002):
        self.dt = dt
        rng = np.random.default_rng(1000 + seed)
        n = 12
        self.k = 0.004 + 0.004 * rng.random(n)          # µm/V of each element
        self.up = np.linspace(2.0, 60.0, n)              # slip limits, V (asymmetric)
        self.down = 0.6 * self.up
        self.k0 = 0.035                                  # the elastic part, µm/V
        self.a_amp = math.exp(-dt / 0.0005)
        self.a_creep = math.exp(-dt / 0.4)
        self.delay = delay
        self.noise = noise_um
        self.rng = np.random.default_rng(seed)
        self.s = 12.0                                    # saturation scale, µm
        self.y0 = 3.0
        self.v = 0.0
        self.d = np.zeros(n)
        self.c = 0.0
        self.line = [0.0] * delay
        self.u_range = (-20.0, 150.0)

    def _sat(self, x):
        return self.s * (math.tanh((x - self.y0) / self.s) + math.tanh(self.y0 / self.s))

    def sample(self, u):
        lo, hi = self.u_range
        u = min(max(u, lo), hi)
        v_new = self.a_amp * self.v + (1.0 - self.a_amp) * u
        dv = v_new - self.v
        self.v = v_new
        self.d = np.minimum(np.maximum(self.d + dv, -self.down), self.up)
        raw = self.k0 * v_new + float(self.k @ self.d)
        self.c = self.a_creep * self.c + (1.0 - self.a_creep) * raw
        y = self._sat(raw) + 0.04 * self.c + self.noise * self.rng.standard_normal()
        if not self.delay:
            return y
        self.line.append(y)
        return self.line.pop(0)


class MaxwellSlipStage:
    """See the module docstring; ``dt``, ``u_range`` and ``play`` only."""

    def __init__(self, seed=0, dt=2e-4):
        self._core = _MaxwellSlipCore(dt, seed)
        self.dt = dt
        self.u_range = self._core.u_range

    def play(self, u):
        u = np.asarray(u, dtype=float)
        return np.array([self._core.sample(float(v)) for v in u])


class ResonantStage:
    """See the module docstring (the Plant protocol: ``reset`` and ``step``)."""

    def __init__(self, seed=0, dt=1e-4, f_res=700.0, zeta=0.03, delay=2, noise_um=0.002):
        from scipy.linalg import expm

        self.dt = dt
        self.u_range = (0.0, 100.0)
        self.seed = seed
        self.r = np.array([0.0, 4.0, 9.0, 15.0, 22.0, 30.0, 40.0])
        self.w = np.array([0.012, 0.006, 0.005, 0.004, 0.003, 0.002, 0.002])
        wn = 2 * math.pi * f_res
        a = np.array([[0.0, 1.0, 0.0], [-wn * wn, -2 * zeta * wn, wn * wn], [0.0, 0.0, 0.0]]) * dt
        e = expm(a)
        self._phil = e[:2, :2].tolist()
        self._gaml = e[:2, 2].tolist()
        self._r = self.r.tolist()
        self._w = self.w.tolist()
        self.delay = delay
        self.noise = noise_um
        self.reset()

    def reset(self):
        self.z = [0.0] * self.r.size
        self.x0 = 0.0
        self.x1 = 0.0
        self.line = [0.0] * self.delay
        self.rng = np.random.default_rng(self.seed)
        self._noise = iter(())

    def _next_noise(self):
        try:
            return next(self._noise)
        except StopIteration:
            self._noise = iter(self.rng.standard_normal(4096).tolist())
            return next(self._noise)

    def step(self, u):
        lo, hi = self.u_range
        u = min(max(float(u), lo), hi)
        f = 0.0
        z = self.z
        for i, (ri, wi) in enumerate(zip(self._r, self._w)):
            zi = min(max(z[i], u - ri), u + ri)
            z[i] = zi
            f += wi * zi
        (p00, p01), (p10, p11) = self._phil
        g0, g1 = self._gaml
        x0 = p00 * self.x0 + p01 * self.x1 + g0 * f
        self.x1 = p10 * self.x0 + p11 * self.x1 + g1 * f
        self.x0 = x0
        y = x0 + self.noise * self._next_noise()
        if not self.delay:
            return y
        self.line.append(y)
        return self.line.pop(0)


class ButterflyStage:
    """Play-operator hysteresis plus electrostriction, ``y = P[v] + c v^2``, on a bipolar -60..60 V
    range: below about -36 V more command gives less displacement on the branch rising from the
    bottom (the butterfly loop of a stack driven too far negative). An amplifier lag, one sample
    of delay, noise; 5 kHz. Not monotone over its own ``u_range``."""

    def __init__(self, seed=0, dt=2e-4, delay=1, noise_um=0.001):
        self.dt = dt
        self.u_range = (-60.0, 60.0)
        self.seed = seed
        self._r = np.linspace(0.0, 36.0, 10).tolist()
        w = np.linspace(1.0, 0.3, 10)
        self._w = (w / w.sum() * 0.7 * 8.0 / 60.0).tolist()
        self.c = 0.3 * 8.0 / 60.0**2
        self.a_amp = math.exp(-dt / 2e-4)
        self.delay = delay
        self.noise = noise_um
        self.reset()

    def reset(self):
        self.z = [0.0] * len(self._r)
        self.v = 0.0
        self.line = [0.0] * self.delay
        self.rng = np.random.default_rng(self.seed)

    def step(self, u):
        lo, hi = self.u_range
        self.v = self.a_amp * self.v + (1.0 - self.a_amp) * min(max(float(u), lo), hi)
        v, f, z = self.v, 0.0, self.z
        for i, (ri, wi) in enumerate(zip(self._r, self._w)):
            z[i] = min(max(z[i], v - ri), v + ri)
            f += wi * z[i]
        y = f + self.c * v * v + self.noise * float(self.rng.standard_normal())
        if not self.delay:
            return y
        self.line.append(y)
        return self.line.pop(0)


class Recorder:
    """Every command a stage receives, in order, with the resets (a reset puts the stage at rest, 0 V)."""

    def __init__(self, plant, rest=0.0):
        self._p = plant
        self.dt = plant.dt
        self.u_range = plant.u_range
        self.rest = rest
        self.commands = [rest]
        if hasattr(plant, "step"):
            self.step = self._step
            self.reset = self._reset
        if hasattr(plant, "play"):
            self.play = self._play

    def _reset(self):
        self._p.reset()
        self.commands.append(self.rest)  # a reset brings the stage back to rest

    def _step(self, u):
        self.commands.append(float(u))
        return self._p.step(u)

    def _play(self, u):
        self.commands.extend(float(v) for v in np.asarray(u, dtype=float))
        return self._p.play(u)

    def largest_step(self):
        return float(np.max(np.abs(np.diff(np.asarray(self.commands)))))

    def outside(self):
        c = np.asarray(self.commands)
        lo, hi = self.u_range
        return int(np.sum((c < lo) | (c > hi)))
