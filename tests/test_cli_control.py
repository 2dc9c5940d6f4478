import json

import numpy as np
import pytest

import piezohyst as ph
from piezohyst import paper_values as pv
from piezohyst.cli import main


@pytest.fixture
def pi_model_file(tmp_path):
    model = ph.PrandtlIshlinskii(ph.equal_thresholds(20, 100.0), np.array(pv.PI_WEIGHTS) * 0.0225)
    return ph.save_model(model, tmp_path / "pi.json"), model


def test_compensate_writes_commands_that_invert_the_model(tmp_path, pi_model_file, capsys):
    path, model = pi_model_file
    ref = ph.sinusoid(1.0, 1, 0.2, 2.0, 1e-3)
    (tmp_path / "ref.csv").write_text("t,x_d\n" + "\n".join(f"{i * 1e-3},{v}" for i, v in enumerate(ref)))
    assert main(["compensate", "--model", str(path), "--reference", str(tmp_path / "ref.csv"),
                 "-o", str(tmp_path / "cmd.csv"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["clipped_samples"] == 0
    cmd = np.loadtxt(tmp_path / "cmd.csv", delimiter=",", comments="#", skiprows=4)
    np.testing.assert_allclose(model.simulate(cmd[:, 2]), ref, atol=1e-9)
    assert (tmp_path / "cmd.csv").read_text().startswith("# piezohyst")


def test_compensate_refuses_out_of_range_command(tmp_path, pi_model_file, capsys):
    path, _ = pi_model_file
    (tmp_path / "ref.csv").write_text("t,x_d\n0,0.5\n0.001,9.0\n")
    code = main(["compensate", "--model", str(path), "--reference", str(tmp_path / "ref.csv"), "-o", str(tmp_path / "c.csv")])
    assert code == 2
    err = capsys.readouterr().err
    assert "leaves the amplifier range" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "c.csv").exists()
    # --clip clips and says how many
    assert main(["compensate", "--model", str(path), "--reference", str(tmp_path / "ref.csv"),
                 "-o", str(tmp_path / "c.csv"), "--clip", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["clipped_samples"] == 1


def test_compensate_and_export_drive_the_range_the_model_was_identified_on(tmp_path, capsys):
    """A stage identified on -100..100 V (a bipolar amplifier): the command table and the exported
    compensator default to that range, not to 0..100 V (which refused every command below 0 V);
    --u-min / --u-max still override each end, and a model file without a record says nothing, so
    0..100 V stays the default there (as for a record within it: the test below)."""
    u = ph.sinusoid(1.0, 3, -100.0, 100.0, 1e-3)
    model = ph.PrandtlIshlinskii(ph.equal_thresholds(10, 100.0), np.full(10, 0.01))
    fit = ph.fit_pi(u, model.simulate(u), n=10)
    path = ph.save_model(fit.model, tmp_path / "bipolar.json", fit=fit)
    ref = ph.sinusoid(1.0, 1, -0.5, 0.5, 1e-3)
    (tmp_path / "ref.csv").write_text("t,x_d\n" + "\n".join(f"{i * 1e-3},{v}" for i, v in enumerate(ref)))
    base = ["compensate", "--model", str(path), "--reference", str(tmp_path / "ref.csv"), "--json"]
    assert main(base + ["-o", str(tmp_path / "a.csv")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["amplifier_range_V"] == [-100.0, 100.0] and "identified" in res["amplifier_range_from"]
    assert res["clipped_samples"] == 0 and res["u_min_V"] < -10.0
    # an end given on the command line wins, and the error names where each end came from
    assert main(base + ["-o", str(tmp_path / "b.csv"), "--u-min", "0"]) == 2
    err = capsys.readouterr().err
    assert "0..100 V (from --u-min and the default 100 V)" in err, err
    assert main(base + ["-o", str(tmp_path / "b.csv"), "--u-max", "0"]) == 2
    assert "-100..0 V (from the model's identified input range and --u-max)" in capsys.readouterr().err
    assert main(["export", str(path), "--to", "c", "--out", str(tmp_path / "fw"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["amplifier_range_V"] == [-100.0, 100.0]
    assert "#define" in (tmp_path / "fw" / "compensator.h").read_text()
    # a bare model file (no record): the default 0..100 V
    bare = ph.save_model(model, tmp_path / "bare.json")
    assert main(["compensate", "--model", str(bare), "--reference", str(tmp_path / "ref.csv"), "--json",
                 "-o", str(tmp_path / "c.csv"), "--clip"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["amplifier_range_V"] == [0.0, 100.0] and "default" in res["amplifier_range_from"]


def test_track_with_a_saved_model(tmp_path, capsys):
    rig = ph.VirtualRig(seed=0)
    ds = rig.excite(ph.sinusoid(1.0, 2, 0.0, 100.0, rig.dt))
    path = ph.save_model(ph.fit_pi(ds.u, ds.y).model, tmp_path / "m.json")
    assert main(["track", "--model", str(path), "--freq", "1,5", "--cycles", "2", "--feedback", "pid",
                 "--ki", "500", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)["results"]
    assert [r["freq_hz"] for r in res] == [1.0, 5.0]
    assert all(r["e_max_percent"] < 5 for r in res)


def test_track_needs_a_model(capsys):
    assert main(["track", "--freq", "1"]) == 2
    assert "--model" in capsys.readouterr().err


def test_track_a_reference_file_of_any_shape_with_its_own_period(tmp_path, capsys):
    # an AFM raster (slow rise, fast return): the period comes from the file, exactly, so the
    # scored cycles are whole ones (issue 15: a triangle's estimate used to fail, e_max 9.33 %)
    t = np.arange(16000) * 1e-4
    x = 0.3 + 1.8 * np.concatenate([np.linspace(0, 1, 3000), np.linspace(1, 0, 1000)] * 4)
    ref = tmp_path / "raster.csv"
    np.savetxt(ref, np.column_stack([t, x]), delimiter=",", header="t,x", comments="")
    out = tmp_path / "runs.csv"
    assert main(["track", "--method", "best", "--reference", str(ref), "-o", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    r = res["results"][0]
    assert r["evaluated_samples"] == 12000  # cycles 2-4 of 4000 samples
    assert r["e_max_percent"] < 2.0
    runs = np.loadtxt(out, delimiter=",", comments="#", skiprows=3)
    assert runs.shape == (16000, 4) and np.allclose(runs[:, 1], x)
    # stdin in, stdout out: the file alone on stdout
    import subprocess
    import sys

    p = subprocess.run([sys.executable, "-m", "piezohyst", "track", "--model", str(_pi_model_file(tmp_path)),
                        "--reference", "-", "-o", "-"], input=ref.read_bytes(), capture_output=True, timeout=300)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.decode().splitlines()
    assert lines[0].startswith("# piezohyst") and lines[2].startswith("t_ref_s") and len(lines) == 3 + 16000
    assert b"Tracking" in p.stderr


def test_track_a_reference_that_holds_still_prints_no_percentage(tmp_path, capsys):
    # a constant reference has no span: the percentages are "-" with a note (they printed "nan"),
    # null in --json, and the errors in um stand
    ref = tmp_path / "hold.csv"
    np.savetxt(ref, np.column_stack([np.arange(3000) * 1e-4, np.full(3000, 1.2)]), delimiter=",", header="t,x",
               comments="")
    model = str(_pi_model_file(tmp_path))
    assert main(["track", "--model", model, "--reference", str(ref)]) == 0
    out = capsys.readouterr().out
    assert "nan" not in out and "the reference does not move" in out
    assert main(["track", "--model", model, "--reference", str(ref), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)["results"][0]
    assert r["e_max_percent"] is None and r["e_max_um"] > 0


def _pi_model_file(tmp_path):
    import piezohyst as ph

    rig = ph.VirtualRig(seed=0)
    ds = rig.excite(ph.sinusoid(1.0, 2, 0.0, 100.0, rig.dt))
    return ph.save_model(ph.fit_pi(ds).model, tmp_path / "pi.json")


def test_compensate_says_when_the_commands_leave_the_identified_range(tmp_path, capsys):
    """A model identified on 0-50 V, asked for a trajectory that needs up to ~96 V: the table is
    written (the amplifier allows it) with a warning that the model extrapolates there, on stderr
    and in --json's warnings; within the range, and for a file without the fit's range (one saved
    without a fit, or before it was recorded), nothing is said."""
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(10, 100.0), np.linspace(0.02, 0.002, 10))
    u = 25.0 - 25.0 * np.cos(2 * np.pi * np.arange(20000) * 1e-4)
    fit = ph.fit_model(u, true.simulate(u), 1e-4, kind="pi")
    path = ph.save_model(fit.model, tmp_path / "m.json", fit=fit)
    assert json.loads(path.read_text())["fit"]["input_range_V"] == [0.0, 50.0]
    bare = ph.save_model(fit.model, tmp_path / "bare.json")
    k = np.arange(1000) / 1000
    for name, lo, hi in (("far", 10.0, 90.0), ("within", 10.0, 45.0)):
        u2 = 0.5 * (lo + hi) - 0.5 * (hi - lo) * np.cos(2 * np.pi * k)
        ref = true.simulate(np.concatenate([u2, u2]))[1000:]
        (tmp_path / f"{name}.csv").write_text("t,x_d\n" + "\n".join(f"{i * 1e-4},{v}" for i, v in enumerate(ref)))
    for model, name, said in ((path, "far", True), (path, "within", False), (bare, "far", False)):
        assert main(["compensate", "--model", str(model), "--reference", str(tmp_path / f"{name}.csv"),
                     "-o", str(tmp_path / f"{model.stem}_{name}.csv"), "--json"]) == 0
        cap = capsys.readouterr()
        warned = json.loads(cap.out)["warnings"]
        assert bool(warned) is said and ("beyond the 0 .. 50 V the model was identified on" in cap.err) is said, cap
        if said:
            assert "the command goes up to 9" in warned[0], warned


def test_stdin_and_stdout_are_named_as_such_in_messages(tmp_path, monkeypatch, capsys):
    # found by fuzzing: an empty stdin was "/tmp/piezohyst-.../stdin.csv: the file is empty", and
    # -o - said it wrote to /tmp/piezohyst-.../stdout.csv, a file that was never there for the user
    import io
    import sys

    model = str(_pi_model_file(tmp_path))
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(b"")))
    assert main(["track", "--model", model, "--reference", "-"]) == 2
    err = capsys.readouterr().err
    assert "stdin: the file is empty" in err and "/stdin.csv" not in err
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(b"t,x\n0,1\n0.001,1.2\n0.002,1.3\n")))
    assert main(["compensate", "--model", model, "--reference", "-", "-o", "-"]) == 0
    err = capsys.readouterr().err
    assert "to stdout" in err and "stdout.csv" not in err


def test_long_runs_show_progress_on_a_terminal_with_or_without_json(tmp_path):
    """``track`` showed nothing for 12 s, and identify, reproduce and benchmark showed nothing with
    --json even when standard error was a terminal (found by a helper): the step under way is
    shown there, transient, and standard output keeps the JSON alone."""
    import os
    import pty
    import subprocess
    import sys

    pi = tmp_path / "pi.json"
    ph.save_model(ph.PrandtlIshlinskii(np.linspace(0, 90, 10), np.full(10, 0.02)), pi)
    controller, terminal = pty.openpty()
    try:
        proc = subprocess.run([sys.executable, "-m", "piezohyst", "track", "--model", str(pi), "--freq", "1", "--json"],
                              stdout=subprocess.PIPE, stderr=terminal, timeout=300, check=False)
        os.close(terminal)
        shown = b""
        while True:
            try:
                chunk = os.read(controller, 65536)
            except OSError:  # the terminal's other end closed: all read
                break
            if not chunk:
                break
            shown += chunk
    finally:
        os.close(controller)
    assert proc.returncode == 0
    assert "results" in json.loads(proc.stdout)  # the data alone
    assert b"tracking 1 Hz" in shown, shown[-300:]


def test_an_error_into_a_log_is_its_one_line(tmp_path):
    """Into a file or a pipe a spinner printed a blank line before the error (``benchmark
    bouc-wen --data`` a CSV: found by a helper): progress is for terminals only."""
    import subprocess
    import sys

    bad = tmp_path / "x.csv"
    bad.write_text("t,u,y\n0,0,0\n1,1,1\n", encoding="utf-8")
    proc = subprocess.run([sys.executable, "-m", "piezohyst", "benchmark", "bouc-wen", "--data", str(bad)],
                          capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.startswith("piezohyst benchmark: error: ") and proc.stderr.count("\n") == 1, repr(proc.stderr)
