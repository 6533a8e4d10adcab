"""The whole pipeline on one photo: estimate the camera motion, then deconvolve with it.

:func:`deblur` is the engine's one-call face (the CLI's ``edgecme deblur``, the batch
runner and the demo go through it): the motion is estimated on a working copy
(:func:`~.estimate.estimate_motion`) and the photo is deconvolved at its own resolution
(:func:`~.deconv.deconvolve`).
"""

from __future__ import annotations

from ._validation import as_float_image, check_choice
from .estimate import estimate_motion

__all__ = ["deblur"]


def deblur(image, method: str = "xu+ep", model: str = "rotation", max_blur: float | None = None,
           focal_px: float | None = None, *, deconvolution: str = "hyperlaplacian",
           deconv_params: dict | None = None, callback=None, **params):
    """Estimate the camera motion, then deconvolve the image with it at full resolution.

    When no blur is found (``estimate.info.no_blur``, with a warning) the image is not
    deconvolved: ``restored`` is the input as floating point, unchanged.

    Returns
    -------
    restored : ndarray, float32 in [0, 1], shaped like ``image``
    estimate : MotionEstimate
    """
    from .deconv import METHODS as DECONV_METHODS
    from .deconv import check_deconvolution_parameters, deconvolve

    # the deconvolution's own checks, before minutes of estimation
    deconvolution = check_choice(deconvolution, "deconvolution", DECONV_METHODS)
    if deconv_params is not None and not isinstance(deconv_params, dict):
        raise ValueError(f"deconv_params must be a dict; got {type(deconv_params).__name__}")
    check_deconvolution_parameters(deconvolution, dict(deconv_params or {}))
    estimate = estimate_motion(image, method, model, max_blur, focal_px, callback=callback,
                               **params)
    if estimate.info.no_blur:  # nothing to undo: the photo comes back unchanged
        return as_float_image(image, allow_rgb=True), estimate
    restored = deconvolve(image, estimate.motion, deconvolution, callback=callback,
                          **(deconv_params or {}))
    return restored, estimate
