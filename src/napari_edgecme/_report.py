"""Report helpers shared by the benchmarks, the suites and the demo: the machine a run
was on, Markdown tables and number formatting that tolerates missing values."""

from __future__ import annotations

import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

__all__ = ["METHOD_NAMES", "blas_kernel", "fmt", "load_average", "machine_info", "machine_line",
           "markdown_table", "mean_or_none", "median_or_none", "memory_note", "met_mark"]

#: Display names of the estimators (engine name -> name in the tables).
METHOD_NAMES = {"ep": "EpAlone", "xu": "Xu", "xu+ep": "Xu+Ep"}


def _total_memory_gib() -> float | None:
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemTotal:"):
                    return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return None


def load_average() -> float | None:
    """The 1-minute load average (None where the platform has none)."""
    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):  # Windows
        return None


#: The symbols OpenBLAS builds export to name the CPU kernel they run.
_BLAS_CORENAME_SYMBOLS = ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename",
                          "openblas_get_corename64_", "openblas_get_corename")


def blas_kernel() -> str | None:
    """The CPU kernel of numpy's bundled OpenBLAS, e.g. ``"Haswell"`` or ``"SkylakeX"``.

    OpenBLAS picks its kernel from the CPU (``OPENBLAS_CORETYPE`` overrides it), and two
    kernels round differently in the last bits; the alternating estimators can amplify
    that into another basin (``benchmarks/results/xu-candidate.md``). The engine keeps its
    geometry and colour arithmetic out of BLAS, which removed nearly all of it, but the
    MDF update still uses BLAS: reports record the kernel so that a figure can be
    reproduced.

    Returns
    -------
    str or None
        None when numpy does not bundle OpenBLAS (Accelerate, MKL, a system BLAS) or the
        library does not say.
    """
    import ctypes

    libs = Path(np.__file__).resolve().parent.parent / "numpy.libs"
    for lib in sorted(libs.glob("lib*openblas*.so*")) if libs.is_dir() else ():
        try:
            handle = ctypes.CDLL(str(lib))
        except OSError:
            continue
        for symbol in _BLAS_CORENAME_SYMBOLS:
            corename = getattr(handle, symbol, None)
            if corename is not None:
                corename.restype = ctypes.c_char_p
                name = corename()
                return name.decode("ascii", "replace").strip() if name else None
    return None


def machine_info() -> dict:
    """Date, machine name, CPU count, platform and versions, for reports."""
    import scipy

    from . import __version__

    return {
        "date": time.strftime("%Y-%m-%d %H:%M %Z"),
        "load_average": load_average(),
        "node": platform.node(),
        "cpus": os.cpu_count(),
        "memory_gib": _total_memory_gib(),
        "platform": f"{platform.system()} {platform.machine()}",
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "blas_kernel": blas_kernel(),
        "version": __version__,
    }


def machine_line(m: dict) -> str:
    """One Markdown line saying when and on what machine a run was (from :func:`machine_info`)."""
    memory = f", {m['memory_gib']:.0f} GiB RAM" if m.get("memory_gib") else ""
    load = ""
    if m.get("load_average") is not None:
        loads = [m["load_average"], m.get("load_average_end", m["load_average"])]
        load = f"; load average {loads[0]:.1f} at the start, {loads[1]:.1f} at the end"
        if max(loads) > (m.get("cpus") or 1) + 0.5:
            load += " (above the CPU count: the machine was shared, so times are inflated)"
    blas = f"OpenBLAS kernel {m['blas_kernel']}, " if m.get("blas_kernel") else ""
    return (f"{m['date']} on `{m['node']}` ({m['cpus']} CPUs{memory}, {m['platform']}), "
            f"Python {m['python']}, numpy {m['numpy']}, scipy {m['scipy']}, {blas}"
            f"napari-edgecme {m['version']}{load}")


def markdown_table(header, rows, align: str | None = None) -> str:
    """A Markdown table; ``align`` is one letter per column (``l``, ``r`` or ``c``)."""
    align = align or "l" * len(header)
    marks = {"l": "---", "r": "---:", "c": ":---:"}
    lines = ["| " + " | ".join(header) + " |",
             "|" + "|".join(marks[a] for a in align) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def median_or_none(values):
    """Median of the values that are not None (None if there are none)."""
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def mean_or_none(values):
    """Mean of the values that are not None (None if there are none)."""
    values = [v for v in values if v is not None]
    return statistics.fmean(values) if values else None


def fmt(value, spec: str, empty: str = "—") -> str:
    """``format(value, spec)``, or ``empty`` for None."""
    return empty if value is None else format(value, spec)


def met_mark(flag) -> str:
    """A target's status in a table: met, **missed** or not measured (None)."""
    return {True: "met", False: "**missed**", None: "not measured"}[flag]


def memory_note(baseline) -> str:
    """What the peak-RSS figures of fresh-process runs include (``baseline``: MiB)."""
    base = f" ({baseline:.0f} MiB here)" if baseline else ""
    return ("Peak RSS: each run is a fresh Python process reporting its own peak resident "
            "set size (`VmHWM` of `/proc/self/status`; not `ru_maxrss`, which on Linux "
            "inherits the parent's high-water mark through fork and exec). It includes the "
            "interpreter, the libraries and the loaded input, i.e. the baseline of a process "
            f"that only imports the engine and loads the input{base}.")


def check_out_folder(out: Path, what: str) -> None:
    """Refuse, in one line, an ``--out`` that is a file or whose parent folder is missing.

    ``what`` names the folder in the message (``"benchmark"``, ``"demo"``).
    """
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a folder")
    if not out.exists() and not out.parent.is_dir():
        raise ValueError(f"cannot create the {what} folder {out}: its parent folder "
                         f"{out.parent} does not exist")
