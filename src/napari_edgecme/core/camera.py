"""Camera intrinsics, the three pose models, their homographies, and pose grids.

Conventions (fixed once; motion files and tests depend on them):

* pixel coordinates are homogeneous ``x = (col, row, 1)``; pixel centres are
  integers; the principal point defaults to the image centre
  ``((W - 1) / 2, (H - 1) / 2)``;
* a blurred image is ``g(x) = sum_p w_p f(H_p^-1 x)`` (paper Eq. 8): pose ``p`` moves
  the sharp point ``x`` to ``H_p x`` in the blurred image, so the local PSF at ``x``
  has a delta at ``u = H_p x - x`` (Eq. 9);
* ``"rotation"``: pose ``(theta_x, theta_y, theta_z)`` in radians,
  ``H = K expm([theta]_x) K^-1`` (Rodrigues), ``K = [[f, 0, cx], [0, f, cy], [0, 0, 1]]``;
* ``"inplane"``: pose ``(tx, ty, theta_z)``, ``H = T(tx, ty) Rz(theta_z)`` with ``Rz``
  the rotation ``[[cos, -sin], [sin, cos]]`` in ``(x, y)`` about the principal point;
* ``"translation"``: pose ``(tx, ty)`` in pixels, ``H = T(tx, ty)``.

The 3x3 algebra here (products, inverses, determinants, point warps) is spelled out as
elementwise arithmetic in a fixed order, not handed to BLAS or LAPACK: OpenBLAS picks a
CPU kernel that rounds differently in the last bits, and the alternating estimators can
amplify such a difference into a different estimate. Written out, the geometry is the
same bits under every kernel (``tests/core/test_camera.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ._validation import check_choice, check_positive

__all__ = [
    "DEFAULT_FOCAL_35MM",
    "GRID_REACH",
    "MODELS",
    "Intrinsics",
    "PoseGrid",
    "compose_homographies",
    "displacements",
    "homographies",
    "invert_homographies",
    "pose_grid",
    "poses_from_homographies",
    "warp_points",
]

#: The pose models, by name (the names are API and appear in motion files).
MODELS = ("translation", "inplane", "rotation")

#: Reach of the pose grid on each side of the identity, as a fraction of the max blur. The
#: estimators keep the MDF's centroid pose at the identity (claims 1-2); half the max blur
#: holds a path symmetric about its centroid, while real shakes reach up to 0.58 of their
#: extent from it (``benchmarks/bench_grid_reach.py``), so a max blur equal to the extent
#: can clip them. A wider grid (0.58) was measured on all three estimators and left the
#: suites' means where the BLAS kernel alone moves them (``lai`` Xu+Ep +0.00, ``levin``
#: +0.06 dB); an earlier loss on ``lai`` was one case that flips basin with the kernel
#: (``benchmarks/results/grid-reach.md``).
GRID_REACH = 0.5

#: 35 mm-equivalent focal length (mm) assumed when a photo carries no EXIF focal
#: length: between a phone's wide lens (26 mm) and a "normal" lens (50 mm).
DEFAULT_FOCAL_35MM = 35.0

_N_PARAMS = {"translation": 2, "inplane": 3, "rotation": 3}
_PARAM_NAMES = {
    "translation": ("tx", "ty"),
    "inplane": ("tx", "ty", "theta_z"),
    "rotation": ("theta_x", "theta_y", "theta_z"),
}


def n_params(model: str) -> int:
    """Number of pose parameters of ``model``."""
    return _N_PARAMS[check_choice(model, "model", MODELS)]


def param_names(model: str) -> tuple[str, ...]:
    """Names of the pose parameters of ``model``, in order."""
    return _PARAM_NAMES[check_choice(model, "model", MODELS)]


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of the camera that took an image.

    Parameters
    ----------
    focal_px : float
        Focal length in pixels.
    principal_point : tuple of float
        ``(cx, cy)`` in pixels (column, row).
    image_shape : tuple of int
        ``(rows, cols)`` of the image these intrinsics describe.
    """

    focal_px: float
    principal_point: tuple[float, float]
    image_shape: tuple[int, int]
    _K: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        f = check_positive(self.focal_px, "focal_px")
        shape = tuple(self.image_shape)
        if len(shape) != 2 or any(
            isinstance(s, bool) or not float(s).is_integer() or s < 1 for s in shape
        ):
            raise ValueError(
                f"image_shape must be two positive integers (rows, cols); got {self.image_shape!r}"
            )
        pp = np.asarray(self.principal_point, dtype=float)
        if pp.shape != (2,) or not np.all(np.isfinite(pp)):
            raise ValueError(
                f"principal_point must be two finite numbers (cx, cy); got {self.principal_point!r}"
            )
        object.__setattr__(self, "focal_px", f)
        object.__setattr__(self, "image_shape", (int(shape[0]), int(shape[1])))
        object.__setattr__(self, "principal_point", (float(pp[0]), float(pp[1])))
        K = np.array([[f, 0.0, pp[0]], [0.0, f, pp[1]], [0.0, 0.0, 1.0]])
        K.setflags(write=False)
        object.__setattr__(self, "_K", K)

    @classmethod
    def from_image_shape(cls, image_shape, focal_px=None, focal_35mm=None) -> Intrinsics:
        """Intrinsics for an image of ``image_shape`` with the principal point at its centre.

        Parameters
        ----------
        image_shape : tuple of int
            ``(rows, cols)`` (a trailing channel axis is ignored).
        focal_px : float, optional
            Focal length in pixels; wins over everything else.
        focal_35mm : float, optional
            35 mm-equivalent focal length (EXIF ``FocalLengthIn35mmFilm``), converted as
            ``f = f35 / 36 * max(rows, cols)``. Defaults to :data:`DEFAULT_FOCAL_35MM`.
        """
        rows, cols = (int(s) for s in tuple(image_shape)[:2])
        if focal_px is None:
            f35 = DEFAULT_FOCAL_35MM if focal_35mm is None else check_positive(
                focal_35mm, "focal_35mm")
            focal_px = f35 / 36.0 * max(rows, cols)
        return cls(focal_px, ((cols - 1) / 2.0, (rows - 1) / 2.0), (rows, cols))

    @property
    def K(self) -> np.ndarray:
        """Calibration matrix, shape (3, 3)."""
        return self._K

    @property
    def corners(self) -> np.ndarray:
        """Image corners as ``(x, y)``, shape (4, 2)."""
        rows, cols = self.image_shape
        return np.array([[0, 0], [cols - 1, 0], [0, rows - 1], [cols - 1, rows - 1]], float)

    @property
    def max_radius(self) -> float:
        """Distance (px) from the principal point to the farthest image corner."""
        return float(np.max(np.hypot(*(self.corners - self.principal_point).T)))

    def rescaled(self, image_shape) -> Intrinsics:
        """These intrinsics for the same camera at another resolution ``image_shape``.

        The aspect ratio must agree (to rounding); the focal length and principal
        point scale with the image (pixel centres map as ``(c + 0.5) * s - 0.5``).
        """
        rows, cols = (int(s) for s in tuple(image_shape)[:2])
        r0, c0 = self.image_shape
        sy, sx = rows / r0, cols / c0
        # shapes from rounding a scaled copy differ by at most half a pixel per axis, so
        # the two scale factors agree to that share of each side (a relative test: an
        # absolute one on sy - sx failed a 1024 px copy scaled back up to 6000x4000)
        if abs(sy / sx - 1.0) > 1.0 / min(r0, c0) + 1.0 / min(rows, cols):
            raise ValueError(
                f"image_shape {rows}x{cols} has another aspect ratio than the motion's "
                f"{r0}x{c0}; a motion can only be applied to the same image or a resized copy"
            )
        s = math.sqrt(sy * sx)
        cx, cy = self.principal_point
        return Intrinsics(self.focal_px * s, ((cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5),
                          (rows, cols))

    def to_dict(self) -> dict:
        return {"focal_px": self.focal_px, "principal_point": list(self.principal_point),
                "image_shape": list(self.image_shape)}


def compose_homographies(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Products ``A B`` of 3x3 matrices, broadcast over leading axes: (..., 3, 3)."""
    return (A[..., :, 0, None] * B[..., None, 0, :] + A[..., :, 1, None] * B[..., None, 1, :]
            + A[..., :, 2, None] * B[..., None, 2, :])


def _det3(A: np.ndarray) -> np.ndarray:
    """Determinants of 3x3 matrices, shape (..., 3, 3) -> (...)."""
    return (A[..., 0, 0] * (A[..., 1, 1] * A[..., 2, 2] - A[..., 1, 2] * A[..., 2, 1])
            - A[..., 0, 1] * (A[..., 1, 0] * A[..., 2, 2] - A[..., 1, 2] * A[..., 2, 0])
            + A[..., 0, 2] * (A[..., 1, 0] * A[..., 2, 1] - A[..., 1, 1] * A[..., 2, 0]))


def invert_homographies(H) -> np.ndarray:
    """Inverses of homographies by the adjugate, shape (..., 3, 3) -> (..., 3, 3).

    Exact up to rounding for the well-conditioned matrices of the pose models (their
    determinant is 1 for ``rotation`` and ``inplane``).
    """
    H = np.asarray(H, dtype=float)
    a, b, c = H[..., 0, 0], H[..., 0, 1], H[..., 0, 2]
    d, e, f = H[..., 1, 0], H[..., 1, 1], H[..., 1, 2]
    g, h, i = H[..., 2, 0], H[..., 2, 1], H[..., 2, 2]
    adj = np.stack([np.stack([e * i - f * h, c * h - b * i, b * f - c * e], -1),
                    np.stack([f * g - d * i, a * i - c * g, c * d - a * f], -1),
                    np.stack([d * h - e * g, b * g - a * h, a * e - b * d], -1)], -2)
    return adj / _det3(H)[..., None, None]


def _rodrigues(theta: np.ndarray) -> np.ndarray:
    """Rotation matrices ``expm([theta]_x)`` for rotation vectors, shape (n, 3) -> (n, 3, 3)."""
    theta = np.asarray(theta, dtype=float)
    angle = np.linalg.norm(theta, axis=1)
    small = angle < 1e-6
    safe = np.where(small, 1.0, angle)
    # sin(a)/a and (1 - cos(a))/a^2 with their Taylor series near 0
    a = np.where(small, 1.0 - angle**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    x, y, z = theta.T
    zero = np.zeros_like(x)
    cross = np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1),
                      np.stack([-y, x, zero], -1)], -2)
    cross2 = compose_homographies(cross, cross)
    return np.eye(3) + a[:, None, None] * cross + b[:, None, None] * cross2


def _log_rotation(R: np.ndarray) -> np.ndarray:
    """Rotation vectors of rotation matrices, shape (n, 3, 3) -> (n, 3) (inverse of Rodrigues)."""
    cos = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    v = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], -1)
    small = angle < 1e-6
    scale = np.where(small, 0.5 + angle**2 / 12.0,
                     angle / (2.0 * np.sin(np.where(small, 1, angle))))
    return v * scale[:, None]


def check_poses(poses, model: str, name: str = "poses") -> np.ndarray:
    """Validate poses of ``model`` and return them as float64, shape (n, n_params)."""
    d = n_params(model)
    arr = np.asarray(poses, dtype=float) if not isinstance(poses, np.ndarray) else poses
    if arr.dtype == object or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must be numeric; got dtype {arr.dtype}")
    arr = np.asarray(arr, dtype=float)
    if arr.ndim == 1 and arr.shape[0] == d:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != d:
        raise ValueError(
            f"{name} for the {model!r} model must have shape (n, {d}) "
            f"({', '.join(param_names(model))}); got shape {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite; got NaN or inf")
    return arr


def homographies(model: str, intrinsics: Intrinsics, poses) -> np.ndarray:
    """Homographies of poses under ``model``.

    Parameters
    ----------
    model : {"translation", "inplane", "rotation"}
    intrinsics : Intrinsics
    poses : array_like of shape (n, n_params)

    Returns
    -------
    ndarray of shape (n, 3, 3)
        ``H_p`` mapping sharp to blurred pixel coordinates ``(x, y, 1)`` (Eq. 8).
    """
    poses = check_poses(poses, model)
    n = poses.shape[0]
    H = np.tile(np.eye(3), (n, 1, 1))
    if model == "translation":
        H[:, 0, 2] = poses[:, 0]
        H[:, 1, 2] = poses[:, 1]
    elif model == "inplane":
        cx, cy = intrinsics.principal_point
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        H[:, 0, 0], H[:, 0, 1], H[:, 1, 0], H[:, 1, 1] = c, -s, s, c
        # T(t) T(pp) R T(-pp): translation part is t + pp - R pp
        H[:, 0, 2] = poses[:, 0] + cx - (c * cx - s * cy)
        H[:, 1, 2] = poses[:, 1] + cy - (s * cx + c * cy)
    else:
        K = intrinsics.K
        H = compose_homographies(compose_homographies(K, _rodrigues(poses)), invert_homographies(K))
    return H


def poses_from_homographies(model: str, intrinsics: Intrinsics, H) -> np.ndarray:
    """Inverse of :func:`homographies` for homographies of the model's form, (n, 3, 3) -> (n, d)."""
    H = np.asarray(H, dtype=float)
    if model == "rotation":
        K = intrinsics.K
        R = compose_homographies(compose_homographies(invert_homographies(K), H), K)
        return _log_rotation(R / np.cbrt(_det3(R))[:, None, None])
    check_choice(model, "model", MODELS)
    H = H / H[:, 2:3, 2:3]
    if model == "translation":
        return H[:, :2, 2].copy()
    if model == "inplane":
        cx, cy = intrinsics.principal_point
        theta = np.arctan2(H[:, 1, 0], H[:, 0, 0])
        c, s = np.cos(theta), np.sin(theta)
        tx = H[:, 0, 2] - (cx - (c * cx - s * cy))
        ty = H[:, 1, 2] - (cy - (s * cx + c * cy))
        return np.stack([tx, ty, theta], -1)


def warp_points(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Apply homographies (n, 3, 3) to points ``(x, y)`` (m, 2): returns (n, m, 2)."""
    H = np.asarray(H, dtype=float)[:, None]  # (n, 1, 3, 3)
    x, y = np.asarray(xy, dtype=float).T  # (m,) each
    num_x = H[..., 0, 0] * x + H[..., 0, 1] * y + H[..., 0, 2]
    num_y = H[..., 1, 0] * x + H[..., 1, 1] * y + H[..., 1, 2]
    den = H[..., 2, 0] * x + H[..., 2, 1] * y + H[..., 2, 2]
    return np.stack([num_x / den, num_y / den], -1)


def displacements(model: str, intrinsics: Intrinsics, poses, points_rc) -> np.ndarray:
    """Displacements ``u = H_p x - x`` of image points under each pose (Eq. 9).

    Parameters
    ----------
    model, intrinsics, poses
        As for :func:`homographies`; ``poses`` has shape (n_poses, d).
    points_rc : array_like of shape (n_points, 2)
        Points as ``(row, col)``.

    Returns
    -------
    ndarray of shape (n_points, n_poses, 2)
        ``(dx, dy)`` = (column, row) displacement in pixels.
    """
    pts = np.asarray(points_rc, dtype=float).reshape(-1, 2)
    xy = pts[:, ::-1]
    H = homographies(model, intrinsics, poses)
    moved = warp_points(H, xy)  # (n_poses, n_points, 2)
    return np.transpose(moved - xy[None], (1, 0, 2))


def _grid_steps(model: str, intrinsics: Intrinsics) -> np.ndarray:
    """Pose steps that move the farthest image point by about one pixel."""
    r_max = max(intrinsics.max_radius, 1.0)
    if model == "translation":
        return np.array([1.0, 1.0])
    if model == "inplane":
        return np.array([1.0, 1.0, 1.0 / r_max])
    f = intrinsics.focal_px
    rows, cols = intrinsics.image_shape
    cx, cy = intrinsics.principal_point
    dx = max(cx, cols - 1 - cx)  # farthest column from the principal point
    dy = max(cy, rows - 1 - cy)
    # a rotation theta about y moves a point at horizontal distance d by ~theta (f^2+d^2)/f
    return np.array([f / (f * f + dy * dy), f / (f * f + dx * dx), 1.0 / r_max])


@dataclass(frozen=True)
class PoseGrid:
    """A regular grid of poses centred on the identity pose.

    Parameters
    ----------
    model : str
        Pose model name.
    steps : ndarray of shape (d,)
        Grid spacing per pose parameter.
    counts : tuple of int
        Number of grid points per parameter (odd, so the identity is on the grid).
    """

    model: str
    steps: np.ndarray
    counts: tuple[int, ...]

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.counts)

    @property
    def size(self) -> int:
        return int(np.prod(self.counts))

    @property
    def half(self) -> np.ndarray:
        return (np.asarray(self.counts) - 1) // 2

    def poses(self, active=None) -> np.ndarray:
        """Poses of the grid points (all, or where the boolean grid ``active`` is set), (n, d)."""
        if active is None:
            idx = np.indices(self.counts).reshape(len(self.counts), -1).T
        else:  # only the set points: a fine grid of a large photo has millions
            idx = np.argwhere(np.asarray(active, bool).reshape(self.counts))
        return (idx - self.half) * self.steps

    def splat(self, poses, weights) -> np.ndarray:
        """Distribute weights at arbitrary poses onto the grid (multilinear); shape ``counts``.

        Mass falling outside the grid is clamped onto its border, so the total is kept.
        """
        poses = check_poses(poses, self.model)
        weights = np.asarray(weights, float)
        pos = poses / self.steps + self.half
        pos = np.clip(pos, 0, np.asarray(self.counts) - 1)
        base = np.floor(pos).astype(int)
        base = np.minimum(base, np.asarray(self.counts) - 2).clip(0)
        frac = pos - base
        out = np.zeros(self.counts)
        d = len(self.counts)
        for corner in np.ndindex(*(2,) * d):
            corner = np.array(corner)
            wgt = np.prod(np.where(corner, frac, 1 - frac), axis=1) * weights
            ids = np.minimum(base + corner, np.asarray(self.counts) - 1)
            np.add.at(out, tuple(ids.T), wgt)
        return out


def pose_grid(model: str, intrinsics: Intrinsics, max_blur: float,
              roll_fraction: float = 0.5) -> PoseGrid:
    """The estimation grid for ``model``: one-pixel steps, extent from ``max_blur``.

    Parameters
    ----------
    model : {"translation", "inplane", "rotation"}
    intrinsics : Intrinsics
        Of the image at the resolution the grid is used at (a pyramid level's
        intrinsics give that level's coarser grid).
    max_blur : float
        Largest blur extent (pixels, at this resolution) the grid must hold: each
        parameter spans ``+-GRID_REACH * max_blur`` pixels of motion at the farthest
        point (:data:`GRID_REACH`).
    roll_fraction : float
        The in-plane rotation ``theta_z`` spans this fraction of that extent
        (hand shake rolls less than it pans and tilts).

    Returns
    -------
    PoseGrid
    """
    check_choice(model, "model", MODELS)
    max_blur = check_positive(max_blur, "max_blur")
    steps = _grid_steps(model, intrinsics)
    reach = np.full(len(steps), GRID_REACH * max_blur)
    if model != "translation":
        reach[2] *= roll_fraction
    counts = tuple(int(2 * math.ceil(r - 1e-9) + 1) for r in reach)
    return PoseGrid(model, steps, counts)
