"""The edge-profile set: a container of centroid-aligned profiles, its file format, plots.

:class:`EdgeProfiles` holds what :func:`~napari_edgecme.core.edges.extract_edge_profiles`
and :func:`~napari_edgecme.core.edge_picking.profile_along_line` find (paper Eqs. 1, 6,
11): centroids, normals, plateaus, the alpha mattes and their derivatives on a common
grid of offsets, a quality per profile, and the statistics of the extraction. It saves to
and loads from JSON (format ``edgecme-profiles``) and draws itself with matplotlib.
"""

from __future__ import annotations

import math

import numpy as np

from ._validation import check_positive
from .edge_confidence import confidence

__all__ = ["PROFILES_FORMAT", "PROFILES_VERSION", "EdgeProfiles"]

PROFILES_FORMAT = "edgecme-profiles"
PROFILES_VERSION = 1

#: An orientation balance (see :meth:`EdgeProfiles.coverage`) under this is reported as
#: leaving one motion direction poorly constrained.
POOR_BALANCE = 0.15


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
    measures : dict of str to array_like of shape (n,), optional
        Per-profile statistics of the validity tests, by name (those of the automatic
        extraction: :data:`~napari_edgecme.core.edge_tests.MEASURES`). Kept through
        :meth:`subset` and the profile file; :meth:`concatenate` keeps the names every
        set has.

    Notes
    -----
    ``len(profiles)`` is the number of profiles; an empty set is falsy and carries a
    ``reason``. Arrays are float64 (they are small; files round-trip exactly).
    """

    def __init__(self, centroids, normal_angle, c1, c2, profiles, derivatives, offsets,
                 quality, reason: str = "", image_shape=None, max_blur=None, stats=None,
                 curvature=None, window=None, measures=None):
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
        self.measures = {str(k): _vector(v, n, f"measures[{k!r}]")
                         for k, v in dict(measures or {}).items()}

    # -- trust and geometry ----------------------------------------------------------------
    @property
    def confidence(self) -> np.ndarray:
        """Calibrated chance that each profile is true to the local blur, (n,) in (0, 1).

        The probability that the derivative matches the true PSF projection with NCC >=
        0.8, from the profile's test measures (:mod:`~napari_edgecme.core.edge_confidence`,
        fitted and checked on the ``lai`` development set). NaN for profiles without
        measures (files written before they existed).
        """
        return confidence(self.measures, self.max_blur) if len(self) else np.zeros(0)

    def coverage(self, grid: int = 3) -> dict:
        """What the set's geometry can constrain: orientations and places.

        A profile measures the PSF only along its normal (Eq. 11), and only where it is,
        so a set on edges of one orientation says nothing about motion along them, and a
        set in one corner says little about a rotation.

        Parameters
        ----------
        grid : int
            The image is cut into ``grid x grid`` cells for the spatial coverage.

        Returns
        -------
        dict
            ``orientation_bins``: of 8 bins of normal direction (22.5 degrees each,
            modulo 180), how many hold a profile. ``orientation_balance``: the smaller
            over the larger eigenvalue of the normals' scatter ``mean(n n^T)``, in [0, 1]
            (0: all normals parallel; 1: spread evenly). ``weakest_direction_deg``: the
            image direction (degrees from the x axis, modulo 180) along which motion is
            least seen, the eigenvector of the smaller eigenvalue. ``cells``: cells
            holding a profile, of ``grid**2`` (None without ``image_shape``);
            ``cell_counts``: profiles per cell, row by row.
        """
        out = {"profiles": len(self), "orientation_bins": 0, "orientation_balance": 0.0,
               "weakest_direction_deg": None, "cells": None, "cell_counts": None,
               "grid": int(grid)}
        if len(self) == 0:
            return out
        phi = np.mod(self.normal_angle, np.pi)
        out["orientation_bins"] = int(np.unique(np.minimum((phi / (np.pi / 8)).astype(int),
                                                           7)).size)
        n = np.stack([np.cos(phi), np.sin(phi)], -1)
        evals, evecs = np.linalg.eigh(n.T @ n / len(n))
        out["orientation_balance"] = float(evals[0] / max(evals[1], 1e-12))
        weak = evecs[:, 0]
        out["weakest_direction_deg"] = float(np.degrees(np.arctan2(weak[1], weak[0])) % 180.0)
        if self.image_shape is not None:
            H, W = self.image_shape
            r = np.clip((self.centroids[:, 0] / H * grid).astype(int), 0, grid - 1)
            c = np.clip((self.centroids[:, 1] / W * grid).astype(int), 0, grid - 1)
            counts = np.bincount(r * grid + c, minlength=grid * grid)
            out["cells"] = int(np.count_nonzero(counts))
            out["cell_counts"] = counts.reshape(grid, grid).tolist()
        return out

    def coverage_summary(self) -> str:
        """One line on :meth:`coverage`, e.g. for the CLI and the widget."""
        cov = self.coverage()
        if not cov["profiles"]:
            return "no profiles"
        text = (f"normals in {cov['orientation_bins']}/8 orientations "
                f"(balance {cov['orientation_balance']:.2f})")
        if cov["cells"] is not None:
            text += f", {cov['cells']}/{cov['grid'] ** 2} image cells"
        if cov["orientation_balance"] < POOR_BALANCE:
            text += (f"; motion along {cov['weakest_direction_deg']:.0f} deg is poorly "
                     "constrained")
        return text

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
                            window=self.window[idx],
                            measures={k: v[idx] for k, v in self.measures.items()})

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
        full = [it for it in items if len(it)]
        common = set.intersection(*(set(it.measures) for it in full))
        measures = {k: np.concatenate([it.measures[k] for it in full])
                    for k in sorted(common)}
        return cls(cat[0], cat[1], cat[2], cat[3], cat[4], cat[5], offsets, cat[6],
                   image_shape=shape, max_blur=blur, curvature=cat[7], window=cat[8],
                   measures=measures)

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
                            curvature=self.curvature / factor, window=self.window * factor,
                            measures=self.measures)

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
            "measures": {k: [None if not np.isfinite(x) else float(x) for x in v]
                         for k, v in self.measures.items()},
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
        measures = data.get("measures")
        if measures is not None and n > 0:
            if not isinstance(measures, dict):
                raise ValueError("profile file entry 'measures' must be an object")
            parsed = {}
            for key, values in measures.items():
                try:
                    arr = np.array([np.nan if v is None else v for v in values], dtype=float)
                except (TypeError, ValueError):
                    raise ValueError(f"profile file measure {key!r} is not a numeric "
                                     "array") from None
                if arr.shape != (n,):
                    raise ValueError(f"profile file measure {key!r} must hold n={n} "
                                     f"numbers; got shape {arr.shape}")
                parsed[str(key)] = arr
            optional["measures"] = parsed
        if n == 0:
            return cls.empty(str(data.get("reason") or "no edge profiles"), arrays["offsets"],
                             shape, blur, stats)
        return cls(arrays["centroids"], arrays["normal_angle"], arrays["c1"], arrays["c2"],
                   arrays["profiles"], arrays["derivatives"], arrays["offsets"],
                   arrays["quality"], image_shape=shape, max_blur=blur, stats=stats,
                   **optional)

    def save(self, path) -> None:
        """Write the profiles as JSON, atomically (temporary file + rename)."""
        from .io import write_json

        write_json(path, self.to_dict())

    @classmethod
    def load(cls, path) -> EdgeProfiles:
        """Read a profile file; any problem raises one ``ValueError`` line that names it."""
        from .io import read_json

        return read_json(path, "profile file", cls.from_dict)

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
# small utilities
# ---------------------------------------------------------------------------------------

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
