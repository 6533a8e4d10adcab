"""The gamma choice of the "Camera motion" and "Deconvolution" widgets (issue 14, item 3).

An sRGB photo blurred in linear light is restored better when both widgets work in
linear light (gamma sRGB) than on its encoded values (linear, the layers' default); the
restored layer is encoded as the input was; auto decides from the file a layer was
opened from and says why; a bad exponent is refused in one line.
"""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image as PILImage
from PIL.PngImagePlugin import PngInfo

from napari_edgecme._widgets import _gamma
from napari_edgecme._widgets._gamma import NO_FILE, estimate_in_linear_light
from napari_edgecme._widgets.camera_motion import CameraMotionWidget
from napari_edgecme._widgets.deconvolution import DeconvolutionWidget
from napari_edgecme.core.deblur import deblur
from napari_edgecme.core.deconv import deconvolve
from napari_edgecme.core.metrics import aligned_scores
from napari_edgecme.core.photometry import Gamma, linear_to_srgb, srgb_to_linear
from napari_edgecme.core.progress import Progress
from napari_edgecme.core.synth import add_noise, make_case, quantize, sample_image

pytestmark = pytest.mark.gui

SRGB_CHUNK = "8-bit PNG with an sRGB chunk"


def srgb_case(seed: int, size: int = 128):
    """A photo blurred in linear light, then sRGB-encoded, noisy (1%), 8 bits (as
    tests/core/test_gamma.py builds it, smaller)."""
    sharp = sample_image("camera", size)  # sRGB-encoded values, as a photo stores them
    case = make_case(srgb_to_linear(sharp), "translation", extent=9, noise=0, bits=None,
                     rng=seed)
    blurred = quantize(np.clip(add_noise(linear_to_srgb(case.blurred), 0.01,
                                         np.random.default_rng(seed)), 0, 1), 8)
    return SimpleNamespace(sharp=sharp, blurred=blurred.astype(np.float32),
                           motion=case.motion)


def motion_widget(qtbot, viewer, image, gamma: str, method: str = "xu+ep",
                  n_iter: int = 2) -> CameraMotionWidget:
    widget = CameraMotionWidget(viewer)
    qtbot.addWidget(widget)
    widget.reset_choices()
    widget.image_combo.value = image
    widget.method_combo.value = method
    widget.model_combo.value = "translation"
    widget.max_blur.auto.setChecked(False)
    widget.max_blur.spin.setValue(14)
    widget.n_iter.setValue(n_iter)
    widget.gamma.choice = gamma
    return widget


def deconv_widget(qtbot, viewer, image, motion_source, gamma: str) -> DeconvolutionWidget:
    widget = DeconvolutionWidget(viewer)
    qtbot.addWidget(widget)
    widget.reset_choices()
    widget.image_combo.value = image
    widget.motion_combo.value = motion_source
    widget.gamma.choice = gamma
    return widget


def psnr(image, sharp) -> float:
    return aligned_scores(image, sharp, rotation=False)[0]


def test_the_layers_default_is_linear_and_auto_needs_a_file(qtbot, viewer_model):
    image = viewer_model.add_image(srgb_case(0, 64).blurred, name="photo")
    for cls in (CameraMotionWidget, DeconvolutionWidget):
        widget = cls(viewer_model)
        qtbot.addWidget(widget)
        widget.reset_choices()
        control = widget.gamma
        assert control.choice == "linear" and control.setting() == "linear"
        assert control.resolve() == (Gamma.linear(), "given")
        assert control.hint.text() == "gamma: linear (given)"
        assert not control.exponent.isEnabled()
        auto = control.combo.model().item(control.combo.findData("auto"))
        assert not auto.isEnabled()  # the layer was not opened from a file
        control.choice = "srgb"
        assert control.hint.text() == "gamma: srgb (given)"
        control.choice = "power"
        assert control.exponent.isEnabled() and control.setting() == "2.2"
        assert control.resolve(image) == (Gamma.power(2.2), "given")
        control.choice = "auto"  # chosen before the image changed: linear, and why
        assert control.resolve(image) == (Gamma.linear(), NO_FILE)


@pytest.mark.parametrize("seed", [0, 1])
def test_srgb_estimates_and_deconvolves_an_srgb_photo_better_than_linear(
        qtbot, viewer_model, wait_for_run, seed):
    case = srgb_case(seed)
    image = viewer_model.add_image(case.blurred, name="photo")
    scores, restored = {}, {}
    for gamma in ("linear", "srgb"):
        motion_w = motion_widget(qtbot, viewer_model, image, gamma)
        with warnings.catch_warnings():
            # on the encoded values the profiles bend; Xu+Ep may say they disagree
            warnings.filterwarnings("ignore", "the .* edge profiles do not agree",
                                    UserWarning)
            motion_w.run_button.click()
            wait_for_run(motion_w)
        assert motion_w.runner.outcome == "done"
        info = motion_w.last_estimate.info
        assert (info.gamma, info.gamma_reason) == (gamma, "given")  # record_gamma
        field = viewer_model.layers["photo PSF field"]
        assert field.metadata["edgecme_estimate"]["gamma"] == gamma
        deconv_w = deconv_widget(qtbot, viewer_model, image, field, gamma)
        deconv_w.run_button.click()
        wait_for_run(deconv_w)
        assert deconv_w.runner.outcome == "done"
        out = deconv_w.last_layer
        assert out.metadata["edgecme_deconvolution"]["gamma"] == gamma
        restored[gamma] = out.data
        scores[gamma] = psnr(out.data, case.sharp)
        if gamma == "srgb":
            # the two widgets, one after the other, do what the engine's deblur(gamma="srgb")
            # does (up to the round-off of the parameters' spin boxes and of the motion's
            # trip through layer metadata)
            expected, _ = deblur(case.blurred, "xu+ep", "translation", max_blur=14, n_iter=2,
                                 rng=0, gamma="srgb")
            assert np.abs(out.data - expected).mean() < 1e-4
            assert abs(scores[gamma] - psnr(expected, case.sharp)) < 0.05
            assert "encoded as the input; gamma: srgb (given)" in deconv_w.status.text()
            # the latent image (linear light in the estimate) is shown encoded as the photo
            np.testing.assert_allclose(viewer_model.layers["photo latent"].data,
                                       linear_to_srgb(motion_w.last_estimate.latent),
                                       atol=1e-6)
        for layer in list(viewer_model.layers)[1:]:
            viewer_model.layers.remove(layer)
    # measured (aligned PSNR against the sRGB sharp photo, 128 px): seed 0 25.27 vs 24.37 dB,
    # seed 1 25.38 vs 23.44 dB (before the estimators' polish the linear runs scored 19.68
    # and 23.64: the polish repairs much of the wrong-gamma estimate). The bound is the
    # issue's own target for --gamma auto on sRGB photos: 0.5 dB
    assert scores["srgb"] - scores["linear"] >= 0.5, scores
    # the output is encoded as the input: as bright as the photo, not as its linear light
    out = restored["srgb"]
    assert out.dtype == np.float32 and 0 <= out.min() <= out.max() <= 1
    assert abs(float(out.mean()) - float(case.blurred.mean())) < 0.03  # measured 0.011, 0.013
    assert float(case.blurred.mean()) - float(srgb_to_linear(case.blurred).mean()) > 0.15


@pytest.mark.parametrize("gamma, curve", [("srgb", Gamma.srgb()), ("power", Gamma.power(2.2))],
                         ids=["srgb", "power-2.2"])
def test_deconvolution_is_in_linear_light_and_re_encoded(qtbot, viewer_model, wait_for_run,
                                                         gamma, curve):
    case = srgb_case(0, 96)
    light = case.blurred if gamma == "srgb" else curve.encode(srgb_to_linear(case.blurred))
    image = viewer_model.add_image(light, name="photo",
                                   metadata={"edgecme_motion": case.motion.to_dict()})
    widget = deconv_widget(qtbot, viewer_model, image, image, gamma)
    widget.method_combo.value = "wiener"
    widget.run_button.click()
    wait_for_run(widget)
    expected = curve.encode(deconvolve(curve.decode(light), case.motion, "wiener",
                                       **widget.parameters()))
    np.testing.assert_allclose(widget.last_layer.data, expected, atol=1e-6)
    assert widget.last_layer.metadata["edgecme_deconvolution"]["gamma"] == curve.name
    # and unlike the linear run, which deconvolves the encoded values as they are
    plain = deconvolve(light, case.motion, "wiener", **widget.parameters())
    assert np.abs(widget.last_layer.data - plain).mean() > 0.005


def test_auto_on_an_srgb_tagged_png_chooses_srgb_and_says_why(qtbot, viewer_model, plugins,
                                                              tmp_path, wait_for_run):
    case = srgb_case(0, 96)
    path = tmp_path / "shaken.png"
    chunk = PngInfo()
    chunk.add(b"sRGB", b"\x00")  # rendering intent: perceptual
    PILImage.fromarray(np.round(case.blurred * 255).astype(np.uint8)).save(path, pnginfo=chunk)
    (layer,) = viewer_model.open(path, plugin="napari")  # napari records layer.source.path
    plain = viewer_model.add_image(case.blurred, name="array")
    assert layer.data.dtype == np.uint8

    motion_w = motion_widget(qtbot, viewer_model, layer, "linear", method="xu", n_iter=1)
    control = motion_w.gamma
    auto = control.combo.model().item(control.combo.findData("auto"))
    assert auto.isEnabled()
    control.choice = "auto"
    assert control.resolve() == (Gamma.srgb(), SRGB_CHUNK)
    assert control.hint.text() == f"gamma: srgb ({SRGB_CHUNK})"
    motion_w.image_combo.value = plain  # an array layer: auto cannot decide
    assert control.hint.text() == f"gamma: linear ({NO_FILE})"
    assert not auto.isEnabled() or control.choice == "auto"
    motion_w.image_combo.value = layer

    motion_w.run_button.click()
    wait_for_run(motion_w)
    assert motion_w.runner.outcome == "done"
    info = motion_w.last_estimate.info
    assert (info.gamma, info.gamma_reason) == ("srgb", SRGB_CHUNK)
    assert motion_w.status.text().endswith(f"; gamma: srgb ({SRGB_CHUNK})")

    deconv_w = deconv_widget(qtbot, viewer_model, layer, viewer_model.layers["shaken PSF field"],
                             "auto")
    assert deconv_w.gamma.hint.text() == f"gamma: srgb ({SRGB_CHUNK})"
    deconv_w.method_combo.value = "wiener"
    deconv_w.run_button.click()
    wait_for_run(deconv_w)
    settings = deconv_w.last_layer.metadata["edgecme_deconvolution"]
    assert (settings["gamma"], settings["gamma_reason"]) == ("srgb", SRGB_CHUNK)
    assert deconv_w.status.text().endswith(f"gamma: srgb ({SRGB_CHUNK})")


@pytest.mark.parametrize("bad", ["-1", "abc", "0", ""])
@pytest.mark.parametrize("cls", [CameraMotionWidget, DeconvolutionWidget],
                         ids=["camera-motion", "deconvolution"])
def test_a_bad_exponent_is_refused_in_one_line(qtbot, viewer_model, notifications, cls, bad):
    case = srgb_case(0, 64)
    image = viewer_model.add_image(case.blurred, name="photo",
                                   metadata={"edgecme_motion": case.motion.to_dict()})
    widget = cls(viewer_model)
    qtbot.addWidget(widget)
    widget.reset_choices()
    widget.image_combo.value = image
    widget.gamma.choice = "power"
    widget.gamma.exponent.setText(bad)
    message = f"gamma must be auto, linear, srgb or a number > 0 (a power-law exponent such " \
              f"as 2.2); got {bad!r}"
    assert widget.gamma.hint.text() == f"not usable: {message}"
    widget.run_button.click()
    title = "Camera motion" if cls is CameraMotionWidget else "Deconvolution"
    assert widget.runner.outcome == "refused" and not widget.runner.is_running
    assert widget.status.text() == f"{title}: not run: {message}"
    assert notifications.texts("error") == [f"{title}: {message}"]
    assert [layer.name for layer in viewer_model.layers] == ["photo"]  # nothing added
    assert widget.run_button.isEnabled()  # not frozen: a good value runs
    widget.gamma.exponent.setText("2.2")
    assert widget.gamma.hint.text() == "gamma: 2.2 (given)"


def test_closing_the_run_closes_the_engines_generator(monkeypatch):
    closed, seen = [], []

    def engine(image, *args, **kwargs):
        seen.append(float(image.mean()))
        try:
            for step in range(100):
                yield Progress("estimate", step, 100, preview=image)
        finally:
            closed.append(True)

    monkeypatch.setattr(_gamma, "iter_estimate_motion", engine)
    data = np.full((8, 8), 0.5, np.float32)
    gen = estimate_in_linear_light(data, Gamma.srgb(), "given")
    first = next(gen)
    assert seen == [pytest.approx(0.214041, abs=1e-6)]  # sRGB 0.5 in linear light
    # the engine sees linear light; the preview shown is encoded back as the photo is
    np.testing.assert_allclose(first.preview, data, atol=1e-6)
    gen.close()
    assert closed == [True]


def test_a_cancelled_srgb_run_leaves_no_layer(qtbot, viewer_model, wait_for_run):
    case = srgb_case(0, 128)
    image = viewer_model.add_image(case.blurred, name="photo")
    widget = motion_widget(qtbot, viewer_model, image, "srgb", method="xu", n_iter=50)
    widget.run_button.click()
    widget.cancel_button.click()
    wait_for_run(widget)
    assert widget.runner.outcome == "cancelled"
    assert [layer.name for layer in viewer_model.layers] == ["photo"]
    assert widget.last_motion is None


def test_a_motion_estimated_with_another_curve_is_said(qtbot, viewer_model):
    case = srgb_case(0, 64)
    image = viewer_model.add_image(case.blurred, name="photo")
    field = viewer_model.add_image(np.zeros((64, 64), np.float32), name="photo PSF field",
                                   metadata={"edgecme_motion": case.motion.to_dict(),
                                             "edgecme_source": "photo",
                                             "edgecme_estimate": {"gamma": "srgb"}})
    widget = deconv_widget(qtbot, viewer_model, image, field, "linear")
    assert widget.motion_hint.text().endswith("; estimated with gamma srgb")
    widget.gamma.choice = "srgb"
    assert "estimated with gamma" not in widget.motion_hint.text()
