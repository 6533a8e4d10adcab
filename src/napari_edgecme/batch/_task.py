"""One photo of a batch, the Dask task: decode, deblur as ``edgecme deblur``, encode."""

from __future__ import annotations

import argparse
import io
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from .._worker import peak_rss_mib
from ..cli._console import PROG, CLIError, _Console, oserror_message
from ..cli._deblur import deblur_image, estimate_summary
from ..cli._files import output_bits, read_input_image
from ..cli._options import deconvolution_params
from ..core import io as _io
from ..core._validation import first_line
from ..core.deblur import ep_prior_note
from ._report import DONE, FAILED, NO_BLUR

__all__ = ["THUMB_SIDE", "deblur_photo"]

#: Longer side of the before/after thumbnails (pixels).
THUMB_SIDE = 192


def _thumbnail(image: np.ndarray, side: int = THUMB_SIDE) -> np.ndarray:
    """A float image in [0, 1] whose longer side is at most ``side`` (area averaging)."""
    from skimage.transform import resize

    from ..core._validation import as_float_image

    arr = as_float_image(image, allow_rgb=True)
    scale = side / max(arr.shape[:2])
    if scale >= 1:
        return arr
    shape = tuple(max(1, round(n * scale)) for n in arr.shape[:2]) + arr.shape[2:]
    return np.clip(resize(arr, shape, anti_aliasing=True), 0, 1)


def _psf_thumbnail(motion, side: int = THUMB_SIDE) -> np.ndarray:
    """The motion's 5x5 PSF field, max-pooled so that thin PSFs survive the reduction."""
    from skimage.measure import block_reduce

    field_image = motion.psf_field(grid=(5, 5))
    factor = max(1, int(np.ceil(max(field_image.shape) / side)))
    return block_reduce(field_image, (factor, factor), np.max)


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return "this process"


def deblur_photo(name: str, data: bytes, options: argparse.Namespace) -> dict:
    """Deblur one photo given as file bytes, as ``edgecme deblur`` would; the batch's task.

    Parameters
    ----------
    name : str
        The photo's output name (its extension picks the output format).
    data : bytes
        The photo file's content.
    options : argparse.Namespace
        The ``edgecme deblur`` options (``method``, ``model``, ``max_blur``, ``seed``,
        ``deconvolution``, ...), as :func:`deblur_many` builds them.

    Returns
    -------
    dict
        The photo's report row (``status``, ``method``, ``blur_extent_px``, ...,
        ``summary``: the line ``deblur`` would print) and ``files``: output role ->
        encoded bytes (``output``, ``motion``, ``before``, ``after``, ``psf``). A failure
        is a row with status ``"failed"``, its one-line ``reason`` and no files; it is
        never raised.
    """
    t0 = time.perf_counter()
    row: dict = {"photo": name, "status": FAILED, "files": {}}
    with tempfile.TemporaryDirectory(prefix="edgecme-batch-") as tmp:
        folder = Path(tmp)
        src = folder / Path(name).name
        src.write_bytes(data)
        stream = io.StringIO()  # the CLI's warnings about the input (alpha channel)
        console = _Console(quiet=True, stream=stream)

        def own(text: str) -> str:  # messages name the photo, not the temporary copy
            return text.replace(str(src), name)

        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                image = read_input_image(src, console)
                params = deconvolution_params(options, options.deconvolution)
                restored, result, max_blur, source, _ = deblur_image(
                    options, console, image, src, params)
                encoded = folder / ("restored" + Path(name).suffix)
                _io.write_image(encoded, restored, bits=output_bits(image))
                result.motion.save(folder / "motion.json", estimated_by=result.info.method,
                                   profile_misfit=result.info.profile_misfit)
                _io.write_image(folder / "before.png", _thumbnail(image))
                _io.write_image(folder / "after.png", _thumbnail(restored))
                _io.write_image(folder / "psf.png", _psf_thumbnail(result.motion))
            info = result.info
            prior = ep_prior_note(info.method, options.deconvolution, params,
                                  info.profile_misfit)
            row.update(
                status=NO_BLUR if info.no_blur else DONE,
                method=info.method,
                blur_extent_px=round(float(result.motion.blur_extent()), 2),
                profiles=info.n_profiles,
                summary=own(estimate_summary(result, options.method, max_blur, source)
                            + (f"; {prior}" if prior else "")),
                files={role: (folder / file).read_bytes() for role, file in (
                    ("output", encoded.name), ("before", "before.png"),
                    ("after", "after.png"), ("psf", "psf.png"), ("motion", "motion.json"))})
            notes = [line.removeprefix(f"{PROG}: warning: ")
                     for line in stream.getvalue().splitlines()]
            notes += [first_line(w.message) for w in caught
                      if issubclass(w.category, UserWarning)]
            row["notes"] = [own(note) for note in dict.fromkeys(notes)]
            row["warnings"] = " | ".join(row["notes"])
        except (CLIError, ValueError) as err:
            row["reason"] = own(first_line(err))
        except MemoryError:
            row["reason"] = "out of memory; try a smaller max_side for the estimation"
        except OSError as err:
            row["reason"] = own(oserror_message(err))
        except Exception as err:  # a bug: the batch goes on, the report says what it was
            row["reason"] = f"internal error: {type(err).__name__}: {own(first_line(err))}"
    row["seconds"] = round(time.perf_counter() - t0, 2)
    row["worker"] = _worker_name()
    peak = peak_rss_mib()  # the worker process's own high-water mark
    row["worker_peak_mib"] = round(peak) if peak is not None else ""
    return row
