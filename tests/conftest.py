"""Shared fixtures and marker rules. GUI tests live in tests/gui and are marked; the
engine tests need no Qt.

Markers (declared in pyproject.toml):

* ``gui``: napari/Qt widget tests. Every ``viewer`` test (a real napari viewer, under
  Xvfb) is a ``gui`` test too, so ``-m "not gui"`` runs the engine tests alone;
* ``slow``: deselected unless asked for, with ``--run-slow`` or a ``-m`` expression
  that names ``slow`` (e.g. ``-m slow``, ``-m "slow or not slow"``).
"""

import numpy as np
import pytest


def pytest_addoption(parser):
    parser.addoption("--run-slow", action="store_true", default=False,
                     help="also run the tests marked slow (deselected by default)")


@pytest.hookimpl(tryfirst=True)  # before pytest's own -m selection sees the markers
def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.get_closest_marker("viewer") is not None:
            item.add_marker(pytest.mark.gui)
    if config.getoption("--run-slow") or "slow" in (config.getoption("markexpr") or ""):
        return
    kept = [item for item in items if item.get_closest_marker("slow") is None]
    if len(kept) < len(items):
        config.hook.pytest_deselected(
            items=[item for item in items if item.get_closest_marker("slow") is not None])
        items[:] = kept


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def principal_axis():
    """``f(weights) -> (angle, elongation)``: the direction (degrees, of the row/col axes)
    and elongation of a weight image's second moments -- the streak of a drawn PSF."""
    def measure(weights: np.ndarray) -> tuple[float, float]:
        r, c = np.indices(weights.shape, dtype=float)
        total = weights.sum()
        mr, mc = (weights * r).sum() / total, (weights * c).sum() / total
        crr = (weights * (r - mr) ** 2).sum() / total
        ccc = (weights * (c - mc) ** 2).sum() / total
        crc = (weights * (r - mr) * (c - mc)).sum() / total
        low, high = np.linalg.eigvalsh([[crr, crc], [crc, ccc]])
        return float(np.degrees(0.5 * np.arctan2(2 * crc, ccc - crr))), high / max(low, 1e-12)

    return measure


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
