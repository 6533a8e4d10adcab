"""The "Camera motion" widget: estimate how the camera shook from one blurred image.

Runs :func:`~napari_edgecme.core.estimate.iter_estimate_motion` (EpAlone, Xu or
Xu+Ep, paper Eqs. 19-22) in a worker thread, with a progress bar per scale and
iteration and, for Xu and Xu+Ep, a live preview layer of the latent image as it
refines (see-through, just above the photo, never taking the layer selection).
Results, aligned with the input image (same scale and translate):

* ``"<image> PSF field"``: the local PSFs on a grid, each enlarged by one stated
  factor (``metadata["edgecme_psf_enlargement"]``, and on the status line) on a
  gray tile at its sample point (:func:`._psf_view.psf_glyphs`), over the image,
  carrying the motion in ``metadata["edgecme_motion"]`` as the JSON dict of the
  motion file, so it survives saving and feeds the "Deconvolution" widget;
* ``"<image> latent"`` (Xu, Xu+Ep; hidden): the last latent estimate;
* a plot of the motion density function in pose space (marker size = weight);
* "Save motion…" writes the motion file (JSON).

The "gamma" choice (:class:`._gamma.GammaControl`: linear, the default for layers; sRGB;
a power law; auto from the layer's source file) says how the layer's values encode
light: the estimation runs on the image in linear light
(:func:`._gamma.estimate_in_linear_light`), the latent image and its previews are
shown encoded as the photo is, and ``estimate.info`` (and the layers'
``metadata["edgecme_estimate"]``) record the curve and why.

The "max blur" on auto (:class:`._max_blur.MaxBlurControl`) is measured from the image
by the engine, in the worker (``max_blur=None`` to
:func:`~napari_edgecme.core.estimate.iter_estimate_motion`): the status line and
``metadata["edgecme_estimate"]["blur_size"]`` say what was found ("max blur 18 px
(measured: blur about 9 px, from 40 edge profiles)"), as ``edgecme deblur`` does.
"""

from __future__ import annotations

import logging
from functools import partial
from pathlib import Path

import napari
import numpy as np
from magicgui.widgets import ComboBox
from napari.layers import Image, Shapes
from napari.utils.notifications import show_error, show_info
from qtpy.QtWidgets import (
    QCheckBox,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)
from superqt import QCollapsible

from ..core._validation import first_line
from ..core.camera import DEFAULT_FOCAL_35MM, param_names
from ..core.edges import EdgeProfiles
from ..core.estimate import DEFAULTS, MotionEstimate
from ..core.motion import CameraMotion
from ..core.progress import Progress
from ._dock import dock_layout
from ._gamma import GIVEN, Estimated, GammaControl, estimate_in_linear_light, gamma_note
from ._layers import (
    ESTIMATE_KEY,
    MOTION_KEY,
    PROFILES_KEY,
    SOURCE_KEY,
    default_focal_px,
    focal_from_layer,
    image_layers,
    image_shape,
    resampled_kwargs,
    snapshot_image,
)
from ._max_blur import MaxBlurControl, measured_note
from ._plots import deferred_draw, plot_canvas, style_axes, theme_colours
from ._psf_view import psf_glyphs
from ._runner import RunControls
from .edge_profiles import SETTINGS_KEY as PROFILE_SETTINGS_KEY

__all__ = ["METHOD_CHOICES", "MODEL_CHOICES", "CameraMotionWidget", "psf_grid"]

logger = logging.getLogger(__name__)

#: Estimation methods as shown, with the engine's names.
METHOD_CHOICES = [("sharpened image + edge profiles (Xu+Ep)", "xu+ep"),
                  ("sharpened image only (Xu)", "xu"), ("edge profiles only (EpAlone)", "ep")]
#: Pose models as shown, with the engine's names.
MODEL_CHOICES = [("camera turned in 3-D (rotation)", "rotation"),
                 ("slid and turned in the image plane (tx, ty, θz)", "inplane"),
                 ("slid only: same blur everywhere (translation)", "translation")]
#: Metadata key of the PSF field's enlargement (each PSF drawn this many times larger).
ZOOM_KEY = "edgecme_psf_enlargement"
#: Opacity of the live preview of the latent image over the photo.
PREVIEW_OPACITY = 0.6
_AUTO_PROFILES = ("detect automatically", None)


def psf_grid(shape, per_short_side: int = 5) -> tuple[int, int]:
    """PSF sample grid ``(rows, cols)`` for a PSF-field image: square cells, ~5 per short side."""
    rows, cols = shape[:2]
    short = min(rows, cols)
    return (max(1, round(per_short_side * rows / short)),
            max(1, round(per_short_side * cols / short)))


class CameraMotionWidget(QWidget):
    """Estimate the camera motion of a blurred image layer.

    Parameters
    ----------
    viewer : napari.viewer.Viewer
        The viewer (or a :class:`napari.components.ViewerModel`).
    """

    def __init__(self, viewer: napari.viewer.Viewer, parent: QWidget | None = None):
        super().__init__(parent)
        self._viewer = viewer
        self._preview: Image | None = None
        self._suggested: Shapes | None = None
        self.last_motion: CameraMotion | None = None
        self.last_estimate: MotionEstimate | None = None
        self._last_name = ""

        self.image_combo = ComboBox(label="image", choices=self._image_choices)
        self.image_combo.native.setToolTip("The blurred photo (2-D gray or RGB layer)")
        self.method_combo = ComboBox(label="method", choices=METHOD_CHOICES, value="xu+ep")
        self.method_combo.native.setToolTip(
            "How to find the motion. Sharpened image + edge profiles: alternates a "
            "sharpened estimate of the photo with a fit of the blur to straight edges "
            "(Xu+Ep, paper Eq. 22), best in general. Sharpened image only: the baseline "
            "(Xu, L0 latent image, Eq. 21). Edge profiles only: fastest, needs at least "
            "12 clean straight edges (EpAlone, Eq. 16)")
        self.model_combo = ComboBox(label="model", choices=MODEL_CHOICES, value="rotation")
        self.model_combo.native.setToolTip(
            "How the camera may have moved. Turned in 3-D: hand shake, the blur differs "
            "over the photo (3 rotation angles). In the image plane: sliding sideways and "
            "turning about the lens axis. Slid only: one blur for the whole photo")
        self.max_blur = MaxBlurControl(self.image_combo)
        self.gamma = GammaControl(self.image_combo)
        self.focal_auto = QCheckBox("auto")
        self.focal_auto.setChecked(True)
        self.focal_auto.setToolTip("Auto: from the layer's metadata or the file's EXIF, "
                                   f"else a {DEFAULT_FOCAL_35MM:g} mm-equivalent lens")
        self.focal_spin = QDoubleSpinBox()
        self.focal_spin.setRange(1.0, 1e6)
        self.focal_spin.setDecimals(1)
        self.focal_spin.setSuffix(" px")
        self.focal_spin.setEnabled(False)
        self.focal_spin.setToolTip(
            "Focal length in pixels of this image (35 mm-equivalent focal length / 36 × "
            "the longer side). Used by the 3-D rotation model: how far a turn of the "
            "camera moves each pixel")
        self.focal_hint = QLabel("")
        self.focal_hint.setWordWrap(True)
        self.profiles_combo = ComboBox(label="profiles", choices=self._profile_choices)
        self.profiles_combo.native.setToolTip(
            "Edge profiles for the methods that use them: detected automatically, or the "
            "set shown in a layer of the 'Edge profiles' widget (with your hand picks)")
        self.preview_check = QCheckBox("live preview of the sharpened image")
        self.preview_check.setChecked(True)
        self.preview_check.setToolTip(
            "While estimating, show the sharpened image (the latent image) as it refines, "
            "semi-transparent above the photo; it stays as the hidden '<image> latent' "
            "layer at the end")

        # advanced parameters (paper Eqs. 19-22), engine defaults
        self.lambda_w = _float_spin(DEFAULTS["lambda_w"], 0.0, 1.0, 5,
                                    "Higher: fewer camera poses, a thinner blur path (L1 "
                                    "weight λ_w on the motion density function, Eqs. 19, 22)")
        self.lambda_ip = _float_spin(DEFAULTS["lambda_ip"], 0.0, 100.0, 3,
                                     "How much the edge profiles count against the "
                                     "sharpened image (λ_Ip, Eq. 22)")
        self.lambda_f = _float_spin(DEFAULTS["lambda_f"], 1e-5, 1.0, 5,
                                    "Higher: a flatter, more cartoon-like sharpened image "
                                    "(L0 weight λ_f of the latent update, Eq. 21)")
        self.n_iter = _int_spin(DEFAULTS["n_iter"], 1, 100,
                                "Rounds of sharpen-then-fit at each scale of the pyramid")
        self.max_side = _int_spin(DEFAULTS["max_side"], 32, 16384,
                                  "Estimate on a copy whose longer side is at most this (px); "
                                  "larger is slower")
        self.seed = _int_spin(0, 0, 2**31 - 1, "Seed of every random choice (same seed, "
                                                "same result)")
        advanced = QCollapsible("Advanced")
        adv = QWidget()
        adv_form = QFormLayout(adv)
        adv_form.addRow("motion sparsity (λ_w)", self.lambda_w)
        adv_form.addRow("edge-profile weight (λ_Ip)", self.lambda_ip)
        adv_form.addRow("image flatness (λ_f)", self.lambda_f)
        adv_form.addRow("rounds per scale", self.n_iter)
        adv_form.addRow("max working side", self.max_side)
        adv_form.addRow("seed", self.seed)
        advanced.addWidget(adv)
        self.advanced = advanced

        self.controls = RunControls(
            self, "Camera motion",
            run_tip="Estimate how the camera moved, in the background; adds the PSF field "
                    "layer (and the sharpened image) and plots the motion",
            cancel_tip="Stop the estimation now; nothing is added")
        self.run_button = self.controls.run_button
        self.cancel_button = self.controls.cancel_button
        self.status = self.controls.status
        self.runner = self.controls.runner
        self.save_button = QPushButton("Save motion…")
        self.save_button.setToolTip("Write the estimated motion as a JSON motion file")
        self.save_button.setEnabled(False)
        self.canvas, axes = plot_canvas(viewer, 1, height=2.4, left_margin=60,
                                        right_margin=16)
        self._has_plot = bool(axes)
        self._redraw = deferred_draw(self.canvas) if axes else (lambda: None)
        self._colours = theme_colours(viewer)
        self.plot_section = QCollapsible("Plot: camera poses")
        self.plot_section.addWidget(self.canvas)
        self.plot_section.expand(animate=False)

        focal_row = QHBoxLayout()
        focal_row.addWidget(self.focal_spin, 1)
        focal_row.addWidget(self.focal_auto)
        form = QFormLayout()
        form.addRow("image", self.image_combo.native)
        form.addRow("method", self.method_combo.native)
        form.addRow("model", self.model_combo.native)
        form.addRow("gamma", self.gamma)
        form.addRow("max blur", self.max_blur)
        form.addRow("focal length", focal_row)
        form.addRow("", self.focal_hint)
        form.addRow("profiles", self.profiles_combo.native)
        form.addRow("", self.preview_check)
        layout = QVBoxLayout()
        layout.addLayout(form)
        layout.addWidget(advanced)
        layout.addWidget(self.controls)
        layout.addWidget(self.plot_section)
        layout.addWidget(self.save_button)
        layout.addStretch(1)
        dock_layout(self, layout)

        self.run_button.clicked.connect(self.run)
        self.save_button.clicked.connect(lambda: self.save_motion())
        self.image_combo.changed.connect(self._on_image_changed)
        self.method_combo.changed.connect(self._on_method_changed)
        self.focal_auto.toggled.connect(self._on_focal_auto)
        self.reset_choices()
        self._on_method_changed(self.method_combo.value)
        self._plot_motion(None)

    # -- choices ---------------------------------------------------------------------------
    def _image_choices(self, _widget=None):
        return image_layers(self._viewer)

    def _profile_choices(self, _widget=None):
        return [_AUTO_PROFILES] + [
            (layer.name, layer) for layer in self._viewer.layers
            if isinstance(layer, Shapes) and layer.metadata.get(PROFILES_KEY) is not None]

    def reset_choices(self, *_args) -> None:
        """Refresh the layer choices (napari calls this when layers change)."""
        self.image_combo.reset_choices()
        self.profiles_combo.reset_choices()
        self._on_image_changed(self.image_combo.value, keep_status=True)

    def _on_image_changed(self, layer, keep_status: bool = False) -> None:
        if not keep_status:  # the status line described the previous image's run
            self.runner.clear_status()
        if layer is None:
            self.focal_hint.setText("")
            return
        self._update_focal_hint()
        # offer the image's own (hand-edited) profiles once; a later choice of the user sticks
        own = next((shapes for _name, shapes in self._profile_choices()[1:]
                    if shapes.metadata.get(SOURCE_KEY) == layer.name), None)
        if own is not None and own != self._suggested:
            self._suggested = own
            self.profiles_combo.value = own

    def _on_method_changed(self, method) -> None:
        uses_profiles = method != "xu"
        self.profiles_combo.enabled = uses_profiles
        self.lambda_ip.setEnabled(method == "xu+ep")
        self.preview_check.setEnabled(method != "ep")

    def _on_focal_auto(self, on: bool) -> None:
        self.focal_spin.setEnabled(not on)
        self._update_focal_hint()

    def _update_focal_hint(self) -> None:
        layer = self.image_combo.value
        if layer is None:
            return
        if self.focal_auto.isChecked():
            focal, source = focal_from_layer(layer)
            value = focal if focal is not None else default_focal_px(image_shape(layer))
            self.focal_spin.setValue(value)
            self.focal_hint.setText(f"auto: {value:.1f} px, {source}")
        else:
            self.focal_hint.setText("manual (pixels of this image)")

    # -- run -------------------------------------------------------------------------------
    def run(self) -> None:
        """Estimate the camera motion of the chosen image in a worker thread."""
        image = self.image_combo.value
        if image is None:
            self.runner.refuse("choose an image layer first")
            return
        method, model = self.method_combo.value, self.model_combo.value
        try:
            data = snapshot_image(image)
            curve, reason = self.gamma.resolve(image, data)
            profiles = self._chosen_profiles(data.shape) if method != "xu" else None
        except ValueError as err:
            self.runner.refuse(first_line(err))
            return
        if self.focal_auto.isChecked():
            focal_px = focal_from_layer(image)[0]
        else:
            focal_px = float(self.focal_spin.value())
        max_blur = self.max_blur.value_for(data.shape)  # None on auto: the engine measures
        preview = self.preview_check.isChecked() and method != "ep"
        gen = estimate_in_linear_light(
            data, curve, reason, method, model, max_blur, focal_px, profiles,
            lambda_w=self.lambda_w.value(), lambda_ip=self.lambda_ip.value(),
            lambda_f=self.lambda_f.value(), n_iter=self.n_iter.value(),
            max_side=self.max_side.value(), preview=preview, rng=self.seed.value())
        self.runner.start(gen, on_result=partial(self._show_result, image,
                                                 self._profiles_gamma(profiles)),
                          on_preview=partial(self._show_preview, image), on_end=self._end)

    def cancel(self) -> None:
        """Stop the running estimation (nothing is added)."""
        self.runner.cancel()

    def _chosen_profiles(self, shape) -> EdgeProfiles | None:
        layer = self.profiles_combo.value
        if layer is None:
            return None
        profiles = layer.metadata.get(PROFILES_KEY)
        if isinstance(profiles, dict):
            profiles = EdgeProfiles.from_dict(profiles)
        if not isinstance(profiles, EdgeProfiles):
            raise ValueError(f"layer {layer.name!r} holds no edge profiles")
        if profiles.image_shape is not None and tuple(profiles.image_shape) != tuple(shape[:2]):
            raise ValueError(
                f"the profiles in {layer.name!r} were taken on a "
                f"{profiles.image_shape[0]}x{profiles.image_shape[1]} image; this image is "
                f"{shape[0]}x{shape[1]}")
        return profiles

    def _profiles_gamma(self, profiles) -> str | None:
        """The curve the chosen profiles layer was taken through (None: detected
        automatically, or not recorded)."""
        layer = self.profiles_combo.value
        if profiles is None or layer is None:
            return None
        settings = layer.metadata.get(PROFILE_SETTINGS_KEY)
        return settings.get("gamma") if isinstance(settings, dict) else None

    # -- main-thread handlers -----------------------------------------------------------------
    def _show_preview(self, image: Image, record: Progress) -> None:
        latent = record.preview
        if latent is None:
            return
        where = resampled_kwargs(image, latent.shape)
        if self._preview is None or self._preview not in self._viewer.layers:
            self._preview = Image(latent, name=f"{image.name} latent (preview)",
                                  colormap="gray", contrast_limits=(0.0, 1.0),
                                  opacity=PREVIEW_OPACITY, blending="translucent",
                                  metadata={SOURCE_KEY: image.name}, **where)
            self._insert_above(image, self._preview)
        else:
            self._preview.data = latent
            self._preview.scale = where["scale"]
            self._preview.translate = where["translate"]

    def _insert_above(self, image: Image, layer: Image) -> None:
        """Add ``layer`` just above ``image``, leaving the user's layer selection alone."""
        layers = self._viewer.layers
        selected, active = set(layers.selection), layers.selection.active
        index = layers.index(image) + 1 if image in layers else len(layers)
        layers.insert(index, layer)
        layers.selection.clear()
        layers.selection.update(selected)
        if active is not None and active in layers:
            layers.selection.active = active

    def _show_result(self, image: Image, profiles_gamma: str | None, result: Estimated) -> str:
        estimate, latent = result.estimate, result.latent
        motion, info = estimate.motion, estimate.info
        summary = {"method": info.method, "model": info.model, "max_blur": info.max_blur,
                   "focal_px": info.focal_px, "n_profiles": info.n_profiles,
                   "seconds": round(info.seconds, 3), "converged": info.converged,
                   "message": info.message, "blur_size": info.blur_size,
                   "edge_spread": info.edge_spread, "profile_misfit": info.profile_misfit,
                   "gamma": info.gamma, "gamma_reason": info.gamma_reason}
        meta = {MOTION_KEY: motion.to_dict(), SOURCE_KEY: image.name, ESTIMATE_KEY: summary}
        glyphs = psf_glyphs(motion, psf_grid(motion.image_shape))
        self._viewer.add_layer(Image(
            glyphs.rgba, name=f"{image.name} PSF field", rgb=True, blending="translucent",
            contrast_limits=(0.0, 1.0),
            metadata={**meta, ZOOM_KEY: glyphs.enlargement},
            **resampled_kwargs(image, glyphs.rgba.shape[:2])))
        if latent is not None:  # encoded as the photo is
            latent_name = f"{image.name} latent"
            where = resampled_kwargs(image, latent.shape)
            if self._preview is not None and self._preview in self._viewer.layers:
                layer, self._preview = self._preview, None  # the preview becomes the result
                layer.data = latent
                layer.scale, layer.translate = where["scale"], where["translate"]
                layer.name = latent_name
                layer.opacity = 1.0
                layer.metadata.update(meta)
            else:
                layer = Image(latent, name=latent_name, colormap="gray",
                              contrast_limits=(0.0, 1.0), metadata=dict(meta), **where)
                self._viewer.add_layer(layer)
            layer.visible = False
        self.last_motion, self.last_estimate = motion, estimate
        self._last_name = image.name
        self.save_button.setEnabled(True)
        self._plot_motion(motion)
        # what auto measured, and the curve unless it is the layers' default (linear, as
        # chosen)
        measured = ""
        if info.blur_size:
            measured = f"; {measured_note(info.max_blur, info.blur_size)}"
            self.max_blur.show_measured(image, info.max_blur)
        gamma = ("" if info.gamma == "linear" and info.gamma_reason == GIVEN
                 else f"; {gamma_note(info.gamma, info.gamma_reason)}")
        if profiles_gamma is not None and profiles_gamma != info.gamma:
            gamma += f"; the edge profiles were taken with gamma {profiles_gamma}"
        if info.no_blur:
            return (f"no blur found ({info.seconds:.1f} s): the motion is the identity. If the "
                    f"photo is blurred, try a larger max blur or another model"
                    f"{measured}{gamma}")
        text = (f"{motion.n_poses} poses, blur extent {motion.blur_extent():.1f} px (longest "
                f"side of the PSFs) "
                f"({info.seconds:.1f} s); PSF field: each PSF drawn "
                f"{glyphs.enlargement}x its size")
        if info.message.startswith("fell back"):
            text += f"; {info.message.split(';')[0]}"
        if info.profile_model():  # which profile model EpAlone kept
            text += f"; fitted as {info.profile_model()}"
        return text + measured + gamma

    def _end(self, outcome: str) -> None:
        # the live preview is transient: a cancelled or failed run leaves no layer behind
        if outcome != "done" and self._preview is not None:
            if self._preview in self._viewer.layers:
                self._viewer.layers.remove(self._preview)
        self._preview = None

    # -- results ---------------------------------------------------------------------------
    def save_motion(self, path: str | Path | None = None) -> Path | None:
        """Write the last estimated motion as a JSON motion file (asks where when no ``path``)."""
        if self.last_motion is None:
            show_error("Camera motion: nothing to save; run an estimation first")
            return None
        if path is None:
            path, _ = QFileDialog.getSaveFileName(self, "Save camera motion",
                                                  f"{self._last_name}-motion.json",
                                                  "JSON files (*.json)")
            if not path:
                return None
        path = Path(path)
        try:
            info = self.last_estimate.info
            self.last_motion.save(path, estimated_by=info.method,
                                  profile_misfit=info.profile_misfit)
        except OSError as err:
            show_error(f"Camera motion: cannot save {path}: {first_line(err)}")
            return None
        show_info(f"Camera motion: saved to {path}")
        return path

    def _plot_motion(self, motion: CameraMotion | None) -> None:
        """The motion density function in pose space: marker area = weight."""
        if not self._has_plot:
            return
        fg, bg = self._colours
        figure = self.canvas.figure
        figure.clear()  # drops the previous run's axes and colour bar
        ax = figure.add_subplot()
        style_axes(ax, fg, bg)
        if motion is None:
            ax.set_title("camera poses (run an estimation)", fontsize=8)
            self._redraw()
            return
        names = param_names(motion.model)
        poses = np.array(motion.poses, float)
        labels = []
        for k, name in enumerate(names):
            if name.startswith("theta"):
                poses[:, k] *= 1e3
                labels.append(f"{name} (mrad)")
            else:
                labels.append(f"{name} (px)")
        weights = np.asarray(motion.weights, float)
        sizes = 4 + 80 * weights / weights.max()
        order = np.argsort(weights)
        if poses.shape[1] == 3:
            points = ax.scatter(poses[order, 0], poses[order, 1], s=sizes[order],
                                c=poses[order, 2], cmap="viridis", edgecolors="none")
            bar = figure.colorbar(points, ax=ax, shrink=0.9)
            bar.set_label(labels[2], color=fg, fontsize=8)
            bar.ax.tick_params(colors=fg, labelsize=7)
            bar.outline.set_edgecolor(fg)
        else:
            ax.scatter(poses[order, 0], poses[order, 1], s=sizes[order], color="#ff8c00",
                       edgecolors="none")
        ax.set_xlabel(labels[0], fontsize=8)
        ax.set_ylabel(labels[1], fontsize=8)
        ax.set_title(f"{motion.n_poses} camera poses (dot area = time spent)", fontsize=8)
        ax.relim()
        ax.autoscale_view()
        ax.set_aspect("equal", adjustable="datalim")
        self._redraw()


def _float_spin(value: float, low: float, high: float, decimals: int, tip: str) -> QDoubleSpinBox:
    spin = QDoubleSpinBox()
    spin.setRange(low, high)
    spin.setDecimals(decimals)
    spin.setStepType(QDoubleSpinBox.StepType.AdaptiveDecimalStepType)
    spin.setValue(value)
    spin.setToolTip(tip)
    return spin


def _int_spin(value: int, low: int, high: int, tip: str) -> QSpinBox:
    spin = QSpinBox()
    spin.setRange(low, high)
    spin.setValue(value)
    spin.setToolTip(tip)
    return spin
