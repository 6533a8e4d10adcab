"""The "Camera motion" widget, offscreen against a ViewerModel (no GL canvas)."""

from __future__ import annotations

import re
import time
from types import SimpleNamespace

import numpy as np
import pytest
from napari.utils import progress

from napari_edgecme._widgets._psf_view import BACKGROUND, psf_glyphs
from napari_edgecme._widgets.camera_motion import CameraMotionWidget, psf_grid
from napari_edgecme.core.camera import Intrinsics
from napari_edgecme.core.estimate import DEFAULTS
from napari_edgecme.core.motion import CameraMotion

pytestmark = pytest.mark.gui

SCALE, TRANSLATE = (0.5, 0.5), (10.0, -4.0)


def make_widget(qtbot, viewer, image, *, method="xu", n_iter=1) -> CameraMotionWidget:
    widget = CameraMotionWidget(viewer)
    qtbot.addWidget(widget)
    widget.reset_choices()  # what napari does for a docked widget when layers change
    widget.image_combo.value = image
    widget.method_combo.value = method
    widget.model_combo.value = "inplane"
    widget.max_blur.auto.setChecked(False)
    widget.max_blur.spin.setValue(7)
    widget.n_iter.setValue(n_iter)  # in the "advanced" fold: keeps the suite fast
    return widget


@pytest.fixture
def setup(qtbot, viewer_model, edge_case):
    image = viewer_model.add_image(edge_case.blurred, name="shaken", scale=SCALE,
                                   translate=TRANSLATE)
    return SimpleNamespace(viewer=viewer_model, image=image,
                           widget=make_widget(qtbot, viewer_model, image))


def test_defaults_are_the_engines(qtbot, viewer_model, edge_case):
    image = viewer_model.add_image(edge_case.blurred, name="shaken")
    widget = CameraMotionWidget(viewer_model)
    qtbot.addWidget(widget)
    widget.reset_choices()
    assert widget.image_combo.value is image
    assert widget.method_combo.value == "xu+ep"
    assert widget.model_combo.value == "rotation"
    assert widget.max_blur.auto.isChecked()  # measured when run: no value shown
    assert widget.max_blur.value_for(edge_case.blurred.shape) is None
    assert not widget.max_blur.spin.isEnabled()
    assert widget.max_blur.spin.text() == "measured when run"
    assert widget.focal_auto.isChecked()
    assert widget.profiles_combo.value is None  # detect automatically
    assert widget.lambda_w.value() == pytest.approx(DEFAULTS["lambda_w"])
    assert widget.lambda_ip.value() == pytest.approx(DEFAULTS["lambda_ip"])
    assert widget.lambda_f.value() == pytest.approx(DEFAULTS["lambda_f"])
    assert widget.n_iter.value() == DEFAULTS["n_iter"]
    assert widget.max_side.value() == DEFAULTS["max_side"]
    assert not widget.advanced.isExpanded()
    assert not widget.cancel_button.isEnabled() and not widget.save_button.isEnabled()


def test_a_run_adds_an_aligned_psf_field_and_latent_carrying_the_motion(setup, wait_for_run,
                                                                       tmp_path,
                                                                       assert_same_motion):
    s = setup
    s.widget.run_button.click()
    assert not s.widget.run_button.isEnabled()  # disabled while running
    wait_for_run(s.widget)
    assert s.widget.runner.outcome == "done"
    assert s.widget.run_button.isEnabled() and not s.widget.cancel_button.isEnabled()
    assert [layer.name for layer in s.viewer.layers] == [
        "shaken", "shaken latent", "shaken PSF field"]

    field, latent = s.viewer.layers["shaken PSF field"], s.viewer.layers["shaken latent"]
    motion = CameraMotion.from_dict(field.metadata["edgecme_motion"])
    assert_same_motion(motion, s.widget.last_motion)
    assert motion.model == "inplane" and motion.image_shape == (112, 112)
    assert np.isclose(sum(motion.weights), 1.0)
    assert latent.metadata["edgecme_motion"] == field.metadata["edgecme_motion"]

    # the PSF field is the motion's, drawn over the image: same grid, scale and translate
    glyphs = psf_glyphs(motion, psf_grid((112, 112)))
    assert field.rgb and field.data.shape == (112, 112, 4)
    np.testing.assert_array_equal(field.data, glyphs.rgba)
    assert field.blending == "translucent"
    assert field.metadata["edgecme_psf_enlargement"] == glyphs.enlargement >= 2
    assert f"each PSF drawn {glyphs.enlargement}x its size" in s.widget.status.text()
    for layer in (field, latent):
        np.testing.assert_allclose(layer.scale, SCALE)
        np.testing.assert_allclose(layer.translate, TRANSLATE)
    assert not latent.visible
    assert field.metadata["edgecme_estimate"]["method"] == "xu"

    # the pose-space view shows every pose, and the motion saves as a motion file
    scatter = s.widget.canvas.figure.axes[0].collections[0]
    assert len(scatter.get_offsets()) == motion.n_poses
    assert s.widget.save_button.isEnabled()
    saved, estimated_by, misfit = CameraMotion.load_estimate(
        s.widget.save_motion(tmp_path / "m.json"))
    assert_same_motion(saved, motion)
    assert estimated_by == "xu"  # the file names its estimator, as the layer does
    assert misfit is None  # Xu fits no edge profiles
    assert f"{motion.n_poses} poses" in s.widget.status.text()
    # one blur extent (issue 15, item 10): the number shown is CameraMotion.blur_extent
    (shown,) = re.findall(r"blur extent (\d+\.\d) px \(longest side of the PSFs\)",
                          s.widget.status.text())
    assert shown == f"{motion.blur_extent():.1f}"


def test_the_latent_preview_updates_while_xu_refines(setup, wait_for_run):
    s = setup
    s.widget.n_iter.setValue(3)
    inserted, names, updates = [], [], []

    def on_inserted(event):
        inserted.append(event.value)
        names.append(event.value.name)
        event.value.events.data.connect(lambda _event: updates.append(
            (s.viewer.layers.selection.active, event.value.opacity,
             s.viewer.layers.index(event.value))))

    s.viewer.layers.events.inserted.connect(on_inserted)
    s.widget.runner.PREVIEW_INTERVAL_MS = 0  # every preview: the iterations are fast here
    s.widget.run_button.click()
    wait_for_run(s.widget)
    preview = inserted[0]
    assert names[0] == "shaken latent (preview)"
    # while running: see-through, just above the photo, and the photo stays selected
    for active, opacity, index in updates[:-1]:
        assert active is s.image and opacity < 1.0 and index == 1
    assert preview.opacity == 1.0 and not preview.visible  # the result: hidden, opaque
    assert len(updates) >= 2  # refined by the next iterations, then the final latent
    assert preview.name == "shaken latent"  # the preview became the result
    assert preview is s.viewer.layers["shaken latent"]


def test_cancel_mid_run_stops_quickly_and_leaves_no_layer(qtbot, setup, notifications):
    s = setup
    s.widget.n_iter.setValue(60)  # about ten seconds of work
    s.widget.run_button.click()
    qtbot.waitUntil(lambda: s.widget.runner.progress_bar is not None
                    and s.widget.runner.progress_bar.n >= 1)
    bar = s.widget.runner.progress_bar
    assert bar in progress._all_instances  # what napari's activity dock shows
    assert any(layer.name.endswith("(preview)") for layer in s.viewer.layers)

    start = time.perf_counter()
    s.widget.cancel_button.click()
    qtbot.waitUntil(lambda: not s.widget.runner.is_running, timeout=5000)
    assert time.perf_counter() - start < 1.5
    assert s.widget.runner.outcome == "cancelled"
    assert [layer.name for layer in s.viewer.layers] == ["shaken"]  # preview removed too
    assert s.widget.run_button.isEnabled() and not s.widget.cancel_button.isEnabled()
    assert s.widget.runner.progress_bar is None and bar not in progress._all_instances
    assert s.widget.last_motion is None
    assert "Camera motion: cancelled" in notifications.texts("info")


def test_epalone_on_an_image_without_edges_notifies_and_adds_no_layer(qtbot, viewer_model,
                                                                      notifications,
                                                                      wait_for_run):
    flat = viewer_model.add_image(np.full((96, 96), 0.5, np.float32), name="flat")
    widget = make_widget(qtbot, viewer_model, flat, method="ep")
    widget.run_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "failed"
    assert [layer.name for layer in viewer_model.layers] == ["flat"]
    errors = notifications.texts("error")
    assert len(errors) == 1 and "EpAlone needs at least 12 usable edge profiles" in errors[0]
    assert widget.run_button.isEnabled() and not widget.save_button.isEnabled()


def test_bad_input_is_refused_with_the_engines_reason(setup, notifications, wait_for_run):
    s = setup
    s.widget.max_blur.spin.setValue(80)  # more than half the 112 px image
    s.widget.run_button.click()
    wait_for_run(s.widget)
    assert s.widget.runner.outcome == "failed"
    assert [layer.name for layer in s.viewer.layers] == ["shaken"]
    (error,) = notifications.texts("error")
    assert error == ("Camera motion: max_blur must be less than half the smaller image side "
                     "(56 px); got 80")
    assert "max_blur must be less than half" in s.widget.status.text()


def test_focal_length_from_metadata_exif_tag_or_manual(qtbot, viewer_model, edge_case,
                                                       wait_for_run):
    meta = viewer_model.add_image(edge_case.blurred, name="meta", metadata={"focal_px": 321.0})
    exif = viewer_model.add_image(edge_case.blurred, name="exif",
                                  metadata={"exif": {"FocalLengthIn35mmFilm": 50}})
    widget = make_widget(qtbot, viewer_model, meta)
    assert widget.focal_spin.value() == pytest.approx(321.0)
    assert "layer metadata" in widget.focal_hint.text()
    widget.image_combo.value = exif
    assert widget.focal_spin.value() == pytest.approx(50 / 36 * 112, abs=0.05)
    assert "50 mm equivalent" in widget.focal_hint.text()

    widget.focal_auto.setChecked(False)
    widget.focal_spin.setValue(200.0)
    widget.run_button.click()
    wait_for_run(widget)
    field = viewer_model.layers["exif PSF field"]
    assert field.metadata["edgecme_motion"]["intrinsics"]["focal_px"] == pytest.approx(200.0)


def test_rgb_images_are_estimated(qtbot, viewer_model, edge_case, wait_for_run):
    rgb = np.stack([edge_case.blurred, 0.8 * edge_case.blurred, 0.6 * edge_case.blurred], -1)
    image = viewer_model.add_image(rgb, name="colour", rgb=True)
    widget = make_widget(qtbot, viewer_model, image)
    widget.run_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "done"
    assert viewer_model.layers["colour PSF field"].data.shape == (112, 112, 4)


def test_the_psf_field_shows_each_streak_enlarged_in_its_direction(principal_axis):
    """Each drawn glyph's principal axis is its PSF's within 10 degrees (issue 15, item 6)."""
    cam = Intrinsics.from_image_shape((300, 400))
    t = np.linspace(0.0, 1.0, 40)
    # a slide plus a turn about the lens axis: streaks of different directions and lengths
    motion = CameraMotion.from_trajectory(np.stack([4 * t, 1 * t, 0.03 * t], -1), "inplane",
                                          cam)
    glyphs = psf_glyphs(motion, psf_grid(cam.image_shape))
    cell = min(300 / 5, 400 / 7)
    assert psf_grid(cam.image_shape) == (5, 7)
    assert glyphs.rgba.shape == (300, 400, 4) and glyphs.enlargement >= 2
    assert glyphs.boxes[0][2] >= 0.5 * cell  # the largest PSF fills most of its cell
    checked = 0
    for (r0, c0, side), psf in zip(glyphs.boxes, glyphs.psfs, strict=True):
        tile = glyphs.rgba[r0:r0 + side, c0:c0 + side]
        assert tile.shape[:2] == (side, side)  # every tile inside the image here
        drawn = np.clip((tile[..., 0] - BACKGROUND) / (1 - BACKGROUND), 0, 1)  # red channel
        true_angle, elongation = principal_axis(psf)
        if elongation < 3:  # a round blob has no direction to compare
            continue
        angle, _ = principal_axis(drawn)
        diff = abs((angle - true_angle + 90) % 180 - 90)
        assert diff < 10, (r0, c0, angle, true_angle)
        checked += 1
        # enlarged: the glyph's spread is the PSF's times the stated factor
        spread = np.sqrt(np.sum(np.indices(drawn.shape) ** 2 * drawn) / drawn.sum()
                         - (np.sum(np.indices(drawn.shape) * drawn, axis=(1, 2))
                            / drawn.sum()) ** 2)
        assert spread.max() > 0.5 * glyphs.enlargement
    assert checked >= 10
    # a neutral gray tile under every glyph, transparent between tiles
    r0, c0, side = glyphs.boxes[0]
    corner = glyphs.rgba[r0, c0]
    np.testing.assert_allclose(corner[:3], BACKGROUND, atol=1e-6)
    assert 0.8 < corner[3] < 1.0
    assert glyphs.rgba[0, 0, 3] == 0


def test_psf_grid_has_square_cells():
    assert psf_grid((100, 100)) == (5, 5)
    assert psf_grid((300, 400)) == (5, 7)
    assert psf_grid((400, 300)) == (7, 5)


def test_a_sharp_image_reads_no_blur_found_in_the_status(qtbot, viewer_model, edge_case,
                                                          wait_for_run):
    image = viewer_model.add_image(edge_case.sharp, name="sharp")
    widget = make_widget(qtbot, viewer_model, image, n_iter=2)
    widget.run_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "done"
    assert widget.last_estimate.info.no_blur
    assert widget.status.text().startswith("Camera motion: no blur found")
    assert "larger max blur" in widget.status.text()


def test_an_epalone_run_says_which_profile_model_it_kept(qtbot, viewer_model, edge_case,
                                                         wait_for_run, tmp_path):
    """... and records its profile misfit (which sets its restoration's prior) on the
    layer and in the motion file it saves."""
    image = viewer_model.add_image(edge_case.blurred, name="shaken")
    widget = make_widget(qtbot, viewer_model, image, method="ep")
    widget.run_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "done"
    summary = viewer_model.layers["shaken PSF field"].metadata["edgecme_estimate"]
    assert summary["method"] == "ep"
    said = ("fitted as soft edges (1 px spread)" if summary["edge_spread"] > 0
            else "fitted as step edges")
    assert said in widget.status.text()
    misfit = widget.last_estimate.info.profile_misfit
    assert summary["profile_misfit"] == misfit and 0 <= misfit <= 0.2
    _, estimated_by, saved = CameraMotion.load_estimate(widget.save_motion(tmp_path / "m.json"))
    assert (estimated_by, saved) == ("ep", misfit)
