"""Before/after timing of estimation: one job, two code trees, runs interleaved.

The speed benchmark's 800x800 gray case (a 31 px rotation shake, ``bench_speed.py``) is
estimated with each method in fresh processes, alternating between the ``--before`` and
``--after`` source trees (``git archive`` snapshots, say), so that both see the same
machine load. Prints a Markdown table of median wall and CPU seconds, peak memory and
the after/before ratios, and writes it to ``--out`` if given.

    mkdir -p /tmp/a /tmp/b
    git archive OLD src | tar -x -C /tmp/a; git archive HEAD src | tar -x -C /tmp/b
    python benchmarks/bench_ab.py --before /tmp/a/src --after /tmp/b/src --repeat 3
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

from napari_edgecme._bench._config import SPEED_BLUR, make_config
from napari_edgecme._bench._speed import speed_inputs
from napari_edgecme._report import load_average, machine_info, machine_line
from napari_edgecme._worker import run_job


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", required=True, help="source tree (folder holding "
                        "napari_edgecme) of the reference code")
    parser.add_argument("--after", required=True, help="source tree of the changed code")
    parser.add_argument("--methods", default="ep,xu+ep", help="comma-separated methods")
    parser.add_argument("--repeat", type=int, default=3, help="runs per tree and method")
    parser.add_argument("--timeout", type=float, default=1800.0, help="seconds per run")
    parser.add_argument("--out", default=None, help="Markdown file to write")
    args = parser.parse_args(argv)
    trees = {"before": str(Path(args.before).resolve()),
             "after": str(Path(args.after).resolve())}
    for name, tree in trees.items():
        if not (Path(tree) / "napari_edgecme").is_dir():
            print(f"error: --{name} {tree} holds no napari_edgecme package", file=sys.stderr)
            return 2
    machine = machine_info()
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        paths = speed_inputs(make_config(quick=True, large=False, speed_size=800), Path(tmp))
        rows = []
        for method in args.methods.split(","):
            job = {"kind": "estimate", "image": paths["blurred"], "method": method,
                   "model": "rotation", "max_blur": SPEED_BLUR}
            runs = {name: [] for name in trees}
            for i in range(args.repeat):
                for name, tree in trees.items():
                    res = run_job(job, args.timeout, source=tree)
                    if not res.get("ok"):  # e.g. EpAlone refusing: no time to compare
                        print(f"{method} ({name}) failed: {res.get('error')}", file=sys.stderr)
                        break
                    runs[name].append(res)
                    print(f"{method} {name} run {i + 1}: {res['estimate_s']:.1f} s wall, "
                          f"{res['estimate_cpu_s']:.1f} s CPU, {res['peak_rss_mib']:.0f} MiB",
                          file=sys.stderr, flush=True)
                if not all(len(rs) == i + 1 for rs in runs.values()):
                    break
            if not all(runs.values()):
                rows.append((method, None, None, None))
                continue
            med = {name: {key: statistics.median(r[key] for r in rs)
                          for key in ("estimate_s", "estimate_cpu_s")}
                   for name, rs in runs.items()}
            peak = {name: max(r["peak_rss_mib"] for r in rs) for name, rs in runs.items()}
            ran = {name: rs[0].get("method_run", method) for name, rs in runs.items()}
            rows.append((method, med, peak, ran))
    machine["load_average_end"] = load_average()
    lines = [f"# Estimation before / after, 800x800 gray, {SPEED_BLUR:g} px rotation shake",
             "", f"{machine_line(machine)}; {(time.perf_counter() - t_start) / 60:.1f} min; "
             f"medians of {args.repeat} fresh-process runs per tree, interleaved.", "",
             "| method (ran as: before / after) | wall before (s) | wall after (s) | ratio | "
             "CPU before (s) | CPU after (s) | ratio | peak before (MiB) | peak after (MiB) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for method, med, peak, ran in rows:
        if med is None:
            lines.append(f"| {method} | failed (see the log) | | | | | | | |")
            continue
        method = f"{method} ({ran['before']} / {ran['after']})"
        b, a = med["before"], med["after"]
        lines.append(f"| {method} | {b['estimate_s']:.1f} | {a['estimate_s']:.1f} | "
                     f"{a['estimate_s'] / b['estimate_s']:.2f} | {b['estimate_cpu_s']:.1f} | "
                     f"{a['estimate_cpu_s']:.1f} | {a['estimate_cpu_s'] / b['estimate_cpu_s']:.2f}"
                     f" | {peak['before']:.0f} | {peak['after']:.0f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
