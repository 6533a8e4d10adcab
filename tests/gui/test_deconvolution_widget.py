"""The "Deconvolution" widget, offscreen against a ViewerModel (no GL canvas)."""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import pytest
from napari.utils import progress

from napari_edgecme._widgets.camera_motion import CameraMotionWidget
from napari_edgecme._widgets.deconvolution import DeconvolutionWidget
from napari_edgecme.core.deconv import DEFAULTS
from napari_edgecme.core.metrics import aligned_psnr
from napari_edgecme.core.motion import CameraMotion

pytestmark = pytest.mark.gui

SCALE, TRANSLATE = (2.0, 2.0), (-3.0, 7.5)


@pytest.fixture
def setup(qtbot, viewer_model, photo_case):
    """A blurred photo layer carrying its true motion, and the widget."""
    blurred = photo_case.blurred.copy()
    image = viewer_model.add_image(blurred, name="photo", scale=SCALE, translate=TRANSLATE,
                                   metadata={"edgecme_motion": photo_case.motion.to_dict()})
    widget = DeconvolutionWidget(viewer_model)
    qtbot.addWidget(widget)
    widget.reset_choices()  # what napari does for a docked widget when layers change
    widget.image_combo.value = image
    return SimpleNamespace(viewer=viewer_model, image=image, widget=widget, original=blurred.copy())


def test_a_smoothness_set_by_hand_replaces_the_automatic_one(setup):
    w = setup.widget
    w.lambda_f.setValue(2e-3)
    assert w.parameters()["lambda_f"] == pytest.approx(2e-3)
    w.lambda_f.setValue(w.lambda_f.minimum())  # back to "auto"
    assert w.parameters()["lambda_f"] is None


def test_defaults_are_the_engines(setup):
    w = setup.widget
    assert w.method_combo.value == "hyperlaplacian"
    assert DEFAULTS["hyperlaplacian"]["lambda_f"] is None  # from the photo's noise
    assert w.lambda_f.text() == "auto (from the noise)"
    assert w.parameters() == {"lambda_f": None,
                              "alpha": pytest.approx(DEFAULTS["hyperlaplacian"]["alpha"]),
                              "solver": DEFAULTS["hyperlaplacian"]["solver"],
                              "color": DEFAULTS["hyperlaplacian"]["color"],
                              "chroma": DEFAULTS["hyperlaplacian"]["chroma"]}
    assert w.motion_combo.value is setup.image  # the image's own (true) motion
    w.method_combo.value = "rl"
    assert w.parameters() == {"iterations": DEFAULTS["rl"]["iterations"]}
    assert w.params.currentIndex() == 1
    w.method_combo.value = "wiener"
    assert w.parameters() == {"nsr": pytest.approx(DEFAULTS["wiener"]["nsr"])}


def test_the_chroma_choice_applies_to_luminance_plus_chroma_only(setup):
    w = setup.widget
    w.color_combo.value = "rgb"
    assert not w.chroma_combo.native.isEnabled()
    w.chroma_combo.value = "half"  # set while disabled: not passed with color='rgb'
    assert w.parameters()["chroma"] == DEFAULTS["hyperlaplacian"]["chroma"]
    w.color_combo.value = "opponent"
    assert w.chroma_combo.native.isEnabled()
    assert (w.parameters()["color"], w.parameters()["chroma"]) == ("opponent", "half")


def test_deblurring_with_the_true_motion_adds_a_restored_float32_layer(setup, wait_for_run,
                                                                      photo_case,
                                                                      assert_same_motion):
    s = setup
    s.widget.run_button.click()
    assert not s.widget.run_button.isEnabled()
    wait_for_run(s.widget)
    assert s.widget.runner.outcome == "done"
    assert [layer.name for layer in s.viewer.layers] == ["photo", "photo deblurred"]

    restored = s.viewer.layers["photo deblurred"]
    assert restored is s.widget.last_layer
    assert restored.data.dtype == np.float32 and restored.data.shape == (96, 96)
    np.testing.assert_allclose(restored.scale, SCALE)
    np.testing.assert_allclose(restored.translate, TRANSLATE)
    assert_same_motion(CameraMotion.from_dict(restored.metadata["edgecme_motion"]),
                       photo_case.motion)
    assert restored.metadata["edgecme_deconvolution"]["method"] == "hyperlaplacian"
    # the input is untouched, and the result is sharper (the engine's own doctest bar)
    np.testing.assert_array_equal(s.image.data, s.original)
    gain = (aligned_psnr(restored.data, photo_case.sharp)
            - aligned_psnr(photo_case.blurred, photo_case.sharp))
    assert gain > 2.0


def test_an_rgb_image_with_a_motion_from_a_json_file(qtbot, viewer_model, photo_case,
                                                     tmp_path, wait_for_run, notifications,
                                                     assert_same_motion):
    rgb = np.stack([photo_case.blurred, 0.7 * photo_case.blurred,
                    0.4 * photo_case.blurred], -1).astype(np.float32)
    image = viewer_model.add_image(rgb, name="colour", rgb=True)
    widget = DeconvolutionWidget(viewer_model)
    qtbot.addWidget(widget)
    widget.reset_choices()
    widget.image_combo.value = image
    path = tmp_path / "truth.json"
    photo_case.motion.save(path)
    loaded = widget.load_motion(path)
    assert_same_motion(loaded, photo_case.motion)
    assert widget.motion_combo.value is loaded
    assert "file: truth.json" in widget.motion_combo.native.currentText()
    widget.method_combo.value = "rl"
    widget.rl_iterations.setValue(10)
    widget.run_button.click()
    wait_for_run(widget)
    restored = viewer_model.layers["colour deblurred"]
    assert restored.rgb and restored.data.shape == (96, 96, 3)
    assert restored.data.dtype == np.float32
    assert restored.metadata["edgecme_deconvolution"] == {"method": "rl", "iterations": 10,
                                                          "gamma": "linear",
                                                          "gamma_reason": "given"}
    assert any("loaded truth.json" in text for text in notifications.texts("info"))


def _parameters_of_a_run(widget, wait_for_run, monkeypatch) -> dict:
    """Run ``widget`` to the end; the parameters its deconvolution was called with."""
    from napari_edgecme._widgets import _gamma
    from napari_edgecme.core import deconv

    seen = {}

    def spy(image, motion, method, **params):
        seen.update(params)
        return (yield from deconv.iter_deconvolve(image, motion, method, **params))

    monkeypatch.setattr(_gamma, "iter_deconvolve", spy)
    widget.run_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "done"
    return seen


@pytest.mark.parametrize("estimated_by, misfit", [(None, None), ("ep", 0.15), ("ep", 0.06)])
def test_a_motion_file_is_restored_as_deblur_restores_an_estimate_of_its_method(
        setup, tmp_path, wait_for_run, monkeypatch, estimated_by, misfit):
    """A motion file naming EpAlone as its estimator (``estimated_by``) gets EpAlone's
    stronger prior for the misfit it records, as its layer would; one naming none gets
    the noise's weight."""
    from napari_edgecme.core import deconv
    from napari_edgecme.core.deblur import restoring_params

    s = setup
    path = tmp_path / "motion.json"
    s.widget.fitted_motion().motion.save(path, estimated_by=estimated_by,
                                         profile_misfit=misfit)
    s.widget.load_motion(path)
    assert s.widget._motion_estimate("method") == estimated_by
    assert s.widget._motion_estimate("profile_misfit") == misfit
    s.widget.motion_combo.value = s.image  # the layer's motion: not the file's estimator
    assert s.widget._motion_estimate("method") is None
    s.widget.motion_combo.value = s.widget._file_motion[1]
    seen = _parameters_of_a_run(s.widget, wait_for_run, monkeypatch)
    if estimated_by == "ep":
        expected = restoring_params(s.original, "ep", "hyperlaplacian", {"lambda_f": None},
                                    profile_misfit=misfit)
        assert seen["lambda_f"] == expected["lambda_f"] >= deconv.REFERENCE_LAMBDA_F
    else:
        assert seen["lambda_f"] is None


def test_a_bad_motion_file_is_refused_with_a_notification(setup, tmp_path, notifications):
    path = tmp_path / "bad.json"
    path.write_text('{"format": "something else"}')
    assert setup.widget.load_motion(path) is None
    (error,) = notifications.texts("error")
    assert error.startswith("Deconvolution: ") and "not an edgecme motion file" in error
    assert setup.widget.motion_combo.value is setup.image  # unchanged


def test_no_motion_is_refused_on_the_main_thread(qtbot, viewer_model, photo_case,
                                                 notifications):
    viewer_model.add_image(photo_case.blurred, name="plain")
    widget = DeconvolutionWidget(viewer_model)
    qtbot.addWidget(widget)
    widget.reset_choices()
    assert widget.motion_combo.value is None
    widget.run_button.click()
    assert not widget.runner.is_running
    assert len(viewer_model.layers) == 1
    (error,) = notifications.texts("error")
    assert "choose a motion" in error


def test_a_motion_that_fits_neither_as_crop_nor_as_copy_is_refused_before_running(
        qtbot, viewer_model, photo_case, notifications):
    wide = viewer_model.add_image(np.zeros((96, 150), np.float32) + 0.5, name="wide")
    viewer_model.add_image(photo_case.blurred, name="photo",
                           metadata={"edgecme_motion": photo_case.motion.to_dict()})
    widget = DeconvolutionWidget(viewer_model)
    qtbot.addWidget(widget)
    widget.reset_choices()
    widget.image_combo.value = wide
    assert widget.motion_combo.value is viewer_model.layers["photo"]
    assert widget.motion_hint.text().startswith("Does not fit: the motion is for a 96x96")
    widget.run_button.click()
    assert not widget.runner.is_running and widget.runner.outcome == "refused"
    assert [layer.name for layer in viewer_model.layers] == ["wide", "photo"]
    (error,) = notifications.texts("error")
    assert error.startswith("Deconvolution: the motion is for a 96x96 image; this image is "
                            "96x150 and neither a crop")
    assert widget.status.text().startswith("Deconvolution: not run: the motion is for")


def test_a_crop_placed_by_its_translate_gets_the_motion_moved_not_rescaled(
        qtbot, viewer_model, photo_case, wait_for_run, notifications):
    """The issue's case: a small crop of the estimated image is deconvolved with its motion."""
    full = viewer_model.add_image(photo_case.blurred, name="photo", scale=SCALE,
                                  translate=TRANSLATE,
                                  metadata={"edgecme_motion": photo_case.motion.to_dict()})
    r, c = 40, 30
    crop_data = photo_case.blurred[r:r + 24, c:c + 32]
    crop = viewer_model.add_image(crop_data, name="crop", scale=SCALE,
                                  translate=(TRANSLATE[0] + SCALE[0] * r,
                                             TRANSLATE[1] + SCALE[1] * c))
    widget = DeconvolutionWidget(viewer_model)
    qtbot.addWidget(widget)
    widget.reset_choices()
    widget.image_combo.value = crop
    assert widget.motion_combo.value is full
    fit = widget.fitted_motion()
    expected = photo_case.motion.cropped((r, c), (24, 32))
    assert fit.motion == expected and not fit.guess
    assert "a 24x32 crop at (row 40, col 30) of the motion's 96x96 image" in fit.note
    assert "crop at (row 40, col 30)" in widget.motion_hint.text()
    # the PSFs are the full image's at the same pixels, not a 4x smaller rescaled blur
    points = np.array([[3.0, 5.0], [20.0, 28.0]])
    size = photo_case.motion.psf_size()
    np.testing.assert_allclose(fit.motion.psf(points, size),
                               photo_case.motion.psf(points + np.array([r, c]), size), atol=1e-12)
    widget.run_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "done"
    restored = viewer_model.layers["crop deblurred"]
    assert CameraMotion.from_dict(restored.metadata["edgecme_motion"]) == expected
    assert notifications.texts("warning") == []


def test_a_smaller_image_at_the_origin_is_a_guess_said_as_a_warning(
        qtbot, viewer_model, photo_case, notifications):
    viewer_model.add_image(photo_case.blurred, name="photo",
                           metadata={"edgecme_motion": photo_case.motion.to_dict()})
    crop = viewer_model.add_image(photo_case.blurred[:24, :40], name="cut")
    half = viewer_model.add_image(photo_case.blurred[::2, ::2], name="half")
    widget = DeconvolutionWidget(viewer_model)
    qtbot.addWidget(widget)
    widget.reset_choices()
    widget.image_combo.value = crop
    fit = widget.fitted_motion()
    assert fit.guess and fit.motion == photo_case.motion.cropped((0, 0), (24, 40))
    assert "taken as a crop at the top-left corner" in widget.motion_hint.text()
    widget.image_combo.value = half
    fit = widget.fitted_motion()
    assert fit.guess and fit.motion == photo_case.motion.rescale((48, 48))
    assert "taken as a resized copy" in fit.note
    # a resized copy laid over the image by its scale is no guess
    half.scale = (2.0, 2.0)
    half.translate = (0.5, 0.5)
    fit = widget.fitted_motion()
    assert not fit.guess and fit.motion == photo_case.motion.rescale((48, 48))
    widget.image_combo.value = crop
    widget.run_button.click()
    assert widget.runner.is_running
    (warning,) = notifications.texts("warning")
    assert "taken as a crop at the top-left corner" in warning
    widget.runner.cancel()


def test_no_motion_is_said_under_the_motion_choice_not_only_in_a_toast(qtbot, viewer_model,
                                                                       photo_case):
    viewer_model.add_image(photo_case.blurred, name="plain")
    widget = DeconvolutionWidget(viewer_model)
    qtbot.addWidget(widget)
    widget.reset_choices()
    assert widget.motion_hint.text().startswith("No motion yet: estimate one with "
                                                "'Camera motion'")
    widget.run_button.click()
    assert widget.status.text().startswith("Deconvolution: not run: choose a motion")
    viewer_model.add_image(photo_case.blurred, name="photo",
                           metadata={"edgecme_motion": photo_case.motion.to_dict()})
    widget.reset_choices()
    assert widget.motion_hint.text().startswith("inplane motion, ")
    motion = photo_case.motion
    assert (f"inplane motion, {motion.n_poses} poses, blur extent {motion.blur_extent():.1f}"
            " px (longest side of the PSFs)") in widget.motion_hint.text()


def test_cancel_mid_run_stops_quickly_and_leaves_no_layer(qtbot, setup):
    s = setup
    s.widget.method_combo.value = "rl"
    s.widget.rl_iterations.setValue(20000)  # about a minute of work
    s.widget.run_button.click()
    qtbot.waitUntil(lambda: s.widget.runner.progress_bar is not None
                    and s.widget.runner.progress_bar.n >= 1)
    bar = s.widget.runner.progress_bar
    assert bar.total >= 20000
    start = time.perf_counter()
    s.widget.cancel_button.click()
    qtbot.waitUntil(lambda: not s.widget.runner.is_running, timeout=5000)
    assert time.perf_counter() - start < 1.0
    assert s.widget.runner.outcome == "cancelled"
    assert [layer.name for layer in s.viewer.layers] == ["photo"]
    assert s.widget.run_button.isEnabled() and not s.widget.cancel_button.isEnabled()
    assert s.widget.runner.progress_bar is None and bar not in progress._all_instances
    np.testing.assert_array_equal(s.image.data, s.original)


def test_the_motion_estimated_by_xu_ep_sharpens_the_image(qtbot, viewer_model, edge_case,
                                                          wait_for_run):
    """The whole plugin on a small shaken edge scene: estimate (Xu+Ep), then deconvolve."""
    image = viewer_model.add_image(edge_case.blurred, name="shaken")
    motion = CameraMotionWidget(viewer_model)
    deconv = DeconvolutionWidget(viewer_model)
    qtbot.addWidget(motion)
    qtbot.addWidget(deconv)
    motion.reset_choices()
    motion.image_combo.value = image
    motion.model_combo.value = "inplane"
    motion.max_blur.auto.setChecked(False)
    motion.max_blur.spin.setValue(7)
    motion.n_iter.setValue(4)
    assert motion.method_combo.value == "xu+ep"
    motion.run_button.click()
    wait_for_run(motion)
    assert motion.runner.outcome == "done"
    assert motion.last_estimate.info.n_profiles >= 12

    deconv.reset_choices()  # napari does this when the PSF field layer is added
    deconv.image_combo.value = image
    assert deconv.motion_combo.value is viewer_model.layers["shaken PSF field"]
    deconv.run_button.click()
    wait_for_run(deconv)
    restored = viewer_model.layers["shaken deblurred"].data
    gain = (aligned_psnr(restored, edge_case.sharp)
            - aligned_psnr(edge_case.blurred, edge_case.sharp))
    assert gain > 3.0


@pytest.mark.parametrize("estimated_by", [None, "xu+ep", "ep"])
def test_a_motion_is_restored_as_deblur_restores_an_estimate_of_its_method(
        setup, wait_for_run, monkeypatch, estimated_by):
    from napari_edgecme.core import deconv
    from napari_edgecme.core.deblur import restoring_params

    s = setup
    if estimated_by is not None:  # as the camera-motion widget records its estimate
        s.image.metadata = {**s.image.metadata, "edgecme_estimate": {
            "method": estimated_by, "profile_misfit": 0.08}}
    seen = _parameters_of_a_run(s.widget, wait_for_run, monkeypatch)
    expected = restoring_params(s.original, estimated_by or "xu", "hyperlaplacian",
                                {"lambda_f": None}, profile_misfit=0.08)
    assert seen["lambda_f"] == expected["lambda_f"]
    if estimated_by == "ep":  # EpAlone's prior: never below the reference weight
        assert seen["lambda_f"] >= deconv.REFERENCE_LAMBDA_F
    else:  # the weight from the photo's noise, set by the engine
        assert seen["lambda_f"] is None


@pytest.mark.parametrize("from_file", [False, True])
def test_a_deblurred_layer_carries_its_motions_estimate_to_the_next_restoration(
        setup, tmp_path, wait_for_run, monkeypatch, from_file):
    """The deblurred layer keeps the estimate summary of the motion it was restored with
    (a layer's, or a motion file's estimator and misfit), so that choosing it as the
    motion source restores as ``deblur`` restores that estimate: here EpAlone's stronger
    prior for a misfit of 12%."""
    from napari_edgecme.core.deblur import restoring_params

    s = setup
    if from_file:
        path = tmp_path / "motion.json"
        s.widget.fitted_motion().motion.save(path, estimated_by="ep", profile_misfit=0.12)
        s.widget.load_motion(path)
    else:
        s.image.metadata = {**s.image.metadata, "edgecme_estimate": {
            "method": "ep", "profile_misfit": 0.12}}
    first = _parameters_of_a_run(s.widget, wait_for_run, monkeypatch)
    assert "EpAlone prior 5.8x (profile misfit 12%)" in s.widget.status.text()
    deblurred = s.widget.last_layer
    assert deblurred.metadata["edgecme_estimate"]["method"] == "ep"
    assert deblurred.metadata["edgecme_estimate"]["profile_misfit"] == 0.12
    s.widget.reset_choices()
    s.widget.motion_combo.value = deblurred
    again = _parameters_of_a_run(s.widget, wait_for_run, monkeypatch)
    expected = restoring_params(s.original, "ep", "hyperlaplacian", {"lambda_f": None},
                                profile_misfit=0.12)["lambda_f"]
    assert first["lambda_f"] == again["lambda_f"] == expected
