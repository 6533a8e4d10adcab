"""The speed benchmark: the EFF operator, estimation and deconvolution at 800x800, 12 MP."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .._report import (
    fmt,
    load_average,
    machine_info,
    machine_line,
    markdown_table,
    median_or_none,
    memory_note,
    met_mark,
)
from .._worker import run_job
from ._config import BITS, LARGE_SHAPE, METHODS, NOISE, SPEED_BLUR, BenchConfig, config_dict

__all__ = ["run_speed", "speed_inputs", "speed_markdown"]


def speed_inputs(config: BenchConfig, workdir: Path) -> dict:
    """The 800x800 gray case and (optionally) the 12 MP RGB case, blurred with the EFF."""
    from ..core.camera import Intrinsics
    from ..core.operators import blur
    from ..core.synth import add_noise, densify_path, quantize, random_trajectory, sample_image

    rng = np.random.default_rng(0)
    paths = {}
    sharp = sample_image("camera", config.speed_size)
    intr = Intrinsics.from_image_shape(sharp.shape)
    truth = densify_path(random_trajectory("rotation", intr, SPEED_BLUR, rng=rng),
                         "rotation", intr)
    blurred = quantize(add_noise(blur(sharp, truth), NOISE, rng), BITS)
    for name, arr in (("sharp", sharp), ("blurred", blurred)):
        paths[name] = str(workdir / f"speed-{name}.npy")
        np.save(paths[name], arr)
    paths["truth"] = str(workdir / "speed-truth.json")
    truth.save(paths["truth"])
    if config.large:
        from skimage import data, transform

        photo = transform.resize(data.astronaut(), (*LARGE_SHAPE, 3), order=1,
                                 anti_aliasing=False).astype(np.float32)
        intr = Intrinsics.from_image_shape(LARGE_SHAPE)
        truth = densify_path(random_trajectory("rotation", intr, SPEED_BLUR, rng=rng),
                             "rotation", intr)
        large = quantize(add_noise(blur(photo, truth), NOISE, rng), BITS)
        paths["large"] = str(workdir / "large-blurred.npy")
        np.save(paths["large"], np.round(large * 255).astype(np.uint8))  # as a photo file
        paths["large_truth"] = str(workdir / "large-truth.json")
        truth.save(paths["large_truth"])
    return paths


def _repeat(job: dict, n: int, timeout: float) -> dict:
    """Run ``job`` ``n`` times in fresh processes: median times, largest peak memory."""
    runs = [run_job(job, timeout) for _ in range(n)]
    ok = [r for r in runs if r.get("ok")]
    if not ok:
        return {"ok": False, "error": runs[0].get("error"), "runs": n}
    out = {"ok": True, "runs": len(ok), "failed_runs": n - len(ok)}
    for key in ("estimate_s", "deconvolve_s", "estimate_cpu_s", "deconvolve_cpu_s"):
        if key in ok[0]:
            out[key] = median_or_none([r.get(key) for r in ok])
            out[key + "_all"] = [r.get(key) for r in ok]
    out["peak_rss_mib"] = max((r["peak_rss_mib"] for r in ok if r.get("peak_rss_mib")),
                              default=None)
    for key in ("n_profiles", "poses", "message", "warnings"):
        if key in ok[0]:
            out[key] = ok[0][key]
    return out


def run_speed(config: BenchConfig, workdir: Path, log=None) -> dict:
    """Run the speed benchmark; return the JSON-ready result."""
    log = log or (lambda message: None)
    t_start = time.perf_counter()
    machine = machine_info()
    paths = speed_inputs(config, workdir)
    s = config.speed_size
    rows = []
    baseline = run_job({"kind": "baseline", "image": paths["blurred"]}, 300)

    op = run_job({"kind": "operator", "image": paths["sharp"], "motion": paths["truth"],
                  "repeat": config.operator_repeat}, config.timeout)
    label = f"EFF operator, {s}x{s} gray float32, {SPEED_BLUR:g} px rotation"
    if op.get("ok"):
        detail = (f"{op['tiles'][0]}x{op['tiles'][1]} tiles, PSF {op['psf_size']} px, "
                  f"{op['poses']} poses; median of {config.operator_repeat}")
        for what in ("build", "forward", "adjoint"):
            rows.append({"task": f"{label}: {what}", "seconds": op[f"{what}_s"],
                         "detail": detail, "ok": True})
    else:
        rows.append({"task": label, "ok": False, "error": op.get("error")})
    log(f"speed: EFF operator {'done' if op.get('ok') else 'failed: ' + op.get('error', '')}")

    targets = {"ep": (10.0, 2048.0), "xu+ep": (60.0, 2048.0), "hyperlaplacian": (10.0, None)}
    for method in config.speed_methods:
        job = {"kind": "estimate", "image": paths["blurred"], "method": method,
               "model": "rotation", "max_blur": SPEED_BLUR, "n_iter": config.n_iter}
        res = _repeat(job, config.repeat, config.timeout)
        rows.append(_speed_row(f"estimation {METHODS[method]}, {s}x{s} gray, max_blur "
                               f"{SPEED_BLUR:g}, rotation", res, "estimate_s",
                               targets.get(method), config.repeat))
        log(f"speed: estimation {METHODS[method]}: {_speed_log(res, 'estimate_s')}")
    for method in config.deconv_methods:
        job = {"kind": "deconvolve", "image": paths["blurred"], "motion": paths["truth"],
               "method": method}
        res = _repeat(job, config.repeat, config.timeout)
        rows.append(_speed_row(f"deconvolution {method}, {s}x{s} gray, true motion", res,
                               "deconvolve_s", targets.get(method), config.repeat))
        log(f"speed: deconvolution {method}: {_speed_log(res, 'deconvolve_s')}")
    if config.large:
        job = {"kind": "deconvolve", "image": paths["large"], "motion": paths["large_truth"],
               "method": "hyperlaplacian"}
        res = _repeat(job, 1, max(config.timeout, 3600.0))
        rows.append(_speed_row(f"deconvolution hyperlaplacian, {LARGE_SHAPE[1]}x"
                               f"{LARGE_SHAPE[0]} RGB (12 MP, 8-bit), {SPEED_BLUR:g} px "
                               "rotation", res, "deconvolve_s", (180.0, 6144.0), 1))
        log(f"speed: 12 MP deconvolution: {_speed_log(res, 'deconvolve_s')}")
    machine["load_average_end"] = load_average()
    return {"kind": "speed", "quick": config.quick, "machine": machine,
            "config": config_dict(config), "baseline_rss_mib": baseline.get("peak_rss_mib"),
            "rows": rows, "seconds": time.perf_counter() - t_start}


def _speed_row(task, res, key, target, runs) -> dict:
    row = {"task": task, "ok": res.get("ok", False), "runs": runs}
    if not res.get("ok"):
        row["error"] = res.get("error")
        return row
    row.update(seconds=res[key], all=res.get(key + "_all"), cpu_s=res.get(key[:-2] + "_cpu_s"),
               peak_rss_mib=res.get("peak_rss_mib"),
               detail=f"median of {res['runs']}" if res["runs"] > 1 else "1 run")
    if res.get("message"):
        row["detail"] += f"; {res['message']}"
    if res.get("n_profiles"):
        row["detail"] += f"; {res['n_profiles']} edge profiles"
    if target is not None:
        seconds, mib = target
        met = res[key] <= seconds and (mib is None or (res.get("peak_rss_mib") or 0) <= mib)
        row["target"] = (f"<= {seconds:g} s" + (f", <= {mib / 1024:g} GiB" if mib else ""))
        row["met"] = bool(met)
    return row


def _speed_log(res, key) -> str:
    if not res.get("ok"):
        return f"failed: {res.get('error')}"
    mem = f", peak {res['peak_rss_mib']:.0f} MiB" if res.get("peak_rss_mib") else ""
    return f"{res[key]:.1f} s{mem}"


def speed_markdown(result: dict) -> str:
    """The speed benchmark as Markdown."""
    table = []
    for r in result["rows"]:
        if not r.get("ok"):
            table.append([r["task"], "failed", "", "", f"{r.get('error')}"])
            continue
        target = f"{r['target']}: {met_mark(r['met'])}" if "target" in r else ""
        table.append([r["task"], f"{r['seconds']:.3f}" if r["seconds"] < 1 else
                      f"{r['seconds']:.1f}", fmt(r.get("cpu_s"), ".1f", ""),
                      fmt(r.get("peak_rss_mib"), ".0f", ""), target, r.get("detail", "")])
    lines = [f"# Speed benchmark{' (quick)' if result['quick'] else ''}", "",
             machine_line(result["machine"]) + f"; {result['seconds'] / 60:.1f} min.", "",
             markdown_table(["task", "time (s)", "CPU (s)", "peak RSS (MiB)", "target",
                             "notes"], table, "lrrrll"), "",
             "Inputs are blurred with the EFF operator, 1 % noise, 8-bit. Operator times are "
             "medians of repeated applications in one process; estimation and deconvolution "
             "times are wall-clock seconds of the call in a fresh process (median where "
             "repeated), and CPU is the process's user + system time over all its threads "
             "(on an idle machine the wall-clock time is at most about the CPU time; much "
             "more means the run waited for a shared CPU). "
             + memory_note(result.get("baseline_rss_mib")), ""]
    return "\n".join(lines)
