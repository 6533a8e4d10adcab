"""Which non-negative L1 solver for the MDF update (issue: estimation, item 2).

Every MDF update of the estimators solves

    min_w  1/2 w^T Q w - b^T w + lambda_w sum(w),   w >= 0

with ``Q w`` available as a cheap product (:func:`napari_edgecme.core.mdf.gradient_term`).
This script builds that problem as the Xu / Xu+Ep update sees it at the finest scale
(true latent gradients against the blurred image's, the whole pose grid active, the
term normalised by its energy and ``lambda_w`` the engine's default) and times three
solvers to the same objective:

* **FISTA** with adaptive restart (what :func:`~napari_edgecme.core.lasso.nonneg_lasso`
  does): one ``Q w`` product per iteration;
* **projected coordinate descent** on the explicit Gram matrix ``Q`` (built with one
  product per pose, then cyclic sweeps with an incrementally updated ``Q w``);
* **ADMM** (``w = z``, ``z >= 0``) whose ``w`` step ``(Q + rho I) w = ...`` is solved by
  warm-started conjugate gradients.

The reference optimum is FISTA run to 20 000 iterations. A solver "reaches" a relative
gap when ``(F(w) - F*) / |F*|`` falls below it. Times are medians over ``--repeat``
runs on a shared machine: read the ratios.

    python benchmarks/bench_lasso.py [--size PX] [--model rotation] [--max-blur PX]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import numpy as np
from scipy import ndimage

from napari_edgecme.core.camera import Intrinsics, displacements, pose_grid
from napari_edgecme.core.deconv_prior import grad
from napari_edgecme.core.estimate import DEFAULTS
from napari_edgecme.core.lasso import QuadraticTerm, lipschitz_constant, nonneg_lasso
from napari_edgecme.core.mdf import border_taper, gradient_term, psf_basis
from napari_edgecme.core.motion import psf_size_for
from napari_edgecme.core.operators import PatchGrid
from napari_edgecme.core.synth import make_case, sample_image

GAPS = (1e-2, 1e-3, 1e-4)


def build_problem(size: int, model: str, max_blur: float, seed: int):
    case = make_case(sample_image("camera", size), model, extent=0.7 * max_blur, rng=seed)
    intrinsics = Intrinsics.from_image_shape(case.blurred.shape)
    grid = pose_grid(model, intrinsics, max_blur)
    poses = grid.poses()
    corners = np.array([[0, 0], [0, size - 1], [size - 1, 0], [size - 1, size - 1]], float)
    K = psf_size_for(displacements(model, intrinsics, poses, corners))
    pgrid = PatchGrid(case.blurred.shape, K, stride=int(max(2 * K, min(4 * K, 128))))
    basis = psf_basis(model, intrinsics, poses, pgrid)
    taper = border_taper(case.blurred.shape, K // 2)
    f = ndimage.gaussian_filter(np.stack(grad(case.sharp)) * taper, (0, 1, 1))
    g = ndimage.gaussian_filter(np.stack(grad(case.blurred)) * taper, (0, 1, 1))
    term = gradient_term(f, g, pgrid, basis)
    return term.scaled(1.0 / term.constant), poses.shape[0], K


def objective(term: QuadraticTerm, lam: float, w: np.ndarray) -> float:
    return term.value(w) + lam * float(w.sum())


def fista_trace(term, lam, n, max_iter, L):
    """The engine's FISTA (nonneg_lasso), with the iterate recorded after every iteration."""
    trace = []
    t0 = time.perf_counter()
    nonneg_lasso(term, lam, np.full(n, 1.0 / n), max_iter=max_iter, tol=0.0, lipschitz=L,
                 callback=lambda r: trace.append((time.perf_counter() - t0, r.iterate.copy())))
    return trace


def coordinate_descent_trace(term, lam, n, sweeps):
    t0 = time.perf_counter()
    Q = np.empty((n, n))
    eye = np.zeros(n)
    for j in range(n):  # the Gram matrix: one product per pose
        eye[j] = 1.0
        Q[:, j] = term.matvec(eye)
        eye[j] = 0.0
    Q = 0.5 * (Q + Q.T)
    build = time.perf_counter() - t0
    w = np.full(n, 1.0 / n)
    Qw = Q @ w
    diag = np.maximum(np.diag(Q), 1e-30)
    trace = []
    for _ in range(sweeps):
        for j in range(n):
            new = max(0.0, w[j] - (Qw[j] - term.linear[j] + lam) / diag[j])
            if new != w[j]:
                Qw += Q[:, j] * (new - w[j])
                w[j] = new
        trace.append((time.perf_counter() - t0, w.copy()))
    return trace, build


def admm_trace(term, lam, n, max_iter, rho):
    from scipy.sparse.linalg import LinearOperator, cg

    A = LinearOperator((n, n), matvec=lambda v: term.matvec(v) + rho * v, dtype=np.float64)
    z = np.full(n, 1.0 / n)
    u = np.zeros(n)
    w = z.copy()
    trace = []
    t0 = time.perf_counter()
    for _ in range(max_iter):
        w, _ = cg(A, term.linear - lam + rho * (z - u), x0=w, maxiter=20, rtol=1e-6)
        z = np.maximum(w + u, 0.0)
        u += w - z
        trace.append((time.perf_counter() - t0, z.copy()))
    return trace


def first_time(trace, term, lam, best, gap):
    for elapsed, w in trace:
        if (objective(term, lam, w) - best) / abs(best) <= gap:
            return elapsed
    return float("nan")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--model", default="inplane")
    parser.add_argument("--max-blur", type=float, default=15.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    term, n, K = build_problem(args.size, args.model, args.max_blur, args.seed)
    lam = DEFAULTS["lambda_w"]
    L = lipschitz_constant(term.matvec, n)
    reference = nonneg_lasso(term, lam, np.full(n, 1.0 / n), max_iter=20_000, tol=1e-12,
                             lipschitz=L)
    best = objective(term, lam, reference.x)
    t_mv = statistics.median(_timed(lambda: term.matvec(reference.x)) for _ in range(20))
    rho = float(np.median(np.abs(term.linear))) + L / 50

    rows = {}
    for name in ("FISTA", "coordinate descent", "ADMM"):
        runs = []
        for _ in range(args.repeat):
            if name == "FISTA":
                trace, extra = fista_trace(term, lam, n, 2000, L), 0.0
            elif name == "coordinate descent":
                trace, extra = coordinate_descent_trace(term, lam, n, 60)
            else:
                trace, extra = admm_trace(term, lam, n, 400, rho), 0.0
            runs.append([first_time(trace, term, lam, best, gap) for gap in GAPS] + [extra])
        rows[name] = np.median(np.array(runs), axis=0)

    print(f"## Non-negative L1 MDF solvers ({platform.node()}, {time.strftime('%Y-%m-%d')})\n")
    print(f"{args.size}x{args.size} camera, {args.model} shake, max_blur {args.max_blur:g} px: "
          f"{n} poses, PSF {K} px, lambda_w {lam:g}; one Q w product {1e3 * t_mv:.1f} ms; "
          f"reference objective {best:.6g} (FISTA x 20000, support "
          f"{int(np.sum(reference.x > 1e-3 * reference.x.max()))} poses)\n")
    header = " | ".join(f"time to gap {g:g} (s)" for g in GAPS)
    print(f"| solver | {header} | set-up (s) |")
    print("|---" * (len(GAPS) + 2) + "|")
    for name, values in rows.items():
        cells = " | ".join("not reached" if np.isnan(v) else f"{v:.3f}" for v in values[:-1])
        print(f"| {name} | {cells} | {values[-1]:.3f} |")
    engine = nonneg_lasso(term, lam, np.full(n, 1.0 / n), lipschitz=L)
    gap = (objective(term, lam, engine.x) - best) / abs(best)
    print(f"\nThe engine's stopping rule (max_iter 200, tol 1e-4) stops after {engine.nit} "
          f"iterations at relative gap {gap:.1e}.")


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
