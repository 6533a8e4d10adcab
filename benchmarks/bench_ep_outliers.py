"""EpAlone and its false edge profiles: how much would a better outlier rejection give?

For every ``lai`` case (``--quick``: those of ``quick.txt``) the automatic profiles are
extracted as EpAlone extracts them (the case's max blur, seed 0) and EpAlone is run on
them with its misfit gate (``profile_fit.EP_MAX_MISFIT``) lifted, told the max blur and
the true focal length, three ways:

* ``all``: every profile (EpAlone as shipped, before its gate);
* ``faithful``: only the profiles whose derivative correlates at least 0.8 with the true
  PSF's projection on their normal (``metrics.profile_fidelity``): an oracle of perfect
  outlier rejection, out of reach of any estimator, as an upper bound;
* ``trim T``: two passes: the ``all`` fit, then a refit on the profiles whose derivative
  correlates at least ``T`` with that fit's own projection (a trimmed least squares).

Each estimate gets the default deconvolution and is scored as the suite scores it
(aligned PSNR with rotation, PSF NCC); the table then applies the gate after the fact:
cases run, mean gain over the blurred input where run, and cases more than 0.5 dB below
it. One JSON row per case goes to ``--out``. ``benchmarks/results/ep-outliers.md`` has
the study.

    python benchmarks/bench_ep_outliers.py [--quick] [--trim 0.7 0.85] [--jobs 2]
                                           [--out benchmarks/out/ep-outliers.jsonl]
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

FAITHFUL = 0.8
GATES = (0.08, 0.10, 0.12, 0.14)


def _row_ncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a - a.mean(1, keepdims=True)
    b = b - b.mean(1, keepdims=True)
    den = np.sqrt((a * a).sum(1) * (b * b).sum(1))
    return np.divide((a * b).sum(1), den, out=np.zeros(len(den)), where=den > 0)


def one_case(case: dict, trims: tuple[float, ...]) -> dict:
    import napari_edgecme.core.estimate as estimate
    from napari_edgecme._suites._data import lai_load
    from napari_edgecme.core.deconv import deconvolve
    from napari_edgecme.core.edges import extract_edge_profiles
    from napari_edgecme.core.metrics import aligned_psnr, motion_psf_ncc, profile_fidelity
    from napari_edgecme.core.metrics import true_profile_derivatives as projections

    warnings.simplefilter("ignore")
    estimate.EP_MAX_MISFIT = np.inf  # the gate is applied by the table, after the fact
    blurred, sharp, truth = lai_load(case)
    profiles = extract_edge_profiles(blurred, case["max_blur"], rng=0)
    fidelity, _ = profile_fidelity(profiles, truth)
    base = aligned_psnr(blurred, sharp, rotation=True)
    row = {"name": case["name"], "category": case["category"], "n": len(profiles),
           "faithful_share": float(np.mean(fidelity >= FAITHFUL)), "runs": {}}

    def run(key, subset):
        try:
            est = estimate.estimate_motion(
                blurred, method="ep", model="rotation", max_blur=case["max_blur"],
                focal_px=truth.intrinsics.focal_px, profiles=subset, rng=0)
        except ValueError as err:  # too few profiles, parallel normals
            row["runs"][key] = {"n": len(subset), "error": str(err)}
            return None
        restored = deconvolve(blurred, est.motion)
        row["runs"][key] = {"n": len(subset), "misfit": est.info.profile_misfit,
                            "gain": aligned_psnr(restored, sharp, rotation=True) - base,
                            "ncc": motion_psf_ncc(est.motion, truth)}
        return est

    first = run("all", profiles)
    run("faithful", profiles.select(fidelity >= FAITHFUL))
    if first is not None and trims:
        agreement = _row_ncc(np.asarray(profiles.derivatives, np.float64),
                             projections(profiles, first.motion))
        for t in trims:
            run(f"trim {t:g}", profiles.select(agreement >= t))
    return row


def table(rows: list[dict]) -> str:
    keys = list(dict.fromkeys(k for r in rows for k in r["runs"]))
    lines = ["| profiles | gate | cases run | mean gain where run (dB) | > 0.5 dB below the "
             "input | mean PSF NCC where run |", "|---|---:|---:|---:|---:|---:|"]
    for key in keys:
        runs = [r["runs"][key] for r in rows if "gain" in r["runs"].get(key, {})]
        for gate in (*GATES, np.inf):
            kept = [x for x in runs if x["misfit"] <= gate]
            if not kept:
                continue
            gains = np.array([x["gain"] for x in kept])
            lines.append(f"| {key} | {'none' if gate == np.inf else f'{gate:.0%}'} | "
                         f"{len(kept)}/{len(rows)} | {gains.mean():+.2f} | "
                         f"{int(np.sum(gains < -0.5))} | "
                         f"{np.mean([x['ncc'] for x in kept]):.3f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    from napari_edgecme._suites._data import default_data_dir, lai_cases

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the 20 cases of quick.txt")
    parser.add_argument("--data", default=None, help="lai folder (default ../shared/data/lai)")
    parser.add_argument("--trim", type=float, nargs="*", default=[0.7, 0.85],
                        help="agreement thresholds of the two-pass fit")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--out", default="benchmarks/out/ep-outliers.jsonl")
    args = parser.parse_args(argv)
    data = Path(args.data) if args.data else default_data_dir("lai")
    if data is None or not data.is_dir():
        print("bench_ep_outliers: no lai data folder (give --data)", file=sys.stderr)
        return 2
    cases = lai_cases(data, args.quick)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    rows = []
    with ProcessPoolExecutor(args.jobs) as pool, out.open("a") as sink:
        for row in pool.map(one_case, cases, [tuple(args.trim)] * len(cases)):
            rows.append(row)
            sink.write(json.dumps(row) + "\n")
            sink.flush()
            print(row["name"], {k: round(v.get("gain", float("nan")), 2)
                                for k, v in row["runs"].items()}, file=sys.stderr, flush=True)
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
