"""Prediction image ``I_p``, edge-profile image ``I_ep`` and their masks (paper §4.2, Fig. 3).

By claims 1-2 the centroid of an edge profile is where the sharp step edge lies in the
centroid-aligned latent image; by claim 3 (Eq. 20) the blurred image's gradient across
that edge is ``|c1 - c2|`` times the PSF's projection on the normal. So

* ``I_p`` -- thin line segments through the centroids along the edge tangents, each with
  ``|c1 - c2|`` per unit length across the line: the gradient magnitude of the ideal
  step edges;
* ``I_ep`` -- the gradient of the blurred image, kept only inside masks around the
  centroids: a line along the normal (``mask="single"``) or an angular window around
  the normal (``mask="multi"``, more robust to errors in the estimated orientation);

are related by the blur (Eq. 19): ``M . T_w(I_p) ~ M . I_ep``. Blurring a line along the
tangent integrates the PSF along the tangent, which leaves exactly its projection on the
normal. Since ``T_w`` is linear in the MDF weights ``w``, the data term of Eq. 19 is
``mask * (EfficientFilterFlowWeights(I_p, model, intrinsics, poses).forward(w) - I_ep)``.

Both images can be built at any level of an image pyramid: pass the downscaled image
and ``scale`` (new size over original size); centroids map as pixel centres do under
resizing, ``(p + 0.5) * scale - 0.5``, like :meth:`EdgeProfiles.rescaled` and
:meth:`~napari_edgecme.core.camera.Intrinsics.rescaled`.
"""

from __future__ import annotations

import math

import numpy as np

from ._validation import check_choice, check_positive, float_dtype
from .edges import EdgeProfiles, to_luminance

__all__ = ["MASKS", "edge_profile_image", "prediction_image", "profile_masks"]

#: Mask kinds of :func:`edge_profile_image`.
MASKS = ("single", "multi")

#: Standard deviation (px) of the Gaussian cross-section of the prediction lines: the
#: smoothing of the central differences that make ``I_ep`` (a box of two pixels, whose
#: standard deviation is 1/sqrt(3) px), and wide enough that a line sampled on the
#: pixel grid keeps its mass per unit length at every angle (within 1%).
_LINE_SIGMA = 0.55

#: Default total width (radians) of the angular window of the multi-direction mask.
DEFAULT_ANGULAR_WIDTH = math.radians(20.0)


def _check_profiles(profiles) -> EdgeProfiles:
    if not isinstance(profiles, EdgeProfiles):
        raise ValueError(f"profiles must be an EdgeProfiles; got {type(profiles).__name__}")
    return profiles


def _check_shape(shape) -> tuple[int, int]:
    try:
        dims = tuple(int(s) for s in tuple(shape)[:2])
    except (TypeError, ValueError):
        raise ValueError(f"shape must be (rows, cols); got {shape!r}") from None
    if len(dims) != 2 or min(dims) < 1:
        raise ValueError(f"shape must be two positive integers (rows, cols); got {shape!r}")
    return dims


def _scaled_centroids(profiles: EdgeProfiles, scale: float) -> np.ndarray:
    return (profiles.centroids + 0.5) * scale - 0.5


def _default_line_length(profiles: EdgeProfiles, scale: float) -> np.ndarray:
    blur = profiles.max_blur
    if blur is None:  # fall back on the profile grid: R = max_blur + margins
        blur = 0.75 * float(np.max(np.abs(profiles.offsets)))
    # the line must cover the PSF's tangential reach (about blur / 2 each side) plus the
    # lateral extent of the default multi-direction mask where it is compared
    reach = profiles.window * scale * math.tan(DEFAULT_ANGULAR_WIDTH / 2)
    return np.maximum(3.0, blur * scale + 2.0 * reach + 1.0)


def _stencil(centres, half: int, shape):
    """Pixels of a (2 half + 1)^2 square around each centre: flat index, (drow, dcol), inside."""
    H, W = shape
    base = np.round(centres).astype(np.int64)
    d = np.arange(-half, half + 1)
    dr, dc = np.meshgrid(d, d, indexing="ij")
    rows = base[:, 0, None] + dr.ravel()[None]
    cols = base[:, 1, None] + dc.ravel()[None]
    inside = (rows >= 0) & (rows < H) & (cols >= 0) & (cols < W)
    flat = np.where(inside, rows * W + cols, 0)
    return flat, rows - centres[:, 0, None], cols - centres[:, 1, None], inside


def prediction_image(profiles: EdgeProfiles, shape, *, scale: float = 1.0,
                     line_length: float | None = None, dtype=np.float32) -> np.ndarray:
    """The prediction image ``I_p`` (paper §4.2, Fig. 3b, claim 3).

    Parameters
    ----------
    profiles : EdgeProfiles
        Centroid-aligned profiles (of the full-resolution image).
    shape : tuple of int
        ``(rows, cols)`` of the image at this pyramid level.
    scale : float
        Size of this level over the profiles' image (1 at full resolution).
    line_length : float, optional
        Length (px at this level) of every segment. Default, per profile,
        ``max_blur * scale + 2 * reach + 1`` with ``reach = window * scale * tan(w / 2)``
        the lateral half-width of the default multi-direction mask at the end of the
        profile's validated window (see :func:`edge_profile_image`): long enough that
        blurring the segment integrates the whole PSF along the tangent everywhere
        inside the mask.
    dtype : dtype
        float32 (default) or float64.

    Returns
    -------
    ndarray of shape ``shape``
        Each segment passes through a (scaled) centroid along the edge tangent (bent by
        the profile's measured ``curvature``, so that round edges stay round) with a
        Gaussian cross-section (standard deviation 0.55 px) whose integral across the
        line is ``|c1 - c2|``; along the segment the ends are anti-aliased. Where
        segments overlap (neighbouring profiles on one edge) the larger value is kept,
        so that a continuous edge is one line, not a sum of overlapping ones.

    Notes
    -----
    Blurring ``I_p`` by the PSF ``k`` gives, at offset ``rho`` along the normal from a
    centroid, ``|c1 - c2| * int k(rho n + s t) ds = |c1 - c2| P(rho)`` -- the gradient
    magnitude of the blurred step (Eq. 20).
    """
    profiles = _check_profiles(profiles)
    H, W = _check_shape(shape)
    scale = check_positive(scale, "scale")
    dtype = float_dtype(dtype)
    out = np.zeros(H * W, dtype)
    if len(profiles) == 0:
        return out.reshape(H, W)
    if line_length is None:
        lengths = _default_line_length(profiles, scale)
    else:
        lengths = np.full(len(profiles), check_positive(line_length, "line_length"))
    centres = _scaled_centroids(profiles, scale)
    half = math.ceil(float(lengths.max()) / 2.0 + 1.5)
    norm = 1.0 / (_LINE_SIGMA * math.sqrt(2 * math.pi))
    for sl in _blocks(len(profiles), half):
        flat, drow, dcol, inside = _stencil(centres[sl], half, (H, W))
        phi = profiles.normal_angle[sl, None]
        along = drow * np.cos(phi) - dcol * np.sin(phi)  # along the tangent
        # distance along the normal from the (curved) edge through the centroid
        across = (drow * np.sin(phi) + dcol * np.cos(phi)
                  - 0.5 * (profiles.curvature[sl, None] / scale) * along**2)
        near = inside & (np.abs(across) <= 3.5 * _LINE_SIGMA)
        ends = np.clip(lengths[sl, None] / 2.0 + 0.5 - np.abs(along), 0.0, 1.0)
        val = (profiles.contrast[sl, None] * norm * np.exp(-0.5 * (across / _LINE_SIGMA) ** 2)
               * ends)
        keep = near & (val > 0)
        np.maximum.at(out, flat[keep], val[keep].astype(dtype))
    return out.reshape(H, W)


#: Stencil pixels handled at once (bounds the memory for many profiles and large masks).
_BLOCK_PIXELS = 1 << 21


def _blocks(n: int, half: int):
    """Slices of profiles whose stencils hold at most :data:`_BLOCK_PIXELS` pixels."""
    per = (2 * half + 1) ** 2
    step = max(1, _BLOCK_PIXELS // per)
    for start in range(0, n, step):
        yield slice(start, min(n, start + step))


def _default_radius(profiles: EdgeProfiles, scale: float) -> float:
    return float(np.max(np.abs(profiles.offsets))) * scale if profiles.offsets.size else 1.0


def profile_masks(profiles: EdgeProfiles, shape, *, scale: float = 1.0, mask: str = "multi",
                  angular_width: float = DEFAULT_ANGULAR_WIDTH, radius: float | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The single- or multi-direction mask around each centroid, and which profile owns each pixel.

    Parameters
    ----------
    profiles : EdgeProfiles
    shape : tuple of int
        ``(rows, cols)`` at this pyramid level.
    scale : float
        Size of this level over the profiles' image.
    mask : {"single", "multi"}
        ``"single"``: the normal line through the centroid (pixels within half a pixel
        of it). ``"multi"``: that line plus the double wedge of total opening
        ``angular_width`` around it (paper §4.2).
    angular_width : float
        Total opening (radians) of the wedge; default 20 degrees.
    radius : float, optional
        How far along the normal (px at this level) the mask reaches from the centroid;
        default the profiles' half-length ``R * scale``. Each profile's mask is also
        limited to its validated window (``profiles.window * scale``), where no other
        edge was seen.

    Returns
    -------
    mask : ndarray of bool, shape ``shape``
    owner : ndarray of int64, shape ``shape``
        Index of the profile whose mask covers the pixel (the nearest centroid where
        masks overlap), -1 outside.
    """
    profiles = _check_profiles(profiles)
    H, W = _check_shape(shape)
    scale = check_positive(scale, "scale")
    check_choice(mask, "mask", MASKS)
    angular_width = check_positive(angular_width, "angular_width", allow_zero=True,
                                   maximum=math.pi / 2)
    radius = _default_radius(profiles, scale) if radius is None else check_positive(
        radius, "radius")
    owner = np.full(H * W, -1, np.int64)
    if len(profiles) == 0:
        return owner.reshape(H, W) >= 0, owner.reshape(H, W)
    centres = _scaled_centroids(profiles, scale)
    half = math.ceil(radius + 1.0)
    slope = math.tan(angular_width / 2)
    reach_all = np.minimum(radius, profiles.window * scale)

    def covered(sl):
        """Flat indices, distances to the centroid and the profile of each masked pixel."""
        flat, drow, dcol, inside = _stencil(centres[sl], half, (H, W))
        phi = profiles.normal_angle[sl, None]
        across = drow * np.sin(phi) + dcol * np.cos(phi)
        along = drow * np.cos(phi) - dcol * np.sin(phi)
        near = inside & (np.abs(across) <= reach_all[sl, None])
        sel = near & (np.abs(along) <= 0.5)
        if mask == "multi":
            sel |= near & (np.abs(along) <= np.abs(across) * slope)
        idx = np.broadcast_to(np.arange(sl.start, sl.stop)[:, None], flat.shape)
        return flat[sel], np.hypot(across, along)[sel], idx[sel]

    # the nearest centroid wins where masks overlap; ties go to the lowest index
    best = np.full(H * W, np.inf)
    for sl in _blocks(len(profiles), half):
        flat, dist, _ = covered(sl)
        np.minimum.at(best, flat, dist)
    for sl in reversed(list(_blocks(len(profiles), half))):
        flat, dist, idx = covered(sl)
        win = dist <= best[flat]
        order = np.argsort(-idx[win], kind="stable")  # higher indices first, lowest last
        owner[flat[win][order]] = idx[win][order]
    owner = owner.reshape(H, W)
    return owner >= 0, owner


def edge_profile_image(image, profiles: EdgeProfiles, *, scale: float = 1.0,
                       mask: str = "multi", angular_width: float = DEFAULT_ANGULAR_WIDTH,
                       radius: float | None = None, gradient: str = "normal"
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The edge-profile image ``I_ep`` and its mask (paper §4.2, Fig. 3c-d).

    Parameters
    ----------
    image : array_like of shape (H, W) or (H, W, 3)
        The blurred image at this pyramid level (already resized by the caller); RGB is
        reduced to luminance. Any finite intensity range (``I_ep`` is linear in it).
    profiles : EdgeProfiles
        Centroid-aligned profiles of the full-resolution image.
    scale : float
        Size of ``image`` over the profiles' image.
    mask : {"single", "multi"}
        Single-direction (the normal line) or multi-direction (angular window) mask;
        see :func:`profile_masks`.
    angular_width : float
        Total opening of the multi-direction window (radians, default 20 degrees).
    radius : float, optional
        Reach of the masks along the normal (px at this level); default ``R * scale``.
    gradient : {"normal", "magnitude"}
        ``"magnitude"``: ``|grad g|``, as in the paper (claim 3). ``"normal"``
        (default): ``grad g . n`` with ``n`` the normal of the profile that owns the
        pixel -- the same quantity on an edge, but unbiased under noise (the magnitude
        of a noisy gradient is positive on average, which the data term would read as
        blur spreading into the flat margins).

    Returns
    -------
    I_ep : ndarray of shape (H, W)
        The gradient inside the mask, zero outside; float32 (float64 kept).
    mask : ndarray of bool, shape (H, W)

    Notes
    -----
    Gradients are central differences (:func:`numpy.gradient`), in intensity per pixel
    of this level, so that ``I_ep`` integrates to ``|c1 - c2|`` across an edge at every
    level, like ``I_p``.
    """
    # I_ep is linear in the intensities, so any finite range is valid here: the
    # estimator passes its contrast-stretched pyramid levels
    img = to_luminance(image, check_range=False)
    profiles = _check_profiles(profiles)
    check_choice(gradient, "gradient", ("normal", "magnitude"))
    keep, owner = profile_masks(profiles, img.shape, scale=scale, mask=mask,
                                angular_width=angular_width, radius=radius)
    gy, gx = np.gradient(img)
    if gradient == "magnitude":
        g = np.hypot(gx, gy)
    else:
        phi = profiles.normal_angle[np.where(keep, owner, 0)] if len(profiles) else 0.0
        g = gx * np.cos(phi) + gy * np.sin(phi)
    out = np.where(keep, g, 0).astype(img.dtype)
    return out, keep
