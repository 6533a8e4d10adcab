"""Claims about the blur operators: exact adjoints, EFF against the exact warp-sum."""

import numpy as np
import pytest
from scipy.signal import fftconvolve

from napari_edgecme import CameraMotion, Intrinsics
from napari_edgecme.core.operators import (
    OPERATORS,
    EfficientFilterFlow,
    EfficientFilterFlowWeights,
    PatchGrid,
    WarpSum,
    dottest,
)
from napari_edgecme.core.synth import densify_path, random_trajectory, sample_image


@pytest.fixture(scope="module")
def shaky():
    cam = Intrinsics.from_image_shape((70, 90))
    poses = random_trajectory("rotation", cam, 9, 14, roll=1.0, rng=5)
    return CameraMotion.from_trajectory(poses, "rotation", cam)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("name", sorted(OPERATORS))
def test_every_operator_has_an_exact_adjoint(name, dtype, shaky, rng):
    image = rng.random((2, *shaky.image_shape)) if name.endswith("weights") else np.zeros(
        shaky.image_shape)
    op = OPERATORS[name](shaky, image, dtype=dtype)
    tol = 1e-4 if dtype == np.float32 else 1e-10
    assert dottest(op, rng) < tol
    assert op.forward(rng.random(op.shape_in)).dtype == dtype


def test_eff_adjoint_is_exact_with_a_crop_origin_and_uneven_tiles(shaky, rng):
    op = EfficientFilterFlow(shaky, shape=(37, 53), origin=(10.0, -4.0), stride=(20, 16),
                             overlap=(8, 6), dtype=np.float64)
    assert dottest(op, rng) < 1e-10


@pytest.mark.parametrize("shape, stride, overlap", [((64, 90), 20, 10), ((7, 200), 50, 50),
                                                     ((33, 33), 33, 0)])
def test_patch_windows_sum_to_one(shape, stride, overlap):
    grid = PatchGrid(shape, 5, stride, overlap)
    ones = np.ones((grid.n_patches, *grid.patch_shape))
    assert grid.add_windowed(ones, np.float64) == pytest.approx(np.ones(shape))


def test_eff_matches_exact_warp_sum_on_a_31px_rotational_shake():
    # 256 px (a quarter of the warping of the former 512 px) with 32 px tiles, the size the
    # deconvolution picks for this motion (deconv._auto_stride). Measured: 1.8 % here; the
    # operator's default 128 px tiles (2 x 2 on this frame) give 3.2 %, and at 512 px
    # 1.3 % (default tiles) and 0.9 % (32 px).
    image = sample_image("camera", 256)
    cam = Intrinsics.from_image_shape(image.shape)
    motion = densify_path(random_trajectory("rotation", cam, 31, 40, rng=0), "rotation", cam)
    exact = WarpSum(motion).forward(image)
    eff = EfficientFilterFlow(motion, stride=32).forward(image)
    rel = np.linalg.norm(eff - exact) / np.linalg.norm(exact)
    print(f"EFF vs exact, 256x256, 32 px tiles, 31 px rotation: relative L2 error {rel:.4f}")
    assert rel < 0.02


def test_translation_model_is_plain_convolution(rng):
    cam = Intrinsics.from_image_shape((50, 64))
    m = CameraMotion("translation", cam, [[0, 0], [3, 1], [-2, 4], [1.5, -2.5]], [1, 2, 1, 1])
    kernel = m.psf([[0, 0]], 11)[0]
    f = rng.random(cam.image_shape)
    want = fftconvolve(f, kernel, mode="same")
    for op in (EfficientFilterFlow(m, dtype=np.float64), WarpSum(m, dtype=np.float64)):
        assert op.forward(f) == pytest.approx(want, abs=1e-12)


@pytest.mark.parametrize("model", ["translation", "inplane", "rotation"])
def test_identity_motion_is_the_identity(model, rng):
    cam = Intrinsics.from_image_shape((40, 30))
    f = rng.random(cam.image_shape)
    m = CameraMotion.identity(model, cam)
    for name in ("eff", "warp-sum"):
        assert OPERATORS[name](m, f, dtype=np.float64).forward(f) == pytest.approx(f, abs=1e-12)


def test_weights_view_agrees_with_image_view(shaky, rng):
    f = rng.random(shaky.image_shape)
    op = EfficientFilterFlowWeights(f, shaky.model, shaky.intrinsics, shaky.poses,
                                    dtype=np.float64)
    via_weights = op.forward(shaky.weights)
    via_image = EfficientFilterFlow(shaky, psf_size=op.grid.psf_size, dtype=np.float64).forward(f)
    assert via_weights == pytest.approx(via_image, abs=1e-12)


def test_shape_mismatch_is_named(shaky):
    op = EfficientFilterFlow(shaky)
    with pytest.raises(ValueError, match=r"x must have shape \(70, 90\)"):
        op.forward(np.zeros((3, 3)))
