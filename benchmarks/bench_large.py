"""A 12-megapixel RGB photo end to end (issue 8): time, peak memory, progress.

The photo is the one of ``edgecme bench``'s 12 MP speed case (``_bench._speed.speed_inputs``:
scikit-image's astronaut resized to 4000x3000 RGB, a 31 px random camera rotation applied
with the EFF operator, 1 % noise, 8 bits). It goes through ``deblur(...)`` -- Xu+Ep
estimation of a ``rotation`` motion on an automatically downscaled copy, then
hyper-Laplacian deconvolution at full resolution -- in a *fresh* Python process that
only loads the photo, so that the peak memory reported is that of the run (``VmHWM``
of ``/proc/self/status``, not ``ru_maxrss``, which a child inherits from its parent).

Reported: wall-clock and CPU seconds of each stage, peak resident memory (and the
process's baseline after loading the photo), the number of progress records per stage
and the longest wait between two records (how promptly a Cancel is honoured), the
working resolution of the estimation and the rule that set it, and the PSF NCC of the
estimate against the true motion.

    python benchmarks/bench_large.py [--method xu+ep] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from napari_edgecme import _bench
from napari_edgecme._bench._speed import speed_inputs
from napari_edgecme._worker import peak_rss_mib

#: Peak memory allowed by the issue (GiB).
LIMIT_GIB = 6.0
_MARKER = "BENCH-LARGE-RESULT "


def prepare(folder: Path) -> dict:
    """Write the 12 MP blurred photo (uint8 .npy) and its true motion into ``folder``."""
    config = _bench.make_config(quick=False, large=True)
    config.speed_size = 256  # the helper also makes the 800 px speed case: keep it small
    paths = speed_inputs(config, folder)
    return {"image": paths["large"], "truth": paths["large_truth"]}


def worker(image_path: str, truth_path: str, method: str) -> dict:
    """Run ``deblur`` on the photo in this (fresh) process; return the figures."""
    from napari_edgecme import deblur
    from napari_edgecme.core.estimate import DEFAULTS
    from napari_edgecme.core.metrics import motion_psf_ncc
    from napari_edgecme.core.motion import CameraMotion

    image = np.load(image_path)
    truth = CameraMotion.load(truth_path)
    baseline = peak_rss_mib()
    records: dict[str, list[float]] = {}
    last = [time.perf_counter()]
    gaps: dict[str, float] = {}

    def progress(record) -> None:
        now = time.perf_counter()
        records.setdefault(record.stage, []).append(now)
        gaps[record.stage] = max(gaps.get(record.stage, 0.0), now - last[0])
        last[0] = now

    max_blur = _bench.MAX_BLUR_FACTOR * _bench.SPEED_BLUR
    t0, c0 = time.perf_counter(), time.process_time()
    restored, est = deblur(image, method, "rotation", max_blur, rng=0, callback=progress)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    estimate_s = est.info.seconds
    return {
        "shape": list(image.shape), "dtype": str(image.dtype), "method": est.info.method,
        "max_blur": max_blur, "max_side": DEFAULTS["max_side"],
        "working_scale": est.info.working_scale,
        "working_shape": [round(s * est.info.working_scale) for s in image.shape[:2]],
        "n_profiles": est.info.n_profiles, "poses": est.motion.n_poses,
        "converged": est.info.converged, "seconds": seconds, "cpu_seconds": cpu,
        "estimate_seconds": estimate_s, "deconvolve_seconds": seconds - estimate_s,
        "records": {stage: len(times) for stage, times in records.items()},
        "longest_gap_s": gaps, "peak_rss_mib": peak_rss_mib(),
        "baseline_rss_mib": baseline, "restored_dtype": str(restored.dtype),
        "restored_shape": list(restored.shape),
        "psf_ncc": motion_psf_ncc(est.motion, truth),
    }


def report(r: dict) -> str:
    rows, cols = r["shape"][:2]
    peak_gib = r["peak_rss_mib"] / 1024
    verdict = "within" if peak_gib <= LIMIT_GIB else "OVER"
    lines = [
        f"12 MP end to end: deblur() of a {cols}x{rows} RGB {r['dtype']} photo "
        f"({r['method']}, rotation, max_blur {r['max_blur']:g} px)",
        f"  downscale rule: estimation on a copy whose longer side is at most max_side = "
        f"{r['max_side']} px (core/estimate.py DEFAULTS['max_side']): scale "
        f"{r['working_scale']:.4f} -> {r['working_shape'][1]}x{r['working_shape'][0]}; "
        "deconvolution at full resolution",
        f"  time: {r['seconds']:.1f} s wall ({r['cpu_seconds']:.1f} s CPU): estimation "
        f"{r['estimate_seconds']:.1f} s, deconvolution {r['deconvolve_seconds']:.1f} s",
        f"  peak memory (VmHWM): {r['peak_rss_mib']:.0f} MiB = {peak_gib:.2f} GiB, {verdict} "
        f"the {LIMIT_GIB:g} GiB limit (baseline after loading the photo: "
        f"{r['baseline_rss_mib']:.0f} MiB)",
        "  progress records: " + ", ".join(
            f"{stage} {n} (longest gap {r['longest_gap_s'][stage]:.2f} s)"
            for stage, n in r["records"].items())
        + f"; total {sum(r['records'].values())}",
        f"  result: {r['restored_dtype']} {'x'.join(map(str, r['restored_shape']))}; "
        f"{r['n_profiles']} edge profiles, {r['poses']} poses, PSF NCC vs truth "
        f"{r['psf_ncc']:.3f}",
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="12 MP RGB deblur: time, memory, progress")
    parser.add_argument("--method", default="xu+ep", choices=("ep", "xu", "xu+ep"))
    parser.add_argument("--keep", type=Path, help="folder for the inputs (default: temporary)")
    parser.add_argument("--worker", nargs=2, metavar=("IMAGE", "TRUTH"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        result = worker(*args.worker, args.method)
        print(_MARKER + json.dumps(result), flush=True)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        paths = prepare(folder)
        print(f"prepared the 12 MP input in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        out = subprocess.run([sys.executable, __file__, "--method", args.method, "--worker",
                              paths["image"], paths["truth"]], capture_output=True, text=True)
    lines = [line for line in out.stdout.splitlines() if line.startswith(_MARKER)]
    if out.returncode != 0 or not lines:
        print(out.stderr, file=sys.stderr)
        return 1
    result = json.loads(lines[-1][len(_MARKER):])
    print(report(result))
    print(json.dumps(result))
    return 0 if result["peak_rss_mib"] / 1024 <= LIMIT_GIB else 1


if __name__ == "__main__":
    sys.exit(main())
