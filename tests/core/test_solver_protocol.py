"""Claims about the one solver protocol (core/progress.py): every iterative solver is a
generator that yields only Progress records, puts its estimate on the record that ends an
iteration, and stops on request with its last finished iterate."""

import numpy as np
import pytest

from napari_edgecme.core.deconv_solvers import (
    LatentDomain,
    PatchFourier,
    conjugate_gradient,
    hyperlaplacian_steps,
    richardson_lucy_steps,
    wiener,
)
from napari_edgecme.core.lasso import QuadraticTerm, iter_nonneg_lasso, nonneg_lasso
from napari_edgecme.core.latent import iter_l0_latent, l0_latent
from napari_edgecme.core.linop import MatrixOperator
from napari_edgecme.core.progress import Progress, StopRequested, drive, relay, stop
from napari_edgecme.core.synth import make_case, sample_image


@pytest.fixture(scope="module")
def block():
    case = make_case(sample_image("camera", 64), model="inplane", extent=7, noise=0.01, rng=3)
    g = case.blurred.astype(np.float32)
    domain = LatentDomain(case.motion, (0, 64, 0, 64), pad=6, stride=32, dtype=np.float32)
    return case, g, domain


def _spd(n=25, seed=0):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((n, n))
    return a @ a.T + n * np.eye(n), rng.standard_normal(n)


def _lasso_term(seed=0):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((50, 20))
    y = A @ np.abs(rng.standard_normal(20))
    return QuadraticTerm.least_squares(MatrixOperator(A), y)


def solvers(block):
    """name -> a function making a fresh solver generator."""
    case, g, domain = block
    betas = [1.0, 2.0 * np.sqrt(2.0), 8.0]
    common = dict(lam=1500.0, alpha=2 / 3, betas=betas, inner_iterations=1, cg_iterations=4,
                  cg_tol=1e-6, border_iterations=4)
    a, b = _spd()
    return {
        "hyperlaplacian-fourier": lambda: hyperlaplacian_steps(
            domain, g, solver="fourier", fourier=PatchFourier(domain, 8), **common),
        "hyperlaplacian-cg": lambda: hyperlaplacian_steps(
            domain, g, solver="cg", fourier=None, **common),
        "rl": lambda: richardson_lucy_steps(domain, g, iterations=4),
        "wiener": lambda: wiener(domain, g, nsr=0.01, fourier=PatchFourier(domain, 8),
                                 border_iterations=4),
        "conjugate-gradient": lambda: conjugate_gradient(MatrixOperator(a), b, np.zeros(25), 6,
                                                         0.0),
        "l0-latent": lambda: iter_l0_latent(g, case.motion, 6e-3),
        "lasso": lambda: iter_nonneg_lasso(_lasso_term(), 0.1, np.zeros(20), max_iter=30,
                                           tol=0.0),
    }


NAMES = ["hyperlaplacian-fourier", "hyperlaplacian-cg", "rl", "wiener", "conjugate-gradient",
         "l0-latent", "lasso"]


def run_to_end(gen):
    records = []
    while True:
        try:
            record = next(gen)
        except StopIteration as done:
            return records, done.value
        previous = records[-1][0].step if records else 0
        ends = record.step > previous
        # keep a copy of the estimate the record carries (CG updates x in place)
        records.append((record, ends, None if record.iterate is None else record.iterate.copy()))


def estimate_of(result):
    """The array a solver returns (the lasso returns a LassoResult, the latent a crop)."""
    return getattr(result, "x", result)


@pytest.mark.parametrize("name", NAMES)
def test_a_solver_yields_only_progress_records_in_order(block, name):
    records, result = run_to_end(solvers(block)[name]())
    assert records and all(isinstance(r, Progress) for r, _, _ in records)
    steps = [r.step for r, _, _ in records]
    assert steps == sorted(steps) and all(0 <= r.step <= r.total for r, _, _ in records)
    assert records[-1][0].step == records[-1][0].total  # ran every iteration
    assert all(r.message for r, _, _ in records)
    # the record that ends an iteration carries the estimate; the last one is the result
    assert all(iterate is not None for _, ends, iterate in records if ends)
    last = records[-1][2]
    if name == "l0-latent":  # the solver works on the padded domain and returns the frame
        pad = (last.shape[0] - result.shape[0]) // 2
        last = last[pad:-pad, pad:-pad]
    np.testing.assert_array_equal(last, estimate_of(result))


@pytest.mark.parametrize("name", NAMES)
def test_a_callback_stops_any_solver_with_its_last_finished_iterate(block, name):
    seen = []

    def stop_after_two(record):
        if record.iterate is not None:
            seen.append(record.iterate.copy())
        if record.step >= 2:
            raise StopIteration

    result = drive(solvers(block)[name](), stop_after_two)
    _, full = run_to_end(solvers(block)[name]())
    got = estimate_of(result)
    want = seen[-1]
    if name == "l0-latent":
        pad = (want.shape[0] - got.shape[0]) // 2
        want = want[pad:-pad, pad:-pad]
    if name == "wiener":  # one iteration only: stopping after it is finishing
        np.testing.assert_array_equal(got, estimate_of(full))
        return
    assert len(seen) == 2
    np.testing.assert_array_equal(got, want)
    assert not np.array_equal(got, estimate_of(full))  # it did stop early


@pytest.mark.parametrize("name", ["hyperlaplacian-fourier", "rl", "wiener"])
def test_a_solver_stopped_before_its_first_iteration_returns_its_start(block, name):
    _, g, domain = block
    gen = solvers(block)[name]()
    first = next(gen)
    assert first.step == 0 and first.iterate is None
    x = stop(gen)
    start = domain.extend(g)
    if name == "rl":
        start = np.maximum(start, np.float32(1e-3))
    np.testing.assert_array_equal(x, start)


def test_a_stopped_lasso_says_so():
    def stop_at_once(record):
        raise StopIteration

    result = drive(iter_nonneg_lasso(_lasso_term(), 0.1, np.zeros(20), max_iter=30, tol=0.0),
                   stop_at_once)
    assert result.nit == 1 and not result.converged and "stopped" in result.message
    assert isinstance(nonneg_lasso(_lasso_term(), 0.1, np.zeros(20)).message, str)


def test_the_plain_latent_function_takes_a_stopping_callback(block):
    case, g, _ = block
    records = []

    def stop_at_three(record):
        records.append(record)
        if record.step == 3:
            raise StopIteration

    early = l0_latent(g, case.motion, 6e-3, callback=stop_at_three)
    assert [r.step for r in records] == [1, 2, 3] and records[-1].total > 3
    assert early.shape == g.shape and not np.array_equal(early, l0_latent(g, case.motion, 6e-3))


def test_the_image_step_has_no_partial_result_so_a_stop_propagates(block):
    _, g, domain = block
    fourier = PatchFourier(domain, 8)
    fourier.set_observation(g)
    gen = fourier.solve(None, 1.0, 0.01)
    assert isinstance(next(gen), Progress)
    with pytest.raises(StopRequested):
        gen.throw(StopRequested("stop"))


def test_relay_relabels_the_inner_records_and_closes_the_inner_solver():
    a, b = _spd()
    inner = conjugate_gradient(MatrixOperator(a), b, np.zeros(25), 6, 0.0)

    def outer():
        x = yield from relay(inner, lambda r: Progress("outer", 0, 1, "inner: " + r.message))
        return x

    gen = outer()
    record = next(gen)
    assert record.stage == "outer" and record.message.startswith("inner: CG iteration 1")
    gen.close()
    assert inner.gi_frame is None  # closed with the outer one


def test_stop_refuses_a_solver_that_keeps_yielding():
    def stubborn():
        while True:
            try:
                yield Progress("stubborn", 0, 1)
            except StopRequested:
                pass

    gen = stubborn()
    next(gen)
    with pytest.raises(RuntimeError, match="after a stop request"):
        stop(gen)


def test_records_keep_repr_short_and_compare_without_arrays():
    a = Progress("x", 1, 2, iterate=np.zeros(3), preview=np.ones(3))
    b = Progress("x", 1, 2)
    assert a == b and "iterate" not in repr(a)
