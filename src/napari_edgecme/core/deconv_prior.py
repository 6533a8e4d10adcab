"""The hyper-Laplacian gradient prior: finite differences and the exact w-step.

Half-quadratic splitting (Krishnan & Fergus 2009 [1]_) replaces the prior
``sum_i |(D f)_i|^alpha`` by ``sum_i |w_i|^alpha + beta / 2 ||D f - w||^2`` and
alternates an image step (quadratic in ``f``) with a per-pixel step in ``w``:

.. math::  w^*(v) = \\arg\\min_w |w|^\\alpha + \\tfrac{\\beta}{2} (w - v)^2 ,

with ``v`` the current gradient. For ``w > 0`` (take ``v > 0``; the solution is odd in
``v``) a stationary point satisfies ``alpha w^(alpha-1) + beta (w - v) = 0``. With a
change of variable that equation is a polynomial with closed-form roots:

* ``alpha = 1/2``, ``w = s^2``: the depressed cubic ``s^3 - v s + 1/(2 beta) = 0``
  (KF's cubic, here in the variable ``sqrt(w)``); its largest real root is the local minimum;
* ``alpha = 2/3``, ``w = s^3``: the depressed quartic ``s^4 - v s + 2/(3 beta) = 0``
  (KF's quartic, here in the variable ``w^(1/3)``), solved by Ferrari's method; the larger root of
  the quadratic factor with positive roots is the local minimum.

The minimiser is that root when its energy beats ``w = 0`` and 0 otherwise, so
``w*`` is a thresholding function: exactly zero for ``|v|`` below a threshold
(:func:`shrink_threshold`), then jumps to a value close to ``v``. We evaluate the
roots exactly (trigonometric / Cardano formulas, vectorised) only where ``|v|`` is
above that threshold, so the cost is proportional to the number of strong gradients.

References
----------
.. [1] D. Krishnan and R. Fergus, "Fast image deconvolution using hyper-Laplacian
   priors", NIPS 2009.
"""

from __future__ import annotations

import numpy as np

from .linop import LinearOperator

__all__ = [
    "ALPHAS",
    "Gradient",
    "check_alpha",
    "grad",
    "grad_adjoint",
    "shrink_hyperlaplacian",
    "shrink_threshold",
]

#: Exponents with exact w-steps.
ALPHAS = (0.5, 2.0 / 3.0)


def check_alpha(alpha) -> float:
    """Return ``alpha`` snapped to 1/2 or 2/3, or raise a ValueError naming it."""
    try:
        value = float(alpha)
    except (TypeError, ValueError):
        value = np.nan
    for a in ALPHAS:
        if abs(value - a) < 1e-3:
            return a
    raise ValueError(f"alpha must be 1/2 or 2/3 (exact w-step); got {alpha!r}")


# --------------------------------------------------------------------------------------
# finite differences
# --------------------------------------------------------------------------------------

def grad(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward differences with a Neumann boundary.

    Parameters
    ----------
    f : ndarray of shape (M, N)

    Returns
    -------
    gx, gy : ndarray of shape (M, N)
        ``gx[:, j] = f[:, j + 1] - f[:, j]`` and ``gy[i] = f[i + 1] - f[i]``; the last
        column of ``gx`` and the last row of ``gy`` are zero. Both are views of one
        (2, M, N) array, the :class:`Gradient` operator's ``D f``.
    """
    gx, gy = _differences(f)
    return gx, gy


def _differences(f: np.ndarray) -> np.ndarray:
    """``(gx, gy)`` of :func:`grad` in one array of shape (2, M, N)."""
    out = np.zeros((2, *f.shape), f.dtype)
    np.subtract(f[:, 1:], f[:, :-1], out=out[0, :, :-1])
    np.subtract(f[1:], f[:-1], out=out[1, :-1])
    return out


def grad_adjoint(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """Adjoint of :func:`grad` (minus the divergence), ``D^T (gx, gy)``, shape (M, N).

    The last column of ``gx`` and the last row of ``gy`` are ignored (outside the
    range of :func:`grad`), so ``<grad(f), g> == <f, grad_adjoint(g)>`` exactly.
    """
    out = np.zeros_like(gx)
    out[:, :-1] -= gx[:, :-1]
    out[:, 1:] += gx[:, :-1]
    out[:-1] -= gy[:-1]
    out[1:] += gy[:-1]
    return out


class Gradient(LinearOperator):
    """The finite differences ``D = (D_x, D_y)`` of :func:`grad` as an operator.

    ``(M, N) -> (2, M, N)``: ``(D f)[0]`` is ``gx`` and ``(D f)[1]`` is ``gy`` of
    :func:`grad`; the adjoint is :func:`grad_adjoint`, so ``D^T D`` is the (Neumann)
    Laplacian of the image steps (KF's x sub-problem, Eq. 21's splitting).

    Parameters
    ----------
    shape : tuple of int
        ``(M, N)``, the image.
    dtype : dtype
        float32 or float64.
    """

    def __init__(self, shape, dtype=np.float32):
        self.shape_in = tuple(int(s) for s in shape)
        self.shape_out = (2, *self.shape_in)
        self.dtype = np.dtype(dtype)

    def _forward(self, f):
        return _differences(f)

    def _adjoint(self, g):
        return grad_adjoint(g[0], g[1])


# --------------------------------------------------------------------------------------
# the w-step
# --------------------------------------------------------------------------------------

def _stationary_w_half(v, beta):
    """alpha = 1/2: ``w = s^2`` with ``s`` the largest real root of ``s^3 - v s + q = 0``,
    ``q = 1/(2 beta)``; NaN where the cubic has a single real root (it is then negative
    and no ``w > 0`` is stationary)."""
    q = 0.5 / beta
    # three real roots iff 4 v^3 >= 27 q^2, i.e. |arg| <= 1 (trigonometric form)
    arg = -(1.5 * q / v) * np.sqrt(3.0 / v)
    with np.errstate(invalid="ignore"):
        s = 2.0 * np.sqrt(v / 3.0) * np.cos(np.arccos(arg) / 3.0)
    return np.where(np.abs(arg) <= 1.0, s * s, np.nan)


def _stationary_w_two_thirds(v, beta):
    """alpha = 2/3: ``w = s^3`` with ``s`` the local-minimum root of ``s^4 - v s + r = 0``,
    ``r = 2/(3 beta)``, by Ferrari's method; NaN where no positive root exists."""
    r = 2.0 / (3.0 * beta)
    # resolvent cubic m^3 - r m - v^2 / 8 = 0: its largest real root m > sqrt(r) > 0
    # makes s^4 - v s + r = (s^2 + m)^2 - 2m (s + v / (4m))^2
    half_q = -v * v / 16.0  # Q / 2 with Q = -v^2 / 8
    disc = half_q * half_q - (r / 3.0) ** 3  # (Q/2)^2 + (P/3)^3 with P = -r
    with np.errstate(invalid="ignore"):
        sq = np.sqrt(np.maximum(disc, 0.0))
        m_one = np.cbrt(-half_q + sq) + np.cbrt(-half_q - sq)  # Cardano, one real root
        arg = np.clip((-half_q) / np.sqrt((r / 3.0) ** 3), -1.0, 1.0)
        m_three = 2.0 * np.sqrt(r / 3.0) * np.cos(np.arccos(arg) / 3.0)  # three real roots
        m = np.where(disc > 0, m_one, m_three)
        # positive roots solve s^2 - sqrt(2m) s + m - sqrt(2m) v / (4m) = 0
        root2m = np.sqrt(2.0 * m)
        delta = root2m * v / m - 2.0 * m
        s = 0.5 * (root2m + np.sqrt(delta))
    return np.where(delta >= 0, s**3, np.nan)


def _stationary_w(v, beta, alpha):
    """The local minimiser ``w > 0`` for ``v > 0`` (NaN where none exists)."""
    if alpha == 0.5:
        return _stationary_w_half(v, beta)
    return _stationary_w_two_thirds(v, beta)


def shrink_threshold(beta: float, alpha: float) -> float:
    """Smallest ``|v|`` whose w-step is not zero (the jump of the thresholding function).

    Found by bisection on the energy difference between the stationary root and 0;
    for ``alpha = 1/2`` it is ``1.5 beta^(-2/3)`` exactly.
    """
    alpha = check_alpha(alpha)
    beta = float(beta)

    def nonzero_wins(v):
        w = _stationary_w(np.array([v]), beta, alpha)[0]
        return bool(np.isfinite(w) and w**alpha + 0.5 * beta * (w - v) ** 2 < 0.5 * beta * v * v)

    lo, hi = 0.0, 1.0
    while not nonzero_wins(hi):
        lo, hi = hi, 2.0 * hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if nonzero_wins(mid) else (mid, hi)
    return hi


def shrink_hyperlaplacian(v: np.ndarray, beta: float, alpha: float,
                          threshold: float | None = None) -> np.ndarray:
    """The exact w-step ``argmin_w |w|^alpha + beta/2 (w - v)^2``, elementwise (KF's w sub-problem).

    Parameters
    ----------
    v : ndarray
        Gradients (any shape), float32 or float64.
    beta : float
        Splitting weight (> 0).
    alpha : {1/2, 2/3}
        Exponent of the hyper-Laplacian prior.
    threshold : float, optional
        :func:`shrink_threshold` ``(beta, alpha)``, if already known.

    Returns
    -------
    ndarray like ``v``
        Zero where ``|v|`` is below the threshold, else the root of the cubic
        (``alpha = 1/2``) or quartic (``alpha = 2/3``) that minimises the energy.

    Examples
    --------
    >>> import numpy as np
    >>> w = shrink_hyperlaplacian(np.array([0.05, -0.5, 2.0]), beta=8.0, alpha=0.5)
    >>> w[0], bool(w[1] < 0), bool(1.8 < w[2] < 2.0)
    (np.float64(0.0), True, True)
    """
    alpha = check_alpha(alpha)
    v = np.asarray(v)
    if threshold is None:
        threshold = shrink_threshold(beta, alpha)
    out = np.zeros(v.shape, v.dtype)
    mag = np.abs(v)
    idx = np.flatnonzero(mag >= threshold * (1 - 1e-6))
    if idx.size == 0:
        return out
    a = mag.ravel()[idx].astype(np.float64)
    w = _stationary_w(a, beta, alpha)
    keep = np.isfinite(w) & (w**alpha + 0.5 * beta * (w - a) ** 2 < 0.5 * beta * a * a)
    w = np.where(keep, np.minimum(w, a), 0.0)
    np.put(out, idx, np.sign(v.ravel()[idx]) * w)
    return out
