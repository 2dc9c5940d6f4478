import json

import pytest

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


def test_rig_figure_formats(tmp_path, capsys):
    from piezohyst.cli import main

    out = tmp_path / "loops"
    assert main(["rig", "--freq", "1", "--cycles", "1", "--out", str(out), "--format", "pdf,svg"]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["fig2_loops.pdf", "fig2_loops.png", "fig2_loops.svg", "manifest.json", "rig_loops.csv"]
    assert (out / "fig2_loops.pdf").read_bytes()[:5] == b"%PDF-"
    assert b"piezohyst" in (out / "fig2_loops.pdf").read_bytes()  # the producer in its metadata
    # what the figure shows, as docs/formats.md says every figure states (the rig's said only
    # who wrote it: found by a helper)
    from PIL import Image

    with Image.open(out / "fig2_loops.png") as png:
        assert "open-loop loops of the virtual rig at 1 Hz" in png.info["Description"]
    assert "open-loop loops of the virtual rig" in (out / "fig2_loops.svg").read_text(encoding="utf-8")
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        main(["rig", "--format", "jpg"])
    assert stop.value.code == 2
    assert "unknown figure format(s) jpg; the formats are png, pdf, svg" in capsys.readouterr().err
