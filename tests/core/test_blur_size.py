"""The blur size from the image: ``measure_blur_extent`` and ``max_blur_for``."""

import dataclasses

import numpy as np
import pytest

from napari_edgecme.core import blur_size
from napari_edgecme.core.blur_size import (
    BlurSize,
    max_blur_for,
    measure_blur_extent,
    transition_widths,
)
from napari_edgecme.core.estimate import default_max_blur
from napari_edgecme.core.synth import add_noise, edge_scene, make_case, quantize


@pytest.fixture(scope="module")
def scene():
    return edge_scene((240, 320), rng=1)


@pytest.fixture(scope="module")
def cases(scene):
    """Shakes of 8 and 24 px (true extents) of each pose model on one scene."""
    return {(model, extent): make_case(scene, model, extent=extent, rng=seed)
            for seed, (model, extent) in enumerate(
                [(m, e) for m in ("translation", "inplane", "rotation") for e in (8, 24)], 2)}


def test_transition_widths_of_a_box_and_of_a_step():
    offsets = np.arange(-20, 21, dtype=float)
    box = np.zeros((2, offsets.size))
    box[0, 15:25] = 0.1  # 10 one-pixel bins of equal mass: 2..98 % spans 0.96 of 10 px
    box[1, 20] = 1.0  # a sharp step: all mass in one bin
    w = transition_widths(box, offsets)
    assert w[0] == pytest.approx(9.6)
    assert w[1] == pytest.approx(0.96)
    assert transition_widths(np.zeros((0, offsets.size)), offsets).shape == (0,)


@pytest.mark.parametrize("model", ["translation", "inplane", "rotation"])
def test_the_measured_extent_follows_the_true_one(cases, model):
    small = measure_blur_extent(cases[model, 8].blurred, rng=0)
    large = measure_blur_extent(cases[model, 24].blurred, rng=0)
    for size, case in ((small, cases[model, 8]), (large, cases[model, 24])):
        assert size.source == "edge profiles"
        assert size.n_profiles >= blur_size.MIN_PROFILES
        ratio = size.extent_px / case.motion.blur_extent()
        assert 0.6 < ratio < 2.2, (model, case.extent, size)
    # three times the blur reads as clearly more (a small blur reads long: the sharp
    # edges' own width adds to every transition)
    assert large.extent_px > 1.3 * small.extent_px


def test_the_message_says_what_was_found(cases):
    size = measure_blur_extent(cases["inplane", 24].blurred, rng=0)
    assert size.message == (f"blur about {round(size.extent_px)} px, from "
                            f"{size.n_profiles} edge profiles")
    with pytest.raises(dataclasses.FrozenInstanceError):
        size.extent_px = 3.0


def test_a_sharp_photo_reads_as_a_small_blur(scene, cases):
    sharp = measure_blur_extent(quantize(add_noise(scene, 0.01, rng=0)), rng=0)
    blurred = measure_blur_extent(cases["inplane", 24].blurred, rng=0)
    assert sharp.source == "edge profiles"
    assert sharp.extent_px < 7.0
    assert sharp.extent_px < 0.35 * blurred.extent_px


def test_a_noisy_photo_is_still_measured(scene):
    case = make_case(scene, "inplane", extent=16, noise=0.04, rng=5)
    size = measure_blur_extent(case.blurred, rng=0)
    assert size.source == "edge profiles"
    assert 0.6 < size.extent_px / case.motion.blur_extent() < 2.2


def test_the_extent_is_in_the_input_pixels(cases):
    """Measured on a reduced copy (``max_side``), the extent is still in the input's pixels."""
    img = cases["rotation", 24].blurred
    full = measure_blur_extent(img, rng=0)
    half = measure_blur_extent(img, rng=0, max_side=160)  # a copy at half the size
    assert half.extent_px == pytest.approx(full.extent_px, rel=0.3)
    from skimage.transform import resize

    twice = resize(img, (480, 640), order=1)
    doubled = measure_blur_extent(twice, rng=0, max_side=320)
    assert doubled.extent_px == pytest.approx(2 * full.extent_px, rel=0.1)


def test_rgb_and_integers_read_like_gray(cases):
    img = cases["inplane", 8].blurred
    rgb8 = np.round(np.repeat(img[..., None], 3, -1) * 255).astype(np.uint8)
    a = measure_blur_extent(img, rng=0)
    b = measure_blur_extent(rgb8, rng=0)
    assert b.extent_px == pytest.approx(a.extent_px, rel=0.05)
    assert measure_blur_extent(img, rng=0) == a  # same seed, same answer


def test_a_constant_image_gets_the_default_and_says_so():
    size = measure_blur_extent(np.full((100, 120), 0.4, np.float32))
    assert size.source == "default"
    assert size.extent_px == default_max_blur((100, 120))
    assert size.n_profiles == 0
    assert "constant" in size.message and "default" in size.message


def test_a_photo_with_few_edges_falls_back_to_the_default():
    # a smooth shading with one short blurred edge: too few profiles to measure from
    rr, cc = np.mgrid[0:200, 0:260]
    img = 0.3 + 0.3 * np.sin(cc / 60.0) * np.cos(rr / 50.0)
    img[90:110, 120:140] = 0.9
    size = measure_blur_extent(img.astype(np.float32), rng=0)
    assert size.source == "default"
    assert size.n_profiles < blur_size.MIN_PROFILES
    assert size.extent_px == default_max_blur(img.shape)
    assert f"only {size.n_profiles} edge profile" in size.message
    assert "default" in size.message


def test_max_blur_for_adds_the_margin_within_the_estimators_bounds():
    size = BlurSize(20.0, 50, "edge profiles", "")
    assert max_blur_for(size, (400, 600)) == pytest.approx(blur_size.MARGIN * 20.0)
    assert max_blur_for(size, (400, 600, 3)) == pytest.approx(blur_size.MARGIN * 20.0)
    # never 1 px or less, always under half the smaller side
    assert max_blur_for(BlurSize(0.1, 50, "edge profiles", ""), (400, 600)) == 1.0
    big = max_blur_for(BlurSize(500.0, 50, "edge profiles", ""), (100, 600))
    assert 1.0 <= big < 50.0
    assert max_blur_for(BlurSize(3.0, 50, "edge profiles", ""), (3, 3)) == 1.0
    # the default is already a max blur: no margin on it
    assert max_blur_for(BlurSize(26.0, 0, "default", ""), (640, 480)) == 26.0
