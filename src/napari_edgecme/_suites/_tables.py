"""The suites' summaries, targets and Markdown reports."""

from __future__ import annotations

import statistics

import numpy as np

from .._report import fmt, machine_line, markdown_table, mean_or_none, median_or_none, met_mark
from ._cases import COLLAPSE_EXTENT, FAITHFUL_NCC, METHODS, method_label
from ._data import LEVIN_PAN_2016

__all__ = ["real_markdown", "summarise", "targets", "truth_markdown"]


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
                 "blurred_psnr": mean_or_none([r["blurred"]["psnr"] for r in members]),
                 "blurred_ssim": mean_or_none([r["blurred"]["ssim"] for r in members])}
        for key in (*methods, "oracle", "centred"):
            ok = _ok(members, key)
            entry[key] = {"n_ok": len(ok), "psnr": mean_or_none([r["psnr"] for r in ok]),
                          "ssim": mean_or_none([r["ssim"] for r in ok]),
                          "ncc": mean_or_none([r.get("ncc") for r in ok]),
                          "share": mean_or_none([r.get("share") for r in ok]),
                          "collapsed": sum(bool(r.get("collapsed")) for r in ok),
                          "profiles": median_or_none([r.get("n_profiles") for r in ok]),
                          "estimate_s": median_or_none([r.get("estimate_s") for r in ok]),
                          "peak_rss_mib": max((r.get("peak_rss_mib") or 0 for r in ok),
                                              default=None)}
            if members and "psnr_protocol" in members[0]["blurred"]:
                entry[key]["psnr_protocol"] = mean_or_none([r.get("psnr_protocol") for r in ok])
        if members and "psnr_protocol" in members[0]["blurred"]:
            entry["blurred_psnr_protocol"] = mean_or_none([r["blurred"]["psnr_protocol"]
                                                    for r in members])
        if members and "profiles_true" in members[0]:
            for which in ("profiles_true", "profiles_default"):
                nccs = [v for r in members for v in r[which].get("ncc", [])]
                entry[which] = {
                    "median_count": median_or_none([r[which]["n"] for r in members]),
                    "faithful_share": (float(np.mean(np.asarray(nccs) >= FAITHFUL_NCC))
                                       if nccs else None),
                    "median_ncc": float(np.median(nccs)) if nccs else None,
                    "median_width_ratio": median_or_none([r[which].get("median_width_ratio")
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
            out.append(("Xu+Ep >= Xu - 0.2 dB on >= 85% of the cases", f"{share:.1%}",
                        share >= 0.85))
    if "ep" in methods:
        ok = _ok(rows, "ep")
        ran = len(ok) / max(len(rows), 1)
        gain = mean_or_none([r["gain"] for r in ok])
        worse = sum(r["gain"] < -0.5 for r in ok)
        out.append(("EpAlone mean >= blurred + 2 dB", fmt(gain, "+.2f") + " dB",
                    None if gain is None else gain >= 2))
        out.append(("EpAlone runs on >= 90% of the cases", f"{ran:.1%}", ran >= 0.9))
        out.append(("EpAlone never below the blurred input by > 0.5 dB",
                    f"{worse} cases below", worse == 0))
    for key in methods:
        if key == "ep":
            continue
        share = mean_or_none([r.get("share") for r in _ok(rows, key)])
        bound = 0.5 if rows and rows[0]["model"] == "rotation" else 0.75
        out.append((f"{METHODS[key]} recovers >= {bound:.0%} of the oracle's gain "
                    "(mean of per-case ratios)", fmt(share, ".1%"),
                    None if share is None else share >= bound))
    return [{"target": t, "measured": m, "met": met} for t, m, met in out]


def truth_markdown(result: dict) -> str:
    """The ``lai`` or ``levin`` suite as Markdown."""
    suite, methods = result["suite"], result["methods"]
    keys = (*methods, "oracle", "centred")
    rows, summary = result["cases"], result["summary"]
    group = "category" if suite.startswith("lai") else "kernel"
    lines = [f"# `{suite}` suite{' (quick)' if result['quick'] else ''}: "
             f"{len(rows)} cases", "", machine_line(result["machine"])
             + f"; {result['seconds'] / 60:.1f} min, {result['jobs']} case(s) at a time.",
             "", result["protocol"], ""]

    def cell(entry, what, spec):
        return "—" if not entry or entry.get(what) is None else format(entry[what], spec)

    def ran(e, n):
        return "" if e["n_ok"] == n else f" ({e['n_ok']}/{n})"

    header = [group, "cases", "blurred", *(method_label(k) for k in keys),
              *(f"{METHODS[k]} share of oracle gain" for k in methods if k != "ep")]
    table = []
    for s in summary:
        table.append([f"**{s['group']}**" if s["group"] == "all" else s["group"], s["n"],
                      fmt(s["blurred_psnr"], ".2f"),
                      *(cell(s[k], "psnr", ".2f") + ran(s[k], s["n"]) for k in keys),
                      *(cell(s[k], "share", ".1%") for k in methods if k != "ep")])
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
    table = [[s["group"], fmt(s["blurred_ssim"], ".3f"),
              *(cell(s[k], "ssim", ".3f") for k in keys),
              *(cell(s[k], "ncc", ".3f") for k in methods),
              *(str(s[k]["collapsed"]) for k in methods)] for s in summary]
    lines += [f"## Mean SSIM, mean PSF NCC and collapses per {group}", "",
              markdown_table([group, "blurred SSIM", *(f"{method_label(k)} SSIM"
                                                       for k in keys),
                              *(f"{METHODS[k]} NCC" for k in methods),
                              *(f"{METHODS[k]} collapsed" for k in methods)], table,
                             "l" + "r" * (1 + len(keys) + 2 * len(methods))), "",
              f"PSF NCC: centroid-aligned local PSFs of the estimate against the truth on a "
              f"4x4 grid (1 = the same shapes). Collapsed: no pose of the estimate is "
              f"{COLLAPSE_EXTENT:g} px or more from its local PSF's centroid "
              "(`CameraMotion.max_displacement`: the no-blur solution) or the estimator "
              "said it found no blur. Blur extent: the longest side of the local PSFs' "
              "support, largest over a 5x5 grid (`CameraMotion.blur_extent`).", ""]
    if suite == "levin":
        anchor = [r for r in rows if r.get("anchor")]
        prot = [["blurred",
                 fmt(mean_or_none([r["blurred"]["psnr_protocol"] for r in anchor]), ".2f"),
                 fmt(mean_or_none([r["blurred"]["psnr_protocol"] for r in rows]), ".2f")]]
        for k in keys:
            a = [r["runs"][k]["psnr_protocol"] for r in anchor if r["runs"][k].get("ok")]
            b = [r["runs"][k]["psnr_protocol"] for r in rows if r["runs"][k].get("ok")]
            prot.append([method_label(k), fmt(mean_or_none(a), ".2f") + (
                "" if len(a) == len(anchor) else f" ({len(a)}/{len(anchor)})"),
                fmt(mean_or_none(b), ".2f") + (
                    "" if len(b) == len(rows) else f" ({len(b)}/{len(rows)})")])
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
                table.append([s["group"], label, fmt(p["median_count"], ".0f"),
                              f"{p['cases_20']}/{s['n']}", fmt(p["faithful_share"], ".0%"),
                              fmt(p["median_ncc"], ".2f"), fmt(p["median_width_ratio"], ".2f"),
                              fmt(p["max_seconds"], ".2f")])
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
                             [[t["target"], t["measured"], met_mark(t["met"])]
                              for t in result["targets"]], "lrl"), ""]

    def run_cell(r, k):
        e = r["runs"].get(k, {})
        if not e.get("ok"):
            return "failed" if e else "—"
        return f"{e['psnr']:.2f}" + (" (c)" if e.get("collapsed") else "")

    per_case = [[r["name"], fmt(r.get("extent"), ".1f"), fmt(r.get("max_blur"), "g"),
                 f"{r['blurred']['psnr']:.2f}", *(run_cell(r, k) for k in keys),
                 *(fmt(r["runs"].get(k, {}).get("ncc"), ".2f") for k in methods),
                 fmt(r["runs"].get("xu+ep", r["runs"].get("ep", {})).get("n_profiles"), "d",
                    "")] for r in rows]
    lines += ["## Per case: aligned PSNR (dB), PSF NCC, edge profiles", "",
              markdown_table(["case", "extent (px)", "max blur", "blurred",
                              *(method_label(k) for k in keys),
                              *(f"{METHODS[k]} NCC" for k in methods), "profiles"], per_case,
                             "l" + "r" * (3 + len(keys) + len(methods) + 1)), "",
              "(c): the estimate collapsed (see above).", ""]
    detail = []
    for r in rows:
        for k in keys:
            e = r["runs"].get(k, {})
            notes = e.get("error") or "; ".join(e.get("warnings") or [])
            detail.append([r["name"], method_label(k), fmt(e.get("estimate_s"), ".1f"),
                           fmt(e.get("deconvolve_s"), ".1f"), fmt(e.get("peak_rss_mib"), ".0f"),
                           fmt(e.get("poses"), "d", ""), fmt(e.get("extent"), ".1f", ""),
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
             machine_line(result["machine"]) + f"; {result['seconds'] / 60:.1f} min.", "",
             result["protocol"], ""]
    table = []
    for r in result["photos"]:
        cells = [r["name"], fmt(r.get("profiles"), "d", "?")]
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
              "Blur extent: the longest side of the local PSFs' support (bounding box), "
              "largest over a 5x5 grid (`CameraMotion.blur_extent`); **no blur**: no pose "
              f"{COLLAPSE_EXTENT:g} px or more from its PSF's centroid. Times are the whole "
              "command (reading, estimation, deconvolution, writing).", ""]
    return "\n".join(lines)
