"""The unscented transform (squkf.ut, .transform, .rows, .covariance): exact on linear maps, row forms.

``squkf.unscented_transform`` is exact on linear maps and meets the polar-to-Cartesian benchmark;
the row forms of the weighted covariance reproduce it (negative rows downdated where no form avoids
them). References are written out here in covariance form; tolerances follow from the conditioning
of each case (stated where it is set).
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from models import polar, polar_rows

from squkf import JulierWeights, MerweScaledWeights, unscented_transform
from squkf.errors import DowndateError
from squkf.rows import weight_rows as weight_plan
from squkf.transform import transform_factor

# == squkf.unscented_transform =====================================================================


def test_exact_on_linear_functions():
    rng = np.random.default_rng(0)
    for n, m in ((1, 1), (3, 2), (4, 6)):
        A = rng.standard_normal((m, n))
        b = rng.standard_normal(m)
        x = rng.standard_normal(n)
        L = np.tril(rng.standard_normal((n, n)))
        L[np.diag_indices(n)] = np.abs(L.diagonal()) + 0.5
        N = np.tril(rng.standard_normal((m, m))) * 0.1
        for fam in (MerweScaledWeights(), MerweScaledWeights(0.2, 2.0, 0.0), JulierWeights(1.0)):
            mean, S, Pxy = unscented_transform(lambda v, A=A, b=b: A @ v + b, x, L, fam, N, return_cross=True)
            P = A @ L @ L.T @ A.T + N @ N.T
            np.testing.assert_allclose(mean, A @ x + b, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(S @ S.T, P, rtol=1e-11, atol=1e-11 * np.abs(P).max())
            np.testing.assert_allclose(Pxy, L @ L.T @ A.T, rtol=1e-11, atol=1e-11)


def test_vectorized_equals_per_point():
    x = np.array([1.0, np.pi / 2])
    S = np.diag([0.02, np.radians(15)])
    a = unscented_transform(polar, x, S)
    b = unscented_transform(polar_rows, x, S, vectorized=True)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def test_polar_to_cartesian_against_monte_carlo():
    """Julier & Uhlmann (1997a): range 1 +/- 0.02, bearing pi/2 +/- 15 degrees.

    The true mean of y = r sin(theta) is E[r] * exp(-sigma^2/2) = 0.9663 (bias 0.034 from the
    first-order answer 1). With N = 400,000 samples the Monte-Carlo mean's standard error is
    sigma_y / sqrt(N) ~ 8e-5 per axis; the UT's mean (exact to 4th order in theta here) must
    sit within 5 standard errors of it, while the linearisation's mean is off by the full
    bias, 0.034: over 50 times that whole sampling band.
    """
    rng = np.random.default_rng(1997)
    sr, st_ = 0.02, np.radians(15)
    x = np.array([1.0, np.pi / 2])
    S = np.diag([sr, st_])
    N = 400_000
    samples = x + rng.standard_normal((N, 2)) * [sr, st_]
    Y = polar_rows(samples)
    mc_mean = Y.mean(axis=0)
    mc_cov = np.cov(Y.T)
    se = np.sqrt(np.diag(mc_cov) / N)
    mean, Sy = unscented_transform(polar, x, S, MerweScaledWeights())  # kappa = 3 - n = 1
    assert np.all(np.abs(mean - mc_mean) < 5 * se)
    lin_err = np.abs(polar(x) - mc_mean)
    assert lin_err[1] > 50 * 5 * se[1]
    assert lin_err[1] > 0.03
    # Covariance: with alpha = 1, beta = 2, kappa = 1 the central weight Wc0 = Wm0 + beta adds
    # beta * (Y0 - mean)(Y0 - mean)^T; here Y0 - mean = (0, 0.034), inflating var(y) by
    # 2 * 0.034^2 = 2.3e-3 relative to the truth (var y ~ 2.2e-3) -- so y's variance is compared
    # against the truth plus that term, and x's (where Y0 - mean is 0) directly.
    P = Sy @ Sy.T
    dy0 = polar(x)[1] - mean[1]
    assert P[0, 0] == pytest.approx(mc_cov[0, 0], rel=0.05)
    assert P[1, 1] == pytest.approx(mc_cov[1, 1] + 2.0 * dy0**2, rel=0.1)
    # with beta = 0 (Julier's weights) the inflation vanishes and var(y) is close to the truth
    _, Sj = unscented_transform(polar, x, S, JulierWeights(1.0))
    assert (Sj @ Sj.T)[1, 1] == pytest.approx(mc_cov[1, 1], rel=0.25)


# == the row forms of the weighted covariance ======================================================

EPS = np.finfo(float).eps


def weighted_cov(X, Wm, Wc):
    mean = Wm @ X
    D = X - mean
    return mean, (D.T * Wc) @ D


def exact_weighted_cov(X, Wm, Wc):
    """Weighted mean and covariance in exact rational arithmetic (the floats as given)."""
    Xf = [[Fraction(float(v)) for v in row] for row in X]
    Wmf, Wcf = [Fraction(float(w)) for w in Wm], [Fraction(float(w)) for w in Wc]
    d = len(Xf[0])
    mean = [sum(w * row[j] for w, row in zip(Wmf, Xf)) for j in range(d)]
    D = [[row[j] - mean[j] for j in range(d)] for row in Xf]
    P = [[sum(w * r[i] * r[j] for w, r in zip(Wcf, D)) for j in range(d)] for i in range(d)]
    return np.array([float(v) for v in mean]), np.array([[float(v) for v in r] for r in P])


def gram_tol(D, w, rho, Wc=None):
    """Rounding bound for sum_k w_k D_k D_k^T when each row is off by up to eps * rho.

    The rows hold a mean (or the central form's offset mu) summed from weights as large
    as 1/alpha^2 times offsets: rho = sum_i |Wm_i| |X_i - X_0| bounds that sum. Then
    each term is off by about eps |w_k| |D_k| (|D_k| + rho); a sum of N terms adds at most
    gamma_N ~ N eps of their sizes (Higham), so 16 N eps leaves a few gamma_N of slack.
    The central form's own weight c = sum(Wc) - 2 is a sum of weights too: off by up to
    N eps sum|Wc|, times mu mu^T (at most rho^2); pass Wc to include that.
    """
    size = np.abs(D).max(axis=1)
    gamma = 16 * D.shape[0] * EPS
    extra = 0.0 if Wc is None else float(np.abs(Wc).sum()) * rho**2
    return gamma * (float(np.abs(w) @ (size * (size + rho))) + extra)


def form_rows(X, Wm, form):
    """The mean and unscaled rows of a row form, written out plainly (the reference)."""
    if form.central:
        E = X[1:] - X[0]
        mu = Wm[1:] @ E
        return X[0] + mu, np.vstack([E, mu])
    mean = X[0] + Wm @ (X - X[0])
    return mean, X - mean


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 6),
    alpha=st.floats(1e-3, 1.0),
    beta=st.floats(0.0, 3.0),
    kappa=st.floats(-0.5, 3.0),
    seed=st.integers(0, 2**16),
)
def test_row_forms_reproduce_the_weighted_covariance(n, alpha, beta, kappa, seed):
    Wm, Wc = MerweScaledWeights(alpha, beta, kappa).weights(n)
    X = np.random.default_rng(seed).standard_normal((2 * n + 1, n))
    mean, P = exact_weighted_cov(X, Wm, Wc)
    plan = weight_plan(Wm, Wc)
    # Merwe: the central form's extra weight is beta - alpha**2, so it needs no downdate then
    assert plan.central_form is not None
    assert plan.central_form.weights[-1] == pytest.approx(beta - alpha**2, abs=1e-12 * np.abs(Wc).sum())
    if beta >= alpha**2:
        assert plan.best.central and plan.best.neg.size == 0 and plan.fast
    rho = float(np.abs(Wm) @ np.abs(X - X[0]).max(axis=1))
    mean_tol = 64 * EPS * (np.abs(X).max() + rho)
    form = plan.best  # the form the filter uses
    best_mean, D = form_rows(X, Wm, form)
    tol = gram_tol(D, form.weights, rho, Wc if form.central else None)
    np.testing.assert_allclose((D.T * form.weights) @ D, P, rtol=0, atol=tol)
    np.testing.assert_allclose(best_mean, mean, rtol=0, atol=mean_tol)
    # the kernel: the same rows, one QR and a downdate per negative row. Negative weights can
    # make the weighted sum indefinite; then no factor exists and the kernel must say so
    lowest = float(np.linalg.eigvalsh(P)[0])
    if lowest > n * tol:
        kernel_mean, S = transform_factor(X, plan)
        np.testing.assert_allclose(kernel_mean, mean, rtol=0, atol=mean_tol)
        np.testing.assert_allclose(S @ S.T, P, rtol=0, atol=4 * tol)
    elif lowest < -n * tol:
        with pytest.raises(DowndateError):
            transform_factor(X, plan)
    D, form = X - best_mean, plan.mean_form  # the mean form (what the hooks use)
    assert not form.central
    if alpha >= 0.1:
        # for tiny alpha the mean form cancels weights of +-1/alpha^2 and is off by ~1e-6
        # (which is why the filter prefers the central form); here the weights are <= ~1e2
        np.testing.assert_allclose((D.T * form.weights) @ D, P, rtol=0, atol=gram_tol(D, form.weights, rho))


def test_negative_rows_are_downdated_when_no_form_avoids_them():
    """beta < alpha**2 with a negative central weight: both forms have a negative row."""
    Wm, Wc = MerweScaledWeights(1.0, 0.0, -1.0).weights(3)
    plan = weight_plan(Wm, Wc)
    assert plan.mean_form.neg.size == 1 and plan.best.neg.size == 1 and not plan.fast
    X = np.random.default_rng(0).standard_normal((7, 3))
    mean, P = weighted_cov(X, Wm, Wc)
    noise = np.eye(3) * 2.0  # keeps the result positive definite
    _, S = transform_factor(X, plan, noise)
    np.testing.assert_allclose(S @ S.T, P + noise @ noise.T, rtol=1e-12, atol=1e-12)
