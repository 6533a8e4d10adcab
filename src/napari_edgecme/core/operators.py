"""The blur operator ``T_w`` of paper Eq. 8, two ways, each in two linear views.

``g(x) = sum_p w_p f(H_p^-1 x)`` is linear in the sharp image ``f`` for fixed MDF
weights ``w``, and linear in ``w`` for a fixed image. Both views exist for

* the **exact warp-sum** -- one bilinear warp per active pose, the reference; and
* the **efficient filter flow** (EFF, Hirsch et al. 2010) -- the image is cut into
  overlapping patches under windows ``omega_r`` that sum to one, each patch is
  convolved with the PSF at its window centre (rendered from the MDF, Eq. 9) by
  FFT and the results are overlap-added:
  ``T_w f = sum_r C_r^T (k_r * (omega_r . C_r f))`` with ``k_r = B_r w``.

Every operator is a :class:`~napari_edgecme.core.linop.LinearOperator` with an exact
adjoint, so it composes with the crop, the finite differences and the other
operators of :mod:`~napari_edgecme.core.linop` (``M T``, ``T^T T + beta D^T D``), and
the one parametrised dot test of ``tests/core/test_operators.py`` covers it. Values
outside the array are zero for every operator.

Constructors follow what each view holds fixed: an image view is built from the
motion it blurs with, ``WarpSum(motion, shape, origin)``; a weights view from the
fixed image and the pose set its weights live on,
``WarpSumWeights(image, model, intrinsics, poses, origin)`` -- the pose set as
:func:`~napari_edgecme.core.mdf.psf_basis` and
:func:`~napari_edgecme.core.measurement.measurement_matrix` take it.
"""

from __future__ import annotations

import math
import os

import numpy as np
import scipy.fft as sfft
from numpy.lib.stride_tricks import sliding_window_view

from ._validation import as_float_image, check_choice, check_positive, float_dtype
from .camera import (
    Intrinsics,
    check_poses,
    displacements,
    homographies,
    invert_homographies,
    warp_points,
)
from .linop import LinearOperator
from .motion import CameraMotion, psf_matrix, psf_size_for

__all__ = [
    "EfficientFilterFlow",
    "EfficientFilterFlowWeights",
    "PatchGrid",
    "WarpSum",
    "WarpSumWeights",
    "blur",
    "psf_basis",
]

#: Threads scipy.fft may use (-1: all cores), from the environment variable
#: ``EDGECME_FFT_THREADS`` when it is set when the engine is imported: a process that
#: runs beside others of its kind (``edgecme batch``'s workers) sets it to 1.
FFT_WORKERS = int(os.environ.get("EDGECME_FFT_THREADS", "-1") or -1)


# --------------------------------------------------------------------------------------
# exact warp-sum
# --------------------------------------------------------------------------------------

def _bilinear_taps(rows: np.ndarray, cols: np.ndarray, shape) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices and weights of the four bilinear taps at (rows, cols); zero outside.

    Returns ``idx`` and ``wgt``, both (4, n). Sampling is ``(img.ravel()[idx] * wgt).sum(0)``
    and its exact adjoint is ``bincount(idx, wgt * v)`` -- the same taps both ways.
    """
    H, W = shape
    r0 = np.floor(rows).astype(np.int64)
    c0 = np.floor(cols).astype(np.int64)
    fr = rows - r0
    fc = cols - c0
    idx = np.empty((4, rows.size), np.int64)
    wgt = np.empty((4, rows.size), rows.dtype)
    for k, (dr, dc, w) in enumerate(((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc),
                                     (1, 0, fr * (1 - fc)), (1, 1, fr * fc))):
        rr, cc = r0 + dr, c0 + dc
        inside = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
        idx[k] = np.where(inside, rr * W + cc, 0)
        wgt[k] = np.where(inside, w, 0)
    return idx, wgt


def _pose_taps(model, intrinsics, poses, shape, origin):
    """For each pose, the bilinear taps of ``f(H_p^-1 x)`` over the array grid."""
    H, W = shape
    rr, cc = np.meshgrid(np.arange(H, dtype=float) + origin[0],
                         np.arange(W, dtype=float) + origin[1], indexing="ij")
    xy = np.stack([cc.ravel(), rr.ravel()], -1)
    for Hinv in invert_homographies(homographies(model, intrinsics, poses)):
        src = warp_points(Hinv[None], xy)[0]
        yield _bilinear_taps(src[:, 1] - origin[0], src[:, 0] - origin[1], shape)


class WarpSum(LinearOperator):
    """Exact blur ``g = sum_p w_p f(H_p^-1 x)`` (Eq. 8), linear in the image ``f``.

    Parameters
    ----------
    motion : CameraMotion
    shape : tuple of int, optional
        Array shape (default: the motion's image shape).
    origin : tuple of float
        Image pixel ``(row, col)`` of array index ``(0, 0)``; lets the operator act on
        a crop or a padded copy.
    dtype : dtype
        float32 (default) or float64.
    """

    def __init__(self, motion: CameraMotion, shape=None, origin=(0, 0), dtype=np.float32):
        self.motion = motion
        self.shape_in = self.shape_out = tuple(shape or motion.image_shape)
        self.dtype = float_dtype(dtype)
        active = motion.weights > 0
        self._weights = motion.weights[active]
        self._taps = list(_pose_taps(motion.model, motion.intrinsics, motion.poses[active],
                                     self.shape_in, origin))

    def _forward(self, f):
        flat = f.ravel()
        out = np.zeros(flat.size, np.float64)
        for w, (idx, wgt) in zip(self._weights, self._taps, strict=True):
            out += w * (flat[idx] * wgt).sum(0)
        return out.reshape(self.shape_out).astype(self.dtype)

    def _adjoint(self, g):
        flat = g.ravel().astype(np.float64)
        out = np.zeros(flat.size, np.float64)
        for w, (idx, wgt) in zip(self._weights, self._taps, strict=True):
            out += w * np.bincount(idx.ravel(), (wgt * flat).ravel(), minlength=flat.size)
        return out.reshape(self.shape_in).astype(self.dtype)


class WarpSumWeights(LinearOperator):
    """Exact blur of a fixed image, linear in the MDF weights: ``w -> sum_p w_p f(H_p^-1 x)``.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (C, H, W)
        The fixed image(s); channels share the weights.
    model, intrinsics, poses
        The pose set, poses of shape (n, d).
    origin, dtype
        As for :class:`WarpSum`.
    """

    def __init__(self, image, model: str, intrinsics: Intrinsics, poses, origin=(0, 0),
                 dtype=np.float32):
        self.dtype = float_dtype(dtype)
        image = np.asarray(image, self.dtype)
        self._image = image.reshape((-1, *image.shape[-2:]))
        poses = check_poses(poses, model)
        self.shape_in = (len(poses),)
        self.shape_out = image.shape
        shape = image.shape[-2:]
        # columns of the operator: each channel warped by each pose
        self._columns = np.stack([
            (self._image.reshape(len(self._image), -1)[:, idx] * wgt).sum(1)
            for idx, wgt in _pose_taps(model, intrinsics, poses, shape, origin)
        ]).astype(self.dtype)  # (n_poses, C, H*W)

    def _forward(self, w):
        out = np.tensordot(w.astype(np.float64), self._columns, axes=(0, 0))
        return out.reshape(self.shape_out).astype(self.dtype)

    def _adjoint(self, g):
        g = g.reshape(self._columns.shape[1:]).astype(np.float64)
        return np.tensordot(self._columns, g, axes=([1, 2], [0, 1])).astype(self.dtype)


# --------------------------------------------------------------------------------------
# efficient filter flow
# --------------------------------------------------------------------------------------

def _default_stride(psf_size: int) -> int:
    """Tile size: large enough to amortise the PSF margin of each FFT, small enough that
    the PSF varies little across a tile."""
    return max(128, 4 * psf_size)


class PatchGrid:
    """Geometry of the EFF: tiles with tapered overlaps, windows that sum to one.

    The array is cut into tiles of ``stride`` pixels per axis. Each tile's patch
    reaches ``overlap / 2`` pixels into its neighbours; across each overlap the
    windows cross-fade as ``sin^2`` / ``cos^2`` so that they sum to exactly one
    everywhere; the outer sides of border tiles are flat. ``overlap == stride``
    gives the classic half-overlapping raised-cosine windows of Hirsch et al.;
    smaller overlaps trade accuracy for speed (fewer FFT points per pixel).

    Parameters
    ----------
    shape : tuple of int
        ``(H, W)`` of the arrays.
    psf_size : int
        Odd side ``K`` of the per-patch PSFs.
    stride : int or tuple of int, optional
        Target tile size per axis (adjusted so the tiles split the array evenly).
    overlap : int or tuple of int, optional
        Width of the cross-fade between neighbouring tiles (even, at most the tile
        size); default half the tile size.
    """

    def __init__(self, shape, psf_size: int, stride=None, overlap=None):
        self.shape = tuple(int(s) for s in shape)
        self.psf_size = K = int(psf_size)
        self.half = (K - 1) // 2
        if stride is None:
            stride = _default_stride(K)
        stride = (stride, stride) if np.isscalar(stride) else tuple(stride)
        if overlap is not None:
            overlap = (overlap, overlap) if np.isscalar(overlap) else tuple(overlap)
        counts, strides, overlaps, windows, centres = [], [], [], [], []
        for axis, (n, s) in enumerate(zip(self.shape, stride, strict=True)):
            s = check_positive(s, "stride", integer=True)
            m = max(1, math.ceil(n / s))
            s = math.ceil(n / m)
            o = s // 2 if overlap is None else check_positive(overlap[axis], "overlap",
                                                              integer=True, allow_zero=True)
            o = 2 * (min(o, s) // 2)
            counts.append(m)
            strides.append(s)
            overlaps.append(o)
            windows.append(self._windows_1d(m, s, o))
            starts = np.arange(m) * s
            centres.append((starts + np.minimum(starts + s, n) - 1) / 2.0)
        self.counts = tuple(counts)  # tiles per axis
        self.stride = tuple(strides)
        self.overlap = tuple(overlaps)
        self.n_patches = counts[0] * counts[1]
        self.patch_shape = tuple(s + o for s, o in zip(strides, overlaps, strict=True))  # P
        self.out_shape = tuple(p + K - 1 for p in self.patch_shape)  # Q = P + K - 1
        self.fft_shape = tuple(sfft.next_fast_len(q, real=True) for q in self.out_shape)
        #: per-axis windows, shapes (counts[0], P0) and (counts[1], P1)
        self.windows = tuple(windows)
        rr, cc = np.meshgrid(*centres, indexing="ij")
        #: tile centres as array (row, col), shape (n_patches, 2)
        self.centres = np.stack([rr.ravel(), cc.ravel()], -1)

    @staticmethod
    def _windows_1d(m, s, o):
        """Windows of the ``m`` tiles along one axis, (m, s + o); they sum to one."""
        t = (np.arange(o) + 0.5) / max(o, 1)
        rise = np.sin(np.pi / 2 * t) ** 2
        win = np.ones((m, s + o))
        if o:
            win[1:, :o] = rise
            win[:-1, s:] = 1.0 - rise
            win[0, :o // 2] = 0.0  # reaches outside the array: nothing there
            win[-1, s + o // 2:] = 0.0
        return win

    def _window_product(self, dtype):
        wy, wx = (w.astype(dtype) for w in self.windows)
        return wy[:, None, :, None] * wx[None, :, None, :]  # (ny, nx, P0, P1)

    # a canvas holds the array with room for every patch (and its blur margin ``extra``)
    def _canvas_geometry(self, extra):
        lead = [o // 2 + extra for o in self.overlap]
        size = [c * s + o + 2 * extra
                for c, s, o in zip(self.counts, self.stride, self.overlap, strict=True)]
        return lead, size

    def _patches(self, arr, extra, size):
        lead, canvas_size = self._canvas_geometry(extra)
        canvas = np.zeros((*arr.shape[:-2], *canvas_size), arr.dtype)
        canvas[..., lead[0]:lead[0] + self.shape[0], lead[1]:lead[1] + self.shape[1]] = arr
        view = sliding_window_view(canvas, size, axis=(-2, -1))
        return view[..., ::self.stride[0], ::self.stride[1], :, :][
            ..., :self.counts[0], :self.counts[1], :, :]  # (..., ny, nx, *size)

    def windowed_patches(self, arr) -> np.ndarray:
        """``omega_r . C_r arr``: (..., H, W) -> (..., n_patches, P0, P1)."""
        p = self._patches(arr, 0, self.patch_shape) * self._window_product(arr.dtype)
        return p.reshape((*arr.shape[:-2], self.n_patches, *self.patch_shape))

    def output_patches(self, arr) -> np.ndarray:
        """Each patch's blur footprint ``C_r arr`` (patch grown by the PSF).

        Shape (..., n_patches, Q0, Q1).
        """
        p = self._patches(arr, self.half, self.out_shape)
        return p.reshape((*arr.shape[:-2], self.n_patches, *self.out_shape))

    def _add(self, patches, extra, size, dtype):
        lead, canvas_size = self._canvas_geometry(extra)
        canvas = np.zeros((*patches.shape[:-3], *canvas_size), dtype)
        r = 0
        for i in range(self.counts[0]):
            for j in range(self.counts[1]):
                r0, c0 = i * self.stride[0], j * self.stride[1]
                canvas[..., r0:r0 + size[0], c0:c0 + size[1]] += patches[..., r, :, :]
                r += 1
        return canvas[..., lead[0]:lead[0] + self.shape[0], lead[1]:lead[1] + self.shape[1]]

    def add_outputs(self, patches, dtype) -> np.ndarray:
        """Overlap-add blurred patches (..., n_patches, Q0, Q1) into an array (..., H, W)."""
        return self._add(patches, self.half, self.out_shape, dtype)

    def add_windowed(self, patches, dtype) -> np.ndarray:
        """Adjoint of :meth:`windowed_patches`: (..., n_patches, P0, P1) -> (..., H, W)."""
        shaped = patches.reshape((*patches.shape[:-3], *self.counts, *self.patch_shape))
        shaped = shaped * self._window_product(patches.dtype)
        return self._add(shaped.reshape(patches.shape), 0, self.patch_shape, dtype)

    def rfft(self, patches) -> np.ndarray:
        return sfft.rfft2(patches, s=self.fft_shape, axes=(-2, -1), workers=FFT_WORKERS)

    def irfft(self, spectra, crop) -> np.ndarray:
        out = sfft.irfft2(spectra, s=self.fft_shape, axes=(-2, -1), workers=FFT_WORKERS)
        return out[..., :crop[0], :crop[1]]


def psf_basis(model: str, intrinsics: Intrinsics, poses, grid: PatchGrid, origin=(0.0, 0.0),
              dtype=np.float64):
    """Sparse ``B`` (n_patches * K * K, n_poses) of Eq. 9: PSFs at the tile centres.

    ``(B @ w).reshape(n_patches, K, K)`` are the PSFs ``k_r = B_r w`` of the EFF tiles
    for pose weights ``w``; ``origin`` as for :class:`EfficientFilterFlow`.
    """
    centres = grid.centres + np.asarray(origin, float)
    disp = displacements(model, intrinsics, poses, centres)
    return psf_matrix(disp, grid.psf_size, dtype)


def _psf_size_at_centres(model, intrinsics, poses, shape, origin, stride, overlap) -> int:
    """Self-consistent PSF side for the window centres of an EFF on ``shape``."""
    size = 1
    for _ in range(4):  # the centres depend (weakly) on the size through the default stride
        grid = PatchGrid(shape, size, stride, overlap)
        new = psf_size_for(displacements(model, intrinsics, poses,
                                         grid.centres + np.asarray(origin, float)))
        if new <= size:
            return size
        size = new
    return size


class EfficientFilterFlow(LinearOperator):
    """EFF blur (Hirsch et al. 2010), linear in the image.

    ``f -> sum_r C_r^T (k_r * (omega_r C_r f))``.

    Parameters
    ----------
    motion : CameraMotion
        Gives the PSF ``k_r`` at each window centre (Eq. 9).
    shape : tuple of int, optional
        Array shape (default: the motion's image shape).
    origin : tuple of float
        Image pixel ``(row, col)`` of array index ``(0, 0)`` (for crops and padded copies).
    stride, overlap : int, optional
        Tile size and cross-fade width in pixels (see :class:`PatchGrid`).
    psf_size : int, optional
        Odd PSF side (default: the smallest that holds the motion at the centres).
    dtype : dtype
        float32 (default) or float64.
    """

    def __init__(self, motion: CameraMotion, shape=None, origin=(0, 0), stride=None,
                 overlap=None, psf_size=None, dtype=np.float32):
        self.motion = motion
        self.dtype = float_dtype(dtype)
        self.shape_in = self.shape_out = tuple(shape or motion.image_shape)
        if psf_size is None:
            psf_size = _psf_size_at_centres(motion.model, motion.intrinsics, motion.poses,
                                            self.shape_in, origin, stride, overlap)
        self.grid = PatchGrid(self.shape_in, psf_size, stride, overlap)
        B = psf_basis(motion.model, motion.intrinsics, motion.poses, self.grid, origin)
        K = self.grid.psf_size
        #: PSF per window, shape (n_patches, K, K)
        self.psfs = (B @ motion.weights).reshape(-1, K, K).astype(self.dtype)
        self._psf_hat = self.grid.rfft(self.psfs)

    def _forward(self, f):
        g = self.grid
        spectra = g.rfft(g.windowed_patches(f)) * self._psf_hat
        return g.add_outputs(g.irfft(spectra, g.out_shape), self.dtype)

    def _adjoint(self, y):
        g = self.grid
        spectra = g.rfft(g.output_patches(y)) * np.conj(self._psf_hat)
        return g.add_windowed(g.irfft(spectra, g.patch_shape), self.dtype)


class EfficientFilterFlowWeights(LinearOperator):
    """EFF blur of a fixed image, linear in the MDF weights.

    ``w -> sum_r C_r^T ((B_r w) * omega_r C_r f)``.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (C, H, W)
        The fixed image(s) (e.g. the two gradient images of the latent estimate);
        channels share the weights.
    model, intrinsics, poses
        The pose set (n, d) the weights live on.
    origin, stride, overlap, psf_size, dtype
        As for :class:`EfficientFilterFlow`.
    """

    def __init__(self, image, model: str, intrinsics: Intrinsics, poses, origin=(0, 0),
                 stride=None, overlap=None, psf_size=None, dtype=np.float32):
        self.dtype = float_dtype(dtype)
        image = np.asarray(image, self.dtype)
        if image.ndim not in (2, 3):
            raise ValueError(f"image must have shape (H, W) or (C, H, W); got {image.shape}")
        poses = check_poses(poses, model)
        self.shape_in = (len(poses),)
        self.shape_out = image.shape
        shape = image.shape[-2:]
        if psf_size is None:
            psf_size = _psf_size_at_centres(model, intrinsics, poses, shape, origin, stride,
                                            overlap)
        self.grid = PatchGrid(shape, psf_size, stride, overlap)
        #: sparse PSF basis: ``(basis @ w).reshape(n_patches, K, K)`` are the window PSFs
        self.basis = psf_basis(model, intrinsics, poses, self.grid, origin, self.dtype)
        self._patch_hat = self.grid.rfft(self.grid.windowed_patches(image))

    def psfs(self, w) -> np.ndarray:
        """PSFs at the window centres for weights ``w``, (n_patches, K, K)."""
        K = self.grid.psf_size
        return (self.basis @ np.asarray(w, self.dtype)).reshape(-1, K, K)

    def _forward(self, w):
        g = self.grid
        spectra = self._patch_hat * g.rfft(self.psfs(w))
        return g.add_outputs(g.irfft(spectra, g.out_shape), self.dtype)

    def _adjoint(self, y):
        g = self.grid
        K = g.psf_size
        spectra = g.rfft(g.output_patches(y)) * np.conj(self._patch_hat)
        corr = g.irfft(spectra, (K, K))
        if corr.ndim == 4:
            corr = corr.sum(0)
        return (self.basis.T @ corr.reshape(-1)).astype(self.dtype)


def blur(image, motion: CameraMotion, method: str = "eff", **kwargs) -> np.ndarray:
    """Blur an image (H, W) or (H, W, C) with a camera motion: ``"eff"`` (fast) or ``"exact"``.

    The blur is linear, so any finite intensity range is accepted (a latent estimate
    overshoots [0, 1]); integers are scaled by their dtype's maximum.
    """
    check_choice(method, "method", ("eff", "exact"))
    img = as_float_image(image, allow_rgb=True, check_range=False)
    cls = EfficientFilterFlow if method == "eff" else WarpSum
    op = cls(motion.rescale(img.shape), dtype=img.dtype, **kwargs)
    if img.ndim == 2:
        return op.forward(img)
    return np.stack([op.forward(img[..., c]) for c in range(img.shape[2])], -1)
