"""How a deconvolution is cut into blocks and EFF tiles.

Large images are deconvolved in overlapping blocks that cross-fade (windows summing to
one, :class:`BlockPlan`), each with a margin of real data around it; inside a block the
blur is an EFF with tiles as large as the PSF's drift across the image allows
(:func:`auto_stride`).
"""

from __future__ import annotations

import numpy as np

from .motion import CameraMotion, psf_size_for
from .operators import PatchGrid

__all__ = ["MAX_STRIDE", "MIN_BLOCK", "MIN_STRIDE", "PSF_DRIFT", "BlockPlan", "auto_stride",
           "psf_drift_rate", "psf_extent"]

#: Smallest accepted block size (pixels).
MIN_BLOCK = 64

#: Automatic EFF tile size (``stride=None``): PSF drift allowed across half a tile (px)
#: and the range of tile sizes.
PSF_DRIFT = 0.5
MIN_STRIDE = 32
MAX_STRIDE = 256


def psf_extent(motion: CameraMotion) -> int:
    """Odd PSF side holding the motion anywhere in the image (grid plus corners)."""
    rows, cols = motion.image_shape
    r = np.linspace(0, rows - 1, 9)
    c = np.linspace(0, cols - 1, 9)
    pts = np.stack(np.meshgrid(r, c, indexing="ij"), -1).reshape(-1, 2)
    return psf_size_for(motion.displacements(pts))


def psf_drift_rate(motion: CameraMotion, n: int = 9, delta: float = 4.0) -> float:
    """How fast the PSF changes across the image: the largest change of any pose's
    displacement per pixel of image distance (px/px), over an ``n x n`` grid."""
    rows, cols = motion.image_shape
    r = np.linspace(0, rows - 1, n)
    c = np.linspace(0, cols - 1, n)
    pts = np.stack(np.meshgrid(r, c, indexing="ij"), -1).reshape(-1, 2)
    d0 = motion.displacements(pts)
    rate = 0.0
    for step in ((delta, 0.0), (0.0, delta)):
        d1 = motion.displacements(pts + np.array(step))
        rate = max(rate, float(np.max(np.hypot(*(d1 - d0).transpose(2, 0, 1)))) / delta)
    return rate


def auto_stride(motion: CameraMotion) -> int:
    """EFF tile size for deconvolution: as large as possible (cheaper per pixel) while
    the PSF drifts by at most :data:`PSF_DRIFT` px between a tile's centre and its
    window's half-width (``stride / 2``); within [:data:`MIN_STRIDE`, :data:`MAX_STRIDE`]."""
    rate = psf_drift_rate(motion)
    stride = MAX_STRIDE if rate <= 0 else 2.0 * PSF_DRIFT / rate
    return int(np.clip(stride, MIN_STRIDE, MAX_STRIDE))


class BlockPlan:
    """Overlapping blocks that cross-fade (windows summing to one) and their observed boxes."""

    def __init__(self, shape, block_size: int, psf_size: int):
        self.shape = shape
        K = psf_size
        blend = 2 * (min(block_size // 2, max(16, K)) // 2)
        self.grid = PatchGrid(shape, 1, block_size, blend)
        self.margin = 2 * K + 8  # real data kept around each block beyond its window
        self.blocks = []
        g = self.grid
        for i in range(g.counts[0]):
            for j in range(g.counts[1]):
                win_box, wins = [], []
                for axis, k in ((0, i), (1, j)):
                    start = k * g.stride[axis] - g.overlap[axis] // 2
                    lo, hi = max(start, 0), min(start + g.patch_shape[axis], shape[axis])
                    win_box.append((lo, hi))
                    wins.append(g.windows[axis][k, lo - start:hi - start])
                (wr0, wr1), (wc0, wc1) = win_box
                box = (max(wr0 - self.margin, 0), min(wr1 + self.margin, shape[0]),
                       max(wc0 - self.margin, 0), min(wc1 + self.margin, shape[1]))
                self.blocks.append({
                    "box": box,
                    "window_box": (wr0, wr1, wc0, wc1),
                    "window": np.outer(wins[0], wins[1]),
                })

    def __len__(self):
        return len(self.blocks)

    @staticmethod
    def add(out: np.ndarray, block: dict, observed: np.ndarray, *,
            subtract: bool = False) -> None:
        """``out[window] += window * observed-block result`` (the cross-fade).

        ``out`` and ``observed`` are (H, W) and (h, w), or (H, W, C) and (h, w, C) (every
        channel at once); with ``subtract``, ``out[window] -= ...``.
        """
        r0, _, c0, _ = block["box"]
        wr0, wr1, wc0, wc1 = block["window_box"]
        part = observed[wr0 - r0:wr1 - r0, wc0 - c0:wc1 - c0]
        window = block["window"].astype(out.dtype)
        if part.ndim == 3:
            window = window[..., None]
        if subtract:
            out[wr0:wr1, wc0:wc1] -= window * part
        else:
            out[wr0:wr1, wc0:wc1] += window * part
