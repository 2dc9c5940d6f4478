"""The example notebooks run top to bottom in a real Jupyter kernel, and show what they promise.

Needs the ``notebooks`` extra (nbclient, nbformat, ipykernel), which ``make test`` installs; the
notebooks run in a temporary folder with this checkout's piezohyst on the kernel's path.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import piezohyst

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
NOTEBOOKS = sorted(EXAMPLES.glob("*.ipynb"))


def test_there_are_example_notebooks_and_they_are_committed_without_outputs():
    assert len(NOTEBOOKS) >= 2, f"expected two or more notebooks in {EXAMPLES}"
    for path in NOTEBOOKS:
        nb = nbformat.read(path, as_version=4)
        nbformat.validate(nb)
        for cell in nb.cells:
            if cell.cell_type == "code":
                assert not cell.outputs and cell.execution_count is None, f"{path.name}: strip the outputs"


def _run(path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> object:
    # the kernel imports the piezohyst this test imports (a checkout on PYTHONPATH or the installed one)
    src = str(Path(piezohyst.__file__).resolve().parent.parent)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([src, *filter(None, [os.environ.get("PYTHONPATH")])]))
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()  # raises CellExecutionError naming the cell when one fails
    return nb


def _outputs(nb: object) -> list[dict]:
    return [o for cell in nb.cells if cell.cell_type == "code" for o in cell.outputs]  # type: ignore[attr-defined]


def _check_common(nb: object, name: str) -> list[dict]:
    outs = _outputs(nb)
    assert not [o for o in outs if o.output_type == "error"], name
    # no "install ipywidgets" or other warnings printed by the kernel
    stderr = "".join(o.get("text", "") for o in outs if o.output_type == "stream" and o.get("name") == "stderr")
    assert "Warning" not in stderr and "ipywidgets" not in stderr, f"{name}: {stderr[:500]}"
    # the progress display ended with its total time
    progress = [o for o in outs if "piezohyst-progress" in o.get("data", {}).get("text/html", "")]
    assert progress and all("done in" in o["data"]["text/plain"] for o in progress), name
    # every figure shows once: no cell displays the same figure twice
    for cell in nb.cells:  # type: ignore[attr-defined]
        if cell.cell_type == "code":
            images = [o for o in cell.outputs if "image/png" in o.get("data", {})]
            assert len(images) <= 1, f"{name}: a cell shows {len(images)} figures:\n{cell.source}"
    return outs


@pytest.mark.slow
def test_identify_real_stage_notebook(tmp_path, monkeypatch):
    path = EXAMPLES / "01_identify_real_stage.ipynb"
    nb = _run(path, tmp_path, monkeypatch)
    outs = _check_common(nb, path.name)
    html = "".join(o.get("data", {}).get("text/html", "") for o in outs)
    assert "FitResult" in html and "Candidates by hold-out error" in html
    assert sum("image/png" in o.get("data", {}) for o in outs) >= 2
    text = "".join(o.get("text", "") for o in outs if o.output_type == "stream")
    assert "hold-out RMSE" in text
    assert "stage.json" in text and "True" in text  # the saved model reads back and predicts the same


@pytest.mark.slow
def test_commission_notebook(tmp_path, monkeypatch):
    path = EXAMPLES / "02_commission_a_stage.ipynb"
    nb = _run(path, tmp_path, monkeypatch)
    outs = _check_common(nb, path.name)
    html = "".join(o.get("data", {}).get("text/html", "") for o in outs)
    assert "TrackingResult" in html and "FitResult" in html and "model</div>" in html
    assert sum("image/png" in o.get("data", {}) for o in outs) >= 2
    text = "".join(o.get("text", "") for o in outs if o.output_type == "stream")
    for name in ("feedforward ", "feedforward + feedback ", "feedforward + feedback + learning"):
        assert name in text
