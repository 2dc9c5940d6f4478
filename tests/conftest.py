import os

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

# Hypothesis: deterministic in CI, bounded run time (the whole suite must stay < 10 min on 2 cores).
settings.register_profile(
    "ci", max_examples=40, deadline=None, derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile("dev", max_examples=100, deadline=None)
settings.load_profile("ci" if os.environ.get("CI") else "dev")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "data")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
