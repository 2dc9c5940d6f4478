"""The virtual piezo test rig: the paper's set-up (Section III-A), simulated, as the default plant.

The paper's rig is a Piezomechanik PSt500/10/25 stack driving a flexure, a load cell calibrated
to displacement with a laser interferometer, and a PC with D/A and A/D. :class:`VirtualRig`
simulates that chain, sample by sample, from the command voltage to the number the A/D returns:

1. **Amplifier** - the command is clipped to the amplifier's range (default 0-100 V, the
   paper's input span); every clipped sample is counted and reported. The stack voltage then
   follows the command through a first-order lag ``amp_tau`` (amplifier output impedance times
   stack capacitance).
2. **Hysteresis** - the paper's identified Bouc-Wen state h, eq. (8), exact per increment.
3. **Rate dependence and creep** - what the paper's models leave out and a real stack has: a
   chain of Kelvin-Voigt elements, each a first-order lag ``tau_i`` with compliance ``gain_i``
   (relative to d1), driven by the piezoelectric strain ``d1 u``. The short ones widen the loop
   as the frequency rises (the paper's Fig. 2); the long ones make the output creep after a
   step, roughly logarithmically in time as real stacks do.
4. **Mechanics** - the paper's m, b, k of eq. (7) (a lightly damped 1.7 kHz resonance),
   discretised exactly, driven by ``d1 u - h + sum_i gain_i d1 z_i``.
5. **Sensor** - calibration gain (1: calibrated), additive Gaussian noise ``noise_rms_um``,
   quantisation by an ``adc_bits`` A/D over ``sensor_range_um``, and ``delay_samples`` of delay
   (the value read at step k is the displacement of step k - delay).

Defaults and why (the figures they give are checked in ``tests/test_rig.py``):

=====================  ==============================  =================================================
parameter              default                         why
=====================  ==============================  =================================================
dt                     1e-4 s                          10 kHz, a common rate for piezo control loops
m, b, k, d1, alpha,    paper Section III-B             the paper's identified model of its own rig
beta, gamma
u_min, u_max           0, 100 V                        the paper's input span [0, 100]
amp_tau                0.8 ms                          ~200 Hz amplifier/stack bandwidth, typical for a
                                                       µF stack on a laboratory amplifier
kv_tau                 (0.01, 0.3, 3, 30) s            one short element for rate dependence, three
                                                       for creep from 0.1 s to tens of seconds
kv_gain                (0.20, 0.02, 0.02, 0.02)        1 Hz loop 14.2 % of span, 1.43x as wide at 5 Hz
                                                       (Fig. 2); 3.6 % creep from 0.1 s to 10 s
creep_scale            1                               multiplies the three creep gains (variants)
noise_rms_um           0.003 µm                        "a few nm RMS" for a load cell + amplifier
adc_bits, range        16 bits over -1 .. 4 µm         a 16-bit A/D over the calibrated range
sensor_gain            1                               calibrated with the interferometer
delay_samples          1                               one sample of A/D and computation delay
=====================  ==============================  =================================================
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

from . import paper_values as pv
from ._numba import njit
from ._validation import FloatArray, as_scalar, as_signal
from .data import Dataset
from .models.bouc_wen import bw_h_update, bw_params, mech_step
from .plant import BufferedPlant, Plant, open_loop  # noqa: F401  (Plant and open_loop lived here)


class ClippingWarning(UserWarning):
    """Commands left the amplifier's range and were clipped."""


@dataclass(frozen=True)
class RigSettings:
    """Every parameter of :class:`VirtualRig`; see the module docstring for defaults and reasons."""

    dt: float = 1e-4
    m: float = pv.BOUC_WEN["m"]
    b: float = pv.BOUC_WEN["b"]
    k: float = pv.BOUC_WEN["k"]
    d1: float = pv.BOUC_WEN["d1"]
    alpha: float = pv.BOUC_WEN["alpha"]
    beta: float = pv.BOUC_WEN["beta"]
    gamma: float = pv.BOUC_WEN["gamma"]
    u_min: float = 0.0
    u_max: float = 100.0
    amp_tau: float = 8e-4
    kv_tau: tuple[float, ...] = (0.01, 0.3, 3.0, 30.0)
    kv_gain: tuple[float, ...] = (0.20, 0.02, 0.02, 0.02)
    creep_scale: float = 1.0
    noise_rms_um: float = 0.003
    adc_bits: int = 16
    sensor_range_um: tuple[float, float] = (-1.0, 4.0)
    sensor_gain: float = 1.0
    delay_samples: int = 1

    def __post_init__(self) -> None:
        for name in ("dt", "m", "k", "d1"):
            as_scalar(name, getattr(self, name), positive=True)
        for name in ("b", "amp_tau", "noise_rms_um", "creep_scale"):
            as_scalar(name, getattr(self, name), nonnegative=True)
        for name in ("alpha", "beta", "gamma", "sensor_gain", "u_min", "u_max"):
            as_scalar(name, getattr(self, name))
        # (found by fuzzing: settings of the wrong type failed with Python's own words, "'<=' not
        # supported between ...", "too many values to unpack"; adc_bits=true was a 1-bit converter)
        for name in ("kv_tau", "kv_gain", "sensor_range_um"):
            v = getattr(self, name)
            if isinstance(v, (str, bytes)) or not isinstance(v, (tuple, list)):
                raise ValueError(f"{name} must be a list of numbers, got {v!r}")
            for i, x in enumerate(v):
                as_scalar(f"{name}[{i}]", x)
        if len(self.sensor_range_um) != 2:
            raise ValueError(f"sensor_range_um must be (low, high), got {list(self.sensor_range_um)}")
        for name in ("adc_bits", "delay_samples"):
            if isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be an integer, got {getattr(self, name)!r}")
        if not self.beta + self.gamma > 0:
            # (gamma=-0.5 made a loop that grows without bound and pinned the sensor at its ends,
            # without a word; the Bouc-Wen model refuses such parameters as well)
            raise ValueError(f"beta + gamma must be > 0 for a bounded loop, got beta={self.beta:g}, gamma={self.gamma:g}")
        if self.u_max <= self.u_min:
            raise ValueError(f"u_max must be greater than u_min, got {self.u_min}..{self.u_max}")
        if len(self.kv_tau) != len(self.kv_gain):
            raise ValueError(f"kv_tau and kv_gain must have the same length, got {len(self.kv_tau)} and {len(self.kv_gain)}")
        if any(t <= 0 for t in self.kv_tau):
            raise ValueError(f"kv_tau must all be > 0, got {self.kv_tau}")
        if any(g < 0 for g in self.kv_gain):
            raise ValueError(f"kv_gain must all be >= 0, got {self.kv_gain}")
        if not (isinstance(self.adc_bits, int) and 1 <= self.adc_bits <= 32):
            raise ValueError(f"adc_bits must be an integer in 1..32, got {self.adc_bits!r}")
        lo, hi = self.sensor_range_um
        if hi <= lo:
            raise ValueError(f"sensor_range_um must be (low, high) with low < high, got {self.sensor_range_um}")
        if not (isinstance(self.delay_samples, int) and 0 <= self.delay_samples <= 1000):
            raise ValueError(f"delay_samples must be an integer in 0..1000, got {self.delay_samples!r}")

    def effective_gains(self) -> FloatArray:
        """Kelvin-Voigt gains with ``creep_scale`` applied to the creep (all but the first) elements."""
        g = np.array(self.kv_gain, dtype=np.float64)
        if g.size > 1:
            g[1:] *= self.creep_scale
        return g

    def to_dict(self) -> dict[str, Any]:
        """The settings as plain data (what ``--rig-settings`` files hold)."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RigSettings":
        """Settings from plain data; unknown names are refused, missing ones take their defaults."""
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown rig setting(s) {sorted(unknown)}; the settings are {sorted(names)}")
        conv: dict[str, Any] = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()}
        return cls(**conv)


# state vector layout: [v_prev, h, x, w, f_prev, clip_count, z_1..z_n]
_NS = 6


@njit
def _rig_step(p: FloatArray, kv_a: FloatArray, kv_g: FloatArray, amp_a: float, st: FloatArray,
              line: FloatArray, consts: FloatArray, u: float, noise: float) -> float:  # pragma: no cover
    """One sample of the rig. ``consts = [u_min, u_max, gain, noise_rms, q, lo, hi, delay]``."""
    if u < consts[0]:
        u = consts[0]
        st[5] += 1.0
    elif u > consts[1]:
        u = consts[1]
        st[5] += 1.0
    v_prev = st[0]
    v = amp_a * v_prev + (1.0 - amp_a) * u
    h = bw_h_update(st[1], v - v_prev, p[1], p[2], p[3])
    st[0] = v
    st[1] = h
    strain = p[0] * v
    f = strain - h
    for i in range(kv_a.shape[0]):
        zi = kv_a[i] * st[_NS + i] + (1.0 - kv_a[i]) * strain
        st[_NS + i] = zi
        f += kv_g[i] * zi
    x_um = mech_step(p, st, f) * 1e6
    y = consts[2] * x_um + consts[3] * noise
    q = consts[4]
    lo = consts[5]
    y = lo + math.floor((y - lo) / q + 0.5) * q
    if y < lo:
        y = lo
    elif y > consts[6]:
        y = consts[6]
    d = int(consts[7])
    if d == 0:
        return y
    out = line[0]
    for i in range(d - 1):
        line[i] = line[i + 1]
    line[d - 1] = y
    return out


@njit
def _rig_run(p: FloatArray, kv_a: FloatArray, kv_g: FloatArray, amp_a: float, st: FloatArray,
             line: FloatArray, consts: FloatArray, u: FloatArray, noise: FloatArray) -> FloatArray:  # pragma: no cover
    out = np.empty(u.shape[0])
    for k in range(u.shape[0]):
        out[k] = _rig_step(p, kv_a, kv_g, amp_a, st, line, consts, u[k], noise[k])
    return out


class VirtualRig:
    """A simulated piezo-stack rig (the paper's Section III-A).

    It follows both plant protocols (:mod:`piezohyst.plant`): :class:`Plant` (``reset()``,
    ``step(u)``, a per-sample loop) and :class:`BufferedPlant` (``play(table)``, a wave-table
    controller: the table runs from the rig's present state, which carries over to the next play).

    Parameters
    ----------
    settings : RigSettings, optional
        All parameters (defaults: the module docstring's table).
    seed : int
        Seed of the sensor noise; the same seed gives the same run, another seed changes only
        the noise.
    **overrides
        Any :class:`RigSettings` field, e.g. ``VirtualRig(gamma=0.02, creep_scale=2)``.

    Examples
    --------
    >>> import piezohyst as ph
    >>> rig = ph.VirtualRig(seed=0)
    >>> ds = rig.excite(ph.sinusoid(1.0, 2, 0.0, 100.0, rig.dt))
    >>> 1.9 < ph.loop_figures(ds.u, ds.y).span < 2.4
    True
    """

    def __init__(self, settings: RigSettings | None = None, *, seed: int | None = 0, **overrides: Any):
        base = settings if settings is not None else RigSettings()
        self.settings = replace(base, **overrides) if overrides else base
        if seed is not None and (isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer))
                                 or seed < 0):
            # (seed="a" failed eight frames deep in numpy: found by a helper)
            raise ValueError(f"seed must be a whole number >= 0 or None, got {seed!r}")
        self.seed = seed
        s = self.settings
        self.dt = float(s.dt)
        self._p = bw_params(s.m, s.b, s.k, s.d1, s.alpha, s.beta, s.gamma, 0.0, s.dt, True)
        self._kv_a = np.exp(-s.dt / np.array(s.kv_tau, dtype=np.float64))
        self._kv_g = s.effective_gains()
        self._amp_a = math.exp(-s.dt / s.amp_tau) if s.amp_tau > 0 else 0.0
        lo, hi = s.sensor_range_um
        q = (hi - lo) / (2**s.adc_bits)
        self._consts = np.array([s.u_min, s.u_max, s.sensor_gain, s.noise_rms_um, q, lo, hi,
                                 float(s.delay_samples)])
        self.reset()

    # -- the Plant protocol -----------------------------------------------------------------
    def reset(self) -> None:
        """At rest, de-energised; the noise generator restarts from the seed."""
        self._st = np.zeros(_NS + self._kv_a.size)
        # the delay line holds what the A/D read at rest: zero displacement, quantised
        lo, q = self._consts[5], self._consts[4]
        self._line = np.full(max(self.settings.delay_samples, 1), lo + math.floor(-lo / q + 0.5) * q)
        self._rng = np.random.default_rng(self.seed)
        self._n = 0

    def step(self, u: float) -> float:
        """Apply ``u`` volts for one sample; return the measured displacement, µm."""
        x = float(u)
        if not math.isfinite(x):
            raise ValueError(f"the command must be finite, got {u!r}")
        self._n += 1
        return float(_rig_step(self._p, self._kv_a, self._kv_g, self._amp_a, self._st, self._line,
                               self._consts, x, self._rng.standard_normal()))

    # -- whole runs -------------------------------------------------------------------------
    @property
    def u_range(self) -> tuple[float, float]:
        """The amplifier's range, V (lets a loop's anti-windup see the saturation)."""
        return (self.settings.u_min, self.settings.u_max)

    @property
    def clipped(self) -> int:
        """Commands clipped to the amplifier's range since the last reset."""
        return int(self._st[5])

    @property
    def samples(self) -> int:
        """Samples applied since the last reset."""
        return self._n

    def run(self, u: Any) -> FloatArray:
        """Apply a whole command signal from the current state (compiled); return y, µm."""
        x = as_signal("u", u)
        noise = self._rng.standard_normal(x.size)
        self._n += x.size
        return _rig_run(self._p, self._kv_a, self._kv_g, self._amp_a, self._st, self._line,
                        self._consts, x, noise)

    def play(self, u: Any) -> FloatArray:
        """The :class:`~piezohyst.plant.BufferedPlant` protocol: apply the command table ``u``
        (V, one value per ``dt``) from the rig's present state, which carries over to the next
        play; return the measured displacement, µm (compiled; the same as :meth:`run`)."""
        return self.run(u)

    def excite(self, u: Any, *, reset: bool = True) -> Dataset:
        """An open-loop run from rest: the :class:`Dataset` (t s, u V, y µm) a user would record.

        Commands outside the amplifier's range are clipped; the count is in
        ``meta["clipped_samples"]`` and a :class:`ClippingWarning` says so.
        """
        if reset:
            self.reset()
        before = self.clipped
        y = self.run(u)
        clipped = self.clipped - before
        x = np.asarray(u, dtype=np.float64)
        if clipped:
            warnings.warn(
                f"{clipped} of {x.size} commands were outside the amplifier range "
                f"{self.settings.u_min:g}..{self.settings.u_max:g} V and were clipped",
                ClippingWarning, stacklevel=2,
            )
        meta = {"source": "VirtualRig", "seed": self.seed, "clipped_samples": clipped,
                "rig": self.settings.to_dict()}
        return Dataset(np.arange(x.size, dtype=np.float64) * self.dt, x, y, meta)

    def __repr__(self) -> str:
        s = self.settings
        return (f"VirtualRig(dt={s.dt}, seed={self.seed}, u={s.u_min:g}..{s.u_max:g} V, "
                f"noise={s.noise_rms_um * 1e3:g} nm, gamma={s.gamma}, creep_scale={s.creep_scale})")
