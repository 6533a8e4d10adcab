"""Camera-motion estimation: EpAlone (Eq. 16), Xu (L0, Eq. 21-22 with lambda_Ip = 0) and Xu+Ep.

All three share one coarse-to-fine driver (paper Algorithm 1 run over an image
pyramid with ratio ``1/sqrt(2)``):

* the pose grid of each level has one-pixel steps at that level's resolution and
  the level's share of ``max_blur`` (:func:`~.camera.pose_grid`);
* the MDF found at a coarser level is carried to the next one by splatting its
  poses onto the finer grid; the active pose set is its support dilated by one
  grid step, so the problem stays small where the grid is fine;
* every MDF update solves a non-negative L1 problem (:func:`~.lasso.nonneg_lasso`),
  then drops weights below a floor -- ``1/20`` of the largest for EpAlone, ``1/50`` for
  Xu and Xu+Ep (:data:`LATENT_WEIGHT_FLOOR`) -- renormalises and re-centres the MDF on
  the grid (claims 1-2: the result is defined up to a homography);
* **EpAlone** minimises ``sum_i c_i ||M_i w - dE_i||^2 + lambda_w ||w||_1`` (Eq. 16 on
  the measurement matrix of Eqs. 13-15, :mod:`~.measurement`) -- no latent image. The
  paper solves the image-domain Eq. 19 instead, for speed; the direct form is cheaper
  here, uses the profiles' averaged derivatives rather than single-pixel gradients, and
  takes a weight ``c_i`` per profile: its confidence times its agreement with the
  current estimate and a width check against it, updated after every MDF update
  (:mod:`~.profile_fit`). On the 20
  cases of the ``lai`` quick set the mean PSF NCC against the truth went from 0.543
  (Eq. 19) to 0.601, and the estimate takes 3 s instead of 23 s. EpAlone fits the
  profiles twice, as ideal steps and as soft edges (:data:`~.profile_fit.EP_EDGE_SPREAD`),
  and keeps the soft fit unless it explains the profiles clearly worse;
* **Xu** alternates the L0-gradient latent update (Eq. 21) and the gradient-domain
  MDF update; **Xu+Ep** adds ``lambda_Ip`` times the edge-profile term (Eq. 22).
  ``lambda_Ip = 0`` is exactly Xu. Both run the coarse-to-fine alternation twice, from
  a small blob and from a wide motion (:data:`WIDE_START`), and keep the estimate whose
  polished latent has the sparser gradients. Xu+Ep first runs EpAlone on its profiles (the gate,
  :data:`XU_EP_GATE`): profiles that disagree on one motion are dropped for Xu; profiles
  that agree give a second start of the finest-scale alternation (:data:`SECOND_START`),
  and of the two starts' polished estimates the one whose hyper-Laplacian latent has the
  sparser gradients is kept (:func:`gradient_sparsity`);
* Xu and Xu+Ep end with a **polish** (:data:`POLISH_UPDATES`): MDF updates against the
  hyper-Laplacian latent of the estimate (the non-blind deconvolution's prior) instead of
  the L0 latent, whose piecewise-constant edges the alternation has partly explained
  with a smaller, sharper kernel.

A photo larger than ``max_side`` is estimated on a downscaled copy; Xu and Xu+Ep then
carry the alternation on, at 2x steps, up to the photo's own resolution on a few crops
chosen for their edges (:mod:`~.refine`), so that the motion is a path at the photo's
pixel scale rather than the copy's grid.

``iter_estimate_motion`` is the generator (progress records, cancellable);
``estimate_motion`` drives it. :func:`~.deblur.deblur` estimates and then deconvolves at
full resolution.
"""

from __future__ import annotations

import itertools
import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from ._validation import (
    FLOAT_RANGE,
    as_float_image,
    as_rng,
    check_bool,
    check_choice,
    check_positive,
)
from .camera import MODELS, Intrinsics
from .deconv import REFERENCE_LAMBDA_F
from .deconv_prior import grad
from .latent import iter_l0_latent
from .mdf_update import edge_images, iter_mdf_update
from .motion import CameraMotion
from .photometry import to_luminance
from .profile_fit import (
    EP_EDGE_SPREAD,
    EP_MAX_MISFIT,
    EP_SPREAD_TOLERANCE,
    XU_EP_GATE_MISFIT,
    RobustProfileFit,
    check_coverage,
)
from .progress import Progress, StopRequested, drive, relay_as
from .pyramid import (
    WEIGHT_FLOOR,
    Level,
    ScaleRecord,
    contrast_gain,
    dilate,
    initial_weights,
    pyramid_scales,
    resize,
)
from .refine import iter_refine_motion, refinement_steps

__all__ = [
    "DEFAULTS",
    "EP_MAX_MISFIT",
    "METHODS",
    "EstimateInfo",
    "MotionEstimate",
    "ScaleRecord",
    "default_max_blur",
    "estimate_motion",
    "iter_estimate_motion",
]

#: Estimation methods, by name (the names are API).
METHODS = ("ep", "xu", "xu+ep")

#: Default parameters. Costs are normalised by their data energy, so these mean the
#: same at every scale and image size.
DEFAULTS = {
    "lambda_w": 2e-3,  # L1 weight on the MDF (Eqs. 19, 22)
    "lambda_ip": 1.0,  # weight of the edge-profile term in Xu+Ep (Eq. 22)
    "lambda_f": 6e-3,  # L0 weight at the finest scale (Eq. 21); x 1/scale at coarser ones,
    # and / 1.1 per iteration
    "n_iter": 5,  # alternations per scale (Algorithm 1, n_max)
    "max_side": 1024,  # estimate on a copy whose longer side is at most this
    "min_profiles": 12,  # EpAlone needs at least this many edge profiles
    "coarsest_blur": 5.0,  # pyramid stops when the blur is this small (pixels)
}

_EP_UPDATES_PER_SCALE = 2
#: The L0 weight at a level of scale ``s`` starts at ``lambda_f * s ** -_LAMBDA_F_SCALING``.
#: 2 instead of 1 rescued some of the large text shakes for Xu (``lai`` Xu +0.36 dB, text
#: +1.26) but not Xu+Ep beyond one bistable case, and cut Xu+Ep's margin over Xu
#: (``benchmarks/results/lambda-f-scaling.md``).
_LAMBDA_F_SCALING = 1.0
_SALIENT_START = 0.1  # share of latent gradients used by the first MDF update of a scale
#: Alternations at the finest scale (at most; Xu, Xu+Ep). Measured on 16 synthetic
#: cases (the bench set and 8 others): more alternations there let the L0 latent and
#: the MDF drift from the truth (PSF NCC falls by up to 0.17 on some photos) and cost
#: the most time; 3 instead of 5 gave the same mean PSNR (-0.08 dB / +0.08 dB on the
#: two sets), a higher mean PSF NCC and 30 % less CPU time.
_FINEST_UPDATES = 3
_MAX_ITER = 1000  # cap on n_iter (alternations per scale)
#: MDF weights below this fraction of the largest are dropped after every MDF update of Xu and
#: Xu+Ep, in the alternation and in the polish (:func:`~.pyramid.clean_mdf`). Whyte et al.'s 1/20
#: (:data:`~.pyramid.WEIGHT_FLOOR`) cut the light poses where a camera lingers or trails off at
#: every update, and the estimates came out too small (median extent over the truth's on ``lai``: Xu
#: 0.94, Xu+Ep 0.975; ``levin`` kernel 6 lost its 10 px trail). With 1/50: ``lai`` Xu 24.13 -> 24.22
#: dB, Xu+Ep 24.54 -> 24.55 (people -0.15, the other categories 0 to +0.09), extent 0.97 and 0.99;
#: ``levin`` Xu 29.22 -> 29.67, Xu+Ep 29.24 -> 29.73 (share of the oracle's gain: Xu 66 -> 71 %,
#: Xu+Ep 67 -> 72 %); median CPU time 1.08x (Xu) and 1.03x (Xu+Ep) on ``lai``. EpAlone (and Xu+Ep's
#: runs of it) keeps 1/20: with 1/100 there too, the light poses of the profiles' fit were noise,
#: and Xu+Ep lost 0.45 dB on people. The full-resolution refinement keeps 1/20 (1/50 there was
#: probed on one 12 MP case only: PSF NCC 0.572 -> 0.563, share of the oracle's gain 0.55 -> 0.57).
#: See ``benchmarks/results/weight-floor.md``.
LATENT_WEIGHT_FLOOR = 1.0 / 50.0


def _weight_floor(method: str) -> float:
    """The MDF weight floor of ``method``'s updates: :data:`~.pyramid.WEIGHT_FLOOR` for
    EpAlone, :data:`LATENT_WEIGHT_FLOOR` for Xu and Xu+Ep."""
    return WEIGHT_FLOOR if method == "ep" else LATENT_WEIGHT_FLOOR


#: An estimate whose blur extent (px of the working copy, :meth:`CameraMotion.max_displacement`)
#: is below this has collapsed to the no-blur solution.
COLLAPSE_EXTENT = 2.0
#: Xu and Xu+Ep run the coarse-to-fine alternation a second time from a wide motion
#: (the blob over the whole pose grid of :func:`~.pyramid.initial_weights`) with
#: :data:`_RESTART_LAMBDA_F` times the L0 weight, polish both estimates and keep the one
#: whose latent has the sparser gradients (:func:`gradient_sparsity`), as Xu+Ep does with
#: its second start. From the small blob the alternation finds a long shake's path on
#: some photos only: on others it settles on a delta with stray poses or on a short wrong
#: path, and Xu+Ep's start from the profiles (:data:`SECOND_START`) is not offered when
#: the profiles disagree. On the 60 ``lai`` cases Xu went from 23.61 to 24.13 dB and
#: Xu+Ep from 24.24 to 24.54 (share of the oracle's gain 46.8 -> 49.5 %;
#: saturated_03_gyro2 18.7 -> 25.8 dB, text_03_gyro2 15.6 -> 24.2); ``levin`` and the
#: paper's photos were unchanged; it costs about 1.4x the CPU time. It replaced a restart
#: only when 80 % of the weight lay within 2.5 px of the centroid, which those two
#: escaped (4.5 and 10.6 px). See ``benchmarks/results/wide-start.md``. Without it the
#: estimation restarts from the wide motion only after a collapse to no blur
#: (:data:`COLLAPSE_EXTENT`).
WIDE_START = True
#: Whether Xu+Ep's wide start keeps the edge-profile term of Eq. 22. It does not: the
#: profiles have starts of their own (:data:`SECOND_START`, :data:`EP_CANDIDATE`), and
#: the wide start is then Xu's, an explorer the profiles do not steer. With the term,
#: Xu+Ep was within 0.2 dB of Xu on 50 of the 60 ``lai`` cases; without it on 54, its
#: mean unchanged (24.53 -> 24.54 dB).
WIDE_START_PROFILES = False
#: The second, wide start runs with ``lambda_f`` times this (a sharp-edged latent then
#: has to be explained by the blur).
_RESTART_LAMBDA_F = 3.0
#: "No blur found" when the L0 cost of the estimate exceeds the identity's by this factor
#: (:func:`blind_costs`).
_NO_BLUR_RATIO = 1.5
#: Smallest interior side (px) on which :func:`blind_costs` compares the two costs.
_MIN_INTERIOR = 16


@dataclass
class EstimateInfo:
    """Diagnostics of an estimation run (like ``scipy.optimize.OptimizeResult``).

    ``method`` is the method that ran: ``"xu"`` after Xu+Ep fell back for lack of
    edge profiles (``message`` says so).
    """

    method: str
    model: str
    max_blur: float
    focal_px: float
    working_scale: float
    n_profiles: int = 0
    scales: list[ScaleRecord] = field(default_factory=list)
    seconds: float = 0.0
    converged: bool = False
    message: str = ""
    #: runs of the alternation from a wide motion (Xu, Xu+Ep: :data:`WIDE_START`; any
    #: method after a collapse to no blur)
    restarts: int = 0
    #: Xu, Xu+Ep: the gradient sparsity of the polished latents of the first start's
    #: estimate and of the wide start's (:data:`WIDE_START`; the lower is kept)
    wide_sparsity: tuple[float, float] | None = None
    #: True when no blur was found (the motion is then the identity)
    no_blur: bool = False
    #: L0 cost (Eq. 21, per pixel) of the estimate and of the identity motion
    blind_cost: float | None = None
    identity_cost: float | None = None
    #: EpAlone: the share of the edge profiles' energy the estimate leaves unexplained
    #: (Eq. 16; :meth:`~.profile_fit.RobustProfileFit.relative_misfit`), which sets the
    #: prior its motion is restored with (:func:`~.deblur.ep_prior_factor`); Xu+Ep: that
    #: of the EpAlone check on its profiles (:data:`XU_EP_GATE`)
    profile_misfit: float | None = None
    #: the start of the estimate kept, "blob" (the small blob of
    #: :func:`~.pyramid.initial_weights`), "wide" (the wide motion of :data:`WIDE_START`),
    #: and for Xu+Ep "edge profiles" (the alternation from the EpAlone estimate of its
    #: gate, :data:`SECOND_START`) or "EpAlone" (that estimate itself, on step edges whose
    #: normals span the plane: :data:`EP_CANDIDATE`); and the gradient sparsity of the
    #: Xu+Ep candidates' polished latents (:func:`gradient_sparsity`; the lowest is kept):
    #: the blob's or wide start's estimate, the edge profiles' start, EpAlone's
    start: str = "blob"
    start_sparsity: tuple[float, ...] | None = None
    #: EpAlone: the edge spread (px of the working copy) of the profile model whose
    #: estimate was kept, 0 for ideal steps (:data:`~.profile_fit.EP_EDGE_SPREAD`)
    edge_spread: float = 0.0
    #: what the blur-size measurement found when ``max_blur`` was not given, e.g. "blur
    #: about 40 px, from 85 edge profiles" (:class:`~.blur_size.BlurSize`); None if given
    blur_size: str | None = None
    #: Xu, Xu+Ep: the stretch of the polished motion about its centroid pose that was kept
    #: (:data:`SIZE_STRETCHES`; 1.0: none), and the size criterion of each stretch tried,
    #: in their order (:func:`size_criterion`; the lowest is kept)
    stretch: float = 1.0
    stretch_criteria: tuple[float, ...] | None = None

    def profile_model(self) -> str | None:
        """EpAlone: the profile model kept, "soft edges (1 px spread)" or "step edges";
        None for the other methods and when no profiles were used."""
        if self.method != "ep" or not self.n_profiles:
            return None
        return (f"soft edges ({self.edge_spread:g} px spread)" if self.edge_spread > 0
                else "step edges")


@dataclass
class MotionEstimate:
    """Result of :func:`estimate_motion`.

    Attributes
    ----------
    motion : CameraMotion
        The estimated motion, for the input image's own size, re-centred.
    latent : ndarray of shape (h, w) or None
        The last latent estimate at the working resolution (None for EpAlone): the
        polish's hyper-Laplacian latent (:data:`POLISH_UPDATES`), or the L0 latent
        of the alternation when there was no polish.
    profiles : EdgeProfiles or None
        The edge profiles used (EpAlone, Xu+Ep), in input-image coordinates.
    info : EstimateInfo
    """

    motion: CameraMotion
    latent: np.ndarray | None
    profiles: object | None
    info: EstimateInfo


def default_max_blur(shape) -> float:
    """The blur extent assumed when none is given: 4% of the longer side, at least 15 px."""
    return float(max(15, round(0.04 * max(shape[:2]))))


#: Xu+Ep first runs EpAlone on its profiles and drops the edge-profile term (runs as
#: Xu, with a warning) when they leave more than :data:`XU_EP_GATE_MISFIT` unexplained.
XU_EP_GATE = True

def _check_lambda(value, name, default, allow_zero=False):
    if value is None:
        return default
    return check_positive(value, name, allow_zero=allow_zero)


def iter_estimate_motion(image, method: str = "xu+ep", model: str = "rotation",
                         max_blur: float | None = None, focal_px: float | None = None,
                         profiles=None, *, lambda_w: float | None = None,
                         lambda_ip: float | None = None, lambda_f: float | None = None,
                         n_iter: int | None = None, max_side: int | None = None,
                         refine: bool = True, preview: bool = False, rng=None):
    """Estimate the camera motion of a blurred photo, yielding progress records.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        The blurred photo (any numeric dtype; RGB is estimated on luminance).
    method : {"ep", "xu", "xu+ep"}
        EpAlone (Eq. 16), Xu et al. L0 (the baseline) or Xu+Ep (Eq. 22).
    model : {"translation", "inplane", "rotation"}
        Pose model; ``"translation"`` is uniform (space-invariant) blind deblurring.
    max_blur : float, optional
        Largest blur extent to look for, in pixels of ``image``. By default it is
        measured from the photo's edge profiles (:func:`~.blur_size.measure_blur_extent`,
        then :func:`~.blur_size.max_blur_for`; ``info.blur_size`` says what was found,
        e.g. "blur about 40 px, from 85 edge profiles"), falling back to
        :func:`default_max_blur` when nothing can be measured.
    focal_px : float, optional
        Focal length in pixels of ``image`` (default: the 35 mm-equivalent default of
        :class:`~.camera.Intrinsics`).
    profiles : EdgeProfiles, optional
        Edge profiles to use (e.g. picked by hand), in ``image`` coordinates; by
        default they are extracted automatically (EpAlone, Xu+Ep).
    lambda_w, lambda_ip, lambda_f : float, optional
        Weights of Eqs. 19-22 (see :data:`DEFAULTS`); ``lambda_ip = 0`` is Xu.
    n_iter : int, optional
        Alternations per scale (at most 3 at the finest scale, where more drift; see
        ``_FINEST_UPDATES``).
    max_side : int, optional
        Images larger than this are estimated on a downscaled copy (the motion is
        returned for the full image).
    refine : bool
        On such an image, Xu and Xu+Ep then refine the motion at the image's own
        resolution, on crops chosen for their edges (:mod:`~.refine`): the poses of the
        copy's grid would make each full-size PSF a row of dots. EpAlone's motion is
        rescaled as it is.
    preview : bool
        Attach the current latent image to progress records (Xu, Xu+Ep).
    rng : None, int or numpy.random.Generator
        Seeds every random choice (edge-profile extraction); results are
        deterministic for a given seed.

    Yields
    ------
    Progress
        ``stage="estimate"``; ``scale``/``n_scales``, ``iteration``, ``cost``.

    Returns
    -------
    MotionEstimate
    """
    method = check_choice(method, "method", METHODS)
    model = check_choice(model, "model", MODELS)
    img = as_float_image(image, allow_rgb=True, min_size=8)
    gray = to_luminance(img)
    shape = gray.shape
    if max_blur is None and default_max_blur(shape) > min(shape) / 2:
        max_blur = default_max_blur(shape)  # too small to measure in: refused below
    if max_blur is not None:
        max_blur = check_positive(max_blur, "max_blur")
        if max_blur > min(shape) / 2:
            raise ValueError(f"max_blur must be less than half the smaller image side "
                             f"({min(shape) / 2:g} px); got {max_blur:g}")
        if max_blur < 1:
            raise ValueError(f"max_blur must be at least 1 pixel; got {max_blur:g}")
    lambda_w = _check_lambda(lambda_w, "lambda_w", DEFAULTS["lambda_w"], allow_zero=True)
    lambda_ip = _check_lambda(lambda_ip, "lambda_ip", DEFAULTS["lambda_ip"], allow_zero=True)
    lambda_f = _check_lambda(lambda_f, "lambda_f", DEFAULTS["lambda_f"])
    n_iter = DEFAULTS["n_iter"] if n_iter is None else check_positive(
        n_iter, "n_iter", integer=True, maximum=_MAX_ITER)
    max_side = DEFAULTS["max_side"] if max_side is None else check_positive(
        max_side, "max_side", integer=True)
    if focal_px is not None:
        focal_px = check_positive(focal_px, "focal_px")
    if profiles is not None and not hasattr(profiles, "rescaled"):
        raise ValueError(f"profiles must be None or EdgeProfiles; got {type(profiles).__name__}")
    preview = check_bool(preview, "preview")
    refine = check_bool(refine, "refine")
    rng = as_rng(rng)
    blur_size = None
    if max_blur is None:  # measure it (a few seconds), on its own stream of random numbers
        from .blur_size import resolve_max_blur

        yield Progress("estimate", 0, 1, "measuring the blur size from the edge profiles")
        max_blur, blur_size = resolve_max_blur(img, None, rng=rng, max_side=max_side)
    if method == "xu":
        lambda_ip = 0.0
    t_start = time.perf_counter()

    # -- working copy --------------------------------------------------------------
    intr_full = Intrinsics.from_image_shape(shape, focal_px=focal_px)
    work_scale = min(1.0, max_side / max(shape))
    work_shape = tuple(max(8, round(s * work_scale)) for s in shape)
    yield Progress("estimate", 0, 1, "preparing: the working copy")
    work_raw = resize(gray, work_shape)
    offset, gain = contrast_gain(work_raw)
    constant = float(np.ptp(work_raw)) < 1e-6
    if method == "xu" and constant:  # ep, xu+ep say it with profiles
        warnings.warn("the image is constant: there is no blur to estimate (returning "
                      "the identity motion)", UserWarning, stacklevel=2)
    work = ((work_raw - offset) * gain).astype(work_raw.dtype)
    intr_work = intr_full.rescaled(work_shape)
    blur_work = max_blur * work_scale
    info = EstimateInfo(method, model, max_blur, intr_full.focal_px, work_scale)
    if blur_size is not None:
        info.blur_size = blur_size.message

    # -- edge profiles -------------------------------------------------------------
    scales = pyramid_scales(work_shape, blur_work, DEFAULTS["coarsest_blur"])
    if method == "ep":  # no latent to alternate with: re-solve once after the clean-up
        n_iter = min(n_iter, _EP_UPDATES_PER_SCALE)
    # alternations per scale: fewer at the finest for the latent-image methods (the
    # xu+ep -> xu fallback below keeps them valid)
    level_iters = [n_iter] * len(scales)
    if method != "ep":
        level_iters[-1] = min(n_iter, _FINEST_UPDATES)
    total = sum(level_iters) + (1 if method != "xu" else 0)
    step = 0
    yield Progress("estimate", step, total, "preparing", n_scales=len(scales))
    work_profiles = None
    ep_start = None  # Xu+Ep: the EpAlone estimate of its gate, the second start
    ep_candidate = None  # Xu+Ep: the same, a candidate itself (EP_CANDIDATE)
    polished = None  # the polish of the estimate kept, made to compare the starts
    if method != "xu":
        if profiles is None:
            from .edges import iter_extract_edge_profiles

            work_profiles = yield from relay_as(
                iter_extract_edge_profiles(work_raw, blur_work, rng=rng),
                Progress("estimate", step, total, "preparing: edge profiles",
                         n_scales=len(scales)))
            if method == "xu+ep":
                work_profiles = _trusted(work_profiles, DEFAULTS["min_profiles"])
        else:
            work_profiles = profiles.rescaled(work_scale) if work_scale != 1 else profiles
        info.n_profiles = len(work_profiles)
        need = DEFAULTS["min_profiles"]
        if len(work_profiles) < need:
            why = f" ({work_profiles.reason})" if getattr(work_profiles, "reason", "") else ""
            if method == "ep":
                raise ValueError(f"EpAlone needs at least {need} usable edge profiles; found "
                                 f"{len(work_profiles)}{why}")
            warnings.warn(f"only {len(work_profiles)} usable edge profiles (need {need}){why}; "
                          "falling back to method 'xu'", UserWarning, stacklevel=2)
            method, lambda_ip, work_profiles = "xu", 0.0, None
            info.method = "xu"
            info.message = "fell back to 'xu' (too few edge profiles); "
            total -= 1
        else:
            if method == "ep":
                check_coverage(work_profiles)
            step += 1
            yield Progress("estimate", step, total, f"{len(work_profiles)} edge profiles",
                           n_scales=len(scales))
            if method == "xu+ep" and XU_EP_GATE:
                # do the profiles agree on one motion? EpAlone on them is a few seconds
                ep_iters = [min(n_iter, _EP_UPDATES_PER_SCALE)] * len(scales)
                total += sum(ep_iters)
                check = _CoarseToFine(work, intr_work, model, blur_work, scales, ep_iters,
                                      "ep", work_profiles, gain, lambda_w, 0.0, lambda_f,
                                      False, EstimateInfo("ep", model, max_blur,
                                                          intr_full.focal_px, work_scale),
                                      width_check=False)
                gate_motion, _, step = yield from check.iterate(step, total)
                info.profile_misfit = check.profile_misfit
                if info.profile_misfit > XU_EP_GATE_MISFIT:
                    warnings.warn(
                        f"the {len(work_profiles)} edge profiles do not agree on one camera "
                        f"motion ({info.profile_misfit:.0%} of their energy unexplained by "
                        f"EpAlone on them; at most {XU_EP_GATE_MISFIT:.0%}): running method "
                        "'xu'",
                        UserWarning, stacklevel=2)
                    method, lambda_ip, work_profiles = "xu", 0.0, None
                    info.method = "xu"
                    info.message = "ran as 'xu' (the edge profiles disagree); "
                elif SECOND_START:
                    ep_start = gate_motion
                    # are the photo's edges steps, and do the normals span the plane?
                    # (EpAlone's own tests)
                    if EP_CANDIDATE and _spanning(work_profiles):
                        total += sum(ep_iters)
                        kept, step = yield from _soft_edges(check, check.info, step, total)
                        if kept is check:
                            ep_candidate = gate_motion

    # -- coarse to fine ------------------------------------------------------------
    run = _CoarseToFine(work, intr_work, model, blur_work, scales, level_iters, method,
                        work_profiles, gain, lambda_w, lambda_ip, lambda_f, preview, info)
    motion = latent = None
    stopped = False
    try:
        motion, latent, step = yield from run.iterate(step, total)
        if method == "ep":
            info.profile_misfit = run.profile_misfit
            if EP_EDGE_SPREAD > 0:  # the same fit, with soft edges (profile_fit.py)
                total += sum(level_iters)
                run, step = yield from _soft_edges(run, info, step, total)
                motion = run.motion
        if method == "ep":
            _check_ep_misfit(info, len(work_profiles))
        # -- the wide start (Xu, Xu+Ep): the alternation again from a wide motion, with a
        # stronger L0 weight; after a collapse to no blur every method restarts so
        extent = motion.max_displacement()
        collapsed = extent < COLLAPSE_EXTENT
        if not constant and (collapsed or (WIDE_START and method != "ep")):
            info.restarts += 1
            total += sum(level_iters)
            yield Progress("estimate", step, total,
                           (f"no blur found (extent {extent:.1f} px): restarting"
                            if collapsed else "the wide start: the alternation again")
                           + " from a wide motion",
                           n_scales=len(scales))
            without_profiles = method == "xu+ep" and WIDE_START and not WIDE_START_PROFILES
            wide = run.variant(info, lambda_ip=0.0) if without_profiles else run
            again, again_latent, step = yield from wide.iterate(
                step, total, wide_start=True, lambda_f_factor=_RESTART_LAMBDA_F,
                label="wide start")
            if collapsed:
                if again.max_displacement() > extent:
                    motion, latent = again, again_latent
                    info.start = "wide"
                    if method == "ep":  # the misfit of the estimate kept, and its gate
                        info.profile_misfit = wide.profile_misfit
                        _check_ep_misfit(info, len(work_profiles))
            elif again.max_displacement() >= COLLAPSE_EXTENT:
                # both are blurs: keep the sparser latent's
                sparsity, both, step, total = yield from _polish_candidates(
                    run, (motion, again), "wide start", step, total)
                if sparsity is not None:
                    info.wide_sparsity = sparsity
                    won = sparsity[1] < sparsity[0]
                    info.message += (f"the {'wide' if won else 'first'} start won (gradient "
                                     f"sparsity {min(sparsity):.4g} vs {max(sparsity):.4g}); ")
                    if won:
                        motion, latent = again, again_latent
                        info.start = "wide"
                    polished = both[1] if won else both[0]
        if ep_start is not None:
            motion, latent, polished, step, total = yield from _second_start(
                run, ep_start, motion, latent, info, step, total, candidate=ep_candidate,
                polished=polished)
        info.converged = True
        info.message += "completed all scales"
    except StopRequested:
        if motion is None:  # within the first pass: its estimate so far
            motion, latent = run.motion, run.latent
        if motion is None:
            raise
        stopped = True
        info.message += "stopped by callback; returning the estimate so far"

    # -- no blur: the identity explains the image better than any blur found -------------
    if not stopped:
        yield Progress("estimate", step, total, "checking the estimate against no blur",
                       n_scales=len(scales))
        extent = motion.max_displacement()
        if constant:  # said above (Xu) or by the edge profiles (EpAlone, Xu+Ep)
            info.no_blur = True
            info.message += "; no blur found (the image is constant)"
        else:
            # the L0 cost is the latent-image methods' own objective; EpAlone has none, and
            # its profiles measured the blur directly (a good EpAlone estimate of an
            # in-plane shake can cost 1.75x the identity where the truth costs 1.4x)
            comparable = False
            if method != "ep":
                info.blind_cost, info.identity_cost = yield from relay_as(
                    iter_blind_costs(run.finest, motion, lambda_f),
                    Progress("estimate", step, total, "checking the estimate against no blur",
                             n_scales=len(scales)))
                # the cost test needs an image with structure and an interior to compare on
                comparable = math.isfinite(info.identity_cost) and info.identity_cost > 1e-12
            if extent < COLLAPSE_EXTENT or (
                    comparable and info.blind_cost > _NO_BLUR_RATIO * info.identity_cost):
                info.no_blur = True
                why = (f"the estimate collapsed to {extent:.1f} px" if extent < COLLAPSE_EXTENT
                       else f"the {extent:.1f} px blur estimated explains the photo worse than "
                            f"no blur at all (L0 cost {info.blind_cost:.3g} vs "
                            f"{info.identity_cost:.3g})")
                info.message += f"; no blur found ({why})"
                warnings.warn(f"no blur found: {why}; returning the identity motion. If the "
                              "photo is blurred, try a larger max blur or another model",
                              UserWarning, stacklevel=2)
        if info.no_blur:
            motion = CameraMotion.identity(model, intr_work)

    # -- polish: the MDF fitted once more, against the hyper-Laplacian latent ---------
    # after the no-blur test, which asks the L0 objective about the alternation's own
    # estimate
    if polished is not None and POLISH_UPDATES and not info.no_blur and not stopped:
        motion, latent = polished  # polished by the comparison of the starts
    elif POLISH_UPDATES and method != "ep" and not stopped and not info.no_blur:
        total += POLISH_UPDATES
        try:
            motion, latent, step = yield from _polish(run, motion, step, total)
        except StopRequested:
            stopped = True
            info.message += "; stopped during the polish, returning the estimate before it"

    # -- size: the polished path stretched about its centroid while the latent improves --
    if SIZE_STRETCHES and method != "ep" and not stopped and not info.no_blur:
        total += _size_steps()
        try:
            motion, latent, step = yield from _size(run, motion, latent, step, total, info)
        except StopRequested:
            stopped = True
            info.message += "; stopped while sizing the motion, returning the estimate before it"

    # -- full resolution: the alternation carried on past the working copy, on crops ----
    if refine and not stopped and not info.no_blur and method != "ep" and work_scale < 1:
        total += refinement_steps(work_scale)
        motion, step, completed = yield from iter_refine_motion(
            gray, motion, work_scale, max_blur, offset=offset, gain=gain, work=work_raw,
            lambda_w=lambda_w, lambda_f=lambda_f, step=step, total=total, records=info.scales)
        if not completed:
            stopped = True
            info.message += "; stopped during the full-resolution refinement"

    # -- result at the input's own size ----------------------------------------------
    final = motion.compact().recentred().rescale(shape)
    out_profiles = work_profiles
    if out_profiles is not None and work_scale != 1:
        out_profiles = profiles if profiles is not None else work_profiles.rescaled(
            1.0 / work_scale)
    info.seconds = time.perf_counter() - t_start
    if stopped:
        info.converged = False
    return MotionEstimate(final, latent, out_profiles, info)


class _CoarseToFine:
    """The coarse-to-fine alternation (Algorithm 1 over the pyramid), restartable.

    ``iterate`` is a generator of progress records that returns ``(motion, latent,
    step)``; ``motion``/``latent`` always hold the latest estimate, so a cancelled run
    can return it. ``finest`` is the finest level after a run (for :func:`blind_costs`).
    """

    def __init__(self, work, intrinsics, model, blur_work, scales, level_iters, method,
                 profiles, gain, lambda_w, lambda_ip, lambda_f, preview, info, *,
                 edge_spread: float = 0.0, width_check: bool = True):
        self.work, self.intrinsics, self.model = work, intrinsics, model
        self.blur_work, self.scales, self.level_iters = blur_work, scales, level_iters
        self.method, self.profiles, self.gain = method, profiles, gain
        self.lambda_w, self.lambda_ip, self.lambda_f = lambda_w, lambda_ip, lambda_f
        self.preview, self.info = preview, info
        #: EpAlone: the edge spread of its profile model (px of the working copy;
        #: :data:`~.profile_fit.EP_EDGE_SPREAD`), 0 for ideal step edges
        self.edge_spread = edge_spread
        #: EpAlone: whether profiles narrower than the estimate predicts lose weight
        #: (:func:`~.profile_fit.width_weight`); Xu+Ep's gate runs without it
        self.width_check = width_check
        self.motion: CameraMotion | None = None
        self.latent = None
        self.finest: Level | None = None
        #: EpAlone: the share of the profiles the last estimate leaves unexplained
        #: (:meth:`~.profile_fit.RobustProfileFit.relative_misfit`)
        self.profile_misfit: float | None = None

    def variant(self, info: EstimateInfo, *, scales=None, level_iters=None,
                edge_spread: float | None = None,
                lambda_ip: float | None = None) -> _CoarseToFine:
        """The same problem, not yet run, recording into ``info``: on the finest of
        ``scales`` only, say, or with another edge spread or edge-profile weight."""
        return _CoarseToFine(
            self.work, self.intrinsics, self.model, self.blur_work,
            self.scales if scales is None else scales,
            self.level_iters if level_iters is None else level_iters, self.method,
            self.profiles, self.gain, self.lambda_w,
            self.lambda_ip if lambda_ip is None else lambda_ip, self.lambda_f,
            self.preview, info,
            edge_spread=self.edge_spread if edge_spread is None else edge_spread,
            width_check=self.width_check)

    def iterate(self, step: int, total: int, *, wide_start: bool = False,
                lambda_f_factor: float = 1.0, start: CameraMotion | None = None,
                label: str | None = None):
        method, scales, work_shape = self.method, self.scales, self.work.shape
        self.motion = start
        for li, s in enumerate(scales):
            lshape = tuple(max(8, round(n * s)) for n in work_shape)
            level = Level(li, resize(self.work, lshape), self.intrinsics.rescaled(lshape),
                           self.model, max(2.0, self.blur_work * s))
            record = ScaleRecord(li + 1, lshape, level.max_blur, level.grid.size)
            self.info.scales.append(record)
            weights = initial_weights(level, self.motion, wide=wide_start)
            active = np.ones(level.grid.counts, bool) if self.motion is None else dilate(
                weights > 0)
            ep_data = None
            if self.profiles is not None and method == "ep":  # Eq. 16, robust
                ep_data = RobustProfileFit(self.profiles.rescaled(s) if s != 1
                                           else self.profiles, self.edge_spread * s,
                                           width_check=self.width_check)
            elif self.profiles is not None and self.lambda_ip > 0:  # Eq. 22's Eq. 19 term
                ep_data = edge_images(level, self.profiles, s, self.gain)
            # coarse levels: sharper edges, larger weight
            lam_f = lambda_f_factor * self.lambda_f * s ** -_LAMBDA_F_SCALING
            level_iter = self.level_iters[li]
            for it in range(level_iter):
                parts = [label] if label else []
                if len(scales) > 1 or not label:  # a labelled single level needs no scale
                    parts.append(f"scale {li + 1}/{len(scales)}")
                where = ", ".join([*parts, f"iteration {it + 1}/{level_iter}"])
                at = {"scale": li + 1, "n_scales": len(scales), "iteration": it + 1}
                if method != "ep":
                    # a record per splitting step: on a 1024 px copy an alternation
                    # takes seconds, and a consumer can only cancel at a record
                    self.latent = yield from relay_as(
                        iter_l0_latent(level.blurred, level.motion(weights), lam_f, fine=True),
                        Progress("estimate", step, total, f"{where}: latent image", **at))
                    lam_f = max(lam_f / 1.1, 1e-4)
                    yield Progress("estimate", step, total, f"{where}: camera motion", **at)
                weights, cost, n_lasso = yield from relay_as(
                    iter_mdf_update(level, weights, active, self.latent, ep_data,
                                    self.lambda_w, self.lambda_ip, method,
                                    salient=_SALIENT_START * 1.1 ** min(it, 24),
                                    weight_floor=_weight_floor(method)),
                    Progress("estimate", step, total, f"{where}: camera motion", **at))
                if method == "ep":  # IRLS: each profile weighed by its agreement and width
                    ep_data.update(level.cache["measurement"], weights[active])
                    self.profile_misfit = ep_data.relative_misfit()
                self.motion = level.motion(weights)
                record.costs.append(cost)
                record.active_poses.append(int(active.sum()))
                record.lasso_iterations.append(n_lasso)
                step += 1
                latent = self.latent
                yield Progress("estimate", step, total, where, cost=cost,
                               preview=latent.copy() if self.preview and latent is not None
                               else None, **at)
            self.finest = level
        return self.motion, self.latent, step



def _check_ep_misfit(info: EstimateInfo, n_profiles: int) -> None:
    """EpAlone's self-check: refuse, in one line, an estimate that leaves more than
    :data:`~.profile_fit.EP_MAX_MISFIT` of the profiles' energy unexplained."""
    if info.profile_misfit > EP_MAX_MISFIT:
        raise ValueError(
            f"EpAlone: the {n_profiles} edge profiles do not agree on one camera "
            f"motion ({info.profile_misfit:.0%} of their energy is left unexplained by "
            f"the best one; at most {EP_MAX_MISFIT:.0%} is accepted); try method "
            "'xu+ep', which also uses the image")


def _soft_edges(run: _CoarseToFine, info: EstimateInfo, step: int, total: int):
    """EpAlone again with the soft-edge profile model; the run whose estimate is kept.

    A generator of progress records returning ``(run, step)``: the run with an edge
    spread of :data:`~.profile_fit.EP_EDGE_SPREAD` when it leaves at most
    :data:`~.profile_fit.EP_SPREAD_TOLERANCE` times the misfit of the ideal-step fit
    ``run`` (the photo's edges are soft), else ``run``. ``info`` records the choice.
    """
    soft = run.variant(info, edge_spread=EP_EDGE_SPREAD)
    yield Progress("estimate", step, total, f"EpAlone again, for soft edges "
                   f"({EP_EDGE_SPREAD:g} px spread)", n_scales=len(run.scales))
    _, _, step = yield from soft.iterate(step, total)
    step_misfit = run.profile_misfit
    if soft.profile_misfit <= EP_SPREAD_TOLERANCE * step_misfit:
        info.edge_spread, info.profile_misfit = EP_EDGE_SPREAD, soft.profile_misfit
        info.message += (f"soft edges ({EP_EDGE_SPREAD:g} px spread: misfit "
                         f"{soft.profile_misfit:.1%} vs {step_misfit:.1%} as steps); ")
        return soft, step
    info.message += (f"step edges (misfit {step_misfit:.1%}; {soft.profile_misfit:.1%} "
                     f"with a {EP_EDGE_SPREAD:g} px spread); ")
    return run, step


#: Xu+Ep runs its finest-scale alternation a second time, started from the EpAlone
#: estimate of its gate (:data:`XU_EP_GATE`), polishes both estimates (:func:`_polish`)
#: and keeps the one whose hyper-Laplacian latent has the sparser gradients
#: (:func:`gradient_sparsity`). The edge profiles alone often find the shape of the path
#: where the alternation from a small blob falls into a wrong basin (on manmade photos),
#: while their estimate is too thick to deblur with (the profiles measure only
#: projections); the alternation from it thins it. See
#: ``benchmarks/results/second-start.md``.
SECOND_START = True
#: ... and, when the photo's edges are steps -- EpAlone's soft-edge model
#: (:data:`~.profile_fit.EP_EDGE_SPREAD`) fits the profiles more than
#: :data:`~.profile_fit.EP_SPREAD_TOLERANCE` times worse than ideal steps -- the EpAlone
#: estimate itself, polished, is a third candidate. Step edges are where the profiles
#: measure the PSF's projections best (text, man-made scenes), and there the alternation
#: drifted from a good EpAlone estimate (``lai`` text_01_gyro4: EpAlone 22.87 dB, Xu+Ep
#: 18.66). Against soft edges the thick EpAlone estimate still won the sparsity contest
#: but deblurred worse (natural_02_gyro3 -5.0 dB), so it is not offered there. See
#: ``benchmarks/results/ep-candidate.md``. Nor is it offered when the profiles' normals
#: are nearly parallel (EpAlone refuses such a set: :func:`~.profile_fit.check_coverage`),
#: as they fix the path only across one direction (natural_03_gyro4: -1.2 dB with it).
EP_CANDIDATE = True


def gradient_sparsity(latent: np.ndarray, band: int) -> float:
    """The l1/l2 ratio of a latent image's gradients on its interior, in (0, 1].

    ``||grad f||_1 / (sqrt(2 N) ||grad f||_2)`` over the ``N`` pixels left when a band of
    ``band`` px is cut off (Krishnan, Tay & Fergus 2011, "Blind deconvolution using a
    normalized sparsity measure"): scale-free, and lower for a sharper image -- blur
    spreads an edge's gradient over many small values, the ringing of a wrong motion adds
    gradients where the scene has none. Xu+Ep compares its two starts with it
    (:data:`SECOND_START`). The L0 cost (Eq. 21) it replaced is the alternation's own
    objective, and nearly as low for a wrong motion as for the right one: on the 48
    ``lai`` cases that ran both starts (both polished), keeping the lower-cost estimate
    (with a 0.5 % tie band) lost up to 4.1 dB against the better of the two and was
    within 0.2 dB of it on 37; the sparsity lost at most 1.6 dB, was within 0.2 dB on
    40, and its picks deblur 0.11 dB better on average
    (``benchmarks/results/second-start.md``).

    Parameters
    ----------
    latent : ndarray of shape (h, w)
    band : int
        Pixels left out at every side (the PSF's reach, where deconvolution rings).

    Returns
    -------
    float
        NaN when nothing is left, or the interior has no gradient.
    """
    f = np.asarray(latent, np.float64)
    if min(f.shape) - 2 * band < 2:
        return float("nan")
    inner = (slice(band, f.shape[0] - band), slice(band, f.shape[1] - band))
    gx, gy = (d[inner] for d in grad(f))
    l2 = math.sqrt(float(np.sum(gx ** 2) + np.sum(gy ** 2)))
    if not l2 > 0:
        return float("nan")
    return float((np.abs(gx).sum() + np.abs(gy).sum()) / (math.sqrt(2 * gx.size) * l2))


def _second_start(run: _CoarseToFine, start: CameraMotion, motion: CameraMotion, latent,
                  info: EstimateInfo, step: int, total: int, *,
                  candidate: CameraMotion | None = None, polished=None):
    """The finest-scale alternation of ``run`` again, from ``start``; the best estimate.

    The candidates are the first start's estimate ``motion``, the second start's, and
    ``candidate`` when given (the EpAlone estimate itself: :data:`EP_CANDIDATE`). Each
    is polished (:func:`_polish`, at least one update) and they are compared by the
    :func:`gradient_sparsity` of their polish's latents, on the interior of the largest
    PSF. A generator of progress records returning ``(motion, latent, polished, step,
    total)``: the estimate kept (before its polish, for the no-blur test; ``candidate``
    has no alternation of its own and is handed on polished), its latent, and its polish
    ``(motion, latent)``. ``polished``, when given, is ``motion``'s polish already made
    (by the wide start's comparison): it is not made again, and it is what is handed on
    when the first estimate is kept because the second collapsed to no blur or the
    comparison could not be made (None if it was not given).
    """
    level_iters = run.level_iters[-1]
    total += level_iters
    second = run.variant(EstimateInfo(info.method, info.model, info.max_blur, info.focal_px,
                                      info.working_scale),
                         scales=run.scales[-1:], level_iters=[level_iters])
    label = "second start, from the edge profiles' estimate"
    other, other_latent, step = yield from second.iterate(step, total, start=start,
                                                          label=label)
    if other.max_displacement() < COLLAPSE_EXTENT:
        return motion, latent, polished, step, total
    candidates = (motion, other) if candidate is None else (motion, other, candidate)
    made = {} if polished is None else {0: polished}
    sparsity, polishes, step, total = yield from _polish_candidates(
        run, candidates, label, step, total, made=made)
    if sparsity is None:
        return motion, latent, polished, step, total
    info.start_sparsity = sparsity
    best = int(np.argmin(sparsity))
    if best == 0:
        return motion, latent, polishes[0], step, total
    others = ", ".join(f"{x:.4g}" for k, x in enumerate(sparsity) if k != best)
    if best == 1:
        info.start = "edge profiles"
        info.message += (f"the start from the edge profiles' estimate won (gradient "
                         f"sparsity {sparsity[1]:.4g} vs {others}); ")
        return other, other_latent, polishes[1], step, total
    info.start = "EpAlone"
    info.message += (f"the edge profiles' own estimate, polished, won (gradient sparsity "
                     f"{sparsity[2]:.4g} vs {others}); ")
    return polishes[2][0], polishes[2][1], polishes[2], step, total


def _polish_candidates(run: _CoarseToFine, candidates, label: str, step: int, total: int,
                       made=None):
    """Polish candidate estimates and measure their latents' gradient sparsity.

    Each is polished (:func:`_polish`, at least one update) and the
    :func:`gradient_sparsity` of its polish's latent is taken on the interior of the
    largest PSF, the same for all. A generator of progress records returning
    ``(sparsity, polished, step, total)``: the candidates' sparsities in their order
    (None when any cannot be measured) and their polishes ``(motion, latent)``.
    ``made`` maps a candidate's index to its polish when it is already made.
    """
    made = made or {}
    updates = max(1, POLISH_UPDATES)
    total += (len(candidates) - len(made)) * updates
    polished = []
    for which, candidate in enumerate(candidates):
        if which in made:
            polished.append(made[which])
            continue
        polished_motion, polished_latent, step = yield from relay_as(
            _polish(run, candidate, step, total, updates),
            Progress("estimate", step, total, f"{label}: polishing estimate {which + 1} of "
                     f"{len(candidates)} to compare them", n_scales=len(run.scales)))
        polished.append((polished_motion, polished_latent))
    band = interior_band(run.finest.shape, *(m for m, _ in polished))
    sparsity = tuple(gradient_sparsity(f, band) for _, f in polished)
    if not all(math.isfinite(x) for x in sparsity):
        sparsity = None
    return sparsity, polished, step, total


#: MDF updates of the polish that ends Xu and Xu+Ep (0: none). Each solves the gradient
#: term of Eq. 22 (for Xu+Ep without its edge-profile term: :data:`POLISH_EDGE_PROFILES`)
#: against the hyper-Laplacian latent of the current estimate
#: (:func:`~.deconv.iter_deconvolve` with :data:`POLISH_DECONVOLUTION`) on the finest
#: level, with the estimate's support dilated by :data:`POLISH_DILATION` grid steps and
#: the strongest :data:`POLISH_SALIENT` of the salient gradients. The L0 latent the
#: alternation works with has sharper, emptier edges than the photo's, and the MDF
#: fitted to it is too small and too sharp (estimates' extent about 0.9x the truth's on
#: lai); the hyper-Laplacian latent keeps the detail and the soft edges the non-blind
#: deconvolution will keep. See ``benchmarks/results/polish.md``.
POLISH_UPDATES = 2
POLISH_SALIENT = 0.15
POLISH_DILATION = 2
#: Whether Xu+Ep's polish keeps the edge-profile term of Eq. 22 (``lambda_Ip`` times it).
#: It does not: the profiles have chosen the basin by then (the alternation, the second
#: start, the EpAlone candidate), and at the finest scale their inaccuracy -- about one
#: kept profile in five is false to the blur -- only bends the final path. Without the
#: term the polish fits the image data alone: on the 32 ``levin`` captures Xu+Ep went
#: from 29.11 to 29.25 dB, and on the 60 ``lai`` cases its mean was unchanged (24.38 dB;
#: manmade +0.02, natural -0.03, people +0.10, saturated -0.07, text -0.02), with 56 of
#: 60 cases within 0.2 dB of Xu instead of 53 (``benchmarks/results/ep-polish-off.md``).
POLISH_EDGE_PROFILES = False
#: Keywords of the polish's hyper-Laplacian deconvolution (the sizing's too). Its prior
#: weight is fixed at the reference (:data:`~.deconv.REFERENCE_LAMBDA_F`), not set from
#: the photo's noise as the final restoration's is: the polish, the comparisons of the
#: candidates and the sizing were measured with it. A cheaper latent -- splitting from
#: beta = 4 (5 steps) and 4 border CG iterations, 1.8x faster -- left `lai` unchanged
#: but collapsed the estimate of a small photo with clipped highlights
#: (``tests/core/test_no_blur.py``; its low-beta steps matter there), so it is not used
#: (``benchmarks/results/polish.md``).
POLISH_DECONVOLUTION: dict = {"lambda_f": REFERENCE_LAMBDA_F}


def _deconvolution_range(g: np.ndarray):
    """``g`` as the hyper-Laplacian deconvolution accepts it, and the map of its latents
    back: ``(unit, back)``.

    A level beyond :data:`~._validation.FLOAT_RANGE` (a contrast-stretched photo with
    clipped highlights) is mapped onto [0, 1]; ``back`` maps a latent of ``unit`` to
    ``g``'s range and dtype (only the dtype when ``unit`` is ``g``).
    """
    lo, hi = float(g.min()), float(g.max())
    if (FLOAT_RANGE[0] <= lo and hi <= FLOAT_RANGE[1]) or hi <= lo:
        return g, lambda latent: latent.astype(g.dtype, copy=False)
    return ((g - lo) / (hi - lo),
            lambda latent: (latent * (hi - lo) + lo).astype(g.dtype, copy=False))


def _polish(run: _CoarseToFine, motion: CameraMotion, step: int, total: int,
            updates: int = POLISH_UPDATES):
    """``updates`` MDF updates against the hyper-Laplacian latent of ``motion``.

    A generator of progress records returning ``(motion, latent, step)``: the polished
    motion on ``run``'s finest level and the last hyper-Laplacian latent (h, w).

    The MDF starts from ``motion`` re-centred (claims 1-2), whose poses then fall
    between the grid's points: splatted, each spreads over its neighbours, and the
    update starts from a slightly widened path it can grow into or thin again (from the
    grid-aligned path itself the polish gained less: PSF NCC 0.878 instead of 0.909 on
    ``lai`` natural_01_gyro3). The level is deconvolved in the range deconvolution
    accepts (:func:`_deconvolution_range`), its latent mapped back.
    """
    from .deconv import iter_deconvolve

    level = run.finest  # its MDF terms are rebuilt for the polish's own active set
    weights = initial_weights(level, motion.recentred())
    active = dilate(weights > 0, POLISH_DILATION)
    lambda_ip = run.lambda_ip if POLISH_EDGE_PROFILES else 0.0
    ep_data = None
    if run.profiles is not None and lambda_ip > 0:
        ep_data = edge_images(level, run.profiles, 1.0, run.gain)
    unit, back = _deconvolution_range(level.blurred)
    n_scales = len(run.scales)
    latent = None
    for it in range(updates):
        where = f"polish {it + 1}/{updates}"
        latent = yield from relay_as(
            iter_deconvolve(unit, level.motion(weights), "hyperlaplacian",
                            **POLISH_DECONVOLUTION),
            Progress("estimate", step, total, f"{where}: deconvolving (hyper-Laplacian)",
                     n_scales=n_scales))
        latent = back(latent)
        weights, _cost, _n = yield from relay_as(
            iter_mdf_update(level, weights, active, latent, ep_data, run.lambda_w,
                            lambda_ip, run.method, salient=POLISH_SALIENT,
                            weight_floor=_weight_floor(run.method)),
            Progress("estimate", step, total, f"{where}: refitting the motion",
                     n_scales=n_scales))
        step += 1
        yield Progress("estimate", step, total, where, n_scales=n_scales)
    return level.motion(weights), latent, step


#: Stretches of the polished motion about its centroid pose that Xu and Xu+Ep try, in
#: this order, after the polish (:func:`_size`; empty: none). Even polished, the estimates
#: of the latent-image methods come out a little small -- the L1 weight on the MDF and the
#: sparse latent both favour a shorter path: the radius holding 80 % of the weight was a
#: median 0.96x the truth's on the 20 ``lai`` quick cases and 0.95x on the 32 ``levin``
#: captures (0.5-0.6x on levin's kernel 6) -- and the best stretch of each estimate,
#: known from the truth, would gain 0.25 dB (lai) and 0.38 dB (levin). No single stretch
#: does (1.05 for all: +0.06 and -0.01 dB), so each estimate is stretched only as far as
#: :func:`size_criterion` says its latent improves. See ``benchmarks/results/size.md``.
SIZE_STRETCHES = (1.05, 1.10, 1.15, 1.20)
#: Weight of the log residual in :func:`size_criterion`. The latent's gradient sparsity
#: alone keeps stretching (a too-large motion sharpens the edges and rings: on levin it
#: picked stretches that lost 0.01 dB on average against the best's +0.38), the residual
#: alone prefers the smallest motion. Their sum, scored on the record's estimates
#: (stretches 1.0-1.2): 0.03 kept +0.32 dB of levin's +0.38 and +0.12 of lai's +0.25 (20
#: quick cases), 0.1 kept +0.21 and +0.08 with fewer losses (levin: none over 0.2 dB). In
#: the engine 0.03 gave lai +0.16 and levin +0.25 dB but also stretched right-sized
#: estimates of small synthetic photos (128-160 px, 9 px shifts: -0.2 to -1.2 dB, where
#: 0.07-0.08 was needed to keep them): 0.1 is the choice that holds on both.
SIZE_RESIDUAL_WEIGHT = 0.1


def size_criterion(latent: np.ndarray, blurred: np.ndarray, motion: CameraMotion,
                   band: int) -> float:
    """How well a motion and its hyper-Laplacian latent explain a blurred image (lower is
    better): ``gradient_sparsity(f) + SIZE_RESIDUAL_WEIGHT * ln(||T_k f - g||^2 / N)``.

    The latent's normalised gradient sparsity (:func:`gradient_sparsity`: lower for a
    sharper latent) plus the log of the mean squared residual of its re-blur -- the
    negative log-likelihood of Gaussian noise whose variance is the residual's (the
    profile likelihood), scaled. On the interior (``band`` px left out at every side).

    Parameters
    ----------
    latent : ndarray of shape (h, w)
        ``f``, the hyper-Laplacian deconvolution of ``blurred`` with ``motion``.
    blurred : ndarray of shape (h, w)
        ``g``.
    motion : CameraMotion
        ``k``, at the images' size.
    band : int
        Pixels left out at every side; the same for every motion compared.

    Returns
    -------
    float
        NaN when the interior is empty or has no gradient.
    """
    from .operators import blur

    inner = (slice(band, latent.shape[0] - band), slice(band, latent.shape[1] - band))
    residual = blur(latent, motion)[inner].astype(np.float64) - blurred[inner]
    mse = float(np.mean(residual ** 2)) if residual.size else float("nan")
    if not mse > 0:
        return float("nan")
    return gradient_sparsity(latent, band) + SIZE_RESIDUAL_WEIGHT * math.log(mse)


def _size_steps() -> int:
    """Progress steps :func:`_size` takes: the motion as it is, then each stretch."""
    return 1 + len(SIZE_STRETCHES)


def stretched(motion: CameraMotion, factor: float) -> CameraMotion:
    """``motion`` with every pose moved ``factor`` times as far from the centroid pose."""
    centre = motion.centroid_pose()
    return CameraMotion(motion.model, motion.intrinsics,
                        centre + factor * (motion.poses - centre), motion.weights)


def _size(run: _CoarseToFine, motion: CameraMotion, latent, step: int, total: int,
          info: EstimateInfo):
    """Stretch ``motion`` about its centroid pose while :func:`size_criterion` falls.

    The stretches of :data:`SIZE_STRETCHES` whose blur extent stays within the max blur
    (:meth:`~.motion.CameraMotion.blur_extent`, the length ``max_blur`` bounds) are tried
    in their order on ``run``'s finest level, each deconvolved as the polish does; the
    first whose criterion is not lower than the best so far ends the search. A generator
    of progress records returning ``(motion, latent, step)``: the stretch kept and its
    hyper-Laplacian latent (``motion`` and ``latent`` as given when no stretch fits or no
    criterion can be measured).
    """
    from .deconv import iter_deconvolve

    level = run.finest
    n_scales = len(run.scales)
    end = step + _size_steps()  # the steps reserved, whether tried or not
    # the blur extent grows with the stretch: the first stretch past the max blur is
    # followed only by others past it
    fits = list(itertools.takewhile(
        lambda fm: fm[1].blur_extent() <= level.max_blur * (1 + 1e-9),
        ((f, stretched(motion, f)) for f in SIZE_STRETCHES)))
    if not fits:
        yield Progress("estimate", end, total, "sized the motion: no stretch fits the max "
                       "blur", n_scales=n_scales)
        return motion, latent, end
    unit, back = _deconvolution_range(level.blurred)
    # one interior for all: that of the largest stretch tried
    band = interior_band(level.shape, fits[-1][1])
    best = None
    criteria = []
    for factor, candidate in [(1.0, motion), *fits]:
        where = f"sizing the motion: stretch {factor:g}"
        trial = yield from relay_as(
            iter_deconvolve(unit, candidate, "hyperlaplacian", **POLISH_DECONVOLUTION),
            Progress("estimate", step, total, f"{where}: deconvolving (hyper-Laplacian)",
                     n_scales=n_scales))
        criterion = size_criterion(trial, unit, candidate, band)
        criteria.append(criterion)
        step += 1
        yield Progress("estimate", step, total, where, n_scales=n_scales)
        if not math.isfinite(criterion):
            break
        if best is not None and not criterion < best[0]:
            break
        best = (criterion, factor, candidate, trial)
    info.stretch_criteria = tuple(criteria)
    kept = 1.0 if best is None else best[1]
    yield Progress("estimate", end, total, f"sized the motion: stretch {kept:g} kept",
                   n_scales=n_scales)
    if best is None:  # nothing measurable: keep the motion as it is
        return motion, latent, end
    _, factor, motion, latent = best
    info.stretch = factor
    if factor != 1.0:
        info.message += f"; stretched the motion {factor:g}x (size criterion)"
    return motion, back(latent), end


#: Xu+Ep uses the automatic profiles whose calibrated confidence is at least this
#: (:attr:`EdgeProfiles.confidence`), when enough of them remain: its edge-profile term
#: pulls the whole alternation, and a false profile pulls it the wrong way.
XU_EP_MIN_CONFIDENCE = 0.7


def _spanning(profiles) -> bool:
    """Whether the profiles' normals pass EpAlone's orientation check
    (:func:`~.profile_fit.check_coverage`)."""
    try:
        check_coverage(profiles)
    except ValueError:
        return False
    return True


def _trusted(profiles, need: int):
    """The profiles of confidence >= :data:`XU_EP_MIN_CONFIDENCE`, if ``need`` remain."""
    conf = profiles.confidence
    trusted = np.isfinite(conf) & (conf >= XU_EP_MIN_CONFIDENCE)
    return profiles.select(trusted) if trusted.sum() >= need else profiles


def interior_band(shape, *motions: CameraMotion) -> int:
    """Border (px) left out when images made with ``motions`` are compared on ``shape``.

    Half the largest PSF side of the motions at that shape, plus 2: inside it, no pixel
    of a latent or of its re-blur depends on the boundary condition of any of them.
    """
    return max(m.rescale(shape).psf_size() for m in motions) // 2 + 2


def blind_costs(level: Level, motion: CameraMotion, lambda_f: float) -> tuple[float, float]:
    """:func:`iter_blind_costs` run to its end."""
    return drive(iter_blind_costs(level, motion, lambda_f))


def iter_l0_cost(level: Level, motion: CameraMotion, lambda_f: float, band: int | None = None):
    """The L0 blind-deblurring cost (Eq. 21) of ``motion`` on ``level``, per pixel.

    ``E(k) = ||T_k f_k - g||^2 / N + lambda_f ||grad f_k||_0 / N`` with ``f_k`` the L0
    latent for motion ``k`` (:func:`~.latent.l0_latent`), on the interior of the level:
    a band of ``band`` px (default half the PSF size of ``motion``, plus 2) left out.
    A generator of progress records (the latent's); returns NaN when the level has no
    interior left to compare on (an image not much larger than its blur).
    """
    from .operators import blur

    g = level.blurred
    k = motion.rescale(level.shape)
    band = interior_band(level.shape, k) if band is None else band
    if min(g.shape) - 2 * band < _MIN_INTERIOR:
        return float("nan")
    inner = (slice(band, -band), slice(band, -band))
    f, (gx, gy) = yield from iter_l0_latent(g, k, lambda_f, return_gradients=True, fine=True)
    residual = blur(f, k)[inner] - g[inner]
    nonzero = (gx[inner] ** 2 + gy[inner] ** 2) > 0
    return float(np.mean(residual.astype(np.float64) ** 2) + lambda_f * np.mean(nonzero))


def iter_blind_costs(level: Level, motion: CameraMotion, lambda_f: float):
    """The L0 cost (:func:`iter_l0_cost`) of ``motion`` and of the identity, per pixel.

    A motion found on a blurred photo costs about as much as the identity -- the L0
    objective barely prefers the true blur to none, which is why the alternation can
    collapse -- but on a sharp photo a blur costs several times more: the test of
    :data:`_NO_BLUR_RATIO`. Both costs are taken on the same interior (that of
    ``motion``).

    Returns
    -------
    (cost of ``motion``, cost of the identity)
        Both NaN when the level has no interior left to compare on.
    """
    band = interior_band(level.shape, motion)
    first = yield from iter_l0_cost(level, motion, lambda_f, band)
    if not math.isfinite(first):
        return float("nan"), float("nan")
    identity = CameraMotion.identity(motion.model, level.intrinsics)
    second = yield from iter_l0_cost(level, identity, lambda_f, band)
    return first, second


def estimate_motion(image, method: str = "xu+ep", model: str = "rotation",
                    max_blur: float | None = None, focal_px: float | None = None,
                    profiles=None, *, callback=None, **params) -> MotionEstimate:
    """Estimate the camera motion of a blurred photo.

    The plain-function face of :func:`iter_estimate_motion` (same parameters);
    ``callback(progress)`` is called with each progress record and may raise
    ``StopIteration`` to stop early with the estimate so far.

    Examples
    --------
    >>> from napari_edgecme import estimate_motion, make_case, edge_scene
    >>> case = make_case(edge_scene((160, 160), rng=0), "inplane", extent=7, rng=0)
    >>> est = estimate_motion(case.blurred, "xu", "inplane", max_blur=11)
    >>> est.motion.model
    'inplane'
    """
    return drive(iter_estimate_motion(image, method, model, max_blur, focal_px, profiles,
                                      **params), callback)
