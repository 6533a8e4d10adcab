"""The ``edgecme`` command line: blind deblurring from the shell.

::

    edgecme demo                                   # the whole pipeline on a bundled photo
    edgecme deblur photo.png -o sharp.png          # estimate the camera motion, deconvolve
    edgecme batch shoot/ -o restored/              # many photos on a local Dask cluster
    edgecme estimate photo.png -o motion.json      # only the motion
    edgecme deconvolve photo.png --motion motion.json -o sharp.png
    edgecme profiles photo.png -o profiles.json --plot profiles.png
    edgecme psf motion.json -o psf-field.png --grid 5x5
    edgecme synth sharp.png -o blurred.png --save-motion truth.json
    edgecme bench --quick

Conventions
-----------
* Images are read and written by extension (:mod:`napari_edgecme.core.io`): PNG 8/16 bit,
  TIFF (float32 kept), JPEG, BMP. The output depth follows the input (a 16-bit photo
  gives a 16-bit PNG). RGB is estimated on luminance and deconvolved per channel; the
  alpha channel of gray+alpha or RGBA input is dropped (with a warning unless it is
  opaque); stacks and volumes are refused.
* Outputs are written only when everything has been computed, each to a temporary
  name in the target folder and renamed into place: a failed or interrupted run leaves
  no output file, and never a half-written one.
* Progress: a one-line bar on stderr while a long step runs. It is drawn only when
  stderr is a terminal (so logs, pipes and CI output stay clean) and ``--quiet``
  silences it. Engine warnings appear as ``edgecme: warning: ...`` lines; a successful
  run ends with a one-line summary on stderr (not with ``--quiet``). Nothing is
  written to stdout except ``--help`` and ``--version``.
* Exit status: 0 success; 2 bad input or usage (one line ``edgecme: error: ...`` on
  stderr, nothing written); 1 an internal error, i.e. a bug (one line; ``--debug``
  shows the traceback); 130 interrupted (Ctrl-C). ``batch`` exits with 1 also when some
  photos failed (each is reported; the others are written).
* Randomness: ``--seed`` (default 0) seeds every random choice, so the same input,
  options and seed give identical output files.

The command never imports Qt or napari.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import shutil
import sys
import time
import traceback
import warnings
from pathlib import Path

import numpy as np

from . import __version__
from .core import deconv as _deconv
from .core import estimate as _estimate
from .core import io as _io
from .core._validation import first_line
from .core.camera import MODELS, Intrinsics
from .core.motion import CameraMotion
from .core.progress import Progress, drive

__all__ = ["CLIError", "ProgressBar", "build_parser", "main"]

PROG = "edgecme"

#: Exit statuses.
EXIT_OK, EXIT_INTERNAL, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130
#: Exit status of ``batch`` when some photos failed.
EXIT_FAILED = 1

#: Default blur extent of ``synth`` (pixels).
SYNTH_EXTENT = 15.0
#: Default noise of ``synth`` (standard deviation, fraction of the [0, 1] range).
SYNTH_NOISE = 0.01
#: Poses along a synthetic trajectory (as :func:`~napari_edgecme.core.synth.make_case`).
SYNTH_SAMPLES = 48


class CLIError(Exception):
    """A problem the user can fix (bad input, bad option, missing folder): exit status 2."""


class _UsageError(CLIError):
    """Raised by the argument parser instead of printing usage and exiting."""


# --------------------------------------------------------------------------------------
# progress and messages
# --------------------------------------------------------------------------------------

class ProgressBar:
    """A one-line text progress bar for the engine's :class:`Progress` records.

    Call it with each record (it is a valid ``callback`` for the engine's plain
    functions). The line is redrawn in place with a carriage return at most every
    ``min_interval`` seconds (and always at 100 %); a new ``stage`` ends the previous
    line and starts a new one, so a run leaves one finished line per stage::

        estimate   [############--------]  60%  0:07  scale 3/5, iteration 2/5

    Parameters
    ----------
    stream : text stream
        Where to draw (the CLI uses stderr, and only when it is a terminal).
    width : int, optional
        Line width (default: the terminal's width).
    min_interval : float
        Least time between redraws (seconds).
    clock : callable
        Monotonic time source (tests pass a fake one).
    """

    BAR = 20

    def __init__(self, stream, width: int | None = None, min_interval: float = 0.1,
                 clock=time.monotonic):
        self.stream = stream
        self.width = width
        self.min_interval = min_interval
        self.clock = clock
        self._record: Progress | None = None
        self._start = 0.0
        self._last_draw = -math.inf
        self._shown = 0  # characters of the line currently on screen

    def __call__(self, record: Progress) -> None:
        self.update(record)

    def update(self, record: Progress) -> None:
        now = self.clock()
        if self._record is not None and record.stage != self._record.stage:
            self.finish()
        if self._record is None:
            self._start = now
        self._record = record
        if now - self._last_draw >= self.min_interval or record.step >= record.total:
            self._draw(now)

    def line(self, record: Progress, elapsed: float) -> str:
        """The text of the bar for ``record`` after ``elapsed`` seconds."""
        filled = round(record.fraction * self.BAR)
        minutes, seconds = divmod(int(elapsed), 60)
        text = (f"{record.stage:<10} [{'#' * filled}{'-' * (self.BAR - filled)}] "
                f"{100 * record.fraction:3.0f}%  {minutes}:{seconds:02d}  {record.message}")
        width = self.width or shutil.get_terminal_size((80, 24)).columns
        return text[:max(width - 1, 10)]

    def _draw(self, now: float) -> None:
        text = self.line(self._record, now - self._start)
        self.stream.write("\r" + text + " " * max(0, self._shown - len(text)))
        self.stream.flush()
        self._shown = len(text)
        self._last_draw = now

    def clear(self) -> None:
        """Erase the line on screen (before another message is printed)."""
        if self._shown:
            self.stream.write("\r" + " " * self._shown + "\r")
            self.stream.flush()
            self._shown = 0
            self._last_draw = -math.inf

    def finish(self) -> None:
        """Draw the current stage's last state and end its line."""
        if self._record is not None:
            self._draw(self.clock())
            self.stream.write("\n")
            self.stream.flush()
        self._record = None
        self._shown = 0
        self._last_draw = -math.inf


class _Console:
    """Everything the CLI tells the user, on stderr: progress, warnings, summaries, errors."""

    def __init__(self, quiet: bool = False, stream=None):
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        isatty = getattr(self.stream, "isatty", None)
        self.bar = (ProgressBar(self.stream) if not quiet and isatty is not None and isatty()
                    else None)

    def _print(self, text: str) -> None:
        if self.bar is not None:
            self.bar.clear()
        print(text, file=self.stream, flush=True)

    def info(self, message: str) -> None:
        if not self.quiet:
            self._print(f"{PROG}: {message}")

    def warn(self, message: str) -> None:
        self._print(f"{PROG}: warning: {message}")

    def error(self, message: str) -> None:
        self._print(f"{PROG}: error: {message}")

    def progress(self, record: Progress) -> None:
        """Callback for the engine's progress records."""
        if self.bar is not None:
            self.bar.update(record)

    @contextlib.contextmanager
    def stage(self):
        """``with console.stage() as callback:`` a stage reporting through ``callback``.

        The bar ends its line when the stage ends, and is wiped if it raises.
        """
        try:
            yield self.progress
        except BaseException:
            if self.bar is not None:
                self.bar.clear()
            raise
        if self.bar is not None:
            self.bar.finish()

    def run(self, generator):
        """Drive an engine ``iter_*`` generator with the progress bar; return its result."""
        with self.stage() as callback:
            return drive(generator, callback)

    def showwarning(self, message, category, filename, lineno, file=None, line=None):
        """Replacement for :func:`warnings.showwarning`: one ``edgecme: warning:`` line."""
        text = str(message).strip().splitlines()[0] if str(message).strip() else ""
        if not issubclass(category, UserWarning):
            text = f"{category.__name__}: {text}"
        self.warn(text)


# --------------------------------------------------------------------------------------
# inputs and outputs
# --------------------------------------------------------------------------------------

def read_input_image(path, console: _Console | None = None) -> np.ndarray:
    """Read an image file as (H, W) or (H, W, 3); alpha is dropped, stacks refused."""
    path = Path(path)
    arr = _io.read_image(path)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    elif arr.ndim == 3 and arr.shape[2] in (2, 4):
        alpha = arr[..., -1]
        opaque = np.iinfo(alpha.dtype).max if np.issubdtype(alpha.dtype, np.integer) else 1
        if console is not None and np.any(alpha != opaque):
            console.warn(f"{path}: the alpha channel is ignored")
        arr = arr[..., 0] if arr.shape[2] == 2 else arr[..., :3]
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3)):
        raise CLIError(f"{path}: expected a gray or RGB image, shape (rows, cols) or "
                       f"(rows, cols, 3); got shape {arr.shape} (a stack or volume: "
                       "save its planes as separate images)")
    return arr


def output_bits(image: np.ndarray) -> int | None:
    """PNG depth for an output made from ``image``: 16 for 16-bit input, else the default."""
    return 16 if image.dtype in (np.uint16, np.int32, np.uint32, np.int64, np.uint64) else None


def _existing_input(path: Path, what: str) -> Path:
    if not path.exists():
        raise CLIError(f"{what} not found: {path}")
    if path.is_dir():
        raise CLIError(f"expected a file for the {what}, got a directory: {path}")
    return path


def _check_output(path: Path, option: str, image: bool = False) -> Path:
    """Fail early (before any work) if ``path`` cannot be written."""
    if path.is_dir():
        raise CLIError(f"{option} {path} is a directory; give a file name")
    folder = path.parent
    if not folder.is_dir():
        raise CLIError(f"output folder does not exist: {folder} (for {option} {path})")
    if not os.access(folder, os.W_OK):
        raise CLIError(f"output folder is not writable: {folder} (for {option} {path})")
    if image and path.suffix.lower() not in _io.IMAGE_SUFFIXES:
        suffix = repr(path.suffix) if path.suffix else "(no extension)"
        raise CLIError(f"cannot write {option} {path}: unsupported image format {suffix}; "
                       "use one of " + ", ".join(_io.IMAGE_SUFFIXES))
    return path


def _distinct(inputs, outputs) -> None:
    """Refuse outputs that overwrite an input or each other."""
    seen: dict[Path, str] = {}
    for option, path in inputs:
        seen[path.resolve()] = option
    for option, path in outputs:
        key = path.resolve()
        if key in seen:
            raise CLIError(f"{option} {path} would overwrite {seen[key]}; choose another name")
        seen[key] = option


@contextlib.contextmanager
def _writing(*paths):
    """Temporary paths for several outputs, all renamed into place when the block succeeds."""
    with contextlib.ExitStack() as stack:
        yield [stack.enter_context(_io.atomic_path(p)) for p in paths]


def _focal_px(args, path: Path, shape) -> tuple[float | None, str]:
    """Focal length in pixels and where it came from: --focal-px, EXIF, or the default."""
    if getattr(args, "focal_px", None) is not None:
        return args.focal_px, "--focal-px"
    f35 = _io.exif_focal_35mm(path)
    if f35 is not None:
        focal = Intrinsics.from_image_shape(shape, focal_35mm=f35).focal_px
        return focal, f"EXIF 35 mm-equivalent {f35:g} mm"
    return None, "default"


def _max_blur(value: float | None, shape) -> float:
    """``--max-blur`` or the default for the image size, checked against the image."""
    half = min(shape[:2]) / 2
    if value is None:
        value = _estimate.default_max_blur(shape)
        if half <= 1:  # no --max-blur (>= 1 px, < half the side) would do
            raise CLIError(f"image is {shape[0]}x{shape[1]} px: too small to look for a "
                           "blur in (at least 3x3 px; motion estimation needs 8x8)")
        if value >= half:
            raise CLIError(f"image is {shape[0]}x{shape[1]} px: too small for the default "
                           f"--max-blur of {value:g} px; pass a --max-blur below {half:g}")
    return value


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


def _describe(motion: CameraMotion) -> str:
    return (f"{motion.model} motion, {motion.n_poses} poses, blur extent "
            f"{motion.blur_extent():.1f} px")


# --------------------------------------------------------------------------------------
# subcommands
# --------------------------------------------------------------------------------------

def _estimation_params(args) -> dict:
    params = {"rng": args.seed}
    for name in ("lambda_w", "lambda_ip", "lambda_f", "n_iter", "max_side"):
        value = getattr(args, name, None)
        if value is not None:
            params[name] = value
    return params


def _deconv_params(args, method: str) -> dict:
    params = {}
    for name in ("lam", "iterations", "nsr"):
        value = getattr(args, name, None)
        if value is not None:
            params[name] = value
    option = {"lam": "--lam", "iterations": "--iterations", "nsr": "--nsr"}
    allowed = _deconv.DEFAULTS[method]
    for name in params:
        if name not in allowed:
            raise CLIError(f"{option[name]} does not apply to the {method!r} deconvolution")
    return params


def _estimate_motion(args, console: _Console, image, path: Path):
    shape = image.shape[:2]
    max_blur = _max_blur(args.max_blur, shape)
    focal_px, focal_source = _focal_px(args, path, shape)
    profiles = None
    if args.profiles is not None:
        from .core.edges import EdgeProfiles

        profiles = EdgeProfiles.load(_existing_input(args.profiles, "profile file"))
        if profiles.image_shape is not None and tuple(profiles.image_shape) != tuple(shape):
            raise CLIError(f"{args.profiles} holds profiles of a {profiles.image_shape[0]}x"
                           f"{profiles.image_shape[1]} image; {path} is {shape[0]}x{shape[1]}")
    gen = _estimate.iter_estimate_motion(image, args.method, args.model, max_blur, focal_px,
                                         profiles, **_estimation_params(args))
    result = console.run(gen)
    return result, max_blur, focal_source


def _estimate_summary(result, requested: str, max_blur: float, focal_source: str) -> str:
    info = result.info
    method = info.method if info.method == requested else (
        f"{requested} fell back to {info.method}")
    described = ("no blur found (identity motion; if the photo is blurred, try a larger "
                 "--max-blur or another --model)" if info.no_blur else _describe(result.motion))
    text = (f"{described} ({method}, max blur {max_blur:g} px, focal "
            f"{info.focal_px:.0f} px from {focal_source}")
    if info.n_profiles:
        text += f", {info.n_profiles} edge profiles"
        profiles = getattr(result, "profiles", None)
        if profiles is not None and len(profiles):
            cov = profiles.coverage()
            text += (f" in {cov['orientation_bins']}/8 orientations"
                     + (f" and {cov['cells']}/9 image cells" if cov["cells"] is not None
                        else ""))
    text += f", {info.seconds:.1f} s)"
    if not info.converged:
        text += f"; {info.message}"
    return text


def cmd_estimate(args, console: _Console) -> int:
    path = _existing_input(args.image, "image")
    _check_output(args.output, "-o")
    _distinct([("IMAGE", path)], [("-o", args.output)])
    image = read_input_image(path, console)
    result, max_blur, source = _estimate_motion(args, console, image, path)
    with _writing(args.output) as (tmp,):
        result.motion.save(tmp)
    console.info(f"{_estimate_summary(result, args.method, max_blur, source)}; "
                 f"wrote {args.output}")
    return EXIT_OK


def _deblur_image(args, console: _Console, image, path: Path, params: dict):
    """Estimate the motion of ``image`` (read from ``path``) and deconvolve it, as ``deblur``.

    Returns ``(restored, estimate, max_blur, focal source, deconvolution seconds)``; with no
    blur found, ``restored`` is ``image`` itself. ``edgecme batch`` runs this per photo.
    """
    result, max_blur, source = _estimate_motion(args, console, image, path)
    t0 = time.perf_counter()
    if result.info.no_blur:  # nothing to undo: the photo comes back as it was
        restored = image
    else:
        restored = console.run(_deconv.iter_deconvolve(image, result.motion,
                                                       args.deconvolution, **params))
    return restored, result, max_blur, source, time.perf_counter() - t0


def cmd_deblur(args, console: _Console) -> int:
    path = _existing_input(args.image, "image")
    outputs = [("-o", _check_output(args.output, "-o", image=True))]
    if args.save_motion is not None:
        outputs.append(("--save-motion", _check_output(args.save_motion, "--save-motion")))
    _distinct([("IMAGE", path)], outputs)
    params = _deconv_params(args, args.deconvolution)
    image = read_input_image(path, console)
    restored, result, max_blur, source, seconds = _deblur_image(args, console, image, path,
                                                                params)
    with _writing(*(p for _, p in outputs)) as tmps:
        _io.write_image(tmps[0], restored, bits=output_bits(image))
        if args.save_motion is not None:
            result.motion.save(tmps[1])
    wrote = ", ".join(str(p) for _, p in outputs)
    done = ("not deconvolved" if result.info.no_blur else
            f"deconvolved ({args.deconvolution}) in {seconds:.1f} s")
    console.info(f"{_estimate_summary(result, args.method, max_blur, source)}; {done}; "
                 f"wrote {wrote}")
    return EXIT_OK


def cmd_batch(args, console: _Console) -> int:
    from . import batch

    if args.scheduler is not None and args.workers is not None:
        raise _UsageError("--workers sizes the local cluster; it does not apply with "
                          "--scheduler")
    params = {name: getattr(args, name) for name in batch.ESTIMATION_PARAMS
              if getattr(args, name) is not None}
    try:
        with console.stage() as callback:
            result = batch.deblur_many(
                args.inputs, args.output, args.method, args.model, args.max_blur,
                args.focal_px, deconvolution=args.deconvolution,
                deconv_params=_deconv_params(args, args.deconvolution),
                recursive=args.recursive, force=args.force, scheduler=args.scheduler,
                workers=args.workers, callback=callback, log=console.info,
                warn=console.warn, rng=args.seed, **params)
    except ImportError as err:
        raise CLIError(str(err)) from None
    except KeyboardInterrupt:
        console.error(f"interrupted; the photos finished so far are written, see "
                      f"{args.output / 'report.html'}")
        return EXIT_INTERRUPTED
    counts = ", ".join(f"{n} {status}" for status, n in result.counts.items())
    console.info(f"{len(result.rows)} photos: {counts} in {result.seconds:.0f} s; wrote "
                 f"{result.report_html}")
    if result.failed:
        names = ", ".join(row["photo"] for row in result.failed[:5])
        more = f" and {len(result.failed) - 5} more" if len(result.failed) > 5 else ""
        console.warn(f"{len(result.failed)} of {len(result.rows)} photos failed: {names}{more} "
                     f"(reasons in {result.report_csv})")
        return EXIT_FAILED
    return EXIT_OK


def cmd_deconvolve(args, console: _Console) -> int:
    path = _existing_input(args.image, "image")
    motion_path = _existing_input(args.motion, "motion file")
    _check_output(args.output, "-o", image=True)
    _distinct([("IMAGE", path), ("--motion", motion_path)], [("-o", args.output)])
    if args.old_method is not None:
        if args.deconvolution not in (None, args.old_method):
            raise CLIError(f"--method {args.old_method} and --deconvolution "
                           f"{args.deconvolution} disagree; give only --deconvolution")
        console.warn("'deconvolve --method' is now '--deconvolution' (as in 'deblur'); "
                     "the old name goes in the next release")
        args.deconvolution = args.old_method
    args.method = args.deconvolution or "hyperlaplacian"
    params = _deconv_params(args, args.method)
    motion = CameraMotion.load(motion_path)
    image = read_input_image(path, console)
    t0 = time.perf_counter()
    restored = console.run(_deconv.iter_deconvolve(image, motion, args.method, **params))
    seconds = time.perf_counter() - t0
    with _writing(args.output) as (tmp,):
        _io.write_image(tmp, restored, bits=output_bits(image))
    console.info(f"deconvolved {path} ({args.method}, {_describe(motion)}) in {seconds:.1f} s;"
                 f" wrote {args.output}")
    return EXIT_OK


def _figure_formats() -> set[str]:
    """Suffixes matplotlib can save to, or raise CLIError when matplotlib is missing."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise CLIError("--plot needs matplotlib: pip install 'napari-edgecme[plot]'") from None
    return {"." + s for s in FigureCanvasAgg(Figure()).get_supported_filetypes()}


def cmd_profiles(args, console: _Console) -> int:
    from .core.edges import extract_edge_profiles

    path = _existing_input(args.image, "image")
    outputs = [("-o", _check_output(args.output, "-o"))]
    if args.plot is not None:
        _check_output(args.plot, "--plot")
        formats = _figure_formats()
        if args.plot.suffix.lower() not in formats:
            suffix = repr(args.plot.suffix) if args.plot.suffix else "(no extension)"
            raise CLIError(f"cannot write --plot {args.plot}: unsupported figure format "
                           f"{suffix}; use one of " + ", ".join(sorted(formats)))
        outputs.append(("--plot", args.plot))
    _distinct([("IMAGE", path)], outputs)
    image = read_input_image(path, console)
    max_blur = _max_blur(args.max_blur, image.shape)
    t0 = time.perf_counter()
    profiles = extract_edge_profiles(image, max_blur, rng=args.seed)
    seconds = time.perf_counter() - t0
    with _writing(args.output) as (tmp,):  # the profiles first: a plot must not cost them
        profiles.save(tmp)
    if args.plot is not None:
        try:
            with _writing(args.plot) as (tmp,):
                profiles.figure().savefig(tmp, dpi=100)
        except Exception as err:
            console.warn(f"could not draw --plot {args.plot}: {first_line(err)}; the profiles "
                         f"were written to {args.output}")
            outputs = outputs[:1]
    if len(profiles) == 0:
        console.warn(f"no usable edge profiles in {path}: {profiles.reason}")
    wrote = ", ".join(str(p) for _, p in outputs)
    console.info(f"{len(profiles)} edge profiles (max blur {max_blur:g} px, {seconds:.1f} s);"
                 f" wrote {wrote}")
    if len(profiles):
        console.info(f"median confidence {np.median(profiles.confidence):.2f}; "
                     + profiles.coverage_summary())
    return EXIT_OK


def cmd_psf(args, console: _Console) -> int:
    motion_path = _existing_input(args.motion, "motion file")
    _check_output(args.output, "-o", image=True)
    _distinct([("MOTION", motion_path)], [("-o", args.output)])
    motion = CameraMotion.load(motion_path)
    field = motion.psf_field(grid=args.grid)
    with _writing(args.output) as (tmp,):
        _io.write_image(tmp, field)
    rows, cols = motion.image_shape
    console.info(f"PSF field of a {_describe(motion)} on a {args.grid[0]}x{args.grid[1]} grid "
                 f"({rows}x{cols} px); wrote {args.output}")
    return EXIT_OK


def cmd_synth(args, console: _Console) -> int:
    from .core import synth

    path = _existing_input(args.image, "image")
    outputs = [("-o", _check_output(args.output, "-o", image=True)),
               ("--save-motion", _check_output(args.save_motion, "--save-motion"))]
    _distinct([("IMAGE", path)], outputs)
    image = read_input_image(path, console)
    from .core._validation import as_float_image, as_rng

    sharp = as_float_image(image, allow_rgb=True)
    if args.extent >= min(sharp.shape[:2]) / 2:
        raise CLIError(f"--extent {args.extent:g} is too large for a {sharp.shape[0]}x"
                       f"{sharp.shape[1]} image; use less than {min(sharp.shape[:2]) / 2:g}")
    focal_px, source = _focal_px(args, path, sharp.shape)
    intrinsics = Intrinsics.from_image_shape(sharp.shape, focal_px=focal_px)
    rng = as_rng(args.seed)
    t0 = time.perf_counter()
    path_poses = synth.random_trajectory(args.model, intrinsics, args.extent,
                                         n_samples=SYNTH_SAMPLES, rng=rng)
    truth = synth.densify_path(path_poses, args.model, intrinsics)
    with console.stage() as callback:
        blurred = synth.render_blur(sharp, truth, callback=callback)
    if args.noise > 0:
        blurred = synth.add_noise(blurred, args.noise, rng)
    blurred = np.clip(blurred, 0, 1)
    seconds = time.perf_counter() - t0
    with _writing(*(p for _, p in outputs)) as (tmp_image, tmp_motion):
        _io.write_image(tmp_image, blurred, bits=output_bits(image))
        truth.save(tmp_motion)
    console.info(f"shook {path} with a {args.extent:g} px {args.model} shake ({truth.n_poses} "
                 f"poses, focal {intrinsics.focal_px:.0f} px from {source}, noise "
                 f"{args.noise:g}, seed {args.seed}) in {seconds:.1f} s; wrote "
                 f"{args.output}, {args.save_motion}")
    return EXIT_OK


def cmd_demo(args, console: _Console) -> int:
    from . import _demo

    result = _demo.run_demo(args.out, size=args.size, seed=args.seed, n_iter=args.n_iter,
                            log=console.info, warn=console.warn, run=console.run,
                            debug=args.debug)
    console.info(f"wrote {len(result.files)} files to {result.out} in {result.seconds:.0f} s; "
                 f"read {result.report}")
    return EXIT_OK


def cmd_bench(args, console: _Console) -> int:
    from . import _bench

    if args.suite != "synthetic":
        from . import _suites

        written = _suites.run_suite(args.suite, args.out, data=args.data, quick=args.quick,
                                    jobs=args.jobs, cases=args.cases, log=console.info)
        console.info("wrote " + ", ".join(str(p) for p in written))
        return EXIT_OK
    if args.data is not None:
        raise _UsageError("--data applies to the lai, levin and real suites "
                          "(see 'edgecme bench --help')")
    written = _bench.run_bench(args.out, quick=args.quick, size=args.size, cases=args.cases,
                               speed_size=args.speed_size, repeat=args.repeat,
                               large=not args.no_large, log=console.info)
    console.info("wrote " + ", ".join(str(p) for p in written))
    return EXIT_OK


# --------------------------------------------------------------------------------------
# the parser
# --------------------------------------------------------------------------------------

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
                       help="ep = EpAlone (edge profiles only, Eq. 19), xu = Xu et al. L0 "
                            "(the baseline), xu+ep = both (Eq. 22) (default: %(default)s)")
    group.add_argument("--model", choices=MODELS, default="rotation",
                       help="pose model: uniform blur, in-plane shake, or 3-D camera "
                            "rotation (default: %(default)s)")
    group.add_argument("--max-blur", type=_number(), metavar="PX",
                       help="largest blur extent to look for, in pixels (default: 4%% of the "
                            "longer image side, at least 15)")
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


def _add_deconvolution(parser) -> None:
    d = _deconv.DEFAULTS
    group = parser.add_argument_group("deconvolution parameters")
    group.add_argument("--lam", type=_number(), metavar="L",
                       help=f"hyperlaplacian: data weight (default "
                            f"{d['hyperlaplacian']['lam']:g}; higher for cleaner photos, "
                            "lower for noisier ones)")
    group.add_argument("--iterations", type=_number(int), metavar="N",
                       help=f"rl: Richardson-Lucy iterations (default {d['rl']['iterations']})")
    group.add_argument("--nsr", type=_number(), metavar="R",
                       help=f"wiener: noise-to-signal ratio (default {d['wiener']['nsr']:g})")


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
    _add_estimation(p, profiles=False)
    _add_deconvolution(p)

    p = command("estimate", cmd_estimate, "estimate the camera motion only",
                "Estimate the camera motion of a blurred photo and write it as a motion "
                "file (JSON).")
    p.add_argument("image", type=Path, metavar="IMAGE", help="blurred photo")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="MOTION.json",
                   help="motion file to write")
    _add_estimation(p)

    p = command("deconvolve", cmd_deconvolve, "deconvolve with a known camera motion",
                "Restore a blurred photo with a known camera motion (a motion file from "
                "'estimate', 'deblur --save-motion' or 'synth').")
    p.add_argument("image", type=Path, metavar="IMAGE", help="blurred photo")
    p.add_argument("--motion", type=Path, required=True, metavar="MOTION.json",
                   help="camera motion (applied at the image's size)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                   help="restored image (.png, .tif keeps float32, .jpg, .bmp)")
    p.add_argument("--deconvolution", choices=_deconv.METHODS, default=None,
                   help="hyperlaplacian (Krishnan & Fergus), rl (Richardson-Lucy) or wiener "
                        "(default: hyperlaplacian), as in 'deblur'")
    p.add_argument("--method", dest="old_method", choices=_deconv.METHODS, default=None,
                   help="the old name of --deconvolution in this command (it means the "
                        "estimator in 'estimate' and 'deblur'); removed in the next release")
    _add_deconvolution(p)

    p = command("profiles", cmd_profiles, "detect and save edge profiles",
                "Detect, validate and centroid-align the edge profiles of a blurred photo "
                "(paper sections 2 and 4) and save them as JSON.")
    p.add_argument("image", type=Path, metavar="IMAGE", help="blurred photo")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="PROFILES.json",
                   help="profile file to write")
    p.add_argument("--max-blur", type=_number(), metavar="PX",
                   help="largest blur extent, in pixels (default: 4%% of the longer side, "
                        "at least 15)")
    p.add_argument("--plot", type=Path, metavar="PNG",
                   help="also plot the profiles and their derivatives (needs matplotlib)")
    p.add_argument("--seed", type=_number(int, allow_zero=True), default=0, metavar="N",
                   help="seed of the candidate subsampling on large images (default 0)")

    p = command("psf", cmd_psf, "draw the PSF field of a motion file",
                "Draw the local PSFs of a camera motion on a grid over its image, each "
                "scaled to peak 1.")
    p.add_argument("motion", type=Path, metavar="MOTION.json", help="motion file")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="FIELD.png",
                   help="image to write, the size of the motion's image")
    p.add_argument("--grid", type=_grid, default=(5, 5), metavar="ROWSxCOLS",
                   help="PSF sample points (default: 5x5)")

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
                   help="blur extent in pixels: the largest local PSF's bounding-box side "
                        "(default: %(default)g)")
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
    p.add_argument("--suite", choices=("synthetic", "lai", "levin", "real"),
                   default="synthetic",
                   help="synthetic: the project's own shakes (quality and speed); lai: real "
                        "gyro shakes on natural photos, with the true motion; levin: real "
                        "captured uniform blurs; real: the paper's real photos, side-by-side "
                        "sheets (default: %(default)s)")
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


# --------------------------------------------------------------------------------------
# main
# --------------------------------------------------------------------------------------



def _oserror(err: OSError) -> str:
    what = err.strerror or first_line(err)
    return f"{what}: {err.filename}" if err.filename else what


def main(argv=None) -> int:
    """Run ``edgecme`` with ``argv`` (default: ``sys.argv[1:]``); return the exit status."""
    parser = build_parser()
    console = _Console(quiet=False)
    try:
        args = parser.parse_args(argv)
    except _UsageError as err:
        console.error(str(err))
        return EXIT_USAGE
    except SystemExit as done:  # --help, --version
        return done.code if isinstance(done.code, int) else EXIT_OK
    if args.command is None:
        console.error("missing COMMAND (one of demo, deblur, batch, estimate, deconvolve, "
                      "profiles, psf, synth, bench); see 'edgecme --help'")
        return EXIT_USAGE
    console = _Console(quiet=args.quiet)
    try:
        with warnings.catch_warnings():
            # the engine's warnings (e.g. "too few edge profiles, falling back to xu") are
            # for the user: show each once, as one line; other categories keep the
            # interpreter's filters
            warnings.filterwarnings("default", category=UserWarning)
            warnings.showwarning = console.showwarning
            return args.func(args, console)
    except KeyboardInterrupt:
        console.error("interrupted; no output written")
        return EXIT_INTERRUPTED
    except (CLIError, ValueError) as err:
        if args.debug:
            traceback.print_exc()
        console.error(first_line(err))
        return EXIT_USAGE
    except MemoryError:
        if args.debug:
            traceback.print_exc()
        console.error("out of memory; try a smaller image, or --max-side for the estimation")
        return EXIT_USAGE
    except OSError as err:
        if args.debug:
            traceback.print_exc()
        console.error(_oserror(err))
        return EXIT_USAGE
    except Exception as err:
        if args.debug:
            traceback.print_exc()
        console.error(f"internal error: {type(err).__name__}: {first_line(err)} "
                      "(please report it; --debug shows the traceback)")
        return EXIT_INTERNAL
