"""Issue 12: ``piezohyst compensate`` writes the wave table a controller plays - in the format its
extension names, looping without a step (``--periodic``), at the controller's rate (``--fs``) - and
refuses bad input in one line with exit code 2."""

import re

import numpy as np
import pytest

import piezohyst as ph
from piezohyst.cli import main

DT = 1e-4


@pytest.fixture
def pi_file(tmp_path):
    w = np.array([0.02, 0.004, 0.003, -0.001, 0.002, 0.001, 0.0015, -0.0005, 0.001, 0.0008])
    path = tmp_path / "pi.json"
    ph.save_model(ph.PrandtlIshlinskii(ph.equal_thresholds(10, 100.0), w), path)
    return path


@pytest.fixture
def rate_file(tmp_path):
    w = np.array([0.02, 0.004, 0.003, -0.001, 0.002, 0.001, 0.0015, -0.0005, 0.001, 0.0008])
    pi = ph.PrandtlIshlinskii(ph.equal_thresholds(10, 100.0), w)
    path = tmp_path / "rate.json"
    ph.save_model(ph.RateDependent(static=pi, taus=[0.002, 0.02], lag_weights=[0.004, 0.003], dt=DT,
                                   input_tau=5e-4), path)
    return path


def write_ref(path, x, dt=DT, time_col=True):
    if time_col:
        np.savetxt(path, np.column_stack([np.arange(x.size) * dt, x]), delimiter=",", header="t,x",
                   comments="", fmt="%.17g")
    else:
        np.savetxt(path, x, fmt="%.17g")
    return path


def one_line_error(capsys, *words):
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    for w in words:
        assert w in err, err
    return err


def test_each_extension_writes_its_format(tmp_path, pi_file, capsys):
    from scipy.io import loadmat

    ref = write_ref(tmp_path / "ref.csv", ph.sinusoid(5.0, 2, 0.3, 1.7, DT))
    got = {}
    for ext in ("csv", "txt", "npy", "mat", "h"):
        out = tmp_path / f"cmd.{ext}"
        assert main(["compensate", "--model", str(pi_file), "--reference", str(ref), "-o", str(out), "--json"]) == 0
        capsys.readouterr()
        if ext in ("csv", "txt"):
            text = out.read_text()
            assert text.startswith("# piezohyst")
            got[ext] = np.loadtxt(out, delimiter=",", comments="#", skiprows=4)[:, 2]
        elif ext == "npy":
            got[ext] = np.load(out, allow_pickle=False)
        elif ext == "mat":
            s = loadmat(out, squeeze_me=True)
            assert s["fs_hz"] == pytest.approx(1 / DT) and s["model_kind"] == "prandtl-ishlinskii"
            got[ext] = s["u_V"]
        else:
            text = out.read_text()
            assert "#define CMD_LENGTH 4000" in text and re.search(r"#define CMD_RATE_HZ 10000(\.0)?\b", text)
            body = text[text.index("{") + 1:text.index("};")]
            got[ext] = np.array([float(v.strip("() \n")) for v in body.split(",")])
    for ext, u in got.items():
        assert u.shape == (4000,), ext
        np.testing.assert_array_equal(u, got["csv"])


def test_unknown_extension_is_refused_with_the_list(tmp_path, pi_file, capsys):
    ref = write_ref(tmp_path / "ref.csv", ph.sinusoid(5.0, 1, 0.3, 1.7, DT))
    assert main(["compensate", "--model", str(pi_file), "--reference", str(ref), "-o", str(tmp_path / "c.xlsx")]) == 2
    one_line_error(capsys, ".xlsx", ".csv", ".npy", ".mat", ".h")
    assert not (tmp_path / "c.xlsx").exists()


@pytest.mark.parametrize("model", ["pi", "rate"])
def test_periodic_table_loops_without_a_step(tmp_path, pi_file, rate_file, capsys, model):
    import json

    path = pi_file if model == "pi" else rate_file
    x = ph.sinusoid(5.0, 1, 0.3, 1.7, DT)
    ref = write_ref(tmp_path / "ref.csv", x)
    out = tmp_path / "table.npy"
    assert main(["compensate", "--model", str(path), "--reference", str(ref), "--periodic", "-o", str(out),
                 "--json"]) == 0
    res = json.loads(capsys.readouterr().out)["periodic"]
    table = np.load(out)
    assert res["converged"]
    inner = np.max(np.abs(np.diff(table)))
    assert res["largest_inner_step_V"] == pytest.approx(inner)
    # looped, the table's wrap-around is one of its ordinary steps; from rest it is not
    assert abs(table[0] - table[-1]) == pytest.approx(res["wrap_step_V"])
    assert res["wrap_step_V"] <= 1.5 * inner
    assert res["wrap_step_from_rest_V"] > 10 * inner
    # and it is the compensator's periodic steady state: the same cycle again gives the same table
    comp = ph.load_model(path).compensator(DT if model == "rate" else None)
    again = comp.command(np.tile(x, res["cycles"] + 1))[-x.size:]
    assert np.max(np.abs(again - table)) < 1e-5
    if model == "rate":
        assert res["cycles"] > 2  # the lags needed more than one cycle to settle


def test_periodic_refuses_a_reference_that_does_not_loop(tmp_path, pi_file, capsys):
    ref = write_ref(tmp_path / "ref.csv", np.linspace(0.3, 1.7, 2000))
    assert main(["compensate", "--model", str(pi_file), "--reference", str(ref), "--periodic",
                 "-o", str(tmp_path / "t.csv")]) == 2
    one_line_error(capsys, "does not loop")


def test_fs_resamples_to_the_table_rate(tmp_path, pi_file, rate_file, capsys):
    import json

    x = ph.sinusoid(5.0, 1, 0.3, 1.7, DT)
    ref = write_ref(tmp_path / "ref.csv", x)
    out = tmp_path / "t.csv"
    assert main(["compensate", "--model", str(pi_file), "--reference", str(ref), "--fs", "2500", "-o", str(out),
                 "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["resampled"] and res["fs_hz"] == 2500.0
    tab = np.loadtxt(out, delimiter=",", comments="#", skiprows=4)
    assert np.allclose(np.diff(tab[:, 0]), 4e-4)
    assert np.allclose(tab[:, 1], x[::4][:tab.shape[0]], atol=1e-12)  # every 4th sample of the reference
    # a model with dynamics runs only at the rate it was identified at: refused, with the way out
    assert main(["compensate", "--model", str(rate_file), "--reference", str(ref), "--fs", "2500",
                 "-o", str(tmp_path / "r.csv")]) == 2
    one_line_error(capsys, "identified at 10000 Hz", "--fs 10000")
    # a reference at another rate is resampled to the model's own rate
    ref2 = write_ref(tmp_path / "ref2.csv", ph.sinusoid(5.0, 1, 0.3, 1.7, 2e-4), dt=2e-4)
    assert main(["compensate", "--model", str(rate_file), "--reference", str(ref2), "--fs", "10000",
                 "-o", str(tmp_path / "r2.csv")]) == 0
    capsys.readouterr()


@pytest.mark.parametrize("args, words", [
    (["--fs", "0"], ["--fs", "positive"]),
    (["--fs", "nan"], ["--fs"]),
    (["--u-min", "nan"], ["--u-min", "finite"]),
    (["--u-max", "inf"], ["finite"]),
    (["--u-min", "50", "--u-max", "50"], ["--u-min", "below"]),
    (["--u-min", "60", "--u-max", "50"], ["below"]),
])
def test_bad_options_are_one_line_and_exit_2(tmp_path, pi_file, capsys, args, words):
    ref = write_ref(tmp_path / "ref.csv", ph.sinusoid(5.0, 1, 0.3, 1.7, DT))
    assert main(["compensate", "--model", str(pi_file), "--reference", str(ref), "-o", str(tmp_path / "c.csv"),
                 *args]) == 2
    one_line_error(capsys, *words)
    assert not (tmp_path / "c.csv").exists()


@pytest.mark.parametrize("where", ["reference", "time", "unused column"])
def test_non_finite_numbers_anywhere_are_refused(tmp_path, pi_file, capsys, where):
    x = ph.sinusoid(5.0, 1, 0.3, 1.7, DT)
    rows = np.column_stack([np.arange(x.size) * DT, x, np.ones(x.size)])
    rows[100, {"time": 0, "reference": 1, "unused column": 2}[where]] = np.nan if where != "time" else np.inf
    path = tmp_path / "ref.csv"
    np.savetxt(path, rows, delimiter=",", header="t,x,other", comments="", fmt="%.17g")
    assert main(["compensate", "--model", str(pi_file), "--reference", str(path), "--ref-col", "x",
                 "-o", str(tmp_path / "c.csv")]) == 2
    one_line_error(capsys, "NaN or inf", "row 101")


def test_a_period_written_closed_loops_as_the_open_one(tmp_path, pi_file, capsys):
    # found by fuzzing: a period whose last sample repeats its first (as a closed curve is often
    # written) looped with that sample twice, one sample longer than the period
    n = 1000
    x = 1.2 + 0.8 * np.sin(2 * np.pi * np.arange(n + 1) / n)
    t = np.arange(n + 1) * 1e-3
    closed, opened = tmp_path / "closed.csv", tmp_path / "open.csv"
    np.savetxt(closed, np.column_stack([t, x]), delimiter=",", header="t,x", comments="")
    np.savetxt(opened, np.column_stack([t[:-1], x[:-1]]), delimiter=",", header="t,x", comments="")
    tables = {}
    for ref in (closed, opened):
        out = tmp_path / f"u_{ref.stem}.npy"
        assert main(["compensate", "--model", str(pi_file), "--reference", str(ref), "--periodic", "-o", str(out)]) == 0
        tables[ref.stem] = np.load(out)
    assert "last sample repeats its first" in capsys.readouterr().out
    assert tables["closed"].size == n
    np.testing.assert_array_equal(tables["closed"], tables["open"])
