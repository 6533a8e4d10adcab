"""How a deconvolution is cut into blocks and EFF tiles.

Large images are deconvolved in overlapping blocks that cross-fade (windows summing to
one, :class:`BlockPlan`), each with a margin of real data around it; inside a block the
blur is an EFF with tiles as large as the PSF's drift across the image allows
(:func:`auto_stride`).
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from ._validation import float_dtype
from .deconv_solvers import _CHUNK_BYTES, border_tiles
from .motion import CameraMotion, psf_size_for
from .operators import PatchGrid

__all__ = ["BLOCK_MEMORY_BUDGET", "FOURIER_MARGIN", "MAX_BLOCK", "MAX_STRIDE", "MIN_BLOCK",
           "MIN_STRIDE", "PSF_DRIFT", "BlockPlan", "auto_block_size", "auto_stride",
           "block_margin", "block_memory", "block_memory_phases", "fourier_margin",
           "latent_pad", "psf_drift_rate", "psf_extent"]

#: Smallest accepted block size (pixels).
MIN_BLOCK = 64

#: Largest block size chosen from the memory budget (``block_size=None``; pixels): the
#: fixed default before the budget, whose blocks' margins cost a fifth of the work.
MAX_BLOCK = 2048

#: Working memory one block may take when the block size is chosen (bytes): 2 GiB, so
#: that a 24 MP RGB photo with a 151 px PSF stays within the 4 GiB of issue 14 end to
#: end. Besides the block the deconvolution holds the input (8-bit and float32,
#: 0.34 GiB), the result (float32, 0.27 GiB) and the libraries (0.1 GiB): measured
#: 2.59 GiB in all there (1472 px blocks; the block's RSS within 1 % of the model, 7 %
#: above it at 2048 px), which leaves 1.4 GiB for what ``edgecme deblur`` holds
#: besides -- the estimation's leftovers, the linear-light copy -- and the
#: allocator's slack (``benchmarks/results/deconv-memory.md``).
BLOCK_MEMORY_BUDGET = 2 * 2**30

#: Step of the block sizes tried from :data:`MAX_BLOCK` down (pixels).
_BLOCK_STEP = 32

#: Automatic EFF tile size (``stride=None``): PSF drift allowed across half a tile (px)
#: and the range of tile sizes.
PSF_DRIFT = 0.5
MIN_STRIDE = 32
MAX_STRIDE = 256

#: Patch-wise Fourier solver: box margin beyond each EFF window, in PSF sizes.
FOURIER_MARGIN = 1.0


def psf_extent(motion: CameraMotion, beyond: float = 0.0) -> int:
    """Odd PSF side holding the motion anywhere in the image (grid plus corners), or in
    the image grown by ``beyond`` pixels on every side (the latent domains' tile centres
    reach that far: their operators' PSFs are up to that size)."""
    rows, cols = motion.image_shape
    r = np.linspace(-beyond, rows - 1 + beyond, 9)
    c = np.linspace(-beyond, cols - 1 + beyond, 9)
    pts = np.stack(np.meshgrid(r, c, indexing="ij"), -1).reshape(-1, 2)
    return psf_size_for(motion.displacements(pts))


def psf_drift_rate(motion: CameraMotion, n: int = 9, delta: float = 4.0) -> float:
    """How fast the PSF changes across the image: the largest change of any pose's
    displacement per pixel of image distance (px/px), over an ``n x n`` grid."""
    rows, cols = motion.image_shape
    r = np.linspace(0, rows - 1, n)
    c = np.linspace(0, cols - 1, n)
    pts = np.stack(np.meshgrid(r, c, indexing="ij"), -1).reshape(-1, 2)
    d0 = motion.displacements(pts)
    rate = 0.0
    for step in ((delta, 0.0), (0.0, delta)):
        d1 = motion.displacements(pts + np.array(step))
        rate = max(rate, float(np.max(np.hypot(*(d1 - d0).transpose(2, 0, 1)))) / delta)
    return rate


def auto_stride(motion: CameraMotion) -> int:
    """EFF tile size for deconvolution: as large as possible (cheaper per pixel) while
    the PSF drifts by at most :data:`PSF_DRIFT` px between a tile's centre and its
    window's half-width (``stride / 2``); within [:data:`MIN_STRIDE`, :data:`MAX_STRIDE`]."""
    rate = psf_drift_rate(motion)
    stride = MAX_STRIDE if rate <= 0 else 2.0 * PSF_DRIFT / rate
    return int(np.clip(stride, MIN_STRIDE, MAX_STRIDE))


def latent_pad(psf_size: int) -> int:
    """Latent pixels beyond a block's observed box on each side: the PSF reach plus slack."""
    return (psf_size - 1) // 2 + 2


def block_margin(psf_size: int) -> int:
    """Real data kept around each block beyond its window (px): twice the PSF side plus 8,
    so that a cut between blocks lies far from the pixels kept."""
    return 2 * psf_size + 8


def fourier_margin(psf_size: int) -> int:
    """Box margin of the patch-wise Fourier solver beyond each EFF window (px)."""
    return max(8, round(FOURIER_MARGIN * psf_size))


def block_memory_phases(box_shape, psf_size: int, stride: int, *,
                        method: str = "hyperlaplacian", solver: str = "fourier",
                        dtype=np.float32, channels: int = 1,
                        image_edges=(True, True, True, True),
                        operator_psf_size: int | None = None,
                        n_poses: int | None = None) -> dict:
    """Modelled peak working memory (bytes) of one block's deconvolution, per phase.

    Counts the arrays that :class:`~napari_edgecme.core.deconv_solvers.LatentDomain`
    (the EFF operator on the block's latent domain), the solvers of
    :mod:`~napari_edgecme.core.deconv_solvers` and :mod:`~napari_edgecme.core.cg`
    allocate, from the same geometry (:class:`~napari_edgecme.core.operators.PatchGrid`,
    the Fourier boxes, the chunks of tiles). With ``n`` tiles, ``F`` the EFF's FFT
    size, ``B`` the Fourier box (window plus a PSF side each way) and one spectrum of
    a box ``s = B0 (B1 // 2 + 1)`` complex values, the dominant terms are

    * every method: the operator's tile spectra ``n F0 (F1 // 2 + 1)`` complex and the
      tile PSFs ``n K^2`` (while the operator is built, the sparse PSF basis and its
      float64 product too);
    * ``"fourier"`` and ``"wiener"``: ``khat`` and ``conj(khat) y`` (``2 n s``
      complex), the border tiles' masked data, warm starts and masks, and a chunk of
      tiles' temporaries (about 6 spectra per tile, 14 for the border tiles' masked CG);
    * ``"cg"`` and ``"rl"``: three tile-spectra arrays while the operator is applied,
      about ten domain-sized images, and for ``"cg"`` the preconditioner's mean
      power spectrum, built from ``n (2K - 1)^2`` float64 autocorrelations.

    Parameters
    ----------
    box_shape : tuple of int
        ``(h, w)``: the block's observed box, margin included (``BlockPlan`` ``"box"``).
    psf_size : int
        Odd PSF side ``K`` (:func:`psf_extent`).
    stride : int
        EFF tile size (:func:`auto_stride` or the caller's).
    method : {"hyperlaplacian", "rl", "wiener"}
    solver : {"fourier", "cg"}
        The hyper-Laplacian image step (ignored by the other methods).
    dtype : dtype
        The image's; float32 or float64 (the engine's float policy; others as float32).
    channels : int, default 1
        Channels solved at once (:func:`~napari_edgecme.core.deconv.deconvolve` solves
        one at a time and shares the operator and tile spectra between them).
    image_edges : tuple of bool
        Which sides of the box (top, bottom, left, right) are the image's border: the
        Fourier solver's border tiles hold more. All four: an upper bound.
    operator_psf_size : int, optional
        PSF side of the block's EFF operator, which sees the latent pixels beyond the
        image too (``psf_extent(motion, latent_pad(K))``); default ``psf_size``.
    n_poses : int, optional
        Poses of the motion (the sparse basis; default ``2 K``, a densified path).

    Returns
    -------
    dict
        Phase name -> bytes: ``"operator"`` (building the EFF), ``"spectra"`` (the
        Fourier solver's tile spectra), ``"observation"`` and ``"solve"`` (one channel's
        observation spectra; the iterations). The block's peak is the largest.
    """
    isz = float_dtype(dtype).itemsize
    csz = 2 * isz
    K = int(psf_size)
    pad = latent_pad(K)
    h, w = (int(v) for v in box_shape)
    N = (h + 2 * pad, w + 2 * pad)
    Ko = K if operator_psf_size is None else int(operator_psf_size)
    g = PatchGrid(N, Ko, stride)
    n = g.n_patches
    P, F = g.patch_shape, g.fft_shape
    image = N[0] * N[1] * isz  # one domain-sized image
    psfs = n * Ko * Ko * isz
    spec_op = n * F[0] * (F[1] // 2 + 1) * csz  # the EFF's tile spectra
    n_poses = 2 * Ko if n_poses is None else int(n_poses)
    nnz = 4 * n * n_poses  # bilinear splats of each pose at each tile centre
    index = 4 if max(n * Ko * Ko, nnz) < 2**31 else 8
    basis = nnz * (8 + index) + (n * Ko * Ko + 1) * index  # CSR: float64 data, indptr
    phases = {"operator": max(basis + nnz * 3 * 8 * 2,  # COO triplets, then CSR
                              basis + n * Ko * Ko * 8 + psfs,  # B @ w in float64, cast
                              basis + psfs + n * F[0] * F[1] * isz + spec_op)}  # padded, FFT
    fourier = method == "wiener" or (method == "hyperlaplacian" and solver == "fourier")
    if fourier:
        m = fourier_margin(K)
        B = tuple(sfft.next_fast_len(p + 2 * m, real=True) for p in P)
        bsz = B[0] * B[1]
        spec = B[0] * (B[1] // 2 + 1) * csz  # one box's spectrum
        margin = tuple((b - p) // 2 for b, p in zip(B, P, strict=True))
        lead = tuple(o // 2 + mm for o, mm in zip(g.overlap, margin, strict=True))
        canvas = int(np.prod([max(lead[a] + N[a], (g.counts[a] - 1) * g.stride[a] + B[a])
                              for a in range(2)]))
        rows = border_tiles(g.counts[0], g.stride[0], B[0], lead[0], slice(pad, pad + h),
                            image_edges[:2])
        cols = border_tiles(g.counts[1], g.stride[1], B[1], lead[1], slice(pad, pad + w),
                            image_edges[2:])
        border = rows[:, None] | cols[None, :]
        nb = int(border.sum())
        per_chunk = max(1, _CHUNK_BYTES // (B[0] * (B[1] // 2 + 1) * 16))
        step = max(1, per_chunk // g.counts[1])
        ct = min(n, step * g.counts[1])  # tiles in a chunk (whole rows of tiles)
        cb = max(int(border[i:i + step].sum()) for i in range(0, g.counts[0], step))
        fixed = spec_op + psfs + n * P[0] * P[1] * isz + 2 * canvas + n * spec  # + khat
        phases["spectra"] = fixed + ct * (2 * bsz * isz + spec)
        state = n * spec + nb * (spec + bsz) + canvas * isz + 2 * image  # kty, border, y
        phases["observation"] = fixed + channels * (
            state + ct * (bsz * (isz + 1) + 5 * spec) + cb * 4 * spec)
        prior = method == "hyperlaplacian"
        solve = (state + nb * spec  # warm starts of the border tiles
                 + canvas * isz  # the blended solution
                 + (canvas * isz + image + ct * (bsz * isz + spec) if prior else 0)
                 + ct * 4 * spec + cb * (12 * spec + bsz))
        phases["solve"] = fixed + channels * solve
    else:
        apply = 3 * spec_op + n * P[0] * P[1] * isz + 2 * image  # T or T^T applied
        vectors = 10 * image if method == "hyperlaplacian" else 7 * image
        solve = spec_op + psfs + channels * (vectors + apply)
        if method == "hyperlaplacian":  # the circulant preconditioner's spectra
            L = 2 * Ko - 1
            M = tuple(sfft.next_fast_len(v + Ko, real=True) for v in N)
            pre = M[0] * (M[1] // 2 + 1) * 8 * 2 + M[0] * (M[1] // 2 + 1) * isz
            acf = n * L * (L // 2 + 1) * 16
            phases["preconditioner"] = (spec_op + psfs + channels * 2 * image + n * Ko * Ko * 8
                                        + 2 * acf + M[0] * M[1] * 8)
            solve += pre
        phases["solve"] = solve
    return {k: int(v) for k, v in phases.items()}


def block_memory(box_shape, psf_size: int, stride: int, **kwargs) -> int:
    """Modelled peak working memory (bytes) of one block: the largest phase of
    :func:`block_memory_phases` (same parameters)."""
    return max(block_memory_phases(box_shape, psf_size, stride, **kwargs).values())


class BlockPlan:
    """Overlapping blocks that cross-fade (windows summing to one) and their observed boxes.

    Each block is a dict: ``"box"`` (row0, row1, col0, col1), the observed rectangle
    solved (its window grown by :func:`block_margin`, clipped to the image);
    ``"window_box"``, the rectangle its window covers; ``"window_1d"``, the window's
    row and column factors (its weights are their outer product, formed in
    :meth:`add` rather than kept: they would add up to the image's size in float64).
    """

    def __init__(self, shape, block_size: int, psf_size: int):
        self.shape = shape
        K = psf_size
        blend = 2 * (min(block_size // 2, max(16, K)) // 2)
        self.grid = PatchGrid(shape, 1, block_size, blend)
        self.margin = block_margin(K)  # real data kept around each block beyond its window
        self.blocks = []
        g = self.grid
        for i in range(g.counts[0]):
            for j in range(g.counts[1]):
                win_box, wins = [], []
                for axis, k in ((0, i), (1, j)):
                    start = k * g.stride[axis] - g.overlap[axis] // 2
                    lo, hi = max(start, 0), min(start + g.patch_shape[axis], shape[axis])
                    win_box.append((lo, hi))
                    wins.append(g.windows[axis][k, lo - start:hi - start])
                (wr0, wr1), (wc0, wc1) = win_box
                box = (max(wr0 - self.margin, 0), min(wr1 + self.margin, shape[0]),
                       max(wc0 - self.margin, 0), min(wc1 + self.margin, shape[1]))
                self.blocks.append({
                    "box": box,
                    "window_box": (wr0, wr1, wc0, wc1),
                    "window_1d": tuple(wins),
                })

    def __len__(self):
        return len(self.blocks)

    @staticmethod
    def add(out: np.ndarray, block: dict, observed: np.ndarray, *,
            subtract: bool = False) -> None:
        """``out[window] += window * observed-block result`` (the cross-fade).

        ``out`` and ``observed`` are (H, W) and (h, w), or (H, W, C) and (h, w, C) (every
        channel at once); with ``subtract``, ``out[window] -= ...``.
        """
        r0, _, c0, _ = block["box"]
        wr0, wr1, wc0, wc1 = block["window_box"]
        part = observed[wr0 - r0:wr1 - r0, wc0 - c0:wc1 - c0]
        window = np.outer(*block["window_1d"]).astype(out.dtype)
        if part.ndim == 3:
            window = window[..., None]
        if subtract:
            out[wr0:wr1, wc0:wc1] -= window * part
        else:
            out[wr0:wr1, wc0:wc1] += window * part


def auto_block_size(shape, motion: CameraMotion, stride: int | None = None, *,
                    method: str = "hyperlaplacian", solver: str = "fourier",
                    dtype=np.float32, budget: float | None = None) -> int:
    """The block size ``block_size=None`` means: the largest whose blocks fit the budget.

    The largest size from :data:`MAX_BLOCK` (2048) down, in steps of 32 px, for which
    every block of the :class:`BlockPlan` needs at most ``budget`` bytes of working
    memory by :func:`block_memory` (with its own box and image edges, one channel at a
    time, the operator's PSF side taken over the image grown by the latent pad). It is
    never below the block margin (``2 K + 8``, :func:`block_margin`) nor
    :data:`MIN_BLOCK`: a block smaller than its margin solves more margin than block
    (more than 9 times the kept pixels) and shrinking it further would save little
    memory for much more work, so when even a block as large as its margin does not fit
    the budget, that size is returned and the budget is exceeded (at 24 MP: a 203 px PSF
    on 56 px tiles, 3.1 GiB modelled at its 414 px floor). A photo smaller than a
    block gets :data:`MAX_BLOCK` (one block, as before the budget).

    Parameters
    ----------
    shape : tuple of int
        ``(H, W)`` of the image (channels, if any, are solved one at a time).
    motion : CameraMotion
        The camera motion at the image's size.
    stride : int, optional
        EFF tile size (default :func:`auto_stride`, as the deconvolution's).
    method, solver : str
        As for :func:`~napari_edgecme.core.deconv.deconvolve`.
    dtype : dtype
        The image's float dtype (float32, or float64 for float64 input).
    budget : float, optional
        Bytes per block (default :data:`BLOCK_MEMORY_BUDGET`, read at the call).

    Returns
    -------
    int
        The block size, in ``[max(MIN_BLOCK, min(2 K + 8, MAX_BLOCK)), MAX_BLOCK]``.
    """
    shape = tuple(int(v) for v in shape[:2])
    budget = BLOCK_MEMORY_BUDGET if budget is None else float(budget)
    K = psf_extent(motion)
    stride = auto_stride(motion) if stride is None else int(stride)
    model = {"method": method, "solver": solver, "dtype": dtype,
             "operator_psf_size": psf_extent(motion, latent_pad(K)),
             "n_poses": int(np.count_nonzero(motion.weights))}
    memory = {}

    def fits(size):
        for blk in BlockPlan(shape, size, K).blocks:
            r0, r1, c0, c1 = blk["box"]
            key = (r1 - r0, c1 - c0, r0 == 0, r1 == shape[0], c0 == 0, c1 == shape[1])
            if key not in memory:
                memory[key] = block_memory(key[:2], K, stride, image_edges=key[2:], **model)
            if memory[key] > budget:
                return False
        return True

    low = max(MIN_BLOCK, min(block_margin(K), MAX_BLOCK))
    for size in range(MAX_BLOCK, low, -_BLOCK_STEP):
        if fits(size):
            return size
    return low
