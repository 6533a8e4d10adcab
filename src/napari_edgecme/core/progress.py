"""The one progress-and-cancel protocol of the engine.

Every long computation, and every iterative solver inside one, is a generator that
yields :class:`Progress` records and *returns* its result (``StopIteration.value``);
nothing else is ever yielded. Widgets run the top-level ``iter_*(...)`` generators in
worker threads; scripts call the plain function (``deconvolve``, ``l0_latent``,
``nonneg_lasso``, ...), which drives the generator with :func:`drive` and takes a
``callback``.

Solver generators (the steppable protocol)
    A solver (``hyperlaplacian_steps``, ``conjugate_gradient``, ``iter_l0_latent``,
    ``iter_nonneg_lasso``, ...) yields one record per unit of work: ``step`` counts
    the finished iterations out of ``total`` and ``iteration`` repeats it; a record
    that ends an iteration carries the solver's current estimate in ``iterate`` (a
    reference to its working array, no copy: copy it to keep it, never modify it).
    This is SigPy's ``Alg.update()``/``done()``/``.x`` as a generator: ``next(solver)``
    runs one unit of work (an iteration has ended when ``step`` grew),
    ``StopIteration`` is done, ``record.iterate`` is ``x``. A solver nested in another
    is run with :func:`relay`, which re-labels its records for the outer one. A
    sub-step with no estimate of its own before it ends (one closed-form image step,
    ``PatchFourier.solve``) lets a stop request propagate to the solver running it.

Cancelling and stopping:

* ``generator.close()`` stops the work at the next yield; nothing is returned;
* throwing :class:`StopRequested` in (:func:`stop`) makes a solver return its best
  estimate so far at once -- the last finished iterate, or its starting point -- and
  a top-level ``iter_*`` generator yield one record saying it stopped and return its
  result so far (or raise :class:`Cancelled` if it has nothing);
* a ``callback(record)`` passed to a plain function may raise ``StopIteration``
  (as in :func:`scipy.optimize.minimize`): :func:`drive` throws :class:`StopRequested`
  into the generator, with the effect above.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Cancelled", "Progress", "StopRequested", "drive", "relay", "relay_as", "stop"]


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
        An intermediate whole image (e.g. the latent estimate), when the caller
        asked for previews (a copy, the caller's to keep).
    iterate : ndarray or None
        On a solver's records that end an iteration: its current estimate, a
        reference to the working array (copy it to keep it; never modify it).
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
    iterate: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def fraction(self) -> float:
        """``step / total`` in [0, 1]."""
        return min(1.0, self.step / self.total) if self.total > 0 else 0.0


def drive(gen: Generator, callback: Callable[[Progress], object] | None = None):
    """Run an ``iter_*`` generator to completion, passing each record to ``callback``.

    Parameters
    ----------
    gen : generator
        Yields :class:`Progress` records and returns the result (an ``iter_*``
        generator or a solver generator).
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


def relay(gen: Generator, relabel: Callable[[Progress], Progress]):
    """Run a solver nested in another: yield ``relabel(record)`` for each of its records.

    Use as ``result = yield from relay(inner, relabel)`` inside the outer solver. A
    :class:`StopRequested` or ``close()`` that reaches the outer solver at one of these
    records is raised in the outer solver (which then returns its own estimate) and the
    inner one is closed.

    Returns
    -------
    object
        Whatever ``gen`` returns.
    """
    try:
        while True:
            try:
                record = next(gen)
            except StopIteration as done:
                return done.value
            yield relabel(record)
    finally:
        gen.close()



def relay_as(gen: Generator, record: Progress):
    """:func:`relay` with one fixed record: yield ``record`` for each of ``gen``'s records.

    For a caller whose own record says what is running (a step of an estimator) while the
    inner solver's records only mark where a stop may come in.
    """
    return (yield from relay(gen, lambda _inner: record))

def stop(gen: Generator):
    """Ask a suspended solver generator to stop; return its estimate so far.

    Throws :class:`StopRequested` in; a solver returns at once (module notes).

    Raises
    ------
    RuntimeError
        If the generator yields again instead of returning (it is then closed).
    """
    try:
        gen.throw(StopRequested("stop requested"))
    except StopIteration as done:
        return done.value
    gen.close()
    raise RuntimeError("a solver yielded a record after a stop request instead of returning")
