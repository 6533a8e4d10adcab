"""The whole pipeline on one photo: estimate the camera motion, then deconvolve with it.

:func:`deblur` is the engine's one-call face for scripts: the motion is estimated on a
working copy (:func:`~.estimate.estimate_motion`) and the photo is deconvolved at its own
resolution (:func:`~.deconv.deconvolve`). The CLI's ``edgecme deblur`` and the batch
runner take the same two steps with their own progress and reporting, the demo and the
widgets take them one at a time; every one of them restores an estimate with the
parameters :func:`restoring_params` sets for its method (and so do ``edgecme
deconvolve`` and the deconvolution widget with a motion file that names its estimator
and its profile misfit, ``estimated_by`` and ``profile_misfit``). With ``gamma`` other than
linear, both run in linear light: the input is linearised first and the restored image
re-encoded as the input was (:mod:`.photometry`).
"""

from __future__ import annotations

from ._validation import as_float_image, check_choice
from .estimate import estimate_motion
from .photometry import decide_gamma, parse_gamma

__all__ = ["EP_PRIOR_MAX_FACTOR", "EP_PRIOR_MISFIT", "deblur", "ep_prior_factor",
           "ep_prior_note", "record_gamma", "restoring_params"]

#: An EpAlone motion is restored with the hyper-Laplacian's prior weight times
#: ``(profile_misfit / EP_PRIOR_MISFIT) ** 2`` (:func:`ep_prior_factor`): the share of the
#: edge profiles' energy the estimate leaves unexplained measures how rough the motion is,
#: and a wrong PSF acts on the restoration like extra noise, which a stronger prior holds
#: back. Measured with EpAlone's misfit gate lifted (``benchmarks/results/ep-selfcheck.md``):
#: at the former weight, the cases of misfit 12-20% deconvolved worse than their input on
#: 13 of 22 ``lai`` cases; with the factor none of the 56 cases under 20% does, and the
#: ``levin`` captures gain 3.4 dB instead of 3.0.
EP_PRIOR_MISFIT = 0.05
#: The largest factor :func:`ep_prior_factor` gives (a misfit of about 14.1% or more), and
#: the factor of an EpAlone motion whose misfit is not known.
EP_PRIOR_MAX_FACTOR = 8.0


def deblur(image, method: str = "xu+ep", model: str = "rotation", max_blur: float | None = None,
           focal_px: float | None = None, *, deconvolution: str = "hyperlaplacian",
           deconv_params: dict | None = None, callback=None, gamma="linear", **params):
    """Estimate the camera motion, then deconvolve the image with it at full resolution.

    When no blur is found (``estimate.info.no_blur``, with a warning) the image is not
    deconvolved: ``restored`` is the input as floating point, unchanged.

    Parameters
    ----------
    image : array_like of shape (M, N) or (M, N, 3)
    method, model, max_blur, focal_px, callback, **params
        As :func:`~.estimate.estimate_motion`.
    deconvolution, deconv_params
        As :func:`~.deconv.deconvolve` (``method`` and its parameters).
    gamma : {"linear", "srgb", "auto"}, float or Gamma
        The transfer curve ``image`` is stored through. Blur adds light linearly, so
        with ``"srgb"`` (an 8-bit camera photo) or a power-law exponent (``2.2``:
        ``linear = value ** 2.2``) the image is linearised, the motion is estimated
        (edge profiles, L0 latent) and the image deconvolved in linear light, and
        ``restored`` is re-encoded through the same curve (negative ringing clipped
        first). ``"linear"`` (default) takes the values as linear light, as before;
        ``"auto"`` is linear for an array (:func:`~.photometry.decide_gamma` decides
        from a file; the command line does that).

    Returns
    -------
    restored : ndarray, float32 in [0, 1], shaped like ``image``
        Encoded as ``image`` was.
    estimate : MotionEstimate
        ``estimate.info.gamma`` (the curve's name: ``"linear"``, ``"srgb"``, ``"2.2"``)
        and ``estimate.info.gamma_reason`` record the choice (attributes set here).

    Raises
    ------
    ValueError
        A bad ``gamma`` (one line naming it), as the other options, before any work.
    """
    from .deconv import METHODS as DECONV_METHODS
    from .deconv import check_deconvolution_parameters, deconvolve

    # the deconvolution's own checks, before minutes of estimation
    deconvolution = check_choice(deconvolution, "deconvolution", DECONV_METHODS)
    if deconv_params is not None and not isinstance(deconv_params, dict):
        raise ValueError(f"deconv_params must be a dict; got {type(deconv_params).__name__}")
    check_deconvolution_parameters(deconvolution, dict(deconv_params or {}))
    curve = parse_gamma(gamma)
    if curve == "auto":
        curve, reason = decide_gamma(None, image)
    else:
        reason = "given"
    work = image if curve.is_linear else curve.decode(image)  # linear light
    estimate = estimate_motion(work, method, model, max_blur, focal_px, callback=callback,
                               **params)
    record_gamma(estimate.info, curve, reason)
    if estimate.info.no_blur:  # nothing to undo: the photo comes back unchanged
        return as_float_image(image, allow_rgb=True), estimate
    restored = deconvolve(work, estimate.motion, deconvolution, callback=callback,
                          **restoring_params(work, estimate.info.method, deconvolution,
                                             deconv_params,
                                             profile_misfit=estimate.info.profile_misfit))
    if not curve.is_linear:
        restored = curve.encode(restored)
    return restored, estimate


def ep_prior_factor(profile_misfit: float | None) -> float:
    """How much stronger than the reference prior an EpAlone motion is restored with.

    ``(profile_misfit / EP_PRIOR_MISFIT) ** 2`` within ``[1, EP_PRIOR_MAX_FACTOR]``: 1 up
    to a misfit of 5%, 4 at 10%, the largest from about 14.1% on, and the largest when the misfit
    is not known (None: a motion file written without it).

    Parameters
    ----------
    profile_misfit : float or None
        The share of the edge profiles' energy the motion leaves unexplained
        (:attr:`~.estimate.EstimateInfo.profile_misfit`), >= 0.

    Returns
    -------
    float
    """
    if profile_misfit is None:
        return EP_PRIOR_MAX_FACTOR
    return float(min(max((profile_misfit / EP_PRIOR_MISFIT) ** 2, 1.0), EP_PRIOR_MAX_FACTOR))


def _ep_prior_applies(method: str | None, deconvolution: str, params: dict) -> bool:
    """Whether :func:`restoring_params` sets the prior's weight for a motion of ``method``:
    EpAlone, hyper-Laplacian, and no weight given."""
    return (method == "ep" and deconvolution == "hyperlaplacian"
            and params.get("lambda_f") is None and "lam" not in params)


def ep_prior_note(method: str | None, deconvolution: str, params: dict,
                  profile_misfit: float | None) -> str:
    """``"EpAlone prior 4.0x (profile misfit 10%)"`` when the restoration of a motion of
    ``method`` raises the prior's weight for it (:func:`restoring_params`: EpAlone,
    hyper-Laplacian, no weight given), else ``""``: why the output is softer."""
    if not _ep_prior_applies(method, deconvolution, params):
        return ""
    misfit = ("profile misfit not recorded" if profile_misfit is None
              else f"profile misfit {profile_misfit:.0%}")
    return f"EpAlone prior {ep_prior_factor(profile_misfit):.1f}x ({misfit})"


def restoring_params(image, method: str, deconvolution: str, deconv_params=None, *,
                     profile_misfit: float | None = None) -> dict:
    """The deconvolution's parameters for restoring ``image`` with an estimate of ``method``.

    ``deconv_params`` as given, except that an EpAlone motion is restored with a stronger
    hyper-Laplacian prior when no weight is given: the reference weight
    (:data:`~.deconv.REFERENCE_LAMBDA_F`) or the one set from the photo's noise
    (:func:`~.deconv.noise_lambda_f`), whichever is larger, times
    :func:`ep_prior_factor` of the motion's profile misfit. The noise weight (down to
    0.44x the reference on a clean photo) assumes a motion as close as Xu's and Xu+Ep's;
    EpAlone's, from the edge profiles alone, is rougher (on ``levin``'s clean captures it
    rang more at that weight, ``benchmarks/results/noise-weight.md``), the more so the
    less the profiles agree on it (:data:`EP_PRIOR_MISFIT`;
    ``benchmarks/results/ep-selfcheck.md``).

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        The photo to be deconvolved (linear light, [0, 1]).
    method : {"ep", "xu", "xu+ep"}
        The method that estimated the motion (``estimate.info.method``).
    deconvolution : {"hyperlaplacian", "rl", "wiener"}
    deconv_params : dict, optional
    profile_misfit : float, optional
        The estimate's ``info.profile_misfit`` (EpAlone; None: not known).

    Returns
    -------
    dict
    """
    from .deconv import METHODS as DECONV_METHODS
    from .deconv import REFERENCE_LAMBDA_F, noise_lambda_f
    from .estimate import METHODS

    method = check_choice(method, "method", METHODS)
    deconvolution = check_choice(deconvolution, "deconvolution", DECONV_METHODS)
    params = dict(deconv_params or {})
    if _ep_prior_applies(method, deconvolution, params):
        params["lambda_f"] = (max(noise_lambda_f(image), REFERENCE_LAMBDA_F)
                              * ep_prior_factor(profile_misfit))
    return params


def record_gamma(info, curve, reason: str) -> None:
    """Set ``info.gamma`` (the curve's name) and ``info.gamma_reason`` on an
    :class:`~.estimate.EstimateInfo` (attributes beside its fields)."""
    info.gamma = curve.name
    info.gamma_reason = reason
