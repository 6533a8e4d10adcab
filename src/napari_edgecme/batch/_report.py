"""The batch's report: the rows, ``report.csv`` and ``report.html``, and saving a photo's
outputs."""

from __future__ import annotations

import csv
import html
import io
from dataclasses import dataclass
from pathlib import Path

from ..core import io as _io
from ._photos import Photo

__all__ = ["DONE", "FAILED", "NOT_RUN", "NO_BLUR", "REPORT_FIELDS", "SKIPPED", "BatchResult"]

#: Row statuses: restored, no blur found (the photo is written unchanged: not a
#: failure), failed (reason given), outputs of an earlier run kept, not run (interrupted).
DONE, NO_BLUR, FAILED, SKIPPED, NOT_RUN = "done", "no blur", "failed", "skipped", "not run"
#: Columns of ``report.csv`` (the HTML report shows the same, with the thumbnails).
REPORT_FIELDS = ("photo", "status", "method", "blur_extent_px", "profiles", "seconds",
                 "reason", "warnings", "output", "motion", "before", "after", "psf",
                 "worker", "worker_peak_mib", "source")


@dataclass
class BatchResult:
    """What :func:`deblur_many` did.

    Attributes
    ----------
    rows : list of dict
        One report row per photo, in input order (keys :data:`REPORT_FIELDS`).
    out_dir, report_csv, report_html : Path
    cluster : str
        Where the photos ran, e.g. ``"local Dask cluster: 2 workers x 1 thread"``.
    interrupted : bool
        True when a KeyboardInterrupt stopped the batch.
    """

    rows: list[dict]
    out_dir: Path
    report_csv: Path
    report_html: Path
    cluster: str = ""
    interrupted: bool = False
    seconds: float = 0.0

    @property
    def counts(self) -> dict[str, int]:
        """Photos per status."""
        statuses = [row["status"] for row in self.rows]
        return {status: statuses.count(status)
                for status in (DONE, NO_BLUR, SKIPPED, FAILED, NOT_RUN) if status in statuses}

    @property
    def failed(self) -> list[dict]:
        """The rows of the photos that failed."""
        return [row for row in self.rows if row["status"] == FAILED]

    @property
    def ok(self) -> bool:
        """True when every photo was restored (or had no blur) in this run or an earlier one."""
        return all(row["status"] in (DONE, NO_BLUR, SKIPPED) for row in self.rows)


def read_previous(path: Path) -> dict[str, dict]:
    """Rows of an earlier run's ``report.csv`` by photo name (empty if none or unreadable)."""
    try:
        with open(path, newline="", encoding="utf-8") as f:
            return {row["photo"]: row for row in csv.DictReader(f) if "photo" in row}
    except (OSError, csv.Error, UnicodeDecodeError):
        return {}


def _write_text(path: Path, text: str) -> None:
    with _io.atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


_STYLE = """body{font-family:sans-serif;margin:1em}table{border-collapse:collapse}
td,th{border:1px solid #ccc;padding:4px;vertical-align:top;font-size:13px}
img{max-width:192px;max-height:192px}.failed{background:#fdd}.noblur{background:#ffd}
.notrun{color:#888}"""


def _html(rows: list[dict], final: bool, heading: str) -> str:
    def link(thumb, target=None) -> str:  # paths relative to out_dir
        if not thumb:
            return ""
        src, href = html.escape(str(thumb)), html.escape(str(target or thumb))
        return f'<a href="{href}"><img src="{src}" alt="{src}"></a>'

    lines = ["<!DOCTYPE html>", '<html><head><meta charset="utf-8">',
             "<title>edgecme batch report</title>"]
    if not final:  # reload while the batch runs
        lines.append('<meta http-equiv="refresh" content="10">')
    lines += [f"<style>{_STYLE}</style></head><body>",
              f"<h1>edgecme batch report</h1><p>{html.escape(heading)}</p>", "<table>",
              "<tr><th>photo</th><th>status</th><th>method</th><th>blur extent (px)</th>"
              "<th>profiles</th><th>time (s)</th><th>before</th><th>after</th>"
              "<th>PSF field</th><th>reason / warnings</th></tr>"]
    for row in rows:
        css = {FAILED: "failed", NO_BLUR: "noblur", NOT_RUN: "notrun"}.get(row["status"], "")
        note = " | ".join(x for x in (row.get("reason"), row.get("warnings")) if x)
        cells = [html.escape(str(row.get(k, "") or "")) for k in
                 ("photo", "status", "method", "blur_extent_px", "profiles", "seconds")]
        cells += [link(row.get("before"), row.get("source")),
                  link(row.get("after"), row.get("output")), link(row.get("psf")),
                  html.escape(note)]
        lines.append(f'<tr class="{css}">' + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    lines += ["</table></body></html>", ""]
    return "\n".join(lines)


class Report:
    """The batch's rows, and their ``report.csv`` and ``report.html``, rewritten on change."""

    def __init__(self, photos: list[Photo], out_dir: Path):
        self.out_dir = out_dir
        self.csv = out_dir / "report.csv"
        self.html = out_dir / "report.html"
        self.rows = {p.name: {"photo": p.name, "status": NOT_RUN, "source": str(p.source)}
                     for p in photos}
        self.heading = ""

    def set(self, name: str, row: dict) -> None:
        self.rows[name] = {**self.rows[name], **row}

    def write(self, final: bool = False) -> None:
        rows = list(self.rows.values())
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=REPORT_FIELDS, extrasaction="ignore",
                                lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        _write_text(self.csv, text.getvalue())
        _write_text(self.html, _html(rows, final, self.heading))


def save_outputs(photo: Photo, out_dir: Path, files: dict[str, bytes]) -> dict[str, str]:
    """Write a photo's encoded outputs, each atomically, the motion file last."""
    paths = photo.outputs(out_dir)
    written = {}
    for role in ("before", "after", "psf", "output", "motion"):
        path = paths[role]
        path.parent.mkdir(parents=True, exist_ok=True)
        with _io.atomic_path(path) as tmp:
            tmp.write_bytes(files[role])
        written[role] = path.relative_to(out_dir).as_posix()
    return written
