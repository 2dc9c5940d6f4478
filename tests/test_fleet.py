"""Fleet identification (piezohyst.fleet, ``piezohyst fleet identify``): on a LocalCluster in this
process, on a ``dask scheduler`` + ``dask worker`` pair started here (loopback only, killed at the
end), and serially; the same figures every way, the corrupt record a row, the odd actuator flagged."""

import json
import math
import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given
from hypothesis import strategies as st

import piezohyst as ph
from piezohyst.cli import main
from piezohyst.fleet import (
    COLUMNS,
    FitOptions,
    MissingExtraError,
    batch_statistics,
    find_records,
    identify_many,
    identify_record,
    local_cluster,
    plot_histograms,
    write_simulated_batch,
)

from .conftest import ROOT

N_ACTUATORS = 40


def _truth(path):
    """The simulated actuator's own record of its gain and outlier status (the "# meta:" line)."""
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        if line.startswith("# meta:"):
            return json.loads(line[len("# meta:"):])["simulated"]
    raise AssertionError(f"{path} has no meta line")


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """40 simulated actuators (one with 1.6x the gain) of 1500 samples, and one corrupt file."""
    folder = tmp_path_factory.mktemp("batch")
    files = write_simulated_batch(folder, N_ACTUATORS, seed=7, fs=500.0, cycles=3, outliers=1, outlier_gain=1.6)
    (folder / "corrupt.csv").write_text("t_s,u_V,y_um\n0,0,0\n0.002,1\n", encoding="utf-8")
    odd = [f.stem for f in files if _truth(f)["outlier"]]
    assert len(odd) == 1
    return {"dir": folder, "files": files, "outlier": odd[0]}


@pytest.fixture(scope="module")
def serial(batch):
    return identify_many(batch["dir"], client="serial")


def _fit_pi_rmse(path):
    ds = ph.load_dataset(path)
    return ph.fit_pi(ds.u, ds.y).rmse


def _check_batch(df, batch):
    """What every way of running the batch must give."""
    assert list(df.columns) == list(COLUMNS)
    assert len(df) == N_ACTUATORS + 1
    assert df["record"].tolist() == sorted([f.stem for f in batch["files"]] + ["corrupt"])
    bad = df[df["record"] == "corrupt"].iloc[0]
    assert bad["status"] == "error" and "corrupt.csv" in bad["error"] and "DataError" in bad["error"]
    assert (df[df["record"] != "corrupt"]["status"] == "ok").all()
    good = df[df["status"] == "ok"]
    # the flags by hand: beyond 5 raw MADs from the median in any figure (a batch of 40 normal
    # actuators may hold a genuine 3.4-sigma one too; the simulated odd one must be among them)
    by_hand = np.zeros(len(good), dtype=bool)
    for col in ("gain_um_per_v", "loop_width_percent", "fit_rmse_percent_of_span"):
        x = good[col].to_numpy()
        med = np.median(x)
        by_hand |= np.abs(x - med) > 5 * np.median(np.abs(x - med))
    assert good["outlier"].tolist() == by_hand.tolist() and not df[df["status"] != "ok"]["outlier"].any()
    odd = good[good["record"] == batch["outlier"]].iloc[0]
    assert odd["outlier"] and odd["outlier_reason"].startswith("gain")
    assert odd["gain_um_per_v"] == good["gain_um_per_v"].max()
    assert np.all(good["holdout_rmse_um"].isna())  # fit_pi fits the whole record: no hold-out figure
    assert np.all(good["loop_width_percent"].between(5, 25)) and np.all(good["gain_um_per_v"] > 0)


def test_serial_batch_equals_fit_pi_and_flags_the_odd_actuator(batch, serial):
    _check_batch(serial, batch)
    for f in batch["files"][:5]:
        row = serial[serial["file"] == str(f)].iloc[0]
        assert row["fit_rmse_um"] == _fit_pi_rmse(f)
        ds = ph.load_dataset(f)
        lf = ph.loop_figures(ds.u, ds.y)
        assert row["loop_width_um"] == lf.width and row["gain_um_per_v"] == np.ptp(ds.y) / np.ptp(ds.u)


def test_local_cluster_two_workers_equals_serial(batch, serial, tmp_path, monkeypatch):
    from distributed import get_task_stream

    # every record "quick": the first four go one per task, the rest in groups of at most
    # ceil(37 / 8) = 5 records (four tasks per worker), shrinking to single records at the end
    monkeypatch.setattr(ph.fleet, "TASK_SECONDS", 1e9)
    client = local_cluster(2)
    try:
        env = client.run(lambda: (os.environ.get("NUMBA_NUM_THREADS"), __import__("numba").config.NUMBA_NUM_THREADS))
        assert len(env) == 2 and all(v == ("1", 1) for v in env.values())
        assert all(w["nthreads"] == 1 for w in client.scheduler_info()["workers"].values())
        ticks = client.run(lambda: __import__("dask").config.get("distributed.admin.tick.interval"))
        assert set(ticks.values()) == {ph.fleet.LOCAL_CLUSTER_CONFIG["distributed.admin.tick.interval"]}
        profiling = client.run(lambda: __import__("dask").config.get("distributed.worker.profile.enabled"))
        assert set(profiling.values()) == {False}
        seen = []
        with get_task_stream(client) as stream:
            df = identify_many(batch["dir"], client=client, out=tmp_path,
                               progress=lambda d, n, row: seen.append((d, n)))
        tasks = {t["key"] for t in stream.data}
        assert len(tasks) == 4 + len(ph.fleet.group_sizes(N_ACTUATORS + 1 - 4, 5, 2)) == len({t for t in tasks if "piezohyst-fleet-" in str(t)}), sorted(tasks)
        assert client.status == "running"  # a client we passed is left open
        pids = list(client.run(os.getpid).values())
    finally:
        client.close()
        client.cluster.close()
    import psutil

    _, alive = psutil.wait_procs([psutil.Process(p) for p in pids if psutil.pid_exists(p)], timeout=20)
    assert not alive  # the workers stopped with the cluster
    _check_batch(df, batch)
    assert sorted(seen) == [(i, N_ACTUATORS + 1) for i in range(1, N_ACTUATORS + 2)]
    figures = [c for c in COLUMNS if c.endswith(("_um", "_percent", "_span", "_per_v", "samples", "fs_hz"))]
    pd.testing.assert_frame_equal(df[["record", "status", "kind", "method", *figures]],
                                  serial[["record", "status", "kind", "method", *figures]])
    models = sorted((tmp_path / "models").glob("*.json"))
    assert len(models) == N_ACTUATORS
    ds = ph.load_dataset(batch["files"][0])
    assert ph.load_model(models[0]) == ph.fit_pi(ds.u, ds.y).model
    back = pd.read_csv(tmp_path / "summary.csv", keep_default_na=False,
                       na_values=[""])
    assert back["fit_rmse_um"].equals(df["fit_rmse_um"]) and back["outlier"].tolist() == df["outlier"].tolist()


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(procs):
    """Stop the scheduler and worker (SIGTERM, then SIGKILL) and every process they started;
    return the pids of any that had to be killed at the end."""
    import psutil

    tree = []
    for p in procs:
        try:
            tree += psutil.Process(p.pid).children(recursive=True)
        except psutil.NoSuchProcess:
            pass
    for p in reversed(procs):
        p.terminate()
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=10)
    _, alive = psutil.wait_procs(tree, timeout=20)
    for c in alive:
        c.kill()
    return [c.pid for c in alive]


def _scheduler_and_worker(tmp_path, procs):
    """Start a ``dask scheduler`` and one ``dask worker`` on 127.0.0.1 (appended to ``procs``, the
    scheduler first, for :func:`_stop`), wait (bounded) until the worker is there; the address."""
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "NUMBA_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join([os.path.join(ROOT, "src"), os.environ.get("PYTHONPATH", "")])}
    with open(tmp_path / "dask.log", "wb") as log:  # the children keep their own copy of it
        procs.append(subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1",
                                       "--port", str(port), "--no-dashboard", "--dashboard-address", "127.0.0.1:0",
                                       "--idle-timeout", "300"],
                                      env=env, stdout=log, stderr=subprocess.STDOUT))
        procs.append(subprocess.Popen([sys.executable, "-m", "dask", "worker", address, "--host", "127.0.0.1",
                                       "--nthreads", "1", "--nworkers", "1", "--no-dashboard",
                                       "--death-timeout", "60"],
                                      env=env, stdout=log, stderr=subprocess.STDOUT))
    from distributed import Client

    with Client(address, timeout=60) as c:  # bounded wait for the pair to come up
        c.wait_for_workers(1, timeout=120)
    return address


def test_cli_on_a_dask_scheduler_and_worker_started_here(batch, serial, tmp_path, capsys):
    procs = []
    try:
        address = _scheduler_and_worker(tmp_path, procs)
        out = tmp_path / "out"
        code = main(["fleet", "identify", str(batch["dir"]), "--model", "pi", "--scheduler", address,
                     "--out", str(out), "--json"])
        printed = capsys.readouterr()
        assert code == 0, printed.err
    finally:
        left = _stop(procs)
    assert not left, f"processes still running after the test: {left}"
    doc = json.loads(printed.out)  # nothing else on stdout
    summary = pd.read_csv(out / "summary.csv", keep_default_na=False, na_values=[""])  # round-trips floats
    assert doc["records"] == N_ACTUATORS + 1 and doc["ok"] == N_ACTUATORS and doc["failed"] == 1
    assert doc["cluster"] == address
    assert [o["record"] for o in doc["statistics"]["outliers"]] == summary[summary["outlier"]]["record"].tolist()
    assert doc["failed_records"][0]["record"] == "corrupt"
    # the file says what wrote it, in a column (a comment line would be a data row to a spreadsheet)
    assert summary["written_by"].str.startswith("piezohyst ").all()
    assert f"command: piezohyst fleet identify {batch['dir']}" in summary["written_by"].iloc[0]
    _check_batch(summary.drop(columns="written_by"), batch)
    assert len(list((out / "models").glob("*.json"))) == N_ACTUATORS
    assert (out / "fleet_histograms.png").stat().st_size > 0
    for _, row in summary[summary["status"] == "ok"].iterrows():  # the acceptance: ph.fit_pi on the same files
        assert row["fit_rmse_um"] == _fit_pi_rmse(row["file"]), row["record"]
        assert (out / "models" / f"{row['record']}.json").is_file()
    assert summary["fit_rmse_um"].equals(serial["fit_rmse_um"])


def test_resume_skips_done_records_and_checks_they_still_apply(tmp_path, monkeypatch):
    files = write_simulated_batch(tmp_path / "b", 3, seed=3, fs=200.0, cycles=3)
    out = tmp_path / "out"
    first = identify_many(files, client="serial", out=out)
    assert not first["resumed"].any() and (first["status"] == "ok").all()
    stamp = [(out / "models" / f"{f.stem}.json").stat().st_mtime_ns for f in files]

    def no_cluster(*a, **k):
        raise AssertionError("a cluster was started with nothing to fit")

    monkeypatch.setattr(ph.fleet, "local_cluster", no_cluster)
    again = identify_many(files, out=out)  # client=None, but every record is done
    assert again["resumed"].all()
    assert [(out / "models" / f"{f.stem}.json").stat().st_mtime_ns for f in files] == stamp  # not rewritten
    cols = ["record", "status", "fit_rmse_um", "loop_width_um", "gain_um_per_v", "elapsed_s"]
    pd.testing.assert_frame_equal(again[cols], first[cols])
    # other options: refused up front, naming what differs (as they act on the fit: the P-I
    # default size written out)
    with pytest.raises(ValueError, match="other options.*n 20 there, 10 now"):
        identify_many(files, client="serial", out=out, n=10)
    # the default size given, or a seed least squares does not use, is no other option: resumed
    # (both were refused, and every record waited for a refit that changes nothing: fuzzing)
    assert identify_many(files, client="serial", out=out, n=20, seed=5)["resumed"].all()
    # a file whose bytes changed but not its samples (a comment added, other line endings): still
    # the record its model was fitted on (it was "changed" and left out until a refit: fuzzing)
    text = files[2].read_text(encoding="utf-8")
    files[2].write_bytes(("# checked by QA\n" + text).replace("\n", "\r\n").encode("utf-8"))
    assert identify_many(files, client="serial", out=out)["resumed"].all()
    # a data file that changed since its model was made: an error row, not a stale model
    ds = ph.load_dataset(files[1])
    ph.save_dataset(files[1], ph.Dataset(ds.t, ds.u, ds.y * 1.01), force=True)
    third = identify_many(files, client="serial", out=out)
    assert third["status"].tolist() == ["ok", "error", "ok"] and "changed" in third["error"][1]
    forced = identify_many(files, client="serial", out=out, force=True)
    assert (forced["status"] == "ok").all() and not forced["resumed"].any()
    assert forced["fit_rmse_um"][1] == _fit_pi_rmse(files[1]) != first["fit_rmse_um"][1]


def test_other_kinds_go_through_fit_model_and_fit_bouc_wen(tmp_path):
    files = write_simulated_batch(tmp_path, 2, seed=4, fs=200.0, cycles=3)
    ds = ph.load_dataset(files[0])
    df = identify_many(files, kind="asymmetric-pi", client="serial", n=8, delay=0)
    fit = ph.fit_model(ds.u, ds.y, ds.dt, "asymmetric-pi", n=8, delay=0)
    assert df["kind"][0] == fit.model.kind and df["method"][0] == fit.method and df["fit_rmse_um"][0] == fit.rmse
    assert df["holdout_rmse_um"][0] == fit.info["holdout"]["rmse"] > 0
    bw = identify_record(files[0], FitOptions(kind="bouc-wen", max_iter=3, polish=False))
    ref = ph.fit_bouc_wen(ds.u, ds.y, ds.dt, seed=0, max_iter=3, polish=False)
    assert bw["row"]["status"] == "ok" and bw["row"]["fit_rmse_um"] == ref.rmse
    assert bw["document"]["kind"] == "bouc-wen" and bw["document"]["extra"]["fleet"]["options"]["method"] == "pso"


def test_a_record_fitted_for_no_file_builds_no_document(tmp_path):
    # a batch without ``out`` writes no model files: its workers neither build nor send them
    files = write_simulated_batch(tmp_path, 1, seed=5, fs=200.0, cycles=3)
    full = identify_record(files[0])
    bare = identify_record(files[0], document=False)
    assert full["document"] is not None and bare["document"] is None
    assert bare["row"]["status"] == "ok"
    timed = ("elapsed_s", "fit_time_s")
    for k, v in full["row"].items():
        if k not in timed:
            assert bare["row"][k] == v or (v != v and bare["row"][k] != bare["row"][k]), k  # (NaN is NaN)


def test_find_records_folders_globs_and_unique_names(tmp_path):
    for lot in ("lot1", "lot2"):
        (tmp_path / lot).mkdir()
        for name in ("a 1.csv", "b.csv", "notes.md"):
            (tmp_path / lot / name).write_text("t,u,y\n0,0,0\n1,1,1\n", encoding="utf-8")
    (tmp_path / "lot1" / "b.npz").write_bytes(b"")
    recs = find_records([tmp_path / "lot1", str(tmp_path / "lot2" / "*.csv"), tmp_path / "lot1" / "b.csv"])
    names = [n for n, _ in recs]
    assert names == ["lot1__a_1", "b_csv", "b_npz", "lot2__a_1", "lot2__b"]  # duplicates once, names unique
    assert [p.name for _, p in recs] == ["a 1.csv", "b.csv", "b.npz", "a 1.csv", "b.csv"]
    with pytest.raises(FileNotFoundError, match="no such file or folder"):
        find_records(tmp_path / "missing.csv")
    with pytest.raises(FileNotFoundError, match="matches"):
        find_records(str(tmp_path / "*.mat"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no data files"):
        find_records(tmp_path / "empty")
    with pytest.raises(ValueError, match="empty"):
        find_records([])


def test_a_link_to_a_missing_file_is_an_error_row_not_left_out(tmp_path):
    # found by fuzzing: a folder's dangling link was left out of the batch without a word
    ph.fleet.write_simulated_batch(tmp_path, 2, seed=0, fs=2000.0, cycles=4)
    (tmp_path / "gone.csv").symlink_to(tmp_path / "nowhere" / "x.csv")
    df = ph.fleet.identify_many(tmp_path, client="serial")
    assert len(df) == 3
    row = df[df["record"] == "gone"].iloc[0]
    assert row["status"] == "error" and "gone.csv" in row["error"]
    assert (df[df["record"] != "gone"]["status"] == "ok").all()


def test_batch_statistics_median_mad_and_flags():
    gains = [1.0, 2.0, 3.0, 4.0, 100.0, 3.0]  # median 3, |x - 3| = 2,1,0,1,97,0 -> MAD 1 (hand-computed)
    df = pd.DataFrame({"record": list("abcdef"), "status": ["ok"] * 5 + ["error"],
                       "gain_um_per_v": gains, "loop_width_percent": [10.0, 11.0, 10.5, 10.2, 10.4, np.nan],
                       "fit_rmse_percent_of_span": [0.2] * 6})
    st = batch_statistics(df)
    d = st.distributions.loc["gain_um_per_v"]
    assert d["n"] == 5 and d["median"] == 3.0 and d["mad"] == 1.0 and d["unit"] == "µm/V"
    assert d["q25"] == 2.0 and d["q75"] == 4.0  # numpy's linear quantiles of 1,2,3,4,100
    assert st.table["outlier"].tolist() == [False, False, False, False, True, False]
    assert st.table["outlier_reason"][4] == "gain 100 µm/V is 97.0 MADs above the batch median 3"
    # fit RMSE identical for all: MAD 0, nobody differs, nobody flagged for it
    assert st.distributions.loc["fit_rmse_percent_of_span", "mad"] == 0.0
    df.loc[1, "fit_rmse_percent_of_span"] = 0.3
    assert batch_statistics(df).table["outlier_reason"][1] == (
        "fit RMSE 0.3 % of span differs from the median 0.2 that most of the batch shares exactly")
    df.loc[1, "fit_rmse_percent_of_span"] = 0.2 * (1 + 5e-8)  # a rounding's difference: the same figure
    assert not batch_statistics(df).table["outlier"][1]
    df.loc[1, "fit_rmse_percent_of_span"] = 0.2 * (1 + 2e-5)  # beyond a part in a million: shown as such
    assert "0.200004 % of span differs from the median 0.2 " in batch_statistics(df).table["outlier_reason"][1]
    df.loc[1, "fit_rmse_percent_of_span"] = 0.3
    assert batch_statistics(df, threshold=100).table["outlier"].sum() == 1  # 97 MADs < 100; RMSE still flagged
    assert st.to_dict()["outliers"] == [{"record": "e", "reason": st.table["outlier_reason"][4]}]
    with pytest.raises(ValueError, match="threshold"):
        batch_statistics(df, threshold=0)
    with pytest.raises(ValueError, match="lacks the column"):
        batch_statistics(df.drop(columns="gain_um_per_v"))


def test_histograms_take_axes_and_return_what_they_drew(serial):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3)
    try:
        drawn = plot_histograms(batch_statistics(serial), ax=axes)
        assert list(drawn) == ["gain_um_per_v", "loop_width_percent", "fit_rmse_percent_of_span"]
        assert [d["ax"] for d in drawn.values()] == list(axes)
        assert axes[0].get_xlabel() == "gain (µm/V)" and axes[1].get_xlabel() == "loop width (% of span)"
        assert sum(p.get_height() for p in drawn["gain_um_per_v"]["patches"]) == N_ACTUATORS
        assert drawn["gain_um_per_v"]["outliers"] is not None and len(drawn["gain_um_per_v"]["limits"]) == 2
        with pytest.raises(ValueError, match="3 Axes"):
            plot_histograms(serial, ax=axes[:2])
    finally:
        plt.close(fig)


def test_refusals_name_what_is_wrong(tmp_path):
    f = write_simulated_batch(tmp_path, 1, fs=200.0)[0]
    with pytest.raises(TypeError, match="unknown option.*'iterations'"):
        identify_many(f, client="serial", iterations=5)
    with pytest.raises(ValueError, match="unknown model kind"):
        FitOptions(kind="spring")
    with pytest.raises(ValueError, match="'pso' is for kind 'pi' or 'bouc-wen'"):
        FitOptions(kind="preisach", method="pso")
    with pytest.raises(ValueError, match="'auto' is not available for kind 'bouc-wen'"):
        FitOptions(kind="bouc-wen", delay="auto")
    with pytest.raises(ValueError, match="fs must be"):
        FitOptions(fs=-1.0)
    with pytest.raises(TypeError, match="client must be"):
        identify_many(f, client=3)
    with pytest.raises(ValueError, match="workers sizes the local cluster"):
        identify_many(f, client="serial", workers=2)
    with pytest.raises(ValueError, match="seed must be an integer >= 0"):
        FitOptions(seed=-1)
    (tmp_path / "afile").write_text("x", encoding="utf-8")
    with pytest.raises(NotADirectoryError, match="not a folder"):
        identify_many(f, client="serial", out=tmp_path / "afile")
    with pytest.raises(ValueError, match="workers"):
        local_cluster(0)


def test_cli_refusals(tmp_path, capsys):
    f = str(write_simulated_batch(tmp_path, 1, fs=200.0)[0])
    with pytest.raises(SystemExit):  # a local cluster or a scheduler, not both
        main(["fleet", "identify", f, "--model", "pi", "--out", str(tmp_path), "--workers", "2", "--scheduler", "x:1"])
    assert "not allowed with" in capsys.readouterr().err
    port = _free_port()  # nothing listens there
    code = main(["fleet", "identify", f, "--model", "pi", "--out", str(tmp_path / "o"),
                 "--scheduler", f"tcp://127.0.0.1:{port}", "--timeout", "1"])
    assert code == 2 and "cannot reach the Dask scheduler" in capsys.readouterr().err
    assert main(["fleet", "identify", f, "--model", "spring", "--out", str(tmp_path / "o")]) == 2
    assert "unknown model kind" in capsys.readouterr().err


def test_dask_is_optional(tmp_path, monkeypatch, capsys):
    # importing piezohyst (and its fleet module) does not import dask or pandas
    code = ("import sys, piezohyst as ph; ph.fleet; import piezohyst.cli; piezohyst.cli.build_parser(); "
            "print(sorted(m for m in ('dask', 'distributed', 'pandas') if m in sys.modules))")
    env = {**os.environ, "PYTHONPATH": os.path.join(ROOT, "src")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120, check=True)
    assert out.stdout.strip() == "[]"
    # without distributed: a clear message naming the extra, from the API and the command
    f = str(write_simulated_batch(tmp_path, 1, fs=200.0)[0])
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(MissingExtraError, match=r"piezohyst\[fleet\]"):
        identify_many(f)
    assert main(["fleet", "identify", f, "--model", "pi", "--out", str(tmp_path / "o")]) == 2
    assert "piezohyst[fleet]" in capsys.readouterr().err
    assert isinstance(MissingExtraError("x"), ImportError)
    assert identify_many(f, client="serial")["status"].tolist() == ["ok"]  # serial needs no Dask


@given(record_seconds=st.floats(0.0, 100.0), records=st.integers(0, 5000), workers=st.integers(1, 64))
def test_group_size_carries_enough_work_and_keeps_every_worker_busy(record_seconds, records, workers):
    size = ph.fleet.group_size(record_seconds, records, workers)
    assert size >= 1
    if size > 1:  # grouped only when a record is quicker than a task should be, and never into too few tasks
        assert (size - 1) * record_seconds < ph.fleet.TASK_SECONDS
        assert math.ceil(records / size) >= min(records, ph.fleet.TASKS_PER_WORKER * workers) / 2
    if record_seconds >= ph.fleet.TASK_SECONDS or records <= ph.fleet.TASKS_PER_WORKER * workers:
        assert size == 1


@given(records=st.integers(0, 3000), size=st.integers(1, 200), workers=st.integers(1, 64))
def test_group_sizes_cover_the_records_and_shrink(records, size, workers):
    sizes = ph.fleet.group_sizes(records, size, workers)
    assert sum(sizes) == records and all(1 <= k <= size for k in sizes)
    assert sizes == sorted(sizes, reverse=True)
    if records:
        assert sizes[-1] == 1


def test_each_actuators_start_is_fitted_as_identify_fits_it():
    """``FitOptions(history=...)`` is ``fit_model``'s (``--history`` of ``piezohyst fleet
    identify``): with ``kind="auto"`` a record of a stage that came up from the bottom of its range
    gives an after-history model, as ``piezohyst identify`` does, and ``history="none"`` does not;
    the option is refused where nothing is selected."""
    from piezohyst.fleet import FitOptions, fit_record

    from .test_select import _came_from

    lo, hi = -60.0, 100.0
    t = np.arange(6000)
    amp = np.interp(t, [0, 1500, 6000], [1.0, 1.0, 0.3])
    u = np.concatenate([np.linspace(0.0, hi, 200), 0.5 * (lo + hi) + 0.5 * (hi - lo) * np.cos(2 * np.pi * t / 750) * amp])
    ds = ph.Dataset(np.arange(u.size) * 1e-3, u, _came_from(lo, 2)(u))
    kinds = {h: fit_record(ds, FitOptions(kind="auto", history=h)).model.kind for h in ("auto", "none", None)}
    assert kinds["auto"] == kinds[None] == "after-history" and kinds["none"] != "after-history"
    assert FitOptions(kind="auto", history="none").to_dict()["history"] == "none"
    with pytest.raises(ValueError, match="history"):
        FitOptions(kind="pi", method="lsq", history="auto")
    with pytest.raises(ValueError, match="history"):
        FitOptions(kind="auto", history="maybe")


def test_cli_exits_2_when_no_record_is_identified(tmp_path, capsys):
    # found by fuzzing: every record naming a missing column printed "ok": 0 and exited 0, which a
    # script or a CI job takes for success; one record failing among good ones stays exit 0 (a row)
    write_simulated_batch(tmp_path / "b", 2, fs=200.0)
    code = main(["fleet", "identify", str(tmp_path / "b"), "--model", "pi", "--out", str(tmp_path / "o"),
                 "--u-col", "volts", "--workers", "1", "--quiet", "--json"])
    out, err = capsys.readouterr()
    assert code == 2
    assert json.loads(out)["ok"] == 0 and "none of the 2 records was identified" in err and "volts" in err
    (tmp_path / "b2").mkdir()
    good = write_simulated_batch(tmp_path / "b2", 1, fs=200.0)[0]
    (good.parent / "broken.csv").write_text("t,u,y\n0,1\n")
    code = main(["fleet", "identify", str(tmp_path / "b2"), "--model", "pi", "--out", str(tmp_path / "o2"),
                 "--workers", "1", "--quiet", "--json"])
    assert code == 0 and json.loads(capsys.readouterr().out)["failed"] == 1


def test_model_files_of_records_no_longer_in_the_batch_are_named(tmp_path, capsys):
    """A record renamed after its batch was identified left its model file behind without a word
    (found by fuzzing); it is named (never removed: it is the user's result)."""
    files = write_simulated_batch(tmp_path / "b", 2, seed=3, fs=200.0, cycles=3)
    out = tmp_path / "out"
    identify_many(files, client="serial", out=out)
    renamed = files[0].with_name("renamed-" + files[0].name)
    files[0].rename(renamed)
    df = identify_many([renamed, files[1]], client="serial", out=out)
    assert [Path(q).name for q in df.attrs["orphaned_model_files"]] == [f"{files[0].stem}.json"]
    assert (out / "models" / f"{files[0].stem}.json").is_file()
    from piezohyst.cli import main

    assert main(["fleet", "identify", str(renamed), str(files[1]), "--model", "pi", "--out", str(out),
                 "--workers", "1", "--quiet"]) == 0
    assert f"{files[0].stem}.json" in capsys.readouterr().out


def test_files_of_those_names_that_no_batch_wrote_are_not_replaced(tmp_path, capsys):
    """A user's own summary.csv or fleet_histograms.png in the out folder was replaced without a
    word (the summary is written with force, so that a rerun resumes; found by a helper): refused
    before any fit, naming it and the way out; a batch's own summary is replaced by its rerun."""
    from piezohyst.cli import main

    files = write_simulated_batch(tmp_path / "b", 2, seed=5, fs=200.0, cycles=3)
    for name, content in (("summary.csv", b"my precious notes\n"), ("fleet_histograms.png", b"keep")):
        out = tmp_path / f"out-{name}"
        out.mkdir()
        (out / name).write_bytes(content)
        with pytest.raises(FileExistsError, match=rf"{name} exists and is not a file a piezohyst fleet wrote; "
                                                  r"not replacing it.*force=True"):
            identify_many(files, client="serial", out=out)
        assert not (out / "models").exists()  # refused before any fit
        assert main(["fleet", "identify", str(files[0].parent), "--model", "pi", "--out", str(out), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "not replacing it" in err and "--force" in err, err
        assert (out / name).read_bytes() == content
        assert main(["fleet", "identify", str(files[0].parent), "--model", "pi", "--out", str(out), "--quiet", "--force"]) == 0
        assert (out / name).read_bytes() != content
        capsys.readouterr()
    # a batch's own files: its rerun (resumed) replaces them
    out = tmp_path / "out-summary.csv"
    assert main(["fleet", "identify", str(files[0].parent), "--model", "pi", "--out", str(out), "--quiet"]) == 0
    assert pd.read_csv(out / "summary.csv")["resumed"].all()


def test_names_of_any_script_alike_names_and_long_names(tmp_path):
    """压电1, Ω1 and µ1 all became "_1", and 'act 01', 'act_01', 'Act_01' stayed alike whatever was
    added: the batch was refused as not unique; a 251-character name was fitted and its model file
    could not be written (found by a helper). Letters of any script stay, names still alike end
    in a hash of their path (stable from run to run), long names are cut to 200 bytes."""
    folder = tmp_path / "lot"
    folder.mkdir()
    stems = ["压电1", "Ω1", "µ1", "act 01", "act_01", "Act_01", "x" * 246]
    for stem in stems:
        (folder / f"{stem}.csv").write_text("t,u,y\n0,0,0\n1,1,1\n", encoding="utf-8")
    names = dict((p.stem, n) for n, p in find_records(folder))
    assert [names[s] for s in ("压电1", "Ω1", "µ1")] == ["压电1", "Ω1", "µ1"]
    alike = [names[s] for s in ("act 01", "act_01", "Act_01")]
    assert len({n.casefold() for n in alike}) == 3 and all(n.startswith(("act_01-", "Act_01-")) for n in alike)
    assert dict((p.stem, n) for n, p in find_records(folder)) == names  # the same on every run
    long = names["x" * 246]
    assert len(long.encode()) == 200 and long.startswith("x" * 150)


def test_a_model_file_of_another_lots_record_is_not_called_changed(tmp_path):
    """Two lots with the same file names into one out folder: lot B's rows said lot A's files
    "changed" and advised force, which replaced lot A's models (found by a helper)."""
    a = write_simulated_batch(tmp_path / "lotA", 2, seed=1, fs=200.0, cycles=3)
    write_simulated_batch(tmp_path / "lotB", 2, seed=2, fs=200.0, cycles=3)
    out = tmp_path / "out"
    identify_many(tmp_path / "lotA", client="serial", out=out)
    df = identify_many(tmp_path / "lotB", client="serial", out=out)
    assert (df["status"] == "error").all()
    for err in df["error"]:
        assert "was identified from another file" in err and "lotA" in err and "another out folder" in err, err
        assert "force" not in err and "changed" not in err
    assert identify_many(a, client="serial", out=out)["resumed"].all()  # lot A's models untouched


def test_the_python_api_caps_a_local_clusters_workers_as_the_command_line_does(tmp_path):
    """workers=1000 from Python started a process storm (load 53, 1614 leaked semaphores: found
    by a helper); the command line refused it."""
    from piezohyst._blas import MAX_WORKERS_PER_CORE, usable_cores

    f = write_simulated_batch(tmp_path, 1, fs=200.0)[0]
    n = MAX_WORKERS_PER_CORE * usable_cores() + 1
    with pytest.raises(ValueError, match=rf"workers: {n} workers is more than {MAX_WORKERS_PER_CORE}x"):
        identify_many(f, workers=n)
    with pytest.raises(ValueError, match="more than"):
        local_cluster(n)


def test_a_group_whose_worker_dies_is_retried_one_record_at_a_time(tmp_path, monkeypatch):
    """A record that kills its worker (one too large for its memory) failed every record grouped
    with it: KilledWorker on six rows where one was at fault (found by a helper). Here every
    group's task ends its worker as it starts; its records, sent again one per task, are fitted.
    (A single task queued on a dying worker may still be lost with it, as distributed decides;
    what must not happen is a record failing for the group it was in.)"""
    import dask
    from distributed.diagnostics.plugin import WorkerPlugin

    class EndTheWorkerOnGroups(WorkerPlugin):
        def transition(self, key, start, finish, **kwargs):
            if finish == "executing" and "-x" in str(key) and not str(key).endswith("-x1"):
                os._exit(1)

    files = write_simulated_batch(tmp_path / "b", 16, seed=6, fs=500.0, cycles=2)
    monkeypatch.setattr(ph.fleet, "TASK_SECONDS", 1e9)  # every record "quick": groups after the first four
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        client = local_cluster(2)
    try:
        client.register_plugin(EndTheWorkerOnGroups())
        df = identify_many(files, client=client)
    finally:
        client.close()
        client.cluster.close()
    assert len(df) == 16
    failed = df[df["status"] != "ok"]
    keys = failed["error"].str.extract(r"task '([^']+)'", expand=False)
    # tasks of one record may be lost (the first four, "-x1" ones, and those sent again); no
    # record is lost with a group ("-x2" and more)
    assert not keys.str.contains(r"-x(?:[2-9]|\d{2,})$", regex=True).any(), (keys.tolist(), failed["error"].tolist())
    assert (df["status"] == "ok").sum() >= 8, failed["error"].tolist()


def test_losing_the_scheduler_mid_batch_is_an_error_not_failed_records(tmp_path):
    """The scheduler killed mid-batch: 30 of 40 records were rows that "failed on the cluster"
    (FutureCancelledError), the statistics described the other 10, and the exit code was 0 (found
    by a helper). Now an error naming how far it got and that a rerun resumes; the records done
    keep their model files. (A scheduler and a worker on 127.0.0.1, killed and stopped here.)"""
    files = write_simulated_batch(tmp_path / "b", 8, seed=7, fs=500.0, cycles=3)
    procs = []
    try:
        address = _scheduler_and_worker(tmp_path, procs)

        def kill_the_scheduler_after_the_first(done, total, row):
            if done == 1:
                procs[0].kill()

        with pytest.raises(ConnectionError, match=r"lost the Dask scheduler after \d+ of 8 records .*run the same "
                                                  r"command again to resume"):
            identify_many(files, kind="auto", client=address, out=tmp_path / "out", timeout=2.0,
                          progress=kill_the_scheduler_after_the_first)
    finally:
        left = _stop(procs)
    assert not left
    assert 1 <= len(list((tmp_path / "out" / "models").glob("*.json"))) < 8


def test_options_that_read_the_same_samples_resume(tmp_path):
    """--u-col naming the column found without it, or --delimiter , for a comma file, were "other
    options" and the whole batch was refused until --force (found by a helper); options that read
    other samples still are."""
    files = write_simulated_batch(tmp_path / "b", 2, seed=8, fs=200.0, cycles=3)
    out = tmp_path / "out"
    identify_many(files, client="serial", out=out)
    again = identify_many(files, client="serial", out=out, u_col="u_V", y_col="y_um", delimiter=",")
    assert again["resumed"].all() and (again["status"] == "ok").all()
    with pytest.raises(ValueError, match=r"other options .*u_col None there, 'y_um' now"):
        identify_many(files, client="serial", out=out, u_col="y_um", y_col="u_V")


def test_a_batch_logged_to_a_file_gets_progress_lines(tmp_path, capsys):
    """Outside a terminal (nohup, SLURM, CI) a batch printed no progress until the end, then one
    line cut at 80 columns (found by a helper): a line for each tenth of the batch."""
    files = write_simulated_batch(tmp_path / "b", 10, seed=9, fs=200.0, cycles=3)
    identify_many(files, client="serial", progress=True)
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[0].endswith("identifying 10 records on this process (serial)"), lines
    assert [ln.split("] ", 1)[1].split(" (")[0] for ln in lines[1:]] == [f"{k}/10 records" for k in range(1, 11)]
    assert "10/10 records (0 failed)" in lines[-1] and "left" not in lines[-1]


def test_an_interrupt_while_the_batch_files_are_published_leaves_one_runs_set(tmp_path, monkeypatch, capsys):
    """summary.csv, summary.parquet and fleet_histograms.png were published one at a time: a Ctrl-C
    between them left files of two runs that disagree (found by a helper). Here SIGINT comes as the
    first of them is published: the set is the previous run's, or the new one, never a mix."""
    import signal

    files = write_simulated_batch(tmp_path / "b", 2, seed=10, fs=200.0, cycles=3)
    out = tmp_path / "out"
    identify_many(files, client="serial", out=out)  # the models: the runs below read them back (no cluster)
    args = ["fleet", "identify", str(tmp_path / "b"), "--model", "pi", "--out", str(out), "--quiet"]
    assert main(args) == 0
    names = [n for n in ph.fleet.BATCH_FILES if (out / n).exists()]
    assert {"summary.csv", "fleet_histograms.png"} <= set(names)
    before = {n: (out / n).read_bytes() for n in names}
    real = ph._fileio._publish_file

    def publish_then_ctrl_c(tmp, p, force):
        real(tmp, p, force)
        if p.name == "summary.csv":
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(ph._fileio, "_publish_file", publish_then_ctrl_c)
    assert main([*args, "--outlier-mads", "4"]) == 130  # (other options: every file differs)
    assert "interrupted" in capsys.readouterr().err
    changed = {n for n in names if (out / n).read_bytes() != before[n]}
    assert changed in (set(), set(names)), f"files of two runs: {sorted(changed)} new, the others old"
    assert not [n for n in os.listdir(out) if n.startswith(".")]  # no temporary file, no lock left


def test_a_second_run_on_an_out_folder_in_use_is_refused_at_once(tmp_path, capsys):
    """Two runs on one --out at once both exited 0, each taking the other's new model files for
    files that "appeared while this run worked", and a summary marked records as errors whose model
    files were there (found by a helper). The second is refused at once, naming the folder and the
    first run's pid; the lock goes with the first run (and a lock file a killed run left is no lock)."""
    files = write_simulated_batch(tmp_path / "b", 2, seed=11, fs=200.0, cycles=3)
    out = tmp_path / "out"
    seen = {}

    def second_run(done, total, row):
        if done == total:  # (every model file written: without the lock, a second run read them back)
            seen["code"] = main(["fleet", "identify", str(tmp_path / "b"), "--model", "pi", "--out", str(out),
                                 "--quiet"])
            seen["err"] = capsys.readouterr().err
            try:
                identify_many(files, client="serial", out=out)
            except OSError as exc:
                seen["api"] = exc

    df = identify_many(files, client="serial", out=out, progress=second_run)
    assert (df["status"] == "ok").all()
    err = seen["err"]
    assert seen["code"] == 2 and err.count("\n") == 1, err
    assert str(out) in err and f"another piezohyst fleet run (pid {os.getpid()}) is writing there" in err, err
    assert isinstance(seen.get("api"), BlockingIOError) and str(out) in str(seen["api"])
    assert not [n for n in os.listdir(out) if n.startswith(".")]  # the lock file went with the run
    (out / ph.fleet.LOCK_FILE).write_text("999999\n", encoding="ascii")  # left by a killed run: no lock
    assert identify_many(files, client="serial", out=out)["resumed"].all()
    assert not (out / ph.fleet.LOCK_FILE).exists()


@pytest.mark.parametrize("errno_name", ["ENOSPC", "EDQUOT"])
def test_a_full_disk_stops_the_batch_at_the_first_model_file_it_cannot_write(tmp_path, monkeypatch, errno_name):
    """With the disk full every record was fitted, each an error row, before the batch failed on
    summary.csv (found by a helper): it stops at the first model file, naming the folder; the model
    files written stay and a rerun resumes from them."""
    import errno

    from piezohyst._fileio import OutputError

    code = getattr(errno, errno_name)
    files = write_simulated_batch(tmp_path / "b", 4, seed=12, fs=200.0, cycles=3)
    out = tmp_path / "out"
    real = ph.fleet._write_model
    calls = []

    def full_after_one(doc, path, force):
        calls.append(path.name)
        if len(calls) == 1:
            return real(doc, path, force)
        cause = OSError(code, os.strerror(code), str(path))
        if code == errno.ENOSPC:
            raise cause
        raise OutputError(f"cannot write {path}: {cause.strerror}") from cause  # as atomic_write words it

    monkeypatch.setattr(ph.fleet, "_write_model", full_after_one)
    with pytest.raises(OSError, match=rf"cannot write model files in {re.escape(str(out / 'models'))}: "
                                      rf"{re.escape(os.strerror(code))}.*run the same command again to resume") as info:
        identify_many(files, client="serial", out=out)
    assert info.value.errno == code
    assert len(calls) == 2  # stopped there, not one more fit per record
    assert [p.name for p in (out / "models").glob("*.json")] == calls[:1]
    assert not (out / "summary.csv").exists()
    monkeypatch.undo()
    again = identify_many(files, client="serial", out=out)
    assert again["resumed"].sum() == 1 and (again["status"] == "ok").all()
