"""Auto max blur measured from the image, and the gamma choice of the Edge profiles widget
(issue 14, items 2 and 3).

On auto the Camera motion widget gives the engine ``max_blur=None`` and the Edge profiles
widget measures in its worker, both as the engine does (the same numbers: one
measurement everywhere), and both say what was found; the Edge profiles widget takes its
profiles in linear light when told the image is sRGB, which on an sRGB photo brings them
from far off the true blur to on it.
"""

from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image as PILImage
from PIL.PngImagePlugin import PngInfo

from napari_edgecme._widgets.camera_motion import CameraMotionWidget
from napari_edgecme._widgets.edge_profiles import (
    ORIGIN_KEY,
    SETTINGS_KEY,
    EdgeProfilesWidget,
    profile_lines,
)
from napari_edgecme.core import blur_size
from napari_edgecme.core._validation import as_rng
from napari_edgecme.core.blur_size import MARGIN, max_blur_for, measure_blur_extent
from napari_edgecme.core.edges import extract_edge_profiles, profile_along_line
from napari_edgecme.core.measurement import measurement_matrix, profile_misfit
from napari_edgecme.core.photometry import linear_to_srgb, srgb_to_linear
from napari_edgecme.core.synth import add_noise, edge_scene, make_case, quantize

pytestmark = pytest.mark.gui

SRGB_CHUNK = "8-bit PNG with an sRGB chunk"


@pytest.fixture(scope="module")
def shaken():
    """tests/core/test_blur_size.py's in-plane 24 px shake of a 240x320 edge scene, and
    what the engine measures on it with seed 0 (as the widgets run)."""
    case = make_case(edge_scene((240, 320), rng=1), "inplane", extent=24, rng=5)
    size = measure_blur_extent(case.blurred, rng=as_rng(0).spawn(1)[0])
    return SimpleNamespace(case=case, size=size,
                           max_blur=max_blur_for(size, case.blurred.shape),
                           truth=case.motion.blur_extent())


@pytest.fixture
def threads(monkeypatch):
    """The threads ``measure_blur_extent`` ran in (the engine and the Edge profiles widget
    both reach it through ``blur_size.resolve_max_blur``)."""
    seen = []
    real = blur_size.measure_blur_extent

    def measuring(*args, **kwargs):
        seen.append(threading.current_thread())
        return real(*args, **kwargs)

    monkeypatch.setattr(blur_size, "measure_blur_extent", measuring)
    return seen


def motion_widget(qtbot, viewer, image, method="ep", model="inplane") -> CameraMotionWidget:
    widget = CameraMotionWidget(viewer)
    qtbot.addWidget(widget)
    widget.reset_choices()
    widget.image_combo.value = image
    widget.method_combo.value = method
    widget.model_combo.value = model
    return widget


def profiles_widget(qtbot, viewer, image, gamma="linear",
                    max_blur: float | None = None) -> EdgeProfilesWidget:
    widget = EdgeProfilesWidget(viewer)
    qtbot.addWidget(widget)
    widget.reset_choices()
    widget.image_combo.value = image
    widget.gamma.choice = gamma
    if max_blur is not None:
        widget.max_blur.auto.setChecked(False)
        widget.max_blur.spin.setValue(max_blur)
    return widget


# --------------------------------------------------------------------------------------
# auto max blur: measured in the worker, said, recorded
# --------------------------------------------------------------------------------------

def test_camera_motion_on_auto_measures_in_the_worker_and_says_what_it_found(
        qtbot, viewer_model, wait_for_run, shaken, threads):
    image = viewer_model.add_image(shaken.case.blurred, name="shaken")
    widget = motion_widget(qtbot, viewer_model, image)
    assert widget.max_blur.auto.isChecked()
    widget.run_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "done"
    assert threads and all(t is not threading.main_thread() for t in threads)
    info = widget.last_estimate.info
    # the engine measured (max_blur=None): the widget's run is the engine's own
    assert info.blur_size == shaken.size.message
    assert info.max_blur == shaken.max_blur
    # measured here: blur about 23 px from 20 profiles (true 24 px), max blur 45.1 px,
    # 0.94 of the margin times the truth
    assert shaken.size.source == "edge profiles"
    assert 0.75 < info.max_blur / (MARGIN * shaken.truth) < 1.35, info.max_blur
    note = f"max blur {info.max_blur:.0f} px (measured: {shaken.size.message})"
    assert note in widget.status.text()
    assert "measured: blur about" in widget.status.text()
    field = viewer_model.layers["shaken PSF field"]
    assert field.metadata["edgecme_estimate"]["blur_size"] == shaken.size.message
    assert field.metadata["edgecme_estimate"]["max_blur"] == shaken.max_blur
    # the box still shows no number on auto; a value starts from the measured one
    assert widget.max_blur.spin.text() == "measured when run"
    widget.max_blur.auto.setChecked(False)
    assert widget.max_blur.spin.value() == pytest.approx(shaken.max_blur, abs=0.05)


def test_a_given_max_blur_is_not_measured(qtbot, viewer_model, wait_for_run, shaken,
                                          threads):
    image = viewer_model.add_image(shaken.case.blurred, name="shaken")
    widget = motion_widget(qtbot, viewer_model, image)
    widget.max_blur.auto.setChecked(False)
    widget.max_blur.spin.setValue(40)
    widget.run_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "done"
    assert threads == []
    assert widget.last_estimate.info.blur_size is None
    assert widget.last_estimate.info.max_blur == 40
    assert "measured" not in widget.status.text()


def test_edge_profiles_on_auto_measure_as_the_engine_does(qtbot, viewer_model, wait_for_run,
                                                          shaken, threads):
    image = viewer_model.add_image(shaken.case.blurred, name="shaken")
    widget = profiles_widget(qtbot, viewer_model, image)
    widget.detect_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "done"
    assert len(threads) == 1 and threads[0] is not threading.main_thread()
    shapes, _points = widget.current_layers
    profiles = shapes.metadata["edgecme_profiles"]
    # the same max blur as the Camera motion widget's (and deblur's) measurement, and
    # the profiles extract_edge_profiles gives with it
    assert profiles.max_blur == shaken.max_blur
    expected = extract_edge_profiles(shaken.case.blurred, shaken.max_blur, rng=0)
    np.testing.assert_array_equal(profiles.centroids, expected.centroids)
    assert 0.75 < profiles.max_blur / (MARGIN * shaken.truth) < 1.35
    assert widget.status.text() == (
        f"Edge profiles: {len(profiles)} edge profiles detected in 'shaken' (max blur "
        f"{shaken.max_blur:.0f} px (measured: {shaken.size.message}))")
    assert shapes.metadata[SETTINGS_KEY] == {
        "max_blur": shaken.max_blur, "blur_size": shaken.size.message,
        "gamma": "linear", "gamma_reason": "given"}
    # a line drawn by hand joins the set on its grid (the measured max blur)
    assert widget.max_blur.value_or_default_for(image) == shaken.max_blur


def test_edge_profiles_with_a_value_say_it(qtbot, viewer_model, wait_for_run, shaken, threads):
    image = viewer_model.add_image(shaken.case.blurred, name="shaken")
    widget = profiles_widget(qtbot, viewer_model, image, max_blur=30)
    widget.detect_button.click()
    wait_for_run(widget)
    assert threads == []
    shapes, _ = widget.current_layers
    n = len(shapes.metadata["edgecme_profiles"])
    assert widget.status.text() == (f"Edge profiles: {n} edge profiles detected in 'shaken' "
                                    f"(max blur 30 px)")
    assert shapes.metadata[SETTINGS_KEY]["blur_size"] is None


def test_hand_picks_on_auto_before_any_run_use_the_default(qtbot, viewer_model, shaken):
    from napari_edgecme.core.estimate import default_max_blur

    image = viewer_model.add_image(shaken.case.blurred, name="shaken")
    widget = profiles_widget(qtbot, viewer_model, image)
    widget.pick_button.click()
    shapes, _ = widget.current_layers
    assert shapes.metadata["edgecme_profiles"].max_blur == default_max_blur((240, 320)) == 15
    assert shapes.metadata[SETTINGS_KEY]["max_blur"] == 15


# --------------------------------------------------------------------------------------
# gamma in the Edge profiles widget
# --------------------------------------------------------------------------------------

def srgb_edges(seed: int, model: str):
    """An edge scene blurred in linear light (12 px), then sRGB-encoded, noisy (1%), 8 bits."""
    sharp = edge_scene((240, 320), rng=seed)  # read as sRGB values
    case = make_case(srgb_to_linear(sharp), model, extent=12, noise=0, bits=None, rng=seed)
    encoded = quantize(np.clip(add_noise(linear_to_srgb(case.blurred), 0.01,
                                         np.random.default_rng(seed)), 0, 1), 8)
    return SimpleNamespace(blurred=encoded.astype(np.float32), motion=case.motion)


def misfit_to_truth(profiles, motion) -> np.ndarray:
    """Each profile's distance from the true motion's projection (Eq. 14; 0 = exact)."""
    truth = motion.recentred()
    matrix = measurement_matrix(profiles, truth.model, truth.intrinsics, truth.poses)
    return profile_misfit(matrix, profiles, truth.weights)


@pytest.mark.parametrize("seed, model", [(0, "translation"), (1, "inplane")])
def test_srgb_profiles_of_an_srgb_photo_are_true_to_the_blur_and_linear_ones_are_not(
        qtbot, viewer_model, wait_for_run, seed, model):
    case = srgb_edges(seed, model)
    image = viewer_model.add_image(case.blurred, name="photo")
    misfit = {}
    for gamma in ("linear", "srgb"):
        widget = profiles_widget(qtbot, viewer_model, image, gamma, max_blur=16)
        widget.detect_button.click()
        wait_for_run(widget)
        assert widget.runner.outcome == "done"
        shapes, _ = widget.current_layers
        profiles = shapes.metadata["edgecme_profiles"]
        assert shapes.metadata[SETTINGS_KEY]["gamma"] == gamma
        assert shapes.metadata[SETTINGS_KEY]["gamma_reason"] == "given"
        light = case.blurred if gamma == "linear" else srgb_to_linear(case.blurred)
        expected = extract_edge_profiles(light, 16, rng=0)  # taken in that light
        np.testing.assert_array_equal(profiles.centroids, expected.centroids)
        np.testing.assert_array_equal(profiles.derivatives, expected.derivatives)
        misfit[gamma] = float(np.median(misfit_to_truth(profiles, case.motion)))
        if gamma == "srgb":
            assert widget.status.text().endswith("(max blur 16 px; gamma: srgb (given))")
        for layer in list(viewer_model.layers)[1:]:
            viewer_model.layers.remove(layer)
    # measured (median misfit to the true motion's projections, 0 = exact): seed 0
    # translation 0.037 (sRGB) vs 0.505 (linear), seed 1 in-plane 0.043 vs 0.402
    assert misfit["srgb"] < 0.08, misfit
    assert misfit["linear"] > 0.3, misfit
    assert misfit["linear"] > 5 * misfit["srgb"], misfit


def test_hand_picks_are_measured_in_the_light_of_their_set(qtbot, viewer_model, wait_for_run):
    case = srgb_edges(0, "translation")
    image = viewer_model.add_image(case.blurred, name="photo")
    widget = profiles_widget(qtbot, viewer_model, image, "srgb", max_blur=16)
    widget.detect_button.click()
    wait_for_run(widget)
    shapes, _ = widget.current_layers
    before = shapes.metadata["edgecme_profiles"]
    c, n = before.centroids[1], before.normals[1]
    line = np.array([c - 12 * n, c + 12 * n])
    shapes.add_lines([line])
    qtbot.waitUntil(lambda: len(shapes.metadata["edgecme_profiles"]) == len(before) + 1)
    after = shapes.metadata["edgecme_profiles"]
    assert shapes.metadata[ORIGIN_KEY][-1] == "hand"
    drawn = np.asarray(line, np.float32).astype(float)  # napari keeps vertices as float32
    expected = profile_along_line(srgb_to_linear(case.blurred), drawn[0], drawn[1],
                                  max_blur=16)
    np.testing.assert_allclose(after.derivatives[-1], expected.derivatives[0], atol=1e-6)
    hand = after.subset([len(after) - 1])

    # detecting again on the values as stored: the hand pick is measured again, in that light
    widget.gamma.choice = "linear"
    widget.detect_button.click()
    wait_for_run(widget)
    again = shapes.metadata["edgecme_profiles"]
    assert shapes.metadata[ORIGIN_KEY].count("hand") == 1
    assert shapes.metadata[SETTINGS_KEY]["gamma"] == "linear"
    start, end = profile_lines(hand)[0]
    expected = profile_along_line(case.blurred, start, end, max_blur=hand.max_blur)
    np.testing.assert_allclose(again.derivatives[-1], expected.derivatives[0], atol=1e-6)
    # measured: misfit to the truth 0.031 in linear light, 0.728 on the sRGB values
    assert misfit_to_truth(hand, case.motion)[0] < 0.08
    assert misfit_to_truth(again.subset([len(again) - 1]), case.motion)[0] > 0.3


def test_the_motion_widget_says_when_the_profiles_were_taken_in_another_light(
        qtbot, viewer_model, wait_for_run):
    case = srgb_edges(0, "translation")
    image = viewer_model.add_image(case.blurred, name="photo")
    profiles = profiles_widget(qtbot, viewer_model, image, "srgb", max_blur=16)
    profiles.detect_button.click()
    wait_for_run(profiles)
    shapes, _ = profiles.current_layers
    motion = motion_widget(qtbot, viewer_model, image, "ep", "translation")
    motion.max_blur.auto.setChecked(False)
    motion.max_blur.spin.setValue(16)
    assert motion.profiles_combo.value is shapes  # the image's own, offered
    motion.run_button.click()
    wait_for_run(motion)
    assert motion.runner.outcome == "done"
    assert motion.status.text().endswith("; the edge profiles were taken with gamma srgb")
    motion.gamma.choice = "srgb"
    motion.run_button.click()
    wait_for_run(motion)
    assert "taken with gamma" not in motion.status.text()
    assert motion.status.text().endswith("; gamma: srgb (given)")


def test_edge_profiles_auto_gamma_reads_the_file(qtbot, viewer_model, plugins, tmp_path,
                                                 wait_for_run):
    case = srgb_edges(0, "translation")
    path = tmp_path / "edges.png"
    chunk = PngInfo()
    chunk.add(b"sRGB", b"\x00")
    PILImage.fromarray(np.round(case.blurred * 255).astype(np.uint8)).save(path, pnginfo=chunk)
    (layer,) = viewer_model.open(path, plugin="napari")
    widget = profiles_widget(qtbot, viewer_model, layer, "auto", max_blur=16)
    assert widget.gamma.hint.text() == f"gamma: srgb ({SRGB_CHUNK})"
    widget.detect_button.click()
    wait_for_run(widget)
    shapes, _ = widget.current_layers
    settings = shapes.metadata[SETTINGS_KEY]
    assert (settings["gamma"], settings["gamma_reason"]) == ("srgb", SRGB_CHUNK)
    assert widget.status.text().endswith(f"; gamma: srgb ({SRGB_CHUNK}))")
    expected = extract_edge_profiles(srgb_to_linear(layer.data), 16, rng=0)
    np.testing.assert_array_equal(shapes.metadata["edgecme_profiles"].centroids,
                                  expected.centroids)


@pytest.mark.parametrize("bad", ["-1", "abc"])
def test_a_bad_exponent_is_refused_in_one_line(qtbot, viewer_model, notifications, bad):
    image = viewer_model.add_image(srgb_edges(0, "translation").blurred, name="photo")
    widget = profiles_widget(qtbot, viewer_model, image, "power")
    widget.gamma.exponent.setText(bad)
    message = f"gamma must be auto, linear, srgb or a number > 0 (a power-law exponent such " \
              f"as 2.2); got {bad!r}"
    widget.detect_button.click()
    assert widget.runner.outcome == "refused" and not widget.runner.is_running
    assert widget.status.text() == f"Edge profiles: not run: {message}"
    assert notifications.texts("error") == [f"Edge profiles: {message}"]
    widget.pick_button.click()  # nor is a set for hand picks started in an unknown light
    assert [layer.name for layer in viewer_model.layers] == ["photo"]
    assert notifications.texts("error")[-1] == f"Edge profiles: {message}"
