"""Xu+Ep's restoration and its edge profiles: does the estimate's profile misfit say how
strong the deconvolution's prior should be, as it does for EpAlone?

EpAlone's motion is restored with a prior weight that grows with the share of the edge
profiles' energy the estimate leaves unexplained (``deblur.ep_prior_factor``,
``benchmarks/results/ep-selfcheck.md``). Xu+Ep's estimate can be checked against the
same profiles. For every case of a suite (``lai``: told the max blur and the true focal
length, model ``rotation``; ``levin``: told the kernel's size, model ``translation``;
seed 0) Xu+Ep runs as shipped; the photo's edge profiles (extracted as the estimator
extracts them) are compared with the estimate's projections, as ideal steps and with a
1 px edge spread (the lower misfit is kept); the estimate is restored at 0.5, 1, 2 and 4
times the shipped weight (``deconv.noise_lambda_f``) and scored as the suites score.

    python benchmarks/bench_xuep_prior.py {lai,levin} [--quick] [--jobs 2] [--out ROWS.jsonl]
    python benchmarks/bench_xuep_prior.py {lai,levin} --rows ROWS.jsonl   # table only
"""

from __future__ import annotations

import itertools
import sys

import numpy as np

from napari_edgecme._report import markdown_table
from napari_edgecme._suites._study import load_study_case, study_main

FACTORS = (0.5, 1.0, 2.0, 4.0)
MISFIT_BINS = (0.0, 0.05, 0.08, 0.12, 0.2, 1.0)


def run_case(case: dict, suite: str) -> dict:
    """Xu+Ep on one case; its profile misfit and its restorations (in a worker)."""
    from napari_edgecme.core.deconv import deconvolve, noise_lambda_f
    from napari_edgecme.core.edges import extract_edge_profiles
    from napari_edgecme.core.measurement import measurement_matrix, profile_misfit
    from napari_edgecme.core.metrics import aligned_scores, motion_psf_ncc
    from napari_edgecme.core.photometry import to_luminance

    study = load_study_case(case, suite)
    blurred, sharp, truth, rotation = study.blurred, study.sharp, study.truth, study.rotation
    max_blur = study.max_blur
    row = study.row(case)
    est = study.estimate("xu+ep")
    motion = est.motion
    profiles = extract_edge_profiles(to_luminance(blurred), max_blur, rng=0)
    misfits = {}
    if len(profiles):
        energy = (np.asarray(profiles.derivatives, np.float64) ** 2).sum(1)
        for spread in (0.0, 1.0):
            matrix = measurement_matrix(profiles, motion.model, motion.intrinsics,
                                        motion.poses, edge_spread=spread)
            each = profile_misfit(matrix, profiles, motion.weights)
            misfits[f"{spread:g}"] = float(np.sum(each * energy) / energy.sum())
    weight = noise_lambda_f(blurred)
    psnr = {f"{f:g}": aligned_scores(deconvolve(blurred, motion, "hyperlaplacian",
                                                 lambda_f=weight * f), sharp,
                                      rotation=rotation)[0] for f in FACTORS}
    return {**row, "method_run": est.info.method, "n_profiles": len(profiles),
            "misfit": min(misfits.values()) if misfits else None, "misfits": misfits,
            "ncc": motion_psf_ncc(motion, truth), "psnr": psnr}


def table(rows: list[dict]) -> str:
    """Mean gain over the blurred input per misfit bin (rows) and weight factor."""
    head = ["estimate's profile misfit", "cases"] + [f"{f:g}x" for f in FACTORS]
    body = []
    for lo, hi in itertools.pairwise(MISFIT_BINS):
        sel = [r for r in rows if r["misfit"] is not None and lo <= r["misfit"] < hi]
        if sel:
            body.append([f"{lo:.0%}-{hi:.0%}", str(len(sel))] + [
                f"{np.mean([r['psnr'][f'{f:g}'] - r['blurred'] for r in sel]):+.2f}"
                for f in FACTORS])
    body.append(["all", str(len(rows))] + [
        f"{np.mean([r['psnr'][f'{f:g}'] - r['blurred'] for r in rows]):+.2f}"
        for f in FACTORS])
    return markdown_table(head, body)


def main(argv=None) -> int:
    def tabulate(rows, args):
        return (f"{args.suite}: {len(rows)} cases (mean gain of Xu+Ep over the blurred "
                "input, dB, by the estimate's profile misfit and the restoration's weight)"
                f"\n\n{table(rows)}")

    return study_main(__doc__, run_case, tabulate, argv)


if __name__ == "__main__":
    sys.exit(main())
