"""The "Deconvolution" widget: restore a blurred image with a known camera motion.

Runs :func:`~napari_edgecme.core.deconv.iter_deconvolve` (hyper-Laplacian,
Richardson-Lucy or Wiener with the spatially varying blur) in a worker thread. The
motion comes from a layer's metadata (``metadata["edgecme_motion"]``, as written by
the "Camera motion" widget or a sample with its true motion) or from a JSON motion
file. The result is a new float32 layer ``"<image> deblurred"`` with the input's
scale and translate; the input layer is never modified.
"""

from __future__ import annotations

import logging
from functools import partial
from pathlib import Path

import napari
import numpy as np
from magicgui.widgets import ComboBox
from napari.layers import Image
from napari.utils.notifications import show_error, show_info
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

from ..core.deconv import DEFAULTS, iter_deconvolve
from ..core.motion import CameraMotion
from ._common import (
    MOTION_KEY,
    SOURCE_KEY,
    EngineRunner,
    first_line,
    image_layers,
    motion_from,
    snapshot_image,
    spatial_kwargs,
)

__all__ = ["METHOD_CHOICES", "DeconvolutionWidget"]

logger = logging.getLogger(__name__)

#: Deconvolution methods as shown, with the engine's names.
METHOD_CHOICES = [("Hyper-Laplacian (Krishnan-Fergus)", "hyperlaplacian"),
                  ("Richardson-Lucy", "rl"), ("Wiener", "wiener")]
#: Metadata key of the deconvolution settings of a restored layer.
DECONV_KEY = "edgecme_deconvolution"


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
        self._file_motion: tuple[str, CameraMotion] | None = None
        self.last_layer: Image | None = None

        self.image_combo = ComboBox(label="image", choices=self._image_choices)
        self.motion_combo = ComboBox(label="motion", choices=self._motion_choices)
        self.motion_combo.native.setToolTip(
            "A layer carrying a camera motion (e.g. the PSF field of 'Camera motion', or a "
            "sample with its true motion), or a motion file loaded with 'Load JSON…'")
        self.load_button = QPushButton("Load JSON…")
        self.load_button.setToolTip("Read a motion file (edgecme-motion JSON)")
        self.method_combo = ComboBox(label="method", choices=METHOD_CHOICES,
                                     value="hyperlaplacian")

        hl = DEFAULTS["hyperlaplacian"]
        self.lam = QDoubleSpinBox()
        self.lam.setRange(1.0, 1e7)
        self.lam.setDecimals(0)
        self.lam.setStepType(QDoubleSpinBox.StepType.AdaptiveDecimalStepType)
        self.lam.setValue(hl["lam"])
        self.lam.setToolTip("data weight λ for images in [0, 1]: raise it for clean photos, "
                            "lower it for noisy ones")
        self.alpha_combo = ComboBox(choices=[("2/3", 2.0 / 3.0), ("1/2", 0.5)],
                                    value=hl["alpha"])
        self.alpha_combo.native.setToolTip("exponent of the hyper-Laplacian prior")
        self.solver_combo = ComboBox(choices=[("patch-wise Fourier (fast)", "fourier"),
                                              ("conjugate gradients (exact)", "cg")],
                                     value=hl["solver"])
        self.rl_iterations = QSpinBox()
        self.rl_iterations.setRange(1, 100000)
        self.rl_iterations.setValue(DEFAULTS["rl"]["iterations"])
        self.rl_iterations.setToolTip("Richardson-Lucy iterations (more: sharper and noisier)")
        self.nsr = QDoubleSpinBox()
        self.nsr.setRange(1e-6, 10.0)
        self.nsr.setDecimals(6)
        self.nsr.setStepType(QDoubleSpinBox.StepType.AdaptiveDecimalStepType)
        self.nsr.setValue(DEFAULTS["wiener"]["nsr"])
        self.nsr.setToolTip("noise-to-signal ratio")

        self.params = QStackedWidget()
        for rows in ([("λ", self.lam), ("α", self.alpha_combo.native),
                      ("solver", self.solver_combo.native)],
                     [("iterations", self.rl_iterations)],
                     [("noise/signal", self.nsr)]):
            page = QWidget()
            page_form = QFormLayout(page)
            page_form.setContentsMargins(0, 0, 0, 0)
            for label, widget in rows:
                page_form.addRow(label, widget)
            self.params.addWidget(page)

        self.run_button = QPushButton("Run")
        self.cancel_button = QPushButton("Cancel")
        self.status = QLabel("")
        self.status.setWordWrap(True)

        motion_row = QHBoxLayout()
        motion_row.addWidget(self.motion_combo.native, 1)
        motion_row.addWidget(self.load_button)
        form = QFormLayout()
        form.addRow("image", self.image_combo.native)
        form.addRow("motion", motion_row)
        form.addRow("method", self.method_combo.native)
        run_row = QHBoxLayout()
        run_row.addWidget(self.run_button)
        run_row.addWidget(self.cancel_button)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(self.params)
        layout.addLayout(run_row)
        layout.addWidget(self.status)
        layout.addStretch(1)

        self.runner = EngineRunner(self, "Deconvolution", self.run_button, self.cancel_button,
                                   self.status)
        self.run_button.clicked.connect(self.run)
        self.load_button.clicked.connect(lambda: self.load_motion())
        self.method_combo.changed.connect(self._on_method_changed)
        self.image_combo.changed.connect(lambda _value: self.motion_combo.reset_choices())
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
            motion = CameraMotion.load(path)
        except ValueError as err:
            show_error(f"Deconvolution: {first_line(err)}")
            return None
        self._file_motion = (Path(path).name, motion)
        self.motion_combo.reset_choices()
        self.motion_combo.value = motion
        show_info(f"Deconvolution: loaded {Path(path).name} ({motion.model} motion, "
                  f"{motion.n_poses} poses, {motion.image_shape[0]}x{motion.image_shape[1]} "
                  "image)")
        return motion

    def parameters(self) -> dict:
        """The chosen method's parameters, as :func:`iter_deconvolve` takes them."""
        method = self.method_combo.value
        if method == "hyperlaplacian":
            return {"lam": float(self.lam.value()), "alpha": float(self.alpha_combo.value),
                    "solver": self.solver_combo.value}
        if method == "rl":
            return {"iterations": int(self.rl_iterations.value())}
        return {"nsr": float(self.nsr.value())}

    def run(self) -> None:
        """Deconvolve the chosen image with the chosen motion in a worker thread."""
        image = self.image_combo.value
        if image is None:
            show_error("Deconvolution: choose an image layer first")
            return
        source = self.motion_combo.value
        if source is None:
            show_error("Deconvolution: choose a motion: a layer that carries one "
                       "(run 'Camera motion' first) or a JSON file ('Load JSON…')")
            return
        try:
            data = snapshot_image(image)
            motion = motion_from(source)
        except ValueError as err:
            show_error(f"Deconvolution: {first_line(err)}")
            return
        method, params = self.method_combo.value, self.parameters()
        gen = iter_deconvolve(data, motion, method, **params)
        self.runner.start(gen, on_result=partial(self._show_result, image, motion, method,
                                                 params))

    def cancel(self) -> None:
        """Stop the running deconvolution (nothing is added)."""
        self.runner.cancel()

    # -- main-thread handler -----------------------------------------------------------------
    def _show_result(self, image: Image, motion: CameraMotion, method: str, params: dict,
                     restored: np.ndarray) -> str:
        restored = np.asarray(restored, dtype=np.float32)
        rgb = restored.ndim == 3
        extra = {} if rgb else {"colormap": image.colormap.name}
        layer = Image(restored, name=f"{image.name} deblurred", rgb=rgb,
                      contrast_limits=(0.0, 1.0),
                      metadata={MOTION_KEY: motion.to_dict(), SOURCE_KEY: image.name,
                                DECONV_KEY: {"method": method, **params}},
                      **extra, **spatial_kwargs(image))
        self._viewer.add_layer(layer)
        self.last_layer = layer
        return f"added {layer.name!r}"
