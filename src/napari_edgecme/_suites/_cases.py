"""Running one case of a suite: a ground-truth case (``lai``, ``levin``) through fresh-process
estimates, or a real photo (``real``) through the command line."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from .._report import METHOD_NAMES
from .._worker import run_job, worker_env
from ._data import (
    LEVIN_ANCHOR_BORDER,
    LEVIN_ANCHOR_UPSAMPLE,
    case_gamma,
    lai_load,
    levin_load,
    levin_max_blur,
)

__all__ = ["COLLAPSE_EXTENT", "FAITHFUL_NCC", "METHODS", "REFERENCES", "TIMEOUT", "method_label",
           "profile_measures", "run_real_photo", "run_truth_case"]

#: Estimators, by engine name, with their display names.
METHODS = METHOD_NAMES
#: The two restorations with the true motion, as labelled in the tables.
REFERENCES = {"oracle": "oracle", "centred": "truth at its centroid pose"}
#: An estimate whose largest displacement from its PSF centroid (px, a radius:
#: :meth:`CameraMotion.max_displacement`, not the blur extent shown) is below this has
#: collapsed to "no blur" (every case of these suites is blurred by more).
COLLAPSE_EXTENT = 2.0
#: Edge profiles whose derivative matches the true projection at least this well are
#: counted as faithful (the edge-profile issue's measure).
FAITHFUL_NCC = 0.8
#: Seconds allowed for one estimate + deconvolution.
TIMEOUT = 1800.0


def profile_measures(blurred, truth, max_blur: float, detail: bool = False) -> dict:
    """Count, fidelity (NCC, width ratio) and time of the automatic profiles.

    With ``detail``, also the per-profile figures (width ratios, quality, the validity
    measures, confidence), the rejection counts and the coverage, as
    ``benchmarks/bench_profiles.py`` reports them.
    """
    from ..core.edges import extract_edge_profiles
    from ..core.metrics import profile_fidelity

    t0 = time.perf_counter()
    profiles = extract_edge_profiles(blurred, max_blur, rng=0)
    seconds = time.perf_counter() - t0
    out = {"max_blur": max_blur, "n": len(profiles), "seconds": seconds}
    if detail:
        out["rejected"] = profiles.stats.get("rejected", {})
    if len(profiles):
        ncc, ratio = profile_fidelity(profiles, truth)
        if detail:
            out.update(ratio=np.round(ratio, 4).tolist(),
                       quality=np.round(profiles.quality, 4).tolist(),
                       measures={k: np.round(v, 4).tolist()
                                 for k, v in getattr(profiles, "measures", {}).items()},
                       confidence=np.round(profiles.confidence, 4).tolist())
        ratio = ratio[np.isfinite(ratio)]
        out.update(ncc=[round(float(v), 4) for v in ncc],
                   median_ncc=float(np.median(ncc)),
                   faithful=int(np.count_nonzero(ncc >= FAITHFUL_NCC)),
                   median_width_ratio=float(np.median(ratio)) if ratio.size else None)
    if detail:
        out["coverage"] = profiles.coverage()
    return out


def run_truth_case(case: dict, suite: str, workdir: Path, methods, n_iter, log,
                   gamma="linear") -> dict:
    """Estimate with every method, deconvolve, and score one case with ground truth.

    ``gamma`` (:func:`._data.case_gamma`): the estimates and deconvolutions see the
    blurred image in linear light and their results are re-encoded before scoring.
    """
    from ..core.estimate import default_max_blur
    from ..core.metrics import aligned_scores, motion_psf_ncc
    from ..core.motion import CameraMotion

    blurred, sharp, truth = (lai_load if suite == "lai" else levin_load)(case)
    curve, gamma_reason = case_gamma(case, gamma)
    linear = blurred if curve.is_linear else curve.decode(blurred)
    stem = workdir / case["name"]
    np.save(f"{stem}-blurred.npy", linear)
    truth.save(f"{stem}-truth.json")
    rotation = suite == "lai"
    if suite == "levin":
        case["max_blur"] = levin_max_blur(truth)
        case["extent"] = case["max_blur"]
    focal = truth.intrinsics.focal_px if suite == "lai" else None

    def scores(image):
        psnr, ssim = aligned_scores(image, sharp, rotation=rotation)
        out = {"psnr": psnr, "ssim": ssim}
        if suite == "levin":
            out["psnr_protocol"] = _levin_protocol_psnr(image, sharp)
        return out

    row = {**{k: v for k, v in case.items() if k not in ("dir", "file")},
           "shape": list(blurred.shape), "true_extent": truth.blur_extent(),
           "blurred": scores(blurred), "runs": {}, "gamma": curve.name,
           "gamma_reason": gamma_reason}
    if suite == "lai":
        row["profiles_true"] = profile_measures(linear, truth, case["max_blur"])
        row["profiles_default"] = profile_measures(linear, truth,
                                                    default_max_blur(blurred.shape))
    jobs = {m: {"kind": "estimate", "method": m, "model": case["model"],
                "max_blur": case["max_blur"], "focal_px": focal, "n_iter": n_iter,
                "motion": f"{stem}-{m}.json"} for m in methods}
    jobs["oracle"] = {"kind": "deconvolve", "motion": f"{stem}-truth.json"}
    # the true motion about its centroid pose: a perfect estimate, as an estimator returns
    # it (claims 1-2), so the ceiling of the alignment protocol for the estimates
    truth.recentred().save(f"{stem}-truth-centred.json")
    jobs["centred"] = {"kind": "deconvolve", "motion": f"{stem}-truth-centred.json"}
    for key, job in jobs.items():
        job.update(image=f"{stem}-blurred.npy", restored=f"{stem}-{key}.npy")
        res = run_job(job, TIMEOUT)
        entry = {k: res[k] for k in ("ok", "error", "estimate_s", "estimate_cpu_s",
                                     "deconvolve_s", "peak_rss_mib", "n_profiles", "poses",
                                     "message", "warnings", "method_run", "no_blur")
                 if res.get(k) is not None}
        if res.get("ok"):
            restored = np.load(job["restored"])
            entry.update(scores(restored if curve.is_linear else curve.encode(restored)))
            entry["gain"] = entry["psnr"] - row["blurred"]["psnr"]
            if key not in ("oracle", "centred"):
                motion = CameraMotion.load(job["motion"])
                entry["ncc"] = motion_psf_ncc(motion, truth)
                scaled = motion.rescale(truth.image_shape)
                entry["extent"] = scaled.blur_extent()  # shown as "blur extent (px)"
                entry["collapsed"] = bool(scaled.max_displacement() < COLLAPSE_EXTENT
                                          or res.get("no_blur"))
        row["runs"][key] = entry
    oracle_gain = row["runs"].get("oracle", {}).get("gain")
    for key in methods:
        run = row["runs"][key]
        if run.get("ok") and oracle_gain and oracle_gain > 0:
            run["share"] = run["gain"] / oracle_gain
    log(f"{suite} {case['name']}: blurred {row['blurred']['psnr']:.2f} | " + " | ".join(
        f"{method_label(k)} " + (f"{r['psnr']:.2f}" + (f" NCC {r['ncc']:.2f}" if "ncc" in r else "")
                           if r.get("ok") else "failed")
        for k, r in row["runs"].items()))
    return row


def _levin_protocol_psnr(image, sharp) -> float:
    """PSNR under the anchor protocol of the levin README (1/10 px shift, 24 px border)."""
    from ..core.metrics import align_to, psnr

    shifted, _ = align_to(image, sharp, upsample=LEVIN_ANCHOR_UPSAMPLE)
    c = LEVIN_ANCHOR_BORDER
    return psnr(np.clip(shifted, 0, 1)[c:-c, c:-c], np.asarray(sharp, np.float64)[c:-c, c:-c])


def method_label(key: str) -> str:
    return METHODS.get(key) or REFERENCES.get(key, key)


# --------------------------------------------------------------------------------------
# the real photos, through the command line
# --------------------------------------------------------------------------------------

_PROFILES_RE = re.compile(r"(\d+) edge profiles")


def _run_cli(args: list[str], timeout: float) -> dict:
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-m", "napari_edgecme", *args],
                              capture_output=True, text=True, timeout=timeout, env=worker_env(),
                              check=False, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        return {"status": None, "seconds": timeout, "stderr": [f"timed out after {timeout} s"]}
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    return {"status": proc.returncode, "seconds": time.perf_counter() - t0, "stderr": lines}


def run_real_photo(photo: dict, workdir: Path, sheets: Path, methods, log) -> dict:
    from .._sheets import make_sheet, read_rgb
    from ..core.motion import CameraMotion

    row = {**photo, "runs": {}}
    images = {}
    for method in methods:
        out = workdir / f"{photo['name']}-{method}.png"
        motion_path = workdir / f"{photo['name']}-{method}.json"
        res = _run_cli(["deblur", photo["input"], "-o", str(out), "--save-motion",
                        str(motion_path), "--method", method, "--quiet"], TIMEOUT)
        # --quiet drops the summary line: re-read what it would say from the outputs
        entry = {"status": res["status"], "seconds": res["seconds"],
                 "stderr": res["stderr"][-3:]}
        if res["status"] == 0 and motion_path.exists():
            motion = CameraMotion.load(motion_path)
            entry.update(poses=motion.n_poses, extent=motion.blur_extent(),
                         collapsed=motion.max_displacement() < COLLAPSE_EXTENT)
            images[method] = read_rgb(out)
        row["runs"][method] = entry
    profiles = _run_cli(["profiles", photo["input"], "-o",
                         str(workdir / f"{photo['name']}-profiles.json")], 600)
    text = " ".join(profiles["stderr"])
    found = _PROFILES_RE.search(text)
    row["profiles"] = int(found.group(1)) if found else (0 if "no usable" in text else None)
    row["profiles_note"] = profiles["stderr"][-1] if profiles["stderr"] else ""

    def note(method):
        run = row["runs"].get(method, {})
        if run.get("status") != 0:
            why = (run.get("stderr") or ["failed"])[-1].removeprefix("edgecme: ")
            return f"failed: {why[:110]}"
        return f"blur {run['extent']:.1f} px, {run['poses']} poses, {run['seconds']:.0f} s"

    panels = [("input", read_rgb(photo["input"]))]
    notes = [f"{row['profiles']} edge profiles" if row["profiles"] is not None else ""]
    for method in methods:
        panels.append((f"ours: {METHODS[method]}", images.get(method)))
        notes.append(note(method))
    for key, label in (("paper_epalone", "paper: EpAlone"), ("paper_xu_ep", "paper: Xu+Ep")):
        panels.append((label, read_rgb(photo[key]) if photo.get(key) else None))
        notes.append("")
    sheet = make_sheet(panels, sheets / f"{photo['name']}.png",
                       title=f"{photo['name']} (edgecme deblur, default options)", notes=notes)
    row["sheet"] = str(sheet)
    log(f"real {photo['name']}: " + "; ".join(f"{METHODS[m]} {note(m)}" for m in methods)
        + f"; {row['profiles']} profiles")
    return row
