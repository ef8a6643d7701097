"""Sigma-point families: weights, unit points, and the filterpy adapter."""

import numpy as np
import pytest
from filterpy.kalman import JulierSigmaPoints, MerweScaledSigmaPoints, SimplexSigmaPoints
from hypothesis import given, settings
from hypothesis import strategies as st

from squkf import (
    CubatureWeights,
    FilterpyPoints,
    JulierWeights,
    MerweScaledWeights,
    ParameterError,
    SimplexWeights,
)


def test_merwe_matches_nag_formulas():
    # g13ej section 3.2, L = 3, NAG defaults: kappa = 3 - L = 0, alpha = 1, beta = 2
    fam = MerweScaledWeights()
    Wm, Wc = fam.weights(3)
    lam = 1.0 * (3 + 0) - 3
    assert fam.gamma(3) == pytest.approx(np.sqrt(3 + lam))
    assert Wm[0] == pytest.approx(lam / (3 + lam)) if lam else Wm[0] == 0.0
    np.testing.assert_allclose(Wm[1:], 1 / (2 * (3 + lam)))
    assert Wc[0] == pytest.approx(Wm[0] + 1 - 1 + 2)
    xi = fam.unit_sigma_points(3)
    np.testing.assert_allclose(xi[1:4], np.sqrt(3) * np.eye(3))
    np.testing.assert_allclose(xi[4:], -np.sqrt(3) * np.eye(3))


@pytest.mark.parametrize(
    "ours, theirs",
    [
        (MerweScaledWeights(0.1, 2.0, 0.0), MerweScaledSigmaPoints(5, 0.1, 2.0, 0.0)),
        (JulierWeights(1.0), JulierSigmaPoints(5, 1.0)),
        (SimplexWeights(), SimplexSigmaPoints(5)),
    ],
)
def test_families_equal_filterpy_points(ours, theirs):
    """Same weights, and x + xi @ S.T gives filterpy's sigma points for the Cholesky factor."""
    rng = np.random.default_rng(0)
    A = rng.standard_normal((5, 5))
    P = A @ A.T + np.eye(5)
    x = rng.standard_normal(5)
    S = np.linalg.cholesky(P)
    for fam in (ours, FilterpyPoints(theirs)):
        Wm, Wc = fam.weights(5)
        np.testing.assert_allclose(Wm, theirs.Wm, rtol=1e-14)
        np.testing.assert_allclose(Wc, theirs.Wc, rtol=1e-14)
        pts = x + fam.unit_sigma_points(5) @ S.T
        np.testing.assert_allclose(pts, theirs.sigma_points(x, P), rtol=1e-12, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 10),
    alpha=st.floats(1e-3, 2.0),
    beta=st.floats(0.0, 3.0),
    dkappa=st.floats(0.05, 5.0),
)
def test_merwe_moment_identities(n, alpha, beta, dkappa):
    """Weighted mean 0 and weighted covariance I for every valid parameter set."""
    kappa = -n + dkappa
    fam = MerweScaledWeights(alpha, beta, kappa)
    xi = fam.unit_sigma_points(n)
    Wm, Wc = fam.weights(n)
    scale = np.abs(Wm).sum()
    assert abs(Wm.sum() - 1) <= 64 * np.finfo(float).eps * scale
    np.testing.assert_allclose(Wm @ xi, 0, atol=1e-12)
    np.testing.assert_allclose((xi.T * Wc) @ xi, np.eye(n), atol=64 * np.finfo(float).eps * scale)


@pytest.mark.parametrize("fam", [SimplexWeights(), CubatureWeights(), JulierWeights()])
@pytest.mark.parametrize("n", [1, 2, 3, 7])
def test_other_families_moment_identities(fam, n):
    xi = fam.unit_sigma_points(n)
    Wm, Wc = fam.weights(n)
    assert xi.shape == (fam.num_sigmas(n), n)
    np.testing.assert_allclose(Wm.sum(), 1.0, rtol=1e-14)
    np.testing.assert_allclose(Wm @ xi, 0, atol=1e-13)
    np.testing.assert_allclose((xi.T * Wc) @ xi, np.eye(n), atol=1e-13)


def test_augmented_family_keeps_the_spread():
    # g13ej: kappa' defaults to 3 - 2 mx, so L' + kappa' = L + kappa
    fam = MerweScaledWeights()
    aug = fam.augmented(3)
    assert aug.kappa_for(6) == 3 - 6
    assert aug.gamma(6) == pytest.approx(fam.gamma(3))
    fam2 = MerweScaledWeights(0.5, 2.0, 1.0).augmented(4)
    assert fam2.kappa == -3.0 and fam2.alpha == 0.5


@pytest.mark.parametrize(
    "kwargs, errno",
    [({"alpha": 0.0}, 173), ({"alpha": -1.0}, 173), ({"alpha": float("nan")}, 173)],
)
def test_invalid_parameters(kwargs, errno):
    with pytest.raises(ParameterError, match="alpha") as info:
        MerweScaledWeights(**kwargs)
    assert info.value.errno == errno
    assert isinstance(info.value, ValueError)


def test_kappa_domain_checked_at_use():
    fam = MerweScaledWeights(kappa=-3.0)
    fam.weights(4)  # 4 + (-3) > 0
    with pytest.raises(ParameterError, match="kappa") as info:
        fam.weights(3)  # 3 + (-3) = 0
    assert info.value.errno == 172


def test_families_pickle_and_compare():
    import pickle

    for fam in (MerweScaledWeights(0.3, 1.0, 2.0), JulierWeights(2.0), SimplexWeights(), CubatureWeights()):
        fam.weights(3)
        back = pickle.loads(pickle.dumps(fam))
        assert back == fam
        np.testing.assert_array_equal(back.unit_sigma_points(3), fam.unit_sigma_points(3))
