"""Full-viewer tests: the widgets docked in a real napari Viewer, on a virtual X display.

``make_napari_viewer_proxy`` hands plugin code a proxy that raises if anything sets a
napari attribute from a worker thread, so these runs also check that the workers
only compute and that every layer is touched on the main thread. Run with
``pytest -m viewer`` under pytest-xvfb (not on the offscreen platform: no GL there).
"""

from __future__ import annotations

import numpy as np
import pytest

from napari_edgecme._widgets.camera_motion import CameraMotionWidget
from napari_edgecme._widgets.deconvolution import DeconvolutionWidget
from napari_edgecme._widgets.edge_profiles import EdgeProfilesWidget
from napari_edgecme.core.motion import CameraMotion

pytestmark = pytest.mark.viewer

PLUGIN = "napari-edgecme"
SCREENSHOT = "napari-edgecme-viewer.png"


def dock(viewer, name: str):
    """Open a widget as napari does from the Plugins or Layers menu; return the widget."""
    _dock_widget, widget = viewer.window.add_plugin_dock_widget(PLUGIN, name)
    return widget


def test_the_three_widgets_dock_run_and_leave_a_screenshot(make_napari_viewer_proxy, qtbot,
                                                           edge_case, wait_for_run,
                                                           notifications, artifacts_dir):
    viewer = make_napari_viewer_proxy(show=True)
    viewer.window.resize(1900, 1100)
    image = viewer.add_image(edge_case.blurred, name="shaken", scale=(0.5, 0.5),
                             translate=(10.0, -4.0))

    profiles = dock(viewer, "Edge profiles")
    motion = dock(viewer, "Camera motion")
    deconv = dock(viewer, "Deconvolution")
    assert isinstance(profiles, EdgeProfilesWidget)
    assert isinstance(motion, CameraMotionWidget)
    assert isinstance(deconv, DeconvolutionWidget)

    # Edge profiles: detect in a worker, layers added on the main thread
    assert profiles.image_combo.value == image
    profiles.max_blur.auto.setChecked(False)
    profiles.max_blur.spin.setValue(9)
    profiles.detect_button.click()
    wait_for_run(profiles)
    assert profiles.runner.outcome == "done"
    assert [layer.name for layer in viewer.layers] == [
        "shaken", "shaken edge profiles", "shaken profile centroids"]
    shapes = viewer.layers["shaken edge profiles"]
    found = shapes.metadata["edgecme_profiles"]
    assert len(shapes.data) == len(found) >= 12
    # a hand pick across the first profile's edge, after deleting its line
    centre, normal = found.centroids[0], found.normals[0]
    shapes.selected_data = {0}
    shapes.remove_selected()
    shapes.add_lines([np.array([centre - 9 * normal, centre + 9 * normal])])
    qtbot.waitUntil(lambda: shapes.metadata["edgecme_profile_origin"][-1:] == ["hand"])
    assert len(shapes.metadata["edgecme_profiles"]) == len(shapes.data) == len(found)

    # Camera motion (Xu+Ep, the default) with the profiles of the layer, live preview
    assert motion.method_combo.value == "xu+ep"
    assert motion.profiles_combo.value == shapes
    motion.model_combo.value = "inplane"
    motion.max_blur.auto.setChecked(False)
    motion.max_blur.spin.setValue(7)
    motion.n_iter.setValue(4)
    motion.run_button.click()
    wait_for_run(motion)
    assert motion.runner.outcome == "done"
    assert motion.last_estimate.info.n_profiles == len(shapes.data)
    field = viewer.layers["shaken PSF field"]
    estimated = CameraMotion.from_dict(field.metadata["edgecme_motion"])
    assert estimated.image_shape == (112, 112)

    # Deconvolution with the estimated motion (napari refreshed the choices on its own)
    assert deconv.image_combo.value == image
    assert deconv.motion_combo.value == field
    deconv.run_button.click()
    wait_for_run(deconv)
    assert deconv.runner.outcome == "done"
    assert deconv.status.text() == "Deconvolution: added 'shaken deblurred'"
    assert f"{estimated.n_poses} poses" in motion.status.text()
    restored = viewer.layers["shaken deblurred"]
    assert restored.data.dtype == np.float32
    np.testing.assert_allclose(restored.scale, image.scale)
    np.testing.assert_allclose(restored.translate, image.translate)
    assert notifications.texts("error") == []

    # Screenshot for a person: image + PSF field in one panel, the restored image beside it
    for name in ("shaken edge profiles", "shaken profile centroids", "shaken latent"):
        layer = viewer.layers[name]
        layer.visible = False
        viewer.layers.move(viewer.layers.index(layer), len(viewer.layers))
    assert [layer.name for layer in viewer.layers][:3] == [
        "shaken", "shaken PSF field", "shaken deblurred"]
    grid = viewer.canvas.grid
    grid.stride, grid.spacing = 2, 0.05
    grid.enabled = True
    viewer.reset_view()
    qtbot.wait(200)
    path = artifacts_dir / SCREENSHOT
    shot = viewer.screenshot(path=str(path), canvas_only=False, flash=False)
    assert path.exists() and shot.ndim == 3 and shot.shape[0] > 400
    assert shot[..., :3].std() > 10  # not a blank frame


def test_sample_data_opens_in_the_viewer(make_napari_viewer_proxy):
    viewer = make_napari_viewer_proxy()
    viewer.open_sample(PLUGIN, "clock_motion")
    viewer.open_sample(PLUGIN, "edge_scene")
    assert [layer.name for layer in viewer.layers] == [
        "clock (motion blur)", "edge scene (sharp)", "edge scene (synthetic shake)"]
    motion = CameraMotion.from_dict(viewer.layers["edge scene (synthetic shake)"]
                                    .metadata["edgecme_motion"])
    assert motion.image_shape == (256, 256)
