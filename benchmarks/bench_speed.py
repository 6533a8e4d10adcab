"""Speed benchmark: EFF operator, estimation and deconvolution at 800x800, and the
hyper-Laplacian deconvolution of a 12-megapixel RGB photo (issues: estimation,
deconvolution).

Each estimation and deconvolution runs in a fresh Python process that reports its own
peak memory. Writes ``speed[-quick].md`` and ``.json`` into ``--out``. The logic lives in
:mod:`napari_edgecme._bench` (also ``edgecme bench``).

    python benchmarks/bench_speed.py [--quick] [--no-large] [--out DIR]
"""

from __future__ import annotations

import argparse
import sys

from napari_edgecme._bench import run_bench


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="single runs, fewer rows, no 12 MP case")
    parser.add_argument("--no-large", action="store_true", help="skip the 12 MP case")
    parser.add_argument("--out", default="edgecme-bench", help="output folder")
    args = parser.parse_args(argv)
    written = run_bench(args.out, quick=args.quick, parts=("speed",), large=not args.no_large,
                        log=lambda line: print(line, file=sys.stderr, flush=True))
    print("\n".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
