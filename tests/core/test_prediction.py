"""Claims about the prediction image, the edge-profile image and their masks (paper §4.2).

The central claim (Eq. 19, claim 3): blurring ``I_p`` with the true camera motion
reproduces ``I_ep`` inside the masks, and the data term is expressible with the EFF
operator that is linear in the MDF weights.
"""

import math

import numpy as np
import pytest

from napari_edgecme.core.edges import EdgeProfiles, extract_edge_profiles
from napari_edgecme.core.operators import EfficientFilterFlowWeights, WarpSum
from napari_edgecme.core.prediction import (
    edge_profile_image,
    prediction_image,
    profile_masks,
)
from napari_edgecme.core.synth import make_case


def one_profile(centroid=(40.3, 50.7), angle=0.4, contrast=0.5, curvature=0.0, R=8,
                window=None):
    off = np.arange(-R, R + 1, dtype=float)
    d = np.exp(-0.5 * off**2)
    d /= d.sum()
    return EdgeProfiles([centroid], [angle], [0.2 + contrast], [0.2], [np.cumsum(d)], [d], off,
                        [1.0], max_blur=6.0, curvature=[curvature],
                        window=None if window is None else [window])


def scene(shape=(224, 224)):
    """Two discs, a square and a triangle on a dark ground (like the paper's Fig. 3)."""
    rr, cc = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    img = np.full(shape, 0.15)
    out = np.zeros(shape)
    for dr in (-0.375, -0.125, 0.125, 0.375):
        for dc in (-0.375, -0.125, 0.125, 0.375):
            r, c = rr + dr, cc + dc
            sub = img.copy()
            sub[(r - 60) ** 2 + (c - 60) ** 2 <= 34**2] = 0.8
            sub[(r - 164) ** 2 + (c - 164) ** 2 <= 32**2] = 0.6
            u, v = r - 60 + (c - 164) * 0.3, c - 164 - (r - 60) * 0.3  # a rotated square
            sub[(np.abs(u) < 30) & (np.abs(v) < 30)] = 0.7
            tri = (r > 130) & (r < 200) & (np.abs(c - 62) < (r - 130) * 0.55)
            sub[tri] = 0.85
            out += sub
    return (out / 16).astype(np.float32)


@pytest.fixture(scope="module", params=[("rotation", 9, 0.0, 1), ("inplane", 9, 0.01, 2)],
                ids=["rotation-noise-free", "inplane-noise-1pc"])
def blurred(request):
    model, extent, noise, seed = request.param
    case = make_case(scene(), model, extent=extent, noise=noise, bits=8 if noise else None,
                     rng=seed)
    prof = extract_edge_profiles(case.blurred, extent + 2, rng=0)
    return case, prof


# ---------------------------------------------------------------------------------------
# I_p
# ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("angle", [0.0, 0.3, math.pi / 4, 2.0, -2.7])
def test_prediction_line_carries_the_contrast_per_unit_length(angle):
    prof = one_profile(angle=angle)
    ip = prediction_image(prof, (80, 100), line_length=20)
    assert ip.dtype == np.float32 and ip.shape == (80, 100)
    # integral over the image = contrast x length, at any angle and sub-pixel position
    assert ip.sum() == pytest.approx(0.5 * 20, rel=0.01)
    # the line runs along the tangent: no mass beyond its narrow cross-section
    rr, cc = np.nonzero(ip)
    n, t = prof.normals[0], prof.tangents[0]
    d = np.stack([rr - 40.3, cc - 50.7], -1)
    assert np.abs(d @ n).max() < 2.0
    assert np.abs(d @ t).max() < 10.5 + 1.0
    weights = ip[rr, cc]
    assert abs(np.average(d @ n, weights=weights)) < 0.02  # centred on the centroid


def test_a_curved_profile_draws_an_arc():
    r = 30.0
    prof = one_profile(centroid=(50.0, 50.0), angle=math.pi / 2, curvature=-1 / r)
    ip = prediction_image(prof, (100, 100), line_length=30)
    # the normal points down (+row); curvature -1/r bends the ends up towards -row: the
    # bottom of a circle of radius r centred r pixels above the centroid
    rr, cc = np.nonzero(ip > 0.05)
    centre = np.array([50.0 - r, 50.0])
    dist = np.hypot(rr - centre[0], cc - centre[1])
    assert np.abs(np.average(dist, weights=ip[rr, cc]) - r) < 0.3
    assert np.ptp(rr) >= 3  # it does bend


def test_overlapping_segments_on_one_edge_are_one_line():
    one = one_profile(centroid=(40.0, 50.0), angle=0.0)
    two = EdgeProfiles.concatenate([one, one_profile(centroid=(44.0, 50.0), angle=0.0)])
    a = prediction_image(one, (80, 100), line_length=20)
    b = prediction_image(two, (80, 100), line_length=20)
    assert b.max() == pytest.approx(a.max())  # not doubled where they overlap


def test_prediction_image_at_a_pyramid_level_matches_rescaled_profiles(blurred):
    _, prof = blurred
    shape = (112, 112)
    a = prediction_image(prof, shape, scale=0.5)
    b = prediction_image(prof.rescaled(0.5), shape)
    np.testing.assert_allclose(a, b, atol=1e-6)
    full = prediction_image(prof, prof.image_shape)
    # the total line mass (contrast x length) scales with the image
    assert a.sum() == pytest.approx(0.5 * full.sum(), rel=0.1)


def test_empty_profiles_give_empty_images():
    empty = EdgeProfiles.empty("nothing")
    assert not prediction_image(empty, (10, 12)).any()
    iep, mask = edge_profile_image(np.random.default_rng(0).random((10, 12)), empty)
    assert not mask.any() and not iep.any()


# ---------------------------------------------------------------------------------------
# masks and I_ep
# ---------------------------------------------------------------------------------------

def test_single_mask_is_the_normal_line_and_multi_mask_a_wedge_around_it():
    prof = one_profile(centroid=(50.2, 49.6), angle=0.3, R=10)
    single, owner = profile_masks(prof, (100, 100), mask="single")
    multi, _ = profile_masks(prof, (100, 100), mask="multi", angular_width=math.radians(30))
    assert np.all(multi[single]) and multi.sum() > 2 * single.sum()
    assert set(np.unique(owner)) == {-1, 0}
    n, t = prof.normals[0], prof.tangents[0]
    for m, half_angle in ((single, None), (multi, math.radians(15))):
        rr, cc = np.nonzero(m)
        d = np.stack([rr - 50.2, cc - 49.6], -1)
        across, along = d @ n, d @ t
        assert np.abs(across).max() <= 10 + 1e-9
        if half_angle is None:
            assert np.abs(along).max() <= 0.5 + 1e-9
        else:
            assert np.all((np.abs(along) <= 0.5 + 1e-9)
                          | (np.abs(along) <= np.abs(across) * math.tan(half_angle) + 1e-9))
    # the mask stops where the profile's validated window ends
    short, _ = profile_masks(one_profile(centroid=(50.2, 49.6), angle=0.3, R=10, window=4),
                             (100, 100), mask="multi")
    rr, cc = np.nonzero(short)
    assert np.abs(np.stack([rr - 50.2, cc - 49.6], -1) @ n).max() <= 4 + 1e-9


def test_edge_profile_image_is_the_gradient_inside_the_mask(blurred):
    case, prof = blurred
    gy, gx = np.gradient(case.blurred)
    iep, mask = edge_profile_image(case.blurred, prof, gradient="magnitude")
    assert iep.dtype == case.blurred.dtype and mask.dtype == bool
    np.testing.assert_allclose(iep[mask], np.hypot(gx, gy)[mask], rtol=1e-6)
    assert not iep[~mask].any()
    along_normal, mask2 = edge_profile_image(case.blurred, prof, gradient="normal")
    assert np.array_equal(mask, mask2)
    # on the edges the two agree: the gradient points along the profile's normal
    strong = mask & (iep > 0.5 * iep.max())
    assert np.median(along_normal[strong] / iep[strong]) > 0.97


def test_images_do_not_depend_on_how_the_profiles_are_batched(blurred, monkeypatch):
    import napari_edgecme.core.prediction as prediction

    case, prof = blurred
    whole = (prediction_image(prof, case.blurred.shape),
             *profile_masks(prof, case.blurred.shape, mask="multi"))
    monkeypatch.setattr(prediction, "_BLOCK_PIXELS", 3000)  # a few profiles per batch
    batched = (prediction_image(prof, case.blurred.shape),
               *profile_masks(prof, case.blurred.shape, mask="multi"))
    for a, b in zip(whole, batched, strict=True):
        assert np.array_equal(a, b)


def test_rgb_input_uses_luminance(blurred):
    case, prof = blurred
    rgb = np.repeat(case.blurred[..., None], 3, -1)
    a, _ = edge_profile_image(case.blurred, prof)
    b, _ = edge_profile_image(rgb, prof)
    np.testing.assert_allclose(a, b, atol=1e-6)


@pytest.mark.parametrize("kwargs, match", [
    ({"mask": "double"}, "mask must be one of"),
    ({"scale": 0}, "scale"),
    ({"angular_width": 4.0}, "angular_width"),
    ({"gradient": "sobel"}, "gradient"),
    ({"radius": -1}, "radius"),
])
def test_invalid_arguments_are_named(blurred, kwargs, match):
    case, prof = blurred
    with pytest.raises(ValueError, match=match):
        edge_profile_image(case.blurred, prof, **kwargs)


def test_profiles_must_be_edge_profiles():
    with pytest.raises(ValueError, match="profiles must be an EdgeProfiles"):
        prediction_image([[1, 2]], (10, 10))
    with pytest.raises(ValueError, match="shape"):
        prediction_image(one_profile(), (0, 10))


# ---------------------------------------------------------------------------------------
# Eq. 19: the data term with the true motion
# ---------------------------------------------------------------------------------------

def test_true_motion_blurs_the_prediction_into_the_edge_profile_image(blurred):
    """``mask * (EFF_w(I_p) - I_ep)`` is small for the true (centroid-aligned) MDF."""
    case, prof = blurred
    truth = case.motion.recentred()  # claim 2: profiles are aligned to the centroid pose
    ip = prediction_image(prof, case.blurred.shape)
    op = EfficientFilterFlowWeights(ip, truth.model, truth.intrinsics, truth.poses,
                                    dtype=np.float64)
    blurred_eff = op.forward(truth.weights)  # linear in the weights: Eq. 19's T_w(I_p)
    blurred_exact = WarpSum(truth, dtype=np.float64).forward(ip)
    for mask in ("single", "multi"):
        iep, m = edge_profile_image(case.blurred, prof, mask=mask)
        scale = np.linalg.norm(m * iep)
        rel_eff = np.linalg.norm(m * (blurred_eff - iep)) / scale  # the data term of Eq. 19
        rel_exact = np.linalg.norm(m * (blurred_exact - iep)) / scale
        # without blur the residual is far larger: the data term measures the motion
        rel_none = np.linalg.norm(m * (ip - iep)) / scale
        print(f"{case.model}, noise {case.noise:g}, {mask}-direction mask ({int(m.sum())} px, "
              f"{len(prof)} profiles): relative residual with the true MDF {rel_eff:.3f} "
              f"(EFF), {rel_exact:.3f} (exact warp-sum); without blur {rel_none:.3f}")
        limit = 0.2 if case.noise == 0 else 0.4
        assert rel_eff < limit and rel_exact < limit
        assert rel_none > 2.5 * rel_eff


def test_data_term_is_linear_in_the_weights(blurred):
    case, prof = blurred
    truth = case.motion.recentred()
    ip = prediction_image(prof, case.blurred.shape, scale=1.0)
    op = EfficientFilterFlowWeights(ip, truth.model, truth.intrinsics, truth.poses[:8],
                                    dtype=np.float64)
    rng = np.random.default_rng(0)
    a, b = rng.random(8), rng.random(8)
    np.testing.assert_allclose(op.forward(2 * a + 3 * b), 2 * op.forward(a) + 3 * op.forward(b),
                               atol=1e-12)
