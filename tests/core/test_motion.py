"""Claims about CameraMotion: validation, PSFs (Eq. 9), rescaling and the motion file."""

import json

import numpy as np
import pytest

from napari_edgecme import CameraMotion, Intrinsics
from napari_edgecme.core.synth import densify_path, random_trajectory


@pytest.fixture
def cam():
    return Intrinsics.from_image_shape((120, 160))


def test_translation_psf_puts_weight_at_the_displacement(cam):
    m = CameraMotion("translation", cam, [[0, 0], [2, 0], [0, -1]], [2, 1, 1])
    k = m.psf([[60, 80]], size=7)[0]
    assert k.sum() == pytest.approx(1)
    assert k[3, 3] == pytest.approx(0.5)  # centre = zero displacement
    assert k[3, 5] == pytest.approx(0.25)  # +2 in x -> two columns right
    assert k[2, 3] == pytest.approx(0.25)  # -1 in y -> one row up (row axis = y)


def test_subpixel_displacement_is_splatted_bilinearly(cam):
    m = CameraMotion("translation", cam, [[0.25, 0.5]], [1])
    k = m.psf([[0, 0]], size=3)[0]
    np.testing.assert_allclose(k[1:, 1:], [[0.375, 0.125], [0.375, 0.125]])


@pytest.mark.parametrize("model", ["inplane", "rotation"])
def test_psfs_sum_to_one_and_vary_over_the_image(cam, model):
    poses = random_trajectory(model, cam, 11, 20, roll=2.0, rng=3)
    m = CameraMotion.from_trajectory(poses, model, cam)
    pts = [[0, 0], [119, 159], [60, 80]]
    k = m.psf(pts)
    assert k.shape[1] == k.shape[2] and k.shape[1] % 2 == 1
    assert k.sum(axis=(1, 2)) == pytest.approx(1)
    assert np.abs(k[0] - k[1]).sum() > 0.1


def test_psf_size_too_small_is_refused(cam):
    m = CameraMotion("translation", cam, [[0, 0], [4, 0]], [1, 1])
    with pytest.raises(ValueError, match="at least 9"):
        m.psf([[0, 0]], size=5)


def test_psf_field_draws_each_psf_at_its_point(cam):
    m = CameraMotion("translation", cam, [[0, 0]], [1])
    field = m.psf_field(grid=(2, 2), magnify=1)
    assert field.shape == cam.image_shape and field.dtype == np.float32
    assert np.count_nonzero(field) == 4
    assert field.max() == 1


def test_rescale_scales_translations_and_keeps_angles(cam):
    small = Intrinsics.from_image_shape((60, 80))
    poses = random_trajectory("inplane", small, 7, 12, rng=1)
    m = CameraMotion.from_trajectory(poses, "inplane", small)
    big = m.rescale((120, 160))
    assert big.poses[:, :2] == pytest.approx(2 * m.poses[:, :2])
    assert big.poses[:, 2] == pytest.approx(m.poses[:, 2])
    r = CameraMotion.from_trajectory(random_trajectory("rotation", small, 7, 12, rng=1),
                                     "rotation", small)
    assert r.rescale((120, 160)).poses == pytest.approx(r.poses)
    # displacements double at corresponding points
    d_small = r.displacements([[10.5, 20.5]])
    d_big = r.rescale((120, 160)).displacements([[21.5, 41.5]])
    assert d_big == pytest.approx(2 * d_small, rel=1e-3, abs=1e-3)
    with pytest.raises(ValueError, match="aspect ratio"):
        m.rescale((120, 60))


@pytest.mark.parametrize("model", ["translation", "inplane", "rotation"])
def test_cropped_moves_the_principal_point_and_keeps_every_psf(cam, model):
    poses = random_trajectory(model, cam, 9, 16, roll=2.0, rng=5)
    m = CameraMotion.from_trajectory(poses, model, cam)
    offset, shape = (30, 100), (24, 40)
    crop = m.cropped(offset, shape)
    assert crop.image_shape == shape
    assert crop.intrinsics.focal_px == m.intrinsics.focal_px
    cx, cy = m.intrinsics.principal_point
    assert crop.intrinsics.principal_point == (cx - 100, cy - 30)
    np.testing.assert_array_equal(crop.poses, m.poses)
    # the PSF at crop pixel p is the PSF at image pixel p + offset (not a rescaled one)
    local = np.array([[0, 0], [23, 39], [11.5, 20.25]])
    size = m.psf_size()
    np.testing.assert_allclose(crop.psf(local, size), m.psf(local + offset, size),
                               atol=1e-12)
    if model == "translation":  # the blur keeps its size; a rescale would shrink it
        assert crop.blur_extent() == pytest.approx(m.blur_extent())
        assert m.rescale((60, 80)).blur_extent() == pytest.approx(0.5 * m.blur_extent())
    assert m.cropped((0, 0), cam.image_shape) is m
    # a crop round trip through the motion file keeps it
    assert CameraMotion.from_dict(crop.to_dict()) == crop


@pytest.mark.parametrize("offset, shape", [((-1, 0), (10, 10)), ((0, 155), (10, 10)),
                                           ((115, 0), (10, 10))])
def test_a_crop_outside_the_image_is_refused(cam, offset, shape):
    m = CameraMotion.identity("inplane", cam)
    with pytest.raises(ValueError, match="does not lie inside the motion's 120x160 image"):
        m.cropped(offset, shape)


def test_recentred_moves_the_centroid_to_the_identity(cam):
    poses = random_trajectory("rotation", cam, 9, 16, rng=2) + np.array([0.001, -0.002, 0.0005])
    m = densify_path(poses, "rotation", cam)
    c = m.recentred()
    assert np.abs(c.centroid_pose()).max() < 1e-6
    # the shape of every PSF is unchanged (claim 2): only shifted. The bound allows for
    # the bilinear splatting of a one-pixel-thin path at other sub-pixel offsets.
    from napari_edgecme.core.metrics import psf_ncc
    for a, b in zip(m.psf([[0, 0], [60, 80]], 31), c.psf([[0, 0], [60, 80]], 31), strict=True):
        assert psf_ncc(a, b) > 0.95


@pytest.mark.parametrize("model", ["translation", "inplane", "rotation"])
def test_motion_file_round_trips(tmp_path, cam, model):
    d = 2 if model == "translation" else 3
    poses = random_trajectory(model, cam, 9, 10, rng=0)
    m = CameraMotion(model, cam, poses, np.arange(1, 11, dtype=float))
    path = tmp_path / "m.json"
    m.save(path)
    data = json.loads(path.read_text())
    assert data["format"] == "edgecme-motion" and data["version"] == 1
    assert set(data) == {"format", "version", "model", "intrinsics", "poses", "weights"}
    assert len(data["poses"][0]) == d
    back = CameraMotion.load(path)
    assert back == m
    assert not list(tmp_path.glob(".*tmp*"))


@pytest.mark.parametrize("method", ["ep", "xu", "xu+ep"])
def test_a_motion_file_names_the_estimator_that_made_it(tmp_path, cam, method):
    """``estimated_by`` is written when given and read back beside the motion; a file
    without it (a ground truth, a file of an older version) names none, and the motion
    of either reads the same."""
    m = CameraMotion("translation", cam, [[0, 0], [1, 0]], [1, 1])
    named, plain = tmp_path / "named.json", tmp_path / "plain.json"
    m.save(named, estimated_by=method)
    m.save(plain)
    assert json.loads(named.read_text())["estimated_by"] == method
    assert "estimated_by" not in json.loads(plain.read_text())
    assert CameraMotion.load_estimate(named) == (m, method, None)
    assert CameraMotion.load_estimate(plain) == (m, None, None)
    assert CameraMotion.load(named) == m
    assert CameraMotion.from_dict(m.to_dict(estimated_by=method)) == m


def test_a_motion_file_keeps_the_profile_misfit_of_its_estimate(tmp_path, cam):
    """``profile_misfit`` (the share of the edge profiles' energy the estimate leaves
    unexplained, which sets an EpAlone motion's restoration) is written when given and
    read back, above 1 too (profiles a motion does not explain at all); a misfit that is
    not a finite number >= 0 is refused in one line, on writing and reading."""
    m = CameraMotion("translation", cam, [[0, 0], [1, 0]], [1, 1])
    m.save(tmp_path / "m.json", estimated_by="ep", profile_misfit=0.137)
    assert json.loads((tmp_path / "m.json").read_text())["profile_misfit"] == 0.137
    assert CameraMotion.load_estimate(tmp_path / "m.json") == (m, "ep", 0.137)
    m.save(tmp_path / "far.json", estimated_by="xu+ep", profile_misfit=1.5)
    assert CameraMotion.load_estimate(tmp_path / "far.json") == (m, "xu+ep", 1.5)
    with pytest.raises(ValueError, match=r"^profile_misfit must be a finite number >= 0; "
                                         r"got -0\.5$"):
        m.save(tmp_path / "bad.json", profile_misfit=-0.5)
    with pytest.raises(ValueError, match=r"^profile_misfit must be a finite number >= 0"):
        m.save(tmp_path / "bad.json", profile_misfit=float("inf"))
    assert not (tmp_path / "bad.json").exists()
    for bad in ("0.1", True, -0.01):
        path = tmp_path / "bad.json"
        path.write_text(json.dumps({**GOOD, "profile_misfit": bad}))
        with pytest.raises(ValueError, match=r"motion file's profile_misfit must be a "
                                             r"finite number >= 0") as info:
            CameraMotion.load_estimate(path)
        assert "\n" not in str(info.value)
        assert CameraMotion.load(path).n_poses >= 1  # the motion itself reads as ever


def test_an_unknown_estimator_is_refused_in_one_line(tmp_path, cam):
    m = CameraMotion("translation", cam, [[0, 0], [1, 0]], [1, 1])
    with pytest.raises(ValueError, match="estimated_by must be one of 'ep', 'xu', 'xu\\+ep'; "
                                         "got 'wiener'"):
        m.save(tmp_path / "m.json", estimated_by="wiener")
    assert not (tmp_path / "m.json").exists()
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({**GOOD, "estimated_by": 3}))
    with pytest.raises(ValueError, match=r"motion file's estimated_by must be one of "
                                         r"'ep', 'xu', 'xu\+ep'; got 3") as info:
        CameraMotion.load_estimate(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)
    # the motion itself is sound: readers that do not steer a restoration by the name
    # (edgecme psf, the suites) read it as ever
    assert CameraMotion.load(path) == CameraMotion.from_dict(GOOD)


def test_only_nonzero_weights_are_stored(tmp_path, cam):
    m = CameraMotion("translation", cam, [[0, 0], [1, 0]], [1, 0])
    m.save(tmp_path / "m.json")
    assert len(json.loads((tmp_path / "m.json").read_text())["weights"]) == 1


GOOD = {"format": "edgecme-motion", "version": 1, "model": "translation",
        "intrinsics": {"focal_px": 100.0, "principal_point": [9.5, 9.5], "image_shape": [20, 20]},
        "poses": [[0.0, 0.0], [1.0, 0.0]], "weights": [0.5, 0.5]}


@pytest.mark.parametrize("change, match", [
    ({"format": "other"}, "not an edgecme motion file"),
    ({"version": 2}, "unsupported motion file version 2"),
    ({"model": "affine"}, "model must be one of"),
    ({"weights": [0.5, -0.5]}, "weights must be >= 0"),
    ({"weights": [0.0, 0.0]}, "must not all be zero"),
    ({"weights": [1.0]}, "weights must have shape"),
    ({"poses": [[0.0], [1.0]]}, r"shape \(n, 2\)"),
    ({"poses": [[0.0, "x"], [1.0, 0.0]]}, "malformed"),
    ({"intrinsics": {"focal_px": 1}}, "intrinsics"),
    ({"intrinsics": {"focal_px": -1, "principal_point": [0, 0], "image_shape": [2, 2]}},
     "focal_px"),
    ({"poses": []}, "no poses"),
])
def test_malformed_motion_files_give_one_line(tmp_path, change, match):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({**GOOD, **change}))
    with pytest.raises(ValueError, match=match) as info:
        CameraMotion.load(path)
    assert "\n" not in str(info.value)


def test_not_json_and_missing_file(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text("{nope")
    with pytest.raises(ValueError, match="not valid JSON"):
        CameraMotion.load(path)
    with pytest.raises(ValueError, match="not found"):
        CameraMotion.load(tmp_path / "missing.json")
    path.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ValueError, match="motion file"):
        CameraMotion.load(path)


@pytest.mark.parametrize("kwargs, match", [
    (dict(weights=[np.nan, 1]), "finite"),
    (dict(poses=[[np.inf, 0], [0, 0]]), "finite"),
    (dict(weights=[-1, 2]), ">= 0"),
])
def test_bad_motion_arguments_name_the_parameter(cam, kwargs, match):
    args = dict(model="translation", intrinsics=cam, poses=[[0, 0], [1, 0]], weights=[1, 1])
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        CameraMotion(**args)


def test_mass_radius_ignores_a_faint_stray_pose(cam):
    # a delta with 90 % of the weight and a stray pose 9 px away: the extent's radius
    # reads the stray pose, the 80 % mass radius only the centroid's offset from the delta
    m = CameraMotion("translation", cam, [[0, 0], [9, 0]], [0.9, 0.1])
    assert m.max_displacement() == pytest.approx(8.1)
    assert m.mass_radius(0.8) == pytest.approx(0.9)
    # an even path: both radii are its half-length
    even = CameraMotion("translation", cam, [[0, 0], [10, 0]], [1, 1])
    assert even.mass_radius(0.8) == pytest.approx(5.0) == even.max_displacement()
    with pytest.raises(ValueError, match="share"):
        m.mass_radius(0)


def test_band_limited_psf_ncc_forgives_only_what_the_photo_cannot_carry(cam):
    """A thin path and the same path doubled 3 px across it differ at the pixel scale and
    agree at the resolution of a photo upscaled 6 times; a path turned by 30 degrees
    still disagrees there."""
    from napari_edgecme.core.metrics import band_sigma_for_upscale, motion_psf_ncc

    line = [[x, 0.0] for x in range(-10, 11)]
    truth = CameraMotion("translation", cam, line, np.ones(len(line)))
    doubled = [[x, dy] for x, _ in line for dy in (-1.5, 1.5)]
    thick = CameraMotion("translation", cam, doubled, np.ones(len(doubled)))
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    turned = CameraMotion("translation", cam, [[x * c, x * s] for x, _ in line],
                          np.ones(len(line)))
    sigma = band_sigma_for_upscale(6.0)
    assert motion_psf_ncc(thick, truth) < 0.1
    assert motion_psf_ncc(thick, truth, band_sigma=sigma) > 0.95
    assert motion_psf_ncc(turned, truth, band_sigma=sigma) < 0.8
    assert motion_psf_ncc(thick, truth, band_sigma=0.0) == motion_psf_ncc(thick, truth)
    # the Gaussian's transfer exp(-2 pi^2 sigma^2 f^2) is 1/2 at the Nyquist limit 1 / (2 u)
    assert np.exp(-2 * np.pi**2 * sigma**2 / 12.0**2) == pytest.approx(0.5)
    assert band_sigma_for_upscale(1.0) == 0.0


@pytest.mark.parametrize("kwargs, match", [
    ({"band_sigma": -1.0}, "band_sigma must be a finite number >= 0"),
    ({"band_sigma": float("nan")}, "band_sigma must be a finite number >= 0"),
])
def test_band_limited_psf_ncc_refuses_a_bad_sigma_in_one_line(cam, kwargs, match):
    from napari_edgecme.core.metrics import band_sigma_for_upscale, motion_psf_ncc

    m = CameraMotion("translation", cam, [[0, 0], [3, 0]], [1, 1])
    with pytest.raises(ValueError, match=match):
        motion_psf_ncc(m, m, **kwargs)
    with pytest.raises(ValueError, match="factor must be a finite number > 0"):
        band_sigma_for_upscale(0.0)
