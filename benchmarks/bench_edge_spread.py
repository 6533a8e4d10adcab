"""EpAlone's soft-edge profile model (``profile_fit.EP_EDGE_SPREAD``): the study behind it.

On every case of the ``lai`` set (or its quick subset), EpAlone estimated as the suite
runs it (told the case's max blur and the true focal length, model ``rotation``,
``rng=0``), deconvolved with the default hyper-Laplacian deconvolution and scored by the
suite's aligned PSNR (shift and in-plane rotation) and PSF NCC against the truth, under
*variants* of the profile model -- module constants set for the run, nothing else:

* ``committed``: the engine as it is (both models, the soft one kept within
  ``EP_SPREAD_TOLERANCE``; the width check, ``profile_fit.NARROW_PROFILE_POWER``;
  refusal above ``EP_MAX_MISFIT``);
* ``no-width-check``: the same without the width check (the engine before it);
  ``width-power-1`` / ``width-power-3``: other powers of it; ``width-tol14``: with the
  soft model kept within 1.4x the step misfit; ``width-all``: no refusal;
* the soft-edge study's variants, all without the width check: ``steps``: the step
  model only (``EP_EDGE_SPREAD = 0``), refusing above 10 % (the engine before the
  soft-edge model); ``steps-all`` / ``soft-all``: the step / the 1 px soft model alone,
  no refusal; ``true-derivatives``: the step model on the same automatic profiles with
  their derivatives replaced by the true PSF's projections
  (``metrics.true_profile_derivatives``): what the solver does with faithful profiles,
  no refusal.

``--method xu+ep`` scores Xu+Ep instead. Its gate runs EpAlone with the step model and
without the width check, so of these variants only ``true-derivatives`` changes it; the
Xu+Ep figures with the check in the gate (``edge-spread-width-xuep-quick.json``) were
made with a temporary patch that turned it on there.

Each variant prints one line per category and one for all cases: cases run, mean gain
over the blurred input where it ran, cases more than 0.5 dB below the input, mean PSF
NCC, and the mean gain over all cases counting a refusal as the input returned (0 dB).
Also the median wall and CPU seconds of an EpAlone estimation where it ran (the variants run one
after the other in one session, so their times compare). Two cases at a time
(``--jobs``); about 2-4 min per variant on 2 cores for all 60.

    python benchmarks/bench_edge_spread.py [--quick] [--variants committed,steps] [--data DIR]
                                           [--method {ep,xu+ep}] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from napari_edgecme._report import markdown_table
from napari_edgecme._suites import default_data_dir, lai_cases, lai_load

#: No width check: the engine before it, and the soft-edge study's variants.
_OFF = {"profile_fit.NARROW_PROFILE_POWER": 0.0}
#: Module constants each variant sets (``module.NAME``: value), and whether the profiles'
#: derivatives are replaced by the truth's projections.
VARIANTS = {
    "committed": ({}, False),
    "no-width-check": (_OFF, False),
    "width-power-1": ({"profile_fit.NARROW_PROFILE_POWER": 1.0}, False),
    "width-power-3": ({"profile_fit.NARROW_PROFILE_POWER": 3.0}, False),
    "width-tol14": ({"estimate.EP_SPREAD_TOLERANCE": 1.4}, False),
    "width-all": ({"estimate.EP_MAX_MISFIT": math.inf}, False),
    "steps": ({**_OFF, "estimate.EP_EDGE_SPREAD": 0.0, "estimate.EP_MAX_MISFIT": 0.10},
              False),
    "steps-all": ({**_OFF, "estimate.EP_EDGE_SPREAD": 0.0, "estimate.EP_MAX_MISFIT": math.inf},
                  False),
    "soft-all": ({**_OFF, "estimate.EP_SPREAD_TOLERANCE": math.inf,
                  "estimate.EP_MAX_MISFIT": math.inf}, False),
    "true-derivatives": ({**_OFF, "estimate.EP_EDGE_SPREAD": 0.0,
                          "estimate.EP_MAX_MISFIT": math.inf}, True),
}


def run_case(case: dict, variant: str, method: str = "ep") -> dict:
    """``method`` (EpAlone, or Xu+Ep: see the module docstring) on one case under
    ``variant``: a row of scores (in a worker process)."""
    import importlib

    from napari_edgecme.core.deconv import deconvolve
    from napari_edgecme.core.edges import extract_edge_profiles
    from napari_edgecme.core.estimate import estimate_motion
    from napari_edgecme.core.metrics import (
        aligned_scores,
        motion_psf_ncc,
        true_profile_derivatives,
    )

    settings, true_derivatives = VARIANTS[variant]
    for key, value in settings.items():
        module, name = key.rsplit(".", 1)
        setattr(importlib.import_module(f"napari_edgecme.core.{module}"), name, value)
    blurred, sharp, truth = lai_load(case)
    row = {"name": case["name"], "category": case["category"],
           "blurred": aligned_scores(blurred, sharp, rotation=True)[0]}
    profiles = None
    if true_derivatives:
        profiles = extract_edge_profiles(blurred, case["max_blur"], rng=0)
        profiles.derivatives = true_profile_derivatives(profiles, truth)
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            est = estimate_motion(blurred, method, "rotation", case["max_blur"],
                                  truth.intrinsics.focal_px, profiles=profiles, rng=0)
    except ValueError as exc:
        return {**row, "ok": False, "error": str(exc).splitlines()[0][:200]}
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    restored = deconvolve(blurred, est.motion)
    return {**row, "ok": True, "seconds": seconds, "cpu_seconds": cpu,
            "psnr": aligned_scores(restored, sharp, rotation=True)[0],
            "ncc": motion_psf_ncc(est.motion, truth), "misfit": est.info.profile_misfit,
            "edge_spread": est.info.edge_spread,
            "extent_ratio": est.motion.blur_extent() / truth.blur_extent()}


def summary(rows: list[dict]) -> list[list[str]]:
    """Per category and for all: run, gain where run, below -0.5 dB, NCC, gain over all."""
    out = []
    for cat in [*sorted({r["category"] for r in rows}), "all"]:
        sel = [r for r in rows if cat in ("all", r["category"])]
        ran = [r for r in sel if r["ok"]]
        gain = np.array([r["psnr"] - r["blurred"] for r in ran])
        out.append([cat if cat != "all" else "**all**", f"{len(ran)}/{len(sel)}",
                    f"{gain.mean():+.2f}" if ran else "—", str(int((gain < -0.5).sum())),
                    f"{np.mean([r['ncc'] for r in ran]):.3f}" if ran else "—",
                    f"{gain.sum() / len(sel):+.2f}"])
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the 20 cases of quick.txt")
    parser.add_argument("--variants", default=",".join(VARIANTS),
                        help=f"comma-separated, of {', '.join(VARIANTS)}")
    parser.add_argument("--data", default=None, help="lai folder (default: ../shared/data/lai)")
    parser.add_argument("--method", default="ep", choices=["ep", "xu+ep"],
                        help="the estimator scored (default: ep, EpAlone)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--json", default=None, help="write every row here")
    args = parser.parse_args(argv)
    variants = args.variants.split(",")
    unknown = set(variants) - set(VARIANTS)
    if unknown:
        parser.error(f"unknown variants: {', '.join(sorted(unknown))}")
    data = Path(args.data) if args.data else default_data_dir("lai")
    if data is None or not data.is_dir():
        parser.error("no lai data: pass --data DIR")
    cases = lai_cases(data, args.quick)
    results = {}
    for variant in variants:
        t0 = time.perf_counter()
        with ProcessPoolExecutor(max(1, args.jobs)) as pool:
            rows = list(pool.map(run_case, cases, [variant] * len(cases),
                                 [args.method] * len(cases)))
        results[variant] = rows
        ran = [r for r in rows if r["ok"]]
        times = (f"median estimation {statistics.median(r['seconds'] for r in ran):.1f} s "
                 f"wall, {statistics.median(r['cpu_seconds'] for r in ran):.1f} s CPU"
                 if ran else "")
        print(f"\n### {variant} ({len(cases)} cases, {time.perf_counter() - t0:.0f} s; "
              f"{times})\n")
        print(markdown_table(["category", "run", "gain where run (dB)", "below -0.5 dB",
                              "PSF NCC", "gain, refusals as 0 (dB)"], summary(rows),
                             "lrrrrr"))
        sys.stdout.flush()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
