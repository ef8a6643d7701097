"""squkf.linalg: tria, solve_lower and chol_update on stacked arrays equal each slice; all_finite is exact."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from squkf.linalg import all_finite, chol_update, solve_lower, tria

B = 3  # the batch size


# -- linalg, stacked versus per slice ---------------------------------------------------

dims = st.integers(1, 7)
seeds = st.integers(0, 2**32 - 1)


def lower_factor(rng, n, batch=()):
    """Well-conditioned random lower factors with a positive diagonal."""
    L = np.tril(rng.normal(size=batch + (n, n)), -1) * 0.3
    d = rng.uniform(0.5, 2.0, batch + (n,))
    return L + d[..., None] * np.eye(n)


@settings(max_examples=60, deadline=None)
@given(seed=seeds, n=dims, extra=st.integers(-3, 4))
def test_tria_stacked_equals_per_slice(seed, n, extra):
    rng = np.random.default_rng(seed)
    k = max(1, n + extra)
    rows = rng.normal(size=(B, k, n))
    S = tria(rows.copy())
    for i in range(B):
        Si = tria(rows[i].copy(order="F"))  # tria overwrites a single matrix
        np.testing.assert_array_equal(np.triu(S[i], 1), 0.0)
        assert np.all(np.diagonal(S[i]) >= 0)
        # the Gram matrix is what tria promises; for k >= n the factor is unique, so compare it too
        G = rows[i].T @ rows[i]
        np.testing.assert_allclose(S[i] @ S[i].T, G, rtol=0, atol=1e-12 * max(1.0, np.abs(G).max()))
        np.testing.assert_array_equal(S[i], Si)  # one kernel, one lane per matrix


@settings(max_examples=100, deadline=None)
@given(
    seed=seeds,
    n=st.integers(1, 20),
    extra=st.integers(-3, 6),
    scale=st.sampled_from([1e-150, 1e-8, 1.0, 1e8, 1e150]),
    zero_col=st.booleans(),
    fortran=st.booleans(),
)
def test_tria_of_one_matrix_is_a_lower_factor_with_a_non_negative_diagonal(
    seed, n, extra, scale, zero_col, fortran
):
    """The Householder kernel alone gives the diagonal's sign: check it on any rows, any layout.

    Zero columns (a singular noise factor), fewer rows than columns and extreme scales included;
    the Gram matrix is reproduced to the rounding of a QR (``c k eps`` relative to its size).
    """
    rng = np.random.default_rng(seed)
    k = max(1, n + extra)
    rows = rng.normal(size=(k, n)) * scale
    if zero_col:
        rows[:, rng.integers(n)] = 0.0
    rows = np.asfortranarray(rows) if fortran else np.ascontiguousarray(rows)
    G = rows.T @ rows
    S = tria(rows.copy(order="F" if fortran else "C"))
    assert S.shape == (n, n)
    np.testing.assert_array_equal(np.triu(S, 1), 0.0)
    assert np.all(np.diagonal(S) >= 0.0)
    assert np.all(np.isfinite(S))
    np.testing.assert_allclose(S @ S.T, G, rtol=0, atol=1e-13 * max(k, n) * np.abs(G).max())


@settings(max_examples=60, deadline=None)
@given(seed=seeds, n=dims, nrhs=st.sampled_from([None, 1, 3]), trans=st.booleans())
def test_solve_lower_stacked_equals_per_slice(seed, n, nrhs, trans):
    rng = np.random.default_rng(seed)
    S = lower_factor(rng, n, (B,))
    b = rng.normal(size=(B, n) if nrhs is None else (B, n, nrhs))
    X = solve_lower(S, b, trans=trans)
    assert X.shape == b.shape
    for i in range(B):
        Xi = solve_lower(np.asfortranarray(S[i]), b[i].copy(), trans=trans)
        A = S[i].T if trans else S[i]
        # both solve the same system: residuals at rounding, and they agree to cond * eps
        np.testing.assert_allclose(A @ X[i], b[i], rtol=0, atol=1e-12 * max(1.0, np.abs(b[i]).max()))
        np.testing.assert_array_equal(X[i], Xi)


def test_solve_lower_stacked_singular_raises():
    S = lower_factor(np.random.default_rng(0), 3, (B,))
    S[1, 2, 2] = 0.0
    with pytest.raises(np.linalg.LinAlgError):
        solve_lower(S, np.ones((B, 3)))


@settings(max_examples=60, deadline=None)
@given(seed=seeds, n=dims, sign=st.sampled_from([1.0, -1.0]), size=st.floats(0.05, 0.9))
def test_chol_update_stacked_equals_per_slice(seed, n, sign, size):
    rng = np.random.default_rng(seed)
    S = lower_factor(rng, n, (B,))
    u = rng.normal(size=(B, n))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    # v = S u * size has ||S^-1 v|| = size < 1: a downdate that keeps P positive definite
    v = np.einsum("bij,bj->bi", S, u) * size
    S1 = chol_update(S, v, sign)
    for i in range(B):
        S1i = chol_update(S[i], v[i], sign)
        target = S[i] @ S[i].T + sign * np.outer(v[i], v[i])
        scale = np.abs(S[i] @ S[i].T).max() / (1.0 - size**2)
        np.testing.assert_allclose(S1[i] @ S1[i].T, target, rtol=0, atol=1e-12 * scale)
        np.testing.assert_array_equal(np.triu(S1[i], 1), 0.0)
        np.testing.assert_array_equal(S1[i], S1i)


# == all_finite ====================================================================================


def test_all_finite_is_exact_and_quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert all_finite(np.array([1e200, -1e200, 3.0]))  # the dot overflows; the entries are finite
        assert all_finite(np.zeros((0, 3)))
        for bad in (np.nan, np.inf, -np.inf):
            a = np.ones((4, 3))
            a[2, 1] = bad
            assert not all_finite(a)
            assert not all_finite(np.asfortranarray(a))
