"""The image pyramid of the coarse-to-fine estimators and the MDF on each level's grid.

Levels shrink by :data:`PYRAMID_RATIO` (paper §5, after Xu et al.) down to a blur of a
few pixels. Each :class:`Level` holds its observation, camera and pose grid (one-pixel
steps at its resolution, :func:`~.camera.pose_grid`); the MDF found at one level is
splatted onto the next one's grid (:func:`initial_weights`), and the active pose set is
its support dilated by one grid step (:func:`dilate`), so the problem stays small where
the grid is fine. After every update the MDF is cleaned (:func:`clean_mdf`): small
weights and small clusters dropped, renormalised, re-centred on the grid (claims 1-2:
the motion is defined up to a homography).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from .camera import PoseGrid, displacements, pose_grid
from .motion import CameraMotion, psf_size_for
from .operators import PatchGrid

__all__ = ["CLUSTER_FLOOR", "PYRAMID_RATIO", "ROLL_FROM_BLUR", "WEIGHT_FLOOR", "Level",
           "ScaleRecord", "clean_mdf", "contrast_gain", "dilate", "initial_weights",
           "pyramid_scales", "resize"]

#: Size ratio of consecutive levels.
PYRAMID_RATIO = 1.0 / math.sqrt(2.0)
#: Levels whose blur (px) is below this keep the roll ``theta_z`` at 0.
ROLL_FROM_BLUR = 12.0
#: Clusters of the MDF lighter than this share of the heaviest one are dropped.
CLUSTER_FLOOR = 0.1
#: Weights below this fraction of the largest are dropped (Whyte et al.).
WEIGHT_FLOOR = 1.0 / 20.0


def resize(img: np.ndarray, shape) -> np.ndarray:
    """``img`` (H, W) resampled to ``shape`` (bilinear, anti-aliased), its dtype kept."""
    from skimage.transform import resize as resample

    if tuple(shape) == img.shape:
        return img
    return resample(img, shape, order=1, anti_aliasing=True,
                    preserve_range=True).astype(img.dtype)


def contrast_gain(img: np.ndarray) -> tuple[float, float]:
    """Offset and gain that stretch the 0.5 and 99.5 percentiles of ``img`` to 0 and 1.

    The MDF does not depend on an affine change of intensities, but the L0 weight
    ``lambda_f`` does: stretching makes one default serve dim and bright photos alike.
    Edge profiles are still measured on the unstretched image (their contrast and
    saturation tests refer to the [0, 1] range of the file), and ``I_p`` is multiplied
    by the gain so that Eq. 19 compares like with like.
    """
    lo, hi = np.percentile(img, [0.5, 99.5])
    if hi - lo < 1e-6:
        return 0.0, 1.0
    return float(lo), float(1.0 / (hi - lo))


def pyramid_scales(shape, max_blur: float, coarsest_blur: float) -> list[float]:
    """Scales of the pyramid levels, coarse to fine (the last is 1).

    Levels shrink by ``1/sqrt(2)`` until the blur is ``coarsest_blur`` pixels, but the
    coarsest level keeps at least 48 pixels on its smaller side.
    """
    n = 1
    if max_blur > coarsest_blur:
        n = math.floor(math.log(coarsest_blur / max_blur) / math.log(PYRAMID_RATIO)) + 1
    if min(shape) > 48:
        n = min(n, math.floor(math.log(48 / min(shape)) / math.log(PYRAMID_RATIO)) + 1)
    else:
        n = 1
    return [PYRAMID_RATIO ** (n - 1 - i) for i in range(n)]


@dataclass
class ScaleRecord:
    """What happened at one pyramid level."""

    level: int
    shape: tuple[int, int]
    max_blur: float
    grid_size: int
    active_poses: list[int] = field(default_factory=list)
    costs: list[float] = field(default_factory=list)
    lasso_iterations: list[int] = field(default_factory=list)

    @property
    def iterations(self) -> int:
        return len(self.costs)



class Level:
    """One pyramid level: the observation, its camera, pose grid and MDF terms."""

    def __init__(self, index, blurred, intrinsics, model, max_blur, grid: PoseGrid | None = None):
        self.index = index
        self.blurred = blurred
        self.shape = blurred.shape
        self.intrinsics = intrinsics
        self.model = model
        self.max_blur = max_blur
        if grid is None:
            # roll (theta_z) barely changes the PSFs of a small image: keep it fixed at the
            # coarse levels, where freeing it only adds ambiguity
            roll = 0.5 if max_blur >= ROLL_FROM_BLUR else 0.0
            grid = pose_grid(model, intrinsics, max_blur, roll_fraction=roll)
        #: the pose grid; a crop of a larger image shares that image's grid (:mod:`.refine`)
        self.grid: PoseGrid = grid
        self.cache: dict = {}

    def motion(self, weights_grid: np.ndarray) -> CameraMotion:
        keep = weights_grid > 0
        return CameraMotion(self.model, self.intrinsics, self.grid.poses(keep),
                            weights_grid[keep])

    def patch_grid(self, poses) -> PatchGrid:
        """Tiles for the MDF terms: a few per axis, each several PSFs wide."""
        probe = PatchGrid(self.shape, 1, stride=max(self.shape))
        corners = np.array([[0, 0], [0, self.shape[1] - 1], [self.shape[0] - 1, 0],
                            [self.shape[0] - 1, self.shape[1] - 1]], float)
        K = psf_size_for(displacements(self.model, self.intrinsics, poses,
                                       np.vstack([probe.centres, corners])))
        stride = int(max(2 * K, min(4 * K, 128, math.ceil(max(self.shape) / 3))))
        return PatchGrid(self.shape, K, stride=stride)


def initial_weights(level: Level, previous: CameraMotion | None,
                     wide: bool = False) -> np.ndarray:
    if previous is None and wide:
        # a blob over the whole grid (a third of its reach): the wide start (Xu, Xu+Ep)
        # and the restart after a collapse
        half = np.maximum(level.grid.half, 1).astype(float)
        offsets = np.indices(level.grid.counts) - np.asarray(level.grid.half).reshape(
            (-1,) + (1,) * len(level.grid.counts))
        sigma = (half / 3.0).reshape((-1,) + (1,) * len(level.grid.counts))
        w = np.exp(-0.5 * np.sum((offsets / sigma) ** 2, axis=0))
        return w / w.sum()
    if previous is None:
        # a small blob, not a delta: the delta is a fixed point of the alternation (the
        # L0 latent of a delta-blurred image explains the data with a delta again)
        w = np.zeros(level.grid.counts)
        centre = tuple(slice(max(h - 1, 0), h + 2) for h in level.grid.half)
        offsets = np.indices(w[centre].shape) - np.minimum(level.grid.half, 1).reshape(
            (-1,) + (1,) * w.ndim)
        w[centre] = np.exp(-np.sum(offsets.astype(float) ** 2, axis=0))
        return w / w.sum()
    moved = previous.rescale(level.shape)
    w = level.grid.splat(moved.poses, moved.weights)
    return w / w.sum()


def dilate(support: np.ndarray, steps: int = 1) -> np.ndarray:
    structure = np.ones((3,) * support.ndim, bool)
    return ndimage.binary_dilation(support, structure, iterations=steps)


def clean_mdf(weights: np.ndarray, weight_floor: float = WEIGHT_FLOOR) -> np.ndarray:
    """Drop weights below ``weight_floor`` x the largest and small isolated clusters;
    renormalise; re-centre.

    A camera traces one connected path through pose space: clusters of the support
    (connected on the grid, diagonals included) holding less than :data:`CLUSTER_FLOOR`
    of the heaviest cluster's weight are ghosts fitted to deconvolution artefacts, and are
    removed (Pan et al. do the same on kernels). ``weight_floor`` defaults to
    :data:`WEIGHT_FLOOR` (Whyte et al.'s 1/20); Xu and Xu+Ep use a lower one
    (:data:`~.estimate.LATENT_WEIGHT_FLOOR`).
    """
    w = np.where(weights >= weight_floor * weights.max(), weights, 0.0)
    w /= w.sum()
    if CLUSTER_FLOOR > 0:
        labels, n = ndimage.label(w > 0, np.ones((3,) * w.ndim, bool))
        if n > 1:
            mass = ndimage.sum_labels(w, labels, np.arange(1, n + 1))
            keep = np.flatnonzero(mass >= CLUSTER_FLOOR * mass.max()) + 1
            w = np.where(np.isin(labels, keep), w, 0.0)
            w /= w.sum()
    idx = np.indices(w.shape).reshape(w.ndim, -1)
    centroid = idx @ w.ravel()
    shift = np.round(np.asarray(w.shape) // 2 - centroid).astype(int)
    if np.any(shift):
        moved = np.zeros_like(w)
        src = tuple(slice(max(0, -s), n - max(0, s)) for s, n in zip(shift, w.shape, strict=True))
        dst = tuple(slice(max(0, s), n - max(0, -s)) for s, n in zip(shift, w.shape, strict=True))
        moved[dst] = w[src]
        if moved.sum() > 0:
            w = moved / moved.sum()
    return w
