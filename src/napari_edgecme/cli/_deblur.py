"""The commands that estimate the camera motion and undo it: estimate, deblur, batch, deconvolve.

``--gamma {auto,linear,srgb,VALUE}``: the motion is estimated and the photo deconvolved in
linear light; the input is linearised through its transfer curve (``auto``: decided from
the file, :func:`~napari_edgecme.core.photometry.decide_gamma`) and the output re-encoded
through the same curve. The summary says what was chosen and why.
"""

from __future__ import annotations

import time
from pathlib import Path

from ..core import deconv as _deconv
from ..core import estimate as _estimate
from ..core import io as _io
from ..core.deblur import ep_prior_note, record_gamma, restoring_params
from ..core.motion import CameraMotion
from ..core.photometry import Gamma, decide_gamma, parse_gamma
from ._console import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, CLIError, _Console, _UsageError
from ._files import (
    _check_output,
    _distinct,
    _existing_input,
    _writing,
    output_bits,
    read_input_image,
)
from ._options import _describe, _estimation_params, _focal_px, _max_blur, deconvolution_params


def gamma_setting(args) -> Gamma | str:
    """``--gamma`` checked (``"auto"`` or a :class:`Gamma`); a bad value is a usage error."""
    try:
        value = getattr(args, "gamma", None)
        return parse_gamma("auto" if value is None else value)
    except ValueError as err:
        raise _UsageError(str(err).replace("gamma must", "--gamma must", 1)) from None


def linear_input(args, image, path: Path) -> tuple[object, Gamma, str]:
    """The image in linear light, its transfer curve and why (``--gamma``, from the file
    for ``auto``); a linear image comes back as read."""
    curve = gamma_setting(args)
    if curve == "auto":
        curve, reason = decide_gamma(path, image)
    else:
        reason = "given"
    return (image if curve.is_linear else curve.decode(image)), curve, reason


def gamma_note(curve: Gamma, reason: str) -> str:
    """``gamma: srgb (8-bit PNG)``, as the summaries print it."""
    return f"gamma: {curve.name} ({reason})"


def _estimate_motion(args, console: _Console, image, path: Path, curve=None, reason=""):
    """Estimate on ``image`` (already linear light when ``curve`` is given)."""
    if curve is None:
        image, curve, reason = linear_input(args, image, path)
    shape = image.shape[:2]
    max_blur = _max_blur(args.max_blur, shape, measure=True)
    focal_px, focal_source = _focal_px(args, path, shape)
    profiles = None
    if args.profiles is not None:
        from ..core.edges import EdgeProfiles

        profiles = EdgeProfiles.load(_existing_input(args.profiles, "profile file"))
        if profiles.image_shape is not None and tuple(profiles.image_shape) != tuple(shape):
            raise CLIError(f"{args.profiles} holds profiles of a {profiles.image_shape[0]}x"
                           f"{profiles.image_shape[1]} image; {path} is {shape[0]}x{shape[1]}")
    gen = _estimate.iter_estimate_motion(image, args.method, args.model, max_blur, focal_px,
                                         profiles, **_estimation_params(args))
    result = console.run(gen)
    record_gamma(result.info, curve, reason)
    return result, max_blur, focal_source


def estimate_summary(result, requested: str, max_blur: float, focal_source: str) -> str:
    info = result.info
    method = info.method if info.method == requested else (
        f"{requested} fell back to {info.method}")
    described = ("no blur found (identity motion; if the photo is blurred, try a larger "
                 "--max-blur or another --model)" if info.no_blur else _describe(result.motion))
    if info.blur_size:  # measured (no --max-blur)
        text = (f"{described} ({method}, max blur {info.max_blur:.0f} px (measured: "
                f"{info.blur_size})")
    else:
        text = f"{described} ({method}, max blur {info.max_blur:g} px"
    text += f", focal {info.focal_px:.0f} px from {focal_source}"
    if info.n_profiles:
        text += f", {info.n_profiles} edge profiles"
        profiles = getattr(result, "profiles", None)
        if profiles is not None and len(profiles):
            cov = profiles.coverage()
            text += (f" in {cov['orientation_bins']}/8 orientations"
                     + (f" and {cov['cells']}/9 image cells" if cov["cells"] is not None
                        else ""))
    if info.profile_model():  # which profile model EpAlone kept
        text += f", fitted as {info.profile_model()}"
    start = getattr(info, "start", "blob")
    if start == "edge profiles":
        text += ", kept the start from the profiles' estimate"
    elif start == "EpAlone":
        text += ", kept the profiles' own estimate (polished)"
    elif start == "wide":
        text += ", kept the start from a wide motion"
    text += f", {info.seconds:.1f} s)"
    if not info.converged:
        text += f"; {info.message}"
    if getattr(info, "gamma", None) is not None:
        text += f"; gamma: {info.gamma} ({info.gamma_reason})"
    return text


def cmd_estimate(args, console: _Console) -> int:
    path = _existing_input(args.image, "image")
    _check_output(args.output, "-o")
    _distinct([("IMAGE", path)], [("-o", args.output)])
    gamma_setting(args)
    image = read_input_image(path, console)
    result, max_blur, source = _estimate_motion(args, console, image, path)
    with _writing(args.output) as (tmp,):
        result.motion.save(tmp, estimated_by=result.info.method,
                           profile_misfit=result.info.profile_misfit)
    console.info(f"{estimate_summary(result, args.method, max_blur, source)}; "
                 f"wrote {args.output}")
    return EXIT_OK


def deblur_image(args, console: _Console, image, path: Path, params: dict):
    """Estimate the motion of ``image`` (read from ``path``) and deconvolve it, as ``deblur``.

    Both run in linear light (``args.gamma``, :func:`linear_input`), and ``restored`` is
    re-encoded as ``image`` was; ``estimate.info.gamma`` and ``.gamma_reason`` say how.
    Returns ``(restored, estimate, max_blur, focal source, deconvolution seconds)``; with no
    blur found, ``restored`` is ``image`` itself. ``edgecme batch`` runs this per photo.
    """
    work, curve, reason = linear_input(args, image, path)
    result, max_blur, source = _estimate_motion(args, console, work, path, curve, reason)
    t0 = time.perf_counter()
    if result.info.no_blur:  # nothing to undo: the photo comes back as it was
        restored = image
    else:
        params = restoring_params(work, result.info.method, args.deconvolution, params,
                                  profile_misfit=result.info.profile_misfit)
        restored = console.run(_deconv.iter_deconvolve(work, result.motion,
                                                       args.deconvolution, **params))
        if not curve.is_linear:
            restored = curve.encode(restored)
    return restored, result, max_blur, source, time.perf_counter() - t0


def cmd_deblur(args, console: _Console) -> int:
    path = _existing_input(args.image, "image")
    outputs = [("-o", _check_output(args.output, "-o", image=True))]
    if args.save_motion is not None:
        outputs.append(("--save-motion", _check_output(args.save_motion, "--save-motion")))
    _distinct([("IMAGE", path)], outputs)
    params = deconvolution_params(args, args.deconvolution)
    gamma_setting(args)
    image = read_input_image(path, console)
    restored, result, max_blur, source, seconds = deblur_image(args, console, image, path,
                                                                params)
    with _writing(*(p for _, p in outputs)) as tmps:
        _io.write_image(tmps[0], restored, bits=output_bits(image))
        if args.save_motion is not None:
            result.motion.save(tmps[1], estimated_by=result.info.method,
                               profile_misfit=result.info.profile_misfit)
    wrote = ", ".join(str(p) for _, p in outputs)
    colour = _deconv.color_description(image.shape, args.deconvolution, params)
    details = [args.deconvolution, colour, ep_prior_note(
        result.info.method, args.deconvolution, params, result.info.profile_misfit)]
    done = ("not deconvolved" if result.info.no_blur else
            f"deconvolved ({', '.join(d for d in details if d)}) in {seconds:.1f} s")
    console.info(f"{estimate_summary(result, args.method, max_blur, source)}; {done}; "
                 f"wrote {wrote}")
    return EXIT_OK


def cmd_batch(args, console: _Console) -> int:
    from .. import batch

    if args.scheduler is not None and args.workers is not None:
        raise _UsageError("--workers sizes the local cluster; it does not apply with "
                          "--scheduler")
    params = {name: getattr(args, name) for name in batch.ESTIMATION_PARAMS
              if getattr(args, name) is not None}
    gamma = gamma_setting(args)
    try:
        with console.stage() as callback:
            result = batch.deblur_many(
                args.inputs, args.output, args.method, args.model, args.max_blur,
                args.focal_px, deconvolution=args.deconvolution,
                deconv_params=deconvolution_params(args, args.deconvolution),
                gamma=gamma,
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
    params = deconvolution_params(args, args.method)
    gamma_setting(args)
    motion, estimated_by, misfit = CameraMotion.load_estimate(motion_path)
    image = read_input_image(path, console)
    work, curve, reason = linear_input(args, image, path)
    prior = ep_prior_note(estimated_by, args.method, params, misfit)
    if estimated_by is not None:  # restored as 'deblur' restores an estimate of its method
        params = restoring_params(work, estimated_by, args.method, params,
                                  profile_misfit=misfit)
    t0 = time.perf_counter()
    restored = console.run(_deconv.iter_deconvolve(work, motion, args.method, **params))
    if not curve.is_linear:
        restored = curve.encode(restored)
    seconds = time.perf_counter() - t0
    with _writing(args.output) as (tmp,):
        _io.write_image(tmp, restored, bits=output_bits(image))
    colour = _deconv.color_description(image.shape, args.method, params)
    by = (f", estimated by {estimated_by}{', ' + prior if prior else ''}"
          if estimated_by is not None else "")
    console.info(f"deconvolved {path} ({args.method}, {colour + ', ' if colour else ''}"
                 f"{_describe(motion)}{by}) in {seconds:.1f} s;"
                 f" {gamma_note(curve, reason)}; wrote {args.output}")
    return EXIT_OK
