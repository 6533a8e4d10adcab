"""Real photos never crash the estimator, and a sharp photo is not "deblurred".

* An internal image -- a pyramid level stretched between percentiles, which a photo
  with clipped highlights pushes far beyond [0, 1] -- is never re-validated as if it were
  the user's input (it used to end ``deblur`` of ordinary 8-bit JPEGs with "image must be
  scaled to [0, 1]").
* A collapse to the no-blur solution is detected and retried from a wide motion, which
  also runs beside every estimate, and of two blurs the sparser latent's is kept; when
  the image shows no blur, the estimator says "no blur found", returns the identity
  motion, and ``deblur`` returns the photo unchanged.
"""

import numpy as np
import pytest

from napari_edgecme.core import synth
from napari_edgecme.core.deblur import deblur
from napari_edgecme.core.deconv import deconvolve
from napari_edgecme.core.estimate import (
    COLLAPSE_EXTENT,
    estimate_motion,
)
from napari_edgecme.core.metrics import motion_psf_ncc, psnr


@pytest.fixture(scope="module")
def clipped_case():
    """A blurred edge-rich scene in dim mid-greys with a few clipped highlights (lamps: 0.2%
    of the pixels at 1.0, as a camera records them)."""
    case = synth.make_case(0.3 + 0.25 * synth.sample_image("edges", 160), "inplane", 9, 0.01,
                           rng=3)
    rng = np.random.default_rng(1)
    for r, c in rng.integers(20, 140, size=(5, 2)):
        case.blurred[r:r + 3, c:c + 3] = 1.0
    return case


def test_clipped_highlights_stretch_a_level_far_beyond_the_input_range(clipped_case):
    lo, hi = np.percentile(clipped_case.blurred, [0.5, 99.5])
    assert (1.0 - lo) / (hi - lo) > 1.5  # the stretched level the old code refused


@pytest.mark.parametrize("method", ["ep", "xu+ep"])
def test_an_edge_profile_method_estimates_an_image_with_clipped_highlights(clipped_case,
                                                                            method):
    est = estimate_motion(clipped_case.blurred, method, "inplane", max_blur=13, n_iter=2,
                          rng=0)
    assert est.info.method == method and est.info.n_profiles >= 12
    assert est.motion.max_displacement() > COLLAPSE_EXTENT


@pytest.fixture(scope="module")
def sharp_photo():
    return synth.sample_image("edges", 160)


def test_a_sharp_photo_comes_back_unchanged_with_no_blur_found(sharp_photo):
    with pytest.warns(UserWarning, match="no blur found"):
        restored, est = deblur(sharp_photo, "xu", "inplane", max_blur=11, rng=0)
    assert est.info.no_blur and "no blur found" in est.info.message
    assert est.motion.n_poses == 1 and est.motion.blur_extent() < 1e-9
    np.testing.assert_array_equal(restored, sharp_photo.astype(np.float32))


def test_a_blurred_photo_is_not_taken_for_a_sharp_one():
    case = synth.make_case(synth.sample_image("edges", 160), "inplane", 9, 0.01, rng=3)
    est = estimate_motion(case.blurred, "xu", "inplane", max_blur=13, rng=0)
    assert not est.info.no_blur
    # the L0 cost of the blur found is close to the identity's (what makes the alternation
    # collapse-prone), far from the several-fold excess of a blur "found" on a sharp photo
    assert est.info.blind_cost < 1.5 * est.info.identity_cost


@pytest.mark.parametrize("seed", [3, 4])
def test_every_estimate_also_starts_from_a_wide_motion_and_the_sparser_latent_wins(seed):
    # a 4 px blur, small beside the wide start's blob (a third of a 16 px reach): the two
    # starts are compared by their polished latents' gradient sparsity, the sparser wins,
    # and the estimate kept recovers the small blur
    case = synth.make_case(synth.sample_image("edges", 160), "inplane", 4, 0.01, rng=seed)
    est = estimate_motion(case.blurred, "xu", "inplane", max_blur=8, rng=0)
    assert est.info.restarts == 1
    first, wide = est.info.wide_sparsity
    assert est.info.start == ("wide" if wide < first else "blob")
    assert f"the {'wide' if wide < first else 'first'} start won" in est.info.message
    assert motion_psf_ncc(est.motion, case.motion) > 0.7
    gain = psnr(deconvolve(case.blurred, est.motion), case.sharp) - psnr(case.blurred,
                                                                         case.sharp)
    assert gain > 1.0
