"""Claims about ``edgecme demo`` and ``edgecme bench``: the demo runs end to end in a
reduced mode (128 px) and its report holds the PSNR/NCC table; it writes only its own
file names; an estimator that fails is reported, not a crash; the benchmark in its
smallest configuration writes Markdown and JSON tables with real measurements."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from napari_edgecme import _bench, _demo, _report, _worker
from napari_edgecme.cli import main
from napari_edgecme.core.io import read_image
from napari_edgecme.core.motion import CameraMotion

REDUCED = ["--size", "128", "--n-iter", "2"]


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    """One reduced demo run into a folder that already holds an unrelated file."""
    out = tmp_path_factory.mktemp("demo-parent") / "demo"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    status = main(["--quiet", "demo", "--out", str(out), *REDUCED])
    return status, out


def test_demo_runs_in_reduced_mode_and_reports_the_table(demo_run):
    status, out = demo_run
    assert status == 0
    report = (out / "report.md").read_text()
    assert "| result | aligned PSNR (dB) | gain (dB) | SSIM | PSF NCC |" in report
    for name in ("blurred input", "EpAlone", "Xu+Ep", "oracle (true motion)"):
        assert f"| {name} |" in report
    data = json.loads((out / "report.json").read_text())
    rows = {r["key"]: r for r in data["rows"]}
    assert data["config"]["size"] == 128 and data["config"]["shape"] == [128, 128]
    # the oracle restores what the shake destroyed; the table holds the measured values
    assert rows["oracle"]["psnr"] > rows["blurred"]["psnr"] + 2.0
    assert f"| {rows['oracle']['psnr']:.2f} |" in report
    for key, name in _demo.METHODS.items():
        row = rows[key]
        if "failed" in row:  # reported instead of crashing
            assert f"**{name} failed**" in report
            assert not (out / f"restored-{key.replace('+', '-')}.png").exists()
        else:
            assert math.isfinite(row["psnr"]) and -1 <= row["ncc"] <= 1
            assert f"| {row['psnr']:.2f} |" in report
            motion, estimated_by, misfit = CameraMotion.load_estimate(
                out / f"motion-{key.replace('+', '-')}.json")
            assert motion.image_shape == (128, 128)
            assert estimated_by == row["method_run"] in (key, "xu")  # Xu+Ep may run as Xu
            # the profiles' misfit, which sets an EpAlone motion's restoration (both
            # methods fit the profiles: Xu+Ep for its gate)
            assert misfit == row["profile_misfit"] is not None


def test_demo_writes_readable_images_and_figures_and_only_its_own_files(demo_run):
    _, out = demo_run
    names = {p.name for p in out.iterdir()}
    assert names - {"notes.txt"} <= set(_demo.DEMO_FILES)
    assert (out / "notes.txt").read_text() == "mine\n"  # an unrelated file survives
    assert not [n for n in names if ".tmp-" in n]
    for name in ("sharp.png", "blurred.png", "restored-oracle.png"):
        assert read_image(out / name).shape == (128, 128)
    sharp = read_image(out / "sharp.png").astype(float)
    blurred = read_image(out / "blurred.png").astype(float)
    assert np.abs(sharp - blurred).mean() > 1  # the photo really was shaken
    for name in ("psf-fields.png", "comparison.png", "edge-profile-locations.png",
                 "edge-profiles.png"):
        assert read_image(out / name).ndim == 3
    truth = CameraMotion.load(out / "motion-true.json")
    assert truth.model == "rotation" and truth.image_shape == (128, 128)
    report = (out / "report.md").read_text()
    for name in ("comparison.png", "psf-fields.png", "edge-profile-locations.png"):
        assert f"]({name})" in report


def test_a_failing_estimator_is_reported_not_a_crash(tmp_path, monkeypatch, capsys):
    real = _demo.iter_estimate_motion

    def no_profiles(image, method, *args, **kwargs):
        if method == "ep":
            raise ValueError("EpAlone needs at least 12 usable edge profiles; found 3")
        return real(image, method, *args, **kwargs)

    monkeypatch.setattr(_demo, "iter_estimate_motion", no_profiles)
    monkeypatch.setattr(_demo, "_matplotlib", lambda: None)  # and without matplotlib
    (tmp_path / "demo").mkdir()
    (tmp_path / "demo" / "restored-ep.png").write_bytes(b"stale, from an earlier run")
    status = main(["demo", "--out", str(tmp_path / "demo"), *REDUCED])
    err = capsys.readouterr().err
    assert status == 0
    assert ("edgecme: warning: EpAlone failed: EpAlone needs at least 12 usable edge "
            "profiles; found 3") in err
    report = (tmp_path / "demo" / "report.md").read_text()
    assert "**EpAlone failed**: ValueError: EpAlone needs at least 12" in report
    assert "| EpAlone | failed (see the notes) |" in report
    assert not (tmp_path / "demo" / "restored-ep.png").exists()  # no stale result left
    assert not (tmp_path / "demo" / "edge-profiles.png").exists()  # needs matplotlib
    assert "Install matplotlib" in report
    montage = read_image(tmp_path / "demo" / "psf-fields.png")
    assert montage.shape[0] == 128 and montage.shape[1] == 3 * 128 + 2 * 4


def test_demo_refuses_an_output_that_is_not_a_folder(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    assert main(["demo", "--out", str(tmp_path / "file")]) == 2
    assert main(["demo", "--out", str(tmp_path / "no" / "demo")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == f"edgecme: error: --out {tmp_path / 'file'} exists and is not a folder"
    assert "parent folder" in err[1] and len(err) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


@pytest.mark.slow  # about 40 s: eleven fresh worker processes
def test_bench_smallest_configuration_writes_markdown_and_json(tmp_path, capsys):
    out = tmp_path / "bench"
    status = main(["bench", "--quick", "--out", str(out), "--size", "64", "--cases", "1",
                   "--speed-size", "96", "--repeat", "1"])
    err = capsys.readouterr().err
    assert status == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["quality-quick.json", "quality-quick.md",
                                                     "speed-quick.json", "speed-quick.md"]
    quality = json.loads((out / "quality-quick.json").read_text())
    (case,) = quality["cases"]
    assert case["name"] == "camera-inplane-13px" and case["shape"] == [64, 64]
    assert set(case["runs"]) == {"ep", "xu", "xu+ep", "oracle"}
    for run in case["runs"].values():
        if run["ok"]:
            assert math.isfinite(run["psnr"]) and run["peak_rss_mib"] > 50
        else:
            assert run["error"]  # a failure is a row entry with its reason
    assert case["runs"]["oracle"]["ok"] and case["runs"]["xu"]["ok"]
    assert quality["machine"]["cpus"] >= 1 and quality["machine"]["node"]
    text = (out / "quality-quick.md").read_text()
    assert "| method | succeeded | mean PSNR (dB)" in text
    assert "| camera-inplane-13px |" in text and "VmHWM" in text

    speed = json.loads((out / "speed-quick.json").read_text())
    tasks = {r["task"].split(",")[0]: r for r in speed["rows"]}
    assert tasks["EFF operator"]["ok"] and tasks["EFF operator"]["seconds"] > 0
    deconv = tasks["deconvolution hyperlaplacian"]
    assert deconv["ok"] and deconv["seconds"] > 0 and deconv["peak_rss_mib"] > 50
    assert "target" in deconv
    assert "| task | time (s) | CPU (s) | peak RSS (MiB) |" in (out / "speed-quick.md").read_text()
    assert deconv["cpu_s"] > 0


def test_bench_worker_reports_a_failure_as_data(tmp_path):
    res = _worker.run_job({"kind": "deconvolve", "image": str(tmp_path / "missing.npy"),
                          "motion": str(tmp_path / "missing.json")}, timeout=120)
    assert res["ok"] is False and "FileNotFoundError" in res["error"]


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="Linux /proc only")
def test_a_worker_reports_its_own_peak_memory_not_its_parents(tmp_path):
    np.save(tmp_path / "image.npy", np.zeros((64, 64), np.float32))
    ballast = np.ones(2**26)  # 512 MiB held by this (the parent) process
    res = _worker.run_job({"kind": "baseline", "image": str(tmp_path / "image.npy")}, 120)
    assert res["ok"] and 30 < res["peak_rss_mib"] < 400, res
    del ballast


def test_quality_cases_cover_the_issue_grid():
    config = _bench.make_config()
    assert len(config.cases) >= 8
    assert {c.model for c in config.cases} == {"inplane", "rotation"}
    assert "edges" in {c.image for c in config.cases}
    assert min(c.extent for c in config.cases) >= 13 and max(c.extent for c in config.cases) <= 31
    assert len({c.seed for c in config.cases}) == len(config.cases)
    quick = _bench.make_config(quick=True)
    assert not quick.large and len(quick.cases) < len(config.cases)


def test_markdown_table_alignment():
    text = _report.markdown_table(["a", "b"], [[1, "x"]], "lr")
    assert text.splitlines() == ["| a | b |", "|---|---:|", "| 1 | x |"]
