"""Small plants for tests: each follows the Plant protocol (dt, reset(), step(u) -> y)."""

import math


class PIPlant:
    """A plant that *is* a P-I model (no dynamics, no noise)."""

    def __init__(self, model, dt=1e-3):
        self.model = model
        self.dt = dt
        self.reset()

    def reset(self):
        self._s = self.model.stepper()

    def step(self, u):
        return self._s.step(u)


class QuasiStaticBoucWenPlant:
    """d1 u - h of a Bouc-Wen model (µm), no dynamics."""

    def __init__(self, model, dt=1e-3):
        from piezohyst.models.bouc_wen import bw_h_update

        self.model = model
        self.dt = dt
        self._upd = bw_h_update
        self.reset()

    def reset(self):
        self._u = 0.0
        self._h = self.model.h0

    def step(self, u):
        m = self.model
        self._h = self._upd(self._h, u - self._u, m.alpha * m.d1, m.beta, m.gamma)
        self._u = u
        return (m.d1 * u - self._h + m.offset) * 1e6


class FirstOrderPlant:
    """y' = (K u - y) / tau, exact discretisation; optional constant disturbance."""

    def __init__(self, gain=2.0, tau=0.05, dt=1e-3, disturbance=0.0):
        self.gain, self.tau, self.dt, self.disturbance = gain, tau, dt, disturbance
        self._a = math.exp(-dt / tau)
        self.reset()

    def reset(self):
        self.y = 0.0

    def step(self, u):
        self.y = self._a * self.y + (1 - self._a) * (self.gain * u + self.disturbance)
        return self.y


class UnboundedIntegrator:
    """y' = u: an integrator, unstable under too much delay/gain."""

    def __init__(self, dt=1e-3):
        self.dt = dt
        self.reset()

    def reset(self):
        self.y = 0.0
        self._prev = [0.0, 0.0]

    def step(self, u):
        # two samples of delay make high gains unstable
        self._prev.append(u)
        self.y += self.dt * self._prev.pop(0) * 1000.0
        return self.y
