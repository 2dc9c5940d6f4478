"""Figures (matplotlib). Every function takes ``ax=`` or ``axes=`` (a new figure when omitted)
and returns the artists it drew; every axis carries its unit. Nothing here is needed to compute a
result.

* :func:`plot_loops` - voltage-displacement loops with their widths marked (the paper's Fig. 2);
* :func:`plot_model_vs_measured` - measured and identified loops (Figs. 3 and 4);
* :func:`plot_fit` - a fit: loops, time series and the residual, with the held-out part marked;
* :func:`plot_tracking` - a tracking run: output against desired over time, the error on the
  scale of the scored window (marked), the command with the actuator's range, and output against
  desired (Figs. 6-9);
* :func:`save` / :func:`save_formats` - PNG, PDF or SVG, written atomically, with what produced
  the file in its metadata.

:meth:`TrackingResult.plot <piezohyst.control.tracking.TrackingResult.plot>` and
:meth:`FitResult.plot <piezohyst.identify.result.FitResult.plot>` return the whole figure.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

#: The file formats :func:`save` writes (matplotlib's names).
FORMATS = ("png", "pdf", "svg")
_DPI = 120


def _ax(ax: Any = None) -> Any:
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=(6.4, 4.8), layout="constrained")
    return _check_axes(ax, "ax")


def _check_axes(ax: Any, name: str) -> Any:
    """``ax`` if it is a matplotlib Axes, else a TypeError naming the argument (a string or a list
    of Axes failed inside matplotlib with "'str' object has no attribute 'plot'": found by fuzzing)."""
    from matplotlib.axes import Axes

    if not isinstance(ax, Axes):
        raise TypeError(f"{name} must be a matplotlib Axes (e.g. from plt.subplots()), got {type(ax).__name__}")
    return ax


def use_headless_backend() -> None:
    """Switch matplotlib to the file-only Agg backend (for the CLI and tests)."""
    import matplotlib

    matplotlib.use("Agg")


def figure_result(fig: Any) -> Any:
    """Return ``fig`` to show it once as a Jupyter cell's value.

    With the inline backend a figure made through pyplot is shown at the end of the cell *and*
    as the cell's value; a figure that is returned is therefore detached from pyplot there (it
    stays a complete Figure: ``fig.savefig`` and ``display(fig)`` work). Elsewhere (scripts, GUI
    backends) nothing changes, so ``plt.show()`` shows it.
    """
    import matplotlib

    if "inline" in str(matplotlib.get_backend()).lower():
        import matplotlib.pyplot as plt

        plt.close(fig)
    return fig


#: Columns a time series is reduced to before drawing (:func:`_envelope`): more than a saved
#: figure's time axis has pixels (10 in at 120 dpi is 1200 pixels for the whole figure).
ENVELOPE_COLUMNS = 2000


def _envelope(t: Any, y: Any, columns: int = ENVELOPE_COLUMNS) -> tuple[Any, Any]:
    """``(t, y)`` reduced to what a line over ``columns`` pixel columns can show: per column of
    equal time, the samples of its minimum and its maximum, in time order (the first and last
    samples kept). A line through these covers the same pixels as the whole series, its extremes
    exact, so the figure looks the same and is drawn from a few thousand points instead of tens
    of thousands. ``t`` must be increasing; shorter series are returned as they are."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    n = y.size
    per = n // columns
    if per < 4 or t.size != n:
        return t, y
    m = columns * per
    blocks = y[:m].reshape(columns, per)
    base = np.arange(columns) * per
    i_min = base + np.argmin(blocks, axis=1)
    i_max = base + np.argmax(blocks, axis=1)
    keep = np.unique(np.concatenate([[0], i_min, i_max, np.arange(m, n), [n - 1]]))
    return t[keep], y[keep]


def _unit_scale(values: Any) -> tuple[float, str]:
    """Scale and unit for displacement errors: nm below 1 µm, else µm."""
    peak = float(np.max(np.abs(values))) if np.size(values) else 0.0
    return (1e3, "nm") if peak < 1.0 else (1.0, "µm")


def _loop_marker(u: Any, y: Any, width: float, u_mid: float) -> tuple[float, float]:
    """The two ends of a vertical bar of length ``width`` at ``u_mid``, between the branches."""
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    du = np.gradient(u)
    centre = []
    for sel in (du > 0, du < 0):
        if sel.sum() >= 2:
            order = np.argsort(u[sel])
            centre.append(float(np.interp(u_mid, u[sel][order], y[sel][order])))
    c = float(np.mean(centre)) if centre else float(np.mean(y))
    return c - width / 2, c + width / 2


def plot_loops(runs: Sequence[tuple[str, Any, Any]], *, ax: Any = None,
               xlabel: str = "input voltage u (V)", ylabel: str = "displacement y (µm)",
               title: str | None = None, widths: bool = True) -> list[Any]:
    """Voltage-displacement loops, one per ``(label, u, y)``, with their widths (the paper's Fig. 2).

    Without ``ax``: one panel per loop, side by side on shared axes (small multiples), each with
    its mid-range width drawn as a bar and written in µm and % of the span
    (:func:`~piezohyst.analysis.loop_figures`), so a loop that widens with frequency can be read.
    With ``ax``: all loops on that axis, the widths in the legend.

    Parameters
    ----------
    runs : sequence of (str, array_like, array_like)
        Label, input (V) and output (µm) of one steady loop each (e.g. the last period).
    widths : bool
        Mark and write each loop's width.

    Returns
    -------
    list of Line2D
        The loop lines (``lines[0].axes.figure`` is the figure).
    """
    from .analysis import loop_figures

    runs = list(runs)
    if not runs:
        raise ValueError("runs is empty: give at least one (label, u, y)")
    if ax is None:
        import matplotlib.pyplot as plt

        n = len(runs)
        fig, axs = plt.subplots(1, n, figsize=(max(3.2 * n, 4.8), 3.9), sharex=True, sharey=True,
                                layout="constrained", squeeze=False)
        panels = list(axs[0])
        if title:
            fig.suptitle(title, fontsize=10)
    else:
        panels = [_check_axes(ax, "ax")] * len(runs)
    lines = []
    for i, ((label, u, y), a) in enumerate(zip(runs, panels)):
        u = np.asarray(u, dtype=float)
        y = np.asarray(y, dtype=float)
        text = label
        lf = None
        if widths:
            try:
                lf = loop_figures(u, y, period=u.size)
            except ValueError:  # not a loop (monotone input): no width to mark
                lf = None
        if lf is not None:
            text = f"{label}: width {lf.width:.3g} µm ({lf.width_percent:.1f} % of span)"
        color = f"C{i}"
        (ln,) = a.plot(u, y, lw=1.0, color=color, label=text if ax is not None else label)
        lines.append(ln)
        if lf is not None:
            lo, hi = _loop_marker(u, y, lf.width, lf.u_mid)
            a.plot([lf.u_mid, lf.u_mid], [lo, hi], color="k", lw=2.0, solid_capstyle="butt")
            if ax is None:
                a.annotate(f"width {lf.width:.3g} µm\n{lf.width_percent:.1f} % of span",
                           xy=(lf.u_mid, hi), xytext=(0.04, 0.96), textcoords="axes fraction",
                           va="top", fontsize=8, arrowprops={"arrowstyle": "-", "lw": 0.6, "color": "0.3"})
        if ax is None:
            a.set_title(label, fontsize=9)
        a.set_xlabel(xlabel)
        a.grid(True, alpha=0.3)
    panels[0].set_ylabel(ylabel)
    if ax is not None:
        ax.legend(fontsize=8)
        if title:
            ax.set_title(title, fontsize=10)
    return lines


def plot_model_vs_measured(u: Any, y_measured: Any, y_model: Any, *, model_name: str, ax: Any = None,
                           title: str | None = None, data_label: str = "measured") -> list[Any]:
    """Measured and simulated loops on one axis (the paper's Figs. 3 and 4).

    ``data_label`` names the measurement (``"measured (virtual rig)"``, a file name, ...).
    """
    ax = _ax(ax)
    a = ax.plot(u, y_measured, lw=1.6, color="0.6", label=data_label)
    b = ax.plot(u, y_model, lw=1.0, ls="--", color="C3", label=f"identified {model_name}")
    ax.set_xlabel("input voltage u (V)")
    ax.set_ylabel("displacement y (µm)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    if title:
        ax.set_title(title, fontsize=10)
    return [*a, *b]


def plot_fit(u: Any, y: Any, y_model: Any, *, t: Any = None, dt: float | None = None,
             split: int | None = None, model_name: str = "model", data_label: str = "measured",
             axes: Any = None, title: str | None = None) -> list[Any]:
    """A fit judged by eye: the loops, measured and model over time, and the residual.

    Parameters
    ----------
    u, y, y_model : array_like
        Input (V), measured output (µm) and the model's output (µm), aligned sample by sample.
    t : array_like, optional
        Time (s); else ``k * dt``, else the sample number.
    split : int, optional
        First held-out sample: the part from there on is shaded and its RMSE given apart.
    axes : sequence of 3 Axes, optional
        Loop, time series and residual panels (a new figure when omitted).

    Returns
    -------
    list of Artist
    """
    from ._validation import as_signal

    us = as_signal("u", u)
    ys = as_signal("y", y)
    ms = as_signal("y_model", y_model)
    if not us.size == ys.size == ms.size:
        raise ValueError(f"u, y and y_model must have the same length, got {us.size}, {ys.size}, {ms.size}")
    if t is not None:
        ts = as_signal("t", t)
        tlabel = "time (s)"
    elif dt is not None:
        ts = np.arange(us.size, dtype=np.float64) * float(dt)
        tlabel = "time (s)"
    else:
        ts = np.arange(us.size, dtype=float)
        tlabel = "sample"
    created = axes is None
    if created:
        import matplotlib.pyplot as plt

        fig = plt.figure(figsize=(10.0, 5.2), layout="constrained")
        m = fig.subplot_mosaic([["loop", "time"], ["loop", "resid"]], width_ratios=[1, 1.6])
        m["resid"].sharex(m["time"])
        axes = (m["loop"], m["time"], m["resid"])
        if title:
            fig.suptitle(title, fontsize=10)
    if isinstance(axes, (str, bytes)) or not hasattr(axes, "__len__") or len(axes) != 3:
        raise TypeError(f"axes must be three matplotlib Axes (loop, time, residual), got {axes!r:.60}")
    a_loop, a_time, a_res = (_check_axes(a, f"axes[{i}]") for i, a in enumerate(axes))
    arts: list[Any] = []
    arts += a_loop.plot(us, ys, lw=1.4, color="0.6", label=data_label)
    arts += a_loop.plot(us, ms, lw=0.9, ls="--", color="C3", label=model_name)
    a_loop.set_xlabel("input voltage u (V)")
    a_loop.set_ylabel("displacement y (µm)")
    a_loop.legend(fontsize=8)
    arts += a_time.plot(*_envelope(ts, ys), lw=1.4, color="0.6", label=data_label)
    arts += a_time.plot(*_envelope(ts, ms), lw=0.9, ls="--", color="C3", label=model_name)
    a_time.set_ylabel("displacement (µm)")
    a_time.legend(fontsize=8, loc="upper right")
    resid = ys - ms
    scale, unit = _unit_scale(resid)
    parts = ([(slice(0, us.size), "")] if split is None
             else [(slice(0, split), "fitted part: "), (slice(split, us.size), "held out: ")])
    for i, (sl, name) in enumerate(parts):
        r = resid[sl]
        if r.size:
            rmse = float(np.sqrt(np.mean(r**2)))
            arts += a_res.plot(*_envelope(ts[sl], r * scale), lw=0.7, color=f"C{i}",
                               label=f"{name}RMSE {rmse * scale:.3g} {unit}")
    a_res.axhline(0.0, color="0.5", lw=0.6)
    a_res.set_ylabel(f"residual y - model ({unit})")
    a_res.set_xlabel(tlabel)
    a_res.legend(fontsize=8, loc="upper right")
    if split is not None and 0 < split < us.size:
        for a in (a_time, a_res):
            a.axvspan(ts[split], ts[-1], color="C1", alpha=0.08, lw=0)
    for a in axes:
        a.grid(True, alpha=0.3)
    if title and not created:
        a_time.set_title(title, fontsize=10)
    if created:
        a_time.tick_params(labelbottom=False)
    return arts


def plot_tracking(t: Any, reference: Any, output: Any, *, command: Any = None, scored: slice | None = None,
                  u_range: Any = None, axes: Any = None, title: str | None = None) -> list[Any]:
    """A tracking run (the paper's Figs. 6-9), in up to four panels.

    1. desired and measured displacement over time (µm);
    2. the error ``y - r`` (nm or µm), its axis scaled to the *scored* window - the samples the
       figures of merit are computed on, shaded in every time panel - so a start-up transient
       the metrics exclude does not flatten it (what leaves the axis is said on it);
    3. the command (V), with the actuator's range and the samples outside it marked;
    4. measured against desired displacement over the scored window, with the line y = r.

    Parameters
    ----------
    t, reference, output : array_like
        Time (s), desired and measured displacement (µm).
    command : array_like, optional
        The command (V); panel 3 is drawn only with it.
    scored : slice, optional
        The samples the metrics use (default: all).
    u_range : (low, high), optional
        The actuator's range (V), drawn in panel 3.
    axes : sequence of Axes, optional
        ``(time, error)`` or ``(time, error, command, output-vs-desired)`` (entries may be None);
        a new figure when omitted.

    Returns
    -------
    list of Artist
    """
    tt = np.asarray(t, dtype=float)
    r = np.asarray(reference, dtype=float)
    y = np.asarray(output, dtype=float)
    u = None if command is None else np.asarray(command, dtype=float)
    n = r.size
    sl = scored if scored is not None else slice(0, n)
    lo_k, hi_k, _ = sl.indices(n)
    created = axes is None
    if created:
        import matplotlib.pyplot as plt

        fig = plt.figure(figsize=(10.0, 6.4 if u is not None else 5.2), layout="constrained")
        m = fig.subplot_mosaic([["time", "xy"], ["error", "xy"], ["command", "xy"]] if u is not None
                               else [["time", "xy"], ["error", "xy"]], width_ratios=[1.9, 1])
        for k in ("error", "command"):
            if k in m:
                m[k].sharex(m["time"])
        axes = (m["time"], m["error"], m.get("command"), m["xy"])
        if title:
            fig.suptitle(title, fontsize=10)
    if isinstance(axes, (str, bytes)) or not hasattr(axes, "__len__") or not 1 <= len(axes) <= 4:
        raise TypeError(f"axes must be up to four matplotlib Axes (time, error, command, x-y), got {axes!r:.60}")
    axes = [a if a is None else _check_axes(a, f"axes[{i}]") for i, a in enumerate(axes)]
    axes = list(axes) + [None] * (4 - len(axes))
    ax_t, ax_e, ax_u, ax_xy = axes[:4]
    arts: list[Any] = []

    def shade(a: Any) -> None:
        if hi_k - lo_k < n and hi_k > lo_k:
            a.axvspan(tt[lo_k], tt[hi_k - 1], color="C2", alpha=0.08, lw=0)

    if ax_t is not None:
        arts += ax_t.plot(*_envelope(tt, r), lw=1.6, color="0.6", label="desired")
        arts += ax_t.plot(*_envelope(tt, y), lw=0.9, color="C0", label="measured")
        shade(ax_t)
        ax_t.set_ylabel("displacement (µm)")
        ax_t.legend(loc="upper right", fontsize=8)
    e = y - r
    if ax_e is not None:
        es = e[lo_k:hi_k] if hi_k > lo_k else e
        scale, unit = _unit_scale(es)
        arts += ax_e.plot(*_envelope(tt, e * scale), lw=0.8, color="C3")
        shade(ax_e)
        ax_e.axhline(0.0, color="0.5", lw=0.6)
        peak = float(np.max(np.abs(es))) * scale if es.size else 0.0
        lim = 1.15 * peak if peak > 0 else 1.0
        ax_e.set_ylim(-lim, lim)
        ax_e.set_ylabel(f"error y - r ({unit})")
        outside = int(np.sum(np.abs(e * scale) > lim))
        note = "shaded: scored window" if hi_k - lo_k < n else "all samples scored"
        if outside:
            note += f"; {outside} samples before it off scale (start-up)"
        ax_e.text(0.01, 0.03, note, transform=ax_e.transAxes, fontsize=7, color="0.3")
    if ax_u is not None and u is not None:
        arts += ax_u.plot(*_envelope(tt, u), lw=0.8, color="C4")
        shade(ax_u)
        ax_u.set_ylabel("command u (V)")
        if u_range is not None:
            lo_u, hi_u = float(u_range[0]), float(u_range[1])
            for v in (lo_u, hi_u):
                ax_u.axhline(v, color="0.3", lw=0.8, ls="--")
            out = (u < lo_u) | (u > hi_u)
            if out.any():
                arts += ax_u.plot(tt[out], u[out], "x", color="C3", ms=4,
                                  label=f"{int(out.sum())} commands outside {lo_u:g}..{hi_u:g} V (clipped)")
                ax_u.legend(loc="upper right", fontsize=8)
    bottom = ax_u if (ax_u is not None and u is not None) else ax_e
    if bottom is not None:
        bottom.set_xlabel("time (s)")
    if created:  # the time panels share x: one set of tick labels, at the bottom
        for a in (ax_t, ax_e, ax_u):
            if a is not None and a is not bottom:
                a.tick_params(labelbottom=False)
    if ax_xy is not None:
        rs, ys_ = r[lo_k:hi_k], y[lo_k:hi_k]
        arts += ax_xy.plot(rs, ys_, lw=0.8, color="C0", label="measured")
        ends = [float(min(rs.min(), ys_.min())), float(max(rs.max(), ys_.max()))] if rs.size else [0.0, 1.0]
        arts += ax_xy.plot(ends, ends, lw=0.8, ls="--", color="0.4", label="y = r")
        ax_xy.set_xlabel("desired displacement r (µm)")
        ax_xy.set_ylabel("measured displacement y (µm)")
        ax_xy.set_title("output vs desired (scored window)", fontsize=9)
        ax_xy.legend(loc="upper left", fontsize=8)
        pad = 0.05 * (ends[1] - ends[0]) or 0.05
        ax_xy.set_xlim(ends[0] - pad, ends[1] + pad)
        ax_xy.set_ylim(ends[0] - pad, ends[1] + pad)
    for a in (ax_t, ax_e, ax_u, ax_xy):
        if a is not None:
            a.grid(True, alpha=0.3)
    if title and not created and ax_t is not None:
        ax_t.set_title(title, fontsize=10)
    return arts


# -- files -----------------------------------------------------------------------------------------
def check_formats(formats: Any) -> tuple[str, ...]:
    """``"png,pdf"`` or ``["png", "svg"]`` as a checked tuple of formats from :data:`FORMATS`."""
    if isinstance(formats, str):
        items = [f.strip().lower().lstrip(".") for f in formats.split(",")]
    else:
        try:
            items = [str(f).strip().lower().lstrip(".") for f in formats]
        except TypeError:
            raise TypeError(f"formats must be a string like 'png,pdf' or a list of names, got {formats!r}") from None
    items = [f for f in items if f]
    bad = [f for f in items if f not in FORMATS]
    if bad or not items:
        raise ValueError(f"unknown figure format(s) {bad or formats!r}; the formats are {', '.join(FORMATS)}")
    return tuple(dict.fromkeys(items))


def _metadata(fmt: str, note: str | None, who: str | None = None) -> dict[str, Any]:
    """What produced the file, in the keys each format has for it (``who``: default
    :func:`~piezohyst._fileio.producer`, this process's package, command and time)."""
    if who is None:
        from ._fileio import producer

        who = producer()
    if fmt == "png":
        return {"Software": who, **({"Description": note} if note else {})}
    if fmt == "pdf":
        return {"Creator": who, **({"Subject": note} if note else {})}
    return {"Creator": who, **({"Description": note} if note else {})}  # svg (Dublin Core)


def save(fig_or_ax: Any, path: str | os.PathLike[str], *, force: bool = True, note: str | None = None,
         close: bool = True, producer: str | None = None) -> Path:
    """Save a figure atomically as PNG, PDF or SVG (from the file's suffix), with what produced it
    (package, version, command, time) and ``note`` in the file's metadata.

    ``producer`` replaces that first line (a worker process drawing a figure for a command it
    did not run passes the command's own). Returns the path; the figure is closed unless
    ``close=False``.
    """
    from ._fileio import atomic_write

    fig = fig_or_ax if hasattr(fig_or_ax, "savefig") else fig_or_ax.figure
    out = atomic_write(path, figure_writer(fig, path, note=note, producer=producer), force=force)
    if close:
        import matplotlib.pyplot as plt

        plt.close(fig)
    return out


def figure_writer(fig: Any, path: str | os.PathLike[str], *, note: str | None = None,
                  producer: str | None = None) -> Callable[[Path], None]:
    """What :func:`save` writes, as a ``write(tmp)`` for :mod:`piezohyst._fileio`'s atomic writers
    (a figure published together with other files: :func:`~piezohyst._fileio.atomic_write_files`);
    the format from ``path``'s suffix, refused now if it has none of :data:`FORMATS`."""
    p = Path(path)
    fmt = p.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise ValueError(f"{p}: cannot tell the figure format from the suffix {p.suffix!r}; "
                         f"use one of {', '.join('.' + f for f in FORMATS)}")
    meta = _metadata(fmt, note, producer)

    def write(tmp: Path) -> None:
        fig.savefig(tmp, format=fmt, dpi=_DPI, metadata=meta)

    return write


def save_formats(fig_or_ax: Any, path: str | os.PathLike[str], formats: Any = ("png",), *,
                 force: bool = True, note: str | None = None, producer: str | None = None) -> list[Path]:
    """Save one figure in several formats: ``path`` with each format's suffix (``fig2.png``,
    ``fig2.pdf``, ...). ``formats`` and ``producer`` as in :func:`check_formats` and :func:`save`.
    Closes the figure."""
    fmts = check_formats(formats)
    base = Path(path)
    if base.suffix.lower().lstrip(".") in FORMATS:
        base = base.with_suffix("")
    fig = fig_or_ax if hasattr(fig_or_ax, "savefig") else fig_or_ax.figure
    try:
        return [save(fig, base.with_name(f"{base.name}.{f}"), force=force, note=note, close=False,
                     producer=producer) for f in fmts]
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)
