"""The PSF field as a labelled figure (``edgecme psf``): glyphs enlarged, axes in pixels."""

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from napari_edgecme import CameraMotion, Intrinsics
from napari_edgecme.core.psf_view import (
    BACKGROUND,
    psf_glyphs,
    save_psf_field_figure,
    square_grid,
)


@pytest.fixture(scope="module")
def slide_and_turn():
    """A slide plus a turn about the lens axis: streaks of different directions and lengths."""
    cam = Intrinsics.from_image_shape((300, 400))
    t = np.linspace(0.0, 1.0, 40)
    return CameraMotion.from_trajectory(np.stack([4 * t, 1 * t, 0.03 * t], -1), "inplane", cam)


@pytest.fixture(scope="module")
def figure(slide_and_turn, tmp_path_factory):
    path = tmp_path_factory.mktemp("psf") / "field.png"
    return save_psf_field_figure(slide_and_turn, path, width=1000)


def _read_png(path):
    from matplotlib.image import imread

    return imread(path)  # float in [0, 1], (height, width, 3 or 4)


def test_the_figure_is_a_png_of_the_stated_size(figure):
    png = _read_png(figure.path)
    assert figure.path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # 1000 px wide; 64 px of title, 92 px of axis labels and scale bar around axes of
    # the image's aspect (910 px wide, 300 / 400 of that high)
    assert figure.size == (1000, round(64 + 910 * 300 / 400 + 92))
    assert png.shape[:2] == (figure.size[1], figure.size[0])
    left, top, width, height = figure.axes_box
    assert (left, top, width) == (70, 64, 910)
    assert height / width == pytest.approx(300 / 400, abs=2e-3)


def test_the_title_states_the_motion_the_enlargement_and_the_scale(figure, slide_and_turn):
    extent = slide_and_turn.blur_extent()
    assert f"inplane motion, 40 poses, blur extent {extent:.1f} px" in figure.title
    assert "longest side of the PSFs" in figure.title
    assert f"each PSF drawn {figure.glyphs.enlargement}x enlarged" in figure.title
    assert figure.glyphs.enlargement >= 2
    assert f"gray tile = {figure.glyphs.window} px of blur" in figure.title
    assert 1 <= figure.scale_bar_px <= figure.glyphs.window
    assert figure.glyphs.points.shape == (5 * 7, 2)  # square cells, 5 on the short side


def test_the_drawn_streaks_point_along_the_psfs(figure, principal_axis):
    """Each glyph's principal axis, measured in the PNG, is its PSF's within 10 degrees."""
    png = _read_png(figure.path)
    glyphs = figure.glyphs
    left, top, width, height = figure.axes_box
    canvas_rows, canvas_cols = glyphs.rgba.shape[:2]
    sx, sy = width / canvas_cols, height / canvas_rows  # PNG px per canvas px
    assert sx == pytest.approx(1, abs=0.01) and sy == pytest.approx(1, abs=0.01)
    checked = 0
    for (r0, c0, side), psf in zip(glyphs.boxes, glyphs.psfs, strict=True):
        x0, x1 = round(left + c0 * sx) + 2, round(left + (c0 + side) * sx) - 2
        y0, y1 = round(top + r0 * sy) + 2, round(top + (r0 + side) * sy) - 2
        tile = png[y0:y1, x0:x1, :3].astype(float)
        # the tile is neutral gray (R = B); the glyph is yellow (R > B)
        drawn = np.clip(tile[..., 0] - tile[..., 2], 0, None)
        gray = tile[0, 0]
        assert gray[0] == pytest.approx(gray[2], abs=0.02) and gray[0] < 0.5
        true_angle, elongation = principal_axis(psf)
        if elongation < 3:  # a round blob has no direction to compare
            continue
        angle, drawn_elongation = principal_axis(drawn)
        diff = abs((angle - true_angle + 90) % 180 - 90)
        assert diff < 10, (r0, c0, angle, true_angle)
        assert drawn_elongation > 2
        checked += 1
    assert checked >= 10


def test_the_glyph_canvas_can_be_finer_than_the_image_for_a_figure(slide_and_turn):
    overlay = psf_glyphs(slide_and_turn, (5, 7))
    assert overlay.canvas_scale == 1 and overlay.rgba.shape == (300, 400, 4)
    fine = psf_glyphs(slide_and_turn, (5, 7), max_side=800, upscale=True)
    assert fine.canvas_scale == 2 and fine.rgba.shape == (600, 800, 4)
    assert fine.enlargement == overlay.enlargement and fine.window == overlay.window
    assert fine.boxes[0][2] == pytest.approx(2 * overlay.boxes[0][2], abs=1)
    r0, c0, _ = fine.boxes[0]
    np.testing.assert_allclose(fine.rgba[r0, c0, :3], BACKGROUND, atol=1e-6)


def test_square_grid():
    assert square_grid((100, 100)) == (5, 5)
    assert square_grid((300, 400)) == (5, 7)
    assert square_grid((400, 300), 3) == (4, 3)


@pytest.mark.parametrize("motion", ["identity", "tall"])
def test_a_delta_and_a_tall_image_draw_too(motion, tmp_path):
    if motion == "identity":
        m = CameraMotion.identity("rotation", Intrinsics.from_image_shape((64, 48)))
    else:
        cam = Intrinsics.from_image_shape((1200, 300))
        m = CameraMotion.from_trajectory([[0, 0], [6, 3]], "translation", cam)
    fig = save_psf_field_figure(m, tmp_path / "f.png", grid=(3, 3), width=600)
    png = _read_png(fig.path)
    assert png.shape[:2] == (fig.size[1], fig.size[0]) and fig.size[0] == 600
    assert fig.size[1] <= 1.6 * 600
    if motion == "identity":
        assert "blur extent 0.0 px" in fig.title
    else:
        assert "blur extent 6.0 px" in fig.title and "2 poses" in fig.title


def test_without_matplotlib_the_figure_raises_a_clear_import_error(slide_and_turn, tmp_path,
                                                                  monkeypatch):
    for name in ("matplotlib", "matplotlib.figure", "matplotlib.backends",
                 "matplotlib.backends.backend_agg", "matplotlib.lines"):
        monkeypatch.setitem(sys.modules, name, None)  # "import x" raises ImportError
    with pytest.raises(ImportError, match=r"needs matplotlib.*psf_field"):
        save_psf_field_figure(slide_and_turn, tmp_path / "f.png")
    assert not (tmp_path / "f.png").exists()
    # the raw field needs no plot library
    field = slide_and_turn.psf_field((3, 3))
    assert field.shape == (300, 400) and field.max() == pytest.approx(1)


def test_the_figure_never_imports_qt_or_napari(tmp_path):
    code = textwrap.dedent(f"""
        import sys
        from napari_edgecme import CameraMotion, Intrinsics
        from napari_edgecme.core.psf_view import save_psf_field_figure
        cam = Intrinsics.from_image_shape((60, 80))
        m = CameraMotion.from_trajectory([[0, 0], [3, 1]], "translation", cam)
        save_psf_field_figure(m, {str(tmp_path / "f.png")!r}, grid=(2, 2))
        bad = sorted(n for n in sys.modules if n == "matplotlib.pyplot" or n.split(".")[0]
                     in ("PyQt5", "PyQt6", "PySide2", "PySide6", "qtpy", "napari", "vispy"))
        print("BAD", bad)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    assert "BAD []" in out
    assert (tmp_path / "f.png").stat().st_size > 1000
