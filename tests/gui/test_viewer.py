"""Full-viewer tests: the widgets docked in a real napari Viewer, on a virtual X display.

``make_napari_viewer_proxy`` hands plugin code a proxy that raises if anything sets a
napari attribute from a worker thread, so these runs also check that the workers
only compute and that every layer is touched on the main thread. Run with
``pytest -m viewer`` under pytest-xvfb (not on the offscreen platform: no GL there).
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from qtpy.QtCore import QTimer
from qtpy.QtWidgets import QDockWidget

from napari_edgecme._widgets.camera_motion import CameraMotionWidget
from napari_edgecme._widgets.deconvolution import DeconvolutionWidget
from napari_edgecme._widgets.edge_profiles import EdgeProfilesWidget
from napari_edgecme.core.motion import CameraMotion
from napari_edgecme.core.progress import Progress

pytestmark = pytest.mark.viewer

PLUGIN = "napari-edgecme"
SCREENSHOT = "napari-edgecme-viewer.png"
WIDGETS = ("Edge profiles", "Camera motion", "Deconvolution")
#: The screen the docked widgets must fit (issue 15: a 1920x1080 display).
SCREEN = (1920, 1080)


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


def _docks(window) -> dict:
    """The plugin's dock widgets in a main window, by widget name."""
    found = {}
    for dock in window.findChildren(QDockWidget):
        for name in WIDGETS:
            if dock.windowTitle().startswith(name) and "napari-edgecme" in dock.windowTitle():
                found[name] = dock
    return found


def test_the_three_docked_widgets_fit_a_1920x1080_screen(make_napari_viewer_proxy, qtbot,
                                                         edge_case, artifacts_dir):
    """Docked from the menus (napari's way), the three widgets share one tab group and the
    window fits 1920x1080 with every widget's Run button and status line on screen."""
    viewer = make_napari_viewer_proxy(show=True)
    viewer.add_image(edge_case.blurred, name="shaken")
    widgets = {name: dock(viewer, name) for name in WIDGETS}
    window = widgets["Deconvolution"].window()  # the Qt main window (not a proxy)
    docks = _docks(window)
    assert set(docks) == set(WIDGETS)
    qtbot.waitUntil(lambda: all(len(window.tabifiedDockWidgets(d)) == 2
                                for d in docks.values()))
    window.resize(*SCREEN)
    qtbot.wait(100)
    hint = window.minimumSizeHint()
    assert hint.height() <= SCREEN[1] and hint.width() <= SCREEN[0]
    frame = window.frameGeometry()
    assert frame.height() <= SCREEN[1] and frame.width() <= SCREEN[0]
    for name in WIDGETS:  # each tab in turn: its controls are on screen, not squeezed
        docks[name].raise_()
        qtbot.wait(50)
        widget = widgets[name]
        for control in (widget.controls.run_button, widget.controls.cancel_button,
                        widget.status):
            assert control.isVisible()
            bottom = control.mapTo(window, control.rect().bottomRight())
            assert 0 <= bottom.y() <= window.height() and 0 <= bottom.x() <= window.width()
            assert control.height() >= control.minimumSizeHint().height()
    docks["Edge profiles"].raise_()
    qtbot.wait(100)
    path = artifacts_dir / "widgets-docked.png"
    window.grab().save(str(path))
    assert path.exists()


def test_a_flood_of_records_never_keeps_the_viewer_busy_for_100_ms(make_napari_viewer_proxy,
                                                                   qtbot, wait_for_run):
    """Thousands of records through a docked widget's runner, with napari's own progress
    bar in the activity dock: while they flow, the main thread never works 100 ms at a time.

    Measured by a 5 ms main-thread timer: between two of its ticks, the main thread's
    own CPU time (``time.thread_time``) -- the handlers and the repaints they cause. On
    this shared 2-core machine with software GL the wall-clock gaps are larger (a
    repaint of the window costs ~45 ms of rendering threads, and the CPU is contended);
    they are printed. From the first update to the last record: napari adding and
    removing its progress bar at the start and end of a run are one-off costs.
    """
    viewer = make_napari_viewer_proxy(show=True)
    viewer.add_image(np.zeros((64, 64), np.float32), name="img")
    widget = dock(viewer, "Deconvolution")
    runner = widget.runner
    n = 20_000

    def flood():
        for i in range(n):
            if i % 100 == 0:  # 200 pauses: the flood lasts >= 0.8 s on any machine
                time.sleep(0.004)
            yield Progress("demo", i + 1, n, f"record {i + 1}")
        return None

    ticks = []
    timer = QTimer()
    timer.setInterval(5)
    timer.timeout.connect(lambda: ticks.append(
        (time.perf_counter(), time.thread_time(), runner.n_updates, runner.n_records)))
    timer.start()
    start = time.perf_counter()
    runner.start(flood(), on_result=lambda _r: "flood done")
    wait_for_run(widget, timeout=60_000)
    run_time = time.perf_counter() - start
    timer.stop()
    flow = np.array([(wall, cpu) for wall, cpu, updates, records in ticks
                     if updates >= 1 and records < n])
    wall_gaps, cpu_gaps = np.diff(flow, axis=0).T
    duration = flow[-1, 0] - flow[0, 0]
    print(f"{n} records, {runner.n_updates} updates over {duration:.2f} s: longest "
          f"main-thread gap {1e3 * wall_gaps.max():.0f} ms wall, "
          f"{1e3 * cpu_gaps.max():.0f} ms CPU")
    assert runner.n_records == n
    assert duration > 0.5  # the flood was measured, not its end
    assert runner.n_updates <= 2 + run_time / (0.9 * runner.UPDATE_INTERVAL_MS / 1e3)
    assert cpu_gaps.max() < 0.100, f"main thread busy {1e3 * cpu_gaps.max():.0f} ms"
    assert widget.status.text() == "Deconvolution: flood done"


def test_sample_data_opens_in_the_viewer(make_napari_viewer_proxy):
    viewer = make_napari_viewer_proxy()
    viewer.open_sample(PLUGIN, "clock_motion")
    viewer.open_sample(PLUGIN, "edge_scene")
    assert [layer.name for layer in viewer.layers] == [
        "clock (motion blur)", "edge scene (sharp)", "edge scene (synthetic shake)"]
    motion = CameraMotion.from_dict(viewer.layers["edge scene (synthetic shake)"]
                                    .metadata["edgecme_motion"])
    assert motion.image_shape == (256, 256)
