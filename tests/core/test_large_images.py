"""Claims about large photos (issue 14): progress often, Cancel at once, memory bounded.

Timing is never asserted here (the benchmark ``benchmarks/bench_large.py`` measures it);
these tests state the structure that keeps the records close and a stop prompt -- a
record per chunk of tiles, per slab of the w-step, before each block's operator is
built -- that a stop at *any* record returns without further image work, and that the
memory-bounded code paths (chunked spectra, slab-wise w-step, in-place output, slab-wise
quantisation) give the same numbers as doing everything at once.
"""

import numpy as np
import pytest
from test_deconv import run as records_of

from napari_edgecme import Intrinsics
from napari_edgecme.core import deconv, io
from napari_edgecme.core import deconv_solvers as solvers
from napari_edgecme.core.deconv import deconvolve, iter_deconvolve, noise_lambda_f
from napari_edgecme.core.deconv_prior import shrink_hyperlaplacian, shrink_threshold
from napari_edgecme.core.deconv_solvers import LatentDomain, PatchFourier, hyperlaplacian_steps
from napari_edgecme.core.edges import extract_edge_profiles, iter_extract_edge_profiles
from napari_edgecme.core.latent import iter_l0_latent, l0_latent
from napari_edgecme.core.operators import blur
from napari_edgecme.core.progress import Cancelled, StopRequested, drive
from napari_edgecme.core.synth import densify_path, edge_scene, make_case, random_trajectory


@pytest.fixture(scope="module")
def rgb_case():
    """A 150 x 210 RGB photo shaken by a 9 px camera rotation, and its motion."""
    shape = (150, 210)
    cam = Intrinsics.from_image_shape(shape)
    motion = densify_path(random_trajectory("rotation", cam, 9, rng=3), "rotation", cam)
    rng = np.random.default_rng(0)
    sharp = np.clip(np.cumsum(rng.normal(0, 0.05, (*shape, 3)), axis=1) % 1.0, 0, 1)
    blurred = np.clip(blur(sharp.astype(np.float32), motion), 0, 1).astype(np.float32)
    return blurred, motion


@pytest.fixture
def work_counter(monkeypatch):
    """Counts the samples that pass through the solvers' FFTs and the blur operators built:
    the image work, independent of the machine's speed."""
    count = {"fft": 0, "domains": 0}
    real_rfft2, real_irfft2 = solvers.sfft.rfft2, solvers.sfft.irfft2
    real_domain = deconv.LatentDomain

    def rfft2(a, *args, **kwargs):
        count["fft"] += np.size(a)
        return real_rfft2(a, *args, **kwargs)

    def irfft2(a, *args, **kwargs):
        out = real_irfft2(a, *args, **kwargs)
        count["fft"] += out.size
        return out

    def domain(*args, **kwargs):
        count["domains"] += 1
        return real_domain(*args, **kwargs)

    monkeypatch.setattr(solvers.sfft, "rfft2", rfft2)
    monkeypatch.setattr(solvers.sfft, "irfft2", irfft2)
    monkeypatch.setattr(deconv, "LatentDomain", domain)
    return count


# ---------------------------------------------------------------------------------------
# records come per unit of work
# ---------------------------------------------------------------------------------------

def test_tile_spectra_and_the_observation_come_a_chunk_of_tiles_per_record(rgb_case,
                                                                        monkeypatch):
    g, motion = rgb_case[0][..., 0], rgb_case[1]
    domain = LatentDomain(motion, (0, 150, 0, 210), 8, stride=32)
    monkeypatch.setattr(solvers, "_CHUNK_BYTES", 1)  # one row of tiles per chunk
    fourier = PatchFourier(domain, 8, build=False)
    chunks = len(list(fourier._chunks()))
    assert chunks == fourier.counts[0] > 2
    build, _ = records_of(fourier.iter_build())
    assert [r.step for r in build] == list(range(1, chunks + 1))
    assert all(r.total == chunks for r in build)
    observe, _ = records_of(fourier.iter_set_observation(g))
    assert len(observe) == chunks and observe[-1].step == observe[-1].total == fourier.n


def test_the_w_step_yields_a_record_per_slab(rgb_case, monkeypatch):
    g, motion = rgb_case[0][..., 0], rgb_case[1]
    domain = LatentDomain(motion, (0, 150, 0, 210), 8, stride=32)
    common = dict(lam=1500.0, alpha=2 / 3, betas=[1.0, 8.0], inner_iterations=1,
                  solver="fourier", cg_iterations=1, cg_tol=1e-4, border_iterations=2)

    def count(slab):
        monkeypatch.setattr(solvers, "W_STEP_SLAB", slab)
        records, x = records_of(hyperlaplacian_steps(domain, g, fourier=PatchFourier(domain, 8),
                                                     **common))
        return len(records), x

    n_one, x_one = count(10**9)  # one slab per gradient image
    rows = domain.shape[0]
    n_many, x_many = count(domain.shape[1] * 10)  # 10 rows per slab
    slabs = -(-rows // 10)
    # two gradient images per w-step, two w-steps: (slabs - 1) more records per image
    assert n_many - n_one == 2 * 2 * (slabs - 1)
    np.testing.assert_array_equal(x_many, x_one)  # elementwise: the same numbers


@pytest.mark.parametrize("color, parts", [("rgb", 1), ("opponent", 2)])
def test_deconvolve_says_so_before_building_each_blocks_operator(rgb_case, work_counter, color,
                                                                 parts):
    """Each block's operator is built once per part (RGB: for the three channels; the
    opponent basis: for the luminance, then for the two chroma axes)."""
    blurred, motion = rgb_case
    gen = iter_deconvolve(blurred, motion, block_size=96, color=color, chroma="full")
    first = next(gen)
    assert "building the blur operator" in first.message
    assert work_counter == {"fft": 0, "domains": 0}  # nothing built before the first record
    records = [first]
    built = []  # blur operators built when each record came
    for record in gen:
        records.append(record)
        built.append(work_counter["domains"])
    gen.close()
    announcing = [i for i, r in enumerate(records) if "building the blur operator" in r.message]
    n_blocks = len(deconv.BlockPlan(blurred.shape[:2], 96, deconv.psf_extent(motion)))
    assert n_blocks > 1 and len(announcing) == parts * n_blocks
    # each announcement comes before its block's operator is built
    assert [built[i - 1] if i else 0 for i in announcing] == list(range(parts * n_blocks))


# ---------------------------------------------------------------------------------------
# a stop at any record: no more image work
# ---------------------------------------------------------------------------------------

def _stop_at(index, seen):
    def callback(record):
        seen.append(record)
        if len(seen) > index:
            raise StopIteration  # at this record and every later one, as a Cancel
    return callback


def test_a_stop_at_any_record_of_deconvolve_returns_without_more_fft_work(rgb_case,
                                                                          work_counter):
    blurred, motion = rgb_case
    full, _ = records_of(iter_deconvolve(blurred, motion, block_size=96))
    assert len(full) > 50
    for index in sorted({0, 1, 2, 3, len(full) // 3, len(full) // 2, len(full) - 2,
                         *range(5, len(full) - 1, len(full) // 4)}):
        seen = []
        at_stop = {}

        def callback(record, seen=seen, at_stop=at_stop, index=index):
            seen.append(record)
            if len(seen) > index:
                at_stop.setdefault("work", dict(work_counter))
                raise StopIteration

        out = deconvolve(blurred, motion, block_size=96, callback=callback)
        assert work_counter == at_stop["work"], index  # no FFT, no operator after the stop
        assert out.shape == blurred.shape and out.dtype == np.float32
        assert "stopped" in seen[-1].message and len(seen) == index + 2


def test_deblur_stopped_in_the_estimation_builds_no_deconvolution_operator(work_counter):
    from napari_edgecme import deblur

    case = make_case(edge_scene((96, 96), rng=0), "inplane", extent=7, noise=0.01, rng=0)
    full = []
    deblur(case.blurred, "xu", "inplane", 9, rng=0, n_iter=2, callback=full.append)
    # a record after the first MDF update (an estimate exists) and before the last
    index = next(i for i, r in enumerate(full) if r.cost is not None) + 2
    assert full[index].stage == "estimate"
    work_counter["domains"] = 0
    seen = []
    restored, est = deblur(case.blurred, "xu", "inplane", 9, rng=0, n_iter=2,
                           callback=_stop_at(index, seen))
    assert not est.info.converged
    assert seen[index].stage == "estimate" and seen[-1].stage == "deconvolve"
    assert work_counter["domains"] == 0  # the deconvolution stopped at its first record
    np.testing.assert_allclose(restored, np.clip(case.blurred, 0, 1), rtol=0, atol=1e-6)


def test_the_latent_steps_records_within_a_step_stop_it_with_the_last_finished_step(
        rgb_case, monkeypatch):
    g, motion = rgb_case[0][..., 1], rgb_case[1]
    monkeypatch.setattr(solvers, "_CHUNK_BYTES", 1)  # many chunks, many records
    coarse, result = records_of(iter_l0_latent(g, motion, 6e-3))
    fine, fine_result = records_of(iter_l0_latent(g, motion, 6e-3, fine=True))
    np.testing.assert_array_equal(fine_result, result)  # records change nothing
    ends = [r for r in fine if r.iterate is not None]
    assert [r.step for r in ends] == [r.step for r in coarse]  # the same steps end
    assert len(fine) > 3 * len(coarse)
    # set-up records before the first step
    assert fine[0].step == 0 and fine[0].iterate is None
    for index in (0, 5, len(fine) // 2, len(fine) - 3):
        seen = []
        got = drive(iter_l0_latent(g, motion, 6e-3, fine=True), _stop_at(index, seen))
        done = seen[index].step  # steps finished when the stop came
        want = g if done == 0 else l0_latent(g, motion, 6e-3, beta_max=_beta_after(done))
        np.testing.assert_array_equal(got, want)
    assert l0_latent(g, motion, 6e-3).shape == g.shape


def _beta_after(steps: int, lambda_f: float = 6e-3) -> float:
    """A ``beta_max`` at which the splitting runs exactly ``steps`` steps."""
    return 2 * lambda_f * 2.0**steps * 0.99


def test_edge_profiles_come_with_records_and_the_same_profiles():
    case = make_case(edge_scene((160, 200), rng=4), "inplane", extent=9, rng=5)
    records, profiles = records_of(iter_extract_edge_profiles(case.blurred, 12, rng=0))
    plain = extract_edge_profiles(case.blurred, 12, rng=0)
    n_scales = len(profiles.stats["scales"])
    assert n_scales == 2 and len(records) == 2 * n_scales + 1
    assert [r.step for r in records] == list(range(1, 2 * n_scales + 2))
    assert len(profiles) == len(plain) > 10
    np.testing.assert_array_equal(profiles.derivatives, plain.derivatives)
    np.testing.assert_array_equal(profiles.centroids, plain.centroids)


# ---------------------------------------------------------------------------------------
# memory-bounded paths give the same numbers
# ---------------------------------------------------------------------------------------

def test_rgb_is_assembled_in_place_as_three_gray_deconvolutions(rgb_case):
    blurred, motion = rgb_case
    rgb = deconvolve(blurred, motion, block_size=96, color="rgb")
    assert rgb.flags["C_CONTIGUOUS"] and rgb.dtype == np.float32
    assert rgb.min() >= 0 and rgb.max() <= 1
    weight = noise_lambda_f(blurred)  # one prior weight for the photo, from its noise
    for c in range(3):
        np.testing.assert_array_equal(rgb[..., c], deconvolve(blurred[..., c], motion,
                                                              block_size=96, lambda_f=weight))


def test_tile_spectra_do_not_depend_on_the_chunk_size(rgb_case, monkeypatch):
    g, motion = rgb_case[0][..., 2], rgb_case[1]
    domain = LatentDomain(motion, (0, 150, 0, 210), 8, stride=32)
    built = {}
    for name, size in (("one chunk", 2**40), ("row chunks", 1)):
        monkeypatch.setattr(solvers, "_CHUNK_BYTES", size)
        fourier = PatchFourier(domain, 8)
        fourier.set_observation(g)
        built[name] = fourier
    a, b = built["one chunk"], built["row chunks"]
    assert len(list(a._chunks())) == 1 < len(list(b._chunks()))
    for attr in ("khat", "kty", "_kty_masked"):
        np.testing.assert_array_equal(getattr(a, attr), getattr(b, attr))
    everything = slice(0, a.n)
    np.testing.assert_array_equal(a.k2(everything), b.k2(everything))


def test_the_slab_wise_w_step_is_the_whole_image_w_step():
    rng = np.random.default_rng(1)
    v = rng.normal(0, 0.3, (700, 300)).astype(np.float32)
    beta, alpha = 8.0, 2 / 3
    thr = shrink_threshold(beta, alpha)
    whole = shrink_hyperlaplacian(v, beta, alpha, thr)
    slabs = solvers._slabs(v.shape)
    pieces = np.concatenate([shrink_hyperlaplacian(v[s], beta, alpha, thr) for s in slabs])
    assert len(slabs) == 1  # 210 000 pixels: one slab at the default size
    parts = [slice(r, min(r + 64, 700)) for r in range(0, 700, 64)]
    np.testing.assert_array_equal(
        np.concatenate([shrink_hyperlaplacian(v[s], beta, alpha, thr) for s in parts]), whole)
    np.testing.assert_array_equal(pieces, whole)


def test_the_output_is_clipped_in_place():
    rng = np.random.default_rng(2)
    a = rng.normal(0.5, 0.7, (1200, 900, 3)).astype(np.float32)
    want = np.clip(a, 0, 1)
    got = deconv._clipped(a)
    assert got is a
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("depth", [8, 16])
def test_writing_quantises_slab_by_slab_as_at_once(depth, monkeypatch):
    rng = np.random.default_rng(3)
    a = rng.normal(0.5, 0.6, (301, 77, 3)).astype(np.float32)
    a[0, 0, 0], a[5, 3, 1], a[7, 7, 2] = np.nan, np.inf, -np.inf
    want = np.round(np.clip(np.nan_to_num(a.astype(np.float64)), 0, 1) * (2**depth - 1))
    want = want.astype(np.uint16 if depth == 16 else np.uint8)
    monkeypatch.setattr(io, "_QUANTIZE_PIXELS", 1000)  # 4 rows a slab: 76 slabs
    np.testing.assert_array_equal(io._quantized(a, depth), want)
    np.testing.assert_array_equal(io._quantized(a[..., 0] > 0.5, depth),
                                  (a[..., 0] > 0.5).astype(want.dtype) * (2**depth - 1))


def test_a_written_png_holds_the_quantised_image(tmp_path, monkeypatch):
    import imageio.v3 as iio

    monkeypatch.setattr(io, "_QUANTIZE_PIXELS", 500)
    a = np.random.default_rng(4).random((64, 48, 3)).astype(np.float32)
    io.write_image(tmp_path / "out.png", a)
    np.testing.assert_array_equal(iio.imread(tmp_path / "out.png"),
                                  np.round(a.astype(np.float64) * 255).astype(np.uint8))


def test_a_stop_before_any_result_still_raises_cancelled():
    case = make_case(edge_scene((96, 96), rng=0), "inplane", extent=7, noise=0.01, rng=0)
    from napari_edgecme import deblur

    def at_once(record):
        raise StopIteration

    with pytest.raises(Cancelled):
        deblur(case.blurred, "xu", "inplane", 9, rng=0, callback=at_once)


def test_stop_requested_reaches_set_up_records_of_a_block(rgb_case):
    blurred, motion = rgb_case
    gen = iter_deconvolve(blurred, motion, block_size=96)
    while "tile spectra" not in (record := next(gen)).message or "ready" in record.message:
        pass
    last = gen.throw(StopRequested("cancel"))
    assert "stopped" in last.message and last.step == 0
    with pytest.raises(StopIteration) as done:
        next(gen)
    # the input where nothing ran (cross-faded blocks: to float rounding)
    np.testing.assert_allclose(done.value.value, np.clip(blurred, 0, 1), rtol=0, atol=1e-6)


def test_the_image_so_far_is_finished_blocks_and_the_input_elsewhere(rgb_case):
    # previews (the image so far, as a stop returns it) while block k runs: where only one
    # block's window reaches, a finished block shows the final result and a block not yet
    # reached the input -- whichever way the input's share is added in (module notes)
    blurred, motion = rgb_case[0][..., 0], rgb_case[1]
    final = deconvolve(blurred, motion, block_size=96)
    plan = deconv.BlockPlan(blurred.shape, 96, deconv.psf_extent(motion))
    cover = np.zeros(blurred.shape, int)
    for blk in plan.blocks:
        wr0, wr1, wc0, wc1 = blk["window_box"]
        cover[wr0:wr1, wc0:wc1] += 1
    only = []
    for blk in plan.blocks:
        wr0, wr1, wc0, wc1 = blk["window_box"]
        mask = np.zeros(blurred.shape, bool)
        mask[wr0:wr1, wc0:wc1] = True
        only.append(mask & (cover == 1))
    assert len(plan) == 6 and all(m.any() for m in only)
    records, _ = records_of(iter_deconvolve(blurred, motion, block_size=96, preview=True))
    checked = 0
    for record in records:
        if record.preview is None:
            continue
        running = int(record.message.split("block ")[1].split("/")[0]) - 1
        for b, mask in enumerate(only):
            if b < running:
                np.testing.assert_allclose(record.preview[mask], final[mask], atol=1e-6)
            elif b > running:
                np.testing.assert_allclose(record.preview[mask], blurred[mask], atol=1e-6)
        checked += 1
    assert checked == 6 * 6  # six blocks, six half-quadratic steps each
