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

#: A profile beside a clipped plateau narrower (in variance; 0.8 in width) than this
#: share of the blur field of the unclipped profiles is a clipped transition
#: (see ``_clipped_too_narrow``).
_CLIP_NARROW = 0.65

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
                      slack=1.0):
    """Keep profiles whose width is consistent with one camera-shake blur field.

    A blurred step's derivative is the PSF projection convolved with the sharp edge's
    own profile, so its variance is ``n^T Sigma(x) n`` (``Sigma`` the covariance of the
    local PSF) *plus* the sharp edge's variance, never less. For camera shake the PSF
    displacements are nearly affine in ``x`` over the image, so ``Sigma(x)`` is a
    quadratic polynomial in ``x``. We fit that field to the lower side of the measured
    variances (a quantile regression at ``tau``, :func:`_blur_field`) and refuse
    profiles wider than ``(1 + rel) * fit + slack`` px^2: soft or shaded scene edges,
    which would make the blur look larger than it is.

    Returns
    -------
    consistent : ndarray of bool, shape (n,)
        True where the profile is consistent.
    width_excess : ndarray of shape (n,)
        The measured variance over the largest one accepted: ``<= 1`` when consistent.
    """
    tau = _SOFT_TAU if tau is None else tau
    rel = _SOFT_REL if rel is None else rel
    var = deriv @ (offsets**2)
    field = _blur_field(centroids, angles, var, shape, tau)
    limit = (1.0 + rel) * np.maximum(field(centroids, angles), 0.0) + slack
    return var <= limit, var / limit


def _clipped_too_narrow(centroids, angles, deriv, offsets, shape, clipped):
    """Profiles beside a clipped plateau that are narrower than the blur field, (n,) bool.

    A plateau at the sensor's limit is harmless when the scene is flat there; but a light
    brighter than white, clipped after the blur, cuts the transition short, and the
    profile comes out narrow and smooth (no kink gives it away). So a profile beside a
    clipped plateau must be as wide as the blur field of the profiles with unclipped
    plateaus predicts (median regression, :func:`_blur_field`): a variance below
    :data:`_CLIP_NARROW` of it is refused. With fewer than 6 unclipped profiles (a page
    of text, a white background) there is no reference and nothing is refused.
    """
    clipped = np.asarray(clipped, bool)
    refused = np.zeros(len(centroids), bool)
    reference = ~clipped
    if reference.sum() < 6 or not clipped.any():
        return refused
    var = deriv @ (offsets**2)
    field = _blur_field(centroids[reference], angles[reference], var[reference], shape, 0.5,
                        max_degree=0)
    pred = field(centroids[clipped], angles[clipped])
    refused[clipped] = var[clipped] < _CLIP_NARROW * np.maximum(pred, 0.0)
    return refused


def _blur_field(centroids, angles, var, shape, tau, max_degree=2):
    """Fit ``n^T Sigma(x) n`` to profile variances by quantile regression at ``tau``.

    ``Sigma(x)`` is a polynomial in the image position: constant, affine from 30
    profiles, quadratic from 60 (3-18 coefficients; at most ``max_degree``); the check
    loss is minimised by
    iteratively reweighted least squares. Returns ``field(points, angles) -> (m,)``,
    the fitted variance at those points along those normals.
    """
    n = len(centroids)
    H, W = shape
    size = float(max(H, W))
    degree = min(max_degree, 0 if n < 30 else (1 if n < 60 else 2))

    def features(points, phi):
        x = (points[:, 1] - (W - 1) / 2) / size
        y = (points[:, 0] - (H - 1) / 2) / size
        basis = [np.ones(len(points))]
        if degree >= 1:
            basis += [x, y]
        if degree >= 2:
            basis += [x * x, x * y, y * y]
        B = np.stack(basis, -1)
        c, s = np.cos(phi), np.sin(phi)
        return np.concatenate([B * (c * c)[:, None], B * (2 * c * s)[:, None],
                               B * (s * s)[:, None]], 1)

    F = features(centroids, angles)
    scale = max(float(np.median(var)), 1e-3)
    ridge = 1e-6 * np.eye(F.shape[1]) * n
    w = np.ones(n)
    theta = np.zeros(F.shape[1])
    theta[0] = theta[2 * F.shape[1] // 3] = scale  # isotropic start: n^T (scale I) n
    for _ in range(_QUANTILE_ITERS):
        A = F.T @ (F * w[:, None]) + ridge
        try:
            theta = np.linalg.solve(A, F.T @ (w * var))
        except np.linalg.LinAlgError:  # pragma: no cover - degenerate orientations
            break
        r = var - F @ theta
        # iteratively reweighted least squares for the check loss of quantile tau
        w = np.where(r > 0, tau, 1.0 - tau) / np.maximum(np.abs(r), 0.02 * scale)

    def field(points, phi):
        return features(np.asarray(points, float).reshape(-1, 2),
                        np.asarray(phi, float).reshape(-1)) @ theta

    return field


def _ncc_rows(a, b) -> np.ndarray:
    a = a - a.mean(1, keepdims=True)
    b = b - b.mean(1, keepdims=True)
    den = np.sqrt((a * a).sum(1) * (b * b).sum(1))
    return np.where(den > 0, (a * b).sum(1) / np.where(den > 0, den, 1.0), 0.0)
