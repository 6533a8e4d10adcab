"""EpAlone's gate and its restoration: refuse a rough estimate, or restore it gently?

EpAlone refuses when its estimate leaves more than ``EP_MAX_MISFIT`` of the edge
profiles' energy unexplained. This study asks what a rougher estimate does to the photo,
and whether the photo or the restoration can make up for it, so that the gate can be
relaxed (more cases run) without harmful outputs.

For every case of a suite (``lai``: told the max blur and the true focal length, model
``rotation``; ``levin``: told the kernel's size, model ``translation``; seed 0), EpAlone
runs with its misfit gate lifted. The estimate is

* restored with the hyper-Laplacian deconvolution at the weight EpAlone's estimates had
  before the misfit-dependent factor (the larger of the photo's noise weight and the
  reference, ``deconv.REFERENCE_LAMBDA_F``), and at 2, 4 and 8 times it, and scored as
  the suites score (aligned PSNR, with in-plane rotation on ``lai``; PSF NCC);
* deconvolved on its luminance as the estimator's polish deconvolves
  (``estimate.POLISH_DECONVOLUTION``): the latent's gradient sparsity
  (``estimate.gradient_sparsity``, lower for a sharper image) against the blurred
  luminance's own on the same interior, a candidate self-check from the photo.

Two tables apply rules after the fact: misfit gates against a sparsity gate (refuse when
the latent is not sparser than the blurred photo by a given ratio), and misfit gates
against the restoration's weight factor. Each cell: cases run, mean gain over the
blurred input where run (dB), cases more than 0.5 dB below it.
``benchmarks/results/ep-selfcheck.md`` has the study; about 10 min for ``lai`` and 2 min
for ``levin`` on 2 cores.

    python benchmarks/bench_ep_selfcheck.py {lai,levin} [--jobs 2] [--out ROWS.jsonl]
    python benchmarks/bench_ep_selfcheck.py {lai,levin} --rows ROWS.jsonl   # table only
"""

from __future__ import annotations

import math
import sys

import numpy as np

from napari_edgecme._report import markdown_table
from napari_edgecme._suites._study import load_study_case, study_main

MISFIT_GATES = (0.12, 0.14, 0.16, 0.20, math.inf)
SPARSITY_GATES = (math.inf, 1.0, 0.97, 0.95, 0.93, 0.9)
#: The restoration's prior weight times these (a stronger prior for a rougher motion?)
PRIOR_FACTORS = (2.0, 4.0, 8.0)


def run_case(case: dict, suite: str) -> dict:
    """EpAlone on one case with its misfit gate lifted: a row of scores (in a worker)."""
    from napari_edgecme.core import estimate
    from napari_edgecme.core.deconv import REFERENCE_LAMBDA_F, deconvolve, noise_lambda_f
    from napari_edgecme.core.measurement import measurement_matrix, profile_misfit
    from napari_edgecme.core.metrics import aligned_scores, motion_psf_ncc
    from napari_edgecme.core.operators import blur
    from napari_edgecme.core.photometry import to_luminance

    estimate.EP_MAX_MISFIT = math.inf
    study = load_study_case(case, suite)
    blurred, sharp, truth, rotation = study.blurred, study.sharp, study.truth, study.rotation
    gray = to_luminance(blurred)
    row = study.row(case)
    try:
        est = study.estimate("ep")
    except ValueError as exc:  # too few profiles, or nearly parallel normals
        return {**row, "error": str(exc).splitlines()[0][:200]}
    motion = est.motion
    prof = est.profiles
    each = profile_misfit(measurement_matrix(prof, motion.model, motion.intrinsics,
                                             motion.poses, edge_spread=est.info.edge_spread),
                          prof, motion.weights)
    band = estimate.interior_band(gray.shape, motion, truth)
    inner = (slice(band, -band), slice(band, -band))
    former = max(noise_lambda_f(blurred), REFERENCE_LAMBDA_F)  # before the misfit factor
    restored = deconvolve(blurred, motion, "hyperlaplacian", lambda_f=former)
    stronger = {f"{factor:g}": aligned_scores(
        deconvolve(blurred, motion, "hyperlaplacian", lambda_f=former * factor), sharp,
        rotation=rotation)[0] for factor in PRIOR_FACTORS}
    latent = deconvolve(gray, motion, "hyperlaplacian", **estimate.POLISH_DECONVOLUTION)
    truth_latent = deconvolve(gray, truth, "hyperlaplacian", **estimate.POLISH_DECONVOLUTION)
    residual = blur(latent, motion)[inner].astype(np.float64) - gray[inner]
    return {**row, "psnr": aligned_scores(restored, sharp, rotation=rotation)[0],
            "ncc": motion_psf_ncc(motion, truth), "misfit": est.info.profile_misfit,
            "n_profiles": est.info.n_profiles,
            "sparsity": estimate.gradient_sparsity(latent, band),
            "blurred_sparsity": estimate.gradient_sparsity(gray, band),
            "truth_sparsity": estimate.gradient_sparsity(truth_latent, band),
            "log_residual": math.log(float(np.mean(residual ** 2))),
            "extent_ratio": motion.blur_extent() / truth.blur_extent(),
            "psnr_prior_factor": stronger,
            # how the misfit spreads over the profiles (candidate confidence measures)
            "profile_misfits": {"median": float(np.median(each)),
                                "q25": float(np.quantile(each, 0.25)),
                                "share_under_0.1": float(np.mean(each < 0.1)),
                                "share_over_0.5": float(np.mean(each > 0.5))}}


def _cell(gains) -> str:
    below = sum(g < -0.5 for g in gains)
    return f"{len(gains)} / {np.mean(gains):+.2f} / {below}" if gains else "0"


def prior_table(rows: list[dict]) -> str:
    """Cells per misfit gate (rows) and the restoration's weight factor (columns)."""
    fits = [r for r in rows if "psnr" in r]
    head = ["misfit gate"] + [f"{f:g}x the former weight" for f in (1.0, *PRIOR_FACTORS)]
    body = []
    for m in MISFIT_GATES:
        run = [r for r in fits if r["misfit"] <= m]
        line = ["none" if m == math.inf else f"{m:.0%}",
                _cell([r["psnr"] - r["blurred"] for r in run])]
        line += [_cell([r["psnr_prior_factor"][f"{f:g}"] - r["blurred"] for r in run])
                 for f in PRIOR_FACTORS]
        body.append(line)
    return markdown_table(head, body)


def table(rows: list[dict]) -> str:
    """Cells per misfit gate (rows) and sparsity-ratio gate (columns), at the former
    weight."""
    fits = [r for r in rows if "psnr" in r]
    head = ["misfit gate"] + [("none" if s == math.inf else f"ratio <= {s:.2f}")
                              for s in SPARSITY_GATES]
    body = []
    for m in MISFIT_GATES:
        line = ["none" if m == math.inf else f"{m:.0%}"]
        for s in SPARSITY_GATES:
            run = [r for r in fits if r["misfit"] <= m
                   and r["sparsity"] / r["blurred_sparsity"] <= s]
            line.append(_cell([r["psnr"] - r["blurred"] for r in run]))
        body.append(line)
    return markdown_table(head, body)


def main(argv=None) -> int:
    def tabulate(rows, args):
        return (f"{args.suite}: {sum('psnr' in r for r in rows)} of {len(rows)} cases "
                "estimated (cells: cases run, mean gain over the blurred input where run "
                "(dB), cases more than 0.5 dB below)\n\n"
                f"{table(rows)}\n\n{prior_table(rows)}")

    return study_main(__doc__, run_case, tabulate, argv)


if __name__ == "__main__":
    sys.exit(main())
