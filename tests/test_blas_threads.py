"""piezohyst._blas: one OpenBLAS thread inside the block, the count restored after, found cheaply."""

import sys
import types

import numpy as np
import pytest

from piezohyst import _blas


def test_one_thread_inside_restored_after():
    import scipy.linalg  # noqa: F401 - scipy's own OpenBLAS, when it has one, is loaded too

    controls = _blas._openblas_controls()
    if not controls:
        pytest.skip("no OpenBLAS found in this process")
    before = [int(get()) for _, get in controls]
    with _blas.single_threaded_blas():
        assert all(int(get()) == 1 for _, get in controls)
        a = np.arange(12.0).reshape(4, 3)
        np.testing.assert_array_equal(a.T @ a, np.einsum("ki,kj->ij", a, a))
    assert [int(get()) for _, get in controls] == before


def test_the_scan_is_kept_until_a_module_is_imported(monkeypatch):
    scans = []
    monkeypatch.setattr(_blas, "_found", None)
    monkeypatch.setattr(_blas, "_scan_openblas", lambda: scans.append(1) or [])
    _blas._openblas_controls()
    _blas._openblas_controls()
    assert len(scans) == 1
    monkeypatch.setitem(sys.modules, "piezohyst_test_new_module", types.ModuleType("piezohyst_test_new_module"))
    _blas._openblas_controls()
    assert len(scans) == 2


def test_the_model_search_solves_on_one_thread(monkeypatch):
    # the search's hundreds of small Cholesky solves took 2-14x longer on two threads of a busy
    # 2-core machine (commission() 3.6 -> 7.2 s when a helper slipped in between fit_model and
    # its decorator): every solve inside fit_model must see one thread
    import piezohyst as ph
    import piezohyst.identify.linear as linear

    if not _blas._openblas_controls():
        pytest.skip("no OpenBLAS found in this process")
    seen = []
    solve = linear.bounded_lstsq_gram

    def spy(*args, **kwargs):
        seen.append(max(int(get()) for _, get in _blas._openblas_controls()))
        return solve(*args, **kwargs)

    monkeypatch.setattr(linear, "bounded_lstsq_gram", spy)
    u = ph.sinusoid(1.0, 4, 0.0, 100.0, 1e-3) * np.linspace(1.0, 0.5, 4000)
    y = ph.PrandtlIshlinskii([0.0, 10.0, 25.0], [0.1, 0.05, 0.03]).simulate(u)
    ph.fit_model(u, y, 1e-3, kinds=["pi"])
    assert seen and max(seen) == 1
