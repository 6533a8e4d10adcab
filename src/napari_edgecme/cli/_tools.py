"""The tool commands: profiles (detect edge profiles), psf (draw a motion), synth (shake
an image)."""

from __future__ import annotations

import time

import numpy as np

from ..core import io as _io
from ..core._validation import first_line
from ..core.camera import Intrinsics
from ..core.motion import CameraMotion
from ._console import EXIT_OK, CLIError, _Console
from ._files import (
    _check_output,
    _distinct,
    _existing_input,
    _writing,
    output_bits,
    read_input_image,
)
from ._options import _describe, _focal_px, _max_blur

#: Default blur extent of ``synth`` (pixels).
SYNTH_EXTENT = 15.0
#: Default noise of ``synth`` (standard deviation, fraction of the [0, 1] range).
SYNTH_NOISE = 0.01
#: Poses along a synthetic trajectory (as :func:`~napari_edgecme.core.synth.make_case`).
SYNTH_SAMPLES = 48


def _figure_formats() -> set[str]:
    """Suffixes matplotlib can save to, or raise CLIError when matplotlib is missing."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise CLIError("--plot needs matplotlib: pip install 'napari-edgecme[plot]'") from None
    return {"." + s for s in FigureCanvasAgg(Figure()).get_supported_filetypes()}


def cmd_profiles(args, console: _Console) -> int:
    from ..core._validation import as_rng
    from ..core.blur_size import resolve_max_blur
    from ..core.edges import extract_edge_profiles
    from ._deblur import gamma_note, gamma_setting, linear_input

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
    gamma_setting(args)  # a bad --gamma is a usage error before any work
    image, curve, reason = linear_input(args, read_input_image(path, console), path)
    max_blur = _max_blur(args.max_blur, image.shape, measure=True)
    t0 = time.perf_counter()
    rng = as_rng(args.seed)
    # measured as deblur's estimator does (its stream of the seed)
    max_blur, size = resolve_max_blur(image, max_blur, rng=rng)
    used = (f"max blur {max_blur:g} px" if size is None
            else f"max blur {max_blur:.0f} px (measured: {size.message})")
    profiles = extract_edge_profiles(image, max_blur, rng=rng)
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
    console.info(f"{len(profiles)} edge profiles ({used}, {seconds:.1f} s; "
                 f"{gamma_note(curve, reason)}); wrote {wrote}")
    if len(profiles):
        console.info(f"median confidence {np.median(profiles.confidence):.2f}; "
                     + profiles.coverage_summary())
    return EXIT_OK


def cmd_psf(args, console: _Console) -> int:
    from ..core.psf_view import save_psf_field_figure, square_grid

    motion_path = _existing_input(args.motion, "motion file")
    _check_output(args.output, "-o", image=True)
    _distinct([("MOTION", motion_path)], [("-o", args.output)])
    motion = CameraMotion.load(motion_path)
    grid = square_grid(motion.image_shape) if args.grid is None else args.grid
    rows, cols = motion.image_shape
    if not args.raw and args.output.suffix.lower() == ".png":
        try:
            with _writing(args.output) as (tmp,):
                figure = save_psf_field_figure(motion, tmp, grid=grid)
        except ImportError as err:
            console.warn(f"{first_line(err)}; writing the raw PSF field instead")
        else:
            width, height = figure.size
            n = figure.glyphs.enlargement
            drawn = f"drawn {n}x enlarged" if n > 1 else "drawn at its true size"
            console.info(f"PSF field of a {_describe(motion)} on a {grid[0]}x{grid[1]} grid, "
                         f"each PSF {drawn}, axes in image px ({width}x{height} px figure); "
                         f"wrote {args.output}")
            return EXIT_OK
    field = motion.psf_field(grid=grid)
    with _writing(args.output) as (tmp,):
        _io.write_image(tmp, field)
    console.info(f"PSF field of a {_describe(motion)} on a {grid[0]}x{grid[1]} grid "
                 f"({rows}x{cols} px; raw: each PSF at its point, scaled to peak 1); "
                 f"wrote {args.output}")
    return EXIT_OK


def cmd_synth(args, console: _Console) -> int:
    from ..core import synth

    path = _existing_input(args.image, "image")
    outputs = [("-o", _check_output(args.output, "-o", image=True)),
               ("--save-motion", _check_output(args.save_motion, "--save-motion"))]
    _distinct([("IMAGE", path)], outputs)
    image = read_input_image(path, console)
    from ..core._validation import as_float_image, as_rng

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
    console.info(f"shook {path} with a {args.model} shake of blur extent "
                 f"{truth.blur_extent():.1f} px (longest side of the PSFs; {truth.n_poses} "
                 f"poses, focal {intrinsics.focal_px:.0f} px from {source}, noise "
                 f"{args.noise:g}, seed {args.seed}) in {seconds:.1f} s; wrote "
                 f"{args.output}, {args.save_motion}")
    return EXIT_OK
