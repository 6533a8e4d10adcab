"""EpAlone's robust edge-profile fit (Eq. 16 with a weight per profile) and self-checks.

Automatic extraction keeps some false profiles (on lai, about one in five has a
derivative that correlates under 0.8 with the true PSF's projection), and a least-squares
fit bends towards them. Three things weight each profile ``i``:

* a **prior**: its calibrated confidence (:attr:`~.profiles.EdgeProfiles.confidence`,
  the chance that it is faithful), floored at :data:`PRIOR_FLOOR` so that no profile is
  silenced before the data have spoken;
* an **agreement** with the current estimate: the Cauchy weight
  ``1 / (1 + (r_i / c)^2)`` of its misfit ``r_i`` (:func:`~.measurement.profile_misfit`),
  with the scale ``c`` twice the median misfit (at least :data:`MISFIT_SCALE_FLOOR`):
  a profile the motion explains as well as the typical one keeps most of its weight,
  one several times worse than typical loses nearly all of it (iteratively reweighted
  least squares, Holland & Welsch 1977);
* a **width check** against the same estimate (:func:`width_weight`): a faithful
  profile is the projection convolved with the edge's own transition, never narrower
  than the projection, so one narrower than predicted loses weight as the square of the
  variance ratio (:data:`NARROW_PROFILE_POWER`).

On the 20 cases of the ``lai`` quick set, fitting Eq. 16 on the full pose grid, the mean
PSF NCC against the truth is 0.583 with equal weights and 0.604 with the prior and the
agreement. The width check (on all 60 ``lai`` cases, EpAlone as shipped): mean gain
where EpAlone runs +1.56 -> +1.98 dB, cases more than 0.5 dB below the input 7 -> 4,
cases run 38 -> 34.

The profile model: a photo's edges are not ideal steps, so each profile is also fitted
as the projection convolved with a small Gaussian (:data:`EP_EDGE_SPREAD`); EpAlone keeps
that soft fit unless it explains the profiles clearly worse (:data:`EP_SPREAD_TOLERANCE`).
Then the self-checks: a set whose normals are nearly parallel is refused
(:func:`check_coverage`), and so is an estimate that leaves more than
:data:`EP_MAX_MISFIT` of the profiles' energy unexplained.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from .lasso import QuadraticTerm
from .measurement import profile_misfit, profile_term
from .profiles import POOR_BALANCE, EdgeProfiles

__all__ = ["EP_EDGE_SPREAD", "EP_MAX_MISFIT", "EP_SPREAD_TOLERANCE", "MISFIT_SCALE_FLOOR",
           "NARROW_PROFILE_POWER", "PRIOR_FLOOR", "XU_EP_GATE_MISFIT", "RobustProfileFit",
           "check_coverage", "width_weight"]

#: Smallest prior weight of a profile (its confidence is floored here).
PRIOR_FLOOR = 0.1
#: Smallest Cauchy scale of the misfits: below this every profile fits well enough that
#: the differences are noise, and none should be down-weighted for them.
MISFIT_SCALE_FLOOR = 0.05
#: Power of the width weight (:func:`width_weight`): a profile with ``q`` times the
#: variance its predicted projection has (``q < 1``) keeps ``q ** NARROW_PROFILE_POWER``
#: of its weight; 0 turns the check off. Chosen on the 60 ``lai`` cases (EpAlone where it
#: runs, mean gain over the blurred input): 0: +1.56 dB, 38 run, 7 more than 0.5 dB below
#: the input; 1: +1.63, 37, 7; 2: +1.98, 34, 4; 3: +1.89, 34, 6
#: (``benchmarks/results/edge-spread.md``).
NARROW_PROFILE_POWER = 2.0


class RobustProfileFit:
    """The profiles of one pyramid level and their weights, updated against each estimate.

    Parameters
    ----------
    profiles : EdgeProfiles
        ``n`` centroid-aligned profiles at this level's resolution.
    edge_spread : float
        Standard deviation (px of this level) of the sharp edges' own transition in the
        profile model (:func:`~.measurement.measurement_matrix`); 0: ideal steps.
    width_check : bool, default True
        Multiply the weights by :func:`width_weight` (EpAlone). Xu+Ep's gate, whose
        threshold and second start were calibrated without it, turns it off: with it,
        Xu+Ep lost 0.06 dB on the 20 ``lai`` quick cases (-0.95 on one).

    Attributes
    ----------
    prior : ndarray of shape (n,)
        Confidence, floored at :data:`PRIOR_FLOOR` (1 where it is unknown).
    weights : ndarray of shape (n,)
        ``prior`` times the Cauchy weight of the last misfits and the width weight
        (``prior`` before any update).
    misfit : ndarray of shape (n,) or None
        The misfits of the last :meth:`update`.
    """

    def __init__(self, profiles: EdgeProfiles, edge_spread: float = 0.0,
                 width_check: bool = True):
        self.profiles = profiles
        self.edge_spread = float(edge_spread)
        self.width_check = bool(width_check)
        confidence = np.asarray(profiles.confidence, float)
        self.prior = np.where(np.isfinite(confidence),
                              np.clip(confidence, PRIOR_FLOOR, 1.0), 1.0)
        self.weights = self.prior.copy()
        self.misfit: np.ndarray | None = None

    def term(self, matrix: sparse.csr_matrix) -> QuadraticTerm:
        """The weighted data term of Eq. 16 on the pose set of ``matrix``."""
        return profile_term(matrix, self.profiles, self.weights)

    def update(self, matrix: sparse.csr_matrix, w: np.ndarray) -> np.ndarray:
        """Re-weight every profile by its agreement with the MDF ``w`` (and, with
        ``width_check``, by :func:`width_weight`); return the weights."""
        self.misfit = profile_misfit(matrix, self.profiles, w)
        scale = max(2.0 * float(np.median(self.misfit)), MISFIT_SCALE_FLOOR)
        agreement = 1.0 / (1.0 + (self.misfit / scale) ** 2)
        if self.width_check and NARROW_PROFILE_POWER:
            n, N = len(self.profiles), self.profiles.offsets.size
            predicted = (matrix @ np.asarray(w, np.float64)).reshape(n, N)
            agreement = agreement * width_weight(self.profiles.derivatives, predicted,
                                                 self.profiles.offsets)
        self.weights = self.prior * agreement
        return self.weights

    def relative_misfit(self) -> float:
        """``sum_i ||M_i w - dE_i||^2 / sum_i ||dE_i||^2`` over all profiles, unweighted,
        for the MDF of the last :meth:`update`.

        How much of the profiles the motion leaves unexplained: the self-check of EpAlone.
        """
        if self.misfit is None:
            raise ValueError("relative_misfit needs an update() first")
        energy = (np.asarray(self.profiles.derivatives, np.float64) ** 2).sum(1)
        return float(np.sum(self.misfit * energy) / max(float(energy.sum()), 1e-300))


def _variance(rows: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Second central moment of each row taken as a mass distribution over ``offsets``."""
    mass = np.maximum(rows.sum(1), 1e-300)
    mean = rows @ offsets / mass
    return rows @ offsets ** 2 / mass - mean ** 2


def width_weight(derivatives, predicted, offsets) -> np.ndarray:
    """How far each profile is from being too narrow for the motion: weights in [0, 1].

    A blurred step's derivative is the local PSF's projection convolved with the sharp
    edge's own transition (and the sampling), and variances add under convolution: a
    faithful profile is never narrower than its projection. One that is (a clipped
    highlight cut short, texture, an edge of a subject that did not move with the
    camera, a transition the window truncated) keeps ``q ** NARROW_PROFILE_POWER`` of its
    weight, ``q`` its variance over that of the projection the current MDF predicts;
    profiles as wide as predicted or wider keep all of it (a soft scene edge is wider
    and still measures the motion). On ``lai``, 67% of the automatic profiles whose
    derivative correlates under 0.8 with the true projection are narrower than it
    (rms width under 0.8 of the truth's).

    Parameters
    ----------
    derivatives : array_like of shape (n, N)
        The profiles' derivatives ``dE_i`` (Eq. 11).
    predicted : array_like of shape (n, N)
        Their projections ``M_i w`` under the current MDF (Eq. 14).
    offsets : array_like of shape (N,)
        The sample positions (px).

    Returns
    -------
    ndarray of shape (n,)
        ``min(1, var(dE_i) / var(M_i w)) ** NARROW_PROFILE_POWER``.
    """
    offsets = np.asarray(offsets, np.float64)
    measured = _variance(np.asarray(derivatives, np.float64), offsets)
    expected = _variance(np.clip(np.asarray(predicted, np.float64), 0.0, None), offsets)
    ratio = np.clip(measured / np.maximum(expected, 1e-6), 0.0, 1.0)
    return ratio ** NARROW_PROFILE_POWER


#: EpAlone refuses when its estimate leaves more than this share of the edge profiles'
#: energy unexplained (:attr:`~.estimate.EstimateInfo.profile_misfit`): the profiles then
#: measure something else than one camera motion (false profiles, a moving subject, a
#: blur beyond what the set resolves). Up to it, the restoration holds a rougher motion
#: back with a stronger prior (:func:`~.deblur.ep_prior_factor`). With the gate lifted
#: (``benchmarks/results/ep-selfcheck.md``), 0.12 / 0.16 / 0.20 runs 34 / 52 / 56 of the 60
#: ``lai`` cases and 25 / 30 / 30 of the 32 ``levin`` captures; restored at the former
#: weight 3 / 14 / 16 of the ``lai`` ones end more than 0.5 dB below the blurred input,
#: restored with the factor none do. (It was 0.12 while every EpAlone motion was restored
#: with the same weight.)
EP_MAX_MISFIT = 0.20

#: Xu+Ep drops its profiles and runs as Xu when EpAlone on them (ideal step edges, no
#: edge spread, no width check) leaves more than this unexplained
#: (:data:`~.estimate.XU_EP_GATE`). On the 60 ``lai`` cases, counting a refusal as the
#: input returned, EpAlone's mean PSNR was 20.29 dB without a check (blurred 20.36),
#: 20.85 at 0.10 (38 run), 21.02 at 0.08 (27 run), 20.77 at 0.06 (10 run); 0.10 keeps
#: more profile sets for a 0.17 dB loss.
XU_EP_GATE_MISFIT = 0.10

#: The sharp photo's edges are rarely ideal steps, and sampling a profile between pixels
#: spreads it further: a measured profile is then the PSF's projection convolved with
#: about a Gaussian of this standard deviation (px of the working copy; on 10 ``lai``
#: cases the median NCC of measured against true projections is 0.933 as they are, 0.950
#: with the true ones spread by 1 px). Fitted as ideal steps, that spread is explained
#: by a thicker MDF -- a blob where the camera traced a thin path -- and deconvolving
#: with the blob rings. EpAlone fits both models and keeps the soft one unless it leaves
#: more than :data:`EP_SPREAD_TOLERANCE` times the misfit of the step model (on a
#: synthetic scene of ideal steps it leaves 1.4-6 times more; on the same scene with
#: soft edges, the same).
#: ``benchmarks/results/edge-spread.md`` has the study.
EP_EDGE_SPREAD = 1.0
#: See :data:`EP_EDGE_SPREAD`. On ``lai`` (counting refusals as the input returned)
#: 1.25 / 1.3 / 1.4 / 1.5 give +0.92 / +0.99 / +1.07 / +1.12 dB over the blurred input;
#: the synthetic in-plane shake of ``tests/core/test_ep_alone.py``, whose step edges the
#: soft model fits 1.36 times worse, needs less than 1.36.
EP_SPREAD_TOLERANCE = 1.3


def check_coverage(profiles: EdgeProfiles) -> None:
    """Refuse (EpAlone) a profile set whose normals are nearly parallel (Eq. 11).

    Each profile measures the PSF only along its normal, so such a set cannot see the
    motion along the edges; the threshold is the one at which the coverage summary
    already warns (:data:`~.profiles.POOR_BALANCE`).
    """
    cov = profiles.coverage()
    if cov["orientation_balance"] < POOR_BALANCE:
        raise ValueError(
            f"EpAlone: the {len(profiles)} edge profiles have nearly parallel normals "
            f"(orientation balance {cov['orientation_balance']:.2f}, under "
            f"{POOR_BALANCE:g}): motion along {cov['weakest_direction_deg']:.0f} deg is not "
            "measured; pick edges of other orientations or try method 'xu+ep'")
