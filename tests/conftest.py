"""Shared fixtures. GUI tests live in tests/gui and are marked; the engine tests need no Qt."""

import numpy as np
import pytest


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
