"""The deconvolution's prior weight against the photo's noise (``deconv.noise_lambda_f``).

For every case of a real-photo suite (``lai``: the 20 of ``quick.txt`` unless ``--all``;
``levin``: the 32 captures) the Xu+Ep motion is estimated once as the suite estimates it
(seed 0, the case's max blur; on ``lai`` the true focal length) and cached in
``--cache``; then the blurred photo is deconvolved with that estimate and with the true
motion (the oracle) at several multiples of the reference weight
(``deconv.REFERENCE_LAMBDA_F``) and at the default weight, set from the photo's noise.
Scored as the suites score (aligned PSNR, with the in-plane rotation search on ``lai``;
on ``levin`` also the anchor protocol of its README). One JSON row per case goes to
``--out``; the table is the mean gain over the blurred input per weight.

    python benchmarks/bench_noise_weight.py levin [--jobs 2] [--factors 0.25 0.5 1 1.5 2]
    python benchmarks/bench_noise_weight.py lai [--all] [--jobs 2]

``benchmarks/results/noise-weight.md`` has the study.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np


def one_case(suite: str, case: dict, factors: tuple[float, ...], cache: str) -> dict:
    from napari_edgecme._suites._cases import _levin_protocol_psnr
    from napari_edgecme._suites._data import lai_load, levin_load, levin_max_blur
    from napari_edgecme.core import deconv
    from napari_edgecme.core.estimate import estimate_motion
    from napari_edgecme.core.metrics import aligned_psnr
    from napari_edgecme.core.motion import CameraMotion
    from napari_edgecme.core.photometry import estimate_noise

    warnings.simplefilter("ignore")
    blurred, sharp, truth = (lai_load if suite == "lai" else levin_load)(case)
    rotation = suite == "lai"
    path = Path(cache) / f"{suite}-{case['name']}-xuep.json"
    if path.exists():
        motion = CameraMotion.load(path)
    else:
        max_blur = case["max_blur"] if suite == "lai" else levin_max_blur(truth)
        focal = truth.intrinsics.focal_px if suite == "lai" else None
        motion = estimate_motion(blurred, "xu+ep", case["model"], max_blur, focal,
                                 rng=0).motion
        motion.save(path)
    noise = estimate_noise(blurred)
    row = {"suite": suite, "name": case["name"], "category": case["category"],
           "noise_255": noise * 255,
           "default_factor": deconv.noise_lambda_f(blurred) / deconv.REFERENCE_LAMBDA_F,
           "blurred": aligned_psnr(blurred, sharp, rotation=rotation)}
    if suite == "levin":
        row["blurred_anchor"] = _levin_protocol_psnr(blurred, sharp)
    weights = {f"{f:g}": f * deconv.REFERENCE_LAMBDA_F for f in factors}
    weights["default"] = None
    for key, m in (("estimate", motion), ("oracle", truth)):
        row[key] = {}
        for label, weight in weights.items():
            restored = deconv.deconvolve(blurred, m, lambda_f=weight)
            row[key][label] = aligned_psnr(restored, sharp, rotation=rotation)
            if suite == "levin" and case.get("anchor"):
                row.setdefault(key + "_anchor", {})[label] = _levin_protocol_psnr(restored,
                                                                                  sharp)
    return row


def table(rows: list[dict]) -> str:
    labels = list(rows[0]["estimate"])
    anchors = [r for r in rows if "estimate_anchor" in r]
    head = "| weight | Xu+Ep gain (dB) | oracle gain (dB) | share of the oracle's gain |"
    rule = "|---|---:|---:|---:|"
    if anchors:
        head += f" Xu+Ep on the {len(anchors)} anchors, README protocol (dB) |"
        rule += "---:|"
    lines = [head, rule]
    for label in labels:
        est = np.array([r["estimate"][label] - r["blurred"] for r in rows])
        ora = np.array([r["oracle"][label] - r["blurred"] for r in rows])
        name = ("default (from the noise)" if label == "default"
                else f"{label} x reference")
        line = f"| {name} | {est.mean():+.2f} | {ora.mean():+.2f} | {np.mean(est / ora):.1%} |"
        if anchors:
            line += f" {np.mean([r['estimate_anchor'][label] for r in anchors]):.2f} |"
        lines.append(line)
    noise = [r["noise_255"] for r in rows]
    factor = [r["default_factor"] for r in rows]
    lines.append("")
    lines.append(f"{len(rows)} cases; noise {min(noise):.2f}-{max(noise):.2f} /255 (median "
                 f"{np.median(noise):.2f}); default weight {min(factor):.2f}-{max(factor):.2f}x "
                 "the reference.")
    return "\n".join(lines)


def main(argv=None) -> int:
    from napari_edgecme._suites._data import default_data_dir, lai_cases, levin_cases

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("suite", choices=("lai", "levin"))
    parser.add_argument("--all", action="store_true", help="lai: all 60 cases")
    parser.add_argument("--data", default=None, help="data folder (default ../shared/data/)")
    parser.add_argument("--factors", type=float, nargs="+", default=[0.25, 0.5, 1, 1.5, 2],
                        help="multiples of the reference weight to try")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--cache", default="benchmarks/out/noise-weight-motions")
    parser.add_argument("--out", default="benchmarks/out/noise-weight.jsonl")
    args = parser.parse_args(argv)
    data = Path(args.data) if args.data else default_data_dir(args.suite)
    if data is None or not data.is_dir():
        print(f"bench_noise_weight: no {args.suite} data folder (give --data)", file=sys.stderr)
        return 2
    if args.suite == "lai":
        cases = lai_cases(data, quick=not args.all)
    else:
        cases = levin_cases(data, quick=False)
    Path(args.cache).mkdir(parents=True, exist_ok=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    rows = []
    n = len(cases)
    with ProcessPoolExecutor(args.jobs) as pool, out.open("a") as sink:
        for row in pool.map(one_case, [args.suite] * n, cases, [tuple(args.factors)] * n,
                            [args.cache] * n):
            rows.append(row)
            sink.write(json.dumps(row) + "\n")
            sink.flush()
            print(row["name"], f"noise {row['noise_255']:.2f}/255",
                  {k: round(v - row["blurred"], 2) for k, v in row["estimate"].items()},
                  file=sys.stderr, flush=True)
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
