"""Solvers behind :mod:`napari_edgecme.core.deconv`, on one block of the image.

A block is a rectangle of the observed image ``g`` (``h x w``). Its *latent domain*
is that rectangle grown by ``pad`` pixels on every side, enough to hold every scene
point that any observed pixel sees through the blur. The data term is masked: the
blur ``T`` (the EFF operator of :mod:`~napari_edgecme.core.operators`, built with
``origin`` at the domain's corner) acts on the whole domain and only the observed
pixels are compared with ``g``,

.. math::  E_{data}(f) = \\tfrac{\\lambda}{2} \\| M T f - g \\|^2 ,

with ``M`` the crop to the observed rectangle. Pixels just outside the frame are
free unknowns constrained by the data they blur into and by the prior, so no
periodic or reflective assumption is made about the scene beyond the frame and no
ringing frame appears at the border.

Three solvers work on a :class:`LatentDomain`:

* :func:`hyperlaplacian_steps` -- half-quadratic splitting (Krishnan & Fergus 2009),
  image step by conjugate gradients on the EFF normal equations (exact) or by
  :class:`PatchFourier` (closed form per EFF tile);
* :func:`richardson_lucy_steps` -- multiplicative RL with the masked EFF operator;
* :func:`wiener` -- one patch-wise Fourier solve with a gradient (``1/|omega|^2``)
  image spectrum.

They are generators: they yield ``(kind, info)`` tuples after each unit of work
(``kind`` is ``"iteration"`` when an outer iteration has finished, ``"substep"``
inside one) and return the latent estimate on the domain. The current iterate is
also kept in ``state["x"]`` so that a caller stopping early can use it.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft
from numpy.lib.stride_tricks import sliding_window_view

from .deconv_prior import grad, grad_adjoint, shrink_hyperlaplacian, shrink_threshold
from .motion import CameraMotion
from .operators import FFT_WORKERS, EfficientFilterFlow

__all__ = [
    "LatentDomain",
    "PatchFourier",
    "conjugate_gradient",
    "hyperlaplacian_steps",
    "richardson_lucy_steps",
    "wiener",
]

#: Bytes of complex spectra processed per chunk of tiles in :class:`PatchFourier`.
_CHUNK_BYTES = 48 * 2**20


class LatentDomain:
    """A block of the image with its padded latent domain and masked blur operator.

    Parameters
    ----------
    motion : CameraMotion
        The motion at the image's size.
    box : tuple of int
        ``(row0, row1, col0, col1)``: the observed rectangle in image pixels.
    pad : int
        Latent pixels added beyond the observed rectangle on each side (at least the
        PSF half-width).
    stride : int, optional
        EFF tile size (default: the operator's).
    dtype : dtype
        float32 or float64.

    Attributes
    ----------
    shape : tuple of int
        ``(h + 2 pad, w + 2 pad)``, the latent domain.
    inner : tuple of slice
        The observed rectangle inside the domain.
    op : EfficientFilterFlow
        ``T`` on the domain; array index ``(0, 0)`` is image pixel ``(row0 - pad, col0 - pad)``.
    """

    def __init__(self, motion: CameraMotion, box, pad: int, stride=None, dtype=np.float32):
        r0, r1, c0, c1 = (int(b) for b in box)
        self.box = (r0, r1, c0, c1)
        self.pad = int(pad)
        self.observed_shape = (r1 - r0, c1 - c0)
        self.shape = (r1 - r0 + 2 * self.pad, c1 - c0 + 2 * self.pad)
        self.inner = (slice(self.pad, self.pad + r1 - r0), slice(self.pad, self.pad + c1 - c0))
        self.origin = (r0 - self.pad, c0 - self.pad)
        self.dtype = np.dtype(dtype)
        self.op = EfficientFilterFlow(motion, shape=self.shape, origin=self.origin,
                                      stride=stride, dtype=self.dtype)

    def embed(self, g: np.ndarray) -> np.ndarray:
        """``M^T g``: observed (h, w) -> domain, zero outside the observed rectangle."""
        out = np.zeros(self.shape, self.dtype)
        out[self.inner] = g
        return out

    def data_forward(self, x: np.ndarray) -> np.ndarray:
        """``M T x``: domain -> observed (h, w)."""
        return self.op.forward(x)[self.inner]

    def data_adjoint(self, r: np.ndarray) -> np.ndarray:
        """``T^T M^T r``: observed (h, w) -> domain."""
        return self.op.adjoint(self.embed(r))

    def extend(self, g: np.ndarray, extra: int = 0) -> np.ndarray:
        """The observation mirrored (``reflect``) into the pad (and ``extra`` more pixels)."""
        return np.pad(g, self.pad + extra, mode="reflect").astype(self.dtype, copy=False)


# --------------------------------------------------------------------------------------
# patch-wise Fourier solver
# --------------------------------------------------------------------------------------

def _fast_box(patch: int, margin: int) -> int:
    """Smallest FFT-friendly length >= patch + 2 margin with an even excess over ``patch``."""
    n = sfft.next_fast_len(patch + 2 * margin, real=True)
    while (n - patch) % 2:
        n = sfft.next_fast_len(n + 1, real=True)
    return n


class PatchFourier:
    """Closed-form image step per EFF tile, blended by the EFF windows.

    For each tile ``r`` of the operator's :class:`~napari_edgecme.core.operators.PatchGrid`
    a box around its window (grown by ``margin`` pixels on every side) is solved in
    closed form with the tile's PSF ``k_r``, as if the blur were the circular
    convolution with ``k_r`` inside the box:

    .. math::  \\hat f_r = \\frac{\\lambda \\overline{\\hat k_r} \\hat y_r + \\widehat{(D^T z)}_r}
               {\\lambda |\\hat k_r|^2 + \\beta (|\\hat d_x|^2 + |\\hat d_y|^2)}   (KF Eq. 3)

    (``z`` = ``beta w``, the prior's pull; ``z = 0`` gives the Wiener filter), and the
    solution is ``f = sum_r omega_r C_r^T f_r`` with the EFF windows ``omega_r``, which
    sum to one. The margin keeps the wrap-around of the circular model away from the
    window. Boxes that reach beyond the observed rectangle (border tiles) have unknown
    data there; they are handled by majorise-minimise on the masked data term: the
    missing data are filled with the tile's own blurred estimate ``k_r * f_r``
    (initially with the mirrored observation), which makes each border tile's
    quadratic a majoriser of its masked data term that touches it at the current
    estimate.

    Parameters
    ----------
    domain : LatentDomain
    margin : int
        Minimum box margin beyond each window (at least the PSF size is sensible).
    """

    def __init__(self, domain: LatentDomain, margin: int):
        self.domain = domain
        op = domain.op
        grid = op.grid
        self.dtype = domain.dtype
        self.counts = grid.counts
        self.n = grid.n_patches
        self.stride = grid.stride
        P = self.patch = grid.patch_shape
        self.box = tuple(_fast_box(p, margin) for p in P)
        self.margin = tuple((b - p) // 2 for b, p in zip(self.box, P, strict=True))
        # extended canvas: box (i, j) starts at canvas (i * s0, j * s1)
        self.lead = tuple(o // 2 + m for o, m in zip(grid.overlap, self.margin, strict=True))
        self.canvas = tuple(
            max(self.lead[a] + domain.shape[a], (self.counts[a] - 1) * self.stride[a] + self.box[a])
            for a in range(2))
        B0, B1 = self.box
        self._spec_shape = (B0, B1 // 2 + 1)
        # tile PSFs centred on the box origin, their spectra
        K = grid.psf_size
        h = (K - 1) // 2
        kbox = np.zeros((self.n, B0, B1), self.dtype)
        kbox[:, :K, :K] = op.psfs
        kbox = np.roll(kbox, (-h, -h), axis=(1, 2))
        self.khat = self._rfft(kbox)
        self.k2 = (self.khat.real**2 + self.khat.imag**2).astype(self.dtype)
        wy = 2.0 - 2.0 * np.cos(2 * np.pi * np.arange(B0) / B0)
        wx = 2.0 - 2.0 * np.cos(2 * np.pi * np.arange(B1 // 2 + 1) / B1)
        self.d2 = (wy[:, None] + wx[None, :]).astype(self.dtype)
        wy_, wx_ = (w.astype(self.dtype) for w in grid.windows)
        self.windows = (wy_[:, None, :, None] * wx_[None, :, None, :]).reshape(self.n, *P)
        # data a box's circular model can use: observed pixels at least the PSF
        # half-width from the box edge (nearer ones see latent pixels outside the box)
        self._observed = np.zeros(self.canvas, bool)
        inner = domain.inner
        self._observed[self.lead[0] + inner[0].start:self.lead[0] + inner[0].stop,
                       self.lead[1] + inner[1].start:self.lead[1] + inner[1].stop] = True
        self._interior = np.zeros(self.box, bool)
        self._interior[h:B0 - h, h:B1 - h] = True
        per_tile = B0 * (B1 // 2 + 1) * np.dtype(np.complex128).itemsize
        self.chunk = max(1, _CHUNK_BYTES // per_tile)
        self.kty = None
        self._y = None

    # -- geometry -----------------------------------------------------------------
    def _rfft(self, a):
        return sfft.rfft2(a, axes=(-2, -1), workers=FFT_WORKERS)

    def _irfft(self, a):
        return sfft.irfft2(a, s=self.box, axes=(-2, -1), workers=FFT_WORKERS)

    def _to_canvas(self, arr: np.ndarray, mode: str) -> np.ndarray:
        """Place a domain-shaped array on the extended canvas (``zero`` or ``reflect`` outside)."""
        before = self.lead
        after = tuple(c - l - s for c, l, s in zip(self.canvas, before, arr.shape, strict=True))
        if mode == "zero":
            return np.pad(arr, tuple(zip(before, after, strict=True)))
        return np.pad(arr, tuple(zip(before, after, strict=True)), mode="reflect")

    def _boxes(self, canvas: np.ndarray) -> np.ndarray:
        """All boxes of a canvas, (n, B0, B1) (a strided view)."""
        view = sliding_window_view(canvas, self.box)[::self.stride[0], ::self.stride[1]]
        return view[:self.counts[0], :self.counts[1]].reshape(self.n, *self.box)

    def _blend(self, boxes_iter) -> np.ndarray:
        """``sum_r omega_r C_r^T f_r`` from (tile indices, box solutions) chunks."""
        canvas = np.zeros(self.canvas, self.dtype)
        m0, m1 = self.margin
        P0, P1 = self.patch
        nx = self.counts[1]
        for idx, boxes in boxes_iter:
            for r, b in zip(idx, boxes, strict=True):
                i, j = divmod(int(r), nx)
                r0, c0 = i * self.stride[0] + m0, j * self.stride[1] + m1
                canvas[r0:r0 + P0, c0:c0 + P1] += b[m0:m0 + P0, m1:m1 + P1] * self.windows[r]
        l0, l1 = self.lead
        return canvas[l0:l0 + self.domain.shape[0], l1:l1 + self.domain.shape[1]]

    # -- data ---------------------------------------------------------------------
    def set_observation(self, g: np.ndarray) -> None:
        """Take the observed block ``g`` (h, w); caches ``conj(k_r) y_r`` per tile."""
        self._y = self._to_canvas(self.domain.extend(g), "reflect")
        boxes = self._boxes(self._y)
        observed = self._boxes(self._observed)
        self.kty = np.empty((self.n, *self._spec_shape), self.khat.dtype)
        for s in range(0, self.n, self.chunk):
            sl = slice(s, s + self.chunk)
            yhat = self._rfft(boxes[sl])
            # unusable data <- the circular blur of the (mirrored) observation: a
            # periodic, consistent start for the majorise-minimise fill
            blurred = self._irfft(self.khat[sl] * yhat)
            fill = np.where(observed[sl] & self._interior, boxes[sl], blurred)
            self.kty[sl] = np.conj(self.khat[sl]) * self._rfft(fill)

    def solve(self, prior_rhs, lam: float, beta: float, refine: int = 0):
        """One image step; a generator yielding once per chunk of tiles, returning ``f``.

        Parameters
        ----------
        prior_rhs : ndarray of shape domain.shape or None
            ``D^T z`` with ``z = beta w`` (None: no prior pull, the Wiener filter).
        lam, beta : float
            Data weight and prior (splitting) weight.
        refine : int
            Extra majorise-minimise passes (fill, then re-solve) per tile.
        """
        if self.kty is None:
            raise RuntimeError("set_observation() must be called before solve()")
        prior_boxes = None
        if prior_rhs is not None:
            prior_boxes = self._boxes(self._to_canvas(prior_rhs, "zero"))
        y_boxes = self._boxes(self._y)
        observed = self._boxes(self._observed)
        lam_c = self.dtype.type(lam)
        beta_c = self.dtype.type(beta)
        results = []
        for s in range(0, self.n, self.chunk):
            idx = np.arange(s, min(s + self.chunk, self.n))
            prior_hat = self._rfft(prior_boxes[idx]) if prior_boxes is not None else 0
            den = lam_c * self.k2[idx] + beta_c * self.d2
            valid = observed[idx] & self._interior
            for mm in range(1 + refine):
                xhat = (lam_c * self.kty[idx] + prior_hat) / den
                # majorise-minimise: unusable data <- the tile's blurred estimate
                blurred = self._irfft(self.khat[idx] * xhat)
                fill = np.where(valid, y_boxes[idx], blurred)
                self.kty[idx] = np.conj(self.khat[idx]) * self._rfft(fill)
            boxes = self._irfft(xhat).astype(self.dtype, copy=False)
            results.append((idx, boxes))
            yield
        return self._blend(results)


# --------------------------------------------------------------------------------------
# conjugate gradients
# --------------------------------------------------------------------------------------

def conjugate_gradient(apply_a, b: np.ndarray, x0: np.ndarray, iterations: int, tol: float):
    """Conjugate gradients for ``A x = b`` (A symmetric positive definite), as a generator.

    Yields ``(k, relative_residual)`` after each iteration and returns ``x``. Stops when
    ``||b - A x|| <= tol ||b||`` or after ``iterations`` steps. Inner products in float64.
    """
    x = x0.copy()
    r = b - apply_a(x)
    p = r.copy()
    rr = float(np.vdot(r, r))
    bnorm = math.sqrt(float(np.vdot(b, b))) or 1.0
    for k in range(1, iterations + 1):
        if math.sqrt(rr) <= tol * bnorm:
            break
        ap = apply_a(p)
        alpha = rr / max(float(np.vdot(p, ap)), 1e-300)
        x += x.dtype.type(alpha) * p
        r -= r.dtype.type(alpha) * ap
        rr_new = float(np.vdot(r, r))
        p *= p.dtype.type(rr_new / max(rr, 1e-300))
        p += r
        rr = rr_new
        yield k, math.sqrt(rr) / bnorm
    return x


# --------------------------------------------------------------------------------------
# the three methods on one block
# --------------------------------------------------------------------------------------

def hyperlaplacian_steps(domain: LatentDomain, g: np.ndarray, *, lam: float, alpha: float,
                         betas, inner_iterations: int, solver: str,
                         fourier: PatchFourier | None, cg_iterations: int, cg_tol: float,
                         refine: int, state: dict):
    """Half-quadratic splitting for the hyper-Laplacian prior on one block (KF Alg. 1).

    ``min_f lam/2 ||M T f - g||^2 + sum |D_x f|^alpha + |D_y f|^alpha``; for each
    ``beta`` in ``betas`` and each inner iteration: the w-step
    (:func:`~napari_edgecme.core.deconv_prior.shrink_hyperlaplacian`) on the current
    gradients, then the image step
    ``(lam T^T M^T M T + beta D^T D) f = lam T^T M^T g + beta D^T w`` by ``solver``.
    """
    x = domain.extend(g)
    state["x"] = x
    if solver == "fourier":
        fourier.set_observation(g)
        b_data = None
    else:
        b_data = domain.data_adjoint(g) * domain.dtype.type(lam)
    for beta in betas:
        thr = shrink_threshold(beta, alpha)
        for it in range(inner_iterations):
            gx, gy = grad(x)
            wx = shrink_hyperlaplacian(gx, beta, alpha, thr)
            wy = shrink_hyperlaplacian(gy, beta, alpha, thr)
            prior_rhs = grad_adjoint(wx, wy)
            prior_rhs *= domain.dtype.type(beta)
            del gx, gy, wx, wy
            if solver == "fourier":
                x = yield from _substeps(fourier.solve(prior_rhs, lam, beta, refine))
            else:
                x = yield from _cg_image_step(domain, b_data + prior_rhs, x, lam, beta,
                                              cg_iterations, cg_tol)
            state["x"] = x
            yield "iteration", {"beta": beta, "inner": it + 1}
    return x


def _substeps(gen):
    """Forward a solver's per-chunk yields as ``("substep", {})`` and return its value."""
    while True:
        try:
            next(gen)
        except StopIteration as done:
            return done.value
        yield "substep", {}


def _cg_image_step(domain, b, x0, lam, beta, iterations, tol):
    lam_c = domain.dtype.type(lam)
    beta_c = domain.dtype.type(beta)

    def apply_a(v):
        out = domain.op.adjoint(domain.embed(domain.data_forward(v)))
        out *= lam_c
        gx, gy = grad(v)
        out += beta_c * grad_adjoint(gx, gy)
        return out

    gen = conjugate_gradient(apply_a, b, x0, iterations, tol)
    while True:
        try:
            k, res = next(gen)
        except StopIteration as done:
            return done.value
        yield "substep", {"cg": k, "residual": res}


def richardson_lucy_steps(domain: LatentDomain, g: np.ndarray, *, iterations: int,
                          state: dict):
    """Richardson-Lucy with the masked SV operator (non-negative, multiplicative).

    ``f <- f . T^T M^T (g / (M T f)) / T^T M^T 1``; latent pixels that no observed pixel
    sees (normaliser below 1e-3) keep their initial value. The estimate starts from the
    mirrored observation, floored at ``eps`` so that no pixel is stuck at zero.
    """
    eps = domain.dtype.type(1e-3)
    x = np.maximum(domain.extend(g), eps)
    state["x"] = x
    norm = domain.data_adjoint(np.ones(domain.observed_shape, domain.dtype))
    seen = norm > 1e-3
    inv_norm = np.where(seen, 1.0 / np.where(seen, norm, 1.0), 0.0).astype(domain.dtype)
    for it in range(iterations):
        ratio = g / np.maximum(domain.data_forward(x), eps)
        update = domain.data_adjoint(ratio)
        update *= inv_norm
        x = np.where(seen, x * update, x)
        state["x"] = x
        yield "iteration", {"iteration": it + 1}
    return x


def wiener(domain: LatentDomain, g: np.ndarray, *, nsr: float, fourier: PatchFourier,
           refine: int, state: dict):
    """Patch-wise Wiener filter ``conj(k) y / (|k|^2 + nsr |d|^2)`` per tile, blended.

    The image spectrum is modelled as ``|omega|^-2`` (a gradient prior), so ``nsr``
    multiplies ``|d_x|^2 + |d_y|^2`` -- the Wiener filter for that model, and the
    image step of :func:`hyperlaplacian_steps` with ``w = 0``.
    """
    state["x"] = domain.extend(g)
    fourier.set_observation(g)
    x = yield from _substeps(fourier.solve(None, 1.0, nsr, refine))
    state["x"] = x
    yield "iteration", {"iteration": 1}
    return x
