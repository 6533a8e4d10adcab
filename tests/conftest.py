"""Shared fixtures. GUI tests live in tests/gui and are marked; the engine tests need no Qt."""

import numpy as np
import pytest


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


try:  # property tests: the same examples on every run (CI must not be a lottery);
    # HYPOTHESIS_PROFILE=explore draws fresh ones when hunting for bugs
    from hypothesis import HealthCheck, settings

    # a shared, loaded machine must not fail a test for being slow
    settings.register_profile("reproducible", derandomize=True,
                              suppress_health_check=[HealthCheck.too_slow])
    settings.register_profile("explore", max_examples=1000)
    settings.load_profile(__import__("os").environ.get("HYPOTHESIS_PROFILE", "reproducible"))
except ImportError:
    pass
