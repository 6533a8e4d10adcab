"""What the options mean for the engine: focal length, largest blur, solver parameters."""

from __future__ import annotations

from pathlib import Path

from ..core import deconv as _deconv
from ..core import estimate as _estimate
from ..core import io as _io
from ..core.camera import Intrinsics
from ..core.motion import CameraMotion
from ._console import CLIError


def _focal_px(args, path: Path, shape) -> tuple[float | None, str]:
    """Focal length in pixels and where it came from: --focal-px, EXIF, or the default."""
    if getattr(args, "focal_px", None) is not None:
        return args.focal_px, "--focal-px"
    f35 = _io.exif_focal_35mm(path)
    if f35 is not None:
        focal = Intrinsics.from_image_shape(shape, focal_35mm=f35).focal_px
        return focal, f"EXIF 35 mm-equivalent {f35:g} mm"
    return None, "default"


def _max_blur(value: float | None, shape, measure: bool = False) -> float | None:
    """``--max-blur`` or the default for the image size, checked against the image.

    With ``measure`` and no ``--max-blur``, None: it is measured from the photo (by the
    estimator in ``deblur``, ``estimate`` and ``batch``, by ``profiles`` itself:
    :func:`~napari_edgecme.core.blur_size.measure_blur_extent`), after the same checks
    of the image's size against the default it falls back to.
    """
    half = min(shape[:2]) / 2
    if value is None:
        value = _estimate.default_max_blur(shape)
        if half <= 1:  # no --max-blur (>= 1 px, < half the side) would do
            raise CLIError(f"image is {shape[0]}x{shape[1]} px: too small to look for a "
                           "blur in (at least 3x3 px; motion estimation needs 8x8)")
        if value >= half:
            raise CLIError(f"image is {shape[0]}x{shape[1]} px: too small for the default "
                           f"--max-blur of {value:g} px; pass a --max-blur below {half:g}")
        if measure:  # the estimator measures it (and falls back to that default)
            return None
    return value


def _describe(motion: CameraMotion) -> str:
    """What every command says of a motion (the blur extent: :meth:`CameraMotion.blur_extent`)."""
    return (f"{motion.model} motion, {motion.n_poses} poses, blur extent "
            f"{motion.blur_extent():.1f} px (longest side of the PSFs)")


def _estimation_params(args) -> dict:
    params = {"rng": args.seed}
    for name in ("lambda_w", "lambda_ip", "lambda_f", "n_iter", "max_side", "refine"):
        value = getattr(args, name, None)
        if value is not None:
            params[name] = value
    return params


#: The deconvolution's parameters that are options of the command line (``--NAME``).
DECONVOLUTION_OPTIONS = ("lam", "iterations", "nsr", "color", "chroma")


def deconvolution_params(args, method: str) -> dict:
    params = {}
    for name in DECONVOLUTION_OPTIONS:
        value = getattr(args, name, None)
        if value is not None:
            params[name] = value
    option = {name: f"--{name}" for name in params}
    allowed = _deconv.DEFAULTS[method]
    for name in params:
        if name not in allowed:
            raise CLIError(f"{option[name]} does not apply to the {method!r} deconvolution")
    # --lam is the data weight; the engine's keyword is lambda_f = 2 / lam ('lam' is
    # deprecated there), and deblur_many takes lambda_f too
    if "lam" in params:
        params["lambda_f"] = 2.0 / params.pop("lam")
    return params
