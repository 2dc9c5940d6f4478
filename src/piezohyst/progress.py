"""Progress for long calls, shown in Jupyter and in a terminal.

:class:`Progress` is one display of one long job. It is the ``progress`` callback that
:func:`~piezohyst.identify.fit_model` and :func:`~piezohyst.commission` call with the name of each
stage, and a counter for work of known size (:func:`~piezohyst.pso_minimize` counts its
iterations in it)::

    with ph.Progress("choosing a model") as p:
        fit = ph.fit_model(u, y, dt, kind="auto", progress=p)

Where it shows, chosen when it is created (``mode="auto"``):

* in a Jupyter kernel: an HTML block under the cell, updated in place through an IPython display
  handle (no ipywidgets needed); a plain-text copy goes with it for front ends without HTML. It
  closes itself when the cell finishes, showing the total time;
* in a terminal (standard error is a TTY): a rich progress line on standard error, removed when
  the job ends;
* anywhere else (a pipe, a log file, a test run): nothing.

While a display is open, a PSO run started inside the job (e.g. the Bouc-Wen candidate of
``fit_model``) reports its iterations in it as a second line, so a 40-second stage does not look
stalled. Nothing here changes what a computation returns.
"""

from __future__ import annotations

import html
import sys
import time
from typing import Any

__all__ = ["Progress", "active", "detect_mode"]

MODES = ("auto", "jupyter", "terminal", "off")

#: Open displays, innermost last (a PSO run reports into the innermost one).
_ACTIVE: list[Progress] = []
_HOOKED = False


def detect_mode() -> str:
    """``"jupyter"`` inside a Jupyter kernel, ``"terminal"`` when stderr is a TTY, else ``"off"``."""
    ip = _ipython()
    if ip is not None and getattr(ip, "kernel", None) is not None:
        return "jupyter"
    try:
        if sys.stderr is not None and sys.stderr.isatty():
            return "terminal"
    except (AttributeError, ValueError):  # a closed or replaced stream
        pass
    return "off"


def active() -> Progress | None:
    """The innermost open :class:`Progress`, or None."""
    return _ACTIVE[-1] if _ACTIVE else None


def _ipython() -> Any:
    mod = sys.modules.get("IPython")
    if mod is None:
        return None
    try:
        return mod.get_ipython()
    except Exception:  # pragma: no cover - a broken IPython install
        return None


def _fmt_time(s: float) -> str:
    if s < 60:
        return f"{s:.1f} s"
    m, s = divmod(int(round(s)), 60)
    return f"{m} min {s:02d} s" if m < 60 else f"{m // 60} h {m % 60:02d} min"


def _fmt_fields(fields: dict[str, Any]) -> str:
    return ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in fields.items())


class _Counter:
    """Counted work of known size (``completed`` of ``total``) with a few named figures."""

    def __init__(self, description: str, total: int | None):
        self.description = description
        self.total = total
        self.completed = 0
        self.fields: dict[str, Any] = {}

    def text(self) -> str:
        s = self.description
        if self.total:
            s += f" {self.completed}/{self.total}"
        elif self.completed:
            s += f" {self.completed}"
        if self.fields:
            s += f" ({_fmt_fields(self.fields)})"
        return s


class Progress:
    """A progress display for one long job (module docstring).

    Parameters
    ----------
    description : str
        What the job is ("commissioning", "PSO: Bouc-Wen").
    total : int, optional
        Units of work when known (iterations); without it the display shows the current stage
        and the elapsed time.
    mode : {"auto", "jupyter", "terminal", "off"}
        Where to show it; ``"auto"`` decides with :func:`detect_mode`.
    min_interval : float
        Least time between two redraws for :meth:`advance` (s); stage changes always redraw.

    Notes
    -----
    Call it with a string to start a stage (that is the ``progress=`` callback of
    :func:`~piezohyst.identify.fit_model` and :func:`~piezohyst.commission`); :meth:`advance`
    counts work; :meth:`close` (or leaving a ``with`` block) ends it. In Jupyter it also ends
    when the cell finishes.

    Examples
    --------
    >>> from piezohyst import Progress
    >>> with Progress("demo", total=3, mode="off") as p:
    ...     p("first stage")
    ...     p.advance(3, best=0.5)
    >>> p.stage, p.counter.completed, p.closed
    ('first stage', 3, True)
    """

    def __init__(self, description: str = "working", total: int | None = None, *, mode: str = "auto",
                 min_interval: float = 0.2):
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if total is not None and (isinstance(total, bool) or int(total) != total or total < 0):
            raise ValueError(f"total must be a whole number >= 0 or None, got {total!r}")
        self.description = str(description)
        self.mode = detect_mode() if mode == "auto" else mode
        self.min_interval = float(min_interval)
        self.counter = _Counter("", int(total) if total is not None else None)
        self.stage = ""
        self.stages = 0
        self.sub: _Counter | None = None
        self.closed = False
        self.t0 = time.perf_counter()
        self.elapsed_s = 0.0
        self._last_draw = -float("inf")
        self._view: Any = _make_view(self)
        _ACTIVE.append(self)
        self._draw(force=True)

    # -- the callback and the counters -------------------------------------------------------
    def __call__(self, stage: str) -> None:
        """Start the stage ``stage`` (the ``progress=`` callback of long calls)."""
        self.stage = str(stage)
        self.stages += 1
        self.sub = None
        self._draw(force=True)

    def advance(self, n: int = 1, **fields: Any) -> None:
        """Count ``n`` units of work done; ``fields`` are figures to show (``best=1.2e-3``)."""
        self.counter.completed += n
        self.counter.fields.update(fields)
        self._draw()

    def start_sub(self, description: str, total: int | None = None) -> None:
        """Show a second, nested counter (a PSO run inside a stage) until :meth:`end_sub`."""
        self.sub = _Counter(description, total)
        self._draw(force=True)

    def advance_sub(self, n: int = 1, **fields: Any) -> None:
        """Count work on the nested counter."""
        if self.sub is not None:
            self.sub.completed += n
            self.sub.fields.update(fields)
            self._draw()

    def end_sub(self) -> None:
        """Remove the nested counter."""
        self.sub = None
        self._draw(force=True)

    def close(self) -> None:
        """End the display (showing the total time where it stays visible). Idempotent."""
        if self.closed:
            return
        self.closed = True
        self.elapsed_s = time.perf_counter() - self.t0
        if self in _ACTIVE:
            _ACTIVE.remove(self)
        self._view.close()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- rendering ------------------------------------------------------------------------------
    def text(self, *, with_time: bool = True) -> str:
        """The display as one line of plain text."""
        elapsed = self.elapsed_s if self.closed else time.perf_counter() - self.t0
        parts = [self.description]
        if self.stage:
            parts.append(self.stage)
        count = self.counter.text().strip()
        if count:
            parts.append(count)
        if self.sub is not None and not self.closed:
            parts.append(self.sub.text())
        if with_time:
            parts.append(f"done in {_fmt_time(elapsed)}" if self.closed else _fmt_time(elapsed))
        return " | ".join(parts)

    def html(self) -> str:
        """The display as an HTML block (what Jupyter shows)."""
        elapsed = self.elapsed_s if self.closed else time.perf_counter() - self.t0
        e = html.escape
        head = f"<b>{e(self.description)}</b>"
        if self.closed:
            head += f" &middot; done in {e(_fmt_time(elapsed))}"
        else:
            head += f" &middot; {e(_fmt_time(elapsed))}"
        if self.stages:
            head += f" &middot; stage {self.stages}: {e(self.stage)}"
        rows = [head]
        for c in (self.counter, self.sub if not self.closed else None):
            if c is None or (c is self.counter and not (c.total or c.completed)):
                continue
            bar = f' <progress value="{c.completed}" max="{c.total}" style="width:12em"></progress>' if c.total else ""
            rows.append(f"{e(c.description)}{bar} {e(c.text()[len(c.description):].strip())}")
        return ('<div class="piezohyst-progress" style="font-family:monospace;font-size:90%">'
                + "<br>".join(rows) + "</div>")

    def _draw(self, force: bool = False) -> None:
        if self.closed:
            return
        now = time.perf_counter()
        if not force and now - self._last_draw < self.min_interval:
            return
        self._last_draw = now
        self._view.draw()

    def __repr__(self) -> str:
        return f"Progress({self.text()!r})"


# -- where it shows ----------------------------------------------------------------------------------
class _Off:
    def __init__(self, p: Progress):
        pass

    def draw(self) -> None:
        pass

    def close(self) -> None:
        pass


class _Jupyter:
    """An IPython display updated in place (``display_id``); closed at the end of the cell."""

    def __init__(self, p: Progress):
        from IPython.display import display

        self.p = p
        self.handle = display(self._bundle(), raw=True, display_id=True)
        _hook_cell_end()

    def _bundle(self) -> dict[str, str]:
        return {"text/plain": self.p.text(), "text/html": self.p.html()}

    def draw(self) -> None:
        if self.handle is not None:
            self.handle.update(self._bundle(), raw=True)

    def close(self) -> None:
        self.draw()


def _hook_cell_end() -> None:
    """Close every open Jupyter display when the cell that opened it finishes."""
    global _HOOKED
    ip = _ipython()
    if _HOOKED or ip is None:
        return

    def close_all(*_: Any) -> None:
        for p in [p for p in _ACTIVE if p.mode == "jupyter"]:
            p.close()

    ip.events.register("post_run_cell", close_all)
    _HOOKED = True


class _Terminal:
    """A transient rich progress line on standard error."""

    def __init__(self, p: Progress):
        from rich.console import Console
        from rich.progress import BarColumn, Progress as RichProgress, SpinnerColumn, TextColumn, TimeElapsedColumn

        self.p = p
        self.bar = RichProgress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(),
                                TimeElapsedColumn(), console=Console(stderr=True), transient=True)
        self.task = self.bar.add_task(p.text(with_time=False), total=p.counter.total)
        self.bar.start()  # raises rich's LiveError if another live display is running
        import atexit

        atexit.register(p.close)  # a display never closed still gives the terminal back

    def draw(self) -> None:  # the elapsed time has its own column
        self.bar.update(self.task, description=self.p.text(with_time=False), completed=self.p.counter.completed)

    def close(self) -> None:
        self.bar.stop()


def _make_view(p: Progress) -> Any:
    if p.mode == "jupyter":
        try:
            return _Jupyter(p)
        except ImportError:  # IPython missing: asked for Jupyter outside of it
            return _Off(p)
    if p.mode == "terminal":
        from rich.errors import LiveError

        try:
            return _Terminal(p)
        except LiveError:  # another rich display (the CLI's own) holds the terminal
            return _Off(p)
    return _Off(p)
