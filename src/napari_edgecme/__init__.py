"""napari-edgecme: camera motion from edge profiles in one motion-blurred photo.

An implementation of Vasu & Rajagopalan, "From local to global: edge profiles to
camera motion in blurred images" (CVPR 2017): a headless engine
(:mod:`napari_edgecme.core`), a napari plugin and the ``edgecme`` command line.
Importing this package loads no Qt and no napari.
"""

from .core.camera import MODELS, Intrinsics, pose_grid
from .core.deconv import deconvolve, iter_deconvolve
from .core.estimate import (
    METHODS,
    MotionEstimate,
    deblur,
    estimate_motion,
    iter_estimate_motion,
)
from .core.metrics import aligned_psnr, aligned_ssim, motion_psf_ncc, psf_ncc
from .core.motion import CameraMotion
from .core.operators import EfficientFilterFlow, WarpSum, blur
from .core.synth import edge_scene, make_case, random_trajectory, render_blur

__version__ = "0.1.0"

__all__ = [
    "METHODS",
    "MODELS",
    "CameraMotion",
    "MotionEstimate",
    "EfficientFilterFlow",
    "Intrinsics",
    "WarpSum",
    "__version__",
    "aligned_psnr",
    "aligned_ssim",
    "blur",
    "deblur",
    "deconvolve",
    "edge_scene",
    "estimate_motion",
    "iter_deconvolve",
    "iter_estimate_motion",
    "make_case",
    "motion_psf_ncc",
    "pose_grid",
    "psf_ncc",
    "random_trajectory",
    "render_blur",
]
