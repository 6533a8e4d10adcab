"""The real-photo suites (issue: real photos are the yardstick): ``lai``, ``levin``, ``real``.

``lai``: real gyro-recorded camera shakes on natural photos (5 categories), true motion;
``levin``: real captured uniform blurs with sharp ground truth (and the anchor protocol of
its README); ``real``: the paper's real photos, deblurred through the CLI, one side-by-side
sheet each. Writes ``<suite>[-quick].md`` and ``.json`` (and ``real-sheets/``) into
``--out``. The logic lives in :mod:`napari_edgecme._suites` (also ``edgecme bench --suite``).

    python benchmarks/bench_suites.py lai [--quick] [--jobs 2] [--data DIR] [--out DIR]

The reports name numpy's OpenBLAS kernel. The engine's geometry and colour arithmetic do
not use BLAS, and the Haswell and SkylakeX kernels give the same ``lai`` figures but for
one Xu+Ep case (0.09 dB; ``benchmarks/results/lai-skylakex.md``); the MDF update's
least-squares products still use BLAS, so compare before and after under one kernel.
"""

from __future__ import annotations

import argparse
import sys

from napari_edgecme._suites import SUITES, run_suite


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("suite", choices=tuple(SUITES))
    parser.add_argument("--quick", action="store_true",
                        help="lai: the 20 cases of quick.txt; levin: the 8 anchor cases")
    parser.add_argument("--jobs", type=int, default=1, help="cases at a time")
    parser.add_argument("--data", default=None,
                        help="data folder (default: ../shared/data/<suite>)")
    parser.add_argument("--out", default="benchmarks/out", help="output folder")
    args = parser.parse_args(argv)
    written = run_suite(args.suite, args.out, data=args.data, quick=args.quick,
                        jobs=args.jobs, log=lambda line: print(line, file=sys.stderr,
                                                               flush=True))
    print("\n".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
