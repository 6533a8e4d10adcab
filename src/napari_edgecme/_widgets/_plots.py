"""Matplotlib canvases for the dock widgets, in the viewer's theme colours."""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
from qtpy.QtCore import QTimer
from qtpy.QtWidgets import QLabel

from ._dock import is_alive

__all__ = ["deferred_draw", "plot_canvas", "style_axes", "theme_colours"]

logger = logging.getLogger(__name__)


def plot_canvas(viewer, n_axes: int, height: float = 2.6, left_margin: int = 48,
                right_margin: int = 12):
    """A matplotlib canvas for a dock widget, in the viewer's theme colours.

    The margins are fixed in pixels (room for tick labels and axis labels whatever
    size the dock gives the canvas) and re-applied when the canvas is resized; a
    constrained layout would cost more than drawing the plot.

    Parameters
    ----------
    viewer
        For the theme colours.
    n_axes : int
        Side-by-side axes.
    height : float
        Preferred height in inches (at 72 dpi: the canvas's minimum height).
    left_margin, right_margin : int
        Pixels left of the first axes (more for a y label) and right of the last
        (more for a colour bar's label).

    Returns
    -------
    (FigureCanvasQTAgg, list of Axes) or (QLabel, [])
        A label saying how to get plots when matplotlib (the ``plot`` extra) is missing.
    """
    try:
        from matplotlib.backends.backend_qtagg import FigureCanvasQTAgg
        from matplotlib.figure import Figure
    except ImportError:
        label = QLabel("Install matplotlib to see plots here: pip install 'napari-edgecme[plot]'")
        label.setWordWrap(True)
        return label, []
    fg, bg = theme_colours(viewer)
    fig = Figure(figsize=(3.6, height), facecolor=bg)
    canvas = FigureCanvasQTAgg(fig)

    def fit_margins(_event=None):
        width, tall = fig.bbox.width, fig.bbox.height
        if width > 4 * (left_margin + right_margin) and tall > 4 * (36 + 22):
            fig.subplots_adjust(left=left_margin / width, right=1 - right_margin / width,
                                bottom=36 / tall, top=1 - 22 / tall, wspace=0.45)

    fit_margins()
    canvas.mpl_connect("resize_event", fit_margins)
    axes = list(np.atleast_1d(fig.subplots(1, n_axes)))
    for ax in axes:
        style_axes(ax, fg, bg)
    canvas.setMinimumHeight(int(height * 72))
    return canvas, axes


def deferred_draw(canvas) -> Callable[[], None]:
    """A function that redraws ``canvas`` once the event loop is idle (calls coalesce).

    Like matplotlib's ``draw_idle``, but the timer is a child of the canvas: when the
    widget is deleted with a redraw still pending, the timer goes with it.
    """
    timer = QTimer(canvas)
    timer.setSingleShot(True)
    timer.setInterval(0)

    def draw() -> None:
        # A CI run once saw the timer fire after the canvas's C++ object was gone
        # (matplotlib's draw ends in ``canvas.update()``): a redraw of a deleted
        # canvas is moot, any other error is real.
        try:
            canvas.draw()
        except RuntimeError:
            if is_alive(canvas):
                raise

    timer.timeout.connect(draw)
    return timer.start


def style_axes(ax, fg: str, bg: str) -> None:
    ax.set_facecolor(bg)
    for spine in ax.spines.values():
        spine.set_color(fg)
    ax.tick_params(colors=fg, labelsize=7)
    ax.xaxis.label.set_color(fg)
    ax.yaxis.label.set_color(fg)
    ax.title.set_color(fg)
    ax.xaxis.label.set_fontsize(8)
    ax.yaxis.label.set_fontsize(8)
    ax.title.set_fontsize(8)


def theme_colours(viewer) -> tuple[str, str]:
    """``(foreground, background)`` of the viewer's theme, as hex strings."""
    try:
        from napari.utils.theme import get_theme

        theme = get_theme(viewer.theme)
        return theme.text.as_hex(), theme.background.as_hex()
    except Exception:  # unknown or "system" theme: neutral dark colours
        logger.debug("theme colours unavailable", exc_info=True)
        return "#f0f1f2", "#262930"
