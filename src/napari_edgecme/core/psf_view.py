"""A PSF field people can read: each local PSF enlarged in its grid cell, on a gray tile.

Local PSFs of a camera shake are a few pixels long; drawn at their true size on a
grid 80 px apart they are dots at fit-to-window zoom. :func:`psf_glyphs` draws each
one enlarged by one stated factor (the same for all, so that sizes compare), smoothly
(bilinear), centred on its sample point, on a neutral gray tile so that the streak
reads over any photo. Numpy and SciPy only: the image is an RGBA array, laid over the
photo by the napari widget and put in a labelled figure by :func:`save_psf_field_figure`
(matplotlib, Agg, imported only there). No Qt, no napari.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import map_coordinates

from .motion import CameraMotion

__all__ = ["BACKGROUND", "GLYPH_COLOUR", "TILE_ALPHA", "PsfFieldFigure", "PsfGlyphs",
           "psf_glyphs", "save_psf_field_figure", "square_grid"]

#: Gray level of the tile behind each PSF.
BACKGROUND = 0.25
#: Colour of a PSF at its peak (it fades into the tile).
GLYPH_COLOUR = (1.0, 0.85, 0.25)
#: Opacity of a tile (the photo shows through a little, and fully between tiles).
TILE_ALPHA = 0.85


@dataclass(frozen=True)
class PsfGlyphs:
    """A drawn PSF field.

    Attributes
    ----------
    rgba : ndarray of shape (rows, cols, 4), float32
        The drawing, transparent between the tiles. Its pixels are the image's
        pixels times ``canvas_scale`` (lay it over the image with a resampling
        transform).
    enlargement : int
        How many times each PSF is drawn larger than its true size in the image.
    points : ndarray of shape (n, 2)
        The sample points ``(row, col)`` in the image.
    boxes : list of tuple
        ``(row0, col0, side)`` of each tile in ``rgba``.
    psfs : ndarray of shape (n, size, size)
        The PSFs drawn (centre pixel = zero displacement).
    canvas_scale : float
        ``rgba`` pixels per image pixel (at most 1 unless asked otherwise).
    window : int
        Side (px of blur, in the image) of the displacement window each tile shows:
        a tile spans ``window`` image pixels of blur, drawn ``enlargement`` times larger.
    """

    rgba: np.ndarray
    enlargement: int
    points: np.ndarray
    boxes: list
    psfs: np.ndarray
    canvas_scale: float
    window: int = 0


def square_grid(shape, per_short_side: int = 5) -> tuple[int, int]:
    """PSF sample grid ``(rows, cols)`` with square cells, ``per_short_side`` on the short side."""
    rows, cols = (int(s) for s in tuple(shape)[:2])
    short = min(rows, cols)
    return (max(1, round(per_short_side * rows / short)),
            max(1, round(per_short_side * cols / short)))


def psf_glyphs(motion: CameraMotion, grid, fill: float = 0.85, max_side: int = 1600,
               floor: float = 0.02, upscale: bool = False) -> PsfGlyphs:
    """Draw the local PSFs of ``motion`` on a grid, each enlarged to fill its cell.

    Parameters
    ----------
    motion : CameraMotion
    grid : tuple of int
        ``(rows, cols)`` of sample points, at the centres of equal cells.
    fill : float
        Fraction of a cell's side the largest PSF's tile takes.
    max_side : int
        Longest side of the drawing (larger images get a coarser canvas).
    floor : float
        Fraction of a PSF's peak below which it counts as empty, to size the window
        every PSF is cut to.
    upscale : bool
        Let the canvas be finer than the image (``canvas_scale > 1``) when the image's
        longest side is under ``max_side``, e.g. to fill a figure smoothly.

    Returns
    -------
    PsfGlyphs
    """
    rows, cols = motion.image_shape
    grid = (int(grid[0]), int(grid[1]))
    if min(grid) < 1:
        raise ValueError(f"grid must be two positive integers (rows, cols); got {grid!r}")
    r = (np.arange(grid[0]) + 0.5) * rows / grid[0] - 0.5
    c = (np.arange(grid[1]) + 0.5) * cols / grid[1] - 0.5
    points = np.stack([g.ravel() for g in np.meshgrid(r, c, indexing="ij")], -1)
    psfs = motion.psf(points)
    size = psfs.shape[1]
    centre = size // 2
    peaks = psfs.max(axis=(1, 2), keepdims=True)
    norm = psfs / np.maximum(peaks, 1e-12)
    _, rr, cc = np.nonzero(norm > floor)
    half = max(1, int(max(np.abs(rr - centre).max(initial=0),
                          np.abs(cc - centre).max(initial=0))))
    window = 2 * half + 1  # every PSF's support fits, centred on its zero displacement
    cell = min(rows / grid[0], cols / grid[1])
    enlargement = max(1, math.floor(fill * cell / window))
    scale = max_side / max(rows, cols)
    if not upscale:
        scale = min(1.0, scale)
    canvas = (max(1, round(rows * scale)), max(1, round(cols * scale)))
    side = max(3, round(enlargement * window * scale))
    rgba = np.zeros((*canvas, 4), np.float32)
    colour = np.asarray(GLYPH_COLOUR, np.float32)
    mid = (side - 1) / 2.0
    offsets = centre + (np.arange(side) - mid) / (enlargement * scale)
    uu, vv = np.meshgrid(offsets, offsets, indexing="ij")
    boxes = []
    for (pr, pc), kernel in zip(points, norm, strict=True):
        glyph = map_coordinates(kernel, [uu, vv], order=1, mode="constant", cval=0.0)
        value = np.sqrt(np.clip(glyph, 0.0, 1.0)).astype(np.float32)  # faint tails show
        r0 = round((pr + 0.5) * scale - 0.5 - mid)
        c0 = round((pc + 0.5) * scale - 0.5 - mid)
        boxes.append((r0, c0, side))
        rs0, cs0 = max(r0, 0), max(c0, 0)
        rs1, cs1 = min(r0 + side, canvas[0]), min(c0 + side, canvas[1])
        if rs1 <= rs0 or cs1 <= cs0:
            continue
        v = value[rs0 - r0:rs1 - r0, cs0 - c0:cs1 - c0, None]
        tile = BACKGROUND * (1.0 - v) + colour * v
        rgba[rs0:rs1, cs0:cs1, :3] = tile
        rgba[rs0:rs1, cs0:cs1, 3] = TILE_ALPHA + (1.0 - TILE_ALPHA) * v[..., 0]
    return PsfGlyphs(rgba, enlargement, points, boxes, psfs, scale, window)


@dataclass(frozen=True)
class PsfFieldFigure:
    """What :func:`save_psf_field_figure` wrote.

    Attributes
    ----------
    path : Path
        The PNG.
    size : tuple of int
        ``(width, height)`` of the PNG in pixels.
    axes_box : tuple of float
        ``(left, top, width, height)`` in PNG pixels of the image area: image pixel
        ``(row, col)`` is drawn at PNG ``(left + (col + 0.5) * width / cols - 0.5,
        top + (row + 0.5) * height / rows - 0.5)``.
    glyphs : PsfGlyphs
        The drawing shown (its canvas spans ``axes_box``).
    title : str
        The figure's title (two lines).
    scale_bar_px : float
        Length of the scale bar, in pixels of blur in the image.
    """

    path: Path
    size: tuple
    axes_box: tuple
    glyphs: PsfGlyphs
    title: str
    scale_bar_px: float


def _nice_length(limit: float) -> float:
    """The largest 1, 2 or 5 times a power of ten that is at most ``limit`` (at least 1)."""
    if limit < 1:
        return 1.0
    power = 10.0 ** math.floor(math.log10(limit))
    return max(m * power for m in (1, 2, 5) if m * power <= limit)


def save_psf_field_figure(motion: CameraMotion, path, grid=None, width: int = 1000,
                          dpi: int = 100, max_height: int | None = None,
                          fill: float = 0.85) -> PsfFieldFigure:
    """Write a labelled PNG of the PSF field of ``motion``: what ``edgecme psf`` draws.

    The local PSFs on a grid of sample points, each drawn by :func:`psf_glyphs` enlarged
    by one stated factor on a gray tile centred on its point; axes in image pixels, a
    title stating the motion (model, poses, :meth:`~CameraMotion.blur_extent`) and the
    enlargement, and a scale bar in pixels of blur. Matplotlib is imported here only,
    through its Agg canvas (no pyplot, no GUI backend).

    Parameters
    ----------
    motion : CameraMotion
    path : path-like
        The PNG to write (PNG whatever its suffix).
    grid : tuple of int, optional
        ``(rows, cols)`` of sample points (default: square cells, 5 on the short side).
    width : int
        Width of the PNG in pixels.
    dpi : int
        Resolution the text is set at (10 pt text is about 14 px at 100).
    max_height : int, optional
        Tallest the PNG may be (default ``1.6 * width``); a tall image gets narrower axes.
    fill : float
        Fraction of a cell the largest PSF's tile takes.

    Returns
    -------
    PsfFieldFigure

    Raises
    ------
    ImportError
        If matplotlib is not installed; ``motion.psf_field(grid)`` still gives the raw
        PSF field as an image.
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from matplotlib.lines import Line2D
    except ImportError as err:
        raise ImportError(
            "the PSF-field figure needs matplotlib (pip install matplotlib); without it, "
            "CameraMotion.psf_field(grid) gives the raw PSF field as an image") from err

    rows, cols = motion.image_shape
    grid = square_grid((rows, cols)) if grid is None else (int(grid[0]), int(grid[1]))
    width = int(width)
    if width < 200:
        raise ValueError(f"width must be at least 200 px; got {width}")
    max_height = int(1.6 * width) if max_height is None else int(max_height)
    left, right, top, bottom = 70, 20, 64, 92  # margins (px): tick labels, title, scale bar
    aw = width - left - right
    ah = aw * rows / cols
    if top + ah + bottom > max_height:  # a tall image: narrower axes, centred
        ah = max(50.0, max_height - top - bottom)
        aw = ah * cols / rows
        left = (width - aw) / 2 + 25
    height = round(top + ah + bottom)
    ah = height - top - bottom
    glyphs = psf_glyphs(motion, grid, fill=fill, max_side=round(max(aw, ah)), upscale=True)

    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, facecolor="white")
    FigureCanvasAgg(fig)
    ax = fig.add_axes((left / width, bottom / height, aw / width, ah / height))
    ax.set_facecolor("0.93")
    ax.imshow(glyphs.rgba, extent=(-0.5, cols - 0.5, rows - 0.5, -0.5), aspect="auto",
              interpolation="antialiased")
    ax.set_xlim(-0.5, cols - 0.5)
    ax.set_ylim(rows - 0.5, -0.5)
    ax.set_xlabel("column (image px)", fontsize=9)
    ax.set_ylabel("row (image px)", fontsize=9)
    ax.tick_params(labelsize=8)
    n = glyphs.enlargement
    enlarged = f"each PSF drawn {n}x enlarged" if n > 1 else "each PSF drawn at its true size"
    title = (f"PSF field: {motion.model} motion, {motion.n_poses} poses, blur extent "
             f"{motion.blur_extent():.1f} px (longest side of the PSFs)\n"
             f"{grid[0]}x{grid[1]} local PSFs at their image points, {enlarged} "
             f"(gray tile = {glyphs.window} px of blur)")
    fig.text(0.5, 1 - 8 / height, title, ha="center", va="top", fontsize=10)

    # scale bar, bottom right under the axes: ``bar`` px of blur as drawn
    bar = _nice_length(0.8 * glyphs.window)
    bar_px = bar * n * aw / cols  # figure pixels
    x1 = (left + aw) / width
    x0 = x1 - bar_px / width
    y = 16 / height
    fig.add_artist(Line2D([x0, x1], [y, y], transform=fig.transFigure, color="black",
                          linewidth=3, solid_capstyle="butt"))
    for x in (x0, x1):
        fig.add_artist(Line2D([x, x], [y - 5 / height, y + 5 / height],
                              transform=fig.transFigure, color="black", linewidth=1))
    fig.text(x0 - 8 / width, y, f"scale: {bar:g} px of blur (drawn {n}x enlarged)",
             ha="right", va="center", fontsize=9)
    path = Path(path)
    fig.savefig(path, format="png", dpi=dpi, facecolor="white")
    return PsfFieldFigure(path, (width, height), (float(left), float(top), float(aw), float(ah)),
                          glyphs, title, bar)
