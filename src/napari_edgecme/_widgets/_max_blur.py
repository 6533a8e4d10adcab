"""The "max blur" control: the largest blur extent to look for, auto or a value."""

from __future__ import annotations

from qtpy.QtWidgets import QCheckBox, QDoubleSpinBox, QHBoxLayout, QWidget

from ..core.estimate import default_max_blur
from ._layers import image_shape

__all__ = ["MaxBlurControl"]


class MaxBlurControl(QWidget):
    """Largest blur extent to look for, in pixels: "auto" (the engine's default) or a value.

    Auto is :func:`~napari_edgecme.core.estimate.default_max_blur` of the chosen
    image (4% of its longer side, at least 15 px): the one computation every widget
    shows and runs with.

    Parameters
    ----------
    image_combo : magicgui ComboBox, optional
        The widget's image choice: while on auto, the value shown follows it.
    """

    def __init__(self, image_combo=None, parent: QWidget | None = None):
        super().__init__(parent)
        self._combo = image_combo
        self.auto = QCheckBox("auto")
        self.auto.setChecked(True)
        self.auto.setToolTip("Auto: 4% of the image's longer side, at least 15 px "
                             "(the engine's default)")
        self.spin = QDoubleSpinBox()
        self.spin.setRange(1.0, 500.0)
        self.spin.setDecimals(1)
        self.spin.setSingleStep(1.0)
        self.spin.setSuffix(" px")
        self.spin.setValue(15.0)
        self.spin.setEnabled(False)
        self.spin.setToolTip("The longest blur streak to look for, in image pixels (the "
                             "side of the largest local PSF's bounding box); larger is "
                             "slower and sees more clutter")
        self.auto.toggled.connect(self._on_auto)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.spin, 1)
        layout.addWidget(self.auto)
        if image_combo is not None:
            image_combo.changed.connect(lambda _value: self.refresh())
            self.refresh()

    def _on_auto(self, on: bool) -> None:
        self.spin.setEnabled(not on)
        self.refresh()

    def refresh(self) -> None:
        """While on auto, show the value auto resolves to for the chosen image."""
        layer = None if self._combo is None else self._combo.value
        if layer is not None:
            self.show_default_for(image_shape(layer))

    def show_default_for(self, shape) -> None:
        """While on auto, display the value auto resolves to for an image of ``shape``."""
        if self.auto.isChecked() and shape is not None:
            self.spin.setValue(default_max_blur(shape))

    def value_for(self, shape) -> float:
        """The max blur to use for an image of ``shape`` (pixels)."""
        if self.auto.isChecked():
            return default_max_blur(shape)
        return float(self.spin.value())
