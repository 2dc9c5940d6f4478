"""The paper's experiment end to end (issue #5): tables, figures, report, determinism."""

import json

import pytest

from piezohyst.cli import main
from piezohyst.experiments.paper import FIGURES, run_paper_experiment


@pytest.mark.slow
def test_reproduce_writes_tables_figures_and_report(tmp_path, capsys):
    assert main(["reproduce", "--out", str(tmp_path), "--format", "svg", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    # Tolerances from the spread over seeds 0-7 (run_paper_experiment(seed=s), measured for issue 13):
    #   RMSE um, feedforward alone: Bouc-Wen 1/3/5 Hz 0.0074-0.0101 / 0.0196-0.0279 / 0.0417-0.0497,
    #                               P-I 0.0162-0.0454 / 0.0241-0.0471 / 0.0440-0.0613;
    #   with PID: 0.0033-0.0049 (Bouc-Wen), 0.0033-0.0111 (P-I); the sensor noise is 3 nm RMS;
    #   e_max with PID <= 0.036 um; Table III RMSE 0.0033-0.0046 um, every target met.
    # Bounds: ~1.6x the largest value seen, and the noise floor from below; feedback must cut the
    # error (ratio seen <= 0.5) and the Bouc-Wen feedforward's error must grow with frequency
    # (ratio 5 Hz / 1 Hz seen >= 4).
    ff_max = {"table_I": 0.08, "table_II": 0.1}
    for table in ("table_I", "table_II"):
        rows = res[table]
        assert len(rows) == 6
        by = {(r["freq_hz"], r["feedback"]): r for r in rows}
        for r in rows:
            assert r["paper_rmse_um"] is not None  # the paper's figure beside ours
            if r["feedback"]:
                assert 0.0025 < r["rmse_um"] < 0.015, r
                assert r["e_max_um"] < 0.05, r
            else:
                assert 0.005 < r["rmse_um"] < ff_max[table], r
            # clipping is counted and reported; at most a start-up transient here
            assert r["clipped_samples"] is not None and r["clipped_samples"] < 100
        for f in (1.0, 3.0, 5.0):
            assert by[(f, True)]["rmse_um"] < 0.7 * by[(f, False)]["rmse_um"], (table, f)
    bw = {r["freq_hz"]: r["rmse_um"] for r in res["table_I"] if not r["feedback"]}
    assert bw[5.0] > 2 * bw[1.0]
    for r in res["table_piezohyst"]:
        assert 0.0025 < r["rmse_um"] < 0.008 and r["e_max_um"] < 0.03 and r["meets_target"], r
    for fname in FIGURES.values():
        data = (tmp_path / fname).read_bytes()
        assert data[:4] == b"\x89PNG" and len(data) > 10_000
        svg = (tmp_path / fname.replace(".png", ".svg")).read_text(encoding="utf-8")
        assert svg.lstrip().startswith("<?xml") and "piezohyst 0.2" in svg  # what produced it
    report = (tmp_path / "report.md").read_text()
    assert "Table I" in report and "Table II" in report and "claims" in report
    for fname in FIGURES.values():
        assert f"({fname})" in report  # embedded
    assert [c["claim"] for c in res["claims"]]  # each claim stated with its verdict
    assert all(isinstance(c["holds"], bool) for c in res["claims"])
    # the third table and the ablation (issue #7)
    assert len(res["table_piezohyst"]) == 6 and "Table III" in report and "Ablation" in report
    assert set(res["ablation"]) >= {"paper_pso_pi_ff", "lsq_pi_ff", "rate_pi_ff", "rate_pi_ff_fb", "rate_pi_ff_fb_ilc"}
    # refuses to overwrite without --force
    assert main(["reproduce", "--out", str(tmp_path)]) == 2


def test_same_seed_same_tables():
    kw = dict(seed=3, freqs=(1.0, 5.0), cycles=2, pso_bw=(10, 15), pso_pi=(20, 50), beyond=False)
    a = run_paper_experiment(**kw)
    b = run_paper_experiment(**kw)
    assert a.table("pi") == b.table("pi")
    assert a.table("bouc-wen") == b.table("bouc-wen")
    c = run_paper_experiment(**{**kw, "seed": 4})
    assert c.table("pi") != a.table("pi")
