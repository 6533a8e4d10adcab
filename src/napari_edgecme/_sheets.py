"""Side-by-side comparison sheets of blurred photos and their restorations.

A *sheet* is one PNG for a benchmark case: the first row shows every panel (the
blurred input, the restorations of the methods, a reference...) as a whole image
with its label; each further row shows the same square crop of every panel at 1:1
pixel scale or an integer nearest-neighbour zoom of it, so that ringing, residual
blur and noise can be judged without resampling artefacts. The crops default to the
windows of the first panel with the most edge energy (:func:`choose_crops`) and are
outlined, numbered, on the first panel of the first row.

matplotlib is used only through its object-oriented API (``Figure`` and the Agg
canvas, never ``pyplot``), imported inside the functions: importing this module
costs nothing and needs no display.
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = ["choose_crops", "make_sheet", "read_rgb"]

#: Figure resolution; every layout size below is in pixels at this dpi.
_DPI = 100
#: Upper bound of the sheet's width in pixels.
_MAX_WIDTH = 2600
#: Column width the integer zoom of the crops aims at (pixels).
_TARGET_COLUMN = 400
#: Largest integer zoom of a crop.
_MAX_ZOOM = 4
_MARGIN = 12  # outer margin (px)
_GAP = 10  # gap between columns and rows (px)
_LABEL_LINE = 17  # height of a label line (10 pt text) in px
_NOTE_LINE = 14  # height of a note line (8 pt text) in px
_CROP_HEADER = 22  # height of the header line above a crop row (px)
_TITLE_BAND = 34  # height of the figure title band (px)
_NONE_GREY = "0.82"
#: Outline colours of the crops (bright, visible on most photos), cycled.
_CROP_COLOURS = ("#ff2d55", "#ffd60a", "#30d5ff", "#7cff4f", "#ff9f0a", "#bf5af2")


# ----------------------------------------------------------------------------- helpers


def _to_unit(image) -> np.ndarray:
    """An image as float in [0, 1] for display: (H, W) gray or (H, W, 3) RGB.

    The engine's float policy (:func:`~.core._validation.as_float_image`: integers scaled
    by their dtype's maximum, float64 kept, anything else float32), any finite range
    accepted and clipped to [0, 1] with NaN as 0; (H, W, 1) and gray+alpha keep the gray
    plane and RGBA drops the alpha.
    """
    from .core._validation import as_float_image

    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] in (1, 2):
        arr = arr[:, :, 0]
    elif arr.ndim == 3 and arr.shape[2] == 4:
        arr = arr[:, :, :3]
    if np.issubdtype(arr.dtype, np.floating):
        arr = np.nan_to_num(arr, nan=0.0, posinf=1.0, neginf=0.0)
    out = as_float_image(arr, "panel", allow_rgb=True, min_size=1, check_range=False)
    return np.clip(out, 0.0, 1.0, out=out)


def _luminance(image) -> np.ndarray:
    """The float64 luminance (the engine's Rec. 709 weights) of a gray or RGB image, (H, W)."""
    from .core.edges import to_luminance

    return to_luminance(_to_unit(image)).astype(np.float64)


def _default_crop_size(shape: tuple[int, int]) -> int:
    """About a quarter of the smaller side, clamped to [64, 200] pixels."""
    return int(min(200, max(64, round(min(shape) / 4))))


# ----------------------------------------------------------------------------- crops


def choose_crops(image, n: int = 2, size: int | None = None) -> list[tuple[int, int, int, int]]:
    """Pick ``n`` non-overlapping square windows where a restoration is easiest to judge.

    The score of a window is its edge energy: the sum over the window of the gradient
    magnitude (Sobel) of the luminance smoothed by a Gaussian of sigma 1 px, summed
    for every position at once with an integral image. Windows must keep clear of a
    border band of 5 % of the smaller image side. The choice is greedy: the best
    window, then the best window that overlaps none of those already chosen, and so
    on. Ties go to the top-most, then left-most window, so the result is
    deterministic.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        Gray or RGB image, float in [0, 1] (integer images are scaled by their
        dtype's maximum; an alpha channel is ignored).
    n : int, optional
        Number of windows wanted (default 2).
    size : int, optional
        Side of the windows in pixels. Default: about 1/4 of the smaller image side,
        clamped to [64, 200]. Either way it is reduced to what the image allows
        (the smaller side minus the two border bands; the border band is dropped for
        images too small to have one).

    Returns
    -------
    list of tuple of int
        ``(row0, col0, rows, cols)`` of each window, best first, with
        ``rows == cols == size``. Fewer than ``n`` entries when no further
        non-overlapping window fits in the image.
    """
    from scipy import ndimage

    n = int(n)
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    lum = _luminance(image)
    h, w = lum.shape
    side = min(h, w)
    border = round(0.05 * side)
    if side - 2 * border < 1:
        border = 0
    allowed = side - 2 * border
    size = _default_crop_size((h, w)) if size is None else int(size)
    if size < 1:
        raise ValueError(f"size must be >= 1, got {size}")
    size = min(size, allowed)
    if n == 0:
        return []

    smooth = ndimage.gaussian_filter(lum, 1.0, mode="reflect")
    energy = np.hypot(ndimage.sobel(smooth, axis=0, mode="reflect"),
                      ndimage.sobel(smooth, axis=1, mode="reflect"))
    integral = np.zeros((h + 1, w + 1))
    np.cumsum(energy, axis=0, out=integral[1:, 1:])
    np.cumsum(integral[1:, 1:], axis=1, out=integral[1:, 1:])
    # score[i, j] = energy in the window whose top-left corner is (border + i, border + j)
    r_hi = h - border - size  # last admissible top row
    c_hi = w - border - size
    a = integral[border:r_hi + 1, border:c_hi + 1]
    b = integral[border:r_hi + 1, border + size:c_hi + size + 1]
    c = integral[border + size:r_hi + size + 1, border:c_hi + 1]
    d = integral[border + size:r_hi + size + 1, border + size:c_hi + size + 1]
    score = d - b - c + a

    crops: list[tuple[int, int, int, int]] = []
    for _ in range(n):
        flat = int(np.argmax(score))
        i, j = divmod(flat, score.shape[1])
        if not np.isfinite(score[i, j]):
            break
        crops.append((border + i, border + j, size, size))
        # windows of the same size overlap this one iff both offsets are < size
        score[max(0, i - size + 1):i + size, max(0, j - size + 1):j + size] = -np.inf
    return crops


# ----------------------------------------------------------------------------- sheet


def _fit_lines(text: str, width_px: float, char_px: float, max_lines: int) -> list[str]:
    """Wrap ``text`` to a column ``width_px`` wide, at most ``max_lines`` lines."""
    if not text:
        return []
    chars = max(4, int(width_px // char_px))
    lines = textwrap.wrap(text, chars, break_long_words=True) or [""]
    if len(lines) > max_lines:
        lines = lines[:max_lines]
        lines[-1] = lines[-1][:max(1, chars - 1)].rstrip() + "…"
    return lines


def _check_crops(crops, h: int, w: int) -> list[tuple[int, int, int, int]]:
    """Clip the crops to the common image size; refuse malformed or outside ones."""
    out = []
    for k, crop in enumerate(crops):
        try:
            r0, c0, rr, cc = (int(v) for v in crop)
        except (TypeError, ValueError):
            raise ValueError(f"crop {k} must be (row0, col0, rows, cols), got {crop!r}") from None
        r1, c1 = min(h, r0 + rr), min(w, c0 + cc)
        r0, c0 = max(0, r0), max(0, c0)
        if r1 <= r0 or c1 <= c0:
            raise ValueError(f"crop {k} {tuple(crop)} lies outside the {h}x{w} images")
        out.append((r0, c0, r1 - r0, c1 - c0))
    return out


def _none_axes(ax, fontsize: float) -> None:
    """Draw the "not available" panel: plain grey with "(none)"."""
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_visible(False)
    ax.set_facecolor(_NONE_GREY)
    ax.text(0.5, 0.5, "(none)", transform=ax.transAxes, ha="center", va="center",
            fontsize=fontsize, color="0.35")


def _show(ax, img: np.ndarray, *, extent, interpolation: str) -> None:
    """imshow a gray (in gray) or RGB image in [0, 1] without axis decorations.

    Gray is drawn as RGB with equal channels rather than through a colormap, whose
    256-entry lookup table would shift some 8-bit values by one.
    """
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    ax.imshow(img, extent=extent, interpolation=interpolation)
    ax.set_axis_off()


def _overview_image(img: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The whole image for the first row, at its display size ``shape`` (rows, cols).

    A shrinking image is resampled here (antialiased, so that matplotlib then draws it
    1:1 and a 12-megapixel photo is not handed to Agg); an image shown at its size or
    larger is returned as it is (drawn nearest-neighbour).
    """
    dh, dw = shape
    h, w = img.shape[:2]
    if dh >= h and dw >= w:
        return img
    from skimage.transform import resize

    out = resize(img, (dh, dw, *img.shape[2:]), order=1, anti_aliasing=True,
                 preserve_range=True)
    return np.clip(out, 0.0, 1.0)


def make_sheet(panels: Sequence[tuple[str, np.ndarray | None]], path, *, title: str = "",
               crops: Sequence[tuple[int, int, int, int]] | None = None,
               notes: Sequence[str | None] | None = None) -> Path:
    """Write a comparison sheet: whole images side by side, then the same crops of each.

    Row 1 shows every panel whole, titled with its label (and its note, in smaller
    text, on a second line). Each further row shows one crop of every panel at 1:1
    pixel scale, or at an integer nearest-neighbour zoom (up to x4) when the crops are
    small, so that no crop pixel is interpolated; only when the sheet would exceed
    about 2600 px in width are the crops scaled down. Each crop is outlined and
    numbered on the first available panel of row 1, and its row is headed with the
    same number and colour, its position and its zoom.

    Parameters
    ----------
    panels : sequence of (str, ndarray or None)
        ``(label, image)`` pairs, left to right. An image is (H, W) gray or
        (H, W, 3) RGB (an alpha channel is dropped), float in [0, 1] or uint8
        (other integer types are scaled by their maximum). Gray images are shown
        in gray. ``None`` means "not available": an empty grey panel with the label
        and "(none)". Images may differ slightly in size (e.g. a method's output
        1 px larger): all are cropped from the top-left to the smallest common
        (H, W).
    path : path-like
        Output PNG. Written atomically: to a temporary file in the same folder,
        then renamed into place (the folder is created when missing).
    title : str, optional
        Figure title, centred above everything.
    crops : sequence of (int, int, int, int), optional
        ``(row0, col0, rows, cols)`` windows in image pixels. Default:
        :func:`choose_crops` of the first panel's image (the first available one
        when that is None). Windows are clipped to the common size.
    notes : sequence of str or None, optional
        One note per panel (e.g. ``"blur 12.3 px, 40 profiles"``), shown under the
        label; ``None`` or ``""`` for none.

    Returns
    -------
    Path
        The written PNG.

    Raises
    ------
    ValueError
        No panels, no panel with an image, ``notes`` of the wrong length, an image
        of a wrong shape, or a crop outside the images.
    """
    from matplotlib import patheffects
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    panels = list(panels)
    if not panels:
        raise ValueError("make_sheet needs at least one panel")
    labels = [str(label) for label, _ in panels]
    images = [None if img is None else np.asarray(img) for _, img in panels]
    for label, img in zip(labels, images, strict=True):
        ok = img is None or img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (1, 2, 3, 4))
        if not ok:
            raise ValueError(f"panel {label!r}: expected an image of shape (H, W) or "
                             f"(H, W, 3), got {img.shape}")
    present = [k for k, img in enumerate(images) if img is not None]
    if not present:
        raise ValueError("make_sheet needs at least one panel with an image")
    if notes is None:
        notes = [None] * len(panels)
    notes = ["" if note is None else str(note) for note in notes]
    if len(notes) != len(panels):
        raise ValueError(f"notes has {len(notes)} entries for {len(panels)} panels")

    h = min(images[k].shape[0] for k in present)
    w = min(images[k].shape[1] for k in present)
    if h < 1 or w < 1:
        raise ValueError(f"the panels' common size {h}x{w} is empty")
    # display versions, cropped to the common size from the top-left
    shown = [None if img is None else _to_unit(img[:h, :w]) for img in images]
    first = present[0]
    if crops is None:
        crops = choose_crops(shown[first])
    crops = _check_crops(crops, h, w)

    # ---- horizontal layout: column width and crop zoom
    ncol = len(panels)
    avail = (_MAX_WIDTH - 2 * _MARGIN - (ncol - 1) * _GAP) / ncol
    if crops:
        crop_w = max(cc for _, _, _, cc in crops)
        if crop_w <= avail:
            zoom = max(1, min(_MAX_ZOOM, _TARGET_COLUMN // crop_w, int(avail // crop_w)))
            col_w = crop_w * zoom
        else:  # too many panels for 1:1: shrink, interpolated
            zoom = avail / crop_w
            col_w = int(avail)
    else:
        zoom = 1
        col_w = int(min(avail, max(160, min(w, 512))))
    col_w = max(1, int(col_w))
    width = 2 * _MARGIN + ncol * col_w + (ncol - 1) * _GAP

    # ---- vertical layout (pixels from the top)
    small = col_w < 150
    label_pt, note_pt = (8.0, 7.0) if small else (10.0, 8.0)
    label_char, note_char = label_pt * 0.75, note_pt * 0.75  # ~ px per character
    label_lines = [_fit_lines(t, col_w, label_char, 2) for t in labels]
    note_lines = [_fit_lines(t, col_w, note_char, 2) for t in notes]
    n_label = max(len(lines) for lines in label_lines)
    n_note = max(len(lines) for lines in note_lines)
    label_scale = label_pt / 10.0
    label_band = math.ceil(n_label * _LABEL_LINE * label_scale
                           + n_note * _NOTE_LINE * label_scale) + 4
    over_h = min(round(col_w * h / w), 2 * col_w)
    over_w = min(col_w, round(over_h * w / h))
    over_h, over_w = max(1, over_h), max(1, over_w)
    crop_rows = [max(1, round(rr * zoom)) for _, _, rr, _ in crops]

    y = _MARGIN + (_TITLE_BAND if title else 0)
    label_top = y
    y += label_band
    over_top = y
    y += over_h
    crop_tops = []
    for rows in crop_rows:
        y += _GAP + _CROP_HEADER
        crop_tops.append(y)
        y += rows
    height = y + _MARGIN

    fig = Figure(figsize=(width / _DPI, height / _DPI), dpi=_DPI, facecolor="white")
    FigureCanvasAgg(fig)

    def axes_at(x0: float, top: float, ax_w: float, ax_h: float):
        return fig.add_axes((x0 / width, 1.0 - (top + ax_h) / height,
                             ax_w / width, ax_h / height))

    def fig_text(x0: float, top: float, text: str, **kw):
        return fig.text(x0 / width, 1.0 - top / height, text, **kw)

    if title:
        fig.suptitle(title, x=0.5, y=1.0 - (_MARGIN + _TITLE_BAND / 2) / height,
                     va="center", fontsize=13, fontweight="bold")

    stroke = [patheffects.withStroke(linewidth=2.5, foreground="black")]
    col_x = [_MARGIN + k * (col_w + _GAP) for k in range(ncol)]
    extent = (-0.5, w - 0.5, h - 0.5, -0.5)  # data coordinates = image pixels
    for k in range(ncol):
        x0 = col_x[k]
        # label (and note) lines, stacked above the overview
        top = label_top
        for line in label_lines[k]:
            fig_text(x0 + col_w / 2, top, line, ha="center", va="top", fontsize=label_pt,
                     fontweight="bold")
            top += _LABEL_LINE * label_scale
        for line in note_lines[k]:
            fig_text(x0 + col_w / 2, top, line, ha="center", va="top", fontsize=note_pt,
                     color="0.25")
            top += _NOTE_LINE * label_scale
        # row 1: the whole image, centred in its column
        ax = axes_at(x0 + (col_w - over_w) // 2, over_top, over_w, over_h)
        if shown[k] is None:
            _none_axes(ax, label_pt)
        else:
            _show(ax, _overview_image(shown[k], (over_h, over_w)), extent=extent,
                  interpolation="nearest")
            if k == first:
                for i, (r0, c0, rr, cc) in enumerate(crops):
                    colour = _CROP_COLOURS[i % len(_CROP_COLOURS)]
                    ax.add_patch(Rectangle((c0 - 0.5, r0 - 0.5), cc, rr, fill=False,
                                           edgecolor=colour, linewidth=1.5))
                    ax.text(c0 + 0.02 * w, r0 + 0.02 * h, str(i + 1), color=colour,
                            ha="left", va="top", fontsize=9, fontweight="bold",
                            path_effects=stroke, clip_on=True)
                ax.set_xlim(extent[0], extent[1])
                ax.set_ylim(extent[2], extent[3])
        # crop rows
        for i, (r0, c0, rr, cc) in enumerate(crops):
            cw = max(1, round(cc * zoom))
            ax = axes_at(x0 + (col_w - cw) // 2, crop_tops[i], cw, crop_rows[i])
            if shown[k] is None:
                _none_axes(ax, label_pt)
                continue
            piece = shown[k][r0:r0 + rr, c0:c0 + cc]
            interp = "nearest" if zoom >= 1 else "antialiased"
            _show(ax, piece, extent=(c0 - 0.5, c0 + cc - 0.5, r0 + rr - 0.5, r0 - 0.5),
                  interpolation=interp)

    # crop row headers: a numbered colour tag, position and zoom
    for i, (r0, c0, rr, cc) in enumerate(crops):
        colour = _CROP_COLOURS[i % len(_CROP_COLOURS)]
        top = crop_tops[i] - _CROP_HEADER / 2
        fig_text(_MARGIN + 2, top, f" {i + 1} ", ha="left", va="center", fontsize=9,
                 fontweight="bold", color="black",
                 bbox={"facecolor": colour, "edgecolor": "none", "pad": 1.5})
        scale = f"x{zoom:g}" if zoom >= 1 else f"x{zoom:.2f} (reduced)"
        fig_text(_MARGIN + 28, top, f"crop {i + 1}: rows {r0}–{r0 + rr - 1}, cols "
                 f"{c0}–{c0 + cc - 1} ({rr}x{cc} px), shown {scale}", ha="left",
                 va="center", fontsize=9, color="0.2")

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".tmp.png", dir=path.parent)
    os.close(fd)
    try:
        fig.savefig(tmp, format="png", dpi=_DPI, facecolor="white")
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:  # incl. KeyboardInterrupt: leave no temporary file behind
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    return path


# ----------------------------------------------------------------------------- reading


def read_rgb(path) -> np.ndarray:
    """Read an image file as float32 RGB in [0, 1].

    Parameters
    ----------
    path : path-like
        An image file the engine reads (JPEG, PNG, BMP, TIFF, ...): gray ("L"), gray+alpha,
        palette, RGB or RGBA, 8 or 16 bit. A multi-frame file gives its first frame.
        EXIF orientation is not applied (the same pixels the engine reads).

    Returns
    -------
    ndarray of shape (H, W, 3), float32
        Gray is replicated to the three channels, alpha is dropped, integers are
        scaled by their dtype's maximum (uint8 by 255, uint16 by 65535).
    """
    from .core.io import read_image

    arr = read_image(path)  # one-line errors naming the file
    if arr.ndim == 4:  # an animation (GIF): frames first
        arr = arr[0]
    out = _to_unit(arr).astype(np.float32, copy=False)
    if out.ndim == 2:
        out = np.repeat(out[:, :, None], 3, axis=2)
    return np.ascontiguousarray(out)
