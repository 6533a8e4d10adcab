"""Fresh-process jobs: one estimation, deconvolution or operator timing per Python process,
which reports its own peak memory (see :func:`peak_rss_mib`).

The parent calls :func:`run_job`; the child is this module run as
``python -m napari_edgecme._worker``, reading the job as JSON on stdin and printing its
result on a line starting with :data:`MARKER`. Used by the benchmarks, the suites and
the batch workers (for their peak memory).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

__all__ = ["MARKER", "peak_rss_mib", "run_job", "worker_env", "worker_main"]

#: Prefix of the line a worker process prints its result on.
MARKER = "EDGECME-BENCH-RESULT "


def peak_rss_mib() -> float | None:
    """Peak resident set size of this process (MiB), since it started.

    Linux: ``VmHWM`` of ``/proc/self/status``, the high-water mark of this process's
    own address space. Not ``getrusage().ru_maxrss``: Linux carries the parent's
    high-water mark over fork and exec into the child's ``ru_maxrss`` (a worker
    started by a parent holding 2 GiB reports at least 2 GiB), and
    ``RUSAGE_CHILDREN`` has the same flaw. Elsewhere ``ru_maxrss`` is the best there is.
    """
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 2**10  # kB
    except OSError:
        pass
    try:
        import resource
    except ImportError:  # Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 2**10  # bytes vs KiB


def _job_baseline(job: dict) -> dict:
    from .core import deconv, estimate  # noqa: F401 - the import is what is measured

    np.load(job["image"])
    return {}


def _job_estimate(job: dict) -> dict:
    from .core.deblur import restoring_params
    from .core.deconv import deconvolve
    from .core.estimate import estimate_motion

    image = np.load(job["image"])
    t0, c0 = time.perf_counter(), time.process_time()
    est = estimate_motion(image, job["method"], job["model"], job["max_blur"],
                          job.get("focal_px"), rng=0, n_iter=job.get("n_iter"))
    out = {"estimate_s": time.perf_counter() - t0, "estimate_cpu_s": time.process_time() - c0,
           "n_profiles": est.info.n_profiles, "poses": est.motion.n_poses,
           "message": est.info.message, "converged": est.info.converged,
           "method_run": est.info.method, "no_blur": est.info.no_blur}
    if job.get("motion"):
        est.motion.save(job["motion"], estimated_by=est.info.method,
                        profile_misfit=est.info.profile_misfit)
    if job.get("restored"):
        t0, c0 = time.perf_counter(), time.process_time()
        restored = deconvolve(image, est.motion,
                              **restoring_params(image, est.info.method, "hyperlaplacian",
                                                 profile_misfit=est.info.profile_misfit))
        out["deconvolve_s"] = time.perf_counter() - t0
        out["deconvolve_cpu_s"] = time.process_time() - c0
        np.save(job["restored"], restored)
    return out


def _job_deconvolve(job: dict) -> dict:
    from .core.deconv import deconvolve
    from .core.motion import CameraMotion

    image = np.load(job["image"])
    motion = CameraMotion.load(job["motion"])
    t0, c0 = time.perf_counter(), time.process_time()
    restored = deconvolve(image, motion, job.get("method", "hyperlaplacian"))
    out = {"deconvolve_s": time.perf_counter() - t0, "deconvolve_cpu_s": time.process_time() - c0}
    if job.get("restored"):
        np.save(job["restored"], restored)
    return out


def _job_operator(job: dict) -> dict:
    from .core.motion import CameraMotion
    from .core.operators import EfficientFilterFlow

    image = np.load(job["image"]).astype(np.float32)
    motion = CameraMotion.load(job["motion"])
    repeat = int(job["repeat"])

    def median_time(fn, n):
        times = []
        for _ in range(n):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        return statistics.median(times)

    op = EfficientFilterFlow(motion)
    blurred = op.forward(image)
    grid = op.grid
    return {"build_s": median_time(lambda: EfficientFilterFlow(motion), max(3, repeat // 3)),
            "forward_s": median_time(lambda: op.forward(image), repeat),
            "adjoint_s": median_time(lambda: op.adjoint(blurred), repeat),
            "tiles": list(grid.counts), "psf_size": grid.psf_size, "poses": motion.n_poses}


JOBS = {"baseline": _job_baseline, "estimate": _job_estimate,
         "deconvolve": _job_deconvolve, "operator": _job_operator}


def worker_main() -> None:
    """Run one job read as JSON from stdin; print the result (and peak memory) as JSON."""
    job = json.loads(sys.stdin.read())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = JOBS[job["kind"]](job)
            result["ok"] = True
        except Exception as err:  # reported as a failed entry by the parent
            text = str(err).strip().splitlines()
            result = {"ok": False, "error": f"{type(err).__name__}: {text[0] if text else ''}"}
    result["warnings"] = list(dict.fromkeys(str(w.message).splitlines()[0] for w in caught
                                            if str(w.message)))
    result["peak_rss_mib"] = peak_rss_mib()
    print(MARKER + json.dumps(result), flush=True)


def worker_env(source: str | None = None) -> dict:
    """The environment of a worker process: this one's, with this package first on the path
    (a worker runs the same code as its parent, whatever is installed), or the source tree
    ``source`` (a folder holding ``napari_edgecme``: another version, for comparisons)."""
    env = os.environ.copy()
    package_root = source or str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = package_root + (os.pathsep + env["PYTHONPATH"]
                                        if env.get("PYTHONPATH") else "")
    return env


def run_job(job: dict, timeout: float, source: str | None = None) -> dict:
    """Run ``job`` in a fresh Python process (importing this package, or the one in the
    source tree ``source``); a failure comes back as ``{"ok": False, ...}``."""
    env = worker_env(source)
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-m", "napari_edgecme._worker"],
                              input=json.dumps(job), capture_output=True, text=True,
                              timeout=timeout, env=env, check=False)
    except subprocess.TimeoutExpired:
        return {"ok": False, "error": f"timed out after {timeout:.0f} s"}
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith(MARKER):
            result = json.loads(line[len(MARKER):])
            result["process_s"] = time.perf_counter() - t0
            return result
    tail = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
    reason = tail[-1] if tail else "no output"
    return {"ok": False, "error": f"worker process exited with status {proc.returncode}: "
                                  f"{reason}"}


if __name__ == "__main__":
    worker_main()
