"""Hand picking: one edge profile across a line the user draws (napari's picker, the API).

The same tests as the automatic extraction (:mod:`.edge_tests`), on one candidate whose
position and normal come from the drawn line instead of the Canny detector.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from ._validation import check_positive
from .edge_tests import (
    REASONS,
    _analyse,
    _best_window,
    _finish,
    _Geometry,
    _geometry,
    _measures,
    _quality,
    _sample,
    _settings,
    _window_limit,
)
from .photometry import to_luminance
from .profiles import EdgeProfiles

__all__ = ["profile_along_line"]


def profile_along_line(image, start, end, *, max_blur=None, n_lines=5, line_spread=None,
                       min_contrast=0.06, min_snr=10.0, flat_tol=0.06, monotone_tol=0.08,
                       straight_tol=0.35, saturation=0.99) -> EdgeProfiles:
    """One edge profile across a hand-drawn line, or none with the reason why.

    The line from ``start`` to ``end`` should cross one straight edge, with flat ground on
    both sides. It is sampled with the same parallel lines and put through the same
    tests as :func:`extract_edge_profiles`; the normal is taken from the line and then
    corrected from the parallel lines (so a stroke up to about 30 degrees off the true
    normal is fine), and the profile is centred at its centroid.

    Parameters
    ----------
    image : array_like of shape (M, N) or (M, N, 3)
    start, end : sequence of two floats
        End points ``(row, col)`` of the line.
    max_blur : float, optional
        As for :func:`extract_edge_profiles`; giving it puts the profile on the same
        offsets grid as automatically extracted ones (so they can be
        :meth:`EdgeProfiles.concatenate`-d). Default: the largest blur whose window fits
        the drawn line.
    n_lines, line_spread, min_contrast, min_snr, flat_tol, monotone_tol, straight_tol, \
saturation
        As for :func:`extract_edge_profiles`.

    Returns
    -------
    EdgeProfiles
        One profile, or none with ``reason`` (e.g. ``"not monotone"``,
        ``"plateau too noisy"``, ``"line too short ..."``).
    """
    img = to_luminance(image)
    p0 = _point(start, "start")
    p1 = _point(end, "end")
    n_lines = check_positive(n_lines, "n_lines", integer=True)
    H, W = img.shape
    vec = p1 - p0
    length = float(np.hypot(*vec))
    if max_blur is None:
        mb = 1.0
        while _geometry(mb + 1.0, n_lines, line_spread).half <= length / 2:
            mb += 1.0
        max_blur = mb
    max_blur = check_positive(max_blur, "max_blur")
    tests, geom = _settings(img, max_blur, min_contrast, min_snr, flat_tol, monotone_tol,
                            straight_tol, saturation, n_lines, line_spread)
    offsets = np.arange(-geom.half, geom.half + 1, dtype=float)
    stats = {"noise": tests.noise}

    def refuse(reason):
        return EdgeProfiles.empty(reason, offsets, img.shape, max_blur, stats)

    for name, p in (("start", p0), ("end", p1)):
        if not (-0.5 <= p[0] <= H - 0.5 and -0.5 <= p[1] <= W - 0.5):
            return refuse(f"{name} point ({p[0]:.1f}, {p[1]:.1f}) lies outside the "
                          f"{H}x{W} image")
    need = 4 * geom.plateau + 4
    if length < need:
        return refuse(f"line too short: {length:.1f} px; draw at least {need} px across the "
                      f"edge, with flat ground on both sides")
    angle = math.atan2(vec[0], vec[1])
    centre = 0.5 * (p0 + p1)
    # pass 1 over the drawn line itself: one window as long as the line
    half_line = max(geom.plateau * 2 + 2, int(length // 2))
    g1 = _Geometry(geom.max_blur, geom.plateau, half_line, (half_line,), geom.lateral, geom.gap)
    S = _sample(img, centre[None], np.array([angle]), g1.t, geom.lateral)
    if np.mean(S[0, :, -4:]) < np.mean(S[0, :, :4]):  # orient towards the brighter side
        angle += math.pi  # normal and tangent turn round: reverse both sample axes
        S = S[:, ::-1, ::-1]
    off = _stroke_angle_error(img, p0, p1, float(np.clip(0.2 * max_blur, 1.0, 8.0)))
    if off > math.radians(35.0):
        return refuse(f"line crosses the edge {math.degrees(off):.0f} degrees off its normal; "
                      f"draw it roughly perpendicular to the edge")
    r1 = _analyse(S, g1, tests, final=False, max_tilt=np.deg2rad(35.0))
    if r1["reason"][0] != 0:
        return refuse(REASONS[int(r1["reason"][0])])
    nrm = np.array([math.sin(angle), math.cos(angle)])
    c = centre + r1["centroid"][0] * nrm
    angle2 = angle - float(r1["tilt"][0])
    # pass 2 at the centroid, the window no longer than the drawn line
    windows = tuple(w for w in geom.windows if w <= max(half_line, geom.windows[-1]))
    S2 = _sample(img, c[None], np.array([angle2]), geom.t, geom.lateral, r1["bend"])
    limit = _window_limit(c[None], np.array([angle2]), geom.lateral, r1["bend"], img.shape)
    r2 = _best_window(S2, geom, tests, final=True, max_tilt=tests.max_tilt, windows=windows,
                      limit=limit)
    if r2["reason"][0] != 0:
        return refuse(REASONS[int(r2["reason"][0])])
    r2["centre"] = c[None]
    r2["curvature"] = 2.0 * (r1["bend"] + r2["bend"])
    r2["sample_angle"] = np.array([angle2])
    r2["angle"] = np.array([angle2 - float(r2["tilt"][0])])
    prof = _finish(r2, geom)
    quality = _quality(r2, np.full(1, np.nan), geom, tests)
    measures = _measures(r2, np.full(1, np.nan), np.full(1, np.nan), geom)
    return EdgeProfiles(prof["centroid"], prof["angle"], r2["c1"], r2["c2"], prof["alpha"],
                        prof["deriv"], offsets, quality, image_shape=img.shape,
                        max_blur=max_blur, stats=stats, curvature=r2["curvature"],
                        window=prof["window"], measures=measures)


def _stroke_angle_error(img, p0, p1, sigma) -> float:
    """Angle (radians, 0..pi/2) between a drawn line and the normal of the edge it crosses.

    The edge normal is the magnitude-weighted mean gradient orientation (doubled angles)
    within ``2 sigma`` of the strongest gradient along the line, at scale ``sigma``; 0 when
    the line crosses no gradient at all (the other tests then say why).
    """
    H, W = img.shape
    pad = math.ceil(3 * sigma) + 2
    r0 = max(0, int(min(p0[0], p1[0])) - pad)
    r1 = min(H, int(max(p0[0], p1[0])) + pad + 1)
    c0 = max(0, int(min(p0[1], p1[1])) - pad)
    c1 = min(W, int(max(p0[1], p1[1])) + pad + 1)
    crop = ndimage.gaussian_filter(img[r0:r1, c0:c1].astype(np.float64), sigma, mode="nearest")
    if min(crop.shape) < 2:
        return 0.0
    gr, gc = np.gradient(crop)
    n = max(2, int(2 * np.hypot(*(p1 - p0))))
    u = np.linspace(0.0, 1.0, n)
    pts = [p0[0] + u * (p1[0] - p0[0]) - r0, p0[1] + u * (p1[1] - p0[1]) - c0]
    vr = ndimage.map_coordinates(gr, pts, order=1, mode="nearest")
    vc = ndimage.map_coordinates(gc, pts, order=1, mode="nearest")
    mag = np.hypot(vr, vc)
    if not mag.max() > 0:
        return 0.0
    near = np.abs(u - u[np.argmax(mag)]) * np.hypot(*(p1 - p0)) <= 2 * sigma
    doubled = np.sum(mag[near] * np.exp(2j * np.arctan2(vr[near], vc[near])))
    normal = 0.5 * np.angle(doubled)
    line = math.atan2(p1[0] - p0[0], p1[1] - p0[1])
    diff = abs(math.remainder(line - normal, math.pi))
    return float(diff)


def _point(p, name) -> np.ndarray:
    try:
        arr = np.asarray(p, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be two numbers (row, col); got {p!r}") from None
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be two finite numbers (row, col); got {p!r}")
    return arr
