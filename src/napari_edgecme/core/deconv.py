r"""Non-blind deconvolution with a spatially varying camera motion (paper section 6).

Given a blurred photo ``g`` and its camera motion (an MDF over poses, paper Eq. 8),
recover the sharp image ``f`` from ``g = T f + n``, where ``T`` is the spatially
varying blur as the efficient filter flow (EFF) of
:class:`~napari_edgecme.core.operators.EfficientFilterFlow`: overlapping windowed
tiles, one PSF per tile (Eq. 9), overlap-add. Three methods:

``"hyperlaplacian"`` (default)
    Krishnan & Fergus [1]_ (KF):

    .. math::  \min_f \|M T f - g\|^2 + \lambda_f \sum_i |(D_x f)_i|^\alpha
               + |(D_y f)_i|^\alpha ,\qquad \alpha \in \{1/2, 2/3\}

    -- the form of the latent-image update of the estimation (Eq. 21, an L0 prior
    there), with ``lambda_f`` in the same role: the weight of the gradient prior
    against the data. KF write it with a data weight, ``lambda/2 ||M T f - g||^2 +
    prior``: the same minimiser for ``lambda = 2 / lambda_f``, the ``lam`` below and the
    deprecated keyword of that name.

    by half-quadratic splitting: the auxiliary gradients ``w`` get an exact
    per-pixel shrinkage (the roots of a cubic for 1/2, of a quartic for 2/3;
    :mod:`~napari_edgecme.core.deconv_prior`: KF's w sub-problem), then the image by
    the quadratic step ``(lam T^T M^T M T + beta D^T D) f = lam T^T M^T g + beta D^T w``
    (KF's x sub-problem, with the SV operator), for ``beta`` = 1, 2 sqrt 2, 8, ... <= 256 (the
    reference schedule: 6 steps), one inner iteration each. Two image-step solvers:

    * ``solver="fourier"`` (default): per EFF tile, the closed-form Fourier solution
      with that tile's PSF in a box one PSF size larger than the tile's window, the
      boxes blended by the EFF windows
      (:class:`~napari_edgecme.core.deconv_solvers.PatchFourier`);
    * ``solver="cg"``: conjugate gradients on the normal equations over the EFF
      operator itself -- exact for the EFF model -- warm-started, preconditioned by
      the circulant inverse with the tiles' mean power spectrum, 10 iterations per
      step by default.

    Which is the default, and why (``benchmarks/bench_deconv.py``, 20 synthetic
    256 px cases, 13-31 px shake): the Fourier variant is 0.2 dB below CG run to
    convergence on average (median -0.15 dB; from -2.2 dB to +1.5 dB per case -- it
    loses most where a 31 px blur turns fast across a small image, the PSF changing
    within one box), while costing the same CPU time as 10 CG iterations on 256 px
    images, a third of it at 800 px, and it is the only one that restores a 12 MP RGB
    photo within the three-minute budget. Choose ``solver="cg"`` for small images
    with strongly varying blur.

``"rl"``
    Richardson-Lucy with the same masked SV operator,
    ``f <- f . T^T M^T (g / M T f) / T^T M^T 1`` -- non-negative; the number of
    ``iterations`` is the regulariser (noise grows with it; 30 is best on average at
    1 % noise).

``"wiener"``
    One patch-wise Fourier solve per tile with an image spectrum ``~ |omega|^-2``:
    ``conj(k) y / (|k|^2 + nsr |d|^2)``. A fraction of a second; for a quick look.

Tiles
-----
The EFF tile size adapts to the motion (``stride=None``): the largest size (32 to
256 px) over which any pose's displacement drifts by at most half a pixel between a
tile's centre and half a tile away. A constant or slowly turning blur gets large,
cheap tiles; a fast-turning one small, accurate tiles.

Boundaries
----------
No periodic or mirrored scene is assumed beyond the frame. The unknown image lives
on a *latent domain* larger than the photo by the PSF half-width on every side, and
only observed pixels enter the data term (the mask ``M``, as in Reeves [3]_ and
Almeida & Figueiredo [4]_): pixels just outside the frame are unknowns that explain
the blur leaking in, and are constrained by that data and by the prior. CG and RL
use the EFF operator built on the padded domain (its ``origin`` argument); the
patch-wise Fourier solver solves its border tiles' masked problems by conjugate
gradients in the Fourier domain. On the spec's synthetic cases the outer 5 % band
is above the interior's PSNR; on crops whose frame cuts through the scene it is on
average 1.4 dB below it, against 4.5 dB with the reference's replicate padding.

Large images
------------
The image is processed in blocks of ``block_size`` pixels that overlap and
cross-fade (windows summing to one); each block is solved on its own latent domain
with a margin of real data of twice the PSF size plus 8 px around the part that is
kept, so a cut between blocks is handled like the image border and lies far from the
kept pixels (block and whole-image results agree to ~40 dB, with no seam). Memory is
bounded by one block besides the input and the result, which is written in place in
its final (H, W, C) layout and clipped there (no full-size copy at the end;
``benchmarks/results/large-24mp.md`` for 12 and 24 MP).

A block's working memory grows with its latent domain times what each pixel costs:
the tiles' spectra, ``(F / stride)^2`` per pixel for the EFF's FFT size ``F`` and
``(B / stride)^2`` for the Fourier boxes ``B`` (a tile's window plus a PSF side each
way), so it rises steeply with the PSF side ``K`` when the tiles are small. It is
modelled from what the operator and solvers allocate
(:func:`~napari_edgecme.core.deconv_blocks.block_memory`; 1-15 % above the
allocations measured for the default solver, ``benchmarks/results/deconv-memory.md``),
and by default (``block_size=None``) the block size is the largest up to 2048 whose
every block fits
:data:`~napari_edgecme.core.deconv_blocks.BLOCK_MEMORY_BUDGET`, 2 GiB
(:func:`~napari_edgecme.core.deconv_blocks.auto_block_size`); it is never chosen
below the block's margin ``2 K + 8``, where the margins would be most of the work and
a smaller block would save little memory: a PSF of about 200 px on small, fast-turning
tiles (56 px at 24 MP) then exceeds the budget. An ``int`` is used as given. A progress
record comes before each block's blur operator is built, after each chunk of tiles
(tile spectra, the observation's spectra, each image step), after each slab of about
a million pixels of the w-step, and after each half-quadratic step -- a few tenths
of a second of work apart at most, whatever the image size -- and a stop at any of
them returns at once. The hyper-Laplacian solves an RGB image in an opponent basis by
default (``color="opponent"``): the luminance, then two chroma axes
(:func:`opponent_data_weights`), the chroma at half resolution on large photos
(:data:`HALF_CHROMA_PIXELS`); with ``color="rgb"``, and for RL and Wiener, RGB images
are deconvolved channel by channel with one motion (the operator and tile spectra are
built once per block).

References
----------
.. [1] D. Krishnan and R. Fergus, "Fast image deconvolution using hyper-Laplacian
   priors", NIPS 2009.
.. [2] M. Hirsch, S. Sra, B. Schölkopf and S. Harmeling, "Efficient filter flow for
   space-variant multiframe blind deconvolution", CVPR 2010.
.. [3] S. J. Reeves, "Fast image restoration without boundary artifacts", IEEE TIP
   14(10), 2005.
.. [4] M. S. C. Almeida and M. A. T. Figueiredo, "Deconvolving images with unknown
   boundaries using the alternating direction method of multipliers", IEEE TIP
   22(8), 2013.
"""

from __future__ import annotations

import inspect
import math
import warnings
from collections.abc import Callable, Generator

import numpy as np

from ._validation import as_float_image, check_bool, check_choice, check_positive
from .deconv_blocks import (
    MIN_BLOCK,
    BlockPlan,
    auto_block_size,
    auto_stride,
    fourier_margin,
    latent_pad,
    psf_extent,
)
from .deconv_prior import check_alpha
from .deconv_solvers import (
    LatentDomain,
    PatchFourier,
    hyperlaplacian_steps,
    richardson_lucy_steps,
    wiener,
)
from .motion import CameraMotion
from .photometry import mix_channels
from .progress import Progress, StopRequested, drive, relay, stop

__all__ = ["CHROMAS", "COLORS", "DEFAULTS", "HALF_CHROMA_PIXELS", "METHODS", "METHOD_PARAMETERS",
           "MOTION_NOISE", "NOISE_CROP", "OPPONENT", "REFERENCE_LAMBDA_F", "REFERENCE_NOISE",
           "SOLVERS", "check_deconvolution_parameters", "color_description", "deconvolve",
           "double_size", "from_opponent", "half_size", "iter_deconvolve", "lambda_f_for_noise",
           "noise_lambda_f", "to_opponent"]

#: Deconvolution methods, by name.
METHODS = ("hyperlaplacian", "rl", "wiener")

#: Image-step solvers of the hyper-Laplacian method.
SOLVERS = ("fourier", "cg")

#: Colour bases of the hyper-Laplacian method for RGB images, and chroma resolutions.
COLORS = ("opponent", "rgb")
CHROMAS = ("auto", "full", "half")

#: The keywords of :func:`deconvolve` each method uses; ``"common"``: all methods.
METHOD_PARAMETERS = {
    "hyperlaplacian": ("lambda_f", "alpha", "beta_start", "beta_rate", "beta_max",
                       "inner_iterations", "solver", "cg_iterations", "cg_tol",
                       "border_iterations", "color", "chroma"),
    "rl": ("iterations",),
    "wiener": ("nsr",),
    "common": ("block_size", "stride", "preview"),
}

#: Deprecated keywords: old name -> the parameter it stands for, and its method.
DEPRECATED_ALIASES = {"lam": ("lambda_f", "hyperlaplacian")}


class _NotGiven:
    """The default of a deprecated keyword: not passed (``None`` is a value, refused)."""

    def __repr__(self) -> str:
        return "<not given>"


NOT_GIVEN = _NotGiven()

#: Patch-wise Fourier solver: conjugate-gradient iterations on the border tiles' masked
#: problems per image step (its box margin: ``deconv_blocks.FOURIER_MARGIN``); the
#: hyper-Laplacian's is the default of its ``border_iterations``.
FOURIER_BORDER_ITERATIONS = {"hyperlaplacian": 8, "wiener": 12}


def deconvolve(image, motion: CameraMotion, method: str = "hyperlaplacian", *,
               lambda_f: float | None = None, alpha: float = 2.0 / 3.0,
               beta_start: float = 1.0, beta_rate: float = 2.0 * math.sqrt(2.0),
               beta_max: float = 256.0, inner_iterations: int = 1, solver: str = "fourier",
               cg_iterations: int = 10, cg_tol: float = 1e-4,
               border_iterations: int = FOURIER_BORDER_ITERATIONS["hyperlaplacian"],
               color: str = "opponent", chroma: str = "auto", iterations: int = 30,
               nsr: float = 1e-2, block_size: int | None = None,
               stride: int | None = None, preview: bool = False, lam: float = NOT_GIVEN,
               callback: Callable[[Progress], object] | None = None) -> np.ndarray:
    """Restore a blurred photo with a known (spatially varying) camera motion.

    Each method reads only its own parameters (:data:`METHOD_PARAMETERS`); a value
    other than the default for another method's parameter is refused.

    Parameters
    ----------
    image : array_like of shape (H, W) or (H, W, 3)
        The blurred photo, gray or RGB, any numeric dtype (integers are scaled by
        their dtype's maximum; floats are taken as [0, 1]). Never modified.
    motion : CameraMotion
        The camera motion; applied at the image's own size
        (:meth:`CameraMotion.rescale`), so a motion estimated on a downscaled copy
        works. A motion for another aspect ratio is refused.
    method : {"hyperlaplacian", "rl", "wiener"}
        See the module notes.
    lambda_f : float, optional
        hyperlaplacian: weight of the gradient prior against ``||M T f - g||^2``
        (module notes), for images in [0, 1] -- the role ``lambda_f`` has in the
        estimation's latent update (Eq. 21). ``2 / lambda_f`` is KF's data weight
        ``lambda``. By default it is set from the photo's noise
        (:func:`noise_lambda_f`): 2/1500 (about 1.33e-3) at the 2/255 of the ``lai``
        photos, down to 0.44x that on a clean capture, up with the noise's variance on
        noisier photos. Give a value to fix it: lower for a sharper, noisier result.
    alpha : float, default 2/3
        hyperlaplacian: prior exponent, 1/2 or 2/3 (exact w-steps). 2/3 is 0.2 dB
        better on average at 1 % noise; 1/2 favours piecewise-flat scenes.
    beta_start, beta_rate, beta_max : float, default 1, 2 sqrt 2, 256
        hyperlaplacian: the continuation schedule of the splitting weight (the
        reference's; 6 steps).
    inner_iterations : int, default 1
        hyperlaplacian: w-step/image-step alternations per ``beta``.
    solver : {"fourier", "cg"}, default "fourier"
        hyperlaplacian: image-step solver (module notes).
    cg_iterations : int, default 10
        hyperlaplacian with ``solver="cg"``: CG iterations per image step.
    cg_tol : float, default 1e-4
        hyperlaplacian with ``solver="cg"``: relative residual that ends an image step.
    border_iterations : int, default 8
        hyperlaplacian with ``solver="fourier"``: conjugate-gradient iterations per image
        step on the masked problems of the tiles at the image's border (warm-started
        from the previous step). Most of a small image's time goes there: at 800x800
        with a 41 px PSF, 16 of the 25 tiles are border tiles; with its true motion, 4
        iterations ran 1.4x faster than 8 and lost 1.5 dB over the whole frame, 0.25 dB
        50 px inside it (``benchmarks/results/polish.md``).
    color : {"opponent", "rgb"}, default "opponent"
        hyperlaplacian, RGB images: ``"opponent"`` solves the luminance (the mean of R,
        G and B, as a gray photo) and two chroma axes of an orthonormal basis
        (:data:`OPPONENT`, :func:`opponent_data_weights`); ``"rgb"`` solves R, G, B one
        by one. With Xu+Ep's estimates the two are within 0.1 dB on ``lai``; with half
        resolution chroma (below) a 12 MP photo takes half the time, 0.15 dB better
        (``benchmarks/results/color.md``).
    chroma : {"auto", "full", "half"}, default "auto"
        hyperlaplacian with ``color="opponent"``: solve the chroma at half resolution
        (about half the time) -- ``"auto"`` from :data:`HALF_CHROMA_PIXELS` up.
    iterations : int, default 30
        rl: Richardson-Lucy iterations.
    nsr : float, default 0.01
        wiener: noise-to-signal ratio relative to a ``|omega|^-2`` image spectrum
        (best on average at 1 % noise).
    block_size : int or None, default None
        all methods: side of the blocks a large image is cut into (>= 64), each solved
        with a margin of ``2 K + 8`` px of real data around it (``K`` the PSF side).
        None chooses it from the memory budget
        (:func:`~napari_edgecme.core.deconv_blocks.auto_block_size`): the largest size
        up to 2048 whose blocks each need at most
        :data:`~napari_edgecme.core.deconv_blocks.BLOCK_MEMORY_BUDGET` (2 GiB) of
        working memory by the memory model, but not below the margin (module notes,
        *Large images*). 2048 was the fixed default, and is still the choice unless
        the blur is large (at 24 MP RGB: a 151 px PSF on 78 px tiles gets 1472 px
        blocks, an 85 px one 2048).
    stride : int or None, default None
        all methods: EFF tile size in pixels (>= 8); None adapts it to how fast the
        PSF changes across the image (module notes).
    preview : bool, default False
        all methods: attach the current whole-image estimate to each iteration's
        progress record (costs a copy of the image per record).
    lam : float, optional
        Deprecated (DeprecationWarning): hyperlaplacian's data weight, KF's
        ``lambda``; pass ``lambda_f = 2 / lam`` instead.
    callback : callable, optional
        Called with every :class:`~napari_edgecme.core.progress.Progress` record;
        raising ``StopIteration`` in it stops the work and returns the image as
        restored so far (blocks not reached are returned unrestored).

    Returns
    -------
    ndarray of shape (H, W) or (H, W, 3)
        The restored image clipped to [0, 1]; float32 (float64 when the input is
        float64: the engine's float policy).

    Raises
    ------
    ValueError
        On a bad image (shape, NaN/inf), an unknown method, a parameter out of range
        or of another method, or a motion of another aspect ratio; the message names
        it.

    Examples
    --------
    >>> from napari_edgecme.core.synth import make_case, sample_image
    >>> from napari_edgecme.core.metrics import aligned_psnr
    >>> case = make_case(sample_image("camera", 96), "inplane", extent=9, rng=0)
    >>> restored = deconvolve(case.blurred, case.motion)
    >>> restored.shape, restored.dtype
    ((96, 96), dtype('float32'))
    >>> bool(aligned_psnr(restored, case.sharp) > aligned_psnr(case.blurred, case.sharp) + 2)
    True
    """
    return drive(iter_deconvolve(
        image, motion, method, lambda_f=lambda_f, alpha=alpha, beta_start=beta_start,
        beta_rate=beta_rate, beta_max=beta_max, inner_iterations=inner_iterations,
        solver=solver, cg_iterations=cg_iterations, cg_tol=cg_tol,
        border_iterations=border_iterations, color=color, chroma=chroma, iterations=iterations,
        nsr=nsr, block_size=block_size, stride=stride, preview=preview, lam=lam), callback)


def iter_deconvolve(image, motion: CameraMotion, method: str = "hyperlaplacian", *,
                    lambda_f: float | None = None, alpha: float = 2.0 / 3.0,
                    beta_start: float = 1.0, beta_rate: float = 2.0 * math.sqrt(2.0),
                    beta_max: float = 256.0, inner_iterations: int = 1,
                    solver: str = "fourier", cg_iterations: int = 10, cg_tol: float = 1e-4,
                    border_iterations: int = FOURIER_BORDER_ITERATIONS["hyperlaplacian"],
                    color: str = "opponent", chroma: str = "auto", iterations: int = 30,
                    nsr: float = 1e-2, block_size: int | None = None,
                    stride: int | None = None, preview: bool = False,
                    lam: float = NOT_GIVEN) -> Generator[Progress, None, np.ndarray]:
    """:func:`deconvolve` as a generator: yields progress records, returns the image.

    Inputs are validated when the generator starts (at the first ``next``), before
    any record. ``close()`` stops the work at the next record; records come every few
    tenths of a second of work (module notes, *Large images*). Throwing
    :class:`~napari_edgecme.core.progress.StopRequested` in makes the generator yield
    one last record saying it stopped and return the image restored so far: finished
    blocks, the running block's current iterate, and the unrestored input elsewhere.

    Parameters
    ----------
    image, motion, method, lambda_f, alpha, beta_start, beta_rate, beta_max, \
inner_iterations, solver, cg_iterations, cg_tol, border_iterations, color, chroma, \
iterations, nsr, block_size, stride, preview, lam
        As for :func:`deconvolve` (the same keywords and defaults).

    Yields
    ------
    Progress
        ``stage="deconvolve"``; ``step`` counts finished iterations (half-quadratic
        steps, RL iterations, Wiener solves) over all blocks and channels, ``total`` of
        them, and never decreases; records inside an iteration (operator set-up, chunks
        of tiles, slabs of the w-step, CG iterations) repeat the step. ``preview``
        holds the current whole-image estimate on iteration records when
        ``preview=True``.

    Returns
    -------
    ndarray of shape (H, W) or (H, W, 3)
        The restored image, as for :func:`deconvolve` (``StopIteration.value``).
    """
    arguments = dict(locals())
    given = {name: arguments[name] for name in _PARAMETER_NAMES
             if not _is_default(arguments[name], _SIGNATURE_DEFAULTS[name])}
    img = as_float_image(image, "image", allow_rgb=True)
    method = check_choice(method, "method", METHODS)
    opts = check_deconvolution_parameters(method, given)
    if method == "hyperlaplacian" and opts["lambda_f"] is None:
        opts["lambda_f"] = noise_lambda_f(img)
        opts["lam"] = 2.0 / opts["lambda_f"]
    motion = _fit_motion(motion, img.shape)
    if img.ndim == 3 and method == "hyperlaplacian" and opts["color"] == "opponent":
        return (yield from _run_opponent(img, motion, method, opts))
    return (yield from _run(img, motion, method, opts))


def _is_default(value, default) -> bool:
    """Whether a keyword was left at (or given as) its default."""
    if value is default:
        return True
    try:
        return type(value) is type(default) and bool(value == default)
    except (TypeError, ValueError):
        return False


#: Every parameter keyword of :func:`deconvolve` / :func:`iter_deconvolve`, and defaults.
_PARAMETER_NAMES = (*(n for names in METHOD_PARAMETERS.values() for n in names),
                    *DEPRECATED_ALIASES)
_SIGNATURE_DEFAULTS = {name: inspect.signature(iter_deconvolve).parameters[name].default
                       for name in _PARAMETER_NAMES}

#: Default parameters per method and the ones all methods take (``"common"``): the
#: defaults of :func:`deconvolve`'s signature, for display. The deprecated ``lam``
#: appears with its equivalent default (``2 / lambda_f``) for callers written against
#: the old name.
DEFAULTS = {method: {name: _SIGNATURE_DEFAULTS[name] for name in names}
            for method, names in METHOD_PARAMETERS.items()}
DEFAULTS["hyperlaplacian"]["lam"] = None  # as lambda_f: from the photo's noise


#: The hyper-Laplacian's prior weight at :data:`REFERENCE_NOISE`: 2/1500, the weight
#: best on average over the synthetic sets at 1 % noise (``benchmarks/bench_deconv.py``;
#: 2/1000 .. 2/2000 within 0.3 dB) and for the estimated motions of the ``lai`` photos.
REFERENCE_LAMBDA_F = 2.0 / 1500.0
#: The noise of the ``lai`` photos (:func:`~.photometry.estimate_noise`: 1.6-2.4 /255,
#: median 2/255), where :data:`REFERENCE_LAMBDA_F` is the best weight.
REFERENCE_NOISE = 2.0 / 255.0
#: The error of an estimated motion, as white noise it adds to the photo's (on a
#: [0, 1] scale): what keeps the best weight from falling with the photo's noise
#: towards zero. A MAP weight grows with the noise variance; with an estimated motion
#: the residual also holds the motion's error, so the weight goes as
#: ``noise**2 + MOTION_NOISE**2``. Measured on the Xu+Ep estimates of the two
#: real-photo sets (``benchmarks/results/noise-weight.md``): on ``levin``'s captures
#: (noise 0.2-0.3 /255) the best weight was 0.4-0.5x the reference (+0.33 dB), on
#: ``lai`` (2/255) the reference itself (0.7-1.5x within 0.1 dB); 1.77/255 puts 0.44x at
#: zero noise and 1x at the reference.
MOTION_NOISE = 1.77 / 255.0
#: Largest side of the central crop :func:`noise_lambda_f` measures the noise on.
NOISE_CROP = 1024


def noise_lambda_f(image) -> float:
    """The hyper-Laplacian's prior weight for a photo: its default ``lambda_f``.

    ``REFERENCE_LAMBDA_F * (s**2 + MOTION_NOISE**2) / (REFERENCE_NOISE**2 +
    MOTION_NOISE**2)``, where ``s`` is the photo's noise
    (:func:`~.photometry.estimate_noise` on its luminance, on a central crop of at most
    :data:`NOISE_CROP` px a side).

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        The blurred photo, floating point on a [0, 1] scale (as deconvolved).

    Returns
    -------
    float
        From 0.44x :data:`REFERENCE_LAMBDA_F` for a noiseless photo, 1x at
        :data:`REFERENCE_NOISE`, 2.7x at twice that.
    """
    from .photometry import estimate_noise

    arr = np.asarray(image)
    if arr.ndim not in (2, 3):  # the engine's one message for a bad shape
        as_float_image(arr, "image", allow_rgb=True)
    rows, cols = arr.shape[:2]
    r0, c0 = max(0, (rows - NOISE_CROP) // 2), max(0, (cols - NOISE_CROP) // 2)
    # estimate_noise validates the crop (dtype, NaN, range) as every input is
    return lambda_f_for_noise(estimate_noise(arr[r0:r0 + NOISE_CROP, c0:c0 + NOISE_CROP]))


def lambda_f_for_noise(noise: float) -> float:
    """The prior weight :func:`noise_lambda_f` gives a photo of this noise (on [0, 1]).

    ``REFERENCE_LAMBDA_F * (noise**2 + MOTION_NOISE**2) / (REFERENCE_NOISE**2 +
    MOTION_NOISE**2)``.
    """
    noise = check_positive(noise, "noise", allow_zero=True)
    return REFERENCE_LAMBDA_F * ((noise ** 2 + MOTION_NOISE ** 2)
                                 / (REFERENCE_NOISE ** 2 + MOTION_NOISE ** 2))


# --------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------

def check_deconvolution_parameters(method: str, params: dict) -> dict:
    """Validate the parameters of a deconvolution method; the one check of them.

    :func:`deconvolve` runs it on the keywords given other than their defaults;
    :func:`~napari_edgecme.core.deblur.deblur` on its ``deconv_params`` before it
    spends minutes estimating.

    Parameters
    ----------
    method : {"hyperlaplacian", "rl", "wiener"}
        An already checked method name.
    params : dict
        Parameter name -> value, any subset of ``method``'s parameters, those common
        to all methods (:data:`METHOD_PARAMETERS`) and deprecated aliases (which warn
        with a DeprecationWarning).

    Returns
    -------
    dict
        Every parameter of ``method`` and the common ones, defaults filled in, values
        checked and normalised, aliases resolved; plus ``"lam"`` (hyperlaplacian: the
        data weight ``2 / lambda_f`` the solvers use). A ``lambda_f`` left at None (its
        default: from the photo) stays None, and so does ``"lam"``: the photo decides
        them (:func:`noise_lambda_f`).

    Raises
    ------
    ValueError
        On an unknown name, a parameter of another method, both a parameter and its
        alias, or a value out of range; one line naming the parameter.
    """
    allowed = {**DEFAULTS[method], **DEFAULTS["common"]}
    allowed.pop("lam", None)
    own = set(allowed) | {a for a, (_, m) in DEPRECATED_ALIASES.items() if m == method}
    for name in params:
        if name not in own:
            listed = ", ".join(sorted(allowed))
            if name in _PARAMETER_NAMES:
                raise ValueError(f"parameter {name!r} does not apply to method {method!r}; "
                                 f"its parameters: {listed}")
            raise ValueError(f"unknown parameter {name!r} for method {method!r}; "
                             f"accepted: {listed}")
    opts = {**allowed, **{n: v for n, v in params.items() if n not in DEPRECATED_ALIASES}}
    if method == "hyperlaplacian":
        if "lam" in params:
            warnings.warn("deconvolution parameter 'lam' is deprecated: pass lambda_f = "
                          "2 / lam (the weight of the gradient prior, as in the estimation)",
                          DeprecationWarning, stacklevel=3)
            if "lambda_f" in params:
                raise ValueError("lam is the deprecated form of lambda_f: pass one of them")
            opts["lam"] = check_positive(params["lam"], "lam")
            opts["lambda_f"] = 2.0 / opts["lam"]
        elif opts["lambda_f"] is None:  # from the photo (noise_lambda_f), when it is known
            opts["lam"] = None
        else:
            opts["lambda_f"] = check_positive(opts["lambda_f"], "lambda_f")
            opts["lam"] = 2.0 / opts["lambda_f"]
        opts["alpha"] = check_alpha(opts["alpha"])
        opts["beta_start"] = check_positive(opts["beta_start"], "beta_start")
        opts["beta_rate"] = check_positive(opts["beta_rate"], "beta_rate")
        if opts["beta_rate"] <= 1:
            raise ValueError(f"beta_rate must be > 1; got {opts['beta_rate']!r}")
        opts["beta_max"] = check_positive(opts["beta_max"], "beta_max")
        if opts["beta_max"] < opts["beta_start"]:
            raise ValueError(f"beta_max must be >= beta_start ({opts['beta_start']:g}); "
                             f"got {opts['beta_max']!r}")
        opts["inner_iterations"] = check_positive(opts["inner_iterations"], "inner_iterations",
                                                  integer=True)
        opts["solver"] = check_choice(opts["solver"], "solver", SOLVERS)
        opts["cg_iterations"] = check_positive(opts["cg_iterations"], "cg_iterations",
                                               integer=True)
        opts["cg_tol"] = check_positive(opts["cg_tol"], "cg_tol", maximum=1.0)
        opts["border_iterations"] = check_positive(opts["border_iterations"],
                                                   "border_iterations", integer=True)
        opts["color"] = check_choice(opts["color"], "color", COLORS)
        opts["chroma"] = check_choice(opts["chroma"], "chroma", CHROMAS)
        if opts["color"] == "rgb" and opts["chroma"] == "half":
            raise ValueError("chroma='half' needs color='opponent' (RGB channels have no "
                             "chroma to subsample)")
    elif method == "rl":
        opts["iterations"] = check_positive(opts["iterations"], "iterations", integer=True)
    else:
        opts["nsr"] = check_positive(opts["nsr"], "nsr")
    if opts["block_size"] is not None:
        opts["block_size"] = check_positive(opts["block_size"], "block_size", integer=True)
        if opts["block_size"] < MIN_BLOCK:
            raise ValueError(f"block_size must be >= {MIN_BLOCK}; got {opts['block_size']!r}")
    if opts["stride"] is not None:
        opts["stride"] = check_positive(opts["stride"], "stride", integer=True)
        if opts["stride"] < 8:
            raise ValueError(f"stride must be >= 8; got {opts['stride']!r}")
    opts["preview"] = check_bool(opts["preview"], "preview")
    return opts


def _fit_motion(motion, shape) -> CameraMotion:
    if not isinstance(motion, CameraMotion):
        raise ValueError(f"motion must be a CameraMotion; got {type(motion).__name__}")
    try:
        return motion.rescale(shape[:2])
    except ValueError as err:
        raise ValueError(f"motion does not fit the image: {err}") from None


def _betas(opts) -> list[float]:
    """The continuation schedule: beta_start * beta_rate^k while <= beta_max (KF: 6 steps)."""
    betas, beta = [], opts["beta_start"]
    while beta <= opts["beta_max"] * (1 + 1e-9):
        betas.append(beta)
        beta *= opts["beta_rate"]
    return betas


def _block_solver(method: str, opts: dict):
    """``(iterations per block and channel, start(domain, fourier, g, lam) -> solver
    generator)``; ``lam`` is the hyper-Laplacian's data weight for that channel."""
    if method == "hyperlaplacian":
        betas = _betas(opts)

        def start(domain, fourier, g, lam):
            return hyperlaplacian_steps(
                domain, g, lam=lam, alpha=opts["alpha"], betas=betas,
                inner_iterations=opts["inner_iterations"], solver=opts["solver"],
                fourier=fourier, cg_iterations=opts["cg_iterations"], cg_tol=opts["cg_tol"],
                border_iterations=opts["border_iterations"])
        return len(betas) * opts["inner_iterations"], start
    if method == "rl":
        def start(domain, fourier, g, lam):
            return richardson_lucy_steps(domain, g, iterations=opts["iterations"])
        return opts["iterations"], start

    def start(domain, fourier, g, lam):
        return wiener(domain, g, nsr=opts["nsr"], fourier=fourier,
                      border_iterations=FOURIER_BORDER_ITERATIONS["wiener"])
    return 1, start


def _run(img: np.ndarray, motion: CameraMotion, method: str, opts: dict, lams=None,
         channel_names=None):
    """The block loop behind :func:`iter_deconvolve` (inputs already validated).

    ``lams``: the hyper-Laplacian's data weight per channel (default ``opts["lam"]``
    for all); ``channel_names``: how records name the channels (default numbers).

    Each block and channel is one solver generator of
    :mod:`~napari_edgecme.core.deconv_solvers`; its records become ``"deconvolve"``
    records with the step counted over the whole image, and a stop request is passed
    on to it (:func:`~napari_edgecme.core.progress.stop`) for its current iterate.
    """
    dtype = img.dtype
    H, W = img.shape[:2]
    channels = [img] if img.ndim == 2 else [img[..., c] for c in range(img.shape[2])]
    nc = len(channels)
    if lams is None:
        lams = [opts.get("lam")] * nc
    K = psf_extent(motion)
    pad = latent_pad(K)  # latent pixels beyond the observed box: the PSF reach + slack
    use_fourier = method == "wiener" or (method == "hyperlaplacian"
                                         and opts["solver"] == "fourier")
    stride, plan, chosen = _block_plan((H, W), motion, method, opts, dtype)
    nb = len(plan)
    per, start = _block_solver(method, opts)
    total = nb * nc * per
    # the result in its returned layout, (H, W, C) or (H, W): no copy at the end
    out = np.zeros((H, W, nc) if img.ndim == 3 else (H, W), dtype)
    planes = [out] if img.ndim == 2 else [out[..., c] for c in range(nc)]
    step = 0
    current = (0, -1)  # (block, channel) being solved; earlier pairs are in ``out``
    solver = None  # the running block's solver generator, None between solvers
    inner = None

    def assemble(iterate: np.ndarray | None, in_place: bool = False) -> np.ndarray:
        """Finished blocks, the running block's ``iterate`` (on its domain), and the input
        where nothing ran (in ``out`` itself with ``in_place``: the run is over).

        The block windows sum to one, so the input's share is either added for the
        blocks not reached, or the whole input added and the share of the blocks
        reached taken off again -- whichever touches fewer pixels.
        """
        res = out if in_place else out.copy()
        res_planes = [res] if img.ndim == 2 else [res[..., c] for c in range(nc)]
        pending = [(b, c) for b in range(nb) for c in range(nc) if (b, c) >= current
                   and not ((b, c) == current and iterate is not None)]
        reached = [(b, c) for b in range(nb) for c in range(nc) if (b, c) < current
                   or ((b, c) == current and iterate is not None)]
        input_pairs, subtract = pending, False
        if len(reached) < len(pending):
            res += img  # every block's share of the input, minus the reached ones below
            input_pairs, subtract = reached, True
        by_block = {}
        for b, c in input_pairs:
            by_block.setdefault(b, []).append(c)
        for b, chans in by_block.items():
            blk = plan.blocks[b]
            r0, r1, c0, c1 = blk["box"]
            if len(chans) == nc and img.ndim == 3:  # every channel at once
                plan.add(res, blk, img[r0:r1, c0:c1], subtract=subtract)
            else:
                for c in chans:
                    plan.add(res_planes[c], blk, channels[c][r0:r1, c0:c1],
                             subtract=subtract)
        if iterate is not None and current[1] >= 0:
            plan.add(res_planes[current[1]], plan.blocks[current[0]], iterate[inner])
        return _clipped(res)

    try:
        for b, blk in enumerate(plan.blocks):
            where_b = f"block {b + 1}/{nb}, " if nb > 1 else ""
            said = chosen if b == 0 and nb > 1 else ""
            yield Progress("deconvolve", step, total,
                           f"{where_b}building the blur operator{said}")
            domain = LatentDomain(motion, blk["box"], pad, stride, dtype)
            inner = domain.inner
            yield Progress("deconvolve", step, total, f"{where_b}blur operator ready")
            fourier = None
            if use_fourier:
                fourier = PatchFourier(domain, margin=fourier_margin(K), build=False)
                yield from relay(fourier.iter_build(), lambda r, at=step, where=where_b: Progress(
                    "deconvolve", at, total, where + r.message))
                yield Progress("deconvolve", step, total, f"{where_b}tile spectra ready")
            r0, r1, c0, c1 = blk["box"]
            for c in range(nc):
                current = (b, c)
                named = (f"channel {c + 1}/{nc}, " if channel_names is None
                         else f"{channel_names[c]}, ")
                where = where_b + (named if nc > 1 or channel_names else "")
                solver = start(domain, fourier, np.ascontiguousarray(channels[c][r0:r1, c0:c1]),
                               lams[c])
                k = 0  # the solver's finished iterations
                while True:
                    try:
                        record = next(solver)
                    except StopIteration as done:
                        x = done.value
                        break
                    preview = None
                    if record.step > k:
                        step += record.step - k
                        k = record.step
                        if opts["preview"]:
                            preview = assemble(record.iterate)
                    yield Progress("deconvolve", step, total, where + record.message,
                                   iteration=k, preview=preview)
                solver = None
                plan.add(planes[c], blk, x[domain.inner])
            current = (b + 1, -1)
    except StopRequested:
        result = assemble(stop(solver) if solver is not None else None, in_place=True)
        try:
            yield Progress("deconvolve", step, total,
                           f"stopped by request after {step}/{total} iterations; returning "
                           "the image restored so far (unrestored where not reached)")
        except StopRequested:
            pass
        return result
    finally:
        if solver is not None:
            solver.close()
    return _clipped(out)


# --------------------------------------------------------------------------------------
# colour: an opponent basis, chroma optionally at half resolution
# --------------------------------------------------------------------------------------

#: Orthonormal opponent basis of (R, G, B), rows: luminance ``(R + G + B) / sqrt 3`` and
#: two chroma axes ``(R - B) / sqrt 2``, ``(R - 2 G + B) / sqrt 6``. Orthonormal, so the
#: data term of the three channels together is the RGB one, and i.i.d. noise stays
#: i.i.d. with the same sigma.
OPPONENT = np.array([[1, 1, 1], [1, 0, -1], [1, -2, 1]], float)
OPPONENT /= np.linalg.norm(OPPONENT, axis=1, keepdims=True)

#: Each opponent channel is solved scaled into [0, 1] (the solvers' and the clip's
#: range): ``scale * channel + offset``. Luminance / sqrt 3 is the mean of R, G, B;
#: both chroma axes get one scale, the largest that keeps them inside [0, 1].
OPPONENT_SCALE = np.array([1 / math.sqrt(3), math.sqrt(6) / 4, math.sqrt(6) / 4])
OPPONENT_OFFSET = np.array([0.0, 0.5, 0.5])

#: ``chroma="auto"``: chroma at half resolution from this many pixels up (6 MP, about
#: 3000 x 2000). Below it, half-resolution chroma lost 0.5 dB against full resolution on
#: 20 ``lai`` photos at 640 px (the oracle deconvolution); camera files above it carry
#: chroma at about half resolution anyway (a Bayer mosaic; JPEG's 4:2:0), and there it
#: halved the time of a 12 MP deconvolution (true motion).
HALF_CHROMA_PIXELS = 6_000_000


def to_opponent(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) RGB -> (H, W, 3) opponent channels, scaled into [0, 1] (same dtype)."""
    out = mix_channels(rgb, OPPONENT * OPPONENT_SCALE[:, None])
    out += OPPONENT_OFFSET.astype(rgb.dtype)
    return out


def from_opponent(opp: np.ndarray) -> np.ndarray:
    """The inverse of :func:`to_opponent` (not clipped)."""
    basis = OPPONENT / OPPONENT_SCALE[:, None]  # rows of OPPONENT^-T
    return mix_channels(opp - OPPONENT_OFFSET.astype(opp.dtype), basis.T)


def opponent_data_weights(lam: float, alpha: float) -> list[float]:
    """The hyper-Laplacian data weight of each scaled opponent channel.

    The luminance is solved as the mean of R, G and B, a gray image, with ``lam``: as a
    gray photo is (so a gray photo stored as RGB is restored exactly as the gray image
    is). Each chroma axis gets the RGB weight in the orthonormal basis: scaled by ``s``
    into [0, 1] it is solved with ``lam s^(alpha - 2)``, which has the same minimiser,
    scaled (the data term scales by ``s^2``, the prior by ``s^alpha``).

    Notes
    -----
    With independent noise per channel the mean carries a third of one channel's noise
    variance, and with the true motion a luminance weight that credits it --
    ``lam (3 / (1 + 2 rho)) ** (1 - alpha / 2)``, ``rho`` the channels' noise
    correlation (:func:`~.photometry.channel_noise_correlation`) -- was 0.43 dB better
    than R, G, B on the 60 ``lai`` cases (``lam``: -0.04). With an *estimated* motion
    the residual is the motion's error more than noise, and the larger weight fits it:
    on a 12 MP photo with its Xu+Ep estimate it lost 0.35-0.5 dB to R, G, B, where
    ``lam`` gained 0.16; on 20 ``lai`` cases with their estimates the two were within
    0.1 dB of R, G, B (``benchmarks/results/color.md``). A deconvolution serves
    estimates, so ``lam``.

    Returns
    -------
    list of 3 floats
        Luminance, chroma 1, chroma 2.
    """
    return [lam, *(lam * float(sc) ** (alpha - 2.0) for sc in OPPONENT_SCALE[1:])]


def half_size(a: np.ndarray) -> np.ndarray:
    """2x2 means of an (H, W[, C]) array; an odd last row or column is repeated."""
    H, W = a.shape[:2]
    if H % 2 or W % 2:
        pad = [(0, H % 2), (0, W % 2)] + [(0, 0)] * (a.ndim - 2)
        a = np.pad(a, pad, mode="edge")
    h, w = a.shape[0] // 2, a.shape[1] // 2
    return a.reshape(h, 2, w, 2, *a.shape[2:]).mean(axis=(1, 3), dtype=a.dtype)


#: Keys' cubic convolution (a = -1/2) at the two phases of a 2x upsampling: an output
#: pixel lies a quarter of an input pixel from its nearest input pixel centre.
_KEYS_QUARTER = np.array([-0.0703125, 0.8671875, 0.2265625, -0.0234375])


def double_size(a: np.ndarray, shape) -> np.ndarray:
    """The inverse of :func:`half_size`'s geometry: (h, w) -> ``shape`` (``2h - 1 <=
    shape[0] <= 2h``, the same for ``w``), by separable cubic convolution; output pixel
    centre ``2 i + 1/2`` is input pixel centre ``i``. Same dtype."""
    k = _KEYS_QUARTER.astype(a.dtype)
    for axis in (0, 1):
        n = a.shape[axis]
        pad = [(0, 0), (0, 0)]
        pad[axis] = (2, 2)
        p = np.pad(a, pad, mode="edge")
        taps = [np.take(p, np.arange(j, j + n), axis=axis) for j in range(5)]  # a[i + j - 2]
        # output 2i lies at input i - 1/4, output 2i + 1 at i + 1/4
        even = k[0] * taps[3] + k[1] * taps[2] + k[2] * taps[1] + k[3] * taps[0]
        odd = k[0] * taps[1] + k[1] * taps[2] + k[2] * taps[3] + k[3] * taps[4]
        del taps, p
        a = np.stack([even, odd], axis=axis + 1).reshape(
            (2 * n, a.shape[1]) if axis == 0 else (a.shape[0], 2 * n))
    return np.ascontiguousarray(a[:shape[0], :shape[1]])


def color_description(image_shape, method: str, params: dict) -> str | None:
    """How :func:`deconvolve` treats the colour of an image of this shape, in words.

    ``params`` as :func:`deconvolve` takes them (defaults where missing). None for a
    gray image; ``"R, G, B each"``, ``"luminance + chroma"`` or ``"luminance +
    half-resolution chroma"`` for an RGB one (the command line's summary says it).
    """
    if len(image_shape) != 3:
        return None
    opts = {**DEFAULTS.get(method, {}), **params}
    if method != "hyperlaplacian" or opts["color"] == "rgb":
        return "R, G, B each"
    half = _half_chroma(tuple(image_shape[:2]), opts["chroma"])
    return "luminance + half-resolution chroma" if half else "luminance + chroma"


def _half_chroma(shape, chroma: str) -> bool:
    if chroma == "auto":
        return shape[0] * shape[1] >= HALF_CHROMA_PIXELS
    return chroma == "half"


def _run_opponent(img: np.ndarray, motion: CameraMotion, method: str, opts: dict):
    """:func:`_run` on an RGB image in the opponent basis: luminance, then chroma (at
    half resolution when ``opts["chroma"]`` says so); the RGB result, clipped.

    Records count steps over both parts; ``preview`` images are RGB (the part not yet
    solved is the input's). A stop request returns the parts restored so far.
    """
    H, W = img.shape[:2]
    opp = to_opponent(img)
    luminance = np.ascontiguousarray(opp[..., 0])
    chroma = np.ascontiguousarray(opp[..., 1:])
    del opp
    weights = opponent_data_weights(opts["lam"], opts["alpha"])
    half = _half_chroma((H, W), opts["chroma"])
    chroma_img, chroma_motion = chroma, motion
    if half:
        chroma_img = half_size(chroma)
        chroma_motion = motion.rescale(chroma_img.shape[:2])
    parts = [  # image, motion, data weights, record names
        (luminance, motion, weights[:1], ["luminance"]),
        (chroma_img, chroma_motion, weights[1:],
         ["chroma 1/2" + (" (half resolution)" if half else ""),
          "chroma 2/2" + (" (half resolution)" if half else "")])]
    totals = [_steps(part[0], part[1], method, opts) for part in parts]
    total = sum(totals)
    current = [luminance[..., None], chroma]  # each part's estimate, full size

    def full(i, x):
        if x.ndim == 2:
            return x[..., None]
        if i == 1 and half:
            return np.stack([double_size(x[..., c], (H, W)) for c in range(x.shape[2])], -1)
        return x

    def rgb():
        return _clipped(from_opponent(np.concatenate(current, axis=-1)))

    done = last = 0
    stopped = False
    for i, (part, part_motion, lams, names) in enumerate(parts):
        inner = _run(part, part_motion, method, opts, lams=lams, channel_names=names)
        while True:
            try:
                record = next(inner)
            except StopIteration as result:
                current[i] = full(i, result.value)
                break
            preview = None
            if record.preview is not None:
                kept = current[i]
                current[i] = full(i, record.preview)
                preview = rgb()
                current[i] = kept
            last = done + record.step
            try:
                yield Progress("deconvolve", last, total, record.message,
                               iteration=record.iteration, preview=preview)
            except StopRequested:
                try:
                    inner.throw(StopRequested("stop requested"))  # its "stopped" record
                    next(inner)
                except StopIteration as result:
                    current[i] = full(i, result.value)
                stopped = True
                break
        inner.close()
        done += totals[i]
        if stopped:
            break
    res = rgb()
    if stopped:
        try:
            yield Progress("deconvolve", last, total,
                           "stopped by request; returning the image restored so far "
                           "(unrestored where not reached)")
        except StopRequested:
            pass
    return res


def _block_plan(shape, motion, method, opts, dtype):
    """``(stride, BlockPlan, how the block size was chosen)`` of :func:`_run`."""
    stride = opts["stride"] if opts["stride"] is not None else auto_stride(motion)
    block_size = opts["block_size"]
    chosen = ""  # how the block size was chosen, for the first record
    if block_size is None:
        block_size = auto_block_size(shape, motion, stride, method=method,
                                     solver=opts.get("solver", "fourier"), dtype=dtype)
        chosen = f" (blocks of {block_size} px, from the memory budget)"
    return stride, BlockPlan(shape, block_size, psf_extent(motion)), chosen


def _steps(img: np.ndarray, motion, method, opts) -> int:
    """The iterations :func:`_run` counts for ``img`` (its ``total``)."""
    _, plan, _ = _block_plan(img.shape[:2], motion, method, opts, img.dtype)
    channels = 1 if img.ndim == 2 else img.shape[2]
    return len(plan) * channels * _block_solver(method, opts)[0]


def _clipped(res: np.ndarray) -> np.ndarray:
    """``res`` clipped to [0, 1] in place (no full-size temporary); returns ``res``."""
    return np.clip(res, 0, 1, out=res)
