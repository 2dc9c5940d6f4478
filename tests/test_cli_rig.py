import json

from piezohyst.cli import main


def test_rig_command_writes_figure_and_csv(tmp_path, capsys):
    assert main(["rig", "--freq", "1,5", "--cycles", "2", "--out", str(tmp_path), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert [r["freq_hz"] for r in res["loops"]] == [1.0, 5.0]
    assert res["loops"][1]["width_um"] > res["loops"][0]["width_um"]
    png = (tmp_path / "fig2_loops.png").read_bytes()
    assert png[:4] == b"\x89PNG" and b"piezohyst" in png  # says what produced it
    csv = (tmp_path / "rig_loops.csv").read_text()
    assert csv.startswith("# piezohyst")
    # refuses to overwrite without --force
    assert main(["rig", "--freq", "1", "--cycles", "1", "--out", str(tmp_path)]) == 2
    assert "--force" in capsys.readouterr().err


def test_rig_settings_file_errors(tmp_path, capsys):
    bad = tmp_path / "s.json"
    bad.write_text('{"colour": 1}')
    assert main(["rig", "--freq", "1", "--cycles", "1", "--rig-settings", str(bad)]) == 2
    assert "unknown rig setting" in capsys.readouterr().err
