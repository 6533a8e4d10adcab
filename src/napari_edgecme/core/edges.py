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
straight), nothing is saturated, the profile agrees with its neighbours of similar
orientation, and it is no wider than the blur field that all profiles together show
(soft or shaded scene edges would make the blur look larger). Near-duplicates along an
edge are suppressed so that the kept profiles are at least ``spacing`` pixels apart.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage, sparse
from scipy.spatial import cKDTree

from ._validation import as_float_image, as_rng, check_positive
from .camera import Intrinsics, check_poses, displacements

__all__ = [
    "PROFILES_FORMAT",
    "PROFILES_VERSION",
    "REASONS",
    "EdgeProfiles",
    "estimate_noise",
    "extract_edge_profiles",
    "measurement_matrix",
    "profile_along_line",
    "srgb_to_linear",
    "to_luminance",
]

PROFILES_FORMAT = "edgecme-profiles"
PROFILES_VERSION = 1

#: Why a candidate profile was refused, by code (0 = kept). The strings are API: the
#: napari picker shows them, and :attr:`EdgeProfiles.stats` counts them.
REASONS = {
    1: "too close to the image border",
    2: "saturated",
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

_OUTLIER_FLOOR = 0.4
_OUTLIER_MADS = 3.0
_SOFT_TAU = 0.2
_SOFT_REL = 0.35

_WINDOW_DEPENDENT = (_SATURATED, _LOW_CONTRAST, _AT_END, _SHORT, _NOISY)

#: Fine sampling step along the normal (pixels): alternate samples are the bin edges
#: (for the derivative) and the bin centres (for the profile) of the one-pixel output grid.
_FINE = 0.5

# Rec. 709 luminance, as skimage.color.rgb2gray
_LUMA = np.array([0.2125, 0.7154, 0.0721])


# ---------------------------------------------------------------------------------------
# the result
# ---------------------------------------------------------------------------------------

class EdgeProfiles:
    """A set of centroid-aligned edge profiles (paper Eqs. 1, 6, 11).

    Parameters
    ----------
    centroids : array_like of shape (n, 2)
        Centroid of each profile as image ``(row, col)``: the sub-pixel point on the
        normal where the centroid of the profile derivative lies, i.e. where the sharp
        step edge lies in the centroid-aligned latent image (claims 1-2).
    normal_angle : array_like of shape (n,)
        Direction ``phi`` (radians) of the edge normal in ``(x, y) = (col, row)``
        coordinates, pointing from the ``c2`` (darker) side to the ``c1`` side.
    c1, c2 : array_like of shape (n,)
        Intensities of the two flat regions (plateaus) on either side (Eq. 1).
    profiles : array_like of shape (n, N)
        The sampled alpha matte ``(L - c2) / (c1 - c2)`` at ``offsets`` (Eq. 1), averaged
        over the parallel lines. Outside the validated window it is continued by its
        plateau values 0 and 1.
    derivatives : array_like of shape (n, N)
        Derivative of the alpha matte: mass of the normal projection of the local PSF in
        the one-pixel bins centred at ``offsets`` (Eq. 11). Non-negative, each row sums
        to one, centroid at offset 0; zero outside the detected transition.
    offsets : array_like of shape (N,)
        Integer sample positions along the normal (pixels) relative to the centroid,
        ``-R .. R``.
    quality : array_like of shape (n,)
        Score in [0, 1] (contrast-to-noise, plateau flatness, monotonicity,
        straightness, agreement with neighbours, flat margin length).
    reason : str
        Empty when ``n > 0``; otherwise why no profile was found.
    curvature : array_like of shape (n,), optional
        Signed curvature (1/px) of the edge at the centroid: the edge runs through
        ``centroid + s * tangent + (curvature / 2) * s**2 * normal``. Zero by default.
    window : array_like of shape (n,), optional
        Half-length (px) of the window, centred on the centroid, over which the profile
        was validated (flat plateaus, no other edge). Default: the whole grid,
        ``max(|offsets|)``.
    image_shape : tuple of int, optional
        ``(rows, cols)`` of the image the profiles come from.
    max_blur : float, optional
        Largest blur extent (pixels) the profiles were extracted for.
    stats : dict, optional
        Bookkeeping of the extraction (candidates, rejections by reason, ...).

    Notes
    -----
    ``len(profiles)`` is the number of profiles; an empty set is falsy and carries a
    ``reason``. Arrays are float64 (they are small; files round-trip exactly).
    """

    def __init__(self, centroids, normal_angle, c1, c2, profiles, derivatives, offsets,
                 quality, reason: str = "", image_shape=None, max_blur=None, stats=None,
                 curvature=None, window=None):
        self.offsets = np.asarray(offsets, dtype=float).reshape(-1)
        N = self.offsets.size
        self.centroids = np.asarray(centroids, dtype=float).reshape(-1, 2)
        n = self.centroids.shape[0]
        self.normal_angle = _vector(normal_angle, n, "normal_angle")
        self.c1 = _vector(c1, n, "c1")
        self.c2 = _vector(c2, n, "c2")
        self.quality = _vector(quality, n, "quality")
        self.curvature = np.zeros(n) if curvature is None else _vector(curvature, n,
                                                                       "curvature")
        full = float(np.max(np.abs(self.offsets))) if N else 0.0
        self.window = np.full(n, full) if window is None else _vector(window, n, "window")
        self.profiles = _matrix(profiles, n, N, "profiles")
        self.derivatives = _matrix(derivatives, n, N, "derivatives")
        self.reason = str(reason) if n == 0 else ""
        if n == 0 and not self.reason:
            self.reason = "no edge profiles"
        self.image_shape = (None if image_shape is None
                            else tuple(int(s) for s in tuple(image_shape)[:2]))
        self.max_blur = None if max_blur is None else float(max_blur)
        self.stats = dict(stats or {})

    # -- basic protocol ------------------------------------------------------------------
    @classmethod
    def empty(cls, reason: str, offsets=(0.0,), image_shape=None, max_blur=None,
              stats=None) -> EdgeProfiles:
        """No profiles, with the ``reason`` why none were found."""
        N = len(np.asarray(offsets).reshape(-1))
        z = np.zeros(0)
        return cls(np.zeros((0, 2)), z, z, z, np.zeros((0, N)), np.zeros((0, N)), offsets, z,
                   reason=reason, image_shape=image_shape, max_blur=max_blur, stats=stats)

    def __len__(self) -> int:
        return self.centroids.shape[0]

    def __repr__(self) -> str:
        if len(self) == 0:
            return f"EdgeProfiles(n=0, reason={self.reason!r})"
        return (f"EdgeProfiles(n={len(self)}, N={self.offsets.size}, "
                f"image_shape={self.image_shape}, max_blur={self.max_blur})")

    @property
    def contrast(self) -> np.ndarray:
        """``|c1 - c2|``, shape (n,): the gradient magnitude of the ideal step edge (claim 3)."""
        return np.abs(self.c1 - self.c2)

    @property
    def normals(self) -> np.ndarray:
        """Unit normals as ``(drow, dcol)``, shape (n, 2)."""
        return np.stack([np.sin(self.normal_angle), np.cos(self.normal_angle)], -1)

    @property
    def tangents(self) -> np.ndarray:
        """Unit tangents (the normal turned by +90 degrees in ``(x, y)``), ``(drow, dcol)``."""
        return np.stack([np.cos(self.normal_angle), -np.sin(self.normal_angle)], -1)

    def subset(self, indices) -> EdgeProfiles:
        """The profiles at ``indices`` (int array or list), in that order."""
        idx = np.asarray(indices)
        if idx.dtype == bool:
            return self.select(idx)
        idx = idx.astype(np.int64).reshape(-1)
        n = len(self)
        if idx.size and (idx.min() < -n or idx.max() >= n):
            raise ValueError(f"indices must lie in [-{n}, {n}); got {idx.min()}..{idx.max()}")
        reason = "" if idx.size else "no profiles selected"
        return EdgeProfiles(self.centroids[idx], self.normal_angle[idx], self.c1[idx],
                            self.c2[idx], self.profiles[idx], self.derivatives[idx],
                            self.offsets, self.quality[idx], reason=reason,
                            image_shape=self.image_shape, max_blur=self.max_blur,
                            stats=self.stats, curvature=self.curvature[idx],
                            window=self.window[idx])

    def select(self, mask) -> EdgeProfiles:
        """The profiles where the boolean ``mask`` of shape (n,) is true."""
        mask = np.asarray(mask)
        if mask.dtype != bool or mask.shape != (len(self),):
            raise ValueError(f"mask must be a boolean array of shape ({len(self)},); "
                             f"got dtype {mask.dtype} and shape {mask.shape}")
        return self.subset(np.flatnonzero(mask))

    @classmethod
    def concatenate(cls, items) -> EdgeProfiles:
        """Join profile sets (e.g. automatic ones and hand-picked ones).

        Sets with different ``offsets`` ranges are put on the widest one: derivatives
        are padded with zeros and profiles with their plateau values 0 and 1.
        """
        items = [it for it in items if isinstance(it, EdgeProfiles)]
        if not items:
            raise ValueError("concatenate needs at least one EdgeProfiles")
        R = max(round(np.max(np.abs(it.offsets))) for it in items)
        offsets = np.arange(-R, R + 1, dtype=float)
        parts = [it._padded(R) for it in items if len(it)]
        shape = next((it.image_shape for it in items if it.image_shape), None)
        blur = max((it.max_blur for it in items if it.max_blur is not None), default=None)
        if not parts:
            return cls.empty(items[0].reason, offsets, shape, blur)
        cat = [np.concatenate(x) for x in zip(*parts, strict=True)]
        return cls(cat[0], cat[1], cat[2], cat[3], cat[4], cat[5], offsets, cat[6],
                   image_shape=shape, max_blur=blur, curvature=cat[7], window=cat[8])

    def _padded(self, R):
        r = round(np.max(np.abs(self.offsets)))
        if not np.allclose(self.offsets, np.arange(-r, r + 1)):
            raise ValueError("only profiles on integer offsets -R..R can be concatenated")
        pad = R - r
        prof = np.pad(self.profiles, ((0, 0), (pad, 0)), constant_values=0.0)
        prof = np.pad(prof, ((0, 0), (0, pad)), constant_values=1.0)
        der = np.pad(self.derivatives, ((0, 0), (pad, pad)))
        return (self.centroids, self.normal_angle, self.c1, self.c2, prof, der, self.quality,
                self.curvature, self.window)

    # -- pyramids -----------------------------------------------------------------------
    def rescaled(self, factor: float) -> EdgeProfiles:
        """These profiles for the same image resized by ``factor`` (a pyramid level).

        Centroids map as pixel centres do under resizing, ``(p + 0.5) * factor - 0.5``
        (the convention of :meth:`Intrinsics.rescaled`); angles and plateaus are
        unchanged; the alpha mattes are resampled at ``offsets / factor`` and the
        derivatives are the bin masses of the (piecewise linear) cumulative at the new
        bin edges, so they still sum to one with their centroid at 0. The new grid is
        ``-R'..R'`` with ``R' = ceil(R * factor)``.

        Parameters
        ----------
        factor : float
            New size over old size (``< 1`` for a coarser level).
        """
        factor = check_positive(factor, "factor")
        R = round(np.max(np.abs(self.offsets))) if self.offsets.size else 0
        R2 = max(1, math.ceil(R * factor - 1e-9))
        new_off = np.arange(-R2, R2 + 1, dtype=float)
        shape = (None if self.image_shape is None
                 else tuple(max(1, round(s * factor)) for s in self.image_shape))
        blur = None if self.max_blur is None else self.max_blur * factor
        if len(self) == 0:
            return EdgeProfiles.empty(self.reason, new_off, shape, blur, self.stats)
        old_edges = np.concatenate([self.offsets - 0.5, self.offsets[-1:] + 0.5])
        cdf = np.concatenate([np.zeros((len(self), 1)), np.cumsum(self.derivatives, 1)], 1)
        new_edges = np.concatenate([new_off - 0.5, new_off[-1:] + 0.5]) / factor
        cdf_new = _interp_rows(new_edges, old_edges, cdf, 0.0, 1.0)
        der = np.clip(np.diff(cdf_new, axis=1), 0.0, None)
        der /= np.maximum(der.sum(1, keepdims=True), 1e-300)
        prof = _interp_rows(new_off / factor, self.offsets, self.profiles, 0.0, 1.0)
        cen = (self.centroids + 0.5) * factor - 0.5
        return EdgeProfiles(cen, self.normal_angle, self.c1, self.c2, prof, der, new_off,
                            self.quality, image_shape=shape, max_blur=blur, stats=self.stats,
                            curvature=self.curvature / factor, window=self.window * factor)

    # -- files -----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The profiles as the JSON-ready dict of the profile file (format version 1)."""
        return {
            "format": PROFILES_FORMAT,
            "version": PROFILES_VERSION,
            "image_shape": None if self.image_shape is None else list(self.image_shape),
            "max_blur": self.max_blur,
            "reason": self.reason,
            "offsets": self.offsets.tolist(),
            "centroids": self.centroids.tolist(),
            "normal_angle": self.normal_angle.tolist(),
            "c1": self.c1.tolist(),
            "c2": self.c2.tolist(),
            "quality": self.quality.tolist(),
            "curvature": self.curvature.tolist(),
            "window": self.window.tolist(),
            "profiles": self.profiles.tolist(),
            "derivatives": self.derivatives.tolist(),
            "stats": _jsonable(self.stats),
        }

    @classmethod
    def from_dict(cls, data) -> EdgeProfiles:
        """Build profiles from the dict of a profile file; ``ValueError`` names what is wrong."""
        if not isinstance(data, dict):
            raise ValueError("profile file must hold a JSON object")
        if data.get("format") != PROFILES_FORMAT:
            raise ValueError(f"not an edgecme profile file: 'format' is {data.get('format')!r}, "
                             f"expected {PROFILES_FORMAT!r}")
        if data.get("version") != PROFILES_VERSION:
            raise ValueError(f"unsupported profile file version {data.get('version')!r}; "
                             f"this program reads version {PROFILES_VERSION}")
        keys = ("offsets", "centroids", "normal_angle", "c1", "c2", "quality", "profiles",
                "derivatives")
        for key in keys:
            if key not in data:
                raise ValueError(f"profile file has no {key!r} entry")
        arrays = {}
        for key in keys:
            try:
                arr = np.asarray(data[key], dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f"profile file entry {key!r} is not a numeric array") from None
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"profile file entry {key!r} holds non-finite values")
            arrays[key] = arr
        N = arrays["offsets"].size
        if arrays["offsets"].ndim != 1 or N == 0:
            raise ValueError("profile file entry 'offsets' must be a non-empty list")
        n = arrays["centroids"].shape[0] if arrays["centroids"].ndim == 2 else (
            0 if arrays["centroids"].size == 0 else -1)
        expected = {"centroids": (n, 2), "normal_angle": (n,), "c1": (n,), "c2": (n,),
                    "quality": (n,), "profiles": (n, N), "derivatives": (n, N)}
        for key, shape in expected.items():
            arr = arrays[key]
            if n == 0 and arr.size == 0:
                continue
            if n < 0 or arr.shape != shape:
                raise ValueError(f"profile file entry {key!r} must have shape "
                                 f"{tuple('n' if s == n else s for s in shape)} consistent with "
                                 f"'centroids' and 'offsets'; got {arr.shape}")
        shape = data.get("image_shape")
        blur = data.get("max_blur")
        try:
            shape = None if shape is None else tuple(int(s) for s in shape)
            blur = None if blur is None else float(blur)
        except (TypeError, ValueError):
            raise ValueError("profile file 'image_shape'/'max_blur' are malformed") from None
        stats = data.get("stats") if isinstance(data.get("stats"), dict) else {}
        optional = {}
        for key in ("curvature", "window"):
            if data.get(key) is None or n <= 0:
                continue
            try:
                arr = np.asarray(data[key], dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f"profile file entry {key!r} is not a numeric array") from None
            if arr.shape != (n,) or not np.all(np.isfinite(arr)):
                raise ValueError(f"profile file entry {key!r} must hold n={n} finite "
                                 f"numbers; got shape {arr.shape}")
            optional[key] = arr
        if n == 0:
            return cls.empty(str(data.get("reason") or "no edge profiles"), arrays["offsets"],
                             shape, blur, stats)
        return cls(arrays["centroids"], arrays["normal_angle"], arrays["c1"], arrays["c2"],
                   arrays["profiles"], arrays["derivatives"], arrays["offsets"],
                   arrays["quality"], image_shape=shape, max_blur=blur, stats=stats,
                   **optional)

    def save(self, path) -> None:
        """Write the profiles as JSON, atomically (temporary file + rename)."""
        path = Path(path)
        tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
        try:
            with open(tmp, "w", encoding="utf-8") as fh:
                json.dump(self.to_dict(), fh)
                fh.write("\n")
            os.replace(tmp, path)
        finally:
            if tmp.exists():
                tmp.unlink()

    @classmethod
    def load(cls, path) -> EdgeProfiles:
        """Read a profile file; any problem raises one ``ValueError`` line that names it."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise ValueError(f"profile file not found: {path}") from None
        except (OSError, UnicodeDecodeError) as err:
            raise ValueError(f"cannot read profile file {path}: {_first_line(err)}") from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            raise ValueError(f"profile file {path} is not valid JSON: {err.msg} "
                             f"(line {err.lineno})") from None
        try:
            return cls.from_dict(data)
        except ValueError as err:
            raise ValueError(f"{path}: {err}") from None

    # -- display ---------------------------------------------------------------------------
    def figure(self, indices=None, path=None, max_lines: int = 60):
        """Plot selected profiles (alpha mattes) and their derivatives.

        Parameters
        ----------
        indices : array_like of int, optional
            Profiles to draw (default: all, thinned evenly to ``max_lines``).
        path : str or Path, optional
            Also save the figure there (format from the suffix).
        max_lines : int
            Most curves drawn per panel.

        Returns
        -------
        matplotlib.figure.Figure
            Drawn on an Agg canvas; no pyplot state is touched. Needs matplotlib
            (the ``plot`` extra).
        """
        try:
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure
        except ImportError:  # pragma: no cover - depends on the environment
            raise ImportError("EdgeProfiles.figure needs matplotlib: "
                              "pip install 'napari-edgecme[plot]'") from None
        sel = np.arange(len(self)) if indices is None else np.asarray(indices, int).reshape(-1)
        if sel.size > max_lines:
            sel = sel[np.linspace(0, sel.size - 1, max_lines).round().astype(int)]
        fig = Figure(figsize=(9, 3.6), layout="constrained")
        FigureCanvasAgg(fig)
        ax_p, ax_d = fig.subplots(1, 2, sharex=True)
        from matplotlib import colormaps

        cmap = colormaps["viridis"]
        for i in sel:
            colour = cmap(float(np.clip(self.quality[i], 0, 1)))
            ax_p.plot(self.offsets, self.profiles[i], color=colour, lw=1, alpha=0.8)
            ax_d.plot(self.offsets, self.derivatives[i], color=colour, lw=1, alpha=0.8)
        if sel.size:
            ax_d.plot(self.offsets, np.median(self.derivatives[sel], 0), color="k", lw=2,
                      label="median")
            ax_d.legend(loc="upper right", fontsize=8)
        ax_p.set_title("edge profiles (alpha matte, Eq. 1)")
        ax_d.set_title("derivatives (PSF projections, Eq. 11)")
        for ax in (ax_p, ax_d):
            ax.set_xlabel("offset along the normal from the centroid (px)")
            ax.grid(alpha=0.3)
        ax_p.set_ylabel("alpha")
        ax_d.set_ylabel("mass per pixel")
        fig.suptitle(f"{sel.size} of {len(self)} profiles (colour: quality)"
                     if len(self) else f"no profiles: {self.reason}", fontsize=10)
        if path is not None:
            fig.savefig(path, dpi=100)
        return fig


# ---------------------------------------------------------------------------------------
# public helpers
# ---------------------------------------------------------------------------------------

def to_luminance(image, name: str = "image", *, check_range: bool = True) -> np.ndarray:
    """Validate an image and return its luminance, (M, N) float32 (float64 kept).

    RGB input is weighted as :func:`skimage.color.rgb2gray` (Rec. 709). Floating-point
    images must be scaled to [0, 1] (the engine's input rule,
    :func:`~napari_edgecme.core._validation.as_float_image`): every threshold of the
    edge tests is on that scale. ``check_range=False`` accepts any finite range, for
    callers whose result is linear in the intensities (see ``as_float_image``).
    """
    img = as_float_image(image, name, allow_rgb=True, min_size=2, check_range=check_range)
    if img.ndim == 3:
        img = (img @ _LUMA.astype(img.dtype)).astype(img.dtype)
    return img


def srgb_to_linear(image) -> np.ndarray:
    """Undo the sRGB transfer curve (IEC 61966-2-1): encoded values -> linear light.

    Blur adds light linearly, so the edge-profile model (Eqs. 1-6) holds for linear
    intensities; an 8-bit photo stores them through the sRGB curve, which bends every
    profile (the dark half of a transition is stretched, the bright half squeezed) and
    moves its centroid. On gamma-encoded synthetic shakes of the bundled photos, the
    median NCC between extracted profile derivatives and the true PSF projections rose
    from 0.81 to 0.97 when the input was linearised first. Linearise once and give the
    same linear image to :func:`extract_edge_profiles` and to the estimator's data terms.

    Parameters
    ----------
    image : array_like of shape (M, N) or (M, N, 3)
        sRGB-encoded values (integers scaled by their dtype, floats in [0, 1]).

    Returns
    -------
    ndarray, same shape, float32 (float64 kept)
    """
    img = as_float_image(image, allow_rgb=True)
    low = img <= 0.04045
    out = np.where(low, img / 12.92, ((np.maximum(img, 0.04045) + 0.055) / 1.055) ** 2.4)
    return out.astype(img.dtype)


def estimate_noise(image) -> float:
    """Standard deviation of white noise in ``image`` (robust, fast).

    Immerkaer's Laplacian-difference mask, with the median absolute response in place
    of the mean so that edges and texture do not inflate the estimate.

    Parameters
    ----------
    image : ndarray of shape (M, N) or (M, N, 3)

    Returns
    -------
    float
        Noise sigma on the image's [0, 1] scale (includes quantisation noise).
    """
    img = to_luminance(image)
    if min(img.shape) < 3:
        return 0.0
    a = img.astype(np.float32, copy=False)
    # [1 -2 1; -2 4 -2; 1 -2 1] = outer([1 -2 1], [1 -2 1]) computed separably
    d = a[:, :-2] - 2 * a[:, 1:-1] + a[:, 2:]
    r = d[:-2] - 2 * d[1:-1] + d[2:]
    return float(np.median(np.abs(r)) / (6.0 * 0.6745))


def measurement_matrix(profiles: EdgeProfiles, model: str, intrinsics: Intrinsics, poses,
                       points=None) -> sparse.csr_matrix:
    """The measurement matrix ``M`` of Eqs. 13-15: MDF weights -> profile derivatives.

    Row block ``i`` holds the Radon slice (Eq. 13) of the PSF at profile ``i``'s
    centroid along its normal: pose ``p`` puts its weight at ``rho_ip = (H_p x_i - x_i) . n_i``,
    splatted linearly into the one-pixel bins of ``profiles.offsets``. With
    centroid-aligned profiles the poses are those of the re-centred motion (claim 2),
    so ``M @ w`` is compared with ``profiles.derivatives.ravel()`` directly.

    Parameters
    ----------
    profiles : EdgeProfiles
        ``n`` profiles on ``N`` offsets.
    model, intrinsics, poses
        The pose set (``n_poses``, d) of the weights.
    points : array_like of shape (n, 2), optional
        Where to evaluate the PSFs (default: the centroids).

    Returns
    -------
    scipy.sparse.csr_matrix of shape (n * N, n_poses)
        Column sums are at most one (mass beyond the offsets range is dropped).
    """
    poses = check_poses(poses, model)
    pts = profiles.centroids if points is None else np.asarray(points, float).reshape(-1, 2)
    n, N = len(profiles), profiles.offsets.size
    if n == 0:
        return sparse.csr_matrix((0, len(poses)))
    disp = displacements(model, intrinsics, poses, pts)  # (n, P, 2) as (dx, dy)
    nx = np.cos(profiles.normal_angle)[:, None]
    ny = np.sin(profiles.normal_angle)[:, None]
    rho = disp[..., 0] * nx + disp[..., 1] * ny  # (n, P)
    pos = rho - profiles.offsets[0]  # fractional bin index
    j0 = np.floor(pos).astype(np.int64)
    frac = pos - j0
    rows, cols, vals = [], [], []
    pose_idx = np.broadcast_to(np.arange(len(poses))[None, :], rho.shape)
    base = (np.arange(n) * N)[:, None]
    for dj, wgt in ((0, 1.0 - frac), (1, frac)):
        j = j0 + dj
        keep = (j >= 0) & (j < N) & (wgt > 0)
        rows.append((base + j)[keep])
        cols.append(pose_idx[keep])
        vals.append(wgt[keep])
    return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(n * N, len(poses)))


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


# ---------------------------------------------------------------------------------------
# automatic extraction
# ---------------------------------------------------------------------------------------

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
        Canny scale (px). Default ``clip(0.2 * max_blur, 1, 8)``: smooth enough that the
        gradient of a blurred edge has one maximum across it, no smoother.
    min_contrast : float
        Smallest accepted ``|c1 - c2|`` on the [0, 1] scale (default 0.06: fainter
        "edges" in real photos are mostly shading, not blurred steps).
    min_snr : float
        Smallest accepted ``|c1 - c2| / noise`` (noise from :func:`estimate_noise`).
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
        Profiles containing a sample at or above this level are refused (default 0.99).
    reject_outliers : bool
        Refuse profiles whose derivative disagrees with the median of their neighbours
        of similar orientation.
    reject_soft : bool
        Refuse profiles wider than the camera-shake blur field fitted to the lower side
        of all profiles' widths (soft or shaded scene edges; see Notes).
    max_candidates : int
        Most candidate points examined (a seeded random subset beyond that).
    max_profiles : int, optional
        Keep at most this many profiles (the best ones).

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

    *Tests* (reasons in :data:`REASONS`): no sample at ``saturation``; contrast at least
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
    fitted by quantile regression (20 %) to the profiles' variances.

    *Alignment.* The alpha matte is cleaned into a monotone cumulative (the mean of the
    running maximum from the left and the running minimum from the right; zero before
    and one after the transition); its increments at the bin edges ``offsets +- 1/2`` are
    the derivative (Eq. 11) and its centroid is the edge position (claims 1-2). The matte
    and the derivative are resampled so that the centroid sits at offset 0.

    *Quality* is the geometric mean of six scores in (0, 1]: contrast-to-noise
    (``1 - exp(-snr / 20)``), plateau flatness, monotonicity and straightness (each
    ``1 - 0.5 x`` its statistic over its limit), agreement with the neighbours (their
    NCC; 0.75 when there are too few) and the validated window's share of ``R``.

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
    img = to_luminance(image)
    max_blur = check_positive(max_blur, "max_blur")
    rng = as_rng(rng)
    n_lines = check_positive(n_lines, "n_lines", integer=True)
    max_candidates = check_positive(max_candidates, "max_candidates", integer=True)
    tests, geom = _settings(img, max_blur, min_contrast, min_snr, flat_tol, monotone_tol,
                            straight_tol, saturation, n_lines, line_spread)
    spacing = max(4.0, 0.35 * max_blur) if spacing is None else check_positive(
        spacing, "spacing", allow_zero=True)
    sigma = (float(np.clip(0.2 * max_blur, 1.0, 8.0)) if sigma is None
             else check_positive(sigma, "sigma"))
    if max_profiles is not None:
        max_profiles = check_positive(max_profiles, "max_profiles", integer=True)
    offsets = np.arange(-geom.half, geom.half + 1, dtype=float)
    shape = img.shape
    stats = {"candidates": 0, "examined": 0, "valid": 0, "outliers": 0, "soft": 0,
             "duplicates": 0, "kept": 0, "rejected": {}, "noise": tests.noise, "sigma": sigma,
             "spacing": spacing}

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

    cand, angle, _ = _edge_candidates(img, sigma, geom, tests, border, spacing)
    stats["candidates"] = len(cand)
    if len(cand) == 0:
        return empty(f"no edge candidates above the contrast threshold "
                     f"(min_contrast={tests.min_contrast:g}, noise {tests.noise:.3g})")
    if len(cand) > max_candidates:
        pick = np.sort(rng.choice(len(cand), max_candidates, replace=False))
        cand, angle = cand[pick], angle[pick]
    stats["examined"] = len(cand)

    res = _two_pass(img, cand, angle, geom, tests, max_tilt_pass1=np.deg2rad(30.0))
    ok = res["reason"] == 0
    stats["rejected"] = _count_reasons(res["reason"])
    stats["valid"] = int(ok.sum())
    if not ok.any():
        return empty("no candidate passed the validity tests ("
                     + _summarise(stats["rejected"]) + ")")
    res = {k: (v[ok] if isinstance(v, np.ndarray) and v.shape[:1] == ok.shape else v)
           for k, v in res.items()}
    prof = _finish(res, geom)

    agreement = np.full(len(prof["centroid"]), np.nan)
    keep = np.ones(len(agreement), bool)
    if reject_outliers and len(agreement) >= 4:
        keep, agreement = _neighbour_outliers(prof["centroid"], prof["angle"], prof["deriv"],
                                              shape, max_blur)
        stats["outliers"] = int((~keep).sum())
        if stats["outliers"]:
            stats["rejected"][REASONS[_OUTLIER]] = stats["outliers"]
    if reject_soft and keep.sum() >= 6:
        soft = ~_blur_consistency(prof["centroid"][keep], prof["angle"][keep],
                                  prof["deriv"][keep], offsets, shape)
        stats["soft"] = int(soft.sum())
        if stats["soft"]:
            stats["rejected"][REASONS[_SOFT]] = stats["soft"]
        keep[np.flatnonzero(keep)[soft]] = False
    quality = _quality(res, agreement, geom, tests)
    idx = np.flatnonzero(keep)
    idx = idx[_spread_out(prof["centroid"][idx], quality[idx], spacing)]
    stats["duplicates"] = int(keep.sum() - len(idx))
    idx = idx[np.lexsort((idx, -quality[idx]))]
    if max_profiles is not None:
        idx = idx[:max_profiles]
    stats["kept"] = len(idx)
    return EdgeProfiles(prof["centroid"][idx], prof["angle"][idx], res["c1"][idx],
                        res["c2"][idx], prof["alpha"][idx], prof["deriv"][idx], offsets,
                        quality[idx], image_shape=shape, max_blur=max_blur, stats=stats,
                        curvature=res["curvature"][idx], window=prof["window"][idx])


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


# ---------------------------------------------------------------------------------------
# sampling and the validity tests
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
    fail((S >= tests.saturation).any(axis=(1, 2)), _SATURATED)
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
            "straight": straight / straight_lim, "width": width, "snr": C / tests.noise}


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
        res = _analyse(S_full[todo, :, lo:M - lo], geom, tests, final, max_tilt)
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
        # a smaller window can only help where clutter beyond the transition spoiled the
        # plateaus (or their estimate); the other failures do not depend on the window
        todo = np.concatenate([wait, todo[np.isin(res["reason"], _WINDOW_DEPENDENT)]])
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


def _interp_rows(x, xp, fp, left, right) -> np.ndarray:
    """Row-wise linear interpolation of ``fp`` (n, M) on the uniform grid ``xp`` at ``x``.

    ``x`` is (n, K) or (K,) (shared by every row). Outside the grid, ``left``/``right``.
    """
    fp = np.asarray(fp, float)
    n, M = fp.shape
    x = np.broadcast_to(np.asarray(x, float), (n, *np.shape(x)[-1:]))
    step = (xp[-1] - xp[0]) / (M - 1) if M > 1 else 1.0
    pos = (x - xp[0]) / step
    j = np.clip(np.floor(pos).astype(np.int64), 0, max(M - 2, 0))
    frac = pos - j
    rows = np.arange(n)[:, None]
    val = fp[rows, j] * (1 - frac) + fp[rows, np.minimum(j + 1, M - 1)] * frac
    val = np.where(pos < 0, left, val)
    return np.where(pos > M - 1, right, val)


def _neighbour_outliers(centroids, angles, deriv, shape, max_blur):
    """Compare each derivative with the median of its neighbours of similar orientation.

    Neighbours: the 16 nearest profiles within ``max(3 max_blur, 6% of the image
    diagonal)`` whose normals agree within 20 degrees up to sign (an opposite normal
    sees the mirrored projection, so its derivative is reversed first). A profile with at
    least 3 such neighbours is an outlier when its NCC with their median derivative is
    below 0.3, or below ``median - 4 * 1.4826 * MAD`` of all scores and below 0.8.

    Returns ``keep`` (n,) and the NCC scores (NaN where there were too few neighbours).
    """
    n = len(centroids)
    radius = max(3.0 * max_blur, 0.06 * math.hypot(*shape))
    k = min(17, n)
    dist, nb = cKDTree(centroids).query(centroids, k=k, distance_upper_bound=radius)
    dist, nb = dist[:, 1:], nb[:, 1:]  # drop self
    valid = np.isfinite(dist)
    nb = np.where(valid, nb, 0)
    dphi = np.angle(np.exp(1j * (angles[nb] - angles[:, None])))
    same = valid & (np.abs(dphi) < np.deg2rad(20))
    opposite = valid & (np.abs(dphi) > np.deg2rad(160))
    use = same | opposite
    cand = np.where(opposite[..., None], deriv[nb][..., ::-1], deriv[nb])  # (n, k-1, N)
    counts = use.sum(1)
    score = np.full(n, np.nan)
    enough = counts >= 3
    if enough.any():
        stack = np.where(use[enough, :, None], cand[enough], np.nan)
        stack = np.sort(stack, axis=1)  # NaNs last
        cnt = counts[enough]
        lo_i = (cnt - 1) // 2
        hi_i = cnt // 2
        r = np.arange(stack.shape[0])
        med = 0.5 * (stack[r, lo_i] + stack[r, hi_i])
        score[enough] = _ncc_rows(deriv[enough], med)
    keep = np.ones(n, bool)
    s = score[np.isfinite(score)]
    if s.size >= 5:
        centre = np.median(s)
        mad = 1.4826 * np.median(np.abs(s - centre))
        bad = np.isfinite(score) & ((score < _OUTLIER_FLOOR)
                                    | ((score < centre - _OUTLIER_MADS * mad) & (score < 0.8)))
        keep = ~bad
    return keep, score


_QUANTILE_ITERS = 30


def _blur_consistency(centroids, angles, deriv, offsets, shape, tau=None, rel=None,
                      slack=1.0) -> np.ndarray:
    """Keep profiles whose width is consistent with one camera-shake blur field.

    A blurred step's derivative is the PSF projection convolved with the sharp edge's
    own profile, so its variance is ``n^T Sigma(x) n`` (``Sigma`` the covariance of the
    local PSF) *plus* the sharp edge's variance, never less. For camera shake the PSF
    displacements are nearly affine in ``x`` over the image, so ``Sigma(x)`` is a
    quadratic polynomial in ``x``. We fit that field to the lower side of the measured
    variances (a quantile regression at ``tau``, by iterative reweighting: 18
    coefficients, fewer when there are few profiles) and refuse profiles wider than
    ``(1 + rel) * fit + slack`` px^2: soft or shaded scene edges, which would make the
    blur look larger than it is.

    Returns
    -------
    ndarray of bool, shape (n,)
        True where the profile is consistent.
    """
    tau = _SOFT_TAU if tau is None else tau
    rel = _SOFT_REL if rel is None else rel
    n = len(centroids)
    var = deriv @ (offsets**2)
    H, W = shape
    size = float(max(H, W))
    x = (centroids[:, 1] - (W - 1) / 2) / size
    y = (centroids[:, 0] - (H - 1) / 2) / size
    basis = [np.ones(n)]
    if n >= 30:
        basis += [x, y]
    if n >= 60:
        basis += [x * x, x * y, y * y]
    B = np.stack(basis, -1)
    c, s = np.cos(angles), np.sin(angles)
    F = np.concatenate([B * (c * c)[:, None], B * (2 * c * s)[:, None], B * (s * s)[:, None]],
                       1)
    scale = max(float(np.median(var)), 1e-3)
    ridge = 1e-6 * np.eye(F.shape[1]) * n
    w = np.ones(n)
    pred = np.full(n, scale)
    for _ in range(_QUANTILE_ITERS):
        A = F.T @ (F * w[:, None]) + ridge
        try:
            theta = np.linalg.solve(A, F.T @ (w * var))
        except np.linalg.LinAlgError:  # pragma: no cover - degenerate orientations
            break
        pred = F @ theta
        r = var - pred
        # iteratively reweighted least squares for the check loss of quantile tau
        w = np.where(r > 0, tau, 1.0 - tau) / np.maximum(np.abs(r), 0.02 * scale)
    return var <= (1.0 + rel) * np.maximum(pred, 0.0) + slack


def _ncc_rows(a, b) -> np.ndarray:
    a = a - a.mean(1, keepdims=True)
    b = b - b.mean(1, keepdims=True)
    den = np.sqrt((a * a).sum(1) * (b * b).sum(1))
    return np.where(den > 0, (a * b).sum(1) / np.where(den > 0, den, 1.0), 0.0)


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


def _count_reasons(codes) -> dict:
    out = {}
    for code in np.unique(codes[codes > 0]):
        out[REASONS[int(code)]] = int((codes == code).sum())
    return out


def _summarise(counts: dict) -> str:
    top = sorted(counts.items(), key=lambda kv: -kv[1])[:3]
    return ", ".join(f"{name}: {k}" for name, k in top) or "nothing examined"


# ---------------------------------------------------------------------------------------
# manual picking
# ---------------------------------------------------------------------------------------

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
    return EdgeProfiles(prof["centroid"], prof["angle"], r2["c1"], r2["c2"], prof["alpha"],
                        prof["deriv"], offsets, quality, image_shape=img.shape,
                        max_blur=max_blur, stats=stats, curvature=r2["curvature"],
                        window=prof["window"])


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


# ---------------------------------------------------------------------------------------
# small utilities
# ---------------------------------------------------------------------------------------

def _point(p, name) -> np.ndarray:
    try:
        arr = np.asarray(p, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be two numbers (row, col); got {p!r}") from None
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be two finite numbers (row, col); got {p!r}")
    return arr


def _matrix(values, n, N, name) -> np.ndarray:
    if n == 0:
        return np.zeros((0, N))
    arr = np.asarray(values, dtype=float)
    if arr.shape != (n, N):
        raise ValueError(f"{name} must have shape ({n}, {N}) (profiles x offsets); "
                         f"got {arr.shape}")
    return arr


def _vector(values, n, name) -> np.ndarray:
    arr = np.asarray(values, dtype=float).reshape(-1)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},) to match centroids; got {arr.shape}")
    return arr


def _wrap(angle) -> np.ndarray:
    return np.angle(np.exp(1j * np.asarray(angle, float)))


def _first_line(err: Exception) -> str:
    return str(err).splitlines()[0] if str(err) else type(err).__name__


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return obj
