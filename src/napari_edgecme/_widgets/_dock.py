"""Dock-widget plumbing: the scrolling layout, tabbing the plugin's docks together, and
model-event connections cut when a widget is destroyed."""

from __future__ import annotations

import logging
from collections.abc import Callable

from qtpy.QtCore import QEvent, QObject, Qt, QTimer
from qtpy.QtWidgets import (
    QComboBox,
    QDockWidget,
    QFrame,
    QLayout,
    QMainWindow,
    QScrollArea,
    QVBoxLayout,
    QWidget,
)

__all__ = ["Connections", "dock_layout", "is_alive"]

logger = logging.getLogger(__name__)

#: Qt property marking the plugin's dock widgets (they join one tab group).
_DOCK_PROPERTY = "edgecme_dock"


def dock_layout(widget: QWidget, content: QLayout) -> QScrollArea:
    """Lay out a dock widget: ``content`` in a vertical scroll area, docked as tabs.

    The scroll area lets the dock be shorter than its content (napari stacks docks
    and the window must fit a 1080 px screen); the widget then joins the other
    docks of this plugin already in the same dock area as one tab group (see
    :class:`_TabJoiner`). Each dock still opens on its own from the Plugins menu.

    Returns
    -------
    QScrollArea
        Holding ``content``.
    """
    inner = QWidget()
    inner.setLayout(content)
    for combo in inner.findChildren(QComboBox):  # long choices must not widen the dock
        combo.setSizeAdjustPolicy(
            QComboBox.SizeAdjustPolicy.AdjustToMinimumContentsLengthWithIcon)
        combo.setMinimumContentsLength(14)
    area = QScrollArea()
    area.setWidgetResizable(True)
    area.setFrameShape(QFrame.Shape.NoFrame)
    area.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAsNeeded)
    area.setWidget(inner)
    bar = area.verticalScrollBar().sizeHint().width()
    area.setMinimumWidth(inner.minimumSizeHint().width() + bar)
    outer = QVBoxLayout(widget)
    outer.setContentsMargins(0, 0, 0, 0)
    outer.addWidget(area)
    widget.setProperty(_DOCK_PROPERTY, True)
    widget.installEventFilter(_TabJoiner(widget))
    return area


class _TabJoiner(QObject):
    """When its widget is first shown docked, tabify its dock with the plugin's others."""

    def __init__(self, widget: QWidget):
        super().__init__(widget)
        self._widget = widget
        self._done = False

    def eventFilter(self, obj, event) -> bool:
        if not self._done and event.type() == QEvent.Type.Show:
            self._done = True
            QTimer.singleShot(0, self._join)  # after napari has placed the dock
        return False

    def _join(self) -> None:
        if not is_alive(self._widget):
            return
        dock = _ancestor(self._widget, QDockWidget)
        main = None if dock is None else dock.parentWidget()
        if dock is None or not isinstance(main, QMainWindow) or dock.isFloating():
            return
        area = main.dockWidgetArea(dock)
        others = [other for other in main.findChildren(QDockWidget)
                  if other is not dock and not other.isFloating() and other.isVisible()
                  and main.dockWidgetArea(other) == area and _holds_plugin_dock(other)]
        if not others or any(o in main.tabifiedDockWidgets(dock) for o in others):
            return
        main.tabifyDockWidget(others[0], dock)
        dock.show()
        dock.raise_()


def _ancestor(widget: QWidget, cls):
    parent = widget.parentWidget()
    while parent is not None and not isinstance(parent, cls):
        parent = parent.parentWidget()
    return parent


def _holds_plugin_dock(dock: QDockWidget) -> bool:
    inner = dock.widget()
    if inner is None:
        return False
    return bool(inner.property(_DOCK_PROPERTY)) or any(
        bool(child.property(_DOCK_PROPERTY)) for child in inner.findChildren(QWidget))


class Connections:
    """Callbacks a widget connects to napari model events, cut when the widget is destroyed.

    Model objects (layers, the layer list) outlive dock widgets; a callback left
    connected to a destroyed Qt widget would fail on the next event.
    """

    def __init__(self, owner: QWidget):
        self._items: list[tuple[object, object, Callable]] = []
        owner.destroyed.connect(lambda *_: self.disconnect_all())

    def connect(self, emitter, callback: Callable, key=None) -> None:
        """Connect ``callback`` to ``emitter``, remembered under ``key`` (e.g. a layer)."""
        emitter.connect(callback)
        self._items.append((key, emitter, callback))

    def disconnect_key(self, key) -> None:
        """Disconnect everything connected under ``key``."""
        for k, emitter, callback in self._items:
            if k is key:
                _disconnect(emitter, callback)
        self._items = [item for item in self._items if item[0] is not key]

    def disconnect_all(self) -> None:
        for _key, emitter, callback in self._items:
            _disconnect(emitter, callback)
        self._items = []


def _disconnect(emitter, callback) -> None:
    try:
        emitter.disconnect(callback)
    except (RuntimeError, ValueError, TypeError):  # already gone
        logger.debug("could not disconnect %r", callback, exc_info=True)


def is_alive(widget) -> bool:
    """Whether a Qt object's C++ side still exists (PyQt and PySide both raise)."""
    try:
        widget.objectName()
    except RuntimeError:
        return False
    return True
