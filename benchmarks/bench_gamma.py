"""Gamma (issue 14, item 3): estimating and deconvolving in linear light, measured.

Runs the ground-truth suites with Xu+Ep twice, ``gamma="linear"`` (the values as they are)
and ``gamma="auto"`` (decided from each case's file, as ``edgecme deblur --gamma auto``),
and writes ``gamma.md``: per set, per category, the blurred input, both runs and their
difference. Sets: ``lai-srgb`` (the lai cases blurred in linear light and sRGB-encoded;
auto -> srgb for these 8-bit PNGs) and ``levin`` (linear captures in .mat files; auto ->
linear). Each run's full report (``<suite>-quick.md``/``.json``) is kept in
``--out/<suite>-<gamma>/``.

    python benchmarks/bench_gamma.py [--full] [--jobs 2] [--out DIR] [--cache DIR]
    python benchmarks/bench_gamma.py --report-only --out DIR   # gamma.md from the JSONs
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from napari_edgecme._report import fmt, machine_line, markdown_table, mean_or_none
from napari_edgecme._suites import run_suite

SETS = ("lai-srgb", "levin")
GAMMAS = ("linear", "auto")
METHOD = "xu+ep"
TARGETS = {"lai-srgb": ("auto >= linear + 0.5 dB (mean)", lambda d: d >= 0.5),
           "levin": ("auto >= linear (no loss, mean)", lambda d: d >= -0.005)}


def _load(out: Path, suite: str, gamma: str, quick: bool):
    path = out / f"{suite}-{gamma}" / f"{suite}{'-quick' if quick else ''}.json"
    return json.loads(path.read_text()) if path.is_file() else None


def report(out: Path, quick: bool) -> str:
    lines = ["# Gamma: estimation and deconvolution in linear light (issue 14, item 3)", "",
             "Xu+Ep on each set twice: `gamma=\"linear\"` (the values as stored) and "
             "`gamma=\"auto\"` (decided from each case's file as `edgecme deblur --gamma auto` "
             "does; with srgb the blurred image is linearised, the motion estimated and the "
             "image deconvolved in linear light, and the result re-encoded before scoring). "
             "Aligned PSNR (dB) as in the suites' own reports, same cases, same seeds. "
             f"Written by `benchmarks/bench_gamma.py`{'' if quick else ' --full'}.", ""]
    for suite in SETS:
        runs = {g: _load(out, suite, g, quick) for g in GAMMAS}
        if not all(runs.values()):
            missing = [g for g, r in runs.items() if r is None]
            lines += [f"## `{suite}`", "", f"Not finished: gamma {', '.join(missing)}.", ""]
            continue
        lin, auto = runs["linear"], runs["auto"]
        by_name = {r["name"]: r for r in auto["cases"]}
        groups: dict[str, list] = {}
        for r in lin["cases"]:
            a = by_name.get(r["name"])
            if a is None:
                continue
            groups.setdefault(r["category"], []).append((r, a))
        every = [pair for members in groups.values() for pair in members]
        chosen = sorted({f"{a['gamma']} ({a['gamma_reason']})" for _, a in every})
        table = []
        for name, members in [*sorted(groups.items()), ("all", every)]:
            def ok_psnr(rows, key):
                return [x["runs"][key]["psnr"] for x in rows if x["runs"][key].get("ok")]

            paired = [(r["runs"][METHOD]["psnr"], a["runs"][METHOD]["psnr"]) for r, a in members
                      if r["runs"][METHOD].get("ok") and a["runs"][METHOD].get("ok")]
            diff = mean_or_none([b - c for c, b in paired])
            table.append([f"**{name}**" if name == "all" else name, len(members),
                          fmt(mean_or_none([r["blurred"]["psnr"] for r, _ in members]), ".2f"),
                          fmt(mean_or_none([c for c, _ in paired]), ".2f"),
                          fmt(mean_or_none([b for _, b in paired]), ".2f"),
                          fmt(diff, "+.2f"),
                          f"{sum(b > c for c, b in paired)}/{len(paired)}",
                          fmt(mean_or_none(ok_psnr([r for r, _ in members], "oracle")), ".2f"),
                          fmt(mean_or_none(ok_psnr([a for _, a in members], "oracle")), ".2f")])
        all_diff = mean_or_none([a["runs"][METHOD]["psnr"] - r["runs"][METHOD]["psnr"]
                                 for r, a in every if r["runs"][METHOD].get("ok")
                                 and a["runs"][METHOD].get("ok")])
        target, test = TARGETS[suite]
        met = "—" if all_diff is None else ("met" if test(all_diff) else "missed")
        group = "category" if suite.startswith("lai") else "kernel"
        lines += [f"## `{suite}`{' (quick)' if quick else ''}: {len(every)} cases", "",
                  "linear run: " + machine_line(lin["machine"])
                  + f"; {lin['seconds'] / 60:.1f} min, {lin['jobs']} case(s) at a time.", "",
                  "auto run: " + machine_line(auto["machine"])
                  + f"; {auto['seconds'] / 60:.1f} min, {auto['jobs']} case(s) at a time.", "",
                  f"auto chose: {'; '.join(chosen)}.", "",
                  markdown_table([group, "cases", "blurred", "Xu+Ep linear", "Xu+Ep auto",
                                  "auto - linear", "cases auto better", "oracle linear",
                                  "oracle auto"], table, "lrrrrrrrr"), "",
                  f"Target: {target}: measured {fmt(all_diff, '+.2f')} dB, **{met}**. "
                  "Oracle: the same deconvolution with the true motion, in the run's light "
                  "(so oracle auto - oracle linear is the deconvolution's own share of the "
                  "gain).", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="all cases, not the quick sets")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", default="benchmarks/out/gamma", type=Path)
    parser.add_argument("--cache", default=None, help="lai-srgb's rendered cases")
    parser.add_argument("--sets", nargs="+", default=list(SETS), choices=SETS)
    parser.add_argument("--report-only", action="store_true")
    parser.add_argument("--report", default=None, type=Path,
                        help="where to write gamma.md (default: --out/gamma.md)")
    args = parser.parse_args(argv)
    quick = not args.full
    args.out.mkdir(parents=True, exist_ok=True)
    if not args.report_only:
        for suite in args.sets:
            for gamma in GAMMAS:
                folder = args.out / f"{suite}-{gamma}"
                folder.mkdir(exist_ok=True)
                run_suite(suite, folder, quick=quick, jobs=args.jobs, methods=(METHOD,),
                          gamma=gamma, cache=args.cache,
                          log=lambda line, g=gamma: print(f"[{g}] {line}", file=sys.stderr,
                                                          flush=True))
                target = args.report or args.out / "gamma.md"
                target.write_text(report(args.out, quick), encoding="utf-8")
    target = args.report or args.out / "gamma.md"
    target.write_text(report(args.out, quick), encoding="utf-8")
    print(target)
    return 0


if __name__ == "__main__":
    sys.exit(main())
