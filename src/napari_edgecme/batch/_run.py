"""Running a batch: the options checked once, the photos run in turn or on Dask, interrupts."""

from __future__ import annotations

import argparse
import time
import uuid
from dataclasses import dataclass, field

import numpy as np

from ..cli._console import oserror_message
from ..cli._options import DECONVOLUTION_OPTIONS, deconvolution_params
from ..core._validation import first_line
from ..core.camera import MODELS
from ..core.progress import Progress
from ._photos import Photo
from ._report import FAILED
from ._task import deblur_photo

__all__ = ["ESTIMATION_PARAMS"]

#: Estimation options a batch takes (as :func:`~napari_edgecme.core.deblur.deblur`).
ESTIMATION_PARAMS = ("lambda_w", "lambda_ip", "lambda_f", "n_iter", "max_side", "refine")


def batch_options(method, model, max_blur, focal_px, deconvolution, deconv_params, params,
                  gamma="auto") -> argparse.Namespace:
    """The ``edgecme deblur`` options of a batch, checked once before any photo runs."""
    from ..core import deconv as _deconv
    from ..core import estimate as _estimate
    from ..core._validation import check_choice
    from ..core.photometry import parse_gamma

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
    handed = dict(deconv_params or {})
    if "lambda_f" in handed:  # the per-photo options speak the CLI's --lam (= 2 / lambda_f)
        handed["lam"] = 2.0 / handed.pop("lambda_f")
    others = sorted(set(handed) - set(DECONVOLUTION_OPTIONS))
    if others:  # each photo runs as 'edgecme deblur' does: with its options only
        raise ValueError(f"deconvolution parameter {others[0]!r} is not an option of a batch; "
                         "it takes lambda_f, " + ", ".join(DECONVOLUTION_OPTIONS[1:]))
    options = argparse.Namespace(
        gamma=parse_gamma(gamma),
        method=check_choice(method, "method", _estimate.METHODS),
        model=check_choice(model, "model", MODELS), max_blur=max_blur,
        focal_px=focal_px, seed=int(seed), profiles=None, deconvolution=deconvolution,
        **{name: params.get(name) for name in ESTIMATION_PARAMS},
        **{name: handed.get(name) for name in DECONVOLUTION_OPTIONS})
    deconvolution_params(options, deconvolution)
    return options


@dataclass
class Tally:
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


def run_sequential(todo, options, on_result, tally, callback):
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


def run_dask(client, todo, options, on_result, tally, callback, log):
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
