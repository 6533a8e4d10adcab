"""The "max blur" control: the largest blur extent to look for, auto or a value."""

from __future__ import annotations

from qtpy.QtWidgets import QCheckBox, QDoubleSpinBox, QHBoxLayout, QWidget

from ..core.blur_size import MARGIN
from ..core.estimate import default_max_blur
from ._layers import image_shape

__all__ = ["AUTO_TEXT", "MaxBlurControl", "measured_note"]

#: What the spin box shows (disabled) while on auto: there is no value until a run.
AUTO_TEXT = "measured when run"
#: The spin box's tooltip on auto, and with a value.
AUTO_TIP = ("Auto: measured from the image's edge profiles when run; the status line says "
            "what was found. Uncheck auto to give a value")
VALUE_TIP = ("The longest blur streak to look for, in image pixels (the side of the largest "
             "local PSF's bounding box); larger is slower and sees more clutter")


def measured_note(max_blur: float, blur_size: str) -> str:
    """``"max blur 131 px (measured: blur about 65 px, from 28 edge profiles)"``, as the
    command line says it (``blur_size``: the measurement's message)."""
    return f"max blur {max_blur:.0f} px (measured: {blur_size})"


class MaxBlurControl(QWidget):
    """Largest blur extent to look for, in pixels: "auto" (measured from the image) or a value.

    On auto a run measures the blur from the image's edge profiles in its worker
    (:func:`~napari_edgecme.core.blur_size.measure_blur_extent`, searching up to
    :data:`~napari_edgecme.core.blur_size.MARGIN` times what it finds,
    :func:`~napari_edgecme.core.blur_size.max_blur_for`), falling back to
    :func:`~napari_edgecme.core.estimate.default_max_blur` (4% of the longer side, at
    least 15 px) when too few edges are found. So the value is not known before the
    run: the spin box is disabled and says :data:`AUTO_TEXT`, and the widget reports the
    measurement when the run is done (:meth:`show_measured`); unchecking auto then starts
    from the measured value (or, before any run on the chosen image, from that default).

    Parameters
    ----------
    image_combo : magicgui ComboBox, optional
        The widget's image choice (where a switch from auto to a value starts).
    """

    def __init__(self, image_combo=None, parent: QWidget | None = None):
        super().__init__(parent)
        self._combo = image_combo
        self._measured: tuple | None = None  # (image layer, max blur) of the last run on auto
        self.auto = QCheckBox("auto")
        self.auto.setChecked(True)
        self.auto.setToolTip(
            f"Auto: measured from the image's edge profiles when run (the search reaches "
            f"{MARGIN:g}x the blur found); with too few straight edges, 4% of the longer "
            f"side, at least 15 px. The run's status line says what was measured")
        self.spin = QDoubleSpinBox()
        self.spin.setRange(1.0, 500.0)
        self.spin.setDecimals(1)
        self.spin.setSingleStep(1.0)
        self.spin.setSuffix(" px")
        self.spin.setSpecialValueText(AUTO_TEXT)  # shown at the minimum, 0, on auto only
        self.auto.toggled.connect(self._on_auto)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.spin, 1)
        layout.addWidget(self.auto)
        self._on_auto(True)

    @property
    def is_auto(self) -> bool:
        """True when a run measures the max blur from the image."""
        return self.auto.isChecked()

    def _on_auto(self, on: bool) -> None:
        self.spin.setEnabled(not on)
        if on:
            self.spin.setMinimum(0.0)
            self.spin.setValue(0.0)  # shows AUTO_TEXT
            self.spin.setToolTip(AUTO_TIP)
        else:
            self.spin.setMinimum(1.0)
            self.spin.setValue(self._starting_value())
            self.spin.setToolTip(VALUE_TIP)

    def _starting_value(self) -> float:
        """Where a switch to a value starts: the last measurement, else the default."""
        layer = None if self._combo is None else self._combo.value
        measured = self.measured_for(layer)
        if measured is not None:
            return measured
        shape = None if layer is None else image_shape(layer)
        return 15.0 if shape is None else default_max_blur(shape)

    def show_measured(self, layer, max_blur: float) -> None:
        """A run on auto measured ``max_blur`` (px) on image ``layer``: unchecking auto
        while that image is chosen starts from it."""
        self._measured = (layer, float(max_blur))

    def measured_for(self, layer) -> float | None:
        """The max blur the last run on auto measured on ``layer``, or None."""
        if self._measured is None or layer is None or not (self._measured[0] == layer):
            return None
        return self._measured[1]

    def value_for(self, shape) -> float | None:
        """The max blur a run on an image of ``shape`` is given (pixels), or None on auto:
        measured from the image in the run's worker."""
        if self.auto.isChecked():
            return None
        return float(self.spin.value())

    def value_or_default_for(self, layer) -> float:
        """A max blur for work on image ``layer`` that cannot wait for a measurement (a
        line drawn by hand): the value, or on auto the last measurement on that image,
        else the default (:func:`~napari_edgecme.core.estimate.default_max_blur`)."""
        value = self.value_for(None)
        if value is not None:
            return value
        measured = self.measured_for(layer)
        return measured if measured is not None else default_max_blur(image_shape(layer))
