"""Xu+Ep's second start: its candidates scored, to study the rule that picks one.

For every ``lai`` case (``--quick``: those of ``quick.txt``; ``--cases``: a list) Xu+Ep
runs as the ``lai`` suite runs it (told the case's max blur and the true focal length,
seed 0). Where its profiles pass the gate, ``estimate._second_start`` polishes the two
starts' estimates (``estimate._polish``), and the EpAlone estimate itself when the edges
are steps (``estimate.EP_CANDIDATE``), to compare them; this script records the
polished candidates (and the unpolished ones they came from), deconvolves each with the
default deconvolution and scores it as the suite does (aligned PSNR with rotation, PSF
NCC), and records for each the criteria a rule could use: the gradient sparsity of its
polish's latent (``estimate.gradient_sparsity``, the current rule) and the L0 cost
(Eq. 21) of the unpolished estimate on the same interior (the rule before it). The
sparsities are the engine's own (``EstimateInfo.start_sparsity``).

One JSON row per case goes to ``--out`` (appended); ``benchmarks/results/second-start.md``
has the table made from such rows.

    python benchmarks/bench_second_start.py [--quick | --cases a b ...] [--jobs 2]
                                            [--out benchmarks/out/second-start.jsonl]
                                            [--motions DIR]
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from pathlib import Path


def one_case(case: dict, motions: Path | None = None) -> dict:
    import napari_edgecme.core.estimate as estimate
    from napari_edgecme._suites._data import lai_load
    from napari_edgecme.core.deconv import deconvolve
    from napari_edgecme.core.metrics import aligned_psnr, motion_psf_ncc
    from napari_edgecme.core.progress import drive

    blurred, sharp, truth = lai_load(case)
    polishes = []  # (run, unpolished, polished, latent) of every polish, in order
    original = estimate._polish

    def recording_polish(run, motion, step, total, *args):
        polished, latent, step = yield from original(run, motion, step, total, *args)
        polishes.append((run, motion, polished, latent))
        return polished, latent, step

    estimate._polish = recording_polish
    try:
        est = estimate.estimate_motion(blurred, "xu+ep", "rotation", case["max_blur"],
                                       truth.intrinsics.focal_px, rng=0)
    finally:
        estimate._polish = original
    row = {"name": case["name"], "category": case["category"], "message": est.info.message,
           "blurred": aligned_psnr(blurred, sharp, rotation=True),
           "final_psnr": aligned_psnr(deconvolve(blurred, est.motion), sharp, rotation=True),
           "final_ncc": motion_psf_ncc(est.motion, truth)}
    if motions is not None:
        est.motion.save(motions / f"{case['name']}-final.json")
    if est.info.start_sparsity is None:  # no second start, or no comparison
        return row
    # the second start's candidates: the first start's estimate, the second's, and the
    # EpAlone estimate's when it was a candidate (estimate.EP_CANDIDATE). After the wide
    # start's comparison (estimate.WIDE_START: two polishes, of the blob's estimate and
    # the wide start's) the estimate it kept is not polished again: its polish is the one
    # of those two that won
    k = len(est.info.start_sparsity)
    candidates = polishes[-k:]
    if est.info.wide_sparsity is not None:
        first, wide = polishes[-k - 1], polishes[-k]
        first_sparsity, wide_sparsity = est.info.wide_sparsity
        candidates = [wide if wide_sparsity < first_sparsity else first,
                      *polishes[-(k - 1):]]
    run = candidates[0][0]
    level = run.finest
    # the L0 costs on the interior the sparsities were compared on (that of the larger PSF)
    band = estimate.interior_band(level.shape, *(p for _, _, p, _ in candidates))
    for key, (_, unpolished, polished, _), sparsity in zip(
            ("first", "second", "ep")[:len(candidates)], candidates,
            est.info.start_sparsity, strict=True):
        final = polished.compact().recentred().rescale(blurred.shape[:2])
        if motions is not None:
            final.save(motions / f"{case['name']}-{key}.json")
        row[key] = {
            "extent": final.blur_extent(), "ncc": motion_psf_ncc(final, truth),
            "psnr": aligned_psnr(deconvolve(blurred, final), sharp, rotation=True),
            "sparsity": sparsity,
            "l0_unpolished": drive(estimate.iter_l0_cost(level, unpolished, run.lambda_f,
                                                         band))}
    return row


def main(argv=None) -> int:
    from napari_edgecme._suites._data import default_data_dir, lai_cases

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--cases", nargs="+")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/out/second-start.jsonl"))
    parser.add_argument("--motions", type=Path,
                        help="also save every polished candidate's motion here, "
                             "CASE-{first,second,ep}.json, and the final one, CASE-final.json")
    args = parser.parse_args(argv)
    cases = lai_cases(default_data_dir("lai"), args.quick)
    if args.cases:
        cases = [c for c in cases if c["name"] in set(args.cases)]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if args.motions:
        args.motions.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(args.jobs) as pool, args.out.open("a") as out:
        for row in pool.map(partial(one_case, motions=args.motions), cases):
            out.write(json.dumps(row) + "\n")
            out.flush()
            print(row["name"], *(row.get(k, {}).get("psnr") for k in ("first", "second", "ep")),
                  file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
