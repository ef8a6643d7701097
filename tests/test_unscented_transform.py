"""squkf.unscented_transform: exact on linear maps; the polar-to-Cartesian benchmark."""

import numpy as np
import pytest
from models import polar, polar_rows

from squkf import JulierWeights, MerweScaledWeights, unscented_transform


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
