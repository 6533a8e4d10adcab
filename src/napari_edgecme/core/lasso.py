"""Non-negative L1-regularised least squares for the MDF (paper Eqs. 16, 19, 22).

Every MDF update of the estimators is an instance of

    min_w  1/2 w^T Q w - b^T w + lambda_w * sum(w),   w >= 0,

(``sum(w)`` is ``||w||_1`` on the non-negative orthant) where ``Q`` and ``b`` are sums
of data terms, each available only through products ``Q w`` that are cheap (they
never touch the full image; see :mod:`napari_edgecme.core.mdf`). We solve it with
FISTA (Beck & Teboulle 2009) with adaptive restart (O'Donoghue & Candès 2015): it
needs one ``Q w`` product per iteration, no line search once the Lipschitz constant
is known (estimated by power iteration), warm-starts from the previous scale's
estimate, and its iterates are non-negative by construction.

Why FISTA: ``benchmarks/bench_lasso.py`` times it against projected coordinate descent
on the explicit Gram matrix (one ``Q w`` product per pose to build, O(n^2) memory) and
ADMM (``w = z``, ``z >= 0``; the ``w`` step by warm-started CG) on the MDF problem of
the finest scale. On 256x256 with an in-plane grid of 2601 poses (measured 2026-11-22,
median of 1, 2-core shared machine) FISTA reached a relative objective gap of 1e-2 /
1e-3 / 1e-4 in 0.27 / 0.88 / 1.25 s; coordinate descent (sweeps in Python) needed 1.6
s just to build the Gram and reached 1e-2 at 1.8 s, 1e-3 not within 60 sweeps
(neighbouring poses are nearly collinear); ADMM reached 1e-2 at 2.0 s and 1e-3 not
within 400 iterations. The engine stops FISTA at ``max_iter=200`` (a gap of about 2e-2
on that problem): each MDF update is followed by a latent update that moves the
problem more than that.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .linop import LinearOperator
from .progress import Progress, StopRequested, drive

__all__ = ["LassoResult", "QuadraticTerm", "iter_nonneg_lasso", "lipschitz_constant",
           "nonneg_lasso"]


@dataclass
class QuadraticTerm:
    """``1/2 w^T Q w - b^T w + c/2`` with ``Q`` a symmetric PSD operator.

    Attributes
    ----------
    normal : LinearOperator
        ``Q``, (n,) -> (n,) (for a least-squares term: ``A^T A``).
    linear : ndarray of shape (n,)
        ``b`` (for a least-squares term ``||A w - y||^2 / 2``: ``A^T y``).
    constant : float
        ``c`` (``||y||^2``), so that :meth:`value` is the least-squares residual.
    """

    normal: LinearOperator
    linear: np.ndarray
    constant: float = 0.0

    @classmethod
    def least_squares(cls, operator: LinearOperator, target: np.ndarray) -> QuadraticTerm:
        """``1/2 ||A w - y||^2``: ``Q = A^T A``, ``b = A^T y``, ``c = ||y||^2``."""
        target = np.asarray(target, operator.dtype)
        return cls(operator.T @ operator, operator.T @ target, float(target @ target))

    def matvec(self, w: np.ndarray) -> np.ndarray:
        """``Q w`` (n,) -> (n,)."""
        return self.normal @ w

    def value(self, w: np.ndarray, Qw: np.ndarray | None = None) -> float:
        Qw = self.matvec(w) if Qw is None else Qw
        return float(0.5 * w @ Qw - self.linear @ w + 0.5 * self.constant)

    def __add__(self, other: QuadraticTerm) -> QuadraticTerm:
        return QuadraticTerm(self.normal + other.normal, self.linear + other.linear,
                             self.constant + other.constant)

    def scaled(self, factor: float) -> QuadraticTerm:
        return QuadraticTerm(factor * self.normal, factor * self.linear,
                             factor * self.constant)


@dataclass
class LassoResult:
    """Outcome of :func:`nonneg_lasso` (in the manner of ``scipy.optimize.OptimizeResult``)."""

    x: np.ndarray
    nit: int
    converged: bool
    message: str
    costs: list[float] = field(default_factory=list)


def lipschitz_constant(matvec, n: int, n_iter: int = 30, rng=0) -> float:
    """Largest eigenvalue of the PSD operator ``matvec`` (power iteration, +5% margin)."""
    v = np.random.default_rng(rng).random(n) + 0.5
    v /= np.linalg.norm(v)
    lam = 0.0
    for _ in range(n_iter):
        u = matvec(v)
        new = float(np.linalg.norm(u))
        if new == 0:
            return 1.0
        v = u / new
        if abs(new - lam) < 1e-4 * new:
            lam = new
            break
        lam = new
    return 1.05 * lam


def nonneg_lasso(term: QuadraticTerm, lam: float, w0: np.ndarray, *, max_iter: int = 200,
                 tol: float = 1e-4, lipschitz: float | None = None,
                 callback: Callable[[Progress], object] | None = None) -> LassoResult:
    """Solve ``min_w 1/2 w^T Q w - b^T w + lam * sum(w)`` subject to ``w >= 0`` by FISTA.

    The plain-function face of :func:`iter_nonneg_lasso`.

    Parameters
    ----------
    term : QuadraticTerm
        The smooth part.
    lam : float
        L1 weight ``lambda_w`` (>= 0).
    w0 : ndarray of shape (n,)
        Starting point (warm start); negative entries are clipped.
    max_iter : int
        Iteration cap.
    tol : float
        Stop when the relative change of ``w`` falls below ``tol``.
    lipschitz : float, optional
        Upper bound on the largest eigenvalue of ``Q`` (estimated when omitted).
    callback : callable, optional
        Called with the :class:`~napari_edgecme.core.progress.Progress` record of every
        iteration, its ``iterate`` the iterate ``w`` (n,) (e.g. to trace the
        convergence, as ``benchmarks/bench_lasso.py`` does; copy it to keep it, never
        modify it). Raising ``StopIteration`` in it stops FISTA and returns the
        current iterate (``converged`` False, the message says it was stopped).

    Returns
    -------
    LassoResult
    """
    return drive(iter_nonneg_lasso(term, lam, w0, max_iter=max_iter, tol=tol,
                                   lipschitz=lipschitz), callback)


def iter_nonneg_lasso(term: QuadraticTerm, lam: float, w0: np.ndarray, *, max_iter: int = 200,
                      tol: float = 1e-4, lipschitz: float | None = None):
    """:func:`nonneg_lasso` as a solver generator (:mod:`~napari_edgecme.core.progress`).

    Yields
    ------
    Progress
        ``stage="lasso"``, one record per FISTA iteration: ``step`` iterations of at
        most ``total = max_iter``, ``iterate`` the iterate ``w`` (n,), ``cost`` the
        objective where it was evaluated (every 10th iteration and the last).

    Returns
    -------
    LassoResult
        ``StopIteration.value``; on :class:`~napari_edgecme.core.progress.StopRequested`
        at once, with the current iterate.
    """
    n = w0.size
    L = lipschitz if lipschitz is not None else lipschitz_constant(term.matvec, n)
    step = 1.0 / max(L, 1e-30)
    x = np.maximum(np.asarray(w0, np.float64), 0)
    y = x.copy()
    t = 1.0
    costs: list[float] = []
    converged = False
    stopped = False
    it = 0
    prev_cost = np.inf
    try:
        for it in range(1, max_iter + 1):
            Qy = term.matvec(y)
            grad = Qy - term.linear + lam
            x_new = np.maximum(y - step * grad, 0.0)
            t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
            # adaptive restart: drop the momentum when it points uphill
            if (y - x_new) @ (x_new - x) > 0:
                t_new = 1.0
                y = x_new.copy()
            else:
                y = x_new + ((t - 1.0) / t_new) * (x_new - x)
            change = np.linalg.norm(x_new - x) / max(np.linalg.norm(x_new), 1e-30)
            x, t = x_new, t_new
            cost = None
            if it % 10 == 0 or change < tol:
                Qx = term.matvec(x)
                cost = term.value(x, Qx) + lam * float(x.sum())
                costs.append(cost)
                if change < tol or abs(prev_cost - cost) <= 1e-7 * abs(cost):
                    converged = True
                prev_cost = cost
            yield Progress("lasso", it, max_iter, f"FISTA iteration {it}/{max_iter}",
                           iteration=it, cost=cost, iterate=x)
            if converged:
                break
    except StopRequested:
        stopped = True
    if stopped:
        message = f"stopped by request after {it} iterations"
    else:
        message = "converged" if converged else f"reached max_iter={max_iter}"
    return LassoResult(x, it, converged, message, costs)
