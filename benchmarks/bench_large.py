"""A 12 or 24 megapixel RGB photo end to end (issues 8 and 14): time, memory, progress, Cancel.

The photo is made as ``edgecme bench``'s 12 MP speed case (``_bench._speed.speed_inputs``):
scikit-image's astronaut resized to 4000x3000 RGB (``--size 12``) or 6000x4000 RGB
(``--size 24``), a 31 px random camera rotation applied with the EFF operator, 1 %
noise, 8 bits (the same random stream as the speed case's). Every measurement runs in
a *fresh* Python process that only loads the photo, so that the peak memory reported
is that of the run (``VmHWM`` of ``/proc/self/status``, not ``ru_maxrss``, which a child
inherits from its parent).

Parts (``--parts``, comma-separated; default ``run``):

``run``
    ``deblur(...)`` -- Xu+Ep estimation of a ``rotation`` motion on an automatically
    downscaled copy, then hyper-Laplacian deconvolution at full resolution. Reported:
    wall-clock and CPU seconds and peak resident memory of each stage (the high-water
    mark is read and reset -- ``/proc/self/clear_refs`` -- when the first deconvolution
    record arrives), the number of progress records per stage, the longest wait between
    two records per stage (the call's start and return count as records) with the
    messages on either side of it, in wall-clock seconds and in CPU seconds of the
    process (all its threads; on a shared machine wall time is inflated by the others),
    the working resolution of the estimation and the PSF NCC of the estimate against
    the true motion.
``cancel``
    After a ``run`` (or ``--from-run`` an earlier one), ``--stops`` runs (default 6),
    each in a fresh process, with a callback that raises ``StopIteration`` at one record
    index and at every record after it, as a user's Cancel would. Half the stops are
    spread evenly in time over the estimation -- ``deblur`` itself, so the latency
    includes its way into the deconvolution, which the repeated request stops at its
    first record -- and half over the deconvolution, where ``deconvolve`` is called
    with the motion the run estimated (the same records, without minutes of estimation
    before each stop). Reported: the latency from the first stop request to the return
    of control (or the ``Cancelled`` exception), the records in between, how it ended.
``cli``
    ``edgecme deblur IMG.png -o OUT.png --save-motion M.json`` in a fresh process (the
    command-line entry point run by a tiny wrapper that prints the process's ``VmHWM``
    at exit): wall, CPU, peak memory, the command's summary line, and the PSF NCC of the
    saved motion against the truth at full resolution.

    python benchmarks/bench_large.py [--size 12|24] [--parts run,cancel,cli]
                                     [--method xu+ep] [--stops 6] [--keep DIR]
                                     [--json OUT] [--from-run EARLIER.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from napari_edgecme import _bench
from napari_edgecme._worker import peak_rss_mib

#: Peak memory allowed by issue 14 (GiB); issue 8 allowed 6 GiB at 12 MP.
LIMIT_GIB = 4.0
#: Cancel latency and progress gap allowed by issue 14 (s).
LIMIT_CANCEL_S = 1.0
LIMIT_GAP_S = 1.0
#: Image shapes by megapixels.
SHAPES = {1: (600, 900), 12: (3000, 4000), 24: (4000, 6000)}  # 1: a quick check of the script
_MARKER = "BENCH-LARGE-RESULT "


# --------------------------------------------------------------------------------------
# inputs
# --------------------------------------------------------------------------------------

def prepare(folder: Path, size: int) -> dict:
    """Write the blurred photo (uint8 .npy and .png) and its true motion into ``folder``.

    Reuses the files when they are already there (``--keep``).
    """
    image = folder / f"large{size}-blurred.npy"
    truth = folder / f"large{size}-truth.json"
    png = folder / f"large{size}-blurred.png"
    if not (image.exists() and truth.exists() and png.exists()):
        blurred, motion = make_photo(SHAPES[size])
        np.save(image, blurred)
        motion.save(truth)
        import imageio.v3 as iio

        iio.imwrite(png, blurred)
    return {"image": str(image), "truth": str(truth), "png": str(png)}


def make_photo(shape):
    """The speed case's large photo at ``shape`` (rows, cols): uint8 RGB, true motion.

    The same steps and random stream as ``_bench._speed.speed_inputs`` (whose first draws
    go to its 800 px case, made here at 256 px as ``bench_large`` always did), with
    ``LARGE_SHAPE`` replaced by ``shape``.
    """
    from skimage import data, transform

    from napari_edgecme._bench._config import BITS, NOISE
    from napari_edgecme.core.camera import Intrinsics
    from napari_edgecme.core.operators import blur
    from napari_edgecme.core.synth import (
        add_noise,
        densify_path,
        quantize,
        random_trajectory,
        sample_image,
    )

    noise, bits, extent = NOISE, BITS, _bench.SPEED_BLUR
    rng = np.random.default_rng(0)
    sharp = sample_image("camera", 256)
    intr = Intrinsics.from_image_shape(sharp.shape)
    small = densify_path(random_trajectory("rotation", intr, extent, rng=rng), "rotation", intr)
    quantize(add_noise(blur(sharp, small), noise, rng), bits)  # the draws of the small case
    photo = transform.resize(data.astronaut(), (*shape, 3), order=1,
                             anti_aliasing=False).astype(np.float32)
    intr = Intrinsics.from_image_shape(shape)
    truth = densify_path(random_trajectory("rotation", intr, extent, rng=rng), "rotation", intr)
    large = quantize(add_noise(blur(photo, truth), noise, rng), bits)
    return np.round(large * 255).astype(np.uint8), truth


# --------------------------------------------------------------------------------------
# fresh-process workers
# --------------------------------------------------------------------------------------

def _reset_peak() -> bool:
    """Reset this process's ``VmHWM`` to its current RSS (Linux >= 4.0)."""
    try:
        with open("/proc/self/clear_refs", "w", encoding="ascii") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _deblur_call(image, method: str, callback):
    from napari_edgecme import deblur

    max_blur = _bench.MAX_BLUR_FACTOR * _bench.SPEED_BLUR
    return deblur(image, method, "rotation", max_blur, rng=0, callback=callback)


def worker_run(image_path: str, truth_path: str, method: str, motion_out: str = "") -> dict:
    """One full ``deblur`` with every record's time; per-stage time, CPU and memory.

    The estimated motion is saved to ``motion_out`` (for the cancel part)."""
    from napari_edgecme.core.estimate import DEFAULTS
    from napari_edgecme.core.metrics import motion_psf_ncc
    from napari_edgecme.core.motion import CameraMotion

    image = np.load(image_path)
    truth = CameraMotion.load(truth_path)
    baseline = peak_rss_mib()
    log = []  # (time, cpu, stage, message)
    split = {}

    def progress(record) -> None:
        now, cpu = time.perf_counter(), time.process_time()
        if record.stage == "deconvolve" and not split:
            split.update(t=now, cpu=cpu, peak=peak_rss_mib(), reset=_reset_peak())
        log.append((now, cpu, record.stage, record.message))

    t0, c0 = time.perf_counter(), time.process_time()
    restored, est = _deblur_call(image, method, progress)
    t1, c1 = time.perf_counter(), time.process_time()
    peak_end = peak_rss_mib()
    if motion_out:
        est.motion.save(motion_out)
    times = [t0] + [e[0] for e in log] + [t1]
    cpus = [c0] + [e[1] for e in log] + [c1]
    stages = ["(start)"] + [e[2] for e in log] + ["(return)"]
    messages = ["deblur called"] + [e[3] for e in log] + ["deblur returned"]
    gaps: dict[str, dict] = {}
    every = []
    for i in range(1, len(times)):
        stage = stages[i] if stages[i] != "(return)" else stages[i - 1]
        gap = {"gap": times[i] - times[i - 1], "cpu": cpus[i] - cpus[i - 1], "stage": stage,
               "after": f"{stages[i - 1]}: {messages[i - 1]}",
               "before": f"{stages[i]}: {messages[i]}", "at_s": times[i] - t0}
        every.append(gap)
        if gap["gap"] > gaps.get(stage, {"gap": -1.0})["gap"]:
            gaps[stage] = gap
    cpu_gaps = {}
    for gap in every:
        if gap["cpu"] > cpu_gaps.get(gap["stage"], {"cpu": -1.0})["cpu"]:
            cpu_gaps[gap["stage"]] = gap
    counts: dict[str, int] = {}
    for e in log:
        counts[e[2]] = counts.get(e[2], 0) + 1
    ts, cs = split.get("t", t1), split.get("cpu", c1)
    return {
        "shape": list(image.shape), "dtype": str(image.dtype), "method": est.info.method,
        "max_side": DEFAULTS["max_side"], "working_scale": est.info.working_scale,
        "working_shape": [round(s * est.info.working_scale) for s in image.shape[:2]],
        "n_profiles": est.info.n_profiles, "poses": est.motion.n_poses,
        "seconds": t1 - t0, "cpu_seconds": c1 - c0,
        "stage_seconds": {"estimate": ts - t0, "deconvolve": t1 - ts},
        "stage_cpu": {"estimate": cs - c0, "deconvolve": c1 - cs},
        "stage_peak_mib": {"estimate": split.get("peak", peak_end),
                           "deconvolve": peak_end if split.get("reset") else None},
        "peak_rss_mib": max(peak_end, split.get("peak", 0.0)),
        "baseline_rss_mib": baseline, "records": counts, "gaps": gaps, "cpu_gaps": cpu_gaps,
        "top_gaps": sorted(every, key=lambda g: -g["gap"])[:8],
        "timeline": [[round(e[0] - t0, 3), e[2]] for e in log],
        "restored_dtype": str(restored.dtype), "restored_shape": list(restored.shape),
        "psf_ncc": motion_psf_ncc(est.motion, truth),
    }


def worker_cancel(image_path: str, method: str, stop_at: int, motion_path: str = "") -> dict:
    """``deblur`` asked to stop at record ``stop_at`` and at every record after it.

    With ``motion_path``, ``deconvolve(image, motion)`` instead (``stop_at`` counts its
    records): a stop in the deconvolution without minutes of estimation before it."""
    from napari_edgecme.core.progress import Cancelled

    image = np.load(image_path)
    if motion_path:
        from napari_edgecme import deconvolve
        from napari_edgecme.core.motion import CameraMotion

        motion = CameraMotion.load(motion_path)
    seen = []  # (time, stage, message)
    t_stop = [None]

    def progress(record) -> None:
        now = time.perf_counter()
        seen.append((now, record.stage, record.message))
        if len(seen) > stop_at:
            if t_stop[0] is None:
                t_stop[0] = now
            raise StopIteration

    t0 = time.perf_counter()
    try:
        if motion_path:
            deconvolve(image, motion, callback=progress)
        else:
            _deblur_call(image, method, progress)
        ended = "returned"
    except Cancelled:
        ended = "Cancelled"
    t1 = time.perf_counter()
    if t_stop[0] is None:
        return {"stop_at": stop_at, "reached": False, "ended": ended}
    at = seen[stop_at]
    after = seen[stop_at + 1:]
    return {"stop_at": stop_at, "call": "deconvolve" if motion_path else "deblur",
            "reached": True, "ended": ended, "at_s": at[0] - t0,
            "stage": at[1], "message": at[2], "latency_s": t1 - t_stop[0],
            "records_after": len(after),
            "after": [f"{s}: {m} (+{t - t_stop[0]:.2f} s)" for t, s, m in after[:4]]}


_CLI_WRAPPER = """
import sys, threading, time
t0, c0 = time.perf_counter(), time.process_time()
import napari_edgecme.cli._console as console_mod
from napari_edgecme.cli import main
from napari_edgecme.core import io
from napari_edgecme._worker import peak_rss_mib
state = {{"where": "reading the photo", "peak": 0.0, "peak_where": ""}}
done = threading.Event()

def rss():
    with open("/proc/self/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return 0.0

def sample():  # where the resident memory was largest (sampled every 0.1 s)
    while not done.is_set():
        now = rss()
        if now > state["peak"]:
            state["peak"], state["peak_where"] = now, state["where"]
        done.wait(0.1)

real_drive, real_write = console_mod.drive, io.write_image

def drive(gen, callback=None):
    def seen(record):
        state["where"] = record.stage + ": " + record.message
        return None if callback is None else callback(record)
    return real_drive(gen, seen)

def write(*args, **kwargs):
    state["where"] = "writing the output"
    return real_write(*args, **kwargs)

console_mod.drive, io.write_image = drive, write
threading.Thread(target=sample, daemon=True).start()
rc = main(sys.argv[1:])
done.set()
print("{marker}" + __import__("json").dumps({{"rc": rc, "seconds": time.perf_counter() - t0,
      "cpu_seconds": time.process_time() - c0, "peak_rss_mib": peak_rss_mib(),
      "sampled_peak_mib": state["peak"], "sampled_peak_at": state["peak_where"]}}), flush=True)
"""


def run_cli(png: str, out: str, truth: str) -> dict:
    """The command with no option but ``--save-motion``; its motion scored against ``truth``."""
    from napari_edgecme.core.metrics import motion_psf_ncc
    from napari_edgecme.core.motion import CameraMotion

    code = _CLI_WRAPPER.format(marker=_MARKER)
    motion = str(Path(out).with_suffix(".motion.json"))
    proc = subprocess.run([sys.executable, "-c", code, "deblur", png, "-o", out,
                           "--save-motion", motion], capture_output=True, text=True)
    result = _parse(proc)
    said = [line for line in proc.stderr.splitlines() if line.startswith("edgecme: ")
            and not line.startswith(("edgecme: warning", "edgecme: error"))]
    result["summary"] = said[-1] if said else ""
    result["psf_ncc"] = None
    if result["rc"] == 0 and Path(motion).exists():
        result["psf_ncc"] = motion_psf_ncc(CameraMotion.load(motion), CameraMotion.load(truth))
    else:  # the command failed: say why, keep the other parts' results
        print(proc.stderr, file=sys.stderr)
    return result


def _parse(proc) -> dict:
    lines = [line for line in proc.stdout.splitlines() if line.startswith(_MARKER)]
    if proc.returncode != 0 or not lines:
        print(proc.stderr, file=sys.stderr)
        raise RuntimeError("a worker process failed")
    return json.loads(lines[-1][len(_MARKER):])


def _fresh(*args) -> dict:
    proc = subprocess.run([sys.executable, __file__, "--worker", *map(str, args)],
                          capture_output=True, text=True)
    return _parse(proc)


def stop_points(run: dict, n: int) -> dict[str, list[int]]:
    """``n`` record indices spread evenly in time over the estimation and deconvolution.

    ``"estimate"``: indices into ``deblur``'s records; ``"deconvolve"``: indices into the
    deconvolution's own records (the ``deconvolve`` call of the cancel part)."""
    timeline = run["timeline"]
    points = {}
    for stage, share in (("estimate", n // 2), ("deconvolve", n - n // 2)):
        idx = [i for i, (_, s) in enumerate(timeline) if s == stage]
        if not idx or share == 0:
            continue
        t_lo, t_hi = timeline[idx[0]][0], timeline[idx[-1]][0]
        chosen = []
        for k in range(share):
            target = t_lo + (k + 0.5) / share * (t_hi - t_lo)
            chosen.append(min(idx, key=lambda i: abs(timeline[i][0] - target)))
        offset = idx[0] if stage == "deconvolve" else 0
        points[stage] = sorted({i - offset for i in chosen})
    return points


# --------------------------------------------------------------------------------------
# report
# --------------------------------------------------------------------------------------

def _mark(ok: bool) -> str:
    return "met" if ok else "**missed**"


def report(size: int, result: dict) -> str:
    lines = []
    r = result.get("run")
    if r:
        rows, cols = r["shape"][:2]
        peak_gib = r["peak_rss_mib"] / 1024
        lines += [
            f"### {size} MP `deblur()`: {cols}x{rows} RGB {r['dtype']} ({r['method']}, "
            f"rotation; estimation on {r['working_shape'][1]}x{r['working_shape'][0]}, "
            f"scale {r['working_scale']:.4f})", "",
            "| stage | wall (s) | CPU (s) | peak RSS (MiB) | records | longest gap (s) | "
            "its CPU (s) | longest gap in CPU s (its wall s): between |",
            "|---|---:|---:|---:|---:|---:|---:|---|"]
        for stage in ("estimate", "deconvolve"):
            gap = r["gaps"].get(stage, {})
            cgap = r.get("cpu_gaps", {}).get(stage, {})
            peak = r["stage_peak_mib"][stage]
            lines.append(
                f"| {stage} | {r['stage_seconds'][stage]:.1f} | {r['stage_cpu'][stage]:.1f} | "
                f"{'n/a' if peak is None else f'{peak:.0f}'} | {r['records'].get(stage, 0)} | "
                f"{gap.get('gap', float('nan')):.2f} | {gap.get('cpu', float('nan')):.2f} | "
                f"{cgap.get('cpu', float('nan')):.2f} ({cgap.get('gap', float('nan')):.2f}): "
                f"{cgap.get('after', '')} -> {cgap.get('before', '')} |")
        worst = max(g["gap"] for g in r["gaps"].values())
        lines += [
            f"| total | {r['seconds']:.1f} | {r['cpu_seconds']:.1f} | {r['peak_rss_mib']:.0f} "
            f"| {sum(r['records'].values())} | {worst:.2f} | | |", "",
            "Longest gaps (wall s, CPU s, at s: between):", ""]
        lines += [f"- {g['gap']:.2f}, {g['cpu']:.2f}, at {g['at_s']:.0f}: {g['after']} -> "
                  f"{g['before']}" for g in r.get("top_gaps", [])]
        lines += [
            "",
            f"Peak {peak_gib:.2f} GiB: {_mark(peak_gib <= LIMIT_GIB)} (<= {LIMIT_GIB:g} GiB); "
            f"longest gap {worst:.2f} s: {_mark(worst <= LIMIT_GAP_S)} (<= {LIMIT_GAP_S:g} s); "
            f"baseline after loading {r['baseline_rss_mib']:.0f} MiB; {r['n_profiles']} "
            f"profiles, {r['poses']} poses, PSF NCC vs truth {r['psf_ncc']:.3f}.", ""]
    stops = result.get("cancel")
    if stops:
        lines += ["| call | stop at record | at (s) | stage: message | latency (s) | "
                  "records after | ended |", "|---|---:|---:|---|---:|---:|---|"]
        for s in stops:
            call = s.get("call", "deblur")
            if not s["reached"]:
                lines.append(f"| {call} | {s['stop_at']} | | not reached | | | {s['ended']} |")
                continue
            lines.append(f"| {call} | {s['stop_at']} | {s['at_s']:.1f} | {s['stage']}: "
                         f"{s['message']} | {s['latency_s']:.2f} | {s['records_after']} | "
                         f"{s['ended']} |")
        lat = [s["latency_s"] for s in stops if s["reached"]]
        if lat:
            lines += ["", f"Cancel latency: median {statistics.median(lat):.2f} s, max "
                      f"{max(lat):.2f} s: {_mark(max(lat) <= LIMIT_CANCEL_S)} "
                      f"(<= {LIMIT_CANCEL_S:g} s).", ""]
    c = result.get("cli")
    if c:
        lines += [f"`edgecme deblur IMG.png -o OUT.png --save-motion M.json` at {size} MP: "
                  f"exit {c['rc']}, "
                  f"{c['seconds']:.1f} s wall, {c['cpu_seconds']:.1f} s CPU, peak "
                  f"{c['peak_rss_mib']:.0f} MiB = {c['peak_rss_mib'] / 1024:.2f} GiB: "
                  f"{_mark(c['peak_rss_mib'] / 1024 <= LIMIT_GIB)} (<= {LIMIT_GIB:g} GiB)"
                  + (f"; largest sampled RSS {c['sampled_peak_mib']:.0f} MiB during "
                     f"\"{c['sampled_peak_at']}\"" if c.get("sampled_peak_at") else "")
                  + ("; PSF NCC vs truth " + ("n/a (no motion)" if c.get("psf_ncc") is None
                                               else f"{c['psf_ncc']:.3f}")) + ".", "",
                  f"Summary: `{c['summary']}`", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="12/24 MP RGB deblur: time, memory, "
                                     "progress, Cancel")
    parser.add_argument("--size", type=int, default=12, choices=sorted(SHAPES))
    parser.add_argument("--parts", default="run", help="comma-separated: run, cancel, cli")
    parser.add_argument("--method", default="xu+ep", choices=("ep", "xu", "xu+ep"))
    parser.add_argument("--stops", type=int, default=6, help="stop points of the cancel part")
    parser.add_argument("--keep", type=Path, help="folder for the inputs (default: temporary)")
    parser.add_argument("--from-run", type=Path, help="the cancel part's stop points from "
                        "this earlier run (its --json with the timeline, and the motion "
                        "saved beside it) instead of a new run")
    parser.add_argument("--json", type=Path, help="write the figures here too (the run's "
                        "timeline and motion beside it)")
    parser.add_argument("--worker", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        kind, *rest = args.worker
        if kind == "run":
            result = worker_run(*rest)
        else:
            result = worker_cancel(rest[0], rest[1], int(rest[2]), *rest[3:])
        print(_MARKER + json.dumps(result), flush=True)
        return 0
    parts = [p.strip() for p in args.parts.split(",") if p.strip()]
    unknown = set(parts) - {"run", "cancel", "cli"}
    if unknown:
        parser.error(f"unknown parts: {', '.join(sorted(unknown))}")
    if "cancel" in parts and "run" not in parts and args.from_run is None:
        parts.insert(0, "run")
    result: dict = {"size": args.size}
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        motion_path = str(args.json.with_suffix(".motion.json") if args.json
                          else Path(tmp) / "motion.json")
        t0 = time.perf_counter()
        paths = prepare(folder, args.size)
        print(f"input ready in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        if "run" in parts:
            result["run"] = _fresh("run", paths["image"], paths["truth"], args.method,
                                   motion_path)
            print(report(args.size, {"run": result["run"]}), file=sys.stderr)
            if args.json:
                args.json.with_suffix(".timeline.json").write_text(
                    json.dumps(result["run"]["timeline"]) + "\n")
        if "cancel" in parts:
            run = result.get("run")
            if run is None:
                run = json.loads(args.from_run.read_text())["run"]
                run["timeline"] = json.loads(
                    args.from_run.with_suffix(".timeline.json").read_text())
                motion_path = str(args.from_run.with_suffix(".motion.json"))
            result["cancel"] = []
            for stage, points in stop_points(run, args.stops).items():
                for at in points:
                    extra = [motion_path] if stage == "deconvolve" else []
                    result["cancel"].append(_fresh("cancel", paths["image"], args.method, at,
                                                   *extra))
                    s = result["cancel"][-1]
                    print(f"stop at {stage} {at}: {s.get('latency_s', float('nan')):.2f} s "
                          f"({s.get('stage')}: {s.get('message')})", file=sys.stderr)
        if "cli" in parts:
            result["cli"] = run_cli(paths["png"], str(Path(tmp) / "restored.png"),
                                    paths["truth"])
    text = report(args.size, result)
    print(text)
    if args.json:
        slim = json.loads(json.dumps(result))
        if "run" in slim:
            slim["run"].pop("timeline", None)
        args.json.write_text(json.dumps(slim, indent=1) + "\n")
    ok = True
    if "run" in result:
        ok &= result["run"]["peak_rss_mib"] / 1024 <= LIMIT_GIB
    if "cli" in result:
        ok &= result["cli"]["rc"] == 0 and result["cli"]["peak_rss_mib"] / 1024 <= LIMIT_GIB
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
