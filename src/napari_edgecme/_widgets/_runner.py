"""One way of running engine generators for the three widgets.

:class:`EngineRunner` runs an ``iter_*`` generator of the engine in a napari worker
thread and owns everything around it: the Run/Cancel buttons, a napari progress
bar that follows the :class:`~napari_edgecme.core.progress.Progress` records, the
status line, notifications, and closing the generator when the run ends.

The rules it enforces (napari's threading model):

* the worker only sees plain data (arrays snapshotted on the main thread with
  :func:`snapshot_image` and parameters); it never touches a layer or a widget;
* every handler (``yielded``, ``returned``, ``warned``, ``errored``, ``aborted``,
  ``finished``) runs on the main thread, where layers are created and updated;
* failures become exactly one napari error notification: bad input -- the engine's
  documented one-line ``ValueError`` -- shows that line; any other exception is a
  bug and shows its type and message, with the traceback in the log; engine
  warnings (e.g. Xu+Ep falling back to Xu) become warning notifications.

Exceptions are caught inside the worker (:func:`_relay`) and handed back as a
:class:`Failed` result rather than left to the worker's ``errored`` signal, for two
reasons seen with napari 0.9 / superqt: a ``RuntimeError`` escaping a generator
worker is taken for a deleted Qt object and the worker never emits ``finished``
(the UI would stay "running"); and whether napari's worker relays errors and
warnings to notifications itself depends on its version. The worker class is
superqt's plain ``GeneratorWorker``, so this module alone decides what is shown.

What reaches napari is throttled: the engine may yield thousands of records a
second (one per solver iteration), and each update of napari's progress bar, of the
status line or of a preview layer costs milliseconds on the main thread (a repaint
of the window, a texture upload) -- as does each queued cross-thread signal. So the
worker does not signal every record: :func:`_relay` leaves the newest record (and the
newest preview) in a :class:`_Mailbox` and wakes the main thread at most once per
:attr:`EngineRunner.UPDATE_INTERVAL_MS`; a main-thread timer collects what arrived
between wake-ups. The engine's records themselves are not changed.

The handlers run one at a time, in the order the worker emitted its signals:
napari's progress bars and notifications call ``QApplication.processEvents()``
while they repaint, so without care the worker's next signals (even ``returned``
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Generator
from dataclasses import dataclass
from functools import partial

from napari.qt.threading import create_worker
from napari.utils import progress
from napari.utils.notifications import show_error, show_info, show_warning
from qtpy.QtCore import QTimer
from qtpy.QtWidgets import QHBoxLayout, QLabel, QProgressBar, QPushButton, QVBoxLayout, QWidget
from superqt.utils import GeneratorWorker

from ..core._validation import first_line
from ..core.progress import Progress

__all__ = ["EngineRunner", "Failed", "RunControls", "time_left"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Failed:
    """What a run returns when the engine raised instead of returning a result.

    Attributes
    ----------
    message : str
        One line for the user.
    error : Exception or None
        The exception of an unexpected failure (a bug), kept for its traceback;
        None when the engine refused its input (a ``ValueError``).
    """

    message: str
    error: Exception | None = None


class _Mailbox:
    """The newest record and the newest preview of a run, from the worker to the main thread."""

    def __init__(self):
        self._lock = threading.Lock()
        self._record: Progress | None = None
        self._preview: Progress | None = None
        #: Records put in so far.
        self.count = 0

    def put(self, record: Progress) -> None:
        with self._lock:
            self._record = record
            self.count += 1
            if record.preview is not None:
                self._preview = record

    def take(self) -> tuple[Progress | None, Progress | None]:
        """The newest record and newest preview record since the last take (or None)."""
        with self._lock:
            out = (self._record, self._preview)
            self._record = self._preview = None
        return out


#: What the worker yields to wake the main thread: "look in the mailbox".
_WAKE = object()


def _relay(gen: Generator, mailbox: _Mailbox, interval: float):
    """Runs in the worker thread: run an engine generator, post its records, return its result.

    Each record goes to ``mailbox``; the worker yields (signals the main thread, and
    lets a cancel in) at most once per ``interval`` seconds while records flow.
    Exceptions come back as a :class:`Failed` result (see the module notes). Closing
    this generator (``GeneratorExit``) is not an exception; the runner closes ``gen``.
    """
    last = -math.inf
    try:
        while True:
            try:
                record = next(gen)
            except StopIteration as stop:
                return stop.value
            if isinstance(record, Progress):
                mailbox.put(record)
            now = time.perf_counter()
            if now - last >= interval:
                last = now
                yield _WAKE
    except ValueError as err:  # the engine's documented "bad input" error
        logger.debug("the engine refused the input", exc_info=True)
        return Failed(first_line(err))
    except Exception as err:
        return Failed(f"{type(err).__name__}: {first_line(err)}", err)


class EngineRunner:
    """Runs one engine generator at a time for a widget, in a napari worker thread.

    Parameters
    ----------
    owner : QWidget
        The widget; when it is destroyed a running job is cancelled and no handler
        touches it any more.
    title : str
        Prefix of the progress bar and of notifications, e.g. ``"Camera motion"``.
    run_button, cancel_button : QPushButton
        Run is disabled while a job runs; Cancel only then.
    status : QLabel
        Shows the latest progress message and the outcome.
    meter : QProgressBar, optional
        A progress bar in the dock: percentage and time left, shown while running.
    """

    #: Shortest interval (ms) between two updates of the status and the progress bars
    #: (records in between are coalesced; see the module notes).
    UPDATE_INTERVAL_MS = 100
    #: Shortest interval (ms) between two previews: showing one is a texture upload
    #: and a canvas redraw (~50-100 ms of main thread with software GL).
    PREVIEW_INTERVAL_MS = 1000

    def __init__(self, owner: QWidget, title: str, run_button: QPushButton,
                 cancel_button: QPushButton, status: QLabel,
                 meter: QProgressBar | None = None):
        self.title = title
        self._run_button = run_button
        self._cancel_button = cancel_button
        self._status = status
        self._meter = meter
        self._worker: GeneratorWorker | None = None
        self._gen: Generator | None = None
        self._alive = True
        self._queue: deque = deque()
        self._delivering = False
        self._outcome = ""
        self._mailbox = _Mailbox()
        self._last_update = self._last_preview = -math.inf
        self._held_preview: Progress | None = None
        self._started_at = 0.0
        # the runner's own timer, not a child of the owner: it may fire once more
        # after the owner is gone. It collects records that arrived between wake-ups.
        self._timer = QTimer()
        self._timer.setInterval(self.UPDATE_INTERVAL_MS)
        self._timer.timeout.connect(lambda: self._deliver(self._update, False))
        #: Updates of the display in the current (or last) run (at most about one per
        #: interval).
        self.n_updates = 0
        self.progress_bar: progress | None = None
        self._on_result: Callable = _ignore
        self._on_preview: Callable = _ignore
        self._on_end: Callable = _ignore
        cancel_button.setEnabled(False)
        cancel_button.clicked.connect(self.cancel)
        if meter is not None:
            meter.setVisible(False)
        # a lambda holding the runner, not the widget: called while the widget dies
        owner.destroyed.connect(lambda *_: self._owner_destroyed())

    # -- state -----------------------------------------------------------------------------
    @property
    def is_running(self) -> bool:
        """True from :meth:`start` until the worker has finished (and the UI is reset)."""
        return self._worker is not None

    @property
    def outcome(self) -> str:
        """How the last run ended: ``""`` (none yet), ``"done"``, ``"failed"``,
        ``"cancelled"``, or ``"refused"`` (not started: see :meth:`refuse`)."""
        return self._outcome

    @property
    def n_records(self) -> int:
        """Progress records the engine yielded in the current (or last) run."""
        return self._mailbox.count

    # -- control ---------------------------------------------------------------------------
    def start(self, gen: Generator, on_result: Callable, *, on_preview: Callable | None = None,
              on_end: Callable | None = None) -> GeneratorWorker | None:
        """Run ``gen`` (an ``iter_*`` generator, not started yet) in a worker thread.

        Parameters
        ----------
        gen : generator
            Yields :class:`Progress` records and returns the result. Created on the
            main thread from snapshots; its body runs in the worker.
        on_result : callable
            ``on_result(result)`` on the main thread when the run completed; returns
            an optional summary line for the status label.
        on_preview : callable, optional
            ``on_preview(progress)`` on the main thread with the newest record that
            carries a preview, at most once per :attr:`PREVIEW_INTERVAL_MS`.
        on_end : callable, optional
            ``on_end(outcome)`` on the main thread after every run, whatever its
            outcome (``"done"``, ``"failed"``, ``"cancelled"``): clean-up of transient
            layers.

        Returns
        -------
        GeneratorWorker or None
            None if a job is already running (Run is disabled then anyway).
        """
        if self.is_running:
            return None
        self._gen = gen
        self._on_result = on_result
        self._on_preview = on_preview or _ignore
        self._on_end = on_end or _ignore
        self._outcome = ""
        self._mailbox = mailbox = _Mailbox()
        self._last_update = self._last_preview = -math.inf
        self._held_preview = None
        self._started_at = time.perf_counter()
        self.n_updates = 0
        self.progress_bar = progress(total=0, desc=self.title)
        handlers = {"yielded": self._on_yielded, "returned": self._on_returned,
                    "warned": self._on_warned, "errored": self._on_errored,
                    "aborted": self._on_aborted, "finished": self._on_finished}
        worker = create_worker(
            _relay, gen, mailbox, self.UPDATE_INTERVAL_MS / 1e3, _start_thread=False,
            _worker_class=GeneratorWorker,
            _connect={name: partial(self._deliver, handler)
                      for name, handler in handlers.items()})
        self._worker = worker
        self._run_button.setEnabled(False)
        self._cancel_button.setEnabled(True)
        self._status.setText(f"{self.title}: starting…")
        if self._meter is not None:
            self._meter.setRange(0, 0)  # busy until the first record
            self._meter.setFormat("starting…")
            self._meter.setVisible(True)
        self._timer.start()
        worker.start()
        return worker

    def cancel(self) -> None:
        """Ask the running job to stop; the engine stops at its next progress record."""
        if self._worker is None:
            return
        self._worker.quit()
        if self._alive:
            self._cancel_button.setEnabled(False)
            self._status.setText(f"{self.title}: cancelling…")

    def refuse(self, message: str) -> None:
        """Say on the status line and in one error notification why a run did not start.

        For the checks a widget makes on the main thread before :meth:`start`
        (no image chosen, no motion, ...); the outcome becomes ``"refused"``.
        """
        if self.is_running:
            return
        self._outcome = "refused"
        self._status.setText(f"{self.title}: not run: {message}")
        show_error(f"{self.title}: {message}")

    def clear_status(self) -> None:
        """Empty the status line (e.g. another image was chosen) unless a job is running."""
        if not self.is_running:
            self._status.setText("")

    # -- worker signals (main thread) ---------------------------------------------------------
    def _deliver(self, handler: Callable, *args) -> None:
        """Run the handlers of the worker's signals one at a time, in order (module notes)."""
        self._queue.append((handler, args))
        if self._delivering:  # re-entered from a processEvents() inside a handler
            return
        self._delivering = True
        error = None
        try:
            while self._queue:
                handler, args = self._queue.popleft()
                try:
                    handler(*args)
                except Exception as err:  # run the rest (``finished``!), then re-raise
                    error = error or err
        finally:
            self._delivering = False
        if error is not None:
            raise error

    def _on_yielded(self, token) -> None:
        """The worker has posted records: show the newest now."""
        if token is _WAKE:
            self._update(True)

    def _update(self, woken: bool) -> None:
        """Show the newest record: status, dock meter, napari's progress bar, preview.

        At most once per interval (to 10%): a wake-up that comes sooner leaves the
        record in the mailbox for the timer (``woken`` False), which comes round
        every interval.
        """
        if self._worker is None:
            return
        now = time.perf_counter()
        if now - self._last_update < 0.9 * self.UPDATE_INTERVAL_MS / 1e3:
            return
        record, preview = self._mailbox.take()
        preview = preview or self._held_preview
        self._held_preview = None
        if preview is not None and (record is None or now - self._last_preview
                                    < self.PREVIEW_INTERVAL_MS / 1e3):
            self._held_preview, preview = preview, None  # shown at a later update
        if record is None:
            return
        self._last_update = now
        self.n_updates += 1
        if self._alive:
            self._status.setText(f"{self.title}: {record.message or 'running'}")
            self._show_meter(record)
            if preview is not None:
                self._last_preview = now
                self._on_preview(preview)
        bar = self.progress_bar
        if bar is not None:
            if bar.total != record.total:
                bar.total = record.total
            bar.set_description(f"{self.title}: {record.message}" if record.message
                                else self.title)
            if record.step > bar.n:
                bar.update(record.step - bar.n)

    def _show_meter(self, record: Progress) -> None:
        meter = self._meter
        if meter is None:
            return
        if record.total <= 0:
            meter.setRange(0, 0)
            meter.setFormat("running…")
            return
        fraction = min(1.0, max(0.0, record.step / record.total))
        meter.setRange(0, 1000)
        meter.setValue(round(1000 * fraction))
        text = f"{100 * fraction:.0f}%"
        left = time_left(time.perf_counter() - self._started_at, fraction)
        if left:
            text += f", {left}"
        meter.setFormat(text)

    def _drop_pending(self) -> None:
        self._timer.stop()
        self._mailbox.take()
        self._held_preview = None

    def _on_returned(self, result) -> None:
        self._drop_pending()
        if isinstance(result, Failed):
            self._outcome = "failed"
            if result.error is None:
                show_error(f"{self.title}: {result.message}")
            else:
                err = result.error
                logger.error("%s failed", self.title, exc_info=(type(err), err,
                                                                 err.__traceback__))
                show_error(f"{self.title} failed unexpectedly: {result.message} "
                           "(the traceback is in the log)")
            if self._alive:
                self._status.setText(f"{self.title} failed: {result.message}")
            return
        self._outcome = "done"
        if self._alive:
            summary = self._on_result(result)
            self._status.setText(f"{self.title}: {summary or 'done'}")

    def _on_warned(self, showwarning_args: tuple) -> None:
        message = showwarning_args[0] if showwarning_args else ""
        show_warning(f"{self.title}: {message}")

    def _on_errored(self, exc: BaseException) -> None:
        # only what _relay cannot catch (BaseException) gets here
        self._outcome = "failed"
        show_error(f"{self.title} failed: {type(exc).__name__}: {first_line(exc)}")
        if self._alive:
            self._status.setText(f"{self.title} failed: {first_line(exc)}")

    def _on_aborted(self) -> None:
        self._drop_pending()
        self._outcome = "cancelled"
        if self._alive:
            show_info(f"{self.title}: cancelled")
            self._status.setText(f"{self.title}: cancelled")

    def _on_finished(self) -> None:
        self._drop_pending()
        if self.progress_bar is not None:
            self.progress_bar.close()
            self.progress_bar = None
        if self._gen is not None:
            # the worker left the generator suspended at a yield if it was cancelled:
            # closing it ends the engine's work for good (the thread is done with it)
            self._gen.close()
            self._gen = None
        self._worker = None
        if not self._outcome:  # finished without any of the signals above
            self._outcome = "cancelled"
        if self._alive:
            self._run_button.setEnabled(True)
            self._cancel_button.setEnabled(False)
            if self._meter is not None:
                self._meter.setVisible(False)
            self._on_end(self._outcome)
        self._on_result = self._on_preview = self._on_end = _ignore

    def _owner_destroyed(self) -> None:
        self._alive = False
        if self._worker is not None:
            self._worker.quit()


def time_left(elapsed: float, fraction: float) -> str:
    """``"about 40 s left"`` from the time a run took so far and the fraction done.

    Empty while too little is known (under a second, or under 2% done).
    """
    if elapsed < 1.0 or fraction < 0.02 or fraction >= 1.0:
        return ""
    left = elapsed * (1.0 - fraction) / fraction
    if left < 60:
        return f"about {max(1, round(left))} s left"
    return f"about {round(left / 60)} min left"


class RunControls(QWidget):
    """Run and Cancel buttons, a progress meter and a status line, with their runner.

    Parameters
    ----------
    owner : QWidget
        The dock widget whose runs these are (see :class:`EngineRunner`).
    title : str
        Prefix of the status line, progress bar and notifications.
    run_text, run_tip : str
        Label and tooltip of the Run button.
    cancel_tip : str
        Tooltip of the Cancel button.
    """

    def __init__(self, owner: QWidget, title: str, run_text: str = "Run", run_tip: str = "",
                 cancel_tip: str = "Stop the run now; nothing is added to the layers"):
        super().__init__(owner)
        self.run_button = QPushButton(run_text)
        self.run_button.setToolTip(run_tip)
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setToolTip(cancel_tip)
        self.meter = QProgressBar()
        self.meter.setToolTip("How far the run is, and about how long it has left")
        self.meter.setTextVisible(True)
        self.status = QLabel("")
        self.status.setWordWrap(True)
        buttons = QHBoxLayout()
        buttons.setContentsMargins(0, 0, 0, 0)
        buttons.addWidget(self.run_button)
        buttons.addWidget(self.cancel_button)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addLayout(buttons)
        layout.addWidget(self.meter)
        layout.addWidget(self.status)
        self.runner = EngineRunner(owner, title, self.run_button, self.cancel_button,
                                   self.status, meter=self.meter)


def _ignore(*_args, **_kwargs):
    return None
