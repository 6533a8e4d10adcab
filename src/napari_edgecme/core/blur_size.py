"""The blur size from the image: how long the camera shake is, before estimating it.

The estimators search a pose grid whose reach is set by ``max_blur`` (pixels; the
longest side of the local PSFs' support, :meth:`~.motion.CameraMotion.blur_extent`).
When the user does not give it, :func:`measure_blur_extent` measures it from the
blurred photo, and :func:`max_blur_for` turns that measurement into the ``max_blur``
to search with.

*Edge profiles (the measurement).* Across a blurred straight step edge the derivative
of the alpha matte is the projection of the local PSF on the edge normal (paper
Eqs. 6, 11), so its width is the PSF's width along that normal. The profiles are
extracted (:func:`~.edges.extract_edge_profiles`) at a generous probe max blur (6 % of
the working copy's longer side; again at 1.5 times the result if that comes out longer
than the probe), and the blur extent is read from the wide end of their transition
widths: the :data:`EDGE_QUANTILE` th percentile of the 2-98 % widths of the
derivatives, times :data:`EDGE_FACTOR`. The factor is there because the projection of a
PSF on most normals is shorter than the longest side of its box, and because the kept
profiles are seldom at the frame's corners, where a rotation blurs most. Statistic and
factor were chosen on the development data as a whole (``lai``, ``levin`` and lai
upscaled 2-3x: 112 real or gyro-recorded shakes of 11-73 px; the factor is the median of
true extent over the percentile there), not on single cases; see
``benchmarks/bench_blur_size.py`` and ``benchmarks/results/blur-size.md`` for the
accuracy per set. It is about +-25 % for most photos: the ratio of the widths to the
extent depends on the shape of the shake (a long roll reads short, a compact
two-dimensional wobble long), which no width statistic removes.

*Faint edges (the second try).* With fewer than :data:`MIN_PROFILES` profiles the
extraction is run again with lower contrast thresholds (:data:`_RELAXED`).

*Default (the last resort).* A constant image, or one with still too few profiles,
gets the old default (:func:`~.estimate.default_max_blur`, 4 % of the longer side), and
the message says so. A spectral backup (the half-power frequency of the gradient
spectrum) and an autocorrelation one (the lag of the gradient autocorrelation's
minimum) were measured on ``lai`` and not kept: the first read 45-68 px on the sharp
photos, the second was off by a factor of e^0.59 (log-ratio spread) on the blurred ones.

*Margin.* :func:`max_blur_for` searches up to :data:`MARGIN` times the measured extent.
An estimator told too short a max blur cannot represent the blur (on two lai cases,
0.8 x the true extent lost 0.5 and 1.8 dB against the suites' 1.3 x), and Xu+Ep told
just the true extent still loses much of a long roll (on the lai quick set, the
gyro-2 cases measured at 0.65 x their extent and searched with 1.6 x that lost
0.5-4.1 dB); told too long it loses little (2.0 x: -0.3 and +0.7 dB). So the margin
gives the suites' own cover, ``max_blur >= 1.3 x`` the true extent, on 90 % of the lai
cases: ``1.3 / (10th percentile of measured / true) = 2.0``.

Everything is measured on a copy whose longer side is at most
``DEFAULTS["max_side"]`` (1024 px, as the estimator works) and reported in the input's
pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._validation import as_rng
from .photometry import to_luminance

__all__ = ["EDGE_FACTOR", "EDGE_QUANTILE", "MARGIN", "MIN_PROFILES", "BlurSize",
           "max_blur_for", "measure_blur_extent", "resolve_max_blur", "transition_widths"]

#: Fewest edge profiles the edge measurement is made from (see the module notes).
MIN_PROFILES = 8
#: Quantile (percent) of the profiles' 2-98 % transition widths read as the blur's width.
EDGE_QUANTILE = 90.0
#: Blur extent = this times that percentile (the median of true extent over the
#: percentile on lai, levin and lai upscaled; see the module notes).
EDGE_FACTOR = 1.43
#: The contrast tests of the second try, on faint edges, when the first finds too few.
_RELAXED = {"min_contrast": 0.03, "min_snr": 6.0}
#: ``max_blur_for`` searches up to this times the measured extent.
MARGIN = 2.0
#: The probe max blur for the first extraction: this share of the working copy's longer
#: side (at least :data:`_PROBE_MIN` px).
_PROBE_SHARE = 0.06
_PROBE_MIN = 15.0


@dataclass(frozen=True)
class BlurSize:
    """A measured blur extent.

    Attributes
    ----------
    extent_px : float
        The blur extent (px of the input image): the longest side of the local PSFs'
        support, as :meth:`~.motion.CameraMotion.blur_extent` defines it.
    n_profiles : int
        Edge profiles the measurement rests on (for ``"default"``: the count that was
        too few).
    source : str
        ``"edge profiles"`` or ``"default"`` (nothing measurable).
    message : str
        One line for people, e.g. ``"blur about 40 px, from 85 edge profiles"``.
    """

    extent_px: float
    n_profiles: int
    source: str
    message: str


def measure_blur_extent(image, *, rng=None, max_side: int | None = None) -> BlurSize:
    """Measure the camera-shake blur extent of a blurred photo.

    Parameters
    ----------
    image : array_like of shape (M, N) or (M, N, 3)
        The blurred photo (any size; integers scaled by their dtype's maximum, floats
        in [0, 1]). RGB is reduced to luminance.
    rng : None, int or numpy.random.Generator
        Seeds the edge-profile extraction's candidate subsampling.
    max_side : int, optional
        Measure on a copy whose longer side is at most this (default the estimator's
        ``DEFAULTS["max_side"]``, 1024).

    Returns
    -------
    BlurSize
        ``extent_px`` in pixels of ``image``.

    Notes
    -----
    See the module notes for the sources and how their constants were chosen. Takes
    one or two edge-profile extractions on the working copy (a few seconds at 1024 px).

    Examples
    --------
    >>> from napari_edgecme.core.synth import edge_scene, make_case
    >>> case = make_case(edge_scene((240, 320), rng=1), "rotation", extent=24, rng=7)
    >>> size = measure_blur_extent(case.blurred, rng=0)
    >>> size.source, 12 < size.extent_px < 48
    ('edge profiles', True)
    """
    from .estimate import DEFAULTS, default_max_blur

    gray = to_luminance(image)
    shape = gray.shape
    max_side = int(DEFAULTS["max_side"] if max_side is None else max_side)
    work, scale = _working_copy(gray, max_side)
    rng = as_rng(rng)
    default = default_max_blur(shape)
    if float(np.ptp(work)) < 1e-6:
        return BlurSize(default, 0, "default",
                        f"the image is constant: no blur to measure; assuming the default "
                        f"{default:g} px")
    n, width = _edge_measure(work, rng)
    faint = ""
    if n < MIN_PROFILES:
        n_faint, width = _edge_measure(work, rng, relaxed=True)
        faint = " faint" if n_faint >= MIN_PROFILES else ""
        n = max(n, n_faint)
    if n >= MIN_PROFILES:
        extent = width / scale
        return BlurSize(extent, n, "edge profiles",
                        f"blur about {_rounded(extent)} px, from {n}{faint} edge profiles")
    return BlurSize(default, n, "default",
                    f"blur size not measured: only {n} edge profile{'s' if n != 1 else ''} "
                    f"(need {MIN_PROFILES}); assuming the default {default:g} px")


def max_blur_for(size: BlurSize, shape) -> float:
    """The ``max_blur`` to search with, given a measured blur size.

    Parameters
    ----------
    size : BlurSize
        From :func:`measure_blur_extent`.
    shape : tuple of int
        The image's ``(rows, cols[, channels])``.

    Returns
    -------
    float
        :data:`MARGIN` times the measured extent (the default itself when ``size`` is the
        default), at least 1 px and less than half the smaller side (the estimator's
        bounds).
    """
    rows, cols = (int(s) for s in tuple(shape)[:2])
    value = size.extent_px if size.source == "default" else MARGIN * size.extent_px
    upper = min(rows, cols) / 2.0 - 0.5
    return float(max(1.0, min(value, upper)))


def resolve_max_blur(image, max_blur: float | None, *, rng,
                     max_side: int | None = None) -> tuple[float, BlurSize | None]:
    """The ``max_blur`` to search with: the one given, or measured from ``image``.

    The one rule of every face (estimator, CLI, widgets) for a max blur left to "auto".
    An image too small for the default max blur (4 % of its longer side at least half
    its smaller side) gets that default unmeasured, for the caller's size check to
    refuse in its own words.

    Parameters
    ----------
    image : array_like of shape (M, N) or (M, N, 3)
        The blurred photo, in the light the estimator sees.
    max_blur : float or None
        The user's value (returned as it is) or None (measure).
    rng : numpy.random.Generator
        The caller's generator: the measurement draws from a stream spawned from it
        (``rng.spawn(1)[0]``), so the caller's own stream is the same either way.
    max_side : int, optional
        As in :func:`measure_blur_extent`.

    Returns
    -------
    (max_blur, size)
        ``size`` is the :class:`BlurSize` measured, or None when nothing was.
    """
    from .estimate import default_max_blur

    if max_blur is not None:
        return float(max_blur), None
    shape = np.shape(image)[:2]
    default = default_max_blur(shape)
    if default > min(shape) / 2:
        return default, None
    size = measure_blur_extent(image, rng=rng.spawn(1)[0], max_side=max_side)
    return max_blur_for(size, shape), size


# ---------------------------------------------------------------------------------------


def _rounded(px: float) -> str:
    """A length as people say it: 2 significant digits above 10 px, 1 decimal below."""
    if px >= 10:
        return f"{round(px):d}"
    return f"{px:.1f}"


def _working_copy(gray: np.ndarray, max_side: int):
    """``gray`` reduced to a longer side of at most ``max_side``; (copy, scale)."""
    from .pyramid import resize

    scale = min(1.0, max_side / max(gray.shape))
    if scale >= 1.0:
        return gray, 1.0
    target = tuple(max(8, round(s * scale)) for s in gray.shape)
    # block means first (cheap on a 24 MP photo), then the anti-aliased resize
    k = int(1.0 / scale) // 2
    if k > 1:
        H, W = (gray.shape[0] // k) * k, (gray.shape[1] // k) * k
        gray = gray[:H, :W].reshape(H // k, k, W // k, k).mean((1, 3), dtype=np.float32)
    return resize(gray.astype(np.float32), target), scale


def transition_widths(derivatives: np.ndarray, offsets: np.ndarray, lo: float = 0.02,
                      hi: float = 0.98) -> np.ndarray:
    """Width (px) between the ``lo`` and ``hi`` points of each profile's cumulative, (n,).

    ``derivatives`` (n, N) are bin masses at ``offsets`` (N,) (Eq. 11); the cumulative
    is taken at the bin edges and interpolated linearly.
    """
    d = np.clip(np.asarray(derivatives, np.float64), 0.0, None)
    n = d.shape[0]
    if n == 0:
        return np.zeros(0)
    cdf = np.cumsum(d, 1)
    cdf /= np.maximum(cdf[:, -1:], 1e-300)
    edges = np.asarray(offsets, np.float64) + 0.5
    out = np.empty(n)
    for i in range(n):
        a, b = np.interp([lo, hi], cdf[i], edges)
        out[i] = b - a
    return out


def _edge_measure(work: np.ndarray, rng, relaxed: bool = False) -> tuple[int, float]:
    """(profile count, blur extent in px of ``work``) from edge profiles.

    The extent is NaN when there are fewer than :data:`MIN_PROFILES` profiles.
    ``relaxed`` lowers the contrast tests to :data:`_RELAXED` (faint edges).
    """
    from .edges import extract_edge_profiles

    upper = min(work.shape) / 2.0 - 1.0
    probe = min(max(_PROBE_MIN, _PROBE_SHARE * max(work.shape)), upper)
    options = _RELAXED if relaxed else {}
    best = (0, float("nan"))
    for _ in range(2):
        if probe < 1:
            break
        prof = extract_edge_profiles(work, probe, rng=rng, **options)
        n = len(prof)
        if n < MIN_PROFILES:
            return max(best[0], n), best[1]
        widths = transition_widths(prof.derivatives, prof.offsets)
        extent = EDGE_FACTOR * float(np.percentile(widths, EDGE_QUANTILE))
        best = (n, extent)
        # a probe accepts transitions up to about sqrt(2) probe: re-probe when the blur
        # may be longer than this probe allowed for
        if extent <= probe or probe >= upper:
            break
        probe = min(1.5 * extent, upper)
    return best
