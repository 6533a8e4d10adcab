"""Bad input in the three widgets (issue 8): the engine's one-line reason as one napari
notification titled with the widget's name, no layer added, the widget ready again.

The API and CLI faces of the same cases are in ``tests/test_robustness.py`` and
``docs/bad-inputs.md``.
"""

from __future__ import annotations

import numpy as np
import pytest

from napari_edgecme._widgets.camera_motion import CameraMotionWidget
from napari_edgecme._widgets.deconvolution import DeconvolutionWidget
from napari_edgecme._widgets.edge_profiles import EdgeProfilesWidget

pytestmark = pytest.mark.gui

NAN_MESSAGE = "image contains 1 non-finite values (NaN or inf)"


def nan_image() -> np.ndarray:
    image = np.full((64, 64), 0.5, np.float32)
    image[10, 20] = np.nan
    return image


def tiny_image() -> np.ndarray:
    return np.random.default_rng(0).random((8, 8)).astype(np.float32)


def make(qtbot, viewer, widget_class, layer):
    widget = widget_class(viewer)
    qtbot.addWidget(widget)
    widget.reset_choices()  # what napari does for a docked widget when layers change
    widget.image_combo.value = layer
    return widget


def camera_motion(qtbot, viewer, layer) -> CameraMotionWidget:
    widget = make(qtbot, viewer, CameraMotionWidget, layer)
    widget.method_combo.value = "xu"
    widget.model_combo.value = "translation"
    widget.n_iter.setValue(1)
    return widget


def deconvolution(qtbot, viewer, layer, motion_source) -> DeconvolutionWidget:
    widget = make(qtbot, viewer, DeconvolutionWidget, layer)
    widget.motion_combo.value = motion_source
    widget.method_combo.value = "wiener"
    return widget


def assert_refused(widget, viewer, names, notifications, title, message, severity="error"):
    assert [layer.name for layer in viewer.layers] == names  # no layer added
    texts = notifications.texts(severity)
    assert len(texts) == 1 and texts[0].startswith(f"{title}: "), texts
    assert message in texts[0], texts[0]
    assert "\n" not in texts[0]
    assert widget.run_button.isEnabled() if hasattr(widget, "run_button") else True


# --------------------------------------------------------------------------------------
# NaN pixels: refused by every widget
# --------------------------------------------------------------------------------------

def test_camera_motion_refuses_an_image_with_nan_pixels(qtbot, viewer_model, notifications,
                                                        wait_for_run):
    layer = viewer_model.add_image(nan_image(), name="nan")
    widget = camera_motion(qtbot, viewer_model, layer)
    widget.run_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "failed"
    assert_refused(widget, viewer_model, ["nan"], notifications, "Camera motion", NAN_MESSAGE)
    assert widget.last_motion is None


def test_deconvolution_refuses_an_image_with_nan_pixels(qtbot, viewer_model, notifications,
                                                        wait_for_run, photo_case):
    source = viewer_model.add_image(photo_case.blurred, name="photo",
                                    metadata={"edgecme_motion": photo_case.motion.to_dict()})
    layer = viewer_model.add_image(nan_image(), name="nan")
    widget = deconvolution(qtbot, viewer_model, layer, source)
    widget.run_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "failed"
    assert_refused(widget, viewer_model, ["photo", "nan"], notifications, "Deconvolution",
                   NAN_MESSAGE)


def test_edge_profiles_refuses_an_image_with_nan_pixels(qtbot, viewer_model, notifications,
                                                        wait_for_run):
    layer = viewer_model.add_image(nan_image(), name="nan")
    widget = make(qtbot, viewer_model, EdgeProfilesWidget, layer)
    widget.detect_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "failed"
    assert_refused(widget, viewer_model, ["nan"], notifications, "Edge profiles", NAN_MESSAGE)
    assert widget.current_layers is None


# --------------------------------------------------------------------------------------
# an 8x8 image: too small to estimate, no edge profiles, but deconvolvable
# --------------------------------------------------------------------------------------

def test_camera_motion_on_an_8x8_image_says_the_blur_does_not_fit(qtbot, viewer_model,
                                                                  notifications, wait_for_run):
    layer = viewer_model.add_image(tiny_image(), name="tiny")
    widget = camera_motion(qtbot, viewer_model, layer)
    assert widget.max_blur.auto.isChecked()  # the default 15 px is too much for 8x8
    widget.run_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "failed"
    assert_refused(widget, viewer_model, ["tiny"], notifications, "Camera motion",
                   "max_blur must be less than half the smaller image side (4 px); got 15")


def test_edge_profiles_on_an_8x8_image_warns_that_it_is_too_small(qtbot, viewer_model,
                                                                  notifications, wait_for_run):
    layer = viewer_model.add_image(tiny_image(), name="tiny")
    widget = make(qtbot, viewer_model, EdgeProfilesWidget, layer)
    widget.detect_button.click()
    wait_for_run(widget)
    assert_refused(widget, viewer_model, ["tiny"], notifications, "Edge profiles",
                   "no usable edge profiles in 'tiny': image 8x8 is too small for max_blur=15",
                   severity="warning")
    assert not notifications.texts("error")


def test_deconvolution_of_an_8x8_image_is_accepted(qtbot, viewer_model, notifications,
                                                   wait_for_run, photo_case):
    # documented: a motion of the same aspect ratio is rescaled; the result is finite
    source = viewer_model.add_image(photo_case.blurred, name="photo",
                                    metadata={"edgecme_motion": photo_case.motion.to_dict()})
    layer = viewer_model.add_image(tiny_image(), name="tiny")
    widget = deconvolution(qtbot, viewer_model, layer, source)
    widget.run_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "done"
    restored = viewer_model.layers["tiny deblurred"].data
    assert restored.shape == (8, 8) and np.all(np.isfinite(restored))
    assert not notifications.texts("error")


# --------------------------------------------------------------------------------------
# stacks are not offered; alpha is dropped
# --------------------------------------------------------------------------------------

@pytest.mark.parametrize("widget_class", [CameraMotionWidget, DeconvolutionWidget,
                                          EdgeProfilesWidget])
def test_a_3d_stack_is_not_offered_as_an_image(qtbot, viewer_model, widget_class):
    viewer_model.add_image(np.zeros((5, 64, 64), np.float32), name="stack")
    flat = viewer_model.add_image(np.zeros((64, 64), np.float32), name="plane")
    widget = widget_class(viewer_model)
    qtbot.addWidget(widget)
    widget.reset_choices()
    assert [layer for layer in widget.image_combo.choices if layer is not None] == [flat]


def test_an_rgba_image_is_estimated_without_its_alpha(qtbot, viewer_model, notifications,
                                                      wait_for_run, edge_case):
    gray = np.round(edge_case.blurred * 255).astype(np.uint8)
    rgba = np.stack([gray, gray, gray, np.full_like(gray, 128)], -1)
    layer = viewer_model.add_image(rgba, name="rgba", rgb=True)
    widget = camera_motion(qtbot, viewer_model, layer)
    widget.max_blur.auto.setChecked(False)
    widget.max_blur.spin.setValue(7)
    widget.run_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "done", notifications.texts()
    assert widget.last_motion is not None
    assert not notifications.texts("error")
