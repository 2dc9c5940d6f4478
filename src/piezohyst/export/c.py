"""The compensator as C99 for a DSP, an FPGA's soft core or a microcontroller.

:func:`generate_c` writes ``compensator.h`` and ``compensator.c``: no dynamic memory, nothing
beyond ``<math.h>`` (libm), every state in static storage, and::

    void   compensator_reset(void);              /* back to the model's initial state        */
    double compensator_step(double desired_um);  /* the command, V, for the next sample      */

``compensator_step`` computes, sample for sample, what ``model.compensator(dt, u_range=...,
max_slew=...)`` computes in Python, which is what ``piezohyst compensate --clip`` writes (the
tests compare them to 1e-9 V on long random and sinusoidal references). It goes through the model
protocol: the exporter asks the compensator for its piece (:meth:`Compensator.to_c
<piezohyst.models.base.Compensator.to_c>`), and each kind emits its own inverse through the
:class:`CEmitter` (wrappers ask their inner parts for theirs); the exporter adds the output limits
of :class:`~piezohyst.models.base.Compensator` (step limit, then clip to the range).

**Optional feedback** (integral, or PI). ``compensator_step_fb(desired_um, measured_um)`` adds
``kp e + I`` to the feedforward, ``I += ki dt e``, with ``e`` the desired displacement of
``COMPENSATOR_FB_DELAY`` calls earlier minus the measurement (set the delay to the samples between
a command and the measurement that shows it, so like is compared with like); the integral stops in
the direction of a command the range clipped (conditional-integration anti-windup, as
:class:`~piezohyst.control.pid.PID` with ``saturated``). Gains in V per µm and V per (µm s) are
compiled in and can be changed with ``compensator_set_gains(kp, ki)``. ``compensator_step`` and
``compensator_step_fb`` share the feedforward's state: use one or the other per sample.

A non-finite ``desired_um`` (or ``measured_um``) changes nothing and returns the last command (the
rest command before the first call), where Python raises an error.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._validation import as_scalar

_IDENT = re.compile(r"[^A-Za-z0-9_]")


def c_comment(text: Any) -> str:
    """``text`` safe inside a C block comment: ``*/`` would end it and ``/*`` is an error under
    ``-Wall -Werror`` (a path such as ``odd/evil*/m.json`` in the provenance line broke the
    build: found by fuzzing)."""
    return str(text).replace("*/", "* /").replace("/*", "/ *")


def c_number(x: float) -> str:
    """A C double literal that reads back as exactly ``x`` (17 significant digits)."""
    v = float(x)
    if not math.isfinite(v):
        raise ValueError(f"cannot write the non-finite number {v!r} into C code")
    s = f"{v:.17g}"
    if not any(ch in s for ch in ".eEn"):
        s += ".0"
    return f"({s})" if s.startswith("-") else s


@dataclass
class CEmitter:
    """Collects the pieces of a C translation unit: constants, static state (with its reset),
    helpers emitted once, and functions. Every name it hands out is unique and starts with
    ``prefix``'s sanitised form."""

    constants: list[str] = field(default_factory=list)
    state: list[str] = field(default_factory=list)
    reset: list[str] = field(default_factory=list)
    helpers: dict[str, str] = field(default_factory=dict)
    functions: list[str] = field(default_factory=list)
    _names: set[str] = field(default_factory=set)

    def name(self, base: str) -> str:
        """A C identifier made from ``base``, unique in this file."""
        stem = _IDENT.sub("_", base)
        if not stem or stem[0].isdigit():
            stem = "ph_" + stem
        out, k = stem, 1
        while out in self._names:
            k += 1
            out = f"{stem}_{k}"
        self._names.add(out)
        return out

    @staticmethod
    def num(x: float) -> str:
        """``x`` as a C double literal that reads back to the same float."""
        return c_number(x)

    @staticmethod
    def _values(values: Any) -> list[str]:
        arr = np.asarray(values, dtype=np.float64).ravel()
        return [c_number(v) for v in arr]

    def _init_list(self, vals: list[str]) -> str:
        rows = [", ".join(vals[i:i + 4]) for i in range(0, len(vals), 4)]
        return "{\n    " + ",\n    ".join(rows) + "\n}"

    def array(self, base: str, values: Any) -> str:
        """``static const double NAME[N]`` (N >= 1: an empty array is written as one 0.0)."""
        vals = self._values(values) or ["0.0"]
        nm = self.name(base)
        self.constants.append(f"static const double {nm}[{len(vals)}] = {self._init_list(vals)};")
        return nm

    def state_scalar(self, base: str, init: float) -> str:
        """``static double NAME``, set to ``init`` by ``compensator_reset``."""
        nm = self.name(base)
        self.state.append(f"static double {nm} = {c_number(init)};")
        self.reset.append(f"    {nm} = {c_number(init)};")
        return nm

    def state_array(self, base: str, init: Any) -> str:
        """``static double NAME[N]``, copied from a constant initial array by ``compensator_reset``."""
        vals = self._values(init) or ["0.0"]
        nm = self.name(base)
        ini = self.array(f"{nm}_init", np.asarray(init, dtype=np.float64)) if vals else None
        self.state.append(f"static double {nm}[{len(vals)}] = {self._init_list(vals)};")
        self.reset.append(f"    for (i = 0; i < {len(vals)}; ++i) {nm}[i] = {ini}[i];")
        return nm

    def helper(self, key: str, code: str) -> str:
        """A helper function emitted once however many pieces use it; returns ``key``."""
        if key not in self.helpers:
            self._names.add(key)
            self.helpers[key] = code
        return key

    def function(self, code: str) -> None:
        """Add a C function definition to the file."""
        self.functions.append(code)


@dataclass(frozen=True)
class CExport:
    """The two files' text and what they were made from."""

    header: str
    source: str
    info: dict[str, Any]


def _limits_code(u_range: tuple[float, float] | None, max_slew: float | None) -> str:
    lines = ["static double ph_limit(double u)", "{", "    double v = u;"]
    if max_slew is not None:
        s = c_number(max_slew)
        lines += ["    if (ph_have_last) {",
                  f"        const double lo = ph_last - {s};",
                  f"        const double hi = ph_last + {s};",
                  "        v = (lo > v) ? lo : v;",
                  "        v = (hi < v) ? hi : v;",
                  "    }"]
    if u_range is not None:
        lines += ["    v = (COMPENSATOR_U_MIN > v) ? COMPENSATOR_U_MIN : v;",
                  "    v = (COMPENSATOR_U_MAX < v) ? COMPENSATOR_U_MAX : v;"]
    lines += ["    ph_last = v;", "    ph_have_last = 1;", "    return v;", "}"]
    return "\n".join(lines)


def mean_slope(model: Any, dt: float | None, u_range: tuple[float, float]) -> float | None:
    """The model's mean slope over ``u_range`` (µm/V): the output's span over the input's on the
    second of two 1 Hz full-range cycles (at the model's ``dt`` where it has dynamics); None where
    it cannot be simulated so (no ``dt``, more than 10^6 samples, an error)."""
    from ..signals import sinusoid

    lo, hi = float(u_range[0]), float(u_range[1])
    step = dt if model.dynamic else 1e-3
    if not hi > lo or step is None or not (0.0 < float(step) and 2.0 / float(step) <= 1e6):
        return None
    u = sinusoid(1.0, 2, lo, hi, float(step))
    try:
        y = np.asarray(model.simulate(u, step if model.dynamic else None), dtype=np.float64)
    except (ValueError, ArithmeticError):
        return None
    y = y[y.size // 2:]
    g = float(np.ptp(y)) / (hi - lo) if np.all(np.isfinite(y)) else math.nan
    return g if math.isfinite(g) and g > 0.0 else None


def _check_feedback_gains(model: Any, dt: float | None, rng: tuple[float, float], kp: float, ki: float,
                          fdt: float) -> None:
    """Refuse compiled-in gains that diverge on any stage the model describes: with the
    feedforward inverting the model, a command change ``du`` moves the stage by ``g du`` (``g``
    the local slope), and the loop of ``compensator_step_fb`` (``e`` measured one sample after the
    command, ``I += ki dt e``, ``u = kp e + I``) is ``y[k+1] = (1 - a - b) y[k] + a y[k-1]`` with
    ``a = kp g``, ``b = ki dt g``: stable only for ``2 a + b < 2`` (Jury's test), and only less so
    with more delay or dynamics. Checked on the model's mean slope, which its steepest part
    exceeds: a refusal is a loop that diverges there for certain."""
    g = mean_slope(model, dt, rng)
    if g is None:
        return
    a, b = kp * g, ki * fdt * g
    if 2.0 * a + b >= 2.0:
        gains = (f"kp={kp:g} V/um, ki={ki:g} V/(um s) and a sample period of {fdt:g} s" if ki else
                 f"kp={kp:g} V/um")  # (without an integral no period was given: "0 s", found by fuzzing)
        raise ValueError(
            f"the feedback gains diverge on this model: with {gains}, "
            f"on the model's mean slope over {rng[0]:g}..{rng[1]:g} V ({g:.4g} um/V) "
            f"the loop gain 2 kp g + ki dt g is {2.0 * a + b:.4g}, and a loop that measures one sample after "
            f"its command is stable only below 2 (less with delay or resonance). Lower the gains"
            + (", or check the sample rate (in Hz)" if b > a else ""))


def generate_c(model: Any, *, dt: float | None = None, u_range: tuple[float, float] | None = None,
               max_slew: float | None = None, provenance: list[str] | None = None, kp: float = 0.0,
               ki: float = 0.0, fb_delay: int = 0, fb_dt: float | None = None) -> CExport:
    """``compensator.h`` and ``compensator.c`` for ``model``'s compensator (module docstring).

    Parameters
    ----------
    model : HysteresisModel
        Any kind whose compensator provides ``to_c``.
    dt : float, optional
        Sample period, s (required for kinds with dynamics: their own ``dt``).
    u_range : (low, high), optional
        Clip the command to it (as ``compensate --clip``).
    max_slew : float, optional
        Largest command change per sample, V (applied before the clip, as in Python).
    provenance : list of str
        Comment lines for the top of both files (producer, model file and its SHA-256).
    kp, ki : float
        Default feedback gains of ``compensator_step_fb`` (V per µm, V per µm s); 0: none.
    fb_delay : int
        ``COMPENSATOR_FB_DELAY``.
    fb_dt : float, optional
        Sample period of the feedback's integral (default ``dt``; needed when ``ki`` is set for a
        rate-independent model).
    """
    from ..models.base import DEFAULT_U_RANGE, check_u_range, kind_of

    rng = check_u_range(u_range)
    kind = kind_of(model)
    own_dt = getattr(model, "dt", None)
    if model.dynamic and dt is None:
        dt = own_dt  # a kind whose compensator needs no dt (Bouc-Wen's, eq. 10) has none
    comp = model.compensator(dt if model.dynamic else None, u_range=rng, max_slew=max_slew)
    rate_bound = model.dynamic and own_dt is not None
    if isinstance(fb_delay, bool) or not isinstance(fb_delay, (int, np.integer)) or not 0 <= fb_delay <= 10000:
        raise ValueError(f"fb_delay must be an integer number of samples in 0..10000, got {fb_delay!r}")
    for nm, g in (("kp", kp), ("ki", ki)):
        if not math.isfinite(float(g)):
            raise ValueError(f"{nm} must be finite, got {g!r}")
        if float(g) < 0.0:  # compensator_step_fb adds kp e + ki sum(e) dt, e = reference - measured
            raise ValueError(f"{nm} must be >= 0 (a negative gain is positive feedback), got {g!r}")
    if fb_dt is not None:  # (a negative one compiled positive feedback: found by fuzzing)
        fb_dt = as_scalar("fb_dt", fb_dt, positive=True)
    fdt = fb_dt if fb_dt is not None else dt
    if ki != 0.0 and fdt is None:
        raise ValueError("integral feedback needs the sample period: give fb_dt (or dt)")
    if kp or ki:  # without a command range, on the default amplifier's (a Python call skipped it: fuzzing)
        _check_feedback_gains(model, dt if model.dynamic else None, rng if rng is not None else DEFAULT_U_RANGE,
                              float(kp), float(ki), float(fdt) if fdt is not None else 0.0)
    em = CEmitter()
    for reserved in ("ph_last", "ph_have_last", "ph_limit", "ph_fb_kp", "ph_fb_ki", "ph_fb_int", "ph_fb_sat",
                     "ph_fb_ref", "ph_fb_pos", "compensator_reset", "compensator_step", "compensator_step_fb",
                     "compensator_set_gains", "i"):
        em._names.add(reserved)
    step_fn = comp.to_c(em, "ph_inv")
    rest = 0.0 if rng is None else min(max(0.0, rng[0]), rng[1])
    head = ["/*", " * compensator: the feedforward of a piezohyst model, as C99 (no dynamic memory, libm only).", " *"]
    for line in provenance or []:
        head.append(f" * {c_comment(line)}")
    period = (f"{float(dt):.17g} s (the model has dynamics: call it at exactly this rate)"  # type: ignore[arg-type]
              if rate_bound else "any (the compensator is rate independent)")
    head += [f" * model kind: {c_comment(kind)}; compensator: {type(comp).__name__}",
             f" * command range: {'%g .. %g V (clipped)' % rng if rng else 'none (not clipped)'}; "
             f"step limit: {'%g V per sample' % max_slew if max_slew else 'none'}",
             f" * sample period: {period}",
             " */"]
    guard = "PIEZOHYST_COMPENSATOR_H"
    hdr = "\n".join(head) + f"""
#ifndef {guard}
#define {guard}

#ifdef __cplusplus
extern "C" {{
#endif

"""
    if rng is not None:
        hdr += f"#define COMPENSATOR_U_MIN {c_number(rng[0])}\n#define COMPENSATOR_U_MAX {c_number(rng[1])}\n"
    if rate_bound and dt is not None:
        hdr += f"#define COMPENSATOR_DT_S {c_number(dt)}\n#define COMPENSATOR_RATE_HZ {c_number(1.0 / dt)}\n"
    # (exported without a sample period, the integral's increment is ki * 0 * e: a ki set at run
    # time did nothing, and the header did not say so: found by fuzzing)
    gains_note = ("/* Feedback gains: kp in V per um, ki in V per (um s). */" if fdt is not None else
                  "/* Feedback gains: kp in V per um, ki in V per (um s). Exported without a sample period\n"
                  "   (piezohyst export --fs): the integral is compiled out, and a ki set here does nothing. */")
    hdr += f"""#define COMPENSATOR_FB_DELAY {int(fb_delay)}

/* Back to the model's initial (de-energised) state; the feedback's integral to 0. */
void compensator_reset(void);

/* The command (V) for the next desired displacement sample (um): the model's inverse, then the
   step limit and the clip to the range. Call once per sample, from the reset state. */
double compensator_step(double desired_um);

/* As compensator_step, plus feedback kp e + ki * integral(e) (V), e = the desired displacement of
   COMPENSATOR_FB_DELAY calls earlier minus measured_um; the integral stops in the direction of a
   clipped command. */
double compensator_step_fb(double desired_um, double measured_um);

{gains_note}
void compensator_set_gains(double kp, double ki);

#ifdef __cplusplus
}}
#endif

#endif /* {guard} */
"""
    fb_dt_lit = c_number(fdt) if fdt is not None else "0.0"
    src = "\n".join(head) + '\n#include <math.h>\n#include "compensator.h"\n\n'
    src += "/* ---- constants (the model's inverse, state-free) ---- */\n" + "\n".join(em.constants) + "\n\n"
    src += "/* ---- state (static storage; compensator_reset restores it) ---- */\n" + "\n".join(em.state) + "\n"
    src += f"""static double ph_last = {c_number(rest)};
static int ph_have_last = 0;
static double ph_fb_kp = {c_number(kp)};
static double ph_fb_ki = {c_number(ki)};
static double ph_fb_int = 0.0;
static int ph_fb_sat = 0;
static double ph_fb_ref[COMPENSATOR_FB_DELAY + 1];
static int ph_fb_pos = 0;
static int ph_fb_filled = 0;

"""
    src += "/* ---- helpers ---- */\n" + "\n\n".join(em.helpers.values()) + ("\n\n" if em.helpers else "\n")
    src += "/* ---- the inverse ---- */\n" + "\n\n".join(em.functions) + "\n\n"
    src += _limits_code(rng, max_slew) + "\n\n"
    reset = "\n".join(em.reset)
    src += f"""void compensator_reset(void)
{{
    int i;
{reset}
    ph_last = {c_number(rest)};
    ph_have_last = 0;
    ph_fb_int = 0.0;
    ph_fb_sat = 0;
    for (i = 0; i < COMPENSATOR_FB_DELAY + 1; ++i) ph_fb_ref[i] = 0.0;
    ph_fb_pos = 0;
    ph_fb_filled = 0;
    (void)i;
}}

double compensator_step(double desired_um)
{{
    if (!isfinite(desired_um)) return ph_last;
    return ph_limit({step_fn}(desired_um));
}}

void compensator_set_gains(double kp, double ki)
{{
    if (isfinite(kp) && isfinite(ki)) {{
        ph_fb_kp = kp;
        ph_fb_ki = ki;
    }}
}}

double compensator_step_fb(double desired_um, double measured_um)
{{
    double ref, e, inc, fb, u, v;
    if (!isfinite(desired_um) || !isfinite(measured_um)) return ph_last;
    /* the desired value of COMPENSATOR_FB_DELAY calls ago (the first ones: the oldest given) */
    ph_fb_ref[ph_fb_pos] = desired_um;
    if (ph_fb_filled < COMPENSATOR_FB_DELAY) {{
        ref = ph_fb_ref[0];
        ++ph_fb_filled;
    }} else {{
        ref = ph_fb_ref[(ph_fb_pos + 1) % (COMPENSATOR_FB_DELAY + 1)];
    }}
    ph_fb_pos = (ph_fb_pos + 1) % (COMPENSATOR_FB_DELAY + 1);
    e = ref - measured_um;
    inc = ph_fb_ki * {fb_dt_lit} * e;
    if (!((inc > 0.0 && ph_fb_sat > 0) || (!(inc > 0.0) && ph_fb_sat < 0))) ph_fb_int += inc;
    fb = ph_fb_kp * e + ph_fb_int;
    u = {step_fn}(desired_um) + fb;
    v = ph_limit(u);
"""
    if rng is not None:
        src += "    ph_fb_sat = (u > COMPENSATOR_U_MAX) ? 1 : ((u < COMPENSATOR_U_MIN) ? -1 : 0);\n"
    src += "    return v;\n}\n"
    info = {"kind": kind, "compensator": type(comp).__name__, "u_range": list(rng) if rng else None,
            "max_slew": max_slew, "dt": dt if rate_bound else None, "kp": kp, "ki": ki, "fb_delay": int(fb_delay)}
    return CExport(header=hdr, source=src, info=info)


def export_c(model: Any, directory: Any, *, force: bool = False, **options: Any) -> dict[str, Any]:
    """Write ``compensator.h`` and ``compensator.c`` into ``directory`` (created if needed;
    existing files are not overwritten without ``force``; the two are written atomically
    together: never one without the other, or halves of two runs).
    ``options`` as :func:`generate_c`. Returns the paths and what was generated."""
    from pathlib import Path

    from .._fileio import atomic_write_texts, check_writable

    out = Path(directory)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out} exists and is not a directory")
    if not out.exists() and out.suffix.lower() in (".c", ".h", ".cc", ".cpp", ".hpp", ".hh"):
        # (--out comp.c made a folder named comp.c holding compensator.c: found by fuzzing)
        raise ValueError(f"{out}: the C export writes a folder (compensator.h and compensator.c into it); "
                         f"give a folder name, not a {out.suffix} file name")
    h_path, c_path = out / "compensator.h", out / "compensator.c"
    for p in (h_path, c_path):
        check_writable(p, force)
    gen = generate_c(model, **options)
    atomic_write_texts({h_path: gen.header, c_path: gen.source}, force=force)
    return {"header": str(h_path), "source": str(c_path), **gen.info}
