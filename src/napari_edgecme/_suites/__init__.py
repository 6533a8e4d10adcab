"""``edgecme bench --suite {lai,lai-srgb,levin,real}``: benchmarks on real camera shake and real
captures.

The synthetic bench (:mod:`.._bench`) blurs photos with the project's own model of a shake;
these suites measure the estimators on data the project did not make:

``lai``
    Real camera shakes recorded with a gyroscope (Lai et al., CVPR 2016), rendered on
    natural photos of five categories (manmade, natural, people, saturated, text) by an
    independent renderer, with the true motion (``../shared/data/lai``: 60 cases,
    ``quick.txt`` 20 of them). Each estimator is told the case's ``max_blur`` and the
    true focal length. PSNR and SSIM are measured after the best global shift *and*
    in-plane rotation (:func:`~.core.metrics.aligned_scores`): a blind estimate is right
    only up to its centroid pose, and these trajectories start at the identity, so their
    centroid pose is rotated by up to about a degree. Also: centroid-aligned PSF NCC of
    each estimate against the truth, edge-profile count, fidelity and yield of the edge
    profiles at the true and at the default max blur
    (:func:`~.core.metrics.profile_fidelity`), the collapse indicator, time and peak
    memory.
``lai-srgb``
    The ``lai`` cases rendered in the physically right order (:func:`._data.lai_srgb_case`):
    the sharp photo linearised, blurred in linear light with the true motion, encoded to
    sRGB, noise as ``lai``'s, 8 bits; scored against the sRGB ``sharp.png`` with ``lai``'s
    protocol. Rendered once into a cache folder (``cache=``, default
    :func:`._data.default_cache_dir`). Run it with ``gamma="srgb"`` (or ``"auto"``) against
    ``gamma="linear"`` to measure estimating and deconvolving in linear light.
``levin``
    The 32 real captures of Levin et al. (CVPR 2009; ``../shared/data/levin``), uniform
    blur, estimated with the ``translation`` model. Same columns, and the figures under the
    protocol the folder's README states for its anchors (8 cases, global shift at
    1/10 px, 24 px border crop: Pan et al. 2016 30.47 dB).
``real``
    The paper's 10 real photos (``../shared/data/paper-real``), no ground truth: each is
    deblurred through the command line, exactly as a user would (``edgecme deblur``, the
    default method Xu+Ep and ``--method ep``, default options otherwise), and a
    side-by-side sheet is drawn per photo: input | EpAlone | Xu+Ep | the paper's EpAlone |
    the paper's Xu+Ep, with the same crops at 1:1 below.

``gamma`` (``"linear"`` by default: the values as they are): with ``"srgb"``, a power-law
exponent or ``"auto"`` (decided from each case's file, as ``edgecme deblur --gamma auto``:
the 8-bit PNGs of ``lai`` and ``lai-srgb`` -> srgb, ``levin``'s ``.mat`` floats -> linear),
every estimate and deconvolution is given the blurred image in linear light and its result
is re-encoded before it is scored.

Every estimate runs in a fresh process (:func:`._worker.run_job`), so its peak memory is
its own; ``jobs`` cases run at once (times are then those of a shared machine). Results go
to ``<suite>[-quick].md`` and ``.json`` (and ``real-sheets/``) in the output folder,
written when the suite ends (temporary name + rename).

Layout: :mod:`._data` (where the data is, loading a case), :mod:`._cases` (running one
case), :mod:`._tables` (summaries and Markdown), this module (:func:`run_suite`).
"""

from __future__ import annotations

import contextlib
import json
import math
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from .._report import check_out_folder, load_average, machine_info
from ._cases import FAITHFUL_NCC, METHODS, profile_measures, run_real_photo, run_truth_case
from ._data import (
    CATEGORIES,
    SUITES,
    default_cache_dir,
    default_data_dir,
    float_image,
    lai_cases,
    lai_load,
    lai_srgb_case,
    levin_cases,
    levin_motion,
    real_photos,
)
from ._tables import real_markdown, summarise, targets, truth_markdown

__all__ = ["CATEGORIES", "FAITHFUL_NCC", "SUITES", "default_data_dir", "float_image",
           "lai_cases", "lai_load", "levin_motion", "profile_measures", "real_photos",
           "run_suite"]


def run_suite(suite: str, out="edgecme-bench", *, data=None, quick: bool = False,
              jobs: int = 1, methods=tuple(METHODS), n_iter: int | None = None,
              cases: int | None = None, log=None, gamma="linear",
              cache=None) -> list[Path]:
    """Run one suite and write its report (Markdown + JSON) into ``out``.

    Parameters
    ----------
    suite : {"lai", "lai-srgb", "levin", "real"}
    out : path-like
        Output folder, created if missing (its parent must exist).
    data : path-like, optional
        The suite's data folder (default :func:`default_data_dir`).
    quick : bool
        ``lai``: the 20 cases of ``quick.txt``; ``levin``: the 8 anchor cases.
    jobs : int
        Cases run at once (each estimate is its own process).
    methods : sequence of {"ep", "xu", "xu+ep"}
        Estimators to run (``real``: EpAlone and Xu+Ep).
    n_iter, cases : int, optional
        Overrides (alternations per scale; the first ``cases`` cases only).
    log : callable, optional
        Called with one line per finished case.
    gamma : {"linear", "srgb", "auto"} or float
        The transfer curve the ground-truth suites are run with (see the module notes;
        not used by ``real``, whose command lines decide for themselves).
    cache : path-like, optional
        ``lai-srgb``: the folder of its rendered cases (default
        :func:`._data.default_cache_dir`).

    Returns
    -------
    list of Path
        The files written.
    """
    from ..core import io as _io

    if suite not in SUITES:
        raise ValueError(f"unknown suite {suite!r}; use one of {', '.join(SUITES)}")
    log = log or (lambda message: None)
    data = Path(data) if data is not None else default_data_dir(suite)
    if data is None or not data.is_dir():
        where = f"{data}" if data is not None else f"../shared/data/{SUITES[suite]}"
        raise ValueError(f"no data for suite {suite!r}: {where} is not a folder "
                         "(pass --data DIR)")
    out = Path(out)
    check_out_folder(out, "benchmark")
    from ..core.photometry import parse_gamma

    parse_gamma(gamma)  # a bad value fails before any case runs
    unknown = set(methods) - set(METHODS)
    if unknown:
        raise ValueError(f"unknown method(s) {sorted(unknown)}; use {', '.join(METHODS)}")
    jobs = max(1, int(jobs))
    machine = machine_info()
    t_start = time.perf_counter()
    out.mkdir(exist_ok=True)
    suffix = "-quick" if quick and suite != "real" else ""
    with tempfile.TemporaryDirectory(prefix=f"edgecme-{suite}-") as tmp:
        workdir = Path(tmp)
        if suite == "real":
            methods = tuple(m for m in ("ep", "xu+ep") if m in methods) or ("ep", "xu+ep")
            photos = real_photos(data)[:cases]
            if not photos:
                raise ValueError(f"no photos in {data} (expected <scene>/input.* folders)")
            sheets = out / "real-sheets"
            sheets.mkdir(exist_ok=True)
            with ThreadPoolExecutor(jobs) as pool:
                rows = list(pool.map(lambda p: run_real_photo(p, workdir, sheets, methods,
                                                               log), photos))
            result = {"suite": suite, "methods": list(methods), "photos": rows,
                      "protocol": ("Each photo deblurred by `edgecme deblur INPUT -o OUT "
                                   "--method M` with every other option at its default (max "
                                   "blur, focal length, model); edge profiles counted by "
                                   "`edgecme profiles` at the default max blur."),
                      "data": str(data)}
            render = real_markdown
        else:
            lai = suite in ("lai", "lai-srgb")
            found = (lai_cases if lai else levin_cases)(data, quick)[:cases]
            if not found:
                raise ValueError(f"no cases in {data}")
            if suite == "lai-srgb":
                cache = Path(cache) if cache is not None else default_cache_dir()
                cache.mkdir(parents=True, exist_ok=True)
                with ThreadPoolExecutor(jobs) as pool:
                    found = list(pool.map(lambda c: lai_srgb_case(c, cache), found))
            with ThreadPoolExecutor(jobs) as pool:
                rows = list(pool.map(lambda c: run_truth_case(
                    c, "lai" if lai else suite, workdir, methods, n_iter, log, gamma), found))
            protocol = (
                "Aligned PSNR/SSIM: after the best global sub-pixel shift and in-plane "
                "rotation (up to 2 degrees), 5% border crop; each estimator told the case's "
                "max blur and the true focal length; model `rotation`; every estimate "
                "followed by the same hyper-Laplacian deconvolution; oracle = that "
                "deconvolution with the true motion." if lai else
                "Aligned PSNR/SSIM: after the best global sub-pixel shift and in-plane "
                "rotation, 5% border crop; model `translation`; each estimator told the "
                "kernel's size (the benchmark's sizeL) as its max blur; the same "
                "hyper-Laplacian deconvolution after every estimate; oracle = that "
                "deconvolution with the kernel `f` of the capture (as a correlation "
                "kernel).")
            if suite == "lai-srgb":
                protocol = ("Cases: each lai case re-rendered in linear light (sharp.png "
                            "linearised, blurred with truth.json, sRGB-encoded, Gaussian "
                            "noise sigma 0.01 on the encoded scale, 8 bits); scored against "
                            "the sRGB sharp.png. " + protocol)
            if str(gamma) != "linear":
                chosen = sorted({f"{r['gamma']} ({r['gamma_reason']})" for r in rows})
                protocol += (f" Gamma {gamma}: estimated and deconvolved in linear light, "
                             "re-encoded before scoring; chosen: " + "; ".join(chosen) + ".")
            result = {"suite": suite, "quick": quick, "methods": list(methods),
                      "gamma": str(gamma),
                      "cases": rows, "summary": summarise(rows, methods),
                      "targets": targets(rows, methods), "protocol": protocol,
                      "data": str(data)}
            render = truth_markdown
        machine["load_average_end"] = load_average()
        result.update(machine=machine, jobs=jobs, quick=quick,
                      seconds=time.perf_counter() - t_start)
    written = []
    with contextlib.ExitStack() as stack:
        for ext, text in ((".md", render(result)),
                          (".json", json.dumps(result, indent=1, default=_jsonable) + "\n")):
            path = out / f"{suite}{suffix}{ext}"
            tmp_path = stack.enter_context(_io.atomic_path(path))
            tmp_path.write_text(text, encoding="utf-8")
            written.append(path)
    return written


def _jsonable(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and math.isnan(obj):
        return None
    return str(obj)
