"""One deconvolution block's memory: the model against measurements, and the block size
chosen from the memory budget against the fixed 2048 px blocks (issue 14).

Parts (``--parts``, comma-separated; default ``model``):

``model``
    For a few whole-image blocks (``--sides``, default 256, 512, 768 px; camera
    rotations giving 31 and 61 px PSFs; the hyper-Laplacian with the Fourier and the
    CG image step, RL, Wiener), the modelled peak working memory
    (``deconv_blocks.block_memory``) against the peak that ``tracemalloc`` measures
    over the block's operator build and one iteration of its solver (the arrays are the
    same at every iteration), each in a fresh Python process. tracemalloc counts the
    buffers numpy allocates, not the FFT library's small scratch.
``large``
    Peak resident memory (``VmHWM``) of ``deconvolve`` on a ``--size`` (24 or 12) MP
    8-bit RGB photo with a camera rotation whose PSF side is ``--psf`` px, in fresh
    processes: with ``block_size=2048`` under the code in ``--before`` (a source tree,
    e.g. ``git archive HEAD src | tar -x -C DIR``; default: this tree), and under this
    tree with ``block_size=2048`` and with the default (the budget's block size).
    Memory does not depend on the photo's content: a random 8-bit image is
    deconvolved, with ``--steps`` half-quadratic steps (default 1: each step
    allocates the same arrays, and the set-up of every block and channel still
    runs). Reported: the process's peak and its resident memory before the call
    (image and libraries), the blocks, CPU and wall seconds, and the model's figure
    for the largest block.

    python benchmarks/bench_deconv_memory.py [--parts model,large] [--sides 256,512,768]
                                             [--size 24] [--psf 151] [--steps 1]
                                             [--before SRC] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

_MARKER = "BENCH-DECONV-MEMORY "
SHAPES = {12: (3000, 4000), 24: (4000, 6000)}
#: Trajectory extents (rotation, seed 0) giving the PSF sides asked for.
EXTENTS = {(256, 31): 21, (256, 61): 41, (512, 31): 21, (512, 61): 42, (768, 31): 21,
           (768, 61): 43, (24, 151): 110, (12, 151): 110, (24, 85): 62, (12, 85): 62}
CASES = [("hyperlaplacian", "fourier"), ("hyperlaplacian", "cg"), ("rl", "cg"),
         ("wiener", "fourier")]


def _vm(key: str) -> float:
    with open("/proc/self/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 2**10
    return float("nan")


# --------------------------------------------------------------------------------------
# children
# --------------------------------------------------------------------------------------

def child_model(job: dict) -> dict:
    import numpy as np

    from napari_edgecme._bench._memory import block_peak, rotation_motion
    from napari_edgecme.core.deconv import FOURIER_BORDER_ITERATIONS
    from napari_edgecme.core.deconv_blocks import (
        auto_stride,
        block_memory_phases,
        latent_pad,
        psf_extent,
    )

    side, method, solver = job["side"], job["method"], job["solver"]
    motion = rotation_motion((side, side), job["extent"])
    K, stride = psf_extent(motion), auto_stride(motion)
    t0 = time.process_time()
    measured, domain = block_peak(motion, side, method, solver,
                                  FOURIER_BORDER_ITERATIONS.get(method, 0))
    phases = block_memory_phases((side, side), K, stride, method=method, solver=solver,
                                 operator_psf_size=psf_extent(motion, latent_pad(K)),
                                 n_poses=int(np.count_nonzero(motion.weights)))
    return {"K": K, "K_operator": domain.op.grid.psf_size, "stride": stride,
            "tiles": domain.op.grid.n_patches, "measured": measured,
            "model": max(phases.values()), "phases": phases,
            "cpu": time.process_time() - t0}


def child_large(job: dict) -> dict:
    import numpy as np

    from napari_edgecme import Intrinsics
    from napari_edgecme.core.deconv import iter_deconvolve
    from napari_edgecme.core.deconv_blocks import psf_extent
    from napari_edgecme.core.synth import densify_path, random_trajectory

    shape = tuple(job["shape"])
    image = np.random.default_rng(0).integers(0, 256, (*shape, 3), dtype=np.uint8)
    # _bench._memory.rotation_motion, spelled out: this child also runs the --before tree
    cam = Intrinsics.from_image_shape(shape)
    motion = densify_path(random_trajectory("rotation", cam, job["extent"], rng=0),
                          "rotation", cam)
    before = {"rss": _vm("VmRSS"), "hwm": _vm("VmHWM")}
    params = {"beta_max": 2.0 ** (1.5 * (job["steps"] - 1))}  # beta_rate 2 sqrt 2
    if job["block_size"] is not None:
        params["block_size"] = job["block_size"]
    t0, c0 = time.perf_counter(), time.process_time()
    first, n_blocks = None, 0
    gen = iter_deconvolve(image, motion, **params)
    while True:
        try:
            record = next(gen)
        except StopIteration as done:
            out = done.value
            break
        if "building the blur operator" in record.message:
            n_blocks += 1
            first = first or record.message
    assert out.shape == image.shape
    return {"K": psf_extent(motion), "before": before, "peak": _vm("VmHWM"),
            "wall": time.perf_counter() - t0, "cpu": time.process_time() - c0,
            "blocks": n_blocks, "first": first}


def _spawn(job: dict, source: str | None = None) -> dict:
    env = dict(os.environ)
    if source:
        env["PYTHONPATH"] = str(Path(source).resolve())
    proc = subprocess.run([sys.executable, __file__, "--child", json.dumps(job)],
                          capture_output=True, text=True, env=env, check=False)
    for line in proc.stdout.splitlines():
        if line.startswith(_MARKER):
            return json.loads(line[len(_MARKER):])
    raise RuntimeError(f"child failed: {proc.stderr[-2000:]}")


# --------------------------------------------------------------------------------------
# parts
# --------------------------------------------------------------------------------------

def part_model(sides) -> list[str]:
    rows = ["| block (px) | PSF K (operator's) | tile | tiles | method | solver | measured "
            "(MiB) | model (MiB) | model / measured |",
            "|---:|---:|---:|---:|---|---|---:|---:|---:|"]
    for side in sides:
        for K in (31, 61):
            for method, solver in CASES:
                r = _spawn({"part": "model", "side": side, "extent": EXTENTS[(side, K)],
                            "method": method, "solver": solver})
                shown = solver if method == "hyperlaplacian" else ""
                rows.append(f"| {side} | {r['K']} ({r['K_operator']}) | {r['stride']} | "
                            f"{r['tiles']} | {method} | {shown} | "
                            f"{r['measured'] / 2**20:.1f} | {r['model'] / 2**20:.1f} | "
                            f"{r['model'] / r['measured']:.2f} |")
                print(rows[-1], flush=True)
    return rows


def part_large(size: int, psf: int, steps: int, before: str | None) -> list[str]:
    import numpy as np

    from napari_edgecme._bench._memory import rotation_motion
    from napari_edgecme.core.deconv_blocks import (
        BlockPlan,
        auto_block_size,
        auto_stride,
        block_memory,
        latent_pad,
        psf_extent,
    )

    shape = SHAPES[size]
    extent = EXTENTS[(size, psf)]
    motion = rotation_motion(shape, extent)
    K, stride = psf_extent(motion), auto_stride(motion)

    def modelled(block_size):
        worst = 0
        for blk in BlockPlan(shape, block_size, K).blocks:
            r0, r1, c0, c1 = blk["box"]
            worst = max(worst, block_memory(
                (r1 - r0, c1 - c0), K, stride, operator_psf_size=psf_extent(motion, latent_pad(K)),
                image_edges=(r0 == 0, r1 == shape[0], c0 == 0, c1 == shape[1]),
                n_poses=int(np.count_nonzero(motion.weights))))
        return worst

    rows = [f"{size} MP ({shape[1]}x{shape[0]}) 8-bit RGB, camera rotation of {extent} px "
            f"blur extent (PSF side K = {K}, EFF tiles of {stride} px), {steps} "
            "half-quadratic step(s), fresh process each:", "",
            "| code | block_size | blocks | peak RSS (MiB) | RSS before the call (MiB) | "
            "model, largest block (MiB) | CPU (s) | wall (s) |",
            "|---|---|---:|---:|---:|---:|---:|---:|"]
    runs = [("before", 2048, before), ("after", 2048, None), ("after", None, None)]
    for name, block_size, source in runs:
        r = _spawn({"part": "large", "shape": shape, "extent": extent, "steps": steps,
                    "block_size": block_size}, source)
        chosen = block_size or auto_block_size(shape, motion)
        label = str(block_size) if block_size else f"None -> {chosen}"
        rows.append(f"| {name} | {label} | {r['blocks']} | {r['peak']:.0f} | "
                    f"{r['before']['rss']:.0f} | {modelled(chosen) / 2**20:.0f} | "
                    f"{r['cpu']:.0f} | {r['wall']:.0f} |")
        print(rows[-1], flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--parts", default="model")
    ap.add_argument("--sides", default="256,512,768")
    ap.add_argument("--size", type=int, default=24, choices=sorted(SHAPES))
    ap.add_argument("--psf", type=int, default=151, choices=(85, 151))
    ap.add_argument("--steps", type=int, default=1)
    ap.add_argument("--before", default=None, help="source tree ('src') of the code before")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--child")
    args = ap.parse_args(argv)
    if args.child:
        job = json.loads(args.child)
        result = (child_model if job["part"] == "model" else child_large)(job)
        print(_MARKER + json.dumps(result), flush=True)
        return 0
    lines = []
    parts = args.parts.split(",")
    if "model" in parts:
        lines += [*part_model([int(s) for s in args.sides.split(",")]), ""]
    if "large" in parts:
        lines += part_large(args.size, args.psf, args.steps, args.before)
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
