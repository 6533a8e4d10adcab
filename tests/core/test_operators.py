"""Claims about the linear operators: every adjoint exact, operators compose, EFF against
the exact warp-sum."""

import importlib
import pkgutil

import numpy as np
import pytest
from scipy.signal import fftconvolve

import napari_edgecme.core
from napari_edgecme import CameraMotion, Intrinsics, pose_grid
from napari_edgecme.core.deconv_prior import Gradient, grad, grad_adjoint
from napari_edgecme.core.deconv_solvers import CirculantPreconditioner, LatentDomain
from napari_edgecme.core.linop import Crop, LinearOperator, MatrixOperator, dottest
from napari_edgecme.core.mdf import edge_profile_term, gradient_term, psf_basis
from napari_edgecme.core.measurement import measurement_matrix
from napari_edgecme.core.operators import (
    EfficientFilterFlow,
    EfficientFilterFlowWeights,
    PatchGrid,
    WarpSum,
    WarpSumWeights,
)
from napari_edgecme.core.profiles import EdgeProfiles
from napari_edgecme.core.synth import densify_path, random_trajectory, sample_image

SHAPE = (70, 90)


def _shaky() -> CameraMotion:
    cam = Intrinsics.from_image_shape(SHAPE)
    poses = random_trajectory("rotation", cam, 9, 14, roll=1.0, rng=5)
    return CameraMotion.from_trajectory(poses, "rotation", cam)


def _fixed_image(dtype, channels=2):
    return np.random.default_rng(3).random((channels, *SHAPE)).astype(dtype)


def _domain(dtype) -> LatentDomain:
    """A block of the frame on its padded latent domain (the deconvolution's ``M T``)."""
    return LatentDomain(_shaky(), (10, 60, 0, 90), pad=6, stride=24, dtype=dtype)


def _profiles() -> EdgeProfiles:
    rng = np.random.default_rng(4)
    n, offsets = 6, np.arange(-8.0, 9.0)
    curves = rng.random((n, offsets.size))
    return EdgeProfiles(rng.uniform(10, 60, (n, 2)), rng.uniform(0, np.pi, n), np.zeros(n),
                        np.ones(n), curves, curves, offsets, np.ones(n))


def _mdf_setting():
    cam = Intrinsics.from_image_shape((48, 56))
    poses = pose_grid("rotation", cam, 5).poses()
    grid = PatchGrid((48, 56), 11, stride=24, overlap=12)
    return cam, poses, grid, psf_basis("rotation", cam, poses, grid)


def _gradient_term_normal(dtype):
    _cam, _poses, grid, basis = _mdf_setting()
    rng = np.random.default_rng(6)
    return gradient_term(rng.standard_normal((2, 48, 56)), rng.standard_normal((2, 48, 56)),
                         grid, basis).normal


def _edge_profile_term_normal(dtype):
    _cam, _poses, grid, basis = _mdf_setting()
    prediction = np.zeros((48, 56))
    prediction[10:40, 20] = 0.7
    prediction[30, 5:50] = 0.4
    mask = np.zeros((48, 56), bool)
    mask[15:30, 15:30] = True
    return edge_profile_term(prediction, prediction, mask, grid, basis).normal


#: Every linear operator of the engine, by name: ``OPERATORS[name](dtype)`` builds one on
#: a small problem. The dot test runs over all of them, and
#: :func:`test_every_operator_class_is_registered` fails when a class has no entry.
OPERATORS = {
    # the blur T (Eq. 8), in the image and in the weights
    "warp-sum": lambda dtype: WarpSum(_shaky(), dtype=dtype),
    "warp-sum-weights": lambda dtype: WarpSumWeights(
        _fixed_image(dtype), "rotation", _shaky().intrinsics, _shaky().poses, dtype=dtype),
    "eff": lambda dtype: EfficientFilterFlow(_shaky(), dtype=dtype),
    "eff-crop-origin-uneven-tiles": lambda dtype: EfficientFilterFlow(
        _shaky(), shape=(37, 53), origin=(10.0, -4.0), stride=(20, 16), overlap=(8, 6),
        dtype=dtype),
    "eff-weights": lambda dtype: EfficientFilterFlowWeights(
        _fixed_image(dtype), "rotation", _shaky().intrinsics, _shaky().poses, dtype=dtype),
    # the pieces of the masked data terms and of the prior
    "crop": lambda dtype: Crop((20, 30), (slice(3, 17), slice(5, None)), dtype),
    "gradient": lambda dtype: Gradient((17, 23), dtype),
    "matrix": lambda dtype: MatrixOperator(
        np.random.default_rng(2).standard_normal((7, 5)).astype(dtype)),
    # the deconvolution: M T, its normal operator and the CG preconditioner
    "masked-blur": lambda dtype: _domain(dtype).data,
    "image-step-normal": lambda dtype: _domain(dtype).normal(750.0, 8.0),
    "circulant-preconditioner": lambda dtype: CirculantPreconditioner(
        _domain(dtype)).operator(750.0, 8.0),
    "difference-and-negation": lambda dtype: (
        -(2.0 * Gradient((9, 11), dtype)).T @ Gradient((9, 11), dtype)
        - Crop((9, 11), (slice(0, 9), slice(0, 11)), dtype)),
    # the MDF data terms (Eqs. 13-16, 19, 22)
    "measurement-matrix": lambda dtype: MatrixOperator(measurement_matrix(
        _profiles(), "rotation", _shaky().intrinsics, _shaky().poses).astype(dtype)),
    "gradient-term-normal": _gradient_term_normal,
    "edge-profile-term-normal": _edge_profile_term_normal,
}

#: Operators computed in float32 whatever their dtype.
FLOAT32_INSIDE = {"gradient-term-normal"}


def _parts(op: LinearOperator):
    """The operator and, recursively, every operator it is built from."""
    yield op
    for value in vars(op).values():
        if isinstance(value, LinearOperator):
            yield from _parts(value)


def _subclasses(cls):
    for sub in cls.__subclasses__():
        yield sub
        yield from _subclasses(sub)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("name", sorted(OPERATORS))
def test_every_operator_has_an_exact_adjoint(name, dtype, rng):
    op = OPERATORS[name](dtype)
    precise = dtype == np.float64 and op.dtype == np.float64 and name not in FLOAT32_INSIDE
    assert dottest(op, rng) < (1e-10 if precise else 1e-4)
    assert op.forward(rng.random(op.shape_in)).dtype == op.dtype
    assert op.adjoint(rng.random(op.shape_out)).dtype == op.dtype


def test_every_operator_class_is_registered():
    for module in pkgutil.iter_modules(napari_edgecme.core.__path__):
        importlib.import_module(f"napari_edgecme.core.{module.name}")
    registered = {type(part) for make in OPERATORS.values() for part in _parts(make(np.float64))}
    missing = {cls.__qualname__ for cls in _subclasses(LinearOperator)} - {
        cls.__qualname__ for cls in registered}
    assert not missing, f"operators without a dot test: {sorted(missing)}"


def test_operators_compose_like_the_steps_written_out(rng):
    domain = _domain(np.float64)
    v = rng.standard_normal(domain.shape)
    by_hand = domain.op.adjoint(Crop(domain.shape, domain.inner, np.float64).adjoint(
        domain.op.forward(v)[domain.inner]))
    by_hand = 750.0 * by_hand + 8.0 * grad_adjoint(*grad(v))
    assert np.array_equal(domain.normal(750.0, 8.0) @ v, by_hand)
    A = MatrixOperator(rng.standard_normal((4, 3)))
    B = MatrixOperator(rng.standard_normal((3, 5)))
    x = rng.standard_normal(5)
    assert (A @ B) @ x == pytest.approx(A.matrix @ (B.matrix @ x))
    y = rng.standard_normal(4)
    assert (A @ B).T @ y == pytest.approx(B.matrix.T @ (A.matrix.T @ y))
    assert (A.T).T is A
    assert (2 * A - A) @ x[:3] == pytest.approx(A.matrix @ x[:3])
    assert np.float32(2) * A @ x[:3] == pytest.approx(2 * A.matrix @ x[:3])


def test_incompatible_operators_are_refused():
    with pytest.raises(ValueError, match="cannot compose"):
        Gradient((5, 5)) @ Gradient((5, 5))
    with pytest.raises(ValueError, match="cannot add"):
        Gradient((5, 5)) + Gradient((5, 6))


@pytest.mark.parametrize("shape, stride, overlap", [((64, 90), 20, 10), ((7, 200), 50, 50),
                                                     ((33, 33), 33, 0)])
def test_patch_windows_sum_to_one(shape, stride, overlap):
    grid = PatchGrid(shape, 5, stride, overlap)
    ones = np.ones((grid.n_patches, *grid.patch_shape))
    assert grid.add_windowed(ones, np.float64) == pytest.approx(np.ones(shape))


def test_eff_matches_exact_warp_sum_on_a_31px_rotational_shake():
    # 256 px (a quarter of the warping of the former 512 px) with 32 px tiles, the size the
    # deconvolution picks for this motion (deconv_blocks.auto_stride). Measured: 1.8 % here; the
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
    for op in (EfficientFilterFlow(m, dtype=np.float64), WarpSum(m, dtype=np.float64)):
        assert op @ f == pytest.approx(f, abs=1e-12)


def test_weights_view_agrees_with_image_view(rng):
    shaky = _shaky()
    f = rng.random(shaky.image_shape)
    op = EfficientFilterFlowWeights(f, shaky.model, shaky.intrinsics, shaky.poses,
                                    dtype=np.float64)
    via_weights = op.forward(shaky.weights)
    via_image = EfficientFilterFlow(shaky, psf_size=op.grid.psf_size, dtype=np.float64).forward(f)
    assert via_weights == pytest.approx(via_image, abs=1e-12)


def test_shape_mismatch_is_named():
    op = EfficientFilterFlow(_shaky())
    with pytest.raises(ValueError, match=r"x must have shape \(70, 90\)"):
        op.forward(np.zeros((3, 3)))
