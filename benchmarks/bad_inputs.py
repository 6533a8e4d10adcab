"""The bad-input matrix (issue 8): what a user sees for each bad input, in the API and the CLI.

Every case below is *run*: the Python API face calls the public function and records
the exception it raises (its type and its one-line message) or, when the input is
accepted, what came back and any warning; the CLI face runs ``edgecme`` in-process
(``napari_edgecme.cli.main``) with stderr captured and records the exit status, the
line(s) printed and whether any file was written. The output is a Markdown table::

    python benchmarks/bad_inputs.py              # print the table
    python benchmarks/bad_inputs.py --write      # and write docs/bad-inputs.md

The napari widgets show the API's message as one error notification titled with the
widget's name (e.g. ``Camera motion: image must be at least 8x8 pixels; got 1x1``) and
add no layer; ``tests/gui/test_bad_input_widgets.py`` checks that face.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from napari_edgecme import (
    CameraMotion,
    Intrinsics,
    deconvolve,
    estimate_motion,
    extract_edge_profiles,
    read_image,
)
from napari_edgecme.cli import main as cli_main
from napari_edgecme.core import synth
from napari_edgecme.core.io import write_image

DOC = Path(__file__).resolve().parents[1] / "docs" / "bad-inputs.md"

#: Fast estimation settings (the matrix checks messages, not quality).
FAST = {"n_iter": 1}
FAST_CLI = ["--n-iter", "1"]


@dataclass
class Case:
    """One bad input: its API call and/or its CLI arguments (run in the data folder)."""

    name: str
    api: object = None  # callable(folder) -> result, or None when the face does not apply
    api_call: str = ""  # how the API was called, for the table
    cli: list | None = None  # edgecme arguments


# --------------------------------------------------------------------------------------
# the input files
# --------------------------------------------------------------------------------------

def make_files(folder: Path) -> dict:
    """Write every input file of the matrix into ``folder``; return the in-memory arrays."""
    import tifffile

    case = synth.make_case(synth.sample_image("edges", 96), "inplane", 5, 0.01, rng=3)
    blurred = case.blurred  # float32 in [0, 1]
    u8 = np.round(blurred * 255).astype(np.uint8)
    write_image(folder / "blurred.png", blurred)
    case.motion.save(folder / "truth.json")
    (folder / "text.png").write_text("this is not an image\n")
    (folder / "empty.png").write_bytes(b"")
    data = (folder / "blurred.png").read_bytes()
    (folder / "truncated.png").write_bytes(data[: len(data) // 2])
    write_image(folder / "one-pixel.png", np.zeros((1, 1)))
    rng = np.random.default_rng(0)
    write_image(folder / "eight.png", rng.random((8, 8)))
    write_image(folder / "flat.png", np.full((96, 96), 0.4))
    nan = blurred.copy()
    nan[10, 10] = np.nan
    tifffile.imwrite(folder / "nan.tif", nan)
    inf = blurred.copy()
    inf[10, 10] = np.inf
    tifffile.imwrite(folder / "inf.tif", inf)
    tifffile.imwrite(folder / "counts.tif", (blurred * 4095).astype(np.float32))
    for dtype in ("bool", "int32", "float16", "float64"):
        tifffile.imwrite(folder / f"dtype-{dtype}.tif", as_dtype(blurred, dtype))
    write_image(folder / "dtype-uint16.png", blurred, bits=16)
    alpha = np.full((96, 96), 128, np.uint8)
    import imageio.v3 as iio

    iio.imwrite(folder / "gray-alpha.png", np.stack([u8, alpha], -1))
    iio.imwrite(folder / "rgba.png", np.stack([u8, u8, u8, alpha], -1))
    iio.imwrite(folder / "rgba-opaque.png", np.stack([u8, u8, u8, np.full_like(u8, 255)], -1))
    tifffile.imwrite(folder / "stack.tif", np.stack([u8] * 5))
    good = case.motion.to_dict()
    motions = {
        "malformed.json": '{"format": "edgecme-motion", "version": 1,',
        "other-format.json": json.dumps({"format": "something-else"}),
        "version-2.json": json.dumps({**good, "version": 2}),
        "negative-weights.json": json.dumps(
            {**good, "weights": [-w for w in good["weights"]]}),
        "zero-weights.json": json.dumps({**good, "weights": [0.0] * len(good["weights"])}),
        "no-poses.json": json.dumps({**good, "poses": [], "weights": []}),
    }
    for name, text in motions.items():
        (folder / name).write_text(text)
    wide = Intrinsics.from_image_shape((96, 192))
    CameraMotion("inplane", wide, case.motion.poses, case.motion.weights).save(
        folder / "wide.json")
    half = case.motion.rescale((48, 48))
    half.save(folder / "half-size.json")
    tiny = Intrinsics.from_image_shape((8, 8))
    CameraMotion.from_trajectory([[0, 0], [20, 0]], "translation", tiny).save(
        folder / "big-blur-8px.json")
    return {"blurred": blurred, "motion": case.motion}


def as_dtype(image: np.ndarray, dtype: str) -> np.ndarray:
    """``image`` (float in [0, 1]) in ``dtype``, scaled as the engine reads that dtype."""
    if dtype == "bool":
        return image > 0.5
    if dtype in ("uint8", "uint16", "int32"):
        return np.round(image * np.iinfo(dtype).max).astype(dtype)
    return image.astype(dtype)


# --------------------------------------------------------------------------------------
# the cases
# --------------------------------------------------------------------------------------

def cases(arrays: dict) -> list[Case]:
    blurred, motion = arrays["blurred"], arrays["motion"]

    def est(image, method="xu+ep", model="inplane", max_blur=7, **kw):
        return lambda folder: estimate_motion(image, method, model, max_blur, rng=0,
                                              **{**FAST, **kw})

    def load(name):
        return lambda folder: read_image(folder / name)

    def load_motion(name):
        return lambda folder: deconvolve(blurred, CameraMotion.load(folder / name), "wiener")

    est_cli = ["estimate", "-o", "out.json", "--model", "inplane", *FAST_CLI]
    out = [
        Case("not an image (a text file)", load("text.png"), "read_image",
             ["deblur", "text.png", "-o", "out.png"]),
        Case("empty file", load("empty.png"), "read_image",
             ["deblur", "empty.png", "-o", "out.png"]),
        Case("truncated PNG (first half of the file)", load("truncated.png"), "read_image",
             ["deblur", "truncated.png", "-o", "out.png"]),
        Case("1x1 image", est(np.zeros((1, 1))), "estimate_motion",
             [*est_cli[:1], "one-pixel.png", *est_cli[1:]]),
        Case("1x1 image", lambda f: deconvolve(np.zeros((1, 1)), motion), "deconvolve"),
        Case("8x8 image, default max_blur", est(rng_image(8), max_blur=None),
             "estimate_motion", [*est_cli[:1], "eight.png", *est_cli[1:]]),
        Case("8x8 image, max_blur 3", est(rng_image(8), max_blur=3), "estimate_motion",
             [*est_cli[:1], "eight.png", *est_cli[1:], "--max-blur", "3"]),
        Case("image smaller than the blur (96 px, max_blur 60)", est(blurred, max_blur=60),
             "estimate_motion", [*est_cli[:1], "blurred.png", *est_cli[1:], "--max-blur", "60"]),
        Case("image smaller than the blur (8x8 image, 20 px motion)",
             lambda f: deconvolve(np.full((8, 8), 0.5), CameraMotion.load(f / "big-blur-8px.json"),
                                  "wiener"), "deconvolve",
             ["deconvolve", "eight.png", "--motion", "big-blur-8px.json", "-o", "out.png",
              "--deconvolution", "wiener"]),
        Case("constant image (no edges), xu+ep", est(np.full((96, 96), 0.4)),
             "estimate_motion", [*est_cli[:1], "flat.png", *est_cli[1:], "--max-blur", "7"]),
        Case("constant image (no edges), ep", est(np.full((96, 96), 0.4), method="ep"),
             "estimate_motion", [*est_cli[:1], "flat.png", *est_cli[1:], "--max-blur", "7",
                                 "--method", "ep"]),
        Case("constant image (no edges), xu", est(np.full((96, 96), 0.4), method="xu"),
             "estimate_motion", [*est_cli[:1], "flat.png", *est_cli[1:], "--max-blur", "7",
                                 "--method", "xu"]),
        Case("constant image (no edges)", lambda f: extract_edge_profiles(
            np.full((96, 96), 0.4), 7), "extract_edge_profiles",
             ["profiles", "flat.png", "-o", "profiles.json", "--max-blur", "7"]),
        Case("NaN pixel", est(with_value(blurred, np.nan)), "estimate_motion",
             [*est_cli[:1], "nan.tif", *est_cli[1:], "--max-blur", "7"]),
        Case("inf pixel", lambda f: deconvolve(with_value(blurred, np.inf), motion),
             "deconvolve", ["deconvolve", "inf.tif", "--motion", "truth.json", "-o", "out.tif"]),
        Case("float image not scaled to [0, 1]", est(blurred * 4095), "estimate_motion",
             [*est_cli[:1], "counts.tif", *est_cli[1:], "--max-blur", "7"]),
    ]
    for dtype in ("bool", "uint8", "uint16", "int32", "float16", "float32", "float64"):
        files = {"uint8": "blurred.png", "uint16": "dtype-uint16.png", "float32": None}
        file = files.get(dtype, f"dtype-{dtype}.tif")
        image = as_dtype(blurred, dtype)
        out.append(Case(f"dtype {dtype}", dtype_api(image, motion), "deconvolve",
                        None if file is None else
                        ["deconvolve", file, "--motion", "truth.json", "-o", "out.tif",
                         "--deconvolution", "wiener"]))
    u8 = np.round(blurred * 255).astype(np.uint8)
    alpha = np.full_like(u8, 128)
    out += [
        Case("gray+alpha", est(np.stack([u8, alpha], -1)), "estimate_motion",
             [*est_cli[:1], "gray-alpha.png", *est_cli[1:], "--max-blur", "7", "--method", "xu"]),
        Case("RGBA", lambda f: deconvolve(np.stack([u8, u8, u8, alpha], -1), motion),
             "deconvolve", ["deconvolve", "rgba.png", "--motion", "truth.json", "-o", "out.png",
                            "--deconvolution", "wiener"]),
        Case("RGBA, opaque", None, "",
             ["deconvolve", "rgba-opaque.png", "--motion", "truth.json", "-o", "out.png",
              "--deconvolution", "wiener"]),
        Case("3-D stack (5 planes)", est(np.stack([u8] * 5)), "estimate_motion",
             ["deblur", "stack.tif", "-o", "out.png"]),
        Case("huge max_blur (1e6)", est(blurred, max_blur=1e6), "estimate_motion",
             [*est_cli[:1], "blurred.png", *est_cli[1:], "--max-blur", "1e6"]),
        Case("negative max_blur", est(blurred, max_blur=-4), "estimate_motion",
             [*est_cli[:1], "blurred.png", *est_cli[1:], "--max-blur", "-4"]),
        Case("zero max_blur", est(blurred, max_blur=0), "estimate_motion",
             [*est_cli[:1], "blurred.png", *est_cli[1:], "--max-blur", "0"]),
        Case("NaN max_blur", est(blurred, max_blur=float("nan")), "estimate_motion",
             [*est_cli[:1], "blurred.png", *est_cli[1:], "--max-blur", "nan"]),
        Case("lambda_w 0 (no L1 weight)", est(blurred, method="xu", lambda_w=0),
             "estimate_motion", [*est_cli[:1], "blurred.png", *est_cli[1:], "--max-blur", "7",
                                 "--method", "xu", "--lambda-w", "0"]),
        Case("negative lambda_w", est(blurred, lambda_w=-1), "estimate_motion",
             [*est_cli[:1], "blurred.png", *est_cli[1:], "--lambda-w", "-1"]),
        Case("zero lambda_f", est(blurred, lambda_f=0), "estimate_motion",
             [*est_cli[:1], "blurred.png", *est_cli[1:], "--lambda-f", "0"]),
        Case("negative lambda_ip", est(blurred, lambda_ip=-0.5), "estimate_motion",
             [*est_cli[:1], "blurred.png", *est_cli[1:], "--lambda-ip", "-0.5"]),
        Case("zero n_iter", est(blurred, n_iter=0), "estimate_motion",
             [*est_cli[:1], "blurred.png", "-o", "out.json", "--n-iter", "0"]),
        Case("negative n_iter", est(blurred, n_iter=-2), "estimate_motion",
             [*est_cli[:1], "blurred.png", "-o", "out.json", "--n-iter", "-2"]),
        Case("fractional n_iter", est(blurred, n_iter=2.5), "estimate_motion",
             [*est_cli[:1], "blurred.png", "-o", "out.json", "--n-iter", "2.5"]),
        Case("zero lam (hyper-Laplacian)", lambda f: deconvolve(blurred, motion, lam=0),
             "deconvolve", ["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                            "out.png", "--lam", "0"]),
        Case("zero RL iterations", lambda f: deconvolve(blurred, motion, "rl", iterations=0),
             "deconvolve", ["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                            "out.png", "--deconvolution", "rl", "--iterations", "0"]),
        Case("unknown method name", est(blurred, method="fergus"), "estimate_motion",
             [*est_cli[:1], "blurred.png", *est_cli[1:], "--method", "fergus"]),
        Case("unknown model name", est(blurred, model="affine"), "estimate_motion",
             [*est_cli[:1], "blurred.png", "-o", "out.json", "--model", "affine"]),
        Case("unknown deconvolution method",
             lambda f: deconvolve(blurred, motion, "lucy"), "deconvolve",
             ["deconvolve", "blurred.png", "--motion", "truth.json", "-o", "out.png",
              "--deconvolution", "lucy"]),
        Case("unknown parameter name", est(blurred, lamda_w=1e-3), "estimate_motion"),
    ]
    motion_cli = ["deconvolve", "blurred.png", "-o", "out.png", "--method", "wiener",
                  "--motion"]
    for label, name in (("motion file: malformed JSON", "malformed.json"),
                        ("motion file: another format", "other-format.json"),
                        ("motion file: another version", "version-2.json"),
                        ("motion file: negative weights", "negative-weights.json"),
                        ("motion file: all-zero weights", "zero-weights.json"),
                        ("motion file: no poses", "no-poses.json"),
                        ("motion file: another aspect ratio (96x192)", "wide.json"),
                        ("motion file: same aspect, half size (48x48)", "half-size.json"),
                        ("motion file: missing", "missing.json")):
        out.append(Case(label, load_motion(name), "CameraMotion.load + deconvolve",
                        [*motion_cli, name]))
    return out


def rng_image(size: int) -> np.ndarray:
    return np.random.default_rng(0).random((size, size))


def with_value(image: np.ndarray, value: float) -> np.ndarray:
    out = image.copy()
    out[10, 10] = value
    return out


def dtype_api(image, motion):
    return lambda folder: deconvolve(image, motion, "wiener")


# --------------------------------------------------------------------------------------
# running the faces
# --------------------------------------------------------------------------------------

def describe(result) -> str:
    """What an accepted call returned, in a few words."""
    if isinstance(result, np.ndarray):
        if result.ndim >= 2 and result.shape[0] > 8:  # an image
            return f"accepted: {result.dtype} image {'x'.join(map(str, result.shape))}"
        return f"accepted: {result.dtype} array {'x'.join(map(str, result.shape))}"
    if hasattr(result, "motion") and hasattr(result, "info"):  # MotionEstimate
        info = result.info
        text = f"accepted: {result.motion.model} motion, {result.motion.n_poses} poses"
        if info.method:
            text += f" (method {info.method})"
        return text
    if hasattr(result, "reason"):  # EdgeProfiles
        why = f" ({result.reason})" if getattr(result, "reason", "") else ""
        return f"accepted: {len(result)} edge profiles{why}"
    return f"accepted: {type(result).__name__}"


def run_api(case: Case, folder: Path) -> tuple[str, str]:
    """``(message, outcome)`` of the API face, run in ``folder`` (file names as given)."""
    with warnings.catch_warnings(record=True) as caught, _inside(folder):
        warnings.simplefilter("always")
        try:
            result = case.api(Path("."))
        except Exception as err:  # what the user sees is the point
            lines = str(err).splitlines() or [""]
            extra = " (+ more lines)" if len(lines) > 1 else ""
            return f"{lines[0]}{extra}", type(err).__name__
    said = [f"warning: {w.message}" for w in caught
            if issubclass(w.category, UserWarning)]
    message = describe(result)
    if said:
        message += "; " + "; ".join(said)
    return message, "returns"


@contextlib.contextmanager
def _inside(folder: Path):
    cwd = Path.cwd()
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(cwd)


def run_cli(case: Case, folder: Path) -> tuple[str, str]:
    """``(stderr, exit status and files written)`` of the CLI face, run in ``folder``."""
    before = {p.name for p in folder.iterdir()}
    err = io.StringIO()
    with _inside(folder), contextlib.redirect_stderr(err), \
            contextlib.redirect_stdout(io.StringIO()):
        status = cli_main(["--quiet", *case.cli])
    after = {p.name for p in folder.iterdir()}
    written = sorted(after - before)
    for name in written:  # keep the folder as it was for the next case
        (folder / name).unlink()
    lines = [line for line in err.getvalue().splitlines() if line.strip()]
    message = " / ".join(lines) if lines else "(nothing)"
    outcome = f"exit {status}"
    outcome += f", wrote {', '.join(written)}" if written else ", nothing written"
    return message, outcome


def cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def table(rows) -> str:
    out = ["| case | face | message the user sees | exit status / exception |",
           "|---|---|---|---|"]
    out += [f"| {cell(a)} | {cell(b)} | {cell(c)} | {cell(d)} |" for a, b, c, d in rows]
    return "\n".join(out)


def run_all(log=None) -> list[tuple[str, str, str, str]]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        arrays = make_files(folder)
        for case in cases(arrays):
            if case.api is not None:
                message, outcome = run_api(case, folder)
                rows.append((case.name, f"API `{case.api_call}`", message, outcome))
            if case.cli is not None:
                message, outcome = run_cli(case, folder)
                rows.append((case.name, "CLI `edgecme " + " ".join(case.cli) + "`", message,
                             outcome))
            if log:
                log(f"{case.name}: done")
    return rows


INTRO = """\
# Bad input: what a user sees

Each row is one bad (or borderline) input run through one face of napari-edgecme: the
Python API (the exception type and its one-line message, or what an accepted call
returned and any warning) and the `edgecme` command line (its stderr, with `--quiet`,
and its exit status; "nothing written" means the folder held no new file afterwards,
temporary files included). The API faces below are `estimate_motion`, `deconvolve`,
`extract_edge_profiles`, `read_image` and `CameraMotion.load`; bad input there is one
`ValueError` line naming the parameter (an unknown keyword is Python's own `TypeError`).
The napari widgets show the same message as one error notification prefixed with the
widget's title (e.g. `Camera motion: ...`) and add no layer
(`tests/gui/test_bad_input_widgets.py`).

**3-D stacks are refused, not processed per plane**, by every face: the API raises
`image must have shape (rows, cols) or (rows, cols, 3); got shape (5, 96, 96) (a stack or
volume: pass one 2-D plane at a time)`, the CLI exits 2 with `expected a gray or RGB
image ... (a stack or volume: save its planes as separate images)`, and the widgets do not
offer stack layers (their image lists hold only 2-D gray/RGB(A) layers). To deblur a
stack, loop over its planes (each plane has its own camera motion).

**Alpha**: the API refuses gray+alpha and RGBA arrays with a hint (`image[..., 0]`,
`image[..., :3]`); the CLI and the widgets drop the alpha channel (the CLI warns unless
it is opaque). **Dtypes**: bool, every integer dtype (scaled by its maximum; negative
values of signed types clip to 0) and float16 compute in float32; float32 stays float32
and float64 stays float64 (`as_float_image`); float images must lie in [0, 1].

**Accepted without a word** (a known gap): deconvolving an image smaller than its blur
returns mostly the prior. (Method `xu` on a constant image now warns that there is no
blur to estimate; `n_iter` is capped at 1000; `rng`, `profiles` and `preview` are
checked before any work.)

Generated by `python benchmarks/bad_inputs.py --write` ({date}, {seconds:.0f} s); do not
edit the table by hand.

"""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help=f"also write {DOC}")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    rows = run_all(log=lambda text: print(text, file=sys.stderr))
    text = table(rows)
    print(text)
    if args.write:
        DOC.parent.mkdir(exist_ok=True)
        DOC.write_text(INTRO.format(date=time.strftime("%Y-%m-%d"),
                                    seconds=time.perf_counter() - t0) + text + "\n")
        print(f"wrote {DOC}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
