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
    Every estimation or deconvolution runs in a fresh Python process (:mod:`napari_edgecme._worker`
    run as a module, reading a job as JSON on stdin), which
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
the date, the machine (``platform.node()``, CPU count) and the package versi

Layout: :mod:`._config` (the cases and rows), :mod:`._quality`, :mod:`._speed`, this module
(:func:`run_bench`, writing the reports); the fresh-process jobs are
:mod:`napari_edgecme._worker`, the report helpers :mod:`napari_edgecme._report`.
"""

from __future__ import annotations

import contextlib
import json
import tempfile
from pathlib import Path

from .._report import check_out_folder, load_average, machine_info, markdown_table
from .._worker import run_job
from ._config import (
    MAX_BLUR_FACTOR,
    METHODS,
    SPEED_BLUR,
    BenchConfig,
    CaseSpec,
    make_config,
)
from ._quality import quality_markdown, run_quality
from ._speed import run_speed, speed_markdown

__all__ = [
    "MAX_BLUR_FACTOR",
    "METHODS",
    "SPEED_BLUR",
    "BenchConfig",
    "CaseSpec",
    "load_average",
    "machine_info",
    "make_config",
    "markdown_table",
    "quality_markdown",
    "run_bench",
    "run_job",
    "run_quality",
    "run_speed",
    "speed_markdown",
]


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
    from ..core import io as _io

    out = Path(out)
    check_out_folder(out, "benchmark")
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
