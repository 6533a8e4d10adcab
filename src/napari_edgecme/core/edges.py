"""Edge profiles: detection, validation and centroid alignment (paper sections 2 and 4.1).

An *edge profile* is the alpha matte of a blurred straight step edge, sampled along the
edge normal (paper Eq. 1): ``L(t) = c1 alpha(t) + c2 (1 - alpha(t))``. For a step edge
blurred by a local PSF ``k``, ``alpha`` is the cumulative of the projection of ``k`` on
the normal (Eq. 6) and its derivative is a Radon slice of ``k`` (Eq. 11). The centroid
of that derivative is where the sharp step edge lies, displaced by the centroid pose of
the camera motion (claims 1-2), so profiles from all over an image can be aligned at
their centroids and related to one motion density function (Eqs. 13-16).

Conventions (fixed; estimators, widgets and files rely on them):

* ``normal_angle`` ``phi`` is the direction of the image gradient across the edge, in
  image ``(x = col, y = row)`` coordinates: the unit normal is ``(cos phi, sin phi)`` in
  ``(x, y)``, i.e. ``(sin phi, cos phi)`` in ``(row, col)``. It points from the darker
  side (``c2``) to the brighter side (``c1``), so ``c1 > c2`` and ``alpha`` rises from
  0 to 1 along ``offsets``.
* ``derivatives[i, j]`` is the mass of the PSF projection ``rho = u . n`` (``u`` the
  displacement of Eq. 9) in the one-pixel bin centred at ``offsets[j]`` relative to the
  profile's centroid: exactly the quantity of Eq. 11/13, binned, with the convention of
  :func:`measurement_matrix`.

Detection follows the heuristics of Cho et al. (2011): Canny edges at a scale suited to
the blur; profiles sampled bilinearly along the normal and averaged over a few parallel
lines; kept only when both plateaus are flat against the contrast, the contrast is high
enough against the noise, the transition is monotone, narrower than the largest blur and
free of an inner plateau (a second edge), the parallel lines agree (the edge is locally
straight), the sensor's limits do not cut into the transition, the profile agrees with
its neighbours of similar orientation, and it is no wider than the blur field that all
profiles together show (soft or shaded scene edges would make the blur look larger).
Near-duplicates along an edge are suppressed so that the kept profiles are at least
``spacing`` pixels apart.
Detection runs at up to three scales (``max_blur`` and fractions of it), and each kept
profile carries its test measures and a calibrated confidence
(:attr:`EdgeProfiles.confidence`); the set reports its orientation and spatial coverage
(:meth:`EdgeProfiles.coverage`).

The pipeline reads from the module names: this module detects candidates and runs the
extraction; :mod:`.edge_tests` holds the validity tests of one profile and the sampling
geometry; :mod:`.edge_consistency` the tests between profiles; :mod:`.edge_picking` the
hand-drawn profile; :mod:`.profiles` the :class:`EdgeProfiles` container and its file
format; :mod:`.photometry` luminance, sRGB and noise; :mod:`.measurement` the
measurement matrix of Eqs. 13-16. The public names of all of them are importable from
here.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from ._validation import as_rng, check_positive
from .edge_consistency import _blur_consistency, _clipped_too_narrow, _neighbour_outliers
from .edge_picking import profile_along_line
from .edge_tests import (
    _OUTLIER,
    _SATURATED,
    _SOFT,
    REASONS,
    _count_reasons,
    _finish,
    _geometry,
    _measures,
    _quality,
    _settings,
    _summarise,
    _two_pass,
)
from .measurement import measurement_matrix
from .photometry import estimate_noise, srgb_to_linear, to_luminance
from .profiles import PROFILES_FORMAT, PROFILES_VERSION, EdgeProfiles
from .progress import Progress, drive

__all__ = [
    "PROFILES_FORMAT",
    "PROFILES_VERSION",
    "REASONS",
    "EdgeProfiles",
    "estimate_noise",
    "extract_edge_profiles",
    "iter_extract_edge_profiles",
    "measurement_matrix",
    "profile_along_line",
    "srgb_to_linear",
    "to_luminance",
]


def extract_edge_profiles(image, max_blur, *, rng=None, sigma=None, min_contrast=0.06,
                          min_snr=10.0, spacing=None, n_lines=5, line_spread=None,
                          flat_tol=0.06, monotone_tol=0.08, straight_tol=0.35,
                          saturation=0.99, reject_outliers=True, reject_soft=True,
                          max_candidates=6000, max_profiles=None) -> EdgeProfiles:
    """Detect, validate and centroid-align edge profiles in a blurred image (paper §2, §4).

    Parameters
    ----------
    image : array_like of shape (M, N) or (M, N, 3)
        Blurred photo; RGB is reduced to luminance. Integers are scaled by their dtype's
        maximum; floating point must be in [0, 1].
    max_blur : float
        Largest blur extent (pixels) expected: the side of the largest local PSF's
        bounding box. It sets the Canny scale, the half-length of the profiles
        ``R = max(8, ceil(max_blur) + max(3, round(0.3 max_blur)) + 1)`` (``offsets`` run
        from ``-R`` to ``R``; 8 px leave room for two flat plateaus), the widest
        transition accepted (``sqrt(2) max_blur + 1``: a bounding box's diagonal) and the
        span of the parallel lines.
    rng : None, int or numpy.random.Generator
        Used only when more than ``max_candidates`` candidates are found, to pick a
        random subset of them. Same input and seed give identical profiles.
    sigma : float, optional
        Canny scale (px). Default ``clip(0.2 * s, 1, 8)`` at each detection scale ``s``:
        smooth enough that the gradient of a blurred edge has one maximum across it, no
        smoother. Given (or given ``line_spread``), detection runs at ``max_blur`` only.
    min_contrast : float
        Smallest accepted ``|c1 - c2|`` on the [0, 1] scale (default 0.06: fainter
        "edges" in real photos are mostly shading, not blurred steps).
    min_snr : float
        Smallest accepted ``|c1 - c2| / noise`` (noise from :func:`estimate_noise`).
        Profiles under ``2 min_snr`` are kept only to make up :data:`ENOUGH_PROFILES`
        (see Notes).
    spacing : float, optional
        Least distance (px) between kept profiles, applied by greedy non-maximum
        suppression in order of quality. Default ``max(4, 0.35 max_blur)``: neighbouring
        profiles on one edge then overlap by at most half of their parallel lines (which
        span ``0.8 max_blur``), so that the kept set is spread along the edges rather
        than piled up where the gradient is strongest.
    n_lines : int
        Parallel lines averaged per profile (default 5).
    line_spread : float, optional
        The parallel lines lie at ``-s .. s`` px along the tangent; default
        ``s = max(2, 0.4 max_blur)``: the edge must follow one smooth curve over about
        the tangential reach of the PSF, because the blur integrates along it there.
    flat_tol : float
        Largest RMS deviation of the plateaus in alpha units (fraction of the contrast),
        on top of an allowance for the measured noise.
    monotone_tol : float
        Largest decrease of the (lightly smoothed) alpha matte within the transition,
        on top of a noise allowance.
    straight_tol : float
        Largest RMS (px) of the parallel lines' centroids about a straight line, on top of
        a noise allowance; the fitted slope corrects the normal angle.
    saturation : float
        The sensor's limits are this level and ``1 - saturation`` (default 0.99). A
        plateau at a limit is accepted; a sample at a limit inside the transition is not,
        nor a profile beside a clipped plateau that is narrower than the other profiles
        show the blur to be (a light brighter than white, clipped after the blur).
    reject_outliers : bool
        Refuse profiles whose derivative disagrees with the median of their neighbours
        of similar orientation.
    reject_soft : bool
        Refuse profiles wider than the camera-shake blur field fitted to the lower side
        of all profiles' widths (soft or shaded scene edges; see Notes).
    max_candidates : int
        Most candidate points examined (a seeded random subset beyond that).
    max_profiles : int, optional
        Keep at most this many profiles (those of highest quality).

    Returns
    -------
    EdgeProfiles
        Sorted by decreasing quality. Empty, with a ``reason``, when no profile passes;
        ``stats`` counts candidates, rejections by reason and kept profiles.

    Raises
    ------
    ValueError
        For invalid arguments (the message names the parameter).

    Notes
    -----
    *Scales.* ``max_blur`` is an upper bound, often a generous one (the default is 4 % of
    the longer side). Everything it sets -- the Canny scale, the parallel lines' spread,
    the curvature allowance, the windows -- asks an edge to be clean and straight over
    the largest blur. So detection runs at ``max_blur``, then at half and a quarter of it
    (down to 6 px; :func:`_scales`) on the candidates not already found: a profile found
    at a smaller scale passed every test there, is never truncated (a transition too
    wide for a scale is refused at it) and sits on the same offsets grid. On the lai
    development set this raised the cases with >= 20 profiles from 58 % to 100 % at the
    default max blur.

    *Candidates.* Canny on the luminance: Gaussian gradient at ``sigma``, non-maximum
    suppression along the gradient, hysteresis between thresholds set by the weakest
    accepted edge (``min_contrast`` spread over ``max_blur``) and by the gradient noise;
    a cheap contrast screen; the strongest pixel per cell of ``spacing / 2`` px.

    *Two passes.* Pass 1 samples ``n_lines`` parallel lines (bilinear, half-pixel steps)
    along the Canny normal through the edge pixel, finds the plateaus ``c1, c2`` and the
    transition, and fits the centroids of the single lines against their lateral offset
    ``s`` by ``a + b s + c s^2``: ``atan(b)`` is the error of the normal angle and ``2c``
    the curvature of the edge. Pass 2 samples again through the centroid, along the
    corrected normal, on lines bent by ``c s^2`` so that they cross a round edge at the
    same place, and applies every test. Both passes try windows from ``R`` down to
    ``0.3 R`` and keep the largest that passes, so that an edge whose blur is smaller
    than ``max_blur`` is not refused for clutter far beyond its transition; the
    validated half-length is kept per profile (``EdgeProfiles.window``).

    *Tests* (reasons in :data:`REASONS`): no sample at a sensor limit inside the
    transition; contrast at least
    ``min_contrast`` and ``min_snr`` times the noise; the transition (where alpha is
    between 0.05 and 0.95, or three noise levels) inside the window with flat margins of
    at least 3 px and 30 % of its width on both sides; both plateaus and every single
    line flat within ``flat_tol`` (plus noise); alpha non-decreasing within
    ``monotone_tol``; the transition no wider than ``sqrt(2) max_blur + 1``; no inner
    plateau (alpha stalling between 0.1 and 0.9 over ``0.3 max_blur``: a second edge);
    the single lines' centroids on a smooth curve within ``straight_tol``, their shapes
    alike, the normal correction under 12 degrees, and the curvature small enough that
    it moves the centroid by less than half a pixel (``|kappa| max_blur^2 / 24``).
    Among the profiles that pass, two consistency tests compare profiles with each other:
    a derivative far from the median of its neighbours of similar orientation is an
    outlier, and a derivative wider than the camera-shake blur field allows is a soft or
    shaded scene edge. The variance of a blurred step's derivative is ``n^T Sigma(x) n``
    (``Sigma`` the local PSF covariance) plus the sharp edge's own variance, never less;
    for camera shake ``Sigma(x)`` is close to a quadratic polynomial in ``x``, which is
    fitted by quantile regression (20 %) to the profiles' variances. A profile beside a
    plateau at a sensor limit must be at least 0.65 times as wide (in variance) as the
    median blur field of the unclipped profiles predicts.

    *Fidelity first, then count.* On the lai development set the share of profiles true
    to the blur rises steeply with their contrast-to-noise ratio (46 % at 10-15, 91 % at
    50-100), so profiles under ``2 min_snr`` are dropped when at least
    :data:`ENOUGH_PROFILES` stronger ones remain.

    *Alignment.* The alpha matte is cleaned into a monotone cumulative (the mean of the
    running maximum from the left and the running minimum from the right; zero before
    and one after the transition); its increments at the bin edges ``offsets +- 1/2`` are
    the derivative (Eq. 11) and its centroid is the edge position (claims 1-2). The matte
    and the derivative are resampled so that the centroid sits at offset 0.

    *Quality* is the geometric mean of six scores in (0, 1]: contrast-to-noise
    (``1 - exp(-snr / 20)``), plateau flatness, monotonicity and straightness (each
    ``1 - 0.5 x`` its statistic over its limit), agreement with the neighbours (their
    NCC; 0.75 when there are too few) and the validated window's share of ``R``; it
    orders the profiles. :attr:`EdgeProfiles.confidence` is the calibrated chance that a
    profile is true to the blur, built from the same measures.

    Real photos are stored through the sRGB curve; linearise them first
    (:func:`srgb_to_linear`) and use the same linear image for the data terms.

    References
    ----------
    .. [1] S. Vasu and A. N. Rajagopalan, "From local to global: edge profiles to camera
       motion in blurred images", CVPR 2017.
    .. [2] T. S. Cho, S. Paris, B. K. P. Horn and W. T. Freeman, "Blur kernel estimation
       using the Radon transform", CVPR 2011.

    Examples
    --------
    >>> from napari_edgecme.core.synth import edge_scene, make_case
    >>> case = make_case(edge_scene((160, 160), rng=1), "inplane", extent=7, rng=2)
    >>> prof = extract_edge_profiles(case.blurred, max_blur=9, rng=0)
    >>> len(prof) > 10, bool(abs(prof.derivatives.sum(1) - 1).max() < 1e-9)
    (True, True)
    """
    return drive(iter_extract_edge_profiles(
        image, max_blur, rng=rng, sigma=sigma, min_contrast=min_contrast, min_snr=min_snr,
        spacing=spacing, n_lines=n_lines, line_spread=line_spread, flat_tol=flat_tol,
        monotone_tol=monotone_tol, straight_tol=straight_tol, saturation=saturation,
        reject_outliers=reject_outliers, reject_soft=reject_soft,
        max_candidates=max_candidates, max_profiles=max_profiles))


def iter_extract_edge_profiles(image, max_blur, *, rng=None, sigma=None, min_contrast=0.06,
                               min_snr=10.0, spacing=None, n_lines=5, line_spread=None,
                               flat_tol=0.06, monotone_tol=0.08, straight_tol=0.35,
                               saturation=0.99, reject_outliers=True, reject_soft=True,
                               max_candidates=6000, max_profiles=None):
    """:func:`extract_edge_profiles` as a generator of progress records.

    The same parameters, checks and result (``StopIteration.value``, the same profiles
    bit for bit); a record after each part of the work -- the candidates and the
    validity tests at each detection scale, then the tests that compare the profiles
    with each other -- so that a caller reporting progress hears from it every few
    tenths of a second. ``close()`` stops it at a record; it has no partial result.

    Yields
    ------
    Progress
        ``stage="profiles"``, ``step`` parts done of ``total`` (two per detection
        scale, and one for the consistency tests).
    """
    img = to_luminance(image)
    max_blur = check_positive(max_blur, "max_blur")
    rng = as_rng(rng)
    n_lines = check_positive(n_lines, "n_lines", integer=True)
    max_candidates = check_positive(max_candidates, "max_candidates", integer=True)
    tests, geom = _settings(img, max_blur, min_contrast, min_snr, flat_tol, monotone_tol,
                            straight_tol, saturation, n_lines, line_spread)
    spacing = max(4.0, 0.35 * max_blur) if spacing is None else check_positive(
        spacing, "spacing", allow_zero=True)
    fixed_scale = sigma is not None or line_spread is not None  # the caller's geometry
    sigma = (float(np.clip(0.2 * max_blur, 1.0, 8.0)) if sigma is None
             else check_positive(sigma, "sigma"))
    if max_profiles is not None:
        max_profiles = check_positive(max_profiles, "max_profiles", integer=True)
    offsets = np.arange(-geom.half, geom.half + 1, dtype=float)
    shape = img.shape
    scales = (max_blur,) if fixed_scale else _scales(max_blur)
    stats = {"candidates": 0, "examined": 0, "valid": 0, "outliers": 0, "soft": 0,
             "duplicates": 0, "kept": 0, "rejected": {}, "noise": tests.noise, "sigma": sigma,
             "spacing": spacing, "scales": list(scales), "valid_by_scale": []}

    def empty(reason):
        return EdgeProfiles.empty(reason, offsets, shape, max_blur, stats)

    # candidates need room for the smallest window; near the border the larger ones are
    # skipped candidate by candidate
    border = math.ceil(math.hypot(geom.windows[-1] + 1.0, float(np.max(np.abs(geom.lateral))))
                       + sigma) + 2
    if min(shape) <= 2 * border + 2:
        return empty(f"image {shape[0]}x{shape[1]} is too small for max_blur={max_blur:g}: "
                     f"profiles need about {2 * border + 3} px per side")
    if float(img.max()) - float(img.min()) < tests.min_contrast:
        return empty("image has no contrast (nearly constant)")

    parts, taken = [], np.zeros((0, 2))
    total = 2 * len(scales) + 1
    for k, scale in enumerate(scales):
        where = f"edge profiles, scale {k + 1}/{len(scales)} ({scale:.3g} px)"

        def record(done, what, k=k, where=where):
            return Progress("profiles", 2 * k + done, total, f"{where}: {what}")
        part = yield from _extract_at_scale(img, scale, sigma if fixed_scale else None, tests,
                                            n_lines, line_spread, spacing, max_candidates,
                                            rng, taken, geom.half, stats, record)
        yield record(2, "tested")
        stats["valid_by_scale"].append(0 if part is None else len(part[1]["centroid"]))
        if part is not None:
            parts.append(part)
            taken = np.concatenate([taken, part[1]["centroid"]])
    if stats["candidates"] == 0:
        return empty(f"no edge candidates above the contrast threshold "
                     f"(min_contrast={tests.min_contrast:g}, noise {tests.noise:.3g})")
    if not parts:
        return empty("no candidate passed the validity tests ("
                     + _summarise(stats["rejected"]) + ")")
    res = {k: np.concatenate([r[k] for r, _ in parts]) for k in parts[0][0]}
    prof = {k: np.concatenate([p[k] for _, p in parts]) for k in parts[0][1]}
    stats["valid"] = len(prof["centroid"])

    agreement = np.full(len(prof["centroid"]), np.nan)
    keep = np.ones(len(agreement), bool)
    if reject_outliers and len(agreement) >= 4:
        keep, agreement = _neighbour_outliers(prof["centroid"], prof["angle"], prof["deriv"],
                                              shape, max_blur)
        stats["outliers"] = int((~keep).sum())
        if stats["outliers"]:
            stats["rejected"][REASONS[_OUTLIER]] = stats["outliers"]
    width_excess = np.full(len(agreement), np.nan)
    if reject_soft and keep.sum() >= 6:
        consistent, width_excess[keep] = _blur_consistency(
            prof["centroid"][keep], prof["angle"][keep], prof["deriv"][keep], offsets, shape)
        soft = ~consistent
        stats["soft"] = int(soft.sum())
        if stats["soft"]:
            stats["rejected"][REASONS[_SOFT]] = stats["soft"]
        keep[np.flatnonzero(keep)[soft]] = False
    # a plateau at the sensor's limit may hide a transition cut short by clipping
    at_limit = res["clipped_plateau"] > 0.5
    if reject_soft and (keep & at_limit).any():
        cut = _clipped_too_narrow(prof["centroid"][keep], prof["angle"][keep],
                                  prof["deriv"][keep], offsets, shape, at_limit[keep])
        if cut.any():
            stats["rejected"][REASONS[_SATURATED]] = (
                stats["rejected"].get(REASONS[_SATURATED], 0) + int(cut.sum()))
        keep[np.flatnonzero(keep)[cut]] = False
    yield Progress("profiles", total, total, "edge profiles: consistency tests done")
    quality = _quality(res, agreement, geom, tests)
    measures = _measures(res, agreement, width_excess, geom)
    idx = np.flatnonzero(keep)
    idx = idx[_spread_out(prof["centroid"][idx], quality[idx], spacing)]
    stats["duplicates"] = int(keep.sum() - len(idx))
    idx = idx[np.lexsort((idx, -quality[idx]))]
    idx = _strong_first(idx, res["snr"], 2.0 * tests.min_snr, stats)
    if max_profiles is not None:
        idx = idx[:max_profiles]
    stats["kept"] = len(idx)
    return EdgeProfiles(prof["centroid"][idx], prof["angle"][idx], res["c1"][idx],
                        res["c2"][idx], prof["alpha"][idx], prof["deriv"][idx], offsets,
                        quality[idx], image_shape=shape, max_blur=max_blur, stats=stats,
                        curvature=res["curvature"][idx], window=prof["window"][idx],
                        measures={k: v[idx] for k, v in measures.items()})


#: Each detection scale is this fraction of the previous one (see :func:`_scales`).
_SCALE_STEP = 0.5
#: No detection scale below this (px): the smallest windows are then about as short as
#: a profile's two plateaus.
_SMALLEST_SCALE = 6.0
#: At most this many scales: the smallest is then ``max_blur / 4``.
_MAX_SCALES = 3


def _scales(max_blur: float) -> tuple:
    """The detection scales, largest first: ``max_blur``, half of it, a quarter.

    ``max_blur`` is an upper bound, and a generous one when it is the default: the Canny
    scale, the parallel lines' spread, the curvature allowance and the windows it sets
    ask of an edge that it be clean and straight over the largest blur. An edge of a
    photo blurred less than that is often clean over its own blur only; the smaller
    scales give it a chance, with the same tests. A profile found at a smaller scale
    must still pass every test there (a transition wider than that scale allows is
    refused, never truncated) and sits on the same offsets grid.
    """
    scales = [float(max_blur)]
    while (len(scales) < _MAX_SCALES
           and scales[-1] * _SCALE_STEP >= min(_SMALLEST_SCALE, max_blur)):
        scales.append(scales[-1] * _SCALE_STEP)
    return tuple(scales)


def _extract_at_scale(img, scale, sigma, tests, n_lines, line_spread, spacing,
                      max_candidates, rng, taken, half, stats, record):
    """Candidates and validity tests at one detection scale; ``None`` when none passed.

    A generator: yields ``record(1, "candidates")`` once the candidates are found, and
    returns the result.

    Candidates within ``spacing`` of a profile already found at a larger scale
    (``taken``, (m, 2)) are skipped. The valid profiles are put on the offsets grid
    ``-half .. half`` of the largest scale. Updates ``stats`` (candidates, examined,
    rejections by reason). Returns the per-candidate test results and the finished
    profiles (dicts of arrays over the valid candidates).
    """
    geom = _geometry(scale, n_lines, line_spread)
    sigma = float(np.clip(0.2 * scale, 1.0, 8.0)) if sigma is None else sigma
    spacing_s = min(spacing, max(4.0, 0.35 * scale))
    border = math.ceil(math.hypot(geom.windows[-1] + 1.0, float(np.max(np.abs(geom.lateral))))
                       + sigma) + 2
    if min(img.shape) <= 2 * border + 2:
        return None
    cand, angle, _ = _edge_candidates(img, sigma, geom, tests, border, spacing_s)
    if len(taken) and len(cand):
        near = cKDTree(taken).query(cand, distance_upper_bound=spacing)[0] < spacing
        cand, angle = cand[~near], angle[~near]
    stats["candidates"] += len(cand)
    if len(cand) > max_candidates:
        pick = np.sort(rng.choice(len(cand), max_candidates, replace=False))
        cand, angle = cand[pick], angle[pick]
    stats["examined"] += len(cand)
    yield record(1, f"{len(cand)} candidates")
    if len(cand) == 0:
        return None
    res = _two_pass(img, cand, angle, geom, tests, max_tilt_pass1=np.deg2rad(30.0))
    for name, count in _count_reasons(res["reason"]).items():
        stats["rejected"][name] = stats["rejected"].get(name, 0) + count
    ok = res["reason"] == 0
    if not ok.any():
        return None
    res = {k: v[ok] for k, v in res.items()
           if isinstance(v, np.ndarray) and v.shape[:1] == ok.shape}
    res["scale"] = np.full(int(ok.sum()), float(scale))
    prof = _finish(res, geom)
    res = {k: v for k, v in res.items() if v.ndim == 1}  # the fine-grid arrays are done
    pad = half - geom.half
    if pad > 0:
        prof["alpha"] = np.pad(prof["alpha"], ((0, 0), (pad, 0)), constant_values=0.0)
        prof["alpha"] = np.pad(prof["alpha"], ((0, 0), (0, pad)), constant_values=1.0)
        prof["deriv"] = np.pad(prof["deriv"], ((0, 0), (pad, pad)))
    return res, prof


#: Profiles of contrast under twice ``min_snr`` noise levels are kept only to make up this
#: many (see :func:`_strong_first`).
ENOUGH_PROFILES = 40


def _strong_first(idx, snr, strong_snr: float, stats) -> np.ndarray:
    """Drop the weak profiles (SNR under ``strong_snr``) when enough strong ones remain.

    On the lai development set the share of profiles true to the blur (NCC >= 0.8)
    rises steeply with their contrast-to-noise ratio: 0.46 at 10-15, 0.60 at 15-30,
    0.91 at 50-100. Fidelity first: the weak ones are kept only to make up
    :data:`ENOUGH_PROFILES` profiles (best quality first, ``idx`` being in quality
    order), so that a dim or low-contrast photo still has a cue.
    """
    strong = snr[idx] >= strong_snr
    room = max(ENOUGH_PROFILES - int(strong.sum()), 0)
    weak = np.flatnonzero(~strong)
    keep = strong.copy()
    keep[weak[:room]] = True
    stats["weak_dropped"] = int((~keep).sum())
    return idx[keep]


def _gradient_noise(sigma: float) -> float:
    """Std of one Gaussian-smoothed central-difference gradient component per unit noise."""
    x = np.arange(-math.ceil(4 * sigma), math.ceil(4 * sigma) + 1)
    g = np.exp(-0.5 * (x / sigma) ** 2)
    g /= g.sum()
    d = np.convolve(g, [0.5, 0.0, -0.5])
    return float(np.linalg.norm(g) * np.linalg.norm(d))


def _edge_candidates(img, sigma, geom, tests, border, spacing):
    """Canny edge pixels (Gaussian gradient, non-maximum suppression, hysteresis).

    Returns candidate ``(row, col)`` (n, 2) float, the gradient direction ``phi`` (n,)
    and the gradient magnitude (n,), thinned to the strongest pixel per cell of about
    ``spacing / 3`` px so that the validation stage is not spent on near-duplicates.
    """
    smooth = ndimage.gaussian_filter(img, sigma, mode="nearest", truncate=3.5)
    gr, gc = np.gradient(smooth)
    mag = np.hypot(gr, gc)
    # thresholds: the weakest edge we accept (min_contrast spread over max_blur) and the
    # gradient-magnitude noise floor
    edge_peak = tests.min_contrast / math.sqrt(geom.max_blur**2 + 2 * math.pi * sigma**2)
    noise_g = tests.noise * _gradient_noise(sigma)
    high = max(0.8 * edge_peak, 4.0 * noise_g)
    low = max(0.4 * edge_peak, 2.5 * noise_g)
    inner = np.zeros(mag.shape, bool)
    inner[border:-border, border:-border] = True
    r, c = np.nonzero((mag > low) & inner)
    if r.size == 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    m = mag[r, c]
    ur, uc = gr[r, c] / m, gc[r, c] / m
    ahead = ndimage.map_coordinates(mag, [r + ur, c + uc], order=1, mode="nearest")
    behind = ndimage.map_coordinates(mag, [r - ur, c - uc], order=1, mode="nearest")
    peak = (m >= ahead) & (m > behind)
    r, c, m = r[peak], c[peak], m[peak]
    edges = np.zeros(mag.shape, bool)
    edges[r, c] = True
    labels, n_labels = ndimage.label(edges, structure=np.ones((3, 3), bool))
    strong = np.zeros(n_labels + 1, bool)
    strong[labels[r[m > high], c[m > high]]] = True
    strong[0] = False
    keep = strong[labels[r, c]]
    r, c, m = r[keep], c[keep], m[keep]
    # cheap contrast screen: the smoothed image a plateau's length beyond the edge on
    # either side, at the largest and the smallest window, must differ by half the
    # contrast the full tests will ask for
    ur, uc = gr[r, c] / m, gc[r, c] / m
    need = 0.7 * max(tests.min_contrast, tests.min_snr * tests.noise)
    best = np.full(r.size, -np.inf)
    for w in {geom.windows[0], geom.windows[-1]}:
        d = float(w - geom.plateau)
        pair = ndimage.map_coordinates(smooth, [np.concatenate([r + d * ur, r - d * ur]),
                                                np.concatenate([c + d * uc, c - d * uc])],
                                       order=1, mode="nearest")
        best = np.maximum(best, pair[:r.size] - pair[r.size:])
    keep = best >= need
    r, c, m = r[keep], c[keep], m[keep]
    # thin: strongest pixel per cell
    cell = max(1, int(spacing // 2))
    ncol = mag.shape[1] // cell + 1
    key = (r // cell) * ncol + c // cell
    order = np.lexsort((-m, key))
    first = np.ones(order.size, bool)
    first[1:] = key[order][1:] != key[order][:-1]
    sel = np.sort(order[first])
    r, c, m = r[sel], c[sel], m[sel]
    phi = np.arctan2(gr[r, c], gc[r, c])
    return np.stack([r, c], -1).astype(float), phi.astype(float), m.astype(float)


#


def _spread_out(points, quality, spacing) -> np.ndarray:
    """Greedy non-maximum suppression: indices (in quality order) at least ``spacing`` apart."""
    order = np.lexsort((np.arange(len(points)), -quality))
    if spacing <= 0:
        return order
    cells: dict = {}
    kept = []
    s2 = spacing * spacing
    for i in order:
        p = points[i]
        key = (int(p[0] // spacing), int(p[1] // spacing))
        clash = False
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                for q in cells.get((key[0] + dr, key[1] + dc), ()):
                    d = points[q] - p
                    if d[0] * d[0] + d[1] * d[1] < s2:
                        clash = True
                        break
                if clash:
                    break
            if clash:
                break
        if not clash:
            cells.setdefault(key, []).append(i)
            kept.append(i)
    return np.asarray(kept, dtype=np.int64)
