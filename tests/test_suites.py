"""The real-photo suites run end to end on data laid out as in ``shared/data`` (here: a tiny
copy made by the test, so the suite needs no shared folder) and report what they measured."""

import json

import imageio.v3 as iio
import numpy as np
import pytest
from scipy.io import savemat

from napari_edgecme import _suites
from napari_edgecme.core import synth


@pytest.fixture(scope="module")
def case():
    return synth.make_case(synth.sample_image("edges", 96), "rotation", 7, 0.01, rng=2)


def _u8(a):
    return np.round(np.clip(a, 0, 1) * 255).astype(np.uint8)


def test_lai_suite_scores_a_case_against_its_true_motion(tmp_path, case):
    data = tmp_path / "lai"
    folder = data / "text_01_gyro1"
    folder.mkdir(parents=True)
    iio.imwrite(folder / "blurred.png", _u8(case.blurred))
    iio.imwrite(folder / "sharp.png", _u8(case.sharp))
    case.motion.save(folder / "truth.json")
    (folder / "case.json").write_text(json.dumps(
        {"image": "text_01", "gyro": 1, "category": "text", "extent_px": 7.0, "max_blur": 9}))
    (data / "quick.txt").write_text("text_01_gyro1\n")
    md, js = _suites.run_suite("lai", tmp_path / "out", data=data, quick=True, methods=("xu",),
                               n_iter=1)
    result = json.loads(js.read_text())
    row = result["cases"][0]
    assert row["runs"]["oracle"]["psnr"] > row["blurred"]["psnr"] + 3  # the truth deblurs
    assert row["runs"]["xu"]["ok"] and 0 < row["runs"]["xu"]["ncc"] <= 1
    assert row["profiles_true"]["n"] > 0 and len(row["profiles_true"]["ncc"]) > 0
    text = md.read_text()
    assert "| text | 1 |" in text and "Edge profiles: yield and fidelity" in text


def test_levin_suite_reads_a_capture_and_its_correlation_kernel(tmp_path):
    sharp = synth.sample_image("edges", 64).astype(np.float64)
    kernel = np.zeros((9, 9))
    kernel[4, 2:7] = 1 / 5  # a horizontal streak: y(x) = sum_u f(u) x(x + u)
    from scipy.ndimage import correlate

    blurred = correlate(sharp, kernel, mode="nearest")
    data = tmp_path / "levin"
    data.mkdir()
    savemat(data / "im01_ker02.mat", {"x": sharp, "y": blurred, "f": kernel})
    motion = _suites.levin_motion(kernel, sharp.shape)
    from napari_edgecme.core.operators import blur

    assert np.abs(blur(sharp, motion, "exact") - blurred)[8:-8, 8:-8].max() < 1e-6
    md, js = _suites.run_suite("levin", tmp_path / "out", data=data, methods=("xu",),
                                n_iter=1)
    assert "anchor protocol" in md.read_text()
    # told the kernel's size as the benchmark states it (sizeL: the taps' 5 px box here)
    assert json.loads(js.read_text())["cases"][0]["max_blur"] == 5.0


def test_real_suite_deblurs_through_the_cli_and_draws_a_sheet(tmp_path, case):
    scene = tmp_path / "paper-real" / "scene"
    scene.mkdir(parents=True)
    iio.imwrite(scene / "input.png", _u8(case.blurred))
    iio.imwrite(scene / "xu_ep.jpg", _u8(case.sharp))  # a stand-in for the paper's output
    md, js = _suites.run_suite("real", tmp_path / "out", data=tmp_path / "paper-real")
    photo = json.loads(js.read_text())["photos"][0]
    assert photo["runs"]["xu+ep"]["status"] == 0
    assert photo["runs"]["ep"]["status"] in (0, 2)  # EpAlone runs or refuses in one line
    sheet = iio.imread(tmp_path / "out" / "real-sheets" / "scene.png")
    assert sheet.ndim == 3 and sheet.shape[1] > 3 * case.blurred.shape[1]
    assert "[sheet](real-sheets/scene.png)" in md.read_text()
