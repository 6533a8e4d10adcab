"""Solvers behind :mod:`napari_edgecme.core.deconv`, on one block of the image.

A block is a rectangle of the observed image ``g`` (``h x w``). Its *latent domain*
is that rectangle grown by ``pad`` pixels on every side, enough to hold every scene
point that any observed pixel sees through the blur. The data term is masked: the
blur ``T`` (the EFF operator of :mod:`~napari_edgecme.core.operators`, built with
``origin`` at the domain's corner) acts on the whole domain and only the observed
pixels are compared with ``g``,

.. math::  E_{data}(f) = \\tfrac{\\lambda}{2} \\| M T f - g \\|^2 ,

with ``M`` the crop to the observed rectangle. ``M T`` is an operator composed from
:class:`~napari_edgecme.core.linop.Crop` and the EFF (:attr:`LatentDomain.data`), and
so is the image step's normal operator ``lam T^T M^T M T + beta D^T D``
(:meth:`LatentDomain.normal`), which :func:`conjugate_gradient` inverts: the one dot
test of the operators covers their adjoints. Pixels just outside the frame are
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

They, and the inner solvers they run (:meth:`PatchFourier.solve`,
:func:`conjugate_gradient`), are solver generators of the engine's one protocol
(:mod:`napari_edgecme.core.progress`): they yield
:class:`~napari_edgecme.core.progress.Progress` records -- ``step`` the finished
iterations of ``total``, one record per unit of work, the current estimate in
``iterate`` on the record that ends an iteration -- and return the latent estimate
on the domain. Thrown :class:`~napari_edgecme.core.progress.StopRequested`, a method
returns at once with its last finished iterate (its starting point before the
first).
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft
from numpy.lib.stride_tricks import sliding_window_view

from .cg import CirculantPreconditioner, conjugate_gradient
from .deconv_prior import Gradient, shrink_hyperlaplacian, shrink_threshold
from .linop import Crop, LinearOperator
from .motion import CameraMotion
from .operators import FFT_WORKERS, EfficientFilterFlow
from .progress import Progress, StopRequested, relay

__all__ = [
    "CirculantPreconditioner",
    "LatentDomain",
    "PatchFourier",
    "conjugate_gradient",
    "hyperlaplacian_steps",
    "richardson_lucy_steps",
    "wiener",
]

#: Bytes of complex spectra processed per chunk of tiles in :class:`PatchFourier`.
_CHUNK_BYTES = 16 * 2**20


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
    crop : Crop
        ``M``: domain -> observed (h, w).
    data : LinearOperator
        ``M T``: domain -> observed (h, w), the operator of the data term.
    gradient : Gradient
        ``D``: domain -> (2, *shape), the finite differences of the prior.
    """

    def __init__(self, motion: CameraMotion, box, pad: int, stride=None, dtype=np.float32):
        r0, r1, c0, c1 = (int(b) for b in box)
        self.box = (r0, r1, c0, c1)
        rows, cols = motion.image_shape
        #: which sides of the observed rectangle are the image's own border
        #: (top, bottom, left, right); the others are cuts between blocks
        self.image_edges = (r0 == 0, r1 == rows, c0 == 0, c1 == cols)
        self.pad = int(pad)
        self.observed_shape = (r1 - r0, c1 - c0)
        self.shape = (r1 - r0 + 2 * self.pad, c1 - c0 + 2 * self.pad)
        self.inner = (slice(self.pad, self.pad + r1 - r0), slice(self.pad, self.pad + c1 - c0))
        self.origin = (r0 - self.pad, c0 - self.pad)
        self.dtype = np.dtype(dtype)
        self.op = EfficientFilterFlow(motion, shape=self.shape, origin=self.origin,
                                      stride=stride, dtype=self.dtype)
        self.crop = Crop(self.shape, self.inner, self.dtype)
        self.data = self.crop @ self.op
        self.gradient = Gradient(self.shape, self.dtype)

    def normal(self, lam: float, beta: float) -> LinearOperator:
        """``lam T^T M^T M T + beta D^T D``, the operator of the image step."""
        dtype = self.dtype.type
        return (dtype(lam) * (self.data.T @ self.data)
                + dtype(beta) * (self.gradient.T @ self.gradient))

    def extend(self, g: np.ndarray) -> np.ndarray:
        """The observation (h, w) mirrored (``reflect``) into the pad: domain-shaped."""
        return np.pad(g, self.pad, mode="reflect").astype(self.dtype, copy=False)


# --------------------------------------------------------------------------------------
# patch-wise Fourier solver
# --------------------------------------------------------------------------------------

def _fast_box(patch: int, margin: int) -> int:
    """Smallest FFT-friendly length >= ``patch + 2 margin``."""
    return sfft.next_fast_len(patch + 2 * margin, real=True)


def _rv(spec: np.ndarray) -> np.ndarray:
    """The real view of a C-contiguous complex array: (..., n) complex -> (..., 2n) real.

    Multiplying it by a real array whose entries are repeated in pairs scales each
    complex entry by a real number without complex arithmetic."""
    return spec.view(spec.real.dtype)


def border_tiles(counts: int, stride: int, box: int, lead: int, inner: slice,
                 edges: tuple[bool, bool]) -> np.ndarray:
    """Which tiles along one axis are *border tiles* of :class:`PatchFourier`, (counts,) bool.

    Tile ``i``'s box spans canvas ``[i stride, i stride + box)``; the observed rectangle
    spans canvas ``lead + inner``. A tile is a border tile when its box reaches beyond a
    side of the observed rectangle that is an image edge (``edges``: before, after).
    """
    starts = np.arange(counts) * stride
    first, stop = lead + inner.start, lead + inner.stop
    before = (starts < first) & bool(edges[0])
    after = (starts + box > stop) & bool(edges[1])
    return before | after


class PatchFourier:
    r"""Closed-form image step per EFF tile, blended by the EFF windows.

    For each tile ``r`` of the operator's :class:`~napari_edgecme.core.operators.PatchGrid`
    a box around its window (grown by ``margin`` pixels on every side) is solved in
    closed form with the tile's PSF ``k_r``, as if the blur were the circular
    convolution with ``k_r`` inside the box:

    .. math::  \hat f_r = \frac{\lambda \overline{\hat k_r} \hat y_r + \widehat{(D^T z)}_r}
               {\lambda |\hat k_r|^2 + \beta (|\hat d_x|^2 + |\hat d_y|^2)}

    (``z = beta w``, the prior's pull; ``z = 0`` gives the Wiener filter), and the
    solution is ``f = sum_r omega_r C_r^T f_r`` with the EFF windows ``omega_r``, which
    sum to one. The margin keeps the box edges away from the window.

    The circular model cannot use the data within the PSF half-width of the box edge
    (they see latent pixels outside the box, wrapped around). Interior tiles replace
    them once by the circular blur of the box's own data -- periodic and consistent,
    so the box solve has no wrap-around ringing. *Border tiles*, whose boxes reach
    beyond the observed rectangle, solve their masked problem
    ``(lam K^T M K + beta D^T D) f = lam K^T M y + D^T z`` (``M``: the usable pixels)
    by conjugate gradients in the Fourier domain, preconditioned by the unmasked
    closed form above (two FFTs per iteration, warm-started from the previous step):
    the image border then gets the same masked data term as the exact solver.

    The tile spectra are computed a chunk of tiles at a time (:meth:`iter_build`, a
    generator yielding a record per chunk, for callers that report progress; the
    constructor runs it unless ``build=False``), and so is the observation's
    (:meth:`iter_set_observation`).

    Parameters
    ----------
    domain : LatentDomain
    margin : int
        Minimum box margin beyond each window (about one PSF size).
    build : bool, default True
        Compute the tile spectra now; with False, run :meth:`iter_build` before use.
    """

    def __init__(self, domain: LatentDomain, margin: int, *, build: bool = True):
        self.domain = domain
        op = domain.op
        grid = op.grid
        self.dtype = domain.dtype
        self.counts = grid.counts
        self.n = grid.n_patches
        self.stride = grid.stride
        P = self.patch = grid.patch_shape
        self.box = tuple(_fast_box(p, margin) for p in P)
        #: box margin before the window (the one after it may be one pixel larger)
        self.margin = tuple((b - p) // 2 for b, p in zip(self.box, P, strict=True))
        # extended canvas: box (i, j) starts at canvas (i * s0, j * s1)
        self.lead = tuple(o // 2 + m for o, m in zip(grid.overlap, self.margin, strict=True))
        self.canvas = tuple(
            max(self.lead[a] + domain.shape[a], (self.counts[a] - 1) * self.stride[a] + self.box[a])
            for a in range(2))
        B0, B1 = self.box
        self._spec_shape = (B0, B1 // 2 + 1)
        K = grid.psf_size
        h = (K - 1) // 2
        # |d_x|^2 + |d_y|^2, each value repeated twice to match _rv(spectrum)
        wy = 2.0 - 2.0 * np.cos(2 * np.pi * np.arange(B0) / B0)
        wx = 2.0 - 2.0 * np.cos(2 * np.pi * np.arange(B1 // 2 + 1) / B1)
        self.d2 = np.repeat(wy[:, None] + wx[None, :], 2, axis=-1).astype(self.dtype)
        wy_, wx_ = (w.astype(self.dtype) for w in grid.windows)
        self.windows = (wy_[:, None, :, None] * wx_[None, :, None, :]).reshape(self.n, *P)
        # usable data of a box: observed pixels at least the PSF half-width from its edge
        self._observed = np.zeros(self.canvas, bool)
        inner = domain.inner
        self._observed[self.lead[0] + inner[0].start:self.lead[0] + inner[0].stop,
                       self.lead[1] + inner[1].start:self.lead[1] + inner[1].stop] = True
        self._interior = np.zeros(self.box, bool)
        self._interior[h:B0 - h, h:B1 - h] = True
        #: border tiles (:func:`border_tiles`): their masked problems are solved by CG
        #: (cuts between blocks lie at least two PSF sizes from the kept region, so the
        #: cheap closed form is enough there)
        top, bottom, left, right = domain.image_edges
        rows = border_tiles(self.counts[0], self.stride[0], B0, self.lead[0], inner[0],
                            (top, bottom))
        cols = border_tiles(self.counts[1], self.stride[1], B1, self.lead[1], inner[1],
                            (left, right))
        self.border = (rows[:, None] | cols[None, :]).ravel()
        self._border_pos = np.cumsum(self.border) - 1
        # Parseval weights of a real FFT's half spectrum along the last axis (for _rv)
        half = np.full(B1 // 2 + 1, 2.0)
        half[0] = 1.0
        if B1 % 2 == 0:
            half[-1] = 1.0
        self._half_weights = np.repeat(half, 2).astype(self.dtype)
        per_tile = B0 * (B1 // 2 + 1) * np.dtype(np.complex128).itemsize
        self.chunk = max(1, _CHUNK_BYTES // per_tile)
        self.kty = None
        self._y = None
        self.khat = None
        if build:
            for _ in self.iter_build():
                pass

    def iter_build(self):
        """Compute the tile PSFs' spectra ``khat``, a chunk of tiles at a time.

        A generator yielding a record after each chunk (``step`` chunks of ``total``);
        returns None. Each tile's PSF is centred on its box's origin.
        """
        op = self.domain.op
        K = op.grid.psf_size
        h = (K - 1) // 2
        B0, B1 = self.box
        spec_dtype = np.result_type(self.dtype, np.complex64)
        self.khat = np.empty((self.n, *self._spec_shape), spec_dtype)
        chunks = list(self._chunks())
        for n_done, (_, sl) in enumerate(chunks, 1):
            kbox = np.zeros((sl.stop - sl.start, B0, B1), self.dtype)
            kbox[:, :K, :K] = op.psfs[sl]
            kbox = np.roll(kbox, (-h, -h), axis=(1, 2))
            khat = self._rfft(kbox)
            self.khat[sl] = khat
            yield Progress("tile spectra", n_done, len(chunks),
                           f"tile spectra {n_done}/{len(chunks)}")

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
        """All boxes of a canvas as a strided view, (ny, nx, B0, B1) (no copy)."""
        view = sliding_window_view(canvas, self.box)[::self.stride[0], ::self.stride[1]]
        return view[:self.counts[0], :self.counts[1]]

    def _chunks(self):
        """Whole rows of tiles, about :data:`_CHUNK_BYTES` of spectra each:
        yields (rows of the tile grid, the tiles' flat indices)."""
        nx = self.counts[1]
        step = max(1, self.chunk // nx)
        for i in range(0, self.counts[0], step):
            j = min(i + step, self.counts[0])
            yield slice(i, j), slice(i * nx, j * nx)

    def _take(self, view: np.ndarray, tile_rows: slice) -> np.ndarray:
        """Boxes of whole rows of tiles, copied into (n, B0, B1)."""
        return np.ascontiguousarray(view[tile_rows]).reshape(-1, *self.box)

    def _blend(self, canvas: np.ndarray, idx, boxes: np.ndarray) -> None:
        """``canvas += sum_r omega_r C_r^T f_r`` over tiles ``idx`` and their box
        solutions ``boxes`` (n, B0, B1), in place on the extended canvas: a chunk of
        tiles at a time, so no more than a chunk's boxes are ever held."""
        m0, m1 = self.margin
        P0, P1 = self.patch
        nx = self.counts[1]
        for r, b in zip(idx, boxes, strict=True):
            i, j = divmod(int(r), nx)
            r0, c0 = i * self.stride[0] + m0, j * self.stride[1] + m1
            canvas[r0:r0 + P0, c0:c0 + P1] += b[m0:m0 + P0, m1:m1 + P1] * self.windows[r]

    def _dot(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Real inner products of the images behind half spectra ``a``, ``b`` (n, ...) -> (n,),
        up to the common factor 1 / (B0 B1) (Parseval)."""
        prod = _rv(a) * _rv(b)
        return (prod @ self._half_weights).sum(-1, dtype=np.float64)

    def k2(self, tiles: slice) -> np.ndarray:
        """``|khat|^2`` of some tiles, each value repeated twice to match ``_rv(spectrum)``.

        Computed when needed (a chunk at a time) rather than kept: it would be as large
        as ``khat`` (gigabytes for a large, fast-turning blur on a 24 MP photo)."""
        khat = self.khat[tiles]
        return np.repeat(khat.real**2 + khat.imag**2, 2, axis=-1).astype(self.dtype, copy=False)

    # -- data ---------------------------------------------------------------------
    def set_observation(self, g: np.ndarray) -> None:
        """Take the observed block ``g`` (h, w): caches ``conj(k_r) y_r`` per tile."""
        for _ in self.iter_set_observation(g):
            pass

    def iter_set_observation(self, g: np.ndarray):
        """:meth:`set_observation` as a generator yielding a record per chunk of tiles.

        Until it has run to its end the observation is incomplete: a caller that stops
        it must not :meth:`solve`.
        """
        self._y = self._to_canvas(self.domain.extend(g), "reflect")
        y_view = self._boxes(self._y)
        obs_view = self._boxes(self._observed)
        self.kty = np.empty((self.n, *self._spec_shape), self.khat.dtype)
        nb = int(self.border.sum())
        self._kty_masked = np.empty((nb, *self._spec_shape), self.khat.dtype)
        self._usable = np.empty((nb, *self.box), bool)
        self._x_border = None  # previous border solutions (spectra), for warm starts
        for tile_rows, sl in self._chunks():
            boxes = self._take(y_view, tile_rows)
            usable = self._take(obs_view, tile_rows) & self._interior
            yhat = self._rfft(boxes)
            # unusable data <- the circular blur of the (mirrored) observation: a
            # periodic, consistent box for the closed form
            blurred = self._irfft(self.khat[sl] * yhat)
            self.kty[sl] = np.conj(self.khat[sl]) * self._rfft(np.where(usable, boxes, blurred))
            sel = np.flatnonzero(self.border[sl])
            if sel.size:
                pos = self._border_pos[sel + sl.start]
                self._usable[pos] = usable[sel]
                self._kty_masked[pos] = np.conj(self.khat[sel + sl.start]) * self._rfft(
                    np.where(usable[sel], boxes[sel], 0))
            yield Progress("observation", sl.stop, self.n,
                           f"observation spectra {sl.stop}/{self.n} tiles")

    def solve(self, prior_rhs, lam: float, beta: float, border_iterations: int = 4):
        """One image step: a solver generator yielding a record per chunk of tiles.

        Returns ``f`` (domain.shape). One closed-form step has no estimate of its own
        before it ends: :class:`~napari_edgecme.core.progress.StopRequested` thrown in
        propagates (the caller keeps its previous iterate).

        Parameters
        ----------
        prior_rhs : ndarray of shape domain.shape or None
            ``D^T z`` with ``z = beta w`` (None: no prior pull, the Wiener filter).
        lam, beta : float
            Data weight and prior (splitting) weight.
        border_iterations : int
            Conjugate-gradient iterations on the border tiles' masked problems.
        """
        if self.kty is None:
            raise RuntimeError("set_observation() must be called before solve()")
        prior_view = None
        if prior_rhs is not None:
            prior_view = self._boxes(self._to_canvas(prior_rhs, "zero"))
        lam_c = self.dtype.type(lam)
        beta_c = self.dtype.type(beta)
        if self._x_border is None:
            self._x_border = np.zeros_like(self._kty_masked)
            first = True
        else:
            first = False
        canvas = np.zeros(self.canvas, self.dtype)  # the blended solution, chunk by chunk
        chunks = list(self._chunks())
        for n_done, (tile_rows, sl) in enumerate(chunks):
            prior_hat = None
            if prior_view is not None:
                prior_hat = self._rfft(self._take(prior_view, tile_rows))
            inv_den = lam_c * self.k2(sl)
            inv_den += beta_c * self.d2
            np.reciprocal(inv_den, out=inv_den)
            xhat = self.kty[sl] * lam_c
            if prior_hat is not None:
                xhat += prior_hat
            _rv(xhat)[:] *= inv_den
            sel = np.flatnonzero(self.border[sl])
            if sel.size:
                pos = self._border_pos[sel + sl.start]
                rhs = self._kty_masked[pos] * lam_c
                if prior_hat is not None:
                    rhs += prior_hat[sel]
                start = xhat[sel] if first else self._x_border[pos]

                def relabel(record, n_done=n_done):
                    return Progress("image step", n_done, len(chunks),
                                    f"tile chunk {n_done + 1}/{len(chunks)}: {record.message}")
                xb = yield from relay(self._masked_cg(sel + sl.start, pos, start, rhs, lam_c,
                                                      beta_c, inv_den[sel], border_iterations),
                                      relabel)
                xhat[sel] = xb
                self._x_border[pos] = xb
            boxes = self._irfft(xhat).astype(self.dtype, copy=False)
            self._blend(canvas, range(sl.start, sl.stop), boxes)
            del boxes, xhat, inv_den  # a chunk's temporaries go before the next chunk's
            yield Progress("image step", n_done + 1, len(chunks),
                           f"tile chunk {n_done + 1}/{len(chunks)} solved")
        l0, l1 = self.lead
        return canvas[l0:l0 + self.domain.shape[0], l1:l1 + self.domain.shape[1]]

    def _masked_cg(self, rows, pos, x, rhs, lam, beta, inv_den, iterations):
        """Batched preconditioned CG for the border tiles' masked box problems, on spectra.

        ``A x = lam conj(k) F(M F^-1(k x)) + beta |d|^2 x``; preconditioner ``inv_den``
        (the unmasked closed form). Each tile has its own step sizes. A solver generator
        yielding a record after every iteration and returning ``x`` (the spectra).
        """
        khat = self.khat[rows]
        khat_conj = np.conj(khat)
        usable = self._usable[pos]
        d2 = self.d2 * beta

        def apply_a(v):
            blurred = self._irfft(khat * v)
            blurred *= usable
            out = self._rfft(blurred)
            out *= khat_conj
            _rv(out)[:] *= lam
            _rv(out)[:] += _rv(v) * d2
            return out

        def step(scalars):
            return scalars.astype(self.dtype)[:, None, None]

        x = x.copy()
        r = rhs - apply_a(x)
        z = r.copy()
        _rv(z)[:] *= inv_den
        p = z.copy()
        rz = self._dot(r, z)
        for k in range(1, iterations + 1):
            ap = apply_a(p)
            pap = self._dot(p, ap)
            alpha = step(np.where(pap > 0, rz / np.where(pap > 0, pap, 1.0), 0.0))
            _rv(x)[:] += alpha * _rv(p)
            _rv(r)[:] -= alpha * _rv(ap)
            np.multiply(_rv(r), inv_den, out=_rv(z))
            rz_new = self._dot(r, z)
            gamma = step(np.where(rz > 0, rz_new / np.where(rz > 0, rz, 1.0), 0.0))
            _rv(p)[:] *= gamma
            _rv(p)[:] += _rv(z)
            rz = rz_new
            yield Progress("border CG", k, iterations,
                           f"border tiles: CG iteration {k}/{iterations}", iteration=k)
        return x


# --------------------------------------------------------------------------------------
# the three methods on one block
# --------------------------------------------------------------------------------------

#: Pixels per slab of the hyper-Laplacian w-step (a record after each slab).
W_STEP_SLAB = 2**20


def _slabs(shape):
    """Row slices of an (H, W) array, about :data:`W_STEP_SLAB` pixels each."""
    rows = max(1, W_STEP_SLAB // max(1, shape[1]))
    return [slice(r, min(r + rows, shape[0])) for r in range(0, shape[0], rows)]


def hyperlaplacian_steps(domain: LatentDomain, g: np.ndarray, *, lam: float, alpha: float,
                         betas, inner_iterations: int, solver: str,
                         fourier: PatchFourier | None, cg_iterations: int, cg_tol: float,
                         border_iterations: int, precondition: bool = True):
    """Half-quadratic splitting for the hyper-Laplacian prior on one block (KF's algorithm).

    ``min_f lam/2 ||M T f - g||^2 + sum |D_x f|^alpha + |D_y f|^alpha``; for each
    ``beta`` in ``betas`` and each inner iteration: the w-step
    (:func:`~napari_edgecme.core.deconv_prior.shrink_hyperlaplacian`) on the current
    gradients, then the image step
    ``(lam T^T M^T M T + beta D^T D) f = lam T^T M^T g + beta D^T w`` by ``solver``.
    A solver generator (module notes): ``len(betas) * inner_iterations`` iterations,
    each one half-quadratic step; within a step a record after each chunk of tiles of
    the observation's spectra (once, first) and of the image step, and after each slab
    of :data:`W_STEP_SLAB` pixels of the w-step.
    """
    total = len(betas) * inner_iterations
    name = "half-quadratic step"
    k = 0  # finished half-quadratic steps

    def running(record=None):
        return Progress("hyperlaplacian", k, total, f"{name} {k + 1}/{total} running",
                        iteration=k)

    def cg_record(record):
        return Progress("hyperlaplacian", k, total, f"{name} {k + 1}/{total}: {record.message}",
                        iteration=k)

    x = domain.extend(g)
    try:
        if solver == "fourier":
            yield from relay(fourier.iter_set_observation(g), running)
        else:
            b_data = (domain.data.T @ g) * domain.dtype.type(lam)
            pre = CirculantPreconditioner(domain) if precondition else None
        yield running()
        for beta in betas:
            thr = shrink_threshold(beta, alpha)
            for _ in range(inner_iterations):
                w = domain.gradient @ x
                # the w-step, one slab of rows of one gradient image at a time, a record
                # after each (elementwise: the same as the whole image at once)
                for plane in w:
                    for rows in _slabs(plane.shape):
                        plane[rows] = shrink_hyperlaplacian(plane[rows], beta, alpha, thr)
                        yield running()
                prior_rhs = domain.gradient.T @ w
                prior_rhs *= domain.dtype.type(beta)
                del w
                yield running()
                if solver == "fourier":
                    x = yield from relay(fourier.solve(prior_rhs, lam, beta, border_iterations),
                                         running)
                else:
                    x = yield from relay(
                        conjugate_gradient(domain.normal(lam, beta), b_data + prior_rhs, x,
                                           cg_iterations, cg_tol,
                                           pre.operator(lam, beta) if pre is not None else None),
                        cg_record)
                k += 1
                yield Progress("hyperlaplacian", k, total,
                               f"{name} {k}/{total} done (beta {beta:.3g})", iteration=k,
                               iterate=x)
    except StopRequested:
        pass
    return x


def richardson_lucy_steps(domain: LatentDomain, g: np.ndarray, *, iterations: int):
    """Richardson-Lucy with the masked SV operator (non-negative, multiplicative).

    ``f <- f . T^T M^T (g / (M T f)) / T^T M^T 1``; latent pixels that no observed pixel
    sees (normaliser below 1e-3) keep their initial value. The estimate starts from the
    mirrored observation, floored at ``eps`` so that no pixel is stuck at zero. A
    solver generator (module notes): ``iterations`` iterations.
    """
    name = "Richardson-Lucy iteration"
    eps = domain.dtype.type(1e-3)
    x = np.maximum(domain.extend(g), eps)
    try:
        norm = domain.data.T @ np.ones(domain.observed_shape, domain.dtype)
        yield Progress("rl", 0, iterations, f"{name} 1/{iterations} running", iteration=0)
        seen = norm > 1e-3
        inv_norm = np.where(seen, 1.0 / np.where(seen, norm, 1.0), 0.0).astype(domain.dtype)
        for k in range(1, iterations + 1):
            ratio = g / np.maximum(domain.data @ x, eps)
            update = domain.data.T @ ratio
            update *= inv_norm
            x = np.where(seen, x * update, x)
            yield Progress("rl", k, iterations, f"{name} {k}/{iterations} done", iteration=k,
                           iterate=x)
    except StopRequested:
        pass
    return x


def wiener(domain: LatentDomain, g: np.ndarray, *, nsr: float, fourier: PatchFourier,
           border_iterations: int):
    """Patch-wise Wiener filter ``conj(k) y / (|k|^2 + nsr |d|^2)`` per tile, blended.

    The image spectrum is modelled as ``|omega|^-2`` (a gradient prior), so ``nsr``
    multiplies ``|d_x|^2 + |d_y|^2`` -- the Wiener filter for that model, and the
    image step of :func:`hyperlaplacian_steps` with ``w = 0``. A solver generator
    (module notes) of one iteration.
    """
    name = "Wiener filter"

    def running(record=None):
        return Progress("wiener", 0, 1, f"{name} 1/1 running", iteration=0)

    x = domain.extend(g)
    try:
        yield from relay(fourier.iter_set_observation(g), running)
        yield running()
        x = yield from relay(fourier.solve(None, 1.0, nsr, border_iterations), running)
        yield Progress("wiener", 1, 1, f"{name} 1/1 done", iteration=1, iterate=x)
    except StopRequested:
        pass
    return x
