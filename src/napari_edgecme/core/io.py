"""Reading and writing images, and the camera's focal length from EXIF.

Images are read by extension with imageio (PNG, JPEG, BMP, ...) or tifffile (TIFF) and
come back as arrays of their stored dtype; the engine's float policy
(:func:`~._validation.as_float_image`) scales integers to [0, 1]. Writing picks the
encoding from the extension: PNG as 8 or 16 bit (16 bit when the source was 16 bit or
``bits=16``), TIFF keeps float32. Every write goes to a temporary name in the target
folder and is renamed into place, so a failed or interrupted write leaves nothing
behind and never clobbers a file half-way.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from ._validation import first_line

__all__ = ["IMAGE_SUFFIXES", "atomic_path", "exif_focal_35mm", "read_image", "read_json",
           "write_image", "write_json"]

#: Extensions read and written.
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp")
_EXIF_IFD = 0x8769
_FOCAL_35MM = 0xA405  # FocalLengthIn35mmFilm




def read_image(path) -> np.ndarray:
    """Read an image file as an array of shape (H, W), (H, W, 3) or (H, W, 4).

    Raises
    ------
    ValueError
        One line naming the file and the problem (missing, not an image, truncated).
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"image file not found: {path}")
    if path.is_dir():
        raise ValueError(f"expected an image file, got a directory: {path}")
    suffix = path.suffix.lower()
    if path.stat().st_size == 0:
        raise ValueError(f"cannot read image {path}: the file is empty (0 bytes)")
    try:
        with warnings.catch_warnings():
            # imageio probes its legacy plugins (DICOM, ...) on unknown data and warns
            # about their deprecation: noise for a user who gave us a wrong file
            warnings.simplefilter("ignore", DeprecationWarning)
            if suffix in (".tif", ".tiff"):
                import tifffile

                arr = tifffile.imread(path)
            else:
                import imageio.v3 as iio

                arr = iio.imread(path)
    except Exception as err:  # any decoder failure is a bad file for the user
        why = first_line(err)
        if "Could not find a backend" in why:  # imageio's words for "no decoder knows it"
            why = "not an image file in a format that can be read (PNG, JPEG, TIFF, BMP, ...)"
        raise ValueError(f"cannot read image {path}: {why}") from None
    arr = np.asarray(arr)
    if arr.size == 0 or arr.ndim < 2:
        raise ValueError(f"{path} holds no image data (shape {arr.shape})")
    return arr


def exif_focal_35mm(path) -> float | None:
    """The EXIF ``FocalLengthIn35mmFilm`` of a photo, or None when it has none."""
    try:
        from PIL import Image

        with Image.open(path) as im:
            exif = im.getexif()
            value = exif.get_ifd(_EXIF_IFD).get(_FOCAL_35MM) or exif.get(_FOCAL_35MM)
    except Exception:  # no EXIF is the normal case for PNG and TIFF
        return None
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return value if value > 0 else None


class atomic_path:
    """Context manager giving a temporary path next to ``path``, renamed into place on success.

    On an exception (or KeyboardInterrupt) the temporary file is removed and ``path``
    is left untouched.
    """

    def __init__(self, path):
        self.path = Path(path)
        if not self.path.parent.is_dir():
            raise ValueError(f"output folder does not exist: {self.path.parent}")
        self.tmp = self.path.with_name(f".{self.path.stem}.tmp-{os.getpid()}{self.path.suffix}")

    def __enter__(self) -> Path:
        return self.tmp

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            os.replace(self.tmp, self.path)
        elif self.tmp.exists():
            self.tmp.unlink()
        return False


def write_image(path, image, bits: int | None = None) -> Path:
    """Write an image in [0, 1] (float) or integer array, encoded by the file's extension.

    Parameters
    ----------
    path : path-like
        ``.png`` (8 or 16 bit), ``.tif``/``.tiff`` (float32 kept), ``.jpg``, ``.bmp``.
    image : ndarray of shape (H, W) or (H, W, 3)
    bits : {8, 16}, optional
        PNG depth for float input (default 8).

    Returns
    -------
    Path
        The written file.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise ValueError(f"unsupported image format {suffix!r} for {path}; use one of "
                         + ", ".join(IMAGE_SUFFIXES))
    arr = np.asarray(image)
    with atomic_path(path) as tmp:
        if suffix in (".tif", ".tiff"):
            import tifffile

            out = arr.astype(np.float32) if np.issubdtype(arr.dtype, np.floating) else arr
            tifffile.imwrite(tmp, out)
        else:
            import imageio.v3 as iio

            if np.issubdtype(arr.dtype, np.floating) or arr.dtype == np.bool_:
                depth = 16 if (bits == 16 and suffix == ".png") else 8
                arr = _quantized(arr, depth)
            elif arr.dtype not in (np.uint8, np.uint16):
                raise ValueError(f"cannot write integer dtype {arr.dtype} as {suffix}")
            if suffix in (".jpg", ".jpeg", ".bmp") and arr.dtype == np.uint16:
                arr = (arr // 257).astype(np.uint8)
            iio.imwrite(tmp, arr, extension=suffix)
    return path


#: Pixels converted at a time when a float image is quantised for writing.
_QUANTIZE_PIXELS = 2**20


def _quantized(arr: np.ndarray, depth: int) -> np.ndarray:
    """Float (or bool) ``arr`` in [0, 1] -> uint8/uint16 of ``depth`` bits, rounded.

    NaN counts as 0 and values are clipped to [0, 1]; the arithmetic is float64, a slab
    of rows at a time, so no float64 copy of the whole image is made.
    """
    levels = 2**depth - 1
    shape = arr.shape
    arr = arr.reshape(1) if arr.ndim == 0 else arr
    out = np.empty(arr.shape, np.uint16 if depth == 16 else np.uint8)
    rows = max(1, _QUANTIZE_PIXELS // max(1, arr[0].size if len(arr) else 1))
    for r in range(0, arr.shape[0], rows):
        part = np.nan_to_num(arr[r:r + rows].astype(np.float64))
        np.clip(part, 0, 1, out=part)
        part *= levels
        out[r:r + rows] = np.round(part, out=part)
    return out.reshape(shape)


def write_json(path, data, indent=None) -> None:
    """Write ``data`` as JSON (one trailing newline), atomically (:class:`atomic_path`)."""
    import json

    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        json.dump(data, fh, indent=indent)
        fh.write("\n")


def read_json(path, what: str, parse=None):
    """Parse the JSON file ``path``; any problem is one ``ValueError`` line naming ``what``.

    ``what`` names the kind of file in the messages ("motion file", "profile file").
    ``parse`` (optional) builds the result from the parsed data (e.g. a ``from_dict``);
    its ``ValueError`` comes back prefixed with the path.
    """
    import json

    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ValueError(f"{what} not found: {path}") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ValueError(f"cannot read {what} {path}: {first_line(err)}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise ValueError(f"{what} {path} is not valid JSON: {err.msg} "
                         f"(line {err.lineno})") from None
    except (ValueError, RecursionError) as err:  # a number of > 4300 digits, deep nesting
        raise ValueError(f"{what} {path} is not valid JSON: {first_line(err)}") from None
    if parse is None:
        return data
    try:
        return parse(data)
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
