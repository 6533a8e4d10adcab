"""Quality metrics: aligned PSNR and SSIM, PSF normalised cross-correlation, profile fidelity.

Protocol. A blind method recovers the sharp image only up to a homography (paper
claim 2): the restored image may sit a sub-pixel or few-pixel shift away from the
ground truth. Before PSNR/SSIM we therefore (1) estimate the global translation
between result and reference by phase correlation with 1/20-pixel precision,
(2) shift the result onto the reference (cubic interpolation), and (3) crop a
border band (default: 5% of the smaller side, at least the largest shift) where
shifting and boundary effects live. With ``rotation=True`` the in-plane rotation
about the image centre is searched as well (the best PSNR over angles, each with its
own best shift): a camera-rotation estimate is right only up to its centroid pose,
which for a recorded trajectory that starts at the identity is rotated by up to
about a degree, and a shift alone then scores even a perfect restoration below the
blurred input. PSFs are compared after moving each one's centroid to its centre
(claims 1-2), by zero-mean normalised cross-correlation.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from ._validation import check_positive
from .motion import CameraMotion, _grid_points

__all__ = ["align_to", "aligned_psnr", "aligned_scores", "aligned_ssim", "band_sigma_for_upscale",
           "motion_psf_ncc", "profile_fidelity", "psf_ncc", "psnr", "true_profile_derivatives"]

#: Largest in-plane rotation (degrees) searched by the rotation-aware alignment.
MAX_ROTATION_DEG = 2.0


def psnr(result, reference, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio (dB) of ``result`` against ``reference``."""
    a = np.asarray(result, np.float64)
    b = np.asarray(reference, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"result and reference must have the same shape; got {a.shape} and "
                         f"{b.shape}")
    mse = np.mean((a - b) ** 2)
    return float(10 * np.log10(data_range**2 / max(mse, 1e-20)))


def align_to(result, reference, max_shift: float | None = None, *,
             upsample: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Shift ``result`` onto ``reference`` by the global sub-pixel translation between them.

    Returns the shifted result and the shift ``(drow, dcol)`` that was applied, found by
    phase correlation to ``1/upsample`` px. A shift larger than ``max_shift`` (default:
    10% of the smaller side) is taken as a failed registration and not applied.
    """
    from skimage.registration import phase_cross_correlation

    a = np.asarray(result, np.float64)
    b = np.asarray(reference, np.float64)
    gray_a = a if a.ndim == 2 else a.mean(-1)
    gray_b = b if b.ndim == 2 else b.mean(-1)
    shift, _, _ = phase_cross_correlation(gray_b, gray_a, upsample_factor=upsample,
                                          normalization=None)
    if max_shift is None:
        max_shift = 0.1 * min(gray_a.shape)
    if np.max(np.abs(shift)) > max_shift:
        shift = np.zeros(2)
    full = tuple(shift) + ((0,) if a.ndim == 3 else ())
    return ndimage.shift(a, full, order=3, mode="nearest"), np.asarray(shift)


def _crop(arr, border):
    return arr[border:arr.shape[0] - border, border:arr.shape[1] - border]


def _rotate(a: np.ndarray, degrees: float) -> np.ndarray:
    """``a`` rotated by ``degrees`` about its centre (cubic, same shape)."""
    if degrees == 0:
        return a
    return ndimage.rotate(a, degrees, axes=(1, 0), reshape=False, order=3, mode="nearest")


def _shift_pair(result, reference, border, rotation_deg=0.0):
    shifted, shift = align_to(_rotate(np.asarray(result, np.float64), rotation_deg), reference)
    if border is None:
        # the rotation moves the corners by up to r * angle: crop them too
        reach = np.deg2rad(abs(rotation_deg)) * 0.5 * np.hypot(*np.shape(reference)[:2])
        border = int(np.ceil(max(0.05 * min(np.shape(reference)[:2]),
                                 np.max(np.abs(shift)) + reach)))
    return _crop(np.clip(shifted, 0, 1), border), _crop(np.asarray(reference, np.float64), border)


def _best_rotation(result, reference) -> float:
    """The in-plane rotation (degrees, |angle| <= MAX_ROTATION_DEG) that, with its best
    shift, gives the highest PSNR: a grid of 0.25 degrees, then a bounded scalar search."""
    from scipy.optimize import minimize_scalar

    # on a half-size luminance copy: the angle is found to a small fraction of a degree
    def small(a):
        a = np.asarray(a, np.float64)
        a = a if a.ndim == 2 else a.mean(-1)
        return ndimage.zoom(a, 0.5, order=1) if min(a.shape) >= 128 else a

    res, ref = small(result), small(reference)
    border = int(np.ceil(0.05 * min(ref.shape))) + 2 + int(
        np.ceil(np.deg2rad(MAX_ROTATION_DEG) * 0.5 * np.hypot(*ref.shape)))

    def cost(angle):
        return -psnr(*_shift_pair(res, ref, border, angle))

    grid = np.arange(-MAX_ROTATION_DEG, MAX_ROTATION_DEG + 1e-9, 0.25)
    costs = [cost(a) for a in grid]
    best = int(np.argmin(costs))
    lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)]
    found = minimize_scalar(cost, bounds=(lo, hi), method="bounded",
                            options={"xatol": 0.01})
    return float(found.x) if found.fun <= costs[best] else float(grid[best])


def _aligned_pair(result, reference, border, rotation: bool = False):
    angle = _best_rotation(result, reference) if rotation else 0.0
    return _shift_pair(result, reference, border, angle)


def aligned_psnr(result, reference, border: int | None = None, *,
                 rotation: bool = False) -> float:
    """PSNR (dB) after global sub-pixel alignment and a border crop (see module notes).

    ``rotation=True`` also searches the in-plane rotation about the centre (within
    :data:`MAX_ROTATION_DEG`), for motions that are right up to a rotated centroid pose.
    """
    a, b = _aligned_pair(result, reference, border, rotation)
    return psnr(a, b)


def aligned_ssim(result, reference, border: int | None = None, *,
                 rotation: bool = False) -> float:
    """SSIM after global sub-pixel alignment and a border crop (see module notes)."""
    return aligned_scores(result, reference, border, rotation=rotation)[1]


def aligned_scores(result, reference, border: int | None = None, *,
                   rotation: bool = False) -> tuple[float, float]:
    """``(PSNR, SSIM)`` after one alignment (the rotation search is the costly part)."""
    from skimage.metrics import structural_similarity

    a, b = _aligned_pair(result, reference, border, rotation)
    ssim = structural_similarity(a, b, data_range=1.0, channel_axis=-1 if a.ndim == 3 else None)
    return psnr(a, b), float(ssim)


def _centre_psf(k: np.ndarray, size: int) -> np.ndarray:
    """Embed PSF ``k`` in a ``size`` x ``size`` array with its centroid at the centre."""
    k = np.asarray(k, np.float64)
    total = k.sum()
    out = np.zeros((size, size))
    r0 = (size - k.shape[0]) // 2
    c0 = (size - k.shape[1]) // 2
    out[r0:r0 + k.shape[0], c0:c0 + k.shape[1]] = k
    if total <= 0:
        return out
    rr, cc = np.indices(out.shape)
    centroid = np.array([(rr * out).sum(), (cc * out).sum()]) / total
    # band-limited (Fourier) shift: unitary, so the NCC does not depend on how the
    # sub-pixel parts of the two centroids happen to fall
    spectrum = ndimage.fourier_shift(np.fft.fft2(out), (size - 1) / 2 - centroid)
    return np.fft.ifft2(spectrum).real


def psf_ncc(a, b) -> float:
    """Zero-mean normalised cross-correlation of two PSFs after centroid alignment.

    Parameters
    ----------
    a, b : ndarray of shape (Ka, Ka) and (Kb, Kb)
        PSFs (any sizes; both are embedded in a common frame, centroid at the centre).

    Returns
    -------
    float
        In [-1, 1]; 1 means identical shapes.
    """
    size = 2 * max(np.shape(a)[0], np.shape(b)[0]) + 1
    x = _centre_psf(a, size).ravel()
    y = _centre_psf(b, size).ravel()
    x -= x.mean()
    y -= y.mean()
    den = np.linalg.norm(x) * np.linalg.norm(y)
    return float(x @ y / den) if den > 0 else 0.0


def motion_psf_ncc(estimate: CameraMotion, truth: CameraMotion, grid=(4, 4),
                   band_sigma: float = 0.0) -> float:
    """Mean centroid-aligned PSF NCC of two motions over a grid of image points.

    The estimate is applied at the truth's image size (:meth:`CameraMotion.rescale`).

    Parameters
    ----------
    estimate, truth : CameraMotion
    grid : (int, int)
        Rows and columns of the image points.
    band_sigma : float
        When positive, both PSFs are low-passed by a Gaussian of this standard deviation
        (pixels) before they are compared: the PSF NCC *at the resolution the photo
        carries*. A photo whose finest detail is ``u`` pixels across (an image upscaled
        ``u`` times has nothing above ``1 / (2 u)`` cycles per pixel) cannot determine a
        PSF's structure finer than that, whatever the estimator; :func:`band_sigma_for_upscale`
        gives the matching ``band_sigma``.
    """
    band_sigma = check_positive(band_sigma, "band_sigma", allow_zero=True)
    est = estimate.rescale(truth.image_shape)
    points = _grid_points(truth.image_shape, grid)
    pad = 2 * math.ceil(3 * band_sigma) if band_sigma > 0 else 0
    size = max(est.psf_size(points), truth.psf_size(points)) + pad
    ka = est.psf(points, size)
    kb = truth.psf(points, size)
    if band_sigma > 0:
        ka = [ndimage.gaussian_filter(k, band_sigma, mode="constant") for k in ka]
        kb = [ndimage.gaussian_filter(k, band_sigma, mode="constant") for k in kb]
    return float(np.mean([psf_ncc(x, y) for x, y in zip(ka, kb, strict=True)]))


def band_sigma_for_upscale(factor: float) -> float:
    """Gaussian (px) with transfer 1/2 at the Nyquist limit of a photo upscaled ``factor`` x.

    An image upscaled ``u`` times carries no frequency above ``f_c = 1 / (2 u)`` cycles
    per pixel; ``exp(-2 pi^2 sigma^2 f_c^2) = 1/2`` gives
    ``sigma = sqrt(ln 2 / 2) 2 u / pi`` (about ``0.375 u``). For :func:`motion_psf_ncc`'s
    ``band_sigma``; 0 for a photo at its own resolution (``factor <= 1``).
    """
    factor = check_positive(factor, "factor")
    return math.sqrt(math.log(2.0) / 2.0) * 2.0 * factor / math.pi if factor > 1.0 else 0.0


def _transition_width(derivative: np.ndarray, offsets: np.ndarray) -> float:
    """Distance between the 10 % and 90 % points of the integrated (clipped) derivative."""
    d = np.clip(np.asarray(derivative, np.float64), 0, None)
    total = d.sum()
    if total <= 0:
        return float("nan")
    cdf = np.cumsum(d) / total
    lo, hi = np.interp([0.1, 0.9], cdf, offsets)
    return float(max(hi - lo, 1e-6))


def true_profile_derivatives(profiles, truth: CameraMotion, size: int | None = None):
    """The true local PSF's projection on each profile's normal, on the profile's offsets.

    Eq. 11: every pixel ``(u, v)`` of the true PSF at the centroid puts its mass at
    ``rho = u cos(phi) + v sin(phi)``; the projection is centroid-aligned (claims 1-2)
    and splatted linearly into the profile's one-pixel bins.

    Parameters
    ----------
    profiles : EdgeProfiles
        N profiles of the blurred image ``truth`` describes (same pixel grid).
    truth : CameraMotion

    Returns
    -------
    ndarray of shape (N, len(profiles.offsets))
    """
    offsets = np.asarray(profiles.offsets, np.float64)
    n = len(profiles)
    out = np.zeros((n, offsets.size))
    if n == 0:
        return out
    points = np.asarray(profiles.centroids, np.float64)
    size = size or truth.psf_size(points)
    psfs = truth.psf(points, size)
    half = (size - 1) // 2
    v, u = np.mgrid[-half:half + 1, -half:half + 1]
    for i, (k, phi) in enumerate(zip(psfs, profiles.normal_angle, strict=True)):
        rho = (u * np.cos(phi) + v * np.sin(phi)).ravel()
        w = k.ravel()
        if w.sum() <= 0:
            continue
        pos = rho - (rho @ w) / w.sum() - offsets[0]
        j = np.floor(pos).astype(int)
        f = pos - j
        for jj, ww in ((j, (1 - f) * w), (j + 1, f * w)):
            ok = (jj >= 0) & (jj < offsets.size)
            np.add.at(out[i], jj[ok], ww[ok])
    return out


def profile_fidelity(profiles, truth: CameraMotion) -> tuple[np.ndarray, np.ndarray]:
    """How true each edge profile is to the local blur it claims to measure.

    Parameters
    ----------
    profiles : EdgeProfiles
        N extracted profiles of a blurred image.
    truth : CameraMotion
        The true motion of that image.

    Returns
    -------
    ncc : ndarray of shape (N,)
        Zero-mean NCC between each profile's derivative and the true PSF's
        centroid-aligned projection on its normal (:func:`true_profile_derivatives`).
    width_ratio : ndarray of shape (N,)
        The profile's 10-90 % transition width over the true projection's.
    """
    truth_d = true_profile_derivatives(profiles, truth)
    deriv = np.asarray(profiles.derivatives, np.float64).reshape(truth_d.shape)
    a = deriv - deriv.mean(1, keepdims=True)
    b = truth_d - truth_d.mean(1, keepdims=True)
    den = np.sqrt((a * a).sum(1) * (b * b).sum(1))
    ncc = np.divide((a * b).sum(1), den, out=np.zeros(len(den)), where=den > 0)
    offsets = np.asarray(profiles.offsets, np.float64)
    ratio = np.array([_transition_width(d, offsets) / _transition_width(t, offsets)
                      for d, t in zip(deriv, truth_d, strict=True)])
    return ncc, ratio
