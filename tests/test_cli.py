"""Claims about the ``edgecme`` command line: every subcommand works on small inputs and
writes readable outputs, ``deblur`` deblurs, bad input is one line on stderr with exit
status 2 and no output, Ctrl-C is exit 130 with no output, and progress shows only on a
terminal. The CLI runs in-process through ``main(argv)``, and through the console script
and ``python -m napari_edgecme`` in a few subprocess tests."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from napari_edgecme.cli import ProgressBar, main
from napari_edgecme.core import synth
from napari_edgecme.core.deblur import ep_prior_factor
from napari_edgecme.core.edges import EdgeProfiles
from napari_edgecme.core.io import read_image, write_image
from napari_edgecme.core.metrics import aligned_psnr
from napari_edgecme.core.motion import CameraMotion
from napari_edgecme.core.progress import Progress

SUBCOMMANDS = ("demo", "deblur", "estimate", "deconvolve", "profiles", "psf", "synth", "bench")
FAST = ["--n-iter", "2"]  # fewer alternations per scale: the tests check the plumbing


# --------------------------------------------------------------------------------------
# fixtures: a small synthetic case on disk
# --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """A folder with a sharp edge scene, its 8-bit blurred copy (in-plane shake, 9 px,
    1 % noise) and the true motion; tests copy what they need into their own folder."""
    root = tmp_path_factory.mktemp("cli-data")
    case = synth.make_case(synth.sample_image("edges", 128), "inplane", 9, 0.01, rng=3)
    write_image(root / "sharp.png", case.sharp)
    write_image(root / "blurred.png", case.blurred)
    case.motion.save(root / "truth.json")
    return root


@pytest.fixture
def work(tmp_path, data) -> Path:
    """The test's own folder holding copies of the data files."""
    for name in ("sharp.png", "blurred.png", "truth.json"):
        shutil.copy(data / name, tmp_path / name)
    return tmp_path


@pytest.fixture
def cd(work, monkeypatch) -> Path:
    monkeypatch.chdir(work)
    return work


def listing(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir()}


def run(argv, capsys):
    """``main(argv)`` in-process: (exit status, stdout, stderr lines)."""
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, [line for line in err.splitlines() if line.strip()]


def as_unit(image) -> np.ndarray:
    return image.astype(np.float64) / np.iinfo(image.dtype).max


# --------------------------------------------------------------------------------------
# help, version, usage
# --------------------------------------------------------------------------------------

@pytest.mark.parametrize("command", SUBCOMMANDS)
def test_every_subcommand_has_help(command, capsys):
    status, out, err = run([command, "--help"], capsys)
    assert status == 0 and not err
    assert out.startswith(f"usage: edgecme {command}")


def test_version_and_top_level_help(capsys):
    status, out, _ = run(["--version"], capsys)
    assert status == 0 and out.strip() == "edgecme 0.1.0 (napari-edgecme)"
    status, out, _ = run(["--help"], capsys)
    assert status == 0
    assert all(command in out for command in SUBCOMMANDS)


def test_no_subcommand_is_a_one_line_usage_error(capsys):
    status, _, err = run([], capsys)
    assert status == 2 and len(err) == 1 and err[0].startswith("edgecme: error: missing COMMAND")


# --------------------------------------------------------------------------------------
# each subcommand on a small input
# --------------------------------------------------------------------------------------

def test_synth_writes_a_blurred_image_and_its_true_motion(cd, capsys):
    status, _, err = run(["synth", "sharp.png", "-o", "b.png", "--save-motion", "t.json",
                          "--model", "rotation", "--extent", "11", "--seed", "5"], capsys)
    assert status == 0, err
    truth = CameraMotion.load("t.json")
    blurred = read_image("b.png")
    assert blurred.shape == (128, 128) and blurred.dtype == np.uint8
    assert truth.model == "rotation" and truth.image_shape == (128, 128)
    sharp = as_unit(read_image("sharp.png"))
    assert aligned_psnr(as_unit(blurred), sharp) < 30  # it is blurred
    # the same seed gives identical files, another seed another shake
    run(["synth", "sharp.png", "-o", "b2.png", "--save-motion", "t2.json", "--model",
         "rotation", "--extent", "11", "--seed", "5"], capsys)
    assert Path("b.png").read_bytes() == Path("b2.png").read_bytes()
    assert Path("t.json").read_bytes() == Path("t2.json").read_bytes()
    run(["synth", "sharp.png", "-o", "b3.png", "--save-motion", "t3.json", "--model",
         "rotation", "--extent", "11", "--seed", "6"], capsys)
    assert CameraMotion.load("t3.json") != truth


def test_synth_and_psf_report_one_blur_extent(cd, capsys):
    """Issue 15, item 10: the extent synth is asked for is the extent every command reports
    (the longest side of the local PSFs' support), not a radius of it."""
    import re

    from napari_edgecme.cli._options import _describe

    extent = re.compile(r"blur extent (\d+\.\d) px \(longest side of the PSFs")
    status, _, err = run(["synth", "sharp.png", "-o", "b.png", "--save-motion", "t.json",
                          "--model", "rotation", "--extent", "17", "--seed", "2"], capsys)
    assert status == 0, err
    (said,) = extent.findall(err[-1])
    assert err[-1].startswith("edgecme: shook sharp.png with a rotation shake of blur extent ")
    truth = CameraMotion.load("t.json")
    assert abs(float(said) - 17) <= 0.1 and abs(truth.blur_extent() - 17) <= 0.1
    assert truth.max_displacement() < 16  # the old radius would have read otherwise
    assert extent.findall(_describe(truth)) == [said]
    for argv in (["psf", "t.json", "-o", "f.png"], ["psf", "t.json", "-o", "r.png", "--raw"]):
        status, _, err = run(argv, capsys)
        assert status == 0, err
        assert extent.findall(err[-1]) == [said]


def test_synth_takes_the_focal_length_from_exif(cd, capsys):
    from PIL import Image

    exif = Image.Exif()
    exif[0xA405] = 28  # FocalLengthIn35mmFilm
    Image.fromarray(read_image("sharp.png")).save("photo.jpg", exif=exif, quality=95)
    status, _, err = run(["synth", "photo.jpg", "-o", "b.png", "--save-motion", "t.json",
                          "--extent", "7"], capsys)
    assert status == 0, err
    assert CameraMotion.load("t.json").intrinsics.focal_px == pytest.approx(28 / 36 * 128)
    status, _, _ = run(["synth", "photo.jpg", "-o", "b.png", "--save-motion", "t.json",
                        "--extent", "7", "--focal-px", "500"], capsys)
    assert CameraMotion.load("t.json").intrinsics.focal_px == pytest.approx(500)


def test_estimate_writes_a_loadable_motion_for_the_image(cd, capsys):
    status, _, err = run(["estimate", "blurred.png", "-o", "m.json", "--method", "xu",
                          "--model", "inplane", "--max-blur", "13", *FAST], capsys)
    assert status == 0, err
    motion, estimated_by, _ = CameraMotion.load_estimate("m.json")
    assert motion.model == "inplane" and motion.image_shape == (128, 128)
    assert motion.n_poses >= 2
    assert estimated_by == "xu"
    assert err[-1].startswith("edgecme: inplane motion,") and "wrote m.json" in err[-1]


def test_estimate_is_deterministic(cd, capsys):
    argv = ["blurred.png", "--method", "xu", "--model", "translation", "--max-blur", "11",
            "--n-iter", "1"]
    assert run(["estimate", *argv, "-o", "a.json"], capsys)[0] == 0
    assert run(["estimate", *argv, "-o", "b.json"], capsys)[0] == 0
    assert Path("a.json").read_bytes() == Path("b.json").read_bytes()


@pytest.mark.parametrize("method", ["ep", "xu+ep"])
def test_edge_profile_methods_estimate_from_an_edge_rich_image(method, tmp_path, capsys):
    case = synth.make_case(synth.sample_image("edges", 128), "inplane", 5, 0.01, rng=3)
    write_image(tmp_path / "b.png", case.blurred)
    status, _, err = run(["estimate", tmp_path / "b.png", "-o", tmp_path / "m.json",
                          "--method", method, "--model", "inplane", "--max-blur", "8", *FAST],
                         capsys)
    assert status == 0, err
    assert "edge profiles" in err[-1]
    assert CameraMotion.load(tmp_path / "m.json").model == "inplane"


def test_deblur_improves_aligned_psnr_and_saves_the_motion(cd, capsys):
    status, _, err = run(["deblur", "blurred.png", "-o", "restored.png", "--method", "xu",
                          "--model", "inplane", "--max-blur", "13", "--n-iter", "3",
                          "--save-motion", "m.json"], capsys)
    assert status == 0, err
    sharp = as_unit(read_image("sharp.png"))
    before = aligned_psnr(as_unit(read_image("blurred.png")), sharp)
    after = aligned_psnr(as_unit(read_image("restored.png")), sharp)
    print(f"deblur: {before:.2f} -> {after:.2f} dB")
    assert after >= before + 2.0
    motion, estimated_by, _ = CameraMotion.load_estimate("m.json")
    assert motion.image_shape == (128, 128) and estimated_by == "xu"


def test_deblur_falls_back_to_xu_with_one_warning_line_when_edges_are_missing(tmp_path,
                                                                              capsys):
    from scipy import ndimage

    texture = ndimage.gaussian_filter(np.random.default_rng(0).random((96, 96)), 3)
    texture = (texture - texture.min()) / np.ptp(texture)
    write_image(tmp_path / "t.png", texture)
    status, _, err = run(["deblur", tmp_path / "t.png", "-o", tmp_path / "r.png", "--model",
                          "translation", "--max-blur", "9", "--n-iter", "1"], capsys)
    assert status == 0, err
    warning = [line for line in err if line.startswith("edgecme: warning:")]
    assert len(warning) == 1 and "falling back to method 'xu'" in warning[0]
    assert "(xu+ep fell back to xu," in err[-1]
    assert read_image(tmp_path / "r.png").shape == (96, 96)


@pytest.mark.parametrize("method", ["hyperlaplacian", "rl", "wiener"])
def test_deconvolve_with_the_true_motion_improves_psnr(method, cd, capsys):
    status, _, err = run(["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                          "r.tif", "--deconvolution", method], capsys)
    assert status == 0, err
    restored = read_image("r.tif")
    assert restored.dtype == np.float32 and restored.shape == (128, 128)  # TIFF keeps float32
    sharp = as_unit(read_image("sharp.png"))
    gain = aligned_psnr(restored, sharp) - aligned_psnr(as_unit(read_image("blurred.png")), sharp)
    print(f"{method}: {gain:+.2f} dB")
    assert gain >= 1.5


def test_deconvolve_keeps_16_bit_and_rgb(cd, capsys):
    gray8 = read_image("blurred.png")
    write_image("b16.png", gray8.astype(np.uint16) * 257)
    assert run(["deconvolve", "b16.png", "--motion", "truth.json", "-o", "r16.png"],
               capsys)[0] == 0
    assert read_image("r16.png").dtype == np.uint16
    write_image("rgb.png", np.stack([gray8, gray8[::-1], gray8[:, ::-1]], -1))
    assert run(["deconvolve", "rgb.png", "--motion", "truth.json", "-o", "r.png",
                "--deconvolution", "wiener"], capsys)[0] == 0
    restored = read_image("r.png")
    assert restored.shape == (128, 128, 3) and restored.dtype == np.uint8


def test_the_summary_says_how_an_rgb_photo_was_deconvolved(cd, capsys):
    gray8 = read_image("blurred.png")
    write_image("photo.png", np.stack([gray8, gray8[::-1], gray8[:, ::-1]], -1))
    said = {}
    for color in ("opponent", "rgb"):
        status, _, err = run(["deconvolve", "photo.png", "--motion", "truth.json", "-o",
                                f"{color}.png", "--color", color], capsys)
        assert status == 0, err
        said[color] = err[-1]
    assert "(hyperlaplacian, luminance + chroma, " in said["opponent"]
    assert "(hyperlaplacian, R, G, B each, " in said["rgb"]
    assert Path("opponent.png").read_bytes() != Path("rgb.png").read_bytes()
    status, _, err = run(["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                          "gray.png"], capsys)
    assert status == 0 and "chroma" not in err[-1] and "each" not in err[-1]


def test_lam_is_passed_as_lambda_f_so_our_own_cli_raises_no_deprecation(cd, capsys):
    import argparse
    import warnings

    from napari_edgecme.cli._options import deconvolution_params
    from napari_edgecme.core.deconv import noise_lambda_f
    from napari_edgecme.core.io import read_image

    args = argparse.Namespace(lam=3000.0, iterations=None, nsr=None)
    assert deconvolution_params(args, "hyperlaplacian") == {"lambda_f": 2.0 / 3000.0}
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        # the data weight the default sets from this photo's noise, given by hand
        photo_lam = 2.0 / noise_lambda_f(read_image("blurred.png"))
        status, _, err = run(["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                              "lam.png", "--lam", repr(photo_lam)], capsys)
        assert status == 0, err
        status, _, err = run(["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                              "default.png"], capsys)
        assert status == 0, err
    assert Path("lam.png").read_bytes() == Path("default.png").read_bytes()


def test_deconvolve_restores_an_epalone_motion_file_as_deblur_restores_epalone(tmp_path,
                                                                               capsys):
    """A motion file that names EpAlone as its estimator is restored with the prior
    ``deblur`` gives an EpAlone estimate of the misfit the file records: on a clean photo
    the reference weight (instead of the lower one its noise sets) at a misfit of 4%, four
    times it at 10%, eight times it when the file records none. The same motion without
    the name gets the noise's weight, as a ground truth does."""
    from napari_edgecme.core.deconv import REFERENCE_LAMBDA_F, noise_lambda_f

    case = synth.make_case(synth.sample_image("edges", 96), "inplane", 7, 0.002, rng=1)
    write_image(tmp_path / "b.png", case.blurred)
    assert noise_lambda_f(read_image(tmp_path / "b.png")) < REFERENCE_LAMBDA_F  # clean
    for name, misfit in [("ep4", 0.04), ("ep10", 0.10), ("ep", None)]:
        case.motion.save(tmp_path / f"{name}.json", estimated_by="ep", profile_misfit=misfit)
    case.motion.save(tmp_path / "plain.json")
    outputs = {}
    for name, motion, extra in [("ep4", "ep4", []), ("ep10", "ep10", []), ("ep", "ep", []),
                                ("plain", "plain", []),
                                ("reference", "plain", ["--lam", "1500"]),
                                ("4x", "plain", ["--lam", "375"]),
                                ("8x", "plain", ["--lam", "187.5"])]:
        status, _, err = run(["deconvolve", tmp_path / "b.png", "--motion",
                              tmp_path / f"{motion}.json", "-o", tmp_path / f"{name}.png",
                              *extra], capsys)
        assert status == 0, err
        outputs[name] = (tmp_path / f"{name}.png").read_bytes()
        if name.startswith("ep"):  # and the summary says why the output is softer
            assert "estimated by ep, EpAlone prior " + {
                "ep4": "1.0x (profile misfit 4%)", "ep10": "4.0x (profile misfit 10%)",
                "ep": "8.0x (profile misfit not recorded)"}[name] in err[-1]
    assert outputs["ep4"] == outputs["reference"]
    assert outputs["ep10"] == outputs["4x"]
    assert outputs["ep"] == outputs["8x"]
    assert outputs["ep4"] != outputs["plain"]


def test_batch_lam_reaches_each_photos_deconvolution_as_lambda_f():
    import warnings

    from napari_edgecme.batch._run import batch_options
    from napari_edgecme.cli import build_parser
    from napari_edgecme.cli._options import deconvolution_params

    args = build_parser().parse_args(["batch", "x.png", "-o", "out", "--lam", "3000"])
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # our own CLI never warns
        handed = deconvolution_params(args, "hyperlaplacian")
        assert handed == {"lambda_f": 2.0 / 3000.0}  # what deblur_many is handed
        options = batch_options("xu", "inplane", None, None, "hyperlaplacian", handed, {})
        assert deconvolution_params(options, "hyperlaplacian") == {"lambda_f": 2.0 / 3000.0}


@pytest.mark.parametrize("command", ["deblur", "batch", "deconvolve"])
def test_colour_options_reach_the_deconvolution_of_every_command_that_deconvolves(command):
    from napari_edgecme.batch._run import batch_options
    from napari_edgecme.cli import build_parser
    from napari_edgecme.cli._options import deconvolution_params

    required = {"deblur": ["x.png", "-o", "o.png"], "batch": ["x.png", "-o", "out"],
                "deconvolve": ["x.png", "--motion", "m.json", "-o", "o.png"]}[command]
    args = build_parser().parse_args([command, *required, "--color", "opponent",
                                      "--chroma", "half"])
    handed = deconvolution_params(args, "hyperlaplacian")
    assert handed == {"color": "opponent", "chroma": "half"}
    # a batch hands them on to each photo's deconvolution unchanged
    options = batch_options("xu", "inplane", None, None, "hyperlaplacian", handed, {})
    assert deconvolution_params(options, "hyperlaplacian") == handed


def test_a_batch_refuses_deconvolution_parameters_it_cannot_hand_on():
    from napari_edgecme.batch._run import batch_options

    with pytest.raises(ValueError, match="'alpha' is not an option of a batch"):
        batch_options("xu", "inplane", None, None, "hyperlaplacian", {"alpha": 0.5}, {})


@pytest.mark.parametrize("command", ["estimate", "deblur", "batch", "deconvolve"])
def test_gamma_is_an_option_of_every_command_that_reads_a_photo(command):
    from napari_edgecme.cli import build_parser

    parser = build_parser()
    required = {"estimate": ["x.png", "-o", "m.json"], "deblur": ["x.png", "-o", "o.png"],
                "batch": ["x.png", "-o", "out"],
                "deconvolve": ["x.png", "--motion", "m.json", "-o", "o.png"]}[command]
    assert parser.parse_args([command, *required]).gamma == "auto"
    for value in ("linear", "srgb", "2.2"):
        assert parser.parse_args([command, *required, "--gamma", value]).gamma == value


def test_deconvolve_names_the_deconvolution_as_deblur_does_and_keeps_the_old_name(cd, capsys):
    """One name for one thing: '--method' is the estimator in 'deblur', so the
    deconvolution is '--deconvolution' in both; the old spelling works for one release."""
    assert run(["deconvolve", "blurred.png", "--motion", "truth.json", "-o", "new.tif",
                "--deconvolution", "wiener"], capsys)[0] == 0
    status, _, err = run(["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                          "old.tif", "--method", "wiener"], capsys)
    assert status == 0
    assert err[0].startswith("edgecme: warning: 'deconvolve --method' is now "
                             "'--deconvolution'")
    assert "(wiener," in err[-1]
    np.testing.assert_array_equal(read_image("old.tif"), read_image("new.tif"))
    status, _, err = run(["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                          "x.tif", "--method", "rl", "--deconvolution", "wiener"], capsys)
    assert status == 2 and "disagree" in err[-1] and not os.path.exists("x.tif")
    for command in ("deblur", "deconvolve"):
        _, out, _ = run([command, "--help"], capsys)
        assert "--deconvolution" in out


def test_rgba_input_drops_the_alpha_channel_with_a_warning(cd, capsys):
    gray8 = read_image("blurred.png")
    alpha = np.full_like(gray8, 255)
    alpha[:10] = 0
    write_image("rgba.png", np.stack([gray8, gray8, gray8, alpha], -1))
    status, _, err = run(["deconvolve", "rgba.png", "--motion", "truth.json", "-o", "r.png",
                          "--deconvolution", "wiener"], capsys)
    assert status == 0
    assert err[0] == "edgecme: warning: rgba.png: the alpha channel is ignored"
    assert read_image("r.png").shape == (128, 128, 3)


def test_profiles_writes_a_profile_file_and_a_plot(cd, capsys):
    status, _, err = run(["profiles", "blurred.png", "-o", "p.json", "--max-blur", "13",
                          "--plot", "p.png"], capsys)
    assert status == 0, err
    profiles = EdgeProfiles.load("p.json")
    assert len(profiles) > 0 and profiles.image_shape == (128, 128)
    assert f"{len(profiles)} edge profiles" in err[-2]
    # what the set can constrain, in the summary: its confidence and coverage
    assert f"median confidence {np.median(profiles.confidence):.2f}" in err[-1]
    assert profiles.coverage_summary() in err[-1] and "/8 orientations" in err[-1]
    assert read_image("p.png").ndim == 3  # a matplotlib figure


def test_profiles_without_max_blur_measure_it_as_deblur_does(cd, capsys):
    """Issue 14: ``profiles`` measured nothing (4% of the side); now it measures as the
    estimator does -- the same numbers for the same photo and seed -- and says so."""
    from napari_edgecme.core._validation import as_rng
    from napari_edgecme.core.blur_size import max_blur_for, measure_blur_extent

    status, _, err = run(["profiles", "blurred.png", "-o", "p.json"], capsys)
    assert status == 0, err
    profiles = EdgeProfiles.load("p.json")
    image = read_image("blurred.png")
    size = measure_blur_extent(image, rng=as_rng(0).spawn(1)[0])
    assert profiles.max_blur == pytest.approx(max_blur_for(size, image.shape))
    note = f"max blur {profiles.max_blur:.0f} px (measured: {size.message})"
    assert err[-2].startswith(f"edgecme: {len(profiles)} edge profiles ({note}, ")
    # measured here: blur about 16 px (true 9 px: short blurs read long on this 128 px
    # scene, the sharp edges' own width adds to each transition), max blur 32 px; the
    # engine's own accuracy claims are in tests/core/test_blur_size.py
    truth = CameraMotion.load("truth.json").blur_extent()
    assert 1.3 * truth <= profiles.max_blur <= 4.0 * truth
    assert size.source == "edge profiles"
    # estimate measures the same: one measurement, two commands
    status, _, err = run(["estimate", "blurred.png", "-o", "m.json", "--method", "ep",
                          "--model", "inplane"], capsys)
    assert status == 0, err
    assert note in err[-1]
    # a given --max-blur is used as given, and not called measured
    status, _, err = run(["profiles", "blurred.png", "-o", "p.json", "--max-blur", "13"],
                         capsys)
    assert "(max blur 13 px, " in err[-2] and "measured" not in err[-2]


def test_a_plot_that_cannot_be_drawn_never_costs_the_profiles(cd, capsys, monkeypatch):
    def broken(self, *args, **kwargs):
        raise RuntimeError("no display backend\nsecond line")

    monkeypatch.setattr(EdgeProfiles, "figure", broken)
    status, _, err = run(["profiles", "blurred.png", "-o", "p.json", "--max-blur", "13",
                          "--plot", "p.png"], capsys)
    assert status == 0, err
    assert len(EdgeProfiles.load("p.json")) > 0 and not os.path.exists("p.png")
    assert any(line == "edgecme: warning: could not draw --plot p.png: no display backend; "
               "the profiles were written to p.json" for line in err)
    assert "wrote p.json" in " ".join(err) and "p.png" not in err[-2]


def test_matplotlib_is_a_dependency_so_plots_are_expected():
    from importlib.metadata import requires

    assert any(r.split(";")[0].strip().startswith("matplotlib")
               and "extra" not in r for r in requires("napari-edgecme"))


def test_profiles_on_an_image_without_edges_warns_and_writes_an_empty_file(tmp_path, capsys):
    write_image(tmp_path / "flat.png", np.full((64, 64), 0.5))
    status, _, err = run(["profiles", tmp_path / "flat.png", "-o", tmp_path / "p.json",
                          "--max-blur", "9"], capsys)
    assert status == 0
    assert err[0].startswith("edgecme: warning: no usable edge profiles")
    profiles = EdgeProfiles.load(tmp_path / "p.json")
    assert len(profiles) == 0 and profiles.reason


def test_estimate_uses_profiles_from_a_file(cd, capsys):
    assert run(["profiles", "blurred.png", "-o", "p.json", "--max-blur", "13"], capsys)[0] == 0
    n = len(EdgeProfiles.load("p.json"))
    status, _, err = run(["estimate", "blurred.png", "-o", "m.json", "--method", "xu+ep",
                          "--model", "inplane", "--max-blur", "13", "--profiles", "p.json",
                          *FAST], capsys)
    assert status == 0, err
    assert ((f"{n} edge profiles in " in err[-1] and "/8 orientations" in err[-1])
            or "falling back" in " ".join(err))


def test_psf_writes_a_labelled_figure_by_default(cd, capsys):
    from PIL import Image

    from napari_edgecme.cli._options import _describe

    status, _, err = run(["psf", "truth.json", "-o", "field.png", "--grid", "3x4"], capsys)
    assert status == 0, err
    motion = CameraMotion.load("truth.json")
    assert err[-1].startswith(f"edgecme: PSF field of a {_describe(motion)} on a 3x4 grid, "
                              "each PSF drawn ")
    assert "x enlarged, axes in image px (1000x" in err[-1]
    assert err[-1].endswith("px figure); wrote field.png")
    with Image.open("field.png") as png:
        assert png.format == "PNG" and png.width == 1000
        size = png.size
    # the figure, not the raw field: larger than the 128x128 motion image, with a white
    # margin (title, axis labels, scale bar) around the gray tiles of the PSFs
    figure = read_image("field.png")
    assert figure.shape[:2] == (size[1], size[0]) and figure.ndim == 3
    assert (figure[:5, :, :3] == 255).all()  # white margin above the title
    top = figure[:60, :, :3]
    assert (top < 128).any()  # the title's dark text
    bottom = figure[-30:, :, :3]
    assert (bottom < 64).sum() > 40  # the scale bar (3 px thick, black)


def test_psf_figure_default_grid_has_square_cells(cd, capsys):
    from napari_edgecme.core.psf_view import square_grid

    status, _, err = run(["psf", "truth.json", "-o", "field.png"], capsys)
    assert status == 0, err
    rows, cols = square_grid((128, 128))
    assert f" on a {rows}x{cols} grid, " in err[-1]


def test_psf_raw_writes_the_raw_field_exactly(cd, capsys):
    status, _, err = run(["psf", "truth.json", "-o", "field.png", "--grid", "3x4", "--raw"],
                         capsys)
    assert status == 0, err
    assert err[-1].endswith("on a 3x4 grid (128x128 px; raw: each PSF at its point, scaled "
                            "to peak 1); wrote field.png")
    field = read_image("field.png")
    assert field.shape == (128, 128) and field.max() == 255
    expected = CameraMotion.load("truth.json").psf_field(grid=(3, 4))
    write_image("expected.png", expected)
    assert np.array_equal(field, read_image("expected.png"))
    # 12 PSFs, one per grid cell: every cell holds some of the drawing
    for r in range(3):
        for c in range(4):
            cell = field[r * 128 // 3:(r + 1) * 128 // 3, c * 32:(c + 1) * 32]
            assert cell.max() > 0
    # another format than PNG is the raw field too
    status, _, err = run(["psf", "truth.json", "-o", "field.tif", "--grid", "3x4"], capsys)
    assert status == 0, err
    assert "raw: each PSF at its point" in err[-1]
    assert np.array_equal(read_image("field.tif"), expected)


def test_psf_without_matplotlib_warns_once_and_writes_the_raw_field(cd, capsys,
                                                                    monkeypatch):
    from napari_edgecme.core import psf_view

    def no_matplotlib(*args, **kwargs):
        raise ImportError("the PSF-field figure needs matplotlib (pip install matplotlib); "
                          "without it, CameraMotion.psf_field(grid) gives the raw field")

    monkeypatch.setattr(psf_view, "save_psf_field_figure", no_matplotlib)
    status, _, err = run(["psf", "truth.json", "-o", "field.png", "--grid", "3x4"], capsys)
    assert status == 0, err
    warnings = [line for line in err if "matplotlib" in line]
    assert len(warnings) == 1
    assert warnings[0].endswith("; writing the raw PSF field instead")
    assert "raw: each PSF at its point" in err[-1]
    expected = CameraMotion.load("truth.json").psf_field(grid=(3, 4))
    write_image("expected.png", expected)
    assert np.array_equal(read_image("field.png"), read_image("expected.png"))
    assert listing(cd) >= {"field.png"} and not [n for n in listing(cd) if "tmp" in n]


# --------------------------------------------------------------------------------------
# bad input: one line, exit status 2, nothing written
# --------------------------------------------------------------------------------------

def _write_stack(path):
    import tifffile

    tifffile.imwrite(path, np.zeros((3, 32, 32), np.float32), photometric="minisblack")


def _write_nan(path):
    import tifffile

    img = np.full((64, 64), 0.5, np.float32)
    img[3, 3] = np.nan
    tifffile.imwrite(path, img)


def _write_counts(path):
    import tifffile

    tifffile.imwrite(path, np.full((64, 64), 4095.0, np.float32))  # raw counts, not [0, 1]


BAD = {
    "missing image": (["deblur", "nope.png", "-o", "out.png"], "image not found: nope.png"),
    "not an image": (["deblur", "text.png", "-o", "out.png"], "cannot read image text.png"),
    "empty file": (["deconvolve", "empty.png", "--motion", "truth.json", "-o", "out.png"],
                   "cannot read image empty.png"),
    "unknown method": (["deblur", "blurred.png", "-o", "out.png", "--method", "lucy"],
                       "argument --method: invalid choice: 'lucy'"),
    "unknown model": (["estimate", "blurred.png", "-o", "out.json", "--model", "affine"],
                      "argument --model: invalid choice: 'affine'"),
    "unknown deconvolution": (["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                               "out.png", "--method", "fft"], "invalid choice: 'fft'"),
    "malformed motion": (["deconvolve", "blurred.png", "--motion", "broken.json", "-o",
                          "out.png"], "is not valid JSON"),
    "motion of another format": (["psf", "other.json", "-o", "out.png"],
                                 "not an edgecme motion file"),
    "motion for another aspect": (["deconvolve", "wide.png", "--motion", "truth.json", "-o",
                                   "out.png"], "motion does not fit the image"),
    "missing motion": (["deconvolve", "blurred.png", "--motion", "nope.json", "-o", "out.png"],
                       "motion file not found: nope.json"),
    "output folder missing": (["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                               "no/such/folder/out.png"], "output folder does not exist"),
    "second output folder missing": (["deblur", "blurred.png", "-o", "out.png",
                                      "--save-motion", "no/m.json"],
                                     "output folder does not exist"),
    "unsupported output format": (["deconvolve", "blurred.png", "--motion", "truth.json",
                                   "-o", "out.xyz"], "unsupported image format '.xyz'"),
    "output overwrites input": (["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                                 "blurred.png"], "would overwrite IMAGE"),
    "output is a folder": (["estimate", "blurred.png", "-o", "."], "is a directory"),
    "negative max blur": (["deblur", "blurred.png", "-o", "out.png", "--max-blur", "-4"],
                          "argument --max-blur: must be > 0"),
    "max blur too large": (["estimate", "blurred.png", "-o", "out.json", "--max-blur", "90"],
                           "max_blur must be less than half the smaller image side"),
    "image too small for the default": (["estimate", "tiny.png", "-o", "out.json"],
                                        "too small for the default --max-blur"),
    "profiles of an image too small for the default": (
        ["profiles", "tiny.png", "-o", "p.json"], "too small for the default --max-blur"),
    "stack": (["deblur", "stack.tif", "-o", "out.png"], "expected a gray or RGB image"),
    "NaN pixels": (["deconvolve", "nan.tif", "--motion", "nan-truth.json", "-o", "out.tif"],
                   "non-finite values"),
    "float image not scaled to [0, 1]": (["deconvolve", "counts.tif", "--motion",
                                          "nan-truth.json", "-o", "out.tif"],
                                         "must be scaled to [0, 1]"),
    "bad grid": (["psf", "truth.json", "-o", "out.png", "--grid", "3by3"],
                 "expected ROWSxCOLS"),
    "option of another method": (["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                                  "out.png", "--iterations", "5"],
                                 "--iterations does not apply to the 'hyperlaplacian'"),
    "colour option of another method": (["deconvolve", "blurred.png", "--motion", "truth.json",
                                         "-o", "out.png", "--deconvolution", "wiener", "--color",
                                         "opponent"],
                                        "--color does not apply to the 'wiener'"),
    "half chroma of RGB channels": (["deconvolve", "blurred.png", "--motion", "truth.json",
                                     "-o", "out.png", "--color", "rgb", "--chroma", "half"],
                                    "chroma='half' needs color='opponent'"),
    "EpAlone without edges": (["estimate", "flat.png", "-o", "out.json", "--method", "ep",
                               "--max-blur", "9"], "EpAlone needs at least"),
    "missing required option": (["synth", "sharp.png", "-o", "out.png"],
                                "the following arguments are required: --save-motion"),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_bad_input_is_one_line_exit_2_and_writes_nothing(case, cd, capsys):
    Path("text.png").write_text("not a png\n")
    Path("empty.png").write_bytes(b"")
    Path("broken.json").write_text('{"format": "edgecme-motion", "version": 1,')
    Path("other.json").write_text(json.dumps({"format": "something-else"}))
    write_image("wide.png", np.zeros((64, 128)))
    write_image("tiny.png", np.zeros((20, 20)))
    write_image("flat.png", np.full((64, 64), 0.4))
    _write_stack("stack.tif")
    _write_nan("nan.tif")
    _write_counts("counts.tif")
    from napari_edgecme.core.camera import Intrinsics

    CameraMotion.identity("translation", Intrinsics.from_image_shape((64, 64))).save(
        "nan-truth.json")
    before = listing(cd)
    argv, expected = BAD[case]
    status, out, err = run(argv, capsys)
    assert status == 2
    assert len(err) == 1, err
    assert err[0].startswith("edgecme: error: ") and expected in err[0], err[0]
    assert "Traceback" not in err[0] and not out
    assert listing(cd) == before  # nothing written, no temporary file left


def test_debug_shows_the_traceback(cd, capsys):
    status = main(["--debug", "deblur", "nope.png", "-o", "out.png"])
    err = capsys.readouterr().err
    assert status == 2
    assert "Traceback" in err and err.rstrip().endswith("image not found: nope.png")


def test_global_options_work_after_the_subcommand_too(cd, capsys):
    status, _, err = run(["deblur", "nope.png", "-o", "out.png", "--debug"], capsys)
    assert status == 2 and any("Traceback" in line for line in err)


# --------------------------------------------------------------------------------------
# interruption, internal errors
# --------------------------------------------------------------------------------------

def _interrupted(*args, **kwargs):
    yield Progress("deconvolve", 1, 10, "working")
    raise KeyboardInterrupt


def test_ctrl_c_exits_130_with_one_line_and_no_output(cd, capsys, monkeypatch):
    import napari_edgecme.core.deconv as deconv

    monkeypatch.setattr(deconv, "iter_deconvolve", _interrupted)
    before = listing(cd)
    status, _, err = run(["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                          "out.png"], capsys)
    assert status == 130
    assert err == ["edgecme: error: interrupted; no output written"]
    assert listing(cd) == before


def test_ctrl_c_after_estimation_leaves_neither_output(cd, capsys, monkeypatch):
    import napari_edgecme.core.deconv as deconv

    monkeypatch.setattr(deconv, "iter_deconvolve", _interrupted)
    before = listing(cd)
    status, _, _ = run(["deblur", "blurred.png", "-o", "out.png", "--save-motion", "m.json",
                        "--method", "xu", "--model", "translation", "--max-blur", "9",
                        "--n-iter", "1"], capsys)
    assert status == 130 and listing(cd) == before


def test_an_internal_error_is_exit_1_and_one_line(cd, capsys, monkeypatch):
    import napari_edgecme.core.deconv as deconv

    def broken(*args, **kwargs):
        raise RuntimeError("something broke\nsecond line")
        yield  # pragma: no cover

    monkeypatch.setattr(deconv, "iter_deconvolve", broken)
    status, _, err = run(["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                          "out.png"], capsys)
    assert status == 1 and len(err) == 1
    assert err[0].startswith("edgecme: error: internal error: RuntimeError: something broke")


def test_a_failed_write_leaves_no_file(cd, capsys, monkeypatch):
    import napari_edgecme.core.io as cio

    real = cio.write_image

    def failing(path, *args, **kwargs):
        Path(path).write_bytes(b"partial")
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(cio, "write_image", failing)
    before = listing(cd)
    status, _, err = run(["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                          "out.png", "--deconvolution", "wiener"], capsys)
    monkeypatch.setattr(cio, "write_image", real)
    assert status == 2 and len(err) == 1 and "No space left on device" in err[0]
    assert listing(cd) == before


# --------------------------------------------------------------------------------------
# progress
# --------------------------------------------------------------------------------------

class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_progress_bar_shows_on_a_terminal_and_quiet_silences_it(cd, monkeypatch):
    argv = ["deconvolve", "blurred.png", "--motion", "truth.json", "-o", "out.png"]
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    assert main(argv) == 0
    text = terminal.getvalue()
    assert "\rdeconvolve [" in text and "100%" in text
    assert text.splitlines()[-1].startswith("edgecme: deconvolved blurred.png")

    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    assert main(["--quiet", *argv]) == 0
    assert terminal.getvalue() == ""


def test_no_progress_bar_when_stderr_is_not_a_terminal(cd, capsys):
    status, _, err = run(["deconvolve", "blurred.png", "--motion", "truth.json", "-o",
                          "out.png"], capsys)
    assert status == 0 and len(err) == 1 and "\r" not in err[0]


def test_progress_bar_draws_throttles_and_keeps_one_line_per_stage():
    now = [0.0]
    stream = io.StringIO()
    bar = ProgressBar(stream, width=72, min_interval=0.5, clock=lambda: now[0])
    bar(Progress("estimate", 0, 4, "preparing"))
    now[0] = 0.1
    bar(Progress("estimate", 1, 4, "skipped: too soon"))
    now[0] = 1.0
    bar(Progress("estimate", 2, 4, "scale 1/2"))
    now[0] = 1.1
    bar(Progress("estimate", 4, 4, "done"))  # 100 % is always drawn
    now[0] = 61.0
    bar(Progress("deconvolve", 1, 2, "half way"))
    bar.finish()
    lines = stream.getvalue().split("\n")
    assert len(lines) == 3 and lines[-1] == ""
    frames = lines[0].split("\r")[1:]
    assert [f.split("]")[1].split()[0] for f in frames] == ["0%", "50%", "100%", "100%"]
    assert "skipped" not in stream.getvalue()
    assert frames[1].startswith("estimate   [##########----------]  50%  0:01  scale 1/2")
    assert lines[1].split("\r")[-1].startswith("deconvolve [##########----------]  50%  0:00")
    assert all(len(f) <= 71 for f in frames)


# --------------------------------------------------------------------------------------
# entry points (subprocesses)
# --------------------------------------------------------------------------------------

def _console_script() -> str:
    script = Path(sys.executable).with_name("edgecme")
    return str(script) if script.exists() else shutil.which("edgecme")


def test_console_script_runs_and_exits_2_on_bad_input(work):
    script = _console_script()
    assert script, "the edgecme console script is not installed"
    res = subprocess.run([script, "psf", "truth.json", "-o", "field.png", "--raw"], cwd=work,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert read_image(work / "field.png").shape == (128, 128)
    res = subprocess.run([script, "deblur", "missing.png", "-o", "out.png"], cwd=work,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.splitlines() == ["edgecme: error: image not found: missing.png"]


def test_python_dash_m_runs_the_cli(work):
    res = subprocess.run([sys.executable, "-m", "napari_edgecme", "deconvolve", "blurred.png",
                          "--motion", "truth.json", "-o", "r.png", "--deconvolution", "wiener",
                          "--quiet"], cwd=work, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    assert read_image(work / "r.png").shape == (128, 128)


def test_the_cli_demo_and_bench_load_no_qt():
    code = ("import sys, napari_edgecme.cli, napari_edgecme._demo, napari_edgecme._bench;"
            "bad = [m for m in sys.modules if m.split('.')[0] in ('qtpy', 'PyQt5', 'PyQt6', "
            "'PySide2', 'PySide6', 'napari', 'magicgui', 'vispy')];"
            "print(bad); sys.exit(1 if bad else 0)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr


def test_deblur_of_a_sharp_photo_says_no_blur_found_and_writes_it_unchanged(cd, capsys):
    status, _, err = run(["deblur", "sharp.png", "-o", "out.png", "--method", "xu", "--model",
                          "inplane", "--max-blur", "11", *FAST], capsys)
    assert status == 0, err
    assert any(line.startswith("edgecme: warning: no blur found") for line in err)
    assert "no blur found" in err[-1] and "not deconvolved" in err[-1]
    np.testing.assert_array_equal(read_image("out.png"), read_image("sharp.png"))


def test_bench_data_applies_to_the_suites_only(cd, capsys):
    status, _, err = run(["bench", "--data", "somewhere"], capsys)
    assert status == 2 and len(err) == 1 and "--data applies to the lai, levin and real" in err[0]
    status, _, err = run(["bench", "--suite", "lai", "--data", "missing-folder"], capsys)
    assert status == 2 and len(err) == 1 and "no data for suite 'lai'" in err[0]


def test_the_summary_says_which_start_the_estimate_kept():
    from napari_edgecme.cli._deblur import estimate_summary
    from napari_edgecme.core.camera import Intrinsics
    from napari_edgecme.core.estimate import EstimateInfo, MotionEstimate
    from napari_edgecme.core.motion import CameraMotion

    motion = CameraMotion.identity("inplane", Intrinsics.from_image_shape((64, 64)))
    info = EstimateInfo("xu+ep", "inplane", 9.0, 77.0, 1.0, converged=True)
    plain = estimate_summary(MotionEstimate(motion, None, None, info), "xu+ep", 9.0, "default")
    info.start = "edge profiles"
    kept = estimate_summary(MotionEstimate(motion, None, None, info), "xu+ep", 9.0, "default")
    info.start = "EpAlone"
    own = estimate_summary(MotionEstimate(motion, None, None, info), "xu+ep", 9.0, "default")
    info.start = "wide"
    wide = estimate_summary(MotionEstimate(motion, None, None, info), "xu+ep", 9.0, "default")
    assert "start" not in plain and "own" not in plain
    assert kept == plain.replace(", 0.0 s)", ", kept the start from the profiles' estimate, "
                                               "0.0 s)")
    assert own == plain.replace(", 0.0 s)", ", kept the profiles' own estimate (polished), "
                                              "0.0 s)")
    assert wide == plain.replace(", 0.0 s)", ", kept the start from a wide motion, 0.0 s)")


def test_the_summary_says_which_profile_model_epalone_kept():
    from napari_edgecme.cli._deblur import estimate_summary
    from napari_edgecme.core.camera import Intrinsics
    from napari_edgecme.core.estimate import EstimateInfo, MotionEstimate
    from napari_edgecme.core.motion import CameraMotion

    motion = CameraMotion.identity("inplane", Intrinsics.from_image_shape((64, 64)))
    info = EstimateInfo("ep", "inplane", 9.0, 77.0, 1.0, n_profiles=30, converged=True)
    steps = estimate_summary(MotionEstimate(motion, None, None, info), "ep", 9.0, "default")
    info.edge_spread = 1.0
    soft = estimate_summary(MotionEstimate(motion, None, None, info), "ep", 9.0, "default")
    assert "30 edge profiles, fitted as step edges, 0.0 s)" in steps
    assert soft == steps.replace("step edges", "soft edges (1 px spread)")
    xu = EstimateInfo("xu", "inplane", 9.0, 77.0, 1.0, converged=True)
    assert "fitted as" not in estimate_summary(MotionEstimate(motion, None, None, xu), "xu",
                                               9.0, "default")


def test_deconvolve_of_a_saved_epalone_motion_gives_the_bytes_deblur_gave(tmp_path, capsys):
    """``deblur --save-motion`` with EpAlone, then ``deconvolve --motion`` of that file:
    the same restoration, since the file keeps the estimator and its profile misfit (the
    EpAlone prior, which both summaries state), and the restoration ``deconvolve`` gives
    the motion at that prior's weight by hand."""
    from napari_edgecme.core.deconv import REFERENCE_LAMBDA_F, noise_lambda_f

    case = synth.make_case(synth.sample_image("edges", 128), "inplane", 5, 0.01, rng=3)
    write_image(tmp_path / "b.png", case.blurred)
    status, _, err = run(["deblur", tmp_path / "b.png", "-o", tmp_path / "d.png",
                          "--save-motion", tmp_path / "m.json", "--method", "ep",
                          "--model", "inplane", "--max-blur", "8", *FAST], capsys)
    assert status == 0, err
    _, estimated_by, misfit = CameraMotion.load_estimate(tmp_path / "m.json")
    assert estimated_by == "ep" and 0 <= misfit <= 0.2
    prior = f"EpAlone prior {ep_prior_factor(misfit):.1f}x (profile misfit {misfit:.0%})"
    assert prior in err[-1]
    status, _, err = run(["deconvolve", tmp_path / "b.png", "--motion", tmp_path / "m.json",
                          "-o", tmp_path / "c.png"], capsys)
    assert status == 0, err
    assert prior in err[-1]
    assert (tmp_path / "c.png").read_bytes() == (tmp_path / "d.png").read_bytes()
    weight = (max(noise_lambda_f(read_image(tmp_path / "b.png")), REFERENCE_LAMBDA_F)
              * ep_prior_factor(misfit))
    CameraMotion.load(tmp_path / "m.json").save(tmp_path / "plain.json")
    status, _, err = run(["deconvolve", tmp_path / "b.png", "--motion", tmp_path / "plain.json",
                          "-o", tmp_path / "h.png", "--lam", repr(2 / weight)], capsys)
    assert status == 0, err
    by_hand = read_image(tmp_path / "h.png").astype(float)  # --lam rounds through 2 / L
    assert np.abs(by_hand - read_image(tmp_path / "d.png")).max() <= 1
