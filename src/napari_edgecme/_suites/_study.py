"""The frame of a per-case study on a ground-truth suite (``benchmarks/bench_ep_*.py``).

A study computes one JSON row per case of ``lai`` or ``levin`` in worker processes
(``run_case(case, suite) -> dict``), writes the rows as they come (``--out``), and
tabulates them; ``--rows`` tabulates rows written earlier instead of running.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ._data import default_data_dir, lai_cases, lai_load, levin_cases, levin_load, levin_max_blur

__all__ = ["StudyCase", "load_study_case", "study_main"]


class StudyCase(NamedTuple):
    """A case as the suites give it to an estimator: the images, the truth, what it is
    told (model, max blur, focal length; None: not told), and whether scoring aligns
    the in-plane rotation too."""

    blurred: np.ndarray
    sharp: np.ndarray
    truth: object  # CameraMotion
    model: str
    max_blur: float
    focal_px: float | None
    rotation: bool

    def row(self, case: dict) -> dict:
        """The start of the case's row: its name, category and the blurred input's
        aligned PSNR (dB), scored as the suites score."""
        from ..core.metrics import aligned_scores

        return {"name": case["name"], "category": case["category"],
                "blurred": aligned_scores(self.blurred, self.sharp, rotation=self.rotation)[0]}

    def estimate(self, method: str, profiles=None):
        """``estimate_motion`` of ``method`` told what the suites tell it, seed 0, its
        warnings silenced; a refusal raises its ``ValueError``. ``profiles``
        (EdgeProfiles): used instead of extracting them."""
        from ..core import estimate

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return estimate.estimate_motion(self.blurred, method, self.model, self.max_blur,
                                            self.focal_px, profiles=profiles, rng=0)


def load_study_case(case: dict, suite: str) -> StudyCase:
    """``lai``: told the case's max blur and the true focal length, model ``rotation``,
    scored with in-plane rotation; ``levin``: told the kernel's size, model
    ``translation``, scored with shifts only -- as the suites run them."""
    if suite == "lai":
        blurred, sharp, truth = lai_load(case)
        return StudyCase(blurred, sharp, truth, "rotation", case["max_blur"],
                         truth.intrinsics.focal_px, True)
    blurred, sharp, truth = levin_load(case)
    return StudyCase(blurred, sharp, truth, "translation", levin_max_blur(truth), None, False)


def study_main(doc: str, run_case, tabulate, argv=None, add_arguments=None) -> int:
    """Parse a study's command line, run or read its rows, print ``tabulate(rows, args)``.

    Parameters
    ----------
    doc : str
        The script's docstring (its first line is the ``--help`` description).
    run_case : callable
        ``run_case(case, suite) -> dict``, picklable (a module-level function): one row,
        with at least ``"name"``, and ``"error"`` when the case could not be run.
    tabulate : callable
        ``tabulate(rows, args) -> str``: what the script prints.
    argv : list of str, optional
    add_arguments : callable, optional
        ``add_arguments(parser)``: the study's own options.

    Returns
    -------
    int
        The exit status (0).
    """
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("suite", choices=["lai", "levin"])
    parser.add_argument("--data", default=None, help="the suite's folder")
    parser.add_argument("--quick", action="store_true", help="lai: the 20 cases of quick.txt")
    parser.add_argument("--jobs", type=int, default=2, help="cases at a time")
    parser.add_argument("--out", default=None, help="write one JSON row per case here")
    parser.add_argument("--rows", default=None, help="tabulate these rows instead of running")
    if add_arguments is not None:
        add_arguments(parser)
    args = parser.parse_args(argv)
    if args.rows:
        rows = [json.loads(line) for line in Path(args.rows).read_text().splitlines()]
    else:
        data = Path(args.data) if args.data else default_data_dir(args.suite)
        if data is None or not data.is_dir():
            parser.error(f"no {args.suite} data: pass --data DIR")
        cases = (lai_cases(data, args.quick) if args.suite == "lai"
                 else levin_cases(data, False))
        rows = []
        out = open(args.out, "w") if args.out else None
        try:
            with ProcessPoolExecutor(max(1, args.jobs)) as pool:
                for row in pool.map(run_case, cases, [args.suite] * len(cases)):
                    rows.append(row)
                    if out:
                        out.write(json.dumps(row) + "\n")
                        out.flush()
                    print(row["name"], row.get("error", ""), file=sys.stderr, flush=True)
        finally:
            if out:
                out.close()
    print(tabulate(rows, args))
    return 0
