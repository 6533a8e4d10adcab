"""Quality metrics: aligned PSNR and SSIM, and PSF normalised cross-correlation.

Protocol. A blind method recovers the sharp image only up to a homography (paper
claim 2): the restored image may sit a sub-pixel or few-pixel shift away from the
ground truth. Before PSNR/SSIM we therefore (1) estimate the global translation
between result and reference by phase correlation with 1/20-pixel precision,
(2) shift the result onto the reference (cubic interpolation), and (3) crop a
border band (default: 5% of the smaller side, at least the largest shift) where
shifting and boundary effects live. PSFs are compared after moving each one's
centroid to its centre (claims 1-2), by zero-mean normalised cross-correlation.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from .motion import CameraMotion, _grid_points

__all__ = ["align_to", "aligned_psnr", "aligned_ssim", "motion_psf_ncc", "psf_ncc", "psnr"]


def psnr(result, reference, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio (dB) of ``result`` against ``reference``."""
    a = np.asarray(result, np.float64)
    b = np.asarray(reference, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"result and reference must have the same shape; got {a.shape} and "
                         f"{b.shape}")
    mse = np.mean((a - b) ** 2)
    return float(10 * np.log10(data_range**2 / max(mse, 1e-20)))


def align_to(result, reference, max_shift: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Shift ``result`` onto ``reference`` by the global sub-pixel translation between them.

    Returns the shifted result and the shift ``(drow, dcol)`` that was applied.
    A shift larger than ``max_shift`` (default: 10% of the smaller side) is taken
    as a failed registration and not applied.
    """
    from skimage.registration import phase_cross_correlation

    a = np.asarray(result, np.float64)
    b = np.asarray(reference, np.float64)
    gray_a = a if a.ndim == 2 else a.mean(-1)
    gray_b = b if b.ndim == 2 else b.mean(-1)
    shift, _, _ = phase_cross_correlation(gray_b, gray_a, upsample_factor=20,
                                          normalization=None)
    if max_shift is None:
        max_shift = 0.1 * min(gray_a.shape)
    if np.max(np.abs(shift)) > max_shift:
        shift = np.zeros(2)
    full = tuple(shift) + ((0,) if a.ndim == 3 else ())
    return ndimage.shift(a, full, order=3, mode="nearest"), np.asarray(shift)


def _crop(arr, border):
    return arr[border:arr.shape[0] - border, border:arr.shape[1] - border]


def _aligned_pair(result, reference, border):
    shifted, shift = align_to(result, reference)
    if border is None:
        border = int(np.ceil(max(0.05 * min(np.shape(reference)[:2]), np.max(np.abs(shift)))))
    return _crop(np.clip(shifted, 0, 1), border), _crop(np.asarray(reference, np.float64), border)


def aligned_psnr(result, reference, border: int | None = None) -> float:
    """PSNR (dB) after global sub-pixel alignment and a border crop (see module notes)."""
    a, b = _aligned_pair(result, reference, border)
    return psnr(a, b)


def aligned_ssim(result, reference, border: int | None = None) -> float:
    """SSIM after global sub-pixel alignment and a border crop (see module notes)."""
    from skimage.metrics import structural_similarity

    a, b = _aligned_pair(result, reference, border)
    return float(structural_similarity(a, b, data_range=1.0,
                                       channel_axis=-1 if a.ndim == 3 else None))


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


def motion_psf_ncc(estimate: CameraMotion, truth: CameraMotion, grid=(4, 4)) -> float:
    """Mean centroid-aligned PSF NCC of two motions over a grid of image points.

    The estimate is applied at the truth's image size (:meth:`CameraMotion.rescale`).
    """
    est = estimate.rescale(truth.image_shape)
    points = _grid_points(truth.image_shape, grid)
    size = max(est.psf_size(points), truth.psf_size(points))
    ka = est.psf(points, size)
    kb = truth.psf(points, size)
    return float(np.mean([psf_ncc(x, y) for x, y in zip(ka, kb, strict=True)]))
