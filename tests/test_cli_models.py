import json
import subprocess
import sys

from piezohyst.cli import main


def test_models_json(capsys):
    assert main(["models", "--freq", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    bw = [r for r in out["loops"] if r["model"].startswith("Bouc-Wen")][0]
    assert 1.8 < bw["span"] < 2.2
    assert out["inverse_pi"]["max_error_computed_V"] < 1e-9
    assert out["inverse_pi"]["max_error_printed_V"] > 15


def test_help_has_examples():
    res = subprocess.run([sys.executable, "-m", "piezohyst.cli", "--help"], capture_output=True, text=True)
    assert res.returncode == 0
    assert "examples:" in res.stdout


def test_bad_frequency_is_a_usage_error(capsys):
    import pytest

    with pytest.raises(SystemExit) as exc:
        main(["models", "--freq", "abc"])
    assert exc.value.code == 2
