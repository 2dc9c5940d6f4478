"""Figures (matplotlib). Every function takes ``ax=`` (a new figure when omitted) and returns the
artists it drew; axes carry units. Nothing here is needed to compute a result."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np


def _ax(ax: Any = None) -> Any:
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=(6.4, 4.8), layout="constrained")
    return ax


def use_headless_backend() -> None:
    """Switch matplotlib to the file-only Agg backend (for the CLI and tests)."""
    import matplotlib

    matplotlib.use("Agg")


def plot_loops(runs: Sequence[tuple[str, Any, Any]], *, ax: Any = None,
               xlabel: str = "input voltage u (V)", ylabel: str = "displacement y (µm)",
               title: str | None = None) -> list[Any]:
    """Voltage-displacement loops, one line per ``(label, u, y)`` (the paper's Fig. 2)."""
    ax = _ax(ax)
    lines = []
    for label, u, y in runs:
        (ln,) = ax.plot(u, y, lw=1.0, label=label)
        lines.append(ln)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    ax.legend()
    if title:
        ax.set_title(title, fontsize=10)
    return lines


def plot_model_vs_measured(u: Any, y_measured: Any, y_model: Any, *, model_name: str, ax: Any = None,
                           title: str | None = None) -> list[Any]:
    """Measured and simulated loops on one axis (the paper's Figs. 3 and 4)."""
    ax = _ax(ax)
    a = ax.plot(u, y_measured, lw=1.6, color="0.6", label="measured (virtual rig)")
    b = ax.plot(u, y_model, lw=1.0, ls="--", color="C3", label=f"identified {model_name}")
    ax.set_xlabel("input voltage u (V)")
    ax.set_ylabel("displacement y (µm)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    if title:
        ax.set_title(title, fontsize=10)
    return [*a, *b]


def plot_tracking(t: Any, reference: Any, output: Any, *, axes: Any = None, title: str | None = None) -> list[Any]:
    """Desired and measured displacement over time, and the error (the paper's Figs. 6-9)."""
    if axes is None:
        import matplotlib.pyplot as plt

        _, axes = plt.subplots(2, 1, figsize=(6.4, 5.6), sharex=True, layout="constrained",
                               gridspec_kw={"height_ratios": [2, 1]})
    ax1, ax2 = axes
    t = np.asarray(t)
    r = np.asarray(reference)
    y = np.asarray(output)
    a = ax1.plot(t, r, lw=1.6, color="0.6", label="desired")
    b = ax1.plot(t, y, lw=0.9, color="C0", label="measured")
    ax1.set_ylabel("displacement (µm)")
    ax1.grid(True, alpha=0.3)
    ax1.legend(loc="best", fontsize=9)
    c = ax2.plot(t, y - r, lw=0.8, color="C3")
    ax2.set_xlabel("time (s)")
    ax2.set_ylabel("error (µm)")
    ax2.grid(True, alpha=0.3)
    if title:
        ax1.set_title(title, fontsize=10)
    return [*a, *b, *c]


def save(fig_or_ax: Any, path: Any, *, force: bool = True, note: str | None = None) -> Any:
    """Save a figure as PNG atomically, with the producer in the PNG metadata."""
    from ._fileio import atomic_write, producer

    fig = fig_or_ax if hasattr(fig_or_ax, "savefig") else fig_or_ax.figure
    meta = {"Software": producer()}
    if note:
        meta["Description"] = note

    def write(tmp: Any) -> None:
        fig.savefig(tmp, format="png", dpi=120, metadata=meta)

    out = atomic_write(path, write, force=force)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return out
