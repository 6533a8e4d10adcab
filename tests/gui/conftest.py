"""Fixtures of the napari widget tests.

Two kinds of test live here (markers declared in pyproject.toml; ``-m "not viewer"``
runs only the first kind, with ``QT_QPA_PLATFORM=offscreen`` and no X display):

* ``@pytest.mark.gui``: widgets built against ``napari.components.ViewerModel`` (no GL
  canvas), driven with pytest-qt on the offscreen platform;
* ``@pytest.mark.viewer``: a few tests in a real ``napari.Viewer`` made by
  ``make_napari_viewer_proxy``, on a virtual X display (pytest-xvfb).

Runs are awaited by polling state (``qtbot.waitUntil``), never by connecting to a
worker signal after it started.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from napari_edgecme.core.synth import SyntheticCase, edge_scene, make_case, sample_image

try:  # the engine's tests run without Qt: then these are not even collected
    import napari  # noqa: F401
    import pytestqt  # noqa: F401
    import qtpy  # noqa: F401
except ImportError:
    collect_ignore_glob = ["test_*.py"]

#: Where tests leave files for people to look at (git-ignored).
ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts"

#: A guard against a hung run (ms), not a timing figure: the longest run here (Xu+Ep in
#: ``test_viewer.py``) takes about 15 s on the idle machine and passed 30 s while the
#: machine ran a two-job benchmark beside the tests.
RUN_TIMEOUT = 120_000


@pytest.fixture(scope="session")
def edge_case() -> SyntheticCase:
    """A 112 px edge scene with a small in-plane shake (many clean edge profiles)."""
    return make_case(edge_scene((112, 112), rng=0), "inplane", extent=5.0, rng=0,
                     name="edges-112")


@pytest.fixture(scope="session")
def photo_case() -> SyntheticCase:
    """A 96 px photo with an in-plane shake (the engine's deconvolution doctest case)."""
    return make_case(sample_image("camera", 96), "inplane", extent=9.0, rng=0,
                     name="camera-96")


@pytest.fixture
def viewer_model():
    from napari.components import ViewerModel

    return ViewerModel()


class Notifications(list):
    """napari notifications received during a test, in order."""

    def texts(self, severity: str | None = None) -> list[str]:
        """Their messages, optionally only those of one severity ("error", "warning", ...)."""
        return [str(n.message) for n in self
                if severity is None or str(n.severity).lower() == severity]


@pytest.fixture
def notifications() -> Notifications:
    """Every napari notification dispatched during the test."""
    from napari.utils.notifications import notification_manager

    received = Notifications()
    notification_manager.notification_ready.connect(received.append)
    yield received
    notification_manager.notification_ready.disconnect(received.append)


@pytest.fixture
def wait_for_run(qtbot):
    """``wait_for_run(widget)``: poll until a widget's run (or a runner's) has ended."""

    def wait(widget, timeout: int = RUN_TIMEOUT) -> None:
        runner = getattr(widget, "runner", widget)
        qtbot.waitUntil(lambda: not runner.is_running, timeout=timeout)
        assert runner.progress_bar is None

    return wait


@pytest.fixture
def assert_same_motion():
    """``assert_same_motion(a, b)``: equal up to the round-off of a JSON round trip."""

    def check(a, b) -> None:
        assert a.model == b.model and a.intrinsics == b.intrinsics
        np.testing.assert_allclose(a.poses, b.poses, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(a.weights, b.weights, rtol=1e-12, atol=1e-15)

    return check


@pytest.fixture(scope="session")
def plugins():
    """npe2's plugin manager with the installed plugins (napari's builtins, this one)."""
    from npe2 import PluginManager

    manager = PluginManager.instance()
    manager.discover()
    return manager


@pytest.fixture(scope="session")
def artifacts_dir() -> Path:
    """``test-artifacts/`` at the repository root (git-ignored), created if needed."""
    ARTIFACTS.mkdir(exist_ok=True)
    return ARTIFACTS
