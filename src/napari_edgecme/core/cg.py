"""Conjugate gradients over linear operators, and the circulant preconditioner of the image step.

The deconvolution's image step (hyper-Laplacian half-quadratic splitting) is a
symmetric positive definite system ``(lam T^T T + beta D^T D) x = b`` whose operator is
the masked EFF blur (:meth:`~.deconv_solvers.LatentDomain.normal`);
:func:`conjugate_gradient` solves it as a solver generator
(:mod:`~napari_edgecme.core.progress`), preconditioned by the same system with the
tile PSFs replaced by their mean power spectrum (:class:`CirculantPreconditioner`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import scipy.fft as sfft

from .linop import LinearOperator
from .operators import FFT_WORKERS
from .progress import Progress, StopRequested

if TYPE_CHECKING:
    from .deconv_solvers import LatentDomain

__all__ = ["CirculantPreconditioner", "conjugate_gradient"]


def conjugate_gradient(normal: LinearOperator, b: np.ndarray, x0: np.ndarray,
                       iterations: int, tol: float, precondition: LinearOperator | None = None):
    """(Preconditioned) conjugate gradients for ``A x = b``, A symmetric positive definite.

    ``normal`` is ``A`` (e.g. :meth:`LatentDomain.normal`), ``precondition`` a
    symmetric positive definite approximation of ``A^-1`` (e.g.
    :meth:`CirculantPreconditioner.operator`), both operators on ``b``'s shape.

    A solver generator (:mod:`~napari_edgecme.core.progress`): yields a record after
    each iteration (``step`` ``k`` of ``total = iterations``, the relative residual in
    the message, ``iterate`` the current ``x``, updated in place by the next
    iteration) and returns ``x``; on
    :class:`~napari_edgecme.core.progress.StopRequested` it returns ``x`` at once.
    Stops when ``||b - A x|| <= tol ||b||`` or after ``iterations`` steps.
    Inner products in float64.
    """
    x = x0.copy()
    r = b - normal @ x
    z = precondition @ r if precondition is not None else r
    p = z.copy()
    rz = float(np.vdot(r, z))
    bnorm = math.sqrt(float(np.vdot(b, b))) or 1.0
    res = math.sqrt(float(np.vdot(r, r))) / bnorm
    try:
        for k in range(1, iterations + 1):
            if res <= tol:
                break
            ap = normal @ p
            alpha = rz / max(float(np.vdot(p, ap)), 1e-300)
            x += x.dtype.type(alpha) * p
            r -= r.dtype.type(alpha) * ap
            z = precondition @ r if precondition is not None else r
            rz_new = float(np.vdot(r, z))
            p *= p.dtype.type(rz_new / max(rz, 1e-300))
            p += z
            rz = rz_new
            res = math.sqrt(float(np.vdot(r, r))) / bnorm
            yield Progress("conjugate gradients", k, iterations,
                           f"CG iteration {k}, relative residual {res:.1e}", iteration=k,
                           iterate=x)
    except StopRequested:
        pass
    return x


class CirculantPreconditioner:
    """``(lam <|k_r|^2> + beta |d|^2)^-1`` on the whole domain, by FFT (for CG).

    ``<|k_r|^2>`` is the power spectrum averaged over the EFF tiles, from the mean
    autocorrelation of the tile PSFs; the operator is circulant with a real positive
    symbol, hence symmetric positive definite, and close to the inverse of the
    normal equations of the image step wherever the PSF varies slowly.
    """

    def __init__(self, domain: LatentDomain):
        psfs = domain.op.psfs.astype(np.float64)
        K = psfs.shape[-1]
        L = 2 * K - 1  # support of an autocorrelation
        self.shape = tuple(sfft.next_fast_len(n + K, real=True) for n in domain.shape)
        self.domain_shape = domain.shape
        self.dtype = domain.dtype
        spec = sfft.rfft2(psfs, s=(L, L), axes=(-2, -1))
        acf = sfft.irfft2((spec.real**2 + spec.imag**2).mean(0), s=(L, L))  # lag 0 at [0, 0]
        lags = np.zeros(self.shape)
        rows = np.r_[0:K, self.shape[0] - K + 1:self.shape[0]]
        cols = np.r_[0:K, self.shape[1] - K + 1:self.shape[1]]
        lags[np.ix_(rows, cols)] = acf
        self.k2 = np.maximum(sfft.rfft2(lags).real, 0.0)  # even and real: a real spectrum
        wy = 2.0 - 2.0 * np.cos(2 * np.pi * np.arange(self.shape[0]) / self.shape[0])
        wx = 2.0 - 2.0 * np.cos(2 * np.pi * np.arange(self.shape[1] // 2 + 1) / self.shape[1])
        self.d2 = wy[:, None] + wx[None, :]

    def operator(self, lam: float, beta: float) -> LinearOperator:
        """The preconditioner for the image step with weights ``lam`` and ``beta``."""
        inv = (1.0 / (lam * self.k2 + beta * self.d2)).astype(self.dtype)
        return _FourierMultiplier(inv, self.shape, self.domain_shape, self.dtype)


class _FourierMultiplier(LinearOperator):
    """``P^T F^-1 diag(symbol) F P``: (H, W) zero-padded to ``fft_shape``, its half
    spectrum multiplied by ``symbol``, cropped back to (H, W).

    With a real symbol (the half spectrum of an even filter) the operator is
    symmetric, its own adjoint.
    """

    def __init__(self, symbol, fft_shape, shape, dtype):
        self.symbol = symbol
        self.fft_shape = tuple(fft_shape)
        self.shape_in = self.shape_out = tuple(shape)
        self.dtype = np.dtype(dtype)

    def _forward(self, r):
        H, W = self.shape_in
        rh = sfft.rfft2(r, s=self.fft_shape, workers=FFT_WORKERS)
        return sfft.irfft2(rh * self.symbol, s=self.fft_shape, workers=FFT_WORKERS)[:H, :W].astype(
            self.dtype, copy=False)

    _adjoint = _forward
