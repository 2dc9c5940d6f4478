"""Figures, figure files, HTML representations and progress displays."""

from __future__ import annotations

import re

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import piezohyst as ph  # noqa: E402
from piezohyst import plots, progress  # noqa: E402
from piezohyst._fileio import OverwriteRefused  # noqa: E402
from piezohyst.control.tracking import TrackingResult  # noqa: E402
from piezohyst.models.asymmetric_pi import OutputMap  # noqa: E402
from piezohyst.models.preisach import grid_size  # noqa: E402


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


def _run_with_startup_transient(clip: bool = False) -> TrackingResult:
    """Four cycles of a 2 µm sinusoid; the first cycle carries a 1 µm transient, the rest a 5 nm error."""
    dt, per = 1e-3, 200
    r = ph.sinusoid(5.0, 4, 0.25, 2.25, dt)
    k = np.arange(r.size)
    e = 0.005 * np.sin(2 * np.pi * k / per * 3)
    e[:50] += np.linspace(-1.0, 0.0, 50)
    u = 40.0 * r + 10.0
    if clip:
        u[300:310] = 101.0
    return TrackingResult(t=k * dt, reference=r, output=r + e, command=u, period=per, label="synthetic")


def test_tracking_error_axis_is_scaled_to_the_scored_window_which_is_shaded():
    run = _run_with_startup_transient()
    fig = run.plot()
    err_ax = next(a for a in fig.axes if a.get_ylabel().startswith("error"))
    assert "(nm)" in err_ax.get_ylabel()
    lo, hi = err_ax.get_ylim()
    # the axis follows the scored window's 5 nm error, not the 1 µm start-up transient
    peak_nm = 1e3 * np.max(np.abs(run.error[200:800]))
    assert hi == pytest.approx(1.15 * peak_nm) and lo == pytest.approx(-1.15 * peak_nm)
    assert peak_nm == pytest.approx(run.e_max * 1e3)
    # the scored window (samples 200..799) is shaded on the time panels
    spans = [p for p in err_ax.patches if p.get_alpha() is not None]
    assert spans
    x0, x1 = spans[0].get_x(), spans[0].get_x() + spans[0].get_width()
    assert x0 == pytest.approx(run.t[200]) and x1 == pytest.approx(run.t[799])
    notes = " ".join(t.get_text() for t in err_ax.texts)
    assert "scored window" in notes and "off scale" in notes


def test_tracking_figure_has_command_and_output_vs_desired_panels_with_units():
    run = _run_with_startup_transient(clip=True)
    fig = run.plot(u_range=(0.0, 100.0))
    labels = {a.get_ylabel() for a in fig.axes}
    assert "command u (V)" in labels and "measured displacement y (µm)" in labels
    for a in fig.axes:  # units on every axis that has a label
        for lab in (a.get_xlabel(), a.get_ylabel()):
            assert not lab or re.search(r"\((µm|nm|V|s)\)", lab), lab
    cmd_ax = next(a for a in fig.axes if a.get_ylabel() == "command u (V)")
    marked = [ln for ln in cmd_ax.lines if ln.get_marker() == "x"]
    assert len(marked) == 1 and marked[0].get_xdata().size == 10  # the ten commands outside 0..100 V


def test_plot_returns_the_figure_and_accepts_axes():
    run = _run_with_startup_transient()
    assert isinstance(run.plot(), matplotlib.figure.Figure)
    fig, axes = plt.subplots(2, 1)
    assert run.plot(axes=axes) is fig


def test_loops_small_multiples_carry_the_widths():
    u = ph.sinusoid(1.0, 1, 0.0, 100.0, 1e-3)
    runs = []
    for label, w in (("1 Hz", 0.1), ("5 Hz", 0.3)):
        y = 0.02 * u + w * np.sin(2 * np.pi * np.arange(u.size) / u.size)  # a loop of known width
        runs.append((label, u, y))
    lines = plots.plot_loops(runs, title="loops")
    fig = lines[0].axes.figure
    panels = [a for a in fig.axes if a.lines]
    assert len(panels) == 2 and panels[0].get_shared_y_axes().joined(panels[0], panels[1])
    for (_, uu, yy), a in zip(runs, panels):
        lf = ph.loop_figures(uu, yy, period=uu.size)
        text = " ".join(t.get_text() for t in a.texts)
        assert f"width {lf.width:.3g} µm" in text and f"{lf.width_percent:.1f} % of span" in text
        bar = a.lines[1].get_ydata()
        assert abs(bar[1] - bar[0]) == pytest.approx(lf.width)


def test_plot_fit_shows_the_residual_and_the_held_out_part():
    u = ph.sinusoid(1.0, 2, 0.0, 10.0, 1e-2)
    y = 0.1 * u
    model = y + 0.002 * np.cos(np.arange(u.size))
    arts = plots.plot_fit(u, y, model, dt=1e-2, split=100)
    fig = arts[0].axes.figure
    res_ax = next(a for a in fig.axes if a.get_ylabel().startswith("residual"))
    assert res_ax.get_ylabel() == "residual y - model (nm)"
    data = np.concatenate([ln.get_ydata() for ln in res_ax.lines if np.size(ln.get_xdata()) > 2])
    np.testing.assert_allclose(data, (y - model) * 1e3)
    assert any("held out" in ln.get_label() for ln in res_ax.lines)
    with pytest.raises(ValueError, match="same length"):
        plots.plot_fit(u, y[:-1], model)


def test_fit_result_plot_and_html():
    rig = ph.VirtualRig(seed=1)
    ds = rig.excite(ph.sinusoid(1.0, 2, 0.0, 100.0, rig.dt))
    fit = ph.fit_pi(ds.u, ds.y, n=8, method="lsq")
    fig = fit.plot(ds)
    assert isinstance(fig, matplotlib.figure.Figure)
    html = fit._repr_html_()
    assert "FitResult" in html and "fit RMSE" in html and "PrandtlIshlinskii model" in html
    with pytest.raises(TypeError, match="measured output"):
        fit.plot(ds.u)


@pytest.mark.parametrize("fmt", plots.FORMATS)
def test_figure_files_say_what_produced_them(tmp_path, fmt):
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    path = plots.save(fig, tmp_path / f"f.{fmt}", note="a test figure")
    data = path.read_bytes()
    assert b"piezohyst " + ph.__version__.encode() in data
    assert b"a test figure" in data


def test_save_formats_writes_each_format_and_refuses_to_overwrite(tmp_path):
    fig, ax = plt.subplots()
    ax.plot([0, 1])
    files = plots.save_formats(fig, tmp_path / "fig2.png", "png, svg")
    assert [p.name for p in files] == ["fig2.png", "fig2.svg"]
    fig, ax = plt.subplots()
    with pytest.raises(OverwriteRefused):
        plots.save_formats(fig, tmp_path / "fig2", ["svg"], force=False)


def test_bad_formats_are_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match="jpeg.*png, pdf, svg"):
        plots.check_formats("png,jpeg")
    with pytest.raises(ValueError, match="unknown figure format"):
        plots.check_formats("")
    fig, _ = plt.subplots()
    with pytest.raises(ValueError, match="suffix '.gif'"):
        plots.save(fig, tmp_path / "x.gif")
    assert plots.check_formats(["PDF", ".svg", "pdf"]) == ("pdf", "svg")


def test_paper_figure_names_follow_the_formats():
    from piezohyst.experiments.paper import FIGURES, figure_files

    names = figure_files("png,pdf")
    assert len(names) == 2 * len(FIGURES) and "fig2_loops.pdf" in names and "fig9_pi_ff_pid_1hz.png" in names


# -- HTML representations ------------------------------------------------------------------------
def _models():
    pi = ph.PrandtlIshlinskii(ph.equal_thresholds(12, 100.0), np.full(12, 0.01))
    return [
        pi,
        ph.BoucWen(m=0.75, b=27.96, k=8.54e7, d1=2.15e-8, alpha=0.472, beta=0.072, gamma=0.0),
        ph.RateDependent(static=pi, taus=[0.01, 0.1], lag_weights=[0.001, 0.002], dt=1e-3),
        ph.Preisach(lo=0.0, hi=10.0, weights=np.full(grid_size(4), 0.1), slope=0.05),
        ph.AsymmetricPI(pi, OutputMap(knots=[0.2, 0.9], coefficients=[0.1, -0.05], centre=0.5)),
    ]


def test_every_kind_has_an_html_summary():
    for kind in ph.kinds():  # the registry gives one to a kind that does not define its own
        assert callable(getattr(ph.models.kind_class(kind), "_repr_html_", None)), kind
    models = _models()
    for m in models:
        html = m._repr_html_()
        assert f"{type(m).__name__} model" in html and m.kind in html
        assert "<script" not in html
    nested = models[4]._repr_html_()
    assert "prandtl-ishlinskii model" in nested  # the inner model as an inner table
    assert "12 values, 0 .. 84.62" in models[0]._repr_html_()  # long arrays summarised


def test_tracking_result_html_names_the_scored_window():
    run = _run_with_startup_transient()
    run.label = "<b>run</b>"
    html = run._repr_html_()
    assert "samples 200..799 of 800" in html and f"{run.e_max:.4g} µm" in html
    assert "&lt;b&gt;run&lt;/b&gt;" in html and "<b>run</b>" not in html  # escaped


# -- progress ----------------------------------------------------------------------------------------
def test_progress_is_a_stage_callback_and_a_counter():
    with ph.Progress("job", total=10, mode="off") as p:
        p("first")
        p("second")
        p.advance(4, best=0.25)
        assert progress.active() is p
        assert "job | second | 4/10 (best 0.25)" in p.text()
        assert '<progress value="4" max="10"' in p.html()
    assert p.closed and progress.active() is None and "done in" in p.text()
    with pytest.raises(ValueError, match="mode"):
        ph.Progress("x", mode="loud")
    with pytest.raises(ValueError, match="total"):
        ph.Progress("x", total=-1, mode="off")


def test_html_progress_escapes_stage_names():
    with ph.Progress("<job>", mode="off") as p:
        p("a < b")
    assert "&lt;job&gt;" in p.html() and "a &lt; b" in p.html()


class _Recorder(ph.Progress):
    def __init__(self) -> None:
        super().__init__("outer", mode="off")
        self.subs: list[tuple[str, int | None]] = []
        self.ticks = 0

    def start_sub(self, description, total=None):
        self.subs.append((description, total))
        super().start_sub(description, total)

    def advance_sub(self, n=1, **fields):
        self.ticks += n
        super().advance_sub(n, **fields)


def test_pso_reports_its_iterations_into_an_open_display():
    with _Recorder() as p:
        p("a stage")
        res = ph.pso_minimize(lambda X: (X**2).sum(axis=1), [(-1, 1)] * 2, seed=0, max_iter=15,
                              description="inner PSO")
        assert p.sub is None  # removed when the run ended
    assert p.subs == [("inner PSO", 15)] and p.ticks == res.nit == 15
    # and with no display open it reports nowhere and returns the same result
    again = ph.pso_minimize(lambda X: (X**2).sum(axis=1), [(-1, 1)] * 2, seed=0, max_iter=15)
    assert again.fun == res.fun and again.nfev == res.nfev


def test_envelope_keeps_each_columns_extremes_in_time_order():
    from piezohyst.plots import _envelope

    g = np.random.default_rng(1)
    t = np.arange(40_003) * 1e-4
    y = np.sin(t) + g.normal(0.0, 0.1, t.size)
    te, ye = _envelope(t, y, columns=500)
    assert te.size < 2 * 500 + 10 and np.all(np.diff(te) > 0)
    assert te[0] == t[0] and te[-1] == t[-1]
    per = t.size // 500
    for c in (0, 137, 499):
        sl = slice(c * per, (c + 1) * per)
        inside = (te >= t[sl][0]) & (te <= t[sl][-1])
        assert ye[inside].max() == y[sl].max() and ye[inside].min() == y[sl].min()
    short_t, short_y = _envelope(t[:1000], y[:1000], columns=500)
    assert short_y.size == 1000
