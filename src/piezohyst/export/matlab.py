"""The model for MATLAB / Simulink: one ``.mat`` file, loadable with ``load`` (and ``scipy.io.loadmat``).

:func:`export_matlab` writes these variables:

* ``model`` - struct: ``kind`` and ``parameters`` (the kind's ``to_dict()``: nested models are
  nested structs with their own ``kind`` and ``parameters``), ``units``;
* ``inverse`` - struct: the inverse's state-free parameters where the kind has them (the inverse
  P-I model of eqs. 12-15, the rate-dependent recursion's factors, the output map, the Bouc-Wen
  constants of eq. 10, the Preisach grid the numerical inverse solves on), from the
  compensator's ``inverse_parameters()``; ``role`` says how they are used;
* ``reference`` - struct: ``t_s``, ``x_d_um``, ``u_V``: a reference trajectory over the model's
  range and the command piezohyst computes for it (with the range clip), to check an
  implementation against, sample for sample;
* ``producer``, ``model_file``, ``model_sha256``, ``u_range_V``, ``dt_s``.

A MATLAB reader, e.g. for a P-I model (eqs. 1-3 applied with the inverse's parameters)::

    S = load('model.mat');
    disp(S.model.kind)                      % 'prandtl-ishlinskii', 'rate-dependent', ...
    p = S.inverse;                          % P-I: thresholds, weights, initial_state, offsets
    z = p.initial_state(:); r = p.thresholds(:); w = p.weights(:);
    x = S.reference.x_d_um; u = zeros(size(x));
    for k = 1:numel(x)
        xs = x(k) - p.input_offset;
        z = min(max(z, xs - r), xs + r);   % eq. (1), every operator
        u(k) = w' * z + p.offset;           % eq. (3)
    end
    u = min(max(u, S.u_range_V(1)), S.u_range_V(2));
    max(abs(u - S.reference.u_V))           % ~1e-12
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .._validation import as_scalar


def _mat(obj: Any) -> Any:
    """Plain data MATLAB can hold: dicts become structs, None an empty array, lists arrays."""
    if isinstance(obj, dict):
        return {str(k): _mat(v) for k, v in obj.items()}
    if obj is None:
        return np.zeros((0, 0))
    if isinstance(obj, (list, tuple)):
        if all(isinstance(v, (int, float, np.number)) and not isinstance(v, bool) for v in obj):
            return np.asarray(obj, dtype=np.float64).reshape(-1, 1)
        return np.array([_mat(v) for v in obj], dtype=object)
    if isinstance(obj, np.ndarray):
        return obj.astype(np.float64).reshape(-1, 1) if obj.ndim == 1 else obj
    if isinstance(obj, bool):
        return obj
    if isinstance(obj, (int, float, np.number)):
        return float(obj)
    return obj


def reference_table(model: Any, u_range: tuple[float, float], dt: float | None, *,
                    max_slew: float | None = None) -> tuple[Any, Any, Any, float]:
    """A reference over the model's range (its output for two 1 Hz full-range cycles of the
    command) and the compensator's clipped (and, with ``max_slew``, rate-limited) command for it,
    sampled every ``dt`` (default 1 ms for a rate-independent model): (t, x_d, u, dt)."""
    from ..signals import sinusoid

    lo, hi = u_range
    step = dt if dt is not None else 1e-3
    u0 = sinusoid(1.0, 2, lo, hi, step)
    own = dt if model.dynamic else None
    x_d = np.asarray(model.predict(u0, own), dtype=np.float64)
    comp = model.compensator(own, u_range=u_range, max_slew=max_slew)
    u = comp.command(x_d)
    return np.arange(x_d.size) * step, x_d, u, step


def export_matlab(model: Any, path: Any, *, u_range: tuple[float, float], dt: float | None = None,
                  provenance: dict[str, str] | None = None, force: bool = False,
                  max_slew: float | None = None) -> dict[str, Any]:
    """Write the ``.mat`` file of the module docstring, atomically (not over an existing file
    without ``force``). Returns what was written."""
    from scipy.io import savemat

    from .._fileio import atomic_write
    from ..modelio import model_units
    from ..models.base import check_u_range, kind_of

    # (found by fuzzing: u_range=None was a bare AssertionError, dt=-1 or "x" was ignored, a .txt
    # name got MATLAB bytes)
    if u_range is None:
        raise ValueError("u_range is required: the amplifier's (low, high) range in V, which the commands keep to")
    rng = check_u_range(u_range)
    assert rng is not None
    if Path(path).suffix.lower() != ".mat":
        raise ValueError(f"{path}: a MATLAB file's name ends in .mat")
    if dt is not None:
        dt = as_scalar("dt", dt, positive=True)
    if max_slew is not None:
        max_slew = as_scalar("max_slew", max_slew, positive=True)
    kind = kind_of(model)
    if model.dynamic and dt is None:
        dt = getattr(model, "dt", None)
        if dt is None:
            raise ValueError(f"the {kind} model has dynamics: give the sample period of the reference table "
                             "(dt; --fs on the command line)")
    comp = model.compensator(dt if model.dynamic else None, u_range=rng, max_slew=max_slew)
    t, x_d, u, step = reference_table(model, rng, dt, max_slew=max_slew)
    doc = {
        "model": {"kind": kind, "parameters": _mat(model.to_dict()), "units": _mat(model_units(model))},
        "inverse": _mat(comp.inverse_parameters() or {"role": "none"}),
        "reference": {"t_s": t.reshape(-1, 1), "x_d_um": x_d.reshape(-1, 1), "u_V": u.reshape(-1, 1)},
        "u_range_V": np.asarray(rng, dtype=np.float64).reshape(1, 2),
        "dt_s": float(step),
        "max_slew_V_per_sample": float(max_slew) if max_slew is not None else 0.0,
    }
    for k, v in (provenance or {}).items():
        doc[k] = v

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            savemat(fh, doc, do_compression=True, oned_as="column")

    out = atomic_write(path, write, force=force)
    return {"written": str(out), "kind": kind, "reference_samples": int(u.size),
            "inverse": sorted(comp.inverse_parameters())}
