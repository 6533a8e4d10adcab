"""Quality benchmark of the camera-motion estimators (issue: estimation).

Blurred / EpAlone / Xu / Xu+Ep / oracle over synthetic shakes of scikit-image photos and
the edge-rich ``edges`` scene (``inplane`` and ``rotation``, 13-31 px, 1 % noise, 8-bit):
aligned PSNR, centroid-aligned PSF NCC, time and peak memory per estimator. Writes
``quality[-quick].md`` and ``.json`` into ``--out``. The logic lives in
:mod:`napari_edgecme._bench` (also ``edgecme bench``).

    python benchmarks/bench_quality.py [--quick] [--out DIR]
"""

from __future__ import annotations

import argparse
import sys

from napari_edgecme._bench import run_bench


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="4 small cases, a few minutes")
    parser.add_argument("--out", default="edgecme-bench", help="output folder")
    args = parser.parse_args(argv)
    written = run_bench(args.out, quick=args.quick, parts=("quality",),
                        log=lambda line: print(line, file=sys.stderr, flush=True))
    print("\n".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
