"""A PSF field people can read: each local PSF enlarged in its grid cell, on a gray tile.

Local PSFs of a camera shake are a few pixels long; drawn at their true size on a
grid 80 px apart they are dots at fit-to-window zoom. :func:`psf_glyphs` draws each
one enlarged by one stated factor (the same for all, so that sizes compare), smoothly
(bilinear), centred on its sample point, on a neutral gray tile so that the streak
reads over any photo. Numpy and SciPy only (no Qt): the image is an RGBA array.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates

from ..core.motion import CameraMotion

__all__ = ["BACKGROUND", "GLYPH_COLOUR", "PsfGlyphs", "psf_glyphs"]

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
        ``rgba`` pixels per image pixel (at most 1).
    """

    rgba: np.ndarray
    enlargement: int
    points: np.ndarray
    boxes: list
    psfs: np.ndarray
    canvas_scale: float


def psf_glyphs(motion: CameraMotion, grid, fill: float = 0.85, max_side: int = 1600,
               floor: float = 0.02) -> PsfGlyphs:
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

    Returns
    -------
    PsfGlyphs
    """
    rows, cols = motion.image_shape
    grid = (int(grid[0]), int(grid[1]))
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
    scale = min(1.0, max_side / max(rows, cols))
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
    return PsfGlyphs(rgba, enlargement, points, boxes, psfs, scale)
