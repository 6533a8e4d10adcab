"""The "gamma" control of the widgets, and the runs in linear light it sets up.

Blur adds light linearly, so estimation and deconvolution belong in linear light; a
photo stores its values through a transfer curve (sRGB for an 8-bit camera photo). The
widgets take a layer's values as linear light unless told otherwise (``linear``, the
default for layers): :class:`GammaControl` lets the user say ``sRGB``, a power law
(``linear = value ** exponent``) or ``auto``, which asks
:func:`~napari_edgecme.core.photometry.decide_gamma` about the file the layer was
opened from (napari's ``layer.source.path``) -- auto means nothing for a layer that was
not read from a file, so it is offered only for one that was. The control shows the
curve a run will use and why, as the command line prints it (``gamma: srgb (8-bit PNG
with an sRGB chunk)``).

:func:`estimate_in_linear_light` and :func:`deconvolve_in_linear_light` are the
generators the widgets hand to their :class:`~._runner.EngineRunner`: created on the
main thread from a snapshot, run in the worker thread, they decode the snapshot, drive
the engine's ``iter_*`` generator on the linear image and encode what is shown (the
restored image, the latent image and its previews) as the input was, as
:func:`~napari_edgecme.core.deblur.deblur` does.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from napari.layers import Image
from qtpy.QtCore import Signal
from qtpy.QtWidgets import QComboBox, QHBoxLayout, QLabel, QLineEdit, QVBoxLayout, QWidget

from ..core._validation import first_line
from ..core.deblur import record_gamma, restoring_params
from ..core.deconv import iter_deconvolve
from ..core.estimate import MotionEstimate, iter_estimate_motion
from ..core.photometry import Gamma, decide_gamma, parse_gamma
from ..core.progress import Progress

__all__ = ["GAMMA_CHOICES", "Estimated", "GammaControl", "deconvolve_in_linear_light",
           "estimate_in_linear_light", "gamma_note", "layer_path"]

#: The choices as shown, with what they mean (``"power"``: the exponent box says which).
GAMMA_CHOICES = [("linear (values are light)", "linear"), ("sRGB", "srgb"),
                 ("power law", "power"), ("auto (from the file)", "auto")]
#: The exponent a power law starts with (a "gamma 2.2" file).
DEFAULT_EXPONENT = "2.2"
#: Why a chosen (not decided) curve is used: the engine's word for it (``deblur``).
GIVEN = "given"
#: Why ``auto`` cannot decide for a layer that was not read from a file.
NO_FILE = "auto: the layer was not opened from a file"


def layer_path(layer) -> Path | None:
    """The file an image layer was opened from (napari's ``layer.source.path``), or None."""
    path = getattr(getattr(layer, "source", None), "path", None)
    return Path(path) if path else None


def gamma_note(curve: Gamma | str, reason: str) -> str:
    """``"gamma: srgb (8-bit PNG with an sRGB chunk)"``, as the command line says it
    (``curve``: a :class:`Gamma` or its name)."""
    return f"gamma: {curve} ({reason})"


class GammaControl(QWidget):
    """The transfer curve of the chosen image layer: linear, sRGB, a power law or auto.

    Parameters
    ----------
    image_combo : magicgui ComboBox
        The widget's image choice: auto, and the line under the control, follow it.

    Attributes
    ----------
    combo : QComboBox
        The choice (its data: ``"linear"``, ``"srgb"``, ``"power"``, ``"auto"``).
    exponent : QLineEdit
        The power law's exponent (``linear = value ** exponent``), as typed.
    hint : QLabel
        What a run will use and why, or why the setting is refused.
    changed : Signal
        Emitted after the hint has followed a new image or setting.
    """

    changed = Signal()

    def __init__(self, image_combo, parent: QWidget | None = None):
        super().__init__(parent)
        self._combo_images = image_combo
        self.combo = QComboBox()
        for label, value in GAMMA_CHOICES:
            self.combo.addItem(label, value)
        self.combo.setToolTip(
            "How the image's values encode light. Blur adds light, so with sRGB or a power "
            "law the motion is estimated and the image deconvolved in linear light, and the "
            "result is encoded back as the input was. Linear: the values are light already "
            "(the default for layers: renders, scientific data). sRGB: 8-bit camera photos. "
            "Power law: linear = value ^ exponent. Auto: decided from the file the layer was "
            "opened from (its colour tags, bit depth and camera)")
        self.exponent = QLineEdit(DEFAULT_EXPONENT)
        self.exponent.setMaximumWidth(70)
        self.exponent.setToolTip("The power law's exponent (display gamma): linear = value ^ "
                                 "exponent; 2.2 for a 'gamma 2.2' file; a number > 0")
        self.hint = QLabel("")
        self.hint.setWordWrap(True)
        row = QHBoxLayout()
        row.setContentsMargins(0, 0, 0, 0)
        row.addWidget(self.combo, 1)
        row.addWidget(self.exponent)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addLayout(row)
        layout.addWidget(self.hint)
        self.combo.currentIndexChanged.connect(lambda _index: self.refresh())
        self.exponent.textChanged.connect(lambda _text: self.refresh())
        image_combo.changed.connect(lambda _value: self.refresh())
        self.refresh()

    @property
    def choice(self) -> str:
        """``"linear"``, ``"srgb"``, ``"power"`` or ``"auto"``."""
        return self.combo.currentData()

    @choice.setter
    def choice(self, value: str) -> None:
        index = self.combo.findData(value)
        if index < 0:
            raise ValueError(f"gamma choice must be one of "
                             f"{[v for _label, v in GAMMA_CHOICES]}; got {value!r}")
        self.combo.setCurrentIndex(index)

    def setting(self) -> str:
        """The choice as ``gamma=`` takes it: ``"linear"``, ``"srgb"``, ``"auto"`` or the
        exponent as typed (``"2.2"``)."""
        choice = self.choice
        return self.exponent.text().strip() if choice == "power" else choice

    def resolve(self, layer: Image | None = None, data: np.ndarray | None = None
                ) -> tuple[Gamma, str]:
        """The curve a run on ``layer`` uses, and why.

        Parameters
        ----------
        layer : Image, optional
            The image layer (default: the chosen one); auto reads its source file.
        data : ndarray, optional
            Its pixels as they will be used (default: the layer's data); their dtype is
            the bit depth auto goes by.

        Returns
        -------
        curve : Gamma
        reason : str
            ``"given"`` for a chosen curve, else :func:`decide_gamma`'s reason (or
            :data:`NO_FILE`).

        Raises
        ------
        ValueError
            One line: a power-law exponent that is not a number > 0.
        """
        curve = parse_gamma(self.setting())
        if curve != "auto":
            return curve, GIVEN
        layer = self._combo_images.value if layer is None else layer
        path = layer_path(layer)
        if path is None:
            return Gamma.linear(), NO_FILE
        if data is None:
            data = np.asarray(layer.data[:1, :1]) if layer is not None else None
        return decide_gamma(path, data)

    def refresh(self) -> None:
        """Follow the chosen image and setting: offer auto only for a layer read from a
        file, and say what a run will use and why (or why it will be refused)."""
        layer = self._combo_images.value
        has_file = layer_path(layer) is not None
        item = self.combo.model().item(self.combo.findData("auto"))
        if item is not None:
            item.setEnabled(has_file or self.choice == "auto")
            item.setToolTip("" if has_file else "Auto decides from the file a layer was "
                                                "opened from; this layer was not")
        self.exponent.setEnabled(self.choice == "power")
        if layer is None:
            self.hint.setText("")
        else:
            try:
                self.hint.setText(gamma_note(*self.resolve(layer)))
            except ValueError as err:
                self.hint.setText(f"not usable: {first_line(err)}")
        self.changed.emit()


@dataclass(frozen=True)
class Estimated:
    """What :func:`estimate_in_linear_light` returns.

    Attributes
    ----------
    estimate : MotionEstimate
        As the engine returned it (its latent in linear light), with ``info.gamma`` and
        ``info.gamma_reason`` recorded (:func:`~napari_edgecme.core.deblur.record_gamma`).
    latent : ndarray or None
        The latent image encoded as the input was, for display (None for EpAlone).
    """

    estimate: MotionEstimate
    latent: np.ndarray | None


def estimate_in_linear_light(data: np.ndarray, curve: Gamma, reason: str, *args, **kwargs):
    """:func:`~napari_edgecme.core.estimate.iter_estimate_motion` on ``data`` in linear light.

    A generator, for the worker thread: it decodes ``data`` through ``curve``, yields the
    engine's progress records (their previews encoded back through ``curve``), records the
    curve in ``estimate.info`` and returns an :class:`Estimated`.

    Parameters
    ----------
    data : ndarray of shape (M, N) or (M, N, 3)
        The image's values as stored (a snapshot).
    curve : Gamma
        The transfer curve they were stored through.
    reason : str
        Why this curve (``"given"``, or ``decide_gamma``'s reason).
    *args, **kwargs
        As :func:`~napari_edgecme.core.estimate.iter_estimate_motion`, after the image.
    """
    work = data if curve.is_linear else curve.decode(data)
    gen = iter_estimate_motion(work, *args, **kwargs)
    try:
        while True:
            try:
                record = next(gen)
            except StopIteration as stop:
                estimate = stop.value
                break
            if (not curve.is_linear and isinstance(record, Progress)
                    and record.preview is not None):
                record = replace(record, preview=curve.encode(record.preview))
            yield record
    finally:
        gen.close()  # a cancelled run (this generator closed) ends the engine's too
    record_gamma(estimate.info, curve, reason)
    latent = estimate.latent
    if latent is not None and not curve.is_linear:
        latent = curve.encode(latent)
    return Estimated(estimate, latent)


def deconvolve_in_linear_light(data: np.ndarray, curve: Gamma, motion, method: str, *,
                               estimated_by: str | None = None,
                               profile_misfit: float | None = None, **params):
    """:func:`~napari_edgecme.core.deconv.iter_deconvolve` on ``data`` in linear light.

    A generator, for the worker thread: it decodes ``data`` through ``curve``, yields the
    engine's progress records and returns the restored image encoded through ``curve``
    (negative ringing clipped first), float32 on [0, 1] for a curve other than linear.

    Parameters
    ----------
    data : ndarray of shape (M, N) or (M, N, 3)
        The image's values as stored (a snapshot).
    curve : Gamma
    motion, method, **params
        As :func:`~napari_edgecme.core.deconv.iter_deconvolve`, after the image.
    estimated_by : {"ep", "xu", "xu+ep"}, optional
        The method that estimated ``motion``, when known: its restoration's parameters
        as :func:`~napari_edgecme.core.deblur.restoring_params` sets them (as ``deblur``
        restores it).
    profile_misfit : float, optional
        That estimate's edge-profile misfit, when known (EpAlone's restoration depends on
        it: :func:`~napari_edgecme.core.deblur.ep_prior_factor`).
    """
    linear = data if curve.is_linear else curve.decode(data)
    if estimated_by is not None:
        params = restoring_params(linear, estimated_by, method, params,
                                  profile_misfit=profile_misfit)
    restored = yield from iter_deconvolve(linear, motion, method, **params)
    return restored if curve.is_linear else curve.encode(restored)
