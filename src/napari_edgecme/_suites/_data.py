"""The suites' data: where it lives and how each case loads (photos, blurs, true motions)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["CATEGORIES", "SUITES", "default_data_dir", "float_image", "lai_cases", "lai_load",
           "levin_cases", "levin_load", "levin_motion", "real_photos"]

#: Suite name -> folder name under ``shared/data``.
SUITES = {"lai": "lai", "levin": "levin", "real": "paper-real"}
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
