"""napari-edgecme: camera motion from edge profiles in one motion-blurred photo.

An implementation of Vasu & Rajagopalan, "From local to global: edge profiles to
camera motion in blurred images" (CVPR 2017): a headless engine
(:mod:`napari_edgecme.core`), a napari plugin and the ``edgecme`` command line.
Importing this package loads no Qt and no napari; the public names below are
imported on first use, so ``import napari_edgecme`` (and ``edgecme --help``) is fast.

Examples
--------
>>> from napari_edgecme import deblur, make_case, sample_image   # doctest: +SKIP
>>> case = make_case(sample_image("camera", 256), "rotation", extent=15, rng=0)
>>> restored, estimate = deblur(case.blurred, method="xu+ep", model="rotation")
>>> estimate.motion.save("motion.json")
"""

from importlib import import_module

__version__ = "0.1.0"

#: public name -> module (relative to this package) that defines it
_EXPORTS = {
    "MODELS": ".core.camera",
    "Intrinsics": ".core.camera",
    "pose_grid": ".core.camera",
    "CameraMotion": ".core.motion",
    "EfficientFilterFlow": ".core.operators",
    "WarpSum": ".core.operators",
    "blur": ".core.operators",
    "EdgeProfiles": ".core.edges",
    "extract_edge_profiles": ".core.edges",
    "profile_along_line": ".core.edges",
    "prediction_image": ".core.prediction",
    "edge_profile_image": ".core.prediction",
    "METHODS": ".core.estimate",
    "MotionEstimate": ".core.estimate",
    "estimate_motion": ".core.estimate",
    "iter_estimate_motion": ".core.estimate",
    "deblur": ".core.deblur",
    "deblur_many": ".batch",
    "deconvolve": ".core.deconv",
    "iter_deconvolve": ".core.deconv",
    "make_case": ".core.synth",
    "render_blur": ".core.synth",
    "random_trajectory": ".core.synth",
    "edge_scene": ".core.synth",
    "sample_image": ".core.synth",
    "aligned_psnr": ".core.metrics",
    "aligned_ssim": ".core.metrics",
    "motion_psf_ncc": ".core.metrics",
    "psf_ncc": ".core.metrics",
    "read_image": ".core.io",
    "write_image": ".core.io",
    "Progress": ".core.progress",
    "Cancelled": ".core.progress",
}

__all__ = ["__version__", *sorted(_EXPORTS)]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(module, __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
