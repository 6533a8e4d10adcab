"""Claims about robustness (issue 8), through the Python API:

* bad input is refused with one line that names what is wrong (ValueError; an unknown
  keyword is Python's TypeError), for every case of the bad-input matrix
  (``docs/bad-inputs.md`` shows the same cases through the CLI);
* every common dtype is accepted and scaled to [0, 1] as documented;
* float32 in gives float32 out (float64 stays float64);
* the same input, parameters and seed give bit-identical motions, motion files and images;
* closing a running generator stops the work at once, leaves no thread and releases
  its memory; Ctrl-C in the CLI mid-estimation writes nothing;
* normal input raises no warning at all.

Images are 48-96 px and runs use one alternation per scale: the file checks plumbing
and messages, not quality.
"""

from __future__ import annotations

import gc
import json
import threading
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest

from napari_edgecme import (
    CameraMotion,
    Intrinsics,
    deblur,
    deconvolve,
    estimate_motion,
    extract_edge_profiles,
    iter_deconvolve,
    iter_estimate_motion,
    read_image,
)
from napari_edgecme.core import synth
from napari_edgecme.core._validation import as_float_image
from napari_edgecme.core.io import write_image

FAST = {"n_iter": 1}


@pytest.fixture(scope="module")
def case():
    """A 96 px edge scene under a 5 px in-plane shake (enough edge profiles for Xu+Ep)."""
    return synth.make_case(synth.sample_image("edges", 96), "inplane", 5, 0.01, rng=3)


@pytest.fixture(scope="module")
def small():
    """A 48 px photo under a 3 px uniform shake: the fastest useful input."""
    return synth.make_case(synth.sample_image("camera", 48), "translation", 3, 0.01, rng=1)


def refused(fn, match: str, error=ValueError) -> str:
    """Run ``fn``; check it raises ``error`` with ``match`` in one line; return the message."""
    with pytest.raises(error) as info:
        fn()
    message = str(info.value)
    assert match in message, message
    assert "\n" not in message, message
    return message


def with_pixel(image, value) -> np.ndarray:
    out = np.array(image, np.float64)
    out[5, 7] = value
    return out


# --------------------------------------------------------------------------------------
# the bad-input matrix: images
# --------------------------------------------------------------------------------------

BAD_IMAGES = {
    "1x1": (np.zeros((1, 1)), "image must be at least 8x8 pixels; got 1x1"),
    "empty": (np.zeros((0, 0)), "image must be at least 8x8 pixels; got 0x0"),
    "a row of pixels": (np.zeros(64), "image must have shape (rows, cols) or (rows, cols, 3); "
                                      "got shape (64,)"),
    "not an array": ("photo.png", "image must be a numeric array; got dtype <U9"),
    "None": (None, "image must be a numeric array; got dtype object"),
    "complex": (np.zeros((64, 64), complex), "image must be real-valued; got dtype complex128"),
    "NaN pixel": (with_pixel(np.full((64, 64), 0.5), np.nan),
                  "image contains 1 non-finite values (NaN or inf)"),
    "inf pixel": (with_pixel(np.full((64, 64), 0.5), -np.inf),
                  "image contains 1 non-finite values (NaN or inf)"),
    "float not scaled to [0, 1]": (np.full((64, 64), 200.0),
                                   "image must be scaled to [0, 1] for floating-point input; "
                                   "got values in [200, 200] (divide 8-bit data by 255"),
    "gray+alpha": (np.zeros((64, 64, 2), np.uint8),
                   "got shape (64, 64, 2) (gray+alpha: drop the alpha channel, image[..., 0])"),
    "RGBA": (np.zeros((64, 64, 4), np.uint8),
             "got shape (64, 64, 4) (RGBA: drop the alpha channel, image[..., :3])"),
    "one channel": (np.zeros((64, 64, 1)), "(one channel: pass image[..., 0])"),
    "3-D stack": (np.zeros((5, 64, 64), np.uint8),
                  "got shape (5, 64, 64) (a stack or volume: pass one 2-D plane at a time)"),
}


@pytest.mark.parametrize("name", list(BAD_IMAGES))
def test_a_bad_image_is_refused_in_one_line_by_estimation(name):
    image, message = BAD_IMAGES[name]
    refused(lambda: estimate_motion(image, "xu", "translation", max_blur=3, **FAST), message)


@pytest.mark.parametrize("name", [n for n in BAD_IMAGES if n not in ("1x1", "empty")])
def test_a_bad_image_is_refused_in_one_line_by_deconvolution_and_profiles(name, small):
    image, message = BAD_IMAGES[name]
    refused(lambda: deconvolve(image, small.motion, "wiener"), message)
    refused(lambda: extract_edge_profiles(image, 3), message)


def test_images_below_the_smallest_size_name_it_per_function(small):
    # estimation needs 8x8 (its coarsest pyramid level); the others only 2x2
    refused(lambda: deconvolve(np.zeros((1, 1)), small.motion),
            "image must be at least 2x2 pixels; got 1x1")
    refused(lambda: extract_edge_profiles(np.zeros((1, 5)), 3),
            "image must be at least 2x2 pixels; got 1x5")


def test_an_8x8_image_needs_a_max_blur_below_half_its_side():
    image = np.random.default_rng(0).random((8, 8))
    refused(lambda: estimate_motion(image, "xu", "translation"),
            "max_blur must be less than half the smaller image side (4 px); got 15")
    # with a max_blur that fits it runs, and says why it had no edge profiles
    with pytest.warns(UserWarning, match=r"image 8x8 is too small for max_blur=3"):
        est = estimate_motion(image, "xu+ep", "translation", max_blur=3, **FAST)
    assert est.info.method == "xu" and est.motion.image_shape == (8, 8)


def test_an_image_smaller_than_the_blur_is_refused_by_estimation(small):
    refused(lambda: estimate_motion(small.blurred, "xu", "translation", max_blur=30),
            "max_blur must be less than half the smaller image side (24 px); got 30")


def test_an_image_smaller_than_its_motion_blur_still_deconvolves_to_finite_values():
    # documented behaviour: the latent domain grows by the PSF half-width on each side
    motion = CameraMotion.from_trajectory([[0, 0], [20, 0]], "translation",
                                          Intrinsics.from_image_shape((8, 8)))
    for method in ("hyperlaplacian", "rl", "wiener"):
        out = deconvolve(np.full((8, 8), 0.5, np.float32), motion, method)
        assert out.shape == (8, 8) and out.dtype == np.float32 and np.all(np.isfinite(out))


def test_a_constant_image_has_no_edges_each_method_says_so():
    flat = np.full((64, 64), 0.4, np.float32)
    reason = "image has no contrast (nearly constant)"
    profiles = extract_edge_profiles(flat, 5)
    assert len(profiles) == 0 and profiles.reason == reason
    refused(lambda: estimate_motion(flat, "ep", "translation", max_blur=5, **FAST),
            f"EpAlone needs at least 12 usable edge profiles; found 0 ({reason})")
    with pytest.warns(UserWarning, match=r"only 0 usable edge profiles .*falling back to "
                                         r"method 'xu'"):
        est = estimate_motion(flat, "xu+ep", "translation", max_blur=5, **FAST)
    assert est.info.method == "xu" and "fell back" in est.info.message
    with pytest.warns(UserWarning, match="the image is constant"):
        estimate_motion(flat, "xu", "translation", max_blur=5, **FAST)
    restored = deconvolve(flat, est.motion, "wiener")
    assert np.all(np.isfinite(restored))


@pytest.mark.parametrize("max_blur", [1, 1.5, 2, 3])
def test_edge_profiles_with_a_blur_of_a_few_pixels_do_not_crash(small, max_blur):
    # max_blur <= 3 used to crash in the window analysis (a numpy broadcast error),
    # and estimation on a downscaled copy reaches such blurs for large photos
    profiles = extract_edge_profiles(small.blurred, max_blur)
    assert len(profiles) >= 0 and profiles.offsets[-1] >= 8


def test_a_photo_estimated_on_a_copy_with_a_blur_under_3_px_runs(case):
    # the working copy's blur is max_blur * max_side / side = 7 * 40 / 96 < 3 px: its
    # edge profiles are looked for (and here too few are found)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        est = estimate_motion(case.blurred, "xu+ep", "inplane", max_blur=7, max_side=40,
                              rng=0, **FAST)
    assert est.motion.image_shape == (96, 96)
    assert all("usable edge profiles" in str(w.message) for w in caught)


# --------------------------------------------------------------------------------------
# the bad-input matrix: parameters and names
# --------------------------------------------------------------------------------------

BAD_ESTIMATION = [
    ({"max_blur": 1e6}, "max_blur must be less than half the smaller image side (24 px); "
                        "got 1e+06"),
    ({"max_blur": -4}, "max_blur must be a finite number > 0; got -4"),
    ({"max_blur": 0}, "max_blur must be a finite number > 0; got 0"),
    ({"max_blur": float("nan")}, "max_blur must be a finite number > 0; got nan"),
    ({"max_blur": float("inf")}, "max_blur must be a finite number > 0; got inf"),
    ({"max_blur": 0.5}, "max_blur must be at least 1 pixel; got 0.5"),
    ({"max_blur": "5"}, "max_blur must be a positive number; got '5'"),
    ({"max_blur": True}, "max_blur must be a positive number; got True"),
    ({"lambda_w": -1}, "lambda_w must be a finite number >= 0; got -1"),
    ({"refine": "yes"}, "refine must be True or False; got 'yes'"),
    ({"lambda_ip": -0.5}, "lambda_ip must be a finite number >= 0; got -0.5"),
    ({"lambda_f": 0}, "lambda_f must be a finite number > 0; got 0"),
    ({"lambda_f": -1e-3}, "lambda_f must be a finite number > 0; got -0.001"),
    ({"n_iter": 0}, "n_iter must be a finite integer > 0; got 0"),
    ({"n_iter": -2}, "n_iter must be a finite integer > 0; got -2"),
    ({"n_iter": 2.5}, "n_iter must be a positive integer; got 2.5"),
    ({"max_side": 0}, "max_side must be a finite integer > 0; got 0"),
    ({"focal_px": 0}, "focal_px must be a finite number > 0; got 0"),
    ({"focal_px": -800.0}, "focal_px must be a finite number > 0; got -800.0"),
    ({"method": "fergus"}, "method must be one of 'ep', 'xu', 'xu+ep'; got 'fergus'"),
    ({"method": "Xu"}, "method must be one of 'ep', 'xu', 'xu+ep'; got 'Xu'"),
    ({"model": "affine"}, "model must be one of 'translation', 'inplane', 'rotation'; "
                          "got 'affine'"),
    ({"model": None}, "model must be one of 'translation', 'inplane', 'rotation'; got None"),
]


@pytest.mark.parametrize("change, message", BAD_ESTIMATION,
                         ids=[next(iter(c)) + "=" + repr(next(iter(c.values())))
                              for c, _ in BAD_ESTIMATION])
def test_a_bad_estimation_parameter_is_refused_before_any_work(small, change, message):
    args = {"method": "xu", "model": "translation", "max_blur": 3, **FAST, **change}
    refused(lambda: estimate_motion(small.blurred, **args), message)
    # the generator refuses at its first step, before any progress record
    gen = iter_estimate_motion(small.blurred, **args)
    refused(lambda: next(gen), message)


def test_zero_l1_and_edge_profile_weights_are_valid(small):
    est = estimate_motion(small.blurred, "xu", "translation", max_blur=3, lambda_w=0,
                          lambda_ip=0, **FAST)
    assert est.motion.n_poses >= 1 and np.isclose(est.motion.weights.sum(), 1)


def test_an_unknown_parameter_name_is_a_one_line_type_error(small):
    refused(lambda: estimate_motion(small.blurred, "xu", "translation", max_blur=3,
                                    lamda_w=1e-3),
            "got an unexpected keyword argument 'lamda_w'", TypeError)
    refused(lambda: deconvolve(small.blurred, small.motion, lamda=100),
            "got an unexpected keyword argument 'lamda'", TypeError)


@pytest.mark.parametrize("method, params, message", [
    ("hyperlaplacian", {"lam": 0}, "lam must be a finite number > 0; got 0"),
    ("hyperlaplacian", {"lam": -5.0}, "lam must be a finite number > 0; got -5.0"),
    ("rl", {"iterations": 0}, "iterations must be a finite integer > 0; got 0"),
    ("rl", {"iterations": -1}, "iterations must be a finite integer > 0; got -1"),
    ("wiener", {"nsr": 0}, "nsr must be a finite number > 0; got 0"),
    ("lucy", {}, "method must be one of 'hyperlaplacian', 'rl', 'wiener'; got 'lucy'"),
])
def test_a_bad_deconvolution_parameter_is_refused(small, method, params, message):
    refused(lambda: deconvolve(small.blurred, small.motion, method, **params), message)


# --------------------------------------------------------------------------------------
# the bad-input matrix: files
# --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def files(tmp_path_factory, small):
    folder = tmp_path_factory.mktemp("bad-files")
    write_image(folder / "good.png", small.blurred)
    (folder / "text.png").write_text("not an image\n")
    (folder / "empty.png").write_bytes(b"")
    data = (folder / "good.png").read_bytes()
    (folder / "truncated.png").write_bytes(data[: len(data) // 2])
    small.motion.save(folder / "motion.json")
    return folder


@pytest.mark.parametrize("name, message", [
    ("text.png", "text.png: not an image file in a format that can be read"),
    ("empty.png", "empty.png: the file is empty (0 bytes)"),
    ("truncated.png", "truncated.png: image file is truncated"),
    ("missing.png", "image file not found: "),
    (".", "expected an image file, got a directory: "),
])
def test_an_unreadable_image_file_is_one_line_naming_it(files, name, message):
    refused(lambda: read_image(files / name), message)


def motion_file(files: Path, small, **change) -> Path:
    path = files / "changed.json"
    path.write_text(json.dumps({**small.motion.to_dict(), **change}))
    return path


@pytest.mark.parametrize("change, message", [
    ({"version": 2}, "unsupported motion file version 2; this program reads version 1"),
    ({"version": True}, "unsupported motion file version True"),
    ({"format": "psf"}, "not an edgecme motion file: 'format' is 'psf'"),
    ({"weights": "all"}, "motion file is malformed: could not convert string to float: 'all'"),
    ({"model": "affine"}, "model must be one of"),
])
def test_a_motion_file_of_another_kind_or_version_is_refused(files, small, change, message):
    refused(lambda: CameraMotion.load(motion_file(files, small, **change)), message)


def test_negative_or_all_zero_weights_are_refused(files, small):
    n = small.motion.n_poses
    refused(lambda: CameraMotion.load(motion_file(files, small, weights=[-1.0] * n)),
            "weights must be >= 0; got minimum -1")
    refused(lambda: CameraMotion.load(motion_file(files, small, weights=[0.0] * n)),
            "weights must not all be zero")


def test_weights_whose_sum_overflows_are_normalised_without_a_warning(files, small):
    n = small.motion.n_poses
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        motion = CameraMotion.load(motion_file(files, small, weights=[1e308] * n))
    np.testing.assert_allclose(motion.weights, 1.0 / n)


@pytest.mark.parametrize("text, message", [
    ('{"format": "edgecme-motion", "version": 1, "poses": [[1e999999', "not valid JSON"),
    ("[" * 100_000 + "]" * 100_000, "not valid JSON"),  # deeper than the recursion limit
    ('{"version": ' + "9" * 5000 + "}", "not valid JSON: Exceeds the limit"),
])
def test_pathological_json_is_one_value_error(files, text, message):
    path = files / "pathological.json"
    path.write_text(text)
    refused(lambda: CameraMotion.load(path), message)


def test_an_integer_too_large_for_a_float_is_a_malformed_file(files, small):
    data = small.motion.to_dict()
    data["intrinsics"]["focal_px"] = "HUGE"
    path = files / "huge.json"
    path.write_text(json.dumps(data).replace('"HUGE"', "1" + "0" * 400))  # valid JSON
    refused(lambda: CameraMotion.load(path), "motion file is malformed")


def test_a_motion_for_another_image_shape(files, small):
    motion = CameraMotion.load(files / "motion.json")
    refused(lambda: deconvolve(np.zeros((48, 96), np.float32), motion),
            "motion does not fit the image: image_shape 48x96 has another aspect ratio than "
            "the motion's 48x48")
    # the same aspect ratio at another size is the same camera: the motion is rescaled
    out = deconvolve(np.zeros((96, 96), np.float32), motion, "wiener")
    assert out.shape == (96, 96)


# --------------------------------------------------------------------------------------
# dtypes
# --------------------------------------------------------------------------------------

DTYPES = ["bool", "uint8", "uint16", "int32", "float16", "float32", "float64"]


def in_dtype(image: np.ndarray, dtype: str) -> np.ndarray:
    if dtype == "bool":
        return image > 0.5
    if dtype in ("uint8", "uint16", "int32"):
        return np.round(image * np.iinfo(dtype).max).astype(dtype)
    return image.astype(dtype)


@pytest.mark.parametrize("dtype", DTYPES)
def test_every_common_dtype_is_scaled_to_the_unit_range(small, dtype):
    image = in_dtype(small.blurred, dtype)
    out = as_float_image(image)
    assert out.dtype == (np.float64 if dtype == "float64" else np.float32)
    assert out.min() >= 0 and out.max() <= 1
    tol = {"bool": 0.5, "uint8": 0.5 / 255, "float16": 1e-3}.get(dtype, 1e-6)
    np.testing.assert_allclose(out, small.blurred, atol=tol + 1e-7)
    if dtype in ("uint8", "uint16", "int32"):
        np.testing.assert_array_equal(in_dtype(np.ones((2, 2)), dtype).astype(float) /
                                      np.iinfo(dtype).max, as_float_image(
                                          in_dtype(np.ones((2, 2)), dtype)))


def test_negative_values_of_signed_integers_clip_to_black():
    image = np.array([[-5, 0], [2**30, 2**31 - 1]], np.int32)
    np.testing.assert_allclose(as_float_image(image), [[0, 0], [0.5, 1]], atol=1e-7)


@pytest.mark.parametrize("dtype", DTYPES)
def test_every_common_dtype_runs_estimation_and_deconvolution(small, dtype):
    image = in_dtype(small.blurred, dtype)
    if dtype == "bool":  # thresholding re-sharpens the blurred edges: there is no blur left
        with pytest.warns(UserWarning, match="no blur found"):
            est = estimate_motion(image, "xu", "translation", max_blur=3, **FAST)
    else:
        est = estimate_motion(image, "xu", "translation", max_blur=3, **FAST)
    out = deconvolve(image, est.motion, "wiener")
    assert out.dtype == (np.float64 if dtype == "float64" else np.float32)
    assert out.shape == image.shape and np.all(np.isfinite(out))


def test_unsupported_dtypes_are_refused_by_name():
    for image, message in ((np.zeros((16, 16), "datetime64[s]"), "got dtype datetime64[s]"),
                           (np.zeros((16, 16), object), "got dtype object"),
                           (np.zeros((16, 16), "U1"), "got dtype <U1")):
        refused(lambda image=image: deconvolve(image, None), "image must be a numeric array; "
                + message)


# --------------------------------------------------------------------------------------
# numerical hygiene: float32 stays float32, no warnings from normal input
# --------------------------------------------------------------------------------------

@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_float32_in_gives_float32_out_and_float64_stays_float64(case, dtype):
    image = case.blurred.astype(dtype)
    restored, est = deblur(image, "xu+ep", "inplane", 7, rng=0, **FAST)
    assert restored.dtype == dtype and est.latent.dtype == dtype
    assert est.info.method == "xu+ep"
    for method in ("hyperlaplacian", "rl", "wiener"):
        params = {"iterations": 3} if method == "rl" else {}
        out = deconvolve(image, est.motion, method, preview=True,
                         callback=lambda r: r.preview is None or r.preview.dtype == dtype,
                         **params)
        assert out.dtype == dtype
    rgb = np.repeat(image[..., None], 3, axis=2)
    assert deconvolve(rgb, est.motion, "wiener").dtype == dtype


def test_previews_are_in_the_input_dtype(small):
    dtypes = set()
    gen = iter_estimate_motion(small.blurred, "xu", "translation", 3, preview=True, n_iter=2)
    for record in gen:
        if record.preview is not None:
            dtypes.add(record.preview.dtype)
    assert dtypes == {np.dtype(np.float32)}


@pytest.mark.parametrize("dtype", ["uint8", "uint16", "float32"])
def test_normal_input_raises_no_warning_anywhere_in_the_pipeline(case, tmp_path, dtype):
    image = in_dtype(case.blurred, dtype)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        profiles = extract_edge_profiles(image, 7, rng=0)
        assert len(profiles) >= 12
        restored, est = deblur(image, "xu+ep", "inplane", 7, rng=0, **FAST)
        for method in ("rl", "wiener"):
            deconvolve(image, est.motion, method, **({"iterations": 3} if method == "rl"
                                                     else {}))
        est.motion.save(tmp_path / "m.json")
        CameraMotion.load(tmp_path / "m.json").psf_field()
        write_image(tmp_path / "r.png", restored)
        read_image(tmp_path / "r.png")
        with np.errstate(all="raise"):  # and no silent floating-point trouble either
            deconvolve(image, est.motion, "wiener")


# --------------------------------------------------------------------------------------
# determinism
# --------------------------------------------------------------------------------------

def test_the_same_seed_gives_bit_identical_motion_files(case, tmp_path):
    runs = []
    for i in range(2):
        est = estimate_motion(case.blurred, "xu+ep", "inplane", 7, rng=11, **FAST)
        est.motion.save(tmp_path / f"{i}.json")
        runs.append(est)
    assert runs[0].info.n_profiles == runs[1].info.n_profiles >= 12
    assert runs[0].motion.to_dict() == runs[1].motion.to_dict()
    assert (tmp_path / "0.json").read_bytes() == (tmp_path / "1.json").read_bytes()
    np.testing.assert_array_equal(runs[0].latent, runs[1].latent)
    # a Generator seeded alike is the same seed
    again = estimate_motion(case.blurred, "xu+ep", "inplane", 7,
                            rng=np.random.default_rng(11), **FAST)
    assert again.motion == runs[0].motion


def test_edge_profiles_are_deterministic_for_a_seed(case):
    a = extract_edge_profiles(case.blurred, 7, rng=4)
    b = extract_edge_profiles(case.blurred, 7, rng=4)
    np.testing.assert_array_equal(a.centroids, b.centroids)
    np.testing.assert_array_equal(a.profiles, b.profiles)


@pytest.mark.parametrize("method, params", [("hyperlaplacian", {}),
                                            ("hyperlaplacian", {"solver": "cg"}),
                                            ("rl", {"iterations": 5}), ("wiener", {})])
def test_deconvolution_is_bit_identical_across_runs(case, method, params):
    a = deconvolve(case.blurred, case.motion, method, **params)
    b = deconvolve(case.blurred, case.motion, method, **params)
    assert a.tobytes() == b.tobytes()


def test_deblurred_image_files_are_bit_identical_across_runs(small, tmp_path):
    for i in range(2):
        restored, _ = deblur(small.blurred, "xu", "translation", 3, rng=0, **FAST)
        write_image(tmp_path / f"{i}.png", restored)
    assert (tmp_path / "0.png").read_bytes() == (tmp_path / "1.png").read_bytes()


# --------------------------------------------------------------------------------------
# cancellation
# --------------------------------------------------------------------------------------

def _close_after(gen, n_records: int) -> float:
    """Take ``n_records`` records from ``gen``, close it; return the seconds close() took."""
    for _ in range(n_records):
        next(gen)
    start = time.perf_counter()
    gen.close()
    return time.perf_counter() - start


@pytest.mark.parametrize("make", [
    lambda img: iter_estimate_motion(img, "xu+ep", "inplane", 7, n_iter=40),
    lambda img: iter_deconvolve(img, synth_motion(img.shape), "rl", iterations=500),
    lambda img: iter_deconvolve(img, synth_motion(img.shape), block_size=64),
], ids=["estimate", "deconvolve-rl", "deconvolve-blocks"])
def test_closing_a_generator_stops_at_once_leaves_no_thread_and_frees_memory(case, make):
    gc.collect()
    threads = threading.active_count()
    tracemalloc.start()
    try:
        baseline = tracemalloc.get_traced_memory()[0]
        gen = make(case.blurred)
        seconds = _close_after(gen, 3)
        with pytest.raises(StopIteration):
            next(gen)  # a closed generator does nothing more
        del gen
        gc.collect()
        left = tracemalloc.get_traced_memory()[0] - baseline
    finally:
        tracemalloc.stop()
    assert seconds < 0.5
    assert threading.active_count() == threads
    assert left < 1 << 20, f"{left / 2**20:.1f} MiB still held after close()"


def synth_motion(shape) -> CameraMotion:
    cam = Intrinsics.from_image_shape(shape[:2])
    return CameraMotion.from_trajectory([[0, 0, 0], [3, 1, 0.01], [6, 2, 0.02]], "inplane",
                                        cam)


def test_ctrl_c_during_estimation_exits_130_and_writes_nothing(case, tmp_path, monkeypatch,
                                                               capsys):
    from napari_edgecme import cli

    write_image(tmp_path / "b.png", case.blurred)
    seen = []

    def interrupt(self, record):  # Ctrl-C arrives while the engine is iterating
        seen.append(record)
        if len(seen) == 3:
            raise KeyboardInterrupt

    monkeypatch.setattr(cli._Console, "progress", interrupt)
    threads = threading.active_count()
    before = sorted(p.name for p in tmp_path.iterdir())
    status = cli.main(["deblur", str(tmp_path / "b.png"), "-o", str(tmp_path / "r.png"),
                       "--save-motion", str(tmp_path / "m.json"), "--max-blur", "7",
                       "--model", "inplane", "--n-iter", "3"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 130 and err == ["edgecme: error: interrupted; no output written"]
    assert len(seen) == 3 and seen[-1].stage == "estimate"
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert threading.active_count() == threads
