"""Figures drawn by the worker process (experiments._figures) are the figures drawn in-process."""

import dataclasses
import io
import pickle
import threading

import numpy as np
import pytest
from PIL import Image

from piezohyst._figures import BackgroundFigures, FigureJob, render

WHO = "piezohyst test; command: reproduce --out x; at 2000-01-01T00:00:00Z"


def _jobs():
    t = np.arange(4000) * 1e-4
    u = 50 - 50 * np.cos(2 * np.pi * 2 * t)
    y = 0.02 * u + 0.1 * np.sin(2 * np.pi * 2 * t)
    return [
        FigureJob("a", "a.png", "plot_loops", ([("2 Hz", u[-2000:], y[-2000:])],), {"title": "loops"}, note="loops"),
        FigureJob("b", "b.png", "plot_tracking", (t, y, y + 0.001), {"command": u, "scored": slice(2000, 4000),
                                                                     "u_range": (0.0, 100.0), "title": "run"},
                  note="tracking"),
    ]


def _pixels(path):
    with Image.open(path) as im:
        return np.asarray(im)


def _info(path):
    with Image.open(path) as im:
        return dict(im.info)


def test_worker_draws_what_render_draws(tmp_path):
    here = render(_jobs(), tmp_path / "here", ("png", "svg"), producer=WHO)
    with BackgroundFigures() as bg:
        bg.submit(_jobs(), tmp_path / "there", ("png", "svg"), producer=WHO)
        there = bg.result()
    assert list(here) == list(there) == ["a", "a.svg", "b", "b.svg"]
    for key in ("a", "b"):
        np.testing.assert_array_equal(_pixels(here[key]), _pixels(there[key]))
        info = _info(there[key])
        assert info["Software"] == WHO and info["Description"] == dict(a="loops", b="tracking")[key]
        assert WHO in there[f"{key}.svg"].read_text(encoding="utf-8")


def test_a_dead_worker_means_drawing_here(tmp_path):
    with BackgroundFigures() as bg:
        bg.submit(_jobs(), tmp_path, ("png",), producer=WHO)
        bg._proc.kill()
        bg._proc.wait()
        paths = bg.result()
    assert sorted(p.name for p in paths.values()) == ["a.png", "b.png"]
    assert all(p.stat().st_size > 1000 for p in paths.values())


def test_a_failing_job_raises_the_real_error_here(tmp_path):
    bad = [FigureJob("x", "x.png", "no_such_plot", (), {}, note="")]
    with BackgroundFigures() as bg:
        bg.submit(bad, tmp_path, ("png",))
        with pytest.raises(AttributeError, match="no_such_plot"):
            bg.result()


def test_warnings_of_the_worker_are_issued_here(tmp_path):
    class FakeProc:
        def __init__(self, reply):
            self.stdout = io.BytesIO(pickle.dumps(reply))
            self.stdin = io.BytesIO()

        def poll(self):
            return 0

    bg = BackgroundFigures.__new__(BackgroundFigures)  # the real class, its worker faked
    bg._lock, bg._thread, bg._spec = threading.Lock(), None, None
    bg._proc = FakeProc(("ok", {"a": tmp_path / "a.png"}, [("the worker saw this", UserWarning)]))
    bg.STEAL_FROM = 10**9  # let the (fake) worker take the job
    bg.submit([FigureJob("a", "a.png", "plot_loops")], tmp_path, ("png",), producer=WHO)
    bg._thread.join()
    with pytest.warns(UserWarning, match="the worker saw this"):
        assert bg.result() == {"a": tmp_path / "a.png"}
    bg.close(kill=True)


def test_the_caller_draws_what_the_worker_has_not_started(tmp_path):
    jobs = [dataclasses.replace(j, key=f"{j.key}{i}", file=f"{j.key}{i}.png") for i, j in enumerate(_jobs() * 3)]
    here = render(jobs, tmp_path / "here", ("png",), producer=WHO)
    with BackgroundFigures() as bg:
        bg.submit(jobs, tmp_path / "both", ("png",), producer=WHO)
        both = bg.result()  # at once: the worker is still importing, so most are drawn here
    assert list(both) == list(here)
    for key in here:
        np.testing.assert_array_equal(_pixels(here[key]), _pixels(both[key]))


def test_one_set_per_submission(tmp_path):
    with BackgroundFigures() as bg:
        with pytest.raises(RuntimeError):
            bg.result()
        bg.submit([], tmp_path, ("png",))
        with pytest.raises(RuntimeError):
            bg.submit([], tmp_path, ("png",))
        assert bg.result() == {}


def test_a_failing_run_kills_the_worker_and_leaves_nothing(tmp_path, monkeypatch):
    from piezohyst.cli import main
    from piezohyst.experiments import paper

    started = []
    init = BackgroundFigures.__init__

    def spy(self):
        init(self)
        started.append(self)

    def failing_run(plant, *, seed, on_step=None, on_paper_part=None):
        paper.run_paper_experiment(plant, seed=seed, freqs=(1.0,), cycles=2, pso_bw=(4, 3), pso_pi=(4, 3),
                                   beyond=False, on_paper_part=on_paper_part)  # the figures are submitted
        raise RuntimeError("the rig caught fire")

    monkeypatch.setattr(BackgroundFigures, "__init__", spy)
    monkeypatch.setattr(paper, "run_paper_experiment", failing_run)
    out = tmp_path / "results"
    try:
        code = main(["reproduce", "--out", str(out), "--json"])
    except RuntimeError:
        code = 1
    assert code != 0
    assert len(started) == 1 and started[0]._proc is None  # stopped
    assert not out.exists() and list(tmp_path.iterdir()) == []  # no set, no temporary folder


def test_no_worker_process_means_drawing_here(tmp_path, monkeypatch):
    import subprocess

    def refuse(*a, **k):
        raise OSError("no processes left")

    monkeypatch.setattr(subprocess, "Popen", refuse)
    with BackgroundFigures() as bg:
        bg.submit(_jobs(), tmp_path, ("png",), producer=WHO)
        paths = bg.result()
    assert sorted(p.name for p in paths.values()) == ["a.png", "b.png"]
