"""EpAlone: camera motion from edge profiles alone (Eq. 16, robustly reweighted).

Claims checked on a scene with exactly known edges (``test_edges``' shapes), under
known shakes: EpAlone recovers the motion; the data term is the weighted Eq. 16; a false
profile loses its weight against the right motion while the true ones keep theirs; the
reweighted fit survives a share of false profiles that bends the plain least squares;
on a scene whose edges are soft, the soft-edge profile model is chosen and recovers the
motion the step model blurs into a blob, and on ideal steps the step model is kept.
"""

import functools

import numpy as np
import pytest
from scipy import ndimage, sparse
from test_edges import _scene, _shaken

from napari_edgecme.core import estimate, profile_fit
from napari_edgecme.core.edges import extract_edge_profiles
from napari_edgecme.core.estimate import EP_MAX_MISFIT, estimate_motion
from napari_edgecme.core.measurement import (
    edge_spread_matrix,
    measurement_matrix,
    profile_misfit,
    profile_term,
)
from napari_edgecme.core.metrics import motion_psf_ncc
from napari_edgecme.core.profile_fit import (
    EP_EDGE_SPREAD,
    MISFIT_SCALE_FLOOR,
    NARROW_PROFILE_POWER,
    PRIOR_FLOOR,
    XU_EP_GATE_MISFIT,
    RobustProfileFit,
    width_weight,
)
from napari_edgecme.core.profiles import EdgeProfiles
from napari_edgecme.core.synth import make_case


def _with_false_profiles(prof: EdgeProfiles, share: float, seed: int) -> tuple:
    """``prof`` with ``share`` of its derivatives replaced by no blur at all (a sharp step).

    The false profile that hurts most: an unblurred edge (texture, a reflection) pulls
    the motion towards the identity.
    """
    rng = np.random.default_rng(seed)
    false = np.zeros(len(prof), bool)
    false[rng.choice(len(prof), round(share * len(prof)), replace=False)] = True
    derivatives = prof.derivatives.copy()
    derivatives[false] = (prof.offsets == 0).astype(float)
    corrupted = EdgeProfiles(prof.centroids, prof.normal_angle, prof.c1, prof.c2,
                             prof.profiles, derivatives, prof.offsets, prof.quality,
                             image_shape=prof.image_shape, max_blur=prof.max_blur,
                             stats=prof.stats, curvature=prof.curvature, window=prof.window,
                             measures=prof.measures)
    return corrupted, false


@pytest.mark.parametrize("model, extent, seed, bound", [
    ("rotation", 11, 3, 0.85), ("rotation", 11, 4, 0.85),
    ("inplane", 9, 3, 0.65), ("inplane", 9, 4, 0.65),
])
def test_epalone_recovers_a_known_shake_from_profiles_alone(model, extent, seed, bound):
    """Measured: rotation 0.89 / 0.90, in-plane 0.72 / 0.74 (PSF NCC against the truth)."""
    case, _ = _shaken(model, extent, seed)
    est = estimate_motion(case.blurred, "ep", model, extent + 2,
                          case.motion.intrinsics.focal_px, rng=0)
    assert est.latent is None  # no latent image: the profiles alone
    assert motion_psf_ncc(est.motion, case.motion) >= bound
    assert 0 <= est.info.profile_misfit < 0.1
    assert est.info.edge_spread == 0  # ideal steps: the soft-edge model fits them worse
    assert "step edges" in est.info.message


def test_the_edge_spread_is_a_gaussian_integrated_over_each_bin():
    sigma = 1.0
    G = edge_spread_matrix(41, sigma).toarray()
    k = np.arange(41) - 20
    column = G[:, 20]
    assert column.sum() == pytest.approx(1.0, abs=1e-12)  # mass kept inside the range
    assert k @ column == pytest.approx(0.0, abs=1e-12)  # centred: no shift of a profile
    assert k ** 2 @ column == pytest.approx(sigma ** 2 + 1 / 12, rel=1e-3)  # + the bin
    assert np.allclose(G, G.T)
    assert G[:, 0].sum() < 0.75  # at the range's end the mass beyond is dropped


def test_the_soft_edge_measurement_is_the_spread_applied_to_each_profile(one_case_profiles):
    _, prof, truth, M = one_case_profiles
    soft = measurement_matrix(prof, truth.model, truth.intrinsics, truth.poses,
                              edge_spread=1.0)
    G = edge_spread_matrix(prof.offsets.size, 1.0)
    spread = sparse.kron(sparse.identity(len(prof)), G) @ M
    assert np.allclose(soft.toarray(), spread.toarray())


@functools.cache
def _soft_shaken(seed: int):
    """The reference scene with its edges softened by a 1 px Gaussian, then shaken."""
    case = make_case(ndimage.gaussian_filter(_scene(), 1.0), "rotation", extent=11,
                     noise=0.01, rng=seed)
    return case, extract_edge_profiles(case.blurred, max_blur=13, rng=0)


@pytest.mark.parametrize("seed", [3, 4])
def test_on_soft_edges_the_spread_model_is_chosen_and_recovers_a_thin_path(seed,
                                                                           monkeypatch):
    """Measured PSF NCC: 0.875 / 0.895 with the spread, 0.750 / 0.731 as steps (the step
    model's estimate is a blob: blur extent 14 px for an 11 px shake; 11.7 with it)."""
    case, prof = _soft_shaken(seed)
    focal = case.motion.intrinsics.focal_px
    est = estimate_motion(case.blurred, "ep", "rotation", 13, focal, profiles=prof, rng=0)
    assert est.info.edge_spread == EP_EDGE_SPREAD
    assert "soft edges" in est.info.message
    soft_ncc = motion_psf_ncc(est.motion, case.motion)
    assert soft_ncc >= 0.85
    assert est.motion.blur_extent() <= 1.15 * case.motion.blur_extent()
    monkeypatch.setattr(estimate, "EP_EDGE_SPREAD", 0.0)  # the step model only
    steps = estimate_motion(case.blurred, "ep", "rotation", 13, focal, profiles=prof, rng=0)
    assert steps.info.edge_spread == 0
    assert motion_psf_ncc(steps.motion, case.motion) <= soft_ncc - 0.08
    assert steps.motion.blur_extent() >= 1.2 * case.motion.blur_extent()


def test_the_data_term_is_eq16_weighted_per_profile(one_case_profiles):
    _, prof, truth, M = one_case_profiles
    weights = np.linspace(0.2, 1.0, len(prof))
    term = profile_term(M, prof, weights)
    w = truth.weights
    residual = ((M @ w).reshape(len(prof), -1) - prof.derivatives) ** 2
    assert term.value(w) == pytest.approx(0.5 * np.sum(weights[:, None] * residual), rel=1e-9)
    assert np.allclose(profile_misfit(M, prof, w),
                       residual.sum(1) / (prof.derivatives ** 2).sum(1))
    with pytest.raises(ValueError, match="non-negative"):
        profile_term(M, prof, -weights)


def test_a_false_profile_loses_its_weight_and_the_true_ones_keep_theirs(one_case_profiles):
    _, prof, truth, M = one_case_profiles
    corrupted, false = _with_false_profiles(prof, 0.2, seed=0)
    fit = RobustProfileFit(corrupted)
    fit.update(M, truth.weights)
    share = fit.weights / fit.prior
    assert np.all(share[false] < 0.2)
    assert np.median(share[~false]) > 0.8


def test_profiles_that_all_fit_are_not_down_weighted_for_noise(one_case_profiles):
    _, prof, truth, M = one_case_profiles
    exact = EdgeProfiles(prof.centroids, prof.normal_angle, prof.c1, prof.c2, prof.profiles,
                         (M @ truth.weights).reshape(len(prof), -1), prof.offsets,
                         prof.quality, image_shape=prof.image_shape, measures=prof.measures)
    fit = RobustProfileFit(exact)
    fit.update(M, truth.weights)
    assert np.max(fit.misfit) < 1e-20
    assert np.all(fit.weights == fit.prior)  # the scale is floored at MISFIT_SCALE_FLOOR
    assert MISFIT_SCALE_FLOOR > 0


def test_a_profile_narrower_than_the_motion_predicts_loses_weight_and_a_wider_one_does_not(
        one_case_profiles):
    """Variances add under convolution: a faithful profile is the projection convolved
    with the edge's own transition, so only the too-narrow side is evidence against it."""
    _, prof, truth, M = one_case_profiles
    predicted = (M @ truth.weights).reshape(len(prof), -1)
    offsets = prof.offsets.astype(float)
    wider = ndimage.gaussian_filter1d(predicted, 1.5, axis=1, mode="constant")
    unblurred = np.tile((offsets == 0).astype(float), (len(prof), 1))
    halfway = 0.5 * (predicted + unblurred)  # a transition cut short
    assert np.all(width_weight(predicted, predicted, offsets) == 1.0)
    assert np.all(width_weight(wider, predicted, offsets) == 1.0)
    def variance(rows):  # each row as a mass distribution over the offsets
        mean = rows @ offsets / rows.sum(1)
        return ((offsets - mean[:, None]) ** 2 * rows).sum(1) / rows.sum(1)

    ratio = variance(halfway) / variance(predicted)
    assert np.all(ratio < 1)
    assert np.allclose(width_weight(halfway, predicted, offsets),
                       ratio ** NARROW_PROFILE_POWER)
    assert np.max(width_weight(unblurred, predicted, offsets)) < 0.02
    corrupted, false = _with_false_profiles(prof, 0.2, seed=0)
    fit = RobustProfileFit(corrupted)
    fit.update(M, truth.weights)  # each weight: prior x Cauchy weight x width weight
    cauchy = 1 / (1 + (fit.misfit / max(2 * np.median(fit.misfit), MISFIT_SCALE_FLOOR)) ** 2)
    assert np.allclose(fit.weights, fit.prior * cauchy
                       * width_weight(corrupted.derivatives, predicted, offsets))
    assert np.max(fit.weights[false] / fit.prior[false]) < 0.02


@pytest.mark.parametrize("seed", [0, 1])
def test_the_width_check_holds_the_motion_against_a_third_of_unblurred_profiles(
        seed, monkeypatch):
    """Measured PSF NCC with 30% of the profiles unblurred (no refusal): 0.72 / 0.69 with
    the width check, 0.34 / 0.40 without (the Cauchy weight alone needs a majority it can
    trust; the width check does not, as an unblurred profile is narrower than any blur)."""
    case, prof = _shaken("rotation", 11, 3)
    corrupted, _ = _with_false_profiles(prof, 0.3, seed)
    focal = case.motion.intrinsics.focal_px
    monkeypatch.setattr(estimate, "EP_MAX_MISFIT", np.inf)
    checked = estimate_motion(case.blurred, "ep", "rotation", 13, focal, profiles=corrupted,
                              rng=0)
    monkeypatch.setattr(profile_fit, "NARROW_PROFILE_POWER", 0.0)
    unchecked = estimate_motion(case.blurred, "ep", "rotation", 13, focal,
                                profiles=corrupted, rng=0)
    assert motion_psf_ncc(checked.motion, case.motion) >= 0.65
    assert motion_psf_ncc(unchecked.motion, case.motion) <= 0.5


def test_the_prior_is_the_confidence_floored(one_case_profiles):
    _, prof, _, _ = one_case_profiles
    fit = RobustProfileFit(prof)
    conf = prof.confidence
    assert np.allclose(fit.prior, np.clip(conf, PRIOR_FLOOR, 1.0))
    unknown = EdgeProfiles(prof.centroids, prof.normal_angle, prof.c1, prof.c2, prof.profiles,
                           prof.derivatives, prof.offsets, prof.quality)
    assert np.all(RobustProfileFit(unknown).prior == 1.0)  # no measures: all trusted alike


@pytest.mark.parametrize("seed", [0, 1])
def test_a_fifth_of_unblurred_profiles_bends_the_estimate_and_the_self_check_says_so(
        seed, monkeypatch):
    """Measured PSF NCC: clean 0.89; a fifth unblurred: 0.73 / 0.72 reweighted with the
    width check, 0.65 / 0.64 without it (0.60 / 0.61 with equal weights). The misfit, over
    all profiles, goes from 0.01 to 0.49: refused."""
    case, prof = _shaken("rotation", 11, 3)
    corrupted, _ = _with_false_profiles(prof, 0.2, seed)
    focal = case.motion.intrinsics.focal_px
    clean = estimate_motion(case.blurred, "ep", "rotation", 13, focal, profiles=prof, rng=0)
    assert motion_psf_ncc(clean.motion, case.motion) >= 0.85
    assert clean.info.profile_misfit < EP_MAX_MISFIT / 4
    with pytest.raises(ValueError, match=r"EpAlone: the \d+ edge profiles do not agree on one "
                                         r"camera motion \(\d+% of their energy"):
        estimate_motion(case.blurred, "ep", "rotation", 13, focal, profiles=corrupted, rng=0)
    monkeypatch.setattr(estimate, "EP_MAX_MISFIT", np.inf)  # what it would have returned
    dirty = estimate_motion(case.blurred, "ep", "rotation", 13, focal, profiles=corrupted,
                            rng=0)
    assert motion_psf_ncc(dirty.motion, case.motion) >= 0.68
    assert dirty.info.profile_misfit > EP_MAX_MISFIT


def test_profiles_of_one_orientation_are_refused_before_any_work():
    """Normals within +-12 degrees (orientation balance 0.01): motion along the edges is
    not measured (Eq. 11), so EpAlone says so instead of guessing it."""
    case, prof = _shaken("rotation", 11, 3)
    phi = np.mod(prof.normal_angle, np.pi)
    parallel = prof.select(np.abs(phi - np.median(phi)) < np.radians(12))
    assert len(parallel) >= 12
    with pytest.raises(ValueError, match=r"nearly parallel normals .* is not measured"):
        estimate_motion(case.blurred, "ep", "rotation", 13, case.motion.intrinsics.focal_px,
                        profiles=parallel, rng=0)


@pytest.fixture(scope="module")
def one_case_profiles():
    case, prof = _shaken("rotation", 11, 3)
    truth = case.motion.recentred()
    M = measurement_matrix(prof, truth.model, truth.intrinsics, truth.poses)
    return case, prof, truth, M


# ---------------------------------------------------------------------------------------
# Xu+Ep: the edge-profile term on top of Xu's L0 alternation (Eq. 22)
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [3, 4])
def test_xu_ep_beats_xu_on_an_edge_rich_scene(seed):
    """Measured PSF NCC, Xu -> Xu+Ep: 0.63 -> 0.84 (seed 3), 0.84 -> 0.88 (seed 4).

    Before Xu had its wide start (``estimate.WIDE_START``) it was 0.62 and 0.59 here and
    the margin asked was 0.15; the wide start rescued Xu on seed 4, not Xu+Ep's lead
    (seeds 5 and 6: 0.91 -> 0.94, 0.88 -> 0.94)."""
    case, _ = _shaken("rotation", 11, seed)
    focal = case.motion.intrinsics.focal_px
    ncc = {m: motion_psf_ncc(estimate_motion(case.blurred, m, "rotation", 13, focal, n_iter=3,
                                             rng=0).motion, case.motion)
           for m in ("xu", "xu+ep")}
    assert ncc["xu+ep"] >= 0.8
    assert ncc["xu+ep"] > ncc["xu"]


def test_xu_ep_runs_as_xu_when_its_profiles_disagree():
    """Two fifths of the profiles unblurred: EpAlone on them leaves 67% unexplained, so
    the edge-profile term would pull the alternation the wrong way; it is dropped."""
    case, prof = _shaken("rotation", 11, 3)
    corrupted, _ = _with_false_profiles(prof, 0.4, seed=0)
    with pytest.warns(UserWarning, match="do not agree on one camera motion"):
        est = estimate_motion(case.blurred, "xu+ep", "rotation", 13,
                              case.motion.intrinsics.focal_px, profiles=corrupted, n_iter=1,
                              rng=0)
    assert est.info.method == "xu" and est.info.profile_misfit > XU_EP_GATE_MISFIT
    assert "disagree" in est.info.message
    assert est.info.start_sparsity is None  # nor started from what they say


def _one_level_xu_run(seed: int, iterations: int):
    """``(case, truth re-centred, run)``: an 11 px camera rotation of a test scene and a
    one-level Xu alternation on it (``iterations`` per start), as Xu+Ep's second start
    runs its finest scale."""
    from napari_edgecme.core.pyramid import contrast_gain

    case, _ = _shaken("rotation", 11, seed)
    truth = case.motion.recentred()
    offset, gain = contrast_gain(case.blurred)
    work = ((case.blurred - offset) * gain).astype(case.blurred.dtype)
    info = estimate.EstimateInfo("xu", "rotation", 13.0, truth.intrinsics.focal_px, 1.0)
    run = estimate._CoarseToFine(work, truth.intrinsics, "rotation", 13.0, [1.0],
                                 [iterations], "xu", None, gain, 2e-3, 0.0, 6e-3, False, info)
    return case, truth, run


def _turned(motion):
    """``motion`` with its path turned by 90 degrees (tilts swapped, one negated): a
    wrong motion of the same length and dwell times."""
    from napari_edgecme.core.motion import CameraMotion

    return CameraMotion(motion.model, motion.intrinsics,
                        motion.poses[:, [1, 0, 2]] * [1, -1, 1], motion.weights)


@pytest.mark.parametrize("seed", [3, 4])
@pytest.mark.parametrize("right_first", [True, False], ids=["right-first", "right-second"])
def test_the_second_start_keeps_the_estimate_with_the_sparser_latent(seed, right_first):
    """Xu+Ep's two starts (``estimate._second_start``): the alternation from the small
    blob, then again from the edge profiles' estimate; both are polished and the one
    kept has the hyper-Laplacian latent with the sparser gradients. Started from the
    true path and from it turned by 90 degrees (PSF NCC 0.1 to the truth; three
    alternations bring it to 0.27-0.29 only), the sparsity picks the right one in
    either order, and the estimate kept has NCC >= 0.8."""
    from napari_edgecme.core.progress import drive

    case, truth, run = _one_level_xu_run(seed, 3)
    turned = _turned(truth)
    assert motion_psf_ncc(turned, case.motion) < 0.2
    first, second = (truth, turned) if right_first else (turned, truth)
    first_estimate, latent, _ = drive(run.iterate(0, 3, start=first))
    info = estimate.EstimateInfo("xu+ep", "rotation", 13.0, truth.intrinsics.focal_px, 1.0)
    kept, _, (polished, polished_latent), _, _ = drive(
        estimate._second_start(run, second, first_estimate, latent, info, 0, 3))
    first_sparsity, second_sparsity = info.start_sparsity
    assert info.start == ("blob" if right_first else "edge profiles")
    assert (first_sparsity < second_sparsity) == right_first
    assert motion_psf_ncc(kept, case.motion) >= 0.8
    # the polish handed on is that of the estimate kept
    assert motion_psf_ncc(polished, kept) >= 0.8 and polished_latent.shape == case.blurred.shape


@pytest.mark.parametrize("sparsities, kept", [((0.30, 0.29), "edge profiles"),
                                              ((0.29, 0.30), "blob")])
def test_the_second_start_follows_the_sparsity_not_the_order(sparsities, kept, monkeypatch):
    """Whatever the two estimates are, the one with the lower gradient sparsity wins,
    and the message says so only when it is the edge profiles' start."""
    from napari_edgecme.core.progress import drive

    _, truth, run = _one_level_xu_run(3, 1)
    first_estimate, latent, _ = drive(run.iterate(0, 1, start=truth))
    values = iter(sparsities)  # the first start's, then the second's
    monkeypatch.setattr(estimate, "gradient_sparsity", lambda latent, band: next(values))
    info = estimate.EstimateInfo("xu+ep", "rotation", 13.0, truth.intrinsics.focal_px, 1.0)
    drive(estimate._second_start(run, truth, first_estimate, latent, info, 0, 1))
    assert info.start == kept and info.start_sparsity == sparsities
    assert ("won (gradient sparsity" in info.message) == (kept == "edge profiles")


@pytest.mark.parametrize("sparsities, kept", [((0.30, 0.31, 0.29), "EpAlone"),
                                              ((0.30, 0.29, 0.31), "edge profiles"),
                                              ((0.29, 0.31, 0.30), "blob")])
def test_with_the_epalone_candidate_the_lowest_of_three_sparsities_wins(sparsities, kept,
                                                                         monkeypatch):
    """The EpAlone estimate itself, offered as a third candidate (``EP_CANDIDATE``), is
    kept when its polished latent is the sparsest -- and then handed on polished, as it
    has no alternation of its own; the message names the winner unless it is the blob."""
    from napari_edgecme.core.progress import drive

    case, truth, run = _one_level_xu_run(3, 1)
    first_estimate, latent, _ = drive(run.iterate(0, 1, start=truth))
    values = iter(sparsities)
    monkeypatch.setattr(estimate, "gradient_sparsity", lambda latent, band: next(values))
    info = estimate.EstimateInfo("xu+ep", "rotation", 13.0, truth.intrinsics.focal_px, 1.0)
    turned = _turned(truth)
    motion, latent, (polished, polished_latent), _, _ = drive(estimate._second_start(
        run, truth, first_estimate, latent, info, 0, 1, candidate=turned))
    assert info.start == kept and info.start_sparsity == sparsities
    assert ("won (gradient sparsity" in info.message) == (kept != "blob")
    if kept == "EpAlone":
        assert "own estimate, polished" in info.message
        assert motion is polished and latent is polished_latent
    else:
        assert motion_psf_ncc(motion, case.motion) >= 0.8


def _offered_candidate(case, profiles, monkeypatch) -> list:
    """Run Xu+Ep briefly and return what its second start was offered as ``candidate``."""
    offered = []
    original = estimate._second_start

    def spy(*args, candidate=None, **kwargs):
        offered.append(candidate)
        return (yield from original(*args, candidate=candidate, **kwargs))

    monkeypatch.setattr(estimate, "_second_start", spy)
    estimate_motion(case.blurred, "xu+ep", "rotation", 13, case.motion.intrinsics.focal_px,
                    profiles=profiles, n_iter=1, rng=0)
    return offered


@pytest.mark.parametrize("seed", [3, 4])
def test_the_epalone_candidate_is_offered_on_step_edges_only(seed, monkeypatch):
    """EpAlone's own test of the profile model decides: on the scene of ideal step edges
    the step model fits better and the EpAlone estimate (close to the truth) is a third
    candidate; on the same scene with soft edges the spread model fits better, the step
    fit is a blob (see the soft-edge test above), and it is not offered."""
    case, prof = _shaken("rotation", 11, seed)
    offered = _offered_candidate(case, prof, monkeypatch)
    assert len(offered) == 1 and offered[0] is not None
    assert motion_psf_ncc(offered[0], case.motion) >= 0.8
    soft_case, soft_prof = _soft_shaken(seed)
    assert _offered_candidate(soft_case, soft_prof, monkeypatch) == [None]


@pytest.mark.parametrize("seed", [3, 4])
def test_the_epalone_candidate_is_not_offered_when_the_normals_are_nearly_parallel(
        seed, monkeypatch):
    """The same step edges, keeping only the profiles whose normals lie within 29 degrees
    of one direction: they pass the gate (they agree on one motion) and start the second
    start, but EpAlone's orientation check refuses them, since they cannot see the motion
    along the edges, so their estimate is not a candidate of its own."""
    from napari_edgecme.core.profile_fit import check_coverage

    case, prof = _shaken("rotation", 11, seed)
    angle = np.mod(prof.normal_angle, np.pi)
    parallel = prof.select(np.abs(np.mod(angle, np.pi) - np.pi / 2) < 0.5)
    with pytest.raises(ValueError, match="nearly parallel"):
        check_coverage(parallel)
    assert _offered_candidate(case, parallel, monkeypatch) == [None]


@pytest.mark.parametrize("seed", [0, 1])
def test_gradient_sparsity_is_lower_for_the_sharp_image_than_for_blur_or_ringing(seed):
    """The l1/l2 ratio of the gradients (Krishnan et al. 2011) that compares the two
    starts: a sharp edge scene scores lower than the same scene blurred, and lower than
    a deconvolution of the blurred scene with a wrong motion (the path turned by 90
    degrees), whose ringing adds gradients; it is scale-free."""
    from napari_edgecme.core.deconv import deconvolve

    case, _ = _shaken("rotation", 11, seed)
    truth = case.motion
    turned = _turned(truth)
    band = truth.psf_size() // 2 + 2
    right = estimate.gradient_sparsity(deconvolve(case.blurred, truth), band)
    wrong = estimate.gradient_sparsity(deconvolve(case.blurred, turned), band)
    sharp = estimate.gradient_sparsity(case.sharp, band)
    blurred = estimate.gradient_sparsity(case.blurred, band)
    assert sharp < blurred and right < wrong and right < blurred
    assert 0 < sharp <= 1
    assert estimate.gradient_sparsity(3.0 * case.sharp + 1.0, band) == pytest.approx(sharp)
    assert np.isnan(estimate.gradient_sparsity(np.ones((20, 20)), 2))
    assert np.isnan(estimate.gradient_sparsity(case.sharp, min(case.sharp.shape) // 2))


def test_after_a_restart_epalone_reports_and_gates_the_misfit_of_the_estimate_it_keeps(
        monkeypatch):
    """After a collapse to no blur EpAlone restarts from a wide motion; when it keeps the
    restart's estimate, the misfit it reports (which sets the restoration's prior) and
    gates is that estimate's, not the collapsed one's. A collapse is forced here by
    counting every estimate narrower than 100 px as collapsed (on this case the restart's
    estimate is the wider one, and is kept), and the restart's pass is made to report a
    misfit 0.05 higher than it found, so that the two cannot be confused."""
    case, _ = _shaken("rotation", 11, 4)
    focal = case.motion.intrinsics.focal_px
    seen = []
    iterate = estimate._CoarseToFine.iterate

    def spy(self, *args, **kwargs):  # the misfit of every pass, as it ends
        out = yield from iterate(self, *args, **kwargs)
        if kwargs.get("wide_start"):
            self.profile_misfit += 0.05
        seen.append(self.profile_misfit)
        return out

    monkeypatch.setattr(estimate._CoarseToFine, "iterate", spy)
    monkeypatch.setattr(estimate, "COLLAPSE_EXTENT", 100.0)
    with pytest.warns(UserWarning, match="no blur found"):  # the forced collapse, again
        est = estimate_motion(case.blurred, "ep", "rotation", 13, focal, rng=0)
    assert est.info.restarts == 1 and est.info.start == "wide"
    assert len(seen) == 3  # steps, soft edges, the restart
    first = seen[int(est.info.edge_spread > 0)]
    assert est.info.profile_misfit == seen[-1] > first + 0.04
    monkeypatch.setattr(estimate, "EP_MAX_MISFIT", (first + seen[-1]) / 2)
    seen.clear()
    with pytest.raises(ValueError, match="do not agree on one camera motion"):
        estimate_motion(case.blurred, "ep", "rotation", 13, focal, rng=0)
