"""``CameraMotion``: a motion density function (MDF) over camera poses, and its PSFs.

A camera motion is a pose model, the intrinsics of the image it blurs, a set of
poses and non-negative weights that sum to one (the MDF, paper Eq. 8). The local
PSF at an image point is the MDF pushed through the displacements ``u = H_p x - x``
(Eq. 9); :func:`psf_matrix` builds that push-forward as a sparse matrix, shared by
:meth:`CameraMotion.psf` and the filter-flow operators.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from ._validation import check_choice, check_positive, first_line
from .camera import (
    MODELS,
    Intrinsics,
    check_poses,
    compose_homographies,
    displacements,
    homographies,
    invert_homographies,
    poses_from_homographies,
)

__all__ = ["MOTION_FORMAT", "MOTION_VERSION", "CameraMotion", "psf_matrix", "psf_size_for"]

MOTION_FORMAT = "edgecme-motion"
MOTION_VERSION = 1


def psf_size_for(disp: np.ndarray) -> int:
    """Smallest odd PSF size holding displacements ``disp`` (..., 2) with bilinear splatting."""
    reach = float(np.max(np.abs(disp))) if disp.size else 0.0
    return 2 * math.ceil(reach - 1e-9) + 1


def psf_matrix(disp: np.ndarray, size: int, dtype=np.float64) -> sp.csr_matrix:
    """The sparse push-forward from pose weights to local PSFs (Eq. 9).

    Parameters
    ----------
    disp : ndarray of shape (n_points, n_poses, 2)
        Displacements ``(dx, dy)`` of each point under each pose
        (:func:`~napari_edgecme.core.camera.displacements`).
    size : int
        Odd PSF side; the centre pixel is zero displacement, the row axis is ``dy``.
    dtype : dtype
        Of the matrix entries.

    Returns
    -------
    scipy.sparse.csr_matrix of shape (n_points * size * size, n_poses)
        ``(B @ w).reshape(n_points, size, size)`` are the PSFs of weights ``w``, each
        splatted bilinearly so that it sums to ``w.sum()``.

    Raises
    ------
    ValueError
        If ``size`` is too small to hold every displacement.
    """
    n_points, n_poses, _ = disp.shape
    half = (size - 1) // 2
    need = psf_size_for(disp)
    if size % 2 == 0 or size < need:
        raise ValueError(f"PSF size must be odd and at least {need} to hold this motion; "
                         f"got {size}")
    col = disp[..., 0] + half
    row = disp[..., 1] + half
    c0 = np.floor(col).astype(np.int64)
    r0 = np.floor(row).astype(np.int64)
    fc, fr = col - c0, row - r0
    base = np.arange(n_points, dtype=np.int64)[:, None] * (size * size)
    pose = np.broadcast_to(np.arange(n_poses, dtype=np.int64)[None, :], c0.shape)
    rows, cols, vals = [], [], []
    for dr, dc, wgt in ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc),
                        (1, 0, fr * (1 - fc)), (1, 1, fr * fc)):
        rr, cc = r0 + dr, c0 + dc
        keep = (wgt > 1e-9) & (rr >= 0) & (rr < size) & (cc >= 0) & (cc < size)
        rows.append((base + rr * size + cc)[keep])
        cols.append(pose[keep])
        vals.append(wgt[keep])
    mat = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                        shape=(n_points * size * size, n_poses), dtype=dtype)
    return mat.tocsr()


class CameraMotion:
    """A camera motion: pose model, intrinsics, poses and MDF weights (paper Eq. 8).

    Parameters
    ----------
    model : {"translation", "inplane", "rotation"}
        Pose model (see :mod:`napari_edgecme.core.camera`).
    intrinsics : Intrinsics
        Of the image this motion blurs.
    poses : array_like of shape (n, d)
        Camera poses; ``d`` is 2 for ``translation`` and 3 otherwise.
    weights : array_like of shape (n,)
        Non-negative time fractions; normalised to sum to one.

    Examples
    --------
    >>> from napari_edgecme import CameraMotion, Intrinsics
    >>> cam = Intrinsics.from_image_shape((64, 64))
    >>> m = CameraMotion.from_trajectory([[0, 0], [2, 0]], "translation", cam)
    >>> m.psf([[32, 32]], size=5)[0, 2]
    array([0. , 0. , 0.5, 0. , 0.5])
    """

    def __init__(self, model: str, intrinsics: Intrinsics, poses, weights):
        self.model = check_choice(model, "model", MODELS)
        if not isinstance(intrinsics, Intrinsics):
            raise ValueError(f"intrinsics must be an Intrinsics; got {type(intrinsics).__name__}")
        self.intrinsics = intrinsics
        poses = check_poses(poses, model)
        w = np.asarray(weights, dtype=float)
        if w.ndim != 1 or w.shape[0] != poses.shape[0]:
            raise ValueError(
                f"weights must have shape ({poses.shape[0]},) to match poses; got shape {w.shape}"
            )
        if not np.all(np.isfinite(w)):
            raise ValueError("weights must be finite; got NaN or inf")
        if np.any(w < 0):
            raise ValueError(f"weights must be >= 0; got minimum {w.min():g}")
        with np.errstate(over="ignore"):
            total = w.sum()
        if not total > 0:
            raise ValueError("weights must not all be zero")
        if not np.isfinite(total):  # finite weights whose sum overflows (e.g. 1e308 twice)
            w = w / w.max()
            total = w.sum()
        self.poses = poses
        # normalise, but leave weights that already sum to one bit-exact (motion files
        # round-trip exactly)
        self.weights = w / total if abs(total - 1.0) > 1e-12 else w.copy()
        self.poses.setflags(write=False)
        self.weights.setflags(write=False)

    # -- construction ---------------------------------------------------------------
    @classmethod
    def from_trajectory(cls, poses, model: str, intrinsics: Intrinsics) -> CameraMotion:
        """A motion that spends equal time at each of ``poses`` (a gyroscope or true path)."""
        poses = check_poses(poses, check_choice(model, "model", MODELS))
        return cls(model, intrinsics, poses, np.ones(len(poses)))

    @classmethod
    def identity(cls, model: str, intrinsics: Intrinsics) -> CameraMotion:
        """The motion of a camera that did not move (every PSF a delta)."""
        d = 2 if model == "translation" else 3
        return cls(model, intrinsics, np.zeros((1, d)), [1.0])

    # -- geometry ----------------------------------------------------------------------
    @property
    def n_poses(self) -> int:
        return len(self.weights)

    @property
    def image_shape(self) -> tuple[int, int]:
        return self.intrinsics.image_shape

    def homographies(self) -> np.ndarray:
        """Homographies of the poses, shape (n, 3, 3)."""
        return homographies(self.model, self.intrinsics, self.poses)

    def displacements(self, points) -> np.ndarray:
        """Displacements ``(dx, dy)`` of ``points`` (n, 2) ``(row, col)``: (n, n_poses, 2)."""
        return displacements(self.model, self.intrinsics, self.poses, _check_points(points))

    def max_displacement(self, points=None) -> float:
        """Largest displacement (px) of any pose from the centroid of its local PSF.

        A radius: the estimator's collapse test (``estimate.COLLAPSE_EXTENT``) is stated in
        it. Evaluated at ``points`` (n, 2) or, by default, over a 5x5 grid covering the image.
        """
        if points is None:
            points = _grid_points(self.image_shape, (5, 5))
        d = self.displacements(points)
        centre = np.einsum("npk,p->nk", d, self.weights)
        return float(np.max(np.hypot(*(d - centre[:, None]).transpose(2, 0, 1))))

    def mass_radius(self, share: float = 0.8, points=None) -> float:
        """Radius (px) about the local PSF's centroid that holds ``share`` of its weight.

        The largest such radius over the points. Unlike :meth:`max_displacement`, a faint
        pose far from the rest does not enlarge it: a delta carrying 90 % of the weight
        with a stray pose 9 px away has a radius of 0.9 px at ``share = 0.8`` (the
        centroid's offset from the delta) where :meth:`max_displacement` reads 8.1 px.

        Parameters
        ----------
        share : float, default 0.8
            Share of the weight, in (0, 1].
        points : array_like of shape (n, 2), optional
            ``(row, col)`` points; default a 5x5 grid covering the image.

        Returns
        -------
        float
            In pixels of :attr:`image_shape`.

        Examples
        --------
        >>> from napari_edgecme import CameraMotion, Intrinsics
        >>> cam = Intrinsics.from_image_shape((64, 64))
        >>> m = CameraMotion("translation", cam, [[0, 0], [9, 0]], [0.9, 0.1])
        >>> round(m.mass_radius(), 2), round(m.max_displacement(), 2)
        (0.9, 8.1)
        """
        if not 0 < share <= 1:
            raise ValueError(f"share must be in (0, 1], got {share!r}")
        if points is None:
            points = _grid_points(self.image_shape, (5, 5))
        d = self.displacements(points)
        w = self.weights / self.weights.sum()
        centre = np.einsum("npk,p->nk", d, w)
        radius = np.hypot(*(d - centre[:, None]).transpose(2, 0, 1))  # (n, n_poses)
        order = np.argsort(radius, axis=1)
        held = np.cumsum(w[order], axis=1)
        # the first pose (nearest first) at which the weight held reaches the share
        first = np.argmax(held >= share * (1 - 1e-9), axis=1)
        return float(np.max(np.take_along_axis(radius, order, 1)[np.arange(len(d)), first]))

    def blur_extent(self, points=None) -> float:
        """Blur extent (px): the longest side of the support of the local PSFs, over the frame.

        The one length this package reports to people as "blur extent" (command line,
        widgets, batch reports, benchmark sheets), and the same length that ``synth
        --extent`` / :func:`~napari_edgecme.core.synth.random_trajectory` ask for and that
        ``max_blur`` bounds.

        At each point, the displacements ``u = H_p x - x`` of the poses of non-zero
        weight span a bounding box; its longest side, ``max(width, height)``, is the
        distance between the extreme displacements along ``x`` or ``y`` (a distance, not a
        count of pixels: one pose gives 0, a uniform horizontal shift over ``L`` px gives
        ``L``). The blur extent is the largest such side over the points. The weights do
        not enter beyond their support, so a faint tail counts in full.

        Parameters
        ----------
        points : array_like of shape (n, 2), optional
            ``(row, col)`` points to measure at. Default: a 5x5 grid spanning the frame
            edge to edge (corners, edge midpoints and centre included), where a camera
            rotation's blur is longest.

        Returns
        -------
        float
            In pixels of :attr:`image_shape`.

        See Also
        --------
        max_displacement : a radius about the PSF centroid, in which the estimator's
            collapse test is stated (not this length).

        Examples
        --------
        >>> from napari_edgecme import CameraMotion, Intrinsics
        >>> cam = Intrinsics.from_image_shape((64, 64))
        >>> CameraMotion.from_trajectory([[0, 0], [5, 0], [10, 2]], "translation",
        ...                              cam).blur_extent()
        10.0
        """
        if points is None:
            points = _frame_points(self.image_shape, (5, 5))
        d = self.displacements(points)[:, self.weights > 0]
        return float(np.max(np.ptp(d, axis=1)))

    def psf_size(self, points=None) -> int:
        """The PSF side that holds this motion at ``points`` (default: over the whole image)."""
        if points is None:
            points = _grid_points(self.image_shape, (9, 9))
        return psf_size_for(self.displacements(points))

    def psf(self, points, size: int | None = None) -> np.ndarray:
        """Local PSFs at image points (Eq. 9).

        Parameters
        ----------
        points : array_like of shape (n, 2)
            Points as ``(row, col)``.
        size : int, optional
            Odd PSF side. Default: the smallest that holds the motion at these points.

        Returns
        -------
        ndarray of shape (n, size, size)
            Centre pixel = zero displacement, row axis = y displacement; bilinear
            splatting; each PSF sums to one.
        """
        pts = _check_points(points)
        disp = displacements(self.model, self.intrinsics, self.poses, pts)
        if size is None:
            size = psf_size_for(disp)
        size = check_positive(size, "size", integer=True)
        B = psf_matrix(disp, size)
        return (B @ self.weights).reshape(len(pts), size, size)

    def psf_field(self, grid=(5, 5), size: int | None = None, magnify: int | None = None
                  ) -> np.ndarray:
        """Local PSFs on a grid of points, drawn into one image aligned with the blurred image.

        Parameters
        ----------
        grid : tuple of int
            ``(rows, cols)`` of PSF sample points, evenly spread over the image.
        size : int, optional
            PSF side (default: enough for the whole image).
        magnify : int, optional
            Nearest-neighbour zoom of each PSF (default: as large as fits its cell).

        Returns
        -------
        ndarray of shape image_shape, float32
            Each PSF scaled to peak 1 and centred on its sample point; zero elsewhere.
        """
        grid = tuple(int(g) for g in grid)
        if len(grid) != 2 or min(grid) < 1:
            raise ValueError(f"grid must be two positive integers (rows, cols); got {grid!r}")
        rows, cols = self.image_shape
        points = _grid_points(self.image_shape, grid)
        if size is None:
            size = self.psf_size(points)
        psfs = self.psf(points, size)
        cell = min(rows / grid[0], cols / grid[1])
        if magnify is None:
            magnify = max(1, int(0.9 * cell // size))
        magnify = check_positive(magnify, "magnify", integer=True)
        out = np.zeros((rows, cols), np.float32)
        for (r, c), k in zip(points, psfs, strict=True):
            tile = np.kron(k / max(k.max(), 1e-12), np.ones((magnify, magnify)))
            h = tile.shape[0] // 2
            r0, c0 = round(r) - h, round(c) - h
            rs0, cs0 = max(r0, 0), max(c0, 0)
            rs1, cs1 = min(r0 + tile.shape[0], rows), min(c0 + tile.shape[1], cols)
            if rs1 > rs0 and cs1 > cs0:
                out[rs0:rs1, cs0:cs1] = np.maximum(
                    out[rs0:rs1, cs0:cs1], tile[rs0 - r0:rs1 - r0, cs0 - c0:cs1 - c0])
        return out

    # -- transformations -----------------------------------------------------------
    def centroid_pose(self) -> np.ndarray:
        """The weighted mean pose (the MDF's centroid, paper claim 1), shape (d,)."""
        return self.weights @ self.poses

    def recentred(self) -> CameraMotion:
        """The same blur up to a homography, with the centroid pose at the identity (claim 2).

        Every pose ``H_j`` becomes ``H_j (H_c)^-1`` with ``H_c`` the centroid pose.
        """
        Hc = homographies(self.model, self.intrinsics, self.centroid_pose()[None])[0]
        H = compose_homographies(self.homographies(), invert_homographies(Hc))
        poses = poses_from_homographies(self.model, self.intrinsics, H)
        return CameraMotion(self.model, self.intrinsics, poses, self.weights)

    def rescale(self, image_shape) -> CameraMotion:
        """This motion for the same camera at another resolution.

        E.g. a motion estimated on a downscaled copy, applied to the full image.

        Parameters
        ----------
        image_shape : tuple of int
            ``(rows, cols)`` of the target image (a trailing channel axis is ignored);
            its aspect ratio must match.

        Returns
        -------
        CameraMotion
            Rotation angles are unchanged; translations scale with the image.
        """
        target = tuple(int(s) for s in tuple(image_shape)[:2])
        if target == self.image_shape:
            return self
        intr = self.intrinsics.rescaled(target)
        poses = self.poses.copy()
        if self.model in ("translation", "inplane"):
            r0, c0 = self.image_shape
            poses[:, 0] *= target[1] / c0
            poses[:, 1] *= target[0] / r0
        return CameraMotion(self.model, intr, poses, self.weights)

    def cropped(self, offset, image_shape) -> CameraMotion:
        """This motion for a crop of its image: the same camera, the principal point moved.

        A crop is not a resized copy: every pixel keeps its size and its blur, so the
        focal length and the poses stay and only the principal point moves by the
        crop's offset. The PSF at crop pixel ``p`` is the PSF at image pixel
        ``p + offset``.

        Parameters
        ----------
        offset : tuple of float
            ``(row, col)`` of the crop's first pixel in this motion's image.
        image_shape : tuple of int
            ``(rows, cols)`` of the crop (a trailing channel axis is ignored).

        Returns
        -------
        CameraMotion

        Raises
        ------
        ValueError
            If the crop does not lie inside this motion's image.

        Examples
        --------
        >>> from napari_edgecme import CameraMotion, Intrinsics
        >>> m = CameraMotion.from_trajectory([[0, 0, 0], [0, 0, 0.01]], "inplane",
        ...                                  Intrinsics.from_image_shape((100, 200)))
        >>> crop = m.cropped((40, 150), (20, 30))
        >>> crop.intrinsics.principal_point
        (-50.5, 9.5)
        >>> bool(np.allclose(crop.psf([[5, 7]], 9), m.psf([[45, 157]], 9)))
        True
        """
        off = np.asarray(offset, dtype=float)
        if off.shape != (2,) or not np.all(np.isfinite(off)):
            raise ValueError(f"offset must be two finite numbers (row, col); got {offset!r}")
        shape = tuple(int(s) for s in tuple(image_shape)[:2])
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"image_shape must be two positive integers; got {image_shape!r}")
        rows, cols = self.image_shape
        tol = 1e-6
        if (off.min() < -tol or off[0] + shape[0] > rows + tol
                or off[1] + shape[1] > cols + tol):
            raise ValueError(
                f"a {shape[0]}x{shape[1]} crop at (row {off[0]:g}, col {off[1]:g}) does not "
                f"lie inside the motion's {rows}x{cols} image")
        if shape == self.image_shape and not off.any():
            return self
        cx, cy = self.intrinsics.principal_point
        intr = Intrinsics(self.intrinsics.focal_px, (cx - off[1], cy - off[0]), shape)
        return CameraMotion(self.model, intr, self.poses, self.weights)

    def compact(self, threshold: float = 0.0) -> CameraMotion:
        """Drop poses whose weight is at most ``threshold`` times the largest weight."""
        keep = self.weights > threshold * self.weights.max()
        return CameraMotion(self.model, self.intrinsics, self.poses[keep], self.weights[keep])

    # -- files ---------------------------------------------------------------------------
    def to_dict(self, *, estimated_by: str | None = None,
                profile_misfit: float | None = None) -> dict:
        """The motion as the JSON-ready dict of the motion file (only non-zero weights).

        Parameters
        ----------
        estimated_by : {"ep", "xu", "xu+ep"}, optional
            The estimator that made the motion (``estimate.info.method``), kept under that
            key so that a motion read back is restored as :func:`~.deblur.deblur`
            restores an estimate of its method (:func:`~.deblur.restoring_params`).
            :meth:`from_dict` and :meth:`load` ignore the key; :meth:`load_estimate`
            reads it.
        profile_misfit : float, optional
            ``estimate.info.profile_misfit``, kept for the same reason: an EpAlone
            motion's restoration depends on it (:func:`~.deblur.ep_prior_factor`). For
            EpAlone, the share of the edge profiles' energy the motion leaves
            unexplained; for Xu+Ep, that of the EpAlone fit of its gate (not used).

        Returns
        -------
        dict
        """
        keep = self.weights > 0
        out = {
            "format": MOTION_FORMAT,
            "version": MOTION_VERSION,
            "model": self.model,
            "intrinsics": self.intrinsics.to_dict(),
            "poses": self.poses[keep].tolist(),
            "weights": self.weights[keep].tolist(),
        }
        if estimated_by is not None:
            out["estimated_by"] = _check_estimator(estimated_by)
        if profile_misfit is not None:
            out["profile_misfit"] = _check_misfit(profile_misfit)
        return out

    @classmethod
    def from_dict(cls, data) -> CameraMotion:
        """Build a motion from the dict of a motion file; ``ValueError`` names what is wrong."""
        if not isinstance(data, dict):
            raise ValueError("motion file must hold a JSON object")
        if data.get("format") != MOTION_FORMAT:
            raise ValueError(
                f"not an edgecme motion file: 'format' is {data.get('format')!r}, "
                f"expected {MOTION_FORMAT!r}"
            )
        version = data.get("version")
        if isinstance(version, bool) or version != MOTION_VERSION:
            raise ValueError(
                f"unsupported motion file version {version!r}; "
                f"this program reads version {MOTION_VERSION}"
            )
        for key in ("model", "intrinsics", "poses", "weights"):
            if key not in data:
                raise ValueError(f"motion file has no {key!r} entry")
        intr = data["intrinsics"]
        if not isinstance(intr, dict) or not {"focal_px", "principal_point",
                                              "image_shape"} <= set(intr):
            raise ValueError(
                "motion file 'intrinsics' must hold focal_px, principal_point and image_shape"
            )
        try:
            intrinsics = Intrinsics(intr["focal_px"], tuple(intr["principal_point"]),
                                    tuple(intr["image_shape"]))
            poses = np.asarray(data["poses"], dtype=float)
            weights = np.asarray(data["weights"], dtype=float)
        except (TypeError, ValueError, OverflowError) as err:
            # OverflowError: an integer too large for a float (JSON allows 1000 digits)
            raise ValueError(f"motion file is malformed: {first_line(err)}") from None
        model = data["model"]
        if poses.size == 0:
            raise ValueError("motion file has no poses")
        return cls(model, intrinsics, poses, weights)

    def save(self, path, *, estimated_by: str | None = None,
             profile_misfit: float | None = None) -> None:
        """Write the motion as JSON (the ``edgecme-motion`` format), atomically.

        Parameters
        ----------
        path : path-like
        estimated_by : {"ep", "xu", "xu+ep"}, optional
            The estimator that made the motion (:meth:`to_dict`).
        profile_misfit : float, optional
            Its edge profiles' misfit (:meth:`to_dict`).
        """
        from .io import write_json

        write_json(path, self.to_dict(estimated_by=estimated_by,
                                      profile_misfit=profile_misfit), indent=1)

    @classmethod
    def load(cls, path) -> CameraMotion:
        """Read a motion file; any problem raises one ``ValueError`` line that names it.

        The estimator's name a file may carry (``estimated_by``) is not read: see
        :meth:`load_estimate`.
        """
        from .io import read_json

        return read_json(path, "motion file", cls.from_dict)

    @classmethod
    def load_estimate(cls, path) -> tuple[CameraMotion, str | None, float | None]:
        """Read a motion file, the name of the estimator that made it and its misfit.

        Parameters
        ----------
        path : path-like

        Returns
        -------
        motion : CameraMotion
        estimated_by : {"ep", "xu", "xu+ep"} or None
            None when the file names no estimator (a ground truth, a trajectory, a file
            written before the key existed, or ``null``).
        profile_misfit : float or None
            The edge profiles' misfit the file records (:meth:`to_dict`), or None.

        Raises
        ------
        ValueError
            One line: the motion is malformed (as :meth:`load`), or the file names an
            estimator this program does not know or a misfit that is not a finite
            number >= 0 -- either would steer the restoration, so neither is guessed.
        """
        from .io import read_json

        def parse(data):
            motion = cls.from_dict(data)
            by, misfit = data.get("estimated_by"), data.get("profile_misfit")
            return (motion, None if by is None else _check_estimator(by, "motion file's "),
                    None if misfit is None else _check_misfit(misfit, "motion file's "))

        return read_json(path, "motion file", parse)

    # -- comparison ------------------------------------------------------------------------
    def __eq__(self, other) -> bool:
        if not isinstance(other, CameraMotion):
            return NotImplemented
        return (self.model == other.model and self.intrinsics == other.intrinsics
                and np.array_equal(self.poses, other.poses)
                and np.array_equal(self.weights, other.weights))

    __hash__ = None

    def __repr__(self) -> str:
        return (f"CameraMotion(model={self.model!r}, n_poses={self.n_poses}, "
                f"image_shape={self.image_shape}, focal_px={self.intrinsics.focal_px:.1f})")




def _check_estimator(name, where: str = "") -> str:
    """``name`` if it is an estimation method (``estimate.METHODS``, imported here: the
    estimator imports this module), else the engine's one ``ValueError`` line."""
    from .estimate import METHODS

    return check_choice(name, f"{where}estimated_by", METHODS)


def _check_misfit(value, where: str = "") -> float:
    """``value`` as a float if it is a finite number >= 0 (a share of the profiles'
    energy, 1 or more for profiles a motion does not explain at all), else one
    ``ValueError`` line."""
    number = isinstance(value, (int, float, np.floating)) and not isinstance(value, bool)
    if not (number and math.isfinite(float(value)) and float(value) >= 0.0):
        raise ValueError(f"{where}profile_misfit must be a finite number >= 0; "
                         f"got {value!r}")
    return float(value)


def _check_points(points) -> np.ndarray:
    pts = np.asarray(points, dtype=float)
    if pts.ndim == 1 and pts.shape == (2,):
        pts = pts[None]
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"points must have shape (n, 2) as (row, col); got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("points must be finite")
    return pts


def _frame_points(shape, grid) -> np.ndarray:
    """A ``grid`` of points spanning an image of ``shape`` edge to edge (corners included)."""
    rows, cols = shape
    r = np.linspace(0.0, rows - 1.0, grid[0])
    c = np.linspace(0.0, cols - 1.0, grid[1])
    rr, cc = np.meshgrid(r, c, indexing="ij")
    return np.stack([rr.ravel(), cc.ravel()], -1)


def _grid_points(shape, grid) -> np.ndarray:
    """Centres (row, col) of a ``grid`` of equal cells over an image of ``shape``: (r*c, 2)."""
    rows, cols = shape
    r = (np.arange(grid[0]) + 0.5) * rows / grid[0] - 0.5
    c = (np.arange(grid[1]) + 0.5) * cols / grid[1] - 0.5
    rr, cc = np.meshgrid(r, c, indexing="ij")
    return np.stack([rr.ravel(), cc.ravel()], -1)
