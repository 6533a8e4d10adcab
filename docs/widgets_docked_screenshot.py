"""Make docs/widgets-docked.png and time the plugin's runs in the viewer against Python.

Usage (needs a display; under Xvfb)::

    xvfb-run -a -s "-screen 0 1920x1080x24" python docs/widgets_docked_screenshot.py PHOTO

Opens PHOTO in a 1920x1080 napari window, docks the three widgets from the plugin
(they join one tab group), runs Detect, Camera motion (Xu+Ep, the defaults) and
Deconvolution (the defaults), then runs the same engine generators from Python with
the same parameters and prints both times. The screenshot shows the photo with the
PSF field over it and the Camera motion tab.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import napari
import numpy as np
from qtpy.QtWidgets import QApplication

from napari_edgecme.core.deconv import iter_deconvolve
from napari_edgecme.core.estimate import iter_estimate_motion

OUT = Path(__file__).resolve().parent / "widgets-docked.png"


def wait(widget, app) -> float:
    """Seconds until the widget's run ends (the event loop keeps running meanwhile)."""
    start = time.perf_counter()
    while widget.runner.is_running:
        app.processEvents()
        time.sleep(0.005)
    return time.perf_counter() - start


def drive(gen):
    """Run an engine generator to its end from Python; its result and the seconds taken."""
    start = time.perf_counter()
    try:
        while True:
            next(gen)
    except StopIteration as stop:
        return stop.value, time.perf_counter() - start


def main(photo: str) -> None:
    app = QApplication.instance() or QApplication([])
    viewer = napari.Viewer(show=True)
    viewer.window._qt_window.resize(1920, 1080)
    name = Path(photo).parent.name or Path(photo).stem
    layer = viewer.open(photo, plugin="napari")[0]
    layer.name = name
    widgets = {n: viewer.window.add_plugin_dock_widget("napari-edgecme", n)[1]
               for n in ("Edge profiles", "Camera motion", "Deconvolution")}
    for _ in range(20):
        app.processEvents()
    profiles, motion, deconv = (widgets[n] for n in widgets)

    profiles.detect_button.click()
    t_detect = wait(profiles, app)
    motion.run_button.click()
    t_motion = wait(motion, app)
    deconv.image_combo.value = layer
    deconv.run_button.click()
    t_deconv = wait(deconv, app)

    for extra in (f"{name} edge profiles", f"{name} profile centroids", f"{name} deblurred"):
        if extra in viewer.layers:
            viewer.layers[extra].visible = False
    viewer.layers.selection.active = layer
    motion_dock = next(d for d in viewer.window._wrapped_dock_widgets.values()
                       if d.inner_widget() is motion)
    motion_dock.raise_()
    viewer.reset_view()
    for _ in range(30):
        app.processEvents()
        time.sleep(0.02)
    window = viewer.window._qt_window
    window.grab().save(str(OUT))
    print(f"window {window.width()}x{window.height()}; wrote {OUT}")

    # the same work from Python (no viewer): the engine's generators, same parameters
    data = np.asarray(layer.data)[..., :3] if layer.rgb else np.asarray(layer.data)
    est = motion.last_estimate
    gen = iter_estimate_motion(
        data, "xu+ep", est.info.model, est.info.max_blur, motion.focal_spin.value(),
        motion._chosen_profiles(data.shape),  # the profile layer's set, as the widget used
        lambda_w=motion.lambda_w.value(), lambda_ip=motion.lambda_ip.value(),
        lambda_f=motion.lambda_f.value(), n_iter=motion.n_iter.value(),
        max_side=motion.max_side.value(), preview=False, rng=motion.seed.value())
    _, p_motion = drive(gen)
    _, p_deconv = drive(iter_deconvolve(data, deconv.fitted_motion().motion,
                                        **deconv.parameters()))
    print(f"detect {t_detect:.1f} s in the viewer")
    print(f"Xu+Ep: {t_motion:.1f} s in the viewer, {p_motion:.1f} s from Python")
    print(f"deconvolution: {t_deconv:.1f} s in the viewer, {p_deconv:.1f} s from Python")
    print(f"status: {motion.status.text()}")
    viewer.close()


if __name__ == "__main__":
    main(sys.argv[1])
