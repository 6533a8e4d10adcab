"""Consistency between edge profiles: neighbours that disagree, edges softer than the blur.

Each profile passed its own validity tests (:mod:`.edge_tests`); these compare profiles
with each other. :func:`_neighbour_outliers` refuses a derivative far from the median of
its neighbours of similar orientation; :func:`_blur_consistency` refuses a derivative wider
than the camera-shake blur field fitted to the lower side of all profiles' widths (a soft
or shaded scene edge would make the blur look larger).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

_OUTLIER_FLOOR = 0.4
_OUTLIER_MADS = 3.0
_SOFT_TAU = 0.2
_SOFT_REL = 0.35


def _neighbour_outliers(centroids, angles, deriv, shape, max_blur):
    """Compare each derivative with the median of its neighbours of similar orientation.

    Neighbours: the 16 nearest profiles within ``max(3 max_blur, 6% of the image
    diagonal)`` whose normals agree within 20 degrees up to sign (an opposite normal
    sees the mirrored projection, so its derivative is reversed first). A profile with at
    least 3 such neighbours is an outlier when its NCC with their median derivative is
    below 0.3, or below ``median - 4 * 1.4826 * MAD`` of all scores and below 0.8.

    Returns ``keep`` (n,) and the NCC scores (NaN where there were too few neighbours).
    """
    n = len(centroids)
    radius = max(3.0 * max_blur, 0.06 * math.hypot(*shape))
    k = min(17, n)
    dist, nb = cKDTree(centroids).query(centroids, k=k, distance_upper_bound=radius)
    dist, nb = dist[:, 1:], nb[:, 1:]  # drop self
    valid = np.isfinite(dist)
    nb = np.where(valid, nb, 0)
    dphi = np.angle(np.exp(1j * (angles[nb] - angles[:, None])))
    same = valid & (np.abs(dphi) < np.deg2rad(20))
    opposite = valid & (np.abs(dphi) > np.deg2rad(160))
    use = same | opposite
    cand = np.where(opposite[..., None], deriv[nb][..., ::-1], deriv[nb])  # (n, k-1, N)
    counts = use.sum(1)
    score = np.full(n, np.nan)
    enough = counts >= 3
    if enough.any():
        stack = np.where(use[enough, :, None], cand[enough], np.nan)
        stack = np.sort(stack, axis=1)  # NaNs last
        cnt = counts[enough]
        lo_i = (cnt - 1) // 2
        hi_i = cnt // 2
        r = np.arange(stack.shape[0])
        med = 0.5 * (stack[r, lo_i] + stack[r, hi_i])
        score[enough] = _ncc_rows(deriv[enough], med)
    keep = np.ones(n, bool)
    s = score[np.isfinite(score)]
    if s.size >= 5:
        centre = np.median(s)
        mad = 1.4826 * np.median(np.abs(s - centre))
        bad = np.isfinite(score) & ((score < _OUTLIER_FLOOR)
                                    | ((score < centre - _OUTLIER_MADS * mad) & (score < 0.8)))
        keep = ~bad
    return keep, score


_QUANTILE_ITERS = 30


def _blur_consistency(centroids, angles, deriv, offsets, shape, tau=None, rel=None,
                      slack=1.0) -> np.ndarray:
    """Keep profiles whose width is consistent with one camera-shake blur field.

    A blurred step's derivative is the PSF projection convolved with the sharp edge's
    own profile, so its variance is ``n^T Sigma(x) n`` (``Sigma`` the covariance of the
    local PSF) *plus* the sharp edge's variance, never less. For camera shake the PSF
    displacements are nearly affine in ``x`` over the image, so ``Sigma(x)`` is a
    quadratic polynomial in ``x``. We fit that field to the lower side of the measured
    variances (a quantile regression at ``tau``, by iterative reweighting: 18
    coefficients, fewer when there are few profiles) and refuse profiles wider than
    ``(1 + rel) * fit + slack`` px^2: soft or shaded scene edges, which would make the
    blur look larger than it is.

    Returns
    -------
    ndarray of bool, shape (n,)
        True where the profile is consistent.
    """
    tau = _SOFT_TAU if tau is None else tau
    rel = _SOFT_REL if rel is None else rel
    n = len(centroids)
    var = deriv @ (offsets**2)
    H, W = shape
    size = float(max(H, W))
    x = (centroids[:, 1] - (W - 1) / 2) / size
    y = (centroids[:, 0] - (H - 1) / 2) / size
    basis = [np.ones(n)]
    if n >= 30:
        basis += [x, y]
    if n >= 60:
        basis += [x * x, x * y, y * y]
    B = np.stack(basis, -1)
    c, s = np.cos(angles), np.sin(angles)
    F = np.concatenate([B * (c * c)[:, None], B * (2 * c * s)[:, None], B * (s * s)[:, None]],
                       1)
    scale = max(float(np.median(var)), 1e-3)
    ridge = 1e-6 * np.eye(F.shape[1]) * n
    w = np.ones(n)
    pred = np.full(n, scale)
    for _ in range(_QUANTILE_ITERS):
        A = F.T @ (F * w[:, None]) + ridge
        try:
            theta = np.linalg.solve(A, F.T @ (w * var))
        except np.linalg.LinAlgError:  # pragma: no cover - degenerate orientations
            break
        pred = F @ theta
        r = var - pred
        # iteratively reweighted least squares for the check loss of quantile tau
        w = np.where(r > 0, tau, 1.0 - tau) / np.maximum(np.abs(r), 0.02 * scale)
    return var <= (1.0 + rel) * np.maximum(pred, 0.0) + slack


def _ncc_rows(a, b) -> np.ndarray:
    a = a - a.mean(1, keepdims=True)
    b = b - b.mean(1, keepdims=True)
    den = np.sqrt((a * a).sum(1) * (b * b).sum(1))
    return np.where(den > 0, (a * b).sum(1) / np.where(den > 0, den, 1.0), 0.0)
