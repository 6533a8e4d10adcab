"""The measurement matrix of the edge-profile cue (paper Eqs. 13-16).

Row block ``i`` of ``M`` maps the motion density function's weights to the derivative of
profile ``i``: each pose puts its weight at the displacement it causes along the profile's
normal (the Radon slice of the local PSF, Eq. 13).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from .camera import Intrinsics, check_poses, displacements
from .profiles import EdgeProfiles

__all__ = ["measurement_matrix"]


def measurement_matrix(profiles: EdgeProfiles, model: str, intrinsics: Intrinsics, poses,
                       points=None) -> sparse.csr_matrix:
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
    return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(n * N, len(poses)))
