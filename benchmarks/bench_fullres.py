"""The full-resolution yardstick for camera photos (issue 14): 1, 12 and 24 MP, as a user runs it.

Cases. A ``lai`` photo (``shared/data/lai/<case>/sharp.png``, 640 px, 8-bit) upscaled to
about 1, 12 and 24 megapixels with its aspect ratio kept (Lanczos, 8-bit), blurred by the
case's recorded gyro shake (``truth.json``, model ``rotation``). The truth's intrinsics are
rescaled to the big image (focal length and principal point scale with it,
``Intrinsics.rescaled``) and its rotation angles are multiplied by one factor so that the
blur extent (``CameraMotion.blur_extent()``, the longest side of the PSFs) is 60 px at
12 MP and proportional to the longer side at the other sizes. The gyro path is then
subdivided *uniformly in time* (every segment between two gyro samples into the same
number of poses, so that no image corner moves more than 1 px between consecutive poses:
the gyro's own dwell times are kept, unlike a constant-speed resampling) and rendered
exactly by dense warping (``core.synth.render_blur``: cubic, mirrored borders), with 1 %
Gaussian noise, quantised to 8 bits and written as an untagged RGB PNG, so that
``--gamma auto`` takes the values as linear, as the blur was made. The rendered motion
(``truth.json``, equal weights) is the truth the estimate is scored against. Everything is
cached in ``--cache`` (default ``/tmp/fullres-cache``) with the seconds rendering took.

Run. Per case and size, in a fresh Python process, the public command exactly as a user
would type it: ``edgecme deblur IMG -o OUT.png --save-motion MOTION.json`` (no other option;
the process runs ``napari_edgecme.cli.main`` and then reads its own peak RSS, ``VmHWM``).
With ``--pythonpath DIR`` the child gets ``PYTHONPATH=DIR`` (a frozen snapshot of ``src``),
and this script imports the engine from there too (rendering, metrics), so a run is
self-consistent while others edit the working tree.

Scored. Wall seconds of the command (process start to exit) and its peak RSS; the PSF NCC
of the estimate against the truth at full resolution (``motion_psf_ncc``, grid 3x3 and the
default 4x4; the estimate is rescaled to the photo as ``deblur`` applies it), and the same
at the source photo's resolution (3x3, both PSFs low-passed by
``band_sigma_for_upscale(upscale)``: a 640 px photo upscaled 6.5 times to 12 MP carries no
detail finer than about 6.5 px, so no estimator can determine a PSF's structure below
that, and the pixel-scale NCC of a thin 60 px path punishes what the photo cannot say); the blur
extent the command reports (its summary line) and that of the saved motion rescaled to full
resolution, beside the truth's; aligned PSNR (rotation-aware as the ``lai`` suite scores,
``aligned_psnr(..., rotation=True)``, but with the angle searched on a copy of about 1 MP:
:func:`aligned_psnr_fast`) against the upscaled sharp image of the
blurred input, the restored image and the oracle (``edgecme deconvolve BLURRED --motion
truth.json -o ORACLE.png``: the same deconvolution with the same defaults as ``deblur``, given
the true motion; cached -- it does not depend on the estimator -- and redone when the
deconvolution's code changes), and the share of the
oracle's gain, ``(restored - blurred) / (oracle - blurred)``. Above ``--psnr-crop-mp``
megapixels the PSNRs are computed on a central crop of that many megapixels (said in the
table).

    python benchmarks/bench_fullres.py [--sizes 12,1,24] [--cases natural_01_gyro1,...]
        [--pythonpath /tmp/snap/src] [--out benchmarks/results/fullres.md] [--merge]
        [--render-step PX]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np

DATA = Path("/work/shared/data/lai")
CACHE = Path("/tmp/fullres-cache")
CASES = ("natural_01_gyro1", "manmade_02_gyro4")
#: Blur extent (px) at 12 MP; other sizes scale with the longer side.
EXTENT_12MP = 60.0
NOISE = 0.01
#: Largest corner movement (px) between consecutive rendered poses.
RENDER_STEP_PX = 1.0
#: Issue 14's targets.
TARGETS = {"ncc": 0.7, "share": 0.7, "wall_s_12": 150.0, "mem_gib": {12: 3.0, 24: 4.0}}
_MARKER = "BENCH-FULLRES-CHILD "

# run inside the fresh process: the command line, then this process's own peak RSS
_CHILD = f"""
import json, sys, time
t0 = time.perf_counter()
from napari_edgecme.cli import main
try:
    rc = main(sys.argv[1:])
except SystemExit as done:
    rc = done.code if isinstance(done.code, int) else 1
import napari_edgecme
from napari_edgecme._worker import peak_rss_mib
print({_MARKER!r} + json.dumps({{"rc": rc, "peak_rss_mib": peak_rss_mib(),
      "seconds_in_process": time.perf_counter() - t0, "cpu_s": time.process_time(),
      "engine": napari_edgecme.__file__}}),
      flush=True)
sys.exit(rc)
"""


def _log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def target_shape(shape640, megapixels: float) -> tuple[int, int]:
    """``(rows, cols)`` of about ``megapixels`` MP with the aspect ratio of ``shape640``."""
    rows0, cols0 = shape640
    scale = math.sqrt(megapixels * 1e6 / (rows0 * cols0))
    return round(rows0 * scale), round(cols0 * scale)


def _seed(name: str) -> int:
    return zlib.crc32(name.encode())


def _time_uniform(poses: np.ndarray, motion_cls, model, intrinsics, step_px: float):
    """The path with every gyro interval cut into the same number of poses, so that no
    image corner moves more than ``step_px`` between consecutive poses (equal weights:
    each gyro interval keeps its share of the exposure)."""
    from napari_edgecme.core.camera import homographies, warp_points

    corners = warp_points(homographies(model, intrinsics, poses), intrinsics.corners)
    steps = np.linalg.norm(np.diff(corners, axis=0), axis=-1).max()
    n = max(1, math.ceil(steps / step_px))
    t = (np.arange(n) / n)[:, None, None]
    seg = poses[:-1][None] * (1 - t) + poses[1:][None] * t  # (n, segments, d)
    dense = np.concatenate([seg.transpose(1, 0, 2).reshape(-1, poses.shape[1]), poses[-1:]])
    return motion_cls.from_trajectory(dense, model, intrinsics), n


def prepare(case: str, mp: int, cache: Path, render_step: float = RENDER_STEP_PX) -> dict:
    """Render (or reuse) the case at ``mp`` megapixels; return its paths and numbers.

    ``truth.json`` is always the path densified to ``RENDER_STEP_PX``; a larger
    ``render_step`` renders the image from a sparser sampling of the same path (cheaper;
    at 24 MP the recorded gyro samples, 3.0 px apart, differ from the 1 px rendering by
    0.00075 RMS, 0.0049 at most, on a 768x768 crop near a corner: a fraction of the 1 %
    noise)."""
    from PIL import Image

    from napari_edgecme.core.motion import CameraMotion
    from napari_edgecme.core.synth import add_noise, quantize, render_blur

    folder = cache / f"{case}-{mp}mp"
    meta_path = folder / "meta.json"
    if meta_path.is_file():
        return json.loads(meta_path.read_text())
    folder.mkdir(parents=True, exist_ok=True)
    sharp640 = np.asarray(Image.open(DATA / case / "sharp.png").convert("RGB"))
    truth640 = CameraMotion.load(DATA / case / "truth.json")
    rows, cols = target_shape(sharp640.shape[:2], mp)
    extent = EXTENT_12MP * max(rows, cols) / max(target_shape(sharp640.shape[:2], 12))
    sharp = np.asarray(Image.fromarray(sharp640).resize((cols, rows), Image.LANCZOS))
    Image.fromarray(sharp).save(folder / "sharp.png")
    intr = truth640.intrinsics.rescaled((rows, cols))
    poses = truth640.poses.copy()  # time order, as recorded
    factor = 1.0
    for _ in range(5):  # displacements are nearly linear in the angles
        current = CameraMotion.from_trajectory(poses * factor, "rotation", intr).blur_extent()
        factor *= extent / current
    truth, per_interval = _time_uniform(poses * factor, CameraMotion, "rotation", intr,
                                        RENDER_STEP_PX)
    truth.save(folder / "truth.json")
    drawn = truth
    if render_step != RENDER_STEP_PX:
        drawn, _ = _time_uniform(poses * factor, CameraMotion, "rotation", intr, render_step)
    _log(f"{case} {mp} MP ({cols}x{rows}): rendering {drawn.n_poses} poses "
         f"(extent {truth.blur_extent():.2f} px, angle factor {factor:.4f})")
    t0 = time.perf_counter()

    def progress(record):
        if record.step % 25 == 0 or record.step == record.total:
            _log(f"  pose {record.step}/{record.total}, {time.perf_counter() - t0:.0f} s")

    blurred = render_blur(sharp.astype(np.float32) / 255, drawn, callback=progress)
    render_s = time.perf_counter() - t0
    blurred = quantize(add_noise(blurred, NOISE, rng=_seed(f"{case}-{mp}")), 8)
    Image.fromarray(np.round(blurred * 255).astype(np.uint8)).save(folder / "blurred.png")
    meta = {"case": case, "mp": mp, "shape": [rows, cols], "target_extent": extent,
            "true_extent": truth.blur_extent(), "angle_factor": factor,
            "poses_640": truth640.n_poses, "poses_per_interval": per_interval,
            "poses": truth.n_poses, "render_step_px": render_step,
            "render_poses": drawn.n_poses, "focal_px": intr.focal_px, "render_s": render_s,
            "noise": NOISE, "sharp": str(folder / "sharp.png"),
            "blurred": str(folder / "blurred.png"), "truth": str(folder / "truth.json")}
    meta_path.write_text(json.dumps(meta, indent=1))
    _log(f"  rendered in {render_s:.0f} s")
    return meta


def run_cli(argv: list[str], pythonpath: str | None, log_path: Path) -> dict:
    """``edgecme ARGV`` in a fresh process: exit status, wall seconds, peak RSS, output."""
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", _CHILD, *argv], capture_output=True,
                         text=True, env=env)
    wall = time.perf_counter() - t0
    log_path.write_text(f"$ edgecme {' '.join(argv)}\n--- stdout\n{out.stdout}\n"
                        f"--- stderr\n{out.stderr}\n")
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith(_MARKER)]
    child = json.loads(lines[-1][len(_MARKER):]) if lines else {"rc": out.returncode}
    messages = [ln.strip() for ln in re.split(r"[\r\n]", out.stderr) if ln.strip()]
    return {**child, "returncode": out.returncode, "wall_s": wall,
            "summary": messages[-1] if messages else ""}


def oracle(meta: dict, pythonpath: str | None) -> dict:
    """The blurred photo deconvolved with the true motion by the command line (cached)."""
    import hashlib

    from napari_edgecme.core import deconv, deconv_blocks, deconv_solvers
    from napari_edgecme.core.motion import CameraMotion

    folder = Path(meta["blurred"]).parent
    path, info_path = folder / "oracle.png", folder / "oracle.json"
    # the cache holds for the deconvolution code it was made with (its defaults included)
    code = hashlib.sha256(b"".join(Path(m.__file__).read_bytes()
                                   for m in (deconv, deconv_blocks, deconv_solvers))).hexdigest()
    if info_path.is_file() and path.is_file():
        cached = json.loads(info_path.read_text())
        if cached.get("deconvolution_code") == code:
            return cached

    # The truth recentred on its centroid pose: exactly the same blur (every pose times
    # one homography, claim 2), so the oracle is the sharp image moved by that pose, as
    # the estimate's restoration is, and the alignment takes it back. The recorded path
    # starts at the identity and wanders up to ~55 px away at 12 MP: deconvolving with it
    # as it is makes every PSF box twice as large (113 px instead of about 60) and the
    # deconvolution several times slower, for the same result.
    truth = CameraMotion.load(meta["truth"]).recentred()
    motion_path = folder / "truth-recentred.json"
    truth.save(motion_path)
    _log(f"{meta['case']} {meta['mp']} MP: oracle deconvolution")
    load = os.getloadavg()[0]
    res = run_cli(["deconvolve", meta["blurred"], "--motion", str(motion_path), "-o", str(path)],
                  pythonpath, folder / "oracle.log")
    res["load_average"] = [load, os.getloadavg()[0]]
    res["motion"] = "truth recentred on its centroid pose"
    res["deconvolution_code"] = code
    if res["rc"] != 0:
        raise RuntimeError(f"oracle deconvolution failed: {res['summary']}")
    res["path"] = str(path)
    info_path.write_text(json.dumps(res, indent=1))
    return res


def _read(path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"), np.float32) / 255


def _central_crop(arrays, megapixels: float):
    rows, cols = arrays[0].shape[:2]
    s = min(1.0, math.sqrt(megapixels * 1e6 / (rows * cols)))
    h, w = round(rows * s), round(cols * s)
    r0, c0 = (rows - h) // 2, (cols - w) // 2
    return [a[r0:r0 + h, c0:c0 + w] for a in arrays], (h, w)


def aligned_psnr_fast(result, reference, search_mp: float = 1.0) -> tuple[float, float]:
    """``aligned_psnr(result, reference, rotation=True)`` with the angle searched on a copy.

    The in-plane rotation is searched (``metrics._best_rotation``, the search
    ``aligned_psnr`` runs) on luminance copies block-averaged by a whole factor to about
    ``search_mp`` megapixels -- an angle does not depend on the scale -- and the shift and
    PSNR are then taken at full resolution (``metrics._shift_pair``), as ``aligned_psnr``
    does. At 1 MP (factor 1) this is ``aligned_psnr`` itself; at 12 MP its own search
    would take minutes per image. Returns ``(PSNR, angle in degrees)``.
    """
    from skimage.transform import downscale_local_mean

    from napari_edgecme.core import metrics

    rows, cols = reference.shape[:2]
    factor = max(1, int(math.sqrt(rows * cols / (search_mp * 1e6))))

    def small(a):
        a = np.asarray(a, np.float64)
        a = a if a.ndim == 2 else a.mean(-1)
        return a if factor == 1 else downscale_local_mean(a, (factor, factor))

    angle = metrics._best_rotation(small(result), small(reference))
    return metrics.psnr(*metrics._shift_pair(result, reference, None, angle)), angle


def score(meta: dict, run: dict, oracle_path: str, motion_path: Path, restored_path: Path,
          crop_mp: float) -> dict:
    from PIL import Image

    from napari_edgecme.core.metrics import band_sigma_for_upscale, motion_psf_ncc
    from napari_edgecme.core.motion import CameraMotion

    truth = CameraMotion.load(meta["truth"])
    shape = tuple(meta["shape"])
    with Image.open(DATA / meta["case"] / "sharp.png") as source:
        upscale = max(shape) / max(source.size)
    row: dict = {"true_extent": truth.blur_extent(), "upscale": upscale,
                 "band_sigma": band_sigma_for_upscale(upscale)}
    found = re.search(r"blur extent ([0-9.]+) px", run["summary"])
    row["reported_extent"] = float(found.group(1)) if found else None
    if motion_path.is_file():
        est = CameraMotion.load(motion_path)
        row["motion_shape"] = list(est.image_shape)
        row["poses"] = est.n_poses
        row["est_extent_full"] = est.rescale(shape).blur_extent()
        row["ncc_3x3"] = motion_psf_ncc(est, truth, grid=(3, 3))
        row["ncc_4x4"] = motion_psf_ncc(est, truth)
        # what the photo can determine: both PSFs at the source photo's resolution
        row["ncc_band"] = motion_psf_ncc(est, truth, grid=(3, 3), band_sigma=row["band_sigma"])
    if not restored_path.is_file():
        return row
    t0 = time.perf_counter()
    sharp = _read(meta["sharp"])
    images = {"blurred": _read(meta["blurred"]), "restored": _read(restored_path)}
    if oracle_path is not None:
        images["oracle"] = _read(oracle_path)
    crop = None
    if sharp.shape[0] * sharp.shape[1] > crop_mp * 1e6 * 1.05:
        cropped, crop = _central_crop([sharp, *images.values()], crop_mp)
        sharp, images = cropped[0], dict(zip(images, cropped[1:], strict=True))
    for name, img in images.items():
        row[f"psnr_{name}"], row[f"angle_{name}"] = aligned_psnr_fast(img, sharp)
    row["psnr_crop"] = list(crop) if crop else None
    row["score_s"] = time.perf_counter() - t0
    gain = row.get("psnr_oracle", np.nan) - row["psnr_blurred"]
    row["share"] = (row["psnr_restored"] - row["psnr_blurred"]) / gain if gain > 0 else None
    return row


def run_case(case: str, mp: int, args, workdir: Path) -> dict:
    meta = prepare(case, mp, args.cache, args.render_step)
    orc = {} if args.no_oracle else oracle(meta, args.pythonpath)
    stem = workdir / f"{case}-{mp}mp"
    restored, motion = Path(f"{stem}-restored.png"), Path(f"{stem}-motion.json")
    run_path = Path(f"{stem}-run.json")
    if args.score_only and run_path.is_file():  # the run was made before: score it again
        run = json.loads(run_path.read_text())
    else:
        for p in (restored, motion, run_path):
            p.unlink(missing_ok=True)
        argv = ["deblur", meta["blurred"], "-o", str(restored), "--save-motion", str(motion)]
        _log(f"{case} {mp} MP: edgecme {' '.join(argv)}")
        load = os.getloadavg()[0]
        run = run_cli(argv, args.pythonpath, Path(f"{stem}-deblur.log"))
        run["load_average"] = [load, os.getloadavg()[0]]
        run_path.write_text(json.dumps(run, indent=1))
    _log(f"  rc {run['rc']}, {run['wall_s']:.1f} s, peak {run.get('peak_rss_mib') or 0:.0f} MiB:"
         f" {run['summary']}")
    row = {"case": case, "mp": mp, "shape": meta["shape"], "render_s": meta["render_s"],
           "render_poses": meta.get("render_poses", meta["poses"]),
           "render_step_px": meta.get("render_step_px", RENDER_STEP_PX),
           "truth_poses": meta["poses"],
           "run": run,
           "oracle_run": {k: orc.get(k) for k in ("wall_s", "cpu_s", "peak_rss_mib", "motion")}}
    row.update(score(meta, run, orc.get("path"), motion, restored, args.psnr_crop_mp))
    scores = {k: v for k, v in row.items() if k.startswith(("ncc", "psnr", "share"))}
    _log(f"  scored: {json.dumps(scores)}")
    return row


def _f(value, spec):
    return "—" if value is None else format(value, spec)


def report(rows: list[dict], machine: str, snapshot: str | None) -> str:
    from napari_edgecme._report import markdown_table

    header = ["case", "size (MP, WxH)", "true extent px", "reported extent px (full res)",
              "wall s (CPU s)", "peak MiB", "PSF NCC 3x3 (4x4)",
              "PSF NCC at the source's resolution (sigma px)", "PSNR blurred / restored / oracle",
              "share of oracle gain"]
    table = []
    for r in rows:
        rows_, cols = r["shape"]
        run = r["run"]
        failed = "" if run["rc"] == 0 else f" **exit {run['rc']}**"
        psnr = (f"{_f(r.get('psnr_blurred'), '.2f')} / {_f(r.get('psnr_restored'), '.2f')} / "
                f"{_f(r.get('psnr_oracle'), '.2f')}")
        if r.get("psnr_crop"):
            psnr += f" (central {r['psnr_crop'][1]}x{r['psnr_crop'][0]})"
        table.append([
            r["case"], f"{rows_ * cols / 1e6:.1f} ({cols}x{rows_})", _f(r["true_extent"], ".1f"),
            f"{_f(r.get('reported_extent'), '.1f')} ({_f(r.get('est_extent_full'), '.1f')})",
            f"{run['wall_s']:.0f} ({_f(run.get('cpu_s'), '.0f')}){failed}",
            _f(run.get("peak_rss_mib"), ".0f"),
            f"{_f(r.get('ncc_3x3'), '.3f')} ({_f(r.get('ncc_4x4'), '.3f')})",
            f"{_f(r.get('ncc_band'), '.3f')} ({_f(r.get('band_sigma'), '.1f')})", psnr,
            _f(r.get("share"), ".2f")])
    lines = [
        "# Full-resolution yardstick (issue 14): `edgecme deblur IMG -o OUT` at 1, 12, 24 MP",
        "", machine + ("" if not snapshot else f"; engine: frozen snapshot `{snapshot}`"), "",
        "Written by `benchmarks/bench_fullres.py` (its docstring says how the cases are made "
        "and scored). Each row is one fresh process running `edgecme deblur IMG -o OUT.png "
        "--save-motion M.json` with no other option. *Reported extent*: the blur extent "
        "the command's summary line prints, and in brackets that of the saved motion "
        "rescaled to the photo. *PSF NCC*: centroid-aligned, at full resolution against the "
        "rendered truth; *at the source's resolution*: both PSFs low-passed by the "
        "Gaussian whose transfer is 1/2 at the Nyquist limit of the upscaled 640 px photo "
        "(`band_sigma_for_upscale`), the detail the photo carries and so the most any "
        "estimator can determine. *PSNR*: aligned (shift and in-plane rotation, the angle "
        "searched on a ~1 MP copy, shift and PSNR at full resolution) against the upscaled "
        "sharp image; the oracle is `edgecme deconvolve` with the true motion; "
        "share = (restored - blurred) / (oracle - blurred).", "",
        f"Targets (12 MP): PSF NCC >= {TARGETS['ncc']}, share >= {TARGETS['share']}, "
        f"<= {TARGETS['wall_s_12']:.0f} s, <= {TARGETS['mem_gib'][12]:g} GiB; 24 MP: "
        f"<= {TARGETS['mem_gib'][24]:g} GiB.", "",
        markdown_table(header, table, "llrrrrrrrr"), ""]
    lines += ["Per run (rendering is cached and not part of the run):", ""]
    for r in rows:
        o = r.get("oracle_run") or {}
        lines.append(
            f"- `{r['case']}` {r['mp']} MP: rendered {r['render_poses']} poses "
            f"(<= {r.get('render_step_px', RENDER_STEP_PX):g} px apart; truth "
            f"{r.get('truth_poses', r['render_poses'])} poses) in {r['render_s']:.0f} s; "
            f"oracle deconvolution ({o.get('motion') or 'truth as recorded'}) "
            f"{_f(o.get('wall_s'), '.0f')} s ({_f(o.get('cpu_s'), '.0f')} s CPU), "
            f"{_f(o.get('peak_rss_mib'), '.0f')} MiB; estimate {r.get('poses', '—')} poses on "
            f"{'x'.join(map(str, r.get('motion_shape', [])[::-1])) or '—'}; alignment angles "
            f"(deg) blurred {_f(r.get('angle_blurred'), '.2f')}, restored "
            f"{_f(r.get('angle_restored'), '.2f')}, oracle {_f(r.get('angle_oracle'), '.2f')}; "
            f"scoring {_f(r.get('score_s'), '.0f')} s; load average during the run "
            f"{r['run']['load_average'][0]:.1f} -> {r['run']['load_average'][1]:.1f}; summary: "
            f"`{r['run']['summary']}`")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="12,1,24",
                        help="megapixels, comma-separated, run in this order (default 12,1,24)")
    parser.add_argument("--cases", default=",".join(CASES),
                        help=f"lai cases, comma-separated (default {','.join(CASES)})")
    parser.add_argument("--pythonpath", help="PYTHONPATH of the command (a frozen src snapshot)")
    parser.add_argument("--out", type=Path, help="write the markdown table here too")
    parser.add_argument("--no-oracle", action="store_true",
                        help="skip the oracle deconvolution (no oracle PSNR, no share)")
    parser.add_argument("--score-only", action="store_true",
                        help="do not run deblur again where WORKDIR holds its run: score it "
                             "(e.g. once the oracle exists)")
    parser.add_argument("--merge", action="store_true",
                        help="keep the other rows of OUT's .json (an earlier run's sizes)")
    parser.add_argument("--cache", type=Path, default=CACHE)
    parser.add_argument("--workdir", type=Path, default=None,
                        help="outputs of the runs (default: CACHE/runs)")
    parser.add_argument("--render-step", type=float, default=RENDER_STEP_PX,
                        help="largest corner movement (px) between rendered poses of a new "
                             f"case (default {RENDER_STEP_PX:g}; the truth is always at "
                             f"{RENDER_STEP_PX:g})")
    parser.add_argument("--psnr-crop-mp", type=float, default=30.0,
                        help="PSNR on a central crop of this many MP above it (default 30: none)")
    args = parser.parse_args(argv)
    if args.pythonpath:
        sys.path.insert(0, str(Path(args.pythonpath).resolve()))
        args.pythonpath = str(Path(args.pythonpath).resolve())
    from napari_edgecme._report import machine_info, machine_line

    machine = machine_info()
    workdir = args.workdir or args.cache / "runs"
    workdir.mkdir(parents=True, exist_ok=True)
    sizes = [int(s) for s in args.sizes.split(",") if s]
    cases = [c for c in args.cases.split(",") if c]
    rows = []
    json_path = args.out.with_suffix(".json") if args.out else None
    if args.merge and json_path is not None and json_path.is_file():  # keep earlier rows
        rows = [r for r in json.loads(json_path.read_text())
                if not (r["mp"] in sizes and r["case"] in cases)]
    for mp in sizes:
        for case in cases:
            rows.append(run_case(case, mp, args, workdir))
            rows.sort(key=lambda r: (r["mp"] != 12, r["mp"], r["case"]))
            machine["load_average_end"] = machine_info()["load_average"]
            text = report(rows, machine_line(machine), args.pythonpath)
            if args.out:  # after every row: a partial table is readable at once
                args.out.write_text(text)
                json_path.write_text(json.dumps(rows, indent=1))
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
