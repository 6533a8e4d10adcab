"""Reproduction of the paper's Fig. 2: what centroid alignment of edge profiles costs (claims 1-2).

For a camera motion and many edge profiles all over a 512x512 image:

(a-c) ``d_c``: the distance, along each profile's normal, between the centroid of the edge
      profile and the point to which the motion's centroid pose ``H_c`` maps the sharp
      edge -- max and mean over the profiles (claim 1 says ``d_c`` is small);
(d-f) NCC between PSFs generated from the MDF estimated from the centroid-aligned
      profiles (Eq. 16, solved directly on a pose grid) and the centroid-aligned
      ground-truth PSFs (the truth re-centred by ``H_c^-1``, claim 2) -- min and mean over
      a 5x5 grid of image points.

(a, d) sweep the in-plane rotation spanned by one ``inplane`` trajectory from 0 to 7
degrees (its translation kept); (b, e) and (c, f) use random trajectories of the
``inplane`` and ``rotation`` models (:func:`~napari_edgecme.core.synth.random_trajectory`,
15 px blur). Two kinds of profiles are used:

* **projected** -- as in the paper: the exact projections of the true PSF (Eq. 13) at a
  5x5 grid of points and 8 orientations, centroid-aligned; this isolates the claims;
* **extracted** -- from an image: a scene of discs and squares with exactly known edges,
  shaken by the same motion (dense exact rendering, 1 % noise, 8 bits), profiles found by
  :func:`~napari_edgecme.core.edges.extract_edge_profiles` (``max_blur`` = 1.3 x the
  blur); ``d_c`` then compares each centroid with the true edge mapped by ``H_c``.

Eq. 16 is solved as a non-negative lasso, ``min 1/2 ||M w - dE||^2 + lambda sum(w)``,
``w >= 0`` (FISTA, 400 iterations, ``lambda = 1e-3 max|M^T dE|``) with ``M`` from
:func:`~napari_edgecme.core.edges.measurement_matrix`, on a pose grid with one-pixel steps
(:func:`~napari_edgecme.core.camera.pose_grid`) spanning the true re-centred poses plus
two steps -- the question here is alignment, not the search range.

Writes ``benchmarks/out/fig2.md`` (the tables), ``fig2.json`` (the numbers) and
``benchmarks/out/fig2.png`` (the six panels of the paper's figure).

    python benchmarks/bench_fig2.py [--quick] [--plot-only]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

from napari_edgecme.core.camera import (
    Intrinsics,
    PoseGrid,
    displacements,
    homographies,
    pose_grid,
    warp_points,
)
from napari_edgecme.core.edges import EdgeProfiles, extract_edge_profiles, measurement_matrix
from napari_edgecme.core.metrics import psf_ncc
from napari_edgecme.core.motion import CameraMotion
from napari_edgecme.core.synth import (
    add_noise,
    densify_path,
    distance_to_edges,
    quantize,
    random_trajectory,
    render_blur,
    render_shapes,
    trajectory_extent,
)

OUT = Path(__file__).with_name("out")
SIZE = 512

#: The plot's lines: (result key, style, legend) for the centroid-error row and the
#: PSF-NCC row.
PLOT_LINES = (
    (("dc_max", "o-", "max, projected"), ("dc_mean", "s-", "mean, projected"),
     ("x_dc_max", "o--", "max, extracted"), ("x_dc_mean", "s--", "mean, extracted")),
    (("ncc_min", "o-", "min, projected"), ("ncc_mean", "s-", "mean, projected"),
     ("x_ncc_min", "o--", "min, extracted"), ("x_ncc_mean", "s--", "mean, extracted")),
)


# ---------------------------------------------------------------------------------------
# scene with known edges
# ---------------------------------------------------------------------------------------

def scene_shapes(size):
    """A 4x4 grid of discs and rotated squares (row, col geometry), like the paper's Fig. 3."""
    shapes = []
    cell = size / 4
    for i in range(4):
        for j in range(4):
            cr, cc = (i + 0.5) * cell, (j + 0.5) * cell
            level = 0.55 + 0.1 * ((i * 4 + j) % 4)
            if (i + j) % 2 == 0:
                shapes.append(("disc", (cr, cc, 0.3 * cell), level))
            else:
                a = 0.4 + 0.3 * i + 0.2 * j + np.pi / 4 * np.arange(0, 8, 2)
                r = 0.36 * cell
                shapes.append(("poly", np.stack([cr + r * np.sin(a), cc + r * np.cos(a)], -1),
                               level))
    return shapes


# ---------------------------------------------------------------------------------------
# profiles from the PSFs, and Eq. 16
# ---------------------------------------------------------------------------------------

def projected_profiles(motion: CameraMotion, n_grid=5, n_angles=8):
    """Centroid-aligned profiles made from the true PSF projections (Eq. 13), and d_c."""
    rows, cols = motion.image_shape
    g = (np.arange(n_grid) + 0.5) / n_grid
    pts = np.stack(np.meshgrid(g * (rows - 1), g * (cols - 1), indexing="ij"), -1).reshape(-1, 2)
    phi = np.arange(n_angles) * np.pi / n_angles + 0.1
    pts = np.repeat(pts, n_angles, 0)
    phi = np.tile(phi, n_grid * n_grid)
    nrm = np.stack([np.cos(phi), np.sin(phi)], -1)  # (x, y)
    disp = displacements(motion.model, motion.intrinsics, motion.poses, pts)
    rho = np.einsum("npk,nk->np", disp, nrm)
    mean = rho @ motion.weights
    Hc = homographies(motion.model, motion.intrinsics, motion.centroid_pose()[None])
    moved = warp_points(Hc, pts[:, ::-1])[0] - pts[:, ::-1]
    d_c = np.abs(mean - np.einsum("nk,nk->n", moved, nrm))
    R = math.ceil(np.max(np.abs(rho - mean[:, None]))) + 2
    off = np.arange(-R, R + 1, dtype=float)
    der = np.zeros((len(pts), off.size))
    pos = rho - mean[:, None] + R
    j = np.floor(pos).astype(int)
    f = pos - j
    for jj, ww in ((j, 1 - f), (j + 1, f)):
        np.add.at(der, (np.repeat(np.arange(len(pts)), rho.shape[1]), jj.ravel()),
                  (ww * motion.weights).ravel())
    centroids = pts + mean[:, None] * np.stack([np.sin(phi), np.cos(phi)], -1)
    one = np.ones(len(pts))
    prof = EdgeProfiles(centroids, phi, one, 0 * one, np.cumsum(der, 1), der, off, one,
                        image_shape=motion.image_shape, max_blur=2.0 * R)
    return prof, d_c


def covering_grid(truth: CameraMotion) -> PoseGrid:
    """A one-pixel-step grid (the engine's steps) spanning the re-centred truth plus 2 steps."""
    steps = pose_grid(truth.model, truth.intrinsics, 1.0).steps
    reach = np.max(np.abs(truth.recentred().poses), axis=0) / steps + 2
    return PoseGrid(truth.model, steps, tuple(int(2 * math.ceil(r) + 1) for r in reach))


def nonneg_lasso(M, d, iters=400, lam_rel=1e-3, seed=0):
    """FISTA for ``min 1/2 ||M w - d||^2 + lam * sum(w)``, ``w >= 0`` (Eq. 16)."""
    v = np.random.default_rng(seed).standard_normal(M.shape[1])
    for _ in range(25):  # power iteration for the Lipschitz constant ||M||^2
        v = M.T @ (M @ v)
        v /= np.linalg.norm(v)
    lip = 1.05 * np.linalg.norm(M.T @ (M @ v))
    lam = lam_rel * np.max(np.abs(M.T @ d))
    w = np.full(M.shape[1], 1.0 / M.shape[1])
    z, t = w.copy(), 1.0
    for _ in range(iters):
        w_new = np.maximum(z - (M.T @ (M @ z - d) + lam) / lip, 0.0)
        t_new = 0.5 * (1 + math.sqrt(1 + 4 * t * t))
        z = w_new + (t - 1) / t_new * (w_new - w)
        w, t = w_new, t_new
    return w


def mdf_from_profiles(prof: EdgeProfiles, grid: PoseGrid, intr: Intrinsics) -> CameraMotion:
    poses = grid.poses()
    M = measurement_matrix(prof, grid.model, intr, poses).tocsr()
    w = nonneg_lasso(M, prof.derivatives.ravel())
    if not np.any(w > 0):
        w = np.ones_like(w)
    keep = w > 1e-3 * w.max()
    return CameraMotion(grid.model, intr, poses[keep], w[keep])


def psf_agreement(est: CameraMotion, truth: CameraMotion, n=5):
    """Min and mean NCC of PSFs on an n x n grid (centroid-aligned, :func:`psf_ncc`)."""
    ref = truth.recentred()
    rows, cols = truth.image_shape
    g = (np.arange(n) + 0.5) / n
    pts = np.stack(np.meshgrid(g * (rows - 1), g * (cols - 1), indexing="ij"), -1).reshape(-1, 2)
    size = max(est.psf_size(pts), ref.psf_size(pts))
    a, b = est.psf(pts, size), ref.psf(pts, size)
    ncc = np.array([psf_ncc(x, y) for x, y in zip(a, b, strict=True)])
    return float(ncc.min()), float(ncc.mean())


# ---------------------------------------------------------------------------------------
# one case
# ---------------------------------------------------------------------------------------

def run_case(truth: CameraMotion, shapes, sharp, rng, max_extracted=200):
    grid = covering_grid(truth)
    prof, d_c = projected_profiles(truth)
    est = mdf_from_profiles(prof, grid, truth.intrinsics)
    row = {"extent": trajectory_extent(truth.model, truth.intrinsics, truth.poses),
           "dc_max": float(d_c.max()), "dc_mean": float(d_c.mean()),
           "grid": grid.size}
    row["ncc_min"], row["ncc_mean"] = psf_agreement(est, truth)
    blurred = quantize(add_noise(render_blur(sharp, truth), 0.01, rng))
    ex = extract_edge_profiles(blurred, 1.3 * row["extent"], rng=0)
    row["n_extracted"] = len(ex)
    if len(ex) >= 10:
        Hc = homographies(truth.model, truth.intrinsics, truth.centroid_pose()[None])[0]
        back = warp_points(np.linalg.inv(Hc)[None], ex.centroids[:, ::-1])[0][:, ::-1]
        err = distance_to_edges(shapes, back)
        row["x_dc_max"], row["x_dc_mean"] = float(err.max()), float(err.mean())
        use = ex.subset(np.arange(min(len(ex), max_extracted)))  # the best ones
        est_x = mdf_from_profiles(use, grid, truth.intrinsics)
        row["x_ncc_min"], row["x_ncc_mean"] = psf_agreement(est_x, truth)
    return row


def fmt(row, key, digits=2):
    val = row.get(key)
    return "-" if val is None else f"{val:.{digits}f}"


def table(rows, first):
    head = (f"| {first} | blur (px) | d_c max | d_c mean | PSF NCC min | PSF NCC mean | "
            "extracted | d_c max | d_c mean | PSF NCC min | PSF NCC mean |")
    out = [head, "|" + "---|" * 11,
           "| | | *projected* | | | | *extracted* | | | | |"]
    for label, r in rows:
        out.append(f"| {label} | {r['extent']:.1f} | {fmt(r, 'dc_max', 3)} | "
                   f"{fmt(r, 'dc_mean', 3)} | {fmt(r, 'ncc_min', 3)} | {fmt(r, 'ncc_mean', 3)} | "
                   f"{r['n_extracted']} | {fmt(r, 'x_dc_max')} | {fmt(r, 'x_dc_mean')} | "
                   f"{fmt(r, 'x_ncc_min', 3)} | {fmt(r, 'x_ncc_mean', 3)} |")
    return out


def plot(sweep, models, path):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 7), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 3)
    series = [(sweep, "in-plane rotation spanned (degrees)", "one trajectory, rotation swept")]
    for name, rows in models.items():
        series.append((rows, f"random {name} trajectory", f"{name} model"))
    for col, (rows, xlabel, title) in enumerate(series):
        xs = np.asarray([lab for lab, _ in rows], float)
        for row, lines in enumerate(PLOT_LINES):
            for key, style, label in lines:
                axes[row, col].plot(xs, [r.get(key, np.nan) for _, r in rows], style,
                                    label=label)
        axes[0, col].set_title(f"{'abc'[col]}: centroid error d_c, {title}", fontsize=9)
        axes[1, col].set_title(f"{'def'[col]}: PSF NCC, {title}", fontsize=9)
        for ax in axes[:, col]:
            ax.set_xlabel(xlabel)
            ax.grid(alpha=0.3)
        axes[0, col].set_ylabel("pixels")
        axes[1, col].set_ylabel("NCC")
        axes[1, col].set_ylim(0, 1.02)
        if col:
            axes[0, col].set_xticks(xs)
            axes[1, col].set_xticks(xs)
    axes[0, 0].legend(fontsize=7)
    axes[1, 0].legend(fontsize=7)
    fig.savefig(path, dpi=72)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer angles and trajectories")
    parser.add_argument("--plot-only", action="store_true",
                        help="redraw fig2.png from the results of the last run (fig2.json)")
    args = parser.parse_args(argv)
    OUT.mkdir(exist_ok=True)
    if args.plot_only:
        saved = json.loads((OUT / "fig2.json").read_text())
        plot(saved["sweep"], saved["models"], OUT / "fig2.png")
        return
    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    intr = Intrinsics.from_image_shape((SIZE, SIZE))
    shapes = scene_shapes(SIZE)
    sharp = render_shapes((SIZE, SIZE), shapes, supersample=3)
    degrees = (0, 2, 4, 7) if args.quick else (0, 1, 2, 3, 4, 5, 6, 7)
    seeds = range(2) if args.quick else range(5)

    base = random_trajectory("inplane", intr, 12.0, n_samples=48, roll=1.0, rng=3)
    theta = base[:, 2] - base[:, 2].mean()
    theta /= max(np.ptp(theta), 1e-12)
    sweep = []
    for deg in degrees:
        poses = base.copy()
        poses[:, 2] = theta * math.radians(deg)
        truth = densify_path(poses, "inplane", intr)
        sweep.append((deg, run_case(truth, shapes, sharp, rng)))
        print(f"rotation {deg} deg done ({time.perf_counter() - t0:.0f} s)", flush=True)
    models = {}
    for model in ("inplane", "rotation"):
        rows = []
        for seed in seeds:
            poses = random_trajectory(model, intr, 15.0, n_samples=48, rng=100 + seed)
            truth = densify_path(poses, model, intr)
            rows.append((seed + 1, run_case(truth, shapes, sharp, rng)))
            print(f"{model} trajectory {seed + 1} done ({time.perf_counter() - t0:.0f} s)",
                  flush=True)
        models[model] = rows

    lines = [f"machine: {platform.node()}, {os.cpu_count()} CPUs, load average "
             f"{', '.join(f'{x:.1f}' for x in os.getloadavg())}; image {SIZE}x{SIZE}, focal "
             f"{intr.focal_px:.0f} px; {time.perf_counter() - t0:.0f} s", "",
             "(a, d) one inplane trajectory, its in-plane rotation scaled to span 0-7 degrees:",
             ""]
    lines += table([(f"{d}", r) for d, r in sweep], "rotation (deg)")
    for name, rows in models.items():
        lines += ["", f"({'b, e' if name == 'inplane' else 'c, f'}) random {name} "
                  "trajectories (15 px):", ""]
        lines += table([(f"{s}", r) for s, r in rows], "trajectory")
    text = "\n".join(lines)
    print(text)
    (OUT / "fig2.md").write_text(text + "\n")
    (OUT / "fig2.json").write_text(json.dumps({"sweep": sweep, "models": models}))
    plot(sweep, models, OUT / "fig2.png")


if __name__ == "__main__":
    main()
