"""One MDF update of the coarse-to-fine estimators (Eq. 16 for EpAlone, Eq. 22 otherwise).

Every update solves a non-negative L1 problem (:func:`~.lasso.nonneg_lasso`) on the
active poses of a level, then cleans the MDF (:func:`~.pyramid.clean_mdf`). The latent-
image methods fit the latent's salient gradients to the observation's (Xu & Jia 2010
edge selection, :func:`salient_gradients`), plus ``lambda_Ip`` times the edge-profile term
for Xu+Ep; EpAlone fits the edge profiles alone (:mod:`~.profile_fit`).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from .deconv_prior import grad
from .lasso import iter_nonneg_lasso
from .mdf import border_taper, edge_profile_term, gradient_term, psf_basis
from .measurement import measurement_matrix
from .progress import Progress, drive
from .pyramid import WEIGHT_FLOOR, Level, clean_mdf

__all__ = ["GRADIENT_SMOOTHING", "LASSO_MAX_ITER", "data_term", "edge_images", "iter_mdf_update",
           "iter_solve_update", "mdf_update", "salient_gradients", "solve_update"]

#: FISTA iterations per MDF update.
LASSO_MAX_ITER = 200
#: Standard deviation (px) of the Gaussian applied to both sides of the gradient term
#: (the same linear filter on both keeps Eq. 22 exact).
GRADIENT_SMOOTHING = 1.0
def edge_images(level: Level, profiles, scale: float, gain: float):
    """``(I_p, I_ep, M)`` of Eq. 19 at this level (profiles in working coordinates)."""
    from .prediction import edge_profile_image, prediction_image

    i_p = prediction_image(profiles, level.shape, scale=scale) * level.blurred.dtype.type(gain)
    i_ep, mask = edge_profile_image(level.blurred, profiles, scale=scale)
    return i_p, i_ep, mask


def salient_gradients(latent_grad: np.ndarray, blurred: np.ndarray, fraction: float,
                       window: int = 5) -> np.ndarray:
    """Keep the latent gradients at salient, straight edges (Xu & Jia 2010 edge selection).

    The usefulness map ``r = |sum_N grad g| / (sum_N |grad g| + eps)`` over a
    ``window`` x ``window`` neighbourhood is near 1 at isolated straight edges and near
    0 in texture and noise, where the gradients cancel. Latent gradients are kept
    where ``r`` is above its median and, within each of four orientation bins, among
    the ``fraction`` strongest -- so every edge direction informs the MDF.

    Parameters
    ----------
    latent_grad : ndarray of shape (2, H, W)
        ``(gx, gy)`` of the latent estimate.
    blurred : ndarray of shape (H, W)
        The observation at this scale.
    fraction : float
        Share of each orientation bin kept (grows over the iterations).
    """
    gx, gy = grad(blurred)
    mag_g = np.hypot(gx, gy)
    num = np.hypot(ndimage.uniform_filter(gx, window), ndimage.uniform_filter(gy, window))
    usefulness = num / (ndimage.uniform_filter(mag_g, window) + 2e-3)
    useful = usefulness > np.median(usefulness)
    mag = np.hypot(latent_grad[0], latent_grad[1])
    angle = np.mod(np.arctan2(latent_grad[1], latent_grad[0]), np.pi)
    bins = np.minimum((angle / (np.pi / 4)).astype(int), 3)
    keep = np.zeros(mag.shape, bool)
    for b in range(4):
        cand = useful & (bins == b) & (mag > 0)
        if cand.any():
            keep |= cand & (mag >= np.quantile(mag[cand], 1.0 - min(fraction, 1.0)))
    return latent_grad * keep


def mdf_update(level: Level, weights, active, latent, ep_data, lambda_w, lambda_ip, method,
              salient: float = 1.0, weight_floor: float = WEIGHT_FLOOR):
    """One MDF update on the active poses (Eq. 16 for EpAlone, Eq. 22 otherwise).

    ``ep_data`` is the level's :class:`~.profile_fit.RobustProfileFit` (EpAlone) or its
    ``(I_p, I_ep, M)`` images (Xu+Ep), or None (Xu). The active set is fixed within a
    level, so its tiles, PSF basis, measurement matrix and edge-profile term are built
    once per level and kept in ``level.cache``. ``weight_floor`` is the cleaning's
    (:func:`~.pyramid.clean_mdf`).

    Returns
    -------
    (weights, cost, lasso iterations)
        The cleaned MDF on ``level.grid`` (shape ``grid.counts``), the final lasso cost.
    """
    return drive(iter_mdf_update(level, weights, active, latent, ep_data, lambda_w,
                                 lambda_ip, method, salient, weight_floor))


def data_term(level: Level, active, latent, ep_data, lambda_ip, method, salient: float = 1.0,
              smoothing: float = GRADIENT_SMOOTHING):
    """The quadratic data term of one MDF update over the active poses, unnormalised.

    EpAlone: Eq. 16 on the measurement matrix; Xu: the gradient term of Eq. 22 (the
    latent's salient gradients blurred into the observation's); Xu+Ep: that plus
    ``lambda_Ip`` times the edge-profile term. Terms of several crops of one image at the
    same pose grid add up (:mod:`~.refine`). ``smoothing`` is the standard deviation (px)
    of the Gaussian applied to both sides of the gradient term.

    Returns
    -------
    QuadraticTerm
        Over ``level.grid.poses(active)``; ``constant`` is the data energy.
    """
    key = active.tobytes()
    if level.cache.get("key") != key:
        poses = level.grid.poses(active)
        level.cache = {"key": key}
        if method == "ep":
            level.cache["measurement"] = measurement_matrix(
                ep_data.profiles, level.model, level.intrinsics, poses,
                edge_spread=ep_data.edge_spread)
        if method != "ep":
            pgrid = level.patch_grid(poses)
            level.cache.update(pgrid=pgrid, basis=psf_basis(level.model, level.intrinsics,
                                                             poses, pgrid))
    if method == "ep":
        return ep_data.term(level.cache["measurement"])  # Eq. 16
    if ep_data is not None and lambda_ip > 0 and "ep" not in level.cache:
        level.cache["ep"] = edge_profile_term(*ep_data, level.cache["pgrid"],
                                              level.cache["basis"])
    pgrid, basis = level.cache["pgrid"], level.cache["basis"]
    taper = border_taper(level.shape, pgrid.psf_size // 2).astype(level.blurred.dtype)
    f_grad = salient_gradients(np.stack(grad(latent)), level.blurred, salient) * taper
    g_grad = np.stack(grad(level.blurred)) * taper
    if smoothing > 0:  # the same linear filter on both sides keeps Eq. 22 exact
        f_grad = ndimage.gaussian_filter(f_grad, (0, smoothing, smoothing))
        g_grad = ndimage.gaussian_filter(g_grad, (0, smoothing, smoothing))
    term = gradient_term(f_grad, g_grad, pgrid, basis)
    if "ep" in level.cache and lambda_ip > 0:  # Eq. 22: both terms in gradient units
        # (the polish passes lambda_ip = 0 on a level whose cache may hold the term:
        # a term scaled by 0 would still cost its products in every FISTA iteration)
        term = term + level.cache["ep"].scaled(lambda_ip)
    return term


def iter_mdf_update(level: Level, weights, active, latent, ep_data, lambda_w, lambda_ip,
                    method, salient: float = 1.0, weight_floor: float = WEIGHT_FLOOR):
    """:func:`mdf_update` as a generator: a record after the data term, one per FISTA
    iteration of the lasso; returns what :func:`mdf_update` returns."""
    term = data_term(level, active, latent, ep_data, lambda_ip, method, salient)
    yield Progress("MDF update", 0, 1, "data term ready")
    return (yield from iter_solve_update(term, weights, active, lambda_w,
                                         weight_floor=weight_floor))


def iter_solve_update(term, weights, active, lambda_w, max_iter: int = LASSO_MAX_ITER,
                      weight_floor: float = WEIGHT_FLOOR):
    """:func:`solve_update` as a solver generator: one record per FISTA iteration."""
    term = term.scaled(1.0 / max(term.constant, 1e-30))
    result = yield from iter_nonneg_lasso(term, lambda_w, weights[active], max_iter=max_iter)
    new = np.zeros(weights.shape)
    new[active] = result.x
    cost = result.costs[-1] if result.costs else float("nan")
    if not new.max() > 0:  # the L1 weight swallowed everything: keep the previous MDF
        return weights, cost, result.nit
    return clean_mdf(new, weight_floor), cost, result.nit


def solve_update(term, weights, active, lambda_w, max_iter: int = LASSO_MAX_ITER,
                 weight_floor: float = WEIGHT_FLOOR):
    """Solve the non-negative L1 problem of one MDF update and clean the result.

    ``term`` is normalised by its data energy first, so that ``lambda_w`` means the same at
    every scale and image size. ``weights`` (shape of the grid) warm-starts the solver and
    is returned unchanged when the L1 weight swallows everything. ``max_iter`` caps the
    FISTA iterations; ``weight_floor`` is the cleaning's (:func:`~.pyramid.clean_mdf`).
    The plain-function face of :func:`iter_solve_update`.
    """
    return drive(iter_solve_update(term, weights, active, lambda_w, max_iter, weight_floor))
