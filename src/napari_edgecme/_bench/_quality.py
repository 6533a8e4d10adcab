"""The quality benchmark: synthetic shakes, EpAlone / Xu / Xu+Ep / oracle, PSNR and PSF NCC."""

from __future__ import annotations

import math
import statistics
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from .._report import (
    fmt,
    load_average,
    machine_info,
    machine_line,
    markdown_table,
    mean_or_none,
    median_or_none,
    memory_note,
    met_mark,
)
from .._worker import run_job
from ._config import MAX_BLUR_FACTOR, METHODS, BenchConfig, config_dict

__all__ = ["quality_markdown", "run_quality"]


def _max_blur(extent: float, shape) -> float:
    return float(min(math.ceil(MAX_BLUR_FACTOR * extent), math.ceil(min(shape) / 2) - 1))


def run_quality(config: BenchConfig, workdir: Path, log=None) -> dict:
    """Run the quality benchmark; return the JSON-ready result."""
    from ..core.metrics import aligned_psnr, motion_psf_ncc
    from ..core.motion import CameraMotion
    from ..core.synth import make_case, sample_image

    log = log or (lambda message: None)
    t_start = time.perf_counter()
    machine = machine_info()
    cases = []
    baseline = None
    n_runs = len(config.cases) * (len(METHODS) + 1)
    done = 0
    for spec in config.cases:
        case = make_case(sample_image(spec.image, config.size), spec.model, spec.extent,
                         config.noise, bits=config.bits, rng=spec.seed, name=spec.name)
        stem = workdir / spec.name
        np.save(f"{stem}-blurred.npy", case.blurred)
        case.motion.save(f"{stem}-truth.json")
        if baseline is None:
            baseline = run_job({"kind": "baseline", "image": f"{stem}-blurred.npy"}, 300)
        max_blur = _max_blur(spec.extent, case.blurred.shape)
        row = {**asdict(spec), "shape": list(case.blurred.shape), "max_blur": max_blur,
               "true_extent": case.motion.blur_extent(),
               "blurred": {"psnr": aligned_psnr(case.blurred, case.sharp)}, "runs": {}}
        jobs = {m: {"kind": "estimate", "method": m, "model": spec.model,
                    "max_blur": max_blur, "n_iter": config.n_iter,
                    "motion": f"{stem}-{m}.json"} for m in METHODS}
        jobs["oracle"] = {"kind": "deconvolve", "motion": f"{stem}-truth.json"}
        for key, job in jobs.items():
            job.update(image=f"{stem}-blurred.npy", restored=f"{stem}-{key}.npy")
            res = run_job(job, config.timeout)
            done += 1
            entry = {k: res.get(k) for k in ("ok", "error", "estimate_s", "estimate_cpu_s",
                                             "deconvolve_s", "deconvolve_cpu_s",
                                             "peak_rss_mib", "n_profiles", "poses",
                                             "message", "warnings")}
            if res.get("ok"):
                restored = np.load(job["restored"])
                entry["psnr"] = aligned_psnr(restored, case.sharp)
                entry["gain"] = entry["psnr"] - row["blurred"]["psnr"]
                if key != "oracle":
                    entry["ncc"] = motion_psf_ncc(CameraMotion.load(job["motion"]),
                                                  case.motion)
                summary = (f"{entry['psnr']:.2f} dB ({entry['gain']:+.2f})"
                           + (f", NCC {entry['ncc']:.3f}" if "ncc" in entry else "")
                           + f", {entry.get('estimate_s') or entry['deconvolve_s']:.1f} s")
            else:
                summary = f"failed: {entry['error']}"
            row["runs"][key] = {k: v for k, v in entry.items() if v is not None}
            log(f"quality [{done}/{n_runs}] {spec.name} {_label(key)}: {summary}")
        cases.append(row)
    machine["load_average_end"] = load_average()
    return {"kind": "quality", "quick": config.quick, "machine": machine,
            "config": config_dict(config), "baseline_rss_mib": (baseline or {}).get(
                "peak_rss_mib"), "cases": cases, "summary": _quality_summary(cases),
            "targets": _quality_targets(cases), "seconds": time.perf_counter() - t_start}


def _label(key: str) -> str:
    return METHODS.get(key, key)


def _runs(cases, key):
    return [c["runs"].get(key, {}) for c in cases]


def _quality_summary(cases) -> list[dict]:
    rows = [{"key": "blurred", "n_ok": len(cases), "n": len(cases),
             "psnr": mean_or_none([c["blurred"]["psnr"] for c in cases]), "gain": 0.0}]
    for key in (*METHODS, "oracle"):
        ok = [r for r in _runs(cases, key) if r.get("ok")]
        rows.append({
            "key": key, "n": len(cases), "n_ok": len(ok),
            "psnr": mean_or_none([r["psnr"] for r in ok]),
            "gain": mean_or_none([r["gain"] for r in ok]),
            "ncc": mean_or_none([r.get("ncc") for r in ok]) if key != "oracle" else None,
            "estimate_s": median_or_none([r.get("estimate_s") for r in ok]),
            "deconvolve_s": median_or_none([r.get("deconvolve_s") for r in ok]),
            "peak_rss_mib": max((r["peak_rss_mib"] for r in ok if r.get("peak_rss_mib")),
                                default=None),
            "fell_back": sum("fell back" in (r.get("message") or "") for r in ok),
        })
    return rows


def _paired(cases, a: str, b: str | None, only=None):
    """Mean of PSNR(a) - PSNR(b) over cases where both succeeded (b None: the blurred)."""
    diffs = []
    for c in cases:
        if only is not None and not only(c):
            continue
        ra = c["runs"].get(a, {})
        rb = c["runs"].get(b, {}) if b else {"ok": True, "psnr": c["blurred"]["psnr"]}
        if ra.get("ok") and rb.get("ok"):
            diffs.append(ra["psnr"] - rb["psnr"])
    return (statistics.fmean(diffs), len(diffs)) if diffs else (None, 0)


def _quality_targets(cases) -> list[dict]:
    """The targets of the estimation and deconvolution issues, checked on these cases."""
    targets = []

    def add(text, value, n, bound, unit=" dB", higher=True):
        met = None if value is None else (value >= bound if higher else value <= bound)
        targets.append({"target": text, "value": value, "n": n, "met": met,
                        "shown": "—" if value is None else f"{value:+.2f}{unit}"})

    add("Xu+Ep mean PSNR >= Xu + 0.3 dB", *_paired(cases, "xu+ep", "xu"), 0.3)
    add("Xu+Ep mean PSNR >= blurred + 4 dB", *_paired(cases, "xu+ep", None), 4.0)
    add("Xu+Ep within 2 dB of the oracle", *_paired(cases, "xu+ep", "oracle"), -2.0)
    add("EpAlone >= blurred + 2 dB on the edge-rich scenes",
        *_paired(cases, "ep", None, only=lambda c: c["image"] == "edges"), 2.0)
    ok = [r["ncc"] for r in _runs(cases, "xu+ep") if r.get("ok")]
    value = statistics.fmean(ok) if ok else None
    targets.append({"target": "Xu+Ep mean PSF NCC >= 0.8", "value": value, "n": len(ok),
                    "met": None if value is None else value >= 0.8,
                    "shown": fmt(value, ".3f")})
    add("oracle (hyper-Laplacian) mean gain >= 6 dB", *_paired(cases, "oracle", None), 6.0)
    return targets


def quality_markdown(result: dict) -> str:
    """The quality benchmark as Markdown."""
    cases = result["cases"]
    cfg = result["config"]
    keys = (*METHODS, "oracle")
    names = {"blurred": "blurred", **METHODS, "oracle": "oracle"}
    lines = [f"# Quality benchmark{' (quick)' if result['quick'] else ''}", "",
             machine_line(result["machine"]) + f"; {result['seconds'] / 60:.1f} min.", "",
             f"{len(cases)} synthetic cases at {cfg['size']} px (longer side): scikit-image "
             "photos and the edge-rich `edges` scene, shaken with a random trajectory of "
             "the `inplane` or `rotation` model (rendered exactly by dense warping), "
             f"{cfg['noise']:.0%} Gaussian noise, {cfg['bits']}-bit. Estimators get "
             f"`max_blur` = {MAX_BLUR_FACTOR:g} x the true extent and the engine's "
             "default parameters"
             + (f" except `n_iter` = {cfg['n_iter']}" if cfg.get("n_iter") else "")
             + "; every estimate and the oracle (true motion) are followed by the same "
             "hyper-Laplacian deconvolution. One run per case and method.", ""]
    summary = {r["key"]: r for r in result["summary"]}
    table = []
    for key in ("blurred", *keys):
        s = summary[key]
        succeeded = f"{s['n_ok']}/{s['n']}"
        if s.get("fell_back"):
            succeeded += f" ({s['fell_back']} fell back to Xu)"
        table.append([names[key], succeeded, fmt(s["psnr"], ".2f"),
                      fmt(s["gain"], "+.2f"), fmt(s.get("ncc"), ".3f"),
                      fmt(s.get("estimate_s"), ".1f"), fmt(s.get("deconvolve_s"), ".1f"),
                      fmt(s.get("peak_rss_mib"), ".0f")])
    lines += ["## Summary", "",
              markdown_table(["method", "succeeded", "mean PSNR (dB)", "mean gain (dB)",
                              "mean PSF NCC", "median estimate (s)", "median deconvolve (s)",
                              "max peak RSS (MiB)"], table, "lrrrrrrr"), "",
              "Means are over the cases where the method succeeded; gains are against the "
              "blurred input of the same case. Xu+Ep falls back to Xu (with a warning) "
              "when it finds fewer edge profiles than EpAlone needs.", ""]
    lines += ["## Targets", "",
              markdown_table(["target", "measured", "cases", "status"],
                             [[t["target"], t["shown"], t["n"], met_mark(t["met"])]
                              for t in result["targets"]], "lrrl"), ""]

    def cell(case, key, what):
        run = case["runs"].get(key, {})
        if not run.get("ok"):
            return "failed" if run else "—"
        return fmt(run.get(what), {"psnr": ".2f", "ncc": ".3f"}.get(what, ".1f"))

    lines += ["## Aligned PSNR (dB) per case", "",
              markdown_table(["case", "blurred", *(names[k] for k in keys)],
                             [[c["name"], f"{c['blurred']['psnr']:.2f}",
                               *(cell(c, k, "psnr") for k in keys)] for c in cases],
                             "l" + "r" * (1 + len(keys))), ""]
    lines += ["## PSF NCC per case (centroid-aligned, 4x4 grid; 1 = same shapes)", "",
              markdown_table(["case", *(METHODS.values())],
                             [[c["name"], *(cell(c, k, "ncc") for k in METHODS)]
                              for c in cases], "l" + "r" * len(METHODS)), ""]
    detail = []
    for c in cases:
        for key in keys:
            run = c["runs"].get(key, {})
            if run.get("ok"):
                notes = "; ".join(run.get("warnings") or [])
                detail.append([c["name"], names[key], fmt(run.get("estimate_s"), ".1f"),
                               fmt(run.get("estimate_cpu_s"), ".1f"),
                               fmt(run.get("deconvolve_s"), ".1f"),
                               fmt(run.get("peak_rss_mib"), ".0f"),
                               fmt(run.get("n_profiles"), "d", ""), fmt(run.get("poses"), "d", ""),
                               notes])
            else:
                detail.append([c["name"], names[key], "", "", "", "", "", "",
                               f"failed: {run.get('error', 'not run')}"])
    lines += ["## Time and peak memory per run", "",
              markdown_table(["case", "method", "estimate (s)", "estimate CPU (s)",
                              "deconvolve (s)", "peak RSS (MiB)", "edge profiles", "poses",
                              "notes"], detail, "llrrrrrrl"), "",
              "Times are wall-clock seconds; CPU is the process's user + system time over "
              "all its threads (wall-clock much above CPU means the run waited for a shared "
              "CPU).", "",
              memory_note(result.get("baseline_rss_mib")), ""]
    return "\n".join(lines)
