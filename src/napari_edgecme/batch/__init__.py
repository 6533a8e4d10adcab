"""Batch deblurring: many photos, one Dask task per photo, a report, resumable.

::

    from napari_edgecme import deblur_many

    result = deblur_many(["shoot/", "more/*.jpg"], "restored/", method="xu+ep")
    print(result.counts, result.report_html)

Each photo is deblurred exactly as ``edgecme deblur`` does it (the same reading, option
checks, estimation, deconvolution and output encoding, :mod:`napari_edgecme.cli`), as one
task on a Dask cluster: by default a :class:`distributed.LocalCluster` sized to this
machine (:func:`local_cluster_size`), or an existing cluster (``client=`` or
``scheduler="tcp://host:port"``). ``workers=1`` runs the photos one after the other in
this process, without Dask.

Data flow
---------
The client reads each photo's bytes and sends them with the task; the task decodes,
deblurs and encodes its outputs in a private temporary folder of the worker and returns
them as bytes; the client writes them into ``out_dir``, each file atomically
(:class:`~napari_edgecme.core.io.atomic_path`). Workers therefore need napari-edgecme
installed but no shared file system, and nothing half-written ever appears in
``out_dir``: a worker that crashes writes nothing.

Outputs, for a photo named ``NAME`` (its path relative to the folder given, or its file
name): ``out_dir/NAME`` the restored image (format by extension, 16-bit in gives 16-bit
out, as ``deblur``), ``out_dir/NAME.motion.json`` the motion (written last: it marks the
photo complete), thumbnails in ``out_dir/thumbs/``, and ``report.csv`` and
``report.html`` (one row per photo), rewritten as each result arrives.

A rerun skips every photo whose image and motion file exist (``force=True`` redoes
them); failed photos have no outputs and are tried again. A first KeyboardInterrupt
(Ctrl-C) stops scheduling and lets the running photos finish and be written; a second
cancels them. Either way the report is written and KeyboardInterrupt is raised again.

Layout: :mod:`._photos` (collecting the inputs), :mod:`._task` (one photo),
:mod:`._report` (the rows and report files), :mod:`._cluster` (Dask), :mod:`._run`
(running the photos), this module (:func:`deblur_many`).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

from ..core.progress import Progress
from ._cluster import INSTALL_HINT as INSTALL_HINT
from ._cluster import WORKER_MEMORY as WORKER_MEMORY
from ._cluster import Cluster, local_cluster_size
from ._cluster import dask_setup as dask_setup
from ._photos import THUMBS as THUMBS
from ._photos import Photo, collect_photos
from ._report import DONE as DONE
from ._report import FAILED, SKIPPED, BatchResult, Report, read_previous, save_outputs
from ._report import NO_BLUR as NO_BLUR
from ._report import NOT_RUN as NOT_RUN
from ._report import REPORT_FIELDS as REPORT_FIELDS
from ._run import ESTIMATION_PARAMS as ESTIMATION_PARAMS
from ._run import Tally, batch_options, run_dask, run_sequential
from ._task import THUMB_SIDE as THUMB_SIDE
from ._task import deblur_photo

__all__ = ["BatchResult", "Photo", "collect_photos", "deblur_many", "deblur_photo",
           "local_cluster_size"]


def deblur_many(paths, out_dir, method: str = "xu+ep", model: str = "rotation",
                max_blur: float | None = None, focal_px: float | None = None, *,
                deconvolution: str = "hyperlaplacian", deconv_params: dict | None = None,
                gamma="auto", recursive: bool = False, force: bool = False, client=None,
                scheduler: str | None = None, workers: int | None = None,
                callback: Callable[[Progress], None] | None = None,
                log: Callable[[str], None] | None = None,
                warn: Callable[[str], None] | None = None, **params) -> BatchResult:
    """Deblur many photos, one Dask task each, with a report; resumable.

    Every photo is deblurred as ``edgecme deblur PHOTO -o OUT --seed N`` would (same
    options and outputs, bit-identical files), see the module notes for the outputs.

    Parameters
    ----------
    paths : str, path-like or iterable of them
        Photo files, folders and glob patterns (:func:`collect_photos`).
    out_dir : path-like
        Output folder, created if missing.
    method, model, max_blur, focal_px
        As :func:`~napari_edgecme.core.deblur.deblur`, for every photo (``max_blur``:
        default measured from each photo, as
        :func:`~napari_edgecme.core.blur_size.resolve_max_blur` does; ``focal_px``:
        default each photo's EXIF, else the 35 mm-equivalent default).
    deconvolution : {"hyperlaplacian", "rl", "wiener"}
    deconv_params : dict, optional
        ``lambda_f``, ``color``, ``chroma`` (hyperlaplacian), ``iterations`` (rl) or
        ``nsr`` (wiener) of the deconvolution, as ``edgecme batch`` takes them (``lam``,
        deprecated: ``lambda_f = 2 / lam``); other parameters are refused.
    gamma : {"auto", "linear", "srgb"}, float or Gamma
        Each photo's transfer curve, as ``edgecme deblur --gamma``: the motion is
        estimated and the photo deconvolved in linear light and the output re-encoded as
        the photo was; ``"auto"`` (default) decides per photo from its file
        (:func:`~napari_edgecme.core.photometry.decide_gamma`: 8-bit JPEG/PNG -> sRGB,
        16-bit or float TIFF -> linear, colour tags first). The summary line says what
        was chosen.
    recursive : bool
        Include the photos of sub-folders.
    force : bool
        Redo photos whose outputs exist (by default they are skipped).
    client : distributed.Client, optional
        Run on this client's cluster (it is left open).
    scheduler : str, optional
        Address of a running Dask scheduler, e.g. ``"tcp://10.0.0.5:8786"``.
    workers : int, optional
        Workers of the local cluster (default: :func:`local_cluster_size`); ``1`` runs
        the photos one at a time in this process, without Dask.
    callback : callable, optional
        Called with a :class:`~napari_edgecme.core.progress.Progress` record (stage
        ``"batch"``, one step per photo) whenever a photo starts or ends.
    log, warn : callable, optional
        Called with one line per finished photo and about the cluster; with each
        warning about a photo.
    **params
        ``rng`` (an integer seed, default 0) and the estimation parameters
        ``lambda_w``, ``lambda_ip``, ``lambda_f``, ``n_iter``, ``max_side``, ``refine``.

    Returns
    -------
    BatchResult
        The report's rows; ``result.ok`` is False when some photo failed.

    Raises
    ------
    ValueError
        Bad options or inputs (one line), before any photo runs; a scheduler that cannot
        be reached.
    ImportError
        Dask is not installed and ``workers`` is not 1.
    KeyboardInterrupt
        After the report was written, when interrupted.

    Examples
    --------
    >>> result = deblur_many("photos/", "restored/", n_iter=2)  # doctest: +SKIP
    >>> result.counts                                            # doctest: +SKIP
    {'done': 5, 'no blur': 1}
    """
    t0 = time.monotonic()
    options = batch_options(method, model, max_blur, focal_px, deconvolution, deconv_params,
                       dict(params), gamma)
    if sum(x is not None for x in (client, scheduler)) > 1:
        raise ValueError("pass either client or scheduler, not both")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ValueError(f"workers must be a positive integer; got {workers!r}")
    if workers is not None and (client is not None or scheduler is not None):
        raise ValueError("workers sizes the local cluster; it does not apply to an existing "
                         "cluster (client or scheduler)")
    log = log or (lambda _text: None)
    warn = warn or (lambda _text: None)
    callback = callback or (lambda _record: None)
    out_dir = Path(out_dir)
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"output folder {out_dir} is a file")
    photos = collect_photos(paths, out_dir, recursive)
    out_dir.mkdir(parents=True, exist_ok=True)
    if not os.access(out_dir, os.W_OK):
        raise ValueError(f"output folder is not writable: {out_dir}")

    report = Report(photos, out_dir)
    previous = read_previous(report.csv)
    todo = []
    for photo in photos:
        if not force and photo.complete(out_dir):
            earlier = previous.get(photo.name, {})
            files = {role: path.relative_to(out_dir).as_posix()
                     for role, path in photo.outputs(out_dir).items() if path.is_file()}
            report.set(photo.name, {**{k: earlier.get(k, "") for k in REPORT_FIELDS},
                                    **files, "photo": photo.name, "source": str(photo.source),
                                    "status": SKIPPED,
                                    "reason": "outputs of an earlier run kept (force to redo)"})
        else:
            todo.append(photo)
    tally = Tally(total=len(todo))

    def on_result(photo: Photo, row: dict) -> None:
        files = row.pop("files", {})
        summary = row.pop("summary", "")
        if files:
            row.update(save_outputs(photo, out_dir, files))
        report.set(photo.name, row)
        report.write()
        tally.finished += 1
        tally.failed += row["status"] == FAILED
        for note in row.pop("notes", []):
            warn(f"{photo.name}: {note}")
        if row["status"] == FAILED:
            log(f"{photo.name}: failed: {row.get('reason', '')}")
        else:
            log(f"{photo.name}: {summary}")

    interrupted = False
    where = "this process, one photo at a time (workers=1)"
    try:
        if workers == 1 and client is None and scheduler is None:
            report.heading = f"{len(photos)} photos; running in {where}"
            report.write()
            if todo:
                log(f"{len(todo)} of {len(photos)} photos to deblur in {where}")
            run_sequential(todo, options, on_result, tally, callback)
        elif todo:
            cluster = Cluster(client, scheduler, workers)
            with cluster as dask_client:
                where = cluster.description
                report.heading = f"{len(photos)} photos; running on {where}"
                report.write()
                log(f"{len(todo)} of {len(photos)} photos to deblur on {where}")
                run_dask(dask_client, todo, options, on_result, tally, callback, log)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        seconds = time.monotonic() - t0
        counts = BatchResult(list(report.rows.values()), out_dir, report.csv, report.html
                             ).counts
        report.heading = (f"{len(photos)} photos on {where}: " + ", ".join(
            f"{n} {status}" for status, n in counts.items())
            + f"; {seconds:.0f} s" + (" (interrupted)" if interrupted else ""))
        report.write(final=True)
    result = BatchResult(list(report.rows.values()), out_dir, report.csv, report.html,
                         cluster=where, interrupted=interrupted, seconds=seconds)
    if interrupted:
        raise KeyboardInterrupt
    return result
