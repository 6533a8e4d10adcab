"""The one progress-and-cancel protocol of the engine.

Every long computation exists as a generator ``iter_*(...)`` that yields
:class:`Progress` records and *returns* its result (``StopIteration.value``).
Widgets run these generators in worker threads; scripts call the plain function,
which drives the generator with :func:`drive`.

Cancelling:

* ``generator.close()`` stops the work at the next yield; nothing is returned;
* a ``callback(record)`` passed to a plain function may raise ``StopIteration``
  (as in :func:`scipy.optimize.minimize`): :func:`drive` throws :class:`StopRequested`
  into the generator, which ends cleanly and returns its best result so far with
  a message saying it was stopped (or raises :class:`Cancelled` if it has nothing).
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Cancelled", "Progress", "StopRequested", "drive"]


class StopRequested(Exception):
    """Thrown into a running generator when its caller asks it to stop early."""


class Cancelled(RuntimeError):
    """Raised by a plain function when it was stopped before it had any result."""


@dataclass(frozen=True)
class Progress:
    """One progress report from a running computation.

    Attributes
    ----------
    stage : str
        What is running, e.g. ``"profiles"``, ``"estimate"``, ``"deconvolve"``.
    step, total : int
        Steps done so far and the expected total (``total`` may grow by a little
        when a stage ends early or late; ``step <= total`` always holds).
    message : str
        One human-readable line, e.g. ``"scale 3/6, iteration 2/5"``.
    scale, n_scales : int or None
        Pyramid level (1 = coarsest) and the number of levels, for estimators.
    iteration : int or None
        Iteration within the current scale or solver.
    cost : float or None
        Current objective value, where one is defined.
    preview : ndarray or None
        An intermediate image (e.g. the latent estimate), when the caller asked
        for previews.
    """

    stage: str
    step: int
    total: int
    message: str = ""
    scale: int | None = None
    n_scales: int | None = None
    iteration: int | None = None
    cost: float | None = None
    preview: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def fraction(self) -> float:
        """``step / total`` in [0, 1]."""
        return min(1.0, self.step / self.total) if self.total > 0 else 0.0


def drive(gen: Generator, callback: Callable[[Progress], object] | None = None):
    """Run an ``iter_*`` generator to completion, passing each record to ``callback``.

    Parameters
    ----------
    gen : generator
        Yields :class:`Progress` records and returns the result.
    callback : callable, optional
        Called with every record. Raising ``StopIteration`` in it stops the work
        cleanly: the generator returns its best result so far (with a message
        that says it was stopped) or, if it has none, :class:`Cancelled` is raised.

    Returns
    -------
    object
        Whatever the generator returns.
    """
    try:
        record = next(gen)
        while True:
            try:
                if callback is not None:
                    callback(record)
            except StopIteration:
                record = gen.throw(StopRequested("stopped by callback"))
                continue
            record = next(gen)
    except StopIteration as done:
        return done.value
    except StopRequested:
        raise Cancelled("stopped by callback before any result was available") from None
    finally:
        gen.close()
