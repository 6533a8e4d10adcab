"""``edgecme demo``: the whole pipeline on a bundled photo, with a report.

A bundled scikit-image photo is shaken with a known, spatially varying camera motion
(:func:`~napari_edgecme.core.synth.make_case`: a random camera-rotation trajectory,
rendered exactly by dense warping, 1 % noise, 8-bit); the motion is estimated from
the blurred image alone with EpAlone and Xu+Ep; the blurred image is deconvolved with
each estimate and with the true motion (the oracle); and everything is written into
one folder: the images, the motion files, PSF-field and edge-profile figures, and a
Markdown report with the PSNR/NCC table and the timings (plus the same numbers as
JSON).

The folder may hold other files: the demo writes (and replaces) only the names in
:data:`DEMO_FILES`, all at the end, each to a temporary name renamed into place, so
an interrupted demo leaves nothing behind. Figures need matplotlib (the ``plot``
extra); without it the PSF fields and the comparison are plain image montages and
the profile plot is left out.
"""

from __future__ import annotations

import contextlib
import json
import math
import time
import traceback
import warnings
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from ._report import METHOD_NAMES, check_out_folder
from .core import io as _io
from .core._validation import first_line
from .core.deblur import restoring_params
from .core.deconv import iter_deconvolve
from .core.edges import EdgeProfiles, extract_edge_profiles
from .core.estimate import iter_estimate_motion
from .core.metrics import aligned_psnr, aligned_ssim, motion_psf_ncc
from .core.motion import CameraMotion
from .core.progress import drive
from .core.synth import make_case, sample_image

__all__ = ["DEFAULT_SIZE", "DEMO_FILES", "DemoResult", "run_demo"]

#: Longer side of the demo photo (px): large enough to look like a photo, small enough
#: that the demo takes well under two minutes on a 2-core machine.
DEFAULT_SIZE = 384
#: The bundled photo that is shaken.
PHOTO = "camera"
#: Pose model of the shake (3-D camera rotation: the PSF changes across the image).
MODEL = "rotation"
#: Blur extent as a fraction of the image side (17 px at the default size).
EXTENT_FRACTION = 0.045
#: The estimators are told ``max_blur`` = this factor times the true extent.
MAX_BLUR_FACTOR = 1.35
NOISE = 0.01
#: Estimation methods shown, with their display names.
METHODS = {key: METHOD_NAMES[key] for key in ("ep", "xu+ep")}
#: PSF sample grid of the figures.
PSF_GRID = (5, 5)

#: Every file name the demo may write (and nothing else).
DEMO_FILES = (
    "report.md", "report.json", "comparison.png",
    "sharp.png", "blurred.png", "restored-ep.png", "restored-xu-ep.png", "restored-oracle.png",
    "motion-true.json", "motion-ep.json", "motion-xu-ep.json",
    "psf-fields.png", "edge-profiles.json", "edge-profiles.png", "edge-profile-locations.png",
)


def _slug(method: str) -> str:
    return method.replace("+", "-")


@dataclass
class DemoResult:
    """What the demo did: the folder, the files written, the table rows and the time."""

    out: Path
    report: Path
    files: list[Path]
    rows: list[dict]
    seconds: float
    summary: dict = field(default_factory=dict)




def run_demo(out="edgecme-demo", *, size: int | None = None, seed: int = 0,
             n_iter: int | None = None, photo: str = PHOTO, model: str = MODEL,
             log=None, warn=None, run=None, debug: bool = False) -> DemoResult:
    """Run the demo and write its files into ``out``.

    Parameters
    ----------
    out : path-like
        Output folder; created if missing (its parent must exist).
    size : int, optional
        Longer side of the photo (default :data:`DEFAULT_SIZE`; the test suite uses 128).
    seed : int
        Seeds the shake, the noise and the edge-profile extraction.
    n_iter : int, optional
        Alternations per scale of the estimators (default: the engine's).
    photo, model : str
        The bundled photo and the pose model of the shake.
    log, warn : callable, optional
        Called with one line of narration / of warning (default: silent).
    run : callable, optional
        Drives an engine generator and returns its result (default
        :func:`~napari_edgecme.core.progress.drive`; the CLI passes its progress bar).
    debug : bool
        Print the traceback of an estimator that fails.

    Returns
    -------
    DemoResult
    """
    log = log or (lambda message: None)
    warn = warn or (lambda message: None)
    run = run or drive
    size = DEFAULT_SIZE if size is None else int(size)
    if size < 64:
        raise ValueError(f"demo size must be at least 64 px; got {size}")
    out = Path(out)
    check_out_folder(out, "demo")
    t_start = time.perf_counter()

    extent = float(max(5, round(EXTENT_FRACTION * size)))
    max_blur = float(math.ceil(MAX_BLUR_FACTOR * extent))
    # the trajectory is scaled to exactly this CameraMotion.blur_extent
    log(f"shaking the bundled '{photo}' photo ({size} px) with a {model} shake of blur "
        f"extent {extent:.1f} px (longest side of the PSFs; {NOISE:.0%} noise, seed {seed})")
    t0 = time.perf_counter()
    case = make_case(sample_image(photo, size), model, extent, NOISE, rng=seed, name=photo)
    t_case = time.perf_counter() - t0
    truth = case.motion
    psnr_blurred = aligned_psnr(case.blurred, case.sharp)

    t0 = time.perf_counter()
    profiles = extract_edge_profiles(case.blurred, max_blur, rng=seed)
    t_profiles = time.perf_counter() - t0
    if len(profiles):
        log(f"{len(profiles)} edge profiles found in {t_profiles:.1f} s")
    else:
        warn(f"no usable edge profiles: {profiles.reason}")

    rows = [{"key": "blurred", "name": "blurred input", "psnr": psnr_blurred,
             "ssim": aligned_ssim(case.blurred, case.sharp)}]
    estimates: dict[str, CameraMotion] = {}
    restored: dict[str, np.ndarray] = {}
    for method, name in METHODS.items():
        log(f"{name}: estimating the camera motion from the blurred image (max blur "
            f"{max_blur:g} px)")
        row = {"key": method, "name": name}
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                t0 = time.perf_counter()
                est = run(iter_estimate_motion(case.blurred, method, model, max_blur,
                                               profiles=profiles, n_iter=n_iter, rng=seed))
                row["estimate_s"] = time.perf_counter() - t0
                t0 = time.perf_counter()
                image = run(iter_deconvolve(case.blurred, est.motion, **restoring_params(
                    case.blurred, est.info.method, "hyperlaplacian",
                    profile_misfit=est.info.profile_misfit)))
                row["deconvolve_s"] = time.perf_counter() - t0
        except Exception as err:  # an estimator failing is a result of the demo
            if debug:
                traceback.print_exc()
            row["failed"] = f"{type(err).__name__}: {first_line(err)}"
            warn(f"{name} failed: {first_line(err)}")
            rows.append(row)
            continue
        notes = list(dict.fromkeys(first_line(w.message) for w in caught))
        for note in notes:
            warn(f"{name}: {note}")
        estimates[method] = est.motion
        restored[method] = image
        row.update(psnr=aligned_psnr(image, case.sharp), ssim=aligned_ssim(image, case.sharp),
                   ncc=motion_psf_ncc(est.motion, truth), poses=est.motion.n_poses,
                   extent=est.motion.blur_extent(), notes=notes,
                   message=est.info.message, method_run=est.info.method,
                   profile_misfit=est.info.profile_misfit)
        row["gain"] = row["psnr"] - psnr_blurred
        log(f"{name}: PSNR {row['psnr']:.2f} dB ({row['gain']:+.2f} dB), PSF NCC "
            f"{row['ncc']:.3f}; estimated in {row['estimate_s']:.1f} s, deconvolved in "
            f"{row['deconvolve_s']:.1f} s")
        rows.append(row)

    log("oracle: deconvolving with the true motion")
    t0 = time.perf_counter()
    restored["oracle"] = run(iter_deconvolve(case.blurred, truth))
    oracle = {"key": "oracle", "name": "oracle (true motion)",
              "deconvolve_s": time.perf_counter() - t0, "poses": truth.n_poses,
              "extent": truth.blur_extent()}
    oracle.update(psnr=aligned_psnr(restored["oracle"], case.sharp),
                  ssim=aligned_ssim(restored["oracle"], case.sharp))
    oracle["gain"] = oracle["psnr"] - psnr_blurred
    rows.append(oracle)

    log("drawing the figures")
    figures = _Figures(case, truth, estimates, restored, rows, profiles)
    config = {"photo": photo, "size": size, "shape": list(case.blurred.shape), "model": model,
              "extent_px": extent, "max_blur_px": max_blur, "noise": NOISE, "bits": 8,
              "seed": seed, "n_iter": n_iter, "focal_px": truth.intrinsics.focal_px,
              "profiles": len(profiles), "profiles_reason": profiles.reason,
              "profiles_s": t_profiles, "shake_s": t_case}
    files = _write_all(out, case, truth, estimates, restored, profiles, figures, rows,
                       config, t_start)
    seconds = time.perf_counter() - t_start
    return DemoResult(out, out / "report.md", files, rows, seconds, config)


# --------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------

def _gray_rgb(image: np.ndarray) -> np.ndarray:
    return np.repeat(np.clip(image, 0, 1)[..., None], 3, axis=-1).astype(np.float32)


def psf_overlay(background: np.ndarray, motion: CameraMotion, grid=PSF_GRID) -> np.ndarray:
    """The motion's PSF field (yellow) over a dimmed gray image, RGB float32 in [0, 1]."""
    field = np.sqrt(motion.rescale(background.shape).psf_field(grid=grid))  # faint paths show
    base = 0.35 * _gray_rgb(background)
    colour = np.array([1.0, 0.85, 0.2], np.float32)
    return (base * (1 - field[..., None]) + field[..., None] * colour).astype(np.float32)


def profile_locations(background: np.ndarray, profiles: EdgeProfiles,
                      min_side: int = 512) -> np.ndarray:
    """Each edge profile drawn as a segment along its normal over a dimmed image (RGB).

    The image is enlarged by an integer factor (nearest neighbour) until its longer
    side is at least ``min_side`` pixels, so that the segments are visible.
    """
    from skimage.draw import line

    zoom = max(1, math.ceil(min_side / max(background.shape)))
    rgb = 0.5 * _gray_rgb(np.kron(background, np.ones((zoom, zoom), background.dtype)))
    rows, cols = rgb.shape[:2]

    def pixel(r, c):  # image (row, col) -> enlarged pixel centre
        return round((r + 0.5) * zoom - 0.5), round((c + 0.5) * zoom - 0.5)

    half = float(np.max(np.abs(profiles.offsets))) if len(profiles) else 0.0
    for (r, c), (nr, nc), q in zip(profiles.centroids, profiles.normals, profiles.quality,
                                   strict=True):
        rr, cc = line(*pixel(r - half * nr, c - half * nc), *pixel(r + half * nr, c + half * nc))
        keep = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
        q = float(np.clip(q, 0, 1))
        rgb[rr[keep], cc[keep]] = (1.0 - 0.7 * q, 0.4 + 0.6 * q, 0.2)
        pr, pc = pixel(r, c)
        rgb[max(pr - 1, 0):pr + 2, max(pc - 1, 0):pc + 2] = (1, 1, 1)
    return rgb


def _montage(panels, gap: int = 4) -> np.ndarray:
    """Panels (H, W, 3) side by side with white gaps."""
    height = max(p.shape[0] for p in panels)
    parts = []
    for i, p in enumerate(panels):
        if i:
            parts.append(np.ones((height, gap, 3), np.float32))
        pad = np.ones((height, p.shape[1], 3), np.float32)
        pad[:p.shape[0]] = p
        parts.append(pad)
    return np.concatenate(parts, axis=1)


def _matplotlib():
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        return None
    return Figure, FigureCanvasAgg


class _Figures:
    """The demo's figures, drawn with matplotlib when it is installed, else as montages."""

    def __init__(self, case, truth, estimates, restored, rows, profiles):
        self.mpl = _matplotlib()
        names = {r["key"]: r for r in rows}
        blurred = case.blurred
        self.psf_panels = [("true motion", psf_overlay(blurred, truth))]
        for method, name in METHODS.items():
            if method in estimates:
                self.psf_panels.append((f"{name} (PSF NCC {names[method]['ncc']:.2f})",
                                        psf_overlay(blurred, estimates[method])))
            else:
                self.psf_panels.append((f"{name}: failed", 0.35 * _gray_rgb(blurred)))
        self.image_panels = [(f"blurred, {names['blurred']['psnr']:.2f} dB",
                              _gray_rgb(blurred))]
        for method, name in METHODS.items():
            if method in restored:
                self.image_panels.append((f"{name}, {names[method]['psnr']:.2f} dB",
                                          _gray_rgb(restored[method])))
        self.image_panels.append((f"oracle, {names['oracle']['psnr']:.2f} dB",
                                  _gray_rgb(restored["oracle"])))
        self.image_panels.append(("sharp", _gray_rgb(case.sharp)))
        self.locations = profile_locations(blurred, profiles)
        self.profiles = profiles

    def _panels_figure(self, panels, path) -> None:
        Figure, Canvas = self.mpl
        n = len(panels)
        h, w = panels[0][1].shape[:2]
        fig = Figure(figsize=(3.2 * n, 3.2 * h / w + 0.45), layout="constrained")
        Canvas(fig)
        for ax, (title, image) in zip(fig.subplots(1, n, squeeze=False)[0], panels,
                                      strict=True):
            ax.imshow(image, interpolation="nearest")
            ax.set_title(title, fontsize=10)
            ax.set_axis_off()
        fig.savefig(path, dpi=float(np.clip(w / 3.0, 80, 200)))  # about one pixel per pixel

    def write_comparison(self, path) -> None:
        if self.mpl:
            self._panels_figure(self.image_panels, path)
        else:
            _io.write_image(path, _montage([p for _, p in self.image_panels]))

    def write_psf_fields(self, path) -> None:
        if self.mpl:
            self._panels_figure(self.psf_panels, path)
        else:
            _io.write_image(path, _montage([p for _, p in self.psf_panels]))

    def write_profile_plot(self, path) -> bool:
        if not self.mpl:
            return False
        self.profiles.figure().savefig(path, dpi=100)
        return True


# --------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------

def _write_all(out: Path, case, truth, estimates, restored, profiles, figures, rows, config,
               t_start: float) -> list[Path]:
    """Write every file to a temporary name, then rename all; remove stale demo files."""
    writers = {
        "sharp.png": lambda p: _io.write_image(p, case.sharp),
        "blurred.png": lambda p: _io.write_image(p, case.blurred),
        "restored-oracle.png": lambda p: _io.write_image(p, restored["oracle"]),
        "motion-true.json": truth.save,
        "edge-profiles.json": profiles.save,
        "edge-profile-locations.png": lambda p: _io.write_image(p, figures.locations),
        "psf-fields.png": figures.write_psf_fields,
        "comparison.png": figures.write_comparison,
    }
    ran = {row["key"]: (row["method_run"], row["profile_misfit"])
           for row in rows if "method_run" in row}
    for method, motion in estimates.items():
        writers[f"restored-{_slug(method)}.png"] = (
            lambda p, m=method: _io.write_image(p, restored[m]))
        # named by the method that ran (Xu+Ep may have run as Xu)
        writers[f"motion-{_slug(method)}.json"] = partial(
            motion.save, estimated_by=ran[method][0], profile_misfit=ran[method][1])
    if figures.mpl:
        writers["edge-profiles.png"] = figures.write_profile_plot
    names = [*writers, "report.md", "report.json"]
    assert set(names) <= set(DEMO_FILES), set(names) - set(DEMO_FILES)
    out.mkdir(exist_ok=True)
    with contextlib.ExitStack() as stack:
        tmps = {name: stack.enter_context(_io.atomic_path(out / name)) for name in names}
        for name, write in writers.items():
            write(tmps[name])
        seconds = time.perf_counter() - t_start  # everything but renaming into place
        report = _report(rows, config, names, figures.mpl is not None, seconds, out)
        tmps["report.md"].write_text(report, encoding="utf-8")
        payload = {"config": config, "rows": rows, "files": names,
                   "machine": _machine(), "seconds": seconds}
        tmps["report.json"].write_text(json.dumps(payload, indent=1, default=float) + "\n",
                                       encoding="utf-8")
    for stale in set(DEMO_FILES) - set(names):  # from an earlier run; ours by name
        (out / stale).unlink(missing_ok=True)
    return [out / name for name in names]


def _machine() -> dict:
    from ._report import machine_info

    return machine_info()


def _report(rows, config, names, have_mpl: bool, seconds: float, out: Path) -> str:
    from ._report import fmt, markdown_table

    machine = _machine()
    table = []
    for r in rows:
        if "failed" in r:
            table.append([r["name"], "failed (see the notes)", "", "", "", "", "", ""])
            continue
        ncc = "1 (truth)" if r["key"] == "oracle" else fmt(r.get("ncc"), ".3f", "")
        table.append([r["name"], fmt(r.get("psnr"), ".2f", ""), fmt(r.get("gain"), "+.2f", ""),
                      fmt(r.get("ssim"), ".3f", ""), ncc, fmt(r.get("estimate_s"), ".1f", ""),
                      fmt(r.get("deconvolve_s"), ".1f", ""), fmt(r.get("poses"), "d", "")])
    rows_md = markdown_table(["result", "aligned PSNR (dB)", "gain (dB)", "SSIM", "PSF NCC",
                              "estimate (s)", "deconvolve (s)", "poses"], table,
                             align="lrrrrrrr")
    c = config
    lines = [
        "# edgecme demo",
        "",
        f"{machine['date']} on {machine['node']} ({machine['cpus']} CPUs, "
        f"{machine['platform']}"
        + (f", load average {machine['load_average']:.1f}"
           if machine.get("load_average") is not None else "")
        + f"), napari-edgecme {machine['version']}: {seconds:.0f} s for everything below.",
        "",
        f"The bundled scikit-image photo `{c['photo']}`, resized to {c['shape'][0]}x"
        f"{c['shape'][1]} px, was shaken with a random hand-shake trajectory of camera "
        f"{c['model']}s (model `{c['model']}`, blur extent {c['extent_px']:g} px -- the "
        f"longest side of the local PSFs, over the frame -- focal length "
        f"{c['focal_px']:.0f} px: the PSF changes across the image), rendered "
        f"exactly by dense warping, with {c['noise']:.0%} Gaussian noise and 8-bit "
        f"quantisation (seed {c['seed']}). The camera motion was then estimated from the "
        "blurred image alone -- the estimators were told only `max_blur` = "
        f"{c['max_blur_px']:g} px -- with **EpAlone** (edge profiles only, paper Eq. 19) and "
        "**Xu+Ep** (L0 latent image plus edge profiles, Eq. 22), and the blurred image was "
        "deconvolved with each estimate (hyper-Laplacian prior, Krishnan & Fergus). The "
        "**oracle** deconvolves with the true motion: what a perfect estimate would give "
        "with the same deconvolution.",
        "",
        "![blurred, restored and sharp images](comparison.png)",
        "",
        rows_md,
        "",
        "Aligned PSNR and SSIM are measured after a global sub-pixel alignment and a 5 % "
        "border crop (a blind estimate is defined up to a homography, paper claim 2). "
        "PSF NCC is the mean normalised cross-correlation of the estimated and true local "
        "PSFs on a 4x4 grid after centroid alignment (1 = the same shapes). Times are "
        "wall-clock seconds on this machine; edge profiles were detected once "
        f"({c['profiles']} profiles in {c['profiles_s']:.1f} s) and shared by both "
        "estimators.",
    ]
    notes = []
    for r in rows:
        if "failed" in r:
            notes.append(f"- **{r['name']} failed**: {r['failed']}")
        for note in r.get("notes", []):
            notes.append(f"- {r['name']}: {note}")
    if notes:
        lines += ["", "Notes:", "", *notes]
    lines += [
        "",
        "## PSF fields",
        "",
        "![true and estimated PSF fields](psf-fields.png)",
        "",
        f"Local PSFs on a {PSF_GRID[0]}x{PSF_GRID[1]} grid (each scaled to peak 1, square "
        "root for visibility) over the dimmed blurred image; left to right: the true "
        "motion, " + ", ".join(METHODS.values()) + ". An estimate is defined up to a "
        "global shift, so compare shapes, not positions.",
        "",
        "## Edge profiles",
        "",
    ]
    if c["profiles"]:
        lines += [f"{c['profiles']} edge profiles passed the validity tests (flat plateaus, "
                  "monotone transition, straight edge, no second edge, agreement with "
                  "neighbours). Each is drawn along its normal, coloured by quality (green "
                  "= high), with its centroid in white:", "",
                  "![edge-profile locations](edge-profile-locations.png)", ""]
    else:
        lines += [f"No usable edge profile was found ({c['profiles_reason']}).", ""]
    if "edge-profiles.png" in names:
        lines += ["The profiles (alpha mattes, paper Eq. 1) and their derivatives (Radon "
                  "slices of the local PSFs, Eq. 11):", "",
                  "![edge profiles](edge-profiles.png)", ""]
    elif not have_mpl:
        lines += ["(Install matplotlib, `pip install 'napari-edgecme[plot]'`, for the "
                  "profile plot and titled figures.)", ""]
    lines += ["## Files", ""]
    lines += [f"- `{name}`" for name in names]
    blurred = out / "blurred.png"
    lines += [
        "",
        "## The same with the command line",
        "",
        "```bash",
        f"edgecme deblur {blurred} -o restored.png --max-blur {c['max_blur_px']:g} "
        "--save-motion motion.json",
        "edgecme psf motion.json -o psf-field.png",
        f"edgecme deconvolve {blurred} --motion {out / 'motion-true.json'} "
        "-o oracle.png",
        "```",
        "",
    ]
    return "\n".join(lines)
