"""The "Edge profiles" widget, offscreen against a ViewerModel (no GL canvas)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from napari.layers import Points, Shapes
from napari.utils.colormaps import ensure_colormap

from napari_edgecme._widgets.camera_motion import CameraMotionWidget
from napari_edgecme._widgets.edge_profiles import (
    ORIGIN_KEY,
    EdgeProfilesWidget,
    profile_lines,
)
from napari_edgecme.core.edges import EdgeProfiles, extract_edge_profiles

pytestmark = pytest.mark.gui

SCALE, TRANSLATE = (0.5, 0.5), (10.0, -4.0)
MAX_BLUR = 9.0


@pytest.fixture
def setup(qtbot, viewer_model, edge_case):
    image = viewer_model.add_image(edge_case.blurred, name="shaken", scale=SCALE,
                                   translate=TRANSLATE)
    widget = EdgeProfilesWidget(viewer_model)
    qtbot.addWidget(widget)
    # napari calls reset_choices on a docked widget when layers change; here we do it
    widget.reset_choices()
    widget.image_combo.value = image
    widget.max_blur.auto.setChecked(False)
    widget.max_blur.spin.setValue(MAX_BLUR)
    return SimpleNamespace(viewer=viewer_model, image=image, widget=widget)


@pytest.fixture
def detected(setup, wait_for_run):
    """``setup`` after a detection: with its ``shapes`` and ``points`` layers."""
    setup.widget.detect_button.click()
    wait_for_run(setup.widget)
    setup.shapes, setup.points = setup.widget.current_layers
    return setup


def profiles_of(shapes) -> EdgeProfiles:
    return shapes.metadata["edgecme_profiles"]


def test_detect_draws_each_profile_as_a_line_across_its_edge_and_its_centroid(detected,
                                                                            edge_case):
    d = detected
    assert d.widget.runner.outcome == "done"
    assert d.widget.detect_button.isEnabled() and not d.widget.cancel_button.isEnabled()
    assert isinstance(d.shapes, Shapes) and isinstance(d.points, Points)
    assert [layer.name for layer in d.viewer.layers] == [
        "shaken", "shaken edge profiles", "shaken profile centroids"]

    profiles = profiles_of(d.shapes)
    expected = extract_edge_profiles(edge_case.blurred, MAX_BLUR, rng=0)
    assert len(profiles) == len(expected) >= 12
    np.testing.assert_allclose(profiles.centroids, expected.centroids)

    # one line per profile, centred on its centroid, along its normal (napari keeps
    # vertices as float32)
    assert len(d.shapes.data) == len(profiles)
    assert set(d.shapes.shape_type) == {"line"}
    lines = np.stack(d.shapes.data).astype(float)
    np.testing.assert_allclose(lines.mean(axis=1), profiles.centroids, atol=1e-4)
    direction = lines[:, 1] - lines[:, 0]
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    np.testing.assert_allclose(direction, profiles.normals, atol=1e-5)
    np.testing.assert_allclose(d.points.data, profiles.centroids)

    # coloured by quality, and aligned with the d.image
    colours = ensure_colormap("viridis").map(np.clip(profiles.quality, 0, 1))
    np.testing.assert_allclose(d.shapes.edge_color, colours, atol=1e-6)
    np.testing.assert_allclose(d.shapes.features["quality"], profiles.quality)
    for layer in (d.shapes, d.points):
        np.testing.assert_allclose(layer.scale, SCALE)
        np.testing.assert_allclose(layer.translate, TRANSLATE)
    np.testing.assert_allclose(d.shapes.features["confidence"], profiles.confidence)
    text = d.widget.count_label.text()
    assert f"{len(profiles)} profiles" in text
    assert f"median confidence {np.median(profiles.confidence):.2f}" in text
    assert profiles.coverage_summary() in text and "orientations" in text
    assert d.widget.runner.progress_bar is None


def test_deleting_lines_deletes_their_profiles(qtbot, detected):
    d = detected
    before = profiles_of(d.shapes)
    d.shapes.selected_data = {0, 2}
    d.shapes.remove_selected()
    qtbot.waitUntil(lambda: len(profiles_of(d.shapes)) == len(before) - 2)
    after = profiles_of(d.shapes)
    keep = np.ones(len(before), bool)
    keep[[0, 2]] = False
    np.testing.assert_allclose(after.centroids, before.centroids[keep])
    np.testing.assert_allclose(d.points.data, after.centroids)
    assert len(d.shapes.data) == len(after)
    assert d.widget.count_label.text().startswith(f"{len(after)} profiles")


def test_a_line_drawn_across_an_edge_becomes_a_hand_picked_profile(qtbot, detected):
    d = detected
    before = profiles_of(d.shapes)
    c, n = before.centroids[0], before.normals[0]
    d.shapes.selected_data = {0}
    d.shapes.remove_selected()
    qtbot.waitUntil(lambda: len(profiles_of(d.shapes)) == len(before) - 1)

    # what a user's stroke across that edge produces (the line tool adds a line shape)
    d.shapes.add_lines([np.array([c - 9 * n, c + 9 * n])])
    qtbot.waitUntil(lambda: len(profiles_of(d.shapes)) == len(before))

    after = profiles_of(d.shapes)
    new = after.subset([len(after) - 1])
    assert np.hypot(*(new.centroids[0] - c)) < 1.0  # the same edge, found again
    assert d.shapes.metadata[ORIGIN_KEY][-1] == "hand"
    assert list(d.shapes.features["origin"])[-1] == "hand"
    # redrawn as a profile line, centred on its own centroid, and selected for the plot
    np.testing.assert_allclose(np.mean(d.shapes.data[-1], axis=0), new.centroids[0], atol=1e-4)
    assert set(d.shapes.selected_data) == {len(after) - 1}
    assert "picked by hand" in d.widget.plot_caption.text()
    assert "1 by hand" in d.widget.count_label.text()


def test_a_refused_pick_says_why_and_is_removed(qtbot, detected, notifications):
    d = detected
    n = len(profiles_of(d.shapes))
    d.shapes.add_lines([np.array([[3.0, 3.0], [5.0, 5.0]])])  # far too short
    qtbot.waitUntil(lambda: len(d.shapes.data) == n)
    d.shapes.add_rectangles([np.array([[20.0, 20.0], [40.0, 40.0]])])
    qtbot.waitUntil(lambda: len(d.shapes.data) == n)
    warnings = notifications.texts("warning")
    assert any("line refused: line too short" in text for text in warnings), warnings
    assert any("not a line" in text for text in warnings), warnings
    assert len(profiles_of(d.shapes)) == n


def test_selecting_a_line_plots_its_profile_and_derivative(detected):
    d = detected
    profiles = profiles_of(d.shapes)
    assert d.widget.plot_caption.text().startswith(f"all {len(profiles)} profiles")
    d.shapes.selected_data = {3}
    assert d.widget.plot_caption.text().startswith("profile 3 (detected)")
    ax_profile, ax_derivative = d.widget.canvas.figure.axes
    (curve_p,) = ax_profile.collections[0].get_segments()
    (curve_d,) = ax_derivative.collections[0].get_segments()
    np.testing.assert_allclose(curve_p[:, 1], profiles.profiles[3])
    np.testing.assert_allclose(curve_d[:, 1], profiles.derivatives[3])
    np.testing.assert_allclose(curve_d[:, 0], profiles.offsets)


def test_export_writes_the_profile_set_as_json(detected, tmp_path):
    d = detected
    path = d.widget.export(tmp_path / "profiles.json")
    loaded = EdgeProfiles.load(path)
    np.testing.assert_allclose(loaded.centroids, profiles_of(d.shapes).centroids)
    np.testing.assert_allclose(loaded.derivatives, profiles_of(d.shapes).derivatives)


def test_a_new_detection_keeps_the_hand_picks(qtbot, detected, wait_for_run):
    d = detected
    before = profiles_of(d.shapes)
    c, n = before.centroids[1], before.normals[1]
    d.shapes.add_lines([np.array([c - 9 * n, c + 9 * n])])
    qtbot.waitUntil(lambda: len(profiles_of(d.shapes)) == len(before) + 1)
    d.widget.detect_button.click()
    wait_for_run(d.widget)
    assert d.widget.current_layers[0] is d.shapes  # the same layers, redrawn
    assert len(d.viewer.layers) == 3
    assert d.shapes.metadata[ORIGIN_KEY].count("hand") == 1
    assert len(profiles_of(d.shapes)) == len(before) + 1


def test_an_image_without_edges_gives_a_notification_and_no_layer(qtbot, viewer_model,
                                                                 notifications,
                                                                 wait_for_run):
    flat = viewer_model.add_image(np.full((96, 96), 0.4, np.float32), name="flat")
    widget = EdgeProfilesWidget(viewer_model)
    qtbot.addWidget(widget)
    widget.reset_choices()
    widget.image_combo.value = flat
    widget.detect_button.click()
    wait_for_run(widget)
    assert [layer.name for layer in viewer_model.layers] == ["flat"]
    assert any("no usable edge profiles" in text for text in notifications.texts("warning"))


def test_pick_by_hand_without_detection_starts_an_empty_profile_layer(qtbot, setup):
    viewer, widget = setup.viewer, setup.widget
    widget.pick_button.click()
    shapes = widget.current_layers[0]
    assert viewer.layers.selection.active is shapes
    assert shapes.mode == "add_line"
    assert len(profiles_of(shapes)) == 0
    np.testing.assert_allclose(shapes.scale, SCALE)


def test_the_profiles_feed_the_motion_widget(qtbot, detected, wait_for_run, notifications):
    d = detected
    # keep only a few profiles: Xu+Ep must use exactly these, and says it has too few
    d.shapes.selected_data = set(range(3, len(d.shapes.data)))
    d.shapes.remove_selected()
    qtbot.waitUntil(lambda: len(profiles_of(d.shapes)) == 3)

    motion = CameraMotionWidget(d.viewer)
    qtbot.addWidget(motion)
    motion.reset_choices()
    motion.image_combo.value = d.image
    assert motion.profiles_combo.value is d.shapes  # offered because they belong to the d.image
    motion.model_combo.value = "inplane"
    motion.max_blur.auto.setChecked(False)
    motion.max_blur.spin.setValue(7)
    motion.n_iter.setValue(1)
    motion.run_button.click()
    wait_for_run(motion)
    assert motion.runner.outcome == "done"
    assert motion.last_estimate.info.n_profiles == 3
    assert motion.last_estimate.info.message.startswith("fell back to 'xu'")
    assert any("falling back to method 'xu'" in text for text in notifications.texts("warning"))


def test_profile_lines_span_the_sampling_window():
    profiles = EdgeProfiles([[10.0, 20.0]], [0.0], [0.9], [0.1], np.zeros((1, 5)),
                            np.zeros((1, 5)), np.arange(-2.0, 3.0), [1.0])
    # normal angle 0 points along +x (columns): the line runs from col 18 to col 22
    np.testing.assert_allclose(profile_lines(profiles)[0], [[10.0, 18.0], [10.0, 22.0]])


@pytest.mark.parametrize("method", ["ep", "xu+ep"])
def test_epalone_and_xu_ep_estimate_from_the_layers_profiles(qtbot, detected, wait_for_run,
                                                            notifications, method):
    pytest.importorskip("napari_edgecme.core.prediction",
                        reason="the engine's prediction images (I_p, I_ep) are not there yet")
    d = detected
    motion = CameraMotionWidget(d.viewer)
    qtbot.addWidget(motion)
    motion.reset_choices()
    motion.image_combo.value = d.image
    assert motion.profiles_combo.value is d.shapes
    motion.method_combo.value = method
    motion.model_combo.value = "inplane"
    motion.max_blur.auto.setChecked(False)
    motion.max_blur.spin.setValue(7)
    motion.n_iter.setValue(1)
    motion.run_button.click()
    wait_for_run(motion)
    assert motion.runner.outcome == "done", notifications.texts()
    assert motion.last_estimate.info.n_profiles == len(profiles_of(d.shapes))
    assert f"{d.image.name} PSF field" in [layer.name for layer in d.viewer.layers]


def test_a_users_choice_of_profiles_sticks(qtbot, detected):
    d = detected
    motion = CameraMotionWidget(d.viewer)
    qtbot.addWidget(motion)
    motion.reset_choices()
    assert motion.profiles_combo.value is d.shapes
    motion.profiles_combo.value = None  # "detect automatically"
    motion.reset_choices()  # as napari does whenever a layer is added or removed
    assert motion.profiles_combo.value is None


def test_on_auto_neither_widget_shows_a_value_it_will_not_use(qtbot, viewer_model):
    """Issue 15, item 3 (the widget showed 15 px while detection used 27), and issue 14:
    auto is measured when run, so the box shows no number; unchecking auto starts from
    the default for the chosen image (4% of its longer side, at least 15 px)."""
    from napari_edgecme.core.estimate import default_max_blur

    photo = viewer_model.add_image(np.zeros((406, 679), np.float32), name="photo")
    # built with the layer already there (as when docked after opening a photo)
    profiles = EdgeProfilesWidget(viewer_model)
    motion = CameraMotionWidget(viewer_model)
    for widget in (profiles, motion):
        qtbot.addWidget(widget)
    assert default_max_blur((406, 679)) == 27.0
    small = viewer_model.add_image(np.zeros((200, 120), np.float32), name="small")
    for widget in (profiles, motion):
        control = widget.max_blur
        assert widget.image_combo.value is photo and control.auto.isChecked()
        assert control.value_for((406, 679)) is None  # the run measures it
        assert not control.spin.isEnabled() and control.spin.text() == "measured when run"
        assert "measured from the image" in control.spin.toolTip()
        control.auto.setChecked(False)
        assert control.spin.isEnabled() and control.spin.value() == 27.0
        assert control.value_for((406, 679)) == 27.0
        control.spin.setValue(12.0)
        assert control.value_for((406, 679)) == 12.0
        control.auto.setChecked(True)
        assert control.spin.text() == "measured when run"
        widget.reset_choices()
        widget.image_combo.value = small
        control.auto.setChecked(False)
        assert control.spin.value() == default_max_blur((200, 120)) == 15.0
        control.auto.setChecked(True)


def test_the_count_and_status_describe_the_chosen_image(qtbot, detected, wait_for_run):
    """Issue 15, item 5: the profile count described the previous image."""
    d = detected
    assert d.widget.count_label.text().startswith(f"{len(profiles_of(d.shapes))} profiles in")
    assert "detected in 'shaken'" in d.widget.status.text()
    other = d.viewer.add_image(np.zeros((64, 64), np.float32), name="other")
    d.widget.reset_choices()
    d.widget.image_combo.value = other
    assert d.widget.count_label.text() == "no profiles for 'other' yet: Detect, or Pick by hand"
    assert d.widget.status.text() == ""
    assert d.widget.current_layers is None
    # selecting the first image's profile layer brings its image and set back
    d.viewer.layers.selection.active = d.shapes
    assert d.widget.image_combo.value is d.image
    assert d.widget.current_layers[0] is d.shapes
    assert "profiles in 'shaken edge profiles'" in d.widget.count_label.text()


def test_a_run_refused_on_the_main_thread_replaces_a_stale_cancelled(qtbot, viewer_model,
                                                                      notifications):
    widget = EdgeProfilesWidget(viewer_model)
    qtbot.addWidget(widget)
    widget.status.setText("Edge profiles: cancelled")  # left by an earlier run
    widget.detect_button.click()  # no image layer at all
    assert widget.runner.outcome == "refused"
    assert widget.status.text() == "Edge profiles: not run: choose an image layer first"
    assert notifications.texts("error") == ["Edge profiles: choose an image layer first"]
