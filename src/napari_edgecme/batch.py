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
"""

from __future__ import annotations

import argparse
import csv
import glob
import html
import io
import os
import tempfile
import time
import uuid
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import _bench
from .cli._console import PROG, CLIError, _Console, oserror_message
from .cli._deblur import deblur_image, estimate_summary
from .cli._files import output_bits, read_input_image
from .cli._options import deconvolution_params
from .core import io as _io
from .core._validation import first_line
from .core.camera import MODELS
from .core.progress import Progress

__all__ = ["BatchResult", "Photo", "collect_photos", "deblur_many", "deblur_photo",
           "local_cluster_size"]

#: Install hint when Dask is missing.
INSTALL_HINT = 'pip install "napari-edgecme[batch]"'
#: Row statuses: restored, no blur found (the photo is written unchanged: not a
#: failure), failed (reason given), outputs of an earlier run kept, not run (interrupted).
DONE, NO_BLUR, FAILED, SKIPPED, NOT_RUN = "done", "no blur", "failed", "skipped", "not run"
#: Columns of ``report.csv`` (the HTML report shows the same, with the thumbnails).
REPORT_FIELDS = ("photo", "status", "method", "blur_extent_px", "profiles", "seconds",
                 "reason", "warnings", "output", "motion", "before", "after", "psf",
                 "worker", "worker_peak_mib", "source")
#: Longer side of the before/after thumbnails (pixels).
THUMB_SIDE = 192
#: Memory a worker should have for one photo (a 12 MP RGB photo peaks at about 1.4 GiB).
WORKER_MEMORY = 2 * 2**30
#: Estimation options a batch takes (as :func:`~napari_edgecme.core.estimate.deblur`).
ESTIMATION_PARAMS = ("lambda_w", "lambda_ip", "lambda_f", "n_iter", "max_side")
THUMBS = "thumbs"
_BLAS_ONE_THREAD = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                           "MKL_NUM_THREADS", "EDGECME_FFT_THREADS")}
_GLOB_CHARS = set("*?[")


# --------------------------------------------------------------------------------------
# inputs
# --------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Photo:
    """One input photo: its file and the name of its outputs inside the output folder."""

    source: Path
    name: str

    def outputs(self, out_dir: Path) -> dict[str, Path]:
        """The files a finished photo has in ``out_dir``, by role."""
        thumbs = out_dir / THUMBS
        return {"output": out_dir / self.name,
                "motion": out_dir / f"{self.name}.motion.json",
                "before": thumbs / f"{self.name}.before.png",
                "after": thumbs / f"{self.name}.after.png",
                "psf": thumbs / f"{self.name}.psf.png"}

    def complete(self, out_dir: Path) -> bool:
        """True when the restored image and the motion file (written last) both exist."""
        files = self.outputs(out_dir)
        return files["output"].is_file() and files["motion"].is_file()


def _is_image(path: Path) -> bool:
    return path.suffix.lower() in _io.IMAGE_SUFFIXES and not path.name.startswith(".")


def collect_photos(inputs: Iterable, out_dir=None, recursive: bool = False) -> list[Photo]:
    """The photos named by files, folders and glob patterns, in the order given.

    Parameters
    ----------
    inputs : iterable of str or path-like
        Files (taken whatever their extension), folders (their image files:
        ``.png .tif .tiff .jpg .jpeg .bmp``, hidden files excluded) and glob patterns
        (``*``, ``?``, ``[...]``; ``**`` with ``recursive``).
    out_dir : path-like, optional
        The output folder: files inside it are never inputs, and outputs may not
        overwrite an input.
    recursive : bool
        Also the image files of sub-folders; their outputs mirror the sub-folders.

    Returns
    -------
    list of Photo
        Each file once; the name of a folder's photo is its path relative to the folder,
        any other photo's its file name.

    Raises
    ------
    ValueError
        One line: an input that does not exist, matches nothing or holds no images, two
        photos whose outputs would have the same name, or an output that would overwrite
        an input.
    """
    out = Path(out_dir).resolve() if out_dir is not None else None

    def outside(path: Path) -> bool:
        return out is None or not path.resolve().is_relative_to(out)

    found: list[Photo] = []
    for item in inputs:
        text = os.fspath(item)
        path = Path(text)
        if path.is_dir():
            if out is not None and path.resolve().is_relative_to(out):
                raise ValueError(f"the output folder {out_dir} would overwrite the input "
                                 f"folder {path}; choose an output folder outside it")
            pattern = "**/*" if recursive else "*"
            files = sorted(p for p in path.glob(pattern) if p.is_file() and _is_image(p)
                           and outside(p))
            if not files:
                raise ValueError(f"no image files ({', '.join(_io.IMAGE_SUFFIXES)}) in "
                                 f"folder {path}" + ("" if recursive else " (-r for sub-folders)"))
            found += [Photo(p, p.relative_to(path).as_posix()) for p in files]
        elif path.is_file():
            found.append(Photo(path, path.name))
        elif _GLOB_CHARS & set(text):
            matches = sorted(Path(p) for p in glob.glob(text, recursive=recursive))
            files = [p for p in matches if p.is_file() and _is_image(p) and outside(p)]
            if not files:
                raise ValueError(f"no image files match {text}")
            found += [Photo(p, p.name) for p in files]
        else:
            raise ValueError(f"input not found: {text}")
    photos: list[Photo] = []
    seen_sources: set[Path] = set()
    by_name: dict[str, Photo] = {}
    for photo in found:
        key = photo.source.resolve()
        if key in seen_sources:
            continue
        seen_sources.add(key)
        other = by_name.get(photo.name)
        if other is not None:
            raise ValueError(f"{other.source} and {photo.source} would both be written as "
                             f"{photo.name}; run them as separate batches")
        by_name[photo.name] = photo
        if out is not None and any(p.resolve() == key
                                   for p in photo.outputs(out).values()):
            raise ValueError(f"the output folder {out_dir} would overwrite the input "
                             f"{photo.source}; choose another output folder")
        photos.append(photo)
    return photos


# --------------------------------------------------------------------------------------
# one photo (the task)
# --------------------------------------------------------------------------------------

def _thumbnail(image: np.ndarray, side: int = THUMB_SIDE) -> np.ndarray:
    """A float image in [0, 1] whose longer side is at most ``side`` (area averaging)."""
    from skimage.transform import resize

    from .core._validation import as_float_image

    arr = as_float_image(image, allow_rgb=True)
    scale = side / max(arr.shape[:2])
    if scale >= 1:
        return arr
    shape = tuple(max(1, round(n * scale)) for n in arr.shape[:2]) + arr.shape[2:]
    return np.clip(resize(arr, shape, anti_aliasing=True), 0, 1)


def _psf_thumbnail(motion, side: int = THUMB_SIDE) -> np.ndarray:
    """The motion's 5x5 PSF field, max-pooled so that thin PSFs survive the reduction."""
    from skimage.measure import block_reduce

    field_image = motion.psf_field(grid=(5, 5))
    factor = max(1, int(np.ceil(max(field_image.shape) / side)))
    return block_reduce(field_image, (factor, factor), np.max)


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return "this process"


def deblur_photo(name: str, data: bytes, options: argparse.Namespace) -> dict:
    """Deblur one photo given as file bytes, as ``edgecme deblur`` would; the batch's task.

    Parameters
    ----------
    name : str
        The photo's output name (its extension picks the output format).
    data : bytes
        The photo file's content.
    options : argparse.Namespace
        The ``edgecme deblur`` options (``method``, ``model``, ``max_blur``, ``seed``,
        ``deconvolution``, ...), as :func:`deblur_many` builds them.

    Returns
    -------
    dict
        The photo's report row (``status``, ``method``, ``blur_extent_px``, ...,
        ``summary``: the line ``deblur`` would print) and ``files``: output role ->
        encoded bytes (``output``, ``motion``, ``before``, ``after``, ``psf``). A failure
        is a row with status ``"failed"``, its one-line ``reason`` and no files; it is
        never raised.
    """
    t0 = time.perf_counter()
    row: dict = {"photo": name, "status": FAILED, "files": {}}
    with tempfile.TemporaryDirectory(prefix="edgecme-batch-") as tmp:
        folder = Path(tmp)
        src = folder / Path(name).name
        src.write_bytes(data)
        stream = io.StringIO()  # the CLI's warnings about the input (alpha channel)
        console = _Console(quiet=True, stream=stream)

        def own(text: str) -> str:  # messages name the photo, not the temporary copy
            return text.replace(str(src), name)

        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                image = read_input_image(src, console)
                restored, result, max_blur, source, _ = deblur_image(
                    options, console, image, src,
                    deconvolution_params(options, options.deconvolution))
                encoded = folder / ("restored" + Path(name).suffix)
                _io.write_image(encoded, restored, bits=output_bits(image))
                result.motion.save(folder / "motion.json")
                _io.write_image(folder / "before.png", _thumbnail(image))
                _io.write_image(folder / "after.png", _thumbnail(restored))
                _io.write_image(folder / "psf.png", _psf_thumbnail(result.motion))
            info = result.info
            row.update(
                status=NO_BLUR if info.no_blur else DONE,
                method=info.method,
                blur_extent_px=round(float(result.motion.blur_extent()), 2),
                profiles=info.n_profiles,
                summary=own(estimate_summary(result, options.method, max_blur, source)),
                files={role: (folder / file).read_bytes() for role, file in (
                    ("output", encoded.name), ("before", "before.png"),
                    ("after", "after.png"), ("psf", "psf.png"), ("motion", "motion.json"))})
            notes = [line.removeprefix(f"{PROG}: warning: ")
                     for line in stream.getvalue().splitlines()]
            notes += [first_line(w.message) for w in caught
                      if issubclass(w.category, UserWarning)]
            row["notes"] = [own(note) for note in dict.fromkeys(notes)]
            row["warnings"] = " | ".join(row["notes"])
        except (CLIError, ValueError) as err:
            row["reason"] = own(first_line(err))
        except MemoryError:
            row["reason"] = "out of memory; try a smaller max_side for the estimation"
        except OSError as err:
            row["reason"] = own(oserror_message(err))
        except Exception as err:  # a bug: the batch goes on, the report says what it was
            row["reason"] = f"internal error: {type(err).__name__}: {own(first_line(err))}"
    row["seconds"] = round(time.perf_counter() - t0, 2)
    row["worker"] = _worker_name()
    peak = _bench._peak_rss_mib()  # the worker process's own high-water mark
    row["worker_peak_mib"] = round(peak) if peak is not None else ""
    return row


# --------------------------------------------------------------------------------------
# the report
# --------------------------------------------------------------------------------------

@dataclass
class BatchResult:
    """What :func:`deblur_many` did.

    Attributes
    ----------
    rows : list of dict
        One report row per photo, in input order (keys :data:`REPORT_FIELDS`).
    out_dir, report_csv, report_html : Path
    cluster : str
        Where the photos ran, e.g. ``"local Dask cluster: 2 workers x 1 thread"``.
    interrupted : bool
        True when a KeyboardInterrupt stopped the batch.
    """

    rows: list[dict]
    out_dir: Path
    report_csv: Path
    report_html: Path
    cluster: str = ""
    interrupted: bool = False
    seconds: float = 0.0

    @property
    def counts(self) -> dict[str, int]:
        """Photos per status."""
        statuses = [row["status"] for row in self.rows]
        return {status: statuses.count(status)
                for status in (DONE, NO_BLUR, SKIPPED, FAILED, NOT_RUN) if status in statuses}

    @property
    def failed(self) -> list[dict]:
        """The rows of the photos that failed."""
        return [row for row in self.rows if row["status"] == FAILED]

    @property
    def ok(self) -> bool:
        """True when every photo was restored (or had no blur) in this run or an earlier one."""
        return all(row["status"] in (DONE, NO_BLUR, SKIPPED) for row in self.rows)


def _read_previous(path: Path) -> dict[str, dict]:
    """Rows of an earlier run's ``report.csv`` by photo name (empty if none or unreadable)."""
    try:
        with open(path, newline="", encoding="utf-8") as f:
            return {row["photo"]: row for row in csv.DictReader(f) if "photo" in row}
    except (OSError, csv.Error, UnicodeDecodeError):
        return {}


def _write_text(path: Path, text: str) -> None:
    with _io.atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


_STYLE = """body{font-family:sans-serif;margin:1em}table{border-collapse:collapse}
td,th{border:1px solid #ccc;padding:4px;vertical-align:top;font-size:13px}
img{max-width:192px;max-height:192px}.failed{background:#fdd}.noblur{background:#ffd}
.notrun{color:#888}"""


def _html(rows: list[dict], final: bool, heading: str) -> str:
    def link(thumb, target=None) -> str:  # paths relative to out_dir
        if not thumb:
            return ""
        src, href = html.escape(str(thumb)), html.escape(str(target or thumb))
        return f'<a href="{href}"><img src="{src}" alt="{src}"></a>'

    lines = ["<!DOCTYPE html>", '<html><head><meta charset="utf-8">',
             "<title>edgecme batch report</title>"]
    if not final:  # reload while the batch runs
        lines.append('<meta http-equiv="refresh" content="10">')
    lines += [f"<style>{_STYLE}</style></head><body>",
              f"<h1>edgecme batch report</h1><p>{html.escape(heading)}</p>", "<table>",
              "<tr><th>photo</th><th>status</th><th>method</th><th>blur extent (px)</th>"
              "<th>profiles</th><th>time (s)</th><th>before</th><th>after</th>"
              "<th>PSF field</th><th>reason / warnings</th></tr>"]
    for row in rows:
        css = {FAILED: "failed", NO_BLUR: "noblur", NOT_RUN: "notrun"}.get(row["status"], "")
        note = " | ".join(x for x in (row.get("reason"), row.get("warnings")) if x)
        cells = [html.escape(str(row.get(k, "") or "")) for k in
                 ("photo", "status", "method", "blur_extent_px", "profiles", "seconds")]
        cells += [link(row.get("before"), row.get("source")),
                  link(row.get("after"), row.get("output")), link(row.get("psf")),
                  html.escape(note)]
        lines.append(f'<tr class="{css}">' + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    lines += ["</table></body></html>", ""]
    return "\n".join(lines)


class _Report:
    """The batch's rows, and their ``report.csv`` and ``report.html``, rewritten on change."""

    def __init__(self, photos: list[Photo], out_dir: Path):
        self.out_dir = out_dir
        self.csv = out_dir / "report.csv"
        self.html = out_dir / "report.html"
        self.rows = {p.name: {"photo": p.name, "status": NOT_RUN, "source": str(p.source)}
                     for p in photos}
        self.heading = ""

    def set(self, name: str, row: dict) -> None:
        self.rows[name] = {**self.rows[name], **row}

    def write(self, final: bool = False) -> None:
        rows = list(self.rows.values())
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=REPORT_FIELDS, extrasaction="ignore",
                                lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        _write_text(self.csv, text.getvalue())
        _write_text(self.html, _html(rows, final, self.heading))


def _save_outputs(photo: Photo, out_dir: Path, files: dict[str, bytes]) -> dict[str, str]:
    """Write a photo's encoded outputs, each atomically, the motion file last."""
    paths = photo.outputs(out_dir)
    written = {}
    for role in ("before", "after", "psf", "output", "motion"):
        path = paths[role]
        path.parent.mkdir(parents=True, exist_ok=True)
        with _io.atomic_path(path) as tmp:
            tmp.write_bytes(files[role])
        written[role] = path.relative_to(out_dir).as_posix()
    return written


# --------------------------------------------------------------------------------------
# where the photos run
# --------------------------------------------------------------------------------------

def local_cluster_size(cores: int | None = None, memory: int | None = None
                       ) -> tuple[int, int, int]:
    """Workers, threads per worker and memory per worker of the default local cluster.

    One single-threaded worker process per core, with numpy's BLAS/OpenMP threads at 1,
    so that photos run side by side without fighting over the cores; fewer workers when
    the memory would give each less than :data:`WORKER_MEMORY`.

    Parameters
    ----------
    cores : int, optional
        Cores this process may use (default: its CPU affinity).
    memory : int, optional
        Bytes of memory (default: the machine's total).

    Returns
    -------
    n_workers, threads_per_worker, memory_limit : int
    """
    if cores is None:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
            os.cpu_count() or 1)
    if memory is None:
        import psutil

        memory = psutil.virtual_memory().total
    n_workers = max(1, min(cores, memory // WORKER_MEMORY))
    return n_workers, 1, int(memory // n_workers)


def dask_setup(worker) -> None:
    """Dask preload hook of the local cluster's workers: Ctrl-C is for the client.

    A terminal sends SIGINT to the whole process group, worker processes included; they
    ignore it, so that the client decides what an interrupt does (running photos finish).
    """
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise ImportError("batch deblurring on several workers needs Dask: "
                          f"{INSTALL_HINT} (or workers=1 / --workers 1 to deblur one photo "
                          "at a time without it)") from None
    return distributed


class _Cluster:
    """Context manager: a Dask client (own local cluster, given client, or by address)."""

    def __init__(self, client=None, scheduler: str | None = None, workers: int | None = None):
        self.given = client
        self.scheduler = scheduler
        self.workers = workers
        self._stack = None
        self.description = ""

    def __enter__(self):
        import contextlib
        import logging

        distributed = _import_distributed()
        import dask

        if self.given is not None:
            self.description = f"the given Dask client ({self.given.scheduler.address})"
            return self.given
        self._stack = contextlib.ExitStack()
        if self.scheduler is not None:
            try:
                client = self._stack.enter_context(
                    distributed.Client(self.scheduler, timeout="10s", set_as_default=False))
            except (OSError, TimeoutError, ValueError) as err:
                self._stack.close()
                raise ValueError(f"cannot connect to the Dask scheduler at "
                                 f"{self.scheduler}: {first_line(err)}") from None
            threads = sum(client.nthreads().values())
            self.description = (f"Dask scheduler {self.scheduler} ({len(client.nthreads())} "
                                f"workers, {threads} threads)")
            return client
        n_workers, threads, memory = local_cluster_size()
        if self.workers is not None:
            n_workers, memory = self.workers, memory * n_workers // self.workers
        with self._stack.pop_all() as stack, dask.config.set({
                # a photo that kills its worker twice is reported, not tried forever
                "distributed.scheduler.allowed-failures": 1}):
            cluster = stack.enter_context(distributed.LocalCluster(
                n_workers=n_workers, threads_per_worker=threads, processes=True,
                memory_limit=memory, dashboard_address=None, env=_BLAS_ONE_THREAD,
                # each photo's failure is reported in its row, not as a log message
                silence_logs=logging.CRITICAL, preload=[__name__]))
            client = stack.enter_context(distributed.Client(cluster, set_as_default=False))
            self._stack = stack.pop_all()
        self.description = (f"local Dask cluster: {n_workers} worker processes x {threads} "
                            f"thread, BLAS/OpenMP threads 1, "
                            f"{memory / 2**30:.1f} GiB memory limit each")
        return client

    def __exit__(self, *exc):
        if self._stack is not None:
            self._stack.close()
        return False


# --------------------------------------------------------------------------------------
# the batch
# --------------------------------------------------------------------------------------

def _options(method, model, max_blur, focal_px, deconvolution, deconv_params, params
             ) -> argparse.Namespace:
    """The ``edgecme deblur`` options of a batch, checked once before any photo runs."""
    from .core import deconv as _deconv
    from .core import estimate as _estimate
    from .core._validation import check_choice

    unknown = sorted(set(params) - {"rng", *ESTIMATION_PARAMS})
    if unknown:
        raise ValueError(f"unknown parameter {unknown[0]!r}; a batch takes "
                         + ", ".join(("rng", *ESTIMATION_PARAMS)))
    seed = params.pop("rng", 0)
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError("rng must be a non-negative integer seed for a batch (every photo "
                         f"is seeded with it); got {seed!r}")
    if deconv_params is not None and not isinstance(deconv_params, dict):
        raise ValueError(f"deconv_params must be a dict; got {type(deconv_params).__name__}")
    deconvolution = check_choice(deconvolution, "deconvolution", _deconv.METHODS)
    _deconv.check_deconvolution_parameters(deconvolution, dict(deconv_params or {}))
    options = argparse.Namespace(
        method=check_choice(method, "method", _estimate.METHODS),
        model=check_choice(model, "model", MODELS), max_blur=max_blur,
        focal_px=focal_px, seed=int(seed), profiles=None, deconvolution=deconvolution,
        **{name: params.get(name) for name in ESTIMATION_PARAMS},
        **{name: (deconv_params or {}).get(name) for name in ("lam", "iterations", "nsr")})
    deconvolution_params(options, deconvolution)
    return options


@dataclass
class _Tally:
    """Counts of this run, for the progress bar."""

    total: int
    start: float = field(default_factory=time.monotonic)
    finished: int = 0
    failed: int = 0
    running: int = 0

    def record(self) -> Progress:
        left = ""
        if 0 < self.finished < self.total:
            seconds = (time.monotonic() - self.start) / self.finished * (
                self.total - self.finished)
            minutes, secs = divmod(round(seconds), 60)
            left = f", about {minutes}:{secs:02d} left"
        message = (f"{self.finished - self.failed} done, {self.failed} failed, "
                   f"{self.running} running, {self.total - self.finished} to go{left}")
        return Progress(stage="batch", step=self.finished, total=max(self.total, 1),
                        message=message)


def _run_sequential(todo, options, on_result, tally, callback):
    for photo in todo:
        tally.running = 1
        callback(tally.record())
        on_result(photo, _submit_data(photo, lambda data, p=photo: deblur_photo(
            p.name, data, options)))
        tally.running = 0
        callback(tally.record())


def _submit_data(photo: Photo, run):
    """``run(bytes of the photo)``, or a failed row when the file cannot be read."""
    try:
        data = photo.source.read_bytes()
    except OSError as err:
        return {"photo": photo.name, "status": FAILED, "reason": oserror_message(err),
                "files": {}}
    return run(data)


class _Interrupts:
    """While active, Ctrl-C (SIGINT) in the main thread is counted, not raised; the second
    one raises KeyboardInterrupt. Elsewhere than the main thread it does nothing."""

    def __init__(self):
        self.count = 0
        self.told = False  # the user was told what the first Ctrl-C does
        self._previous = None

    def _handle(self, signum, frame):
        self.count += 1
        if self.count > 1:
            raise KeyboardInterrupt

    def __enter__(self):
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc):
        import signal

        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
        return False


def _task_row(photo: Photo, future) -> dict:
    """The row of a finished Dask task (an errored task is a failed photo)."""
    if future.status == "finished":
        return future.result()
    err = future.exception()
    name = type(err).__name__
    if name == "KilledWorker":
        reason = "its worker died (out of memory or killed) while deblurring it"
    else:
        reason = f"task failed: {name}: {first_line(err)}"
    return {"photo": photo.name, "status": FAILED, "reason": reason, "files": {}}


def _run_dask(client, todo, options, on_result, tally, callback, log):
    """Keep every worker thread busy with one photo until all ran; two-stage Ctrl-C."""
    from distributed import as_completed

    slots = max(1, sum(client.nthreads().values()))
    queue = iter(todo)
    running: dict = {}  # future -> photo
    finished = as_completed(loop=client.loop)
    with _Interrupts() as interrupts:
        try:
            while True:
                while not interrupts.count and len(running) < slots:
                    photo = next(queue, None)
                    if photo is None:
                        break
                    data = _submit_data(photo, lambda data: client.scatter(data, hash=False))
                    if isinstance(data, dict):  # the file could not be read
                        on_result(photo, data)
                        continue
                    future = client.submit(deblur_photo, photo.name, data, options,
                                           pure=False, retries=0,
                                           key=f"edgecme-deblur-{uuid.uuid4().hex[:12]}")
                    running[future] = photo
                    finished.add(future)
                tally.running = len(running)
                callback(tally.record())
                if not running:
                    break
                if interrupts.count == 1 and not interrupts.told:
                    interrupts.told = True
                    log(f"interrupted: no new photo starts; waiting for the {len(running)} "
                        "running to finish (Ctrl-C again cancels them)")
                if not finished.has_ready():
                    time.sleep(0.1)  # a Ctrl-C is seen within this
                    continue
                for future in finished.next_batch(block=False):
                    photo = running.pop(future)
                    row = _task_row(photo, future)
                    future.release()
                    on_result(photo, row)
        except KeyboardInterrupt:  # the second Ctrl-C: the running photos are dropped
            client.cancel(list(running))
            raise
        if interrupts.count:
            raise KeyboardInterrupt


def deblur_many(paths, out_dir, method: str = "xu+ep", model: str = "rotation",
                max_blur: float | None = None, focal_px: float | None = None, *,
                deconvolution: str = "hyperlaplacian", deconv_params: dict | None = None,
                recursive: bool = False, force: bool = False, client=None,
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
        As :func:`~napari_edgecme.core.estimate.deblur`, for every photo (``max_blur``:
        default 4% of each photo's longer side; ``focal_px``: default each photo's EXIF,
        else the 35 mm-equivalent default).
    deconvolution : {"hyperlaplacian", "rl", "wiener"}
    deconv_params : dict, optional
        ``lam``, ``iterations`` or ``nsr`` of the deconvolution.
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
        ``lambda_w``, ``lambda_ip``, ``lambda_f``, ``n_iter``, ``max_side``.

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
    options = _options(method, model, max_blur, focal_px, deconvolution, deconv_params,
                       dict(params))
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

    report = _Report(photos, out_dir)
    previous = _read_previous(report.csv)
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
    tally = _Tally(total=len(todo))

    def on_result(photo: Photo, row: dict) -> None:
        files = row.pop("files", {})
        summary = row.pop("summary", "")
        if files:
            row.update(_save_outputs(photo, out_dir, files))
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
            _run_sequential(todo, options, on_result, tally, callback)
        elif todo:
            cluster = _Cluster(client, scheduler, workers)
            with cluster as dask_client:
                where = cluster.description
                report.heading = f"{len(photos)} photos; running on {where}"
                report.write()
                log(f"{len(todo)} of {len(photos)} photos to deblur on {where}")
                _run_dask(dask_client, todo, options, on_result, tally, callback, log)
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
