"""The validity tests of an edge profile (paper section 4.1; after Cho et al. 2011).

A candidate edge point is sampled on a few parallel lines along its normal
(:func:`_sample`); :func:`_analyse` finds the two plateaus and the transition of the mean
line and refuses the candidate for the first failed test (:data:`REASONS`);
:func:`_best_window` tries nested windows, largest first; :func:`_two_pass` re-samples
through the centroid along the corrected normal and applies every test again;
:func:`_finish` resamples the cleaned cumulative so that the centroid sits at offset 0
(claims 1-2). The thresholds are gathered in :class:`_Tests`, the sampling geometry that
``max_blur`` implies in :class:`_Geometry`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ._validation import check_positive
from .photometry import estimate_noise
from .profiles import _interp_rows

__all__ = ["MEASURES", "REASONS"]

#: Why a candidate profile was refused, by code (0 = kept). The strings are API: the
#: napari picker shows them, and :attr:`EdgeProfiles.stats` counts them.
REASONS = {
    1: "too close to the image border",
    2: "clipped (saturated) inside the transition",
    3: "contrast too low",
    4: "no transition in the window",
    5: "transition reaches the end of the window",
    6: "plateau too short",
    7: "plateau too noisy",
    8: "not monotone",
    9: "transition wider than max_blur",
    10: "second edge in the window",
    11: "edge not straight (parallel lines disagree)",
    12: "outlier among neighbours of similar orientation",
    13: "wider than the blur the other profiles show (soft or shaded edge)",
}
_BORDER, _SATURATED, _LOW_CONTRAST, _NO_TRANSITION, _AT_END, _SHORT, _NOISY, \
    _NOT_MONOTONE, _TOO_WIDE, _SECOND_EDGE, _NOT_STRAIGHT, _OUTLIER, _SOFT = range(1, 14)

#: Shortest flat margin on each side of the transition, as a fraction of the
#: transition's width (at least 3 px); the output grid has this fraction of ``max_blur``.
_PLATEAU_FRACTION = 0.3

#: Largest centroid shift (px) a curved edge may cause (see ``_analyse``).
_CURVATURE_BIAS = 0.5

#: Smallest alpha level (and one minus the largest) that bounds the transition; the
#: plateaus lie beyond. Real plateaus carry gentle shading, so not much below 0.05.
_TAU_FLOOR = 0.05

#: Fine sampling step along the normal (pixels): alternate samples are the bin edges
#: (for the derivative) and the bin centres (for the profile) of the one-pixel output grid.
_FINE = 0.5


# ---------------------------------------------------------------------------------------
# settings and geometry
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Tests:
    """Thresholds of the validity tests (see :func:`extract_edge_profiles`)."""

    min_contrast: float
    min_snr: float
    flat_tol: float
    monotone_tol: float
    straight_tol: float
    saturation: float
    max_tilt: float  # radians, for the second (final) pass
    noise: float


@dataclass(frozen=True)
class _Geometry:
    """Sampling geometry derived from ``max_blur``."""

    max_blur: float
    plateau: int  # shortest flat margin (px) on each side (longer for wide transitions)
    half: int  # half-length R of the output grid (px)
    windows: tuple  # candidate window half-lengths, largest first
    lateral: np.ndarray  # (L,) offsets of the parallel lines along the tangent (px)
    gap: int  # length (px) of an inner plateau that reveals a second edge

    @property
    def t(self) -> np.ndarray:
        """Fine sample positions along the normal, ``-(R + 1/2) .. R + 1/2`` step 1/2."""
        m = 4 * self.half + 3
        return (np.arange(m) - (m - 1) / 2) * _FINE

    @property
    def width_limit(self) -> float:
        # a PSF whose bounding box has side max_blur projects onto a diagonal normal over
        # up to sqrt(2) max_blur; the support thresholds trim a little of the tails
        return math.sqrt(2.0) * self.max_blur + 1.0

    @property
    def reach(self) -> float:
        """How far from the centre (px) the samples of one profile reach."""
        return math.hypot(self.half + 1.0, float(np.max(np.abs(self.lateral))))


def _geometry(max_blur: float, n_lines: int, line_spread, half_length=None) -> _Geometry:
    plateau = 3
    margin = max(plateau, round(_PLATEAU_FRACTION * max_blur))
    smallest = 2 * plateau + 2
    if half_length is None:
        # at least the smallest window: below ~3 px of blur the plateaus set the length
        half = max(smallest, math.ceil(max_blur - 1e-9) + margin + 1)
    else:
        half = int(half_length)
    fractions = (1.0, 0.8, 0.64, 0.5, 0.4, 0.3)
    # no window longer than the samples (a hand-drawn line may be shorter than `smallest`)
    windows = sorted({min(half, max(smallest, round(half * f))) for f in fractions},
                     reverse=True)
    spread = max(2.0, 0.4 * max_blur) if line_spread is None else float(line_spread)
    lateral = (np.linspace(-spread, spread, n_lines) if n_lines > 1 else np.zeros(1))
    gap = max(3, round(0.3 * max_blur))
    return _Geometry(float(max_blur), plateau, half, tuple(windows), lateral, gap)


def _settings(img, max_blur, min_contrast, min_snr, flat_tol, monotone_tol, straight_tol,
              saturation, n_lines, line_spread):
    min_contrast = check_positive(min_contrast, "min_contrast", allow_zero=True, maximum=1)
    min_snr = check_positive(min_snr, "min_snr", allow_zero=True)
    flat_tol = check_positive(flat_tol, "flat_tol")
    monotone_tol = check_positive(monotone_tol, "monotone_tol")
    straight_tol = check_positive(straight_tol, "straight_tol")
    saturation = check_positive(saturation, "saturation")
    if line_spread is not None:
        line_spread = check_positive(line_spread, "line_spread", allow_zero=True)
    tests = _Tests(min_contrast, min_snr, flat_tol, monotone_tol, straight_tol, saturation,
                   np.deg2rad(12.0), max(estimate_noise(img), 1e-4))
    return tests, _geometry(max_blur, n_lines, line_spread)


# ---------------------------------------------------------------------------------------
# sampling and the tests
# ---------------------------------------------------------------------------------------

def _sample(img, centres, angles, t, lateral, bend=None) -> np.ndarray:
    """Bilinear samples on parallel lines along the normals, (n, L, M) float64.

    Line ``j`` of profile ``i`` passes through
    ``centres[i] + lateral[j] * tangent + bend[i] * lateral[j]**2 * normal`` (so that
    the lines follow an edge of curvature ``2 bend``) and is sampled at ``t`` (px) along
    the normal ``(sin phi, cos phi)`` (row, col).
    """
    nr, nc = np.sin(angles), np.cos(angles)
    tr, tc = nc, -nr
    along = t[None, None, :]
    if bend is not None:
        along = along + (bend[:, None] * lateral[None, :] ** 2)[:, :, None]
    rows = (centres[:, 0, None, None] + lateral[None, :, None] * tr[:, None, None]
            + along * nr[:, None, None])
    cols = (centres[:, 1, None, None] + lateral[None, :, None] * tc[:, None, None]
            + along * nc[:, None, None])
    vals = ndimage.map_coordinates(img, [rows.ravel(), cols.ravel()], order=1,
                                   mode="nearest", prefilter=False)
    return vals.reshape(rows.shape).astype(np.float64)


def _analyse(S, geom: _Geometry, tests: _Tests, final: bool, max_tilt: float) -> dict:
    """Run the validity tests on one window of samples ``S`` (n, L, Mw), fine step 1/2.

    Returns per-candidate arrays: ``reason`` (0 = passed), plateaus ``c1``, ``c2``, the
    mean alpha matte, the cleaned monotone cumulative ``cdf``, the support bounds
    ``ia, ib`` (sample indices), the centroid (px from the window centre), the tilt of
    the true normal against the sampled one, and the test statistics used for quality.
    """
    n, L, Mw = S.shape
    idx = np.arange(Mw)
    t = (idx - (Mw - 1) / 2) * _FINE
    rows = np.arange(n)
    reason = np.zeros(n, np.int64)

    def fail(mask, code):
        reason[(reason == 0) & mask] = code

    m = S.mean(1)
    q = 2 * geom.plateau + 1  # fine samples of the shortest plateau
    noise_mean = tests.noise / math.sqrt(L)
    c2_0 = np.median(m[:, :q], 1)
    c1_0 = np.median(m[:, -q:], 1)
    C0 = c1_0 - c2_0
    # little difference between the ends: a bump (a line, a bar) if the middle strays far,
    # otherwise no edge at all
    bump = np.ptp(m, axis=1) >= max(tests.min_contrast, tests.min_snr * tests.noise)
    fail((C0 < 0.5 * tests.min_contrast) & bump, _NOT_MONOTONE)
    fail(C0 < 0.5 * tests.min_contrast, _LOW_CONTRAST)
    a0 = (m - c2_0[:, None]) / np.maximum(C0, 1e-6)[:, None]
    tau = np.clip(3.0 * noise_mean / np.maximum(C0, 1e-6), _TAU_FLOOR, 0.25)[:, None]
    # the half-way crossing nearest to the window centre anchors the transition
    above = a0 >= 0.5
    cross = ~above[:, :-1] & above[:, 1:]
    dist = np.where(cross, np.abs(idx[1:] - (Mw - 1) / 2), np.inf)
    j = np.argmin(dist, 1)
    has = np.isfinite(dist[rows, j])
    fail(~has, _NO_TRANSITION)
    ih = np.where(has, j + 1, (Mw - 1) // 2)
    left = (a0 <= tau) & (idx < ih[:, None])
    right = (a0 >= 1 - tau) & (idx >= ih[:, None])
    ia = np.where(left.any(1), Mw - 1 - np.argmax(left[:, ::-1], 1), -1)
    ib = np.where(right.any(1), np.argmax(right, 1), Mw)
    fail((ia < 0) | (ib >= Mw), _AT_END)
    guard = 2
    n_left = ia - guard + 1
    n_right = Mw - (ib + guard)
    # flat margins at least a fraction of the transition's own width (and 3 px)
    width0 = (ib - ia) * _FINE
    q_need = 2 * np.maximum(geom.plateau, np.round(_PLATEAU_FRACTION * width0)) + 1
    fail((n_left < q_need) | (n_right < q_need), _SHORT)
    pl = idx < (ia - guard + 1)[:, None]
    pr = idx >= (ib + guard)[:, None]
    c2 = (m * pl).sum(1) / np.maximum(n_left, 1)
    c1 = (m * pr).sum(1) / np.maximum(n_right, 1)
    C = c1 - c2
    fail((C < tests.min_contrast) | (C < tests.min_snr * tests.noise), _LOW_CONTRAST)
    Cs = np.maximum(C, 1e-6)
    alpha = (m - c2[:, None]) / Cs[:, None]
    sig_a = noise_mean / Cs
    # flat plateaus, of the mean profile and of every single line
    rms_l = np.sqrt((alpha**2 * pl).sum(1) / np.maximum(n_left, 1))
    rms_r = np.sqrt(((alpha - 1) ** 2 * pr).sum(1) / np.maximum(n_right, 1))
    flat = np.maximum(rms_l, rms_r)
    flat_lim = tests.flat_tol + 2.0 * sig_a
    fail(flat > flat_lim, _NOISY)
    # monotone transition
    sup = (idx >= ia[:, None]) & (idx <= ib[:, None])
    a_s = alpha.copy()
    a_s[:, 1:-1] = (alpha[:, :-2] + alpha[:, 1:-1] + alpha[:, 2:]) / 3.0
    clipped, clipped_plateau = _clipped_transition(S, ia, ib, pl, pr, tests.saturation)
    fail(clipped, _SATURATED)
    run_max = np.maximum.accumulate(np.where(sup, a_s, -np.inf), axis=1)
    drop = np.where(sup, run_max - a_s, 0.0).max(1)
    fail(drop > tests.monotone_tol + 3.0 * sig_a, _NOT_MONOTONE)
    width = (ib - ia) * _FINE
    fail(width > geom.width_limit, _TOO_WIDE)
    # an inner plateau (no rise over `gap` px inside the transition) is a second edge
    g = 2 * geom.gap
    if Mw > g:
        lo, hi = a_s[:, :-g], a_s[:, g:]
        inside = sup[:, :-g] & sup[:, g:] & (lo > 0.1) & (hi < 0.9)
        stall = inside & (hi - lo < np.maximum(0.015, 3.0 * sig_a)[:, None])
        fail(stall.any(1), _SECOND_EDGE)
    sig_x = tests.noise / Cs * np.sqrt(width + 1.0)
    straight_lim = tests.straight_tol + 3.0 * sig_x
    tilt, bend, straight = np.zeros(n), np.zeros(n), np.zeros(n)
    cdf = np.zeros((n, Mw))
    centroid = np.zeros(n)
    # the single lines are looked at only where the mean profile passed (most candidates
    # in a photo fail above, and these are the (n, L, Mw) computations)
    live = np.flatnonzero(reason == 0)
    if live.size:
        lv = _lines(S[live], alpha[live], c2[live], Cs[live], ia[live], ib[live], pl[live],
                    pr[live], t, geom, tests, final)
        tilt[live], bend[live] = lv["tilt"], lv["bend"]
        straight[live] = lv["straight"] * straight_lim[live]
        fail_live = np.zeros(n, bool)
        fail_live[live] = lv["noisy"]
        fail(fail_live, _NOISY)
        fail(np.abs(tilt) > max_tilt, _NOT_STRAIGHT)
        # a curved edge shifts the profile towards its concave side by about
        # kappa * var_t / 2 (var_t: the PSF's variance along the tangent, at most
        # max_blur^2 / 12 for a linear sweep); refuse edges where that exceeds half a pixel
        fail(np.abs(bend) * geom.max_blur**2 / 12.0 > _CURVATURE_BIAS, _NOT_STRAIGHT)
        if final:
            fail(straight > straight_lim, _NOT_STRAIGHT)
        # cleaned cumulative: 0 before the transition, 1 after, made monotone
        a_c = np.clip(alpha[live], 0.0, 1.0)
        a_c = np.where(idx < ia[live, None], 0.0, a_c)
        a_c = np.where(idx > ib[live, None], 1.0, a_c)
        up = np.maximum.accumulate(a_c, axis=1)
        down = np.minimum.accumulate(a_c[:, ::-1], axis=1)[:, ::-1]
        cdf[live] = 0.5 * (up + down)
        mid = 0.5 * (t[:-1] + t[1:])
        centroid[live] = (np.diff(cdf[live], axis=1) * mid).sum(1)
    return {"reason": reason, "c1": c1, "c2": c2, "alpha": alpha, "cdf": cdf, "ia": ia,
            "ib": ib, "centroid": centroid, "tilt": tilt, "bend": bend, "flat": flat / flat_lim,
            "drop": drop / (tests.monotone_tol + 3.0 * sig_a),
            "straight": straight / straight_lim, "width": width, "snr": C / tests.noise,
            "clipped_plateau": clipped_plateau}


def _clipped_transition(S, ia, ib, pl, pr, saturation: float):
    """Whether the sensor's limits cut into the transition, and how clipped the plateaus are.

    ``S`` (n, L, Mw) are the samples, ``ia, ib`` (n,) the transition's bounds, ``pl, pr``
    (n, Mw) the plateaus' samples; the limits are ``saturation`` and ``1 - saturation``.
    A sample at a limit strictly inside the transition, on any line, is clipping. A
    plateau at a limit is allowed here (a white page, a black sky); whether it hides a
    transition cut short is judged against the other profiles
    (:func:`~napari_edgecme.core.edge_consistency._clipped_too_narrow`).

    Returns
    -------
    clipped : ndarray of bool, shape (n,)
    clipped_plateau : ndarray of shape (n,)
        The larger of the two plateaus' shares of samples at a limit.
    """
    n = S.shape[0]
    clipped, share = np.zeros(n, bool), np.zeros(n)
    # most candidates of a photo have no sample at a limit: look closer only at the others
    some = np.flatnonzero((S.max(axis=(1, 2)) >= saturation)
                          | (S.min(axis=(1, 2)) <= 1.0 - saturation))
    if some.size == 0:
        return clipped, share
    S, ia, ib, pl, pr = S[some], ia[some], ib[some], pl[some], pr[some]
    idx = np.arange(S.shape[2])
    at_limit = (S >= saturation) | (S <= 1.0 - saturation)
    inside = (idx > ia[:, None]) & (idx < ib[:, None])
    clipped[some] = (at_limit & inside[:, None, :]).any(axis=(1, 2))
    frac_l = (at_limit & pl[:, None, :]).mean(1).sum(1) / np.maximum(pl.sum(1), 1)
    frac_r = (at_limit & pr[:, None, :]).mean(1).sum(1) / np.maximum(pr.sum(1), 1)
    share[some] = np.maximum(frac_l, frac_r)
    return clipped, share


def _lines(S, alpha, c2, Cs, ia, ib, pl, pr, t, geom: _Geometry, tests: _Tests,
           final: bool) -> dict:
    """The tests on the single parallel lines (profiles that passed the mean-profile tests).

    Returns the tilt of the true normal (``atan`` of the slope of the lines' centroids
    against their lateral offsets), the bend ``c`` of ``a + b s + c s^2``, the
    straightness statistic (RMS of the centroids about the line, or the lines' shape
    disagreement, whichever is worse, over its limit: > 1 fails) and whether a single
    line's plateaus are too noisy (``final`` only).
    """
    n, L, Mw = S.shape
    idx = np.arange(Mw)
    A = (S - c2[:, None, None]) / Cs[:, None, None]
    sup = (idx >= ia[:, None]) & (idx <= ib[:, None])
    width = (ib - ia) * _FINE
    noisy = np.zeros(n, bool)
    if final and L > 1:
        n_left, n_right = pl.sum(1), pr.sum(1)
        line_l = np.sqrt((A**2 * pl[:, None]).sum(2) / np.maximum(n_left, 1)[:, None])
        line_r = np.sqrt(((A - 1) ** 2 * pr[:, None]).sum(2) / np.maximum(n_right, 1)[:, None])
        noisy = np.maximum(line_l, line_r).max(1) > (2.0 * tests.flat_tol
                                                      + 3.0 * tests.noise / Cs)
    # per-line centroids -> tilt of the true normal, curvature and straightness
    hi_t = t[np.clip(ib, 0, Mw - 1)]
    seg = sup[:, :-1] & sup[:, 1:]
    area = (0.5 * _FINE * (A[:, :, :-1] + A[:, :, 1:]) * seg[:, None]).sum(2)
    x_line = hi_t[:, None] - area  # (n, L)
    s = geom.lateral
    slope, bend, straight = np.zeros(n), np.zeros(n), np.zeros(n)
    if L > 1 and np.ptp(s) > 0:
        sc = s - s.mean()
        centred = x_line - x_line.mean(1, keepdims=True)
        slope = centred @ sc / (sc @ sc)
        resid = centred - slope[:, None] * sc[None]
        straight = np.sqrt((resid**2).mean(1))
        if L > 3:  # x_j = a + b s_j + c s_j^2: c is half the edge's curvature
            q2 = sc**2 - (sc**2).mean()
            bend = resid @ q2 / (q2 @ q2)
    straight = straight / (tests.straight_tol + 3.0 * tests.noise / Cs * np.sqrt(width + 1.0))
    if final and L > 1:
        # the lines must also agree in shape (a corner or a junction within the PSF's
        # reach changes the transition of the outer lines, not only its position)
        guard = 2
        ext = (idx >= (ia - guard)[:, None]) & (idx <= (ib + guard)[:, None])
        dev = np.sqrt(((A - alpha[:, None]) ** 2 * ext[:, None]).sum(2)
                      / np.maximum(ext.sum(1), 1)[:, None]).max(1)
        straight = np.maximum(straight, dev / (tests.flat_tol + 2.5 * tests.noise / Cs))
    return {"tilt": np.arctan(slope), "bend": bend, "straight": straight, "noisy": noisy}


def _window_limit(centres, angles, lateral, bend, shape) -> np.ndarray:
    """Largest window half-length (px) whose samples stay inside the image, per profile."""
    lat = float(np.max(np.abs(lateral)))
    sag = np.abs(bend) * lat**2 if bend is not None else 0.0
    H, W = shape
    limit = np.full(len(centres), np.inf)
    for axis, size, normal, tangent in ((0, H, np.sin(angles), np.cos(angles)),
                                        (1, W, np.cos(angles), np.sin(angles))):
        room = np.minimum(centres[:, axis], size - 1 - centres[:, axis])
        room = room - lat * np.abs(tangent) - sag * np.abs(normal)
        with np.errstate(divide="ignore"):
            along = np.where(np.abs(normal) > 1e-9, room / np.abs(normal), np.inf)
        limit = np.minimum(limit, np.where(room >= 0, along - 0.5, -1.0))
    return np.floor(limit)


def _best_window(S_full, geom: _Geometry, tests: _Tests, final: bool, max_tilt: float,
                 windows=None, limit=None) -> dict:
    """Run :func:`_analyse` on nested windows (largest first); keep the largest that passes.

    ``limit`` (n,) caps the window of each candidate (near the image border). The reason
    reported for a candidate that fails everywhere is that of the largest window it was
    tried with (``"too close to the image border"`` if none fits). Arrays of the matte and
    cumulative are returned on the full fine grid, continued by 0 and 1 outside the
    chosen window.
    """
    n, _L, M = S_full.shape
    windows = geom.windows if windows is None else windows
    limit = np.full(n, np.inf) if limit is None else np.asarray(limit, float)
    out = {"reason": np.full(n, _BORDER, np.int64), "alpha": np.zeros((n, M)),
           "cdf": np.zeros((n, M)), "ia": np.zeros(n, np.int64), "ib": np.zeros(n, np.int64),
           "window": np.zeros(n, np.int64)}
    reported = np.zeros(n, bool)
    todo = np.arange(n)
    for R in windows:
        fits = limit[todo] >= R
        wait, todo = todo[~fits], todo[fits]
        if todo.size == 0:
            todo = wait
            continue
        lo = 2 * (geom.half - R)
        everyone = todo.size == n and bool((todo == np.arange(n)).all())  # a view, no copy
        window = S_full[:, :, lo:M - lo] if everyone else S_full[todo, :, lo:M - lo]
        res = _analyse(window, geom, tests, final, max_tilt)
        first = ~reported[todo]
        for key, v in res.items():
            if key in ("alpha", "cdf", "ia", "ib"):
                continue
            if key not in out:
                out[key] = np.zeros((n, *np.shape(v)[1:]), np.asarray(v).dtype)
            out[key][todo[first]] = v[first]
        reported[todo] = True
        passed = res["reason"] == 0
        take = todo[passed]
        for key, v in res.items():
            if key in ("alpha", "cdf"):
                full = np.zeros((passed.sum(), M))
                full[:, lo + v.shape[1]:] = 1.0
                full[:, lo:lo + v.shape[1]] = v[passed]
                out[key][take] = full
            elif key in ("ia", "ib"):
                out[key][take] = v[passed] + lo
            elif key == "centroid":
                out[key][take] = v[passed]  # window centres coincide
            else:
                out[key][take] = v[passed]
        out["window"][take] = R
        # every failure is tried again on the next smaller window: clutter beyond the
        # transition spoils the plateau estimates, and through them every later test
        # (keeping only "window-dependent" reasons for a retry lost a third of the
        # profiles of natural photos, as measured on the lai set)
        todo = np.concatenate([wait, todo[~passed]])
        if todo.size == 0:
            break
    return out


def _two_pass(img, centres, angles, geom: _Geometry, tests: _Tests, max_tilt_pass1: float,
              windows1=None) -> dict:
    """Pass 1 at the candidate along its normal; pass 2 at the centroid, corrected normal."""
    t = geom.t
    S = _sample(img, centres, angles, t, geom.lateral)
    limit1 = _window_limit(centres, angles, geom.lateral, None, img.shape)
    r1 = _best_window(S, geom, tests, final=False, max_tilt=max_tilt_pass1, windows=windows1,
                      limit=limit1)
    ok1 = r1["reason"] == 0
    reason = r1["reason"].copy()
    n = len(centres)
    angle2 = angles - r1["tilt"]  # tan(tilt) is the slope of centroid against lateral offset
    nrm = np.stack([np.sin(angles), np.cos(angles)], -1)
    centre2 = centres + r1["centroid"][:, None] * nrm
    res = {"reason": reason, "centre": centre2, "angle": angle2}
    idx = np.flatnonzero(ok1)
    if idx.size:
        S2 = _sample(img, centre2[idx], angle2[idx], t, geom.lateral, r1["bend"][idx])
        limit2 = _window_limit(centre2[idx], angle2[idx], geom.lateral, r1["bend"][idx],
                               img.shape)
        r2 = _best_window(S2, geom, tests, final=True, max_tilt=tests.max_tilt, limit=limit2)
        reason[idx] = r2["reason"]
        for key, v in r2.items():
            if key == "reason":
                continue
            arr = np.zeros((n, *v.shape[1:]), v.dtype)
            arr[idx] = v
            res[key] = arr
    else:
        for key, v in r1.items():
            if key != "reason":
                res[key] = np.zeros_like(v)
    # pass 2 measured the residual tilt too; fold it into the final angle (the centroid
    # was measured along the pass-2 normal, ``sample_angle``)
    res["sample_angle"] = angle2
    res["angle"] = np.where(reason == 0, angle2 - res.get("tilt", 0.0), angle2)
    res["curvature"] = 2.0 * (r1["bend"] + res.get("bend", 0.0))
    return res


def _finish(res: dict, geom: _Geometry) -> dict:
    """Resample the cleaned cumulative and the matte so that the centroid sits at offset 0."""
    t = geom.t
    centroid_off = res["centroid"]
    phi = res["sample_angle"]  # the normal along which the centroid was measured
    centre = res["centre"] + centroid_off[:, None] * np.stack([np.sin(phi), np.cos(phi)], -1)
    R = geom.half
    offsets = np.arange(-R, R + 1, dtype=float)
    edges = np.concatenate([offsets - 0.5, [R + 0.5]])
    cdf = _interp_rows(centroid_off[:, None] + edges[None, :], t, res["cdf"], 0.0, 1.0)
    deriv = np.clip(np.diff(cdf, axis=1), 0.0, None)
    deriv /= np.maximum(deriv.sum(1, keepdims=True), 1e-300)
    alpha = _interp_rows(centroid_off[:, None] + offsets[None, :], t, res["alpha"], 0.0, 1.0)
    # the window was validated about the pass-2 centre, not about the final centroid
    window = np.maximum(res["window"] - np.abs(centroid_off), 0.0)
    return {"centroid": centre, "angle": _wrap(res["angle"]), "deriv": deriv, "alpha": alpha,
            "window": window}


def _quality(res, agreement, geom: _Geometry, tests: _Tests) -> np.ndarray:
    """Geometric mean of soft scores, each in (0, 1] (see :class:`EdgeProfiles`)."""
    snr = 1.0 - np.exp(-res["snr"] / 20.0)
    flat = 1.0 - 0.5 * np.clip(res["flat"], 0, 1)
    mono = 1.0 - 0.5 * np.clip(res["drop"], 0, 1)
    straight = 1.0 - 0.5 * np.clip(res["straight"], 0, 1)
    agree = np.where(np.isfinite(agreement), np.clip(agreement, 0.05, 1.0), 0.75)
    margin = 0.5 + 0.5 * res["window"] / geom.half
    parts = np.stack([snr, flat, mono, straight, agree, margin])
    return np.exp(np.log(np.clip(parts, 1e-6, 1.0)).mean(0))


#: The per-profile measures of :attr:`EdgeProfiles.measures`, and what each means.
MEASURES = {
    "snr": "contrast |c1 - c2| over the image noise",
    "flatness": "RMS deviation of the plateaus over its limit (the test fails above 1)",
    "monotonicity": "largest fall of the matte inside the transition over its limit",
    "straightness": "disagreement of the parallel lines over its limit",
    "agreement": "NCC with the median derivative of the neighbours of similar "
                 "orientation (NaN: too few neighbours)",
    "width_excess": "variance of the derivative over the largest the blur field of all "
                    "profiles accepts (NaN: too few profiles to fit the field)",
    "width": "length (px) of the transition, where the matte is between its thresholds",
    "clipped_plateau": "share of the plateau samples at the sensor's limits",
    "tilt": "correction (radians) of the detector's normal by the parallel lines",
    "scale": "detection scale (px) at which the profile was found (``max_blur`` or a "
             "fraction of it)",
}


def _measures(res, agreement, width_excess, geom: _Geometry) -> dict:
    """The per-profile measures (:data:`MEASURES`) of candidates that passed, (n,) each."""
    out = {"snr": res["snr"], "flatness": res["flat"], "monotonicity": res["drop"],
           "straightness": res["straight"], "agreement": agreement,
           "width_excess": width_excess, "width": res["width"],
           "clipped_plateau": res["clipped_plateau"], "tilt": np.abs(res["tilt"]),
           "scale": res.get("scale", np.full(len(res["snr"]), geom.max_blur))}
    return {k: np.asarray(v, float) for k, v in out.items()}


def _count_reasons(codes) -> dict:
    out = {}
    for code in np.unique(codes[codes > 0]):
        out[REASONS[int(code)]] = int((codes == code).sum())
    return out


def _summarise(counts: dict) -> str:
    top = sorted(counts.items(), key=lambda kv: -kv[1])[:3]
    return ", ".join(f"{name}: {k}" for name, k in top) or "nothing examined"


def _wrap(angle) -> np.ndarray:
    return np.angle(np.exp(1j * np.asarray(angle, float)))
