"""Photometry of the input: luminance, transfer curves (gamma), the noise level.

The edge tests work on one channel on the [0, 1] scale, in the units the blur acted on:
:func:`to_luminance` validates and reduces an image, :func:`srgb_to_linear` undoes the
sRGB encoding of a photo (:func:`linear_to_srgb` redoes it), :func:`estimate_noise`
measures the white-noise level that every threshold of the tests is set against.

Blur adds light linearly, so estimation and deconvolution belong in linear light. A
:class:`Gamma` is the transfer curve a file was stored through (``linear``, ``srgb`` or a
power law); :func:`parse_gamma` reads the user's ``--gamma {auto,linear,srgb,VALUE}`` and
:func:`decide_gamma` answers ``auto`` from the file (bit depth, format, ICC profile, PNG
colour chunks, EXIF ColorSpace), with the reason it can print.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._validation import as_float_image

__all__ = ["GAMMA_CHOICES", "LUMA", "Gamma", "decide_gamma", "estimate_noise",
           "linear_to_power", "linear_to_srgb", "mix_channels", "parse_gamma", "power_to_linear",
           "srgb_to_linear", "to_luminance"]

#: The named values of ``gamma`` (besides a number > 0, a power-law exponent).
GAMMA_CHOICES = ("auto", "linear", "srgb")
#: sRGB's breakpoints (IEC 61966-2-1): encoded 0.04045 is linear 0.04045 / 12.92. The
#: linear-side breakpoint is derived from the encoded one (not the rounded 0.0031308) so
#: that the two branches of encode and decode meet exactly and round trips are exact.
_SRGB_KNEE = 0.04045
_SRGB_KNEE_LINEAR = _SRGB_KNEE / 12.92
#: Adobe RGB (1998)'s curve: a pure power law of exponent 563/256 = 2.19921875 ("2.2").
ADOBE_RGB_GAMMA = 563 / 256

#: Rec. 709 luminance weights of (R, G, B), as :func:`skimage.color.rgb2gray`.
LUMA = np.array([0.2125, 0.7154, 0.0721])


def mix_channels(image: np.ndarray, weights) -> np.ndarray:
    """Weighted sums of the three colour channels, in the image's dtype.

    Written out as elementwise arithmetic rather than ``image @ weights.T``: a matrix
    product goes to BLAS, whose CPU kernels round differently in the last bits, and the
    alternating estimators can amplify that into a different estimate. This is the same
    bits on every machine.

    Parameters
    ----------
    image : ndarray of shape (..., 3)
    weights : array_like of shape (3,) or (k, 3)

    Returns
    -------
    ndarray of shape (...) for weights of shape (3,), else (..., k)
    """
    w = np.asarray(weights).astype(image.dtype)
    if w.ndim == 1:
        return mix_channels(image, w[None])[..., 0]
    return (image[..., 0, None] * w[:, 0] + image[..., 1, None] * w[:, 1]
            + image[..., 2, None] * w[:, 2])


def to_luminance(image, name: str = "image", *, check_range: bool = True) -> np.ndarray:
    """Validate an image and return its luminance, (M, N) float32 (float64 kept).

    RGB input is weighted as :func:`skimage.color.rgb2gray` (Rec. 709). Floating-point
    images must be scaled to [0, 1] (the engine's input rule,
    :func:`~napari_edgecme.core._validation.as_float_image`): every threshold of the
    edge tests is on that scale. ``check_range=False`` accepts any finite range, for
    callers whose result is linear in the intensities (see ``as_float_image``).
    """
    img = as_float_image(image, name, allow_rgb=True, min_size=2, check_range=check_range)
    if img.ndim == 3:
        img = mix_channels(img, LUMA)
    return img


def srgb_to_linear(image) -> np.ndarray:
    """Undo the sRGB transfer curve (IEC 61966-2-1): encoded values -> linear light.

    Blur adds light linearly, so the edge-profile model (Eqs. 1-6) holds for linear
    intensities; an 8-bit photo stores them through the sRGB curve, which bends every
    profile (the dark half of a transition is stretched, the bright half squeezed) and
    moves its centroid. On gamma-encoded synthetic shakes of the bundled photos, the
    median NCC between extracted profile derivatives and the true PSF projections rose
    from 0.81 to 0.97 when the input was linearised first. Linearise once and give the
    same linear image to :func:`extract_edge_profiles` and to the estimator's data terms.

    Parameters
    ----------
    image : array_like of shape (M, N) or (M, N, 3)
        sRGB-encoded values (integers scaled by their dtype, floats in [0, 1]).

    Returns
    -------
    ndarray, same shape, float32 (float64 kept)
    """
    img = as_float_image(image, allow_rgb=True)
    low = img <= _SRGB_KNEE
    out = np.where(low, img / 12.92, ((np.maximum(img, _SRGB_KNEE) + 0.055) / 1.055) ** 2.4)
    return out.astype(img.dtype)


def linear_to_srgb(image) -> np.ndarray:
    """Apply the sRGB transfer curve: linear light -> encoded values; the inverse of
    :func:`srgb_to_linear` (``linear_to_srgb(srgb_to_linear(x)) == x`` to float precision
    on [0, 1]).

    Negative values (the ringing of a deconvolution) are clipped to 0 first, values above
    1 to 1: the result is an image on [0, 1].

    Parameters
    ----------
    image : array_like of shape (M, N) or (M, N, 3)
        Linear intensities (floats on [0, 1]; integers scaled by their dtype).

    Returns
    -------
    ndarray, same shape, float32 (float64 kept)
    """
    img = np.clip(as_float_image(image, allow_rgb=True, check_range=False), 0, 1)
    low = img <= _SRGB_KNEE_LINEAR
    out = np.where(low, img * 12.92,
                   1.055 * np.maximum(img, _SRGB_KNEE_LINEAR) ** (1 / 2.4) - 0.055)
    return out.astype(img.dtype)


def power_to_linear(image, exponent: float) -> np.ndarray:
    """Undo a power-law encoding: ``linear = encoded ** exponent`` (negatives -> 0).

    ``exponent`` is the display gamma (2.2 for a "gamma 2.2" file); the inverse is
    :func:`linear_to_power`.
    """
    img = as_float_image(image, allow_rgb=True)
    return (np.maximum(img, 0) ** float(exponent)).astype(img.dtype)


def linear_to_power(image, exponent: float) -> np.ndarray:
    """Power-law encoding ``encoded = linear ** (1 / exponent)``, the inverse of
    :func:`power_to_linear`; clipped to [0, 1] first, as :func:`linear_to_srgb`."""
    img = np.clip(as_float_image(image, allow_rgb=True, check_range=False), 0, 1)
    return (img ** (1.0 / float(exponent))).astype(img.dtype)


@dataclass(frozen=True)
class Gamma:
    """A transfer curve: how a file's values encode linear light.

    ``kind`` is ``"linear"`` (values are linear light), ``"srgb"`` (IEC 61966-2-1) or
    ``"power"`` (``linear = encoded ** exponent``). Build one with :func:`parse_gamma`
    (or :meth:`linear`, :meth:`srgb`, :meth:`power`).
    """

    kind: str
    exponent: float = 1.0

    def __post_init__(self):
        if self.kind not in ("linear", "srgb", "power"):
            raise ValueError(f"unknown transfer curve {self.kind!r}")

    @classmethod
    def linear(cls) -> Gamma:
        return cls("linear")

    @classmethod
    def srgb(cls) -> Gamma:
        return cls("srgb")

    @classmethod
    def power(cls, exponent: float) -> Gamma:
        """A power law (exponent 1 is :meth:`linear`)."""
        exponent = float(exponent)
        return cls("linear") if exponent == 1.0 else cls("power", exponent)

    @property
    def is_linear(self) -> bool:
        return self.kind == "linear"

    @property
    def name(self) -> str:
        """``"linear"``, ``"srgb"`` or the exponent (``"2.2"``), as ``--gamma`` takes it."""
        return f"{self.exponent:.4g}" if self.kind == "power" else self.kind

    def __str__(self) -> str:
        return self.name

    def decode(self, image) -> np.ndarray:
        """Stored values -> linear light, float (float32 unless float64 came in)."""
        if self.kind == "srgb":
            return srgb_to_linear(image)
        if self.kind == "power":
            return power_to_linear(image, self.exponent)
        return as_float_image(image, allow_rgb=True)

    def encode(self, image) -> np.ndarray:
        """Linear light -> stored values on [0, 1] (negatives clipped first)."""
        if self.kind == "srgb":
            return linear_to_srgb(image)
        if self.kind == "power":
            return linear_to_power(image, self.exponent)
        return np.clip(as_float_image(image, allow_rgb=True, check_range=False), 0, 1)


def parse_gamma(value) -> Gamma | str:
    """Read a ``gamma`` setting: ``"auto"`` (returned as is), ``"linear"``, ``"srgb"``, a
    number > 0 (a power-law exponent, also as a string: ``"2.2"``) or a :class:`Gamma`.

    Raises
    ------
    ValueError
        One line naming the bad value.
    """
    if isinstance(value, Gamma):
        return value
    if isinstance(value, str):
        text = value.strip().lower()
        if text == "auto":
            return "auto"
        if text == "linear":
            return Gamma.linear()
        if text in ("srgb", "s-rgb"):
            return Gamma.srgb()
        try:
            number = float(text)
        except ValueError:
            number = None
    elif isinstance(value, numbers.Real) and not isinstance(value, bool):
        number = float(value)
    else:
        number = None
    if number is None or not np.isfinite(number) or number <= 0:
        raise ValueError(f"gamma must be auto, linear, srgb or a number > 0 (a power-law "
                         f"exponent such as 2.2); got {value!r}")
    return Gamma.power(number)


_EXIF_IFD = 0x8769
_INTEROP_IFD = 0xA005
_COLOR_SPACE = 0xA001  # EXIF ColorSpace: 1 = sRGB, 0xFFFF = uncalibrated
_INTEROP_INDEX = 0x0001  # "R98" = sRGB (DCF), "R03" = Adobe RGB (DCF option file)
_FORMATS = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG", ".tif": "TIFF", ".tiff": "TIFF",
            ".bmp": "BMP", ".mat": ".mat", ".npy": ".npy"}


def _bit_depth(image) -> str:
    dtype = np.asarray(image).dtype if image is not None else None
    if dtype is None:
        return "unknown-depth"
    if dtype == np.bool_:
        return "1-bit"
    if np.issubdtype(dtype, np.floating):
        return "float"
    if np.issubdtype(dtype, np.integer):
        return f"{8 * dtype.itemsize}-bit"
    return str(dtype)


def _file_tags(path: Path) -> dict:
    """The colour tags PIL reads cheaply: ICC description, PNG sRGB/gAMA, EXIF ColorSpace."""
    tags: dict = {}
    try:
        from PIL import Image

        with Image.open(path) as im:
            info = dict(im.info)
            icc = info.get("icc_profile")
            if icc:
                tags["icc"] = _icc_description(icc)
            if "srgb" in info:
                tags["png_srgb"] = True
            if info.get("gamma"):
                tags["png_gamma"] = float(info["gamma"])
            exif = im.getexif()
            sub = exif.get_ifd(_EXIF_IFD)
            space = sub.get(_COLOR_SPACE, exif.get(_COLOR_SPACE))
            if space is not None:
                tags["color_space"] = int(space)
                interop = exif.get_ifd(_INTEROP_IFD).get(_INTEROP_INDEX)
                if interop:
                    tags["interop"] = str(interop).strip("\x00 ")
            if exif.get(0x010F) or exif.get(0x0110):  # Make, Model
                tags["camera"] = " ".join(str(exif.get(t, "")).strip("\x00 ")
                                          for t in (0x010F, 0x0110)).strip()
    except Exception:  # no tags (or not an image PIL reads): decide from the bit depth
        return tags
    return tags


def _icc_description(icc: bytes) -> str:
    try:
        import io

        from PIL import ImageCms

        return ImageCms.getProfileDescription(ImageCms.ImageCmsProfile(io.BytesIO(icc))
                                              ).strip()
    except Exception:  # no littleCMS, or a profile it does not parse: look at the bytes
        text = icc.decode("latin-1")
        for name in ("sRGB", "Adobe RGB", "Display P3", "ProPhoto", "Linear"):
            if name.lower() in text.lower():
                return name
        return "unrecognised"


def _from_icc(desc: str) -> tuple[Gamma, str] | None:
    low = desc.lower()
    if "linear" in low or "gamma 1.0" in low:
        return Gamma.linear(), f"linear ICC profile '{desc}'"
    if "srgb" in low or "iec61966" in low.replace(" ", "").replace("-", ""):
        return Gamma.srgb(), f"sRGB ICC profile '{desc}'"
    if "p3" in low:
        return Gamma.srgb(), f"ICC profile '{desc}' uses the sRGB curve; primaries not converted"
    if "adobe rgb" in low or "adobergb" in low:
        return (Gamma.power(ADOBE_RGB_GAMMA),
                f"Adobe RGB ICC profile '{desc}': a power law of about 2.2; primaries not "
                "converted")
    if "prophoto" in low or "romm" in low:
        return Gamma.power(1.8), f"ProPhoto ICC profile '{desc}': a power law of 1.8"
    return None


def decide_gamma(path=None, image=None) -> tuple[Gamma, str]:
    """What ``gamma="auto"`` means for a file (or an array): the curve and why.

    Rules, in order:

    1. No file (an array given to the API), a ``.mat`` or ``.npy`` file: linear.
    2. A colour tag that says: an ICC profile (sRGB, Display P3 -> srgb; Adobe RGB -> a
       power law of 563/256, about 2.2; ProPhoto -> 1.8; a "linear" profile -> linear;
       the primaries are not converted), a PNG ``sRGB`` chunk (srgb) or ``gAMA`` chunk
       (1.0 -> linear, 1/2.2 -> power 2.2), EXIF ColorSpace = 1 (srgb; 0xFFFF with the
       interoperability index R03 is Adobe RGB).
    3. Otherwise where it comes from: an 8-bit file whose EXIF names a camera (Make or
       Model) -> srgb; an untagged 8-bit file with no camera in it -> linear, as are
       16-bit and floating-point files. Untagged 8-bit images are often not what a
       camera recorded: synthetic renders and benchmark sets (``lai`` blurs its encoded
       values), web copies stripped of their EXIF, photos that were processed after the
       blur. On the paper's real photos (web JPEGs without EXIF) deconvolving in linear
       light rang where the encoded values did not (``car_forest``, with one and the
       same motion), so only a file that says where it comes from is linearised; say
       ``gamma="srgb"`` for the others.

    Parameters
    ----------
    path : path-like or None
        The file the image was read from.
    image : ndarray, optional
        The image as read (its dtype is the bit depth).

    Returns
    -------
    gamma : Gamma
    reason : str
        A short phrase for the summary, e.g. ``"8-bit PNG"``, ``"sRGB ICC profile 'sRGB
        IEC61966-2.1'"``, ``"an array, not a file"``.
    """
    depth = _bit_depth(image)
    if path is None:
        return Gamma.linear(), "an array, not a file"
    path = Path(path)
    fmt = _FORMATS.get(path.suffix.lower(), path.suffix.lstrip(".").upper() or "file")
    if fmt in (".mat", ".npy"):
        return Gamma.linear(), f"{depth} data from a {fmt} file"
    tags = _file_tags(path)
    if tags.get("icc"):
        found = _from_icc(tags["icc"])
        if found is not None:
            return found
    if tags.get("png_srgb"):
        return Gamma.srgb(), f"{depth} {fmt} with an sRGB chunk"
    if tags.get("png_gamma"):
        exponent = 1.0 / tags["png_gamma"]
        if abs(exponent - 1.0) < 0.02:
            return Gamma.linear(), f"{depth} {fmt} with gAMA 1.0"
        if abs(exponent - 2.2) < 0.02:  # what an sRGB writer puts in gAMA: 45455
            return Gamma.srgb(), f"{depth} {fmt} with gAMA 1/2.2"
        return Gamma.power(exponent), f"{depth} {fmt} with gAMA 1/{exponent:.3g}"
    space = tags.get("color_space")
    camera = f" from a camera ({tags['camera']})" if tags.get("camera") else ""
    if space == 1:
        return Gamma.srgb(), f"{depth} {fmt}{camera}, EXIF ColorSpace sRGB"
    if space == 0xFFFF and tags.get("interop", "").upper() == "R03":
        return (Gamma.power(ADOBE_RGB_GAMMA),
                f"{depth} {fmt}{camera}, EXIF Adobe RGB: a power law of about 2.2; "
                "primaries not converted")
    if depth == "8-bit" and camera:
        return Gamma.srgb(), f"{depth} {fmt}{camera}"
    if depth == "8-bit":
        return Gamma.linear(), f"{depth} {fmt} with no colour tag and no camera"
    note = f", ICC profile '{tags['icc']}' not recognised" if tags.get("icc") else ""
    return Gamma.linear(), f"{depth} {fmt}{camera}{note}"


def estimate_noise(image) -> float:
    """Standard deviation of white noise in ``image`` (robust, fast).

    Immerkaer's Laplacian-difference mask, with the median absolute response in place
    of the mean so that edges and texture do not inflate the estimate.

    Parameters
    ----------
    image : ndarray of shape (M, N) or (M, N, 3)

    Returns
    -------
    float
        Noise sigma on the image's [0, 1] scale (includes quantisation noise).
    """
    img = to_luminance(image)
    if min(img.shape) < 3:
        return 0.0
    a = img.astype(np.float32, copy=False)
    # [1 -2 1; -2 4 -2; 1 -2 1] = outer([1 -2 1], [1 -2 1]) computed separably
    d = a[:, :-2] - 2 * a[:, 1:-1] + a[:, 2:]
    r = d[:-2] - 2 * d[1:-1] + d[2:]
    return float(np.median(np.abs(r)) / (6.0 * 0.6745))


#: Side of the central crop :func:`channel_noise_correlation` reads (px).
NOISE_CORRELATION_CROP = 1024


def channel_noise_correlation(image) -> float:
    """How correlated the noise of an RGB image's channels is, in [0, 1].

    Independent per-channel noise (a raw sensor, a synthetic render) gives about 0; a
    camera JPEG, whose chroma is smoothed and subsampled, about 1: its noise is mostly
    in the luminance. The mean of the three pairwise correlations of Immerkaer's
    Laplacian-difference responses (:func:`estimate_noise`'s) over the pixels where
    no channel responds more than three times the 75th percentile of the largest
    response (edges and texture left out: there the responses are the scene's).

    Parameters
    ----------
    image : ndarray of shape (M, N, 3)
        Floating point in [0, 1].

    Returns
    -------
    float
        0 for an image too small or too flat to tell (no evidence of correlation).
        Without measurable noise (flat regions exactly flat) the whole image's
        responses are used: 1 for a gray image stored as RGB.
    """
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] != 3 or min(a.shape[:2]) < 3:
        return 0.0
    # a central crop of at most NOISE_CORRELATION_CROP px a side is plenty of samples
    crop = [slice(max(0, (n - NOISE_CORRELATION_CROP) // 2),
                  max(0, (n - NOISE_CORRELATION_CROP) // 2) + NOISE_CORRELATION_CROP)
            for n in a.shape[:2]]
    a = a[crop[0], crop[1]].astype(np.float32)
    d = a[:, :-2] - 2 * a[:, 1:-1] + a[:, 2:]
    r = (d[:-2] - 2 * d[1:-1] + d[2:]).reshape(-1, 3)
    # noise-dominated pixels: no channel's response beyond a few times a typical one
    # (a rule symmetric in the channels: selecting on their sum would bias the sign)
    largest = np.abs(r).max(axis=1)
    flat = r[largest <= 3.0 * np.percentile(largest, 75)].astype(np.float64)
    power = (flat**2).sum(axis=0)
    if flat.shape[0] < 16 or np.any(power <= 0):
        # no noise to measure (a noise-free render): the responses of the scene itself,
        # so that a gray image stored as RGB still reads as shared (1)
        flat = r.astype(np.float64)
        power = (flat**2).sum(axis=0)
        if np.any(power <= 0):
            return 0.0
    pairs = [(0, 1), (0, 2), (1, 2)]
    rho = np.mean([(flat[:, i] * flat[:, j]).sum() / np.sqrt(power[i] * power[j])
                   for i, j in pairs])
    return float(np.clip(rho, 0.0, 1.0))
