"""Synthetic camera shake: random hand-shake trajectories and exact blur rendering.

Rendering warps the sharp image densely along the trajectory (many time samples,
cubic spline sampling) and averages -- deliberately independent of the filter-flow
operator, so that tests and benchmarks do not commit the inverse crime.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ._validation import as_float_image, as_rng, check_choice, check_positive
from .camera import (
    MODELS,
    Intrinsics,
    homographies,
    invert_homographies,
    n_params,
    warp_points,
)
from .motion import CameraMotion
from .progress import Progress

__all__ = [
    "SyntheticCase",
    "add_noise",
    "densify_path",
    "distance_to_edges",
    "edge_scene",
    "make_case",
    "make_dataset",
    "quantize",
    "random_trajectory",
    "render_blur",
    "render_shapes",
    "sample_image",
    "trajectory_extent",
]

#: Bundled scikit-image photos used for synthetic cases (name -> loader name).
SAMPLE_IMAGES = ("camera", "astronaut", "coffee", "text", "page", "chelsea", "rocket", "edges")


def trajectory_extent(model: str, intrinsics: Intrinsics, poses) -> float:
    """Blur extent (px) of a path of poses, as :meth:`CameraMotion.blur_extent` defines it.

    The longest side of the bounding box of a local PSF's support (the distance between
    the extreme displacements along ``x`` or ``y``; one pose gives 0), largest over the
    image's corners, edge midpoints and centre -- 9 of the 25 points
    :meth:`~napari_edgecme.core.motion.CameraMotion.blur_extent` measures at. Every pose
    counts (a path has no weights). The box side is largest at a corner (exactly so for
    ``translation`` and ``inplane``, whose displacements are affine in the point; to
    within 1e-4 px for ``rotation``), so a path, as a motion, and its densified motion
    (:func:`densify_path`) have ``blur_extent()`` equal to this number.
    """
    rows, cols = intrinsics.image_shape
    pts = np.array([[r, c] for r in (0, (rows - 1) / 2, rows - 1)
                    for c in (0, (cols - 1) / 2, cols - 1)], float)
    from .camera import displacements

    d = displacements(model, intrinsics, poses, pts)
    return float(np.max(np.ptp(d, axis=1)))


def random_trajectory(model: str, intrinsics: Intrinsics, extent: float, n_samples: int = 64,
                      roll: float = 0.35, rng=None) -> np.ndarray:
    """A smooth random hand-shake path through pose space.

    The path is a smoothed random walk with momentum (a few changes of direction),
    scaled so that its blur extent (:func:`trajectory_extent`) is ``extent`` pixels: the
    motion ``densify_path(path, ...)`` has ``blur_extent() == extent`` (to 1e-4 px at the
    usual sizes; the scale is refined three times, not solved for, so a blur a third of
    the image's side may come out up to 0.01 px short).

    Parameters
    ----------
    model : {"translation", "inplane", "rotation"}
    intrinsics : Intrinsics
    extent : float
        Blur extent in pixels: the longest side of a local PSF's support (its bounding
        box), largest over the image -- :meth:`CameraMotion.blur_extent`.
    n_samples : int
        Number of poses along the path.
    roll : float
        Strength of the in-plane rotation relative to the other axes, measured in
        pixels of motion at the farthest image corner (ignored for ``translation``).
    rng : None, int or numpy.random.Generator

    Returns
    -------
    ndarray of shape (n_samples, d)
        Poses in time order, their mean at the identity.
    """
    check_choice(model, "model", MODELS)
    extent = check_positive(extent, "extent", allow_zero=True)
    n_samples = check_positive(n_samples, "n_samples", integer=True)
    rng = as_rng(rng)
    d = n_params(model)
    accel = rng.standard_normal((max(n_samples, 2) * 4, d))
    accel = ndimage.gaussian_filter1d(accel, sigma=max(n_samples, 2) * 4 / 12, axis=0)
    velocity = np.cumsum(accel, axis=0)
    path = np.cumsum(velocity, axis=0)[:: 4][:n_samples]
    path = path - path.mean(0)
    scale = np.max(np.abs(path), axis=0)
    path = path / np.where(scale > 0, scale, 1)
    # per-axis step sizes of one pixel at the farthest point; roll scaled down
    from .camera import _grid_steps

    steps = _grid_steps(model, intrinsics)
    mix = np.ones(d)
    if model != "translation":
        mix[2] = roll
    unit = path * steps * mix
    if extent == 0 or n_samples == 1:
        return np.zeros((n_samples, d))
    base = trajectory_extent(model, intrinsics, unit)
    poses = unit * (extent / base)
    for _ in range(3):  # displacements are nearly linear in the pose: refine the scale
        poses *= extent / trajectory_extent(model, intrinsics, poses)
    return poses


def render_blur(image, motion_or_poses, model: str | None = None,
                intrinsics: Intrinsics | None = None, samples_per_pixel: float = 2.0,
                callback=None) -> np.ndarray:
    """Render ``g(x) = mean_t f(H_t^-1 x)`` exactly by dense warping (paper Eq. 7).

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        Sharp image.
    motion_or_poses : CameraMotion or ndarray of shape (n, d)
            A motion (weights honoured) or a time-ordered path, resampled densely by
        :func:`densify_path`.
    model, intrinsics
        Required with a path.
    samples_per_pixel : float
        Temporal sampling density along a path.
    callback : callable, optional
        Called with a :class:`~napari_edgecme.core.progress.Progress` record (stage
        ``"synth"``) after each pose is warped in; a 12 MP RGB image takes a few
        seconds per pose.

    Returns
    -------
    ndarray, like ``image`` (float)
        The blurred image; outside the frame the scene is mirrored.
    """
    img = as_float_image(image, allow_rgb=True)
    if isinstance(motion_or_poses, CameraMotion):
        motion = motion_or_poses
    else:
        if model is None or intrinsics is None:
            raise ValueError("render_blur needs model and intrinsics with a path of poses")
        motion = densify_path(motion_or_poses, model, intrinsics, samples_per_pixel)
    poses, weights = motion.poses, motion.weights
    model, intrinsics = motion.model, motion.intrinsics
    weights = np.asarray(weights, float) / np.sum(weights)
    rows, cols = img.shape[:2]
    rr, cc = np.mgrid[0:rows, 0:cols].astype(float)
    xy = np.stack([cc.ravel(), rr.ravel()], -1)
    channels = [img] if img.ndim == 2 else [img[..., c] for c in range(img.shape[2])]
    coeffs = [ndimage.spline_filter(ch.astype(np.float64), order=3, mode="mirror")
              for ch in channels]
    out = [np.zeros(rows * cols) for _ in channels]
    inverses = invert_homographies(homographies(model, intrinsics, poses))
    for step, (Hinv, w) in enumerate(zip(inverses, weights, strict=True), start=1):
        coords = warp_points(Hinv[None], xy)[0, :, ::-1].T
        for acc, co in zip(out, coeffs, strict=True):
            acc += w * ndimage.map_coordinates(co, coords, order=3, mode="mirror",
                                               prefilter=False)
        if callback is not None:
            callback(Progress("synth", step, len(weights),
                              f"warping pose {step}/{len(weights)}"))
    res = [o.reshape(rows, cols) for o in out]
    res = res[0] if img.ndim == 2 else np.stack(res, -1)
    return res.astype(img.dtype)


def densify_path(poses, model: str, intrinsics: Intrinsics, samples_per_pixel: float = 2.0
                 ) -> CameraMotion:
    """The motion of a camera moving at constant speed along a time-ordered path of poses.

    The path is resampled linearly so that consecutive poses move every image corner
    by at most ``1 / samples_per_pixel`` pixels; the result has equal weights.
    """
    poses = np.asarray(poses, float)
    if len(poses) < 2:
        return CameraMotion.from_trajectory(poses, model, intrinsics)
    steps = np.linalg.norm(np.diff(_corner_paths(model, intrinsics, poses), axis=1), axis=-1)
    per_seg = np.maximum(1, np.ceil(steps.max(0) * samples_per_pixel)).astype(int)
    dense = [poses[:1]]
    for k, n in enumerate(per_seg):
        t = (np.arange(1, n + 1) / n)[:, None]
        dense.append(poses[k] * (1 - t) + poses[k + 1] * t)
    return CameraMotion.from_trajectory(np.concatenate(dense), model, intrinsics)


def _corner_paths(model, intrinsics, poses):
    """Image-corner positions along a path, (4, n, 2)."""
    from .camera import warp_points

    return np.transpose(warp_points(homographies(model, intrinsics, poses), intrinsics.corners),
                        (1, 0, 2))


def add_noise(image, sigma: float, rng=None) -> np.ndarray:
    """Add white Gaussian noise of standard deviation ``sigma`` (image units, [0, 1] scale)."""
    sigma = check_positive(sigma, "sigma", allow_zero=True)
    img = np.asarray(image)
    return (img + as_rng(rng).standard_normal(img.shape) * sigma).astype(img.dtype)


def quantize(image, bits: int = 8) -> np.ndarray:
    """Clip to [0, 1] and round to ``bits``-bit levels, as a camera's file does."""
    levels = 2 ** check_positive(bits, "bits", integer=True) - 1
    img = np.asarray(image)
    return (np.round(np.clip(img, 0, 1) * levels) / levels).astype(img.dtype)


def render_shapes(shape, shapes, background: float = 0.15, supersample: int = 4
                  ) -> np.ndarray:
    """Flat shapes on a flat ground, anti-aliased by supersampling: edges known exactly.

    Parameters
    ----------
    shape : tuple of int
        ``(rows, cols)``.
    shapes : sequence of (kind, geometry, level)
        ``("disc", (row, col, radius), level)`` or ``("poly", vertices, level)`` with
        ``vertices`` an (n, 2) array of ``(row, col)`` of a convex polygon; later shapes
        cover earlier ones.
    background : float
        Grey level of the ground.
    supersample : int
        Samples per pixel along each axis.

    Returns
    -------
    ndarray of shape ``shape``, float32
        See :func:`distance_to_edges` for where the edges are.
    """
    rr, cc = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    out = np.zeros(shape)
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    for dr in offsets:
        for dc in offsets:
            sub = np.full(shape, background)
            for kind, geo, level in shapes:
                sub[_inside_shape(kind, geo, rr + dr, cc + dc)] = level
            out += sub
    return (out / supersample**2).astype(np.float32)


def _inside_shape(kind, geo, r, c) -> np.ndarray:
    if kind == "disc":
        return (r - geo[0]) ** 2 + (c - geo[1]) ** 2 <= geo[2] ** 2
    centre = geo.mean(0)
    inside = np.ones(r.shape, bool)
    for a, b in zip(geo, np.roll(geo, -1, 0), strict=True):
        normal = np.array([-(b[1] - a[1]), b[0] - a[0]])
        side = np.sign((centre - a) @ normal)
        inside &= ((r - a[0]) * normal[0] + (c - a[1]) * normal[1]) * side >= 0
    return inside


def distance_to_edges(shapes, points) -> np.ndarray:
    """Distance (px) from ``points`` (n, 2) ``(row, col)`` to the nearest edge of ``shapes``.

    ``shapes`` as for :func:`render_shapes`; returns an (n,) array.
    """
    points = np.asarray(points, float)
    best = np.full(len(points), np.inf)
    for kind, geo, _ in shapes:
        if kind == "disc":
            d = np.abs(np.hypot(points[:, 0] - geo[0], points[:, 1] - geo[1]) - geo[2])
        else:
            d = np.full(len(points), np.inf)
            for a, b in zip(geo, np.roll(geo, -1, 0), strict=True):
                ab = b - a
                t = np.clip((points - a) @ ab / (ab @ ab), 0, 1)
                d = np.minimum(d, np.hypot(*(points - (a + t[:, None] * ab)).T))
        best = np.minimum(best, d)
    return best


def edge_scene(shape=(256, 256), rng=None) -> np.ndarray:
    """An edge-rich synthetic scene like the paper's Fig. 3: discs and polygons on a dark ground.

    Parameters
    ----------
    shape : tuple of int
        ``(rows, cols)``.
    rng : None, int or Generator
        Varies grey levels and polygon orientations.

    Returns
    -------
    ndarray of float32, shape ``shape``
        Flat regions in [0.1, 0.9] separated by straight and circular step edges.
    """
    from skimage.draw import disk, polygon

    rng = as_rng(rng)
    rows, cols = (int(s) for s in shape)
    img = np.full((rows, cols), 0.12, np.float32)
    n = 3
    cell_r, cell_c = rows / n, cols / n
    for i in range(n):
        for j in range(n):
            cr, cc = (i + 0.5) * cell_r, (j + 0.5) * cell_c
            radius = 0.32 * min(cell_r, cell_c)
            level = rng.uniform(0.55, 0.9)
            if (i + j) % 2 == 0:
                rr, cc_ = disk((cr, cc), radius, shape=(rows, cols))
            else:
                k = rng.integers(3, 7)
                phase = rng.uniform(0, 2 * np.pi)
                ang = phase + 2 * np.pi * np.arange(k) / k
                rr, cc_ = polygon(cr + 1.15 * radius * np.sin(ang),
                                  cc + 1.15 * radius * np.cos(ang), shape=(rows, cols))
            img[rr, cc_] = level
    return img


def sample_image(name: str, size: int | None = None) -> np.ndarray:
    """A bundled scikit-image photo (gray, float32 in [0, 1]) or the synthetic ``"edges"`` scene.

    Parameters
    ----------
    name : str
        One of :data:`SAMPLE_IMAGES`.
    size : int, optional
        Resize (anti-aliased) so the longer side is ``size`` pixels.
    """
    check_choice(name, "name", SAMPLE_IMAGES)
    from skimage import color, data, transform

    if name == "edges":
        s = size or 512
        return edge_scene((s, s), rng=0)
    img = getattr(data, name)()
    if img.ndim == 3:
        img = color.rgb2gray(img[..., :3])
    img = as_float_image(img).astype(np.float32)
    if size is not None and max(img.shape) != size:
        scale = size / max(img.shape)
        out_shape = tuple(max(2, round(s * scale)) for s in img.shape)
        img = transform.resize(img, out_shape, anti_aliasing=True).astype(np.float32)
    return img


@dataclass
class SyntheticCase:
    """One synthetic blur case: sharp image, blurred observation and the true motion."""

    name: str
    sharp: np.ndarray
    blurred: np.ndarray
    motion: CameraMotion
    extent: float
    noise: float

    @property
    def model(self) -> str:
        return self.motion.model


def make_case(image, model: str = "rotation", extent: float = 15.0, noise: float = 0.01,
              bits: int | None = 8, focal_px: float | None = None, n_samples: int = 48,
              rng=None, name: str = "case") -> SyntheticCase:
    """Shake a sharp image with a random trajectory; add noise and quantise.

    Parameters
    ----------
    image : ndarray of shape (H, W)
        Sharp gray image in [0, 1].
    model : {"translation", "inplane", "rotation"}
    extent : float
        Blur extent in pixels (:meth:`CameraMotion.blur_extent` of the true motion; see
        :func:`trajectory_extent`).
    noise : float
        Gaussian noise sigma (fraction of the [0, 1] range).
    bits : int or None
        Quantise to this many bits (None: keep floating point).
    focal_px : float, optional
        Focal length in pixels (default: the engine's default from image size).
    n_samples : int
        Poses along the trajectory.
    rng : None, int or Generator
    name : str

    Returns
    -------
    SyntheticCase
    """
    rng = as_rng(rng)
    sharp = as_float_image(image)
    intr = Intrinsics.from_image_shape(sharp.shape, focal_px=focal_px)
    poses = random_trajectory(model, intr, extent, n_samples=n_samples, rng=rng)
    truth = densify_path(poses, model, intr)
    blurred = render_blur(sharp, truth)
    if noise:
        blurred = add_noise(blurred, noise, rng)
    blurred = quantize(blurred, bits) if bits else np.clip(blurred, 0, 1)
    return SyntheticCase(name, sharp, blurred.astype(sharp.dtype), truth, extent, noise)


def make_dataset(images=("camera", "edges"), models=("inplane", "rotation"),
                 extents=(13.0, 21.0), size: int = 256, noise: float = 0.01, rng=0,
                 n_samples: int = 48) -> list[SyntheticCase]:
    """A small synthetic dataset: every image x model x extent, seeded.

    Used by the tests (small sizes), the benchmarks and the napari sample data.
    """
    rng = as_rng(rng)
    cases = []
    for name in images:
        sharp = sample_image(name, size)
        for model in models:
            for extent in extents:
                cases.append(make_case(sharp, model, extent, noise, rng=rng, n_samples=n_samples,
                                       name=f"{name}-{model}-{extent:g}px"))
    return cases
