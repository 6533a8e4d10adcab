"""The ``edgecme`` argument parser: one sub-parser per command, errors as one line."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from .. import __version__
from ..core import deconv as _deconv
from ..core import estimate as _estimate
from ..core.camera import MODELS
from ._console import PROG, _UsageError
from ._deblur import cmd_batch, cmd_deblur, cmd_deconvolve, cmd_estimate
from ._demo_bench import cmd_bench, cmd_demo
from ._tools import SYNTH_EXTENT, SYNTH_NOISE, cmd_profiles, cmd_psf, cmd_synth


def _grid(text: str) -> tuple[int, int]:
    parts = text.lower().split("x")
    try:
        rows, cols = (int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected ROWSxCOLS such as 5x5; got {text!r}") from None
    if not (1 <= rows <= 64 and 1 <= cols <= 64):
        raise argparse.ArgumentTypeError(f"rows and columns must be 1 to 64; got {text!r}")
    return rows, cols


def _number(kind=float, allow_zero: bool = False, maximum: float | None = None):
    """An argparse ``type`` for a finite positive number (or >= 0) with a clear message."""
    noun = "an integer" if kind is int else "a number"

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {noun}; got {text!r}") from None
        if not math.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
            raise argparse.ArgumentTypeError(
                f"must be {'>= 0' if allow_zero else '> 0'}; got {text}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"must be at most {maximum:g}; got {text}")
        return value

    return parse


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line and do not exit the interpreter."""

    def error(self, message):
        raise _UsageError(f"{message} (see '{self.prog} --help')")


class _Formatter(argparse.HelpFormatter):
    def __init__(self, prog):
        super().__init__(prog, max_help_position=30)
        # room for the subcommand names, which argparse indents beyond its own measure
        self._action_max_length = 16


def _add_common(parser) -> None:
    # repeated on every subcommand so that they work after it too; SUPPRESS keeps the
    # value given before the subcommand
    parser.add_argument("--quiet", "-q", action="store_true", default=argparse.SUPPRESS,
                        help="no progress bar and no summary (warnings and errors still show)")
    parser.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show the traceback of an error")


def _add_estimation(parser, profiles: bool = True) -> None:
    group = parser.add_argument_group("motion estimation")
    group.add_argument("--method", choices=_estimate.METHODS, default="xu+ep",
                       help="ep = EpAlone (edge profiles only, Eq. 16), xu = Xu et al. L0 "
                            "(the baseline), xu+ep = both (Eq. 22) (default: %(default)s)")
    group.add_argument("--model", choices=MODELS, default="rotation",
                       help="pose model: uniform blur, in-plane shake, or 3-D camera "
                            "rotation (default: %(default)s)")
    group.add_argument("--max-blur", type=_number(), metavar="PX",
                       help="largest blur extent to look for, in pixels (default: measured "
                            "from the photo's edge profiles, 2x the blur found; 4%% of the "
                            "longer side, at least 15, when too few edges are found)")
    group.add_argument("--focal-px", type=_number(), metavar="F",
                       help="focal length in pixels (default: from the EXIF 35 mm-equivalent "
                            "focal length, else a 35 mm-equivalent of 35 mm)")
    group.add_argument("--seed", type=_number(int, allow_zero=True), default=0, metavar="N",
                       help="seed of every random choice (default: %(default)s)")
    if profiles:
        group.add_argument("--profiles", type=Path, metavar="PROFILES.json",
                           help="use these edge profiles (from 'edgecme profiles') instead of "
                                "detecting them")
    d = _estimate.DEFAULTS  # defaults shown are the engine's own
    adv = parser.add_argument_group("advanced estimation parameters (paper Eqs. 19-22)")
    adv.add_argument("--n-iter", type=_number(int), metavar="N",
                     help=f"alternations per pyramid scale (default {d['n_iter']})")
    adv.add_argument("--lambda-w", type=_number(allow_zero=True), metavar="L",
                     help=f"L1 weight on the motion density (default {d['lambda_w']:g})")
    adv.add_argument("--lambda-ip", type=_number(allow_zero=True), metavar="L",
                     help=f"weight of the edge-profile term in xu+ep (default "
                          f"{d['lambda_ip']:g})")
    adv.add_argument("--lambda-f", type=_number(), metavar="L",
                     help=f"L0 weight of the latent-image update at the finest scale "
                          f"(default {d['lambda_f']:g})")
    adv.add_argument("--max-side", type=_number(int), metavar="PX",
                     help=f"estimate on a copy downscaled to this longer side (default "
                          f"{d['max_side']})")
    adv.add_argument("--no-refine", dest="refine", action="store_false", default=None,
                     help="on a photo larger than --max-side, keep the copy's motion as it is "
                          "instead of refining it at full resolution (xu, xu+ep)")


def _add_deconvolution(parser) -> None:
    d = _deconv.DEFAULTS
    group = parser.add_argument_group("deconvolution parameters")
    group.add_argument("--lam", type=_number(), metavar="L",
                       help=f"hyperlaplacian: data weight, 2 / lambda_f of the engine "
                            f"(default: from the photo's noise, "
                            f"{2 / _deconv.REFERENCE_LAMBDA_F:g} at "
                            f"{_deconv.REFERENCE_NOISE * 255:g}/255 and up to "
                            f"{2 / _deconv.lambda_f_for_noise(0.0):.0f} on a clean photo; "
                            "an EpAlone motion at most the first, divided by up to 8 as its "
                            "edge profiles disagree with it; higher for a sharper, noisier "
                            "result)")
    group.add_argument("--iterations", type=_number(int), metavar="N",
                       help=f"rl: Richardson-Lucy iterations (default {d['rl']['iterations']})")
    group.add_argument("--nsr", type=_number(), metavar="R",
                       help=f"wiener: noise-to-signal ratio (default {d['wiener']['nsr']:g})")
    group.add_argument("--color", choices=("opponent", "rgb"),
                       help="hyperlaplacian, RGB photos: opponent solves the luminance "
                            "(the channels' mean) and two chroma axes; rgb solves R, G and "
                            "B independently "
                            f"(default {d['hyperlaplacian']['color']})")
    group.add_argument("--chroma", choices=("auto", "full", "half"),
                       help="hyperlaplacian with --color opponent: the chroma at full or half "
                            f"resolution; auto: half from {_deconv.HALF_CHROMA_PIXELS / 1e6:g} MP "
                            f"up (default {d['hyperlaplacian']['chroma']})")


def _add_gamma(parser) -> None:
    # read by cli/_deblur.py and batch/ (args.gamma)
    parser.add_argument("--gamma", dest="gamma", type=str, default="auto",
                        metavar="{auto,linear,srgb,VALUE}",
                        help="transfer curve of the input: auto (decide from the file: 8-bit "
                             "JPEG/PNG -> srgb; 16-bit/float TIFF -> linear), linear, srgb, "
                             "or a power-law exponent such as 2.2; estimation and "
                             "deconvolution run in linear light and the output is re-encoded "
                             "as the input was")


def build_parser() -> argparse.ArgumentParser:
    """The ``edgecme`` argument parser (one sub-parser per subcommand)."""
    parser = _Parser(
        prog=PROG, formatter_class=_Formatter,
        description="Camera motion from edge profiles in one motion-blurred photo "
                    "(Vasu & Rajagopalan, CVPR 2017): estimate it, deblur with it.",
        epilog="Run 'edgecme demo' to see the whole pipeline on a bundled photo. Exit "
               "status: 0 success, 2 bad input or usage (nothing written), 1 internal "
               "error, 130 interrupted. The progress bar shows only when stderr is a "
               "terminal.")
    parser.add_argument("--version", action="version",
                        version=f"{PROG} {__version__} (napari-edgecme)")
    parser.add_argument("--quiet", "-q", action="store_true", default=False,
                        help="no progress bar and no summary (warnings and errors still show)")
    parser.add_argument("--debug", action="store_true", default=False,
                        help="show the traceback of an error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    def command(name, func, help_text, description=None):
        p = sub.add_parser(name, help=help_text, description=description or help_text,
                           formatter_class=_Formatter)
        p.set_defaults(func=func)
        _add_common(p)
        return p

    p = command("demo", cmd_demo,
                "shake a bundled photo, estimate the motion, deblur, write a report",
                "Shake a bundled scikit-image photo with a known spatially varying camera "
                "motion, estimate the motion with EpAlone and Xu+Ep, deconvolve, and write "
                "the images, PSF-field and edge-profile figures and a Markdown report with "
                "PSNR/NCC and timings. Only the demo's own file names are written.")
    p.add_argument("--out", type=Path, default=Path("edgecme-demo"), metavar="DIR",
                   help="output folder, created if missing (default: ./edgecme-demo)")
    p.add_argument("--seed", type=_number(int, allow_zero=True), default=0, metavar="N",
                   help="seed of the shake, the noise and the edge profiles (default 0)")
    p.add_argument("--size", type=_number(int), default=None, help=argparse.SUPPRESS)
    p.add_argument("--n-iter", type=_number(int), default=None, help=argparse.SUPPRESS)

    p = command("deblur", cmd_deblur, "estimate the camera motion and deconvolve",
                "Estimate the camera motion of a blurred photo, then deconvolve it at full "
                "resolution.")
    p.add_argument("image", type=Path, metavar="IMAGE", help="blurred photo")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                   help="restored image (.png, .tif keeps float32, .jpg, .bmp)")
    p.add_argument("--save-motion", type=Path, metavar="MOTION.json",
                   help="also write the estimated motion")
    p.add_argument("--deconvolution", choices=_deconv.METHODS, default="hyperlaplacian",
                   help="non-blind deconvolution method (default: %(default)s)")
    _add_gamma(p)
    _add_estimation(p)
    _add_deconvolution(p)

    p = command("batch", cmd_batch, "deblur many photos on a Dask cluster, with a report",
                "Deblur many photos as 'deblur' does, one task per photo on a local Dask "
                "cluster sized to this machine (or an existing one, --scheduler). Writes "
                "OUTDIR/NAME (the restored photo, in its own format), NAME.motion.json, "
                "thumbnails in OUTDIR/thumbs and report.csv / report.html, updated as "
                "results arrive. A rerun skips photos whose outputs exist (--force redoes "
                "them). Ctrl-C: no new photo starts and the running ones finish; Ctrl-C "
                "again cancels them. Exit status: 0 all photos restored (or no blur "
                "found), 1 some failed (the report says why), 2 bad arguments, 130 "
                "interrupted. Needs Dask (pip install \"napari-edgecme[batch]\") unless "
                "--workers 1.")
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="photo files, folders (their .png .tif .jpg .bmp files) and glob "
                        "patterns")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="OUTDIR",
                   help="output folder, created if missing")
    p.add_argument("-r", "--recursive", action="store_true",
                   help="also the photos in sub-folders (the outputs mirror them)")
    p.add_argument("--force", action="store_true",
                   help="redo photos whose outputs exist (default: skip them)")
    p.add_argument("--workers", type=_number(int), metavar="N",
                   help="worker processes of the local cluster (default: one per core, "
                        "within the memory); 1 runs the photos one at a time in this "
                        "process, without Dask")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="run on this existing Dask cluster instead of a local one")
    p.add_argument("--deconvolution", choices=_deconv.METHODS, default="hyperlaplacian",
                   help="non-blind deconvolution method (default: %(default)s)")
    _add_gamma(p)
    _add_estimation(p, profiles=False)
    _add_deconvolution(p)

    p = command("estimate", cmd_estimate, "estimate the camera motion only",
                "Estimate the camera motion of a blurred photo and write it as a motion "
                "file (JSON).")
    p.add_argument("image", type=Path, metavar="IMAGE", help="blurred photo")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="MOTION.json",
                   help="motion file to write")
    _add_gamma(p)
    _add_estimation(p)

    p = command("deconvolve", cmd_deconvolve, "deconvolve with a known camera motion",
                "Restore a blurred photo with a known camera motion (a motion file from "
                "'estimate', 'deblur --save-motion' or 'synth').")
    p.add_argument("image", type=Path, metavar="IMAGE", help="blurred photo")
    p.add_argument("--motion", type=Path, required=True, metavar="MOTION.json",
                   help="camera motion (applied at the image's size; one that names its "
                        "estimator, as 'estimate', 'deblur --save-motion' and 'batch' "
                        "write them, is restored as 'deblur' restores that method's "
                        "estimates)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                   help="restored image (.png, .tif keeps float32, .jpg, .bmp)")
    p.add_argument("--deconvolution", choices=_deconv.METHODS, default=None,
                   help="hyperlaplacian (Krishnan & Fergus), rl (Richardson-Lucy) or wiener "
                        "(default: hyperlaplacian), as in 'deblur'")
    p.add_argument("--method", dest="old_method", choices=_deconv.METHODS, default=None,
                   help="the old name of --deconvolution in this command (it means the "
                        "estimator in 'estimate' and 'deblur'); removed in the next release")
    _add_gamma(p)
    _add_deconvolution(p)

    p = command("profiles", cmd_profiles, "detect and save edge profiles",
                "Detect, validate and centroid-align the edge profiles of a blurred photo "
                "(paper sections 2 and 4) and save them as JSON.")
    p.add_argument("image", type=Path, metavar="IMAGE", help="blurred photo")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="PROFILES.json",
                   help="profile file to write")
    p.add_argument("--max-blur", type=_number(), metavar="PX",
                   help="largest blur extent, in pixels (default: measured from the photo's "
                        "edge profiles as in 'deblur', 2x the blur found; 4%% of the longer "
                        "side, at least 15, when too few edges are found)")
    p.add_argument("--plot", type=Path, metavar="PNG",
                   help="also plot the profiles and their derivatives (needs matplotlib)")
    p.add_argument("--seed", type=_number(int, allow_zero=True), default=0, metavar="N",
                   help="seed of the candidate subsampling on large images (default 0)")
    _add_gamma(p)  # profiles are measured in linear light, as 'deblur' measures them

    p = command("psf", cmd_psf, "draw the PSF field of a motion file",
                "Draw the local PSFs of a camera motion on a grid over its image. A .png "
                "output is a labelled figure: each PSF enlarged in its grid cell on a gray "
                "tile (the enlargement stated), axes in image pixels, a title with the "
                "model, poses and blur extent, and a scale bar. --raw (or another image "
                "format) writes the raw field instead: an image the size of the motion's "
                "image, each PSF at its point, scaled to peak 1.")
    p.add_argument("motion", type=Path, metavar="MOTION.json", help="motion file")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="FIELD.png",
                   help="image to write: .png a labelled figure (needs matplotlib, else the "
                        "raw field), other formats the raw field")
    p.add_argument("--grid", type=_grid, default=None, metavar="ROWSxCOLS",
                   help="PSF sample points (default: square cells, 5 on the image's short "
                        "side)")
    p.add_argument("--raw", action="store_true",
                   help="write the raw PSF field, the size of the motion's image, instead "
                        "of the figure")

    p = command("synth", cmd_synth, "shake a sharp image with a random camera motion",
                "Blur a sharp image with a random hand-shake trajectory (rendered exactly, "
                "by dense warping), add noise, and save the true motion.")
    p.add_argument("image", type=Path, metavar="IMAGE", help="sharp image")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="BLURRED",
                   help="blurred image to write")
    p.add_argument("--save-motion", type=Path, required=True, metavar="TRUTH.json",
                   help="the true motion")
    p.add_argument("--model", choices=MODELS, default="rotation",
                   help="pose model of the shake (default: %(default)s)")
    p.add_argument("--extent", type=_number(), default=SYNTH_EXTENT, metavar="PX",
                   help="blur extent in pixels: the longest side of the local PSFs' "
                        "support (bounding box), largest over the image (default: "
                        "%(default)g)")
    p.add_argument("--noise", type=_number(allow_zero=True, maximum=1), default=SYNTH_NOISE,
                   metavar="S", help="Gaussian noise sigma on the [0, 1] scale "
                                     "(default: %(default)g)")
    p.add_argument("--seed", type=_number(int, allow_zero=True), default=0, metavar="N",
                   help="seed of the trajectory and the noise (default: %(default)s)")
    p.add_argument("--focal-px", type=_number(), metavar="F",
                   help="focal length in pixels (default: from EXIF, else the default)")

    p = command("bench", cmd_bench, "run the quality and speed benchmarks",
                "Quality (PSNR, PSF NCC, time, peak memory of blurred / EpAlone / Xu / "
                "Xu+Ep / oracle over synthetic shakes) and speed (operator, estimation and "
                "deconvolution at 800x800, deconvolution of a 12 MP RGB photo) benchmarks, "
                "written as Markdown and JSON. Each run is a fresh Python process, so its "
                "peak memory is its own. --suite lai, levin, real: the suites on real "
                "camera shake, real captures and real photos.")
    p.add_argument("--suite", choices=("synthetic", "lai", "lai-srgb", "levin", "real"),
                   default="synthetic",
                   help="synthetic: the project's own shakes (quality and speed); lai: real "
                        "gyro shakes on natural photos, with the true motion; lai-srgb: the "
                        "same shakes rendered in linear light and sRGB-encoded, as a camera "
                        "does; levin: real captured uniform blurs; real: the paper's real "
                        "photos, side-by-side sheets (default: %(default)s)")
    p.add_argument("--data", type=Path, default=None, metavar="DIR",
                   help="the suite's data folder (default: ../shared/data/<suite>, "
                        "paper-real for real)")
    p.add_argument("--jobs", type=_number(int), default=1, metavar="N",
                   help="cases of a suite run at once, each estimate in its own process "
                        "(default: %(default)s)")
    p.add_argument("--quick", action="store_true",
                   help="fewer and smaller cases, no 12 MP case: a few minutes (lai: the 20 "
                        "cases of quick.txt; levin: the 8 anchor cases)")
    p.add_argument("--out", type=Path, default=Path("edgecme-bench"), metavar="DIR",
                   help="output folder, created if missing (default: ./edgecme-bench)")
    p.add_argument("--size", type=_number(int), default=None, help=argparse.SUPPRESS)
    p.add_argument("--cases", type=_number(int), default=None, help=argparse.SUPPRESS)
    p.add_argument("--speed-size", type=_number(int), default=None, help=argparse.SUPPRESS)
    p.add_argument("--repeat", type=_number(int), default=None, help=argparse.SUPPRESS)
    p.add_argument("--no-large", action="store_true", help=argparse.SUPPRESS)
    return parser
