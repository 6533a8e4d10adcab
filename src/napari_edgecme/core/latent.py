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
from .progress import Progress, StopRequested, drive, relay

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
                   return_gradients: bool = False, fine: bool = False):
    """:func:`l0_latent` as a solver generator (:mod:`~napari_edgecme.core.progress`).

    Parameters
    ----------
    blurred, motion, lambda_f, kappa, beta_max, return_gradients
        As :func:`l0_latent`.
    fine : bool, default False
        Also yield records within the steps: one per chunk of tiles of the set-up
        (tile spectra, observation) and of each image step, so that a consumer who
        cancels at a record is heard within a fraction of a step (a step of a 1024 px
        image is up to about a second; the set-up before the first step longer).

    Yields
    ------
    Progress
        ``stage="latent"``: a record after each splitting step (``step`` of ``total``
        steps), its ``iterate`` the latent estimate on the padded domain; with
        ``fine``, records within the steps too, which repeat ``step`` and carry no
        ``iterate``.

    Returns
    -------
    What :func:`l0_latent` returns (``StopIteration.value``). On
    :class:`~napari_edgecme.core.progress.StopRequested` it returns at once with the
    estimate of the last finished step (the mirrored observation before the first).
    """
    H, W = blurred.shape
    pad = (motion.psf_size() + 1) // 2
    domain = LatentDomain(motion, (0, H, 0, W), pad, dtype=blurred.dtype)
    f = domain.extend(blurred)
    betas = splitting_weights(lambda_f, kappa, beta_max)
    gradient = domain.gradient  # D on the domain
    hv = None  # the thresholded gradients (h, v) of the last finished step, (2, *domain.shape)
    done = 0  # finished splitting steps

    def within(record):
        return Progress("latent", done, len(betas), f"L0 splitting step {done + 1}/"
                        f"{len(betas)}: {record.message}", iteration=done)

    def run(gen):
        """Run a sub-step: its records relabelled (``fine``) or not passed on."""
        if fine:
            return (yield from relay(gen, within))
        return drive(gen)

    try:
        solver = PatchFourier(domain, margin=2 * pad, build=False)
        yield from run(solver.iter_build())
        yield from run(solver.iter_set_observation(blurred))
        for beta in betas:
            step_hv = gradient @ f
            small = step_hv[0] * step_hv[0] + step_hv[1] * step_hv[1] < lambda_f / beta
            step_hv[:, small] = 0
            prior = gradient.T @ step_hv
            prior *= blurred.dtype.type(beta)
            f = yield from run(solver.solve(prior, 1.0, beta))
            hv = step_hv
            done += 1
            yield Progress("latent", done, len(betas),
                           f"L0 splitting step {done}/{len(betas)} (beta {beta:.3g})",
                           iteration=done, iterate=f)
    except StopRequested:
        pass
    f = np.ascontiguousarray(f[domain.inner])
    if return_gradients:
        if hv is None:
            hv = gradient @ domain.extend(blurred)
        return f, np.ascontiguousarray(hv[(slice(None), *domain.inner)])
    return f
