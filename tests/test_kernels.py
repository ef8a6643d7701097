"""squkf.kernels, the compiled core: one filter is a block of one, so a fleet filter equals its single one.

Every phase of the step is one numba kernel (:mod:`squkf.kernels`) that computes each filter in its
own lane with the same operations in the same order, whatever the other lanes hold, however many
filters there are, however they are cut into blocks or between threads. So the comparisons here are
for equality, bit for bit. The model functions used are plain arithmetic (no transcendental
functions, whose SIMD and scalar versions in numpy may round differently), so that whatever differs
would be the library's.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import hypothesis.extra.numpy as hnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from models import plain_fx, plain_hx, plain_scenario

import squkf.stacks
from squkf import Fleet, JulierWeights, MerweScaledWeights, SquareRootUKF
from squkf.angles import AngleAdd, AngleMean, AngleResidual
from squkf.kernels import phases, wrappers
from squkf.kernels import threads as kernel_threads
from squkf.linalg import chol_update

ENTRY_KERNELS = [name for name in phases.__all__ if name.endswith("_kernel")]


class _UserResidual(AngleResidual):
    """A user's residual_x (a subclass of squkf's: called in Python, per filter and point)."""


CONFIGS = {
    "merwe": dict(points=MerweScaledWeights(1.0, 2.0, 0.0)),
    "merwe-negative-central-weight": dict(points=MerweScaledWeights(0.3, 0.0, 0.0)),
    "julier-augmented": dict(points=JulierWeights(1.0), scheme="augmented"),
    "merwe-propagated": dict(points=MerweScaledWeights(1.0, 2.0, 0.0), scheme="propagated"),
    # squkf's angle hooks on the measurement: the angle kernel forms the joint kernel's given rows
    "merwe-angle-hooks": dict(
        points=MerweScaledWeights(0.5, 2.0, 0.0), z_mean_fn=AngleMean([1]), residual_z=AngleResidual([1])
    ),
    "julier-augmented-angle-residual": dict(
        points=JulierWeights(1.0), scheme="augmented", residual_z=AngleResidual([1])
    ),
    # squkf's angle hooks on the state: the angle kernel's prior, the downdate kernel's wrapped rows and sum
    "merwe-state-angle-hooks": dict(
        points=MerweScaledWeights(0.5, 2.0, 0.0),
        x_mean_fn=AngleMean([1]),
        residual_x=AngleResidual([1]),
        state_add=AngleAdd([1]),
    ),
    # a user's hook: called in Python, its rows handed to the downdate kernel
    "merwe-python-residual-x": dict(points=MerweScaledWeights(1.0, 2.0, 0.0), residual_x=_UserResidual([1])),
}


def run_fleet(K, config, x0, P0, Q, R, zs, chunk=squkf.stacks.CHUNK):
    fleet = Fleet(K, 4, 2, 0.1, plain_hx, plain_fx, chunk=chunk, **config)
    fleet.x, fleet.P, fleet.Q, fleet.R = x0, P0, Q, R
    out = []
    for z in zs:
        fleet.predict()
        fleet.update(z)
        out.append((fleet.x.copy(), fleet.P.copy(), fleet.log_likelihood.copy()))
    assert not fleet.failed.any()
    return out


@pytest.mark.parametrize("name", list(CONFIGS))
def test_a_fleet_filter_equals_its_single_filter_bit_for_bit(name):
    """70 filters (a block of 64 lanes and a partial one), per-filter R, missing data."""
    config = CONFIGS[name]
    K = 70
    x0, P0, Q, R, zs = plain_scenario(K)
    fleet = run_fleet(K, config, x0, P0, Q, R, zs)
    for k in (0, 1, 3, 63, 64, 69):
        f = SquareRootUKF(4, 2, 0.1, plain_hx, plain_fx, vectorized=True, **config)
        f.x, f.P, f.Q, f.R = x0[k].copy(), P0[k].copy(), Q.copy(), R[k].copy()
        for t, z in enumerate(zs):
            f.predict()
            f.update(None if np.isnan(z[k]).all() else z[k])
            x, P, ll = fleet[t]
            np.testing.assert_array_equal(f.x, x[k], err_msg=f"filter {k}, step {t}")
            np.testing.assert_array_equal(f.P, P[k], err_msg=f"filter {k}, step {t}")
            if not np.isnan(z[k]).all():  # with nothing measured the faces differ on purpose
                assert f.log_likelihood == ll[k], f"filter {k}, step {t}"


@pytest.mark.parametrize(
    "name", ["merwe", "merwe-propagated", "merwe-angle-hooks", "merwe-state-angle-hooks"]
)
def test_results_do_not_depend_on_chunk_block_size_or_thread_count(monkeypatch, name):
    """Chunks of the fleet's step (squkf.stacks), blocks of the isolation, threads: the same bits."""
    K = 300
    x0, P0, Q, R, zs = plain_scenario(K, T=4, seed=1)
    config = CONFIGS[name]
    reference = run_fleet(K, config, x0, P0, Q, R, zs)
    monkeypatch.setattr(kernel_threads, "MIN_FILTERS_PER_THREAD", 7)  # cut small stacks too
    monkeypatch.setattr(kernel_threads, "usable_cores", lambda: 3)  # three threads, not capped on fewer cores
    for block, chunk, threads in ((64, 1024, 1), (37, 50, 2), (300, 7, 2), (5, 300, 3), (16, 1, 2)):
        monkeypatch.setattr(squkf.stacks, "BLOCK", block)
        kernel_threads.set_num_threads(threads)
        try:
            again = run_fleet(K, config, x0, P0, Q, R, zs, chunk=chunk)
        finally:
            kernel_threads.set_num_threads(1)
        say = f"block {block}, chunk {chunk}, {threads} threads"
        for (x, P, ll), (x1, P1, ll1) in zip(reference, again):
            np.testing.assert_array_equal(x, x1, err_msg=say)
            np.testing.assert_array_equal(P, P1, err_msg=say)
            np.testing.assert_array_equal(ll, ll1, err_msg=say)


@settings(max_examples=300, deadline=None)
@given(K=st.integers(1, 20_000), size=st.integers(1, 3000), parts=st.integers(1, 4))
def test_chunks_cover_the_fleet_in_order_and_share_it_evenly_between_threads(K, size, parts):
    cut = squkf.stacks.chunks(K, size, parts)
    assert [c.start for c in cut] == [0] + [c.stop for c in cut[:-1]] and cut[-1].stop == K
    sizes = [c.stop - c.start for c in cut]
    assert min(sizes) >= 1 and max(sizes) <= size
    full = -(-K // size)  # chunks of `size` filters and the rest
    if parts == 1 or full == 1:
        assert sizes == [size] * (full - 1) + [K - size * (full - 1)]
    else:  # a multiple of the threads' count (unless there are fewer filters), sizes within one
        assert len(cut) == min(K, -(-full // parts) * parts)
        assert len(cut) % parts == 0 or len(cut) == K
        assert max(sizes) - min(sizes) <= 1


@pytest.mark.parametrize("bad", [0, -1, 1.5, "2", True, None])
def test_the_thread_count_must_be_a_whole_number_of_at_least_one(bad):
    with pytest.raises(ValueError, match="thread count"):
        kernel_threads.set_num_threads(bad)
    assert kernel_threads.get_num_threads() == 1


def run_every_configuration():
    """Every configuration of :data:`CONFIGS` as a fleet and a filter with its smoother, and the rank-1
    modifications (the smoother's downdates, hooks' negative rows): every kernel of the core runs."""
    x0, P0, Q, R, zs = plain_scenario(5, T=3)
    for config in CONFIGS.values():
        run_fleet(5, config, x0, P0, Q, R, zs)
        f = SquareRootUKF(4, 2, 0.1, plain_hx, plain_fx, vectorized=True, **config)
        f.x, f.P, f.Q, f.R = x0[0], P0[0], Q, R[0]
        means, covariances = f.batch_filter(list(zs[:, 0]))[:2]
        f.rts_smoother(means, covariances)
    L = np.linalg.cholesky(P0)
    for sign in (1.0, -1.0):
        chol_update(L, 0.1 * L[..., 0], sign)
        chol_update(L[0], 0.1 * L[0, :, 0], sign)


def test_every_kernel_has_one_signature():
    """float64, C-contiguous, fixed ranks: each kernel compiles once, whatever the configuration."""
    run_every_configuration()
    used = {name: getattr(phases, name).signatures for name in ENTRY_KERNELS}
    assert all(len(s) >= 1 for s in used.values()), {k: len(v) for k, v in used.items()}
    assert all(len(s) == 1 for s in used.values()), used


def test_every_helper_compiles_once_on_an_empty_cache(tmp_path):
    """The compile time: no helper is compiled twice, for a literal argument or a second lane count.

    Loaded from the cache, the entry kernels bring their helpers' machine code along and the helpers
    themselves never compile; on an empty cache (a fresh process) every one compiles, and once.
    """
    code = (
        f"import json, sys; sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from numba.core.registry import CPUDispatcher\n"
        "import squkf.kernels.phases as p\n"
        "from test_kernels import run_every_configuration\n"
        "run_every_configuration()\n"
        "jitted = {n: f for n, f in vars(p).items() if isinstance(f, CPUDispatcher)}\n"
        "print(json.dumps({n: len(f.signatures) for n, f in jitted.items()}))\n"
    )
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    counts = json.loads(out.stdout.strip().splitlines()[-1])
    assert {n for n, c in counts.items() if c > 1} == set(), counts
    assert all(counts[name] == 1 for name in ENTRY_KERNELS), counts
    assert sum(c == 1 for c in counts.values()) >= 20  # the helpers compiled too: the cache was empty


def test_importing_squkf_compiles_nothing():
    code = (
        "import squkf, squkf.kernels.phases as p\n"
        f"names = {ENTRY_KERNELS!r}\n"
        "print(sum(len(getattr(p, n).signatures) for n in names), len(names))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    compiled, count = map(int, out.split())
    assert count == len(ENTRY_KERNELS) == 9 and compiled == 0


@pytest.mark.parametrize("columns", [phases.LAPACK_MIN_COLUMNS - 1, phases.LAPACK_MIN_COLUMNS, 40])
def test_both_qr_routes_give_the_factor_with_a_non_negative_diagonal(columns):
    """Householder loops below LAPACK_MIN_COLUMNS, LAPACK's dgeqrf and a sign pass from it on."""
    rng = np.random.default_rng(columns)
    rows = rng.normal(size=(5, 2 * columns + 3, columns))
    rows[2, :, 3] = 0.0  # a zero column: a singular factor
    S = wrappers.tria(rows)
    for k in range(5):
        G = rows[k].T @ rows[k]
        np.testing.assert_array_equal(np.triu(S[k], 1), 0.0)
        assert np.all(np.diagonal(S[k]) >= 0.0)
        np.testing.assert_allclose(S[k] @ S[k].T, G, rtol=0, atol=1e-13 * columns * np.abs(G).max())
        if k != 2:  # the factor of a positive definite matrix is unique: numpy's Cholesky agrees
            np.testing.assert_allclose(S[k], np.linalg.cholesky(G), rtol=1e-10, atol=1e-12)
        np.testing.assert_array_equal(S[k], wrappers.tria(rows[k]))


def test_an_error_in_one_chunk_on_a_thread_is_raised_and_changes_no_filter():
    """Chunks on two threads: a model function that raises in one chunk raises, after every chunk ends."""
    K = 8  # four chunks of two, two on each thread
    x0, P0, Q, R, zs = plain_scenario(K, T=2, seed=2)
    fleet = Fleet(K, 4, 2, 0.1, plain_hx, plain_fx, chunk=2, **CONFIGS["merwe"])
    fleet.x, fleet.P, fleet.Q, fleet.R = x0, P0, Q, R
    fleet.predict()
    fleet.update(zs[0])
    x, P = fleet.x.copy(), fleet.P.copy()
    calls, x4 = [], x[4, 0]

    def fx(X, dt):
        calls.append(X.shape[0])
        if X[0, 0, 0] == x4:  # the central point of filter 4: the chunk of filters 4 and 5
            raise ValueError("a broken model")
        return plain_fx(X, dt)

    fleet.fx = fx
    kernel_threads.set_num_threads(2)
    try:
        with pytest.raises(ValueError, match="a broken model"):
            fleet.predict()
    finally:
        kernel_threads.set_num_threads(1)
    assert sorted(calls) == [2, 2, 2, 2]
    np.testing.assert_array_equal(fleet.x, x)
    np.testing.assert_array_equal(fleet.P, P)


@settings(max_examples=60, deadline=None)
@given(
    hnp.arrays(
        np.float64,
        hnp.array_shapes(min_dims=2, max_dims=4, min_side=1, max_side=6),
        elements=st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True),
    )
)
def test_finite_rows_says_what_numpys_isfinite_says(A):
    """The bit test on the exponent: NaN of any sign or payload, +/-inf, subnormals and -0.0 too."""
    expected = np.isfinite(A.reshape(A.shape[0], -1)).all(axis=1)
    np.testing.assert_array_equal(wrappers.finite_rows(A), expected)
    np.testing.assert_array_equal(wrappers.finite_rows(np.asfortranarray(A)), expected)  # a copy: C order


def test_points_without_their_offsets_are_the_same_points():
    """The first set is drawn without its offsets (nothing reads them): the same numbers."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=(7, 4))
    S = np.linalg.cholesky(np.eye(4) + 0.3 * np.ones((4, 4)))[None] * rng.uniform(0.5, 2.0, (7, 1, 1))
    xi = MerweScaledWeights(0.5, 2.0, 0.0).unit_sigma_points(4)
    for gamma in (0.0, float(xi[1, 0])):
        X, dX = wrappers.sigma_points(x, S, xi, gamma)
        X_alone, none = wrappers.sigma_points(x, S, xi, gamma, offsets=False)
        assert none is None
        np.testing.assert_array_equal(X_alone, X)
        np.testing.assert_array_equal(X, x[:, None, :] + dX)
        np.testing.assert_allclose(dX, np.einsum("ij,klj->kil", xi, S), rtol=0, atol=1e-14)
