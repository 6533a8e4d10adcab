"""What Xu+Ep's EpAlone candidate (``estimate.EP_CANDIDATE``) costs, on ``lai`` cases.

Each case is estimated as the ``lai`` suite does (Xu+Ep, told the case's max blur and
the true focal length, seed 0) with the candidate off and on, alternately in one
process, ``--repeat`` times each; the table gives the medians (wall and CPU seconds)
and which start was kept. Timing figures only: nothing is asserted.

    python benchmarks/bench_ep_candidate_time.py CASE [CASE ...] [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings


def main(argv=None) -> int:
    import napari_edgecme.core.estimate as estimate
    from napari_edgecme._suites._data import default_data_dir, lai_cases, lai_load

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="+")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    cases = {c["name"]: c for c in lai_cases(default_data_dir("lai"), False)}
    unknown = sorted(set(args.cases) - set(cases))
    if unknown:
        parser.error(f"no such lai case: {', '.join(unknown)}")
    print("| case | candidate | wall (s) | CPU (s) | start kept |")
    print("|---|---|---:|---:|---|")
    shipped = estimate.EP_CANDIDATE
    try:
        for name in args.cases:
            blurred, _, truth = lai_load(cases[name])
            times = {False: [], True: []}
            kept = {}
            for _ in range(args.repeat):
                for flag in (False, True):
                    estimate.EP_CANDIDATE = flag
                    wall, cpu = time.perf_counter(), time.process_time()
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        est = estimate.estimate_motion(
                            blurred, "xu+ep", "rotation", cases[name]["max_blur"],
                            truth.intrinsics.focal_px, rng=0)
                    times[flag].append((time.perf_counter() - wall,
                                        time.process_time() - cpu))
                    kept[flag] = est.info.start
            for flag in (False, True):
                print(f"| {name} | {'on' if flag else 'off'} | "
                      f"{statistics.median(t[0] for t in times[flag]):.1f} | "
                      f"{statistics.median(t[1] for t in times[flag]):.1f} | {kept[flag]} |",
                      flush=True)
    finally:
        estimate.EP_CANDIDATE = shipped
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
