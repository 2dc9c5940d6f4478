"""The public API of DESIGN.md: every name there exists, is what it should be whatever was
imported before, and ``import piezohyst`` stays light (the CLI parses before numba loads)."""

import importlib
import pkgutil
import subprocess
import sys

import piezohyst as ph

CONTRACT = ["equal_thresholds", "PrandtlIshlinskii", "BoucWen", "pso_minimize", "fit_pi", "fit_bouc_wen",
            "load_dataset", "VirtualRig", "sinusoid", "InversePIFeedforward", "BoucWenFeedforward", "PID",
            "track", "fit_model", "commission", "Dataset", "save_model", "load_model"]


def test_contract_names_exist_and_are_callable():
    for name in CONTRACT:
        assert callable(getattr(ph, name)), name
    assert hasattr(ph.Dataset, "from_dataframe") and hasattr(ph.Dataset, "to_dataframe")


def test_public_names_survive_importing_every_submodule():
    # a submodule named like a public function would replace it on the package when imported
    before = {n: getattr(ph, n) for n in ph.__all__}
    for m in pkgutil.walk_packages(ph.__path__, "piezohyst."):
        if m.name.endswith("__main__"):
            continue
        importlib.import_module(m.name)
    changed = [n for n in ph.__all__ if getattr(ph, n) is not before[n]]
    assert changed == []


def test_import_and_help_do_not_load_numba_or_scipy():
    code = ("import sys, piezohyst, piezohyst.cli as c\n"
            "p = c.build_parser()\n"
            "print(sorted(m for m in ('numba', 'scipy', 'numpy', 'matplotlib') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
