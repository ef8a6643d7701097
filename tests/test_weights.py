"""Sigma-point families and their parameters (squkf.weights): weights, unit points, the filterpy adapter.

The weights and unit points of every family (NAG's formulas, filterpy's points, moment
identities); every family's and every filterpy points object's parameters checked when given.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from filterpy.kalman import JulierSigmaPoints, MerweScaledSigmaPoints, SimplexSigmaPoints
from hypothesis import given, settings
from hypothesis import strategies as st
from models import identity_filter

from squkf import (
    CubatureWeights,
    FilterpyPoints,
    JulierWeights,
    MerweScaledWeights,
    ParameterError,
    SimplexWeights,
)

# == weights and unit points =======================================================================


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


# == parameters checked when they are given ========================================================

EPS = np.finfo(float).eps

# values that are not one real number: each must be refused, never parsed or cast
NOT_REAL = [
    None,
    "1.0",
    b"1",
    1 + 1j,
    np.complex128(1.0),  # float() of this drops the imaginary part with only a warning
    np.array([1.0, 2.0]),
    [1.0],
    True,
    np.bool_(False),
    object(),
]


def check_weights(fam, n):
    """The weights sum to 1 and the unit points have mean 0 and covariance I (to rounding)."""
    xi = fam.unit_sigma_points(n)
    Wm, Wc = fam.weights(n)
    assert np.all(np.isfinite(xi)) and np.all(np.isfinite(Wm)) and np.all(np.isfinite(Wc))
    scale = np.abs(Wm).sum() * n
    assert abs(Wm.sum() - 1.0) <= 64 * EPS * scale
    np.testing.assert_allclose(Wm @ xi, 0.0, atol=64 * EPS * scale * np.abs(xi).max())


# -- squkf's own families ----------------------------------------------------------------------


@settings(max_examples=150, deadline=None)
@given(
    n=st.integers(1, 12),
    log_alpha=st.floats(-4, 4),
    beta=st.floats(-1e6, 1e6),
    spread=st.floats(0.05, 100.0),
)
def test_merwe_any_usual_alpha_gives_finite_weights_summing_to_one(n, log_alpha, beta, spread):
    fam = MerweScaledWeights(10.0**log_alpha, beta, spread - n)  # n + kappa = spread > 0
    check_weights(fam, n)


@settings(max_examples=200, deadline=None)
@given(alpha=st.floats(allow_nan=True, allow_infinity=True), n=st.integers(1, 8))
def test_merwe_any_float_alpha_is_accepted_with_finite_weights_or_refused_naming_alpha(alpha, n):
    """Whatever alpha: either a ParameterError naming alpha (173), or weights that are fine."""
    try:
        fam = MerweScaledWeights(alpha, 2.0, 1.0)
        fam.weights(n)
    except ParameterError as exc:
        assert "alpha" in str(exc) and exc.errno == 173
        assert not (np.isfinite(alpha) and 1e-7 <= alpha <= 1e7)  # the refusal had a reason
        return
    assert np.isfinite(alpha) and alpha > 0
    check_weights(fam, n)


@settings(max_examples=100, deadline=None)
@given(alpha=st.one_of(st.floats(max_value=0.0), st.just(float("nan")), st.just(float("inf"))))
def test_merwe_non_positive_or_non_finite_alpha_is_refused_at_construction(alpha):
    with pytest.raises(ParameterError, match="alpha") as info:
        MerweScaledWeights(alpha)
    assert info.value.errno == 173


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf")])
def test_merwe_non_finite_beta_and_kappa_are_refused_at_construction(value):
    with pytest.raises(ParameterError, match="beta"):
        MerweScaledWeights(1.0, value)
    with pytest.raises(ParameterError, match="kappa") as info:
        MerweScaledWeights(1.0, 2.0, value)
    assert info.value.errno == 172
    with pytest.raises(ParameterError, match="kappa") as info:
        JulierWeights(value)
    assert info.value.errno == 172


@pytest.mark.parametrize("value", NOT_REAL, ids=lambda v: type(v).__name__)
@pytest.mark.parametrize("param", ["alpha", "beta", "kappa"])
def test_non_real_parameters_are_refused_naming_them(param, value):
    if param == "kappa" and value is None:
        pytest.skip("kappa=None means 3 - n")
    kwargs = {"alpha": 0.5, "beta": 2.0, "kappa": 0.0, param: value}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a ComplexWarning would mean a silent cast
        with pytest.raises(ParameterError, match=param):
            MerweScaledWeights(**kwargs)
        if param == "kappa":
            with pytest.raises(ParameterError, match="kappa"):
                JulierWeights(value)


def test_zero_dimensional_arrays_and_numpy_scalars_are_real_numbers():
    fam = MerweScaledWeights(np.array(0.5), np.float32(2.0), np.int64(1))
    assert (fam.alpha, fam.beta, fam.kappa) == (0.5, 2.0, 1.0)
    assert all(type(v) is float for v in (fam.alpha, fam.beta, fam.kappa))


@pytest.mark.parametrize(
    "alpha, kappa, n",
    [
        (1e-9, 1.0, 2),  # alpha**2 (L + kappa) = 3e-18: L + lambda rounds to exactly 0
        (1e-160, 0.0, 3),  # alpha**2 underflows
        (1e160, 0.0, 3),  # alpha**2 overflows
        (1e150, 1e100, 2),  # alpha**2 (L + kappa) overflows
    ],
)
def test_merwe_with_l_plus_lambda_zero_or_inf_is_refused_naming_the_parameters(alpha, kappa, n):
    with pytest.raises(ParameterError, match="alpha") as info:
        MerweScaledWeights(alpha, 2.0, kappa).weights(n)
    assert info.value.errno == 173
    with pytest.raises(ParameterError, match="alpha"):
        MerweScaledWeights(alpha, 2.0, kappa).gamma(n)  # what the augmented set uses


def test_l_plus_lambda_zero_reaches_the_filter_at_construction():
    with pytest.raises(ParameterError, match="alpha"):
        identity_filter(MerweScaledWeights(1e-9, 2.0, 1.0))


@pytest.mark.parametrize("fam", [MerweScaledWeights(), JulierWeights(), SimplexWeights(), CubatureWeights()])
@pytest.mark.parametrize("n", [0, -1, 2.0, "2", None, True])
def test_families_refuse_a_dimension_that_is_not_a_positive_integer(fam, n):
    with pytest.raises(ParameterError, match="n"):
        fam.weights(n)
    with pytest.raises(ParameterError, match="n"):
        fam.unit_sigma_points(n)


# -- filterpy's points objects, adapted ------------------------------------------------------


@pytest.mark.parametrize("alpha", [float("nan"), -1.0, 0.0, float("inf")])
def test_filterpy_merwe_with_bad_alpha_is_refused_when_given(alpha):
    pts = MerweScaledSigmaPoints(2, 0.5, 2.0, 1.0)
    pts.alpha = alpha  # filterpy's own constructor divides by zero for some of these
    with pytest.raises(ParameterError, match="alpha") as info:
        FilterpyPoints(pts)
    assert info.value.errno == 173
    with pytest.raises(ParameterError, match="alpha"):
        identity_filter(pts)


def test_filterpy_merwe_nan_alpha_straight_from_its_constructor():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # filterpy's own arithmetic on NaN
        pts = MerweScaledSigmaPoints(2, float("nan"), 2.0, 1.0)
    with pytest.raises(ParameterError, match="alpha=nan"):
        identity_filter(pts)


@pytest.mark.parametrize("param, value", [("beta", float("inf")), ("kappa", float("nan")), ("kappa", 1j)])
def test_filterpy_merwe_with_bad_beta_or_kappa_is_refused(param, value):
    pts = MerweScaledSigmaPoints(2, 0.5, 2.0, 1.0)
    setattr(pts, param, value)
    with pytest.raises(ParameterError, match=param):
        identity_filter(pts)


@pytest.mark.parametrize("kappa", [-2.0, -2.5, -10.0])
def test_filterpy_julier_with_n_plus_kappa_not_positive_is_refused(kappa):
    pts = JulierSigmaPoints(2, 1.0)
    pts.kappa = kappa  # filterpy divides by n + kappa = 0 for -2
    with pytest.raises(ParameterError, match="kappa") as info:
        identity_filter(pts)
    assert info.value.errno == 172


@pytest.mark.parametrize("alpha", [float("nan"), 0.0, -1.0, "1"])
def test_filterpy_simplex_with_bad_alpha_is_refused(alpha):
    with pytest.raises(ParameterError, match="alpha"):
        identity_filter(SimplexSigmaPoints(2, alpha=alpha))


@settings(max_examples=60, deadline=None)
@given(
    alpha=st.floats(allow_nan=True, allow_infinity=True),
    which=st.sampled_from(["merwe", "simplex"]),
)
def test_filterpy_alpha_property(alpha, which):
    """A filterpy object's alpha is accepted only if positive and finite, else refused naming it."""
    pts = MerweScaledSigmaPoints(2, 0.5, 2.0, 1.0) if which == "merwe" else SimplexSigmaPoints(2)
    pts.alpha = alpha
    try:
        FilterpyPoints(pts)
    except ParameterError as exc:
        assert "alpha" in str(exc)
        assert not (np.isfinite(alpha) and 1e-150 < alpha < 1e150)
        return
    assert np.isfinite(alpha) and alpha > 0


@pytest.mark.parametrize(
    "pts", [MerweScaledSigmaPoints(3, 0.5, 2.0, 0.0), JulierSigmaPoints(3, 0.0), SimplexSigmaPoints(3)]
)
def test_filterpy_points_for_another_dimension_give_a_clear_error(pts):
    with pytest.raises(ParameterError, match=r"n=3.*n=2"):
        identity_filter(pts, dim_x=2)


def test_points_fn_setter_refuses_and_keeps_the_old_points():
    ukf = identity_filter(MerweScaledWeights(0.5))
    before = ukf.points_fn
    Wm = ukf.Wm.copy()
    bad = MerweScaledSigmaPoints(2, 0.5, 2.0, 0.0)
    bad.alpha = float("nan")
    for points in (bad, MerweScaledSigmaPoints(3, 0.5, 2.0, 0.0)):
        with pytest.raises(ParameterError):
            ukf.points_fn = points
        assert ukf.points_fn is before
        np.testing.assert_array_equal(ukf.Wm, Wm)
    ukf.predict()  # still usable


@pytest.mark.parametrize("n", [0, -2, 2.5, "2", None])
def test_filterpy_points_with_a_bad_n_are_refused(n):
    pts = MerweScaledSigmaPoints(2, 0.5, 2.0, 0.0)
    pts.n = n
    with pytest.raises(ParameterError, match="n must be a positive integer"):
        FilterpyPoints(pts)


class FakePoints:
    """A points object with filterpy's interface and whatever weights and points it is given."""

    def __init__(self, Wm, Wc=None, points=None, n=2):
        self.n = n
        self.Wm = np.asarray(Wm)
        self.Wc = self.Wm if Wc is None else np.asarray(Wc)
        self._points = points

    def num_sigmas(self):
        return 2 * self.n + 1

    def sigma_points(self, x, P):
        if self._points is not None:
            return self._points
        g = np.sqrt(self.n)
        return np.vstack([x, x + g * np.eye(self.n), x - g * np.eye(self.n)])


@pytest.mark.parametrize(
    "kwargs",
    [
        {"Wm": [np.nan, 0.25, 0.25, 0.25, 0.25]},
        {"Wm": [0.0, 0.25, 0.25, 0.25, 0.25], "Wc": [np.inf, 0.25, 0.25, 0.25, 0.25]},
        {"Wm": np.array([0.0, 0.25, 0.25, 0.25, 0.25]) + 0j},
        {"Wm": [0.0, 0.25, 0.25, 0.25]},  # one weight short
        {"Wm": [0.0, 0.25, 0.25, 0.25, 0.25], "points": np.full((5, 2), np.nan)},
        {"Wm": [0.0, 0.25, 0.25, 0.25, 0.25], "points": np.zeros((5, 2), dtype=complex)},
        {"Wm": [0.0, 0.25, 0.25, 0.25, 0.25], "points": np.zeros((4, 2))},
    ],
)
def test_points_objects_with_bad_weights_or_points_are_refused(kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ParameterError):
            identity_filter(FakePoints(**kwargs))


def test_a_good_fake_points_object_works():
    ukf = identity_filter(FakePoints([0.0, 0.25, 0.25, 0.25, 0.25]))
    np.testing.assert_allclose(ukf.Wm, [0.0, 0.25, 0.25, 0.25, 0.25])
