"""``--gamma {auto,linear,srgb,VALUE}`` on the command line and in batches (issue 14, item 3):
auto decides from the file and the summary says so, work happens in linear light and the
output is re-encoded as the input was, bad values are one line with exit status 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile
from PIL import Image, PngImagePlugin

from napari_edgecme.cli import main
from napari_edgecme.core import synth
from napari_edgecme.core.io import read_image, write_image
from napari_edgecme.core.metrics import psnr
from napari_edgecme.core.motion import CameraMotion
from napari_edgecme.core.photometry import linear_to_srgb, srgb_to_linear

FAST = ["--model", "translation", "--max-blur", "12", "--n-iter", "1"]


def run(argv, capsys):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, [line for line in err.splitlines() if line.strip()]


@pytest.fixture(scope="module")
def photo(tmp_path_factory) -> Path:
    """An sRGB photo as a camera makes it: blurred in linear light, then encoded, noisy,
    8 bits (blurred.png); its sRGB sharp original; the true motion; and the same blurred
    image in linear light as a 16-bit TIFF."""
    root = tmp_path_factory.mktemp("gamma-cli")
    sharp = synth.sample_image("camera", 128)
    case = synth.make_case(srgb_to_linear(sharp), "translation", 8, noise=0, bits=None,
                           rng=0)
    blurred = synth.quantize(np.clip(synth.add_noise(linear_to_srgb(case.blurred), 0.01,
                                                     np.random.default_rng(0)), 0, 1), 8)
    write_image(root / "sharp.png", sharp)
    # as a camera's PNG export says it: with the sRGB chunk (untagged PNGs mean linear)
    info = PngImagePlugin.PngInfo()
    info.add(b"sRGB", b"\x00")
    Image.fromarray(np.round(blurred * 255).astype(np.uint8)).save(root / "blurred.png",
                                                                  pnginfo=info)
    tifffile.imwrite(root / "linear16.tif",
                     np.round(srgb_to_linear(blurred) * 65535).astype(np.uint16))
    case.motion.save(root / "truth.json")
    return root


def test_auto_says_srgb_for_a_tagged_8bit_png_and_linear_for_a_16bit_tiff(photo, tmp_path, capsys):
    status, _, err = run(["deblur", photo / "blurred.png", "-o", tmp_path / "r.png", *FAST],
                         capsys)
    assert status == 0, err
    assert "; gamma: srgb (8-bit PNG with an sRGB chunk);" in err[-1]
    status, _, err = run(["deblur", photo / "linear16.tif", "-o", tmp_path / "r.tif", *FAST],
                         capsys)
    assert status == 0, err
    assert "; gamma: linear (16-bit TIFF);" in err[-1]
    status, _, err = run(["estimate", photo / "blurred.png", "-o", tmp_path / "m.json",
                          *FAST, "--gamma", "2.2"], capsys)
    assert status == 0, err
    assert "; gamma: 2.2 (given); wrote" in err[-1]


def test_deconvolve_in_linear_light_and_reencode(photo, tmp_path, capsys):
    """With the true motion, the deconvolution alone: srgb (auto) beats linear on an sRGB
    photo, and the output stays sRGB-encoded (compared with the sRGB sharp image)."""
    sharp = read_image(photo / "sharp.png") / 255.0
    scores = {}
    for gamma in ("auto", "linear"):
        out = tmp_path / f"{gamma}.png"
        status, _, err = run(["deconvolve", photo / "blurred.png", "--motion",
                              photo / "truth.json", "-o", out, "--gamma", gamma], capsys)
        assert status == 0, err
        said = "srgb (8-bit PNG with an sRGB chunk)" if gamma == "auto" else "linear (given)"
        assert f"gamma: {said}" in err[-1]
        restored = read_image(out)
        assert restored.dtype == np.uint8  # 8 bits in, 8 bits out
        scores[gamma] = psnr(restored / 255.0, sharp)
    assert scores["auto"] > scores["linear"] + 1.0, scores


@pytest.mark.parametrize("bad", ["bright", "-1", "0", "nan"])
@pytest.mark.parametrize("command", ["deblur", "estimate", "deconvolve", "profiles"])
def test_bad_gamma_is_exit_2_with_one_line(photo, tmp_path, capsys, command, bad):
    outputs = {"deblur": ["-o", tmp_path / "r.png"], "estimate": ["-o", tmp_path / "m.json"],
               "profiles": ["-o", tmp_path / "p.json"],
               "deconvolve": ["--motion", photo / "truth.json", "-o", tmp_path / "r.png"]}
    status, out, err = run([command, photo / "blurred.png", *outputs[command],
                            f"--gamma={bad}"], capsys)
    assert status == 2
    assert len(err) == 1 and err[0].startswith("edgecme: error:") and "--gamma" in err[0]
    assert repr(bad) in err[0] and "Traceback" not in out + "".join(err)
    assert not any(tmp_path.iterdir())  # nothing written


def test_batch_takes_gamma(photo, tmp_path):
    from napari_edgecme import deblur_many

    lines = []
    result = deblur_many([photo / "blurred.png"], tmp_path / "out", "xu", "translation", 12,
                         workers=1, n_iter=1, log=lines.append)
    assert result.ok and any("gamma: srgb (8-bit PNG with an sRGB chunk)" in line for line in lines)
    lines.clear()
    result = deblur_many([photo / "blurred.png"], tmp_path / "lin", "xu", "translation", 12,
                         workers=1, n_iter=1, gamma="linear", log=lines.append)
    assert result.ok and any("gamma: linear (given)" in line for line in lines)
    with pytest.raises(ValueError, match=r"gamma must be .*got 'dim'"):
        deblur_many([photo / "blurred.png"], tmp_path / "bad", gamma="dim", workers=1)
    assert not (tmp_path / "bad").exists()


def test_profiles_are_measured_in_linear_light(photo, tmp_path, capsys):
    """``edgecme profiles`` linearises as ``deblur`` does: on the sRGB-tagged photo auto
    takes sRGB and its profiles match the true blur; taken as linear they do not."""
    from napari_edgecme.core.edges import EdgeProfiles
    from napari_edgecme.core.measurement import measurement_matrix, profile_misfit

    truth = CameraMotion.load(photo / "truth.json").recentred()
    misfit = {}
    for gamma in ("auto", "linear"):
        out = tmp_path / f"{gamma}.json"
        status, _, err = run(["profiles", photo / "blurred.png", "-o", out, "--max-blur", "12",
                              "--gamma", gamma], capsys)
        assert status == 0, err
        reason = "8-bit PNG with an sRGB chunk" if gamma == "auto" else "given"
        summary = next(line for line in err if " edge profiles (" in line)
        assert f"; gamma: {'srgb' if gamma == 'auto' else 'linear'} ({reason})); wrote" in summary
        profiles = EdgeProfiles.load(out)
        matrix = measurement_matrix(profiles, truth.model, truth.intrinsics, truth.poses)
        misfit[gamma] = float(np.median(profile_misfit(matrix, profiles, truth.weights)))
    # measured (median misfit to the true motion's projections, 0 = exact): 0.078 (auto:
    # sRGB) vs 0.159 (taken as linear)
    assert misfit["auto"] < 0.1 and misfit["linear"] > 1.5 * misfit["auto"], misfit
