"""``edgecme bench``: the quality and speed benchmarks of the estimation and deconvolution.

Quality
    Synthetic shakes of bundled scikit-image photos and of the edge-rich ``"edges"``
    scene (:func:`~napari_edgecme.core.synth.make_case`: a random hand-shake trajectory
    of the ``inplane`` or ``rotation`` model, rendered exactly by dense warping --
    not with the estimators' operator -- 1 % Gaussian noise, 8-bit quantisation).
    For every case: the blurred input, EpAlone, Xu and Xu+Ep (each estimate followed
    by the same hyper-Laplacian deconvolution) and the oracle (the true motion, same
    deconvolution). Reported: aligned PSNR (dB), centroid-aligned PSF NCC against the
    true motion, estimation and deconvolution time, and peak memory. The estimators
    are told ``max_blur`` = :data:`MAX_BLUR_FACTOR` x the true blur extent.

Speed
    On an 800x800 gray image under a 31 px camera-rotation shake: the efficient filter
    flow (EFF) operator (build, forward, adjoint; median of repeated applications),
    motion estimation with ``max_blur`` 31 and the ``rotation`` model (EpAlone, Xu,
    Xu+Ep), deconvolution with the true motion (hyper-Laplacian, RL, Wiener), and the
    hyper-Laplacian deconvolution of a 12-megapixel RGB photo (4000x3000; not in
    ``--quick``). The speed inputs are blurred with the EFF operator (their content
    matters little for timing) so that preparing them takes seconds.

Peak memory
    Every estimation or deconvolution runs in a fresh Python process (this module run
    as ``python -m napari_edgecme._bench``, reading a job as JSON on stdin), which
    reports its own peak resident set size when it ends: ``VmHWM`` from
    ``/proc/self/status`` on Linux (``getrusage`` elsewhere). ``ru_maxrss`` is not used
    on Linux because a child inherits its parent's high-water mark through fork and
    exec (``RUSAGE_CHILDREN`` has the same flaw): a worker started by a parent that
    holds the 12 MP test image would report the parent's memory. The figure includes
    the interpreter, numpy, scipy and scikit-image and the loaded input: the
    *baseline* of a process that only imports the engine and loads the input is
    reported beside it.

Timings are wall-clock seconds on a possibly shared machine; where a run repeats the
median is reported. A run that raises (e.g. EpAlone on an image with too few edge
profiles) or times out is recorded as a failed entry, not a crash. The results go to
``quality[-quick].md/.json`` and ``speed[-quick].md/.json`` in the output folder, with
the date, the machine (``platform.node()``, CPU count) and the package version.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "BenchConfig",
    "CaseSpec",
    "load_average",
    "machine_info",
    "make_config",
    "markdown_table",
    "quality_markdown",
    "run_bench",
    "run_quality",
    "run_speed",
    "speed_markdown",
]

#: Estimators, by engine name, with their display names.
METHODS = {"ep": "EpAlone", "xu": "Xu", "xu+ep": "Xu+Ep"}
#: The estimators are told ``max_blur`` = this factor times the true blur extent.
MAX_BLUR_FACTOR = 1.3
NOISE = 0.01
BITS = 8
#: Blur extents of the full quality set (pixels), assigned in turn to the cases.
EXTENTS = (13.0, 19.0, 25.0, 31.0)
#: Speed case: blur extent (px) and ``max_blur`` of the 800x800 estimation.
SPEED_BLUR = 31.0
#: The 12-megapixel RGB case, (rows, cols).
LARGE_SHAPE = (3000, 4000)
#: Prefix of the line a worker process prints its result on.
_MARKER = "EDGECME-BENCH-RESULT "


# --------------------------------------------------------------------------------------
# configuration
# --------------------------------------------------------------------------------------

@dataclass(frozen=True)
class CaseSpec:
    """One synthetic quality case."""

    name: str
    image: str
    model: str
    extent: float
    seed: int


@dataclass
class BenchConfig:
    """What a benchmark run measures (see :func:`make_config`)."""

    quick: bool
    size: int
    cases: list[CaseSpec]
    speed_size: int
    speed_methods: tuple[str, ...]
    deconv_methods: tuple[str, ...]
    repeat: int  # fresh-process runs per speed row (median reported)
    operator_repeat: int  # operator applications per timing (median reported)
    large: bool
    timeout: float  # seconds per run
    n_iter: int | None = None
    noise: float = NOISE
    bits: int = BITS
    extra: dict = field(default_factory=dict)


def quality_cases(images, models, extents, seed: int = 0) -> list[CaseSpec]:
    """Every image x model, the extents assigned in turn; case ``i`` is seeded ``seed + i``."""
    cases = []
    for i, (image, model) in enumerate((im, m) for im in images for m in models):
        extent = extents[i % len(extents)]
        cases.append(CaseSpec(f"{image}-{model}-{extent:g}px", image, model, float(extent),
                              seed + i))
    return cases


def make_config(quick: bool = False, size: int | None = None, cases: int | None = None,
                speed_size: int | None = None, repeat: int | None = None,
                large: bool = True, n_iter: int | None = None) -> BenchConfig:
    """The full or ``quick`` benchmark, with optional overrides (the test suite shrinks it).

    Full: 8 cases (camera, astronaut, coffee, edges x inplane, rotation; extents 13, 19,
    25, 31 px in turn) at 512 px; speed rows repeated 3 times; the 12 MP case.
    Quick: 4 cases (camera, edges x inplane, rotation; 13 and 15 px) at 320 px; speed
    rows once, EpAlone and Xu+Ep only, hyper-Laplacian only, no 12 MP case.

    The sizes follow from the edge profiles: EpAlone needs at least 12 of them, and a
    blur of 25-31 px leaves that many in a photo only from about 512 px up (at 256 px a
    19 px blur already leaves fewer than 12 in most of the photos).
    """
    if quick:
        specs = quality_cases(("camera", "edges"), ("inplane", "rotation"), (13.0, 15.0))
        config = BenchConfig(True, 320, specs, 800, ("ep", "xu+ep"), ("hyperlaplacian",),
                             1, 5, False, 900.0)
    else:
        specs = quality_cases(("camera", "astronaut", "coffee", "edges"),
                              ("inplane", "rotation"), EXTENTS)
        config = BenchConfig(False, 512, specs, 800, tuple(METHODS),
                             ("hyperlaplacian", "rl", "wiener"), 3, 9, large, 1800.0)
    if size is not None:
        config.size = int(size)
    if cases is not None:
        config.cases = config.cases[:int(cases)]
    if speed_size is not None:
        config.speed_size = int(speed_size)
    if repeat is not None:
        config.repeat = config.operator_repeat = int(repeat)
    if not large:
        config.large = False
    config.n_iter = n_iter
    return config


# --------------------------------------------------------------------------------------
# reporting helpers (shared with the demo)
# --------------------------------------------------------------------------------------

def _total_memory_gib() -> float | None:
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemTotal:"):
                    return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return None


def load_average() -> float | None:
    """The 1-minute load average (None where the platform has none)."""
    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):  # Windows
        return None


def machine_info() -> dict:
    """Date, machine name, CPU count, platform and versions, for reports."""
    import scipy

    from . import __version__

    return {
        "date": time.strftime("%Y-%m-%d %H:%M %Z"),
        "load_average": load_average(),
        "node": platform.node(),
        "cpus": os.cpu_count(),
        "memory_gib": _total_memory_gib(),
        "platform": f"{platform.system()} {platform.machine()}",
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "version": __version__,
    }


def _machine_line(m: dict) -> str:
    memory = f", {m['memory_gib']:.0f} GiB RAM" if m.get("memory_gib") else ""
    load = ""
    if m.get("load_average") is not None:
        loads = [m["load_average"], m.get("load_average_end", m["load_average"])]
        load = f"; load average {loads[0]:.1f} at the start, {loads[1]:.1f} at the end"
        if max(loads) > (m.get("cpus") or 1) + 0.5:
            load += " (above the CPU count: the machine was shared, so times are inflated)"
    return (f"{m['date']} on `{m['node']}` ({m['cpus']} CPUs{memory}, {m['platform']}), "
            f"Python {m['python']}, numpy {m['numpy']}, scipy {m['scipy']}, "
            f"napari-edgecme {m['version']}{load}")


def markdown_table(header, rows, align: str | None = None) -> str:
    """A Markdown table; ``align`` is one letter per column (``l``, ``r`` or ``c``)."""
    align = align or "l" * len(header)
    marks = {"l": "---", "r": "---:", "c": ":---:"}
    lines = ["| " + " | ".join(header) + " |",
             "|" + "|".join(marks[a] for a in align) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _median(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def _mean(values):
    values = [v for v in values if v is not None]
    return statistics.fmean(values) if values else None


def _f(value, spec: str, empty: str = "—") -> str:
    return empty if value is None else format(value, spec)


# --------------------------------------------------------------------------------------
# the worker process
# --------------------------------------------------------------------------------------

def _peak_rss_mib() -> float | None:
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
        est.motion.save(job["motion"])
    if job.get("restored"):
        t0, c0 = time.perf_counter(), time.process_time()
        restored = deconvolve(image, est.motion)
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


_JOBS = {"baseline": _job_baseline, "estimate": _job_estimate,
         "deconvolve": _job_deconvolve, "operator": _job_operator}


def _worker_main() -> None:
    """Run one job read as JSON from stdin; print the result (and peak memory) as JSON."""
    job = json.loads(sys.stdin.read())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = _JOBS[job["kind"]](job)
            result["ok"] = True
        except Exception as err:  # reported as a failed entry by the parent
            text = str(err).strip().splitlines()
            result = {"ok": False, "error": f"{type(err).__name__}: {text[0] if text else ''}"}
    result["warnings"] = list(dict.fromkeys(str(w.message).splitlines()[0] for w in caught
                                            if str(w.message)))
    result["peak_rss_mib"] = _peak_rss_mib()
    print(_MARKER + json.dumps(result), flush=True)


def worker_env() -> dict:
    """The environment of a worker process: this one's, with this package first on the path
    (a worker runs the same code as its parent, whatever is installed)."""
    env = os.environ.copy()
    package_root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = package_root + (os.pathsep + env["PYTHONPATH"]
                                        if env.get("PYTHONPATH") else "")
    return env


def run_job(job: dict, timeout: float) -> dict:
    """Run ``job`` in a fresh Python process; a failure comes back as ``{"ok": False, ...}``."""
    env = worker_env()
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-m", "napari_edgecme._bench"],
                              input=json.dumps(job), capture_output=True, text=True,
                              timeout=timeout, env=env, check=False)
    except subprocess.TimeoutExpired:
        return {"ok": False, "error": f"timed out after {timeout:.0f} s"}
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith(_MARKER):
            result = json.loads(line[len(_MARKER):])
            result["process_s"] = time.perf_counter() - t0
            return result
    tail = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
    reason = tail[-1] if tail else "no output"
    return {"ok": False, "error": f"worker process exited with status {proc.returncode}: "
                                  f"{reason}"}


# --------------------------------------------------------------------------------------
# quality
# --------------------------------------------------------------------------------------

def _max_blur(extent: float, shape) -> float:
    return float(min(math.ceil(MAX_BLUR_FACTOR * extent), math.ceil(min(shape) / 2) - 1))


def run_quality(config: BenchConfig, workdir: Path, log=None) -> dict:
    """Run the quality benchmark; return the JSON-ready result."""
    from .core.metrics import aligned_psnr, motion_psf_ncc
    from .core.motion import CameraMotion
    from .core.synth import make_case, sample_image

    log = log or (lambda message: None)
    t_start = time.perf_counter()
    machine = machine_info()
    cases = []
    baseline = None
    n_runs = len(config.cases) * (len(METHODS) + 1)
    done = 0
    for spec in config.cases:
        case = make_case(sample_image(spec.image, config.size), spec.model, spec.extent,
                         config.noise, bits=config.bits, rng=spec.seed, name=spec.name)
        stem = workdir / spec.name
        np.save(f"{stem}-blurred.npy", case.blurred)
        case.motion.save(f"{stem}-truth.json")
        if baseline is None:
            baseline = run_job({"kind": "baseline", "image": f"{stem}-blurred.npy"}, 300)
        max_blur = _max_blur(spec.extent, case.blurred.shape)
        row = {**asdict(spec), "shape": list(case.blurred.shape), "max_blur": max_blur,
               "true_extent": case.motion.blur_extent(),
               "blurred": {"psnr": aligned_psnr(case.blurred, case.sharp)}, "runs": {}}
        jobs = {m: {"kind": "estimate", "method": m, "model": spec.model,
                    "max_blur": max_blur, "n_iter": config.n_iter,
                    "motion": f"{stem}-{m}.json"} for m in METHODS}
        jobs["oracle"] = {"kind": "deconvolve", "motion": f"{stem}-truth.json"}
        for key, job in jobs.items():
            job.update(image=f"{stem}-blurred.npy", restored=f"{stem}-{key}.npy")
            res = run_job(job, config.timeout)
            done += 1
            entry = {k: res.get(k) for k in ("ok", "error", "estimate_s", "estimate_cpu_s",
                                             "deconvolve_s", "deconvolve_cpu_s",
                                             "peak_rss_mib", "n_profiles", "poses",
                                             "message", "warnings")}
            if res.get("ok"):
                restored = np.load(job["restored"])
                entry["psnr"] = aligned_psnr(restored, case.sharp)
                entry["gain"] = entry["psnr"] - row["blurred"]["psnr"]
                if key != "oracle":
                    entry["ncc"] = motion_psf_ncc(CameraMotion.load(job["motion"]),
                                                  case.motion)
                summary = (f"{entry['psnr']:.2f} dB ({entry['gain']:+.2f})"
                           + (f", NCC {entry['ncc']:.3f}" if "ncc" in entry else "")
                           + f", {entry.get('estimate_s') or entry['deconvolve_s']:.1f} s")
            else:
                summary = f"failed: {entry['error']}"
            row["runs"][key] = {k: v for k, v in entry.items() if v is not None}
            log(f"quality [{done}/{n_runs}] {spec.name} {_label(key)}: {summary}")
        cases.append(row)
    machine["load_average_end"] = load_average()
    return {"kind": "quality", "quick": config.quick, "machine": machine,
            "config": _config_dict(config), "baseline_rss_mib": (baseline or {}).get(
                "peak_rss_mib"), "cases": cases, "summary": _quality_summary(cases),
            "targets": _quality_targets(cases), "seconds": time.perf_counter() - t_start}


def _label(key: str) -> str:
    return METHODS.get(key, key)


def _config_dict(config: BenchConfig) -> dict:
    d = asdict(config)
    d["cases"] = [c["name"] for c in d["cases"]]
    return d


def _runs(cases, key):
    return [c["runs"].get(key, {}) for c in cases]


def _quality_summary(cases) -> list[dict]:
    rows = [{"key": "blurred", "n_ok": len(cases), "n": len(cases),
             "psnr": _mean([c["blurred"]["psnr"] for c in cases]), "gain": 0.0}]
    for key in (*METHODS, "oracle"):
        ok = [r for r in _runs(cases, key) if r.get("ok")]
        rows.append({
            "key": key, "n": len(cases), "n_ok": len(ok),
            "psnr": _mean([r["psnr"] for r in ok]),
            "gain": _mean([r["gain"] for r in ok]),
            "ncc": _mean([r.get("ncc") for r in ok]) if key != "oracle" else None,
            "estimate_s": _median([r.get("estimate_s") for r in ok]),
            "deconvolve_s": _median([r.get("deconvolve_s") for r in ok]),
            "peak_rss_mib": max((r["peak_rss_mib"] for r in ok if r.get("peak_rss_mib")),
                                default=None),
            "fell_back": sum("fell back" in (r.get("message") or "") for r in ok),
        })
    return rows


def _paired(cases, a: str, b: str | None, only=None):
    """Mean of PSNR(a) - PSNR(b) over cases where both succeeded (b None: the blurred)."""
    diffs = []
    for c in cases:
        if only is not None and not only(c):
            continue
        ra = c["runs"].get(a, {})
        rb = c["runs"].get(b, {}) if b else {"ok": True, "psnr": c["blurred"]["psnr"]}
        if ra.get("ok") and rb.get("ok"):
            diffs.append(ra["psnr"] - rb["psnr"])
    return (statistics.fmean(diffs), len(diffs)) if diffs else (None, 0)


def _quality_targets(cases) -> list[dict]:
    """The targets of the estimation and deconvolution issues, checked on these cases."""
    targets = []

    def add(text, value, n, bound, unit=" dB", higher=True):
        met = None if value is None else (value >= bound if higher else value <= bound)
        targets.append({"target": text, "value": value, "n": n, "met": met,
                        "shown": "—" if value is None else f"{value:+.2f}{unit}"})

    add("Xu+Ep mean PSNR >= Xu + 0.3 dB", *_paired(cases, "xu+ep", "xu"), 0.3)
    add("Xu+Ep mean PSNR >= blurred + 4 dB", *_paired(cases, "xu+ep", None), 4.0)
    add("Xu+Ep within 2 dB of the oracle", *_paired(cases, "xu+ep", "oracle"), -2.0)
    add("EpAlone >= blurred + 2 dB on the edge-rich scenes",
        *_paired(cases, "ep", None, only=lambda c: c["image"] == "edges"), 2.0)
    ok = [r["ncc"] for r in _runs(cases, "xu+ep") if r.get("ok")]
    value = statistics.fmean(ok) if ok else None
    targets.append({"target": "Xu+Ep mean PSF NCC >= 0.8", "value": value, "n": len(ok),
                    "met": None if value is None else value >= 0.8,
                    "shown": _f(value, ".3f")})
    add("oracle (hyper-Laplacian) mean gain >= 6 dB", *_paired(cases, "oracle", None), 6.0)
    return targets


def _met(flag) -> str:
    return {True: "met", False: "**missed**", None: "not measured"}[flag]


def quality_markdown(result: dict) -> str:
    """The quality benchmark as Markdown."""
    cases = result["cases"]
    cfg = result["config"]
    keys = (*METHODS, "oracle")
    names = {"blurred": "blurred", **METHODS, "oracle": "oracle"}
    lines = [f"# Quality benchmark{' (quick)' if result['quick'] else ''}", "",
             _machine_line(result["machine"]) + f"; {result['seconds'] / 60:.1f} min.", "",
             f"{len(cases)} synthetic cases at {cfg['size']} px (longer side): scikit-image "
             "photos and the edge-rich `edges` scene, shaken with a random trajectory of "
             "the `inplane` or `rotation` model (rendered exactly by dense warping), "
             f"{cfg['noise']:.0%} Gaussian noise, {cfg['bits']}-bit. Estimators get "
             f"`max_blur` = {MAX_BLUR_FACTOR:g} x the true extent and the engine's "
             "default parameters"
             + (f" except `n_iter` = {cfg['n_iter']}" if cfg.get("n_iter") else "")
             + "; every estimate and the oracle (true motion) are followed by the same "
             "hyper-Laplacian deconvolution. One run per case and method.", ""]
    summary = {r["key"]: r for r in result["summary"]}
    table = []
    for key in ("blurred", *keys):
        s = summary[key]
        succeeded = f"{s['n_ok']}/{s['n']}"
        if s.get("fell_back"):
            succeeded += f" ({s['fell_back']} fell back to Xu)"
        table.append([names[key], succeeded, _f(s["psnr"], ".2f"),
                      _f(s["gain"], "+.2f"), _f(s.get("ncc"), ".3f"),
                      _f(s.get("estimate_s"), ".1f"), _f(s.get("deconvolve_s"), ".1f"),
                      _f(s.get("peak_rss_mib"), ".0f")])
    lines += ["## Summary", "",
              markdown_table(["method", "succeeded", "mean PSNR (dB)", "mean gain (dB)",
                              "mean PSF NCC", "median estimate (s)", "median deconvolve (s)",
                              "max peak RSS (MiB)"], table, "lrrrrrrr"), "",
              "Means are over the cases where the method succeeded; gains are against the "
              "blurred input of the same case. Xu+Ep falls back to Xu (with a warning) "
              "when it finds fewer edge profiles than EpAlone needs.", ""]
    lines += ["## Targets", "",
              markdown_table(["target", "measured", "cases", "status"],
                             [[t["target"], t["shown"], t["n"], _met(t["met"])]
                              for t in result["targets"]], "lrrl"), ""]

    def cell(case, key, what):
        run = case["runs"].get(key, {})
        if not run.get("ok"):
            return "failed" if run else "—"
        return _f(run.get(what), {"psnr": ".2f", "ncc": ".3f"}.get(what, ".1f"))

    lines += ["## Aligned PSNR (dB) per case", "",
              markdown_table(["case", "blurred", *(names[k] for k in keys)],
                             [[c["name"], f"{c['blurred']['psnr']:.2f}",
                               *(cell(c, k, "psnr") for k in keys)] for c in cases],
                             "l" + "r" * (1 + len(keys))), ""]
    lines += ["## PSF NCC per case (centroid-aligned, 4x4 grid; 1 = same shapes)", "",
              markdown_table(["case", *(METHODS.values())],
                             [[c["name"], *(cell(c, k, "ncc") for k in METHODS)]
                              for c in cases], "l" + "r" * len(METHODS)), ""]
    detail = []
    for c in cases:
        for key in keys:
            run = c["runs"].get(key, {})
            if run.get("ok"):
                notes = "; ".join(run.get("warnings") or [])
                detail.append([c["name"], names[key], _f(run.get("estimate_s"), ".1f"),
                               _f(run.get("estimate_cpu_s"), ".1f"),
                               _f(run.get("deconvolve_s"), ".1f"),
                               _f(run.get("peak_rss_mib"), ".0f"),
                               _f(run.get("n_profiles"), "d", ""), _f(run.get("poses"), "d", ""),
                               notes])
            else:
                detail.append([c["name"], names[key], "", "", "", "", "", "",
                               f"failed: {run.get('error', 'not run')}"])
    lines += ["## Time and peak memory per run", "",
              markdown_table(["case", "method", "estimate (s)", "estimate CPU (s)",
                              "deconvolve (s)", "peak RSS (MiB)", "edge profiles", "poses",
                              "notes"], detail, "llrrrrrrl"), "",
              "Times are wall-clock seconds; CPU is the process's user + system time over "
              "all its threads (wall-clock much above CPU means the run waited for a shared "
              "CPU).", "",
              _memory_note(result.get("baseline_rss_mib")), ""]
    return "\n".join(lines)


def _memory_note(baseline) -> str:
    base = f" ({baseline:.0f} MiB here)" if baseline else ""
    return ("Peak RSS: each run is a fresh Python process reporting its own peak resident "
            "set size (`VmHWM` of `/proc/self/status`; not `ru_maxrss`, which on Linux "
            "inherits the parent's high-water mark through fork and exec). It includes the "
            "interpreter, the libraries and the loaded input, i.e. the baseline of a process "
            f"that only imports the engine and loads the input{base}.")


# --------------------------------------------------------------------------------------
# speed
# --------------------------------------------------------------------------------------

def _speed_inputs(config: BenchConfig, workdir: Path) -> dict:
    """The 800x800 gray case and (optionally) the 12 MP RGB case, blurred with the EFF."""
    from .core.camera import Intrinsics
    from .core.operators import blur
    from .core.synth import add_noise, densify_path, quantize, random_trajectory, sample_image

    rng = np.random.default_rng(0)
    paths = {}
    sharp = sample_image("camera", config.speed_size)
    intr = Intrinsics.from_image_shape(sharp.shape)
    truth = densify_path(random_trajectory("rotation", intr, SPEED_BLUR, rng=rng),
                         "rotation", intr)
    blurred = quantize(add_noise(blur(sharp, truth), NOISE, rng), BITS)
    for name, arr in (("sharp", sharp), ("blurred", blurred)):
        paths[name] = str(workdir / f"speed-{name}.npy")
        np.save(paths[name], arr)
    paths["truth"] = str(workdir / "speed-truth.json")
    truth.save(paths["truth"])
    if config.large:
        from skimage import data, transform

        photo = transform.resize(data.astronaut(), (*LARGE_SHAPE, 3), order=1,
                                 anti_aliasing=False).astype(np.float32)
        intr = Intrinsics.from_image_shape(LARGE_SHAPE)
        truth = densify_path(random_trajectory("rotation", intr, SPEED_BLUR, rng=rng),
                             "rotation", intr)
        large = quantize(add_noise(blur(photo, truth), NOISE, rng), BITS)
        paths["large"] = str(workdir / "large-blurred.npy")
        np.save(paths["large"], np.round(large * 255).astype(np.uint8))  # as a photo file
        paths["large_truth"] = str(workdir / "large-truth.json")
        truth.save(paths["large_truth"])
    return paths


def _repeat(job: dict, n: int, timeout: float) -> dict:
    """Run ``job`` ``n`` times in fresh processes: median times, largest peak memory."""
    runs = [run_job(job, timeout) for _ in range(n)]
    ok = [r for r in runs if r.get("ok")]
    if not ok:
        return {"ok": False, "error": runs[0].get("error"), "runs": n}
    out = {"ok": True, "runs": len(ok), "failed_runs": n - len(ok)}
    for key in ("estimate_s", "deconvolve_s", "estimate_cpu_s", "deconvolve_cpu_s"):
        if key in ok[0]:
            out[key] = _median([r.get(key) for r in ok])
            out[key + "_all"] = [r.get(key) for r in ok]
    out["peak_rss_mib"] = max((r["peak_rss_mib"] for r in ok if r.get("peak_rss_mib")),
                              default=None)
    for key in ("n_profiles", "poses", "message", "warnings"):
        if key in ok[0]:
            out[key] = ok[0][key]
    return out


def run_speed(config: BenchConfig, workdir: Path, log=None) -> dict:
    """Run the speed benchmark; return the JSON-ready result."""
    log = log or (lambda message: None)
    t_start = time.perf_counter()
    machine = machine_info()
    paths = _speed_inputs(config, workdir)
    s = config.speed_size
    rows = []
    baseline = run_job({"kind": "baseline", "image": paths["blurred"]}, 300)

    op = run_job({"kind": "operator", "image": paths["sharp"], "motion": paths["truth"],
                  "repeat": config.operator_repeat}, config.timeout)
    label = f"EFF operator, {s}x{s} gray float32, {SPEED_BLUR:g} px rotation"
    if op.get("ok"):
        detail = (f"{op['tiles'][0]}x{op['tiles'][1]} tiles, PSF {op['psf_size']} px, "
                  f"{op['poses']} poses; median of {config.operator_repeat}")
        for what in ("build", "forward", "adjoint"):
            rows.append({"task": f"{label}: {what}", "seconds": op[f"{what}_s"],
                         "detail": detail, "ok": True})
    else:
        rows.append({"task": label, "ok": False, "error": op.get("error")})
    log(f"speed: EFF operator {'done' if op.get('ok') else 'failed: ' + op.get('error', '')}")

    targets = {"ep": (10.0, 2048.0), "xu+ep": (60.0, 2048.0), "hyperlaplacian": (10.0, None)}
    for method in config.speed_methods:
        job = {"kind": "estimate", "image": paths["blurred"], "method": method,
               "model": "rotation", "max_blur": SPEED_BLUR, "n_iter": config.n_iter}
        res = _repeat(job, config.repeat, config.timeout)
        rows.append(_speed_row(f"estimation {METHODS[method]}, {s}x{s} gray, max_blur "
                               f"{SPEED_BLUR:g}, rotation", res, "estimate_s",
                               targets.get(method), config.repeat))
        log(f"speed: estimation {METHODS[method]}: {_speed_log(res, 'estimate_s')}")
    for method in config.deconv_methods:
        job = {"kind": "deconvolve", "image": paths["blurred"], "motion": paths["truth"],
               "method": method}
        res = _repeat(job, config.repeat, config.timeout)
        rows.append(_speed_row(f"deconvolution {method}, {s}x{s} gray, true motion", res,
                               "deconvolve_s", targets.get(method), config.repeat))
        log(f"speed: deconvolution {method}: {_speed_log(res, 'deconvolve_s')}")
    if config.large:
        job = {"kind": "deconvolve", "image": paths["large"], "motion": paths["large_truth"],
               "method": "hyperlaplacian"}
        res = _repeat(job, 1, max(config.timeout, 3600.0))
        rows.append(_speed_row(f"deconvolution hyperlaplacian, {LARGE_SHAPE[1]}x"
                               f"{LARGE_SHAPE[0]} RGB (12 MP, 8-bit), {SPEED_BLUR:g} px "
                               "rotation", res, "deconvolve_s", (180.0, 6144.0), 1))
        log(f"speed: 12 MP deconvolution: {_speed_log(res, 'deconvolve_s')}")
    machine["load_average_end"] = load_average()
    return {"kind": "speed", "quick": config.quick, "machine": machine,
            "config": _config_dict(config), "baseline_rss_mib": baseline.get("peak_rss_mib"),
            "rows": rows, "seconds": time.perf_counter() - t_start}


def _speed_row(task, res, key, target, runs) -> dict:
    row = {"task": task, "ok": res.get("ok", False), "runs": runs}
    if not res.get("ok"):
        row["error"] = res.get("error")
        return row
    row.update(seconds=res[key], all=res.get(key + "_all"), cpu_s=res.get(key[:-2] + "_cpu_s"),
               peak_rss_mib=res.get("peak_rss_mib"),
               detail=f"median of {res['runs']}" if res["runs"] > 1 else "1 run")
    if res.get("message"):
        row["detail"] += f"; {res['message']}"
    if res.get("n_profiles"):
        row["detail"] += f"; {res['n_profiles']} edge profiles"
    if target is not None:
        seconds, mib = target
        met = res[key] <= seconds and (mib is None or (res.get("peak_rss_mib") or 0) <= mib)
        row["target"] = (f"<= {seconds:g} s" + (f", <= {mib / 1024:g} GiB" if mib else ""))
        row["met"] = bool(met)
    return row


def _speed_log(res, key) -> str:
    if not res.get("ok"):
        return f"failed: {res.get('error')}"
    mem = f", peak {res['peak_rss_mib']:.0f} MiB" if res.get("peak_rss_mib") else ""
    return f"{res[key]:.1f} s{mem}"


def speed_markdown(result: dict) -> str:
    """The speed benchmark as Markdown."""
    table = []
    for r in result["rows"]:
        if not r.get("ok"):
            table.append([r["task"], "failed", "", "", f"{r.get('error')}"])
            continue
        target = f"{r['target']}: {_met(r['met'])}" if "target" in r else ""
        table.append([r["task"], f"{r['seconds']:.3f}" if r["seconds"] < 1 else
                      f"{r['seconds']:.1f}", _f(r.get("cpu_s"), ".1f", ""),
                      _f(r.get("peak_rss_mib"), ".0f", ""), target, r.get("detail", "")])
    lines = [f"# Speed benchmark{' (quick)' if result['quick'] else ''}", "",
             _machine_line(result["machine"]) + f"; {result['seconds'] / 60:.1f} min.", "",
             markdown_table(["task", "time (s)", "CPU (s)", "peak RSS (MiB)", "target",
                             "notes"], table, "lrrrll"), "",
             "Inputs are blurred with the EFF operator, 1 % noise, 8-bit. Operator times are "
             "medians of repeated applications in one process; estimation and deconvolution "
             "times are wall-clock seconds of the call in a fresh process (median where "
             "repeated), and CPU is the process's user + system time over all its threads "
             "(on an idle machine the wall-clock time is at most about the CPU time; much "
             "more means the run waited for a shared CPU). "
             + _memory_note(result.get("baseline_rss_mib")), ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------
# the command
# --------------------------------------------------------------------------------------

def run_bench(out="edgecme-bench", *, quick: bool = False, parts=("quality", "speed"),
              size: int | None = None, cases: int | None = None,
              speed_size: int | None = None, repeat: int | None = None, large: bool = True,
              n_iter: int | None = None, log=None) -> list[Path]:
    """Run the benchmarks and write ``<part>[-quick].md`` and ``.json`` into ``out``.

    Parameters
    ----------
    out : path-like
        Output folder, created if missing (its parent must exist). Only the report
        files are written, at the end (temporary name + rename).
    quick : bool
        The quick configuration (see :func:`make_config`).
    parts : sequence of {"quality", "speed"}
    size, cases, speed_size, repeat, large, n_iter
        Overrides of the configuration (the test suite shrinks the benchmark).
    log : callable, optional
        Called with one line per finished run.

    Returns
    -------
    list of Path
        The files written.
    """
    from .core import io as _io

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a folder")
    if not out.exists() and not out.parent.is_dir():
        raise ValueError(f"cannot create the benchmark folder {out}: its parent folder "
                         f"{out.parent} does not exist")
    unknown = set(parts) - {"quality", "speed"}
    if unknown:
        raise ValueError(f"unknown benchmark part(s) {sorted(unknown)}; use quality, speed")
    config = make_config(quick, size, cases, speed_size, repeat, large, n_iter)
    results = {}
    with tempfile.TemporaryDirectory(prefix="edgecme-bench-") as tmp:
        if "quality" in parts:
            results["quality"] = run_quality(config, Path(tmp), log)
        if "speed" in parts:
            results["speed"] = run_speed(config, Path(tmp), log)
    suffix = "-quick" if quick else ""
    render = {"quality": quality_markdown, "speed": speed_markdown}
    out.mkdir(exist_ok=True)
    written = []
    with contextlib.ExitStack() as stack:
        for part, result in results.items():
            for ext, text in ((".md", render[part](result)),
                              (".json", json.dumps(result, indent=1, default=float) + "\n")):
                path = out / f"{part}{suffix}{ext}"
                tmp_path = stack.enter_context(_io.atomic_path(path))
                tmp_path.write_text(text, encoding="utf-8")
                written.append(path)
    return written


if __name__ == "__main__":
    _worker_main()
