"""Colour in the deconvolution: per-channel RGB against the opponent basis (issue 14).

Three parts, each written as a section of ``color.md``:

``lai``
    Every ``lai`` case (``--quick``: those of ``quick.txt``) deconvolved with its TRUE
    motion three times -- ``color="rgb"`` (R, G, B solved independently, the old
    default), ``color="opponent", chroma="full"`` and ``color="opponent",
    chroma="half"`` -- so the difference is the deconvolution's alone. Aligned PSNR
    (best global shift and in-plane rotation, as the suites), CPU seconds of the
    deconvolution, and the measured inter-channel noise correlation ``rho``
    (:func:`~napari_edgecme.core.photometry.channel_noise_correlation`), per category.
``lai-xuep``
    The same deconvolutions with each case's Xu+Ep estimate instead of the truth (told
    the true max blur and focal length, seed 0, as the ``lai`` suite runs it; the
    estimates are kept in ``--out/motions`` and reused by a later run).
``real``
    The paper's real photos (``../shared/data/paper-real``, camera JPEGs: no ground
    truth). The motion is estimated once (Xu+Ep, ``gamma="auto"`` from the file, the
    command line's defaults), then the photo is deconvolved in linear light with each
    colour setting; a side-by-side sheet per photo in ``--sheets`` and, per photo, rho
    and a no-reference measure of colour noise: the standard deviation of the
    high-pass chroma (Immerkaer response of the two opponent chroma axes) over the
    flattest quarter of the image, relative to the blurred input's.

    python benchmarks/bench_color.py [--parts lai lai-xuep real] [--quick] [--jobs 2]
                                     [--out benchmarks/out/color]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from napari_edgecme._report import fmt, machine_info, machine_line, markdown_table, mean_or_none
from napari_edgecme._suites._data import default_data_dir, lai_cases, lai_load, real_photos

#: (key, deconvolve() colour parameters)
VARIANTS = (("rgb", {"color": "rgb"}),
            ("opponent", {"color": "opponent", "chroma": "full"}),
            ("opponent-half", {"color": "opponent", "chroma": "half"}))


def _cpu() -> float:
    t = os.times()
    return t.user + t.system


def lai_case(case: dict, motions: Path | None = None) -> dict:
    """One ``lai`` case: the three deconvolutions, scored. With the true motion, or with
    ``motions`` a folder: with the case's Xu+Ep estimate (as the suite runs it), kept
    there and reused from there."""
    from napari_edgecme.core.deconv import deconvolve
    from napari_edgecme.core.estimate import estimate_motion
    from napari_edgecme.core.metrics import aligned_psnr
    from napari_edgecme.core.motion import CameraMotion
    from napari_edgecme.core.photometry import channel_noise_correlation

    blurred, sharp, motion = lai_load(case)
    if motions is not None:
        path = motions / f"{case['name']}-xu+ep.json"
        if path.is_file():
            motion = CameraMotion.load(path)
        else:
            motion = estimate_motion(blurred, "xu+ep", "rotation", case["max_blur"],
                                     motion.intrinsics.focal_px, rng=0).motion
            motion.save(path)
    row = {"name": case["name"], "category": case["category"],
           "rho": channel_noise_correlation(blurred),
           "blurred": aligned_psnr(blurred, sharp, rotation=True)}
    for key, params in VARIANTS:
        c0 = _cpu()
        restored = deconvolve(blurred, motion, **params)
        row[f"{key}_cpu"] = _cpu() - c0
        row[key] = aligned_psnr(restored, sharp, rotation=True)
    return row


def _in_parallel(func, items, jobs: int, *args) -> list[dict]:
    """``func(item, *args)`` for every item in ``jobs`` processes, each row logged."""
    with ProcessPoolExecutor(jobs) as pool:
        rows = []
        for row in pool.map(func, items, *([a] * len(items) for a in args)):
            print(json.dumps(row), file=sys.stderr, flush=True)
            rows.append(row)
    return rows


def lai_report(rows: list[dict]) -> list[str]:
    groups: dict[str, list] = {}
    for r in rows:
        groups.setdefault(r["category"], []).append(r)
    table = []
    for name, members in [*sorted(groups.items()), ("all", rows)]:
        def mean(key, members=members):
            return mean_or_none([r[key] for r in members])

        def median(key, members=members):
            return float(np.median([r[key] for r in members]))

        d_full = [r["opponent"] - r["rgb"] for r in members]
        d_half = [r["opponent-half"] - r["rgb"] for r in members]
        table.append([f"**{name}**" if name == "all" else name, len(members),
                      fmt(mean("rho"), ".2f"), fmt(mean("blurred"), ".2f"),
                      fmt(mean("rgb"), ".2f"), fmt(mean("opponent"), ".2f"),
                      fmt(mean_or_none(d_full), "+.2f"),
                      f"{sum(d > 0 for d in d_full)}/{len(d_full)}", fmt(min(d_full), "+.2f"),
                      fmt(mean("opponent-half"), ".2f"), fmt(mean_or_none(d_half), "+.2f"),
                      fmt(median("rgb_cpu"), ".1f"), fmt(median("opponent_cpu"), ".1f"),
                      fmt(median("opponent-half_cpu"), ".1f")])
    return [markdown_table(["category", "cases", "rho", "blurred", "rgb", "opponent",
                            "opp - rgb", "better", "worst", "opponent half",
                            "half - rgb", "CPU rgb (s)", "CPU opp", "CPU half"],
                           table, "lrrrrrrrrrrrrr")]


def _chroma_noise(image: np.ndarray, mask: np.ndarray) -> float:
    """Std of the Immerkaer response of the two opponent chroma axes on ``mask``."""
    from scipy.ndimage import convolve

    from napari_edgecme.core.deconv import to_opponent

    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], float) / 6.0
    opp = to_opponent(np.asarray(image, np.float64))
    return float(np.mean([np.std(convolve(opp[..., c], kernel, mode="reflect")[mask])
                          for c in (1, 2)]))


def real_photo(photo: dict, sheets: Path) -> dict:
    """One real photo: one Xu+Ep estimate, three deconvolutions, a sheet."""
    from scipy.ndimage import uniform_filter

    from napari_edgecme._sheets import choose_crops, make_sheet, read_rgb
    from napari_edgecme.core.deblur import deblur
    from napari_edgecme.core.deconv import deconvolve
    from napari_edgecme.core.photometry import channel_noise_correlation, decide_gamma

    image = read_rgb(photo["input"])
    curve, reason = decide_gamma(photo["input"])
    t0 = time.perf_counter()
    restored_rgb, estimate = deblur(image, gamma=curve, deconv_params=dict(VARIANTS[0][1]))
    seconds = time.perf_counter() - t0
    linear = curve.decode(image)
    out = {"name": photo["name"], "gamma": f"{curve.name} ({reason})",
           "rho": channel_noise_correlation(linear), "estimate_s": seconds}
    results = {"rgb": restored_rgb}
    for key, params in VARIANTS[1:]:
        c0 = _cpu()
        results[key] = curve.encode(np.clip(deconvolve(linear, estimate.motion, **params), 0, 1))
        out[f"{key}_cpu"] = _cpu() - c0
    # the flattest quarter of the blurred photo (local luminance variance), where what
    # varies after deconvolution is amplified noise, not scene detail
    gray = image.mean(axis=2)
    var = uniform_filter(gray ** 2, 15) - uniform_filter(gray, 15) ** 2
    mask = var <= np.quantile(var, 0.25)
    base = _chroma_noise(image, mask)
    for key, img in results.items():  # None for a gray photo (no chroma at all)
        out[f"{key}_chroma_noise"] = _chroma_noise(img, mask) / base if base > 0 else None
    crops = choose_crops(image, 2)
    make_sheet([("blurred", image), *[(f"Xu+Ep, color {k}", v) for k, v in results.items()]],
               sheets / f"{photo['name']}.png", crops=crops,
               title=f"{photo['name']}: colour in the deconvolution (rho {out['rho']:.2f})")
    return out


def real_report(rows: list[dict]) -> list[str]:
    table = [[r["name"], r["gamma"], fmt(r["rho"], ".2f"),
              *(fmt(r[f"{k}_chroma_noise"], ".2f") for k, _ in VARIANTS),
              fmt(r["opponent_cpu"], ".1f"), fmt(r["opponent-half_cpu"], ".1f")]
             for r in rows]
    return [markdown_table(["photo", "gamma", "rho", "chroma noise rgb", "opponent",
                            "opponent half", "CPU opp (s)", "CPU half"], table, "llrrrrrr")]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", nargs="+", default=["lai", "lai-xuep", "real"],
                        choices=["lai", "lai-xuep", "real"])
    parser.add_argument("--quick", action="store_true", help="lai: the cases of quick.txt")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", default="benchmarks/out/color", type=Path)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    lines = ["# Colour in the deconvolution: per-channel RGB against the opponent basis", "",
             f"Written by `benchmarks/bench_color.py`; {machine_line(machine_info())}.", ""]
    if "lai" in args.parts:
        rows = _in_parallel(lai_case, lai_cases(default_data_dir("lai"), args.quick), args.jobs)
        (args.out / "color-lai.json").write_text(json.dumps(rows, indent=1))
        lines += [f"## `lai`, true motion ({len(rows)} cases)", "",
                  "Aligned PSNR (dB) of the hyper-Laplacian deconvolution with the true "
                  "motion; CPU: median seconds of one deconvolution.", "",
                  *lai_report(rows), ""]
    if "lai-xuep" in args.parts:
        motions = args.out / "motions"
        motions.mkdir(exist_ok=True)
        rows = _in_parallel(lai_case, lai_cases(default_data_dir("lai"), args.quick), args.jobs,
                            motions)
        (args.out / "color-lai-xuep.json").write_text(json.dumps(rows, indent=1))
        lines += [f"## `lai`, Xu+Ep's estimate ({len(rows)} cases)", "",
                  "The same, each case deconvolved with its Xu+Ep estimate (told the true "
                  "max blur and focal length, seed 0, as the suite runs it) instead of the "
                  "truth: what a user gets.", "", *lai_report(rows), ""]
    if "real" in args.parts:
        sheets = args.out / "sheets"
        sheets.mkdir(exist_ok=True)
        rows = _in_parallel(real_photo, real_photos(default_data_dir("real")), args.jobs, sheets)
        (args.out / "color-real.json").write_text(json.dumps(rows, indent=1))
        lines += [f"## The paper's real photos ({len(rows)})", "",
                  "One Xu+Ep estimate per photo (command-line defaults, gamma from the "
                  "file), deconvolved with each colour setting. Chroma noise: standard "
                  "deviation of the high-pass chroma on the flattest quarter of the photo, "
                  "relative to the blurred input (lower: less colour noise).", "",
                  *real_report(rows), ""]
    target = args.out / "color.md"
    target.write_text("\n".join(lines), encoding="utf-8")
    print(target)
    return 0


if __name__ == "__main__":
    sys.exit(main())
