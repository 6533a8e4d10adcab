"""EpAlone's ceiling: what would it recover if every edge profile were true to the blur?

EpAlone solves a convex problem on the edge profiles (Eq. 16), so on a given profile set
its estimate does not depend on where it starts. What limits it is either the inversion
(the pose grid, the prior, the coarse-to-fine scheme, the robust weights) or the
profiles themselves. This study separates the two. For every case of a suite (``lai``:
told the max blur and the true focal length, model ``rotation``; ``levin``: told the
kernel's size, model ``translation``; seed 0) it extracts the edge profiles as EpAlone
does, then runs EpAlone, with its misfit gate lifted, twice on the same edges:

* on the measured profiles (what the engine does);
* on the true projections at the same edges: each profile's derivative replaced by the
  true local PSF's projection on its normal (``metrics.true_profile_derivatives``),
  centroid-aligned as the measured one is. Same count, same positions, same normals.

Each estimate is restored as the engine restores it (``deblur.restoring_params``, with
its profile misfit) and scored as the suites score (aligned PSNR, with in-plane rotation
on ``lai``; PSF NCC; blur extent over the truth's). A profile is counted *false* when it
is not faithful as the suites count it: its derivative correlates under
``FAITHFUL_NCC`` (0.8) with the true projection (``metrics.profile_fidelity``).

The table groups the cases by shake (``lai``) or kernel (``levin``): cases run under the
shipped gate (``profile_fit.EP_MAX_MISFIT``), mean gain over the blurred input where run,
mean PSF NCC, and the share of false profiles, for the measured profiles and for the
true projections. ``benchmarks/results/ep-profile-ceiling.md`` has the study; about
20 min for ``lai`` and 3 min for ``levin`` on 2 cores.

    python benchmarks/bench_ep_profile_ceiling.py {lai,levin} [--jobs 2] [--out ROWS.jsonl]
    python benchmarks/bench_ep_profile_ceiling.py {lai,levin} --rows ROWS.jsonl  # table only
"""

from __future__ import annotations

import copy
import math
import sys
from collections import defaultdict

import numpy as np

from napari_edgecme._report import markdown_table
from napari_edgecme._suites import FAITHFUL_NCC
from napari_edgecme._suites._study import load_study_case, study_main
from napari_edgecme.core.profile_fit import EP_MAX_MISFIT


def _estimate_and_score(study, profiles) -> dict:
    """EpAlone on ``profiles`` (gate lifted), restored as the engine restores: scores."""
    from napari_edgecme.core.deblur import restoring_params
    from napari_edgecme.core.deconv import deconvolve
    from napari_edgecme.core.metrics import aligned_scores, motion_psf_ncc

    try:
        est = study.estimate("ep", profiles)
    except ValueError as exc:  # nearly parallel normals
        return {"error": str(exc).splitlines()[0][:200]}
    misfit = est.info.profile_misfit
    params = restoring_params(study.blurred, "ep", "hyperlaplacian", profile_misfit=misfit)
    restored = deconvolve(study.blurred, est.motion, "hyperlaplacian", **params)
    return {"psnr": aligned_scores(restored, study.sharp, rotation=study.rotation)[0],
            "ncc": motion_psf_ncc(est.motion, study.truth), "misfit": misfit,
            "extent_ratio": est.motion.blur_extent() / study.truth.blur_extent()}


def run_case(case: dict, suite: str) -> dict:
    """One case: the profiles' fidelity, and EpAlone on measured and true profiles."""
    from napari_edgecme.core import estimate
    from napari_edgecme.core.edges import extract_edge_profiles
    from napari_edgecme.core.metrics import profile_fidelity, true_profile_derivatives
    from napari_edgecme.core.photometry import to_luminance

    estimate.EP_MAX_MISFIT = math.inf  # in this worker; the table applies the shipped gate
    study = load_study_case(case, suite)
    row = {**study.row(case), "group": case["name"].rsplit("_", 1)[-1]}
    measured = extract_edge_profiles(to_luminance(study.blurred), study.max_blur, rng=0)
    row["n_profiles"] = len(measured)
    if len(measured) == 0:
        return {**row, "error": measured.reason}
    ncc, _ = profile_fidelity(measured, study.truth)  # as the suites count faithful ones
    row["false_share"] = float(np.mean(ncc < FAITHFUL_NCC))
    true = true_profile_derivatives(measured, study.truth)
    true /= np.maximum(true.sum(1, keepdims=True), 1e-300)  # each row sums to one, as dE
    oracle = copy.copy(measured)
    oracle.derivatives = true.astype(measured.derivatives.dtype)
    row["measured"] = _estimate_and_score(study, measured)
    row["true"] = _estimate_and_score(study, oracle)
    return row


def _cells(rows: list[dict], key: str) -> list[str]:
    """Cases run under the shipped gate, their mean gain (dB) and mean PSF NCC."""
    run = [r for r in rows if "psnr" in r.get(key, {}) and r[key]["misfit"] <= EP_MAX_MISFIT]
    if not run:
        return ["0", "", ""]
    return [str(len(run)), f"{np.mean([r[key]['psnr'] - r['blurred'] for r in run]):+.2f}",
            f"{np.mean([r[key]['ncc'] for r in run]):.2f}"]


def table(rows: list[dict]) -> str:
    """One line per shake or kernel, per category (``lai``) and for all cases."""
    groups: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        groups[r["group"]].append(r)
        if r.get("category") and r["category"] != r["group"]:
            groups[f"category: {r['category']}"].append(r)
    groups["all"] = rows
    head = ["cases", "n", "false profiles", "measured: run", "gain dB", "PSF NCC",
            "true projections: run", "gain dB", "PSF NCC"]
    body = []
    for name, members in sorted(groups.items(), key=lambda kv: (kv[0] == "all",
                                                                 kv[0].startswith("category"),
                                                                 kv[0])):
        share = [r["false_share"] for r in members if "false_share" in r]
        body.append([name, str(len(members)), f"{np.mean(share):.0%}" if share else "",
                     *_cells(members, "measured"), *_cells(members, "true")])
    return markdown_table(head, body)


def main(argv=None) -> int:
    def tabulate(rows, args):
        return (f"{args.suite}: {len(rows)} cases (run: cases under the shipped misfit gate; "
                "gain: mean over the blurred input where run; PSF NCC: mean where run)\n\n"
                f"{table(rows)}")

    return study_main(__doc__, run_case, tabulate, argv)


if __name__ == "__main__":
    sys.exit(main())
