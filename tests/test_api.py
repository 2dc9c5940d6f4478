"""The public API of DESIGN.md: every name there exists, is what it should be whatever was
imported before, and ``import piezohyst`` stays light (the CLI parses before numba loads)."""

import importlib
import pkgutil
import subprocess
import sys

import numpy as np
import pytest

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


# --- a notebook user's session (found by a helper working in Jupyter) -----------------------------
def test_dataset_and_tracking_result_print_in_one_line():
    """Both printed every array (a Dataset 832 characters, a TrackingResult its whole run)."""
    rig = ph.VirtualRig(seed=0)
    ds = rig.excite(ph.sinusoid(1.0, 1, 0.0, 100.0, rig.dt))
    assert repr(ds) == ("Dataset(10000 samples at 10000 Hz, u 0..100 V, y "
                        f"{ds.y.min():.4g}..{ds.y.max():.4g} um, source='VirtualRig')")
    fit = ph.fit_pi(ds.u, ds.y)
    out = ph.track(rig, ph.sinusoid(3.0, 2, 0.25, 2.25, rig.dt), feedforward=ph.InversePIFeedforward(fit.model))
    text = repr(out)
    assert "\n" not in text and len(text) < 200 and f"e_max {out.e_max:.4g} um" in text
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(4, 1)
    assert out.plot(ax=axs) is fig  # ax= as plot_loops names it (it was a TypeError)
    plt.close(fig)


def test_a_data_frame_round_trip_keeps_the_provenance():
    rig = ph.VirtualRig(seed=3)
    ds = rig.excite(ph.sinusoid(1.0, 1, 0.0, 100.0, rig.dt))
    back = ph.Dataset.from_dataframe(ds.to_dataframe())
    assert back.meta["source"] == "VirtualRig" and back.meta["seed"] == 3 and back.meta["rig"] == ds.meta["rig"]
    np.testing.assert_array_equal(back.y, ds.y)


def test_arguments_given_the_wrong_way_are_named():
    m = ph.PrandtlIshlinskii(np.linspace(0.0, 90.0, 10), np.full(10, 0.02))
    with pytest.raises(TypeError, match=r"save_model\(model, path\): the model comes first"):
        ph.save_model("m.json", m)
    with pytest.raises(TypeError, match="path must be a file name .*got dict .*model_from_dict"):
        ph.load_model({"schema": 1})
    with pytest.raises(ValueError, match="thresholds must increase from 0 .*another order"):
        ph.PrandtlIshlinskii([2.0, 1.0, 0.0], [0.1, 0.1, 0.1])
    with pytest.raises(ValueError, match="seed must be a whole number >= 0 or None, got 'a'"):
        ph.VirtualRig(seed="a")
    u = np.ma.masked_array(np.linspace(0.0, 100.0, 200), mask=np.arange(200) == 50)
    with pytest.raises(ValueError, match="u has 1 masked sample.*first at index 50"):
        ph.fit_pi(u, np.linspace(0.0, 10.0, 200))
