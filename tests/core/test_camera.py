"""Claims about camera intrinsics, the three pose models and pose grids."""

import os
import platform
import subprocess
import sys

import numpy as np
import pytest

from napari_edgecme.core.camera import (
    DEFAULT_FOCAL_35MM,
    Intrinsics,
    compose_homographies,
    homographies,
    invert_homographies,
    pose_grid,
    poses_from_homographies,
    warp_points,
)


def move(model, intr, pose, xy):
    return warp_points(homographies(model, intr, [pose]), np.array([xy], float))[0, 0]


@pytest.fixture
def intr():
    return Intrinsics(1000.0, (50.0, 40.0), (81, 101))


def test_default_focal_and_principal_point():
    cam = Intrinsics.from_image_shape((600, 800))
    assert cam.principal_point == (399.5, 299.5)
    assert cam.focal_px == pytest.approx(DEFAULT_FOCAL_35MM / 36 * 800)
    assert Intrinsics.from_image_shape((600, 800), focal_35mm=72).focal_px == pytest.approx(1600)
    assert Intrinsics.from_image_shape((600, 800), focal_px=123.0).focal_px == 123.0


@pytest.mark.parametrize("sign", [1, -1])
def test_translation_moves_points_by_t(intr, sign):
    assert move("translation", intr, (3 * sign, -2 * sign), (10, 20)) == pytest.approx(
        (10 + 3 * sign, 20 - 2 * sign))


@pytest.mark.parametrize("sign", [1, -1])
def test_inplane_rotation_turns_x_axis_towards_rows(intr, sign):
    # Rz = [[cos, -sin], [sin, cos]] in (x, y) about the principal point:
    # +90 degrees takes the point one pixel right of the centre to one pixel below it
    cx, cy = intr.principal_point
    got = move("inplane", intr, (0, 0, sign * np.pi / 2), (cx + 1, cy))
    assert got == pytest.approx((cx, cy + sign))


def test_inplane_translates_after_rotating(intr):
    cx, cy = intr.principal_point
    assert move("inplane", intr, (5, -4, 0.3), (cx, cy)) == pytest.approx((cx + 5, cy - 4))


@pytest.mark.parametrize("sign", [1, -1])
def test_rotation_about_y_pans_right_and_about_x_tilts_up(intr, sign):
    cx, cy = intr.principal_point
    a = sign * 0.01
    f = intr.focal_px
    assert move("rotation", intr, (0, a, 0), (cx, cy)) == pytest.approx((cx + f * np.tan(a), cy))
    assert move("rotation", intr, (a, 0, 0), (cx, cy)) == pytest.approx((cx, cy - f * np.tan(a)))


def test_rotation_about_z_equals_inplane_rotation(intr):
    xy = (90.0, 7.0)
    assert move("rotation", intr, (0, 0, 0.05), xy) == pytest.approx(
        move("inplane", intr, (0, 0, 0.05), xy))


@pytest.mark.parametrize("model", ["translation", "inplane", "rotation"])
def test_poses_round_trip_through_homographies(intr, model, rng):
    d = 2 if model == "translation" else 3
    poses = rng.normal(scale=0.02 if model == "rotation" else 3, size=(7, d))
    if model == "inplane":
        poses[:, 2] *= 0.01
    back = poses_from_homographies(model, intr, homographies(model, intr, poses))
    assert back == pytest.approx(poses, abs=1e-9)


@pytest.mark.parametrize("model", ["translation", "inplane", "rotation"])
def test_grid_step_moves_farthest_point_by_about_one_pixel(intr, model):
    grid = pose_grid(model, intr, max_blur=21)
    corners = intr.corners
    for axis, step in enumerate(grid.steps):
        pose = np.zeros(len(grid.steps))
        pose[axis] = step
        H = homographies(model, intr, [pose])
        shift = np.linalg.norm(warp_points(H, corners)[0] - corners, axis=1).max()
        assert 0.9 < shift < 1.1
    assert all(c % 2 == 1 for c in grid.counts)
    assert grid.counts[0] == 23  # +-10.5 px reached in whole steps: 11 each side


def test_grid_coarsens_with_the_image(intr):
    fine = pose_grid("rotation", intr, 21)
    coarse = pose_grid("rotation", intr.rescaled((41, 51)), 21 / 2)
    assert np.all(coarse.steps > 1.8 * fine.steps)
    assert coarse.size < fine.size / 4


def test_rescaled_rejects_another_aspect_ratio(intr):
    with pytest.raises(ValueError, match="aspect ratio"):
        intr.rescaled((81, 40))


@pytest.mark.parametrize("bad, match", [
    (dict(focal_px=-1, principal_point=(0, 0), image_shape=(2, 2)), "focal_px"),
    (dict(focal_px=np.nan, principal_point=(0, 0), image_shape=(2, 2)), "focal_px"),
    (dict(focal_px=10, principal_point=(0,), image_shape=(2, 2)), "principal_point"),
    (dict(focal_px=10, principal_point=(0, 0), image_shape=(0, 2)), "image_shape"),
])
def test_bad_intrinsics_name_the_parameter(bad, match):
    with pytest.raises(ValueError, match=match):
        Intrinsics(**bad)


def test_unknown_model_is_named(intr):
    with pytest.raises(ValueError, match="model must be one of"):
        homographies("affine", intr, [[0, 0]])
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        homographies("rotation", intr, [[0, 0]])


@pytest.mark.parametrize("shape", [(4000, 6000), (2828, 4243), (2830, 4241), (3456, 5184),
                                   (4016, 6016), (2866, 4187)])
def test_a_motion_found_on_the_working_copy_applies_back_to_camera_sizes(shape):
    # the 1024 px working copy of these sizes rounds its short side; scaled back up ~4-6x
    # that rounding used to fail the aspect check and crash `edgecme deblur`
    copy = tuple(max(8, round(n * 1024 / max(shape))) for n in shape)
    intr = Intrinsics.from_image_shape(copy)
    back = intr.rescaled(shape)
    assert back.image_shape == shape
    with pytest.raises(ValueError, match="another aspect ratio"):
        intr.rescaled((round(shape[0] * 1.1), shape[1]))


def test_inverse_and_product_of_homographies_match_linear_algebra(intr, rng):
    poses = rng.normal(scale=0.02, size=(20, 3))
    H = homographies("rotation", intr, poses)
    assert np.allclose(invert_homographies(H), np.linalg.inv(H), rtol=1e-12, atol=1e-12)
    assert np.allclose(compose_homographies(H, H[::-1]), H @ H[::-1], rtol=1e-12, atol=1e-9)
    assert np.allclose(compose_homographies(H, invert_homographies(H)), np.eye(3), atol=1e-9)


_GEOMETRY_DIGEST = """
import hashlib, numpy as np
from napari_edgecme.core import camera
from napari_edgecme.core.deconv import from_opponent, to_opponent
from napari_edgecme.core.photometry import to_luminance
rng = np.random.default_rng(0)
intr = camera.Intrinsics.from_image_shape((480, 640))
digest = hashlib.sha256()
for model, scale in (("rotation", 0.01), ("inplane", [3.0, 3.0, 0.01])):
    H = camera.homographies(model, intr, rng.normal(scale=scale, size=(64, 3)))
    for a in (H, camera.invert_homographies(H), camera.compose_homographies(H, H[::-1]),
              camera.warp_points(H, rng.random((32, 2)) * 600),
              camera.poses_from_homographies(model, intr, H)):
        digest.update(np.ascontiguousarray(a).tobytes())
rgb = rng.random((48, 48, 3)).astype(np.float32)
for a in (to_luminance(rgb), to_opponent(rgb), from_opponent(rgb)):
    digest.update(a.tobytes())
print(digest.hexdigest())
"""


def _cpu_flags() -> set[str]:
    try:
        with open("/proc/cpuinfo") as info:
            return next((set(line.split(":", 1)[1].split()) for line in info
                         if line.startswith("flags")), set())
    except OSError:
        return set()


def test_geometry_and_colour_are_the_same_bits_under_every_blas_kernel():
    """OpenBLAS kernels round matrix products differently in the last bits (the ``lai``
    figures moved by 0.1 dB between Haswell and SkylakeX); homographies, their inverses,
    point warps and the colour transforms are elementwise arithmetic and must not move."""
    from napari_edgecme._report import blas_kernel

    if blas_kernel() is None or platform.machine() not in ("x86_64", "AMD64"):
        pytest.skip("needs numpy's bundled OpenBLAS on x86-64 (OPENBLAS_CORETYPE)")
    flags = _cpu_flags()
    kernels = ["Prescott"] + [name for name, flag in (("Haswell", "avx2"),
                                                       ("SkylakeX", "avx512f"))
                              if flag in flags]
    if len(kernels) < 2:
        pytest.skip("one OpenBLAS kernel on this CPU")
    digests = {}
    for kernel in kernels:
        env = {**os.environ, "OPENBLAS_CORETYPE": kernel}
        digests[kernel] = subprocess.run([sys.executable, "-c", _GEOMETRY_DIGEST], env=env,
                                         capture_output=True, text=True, check=True,
                                         timeout=120).stdout.strip()
    assert len(set(digests.values())) == 1, digests
