"""Speed and accuracy of the blur operators (issue: foundation).

Prints a Markdown table: the efficient filter flow (EFF) forward and adjoint on an
800x800 float32 image under a 31 px rotational shake, the exact warp-sum with 100
active poses on the same image, their ratio, and the EFF's relative L2 error against
the exact warp-sum; then the deconvolution's image-step normal operator
``lam (M T)^T (M T) + beta D^T D`` on the padded latent domain, composed from operators
(:meth:`~napari_edgecme.core.deconv_solvers.LatentDomain.normal`) and written out step
by step, to show what the composition costs. Timings are medians over repeated runs on
a shared machine: read the ratios, not the absolute numbers.

    python benchmarks/bench_operators.py [--repeat N] [--size PX]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import numpy as np

from napari_edgecme.core.camera import Intrinsics
from napari_edgecme.core.deconv_prior import grad, grad_adjoint
from napari_edgecme.core.deconv_solvers import LatentDomain
from napari_edgecme.core.motion import CameraMotion
from napari_edgecme.core.operators import EfficientFilterFlow, WarpSum
from napari_edgecme.core.synth import densify_path, random_trajectory, sample_image


def median_time(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=9)
    parser.add_argument("--size", type=int, default=800)
    args = parser.parse_args(argv)

    image = sample_image("camera", args.size).astype(np.float32)
    cam = Intrinsics.from_image_shape(image.shape)
    path = random_trajectory("rotation", cam, 31, 48, rng=0)
    dense = densify_path(path, "rotation", cam)
    # the exact warp-sum costs one warp per active pose: measure it with exactly 100
    idx = np.linspace(0, dense.n_poses - 1, 100).round().astype(int)
    motion100 = CameraMotion.from_trajectory(dense.poses[idx], "rotation", cam)

    eff = EfficientFilterFlow(dense)
    blurred = eff.forward(image)
    t_build = median_time(lambda: EfficientFilterFlow(dense), max(3, args.repeat // 3))
    t_fwd = median_time(lambda: eff.forward(image), args.repeat)
    t_adj = median_time(lambda: eff.adjoint(blurred), args.repeat)
    exact = WarpSum(motion100)
    t_exact = median_time(lambda: exact.forward(image), max(3, args.repeat // 3))
    t_exact_adj = median_time(lambda: exact.adjoint(blurred), max(3, args.repeat // 3))

    ref = WarpSum(dense, dtype=np.float64).forward(image.astype(np.float64))
    rel = np.linalg.norm(EfficientFilterFlow(dense, dtype=np.float64).forward(
        image.astype(np.float64)) - ref) / np.linalg.norm(ref)

    # the image step's normal operator, composed and written out (same arithmetic)
    pad = (dense.psf_size() + 1) // 2
    domain = LatentDomain(dense, (0, args.size, 0, args.size), pad)
    lam, beta = np.float32(750.0), np.float32(8.0)
    normal = domain.normal(lam, beta)
    v = np.random.default_rng(0).random(domain.shape).astype(np.float32)

    def written_out(v):
        blurred = domain.op.forward(v)[domain.inner]
        embedded = np.zeros(domain.shape, np.float32)
        embedded[domain.inner] = blurred
        out = domain.op.adjoint(embedded)
        out *= lam
        out += beta * grad_adjoint(*grad(v))
        return out

    assert np.array_equal(normal @ v, written_out(v))
    t_normal = median_time(lambda: normal @ v, args.repeat)
    t_written = median_time(lambda: written_out(v), args.repeat)

    g = eff.grid
    print(f"# Blur operators, {args.size}x{args.size} float32, 31 px rotational shake")
    print(f"machine: {platform.node()} ({platform.machine()}, {platform.processor() or 'cpu'}),"
          f" python {platform.python_version()}, {time.strftime('%Y-%m-%d')}")
    print(f"EFF grid: {g.counts[0]}x{g.counts[1]} tiles of {g.stride[0]} px, overlap "
          f"{g.overlap[0]} px, PSF {g.psf_size} px, FFT {g.fft_shape[0]} px; "
          f"{dense.n_poses} poses on the path\n")
    print("| operator | median time (s) | vs EFF forward |")
    print("|---|---:|---:|")
    print(f"| EFF build (PSFs + spectra) | {t_build:.3f} | {t_build / t_fwd:.1f}x |")
    print(f"| EFF forward | {t_fwd:.3f} | 1.0x |")
    print(f"| EFF adjoint | {t_adj:.3f} | {t_adj / t_fwd:.1f}x |")
    print(f"| exact warp-sum forward, 100 poses | {t_exact:.3f} | {t_exact / t_fwd:.1f}x |")
    print(f"| exact warp-sum adjoint, 100 poses | {t_exact_adj:.3f} | {t_exact_adj / t_fwd:.1f}x |")
    print(f"| image-step normal operator, composed ({domain.shape[0]} px domain) | "
          f"{t_normal:.3f} | {t_normal / t_fwd:.1f}x |")
    print(f"| image-step normal operator, written out | {t_written:.3f} | "
          f"{t_written / t_fwd:.1f}x |")
    print(f"\nEFF vs exact warp-sum (all {dense.n_poses} poses, float64): relative L2 error "
          f"{rel:.4f}")
    print(f"Composed normal operator / written out: {t_normal / t_written:.2f}x "
          "(bit-identical results)")


if __name__ == "__main__":
    main()
