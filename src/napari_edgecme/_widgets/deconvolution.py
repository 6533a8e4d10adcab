"""The "Deconvolution" widget: restore a blurred image with a known camera motion.

Runs :func:`~napari_edgecme.core.deconv.iter_deconvolve` (hyper-Laplacian,
Richardson-Lucy or Wiener with the spatially varying blur) in a worker thread. The
motion comes from a layer's metadata (``metadata["edgecme_motion"]``, as written by
the "Camera motion" widget or a sample with its true motion) or from a JSON motion
file. The result is a new float32 layer ``"<image> deblurred"`` with the input's
scale and translate; the input layer is never modified.

A motion describes the image it was estimated on. The widget fits it to the chosen
image with :func:`fit_motion`: the same image as is; a crop of it -- placed by the
layer's translate, as napari crop tools leave it -- with
:meth:`~napari_edgecme.core.motion.CameraMotion.cropped` (the principal point moves,
the blur does not shrink); a resized copy with
:meth:`~napari_edgecme.core.motion.CameraMotion.rescale`. What it did is shown under
the motion choice before a run; a guess is a warning; anything else is refused.

The "gamma" choice (:class:`._gamma.GammaControl`: linear, the default for layers; sRGB;
a power law; auto from the layer's source file) says how the layer's values encode
light: the image is deconvolved in linear light and the result encoded as the input was
(:func:`._gamma.deconvolve_in_linear_light`); ``metadata["edgecme_deconvolution"]``
records the curve and why. A motion estimated with another curve is said in the motion
line (the blur is the same; only the light it was measured in differs).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import napari
import numpy as np
from magicgui.widgets import ComboBox
from napari.layers import Image, Layer
from napari.utils.notifications import show_error, show_info, show_warning
from qtpy.QtWidgets import (
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSpinBox,
    QStackedWidget,
    QVBoxLayout,
    QWidget,
)

from ..core._validation import first_line
from ..core.deblur import ep_prior_note
from ..core.deconv import DEFAULTS, HALF_CHROMA_PIXELS
from ..core.estimate import METHODS as ESTIMATION_METHODS
from ..core.motion import CameraMotion
from ._dock import dock_layout
from ._gamma import GIVEN, GammaControl, deconvolve_in_linear_light, gamma_note
from ._layers import (
    ESTIMATE_KEY,
    MOTION_KEY,
    SOURCE_KEY,
    image_layers,
    image_shape,
    motion_from,
    snapshot_image,
    spatial_kwargs,
)
from ._runner import RunControls

__all__ = ["METHOD_CHOICES", "DeconvolutionWidget", "MotionFit", "fit_motion"]

logger = logging.getLogger(__name__)

#: Deconvolution methods as shown, with the engine's names.
METHOD_CHOICES = [("sparse gradients (hyper-Laplacian, Krishnan-Fergus)", "hyperlaplacian"),
                  ("iterative (Richardson-Lucy)", "rl"), ("one-step linear (Wiener)", "wiener")]
#: Metadata key of the deconvolution settings of a restored layer.
DECONV_KEY = "edgecme_deconvolution"


@dataclass(frozen=True)
class MotionFit:
    """A camera motion made to fit an image, and what was done to it.

    Attributes
    ----------
    motion : CameraMotion
        For the image's pixel grid.
    note : str
        One line for the user ("" when the motion is the image's own).
    guess : bool
        True when the fit rests on an assumption the user should check (a warning).
    """

    motion: CameraMotion
    note: str = ""
    guess: bool = False


def _plain(layer: Layer) -> bool:
    """Whether a layer's transform is scale and translate only (no rotation or shear)."""
    return (np.allclose(layer.rotate, np.eye(len(layer.scale)))
            and np.allclose(layer.shear, 0.0))


def fit_motion(motion: CameraMotion, image: Image, reference: Layer | None = None) -> MotionFit:
    """Fit ``motion`` to the pixel grid of ``image``: as is, cropped or rescaled.

    Parameters
    ----------
    motion : CameraMotion
        As estimated, for an image of ``motion.image_shape``.
    image : Image
        The layer to deconvolve.
    reference : Layer, optional
        The layer the motion came from (its data lies over the motion's image, as
        the PSF field, a latent or a sample layer does); None for a motion file.

    Returns
    -------
    MotionFit

    Raises
    ------
    ValueError
        One line, when the image is neither the motion's image, nor a crop of it at
        a known place, nor a resized copy.

    Notes
    -----
    With a reference layer, the image's pixel grid is mapped into the motion's
    pixels through world coordinates: the same pixel size at a whole-pixel offset
    is a crop (:meth:`CameraMotion.cropped`), an image covering the motion's frame
    with other pixels a resized copy (:meth:`CameraMotion.rescale`). Without one
    (a file), the layer's translate in pixels is the crop offset. A smaller image
    at the motion image's origin is ambiguous: a resized copy if the aspect ratio
    agrees, else a crop at (0, 0) -- both said as a warning.
    """
    shape = image_shape(image)
    full = motion.image_shape
    scale_i = np.asarray(image.scale, float)[-2:]
    trans_i = np.asarray(image.translate, float)[-2:]
    if reference is not None and _plain(reference) and _plain(image):
        ref_data = np.asarray(image_shape(reference) if isinstance(reference, Image)
                              else full, float)
        factor = np.asarray(full, float) / ref_data
        scale_r = np.asarray(reference.scale, float)[-2:]
        trans_r = np.asarray(reference.translate, float)[-2:]
        pitch = scale_i / scale_r * factor  # motion pixels per image pixel
        offset = ((trans_i - trans_r) / scale_r + 0.5) * factor - 0.5
    elif _plain(image):
        pitch, offset = np.ones(2), trans_i / scale_i
    else:
        pitch, offset = None, None
    size = f"{shape[0]}x{shape[1]}"
    mine = f"{full[0]}x{full[1]}"
    if shape == full and (offset is None or np.allclose(offset, 0, atol=1e-3)):
        return MotionFit(motion)
    if pitch is not None and np.allclose(pitch, 1.0, atol=1e-3):
        whole = np.round(offset)
        if np.allclose(offset, whole, atol=1e-3) and np.any(whole != 0):
            r, c = (int(v) for v in whole)
            try:
                moved = motion.cropped((r, c), shape)
            except ValueError:
                raise ValueError(
                    f"this {size} image at (row {r}, col {c}) reaches outside the motion's "
                    f"{mine} image") from None
            return MotionFit(moved, f"a {size} crop at (row {r}, col {c}) of the motion's "
                                    f"{mine} image: motion moved with the crop (not rescaled)")
        inside = shape[0] <= full[0] and shape[1] <= full[1]
        if np.all(whole == 0) and shape != full and inside:
            return _at_origin(motion, shape)
    if pitch is not None and shape != full:
        covered = np.asarray(shape) * pitch
        if (np.allclose(covered, full, atol=1.0)
                and np.allclose(offset, 0.5 * pitch - 0.5, atol=0.5 * pitch.max())):
            return MotionFit(motion.rescale(shape), f"a resized copy of the motion's {mine} "
                                                    "image: motion rescaled")
    if shape == full:
        return MotionFit(motion, f"placed apart from the motion's image; taken as the same "
                                 f"{mine} image", guess=True)
    raise ValueError(
        f"the motion is for a {mine} image; this image is {size} and neither a crop at a "
        "known place (give the layer the crop's offset as translate) nor a resized copy")


def _at_origin(motion: CameraMotion, shape) -> MotionFit:
    """A smaller image at the origin of the motion's image: a resized copy or a crop?"""
    full = motion.image_shape
    size, mine = f"{shape[0]}x{shape[1]}", f"{full[0]}x{full[1]}"
    ratio = np.asarray(shape, float) / np.asarray(full, float)
    if abs(ratio[0] - ratio[1]) <= 1.0 / min(full) + 1.0 / min(shape):
        return MotionFit(motion.rescale(shape), f"{size} is taken as a resized copy of the "
                         f"motion's {mine} image (motion rescaled); if it is a crop, give the "
                         "layer the crop's offset as translate", guess=True)
    return MotionFit(motion.cropped((0, 0), shape), f"{size} is taken as a crop at the top-left "
                     f"corner of the motion's {mine} image; if it was cut elsewhere, give the "
                     "layer the crop's offset as translate", guess=True)


class DeconvolutionWidget(QWidget):
    """Deblur an image layer with a camera motion (non-blind deconvolution).

    Parameters
    ----------
    viewer : napari.viewer.Viewer
        The viewer (or a :class:`napari.components.ViewerModel`).
    """

    def __init__(self, viewer: napari.viewer.Viewer, parent: QWidget | None = None):
        super().__init__(parent)
        self._viewer = viewer
        #: a motion read from a file: its name, the motion, and the estimator that made it
        #: and its profile misfit (each None when the file does not say)
        self._file_motion: tuple[str, CameraMotion, str | None, float | None] | None = None
        self.last_layer: Image | None = None

        self.image_combo = ComboBox(label="image", choices=self._image_choices)
        self.image_combo.native.setToolTip("The blurred image layer to restore (2-D gray or "
                                           "RGB); it is not modified")
        self.motion_combo = ComboBox(label="motion", choices=self._motion_choices)
        self.motion_combo.native.setToolTip(
            "How the camera moved: a layer carrying a camera motion (the PSF field of "
            "'Camera motion', or a sample with its true motion), or a motion file loaded "
            "with 'Load JSON…'")
        self.motion_hint = QLabel("")
        self.motion_hint.setWordWrap(True)
        self.load_button = QPushButton("Load JSON…")
        self.load_button.setToolTip("Read a motion file (edgecme-motion JSON)")
        self.gamma = GammaControl(self.image_combo)
        self.method_combo = ComboBox(label="method", choices=METHOD_CHOICES,
                                     value="hyperlaplacian")
        self.method_combo.native.setToolTip(
            "Sparse gradients: sharpest, fewest ringing artefacts (the default); "
            "Richardson-Lucy: iterative, sharper with more iterations but noisier; "
            "Wiener: one linear step, fastest, softest")

        hl = DEFAULTS["hyperlaplacian"]
        # the minimum, 0, reads "auto": the engine's default, set from the photo's noise
        self.lambda_f = QDoubleSpinBox()
        self.lambda_f.setRange(0.0, 1.0)
        self.lambda_f.setDecimals(7)
        self.lambda_f.setStepType(QDoubleSpinBox.StepType.AdaptiveDecimalStepType)
        self.lambda_f.setSpecialValueText("auto (from the noise)")
        self.lambda_f.setValue(0.0 if hl["lambda_f"] is None else hl["lambda_f"])
        self.lambda_f.setToolTip("How smooth the result is (weight λ_f of the gradient prior, "
                                 "as in the estimation, images in [0, 1]). auto: set from "
                                 "the photo's noise (2/1500 at 2/255 noise, less on clean "
                                 "photos; an EpAlone motion at least 2/1500, up to 8x that as "
                                 "its edge profiles disagree with it); lower it for a "
                                 "sharper, noisier result")
        self.alpha_combo = ComboBox(choices=[("2/3", 2.0 / 3.0), ("1/2", 0.5)],
                                    value=hl["alpha"])
        self.alpha_combo.native.setToolTip("How strongly small gradients are flattened "
                                           "(exponent α of the hyper-Laplacian prior): 1/2 "
                                           "flattens more")
        self.solver_combo = ComboBox(choices=[("patch-wise Fourier (fast)", "fourier"),
                                              ("conjugate gradients (exact)", "cg")],
                                     value=hl["solver"])
        self.solver_combo.native.setToolTip("Fourier on overlapping tiles (fast, the "
                                            "default) or conjugate gradients with the exact "
                                            "spatially varying blur (slow)")
        self.color_combo = ComboBox(choices=[("R, G, B each", "rgb"),
                                             ("luminance + chroma", "opponent")],
                                    value=hl["color"])
        self.color_combo.native.setToolTip(
            "Colour photos: deblur the luminance (the channels' mean) and two "
            "colour-difference axes, which lets large photos deblur their colour at half "
            "resolution; or deblur R, G and B each on its own (the old way)")
        self.chroma_combo = ComboBox(choices=[("auto (half from "
                                              f"{HALF_CHROMA_PIXELS / 1e6:g} MP)", "auto"),
                                              ("full resolution", "full"),
                                              ("half resolution (faster)", "half")],
                                     value=hl["chroma"])
        self.chroma_combo.native.setToolTip(
            "Luminance + chroma: the colour-difference axes at full or half resolution "
            "(half: about half the time; a camera records colour at about half "
            "resolution anyway: Bayer mosaic, JPEG 4:2:0)")
        self.color_combo.changed.connect(self._sync_chroma)
        self._sync_chroma()
        self.rl_iterations = QSpinBox()
        self.rl_iterations.setRange(1, 100000)
        self.rl_iterations.setValue(DEFAULTS["rl"]["iterations"])
        self.rl_iterations.setToolTip("Richardson-Lucy iterations (more: sharper and noisier)")
        self.nsr = QDoubleSpinBox()
        self.nsr.setRange(1e-6, 10.0)
        self.nsr.setDecimals(6)
        self.nsr.setStepType(QDoubleSpinBox.StepType.AdaptiveDecimalStepType)
        self.nsr.setValue(DEFAULTS["wiener"]["nsr"])
        self.nsr.setToolTip("Noise-to-signal ratio: raise it for noisy photos (smoother)")

        self.params = QStackedWidget()
        for rows in ([("smoothness (λ_f)", self.lambda_f), ("prior exponent (α)",
                                                      self.alpha_combo.native),
                      ("solver", self.solver_combo.native),
                      ("colour", self.color_combo.native),
                      ("chroma", self.chroma_combo.native)],
                     [("iterations", self.rl_iterations)],
                     [("noise/signal", self.nsr)]):
            page = QWidget()
            page_form = QFormLayout(page)
            page_form.setContentsMargins(0, 0, 0, 0)
            for label, widget in rows:
                page_form.addRow(label, widget)
            self.params.addWidget(page)

        self.controls = RunControls(
            self, "Deconvolution",
            run_tip="Deblur the image with the motion in the background; adds "
                    "'<image> deblurred'")
        self.run_button = self.controls.run_button
        self.cancel_button = self.controls.cancel_button
        self.status = self.controls.status
        self.runner = self.controls.runner

        motion_row = QHBoxLayout()
        motion_row.addWidget(self.motion_combo.native, 1)
        motion_row.addWidget(self.load_button)
        form = QFormLayout()
        form.addRow("image", self.image_combo.native)
        form.addRow("motion", motion_row)
        form.addRow("", self.motion_hint)
        form.addRow("gamma", self.gamma)
        form.addRow("method", self.method_combo.native)
        layout = QVBoxLayout()
        layout.addLayout(form)
        layout.addWidget(self.params)
        layout.addWidget(self.controls)
        layout.addStretch(1)
        dock_layout(self, layout)

        self.run_button.clicked.connect(self.run)
        self.load_button.clicked.connect(lambda: self.load_motion())
        self.method_combo.changed.connect(self._on_method_changed)
        self.image_combo.changed.connect(self._on_image_changed)
        self.motion_combo.changed.connect(lambda _value: self._update_motion_hint())
        self.gamma.changed.connect(self._update_motion_hint)
        self.reset_choices()
        self._on_method_changed(self.method_combo.value)

    # -- choices ---------------------------------------------------------------------------
    def _image_choices(self, _widget=None):
        return image_layers(self._viewer)

    def _motion_choices(self, _widget=None):
        """Layers carrying a motion, those computed from (or for) the chosen image first."""
        image = self.image_combo.value if hasattr(self, "image_combo") else None
        name = getattr(image, "name", None)
        # newest (top-most) first, then those that belong to the chosen image first
        layers = [layer for layer in reversed(self._viewer.layers)
                  if MOTION_KEY in layer.metadata]
        layers.sort(key=lambda layer: not (layer.metadata.get(SOURCE_KEY) == name
                                           or layer.name == name))
        choices = [(f"{layer.name}", layer) for layer in layers]
        if self._file_motion is not None:
            choices.append((f"file: {self._file_motion[0]}", self._file_motion[1]))
        return choices

    def reset_choices(self, *_args) -> None:
        """Refresh the layer choices (napari calls this when layers change)."""
        self.image_combo.reset_choices()
        self.motion_combo.reset_choices()
        self._update_motion_hint()

    def _on_image_changed(self, _value) -> None:
        self.motion_combo.reset_choices()
        self.runner.clear_status()
        self._update_motion_hint()

    def fitted_motion(self) -> MotionFit:
        """The chosen motion fitted to the chosen image (:func:`fit_motion`).

        Raises
        ------
        ValueError
            One line: no image, no motion, or a motion that does not fit.
        """
        image = self.image_combo.value
        if image is None:
            raise ValueError("choose an image layer first")
        source = self.motion_combo.value
        if source is None:
            raise ValueError("choose a motion: a layer that carries one (run 'Camera "
                             "motion' first) or a JSON file ('Load JSON…')")
        motion = motion_from(source)
        return fit_motion(motion, image, source if isinstance(source, Layer) else None)

    def _update_motion_hint(self) -> None:
        """Say which motion will be used and how it fits the image, or why none can be."""
        if self.image_combo.value is None:
            self.motion_hint.setText("")
            return
        if self.motion_combo.value is None:
            self.motion_hint.setText("No motion yet: estimate one with 'Camera motion', "
                                     "or load a motion file with 'Load JSON…'.")
            return
        try:
            fit = self.fitted_motion()
        except ValueError as err:
            self.motion_hint.setText(f"Does not fit: {first_line(err)}")
            return
        m = fit.motion
        text = (f"{m.model} motion, {m.n_poses} poses, blur extent {m.blur_extent():.1f} px "
                "(longest side of the PSFs)")
        if fit.note:
            text += f"; {'check: ' if fit.guess else ''}{fit.note}"
        estimated_in = self._motion_gamma()
        if estimated_in is not None and estimated_in != self._gamma_name():
            text += f"; estimated with gamma {estimated_in}"
        self.motion_hint.setText(text)

    def _motion_gamma(self) -> str | None:
        """The curve the chosen motion was estimated with, when its layer says."""
        return self._motion_estimate("gamma")

    def _motion_summary(self) -> dict | None:
        """The chosen motion's estimate summary, None when unknown: its layer's (written by
        the camera-motion widget, and carried on to the layers deblurred with it), or of a
        motion read from a file that names its estimator, the file's ``estimated_by`` and
        ``profile_misfit`` as "method" and "profile_misfit"."""
        source = self.motion_combo.value
        if isinstance(source, Layer):
            summary = source.metadata.get(ESTIMATE_KEY)
            return summary if isinstance(summary, dict) else None
        file = self._file_motion
        if file is not None and source is file[1] and file[2] is not None:
            return {"method": file[2], "profile_misfit": file[3]}
        return None

    def _motion_estimate(self, key: str):
        """An entry of the chosen motion's estimate summary (:meth:`_motion_summary`), or
        None."""
        summary = self._motion_summary()
        return None if summary is None else summary.get(key)

    def _gamma_name(self) -> str | None:
        try:
            return self.gamma.resolve()[0].name
        except ValueError:
            return None

    def _on_method_changed(self, method) -> None:
        self.params.setCurrentIndex([value for _name, value in METHOD_CHOICES].index(method))

    # -- actions ---------------------------------------------------------------------------
    def load_motion(self, path: str | Path | None = None) -> CameraMotion | None:
        """Read a JSON motion file and make it the chosen motion (asks when ``path`` is None)."""
        if path is None:
            path, _ = QFileDialog.getOpenFileName(self, "Load camera motion", "",
                                                  "JSON files (*.json);;All files (*)")
            if not path:
                return None
        try:
            motion, estimated_by, misfit = CameraMotion.load_estimate(path)
        except ValueError as err:
            show_error(f"Deconvolution: {first_line(err)}")
            return None
        self._file_motion = (Path(path).name, motion, estimated_by, misfit)
        self.motion_combo.reset_choices()
        self.motion_combo.value = motion
        show_info(f"Deconvolution: loaded {Path(path).name} ({motion.model} motion, "
                  f"{motion.n_poses} poses, {motion.image_shape[0]}x{motion.image_shape[1]} "
                  "image)")
        return motion

    def _sync_chroma(self, *_) -> None:
        """The chroma choice applies to luminance + chroma only."""
        self.chroma_combo.native.setEnabled(self.color_combo.value == "opponent")

    def parameters(self) -> dict:
        """The chosen method's parameters, as :func:`iter_deconvolve` takes them."""
        method = self.method_combo.value
        if method == "hyperlaplacian":
            chosen = float(self.lambda_f.value())
            return {"lambda_f": chosen if chosen > self.lambda_f.minimum() else None,
                    "alpha": float(self.alpha_combo.value),
                    "solver": self.solver_combo.value,
                    "color": self.color_combo.value,
                    "chroma": (self.chroma_combo.value if self.color_combo.value == "opponent"
                               else DEFAULTS["hyperlaplacian"]["chroma"])}
        if method == "rl":
            return {"iterations": int(self.rl_iterations.value())}
        return {"nsr": float(self.nsr.value())}

    def run(self) -> None:
        """Deconvolve the chosen image with the chosen motion in a worker thread."""
        image = self.image_combo.value
        try:
            fit = self.fitted_motion()
            data = snapshot_image(image)
            curve, reason = self.gamma.resolve(image, data)
        except ValueError as err:
            self.runner.refuse(first_line(err))
            return
        if fit.guess:
            show_warning(f"Deconvolution: {fit.note}")
        method, params = self.method_combo.value, self.parameters()
        # restored as deblur restores an estimate of its method (EpAlone: a prior that
        # grows with its edge profiles' misfit)
        estimated_by = self._motion_estimate("method")
        if estimated_by not in ESTIMATION_METHODS:
            estimated_by = None
        misfit = self._motion_estimate("profile_misfit")
        misfit = misfit if isinstance(misfit, float) else None
        gen = deconvolve_in_linear_light(data, curve, fit.motion, method,
                                         estimated_by=estimated_by, profile_misfit=misfit,
                                         **params)
        settings = {"method": method, **params, "gamma": curve.name, "gamma_reason": reason}
        prior = ep_prior_note(estimated_by, method, params, misfit)
        self.runner.start(gen, on_result=partial(self._show_result, image, fit.motion,
                                                 settings, self._motion_summary(), prior))

    def cancel(self) -> None:
        """Stop the running deconvolution (nothing is added)."""
        self.runner.cancel()

    # -- main-thread handler -----------------------------------------------------------------
    def _show_result(self, image: Image, motion: CameraMotion, settings: dict,
                     summary: dict | None, prior: str, restored: np.ndarray) -> str:
        restored = np.asarray(restored, dtype=np.float32)
        rgb = restored.ndim == 3
        extra = {} if rgb else {"colormap": image.colormap.name}
        metadata = {MOTION_KEY: motion.to_dict(), SOURCE_KEY: image.name, DECONV_KEY: settings}
        if summary is not None:  # the motion's estimate, for a restoration from this layer
            metadata[ESTIMATE_KEY] = dict(summary)
        layer = Image(restored, name=f"{image.name} deblurred", rgb=rgb,
                      contrast_limits=(0.0, 1.0), metadata=metadata,
                      **extra, **spatial_kwargs(image))
        self._viewer.add_layer(layer)
        self.last_layer = layer
        added = f"added {layer.name!r}" + (f", {prior}" if prior else "")
        if settings["gamma"] == "linear" and settings["gamma_reason"] == GIVEN:
            return added
        return (f"{added}, encoded as the input; "
                f"{gamma_note(settings['gamma'], settings['gamma_reason'])}")
