"""Full-resolution refinement of a motion estimated on a downscaled copy.

A photo larger than ``max_side`` is estimated on a copy (:mod:`~.estimate`); rescaled to
the photo, that motion's poses lie on the copy's grid, so each local PSF of a camera
photo becomes a row of dots a few pixels apart (a 12 MP photo estimated at 1024 px: about
4 px). This module carries the coarse-to-fine alternation on past the working copy, at
:data:`REFINE_RATIO` steps up to the photo's own resolution, on a few crops chosen for
their edges rather than on the whole frame:

* every refinement level has the pose grid of the *whole* photo at that resolution
  (one-pixel steps at its farthest point, :func:`~.camera.pose_grid`); each crop is a
  :class:`~.pyramid.Level` on that shared grid with the camera moved to the crop
  (principal point shifted by the crop's corner), so the crops' data terms -- one
  quadratic over the same pose weights each -- add up into one MDF update;
* the MDF of the coarser level is splatted onto the finer grid and smoothed along pose
  space over the gap between the two grids (:func:`carried_weights`), so that the dotted
  path becomes a connected one before the update prunes it; the active poses are its
  support dilated by one step;
* each alternation updates every crop's L0 latent (Eq. 21) and then the MDF on the
  gradient term of Eq. 22, summed over crops (:func:`~.mdf_update.data_term`), with
  both sides smoothed over as many photo pixels as one pixel of the working copy
  spans (on a 12 MP photo with a 60 px shake, one update from a truth known on the
  copy's grid took the PSF NCC from 0.60 to 0.52 with the copy's 1 px smoothing, to
  0.67 with 4 px).

Memory is bounded by the crops (:data:`N_CROPS` of at most :data:`CROP_SIDE` pixels a
side), not by the photo; progress records come from every splitting step of every crop,
so a consumer can cancel promptly.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from .camera import Intrinsics, pose_grid
from .deconv_prior import grad
from .latent import iter_l0_latent
from .mdf_update import GRADIENT_SMOOTHING, data_term, iter_solve_update
from .motion import CameraMotion
from .progress import Progress, StopRequested, relay_as
from .pyramid import WEIGHT_FLOOR, Level, ScaleRecord, contrast_gain, dilate, resize

__all__ = ["CROP_SIDE", "N_CROPS", "REFINE_ITERATIONS", "REFINE_RATIO", "carried_weights",
           "choose_crops", "crop_intrinsics", "iter_refine_motion", "refinement_scales",
           "refinement_steps"]

#: Size ratio of consecutive refinement levels (the last is the photo itself).
REFINE_RATIO = 0.5
#: Crops per refinement level, and the longest side of each (pixels at its level).
N_CROPS = 4
CROP_SIDE = 640
#: Alternations (latent, MDF) at each refinement level.
REFINE_ITERATIONS = 1
#: Growth of the splitting weight per step of the crops' L0 latents (Eq. 21;
#: :func:`~.latent.iter_l0_latent`).
REFINE_KAPPA = 2.0
#: Share of each orientation bin of latent gradients the MDF update uses
#: (:func:`~.mdf_update.salient_gradients`).
REFINE_SALIENT = 0.1
#: FISTA iterations of each refinement MDF update (warm-started from the carried MDF).
REFINE_LASSO_ITER = 200
#: Extra dilation (grid steps) of the carried support that makes the active poses.
REFINE_DILATION = 1


def refinement_scales(work_scale: float) -> list[float]:
    """Scales (of the photo) of the refinement levels above ``work_scale``, coarse to fine.

    ``1, 1/2, 1/4, ...`` while at least 1.25 times ``work_scale``; none when the working
    copy is the photo.
    """
    scales, s = [], 1.0
    while work_scale < 1.0 and s >= 1.25 * work_scale:
        scales.append(s)
        s *= REFINE_RATIO
    return scales[::-1]


def choose_crops(gray: np.ndarray, side_fraction: tuple[float, float], n: int | None = None
                 ) -> list[tuple[float, float]]:
    """Centres of ``n`` crops rich in straight edges, one in each cell of the frame.

    The frame is cut into ``n`` cells (rows x columns as close to its aspect as ``n``
    allows: 2 x 2 for four crops) and each cell gets the window, centred in it, whose sum
    of gradient magnitude weighted by the local straightness of the gradients (the
    usefulness map of Xu & Jia 2010, :func:`~.mdf_update.salient_gradients`) is largest.
    Spread matters more than the very best edges: a rotation about the optical axis and
    one about a tilted axis give nearly the same PSFs on one side of the frame, and
    differ across it. (Picking the best windows anywhere put all four crops of a 12 MP
    landscape in its right third, and the refinement then fitted the motion there at the
    expense of the rest: PSF NCC over the frame fell from 0.50 to 0.34 even with the
    sharp image as the latent.)

    Parameters
    ----------
    gray : ndarray of shape (h, w)
        The photo at any resolution (the working copy).
    side_fraction : (float, float)
        Crop size as fractions of the frame's height and width.
    n : int, optional
        Number of crops (default :data:`N_CROPS`).

    Returns
    -------
    list of (row, col) fractions of the frame, one per cell, row by row.
    """
    n = N_CROPS if n is None else n
    h, w = gray.shape
    rows = max(1, min(n, round(math.sqrt(n * h / w))))
    while n % rows:
        rows -= 1
    cols = n // rows
    gx, gy = grad(gray)
    mag = np.hypot(gx, gy)
    straight = np.hypot(ndimage.uniform_filter(gx, 5), ndimage.uniform_filter(gy, 5))
    score = straight * mag / (ndimage.uniform_filter(mag, 5) + 2e-3)
    win = (max(1, round(side_fraction[0] * h)), max(1, round(side_fraction[1] * w)))
    density = ndimage.uniform_filter(score.astype(np.float64), win, mode="constant")
    # a window must fit in the frame: its centre stays half a window from the border
    lo = [min(k // 2, m - 1 - k // 2) for k, m in zip(win, (h, w), strict=True)]
    fits = np.zeros((h, w), bool)
    fits[lo[0]:max(lo[0] + 1, h - lo[0]), lo[1]:max(lo[1] + 1, w - lo[1])] = True
    centres = []
    for i in range(rows):
        for j in range(cols):
            cell = np.zeros((h, w), bool)
            cell[i * h // rows:(i + 1) * h // rows, j * w // cols:(j + 1) * w // cols] = True
            where = cell & fits
            if not where.any():  # a window larger than the cell: the nearest fitting centre
                where = fits
            masked = np.where(where, density, -np.inf)
            r, c = np.unravel_index(int(np.argmax(masked)), masked.shape)
            centre = ((r + 0.5) / h, (c + 0.5) / w)
            if centre not in centres:
                centres.append(centre)
    return centres


def carried_weights(previous: CameraMotion, grid, shape, ratio: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The MDF of a coarser level on a finer ``grid``, and the active poses around it.

    Two poses one coarse step apart land ``ratio`` fine steps apart. The active poses are
    the splatted support dilated by ``ceil(ratio / 2)`` steps, which joins them into a
    connected tube; the weights are smoothed along every pose axis by a Gaussian of
    ``ratio / 2`` steps within it, so that the first latent of the level sees a connected
    path rather than a row of dots. The MDF updates then sharpen it again.

    Returns
    -------
    weights : ndarray of shape ``grid.counts``, summing to 1
    active : ndarray of bool, same shape
    """
    moved = previous.rescale(shape)
    w = grid.splat(moved.poses, moved.weights)
    active = dilate(w > 0, max(REFINE_DILATION, math.ceil(ratio / 2 - 1e-9)))
    if ratio > 1.0:
        w = ndimage.gaussian_filter(w, ratio / 2.0, mode="constant") * active
    w = np.where(w >= WEIGHT_FLOOR * w.max(), w, 0.0)
    return w / w.sum(), active


def crop_intrinsics(intrinsics: Intrinsics, corner, shape) -> Intrinsics:
    """The camera of a crop: the same focal length, the principal point moved by its corner.

    A pose's homography ``K R K^-1`` maps the crop's pixels as it maps the frame's, so a
    motion with these intrinsics blurs the crop as the frame's motion blurs the frame
    there (a test checks it).

    Parameters
    ----------
    intrinsics : Intrinsics
        Of the whole frame.
    corner : (float, float)
        ``(row, col)`` of the crop's first pixel in the frame.
    shape : (int, int)
        The crop's ``(rows, cols)``.
    """
    cx, cy = intrinsics.principal_point
    return Intrinsics(intrinsics.focal_px, (cx - corner[1], cy - corner[0]), tuple(shape))


def _crop_level(index, gray, box, level_shape, lshape, intrinsics, model, max_blur, grid,
                offset, gain) -> Level:
    """The :class:`Level` of one crop: ``box`` (pixels of the photo) resampled to ``lshape``."""
    r0, r1, c0, c1 = box
    corner = (r0 * level_shape[0] / gray.shape[0], c0 * level_shape[1] / gray.shape[1])
    raw = resize(gray[r0:r1, c0:c1], lshape)
    blurred = ((raw - offset) * gain).astype(raw.dtype)
    return Level(index, blurred, crop_intrinsics(intrinsics, corner, lshape), model,
                 max_blur, grid=grid)


def _crop_boxes(shape, level_shape, centres, side) -> list[tuple[int, int, int, int]]:
    """Boxes (rows and columns of the photo) of crops ``side`` px a side at a level."""
    H, W = shape
    boxes = []
    for fr, fc in centres:
        box = []
        for f, n, ln in ((fr, H, level_shape[0]), (fc, W, level_shape[1])):
            extent = min(n, round(min(side, ln) * n / ln))  # the crop's length in the photo
            start = int(np.clip(round(f * n - extent / 2), 0, n - extent))
            box += [start, start + extent]
        boxes.append(tuple(box))
    return boxes


def iter_refine_motion(gray: np.ndarray, motion: CameraMotion, work_scale: float,
                       max_blur: float, *, lambda_w: float, lambda_f: float,
                       offset: float | None = None, gain: float | None = None,
                       work: np.ndarray | None = None, centres=None, step: int = 0, total: int = 0,
                       records: list | None = None):
    """Refine ``motion`` at the photo's resolution, on crops (a progress generator).

    Parameters
    ----------
    gray : ndarray of shape (H, W)
        The photo's luminance (linear light), as given to the estimator.
    motion : CameraMotion
        The estimate on the working copy (any shape of the photo's aspect ratio).
    work_scale : float
        Size of the working copy relative to the photo (< 1).
    max_blur : float
        Largest blur extent, in pixels of the photo.
    offset, gain : float, optional
        The working copy's contrast stretch, which the L0 weight refers to (default: that
        of :func:`~.pyramid.contrast_gain` on the working copy).
    lambda_w, lambda_f : float
        As for the coarse-to-fine estimator (``lambda_f`` is its finest-level weight;
        here it is scaled by ``work_scale / scale`` as on the pyramid).
    work : ndarray of shape (h, w), optional
        The working copy of ``gray`` (the estimator's, so that it is not made twice),
        for the default stretch and crops; made here when not given.
    centres : list of (float, float), optional
        Crop centres as fractions of the frame (default :func:`choose_crops`).
    step, total : int
        The caller's progress count, continued by the records yielded here.
    records : list, optional
        Gets a :class:`~.pyramid.ScaleRecord` per level (the estimator's ``info.scales``;
        ``shape`` is the level's whole frame, of which the crops are parts).

    Yields
    ------
    Progress
        ``stage="estimate"``, messages "full resolution ...".

    Returns
    -------
    (CameraMotion, int, bool)
        The refined motion, for ``gray.shape`` (on a stop request: that of the last
        finished update), the progress count, and whether every level was run.
    """
    shape = gray.shape
    scales = refinement_scales(work_scale)
    intr_full = motion.intrinsics.rescaled(shape)
    previous, prev_scale = motion, work_scale
    if work is None and (centres is None or offset is None or gain is None):
        work = resize(gray, tuple(max(8, round(n * work_scale)) for n in shape))
    if offset is None or gain is None:
        offset, gain = contrast_gain(work)
    if centres is None:
        side = (min(1.0, CROP_SIDE / shape[0]), min(1.0, CROP_SIDE / shape[1]))
        centres = choose_crops(work, side)
    try:
        for li, s in enumerate(scales):
            lshape_full = tuple(max(8, round(n * s)) for n in shape)
            intr = intr_full.rescaled(lshape_full)
            level_blur = max(2.0, max_blur * s)
            grid = pose_grid(motion.model, intr, level_blur, roll_fraction=0.5)
            weights, active = carried_weights(previous, grid, lshape_full, s / prev_scale)
            crops = []
            for box in _crop_boxes(shape, lshape_full, centres, CROP_SIDE):
                lshape = tuple(max(8, round((b1 - b0) * s)) for b0, b1 in (box[:2], box[2:]))
                crops.append(_crop_level(li, gray, box, lshape_full, lshape, intr,
                                         motion.model, level_blur, grid, offset, gain))
            lam_f = max(lambda_f * work_scale / s, 1e-4)
            # the gradient term's smoothing keeps its width in the working copy's pixels:
            # at the photo's resolution the noise of a gradient outweighs its signal
            smoothing = GRADIENT_SMOOTHING * s / work_scale
            record = ScaleRecord(len(records or ()) + 1, lshape_full, level_blur, grid.size)
            if records is not None:
                records.append(record)
            for it in range(REFINE_ITERATIONS):
                where = (f"full resolution {li + 1}/{len(scales)} ({lshape_full[1]}x"
                         f"{lshape_full[0]}), iteration {it + 1}/{REFINE_ITERATIONS}")
                latents = []
                for ci, crop in enumerate(crops):
                    latent = yield from relay_as(
                        iter_l0_latent(crop.blurred, crop.motion(weights), lam_f,
                                       kappa=REFINE_KAPPA, fine=True),
                        Progress("estimate", step, total,
                                 f"{where}: latent image of crop {ci + 1}/{len(crops)}"))
                    latents.append(latent)
                term = None
                for ci, (crop, latent) in enumerate(zip(crops, latents, strict=True)):
                    t = data_term(crop, active, latent, None, 0.0, "xu",
                                  salient=REFINE_SALIENT * 1.1 ** it, smoothing=smoothing)
                    term = t if term is None else term + t
                    yield Progress("estimate", step, total,
                                   f"{where}: camera motion, crop {ci + 1}/{len(crops)}")
                weights, cost, n_lasso = yield from relay_as(  # a record per FISTA iteration
                    iter_solve_update(term, weights, active, lambda_w,
                                      max_iter=REFINE_LASSO_ITER),
                    Progress("estimate", step, total, f"{where}: camera motion"))
                record.costs.append(cost)
                record.active_poses.append(int(active.sum()))
                record.lasso_iterations.append(n_lasso)
                previous = CameraMotion(motion.model, intr, *_grid_motion(grid, weights))
                step += 1
                yield Progress("estimate", step, total, where, cost=cost)
            prev_scale = s
    except StopRequested:  # the estimate of the last finished update
        return previous, step, False
    return previous, step, True


def _grid_motion(grid, weights):
    keep = weights > 0
    return grid.poses(keep), weights[keep]


def refinement_steps(work_scale: float) -> int:
    """Progress steps :func:`iter_refine_motion` adds for a working copy at ``work_scale``."""
    return len(refinement_scales(work_scale)) * REFINE_ITERATIONS

