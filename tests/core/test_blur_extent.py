"""``CameraMotion.blur_extent``: one length, the longest side of the local PSFs' support."""

import math

import numpy as np
import pytest

from napari_edgecme import CameraMotion, Intrinsics
from napari_edgecme.core import synth


@pytest.mark.parametrize("length", [1.0, 7.0, 17.0, 30.5])
def test_a_uniform_horizontal_shift_of_l_px_has_extent_l(length):
    cam = Intrinsics.from_image_shape((80, 120))
    poses = np.stack([np.linspace(0, length, 41), np.zeros(41)], -1)
    m = CameraMotion.from_trajectory(poses, "translation", cam)
    assert m.blur_extent() == pytest.approx(length, abs=1e-12)
    # a distance, not a count of pixels; the radius about the centroid is half of it
    assert m.max_displacement() == pytest.approx(length / 2)
    # the same shift vertically, or diagonally: the longest side of the box
    assert CameraMotion.from_trajectory(poses[:, ::-1], "translation",
                                        cam).blur_extent() == pytest.approx(length)
    diagonal = np.stack([poses[:, 0], 0.5 * poses[:, 0]], -1)
    assert CameraMotion.from_trajectory(diagonal, "translation",
                                        cam).blur_extent() == pytest.approx(length)


def test_one_pose_has_extent_zero_and_zero_weights_do_not_count():
    cam = Intrinsics.from_image_shape((50, 60))
    assert CameraMotion.identity("rotation", cam).blur_extent() == 0.0
    assert CameraMotion.from_trajectory([[3.0, -2.0]], "translation", cam).blur_extent() == 0
    m = CameraMotion("translation", cam, [[0, 0], [4, 0], [40, 0]], [0.5, 0.5, 0.0])
    assert m.blur_extent() == pytest.approx(4.0)
    # a faint tail counts in full (the support, not a weighted spread)
    m = CameraMotion("translation", cam, [[0, 0], [4, 0], [9, 0]], [0.495, 0.495, 0.01])
    assert m.blur_extent() == pytest.approx(9.0)


def test_an_inplane_rotation_has_the_extent_of_its_longest_corner_arc():
    # 101 rows x 201 cols: principal point (x, y) = (100, 50); a uniform roll 0..theta
    cam = Intrinsics.from_image_shape((101, 201))
    theta = 0.05
    poses = np.stack([np.zeros(9), np.zeros(9), np.linspace(0.0, theta, 9)], -1)
    m = CameraMotion.from_trajectory(poses, "inplane", cam)
    # by hand: the corner (x, y) = (+100, -50) from the principal point moves by
    # u(phi) = (R(phi) - I) p = (100 (cos phi - 1) + 50 sin phi, 100 sin phi + 50 (1 - cos phi));
    # its y component grows monotonically from 0, so the box's longest side is
    # u_y(theta) = 100 sin(theta) + 50 (1 - cos(theta)) = 5.0604 px (the other corners: the
    # same by symmetry, or 100 sin - 50 (1 - cos) = 4.9354 px)
    by_hand = 100 * math.sin(theta) + 50 * (1 - math.cos(theta))
    assert by_hand == pytest.approx(5.0604, abs=1e-4)
    assert m.blur_extent() == pytest.approx(by_hand, rel=1e-9)
    corners = [[0, 0], [0, 200], [100, 0], [100, 200]]
    assert m.blur_extent(corners) == pytest.approx(by_hand, rel=1e-9)
    # at the principal point a roll does not blur; between it and the corners, less
    assert m.blur_extent([[50, 100]]) == pytest.approx(0.0, abs=1e-9)
    assert m.blur_extent([[25, 150]]) == pytest.approx(by_hand / 2, rel=1e-9)


@pytest.mark.parametrize("model", ["translation", "inplane", "rotation"])
@pytest.mark.parametrize("shape", [(96, 96), (90, 160)])
def test_random_trajectory_is_scaled_to_the_blur_extent_it_is_asked_for(model, shape):
    cam = Intrinsics.from_image_shape(shape)
    for seed, extent, roll in [(0, 5.0, 0.35), (1, 17.0, 0.35), (2, 17.0, 2.0),
                               (3, 31.0, 1.0)]:
        path = synth.random_trajectory(model, cam, extent, n_samples=48, roll=roll, rng=seed)
        # the scale is refined a few times, not solved for: within 0.01 px (a 31 px roll
        # on a 96 px image is the worst of these, 0.002 px short)
        assert synth.trajectory_extent(model, cam, path) == pytest.approx(extent, abs=0.01)
        # the same number for the path as a motion, and for the motion ``synth`` renders
        # and saves (the path densified)
        same = synth.trajectory_extent(model, cam, path)
        assert CameraMotion.from_trajectory(path, model, cam).blur_extent() == pytest.approx(
            same, rel=1e-9)
        truth = synth.densify_path(path, model, cam)
        assert truth.blur_extent() == pytest.approx(same, rel=1e-5)


def test_make_case_reports_the_extent_of_its_true_motion():
    case = synth.make_case(synth.sample_image("edges", 64), "rotation", 9.0, 0.0, rng=4)
    assert case.motion.blur_extent() == pytest.approx(case.extent, rel=1e-5)
