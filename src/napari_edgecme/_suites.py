"""``edgecme bench --suite {lai,levin,real}``: benchmarks on real camera shake and real captures.

The synthetic bench (:mod:`._bench`) blurs photos with the project's own model of a shake;
these suites measure the estimators on data the project did not make:

``lai``
    Real camera shakes recorded with a gyroscope (Lai et al., CVPR 2016), rendered on
    natural photos of five categories (manmade, natural, people, saturated, text) by an
    independent renderer, with the true motion (``../shared/data/lai``: 60 cases,
    ``quick.txt`` 20 of them). Each estimator is told the case's ``max_blur`` and the
    true focal length. PSNR and SSIM are measured after the best global shift *and*
    in-plane rotation (:func:`~.core.metrics.aligned_scores`): a blind estimate is right
    only up to its centroid pose, and these trajectories start at the identity, so their
    centroid pose is rotated by up to about a degree. Also: centroid-aligned PSF NCC of
    each estimate against the truth, edge-profile count, fidelity and yield of the edge
    profiles at the true and at the default max blur
    (:func:`~.core.metrics.profile_fidelity`), the collapse indicator, time and peak
    memory.
``levin``
    The 32 real captures of Levin et al. (CVPR 2009; ``../shared/data/levin``), uniform
    blur, estimated with the ``translation`` model. Same columns, and the figures under the
    protocol the folder's README states for its anchors (8 cases, global shift at
    1/10 px, 24 px border crop: Pan et al. 2016 30.47 dB).
``real``
    The paper's 10 real photos (``../shared/data/paper-real``), no ground truth: each is
    deblurred through the command line, exactly as a user would (``edgecme deblur``, the
    default method Xu+Ep and ``--method ep``, default options otherwise), and a
    side-by-side sheet is drawn per photo: input | EpAlone | Xu+Ep | the paper's EpAlone |
    the paper's Xu+Ep, with the same crops at 1:1 below.

Every estimate runs in a fresh process (:func:`._bench.run_job`), so its peak memory is
its own; ``jobs`` cases run at once (times are then those of a shared machine). Results go
to ``<suite>[-quick].md`` and ``.json`` (and ``real-sheets/``) in the output folder,
written when the suite ends (temporary name + rename).
"""

from __future__ import annotations

import contextlib
import json
import math
import re
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from ._bench import (
    _f,
    _machine_line,
    _mean,
    _median,
    load_average,
    machine_info,
    markdown_table,
    run_job,
    worker_env,
)

__all__ = ["SUITES", "default_data_dir", "run_suite"]

#: Suite name -> folder name under ``shared/data``.
SUITES = {"lai": "lai", "levin": "levin", "real": "paper-real"}
#: Estimators by engine name, with display names.
METHODS = {"ep": "EpAlone", "xu": "Xu", "xu+ep": "Xu+Ep"}
#: The two restorations with the true motion, as labelled in the tables.
REFERENCES = {"oracle": "oracle", "centred": "truth at its centroid pose"}
CATEGORIES = ("manmade", "natural", "people", "saturated", "text")
#: Levin's anchor protocol (its README): these 8 cases, 1/10 px shift, 24 px border.
LEVIN_ANCHOR_CASES = tuple(f"im0{i}_ker0{k}" for i in range(1, 5) for k in (2, 5))
LEVIN_ANCHOR_BORDER = 24
LEVIN_ANCHOR_UPSAMPLE = 10
LEVIN_PAN_2016 = 30.47
#: An estimate whose blur extent (px, :meth:`CameraMotion.max_displacement`) is below this
#: has collapsed to "no blur" (every case of these suites is blurred by more).
COLLAPSE_EXTENT = 2.0
#: Edge profiles whose derivative matches the true projection at least this well are
#: counted as faithful (the edge-profile issue's measure).
FAITHFUL_NCC = 0.8
#: Seconds allowed for one estimate + deconvolution.
TIMEOUT = 1800.0


def default_data_dir(suite: str) -> Path | None:
    """``shared/data/<folder>`` beside the checkout (or beside the working folder), if any."""
    folder = SUITES[suite]
    roots = [Path.cwd().parent, Path(__file__).resolve().parents[3]]
    for root in roots:
        candidate = root / "shared" / "data" / folder
        if candidate.is_dir():
            return candidate
    return None


def _float_image(arr) -> np.ndarray:
    from .core._validation import as_float_image

    arr = np.asarray(arr)
    if arr.ndim == 3 and arr.shape[2] == 4:
        arr = arr[..., :3]
    return as_float_image(arr, allow_rgb=True)


# --------------------------------------------------------------------------------------
# the cases
# --------------------------------------------------------------------------------------

def lai_cases(data: Path, quick: bool) -> list[dict]:
    """The cases of the ``lai`` folder (``quick``: those listed in ``quick.txt``)."""
    names = sorted(p.name for p in data.iterdir() if (p / "case.json").is_file())
    if quick:
        listed = (data / "quick.txt").read_text().split()
        names = [n for n in listed if n in names]
    cases = []
    for name in names:
        meta = json.loads((data / name / "case.json").read_text())
        cases.append({"name": name, "category": meta["category"], "model": "rotation",
                      "extent": meta["extent_px"], "max_blur": float(meta["max_blur"]),
                      "dir": str(data / name)})
    return cases


def _lai_load(case: dict):
    from .core.io import read_image
    from .core.motion import CameraMotion

    folder = Path(case["dir"])
    return (_float_image(read_image(folder / "blurred.png")),
            _float_image(read_image(folder / "sharp.png")),
            CameraMotion.load(folder / "truth.json"))


def levin_cases(data: Path, quick: bool) -> list[dict]:
    """The 32 captures (``quick``: the 8 of the anchor protocol)."""
    names = sorted(p.stem for p in data.glob("im0*_ker0*.mat"))
    if quick:
        names = [n for n in names if n in LEVIN_ANCHOR_CASES]
    cases = []
    for name in names:
        kernel = name.split("_")[1]
        cases.append({"name": name, "category": kernel, "model": "translation",
                      "file": str(data / f"{name}.mat"), "anchor": name in LEVIN_ANCHOR_CASES})
    return cases


def levin_motion(kernel: np.ndarray, image_shape) -> object:
    """The translation motion of a Levin kernel ``f`` (a correlation kernel: ``y = x * f``).

    ``y(x) = sum_u f(u) x(x + u)``, i.e. ``g(x) = sum_p w_p f(x - t_p)`` with ``t_p = -u``
    for each tap ``u`` (column, row offsets from the kernel's centre).
    """
    from .core.camera import Intrinsics
    from .core.motion import CameraMotion

    f = np.asarray(kernel, np.float64)
    rows, cols = np.nonzero(f > 0)
    cy, cx = (f.shape[0] - 1) / 2, (f.shape[1] - 1) / 2
    poses = np.stack([-(cols - cx), -(rows - cy)], axis=1)
    return CameraMotion("translation", Intrinsics.from_image_shape(image_shape), poses,
                        f[rows, cols] / f[rows, cols].sum())


def _levin_load(case: dict):
    from scipy.io import loadmat

    mat = loadmat(case["file"])
    sharp = np.clip(np.asarray(mat["x"], np.float32), 0, 1)
    blurred = np.clip(np.asarray(mat["y"], np.float32), 0, 1)
    return blurred, sharp, levin_motion(mat["f"], blurred.shape)


def real_photos(data: Path) -> list[dict]:
    """The photos of the ``paper-real`` folder: input and the paper's outputs, per scene."""
    photos = []
    for folder in sorted(p for p in data.iterdir() if p.is_dir()):
        inputs = sorted(folder.glob("input.*"))
        if not inputs:
            continue
        paper = {key: next(iter(sorted(folder.glob(f"{key}.*"))), None)
                 for key in ("epalone", "xu_ep", "xu2013")}
        photos.append({"name": folder.name, "input": str(inputs[0]),
                       **{f"paper_{k}": (str(v) if v else None) for k, v in paper.items()}})
    return photos


# --------------------------------------------------------------------------------------
# running one ground-truth case
# --------------------------------------------------------------------------------------

def _profile_measures(blurred, truth, max_blur: float) -> dict:
    """Count, fidelity (NCC, width ratio) and orientation spread of the automatic profiles."""
    from .core.edges import extract_edge_profiles
    from .core.metrics import profile_fidelity

    t0 = time.perf_counter()
    profiles = extract_edge_profiles(blurred, max_blur, rng=0)
    seconds = time.perf_counter() - t0
    out = {"max_blur": max_blur, "n": len(profiles), "seconds": seconds}
    if len(profiles):
        ncc, ratio = profile_fidelity(profiles, truth)
        ratio = ratio[np.isfinite(ratio)]
        out.update(ncc=[round(float(v), 4) for v in ncc],
                   median_ncc=float(np.median(ncc)),
                   faithful=int(np.count_nonzero(ncc >= FAITHFUL_NCC)),
                   median_width_ratio=float(np.median(ratio)) if ratio.size else None)
    return out


def _run_truth_case(case: dict, suite: str, workdir: Path, methods, n_iter, log) -> dict:
    """Estimate with every method, deconvolve, and score one case with ground truth."""
    from .core.estimate import default_max_blur
    from .core.metrics import aligned_scores, motion_psf_ncc
    from .core.motion import CameraMotion

    blurred, sharp, truth = (_lai_load if suite == "lai" else _levin_load)(case)
    stem = workdir / case["name"]
    np.save(f"{stem}-blurred.npy", blurred)
    truth.save(f"{stem}-truth.json")
    rotation = suite == "lai"
    if suite == "levin":  # told the kernel's support, as the other methods of Levin's table
        case["max_blur"] = float(max(truth.psf_size() - 2, 3))
        case["extent"] = case["max_blur"]
    focal = truth.intrinsics.focal_px if suite == "lai" else None

    def scores(image):
        psnr, ssim = aligned_scores(image, sharp, rotation=rotation)
        out = {"psnr": psnr, "ssim": ssim}
        if suite == "levin":
            out["psnr_protocol"] = _levin_protocol_psnr(image, sharp)
        return out

    row = {**{k: v for k, v in case.items() if k not in ("dir", "file")},
           "shape": list(blurred.shape), "true_extent": truth.max_displacement(),
           "blurred": scores(blurred), "runs": {}}
    if suite == "lai":
        row["profiles_true"] = _profile_measures(blurred, truth, case["max_blur"])
        row["profiles_default"] = _profile_measures(blurred, truth,
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
            entry.update(scores(np.load(job["restored"])))
            entry["gain"] = entry["psnr"] - row["blurred"]["psnr"]
            if key not in ("oracle", "centred"):
                motion = CameraMotion.load(job["motion"])
                entry["ncc"] = motion_psf_ncc(motion, truth)
                entry["extent"] = motion.rescale(truth.image_shape).max_displacement()
                entry["collapsed"] = bool(entry["extent"] < COLLAPSE_EXTENT
                                          or res.get("no_blur"))
        row["runs"][key] = entry
    oracle_gain = row["runs"].get("oracle", {}).get("gain")
    for key in methods:
        run = row["runs"][key]
        if run.get("ok") and oracle_gain and oracle_gain > 0:
            run["share"] = run["gain"] / oracle_gain
    log(f"{suite} {case['name']}: blurred {row['blurred']['psnr']:.2f} | " + " | ".join(
        f"{_label(k)} " + (f"{r['psnr']:.2f}" + (f" NCC {r['ncc']:.2f}" if "ncc" in r else "")
                           if r.get("ok") else "failed")
        for k, r in row["runs"].items()))
    return row


def _levin_protocol_psnr(image, sharp) -> float:
    """PSNR under the anchor protocol of the levin README (1/10 px shift, 24 px border)."""
    from .core.metrics import align_to, psnr

    shifted, _ = align_to(image, sharp, upsample=LEVIN_ANCHOR_UPSAMPLE)
    c = LEVIN_ANCHOR_BORDER
    return psnr(np.clip(shifted, 0, 1)[c:-c, c:-c], np.asarray(sharp, np.float64)[c:-c, c:-c])


def _label(key: str) -> str:
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


def _run_real_photo(photo: dict, workdir: Path, sheets: Path, methods, log) -> dict:
    from ._sheets import make_sheet, read_rgb
    from .core.motion import CameraMotion

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
            entry.update(poses=motion.n_poses, extent=motion.max_displacement(),
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


# --------------------------------------------------------------------------------------
# summaries and Markdown
# --------------------------------------------------------------------------------------

def _ok(rows, key):
    return [r["runs"][key] for r in rows if r["runs"].get(key, {}).get("ok")]


def summarise(rows: list[dict], methods) -> list[dict]:
    """Means per group (category, or kernel for levin) and overall."""
    groups = {}
    for r in rows:
        groups.setdefault(r["category"], []).append(r)
    out = []
    for name, members in [*sorted(groups.items()), ("all", rows)]:
        entry = {"group": name, "n": len(members),
                 "blurred_psnr": _mean([r["blurred"]["psnr"] for r in members]),
                 "blurred_ssim": _mean([r["blurred"]["ssim"] for r in members])}
        for key in (*methods, "oracle", "centred"):
            ok = _ok(members, key)
            entry[key] = {"n_ok": len(ok), "psnr": _mean([r["psnr"] for r in ok]),
                          "ssim": _mean([r["ssim"] for r in ok]),
                          "ncc": _mean([r.get("ncc") for r in ok]),
                          "share": _mean([r.get("share") for r in ok]),
                          "collapsed": sum(bool(r.get("collapsed")) for r in ok),
                          "profiles": _median([r.get("n_profiles") for r in ok]),
                          "estimate_s": _median([r.get("estimate_s") for r in ok]),
                          "peak_rss_mib": max((r.get("peak_rss_mib") or 0 for r in ok),
                                              default=None)}
            if members and "psnr_protocol" in members[0]["blurred"]:
                entry[key]["psnr_protocol"] = _mean([r.get("psnr_protocol") for r in ok])
        if members and "psnr_protocol" in members[0]["blurred"]:
            entry["blurred_psnr_protocol"] = _mean([r["blurred"]["psnr_protocol"]
                                                    for r in members])
        if members and "profiles_true" in members[0]:
            for which in ("profiles_true", "profiles_default"):
                nccs = [v for r in members for v in r[which].get("ncc", [])]
                entry[which] = {
                    "median_count": _median([r[which]["n"] for r in members]),
                    "faithful_share": (float(np.mean(np.asarray(nccs) >= FAITHFUL_NCC))
                                       if nccs else None),
                    "median_ncc": float(np.median(nccs)) if nccs else None,
                    "median_width_ratio": _median([r[which].get("median_width_ratio")
                                                   for r in members]),
                    "cases_20": sum(r[which]["n"] >= 20 for r in members),
                    "max_seconds": max(r[which]["seconds"] for r in members)}
        out.append(entry)
    return out


def targets(rows: list[dict], methods) -> list[dict]:
    """The estimation issue's targets, checked on these cases."""
    out = []

    def paired(a, b):
        diffs = []
        for r in rows:
            ra, rb = r["runs"].get(a, {}), r["runs"].get(b, {})
            if ra.get("ok") and rb.get("ok"):
                diffs.append(ra["psnr"] - rb["psnr"])
        return diffs

    if "xu+ep" in methods and "xu" in methods:
        d = paired("xu+ep", "xu")
        if d:
            out.append(("Xu+Ep mean >= Xu mean + 0.3 dB", f"{statistics.fmean(d):+.2f} dB",
                        statistics.fmean(d) >= 0.3))
            share = float(np.mean(np.asarray(d) >= -0.2))
            out.append(("Xu+Ep >= Xu - 0.2 dB on >= 85% of the cases", f"{share:.0%}",
                        share >= 0.85))
    if "ep" in methods:
        ok = _ok(rows, "ep")
        ran = len(ok) / max(len(rows), 1)
        gain = _mean([r["gain"] for r in ok])
        worse = sum(r["gain"] < -0.5 for r in ok)
        out.append(("EpAlone mean >= blurred + 2 dB", _f(gain, "+.2f") + " dB",
                    None if gain is None else gain >= 2))
        out.append(("EpAlone runs on >= 90% of the cases", f"{ran:.0%}", ran >= 0.9))
        out.append(("EpAlone never below the blurred input by > 0.5 dB",
                    f"{worse} cases below", worse == 0))
    for key in methods:
        if key == "ep":
            continue
        share = _mean([r.get("share") for r in _ok(rows, key)])
        bound = 0.5 if rows and rows[0]["model"] == "rotation" else 0.75
        out.append((f"{METHODS[key]} recovers >= {bound:.0%} of the oracle's gain "
                    "(mean of per-case ratios)", _f(share, ".0%"),
                    None if share is None else share >= bound))
    return [{"target": t, "measured": m, "met": met} for t, m, met in out]


def _met(flag) -> str:
    return {True: "met", False: "**missed**", None: "not measured"}[flag]


def truth_markdown(result: dict) -> str:
    """The ``lai`` or ``levin`` suite as Markdown."""
    suite, methods = result["suite"], result["methods"]
    keys = (*methods, "oracle", "centred")
    rows, summary = result["cases"], result["summary"]
    group = "category" if suite == "lai" else "kernel"
    lines = [f"# `{suite}` suite{' (quick)' if result['quick'] else ''}: "
             f"{len(rows)} cases", "", _machine_line(result["machine"])
             + f"; {result['seconds'] / 60:.1f} min, {result['jobs']} case(s) at a time.",
             "", result["protocol"], ""]

    def cell(entry, what, spec):
        return "—" if not entry or entry.get(what) is None else format(entry[what], spec)

    def ran(e, n):
        return "" if e["n_ok"] == n else f" ({e['n_ok']}/{n})"

    header = [group, "cases", "blurred", *(_label(k) for k in keys),
              *(f"{METHODS[k]} share of oracle gain" for k in methods if k != "ep")]
    table = []
    for s in summary:
        table.append([f"**{s['group']}**" if s["group"] == "all" else s["group"], s["n"],
                      _f(s["blurred_psnr"], ".2f"),
                      *(cell(s[k], "psnr", ".2f") + ran(s[k], s["n"]) for k in keys),
                      *(cell(s[k], "share", ".0%") for k in methods if k != "ep")])
    lines += [f"## Mean PSNR (dB) per {group}", "",
              markdown_table(header, table, "lr" + "r" * (len(header) - 2)), "",
              "The share of the oracle's gain is the mean over cases of (method - blurred) / "
              "(oracle - blurred). A method that failed on a case (EpAlone refuses with too "
              "few edge profiles) is left out of its mean; the count is in brackets. "
              "*Truth at its centroid pose*: the true motion re-centred on its centroid pose, "
              "as every estimator returns a motion (claims 1-2) -- a perfect estimate; the "
              "gap between it and the oracle is what the alignment protocol (shift and "
              "in-plane rotation only, not the centroid pose's full 3-D rotation) costs an "
              "estimate.", ""]
    table = [[s["group"], _f(s["blurred_ssim"], ".3f"),
              *(cell(s[k], "ssim", ".3f") for k in keys),
              *(cell(s[k], "ncc", ".3f") for k in methods),
              *(str(s[k]["collapsed"]) for k in methods)] for s in summary]
    lines += [f"## Mean SSIM, mean PSF NCC and collapses per {group}", "",
              markdown_table([group, "blurred SSIM", *(f"{_label(k)} SSIM"
                                                       for k in keys),
                              *(f"{METHODS[k]} NCC" for k in methods),
                              *(f"{METHODS[k]} collapsed" for k in methods)], table,
                             "l" + "r" * (1 + len(keys) + 2 * len(methods))), "",
              f"PSF NCC: centroid-aligned local PSFs of the estimate against the truth on a "
              f"4x4 grid (1 = the same shapes). Collapsed: the estimate's blur extent is "
              f"under {COLLAPSE_EXTENT:g} px (the no-blur solution) or the estimator said "
              "it found no blur.", ""]
    if suite == "levin":
        anchor = [r for r in rows if r.get("anchor")]
        prot = [[ "blurred", _f(_mean([r["blurred"]["psnr_protocol"] for r in anchor]), ".2f"),
                  _f(_mean([r["blurred"]["psnr_protocol"] for r in rows]), ".2f")]]
        for k in keys:
            a = [r["runs"][k]["psnr_protocol"] for r in anchor if r["runs"][k].get("ok")]
            b = [r["runs"][k]["psnr_protocol"] for r in rows if r["runs"][k].get("ok")]
            prot.append([_label(k), _f(_mean(a), ".2f") + (
                "" if len(a) == len(anchor) else f" ({len(a)}/{len(anchor)})"),
                _f(_mean(b), ".2f") + ("" if len(b) == len(rows) else f" ({len(b)}/{len(rows)})")])
        prot.append(["Pan et al. 2016 (README anchor)", f"{LEVIN_PAN_2016:.2f}", "—"])
        lines += ["## Under the anchor protocol of the levin README", "",
                  markdown_table(["method", f"{len(anchor)} anchor cases (dB)",
                                  f"all {len(rows)} cases (dB)"], prot, "lrr"), "",
                  "Global shift by phase correlation at 1/10 px, cubic shift, 24 px border "
                  "crop, data range 1 (the README's protocol for its anchors).", ""]
    if summary and "profiles_true" in summary[0]:
        table = []
        for s in summary:
            for which, label in (("profiles_true", "true"), ("profiles_default", "default")):
                p = s[which]
                table.append([s["group"], label, _f(p["median_count"], ".0f"),
                              f"{p['cases_20']}/{s['n']}", _f(p["faithful_share"], ".0%"),
                              _f(p["median_ncc"], ".2f"), _f(p["median_width_ratio"], ".2f"),
                              _f(p["max_seconds"], ".2f")])
        lines += ["## Edge profiles: yield and fidelity", "",
                  markdown_table([group, "max blur", "median count", "cases with >= 20",
                                  f"kept with NCC >= {FAITHFUL_NCC:g}", "median NCC",
                                  "median width ratio", "slowest extraction (s)"], table,
                                 "llrrrrrr"), "",
                  "Automatic extraction (`extract_edge_profiles`, seed 0) at the case's true "
                  "max blur and at the default max blur of the image size. Fidelity: each "
                  "kept profile's derivative against the true local PSF's projection on its "
                  "normal at its centroid (centroid-aligned, 1 px bins; "
                  "`metrics.profile_fidelity`), pooled over the cases; width ratio: 10-90% "
                  "transition width of the profile over the truth's, median per case, then "
                  "the median of those.", ""]
    lines += ["## Targets of the estimation issue", "",
              markdown_table(["target", "measured", "status"],
                             [[t["target"], t["measured"], _met(t["met"])]
                              for t in result["targets"]], "lrl"), ""]

    def run_cell(r, k):
        e = r["runs"].get(k, {})
        if not e.get("ok"):
            return "failed" if e else "—"
        return f"{e['psnr']:.2f}" + (" (c)" if e.get("collapsed") else "")

    per_case = [[r["name"], _f(r.get("extent"), ".1f"), _f(r.get("max_blur"), "g"),
                 f"{r['blurred']['psnr']:.2f}", *(run_cell(r, k) for k in keys),
                 *(_f(r["runs"].get(k, {}).get("ncc"), ".2f") for k in methods),
                 _f(r["runs"].get("xu+ep", r["runs"].get("ep", {})).get("n_profiles"), "d",
                    "")] for r in rows]
    lines += ["## Per case: aligned PSNR (dB), PSF NCC, edge profiles", "",
              markdown_table(["case", "extent (px)", "max blur", "blurred",
                              *(_label(k) for k in keys),
                              *(f"{METHODS[k]} NCC" for k in methods), "profiles"], per_case,
                             "l" + "r" * (3 + len(keys) + len(methods) + 1)), "",
              "(c): the estimate collapsed (see above).", ""]
    detail = []
    for r in rows:
        for k in keys:
            e = r["runs"].get(k, {})
            notes = e.get("error") or "; ".join(e.get("warnings") or [])
            detail.append([r["name"], _label(k), _f(e.get("estimate_s"), ".1f"),
                           _f(e.get("deconvolve_s"), ".1f"), _f(e.get("peak_rss_mib"), ".0f"),
                           _f(e.get("poses"), "d", ""), _f(e.get("extent"), ".1f", ""),
                           notes[:120]])
    lines += ["## Time and peak memory per run", "",
              markdown_table(["case", "method", "estimate (s)", "deconvolve (s)",
                              "peak RSS (MiB)", "poses", "blur extent (px)", "notes"], detail,
                             "llrrrrrl"), "",
              "Wall-clock seconds in a fresh process per run (with several cases at a time "
              "the processes share the CPUs); peak RSS is the process's own `VmHWM`.", ""]
    return "\n".join(lines)


def real_markdown(result: dict) -> str:
    """The ``real`` suite as Markdown."""
    methods = result["methods"]
    lines = [f"# `real` suite: the paper's {len(result['photos'])} real photos", "",
             _machine_line(result["machine"]) + f"; {result['seconds'] / 60:.1f} min.", "",
             result["protocol"], ""]
    table = []
    for r in result["photos"]:
        cells = [r["name"], _f(r.get("profiles"), "d", "?")]
        for m in methods:
            e = r["runs"].get(m, {})
            if e.get("status") == 0:
                cells.append(f"{e['extent']:.1f} px, {e['poses']} poses, {e['seconds']:.0f} s"
                             + (" **no blur**" if e.get("collapsed") else ""))
            else:
                why = (e.get("stderr") or ["?"])[-1].removeprefix("edgecme: ")
                cells.append(f"exit {e.get('status')}: {why}")
        warn = "; ".join(ln.removeprefix("edgecme: warning: ")
                         for m in methods for ln in r["runs"].get(m, {}).get("stderr", [])
                         if "warning" in ln)
        cells.append(warn[:200])
        cells.append(f"[sheet](real-sheets/{r['name']}.png)")
        table.append(cells)
    lines += [markdown_table(["photo", "edge profiles (default max blur)",
                              *(f"{METHODS[m]}: blur, poses, time" for m in methods),
                              "warnings", "sheet"], table, "lr" + "l" * (len(methods) + 2)), "",
              "Blur extent: largest displacement from the local PSF's centroid over a 5x5 grid "
              "(`CameraMotion.blur_extent`). Times are the whole command (reading, "
              "estimation, deconvolution, writing).", ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------
# the command
# --------------------------------------------------------------------------------------

def run_suite(suite: str, out="edgecme-bench", *, data=None, quick: bool = False,
              jobs: int = 1, methods=tuple(METHODS), n_iter: int | None = None,
              cases: int | None = None, log=None) -> list[Path]:
    """Run one suite and write its report (Markdown + JSON) into ``out``.

    Parameters
    ----------
    suite : {"lai", "levin", "real"}
    out : path-like
        Output folder, created if missing (its parent must exist).
    data : path-like, optional
        The suite's data folder (default :func:`default_data_dir`).
    quick : bool
        ``lai``: the 20 cases of ``quick.txt``; ``levin``: the 8 anchor cases.
    jobs : int
        Cases run at once (each estimate is its own process).
    methods : sequence of {"ep", "xu", "xu+ep"}
        Estimators to run (``real``: EpAlone and Xu+Ep).
    n_iter, cases : int, optional
        Overrides (alternations per scale; the first ``cases`` cases only).
    log : callable, optional
        Called with one line per finished case.

    Returns
    -------
    list of Path
        The files written.
    """
    from .core import io as _io

    if suite not in SUITES:
        raise ValueError(f"unknown suite {suite!r}; use one of {', '.join(SUITES)}")
    log = log or (lambda message: None)
    data = Path(data) if data is not None else default_data_dir(suite)
    if data is None or not data.is_dir():
        where = f"{data}" if data is not None else f"../shared/data/{SUITES[suite]}"
        raise ValueError(f"no data for suite {suite!r}: {where} is not a folder "
                         "(pass --data DIR)")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a folder")
    if not out.exists() and not out.parent.is_dir():
        raise ValueError(f"cannot create the benchmark folder {out}: its parent folder "
                         f"{out.parent} does not exist")
    unknown = set(methods) - set(METHODS)
    if unknown:
        raise ValueError(f"unknown method(s) {sorted(unknown)}; use {', '.join(METHODS)}")
    jobs = max(1, int(jobs))
    machine = machine_info()
    t_start = time.perf_counter()
    out.mkdir(exist_ok=True)
    suffix = "-quick" if quick and suite != "real" else ""
    with tempfile.TemporaryDirectory(prefix=f"edgecme-{suite}-") as tmp:
        workdir = Path(tmp)
        if suite == "real":
            methods = tuple(m for m in ("ep", "xu+ep") if m in methods) or ("ep", "xu+ep")
            photos = real_photos(data)[:cases]
            if not photos:
                raise ValueError(f"no photos in {data} (expected <scene>/input.* folders)")
            sheets = out / "real-sheets"
            sheets.mkdir(exist_ok=True)
            with ThreadPoolExecutor(jobs) as pool:
                rows = list(pool.map(lambda p: _run_real_photo(p, workdir, sheets, methods,
                                                               log), photos))
            result = {"suite": suite, "methods": list(methods), "photos": rows,
                      "protocol": ("Each photo deblurred by `edgecme deblur INPUT -o OUT "
                                   "--method M` with every other option at its default (max "
                                   "blur, focal length, model); edge profiles counted by "
                                   "`edgecme profiles` at the default max blur."),
                      "data": str(data)}
            render = real_markdown
        else:
            found = (lai_cases if suite == "lai" else levin_cases)(data, quick)[:cases]
            if not found:
                raise ValueError(f"no cases in {data}")
            with ThreadPoolExecutor(jobs) as pool:
                rows = list(pool.map(lambda c: _run_truth_case(c, suite, workdir, methods,
                                                               n_iter, log), found))
            protocol = (
                "Aligned PSNR/SSIM: after the best global sub-pixel shift and in-plane "
                "rotation (up to 2 degrees), 5% border crop; each estimator told the case's "
                "max blur and the true focal length; model `rotation`; every estimate "
                "followed by the same hyper-Laplacian deconvolution; oracle = that "
                "deconvolution with the true motion." if suite == "lai" else
                "Aligned PSNR/SSIM: after the best global sub-pixel shift and in-plane "
                "rotation, 5% border crop; model `translation`; each estimator told the "
                "kernel's size as its max blur; the same hyper-Laplacian deconvolution "
                "after every estimate; oracle = that deconvolution with the kernel `f` "
                "of the capture (as a correlation kernel).")
            result = {"suite": suite, "quick": quick, "methods": list(methods),
                      "cases": rows, "summary": summarise(rows, methods),
                      "targets": targets(rows, methods), "protocol": protocol,
                      "data": str(data)}
            render = truth_markdown
        machine["load_average_end"] = load_average()
        result.update(machine=machine, jobs=jobs, quick=quick,
                      seconds=time.perf_counter() - t_start)
    written = []
    with contextlib.ExitStack() as stack:
        for ext, text in ((".md", render(result)),
                          (".json", json.dumps(result, indent=1, default=_jsonable) + "\n")):
            path = out / f"{suite}{suffix}{ext}"
            tmp_path = stack.enter_context(_io.atomic_path(path))
            tmp_path.write_text(text, encoding="utf-8")
            written.append(path)
    return written


def _jsonable(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and math.isnan(obj):
        return None
    return str(obj)
