"""A fit's numbers are the same in every process: the one that compiled the kernels and those that
load them from numba's on-disk cache (a fleet's workers, a second run of a command).

Kernels compiled with numba's fastmath "reassoc" leave the order of a sum to the optimiser, and
the code a process compiles and runs was seen to differ from what it writes to the cache: Z'y of
a P-I fit differed in the last bits, and so did fit RMSEs between a fleet's workers and the test
that compared them with ph.fit_pi. The sums of the normal equations are now strictly ordered.
"""

import os
import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent("""
    import numpy as np
    from piezohyst.models.play import pi_gram
    rng = np.random.default_rng(7)
    t = np.arange(3000) / 500.0
    u = 50 + 50 * np.sin(2 * np.pi * t)
    y = 0.02 * u + 0.1 * np.sin(2 * np.pi * t - 0.2) + 1e-3 * rng.standard_normal(t.size)
    st = pi_gram(u, np.linspace(0, 95, 20), y, delays=[0, 2])
    for name in ("gram", "zty", "zsum", "ysum", "yty"):
        print(name, np.asarray(getattr(st, name)).tobytes().hex())
""")


@pytest.mark.slow
def test_normal_equations_same_compiled_and_from_cache(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    env.pop("PIEZOHYST_NO_CACHE", None)
    runs = [subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=300)
            for _ in range(2)]  # the first compiles and writes the cache, the second loads it
    for run in runs:
        assert run.returncode == 0, run.stderr[-2000:]
    assert any((tmp_path / "numba-cache").rglob("*.nbi")), "the first run wrote no cache"
    compiled, cached = (dict(line.split() for line in run.stdout.splitlines()) for run in runs)
    assert compiled == cached


def test_a_fits_residual_is_strictly_ordered_on_noisy_inputs():
    """On a noisy command (the dense path) fit_pi's RMSE comes from pi_step's strict loop, not
    from the reassociated dense kernel that simulate uses for speed."""
    import numpy as np

    import piezohyst as ph
    from piezohyst.models.play import pi_simulate_dense, pi_simulate_strict, prefers_events

    rng = np.random.default_rng(11)
    u = rng.uniform(0.0, 100.0, 4000)
    true = ph.PrandtlIshlinskii(ph.equal_thresholds(8, 100.0), rng.uniform(0.01, 0.1, 8))
    y = true.simulate(u) + 1e-3 * rng.standard_normal(u.size)
    fit = ph.fit_pi(u, y, n=8, u_max=100.0)
    m = fit.model
    assert not prefers_events(u, m.thresholds)
    strict = pi_simulate_dense(u, m.thresholds, m.weights, np.array(m.initial_state), m.input_offset, m.offset)
    np.testing.assert_array_equal(
        pi_simulate_strict(u, m.thresholds, m.weights, np.array(m.initial_state), m.input_offset, m.offset), strict)
    assert fit.rmse == float(np.sqrt(np.mean((y - strict) ** 2)))
