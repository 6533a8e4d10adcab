"""How far a real camera shake reaches from its centroid pose, against the pose grid's reach.

The estimators re-centre the MDF on its centroid pose after every update (claims 1-2), and
:func:`~napari_edgecme.core.camera.pose_grid` spans ``+-GRID_REACH * max_blur`` about it. A
path symmetric about its centroid needs half its extent; a path that lingers at one end
reaches farther on the other side. For every true motion of the ``lai`` set (the 60 gyro
shakes as rendered, rotation model) and the 8 Levin kernels (translation), this prints the
largest displacement (px, at the image's corners and on a 5 x 5 grid of points) of a pose
holding at least 1/20 of the heaviest weight (the estimators' floor) from the centroid
pose, as a fraction of the blur extent and of the max blur each suite tells the estimators,
and whether the grid of :func:`pose_grid` at that max blur holds each such pose.

    python benchmarks/bench_grid_reach.py [--lai DIR] [--levin DIR]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def significant_about_centroid(motion):
    """``motion`` re-centred on its centroid pose, and its poses above the estimators' floor."""
    from napari_edgecme.core.pyramid import WEIGHT_FLOOR

    centred = motion.recentred()
    return centred, centred.poses[centred.weights >= WEIGHT_FLOOR * centred.weights.max()]


def reach(motion, shape) -> float:
    """Largest displacement (px) of a significant pose from the centroid pose."""
    from napari_edgecme.core.camera import displacements

    centred, poses = significant_about_centroid(motion)
    rows, cols = np.meshgrid(np.linspace(0, shape[0] - 1, 5), np.linspace(0, shape[1] - 1, 5),
                             indexing="ij")
    points = np.stack([rows.ravel(), cols.ravel()], axis=1)
    return float(np.abs(displacements(centred.model, centred.intrinsics, poses, points)).max())


def on_grid(motion, max_blur: float) -> bool:
    """Whether every significant pose of ``motion`` about its centroid lies on the grid."""
    from napari_edgecme.core.camera import pose_grid

    centred, poses = significant_about_centroid(motion)
    grid = pose_grid(centred.model, centred.intrinsics, max_blur)
    # the roll axis of the rotation models is the grid's narrower one; compare per axis
    return bool(np.all(np.abs(poses / grid.steps) <= grid.half + 0.5))


def main() -> None:
    from scipy.io import loadmat

    from napari_edgecme._suites._data import lai_cases, lai_load, levin_max_blur, levin_motion
    from napari_edgecme.core.camera import GRID_REACH

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lai", type=Path, default=SHARED / "lai")
    ap.add_argument("--levin", type=Path, default=SHARED / "levin")
    args = ap.parse_args()
    rows = []
    for case in lai_cases(args.lai, quick=False):
        blurred, _, truth = lai_load(case)
        r = reach(truth, blurred.shape)
        rows.append(("lai", case["name"], truth.blur_extent(), case["max_blur"], r,
                     on_grid(truth, case["max_blur"])))
    for k in range(1, 9):
        mat = loadmat(args.levin / f"im01_ker0{k}.mat")
        truth = levin_motion(mat["f"], mat["y"].shape)
        max_blur = levin_max_blur(truth)
        rows.append(("levin", f"ker0{k}", truth.blur_extent(), max_blur,
                     reach(truth, mat["y"].shape), on_grid(truth, max_blur)))
    print(f"GRID_REACH = {GRID_REACH} (the grid spans +-GRID_REACH * max blur about the "
          "centroid pose)\n")
    print("| set | motion | extent (px) | max blur told | reach from centroid (px) "
          "| reach / extent | reach / max blur | on the grid |")
    print("|---|---|---:|---:|---:|---:|---:|---|")
    for s, name, ext, mb, r, ok in rows:
        print(f"| {s} | {name} | {ext:.1f} | {mb:.0f} | {r:.1f} | {r / ext:.2f} | {r / mb:.2f} "
              f"| {'yes' if ok else '**no**'} |")
    for s in ("lai", "levin"):
        sel = [row for row in rows if row[0] == s]
        ratio = np.array([row[4] / row[2] for row in sel])
        print(f"\n{s}: reach / extent median {np.median(ratio):.2f}, max {ratio.max():.2f}; "
              f"{sum(row[5] for row in sel)} of {len(sel)} on the grid")


if __name__ == "__main__":
    main()
