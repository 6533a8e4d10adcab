"""Data terms of the MDF updates as cheap quadratics over the pose weights ``w``.

Both terms are built on the filter-flow geometry (:class:`~.operators.PatchGrid`)
and the sparse PSF basis ``B`` (Eq. 9: the PSF of tile ``r`` is ``k_r = B_r w``;
:func:`~.operators.psf_basis`, the one the EFF operators use, re-exported here), and
both come out as :class:`~.lasso.QuadraticTerm` objects whose products ``Q w`` never
touch a full-size image:

* :func:`gradient_term` -- the first term of Eq. 22, ``||T_w grad f - grad g||^2``
  (also usable with any fixed image). In each tile the windowed latent patch is
  blurred by the tile's PSF and compared with the windowed observed patch:
  ``sum_r ||k_r * (omega_r f) - omega_r g||^2``. Because the comparison runs over the
  whole support of the blurred patch, the normal matrix of each tile is exactly
  Toeplitz -- the autocorrelation of ``omega_r f`` -- so ``Q w`` costs one small FFT
  convolution (``3K - 2`` points a side) per tile. Windowing the residual rather
  than the sum of blurred patches differs from the EFF forward model only by
  ``omega_r (k * f) - k * (omega_r f)``, which is small where windows vary slowly
  against the PSF size; images are tapered to zero at the border first, so the
  border of the frame never enters the fit.
* :func:`edge_profile_term` -- the data term of Eq. 19, ``||M (T_w I_p - I_ep)||^2``,
  with ``T_w`` the exact EFF forward operator. ``I_p`` (thin lines) and the mask
  ``M`` are sparse, so the masked operator is assembled once as an explicit sparse
  matrix (rows: mask pixels; columns: poses), equal to the masked rows of
  :class:`~.operators.EfficientFilterFlowWeights` (a test checks this).

Both terms are returned unnormalised (``1/2 ||A w - y||^2``, constant ``||y||^2``): they
are in the same units (squared gradient magnitudes, by claim 3), so Eq. 22 adds them
with the single weight ``lambda_Ip``; the estimator then divides the sum by the data
energy so that ``lambda_w`` means the same at every scale and image size.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft
import scipy.sparse as sp

from .lasso import QuadraticTerm
from .linop import LinearOperator, MatrixOperator
from .operators import FFT_WORKERS, PatchGrid, psf_basis

__all__ = ["TileAutocorrelation", "border_taper", "edge_profile_term", "gradient_term",
           "masked_eff_matrix", "psf_basis"]


def border_taper(shape, width: int) -> np.ndarray:
    """A weight that rises from 0 at the frame to 1 at ``width`` pixels inside (raised cosine)."""
    out = []
    for n in shape:
        d = np.minimum(np.arange(n), np.arange(n)[::-1]).astype(float)
        out.append(np.clip(np.sin(np.pi / 2 * np.clip(d / max(width, 1), 0, 1)) ** 2, 0, 1))
    return np.outer(*out)


def _lag_window(spectrum_prod, grid: PatchGrid, reach: int) -> np.ndarray:
    """Inverse FFT of per-tile cross spectra, cropped to lags ``[-reach, reach]`` per axis."""
    full = sfft.irfft2(spectrum_prod, s=grid.fft_shape, axes=(-2, -1), workers=FFT_WORKERS)
    idx = [np.r_[f - reach:f, 0:reach + 1] for f in grid.fft_shape]
    return full[..., idx[0][:, None], idx[1][None, :]]


def gradient_term(latent, observed, grid: PatchGrid, basis: sp.csr_matrix) -> QuadraticTerm:
    """``1/2 sum_r ||k_r * (omega_r f) - omega_r g||^2`` over channels (Eq. 22, first term).

    Parameters
    ----------
    latent : ndarray of shape (C, H, W)
        The fixed images ``f`` (e.g. the gradients of the latent estimate), tapered at
        the border by the caller.
    observed : ndarray of shape (C, H, W)
        The observations ``g`` they must blur into (e.g. the blurred image's gradients).
    grid : PatchGrid
    basis : scipy.sparse matrix of shape (n_patches * K * K, n_poses)
        :func:`psf_basis` for the active poses.

    Returns
    -------
    QuadraticTerm
        Over the pose weights.
    """
    K = grid.psf_size
    h = (K - 1) // 2
    pf = grid.rfft(grid.windowed_patches(np.asarray(latent)))  # (C, R, F0, F1/2+1)
    observed_patches = grid.windowed_patches(np.asarray(observed))
    pg = grid.rfft(observed_patches)
    auto = _lag_window((np.abs(pf) ** 2).sum(0), grid, K - 1)  # (R, 2K-1, 2K-1) lags
    cross = _lag_window((np.conj(pf) * pg).sum(0), grid, h)  # (R, K, K): sum_t p(t) d(t+u)
    energy = float(np.sum(observed_patches.astype(np.float64) ** 2))
    normal = TileAutocorrelation(auto, basis)
    linear = normal.basis_transpose @ cross.reshape(-1).astype(np.float64)
    return QuadraticTerm(normal, linear, energy)


class TileAutocorrelation(LinearOperator):
    """``Q = sum_r B_r^T A_r B_r`` of :func:`gradient_term`: (n_poses,) -> (n_poses,).

    ``A_r k`` correlates the PSF ``k`` (K, K) of tile ``r`` with the autocorrelation of
    the tile's windowed latent patch, restricted to the K x K support; symmetric
    positive semi-definite, its own adjoint. Computed in float32 (small FFTs, one
    thread), in and out in float64.

    Parameters
    ----------
    autocorrelation : ndarray of shape (n_patches, 2K - 1, 2K - 1)
        Lags ``-(K - 1) .. K - 1`` per axis of each tile's autocorrelation.
    basis : scipy.sparse matrix of shape (n_patches * K * K, n_poses)
        :func:`psf_basis`.
    """

    def __init__(self, autocorrelation, basis: sp.spmatrix):
        n_patches, L, _ = autocorrelation.shape
        K = self.psf_size = (L + 1) // 2
        # Q_r k = auto_r (*) k restricted to the K x K support: a circular convolution of
        # size M >= 2K - 1 is exact there (each lag within +-(K-1) has a distinct residue)
        M = self.fft_size = sfft.next_fast_len(2 * K - 1, real=True)
        circ = np.zeros((n_patches, M, M), np.float32)
        circ[:, :2 * K - 1, :2 * K - 1] = autocorrelation
        self._auto_hat = sfft.rfft2(np.roll(circ, (-(K - 1), -(K - 1)), axis=(1, 2)),
                                    axes=(-2, -1))
        self.basis = basis.astype(np.float32)
        #: ``B^T`` in CSR
        self.basis_transpose = self.basis.T.tocsr()
        self.n_patches = n_patches
        self.shape_in = self.shape_out = (basis.shape[1],)
        self.dtype = np.dtype(np.float64)

    def _forward(self, w):  # small FFTs: one thread beats the pool
        K, M = self.psf_size, self.fft_size
        k = (self.basis @ w.astype(np.float32)).reshape(self.n_patches, K, K)
        conv = sfft.irfft2(sfft.rfft2(k, s=(M, M), axes=(-2, -1)) * self._auto_hat,
                           s=(M, M), axes=(-2, -1))
        return (self.basis_transpose @ conv[:, :K, :K].reshape(-1)).astype(np.float64)

    _adjoint = _forward


def edge_profile_term(prediction, edge_profile, mask, grid: PatchGrid, basis: sp.csr_matrix
                      ) -> QuadraticTerm:
    """``1/2 ||M (T_w I_p - I_ep)||^2`` -- the data term of Eq. 19.

    Parameters
    ----------
    prediction : ndarray of shape (H, W)
        The prediction image ``I_p`` (sparse: thin lines through the edge centroids).
    edge_profile : ndarray of shape (H, W)
        The edge-profile image ``I_ep``.
    mask : ndarray of shape (H, W), bool
        ``M``: where ``I_ep`` is defined.
    grid, basis
        As for :func:`gradient_term`.
    """
    matrix = masked_eff_matrix(prediction, mask, grid) @ basis  # (n_mask, n_poses)
    operator = MatrixOperator(sp.csr_matrix(matrix, dtype=np.float64))  # M T_(I_p)
    target = np.asarray(edge_profile, np.float64)[np.asarray(mask, bool)]
    return QuadraticTerm.least_squares(operator, target)


def masked_eff_matrix(image, mask, grid: PatchGrid) -> sp.csr_matrix:
    """Rows of the EFF (linear in the PSFs) at the mask pixels, for a sparse fixed image.

    Returns ``S_M`` of shape (n_mask, n_patches * K * K) with
    ``(S_M k)[i] = sum_r (k_r * (omega_r image))(x_i)`` for mask pixel ``x_i`` (row-major
    order), i.e. ``S_M @ B`` equals the masked rows of ``EfficientFilterFlowWeights``.
    """
    image = np.asarray(image, np.float64)
    mask = np.asarray(mask, bool)
    H, W = image.shape
    K = grid.psf_size
    h = (K - 1) // 2
    row_of = np.full(H * W, -1, np.int64)
    row_of[np.flatnonzero(mask)] = np.arange(np.count_nonzero(mask))
    ys, xs = np.nonzero(image)
    vals = image[ys, xs]
    # tiles covering each source pixel, with their window weights (<= 2 per axis)
    tiles = []
    for axis, coord in enumerate((ys, xs)):
        s, o = grid.stride[axis], grid.overlap[axis]
        first = np.clip((coord + o // 2) // s - 1, 0, grid.counts[axis] - 1)
        per_axis = []
        for t in (first, first + 1, first + 2):
            valid = t < grid.counts[axis]
            tt = np.minimum(t, grid.counts[axis] - 1)
            local = coord - (tt * s - o // 2)
            inside = valid & (local >= 0) & (local < s + o)
            wgt = np.where(inside, grid.windows[axis][tt, np.clip(local, 0, s + o - 1)], 0.0)
            per_axis.append((tt, wgt))
        tiles.append(per_axis)
    rows, cols, data = [], [], []
    for du in range(-h, h + 1):
        ty = ys + du
        for dv in range(-h, h + 1):
            tx = xs + dv
            ok = (ty >= 0) & (ty < H) & (tx >= 0) & (tx < W)
            if not ok.any():
                continue
            r = np.where(ok, row_of[np.where(ok, ty * W + tx, 0)], -1)
            hit = r >= 0
            if not hit.any():
                continue
            offset = (du + h) * K + (dv + h)
            for ti, wi in tiles[0]:
                for tj, wj in tiles[1]:
                    wgt = wi * wj
                    keep = hit & (wgt > 0)
                    if keep.any():
                        rows.append(r[keep])
                        cols.append((ti[keep] * grid.counts[1] + tj[keep]) * K * K + offset)
                        data.append((wgt * vals)[keep])
    n_rows = int(np.count_nonzero(mask))
    if not rows:
        return sp.csr_matrix((n_rows, grid.n_patches * K * K))
    return sp.csr_matrix((np.concatenate(data), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(n_rows, grid.n_patches * K * K))
