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


def test_a_reader_that_closes_the_pipe_ends_the_run_as_a_closed_pipe_does():
    """``piezohyst models | head -1``: rich's handler exited with 1 (this tool's code for its own
    bugs) and no word, or 0, by the race (found by a helper). Now 128 + SIGPIPE, silently, as a
    shell reports any writer a closed pipe ends; the reader is gone before the first line here."""
    proc = subprocess.Popen([sys.executable, "-m", "piezohyst", "models", "--freq", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # before the command has imported anything: its first write finds no reader
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 141, err.decode()
    assert err.decode().strip() == ""


def test_files_name_the_command_as_typed_and_quoted(tmp_path):
    """Files said ``command: __main__.py rig --out loops dir`` under ``python -m piezohyst``: the
    command they amount to, quoted so it runs again; Python (not the command line) afterwards
    records its own script again."""
    import shlex

    from piezohyst._fileio import producer

    out = tmp_path / "loops dir é"
    assert main(["rig", "--freq", "1", "--out", str(out)]) == 0
    line = next(p for p in out.iterdir() if p.suffix == ".csv").read_text(encoding="utf-8").splitlines()[0]
    command = line.split("command: ", 1)[1].rsplit("; at ", 1)[0]
    assert shlex.split(command) == ["piezohyst", "rig", "--freq", "1", "--out", str(out)]
    assert "command: piezohyst rig" not in producer()
