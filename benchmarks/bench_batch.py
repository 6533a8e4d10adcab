"""Batch throughput (issue 17): a sequential ``deblur`` loop against ``edgecme batch``.

The same photos -- by default the first 8 cases of ``shared/data/lai/quick.txt``
(640 px, real gyro shakes) -- deblurred with the default options twice, each in a fresh
Python process:

1. **sequential**: one process running ``edgecme deblur PHOTO -o OUT`` (``cli.main``)
   for each photo in turn -- what a user's shell loop does, without paying the
   interpreter start-up per photo;
2. **batch**: ``edgecme batch FOLDER -o OUT`` with the default local Dask cluster.

Both run a copy of the package taken at the start (the working tree may change under a
long benchmark).

Reported, from the same run: wall-clock time for all photos, throughput (photos per
minute) and its ratio, the median time per photo, peak memory (``VmHWM``) of the
sequential process, of the batch's client and of each batch worker (from the report's
``worker_peak_mib``), whether the two runs wrote identical files, the cluster the batch
chose, and the machine load (``uptime``) before each run.

    python benchmarks/bench_batch.py [--data DIR] [--photos 8] [--write]

``--write`` also saves the Markdown to ``benchmarks/results/batch.md``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from napari_edgecme import _bench, _worker

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "lai"
RESULT = ROOT / "benchmarks" / "results" / "batch.md"
_MARKER = "BENCH-BATCH-RESULT "


def worker(mode: str, inputs: Path, out: Path) -> dict:
    """Run one mode in this (fresh) process; return its figures."""
    from napari_edgecme.cli import main

    assert "/code/napari_edgecme/" in _bench.__file__, _bench.__file__  # the snapshot runs
    photos = sorted(inputs.glob("*.png"))
    t0 = time.perf_counter()
    per_photo, statuses = [], []
    if mode == "sequential":
        for photo in photos:
            t = time.perf_counter()
            statuses.append(main(["-q", "deblur", str(photo), "-o", str(out / photo.name)]))
            per_photo.append(time.perf_counter() - t)
    else:
        statuses.append(main(["batch", str(inputs), "-o", str(out)]))
    return {"mode": mode, "photos": len(photos), "seconds": time.perf_counter() - t0,
            "per_photo": per_photo, "statuses": statuses,
            "peak_rss_mib": _worker.peak_rss_mib(), "code": _bench.__file__}


def snapshot_code(folder: Path) -> dict:
    """A copy of this package in ``folder`` and the environment that runs it: both modes
    (and the batch's workers) run the same code even if the working tree changes."""
    import napari_edgecme

    shutil.copytree(Path(napari_edgecme.__file__).parent, folder / "napari_edgecme",
                    ignore=shutil.ignore_patterns("__pycache__"))
    env = _worker.worker_env()
    env["PYTHONPATH"] = os.pathsep.join([str(folder), env.get("PYTHONPATH", "")])
    return env


def run_mode(mode: str, inputs: Path, out: Path, env: dict) -> dict:
    """``worker`` in a fresh process, its stderr kept (the batch says what it chose)."""
    uptime = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    proc = subprocess.run([sys.executable, __file__, "--worker", mode, str(inputs), str(out)],
                          capture_output=True, text=True, env=env)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith(_MARKER)]
    if proc.returncode != 0 or not lines:
        sys.exit(f"{mode} run failed:\n{proc.stderr}")
    result = json.loads(lines[-1][len(_MARKER):])
    result["uptime"] = uptime
    result["stderr"] = proc.stderr
    if mode == "batch":
        with open(out / "report.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        result["per_photo"] = [float(r["seconds"]) for r in rows]
        result["row_statuses"] = [r["status"] for r in rows]
        peaks: dict[str, float] = {}
        for r in rows:
            peaks[r["worker"]] = max(peaks.get(r["worker"], 0.0), float(r["worker_peak_mib"]))
        result["worker_peaks"] = peaks
        result["cluster"] = next((ln.split(" on ", 1)[1] for ln in proc.stderr.splitlines()
                                  if "photos to deblur on " in ln), "?")
    return result


def identical(a: Path, b: Path, names: list[str]) -> int:
    return sum((a / n).read_bytes() == (b / n).read_bytes() for n in names)


def markdown(seq: dict, bat: dict, same: int, cases: list[str], shape) -> str:
    from napari_edgecme.core.estimate import default_max_blur

    n = seq["photos"]
    rate_seq, rate_bat = 60 * n / seq["seconds"], 60 * n / bat["seconds"]
    peaks = ", ".join(f"{v:.0f}" for v in bat["worker_peaks"].values())
    lines = [
        f"# Batch throughput: {n} photos of {max(shape[:2])} px, sequential `deblur` loop "
        "vs `batch`",
        "",
        f"`python benchmarks/bench_batch.py --write`, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {os.cpu_count()} cores, "
        f"Python {platform.python_version()}, default options "
        f"(xu+ep, rotation, max blur 4% of the longer side = {default_max_blur(shape):g} px, "
        "hyper-Laplacian).",
        f"Photos: `blurred.png` ({shape[1]}x{shape[0]}) of the `lai` cases "
        f"{', '.join(cases)}.",
        "",
        "| run | wall (s) | photos / min | median per photo (s) | peak memory (MiB) |",
        "|---|---:|---:|---:|---|",
        f"| sequential: `edgecme deblur` per photo, one process | {seq['seconds']:.0f} | "
        f"{rate_seq:.2f} | {statistics.median(seq['per_photo']):.1f} | "
        f"{seq['peak_rss_mib']:.0f} (the process) |",
        f"| `edgecme batch`, default local cluster | {bat['seconds']:.0f} | {rate_bat:.2f} | "
        f"{statistics.median(bat['per_photo']):.1f} | per worker: {peaks}; client "
        f"{bat['peak_rss_mib']:.0f} |",
        "",
        f"Throughput ratio batch / sequential: **{rate_bat / rate_seq:.2f}x**. Outputs "
        f"identical between the two runs: {same} of {n} restored photos (both runs, and the "
        "batch's workers, ran one copy of the package taken at the start).",
        "",
        f"Default cluster chosen: {bat['cluster']}.",
        "",
        "Machine load (`uptime`) before each run -- the VM is shared with other work, so "
        "wall-clock times vary:",
        "",
        f"- sequential: `{seq['uptime']}`",
        f"- batch: `{bat['uptime']}`",
        "",
        "Median per photo: the sequential loop's time per `deblur` call; the batch's the "
        "task time in `report.csv` (reading, estimation, deconvolution, encoding, "
        "thumbnails) while the other workers run too; the batch's wall time includes "
        "starting the cluster. Peak memory is `VmHWM` of each "
        "process (interpreter and libraries included).",
        "",
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA, help="the lai folder")
    parser.add_argument("--photos", type=int, default=8, help="photos (default 8)")
    parser.add_argument("--write", action="store_true", help=f"also write {RESULT}")
    parser.add_argument("--worker", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        mode, inputs, out = args.worker
        print(_MARKER + json.dumps(worker(mode, Path(inputs), Path(out))), flush=True)
        return 0
    cases = [ln.strip() for ln in (args.data / "quick.txt").read_text().splitlines()
             if ln.strip()][:args.photos]
    with tempfile.TemporaryDirectory(prefix="bench-batch-") as tmp:
        tmp = Path(tmp)
        inputs = tmp / "in"
        inputs.mkdir()
        for case in cases:
            shutil.copy(args.data / case / "blurred.png", inputs / f"{case}.png")
        outs = {mode: tmp / mode for mode in ("sequential", "batch")}
        outs["sequential"].mkdir()
        env = snapshot_code(tmp / "code")
        results = {}
        for mode in ("sequential", "batch"):
            print(f"running {mode} ...", file=sys.stderr, flush=True)
            results[mode] = run_mode(mode, inputs, outs[mode], env)
            print(f"  {results[mode]['seconds']:.0f} s", file=sys.stderr, flush=True)
        same = identical(outs["sequential"], outs["batch"], [f"{c}.png" for c in cases])
        from napari_edgecme.core.io import read_image

        shape = read_image(inputs / f"{cases[0]}.png").shape
    text = markdown(results["sequential"], results["batch"], same, cases, shape)
    print(text)
    if args.write:
        RESULT.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
