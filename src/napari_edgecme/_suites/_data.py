"""The suites' data: where it lives and how each case loads (photos, blurs, true motions)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import zlib
from pathlib import Path

import numpy as np

__all__ = ["CATEGORIES", "LAI_SRGB_NOISE", "SUITES", "case_gamma", "default_cache_dir",
           "default_data_dir", "float_image", "lai_cases", "lai_load", "lai_srgb_case",
           "levin_cases", "levin_load", "levin_motion", "real_photos"]

#: Suite name -> folder name under ``shared/data`` (``lai-srgb`` is rendered from ``lai``).
SUITES = {"lai": "lai", "lai-srgb": "lai", "levin": "levin", "real": "paper-real"}
#: Noise of the ``lai-srgb`` cases: zero-mean Gaussian of this sigma on the stored
#: (sRGB-encoded) [0, 1] scale, then 8-bit rounding -- the noise of the ``lai`` files.
LAI_SRGB_NOISE = 0.01
#: Changes whenever the rendering of ``lai-srgb`` does (the cache is keyed by it).
_LAI_SRGB_VERSION = "1+srgb-chunk"
CATEGORIES = ("manmade", "natural", "people", "saturated", "text")
#: Levin's anchor protocol (its README): these 8 cases, 1/10 px shift, 24 px border.
LEVIN_ANCHOR_CASES = tuple(f"im0{i}_ker0{k}" for i in range(1, 5) for k in (2, 5))
LEVIN_ANCHOR_BORDER = 24
LEVIN_ANCHOR_UPSAMPLE = 10
LEVIN_PAN_2016 = 30.47


def default_data_dir(suite: str) -> Path | None:
    """``shared/data/<folder>`` beside the checkout (or beside the working folder), if any."""
    folder = SUITES[suite]
    roots = [Path.cwd().parent, Path(__file__).resolve().parents[4]]
    for root in roots:
        candidate = root / "shared" / "data" / folder
        if candidate.is_dir():
            return candidate
    return None


def float_image(arr) -> np.ndarray:
    from ..core._validation import as_float_image

    arr = np.asarray(arr)
    if arr.ndim == 3 and arr.shape[2] == 4:
        arr = arr[..., :3]
    return as_float_image(arr, allow_rgb=True)


# --------------------------------------------------------------------------------------
# the cases
# --------------------------------------------------------------------------------------

def lai_cases(data: Path, quick: bool) -> list[dict]:
    """The cases of the ``lai`` folder (``quick``: those listed in ``quick.txt``)."""
    names = sorted(p.name for p in data.iterdir() if (p / "case.json").is_file())
    if quick:
        listed = (data / "quick.txt").read_text().split()
        names = [n for n in listed if n in names]
    cases = []
    for name in names:
        meta = json.loads((data / name / "case.json").read_text())
        cases.append({"name": name, "category": meta["category"], "model": "rotation",
                      "extent": meta["extent_px"], "max_blur": float(meta["max_blur"]),
                      "dir": str(data / name)})
    return cases


def lai_load(case: dict):
    from ..core.io import read_image
    from ..core.motion import CameraMotion

    folder = Path(case["dir"])
    return (float_image(read_image(folder / "blurred.png")),
            float_image(read_image(folder / "sharp.png")),
            CameraMotion.load(folder / "truth.json"))


def default_cache_dir() -> Path:
    """Where rendered ``lai-srgb`` cases are kept: ``$XDG_CACHE_HOME`` (or ``~/.cache``)
    ``/napari-edgecme/lai-srgb``."""
    root = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(root) / "napari-edgecme" / "lai-srgb"


def lai_srgb_case(case: dict, cache: Path) -> dict:
    """The ``lai-srgb`` version of a ``lai`` case: blurred in linear light, sRGB-encoded.

    The physically right order, which ``lai`` itself does not follow (Lai et al. blurred
    the 8-bit sRGB values as they were): ``sharp.png`` (8-bit sRGB) is linearised, blurred
    with the case's true motion (``truth.json``) by :func:`~..core.synth.render_blur`
    (dense cubic warping, independent of the estimator's operator), clipped to [0, 1] and
    encoded to sRGB; then, as ``lai``, Gaussian noise of :data:`LAI_SRGB_NOISE` on the
    [0, 1] scale of the file, clipped and rounded to 8 bits. The noise is added to the
    encoded values so that the file is as noisy as ``lai``'s (a sigma of 0.01 in linear
    light would become up to 0.13 in the shadows after the sRGB curve's slope of 12.92).
    Each case has its own generator (seeded from its name), so reruns are identical.

    The rendered case is a folder like ``lai``'s under ``cache`` (``blurred.png``,
    ``sharp.png``, ``truth.json``, ``case.json``), written once and reused while its
    sources and this rendering are unchanged; :func:`lai_load` reads it. The reference is
    the sRGB-encoded ``sharp.png`` (what the user sees).
    """
    from ..core.io import atomic_path, read_image
    from ..core.motion import CameraMotion
    from ..core.photometry import linear_to_srgb, srgb_to_linear
    from ..core.synth import render_blur

    src = Path(case["dir"])
    digest = hashlib.sha256(_LAI_SRGB_VERSION.encode())
    for name in ("sharp.png", "truth.json"):
        digest.update((src / name).read_bytes())
    key = digest.hexdigest()[:16]
    folder = Path(cache) / case["name"]
    stamp = folder / "source.json"
    if not (stamp.is_file() and json.loads(stamp.read_text()).get("key") == key):
        folder.mkdir(parents=True, exist_ok=True)
        sharp = float_image(read_image(src / "sharp.png")).astype(np.float64)
        truth = CameraMotion.load(src / "truth.json")
        blurred = linear_to_srgb(np.clip(render_blur(srgb_to_linear(sharp), truth), 0, 1))
        rng = np.random.default_rng([2016, zlib.crc32(case["name"].encode())])
        noisy = blurred + rng.normal(0.0, LAI_SRGB_NOISE, blurred.shape)
        _write_srgb_png(folder / "blurred.png",
                        np.round(np.clip(noisy, 0, 1) * 255).astype(np.uint8))
        for name in ("sharp.png", "truth.json", "case.json"):
            with atomic_path(folder / name) as tmp:
                shutil.copyfile(src / name, tmp)
        with atomic_path(stamp) as tmp:
            tmp.write_text(json.dumps({"key": key, "source": str(src),
                                       "noise": LAI_SRGB_NOISE}) + "\n")
    return {**case, "dir": str(folder), "source_dir": str(src)}


def _write_srgb_png(path: Path, image: np.ndarray) -> None:
    """An 8-bit PNG with the ``sRGB`` chunk that says how it is encoded (atomically)."""
    from PIL import Image, PngImagePlugin

    from ..core.io import atomic_path

    info = PngImagePlugin.PngInfo()
    info.add(b"sRGB", b"\x00")  # rendering intent: perceptual
    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG", pnginfo=info)


def case_gamma(case: dict, gamma="linear"):
    """The transfer curve a suite's case is run with, and why: ``gamma`` parsed
    (:func:`~..core.photometry.parse_gamma`); ``"auto"`` decides from the case's file as
    ``edgecme deblur`` does (``lai``'s untagged ``blurred.png``: linear; ``lai-srgb``'s,
    with its ``sRGB`` chunk: srgb; ``levin``'s ``.mat`` floats: linear)."""
    from ..core.io import read_image
    from ..core.photometry import decide_gamma, parse_gamma

    curve = parse_gamma(gamma)
    if curve != "auto":
        return curve, "given"
    if case.get("file"):  # levin: a .mat of floats
        return decide_gamma(case["file"], np.zeros(1, np.float32))
    path = Path(case["dir"]) / "blurred.png"
    return decide_gamma(path, read_image(path))


def levin_cases(data: Path, quick: bool) -> list[dict]:
    """The 32 captures (``quick``: the 8 of the anchor protocol)."""
    names = sorted(p.stem for p in data.glob("im0*_ker0*.mat"))
    if quick:
        names = [n for n in names if n in LEVIN_ANCHOR_CASES]
    cases = []
    for name in names:
        kernel = name.split("_")[1]
        cases.append({"name": name, "category": kernel, "model": "translation",
                      "file": str(data / f"{name}.mat"), "anchor": name in LEVIN_ANCHOR_CASES})
    return cases


def levin_motion(kernel: np.ndarray, image_shape) -> object:
    """The translation motion of a Levin kernel ``f`` (a correlation kernel: ``y = x * f``).

    ``y(x) = sum_u f(u) x(x + u)``, i.e. ``g(x) = sum_p w_p f(x - t_p)`` with ``t_p = -u``
    for each tap ``u`` (column, row offsets from the kernel's centre).
    """
    from ..core.camera import Intrinsics
    from ..core.motion import CameraMotion

    f = np.asarray(kernel, np.float64)
    rows, cols = np.nonzero(f > 0)
    cy, cx = (f.shape[0] - 1) / 2, (f.shape[1] - 1) / 2
    poses = np.stack([-(cols - cx), -(rows - cy)], axis=1)
    return CameraMotion("translation", Intrinsics.from_image_shape(image_shape), poses,
                        f[rows, cols] / f[rows, cols].sum())


def levin_max_blur(truth) -> float:
    """The max blur a ``levin`` case tells the estimators: the kernel's size, as the other
    methods of Levin's table are told it (the side of ``f`` without its zero border, the
    benchmark's ``sizeL.mat``, 11-25 px)."""
    return float(truth.psf_size())


def levin_load(case: dict):
    from scipy.io import loadmat

    mat = loadmat(case["file"])
    sharp = np.clip(np.asarray(mat["x"], np.float32), 0, 1)
    blurred = np.clip(np.asarray(mat["y"], np.float32), 0, 1)
    return blurred, sharp, levin_motion(mat["f"], blurred.shape)


def real_photos(data: Path) -> list[dict]:
    """The photos of the ``paper-real`` folder: input and the paper's outputs, per scene."""
    photos = []
    for folder in sorted(p for p in data.iterdir() if p.is_dir()):
        inputs = sorted(folder.glob("input.*"))
        if not inputs:
            continue
        paper = {key: next(iter(sorted(folder.glob(f"{key}.*"))), None)
                 for key in ("epalone", "xu_ep", "xu2013")}
        photos.append({"name": folder.name, "input": str(inputs[0]),
                       **{f"paper_{k}": (str(v) if v else None) for k, v in paper.items()}})
    return photos
