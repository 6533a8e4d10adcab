"""What ``benchmarks/bench_deconv_memory.py`` and its test measure: one block's memory.

The deconvolution's memory model (:func:`~napari_edgecme.core.deconv_blocks.block_memory`)
is checked against the ``tracemalloc`` peak of one whole-image block -- the EFF operator
on its latent domain, the tile spectra of the Fourier methods, one iteration of the
solver -- on a random image under a synthetic camera rotation.
"""

from __future__ import annotations

import tracemalloc

import numpy as np

__all__ = ["block_peak", "rotation_motion"]


def rotation_motion(shape, extent: float, seed: int = 0):
    """A random hand-shake camera rotation of ``extent`` px for an image of ``shape``."""
    from ..core.camera import Intrinsics
    from ..core.synth import densify_path, random_trajectory

    cam = Intrinsics.from_image_shape(shape)
    return densify_path(random_trajectory("rotation", cam, extent, rng=seed), "rotation", cam)


def block_peak(motion, side: int, method: str, solver: str, border_iterations: int):
    """``tracemalloc`` peak (bytes) of one ``side`` x ``side`` block's operator and solve.

    ``method`` is ``"hyperlaplacian"``, ``"rl"`` or ``"wiener"``; ``solver``
    (``"fourier"`` or ``"cg"``) is the hyper-Laplacian image step's; ``border_iterations``
    those of the Fourier methods' border correction (memory does not depend on it).
    Returns ``(peak, domain)``, the domain for its operator's figures.
    """
    from ..core.deconv_blocks import auto_stride, fourier_margin, latent_pad, psf_extent
    from ..core.deconv_solvers import (
        LatentDomain,
        PatchFourier,
        hyperlaplacian_steps,
        richardson_lucy_steps,
        wiener,
    )

    K = psf_extent(motion)
    g = np.random.default_rng(0).random((side, side)).astype(np.float32)
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        domain = LatentDomain(motion, (0, side, 0, side), latent_pad(K), auto_stride(motion))
        fourier = None
        if method == "wiener" or solver == "fourier":
            fourier = PatchFourier(domain, margin=fourier_margin(K))
        if method == "hyperlaplacian":
            steps = hyperlaplacian_steps(domain, g, lam=1500.0, alpha=2 / 3, betas=[1.0],
                                         inner_iterations=1, solver=solver, fourier=fourier,
                                         cg_iterations=2, cg_tol=1e-9,
                                         border_iterations=border_iterations)
        elif method == "rl":
            steps = richardson_lucy_steps(domain, g, iterations=1)
        else:
            steps = wiener(domain, g, nsr=0.01, fourier=fourier,
                           border_iterations=border_iterations)
        for _ in steps:
            pass
        return tracemalloc.get_traced_memory()[1] - base, domain
    finally:
        tracemalloc.stop()
