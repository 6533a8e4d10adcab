"""The measurement matrix of the edge-profile cue (paper Eqs. 13-16) and its data term.

Row block ``i`` of ``M`` maps the motion density function's weights to the derivative of
profile ``i``: each pose puts its weight at the displacement it causes along the profile's
normal (the Radon slice of the local PSF, Eq. 13). Stacking the blocks gives ``dE = M w``
(Eq. 15), and EpAlone solves Eq. 16 on it: :func:`profile_term` is its data term, with a
weight per profile, and :func:`profile_misfit` says how far each profile is from a motion.

The paper replaces Eq. 16 by the image-domain Eq. 19 because building ``M`` is costly at
full resolution. Here it is not: ``M`` has two entries per profile and pose, the profiles'
derivatives are averages over several parallel lines (far less noisy than the single-pixel
gradients of ``I_ep``), and a weight per profile -- for robustness to false profiles --
is a row scaling.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from .camera import Intrinsics, check_poses, displacements
from .lasso import QuadraticTerm
from .linop import MatrixOperator
from .profiles import EdgeProfiles

__all__ = ["edge_spread_matrix", "measurement_matrix", "profile_misfit", "profile_term"]


def measurement_matrix(profiles: EdgeProfiles, model: str, intrinsics: Intrinsics, poses,
                       points=None, edge_spread: float = 0.0) -> sparse.csr_matrix:
    """The measurement matrix ``M`` of Eqs. 13-15: MDF weights -> profile derivatives.

    Row block ``i`` holds the Radon slice (Eq. 13) of the PSF at profile ``i``'s
    centroid along its normal: pose ``p`` puts its weight at ``rho_ip = (H_p x_i - x_i) . n_i``,
    splatted linearly into the one-pixel bins of ``profiles.offsets``. With
    centroid-aligned profiles the poses are those of the re-centred motion (claim 2),
    so ``M @ w`` is compared with ``profiles.derivatives.ravel()`` directly.

    Parameters
    ----------
    profiles : EdgeProfiles
        ``n`` profiles on ``N`` offsets.
    model, intrinsics, poses
        The pose set (``n_poses``, d) of the weights.
    points : array_like of shape (n, 2), optional
        Where to evaluate the PSFs (default: the centroids).
    edge_spread : float
        Standard deviation (px) of the sharp edges' own transition: each row block
        becomes ``G @ M_i`` (:func:`edge_spread_matrix`); 0 (default): ideal steps.

    Returns
    -------
    scipy.sparse.csr_matrix of shape (n * N, n_poses)
        Column sums are at most one (mass beyond the offsets range is dropped). As a
        composable operator (in the operators' dot test):
        ``MatrixOperator(measurement_matrix(...))``
        (:class:`~napari_edgecme.core.linop.MatrixOperator`).
    """
    poses = check_poses(poses, model)
    pts = profiles.centroids if points is None else np.asarray(points, float).reshape(-1, 2)
    n, N = len(profiles), profiles.offsets.size
    if n == 0:
        return sparse.csr_matrix((0, len(poses)))
    disp = displacements(model, intrinsics, poses, pts)  # (n, P, 2) as (dx, dy)
    nx = np.cos(profiles.normal_angle)[:, None]
    ny = np.sin(profiles.normal_angle)[:, None]
    rho = disp[..., 0] * nx + disp[..., 1] * ny  # (n, P)
    pos = rho - profiles.offsets[0]  # fractional bin index
    j0 = np.floor(pos).astype(np.int64)
    frac = pos - j0
    rows, cols, vals = [], [], []
    pose_idx = np.broadcast_to(np.arange(len(poses))[None, :], rho.shape)
    base = (np.arange(n) * N)[:, None]
    for dj, wgt in ((0, 1.0 - frac), (1, frac)):
        j = j0 + dj
        keep = (j >= 0) & (j < N) & (wgt > 0)
        rows.append((base + j)[keep])
        cols.append(pose_idx[keep])
        vals.append(wgt[keep])
    matrix = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                       np.concatenate(cols))),
                               shape=(n * N, len(poses)))
    if edge_spread > 0:
        matrix = sparse.csr_matrix(sparse.kron(sparse.identity(n, format="csr"),
                                               edge_spread_matrix(N, edge_spread)) @ matrix)
    return matrix


def edge_spread_matrix(n_bins: int, sigma: float) -> sparse.csr_matrix:
    """``G``: a Gaussian of standard deviation ``sigma`` (bins), integrated over each bin.

    The edges of a photo are not ideal steps: each profile is the projection of the
    PSF convolved with the sharp edge's own transition. ``G @ M_i`` models that
    (:data:`~.profile_fit.EP_EDGE_SPREAD`). Mass beyond the ``n_bins`` range is dropped,
    as in :func:`measurement_matrix`.

    Parameters
    ----------
    n_bins : int
        ``N``, the number of one-pixel offsets of a profile.
    sigma : float
        Standard deviation in bins (> 0).

    Returns
    -------
    scipy.sparse.csr_matrix of shape (N, N)
        Symmetric, banded (half-width ``ceil(4 sigma)``); columns away from the ends
        sum to 1.
    """
    from scipy.special import ndtr

    half = int(np.ceil(4 * sigma))
    k = np.arange(-half, half + 1)
    g = ndtr((k + 0.5) / sigma) - ndtr((k - 0.5) / sigma)
    g /= g.sum()  # the tails beyond 4 sigma (6e-5 of the mass) folded back in
    return sparse.diags(np.broadcast_to(g[:, None], (k.size, n_bins)), k,
                        shape=(n_bins, n_bins), format="csr")


def profile_term(matrix: sparse.csr_matrix, profiles: EdgeProfiles, weights=None
                 ) -> QuadraticTerm:
    """``1/2 sum_i c_i ||M_i w - dE_i||^2``: the data term of Eq. 16, a weight per profile.

    Parameters
    ----------
    matrix : scipy.sparse.csr_matrix of shape (n * N, n_poses)
        :func:`measurement_matrix` of ``profiles`` on the pose set of ``w``.
    profiles : EdgeProfiles
        ``n`` profiles on ``N`` offsets (their ``derivatives`` are ``dE``).
    weights : array_like of shape (n,), optional
        ``c_i >= 0`` (default 1): how much each profile is trusted.

    Returns
    -------
    QuadraticTerm
    """
    n, N = len(profiles), profiles.offsets.size
    c = np.ones(n) if weights is None else np.asarray(weights, np.float64).reshape(n)
    if np.any(c < 0) or not np.all(np.isfinite(c)):
        raise ValueError("profile weights must be finite and non-negative")
    rows = np.repeat(np.sqrt(c), N)
    scaled = sparse.diags(rows) @ matrix
    target = rows * np.asarray(profiles.derivatives, np.float64).ravel()
    return QuadraticTerm.least_squares(MatrixOperator(sparse.csr_matrix(scaled)), target)


def profile_misfit(matrix: sparse.csr_matrix, profiles: EdgeProfiles, w) -> np.ndarray:
    """How far each profile is from the projection a motion predicts (Eq. 14).

    Parameters
    ----------
    matrix : scipy.sparse.csr_matrix of shape (n * N, n_poses)
        :func:`measurement_matrix` of ``profiles`` on the pose set of ``w``.
    profiles : EdgeProfiles
    w : array_like of shape (n_poses,)
        MDF weights.

    Returns
    -------
    ndarray of shape (n,)
        ``||M_i w - dE_i||^2 / ||dE_i||^2``: 0 for a profile the motion explains exactly,
        about 1 or more for one it does not explain at all.
    """
    n, N = len(profiles), profiles.offsets.size
    d = np.asarray(profiles.derivatives, np.float64)
    residual = (matrix @ np.asarray(w, np.float64)).reshape(n, N) - d
    return (residual ** 2).sum(1) / np.maximum((d ** 2).sum(1), 1e-300)
