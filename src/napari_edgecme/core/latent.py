"""Latent-image update with an L0 gradient prior (Xu, Zheng & Jia 2013; paper Eq. 21).

    min_f ||M T_w f - g||^2 + lambda_f ||grad f||_0

by half-quadratic splitting (Pan et al. 2014): with auxiliary gradients ``(h, v)``,
alternate the hard threshold ``(h, v) = grad f`` where ``|grad f|^2 >= lambda_f / beta``
(else 0) and the quadratic image step

    min_f ||M T_w f - g||^2 + beta ||grad f - (h, v)||^2,

while ``beta`` grows from ``2 lambda_f`` by ``kappa`` up to ``beta_max``. ``T_w`` is the
spatially varying filter-flow blur on a latent domain padded beyond the frame and
``M`` the crop to the frame (no boundary assumption about the scene). The image step
is the deconvolution module's quadratic solver -- the per-tile closed form
(:class:`~napari_edgecme.core.deconv_solvers.PatchFourier`) -- the same one the
hyper-Laplacian deconvolution uses, so there is one image-step solver in the engine.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .deconv_solvers import LatentDomain, PatchFourier
from .motion import CameraMotion
from .progress import Progress, StopRequested, drive

__all__ = ["iter_l0_latent", "l0_latent", "splitting_weights"]


def l0_latent(blurred: np.ndarray, motion: CameraMotion, lambda_f: float, *,
              kappa: float = 2.0, beta_max: float = 64.0, return_gradients: bool = False,
              callback: Callable[[Progress], object] | None = None):
    """Estimate the latent image under an L0 gradient prior (Eq. 21).

    The plain-function face of :func:`iter_l0_latent`.

    Parameters
    ----------
    blurred : ndarray of shape (H, W)
        The observation ``g`` at the current scale (float32 or float64).
    motion : CameraMotion
        The current MDF estimate, for images of shape (H, W).
    lambda_f : float
        Weight of the L0 gradient prior (Xu et al.: 2e-3 .. 1e-2 for the finest scale).
    kappa, beta_max : float
        Half-quadratic splitting schedule (Pan et al.: 2 and 1e5).
    return_gradients : bool
        Also return the thresholded gradients of the last splitting step.
    callback : callable, optional
        Called with each :class:`~napari_edgecme.core.progress.Progress` record (one
        per splitting step); raising ``StopIteration`` in it stops the splitting and
        returns the latent estimate so far.

    Returns
    -------
    ndarray of shape (H, W)
        The latent estimate on the frame, same dtype as ``blurred`` (and, with
        ``return_gradients``, the gradients, shape (2, H, W)).
    """
    return drive(iter_l0_latent(blurred, motion, lambda_f, kappa=kappa, beta_max=beta_max,
                                return_gradients=return_gradients), callback)


def splitting_weights(lambda_f: float, kappa: float = 2.0, beta_max: float = 64.0) -> list:
    """The continuation ``beta = 2 lambda_f kappa^k < beta_max`` of :func:`iter_l0_latent`."""
    betas, beta = [], 2.0 * lambda_f
    while beta < beta_max:
        betas.append(beta)
        beta *= kappa
    return betas


def iter_l0_latent(blurred: np.ndarray, motion: CameraMotion, lambda_f: float, *,
                   kappa: float = 2.0, beta_max: float = 64.0,
                   return_gradients: bool = False):
    """:func:`l0_latent` as a solver generator (:mod:`~napari_edgecme.core.progress`).

    Yields
    ------
    Progress
        ``stage="latent"``, one record after each splitting step (``step`` of
        ``total`` steps), its ``iterate`` the latent estimate on the padded domain.

    Returns
    -------
    What :func:`l0_latent` returns (``StopIteration.value``). On
    :class:`~napari_edgecme.core.progress.StopRequested` it returns at once with the
    estimate of the last finished step (the mirrored observation before the first).
    """
    H, W = blurred.shape
    pad = (motion.psf_size() + 1) // 2
    domain = LatentDomain(motion, (0, H, 0, W), pad, dtype=blurred.dtype)
    solver = PatchFourier(domain, margin=2 * pad)
    solver.set_observation(blurred)
    f = domain.extend(blurred)
    betas = splitting_weights(lambda_f, kappa, beta_max)
    gradient = domain.gradient  # D on the domain
    hv = None  # the thresholded gradients (h, v), shape (2, *domain.shape)
    try:
        for k, beta in enumerate(betas, 1):
            hv = gradient @ f
            small = hv[0] * hv[0] + hv[1] * hv[1] < lambda_f / beta
            hv[:, small] = 0
            prior = gradient.T @ hv
            prior *= blurred.dtype.type(beta)
            f = drive(solver.solve(prior, 1.0, beta))
            yield Progress("latent", k, len(betas),
                           f"L0 splitting step {k}/{len(betas)} (beta {beta:.3g})",
                           iteration=k, iterate=f)
    except StopRequested:
        pass
    f = np.ascontiguousarray(f[domain.inner])
    if return_gradients:
        if hv is None:
            hv = gradient @ domain.extend(blurred)
        return f, np.ascontiguousarray(hv[(slice(None), *domain.inner)])
    return f
