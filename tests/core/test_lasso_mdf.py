"""Claims about the MDF solver and data terms: the lasso's optimality, and that the cheap
quadratics equal the filter-flow objectives they stand for."""

import numpy as np
import pytest
from scipy.signal import fftconvolve

from napari_edgecme import Intrinsics, pose_grid
from napari_edgecme.core.lasso import QuadraticTerm, nonneg_lasso
from napari_edgecme.core.linop import MatrixOperator
from napari_edgecme.core.mdf import edge_profile_term, gradient_term, masked_eff_matrix, psf_basis
from napari_edgecme.core.operators import EfficientFilterFlowWeights, PatchGrid


def test_nonneg_lasso_satisfies_the_kkt_conditions(rng):
    A = rng.standard_normal((80, 40))
    w_true = np.zeros(40)
    w_true[[3, 17, 29]] = [0.5, 0.3, 0.2]
    y = A @ w_true + 0.01 * rng.standard_normal(80)
    term = QuadraticTerm.least_squares(MatrixOperator(A), y)
    lam = 0.05
    res = nonneg_lasso(term, lam, np.zeros(40), max_iter=5000, tol=1e-10)
    grad = A.T @ (A @ res.x) - A.T @ y + lam
    assert res.converged
    assert np.all(res.x >= 0)
    active = res.x > 1e-8
    assert np.abs(grad[active]).max() < 1e-5  # stationary on the support
    assert grad[~active].min() > -1e-5  # no descent direction off the support
    assert set(np.argsort(res.x)[-3:]) == {3, 17, 29}
    seen = []
    again = nonneg_lasso(term, lam, np.zeros(40), max_iter=50, tol=1e-10,
                         callback=lambda record: seen.append(record.iterate.copy()))
    assert len(seen) == again.nit and np.array_equal(seen[-1], again.x)


def test_a_callback_stops_the_lasso_with_the_current_iterate(rng):
    A = rng.standard_normal((60, 30))
    y = A @ np.abs(rng.standard_normal(30))
    term = QuadraticTerm.least_squares(MatrixOperator(A), y)
    full = nonneg_lasso(term, 0.1, np.zeros(30), max_iter=100, tol=0.0)
    assert full.nit > 7  # uninterrupted, it runs on
    seen = []

    def stop_at_seven(record):
        seen.append(record.iterate.copy())
        if record.step == 7:
            raise StopIteration

    stopped = nonneg_lasso(term, 0.1, np.zeros(30), max_iter=100, tol=0.0,
                           callback=stop_at_seven)
    assert stopped.nit == 7 and not stopped.converged and "stopped" in stopped.message
    np.testing.assert_array_equal(stopped.x, seen[-1])
    assert not np.array_equal(stopped.x, full.x)


@pytest.fixture(scope="module")
def setting():
    rng = np.random.default_rng(1)
    cam = Intrinsics.from_image_shape((90, 110))
    poses = pose_grid("rotation", cam, 7).poses()
    grid = PatchGrid((90, 110), 13, stride=40, overlap=20)
    basis = psf_basis("rotation", cam, poses, grid)
    return rng, cam, poses, grid, basis


def test_gradient_term_is_the_windowed_residual_of_eq22(setting):
    rng, _cam, poses, grid, basis = setting
    f = rng.standard_normal((2, 90, 110))
    g = rng.standard_normal((2, 90, 110))
    term = gradient_term(f, g, grid, basis)
    w = rng.random(len(poses))
    pf, pg = grid.windowed_patches(f), grid.windowed_patches(g)
    K = grid.psf_size
    h = (K - 1) // 2
    k = (basis @ w).reshape(-1, K, K)
    direct = 0.0
    for c in range(2):
        for r in range(grid.n_patches):
            blurred = fftconvolve(pf[c, r], k[r], mode="full")
            target = np.zeros_like(blurred)
            target[h:h + pg.shape[-2], h:h + pg.shape[-1]] = pg[c, r]
            direct += np.sum((blurred - target) ** 2)
    assert term.value(w) == pytest.approx(direct / 2, rel=1e-5)  # float32 products
    assert term.constant == pytest.approx(np.sum(pg**2))
    # and its gradient is Q w - b (central differences are exact on a quadratic)
    e = np.zeros_like(w)
    e[5] = 1.0
    numeric = (term.value(w + e) - term.value(w - e)) / 2
    assert numeric == pytest.approx((term.matvec(w) - term.linear)[5], rel=1e-4)


def test_edge_profile_term_uses_the_exact_masked_eff_rows(setting):
    rng, cam, poses, grid, basis = setting
    prediction = np.zeros((90, 110))
    prediction[20:60, 50] = 0.7
    prediction[70, 10:80] = 0.4
    mask = np.zeros((90, 110), bool)
    mask[30:40, 40:60] = True
    mask[60:80, 30:35] = True
    op = EfficientFilterFlowWeights(prediction, "rotation", cam, poses, stride=40, overlap=20,
                                    psf_size=grid.psf_size, dtype=np.float64)
    w = rng.random(len(poses))
    rows = masked_eff_matrix(prediction, mask, grid) @ basis
    assert rows @ w == pytest.approx(op.forward(w)[mask], rel=1e-10, abs=1e-12)
    target = rng.random((90, 110))
    term = edge_profile_term(prediction, target, mask, grid, basis)
    resid = op.forward(w)[mask] - target[mask]
    assert term.value(w) == pytest.approx(resid @ resid / 2)


def test_clean_mdf_drops_weights_under_the_floor_and_light_clusters():
    """clean_mdf keeps the camera's path: weights of at least WEIGHT_FLOOR x the largest
    on it, and clusters of at least CLUSTER_FLOOR x the heaviest's mass; the rest is
    zeroed, the MDF renormalised and its centroid moved to the grid's centre."""
    from napari_edgecme.core.pyramid import CLUSTER_FLOOR, WEIGHT_FLOOR, clean_mdf

    w = np.zeros((15, 15))
    w[3, 3:11] = 1.0  # the path: eight poses along a row 4 steps above the centre
    w[3, 11] = WEIGHT_FLOOR  # a faint end of the path, at the floor
    w[3, 12] = 0.5 * WEIGHT_FLOOR  # fainter still: under the floor
    w[12, 1] = 0.5 * CLUSTER_FLOOR * 8  # an isolated ghost: half the share a cluster needs
    cleaned = clean_mdf(w)
    assert cleaned.sum() == pytest.approx(1.0)
    # re-centred: the path moved down to the centre row, its columns unchanged
    assert not cleaned[3].any()
    kept = np.flatnonzero(cleaned[7] > 0)
    assert kept.tolist() == list(range(3, 12))  # the path and its faint end; not col 12
    assert np.count_nonzero(cleaned) == 9  # the ghost is gone too
    idx = np.indices(w.shape).reshape(2, -1)
    assert np.allclose(idx @ cleaned.ravel(), [7, 7], atol=0.5)


def test_clean_mdf_floor_is_a_parameter():
    """A lower ``weight_floor`` keeps a faint tail that the default drops."""
    from napari_edgecme.core.pyramid import WEIGHT_FLOOR, clean_mdf

    w = np.zeros((9, 9))
    w[4, 2:7] = 1.0
    w[4, 7] = 0.5 * WEIGHT_FLOOR
    assert clean_mdf(w)[4].astype(bool).sum() == 5
    assert clean_mdf(w, weight_floor=0.25 * WEIGHT_FLOOR)[4].astype(bool).sum() == 6
