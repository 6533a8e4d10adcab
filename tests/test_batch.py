"""Claims about batch deblurring (``edgecme batch``, ``deblur_many``): on a real Dask
``LocalCluster`` (2 worker processes) every good photo is restored bit-identically to
``edgecme deblur`` with the same seed, a corrupt photo is reported and the batch goes on,
a constant photo is "no blur" (written unchanged), a rerun redoes nothing that succeeded,
``--force`` redoes everything; the same on a scheduler and worker started by the test on
127.0.0.1 and passed by address; without Dask ``--workers 1`` runs in-process and anything
else says how to install it; Ctrl-C lets the running photos finish and leaves no partial
file; bad arguments are exit status 2 in one line. Small synthetic photos and few
iterations: the tests check the plumbing, not the quality."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")

from napari_edgecme import batch
from napari_edgecme.batch._run import Tally
from napari_edgecme.cli import main
from napari_edgecme.core import synth
from napari_edgecme.core.io import read_image, write_image

FAST = ["--n-iter", "2", "--max-blur", "9", "--model", "inplane"]
GOOD = ("camera.png", "edges.png", "astronaut.png", "edges-rgb.png")
PHOTOS = (*GOOD, "flat.png", "corrupt.png")


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> Path:
    """Six 72 px photos: four shaken (one RGB), one constant, one corrupt PNG."""
    root = tmp_path_factory.mktemp("batch-photos")
    for i, name in enumerate(GOOD):
        scene = name.removesuffix(".png").removesuffix("-rgb")
        blurred = synth.make_case(synth.sample_image(scene, 72), "inplane", 7, 0.01,
                                  rng=i).blurred
        if name.endswith("-rgb.png"):  # three tinted channels of the shaken photo
            blurred = np.stack([blurred, 0.8 * blurred, blurred**1.5], axis=-1)
        write_image(root / name, blurred)
    write_image(root / "flat.png", np.full((72, 72), 0.5))
    (root / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"not really a png" * 8)
    return root


def run(argv, capsys):
    status = main([str(a) for a in argv])
    _, err = capsys.readouterr()
    return status, [line for line in err.splitlines() if line.strip()]


def report(out: Path) -> dict[str, dict]:
    with open(out / "report.csv", newline="") as f:
        return {row["photo"]: row for row in csv.DictReader(f)}


def stamps(out: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in out.rglob("*")
            if p.is_file() and not p.name.startswith("report.")}


def no_partial_files(out: Path) -> bool:
    return not [p for p in out.rglob("*") if p.name.startswith(".") or ".tmp-" in p.name]


@pytest.fixture(scope="module")
def reference(photos, tmp_path_factory) -> Path:
    """``edgecme deblur`` of each photo with the batch's options (in this process)."""
    root = tmp_path_factory.mktemp("batch-reference")
    for name in (*GOOD, "flat.png"):
        assert main(["-q", "deblur", str(photos / name), "-o", str(root / name),
                     "--save-motion", str(root / f"{name}.motion.json"), "--seed", "3",
                     *FAST]) == 0
    return root


@pytest.fixture(scope="module")
def local_run(photos, tmp_path_factory):
    """``edgecme batch`` of the folder on a LocalCluster of 2 worker processes."""
    out = tmp_path_factory.mktemp("batch-out") / "restored"
    status = main(["batch", str(photos), "-o", str(out), "--workers", "2", "--seed", "3",
                   *FAST])
    return status, out


# --------------------------------------------------------------------------------------
# a real LocalCluster
# --------------------------------------------------------------------------------------

def test_local_cluster_restores_every_good_photo_like_deblur(local_run, reference):
    status, out = local_run
    assert status == 1  # one photo failed
    rows = report(out)
    assert list(rows) == sorted(PHOTOS)
    for name in GOOD:
        assert rows[name]["status"] == "done", rows[name]
        assert (out / name).read_bytes() == (reference / name).read_bytes(), name
        motion = f"{name}.motion.json"
        assert (out / motion).read_bytes() == (reference / motion).read_bytes(), name
        assert rows[name]["method"] in ("xu", "xu+ep") and float(rows[name]["blur_extent_px"]) > 0
        # the motion file names the method that ran, so 'deconvolve' restores it as deblur
        assert json.loads((out / motion).read_text())["estimated_by"] == rows[name]["method"]
        assert rows[name]["worker"].startswith("tcp://127.0.0.1")
        for role in ("before", "after", "psf"):
            thumb = read_image(out / rows[name][role])
            assert max(thumb.shape[:2]) <= batch.THUMB_SIDE
    assert read_image(out / "edges-rgb.png").shape == (72, 72, 3)
    assert no_partial_files(out)


def test_corrupt_photo_is_reported_and_constant_photo_has_no_blur(local_run, photos,
                                                                  reference):
    _, out = local_run
    rows = report(out)
    bad = rows["corrupt.png"]
    assert bad["status"] == "failed" and bad["reason"].startswith("cannot read image corrupt.png")
    assert "\n" not in bad["reason"] and not (out / "corrupt.png").exists()
    flat = rows["flat.png"]
    assert flat["status"] == "no blur"
    assert np.array_equal(read_image(out / "flat.png"), read_image(photos / "flat.png"))
    assert (out / "flat.png").read_bytes() == (reference / "flat.png").read_bytes()
    page = (out / "report.html").read_text()
    assert page.count("<tr") == len(PHOTOS) + 1 and "refresh" not in page
    assert page.count("<img") == 3 * (len(PHOTOS) - 1)


def test_rerun_redoes_nothing_that_succeeded_and_force_redoes_all(local_run, reference,
                                                                  photos, capsys):
    status, out = local_run
    capsys.readouterr()
    before = stamps(out)
    status, err = run(["batch", photos, "-o", out, "--workers", "2", "--seed", "3", *FAST],
                      capsys)
    assert status == 1
    assert stamps(out) == before  # not one output rewritten
    rows = report(out)
    assert {rows[n]["status"] for n in (*GOOD, "flat.png")} == {"skipped"}
    assert rows["edges.png"]["method"] in ("xu", "xu+ep")  # carried over from the first run
    assert rows["corrupt.png"]["status"] == "failed"  # failures have no outputs: tried again
    assert any("1 of 6 photos to deblur" in line for line in err)

    status, err = run(["batch", photos, "-o", out, "--workers", "2", "--seed", "3", "--force",
                       *FAST], capsys)
    assert status == 1
    assert any("6 of 6 photos to deblur" in line for line in err)
    after = stamps(out)
    assert all(after[name] != before[name] for name in before)  # every output rewritten
    for name in GOOD:
        assert (out / name).read_bytes() == (reference / name).read_bytes()
    assert report(out)["camera.png"]["status"] == "done"


# --------------------------------------------------------------------------------------
# an existing cluster, by address
# --------------------------------------------------------------------------------------

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def scheduler_address(tmp_path):
    """A ``dask scheduler`` and one ``dask worker`` on 127.0.0.1, as subprocesses."""
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    logs = [open(tmp_path / name, "w") for name in ("scheduler.log", "worker.log")]
    procs = [subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host",
                               "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              stdout=logs[0], stderr=subprocess.STDOUT)]
    procs.append(subprocess.Popen([sys.executable, "-m", "dask", "worker", address,
                                   "--nthreads", "1", "--no-nanny", "--no-dashboard",
                                   "--host", "127.0.0.1"],
                                  stdout=logs[1], stderr=subprocess.STDOUT))
    try:
        from distributed import Client

        with Client(address, timeout="30s", set_as_default=False) as client:
            client.wait_for_workers(1, timeout=60)
        yield address
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in reversed(procs):
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
        for log in logs:
            log.close()


def test_batch_on_an_existing_scheduler_by_address(scheduler_address, photos, reference,
                                                   tmp_path, capsys):
    inputs = [photos / "edges.png", photos / "flat.png"]
    status, err = run(["batch", *inputs, "-o", tmp_path / "out", "--scheduler",
                       scheduler_address, "--seed", "3", *FAST], capsys)
    assert status == 0, err
    assert any(f"Dask scheduler {scheduler_address}" in line for line in err)
    rows = report(tmp_path / "out")
    assert rows["edges.png"]["status"] == "done" and rows["flat.png"]["status"] == "no blur"
    for name in ("edges.png", "flat.png"):
        assert (tmp_path / "out" / name).read_bytes() == (reference / name).read_bytes()
    from distributed import Client

    with Client(scheduler_address, set_as_default=False) as client:  # the API's client=
        result = batch.deblur_many(inputs[0], tmp_path / "api", model="inplane", max_blur=9,
                                   client=client, rng=3, n_iter=2)
        assert client.status == "running"  # a given client is left open
    assert result.ok and result.cluster.startswith("the given Dask client")
    assert (tmp_path / "api" / "edges.png").read_bytes() == (reference / "edges.png").read_bytes()


# --------------------------------------------------------------------------------------
# without Dask, the API, interruption, bad arguments
# --------------------------------------------------------------------------------------

def test_without_dask_batch_says_how_to_install_and_workers_1_runs_in_process(
        photos, reference, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed fails
    status, err = run(["batch", photos / "edges.png", "-o", tmp_path / "a", *FAST], capsys)
    assert status == 2 and len(err) == 1
    assert 'pip install "napari-edgecme[batch]"' in err[0] and "--workers 1" in err[0]
    status, err = run(["batch", photos / "edges.png", photos / "corrupt.png", "-o",
                       tmp_path / "b", "--workers", "1", "--seed", "3", *FAST], capsys)
    assert status == 1
    assert (tmp_path / "b" / "edges.png").read_bytes() == (reference / "edges.png").read_bytes()
    assert report(tmp_path / "b")["edges.png"]["worker"] == "this process"


def test_api_deblur_many_matches_the_cli(photos, reference, tmp_path):
    result = batch.deblur_many([photos / "edges.png", str(photos / "flat.*")], tmp_path,
                               model="inplane", max_blur=9, workers=1, rng=3, n_iter=2)
    assert result.ok and result.counts == {"done": 1, "no blur": 1}
    assert (tmp_path / "edges.png").read_bytes() == (reference / "edges.png").read_bytes()
    with pytest.raises(ValueError, match="unknown parameter 'lambda_x'"):
        batch.deblur_many(photos, tmp_path, workers=1, lambda_x=1)
    with pytest.raises(ValueError, match="deconvolution"):
        batch.deblur_many(photos, tmp_path, workers=1, deconvolution="magic")


def test_interrupt_in_process_leaves_a_report_and_no_partial_file(photos, tmp_path):
    seen = []

    def log(line):
        seen.append(line)
        if line.startswith("camera.png:"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        batch.deblur_many([photos / n for n in GOOD], tmp_path, model="inplane", max_blur=9,
                          workers=1, rng=3, n_iter=2, log=log)
    rows = report(tmp_path)
    assert rows["camera.png"]["status"] == "done"
    assert {rows[n]["status"] for n in GOOD[1:]} == {"not run"}
    assert no_partial_files(tmp_path) and not (tmp_path / "edges.png").exists()


def test_ctrl_c_lets_running_photos_finish_and_exits_130(photos, tmp_path):
    """SIGINT to the whole process group, as a terminal sends it."""
    folder = tmp_path / "in"
    folder.mkdir()
    shutil.copy(photos / "edges.png", folder / "p0.png")
    for i in range(1, 6):  # larger: still running when p0 is done
        write_image(folder / f"p{i}.png", synth.make_case(
            synth.sample_image("edges", 128), "inplane", 7, 0.01, rng=i).blurred)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "napari_edgecme", "batch", str(folder),
                             "-o", str(out), "--workers", "2", *FAST],
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    lines = []
    for line in proc.stderr:
        lines.append(line.rstrip("\n"))
        if line.startswith("edgecme: p0.png:"):
            break
    os.killpg(proc.pid, signal.SIGINT)
    _, rest = proc.communicate(timeout=120)
    text = "\n".join([*lines, *rest.splitlines()])
    assert proc.returncode == 130, text
    assert "Traceback" not in text and "interrupted; the photos finished so far" in text, text
    rows = report(out)
    statuses = [rows[f"p{i}.png"]["status"] for i in range(6)]
    assert set(statuses) == {"done", "not run"}, text  # nothing failed or half-done
    finished = [line for line in text.splitlines()
                if line.startswith("edgecme: p") and "motion" in line]
    assert statuses.count("done") == len(finished)  # every photo that ran was written
    assert "waiting for the" in text  # photos were running at Ctrl-C: they finished
    assert statuses[:2] == ["done", "done"] and "not run" in statuses
    for i, status in enumerate(statuses):
        assert (out / f"p{i}.png").exists() == (status == "done")
    assert no_partial_files(out)


@pytest.mark.parametrize(("argv", "message"), [
    (["missing-folder", "-o", "out"], "input not found: missing-folder"),
    (["in", "-o", "out", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"],
     "--workers sizes the local cluster"),
    (["in", "-o", "out", "--method", "ep", "--lam", "1", "--deconvolution", "rl"],
     "--lam does not apply"),
    (["in", "-o", "in"], "would overwrite the input"),
    (["in/*.gif", "-o", "out"], "no image files match in/*.gif"),
    (["in", "in2", "-o", "out"], "would both be written as camera.png"),
])
def test_bad_arguments_are_one_line_and_exit_2(argv, message, photos, tmp_path, capsys,
                                               monkeypatch):
    monkeypatch.chdir(tmp_path)
    shutil.copytree(photos, "in")
    Path("in2").mkdir()
    shutil.copy(photos / "camera.png", "in2/camera.png")
    status, err = run(["batch", *argv], capsys)
    assert status == 2 and len(err) == 1 and message in err[0], err
    assert not Path("out").exists()


def test_collect_photos_recursive_mirrors_subfolders_and_skips_the_output(photos, tmp_path):
    root = tmp_path / "shoot"
    (root / "day2").mkdir(parents=True)
    shutil.copy(photos / "camera.png", root / "a.png")
    shutil.copy(photos / "camera.png", root / "day2" / "a.png")
    (root / "notes.txt").write_text("not a photo")
    (root / "out").mkdir()
    shutil.copy(photos / "camera.png", root / "out" / "a.png")
    names = [p.name for p in batch.collect_photos([root], root / "out", recursive=True)]
    assert names == ["a.png", "day2/a.png"]
    assert [p.name for p in batch.collect_photos([root])] == ["a.png"]
    both = batch.collect_photos([root / "a.png", str(root / "*.png")])
    assert len(both) == 1  # the same file once


def test_progress_record_counts_photos_and_time_left():
    tally = Tally(total=4, start=time.monotonic() - 10, finished=2, failed=1,
                         running=2)
    record = tally.record()
    assert (record.stage, record.step, record.total) == ("batch", 2, 4)
    assert record.message.startswith("1 done, 1 failed, 2 running, 2 to go, about 0:1")


def test_local_cluster_size_one_worker_per_core_within_memory():
    assert batch.local_cluster_size(cores=2, memory=24 * 2**30) == (2, 1, 12 * 2**30)
    assert batch.local_cluster_size(cores=8, memory=4 * 2**30)[0] == 2
    assert batch.local_cluster_size(cores=4, memory=2**30)[0] == 1


def test_an_epalone_photo_says_the_prior_it_was_restored_with(tmp_path):
    """As ``edgecme deblur`` does: the log line of a photo deblurred by EpAlone names the
    prior its misfit set, and its motion file keeps the misfit."""
    from napari_edgecme.core.deblur import ep_prior_factor
    from napari_edgecme.core.motion import CameraMotion

    case = synth.make_case(synth.sample_image("edges", 128), "inplane", 5, 0.01, rng=3)
    write_image(tmp_path / "e.png", case.blurred)
    lines = []
    result = batch.deblur_many([tmp_path / "e.png"], tmp_path / "out", method="ep",
                               model="inplane", max_blur=8, workers=1, rng=0, n_iter=2,
                               log=lines.append)
    assert result.ok and result.counts == {"done": 1}
    _, estimated_by, misfit = CameraMotion.load_estimate(tmp_path / "out" / "e.png.motion.json")
    assert estimated_by == "ep" and misfit is not None
    assert lines[-1].endswith(f"; EpAlone prior {ep_prior_factor(misfit):.1f}x "
                              f"(profile misfit {misfit:.0%})")
