import json
import os

import numpy as np
import pytest

import piezohyst as ph
from piezohyst.cli import main

from .conftest import DATA

DBO = os.path.join(DATA, "piezo-dbo", "Model_Vi_Do.dat")


def test_identify_real_data_writes_a_model_that_loads_back(tmp_path, capsys):
    out = tmp_path / "m.json"
    code = main(["identify", DBO, "--u-col", "0", "--y-col", "4", "--fs", "200", "--model", "pi",
                 "--method", "lsq", "-o", str(out), "--json"])
    assert code == 0
    printed = json.loads(capsys.readouterr().out)
    model = ph.load_model(out)
    assert model.weights.tolist() == printed["parameters"]["weights"]
    # same model as the Python API gives on the same data
    ds = ph.load_dataset(DBO, u_col=0, y_col=4, fs=200)
    assert ph.fit_pi(ds.u, ds.y).model == model
    # refuses to overwrite without --force
    assert main(["identify", DBO, "--u-col", "0", "--y-col", "4", "--fs", "200", "-o", str(out)]) == 2
    assert "--force" in capsys.readouterr().err


def test_identify_states_the_units_of_its_figures(capsys):
    """The table said "units of y" and "output units", and the JSON stated no unit for its RMSEs
    (found by a helper): the data are read into µm, and both say so."""
    args = ["identify", DBO, "--u-col", "0", "--y-col", "4", "--fs", "200", "--model", "pi", "--method", "lsq"]
    assert main(args + ["--json"]) == 0
    units = json.loads(capsys.readouterr().out)["units"]
    assert units["y"] == units["rmse"] == units["max_abs_error"] == units["sensor_noise_rms"] == "um"
    assert main(args) == 0
    table = capsys.readouterr().out
    assert "units of y" not in table and "output units" not in table
    assert "weights w_i in µm/V" in table and " µm (" in table.split("fit RMSE", 1)[1].splitlines()[0]


def test_validating_on_the_records_end_trains_on_the_rest_only(capsys):
    # without --train the fit took every sample, the validated ones too, and called their error
    # held out (0.339 against 0.402 fitted on 0:6000 alone; found by fuzzing)
    def validation(*extra):
        assert main(["identify", DBO, "--u-col", "0", "--y-col", "4", "--fs", "200", "--model", "pi", "--method",
                     "lsq", *extra, "--json"]) == 0
        return json.loads(capsys.readouterr().out)["validation"][0]["rmse"]

    assert validation("--validate", "6000:") == validation("--train", "0:6000", "--validate", "6000:")


def test_identify_validation_slices(capsys):
    code = main(["identify", DBO, "--u-col", "0", "--y-col", "4", "--fs", "200", "--train", "0:4000",
                 "--validate", "4000:8000", "--json"])
    assert code == 0
    v = json.loads(capsys.readouterr().out)["validation"][0]
    assert v["n_samples"] == 4000 and v["rmse"] < 0.425


@pytest.mark.parametrize(
    "content, args, needle",
    [
        ("1 2\n3 4\n", [], "no header"),
        ("t,u,y\n0,1,2\n1,x,3\n", [], "not a number"),
        (b"\x89PNG\r\n\x1a\n\x00\x00", [], "not a text file"),
    ],
)
def test_malformed_data_exit_2_one_line(tmp_path, capsys, content, args, needle):
    p = tmp_path / "bad.dat"
    if isinstance(content, bytes):
        p.write_bytes(content)
    else:
        p.write_text(content)
    assert main(["identify", str(p), *args]) == 2
    err = capsys.readouterr().err
    assert needle in err and "bad.dat" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_missing_file_exit_2(capsys):
    assert main(["identify", "/no/such/file.csv"]) == 2
    assert "no such file" in capsys.readouterr().err


def test_bouc_wen_identify_cli(tmp_path, capsys):
    u = ph.sinusoid(1.0, 1, 0.0, 100.0, 1e-3)
    y = ph.BoucWen(m=0.75, b=27.96, k=8.54e7, d1=2.15e-8, alpha=0.472, beta=0.072).simulate(u, 1e-3) * 1e6
    ds = ph.Dataset(ph.signals.time_vector(u.size, 1e-3), u, y)
    f = ph.save_dataset(tmp_path / "bw.csv", ds)
    assert main(["identify", str(f), "--model", "bouc-wen", "--method", "pso", "--iterations", "30",
                 "--json", "-o", str(tmp_path / "bw.json")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert "sensitivity" in res["fit"]
    assert isinstance(ph.load_model(tmp_path / "bw.json"), ph.BoucWen)


TEST = os.path.join(DATA, "piezo-dbo", "Test_Vi_Do_Di.dat")


@pytest.mark.slow
def test_identify_auto_on_real_data_beats_the_data_sets_own_model(tmp_path, capsys):
    # issue 11's acceptance command. Reference figures (shared/data/README.md and issue 11): the
    # authors' own model (a backlash operator and a static output map, fitted on earlier rows)
    # predicts rows 4000:8000 with RMS 0.273; piezohyst 0.1.0's best was 0.40 there and 0.50 on
    # the test file (no offset refit)
    code = main(["identify", DBO, "--u-col", "0", "--y-col", "4", "--fs", "200", "--model", "auto",
                 "--train", "0:4000", "--validate", "4000:8000", "--validate-data", TEST, "--json",
                 "-o", str(tmp_path / "m.json")])
    assert code == 0
    res = json.loads(capsys.readouterr().out)
    assert res["model"] in ph.models.kinds()
    v = res["validation"]
    assert [x["data"] for x in v] == ["samples 4000:8000", TEST]
    assert v[0]["rmse"] < 0.27 and v[1]["rmse"] < 0.50
    # the saved model gives the same prediction through the Python API (any kind)
    m = ph.load_model(tmp_path / "m.json")
    assert m.kind == res["model"]
    ds = ph.load_dataset(DBO, u_col=0, y_col=4, fs=200)
    d = res["fit"]["delay"]
    pred = m.predict(ds.u[:8000], ds.dt)
    rmse = float(np.sqrt(np.mean((ds.y[4000:8000] - pred[4000 - d:8000 - d]) ** 2)))
    assert rmse == pytest.approx(v[0]["rmse"], rel=1e-9)


def test_identify_warmup_runs_through_the_first_samples_without_fitting_them(tmp_path, capsys):
    # a record that starts with a conditioning sweep from a state the model cannot know: with the
    # sweep as warm-up the fit is the one fit_model gives with warmup, and it fits the rest better
    rng = np.random.default_rng(3)
    true = ph.Preisach(lo=0.0, hi=100.0, weights=rng.random(ph.models.preisach.grid_size(6)) * 0.01, slope=0.02)

    def rc(a, b, n):
        return a + (b - a) * 0.5 * (1 - np.cos(np.pi * np.arange(1, n + 1) / n))

    past = np.concatenate([rc(0.0, 90.0, 500), rc(90.0, 40.0, 400)])
    sweep = np.concatenate([rc(40.0, 100.0, 400), rc(100.0, 0.0, 600)])
    t = np.arange(5000) * 1e-3
    u = np.concatenate([sweep, 50.0 - 50.0 * np.cos(2 * np.pi * t) * np.linspace(1.0, 0.3, t.size)])
    y = true.simulate(np.concatenate([past, u]))[past.size:] + 0.002 * rng.standard_normal(u.size)
    path = tmp_path / "rec.csv"
    np.savetxt(path, np.column_stack([np.arange(u.size) * 1e-3, u, y]), delimiter=",", header="t,u,y", comments="")
    got = {}
    for w in (0, sweep.size):
        assert main(["identify", str(path), "--model", "preisach", "--delay", "0", "--warmup", str(w), "--json"]) == 0
        got[w] = json.loads(capsys.readouterr().out)
    want = ph.fit_model(u, y, 1e-3, kind="preisach", delay=0, warmup=sweep.size)
    assert got[sweep.size]["fit"]["rmse"] == pytest.approx(want.rmse, rel=1e-12)
    assert got[sweep.size]["fit"]["rmse"] < got[0]["fit"]["rmse"]
    assert main(["identify", str(path), "--model", "pi", "--method", "lsq", "--warmup", "10"]) == 2
    assert "--warmup" in capsys.readouterr().err


def test_identify_reads_the_rigs_own_loops_file(tmp_path, capsys):
    # `piezohyst rig` writes one (t, u, y) triple per frequency: with one frequency identify finds
    # its columns; with several it says which records there are, in the command line's spelling
    one, three = tmp_path / "one", tmp_path / "three"
    assert main(["rig", "--freq", "2", "--cycles", "2", "--out", str(one)]) == 0
    assert main(["identify", str(one / "rig_loops.csv"), "--model", "pi", "--out", str(tmp_path / "m.json")]) == 0
    assert ph.load_model(tmp_path / "m.json").kind == "prandtl-ishlinskii"
    assert main(["rig", "--freq", "2,4", "--cycles", "2", "--out", str(three)]) == 0
    capsys.readouterr()
    assert main(["identify", str(three / "rig_loops.csv"), "--model", "pi"]) != 0
    err = capsys.readouterr().err
    assert "holds 2 records (2hz, 4hz)" in err and "(--u-col, --y-col)" in err and "in Python" not in err
    assert main(["identify", str(three / "rig_loops.csv"), "--model", "pi", "--u-col", "u_4Hz_V",
                 "--y-col", "y_4Hz_um"]) == 0


def test_identify_bridges_isolated_glitches_and_says_so(tmp_path, capsys):
    """A record with a few gross glitches (one sample off by half the span): the search bridges
    them and the report warns; --keep-glitches fits them as they are (and so fits worse)."""
    rng = np.random.default_rng(5)
    true = ph.Preisach(lo=0.0, hi=100.0, weights=rng.random(ph.models.preisach.grid_size(6)) * 0.01, slope=0.02)
    t = np.arange(6000) * 1e-3
    u = 50.0 - 50.0 * np.cos(2 * np.pi * t) * np.linspace(1.0, 0.3, t.size)
    y = true.simulate(u) + 0.002 * rng.standard_normal(u.size)
    y[[700, 2300, 4100, 5200]] += 0.5 * np.ptp(y)
    path = tmp_path / "rec.csv"
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="")
    got = {}
    for flag in ([], ["--keep-glitches"]):
        assert main(["identify", str(path), "--model", "preisach", "--delay", "0", *flag, "--json"]) == 0
        got[bool(flag)] = json.loads(capsys.readouterr().out)
    assert any("4 isolated glitches" in w and "sample 700" in w for w in got[False]["warnings"])
    assert not any("glitch" in w for w in got[True]["warnings"])
    assert got[False]["fit"]["rmse"] < 0.5 * got[True]["fit"]["rmse"]


def test_resample_reads_a_record_with_a_dropped_sample(tmp_path, capsys):
    # the refusal of a non-uniform time column pointed to --resample, which did not exist
    dt = 1e-3
    u = ph.sinusoid(2.0, 3, 0.0, 100.0, dt)
    y = ph.paper_values.pi_model().simulate(u) * 0.05
    keep = np.arange(u.size) != 700  # one sample lost: a step of 2 ms in the time column
    t = np.arange(u.size)[keep] * dt
    path = tmp_path / "gap.csv"
    path.write_text("t,u,y\n" + "\n".join(f"{a:.6g},{b:.9g},{c:.9g}" for a, b, c in zip(t, u[keep], y[keep])) + "\n")
    assert main(["identify", str(path), "--model", "pi", "--method", "lsq"]) == 2
    assert "--resample" in capsys.readouterr().err
    assert main(["identify", str(path), "--model", "pi", "--method", "lsq", "--resample", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["fit"]["rmse"] < 0.01 * float(np.ptp(y))
