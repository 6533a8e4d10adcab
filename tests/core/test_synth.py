"""Synthetic shake (core/synth.py): exact rendering and its progress reports."""

from __future__ import annotations

import numpy as np
import pytest

from napari_edgecme.core.camera import Intrinsics
from napari_edgecme.core.motion import CameraMotion
from napari_edgecme.core.synth import render_blur


def test_integer_translations_render_as_the_mean_of_shifted_copies():
    rng = np.random.default_rng(0)
    image = rng.random((40, 50))
    intrinsics = Intrinsics.from_image_shape(image.shape)
    motion = CameraMotion("translation", intrinsics, [[0, 0], [3, 0], [0, -2]], [1, 1, 2])
    blurred = render_blur(image, motion)
    # g(x) = sum_p w_p f(H_p^-1 x): a pose (tx, ty) moves content by +tx columns, +ty rows
    expected = (image + np.roll(image, 3, axis=1) + 2 * np.roll(image, -2, axis=0)) / 4
    inner = (slice(4, -4), slice(4, -4))
    np.testing.assert_allclose(blurred[inner], expected[inner], atol=1e-6)


def test_rendering_reports_one_progress_record_per_pose_in_order():
    image = np.zeros((24, 24))
    intrinsics = Intrinsics.from_image_shape(image.shape)
    motion = CameraMotion("translation", intrinsics, [[0, 0], [1, 0], [2, 0]], [1, 1, 1])
    records = []
    render_blur(image, motion, callback=records.append)
    assert [(r.stage, r.step, r.total) for r in records] == [("synth", k, 3) for k in (1, 2, 3)]


def test_shapes_render_with_their_exact_area_and_edges():
    from napari_edgecme.core.synth import distance_to_edges, render_shapes

    square = np.array([[20.0, 20.0], [20.0, 60.0], [60.0, 60.0], [60.0, 20.0]])
    shapes = [("disc", (40.0, 100.0, 15.0), 1.0), ("poly", square, 1.0)]
    image = render_shapes((80, 130), shapes, background=0.0, supersample=8)
    assert image.dtype == np.float32
    assert image.sum() == pytest.approx(np.pi * 15**2 + 40 * 40, rel=2e-3)
    points = [(40.0, 100.0), (40.0, 40.0), (20.0, 30.0), (40.0, 85.0)]
    np.testing.assert_allclose(distance_to_edges(shapes, points), [15, 20, 0, 0], atol=1e-12)
