"""Comparison sheets: crop choice, the sheet PNG, reading photos as RGB (synthetic images only)."""

import imageio.v3 as iio
import numpy as np
import pytest

from napari_edgecme._sheets import choose_crops, make_sheet, read_rgb

pytest.importorskip("matplotlib")


def _overlap(a, b) -> bool:
    (r0, c0, rr, cc), (s0, d0, ss, dd) = a, b
    return r0 < s0 + ss and s0 < r0 + rr and c0 < d0 + dd and d0 < c0 + cc


def _textured(rng, shape):
    """Smooth-ish random texture in [0, 1] (edges everywhere)."""
    from scipy import ndimage

    return np.clip(ndimage.gaussian_filter(rng.random(shape), 1.5) * 4 - 1.5, 0, 1)


# ----------------------------------------------------------------------------- choose_crops


def test_choose_crops_in_bounds_and_disjoint(rng):
    img = _textured(rng, (300, 420))
    crops = choose_crops(img, n=3)
    assert len(crops) == 3
    border = round(0.05 * 300)
    for r0, c0, rr, cc in crops:
        assert rr == cc == 75  # 1/4 of the smaller side, inside [64, 200]
        assert border <= r0 and r0 + rr <= 300 - border
        assert border <= c0 and c0 + cc <= 420 - border
    for i in range(3):
        for j in range(i):
            assert not _overlap(crops[i], crops[j])
    assert all(isinstance(v, int) for crop in crops for v in crop)


def test_choose_crops_finds_the_textured_square(rng):
    img = np.full((400, 400), 0.5)
    img[220:320, 60:160] = _textured(rng, (100, 100))
    r0, c0, rr, cc = choose_crops(img, n=2)[0]
    assert rr == cc == 100
    inter = max(0, min(r0 + rr, 320) - max(r0, 220)) * max(0, min(c0 + cc, 160) - max(c0, 60))
    assert inter >= 0.8 * rr * cc
    # RGB with the same luminance, and a second call: the same answer
    rgb = np.repeat(img[:, :, None], 3, axis=2)
    assert choose_crops(rgb, n=2) == choose_crops(img, n=2)


def test_choose_crops_sizes_and_small_images(rng):
    img = _textured(rng, (1000, 1200))
    assert choose_crops(img, n=1)[0][2] == 200  # clamped to 200
    assert choose_crops(img, n=1, size=50)[0][2] == 50
    small = _textured(rng, (40, 60))
    crops = choose_crops(small, n=2)
    assert crops and all(r0 >= 0 and c0 >= 0 and r0 + rr <= 40 and c0 + cc <= 60
                         for r0, c0, rr, cc in crops)
    assert crops[0][2] <= 40
    # only one 64 px window fits in 100 px minus the border: fewer than asked, no overlap
    crops = choose_crops(np.full((100, 100), 0.3), n=3, size=64)
    assert len(crops) == 1
    assert choose_crops(img, n=0) == []


# ----------------------------------------------------------------------------- make_sheet


def test_make_sheet_writes_png(tmp_path, rng):
    img = _textured(rng, (160, 200, 3))
    path = tmp_path / "case.png"
    out = make_sheet([("blurred", img), ("restored", img ** 0.8)], path, title="case 1",
                     notes=["blur 12.3 px, 40 profiles", None])
    assert out == path and path.is_file()
    png = iio.imread(path)
    assert png.ndim == 3 and png.shape[2] in (3, 4)
    assert 200 <= png.shape[1] <= 2600 and png.shape[0] >= 160
    assert [p.name for p in tmp_path.iterdir()] == ["case.png"]  # no temporary left
    make_sheet([("again", img)], path)  # replaces the file
    assert iio.imread(path).shape != png.shape


def test_make_sheet_none_gray_and_unequal_sizes(tmp_path, rng):
    rgb = _textured(rng, (120, 150, 3))
    larger = np.clip(_textured(rng, (121, 151, 3)), 0, 1).astype(np.float32)  # 1 px larger
    gray = (_textured(rng, (120, 150)) * 255).astype(np.uint8)
    panels = [("blurred", rgb), ("paper", larger), ("gray", gray), ("Xu", None)]
    path = make_sheet(panels, tmp_path / "sheet.png", title="mixed",
                      notes=["a", "b", "c", "failed"], crops=[(10, 20, 64, 64), (50, 70, 40, 60)])
    png = iio.imread(path)[..., :3]
    assert png.ndim == 3
    # the missing panel is a grey block (overview + two crop rows)
    assert np.all(png == 209, axis=2).sum() > 3 * 40 * 40
    # the default crops come from the first panel; a None first panel is tolerated too
    make_sheet([("none", None), ("gray", gray)], tmp_path / "first-none.png")


def test_make_sheet_crops_are_not_resampled(tmp_path, rng):
    img = (rng.random((200, 200)) * 255).astype(np.uint8)
    r0, c0, n = 40, 30, 100
    png = iio.imread(make_sheet([("a", img), ("b", img)], tmp_path / "px.png",
                                crops=[(r0, c0, n, n)]))[..., 0]
    piece = img[r0:r0 + n, c0:c0 + n]
    for zoom in (1, 2, 3, 4):  # an integer nearest-neighbour zoom reproduces every pixel
        tmpl = np.repeat(np.repeat(piece, zoom, 0), zoom, 1)
        side = tmpl.shape[0]
        for y, x in zip(*np.nonzero(png[: png.shape[0] - side + 1, : png.shape[1] - side + 1]
                                    == tmpl[0, 0]), strict=True):
            if np.array_equal(png[y:y + side, x:x + side], tmpl):
                return
    pytest.fail("no crop is shown pixel-exact")


def test_make_sheet_many_panels_bounded_width(tmp_path, rng):
    img = _textured(rng, (160, 160))
    panels = [(f"method {k}", img) for k in range(20)]
    png = iio.imread(make_sheet(panels, tmp_path / "wide.png", crops=[(0, 0, 150, 150)]))
    assert png.shape[1] <= 2600


def test_make_sheet_refuses_bad_input(tmp_path, rng):
    img = _textured(rng, (80, 80))
    with pytest.raises(ValueError, match="at least one panel"):
        make_sheet([], tmp_path / "x.png")
    with pytest.raises(ValueError, match="with an image"):
        make_sheet([("a", None)], tmp_path / "x.png")
    with pytest.raises(ValueError, match="notes"):
        make_sheet([("a", img)], tmp_path / "x.png", notes=["1", "2"])
    with pytest.raises(ValueError, match="outside"):
        make_sheet([("a", img)], tmp_path / "x.png", crops=[(100, 100, 10, 10)])
    assert not list(tmp_path.iterdir())


# ----------------------------------------------------------------------------- read_rgb


def test_read_rgb_gray_and_rgba(tmp_path, rng):
    from PIL import Image

    gray = (rng.random((30, 40)) * 255).astype(np.uint8)
    Image.fromarray(gray).save(tmp_path / "l.png")
    out = read_rgb(tmp_path / "l.png")
    assert out.shape == (30, 40, 3) and out.dtype == np.float32
    np.testing.assert_allclose(out[:, :, 1], gray / 255.0, atol=1e-6)
    assert np.array_equal(out[:, :, 0], out[:, :, 2])

    rgba = (rng.random((20, 25, 4)) * 255).astype(np.uint8)
    Image.fromarray(rgba).save(tmp_path / "rgba.png")
    out = read_rgb(tmp_path / "rgba.png")
    assert out.shape == (20, 25, 3) and out.dtype == np.float32
    np.testing.assert_allclose(out, rgba[:, :, :3] / 255.0, atol=1e-6)
    assert 0.0 <= out.min() and out.max() <= 1.0
