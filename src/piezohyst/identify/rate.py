"""Fits of the rate-dependent, asymmetric P-I and Preisach kinds (each a search on held-out data
over its structure, :func:`~piezohyst.identify.select.fit_model`, restricted to the kind)."""

from __future__ import annotations

from typing import Any, Sequence

from .linear import Structure, fit_structure
from .result import FitResult, paired_signals, unpack_data
from .select import fit_model


def fit_rate_dependent(u: Any, y: Any = None, dt: float | None = None, **options: Any) -> FitResult:
    """A rate-dependent model (:class:`~piezohyst.models.rate.RateDependent`): P-I or Preisach
    with an input lag and output lags, each structure one bounded least-squares fit, the
    structure (lags, input lag, delay, size, static kind) chosen on held-out data. Options as
    :func:`~piezohyst.identify.fit_model`."""
    return fit_model(u, y, dt, "rate-dependent", **options)


def fit_asymmetric_pi(u: Any, y: Any = None, dt: float | None = None, **options: Any) -> FitResult:
    """An asymmetric P-I model (:class:`~piezohyst.models.asymmetric_pi.AsymmetricPI`): P-I (with
    lags where they help and ``dt`` is given) followed by a monotone output map, one bounded
    least-squares problem per structure; options as :func:`~piezohyst.identify.fit_model`."""
    return fit_model(u, y, dt, "asymmetric-pi", **options)


def fit_preisach(u: Any, y: Any = None, dt: float | None = None, **options: Any) -> FitResult:
    """A discrete Preisach model (:class:`~piezohyst.models.preisach.Preisach`), weights >= 0 on
    a triangular grid by bounded least squares, grid levels and delay chosen on held-out data;
    options as :func:`~piezohyst.identify.fit_model` (``n=`` fixes the levels)."""
    return fit_model(u, y, dt, "preisach", **options)


def fit_rate_pi(
    u: Any, y: Any = None, dt: float | None = None, *, n: int = 20, u_max: float | None = None, taus: Sequence[float] | None = None,
    input_taus: Sequence[float] | None = None, delay: int | str = "auto", max_auto_delay: int | None = None,
    fit_offset: bool = True, margin: float | None = None,
) -> FitResult:
    """A rate-dependent P-I model (:class:`~piezohyst.models.rate.RateDependent` around a P-I).

    With ``taus`` and ``input_taus`` both given and ``delay`` an integer, one structure is fitted
    on all the data (``input_taus`` then holds one value, ``u_max`` sets eq. (4) thresholds).
    Otherwise the structure is chosen on held-out data like :func:`~piezohyst.identify.fit_model`,
    within the given lags, input-lag candidates and ``max_auto_delay``; every range left out
    comes from the data.

    Parameters
    ----------
    u, y : array_like
        Input (V) and output (µm) of an identification run that starts at rest.
    dt : float
        Sample period, s.
    n : int
        Play operators.
    taus, input_taus : sequence of float, optional
        Output-lag time constants and candidate input lags (s).
    delay : int or "auto"
        Samples by which y lags u.
    """
    u, y, dt = unpack_data(u, y, dt, need_dt=True)
    if taus is not None and input_taus is not None and len(input_taus) == 1 and delay != "auto":
        us, ys = paired_signals(u, y, 0)
        st = Structure("pi", int(n), 0, tuple(float(t) for t in taus), float(input_taus[0]), int(delay),  # type: ignore[arg-type]
                       "eq4" if u_max is not None else "span", u_max)
        fit, _ = fit_structure(us, ys, dt, st, margin=margin, fit_offset=fit_offset)
        return fit
    return fit_model(u, y, dt, "rate-dependent", n=n, taus=taus, input_taus=input_taus, margin=margin,
                     delay=delay, max_delay=max_auto_delay, statics=("pi",))
