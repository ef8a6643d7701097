"""Noise entering the model (``fx_noise`` / ``hx_noise``): the augmented square-root UKF.

References, each computed independently of squkf:

- a covariance-form augmented UKF written here (sigma points from
  ``np.linalg.cholesky`` of the augmented covariance, weights from Merwe's
  formulas): equal to 1e-10 relative on nonlinear models (the two forms do the
  same arithmetic in another order; the factor form's QR against a Cholesky
  of a formed covariance loses a few digits at most);
- filterpy's linear ``KalmanFilter`` on linear-Gaussian models (equal to
  rounding: the unscented transform is exact for linear maps);
- the additive filter itself, for a model whose noise is in fact additive
  written with the noise as an argument.
"""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter, MerweScaledSigmaPoints
from models import (
    PEND_DT,
    PEND_QW,
    PEND_RV,
    OddPoints,
    assert_filter_state,
    assert_fleet_state,
    filter_state,
    fleet_state,
    noise_linear_model,
    pendulum_filter,
    pendulum_fx,
    pendulum_hx,
    pendulum_noise_filter,
    pendulum_simulate,
    polar_range_hx,
    polar_turn_fx,
    raising,
    range_noise_filter,
)

from squkf import (
    CubatureWeights,
    Fleet,
    JulierWeights,
    MerweScaledWeights,
    ParameterError,
    Redrawn,
    ShapeError,
    SimplexWeights,
    SquareRootUKF,
)

# the paths here end in documented errors or decisions: no numpy RuntimeWarning may escape squkf
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")


def merwe_weights(L, alpha, beta, kappa):
    lam = alpha**2 * (L + kappa) - L
    Wm = np.full(2 * L + 1, 0.5 / (L + lam))
    Wc = Wm.copy()
    Wm[0] = lam / (L + lam)
    Wc[0] = lam / (L + lam) + 1 - alpha**2 + beta
    return Wm, Wc, math.sqrt(L + lam)


def axis_points(mean, cov, gamma):
    C = np.linalg.cholesky(cov)
    return np.vstack([mean, mean + gamma * C.T, mean - gamma * C.T])


def reference_step(x, P, z, alpha, beta, kappa):
    """One step of a covariance-form augmented UKF: points over [x, w], then over [x_prior, v]."""
    n, dw, dv = 2, PEND_QW.shape[0], PEND_RV.shape[0]
    # squkf's rule: the family at n + d keeps the state's spread, kappa lowered by d
    Wm, Wc, g = merwe_weights(n + dw, alpha, beta, kappa - dw)
    Xa = axis_points(
        np.concatenate([x, np.zeros(dw)]), np.block([[P, np.zeros((n, dw))], [np.zeros((dw, n)), PEND_QW]]), g
    )
    F = pendulum_fx(Xa[:, :n], Xa[:, n:], PEND_DT)
    xp = Wm @ F
    Pp = (F - xp).T @ np.diag(Wc) @ (F - xp)
    Wm, Wc, g = merwe_weights(n + dv, alpha, beta, kappa - dv)
    Xa = axis_points(
        np.concatenate([xp, np.zeros(dv)]),
        np.block([[Pp, np.zeros((n, dv))], [np.zeros((dv, n)), PEND_RV]]),
        g,
    )
    Z = pendulum_hx(Xa[:, :n], Xa[:, n:])
    zp = Wm @ Z
    Pzz = (Z - zp).T @ np.diag(Wc) @ (Z - zp)
    Pxz = (Xa[:, :n] - xp).T @ np.diag(Wc) @ (Z - zp)
    K = np.linalg.solve(Pzz, Pxz.T).T
    return xp + K @ (z - zp), Pp - K @ Pzz @ K.T


@pytest.mark.parametrize("alpha, beta, kappa", [(1.0, 2.0, 0.0), (0.5, 2.0, 1.0), (1.0, 0.0, 1.0)])
def test_equals_a_covariance_form_augmented_ukf(alpha, beta, kappa):
    zs = pendulum_simulate(60, seed=1)
    f = pendulum_filter(MerweScaledWeights(alpha, beta, kappa))
    x, P = f.x.copy(), f.P.copy()
    for z in zs:
        x, P = reference_step(x, P, z, alpha, beta, kappa)
        f.predict()
        f.update(z)
        np.testing.assert_allclose(f.x, x, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(f.P, P, rtol=1e-10, atol=1e-13)


def test_filterpy_points_object_works_as_points():
    """filterpy's points built for dim_x serve as their squkf equivalent at n + d."""
    zs = pendulum_simulate(30, seed=2)
    native = pendulum_filter(MerweScaledWeights(0.5, 2.0, 1.0))
    wrapped = pendulum_filter(MerweScaledSigmaPoints(2, alpha=0.5, beta=2.0, kappa=1.0))
    for z in zs:
        for f in (native, wrapped):
            f.predict()
            f.update(z)
    np.testing.assert_array_equal(wrapped.x, native.x)
    np.testing.assert_array_equal(wrapped.P1_2, native.P1_2)
    # a points object for another dimension, with no squkf equivalent, is a clear error
    with pytest.raises(ParameterError, match="build it with n=4"):
        pendulum_filter(OddPoints())


@pytest.mark.parametrize(
    "points",
    [
        MerweScaledWeights(),
        MerweScaledWeights(alpha=0.1),
        JulierWeights(),
        CubatureWeights(),
        SimplexWeights(),
    ],
    ids=["merwe", "merwe-0.1", "julier", "cubature", "simplex"],
)
@pytest.mark.parametrize("dw, dv", [(1, 3), (2, 2)])
def test_linear_gaussian_equals_the_kalman_filter(points, dw, dv):
    F, G, H, D = noise_linear_model(dw, dv)
    Qn = np.diag([0.5, 0.2][:dw])
    Rn = np.diag([0.3, 0.1, 0.05][:dv])
    f = SquareRootUKF(
        3, 2, PEND_DT, lambda x, v: x @ H.T + v @ D.T, lambda x, w, dt: x @ F.T + w @ G.T, points,
        vectorized=True, fx_noise=dw, hx_noise=dv,
    )  # fmt: skip
    f.Q, f.R = Qn, Rn
    kf = KalmanFilter(3, 2)
    kf.F, kf.H, kf.Q, kf.R = F, H, G @ Qn @ G.T, D @ Rn @ D.T
    kf.P = np.eye(3)
    rng = np.random.default_rng(dw * 10 + dv)
    for _ in range(40):
        z = rng.normal(size=2)
        f.predict()
        f.update(z)
        kf.predict()
        kf.update(z)
        np.testing.assert_allclose(f.x, kf.x.ravel(), rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(f.P, kf.P, rtol=1e-9, atol=1e-11)
        assert f.log_likelihood == pytest.approx(kf.log_likelihood, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize(
    "points", [MerweScaledWeights(alpha=0.5), MerweScaledWeights(1.0, 2.0, 1.0), JulierWeights(1.0)], ids=repr
)
def test_additive_model_in_the_noise_argument_form_equals_the_additive_filter(points):
    """Nonlinear fx: equal because the family keeps its spread at n + d (kappa lowered by d)."""
    Q, R = np.diag([0.01, 0.001, 0.02, 0.003]), np.diag([0.05, 0.002])
    additive = SquareRootUKF(4, 2, 1.0, polar_range_hx, polar_turn_fx, points, vectorized=True)
    noisy = SquareRootUKF(
        4, 2, 1.0, lambda x, v: polar_range_hx(x) + v, lambda x, w, dt: polar_turn_fx(x, dt) + w, points,
        vectorized=True, fx_noise=4, hx_noise=2,
    )  # fmt: skip
    for f in (additive, noisy):
        f.x, f.P, f.Q, f.R = np.array([10.0, 0.3, 1.0, 0.1]), np.diag([1.0, 0.01, 0.1, 0.01]), Q, R
    rng = np.random.default_rng(4)
    for k in range(50):
        z = np.array([10.0 + 0.1 * k, math.sin(0.3 + 0.005 * k)]) + rng.normal(size=2) * [0.2, 0.04]
        for f in (additive, noisy):
            f.predict()
            f.update(z)
        np.testing.assert_allclose(noisy.x, additive.x, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(noisy.P1_2, additive.P1_2, rtol=1e-11, atol=1e-13)
        assert noisy.log_likelihood == pytest.approx(additive.log_likelihood, rel=1e-11)


def test_per_point_calls_equal_vectorised():
    zs = pendulum_simulate(20, seed=5)
    vec = pendulum_filter(MerweScaledWeights(0.5))
    per = SquareRootUKF(
        2, 1, PEND_DT, lambda x, v: pendulum_hx(x, v), lambda x, w, dt: pendulum_fx(x, w, dt),
        MerweScaledWeights(0.5), fx_noise=2, hx_noise=2,
    )  # fmt: skip
    per.x, per.P, per.Q, per.R = vec.x, vec.P, PEND_QW, PEND_RV
    for z in zs:
        for f in (vec, per):
            f.predict()
            f.update(z)
    np.testing.assert_allclose(per.x, vec.x, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(per.P1_2, vec.P1_2, rtol=1e-12, atol=1e-15)


def test_ask_tell_hands_out_the_augmented_points():
    zs = pendulum_simulate(5, seed=6)
    f, g = pendulum_filter(MerweScaledWeights(0.5)), pendulum_filter(MerweScaledWeights(0.5))
    for z in zs:
        f.predict()
        f.update(z)
        Xa = g.ask_predict()
        assert Xa.shape == (2 * (2 + 2) + 1, 4)  # [x_i, w_i]
        np.testing.assert_allclose(
            Xa[:, 2:].T @ np.diag(g.Wc) @ Xa[:, 2:], PEND_QW, rtol=1e-12
        )  # w's covariance
        g.tell_predict(pendulum_fx(Xa[:, :2], Xa[:, 2:], PEND_DT))
        Ya = g.ask_update()
        assert Ya.shape == (9, 4)  # [x_i, v_i]
        g.tell_update(pendulum_hx(Ya[:, :2], Ya[:, 2:]), z)
        np.testing.assert_array_equal(g.x, f.x)
        np.testing.assert_array_equal(g.P1_2, f.P1_2)


def test_fleet_filter_equals_its_single_filter_bit_for_bit():
    K, T = 9, 30
    fleet = Fleet(
        K,
        2,
        1,
        PEND_DT,
        pendulum_hx,
        pendulum_fx,
        MerweScaledWeights(0.5),
        fx_noise=2,
        hx_noise=2,
        gate=0.999,
    )
    fleet.x, fleet.P = np.array([0.5, 0.1]), np.diag([0.04, 0.25])
    fleet.Q = np.stack([PEND_QW * (1 + 0.1 * k) for k in range(K)])  # per-filter noise
    fleet.R = PEND_RV
    zs = np.stack([pendulum_simulate(T, seed=10 + k) for k in range(K)])
    zs[3, 4] = np.nan
    zs[5, 7] = 3.0  # a wild return for the gate
    singles = [fleet[k] for k in range(K)]
    assert singles[0].fx_noise == 2 and singles[0].hx_noise == 2
    result = fleet.batch_filter(zs)
    assert result.rejected[5, 7].all()
    for k, f in enumerate(singles):
        means, factors = f.batch_filter(zs[k], return_factors=True)
        np.testing.assert_array_equal(means, result.means[k])
        np.testing.assert_array_equal(factors, result.P1_2s[k])
    back = Fleet.from_filters([fleet[k] for k in range(K)])
    assert back.fx_noise == 2 and back.hx_noise == 2


def test_fleet_ask_tell_hands_out_the_augmented_points():
    fleet = Fleet(4, 2, 1, PEND_DT, pendulum_hx, pendulum_fx, MerweScaledWeights(0.5), fx_noise=2, hx_noise=2)
    fleet.Q, fleet.R = PEND_QW, PEND_RV
    other = fleet.subset(slice(None))
    z = np.full((4, 1), 0.3)
    fleet.predict()
    fleet.update(z)
    Xa = other.ask_predict()
    assert Xa.shape == (4, 9, 4)
    other.tell_predict(pendulum_fx(Xa[..., :2], Xa[..., 2:], PEND_DT))
    Ya = other.ask_update()
    other.tell_update(pendulum_hx(Ya[..., :2], Ya[..., 2:]), z)
    np.testing.assert_array_equal(other.x, fleet.x)
    with pytest.raises(ParameterError, match="assign fleet.R"):
        other.ask_update()
        other.tell_update(np.zeros((4, 9, 1)), z, R=PEND_RV)


@pytest.mark.parametrize("value", [0, -1, 1.5, True, "2", [2]])
@pytest.mark.parametrize("which", ["fx_noise", "hx_noise"])
def test_bad_noise_dimension_is_a_parameter_error(which, value):
    with pytest.raises(ParameterError, match=which):
        SquareRootUKF(2, 1, PEND_DT, pendulum_hx, pendulum_fx, MerweScaledWeights(), **{which: value})
    with pytest.raises(ParameterError, match=which):
        Fleet(3, 2, 1, PEND_DT, pendulum_hx, pendulum_fx, MerweScaledWeights(), **{which: value})


def test_model_function_that_takes_no_noise_is_refused_at_construction():
    with pytest.raises(ParameterError, match=r"fx\(x, w, dt\)"):
        SquareRootUKF(2, 1, PEND_DT, pendulum_hx, lambda x, dt: x, MerweScaledWeights(), fx_noise=2)
    with pytest.raises(ParameterError, match=r"hx\(x, v\)"):
        Fleet(
            3, 2, 1, PEND_DT, lambda x: x[..., :1], pendulum_fx, MerweScaledWeights(), fx_noise=2, hx_noise=1
        )


def test_noise_of_another_dimension_than_fx_takes_fails_with_fxs_own_error_and_changes_nothing():
    f = pendulum_filter(MerweScaledWeights())
    f.predict()
    f.update(np.array([0.4]))
    bad = SquareRootUKF(
        2, 1, PEND_DT, pendulum_hx, pendulum_fx, MerweScaledWeights(), vectorized=True, fx_noise=1, hx_noise=2
    )
    bad.x, bad.P, bad.R = f.x, f.P, PEND_RV
    snap = filter_state(bad)
    with pytest.raises(IndexError) as info:
        bad.predict()  # pendulum_fx reads w[..., 1]: its own IndexError, as it is
    assert_filter_state(bad, snap)
    if sys.version_info >= (3, 11):
        assert info.value.__notes__ == [
            "squkf: fx was called with noise of dimension fx_noise=1, shape (7, 1)"
        ]


# -- issue 29, 2. an exception from fx or hx taking noise propagates unchanged -----------------------


@pytest.mark.parametrize("error", [ValueError, TypeError, IndexError, KeyError, ZeroDivisionError])
@pytest.mark.parametrize("which", ["fx", "hx"])
@pytest.mark.parametrize("front", ["per point", "vectorised", "fleet"])
def test_the_users_exception_from_a_function_taking_noise_propagates_unchanged(error, which, front):
    exc = error("the user's own")
    fns = {"fx": pendulum_fx, "hx": pendulum_hx, which: raising(exc)}
    if front == "fleet":
        f = Fleet(3, 2, 1, PEND_DT, fns["hx"], fns["fx"], MerweScaledWeights(), fx_noise=2, hx_noise=2)
        state, check = fleet_state, assert_fleet_state
        z = np.full((3, 1), 0.3)
    else:
        f = SquareRootUKF(
            2, 1, PEND_DT, fns["hx"], fns["fx"], MerweScaledWeights(), vectorized=front == "vectorised",
            fx_noise=2, hx_noise=2,
        )  # fmt: skip
        state, check = filter_state, assert_filter_state
        z = np.array([0.3])
    if which == "hx":
        f.predict()
    snap = state(f)
    with pytest.raises(error) as info:
        f.predict() if which == "fx" else f.update(z)
    assert info.value is exc  # the very object: its type, message and traceback as fx/hx raised them
    check(f, snap)
    if sys.version_info >= (3, 11):
        (note,) = exc.__notes__
        shape = {"fleet": "(3, 9, 2)", "vectorised": "(9, 2)", "per point": "(2,) at each sigma point"}[front]
        assert f"{which}_noise=2" in note and shape in note


# -- issue 29, 3. a points object built for the dimension a set is drawn in ------------------------
#
# n = 2: the first set is drawn in 2 + fx_noise, the second in 2 + hx_noise (2 without). A filterpy
# points object serves a set of the dimension it was built for as it is, and any other set as its
# squkf equivalent MerweScaledWeights(alpha, beta, kappa), whose kappa is lowered by the noise
# dimension at n + d; it must be built for n or for the dimension of a set it serves.

MERWE = (0.5, 2.0, 1.0)
BUILT_FOR_A_SET = [(2, None, 2), (2, None, 4), (None, 1, 2), (None, 1, 3), (2, 1, 2), (2, 1, 4), (2, 1, 3)]
BUILT_FOR_A_SET += [(2, 2, 2), (2, 2, 4)]
BUILT_FOR_NO_SET = [
    (None, None, 3),
    (2, None, 3),
    (2, None, 5),
    (None, 1, 4),
    (2, 1, 5),
    (2, 2, 3),
    (2, 2, 5),
]


def merwe_equivalent(built, fx_noise, hx_noise):
    """The squkf families that draw each set as ``MerweScaledSigmaPoints(built, *MERWE)`` does."""
    alpha, beta, kappa = MERWE

    def family(d):  # as it is at 2 + d (its augmented(d) has kappa), else its equivalent
        return MerweScaledWeights(alpha, beta, kappa + d if d and built == 2 + d else kappa)

    return family(fx_noise), Redrawn(family(hx_noise))


def pendulum_zs(cls, T):
    zs = pendulum_simulate(T, seed=3)
    return zs if cls is SquareRootUKF else np.stack([zs, zs + 0.01, zs - 0.02])


@pytest.mark.parametrize("cls", [SquareRootUKF, Fleet])
@pytest.mark.parametrize("fx_noise, hx_noise, built", BUILT_FOR_A_SET)
def test_a_points_object_built_for_a_sets_dimension_draws_as_its_squkf_equivalent(
    fx_noise, hx_noise, built, cls
):
    points = MerweScaledSigmaPoints(built, *MERWE)
    first, second = merwe_equivalent(built, fx_noise or 0, hx_noise or 0)
    f = pendulum_noise_filter(points, fx_noise, hx_noise, cls)
    g = pendulum_noise_filter(first, fx_noise, hx_noise, cls, scheme=second)
    zs = pendulum_zs(cls, 8)
    for t in range(8):
        for h in (f, g):
            h.predict()
            h.update(zs[t] if cls is SquareRootUKF else zs[:, t])
        np.testing.assert_array_equal(f.x, g.x)
        np.testing.assert_array_equal(f.P1_2, g.P1_2)
    if cls is SquareRootUKF and not fx_noise:  # the smoother draws the first set as the filter does
        means, covs = g.batch_filter(zs)
        for a, b in zip(f.rts_smoother(means, covs), g.rts_smoother(means, covs)):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("fx_noise, hx_noise, built", BUILT_FOR_NO_SET)
def test_a_points_object_built_for_no_sets_dimension_is_refused_naming_points(fx_noise, hx_noise, built):
    points = MerweScaledSigmaPoints(built, *MERWE)
    dims = sorted({2, 2 + (fx_noise or 0), 2 + (hx_noise or 0)})
    match = rf"^points: .* built for n={built}, .* build it with n={' or n='.join(map(str, dims))}$"
    for cls in (SquareRootUKF, Fleet):
        with pytest.raises(ParameterError, match=match):
            pendulum_noise_filter(points, fx_noise, hx_noise, cls)
    f = pendulum_noise_filter(MerweScaledWeights(*MERWE), fx_noise, hx_noise)
    snap = filter_state(f)
    with pytest.raises(ParameterError, match=match):
        f.points_fn = points
    assert_filter_state(f, snap)
    assert isinstance(f.points_fn, MerweScaledWeights)


@pytest.mark.parametrize("built", [2, 3])
def test_a_second_sets_own_points_object_built_for_its_dimension_draws_as_its_equivalent(built):
    """``Redrawn(weights=...)`` serves the second set only: here drawn in 2 + hx_noise = 3."""
    first = MerweScaledWeights(*MERWE)
    f = pendulum_noise_filter(first, 2, 1, scheme=Redrawn(MerweScaledSigmaPoints(built, *MERWE)))
    g = pendulum_noise_filter(first, 2, 1, scheme=merwe_equivalent(built, 0, 1)[1])
    for z in pendulum_zs(SquareRootUKF, 5):
        for h in (f, g):
            h.predict()
            h.update(z)
        np.testing.assert_array_equal(f.x, g.x)
        np.testing.assert_array_equal(f.P1_2, g.P1_2)


def test_a_second_sets_own_points_object_built_for_another_dimension_is_refused():
    """Built for 4, the first set's dimension, which the second set's own points do not serve."""
    with pytest.raises(
        ParameterError, match=r"^Redrawn\(weights=\.\.\.\): .* n=4, .*build it with n=2 or n=3$"
    ):
        pendulum_noise_filter(MerweScaledWeights(), 2, 1, scheme=Redrawn(MerweScaledSigmaPoints(4, *MERWE)))


@pytest.mark.parametrize("cls", [SquareRootUKF, Fleet])
def test_a_points_object_with_no_squkf_equivalent_is_built_for_every_set(cls):
    # OddPoints: built for n = 2, the dimension of one set, not of the other
    for fx_noise, hx_noise in ((2, None), (None, 1)):
        with pytest.raises(
            ParameterError, match=r"no squkf equivalent \(Merwe or Julier type\) to serve a set"
        ):
            pendulum_noise_filter(OddPoints(), fx_noise, hx_noise, cls)
    f = pendulum_noise_filter(OddPoints(), None, None, cls)  # its own dimension: served as it is
    f.predict()


# -- issue 29, 4. a noise dimension too large to allocate names the noise ----------------------------


@pytest.mark.parametrize("which", ["fx_noise", "hx_noise"])
@pytest.mark.parametrize("cls", [SquareRootUKF, Fleet])
def test_a_noise_dimension_too_large_to_allocate_is_refused_naming_it(which, cls):
    with pytest.raises(ParameterError, match=rf"^{which}=10000000 is too large") as info:
        sizes = (2, 1) if cls is SquareRootUKF else (3, 2, 1)
        cls(*sizes, PEND_DT, pendulum_hx, pendulum_fx, MerweScaledWeights(), **{which: 10**7})
    assert "dim_x" not in str(info.value)


def test_q_and_r_are_the_noise_covariances():
    f = pendulum_filter(MerweScaledWeights())
    assert f.Q.shape == (2, 2) and f.R.shape == (2, 2)  # w's and v's, here also 2 x 2
    g = SquareRootUKF(
        2, 1, PEND_DT, pendulum_hx, lambda x, w, dt: x + w, MerweScaledWeights(), fx_noise=2, hx_noise=2
    )
    with pytest.raises(ShapeError):
        g.R = np.eye(1)  # v has dimension 2, whatever dim_z is
    fleet = Fleet(3, 2, 1, PEND_DT, pendulum_hx, pendulum_fx, MerweScaledWeights(), fx_noise=2, hx_noise=2)
    with pytest.raises(ShapeError):
        fleet.R = np.eye(1)
    fleet.R = PEND_RV
    assert fleet.R.shape == (2, 2)


@pytest.mark.parametrize("scheme", ["augmented", "propagated"])
def test_other_second_sets_are_refused(scheme):
    with pytest.raises(ParameterError, match="redrawn"):
        pendulum_filter(MerweScaledWeights(), scheme=scheme)


def test_what_the_noise_form_cannot_take_is_refused():
    f = pendulum_filter(MerweScaledWeights())
    with pytest.raises(ParameterError, match="UT"):
        f.predict(UT=lambda *a: a)
    X = f.ask_predict()
    with pytest.raises(ParameterError, match="assign ukf.Q"):
        f.tell_predict(pendulum_fx(X[:, :2], X[:, 2:], PEND_DT), Q=PEND_QW)
    f.tell_predict(pendulum_fx(X[:, :2], X[:, 2:], PEND_DT))
    Y = f.ask_update()
    with pytest.raises(ParameterError, match="assign ukf.R"):
        f.tell_update(pendulum_hx(Y[:, :2], Y[:, 2:]), [0.1], R=PEND_RV)
    means, factors = f.batch_filter(pendulum_simulate(3, seed=8), return_factors=True)
    with pytest.raises(ParameterError, match="additive process noise only"):
        f.rts_smoother_factors(means, factors)


@pytest.mark.parametrize("how", ["update", "ask/tell"])
def test_points_changed_after_a_prediction_apply_from_the_next_step_with_hx_noise(how):
    """The update finishes with the set the prediction drew and that set's noise points, as it does
    without noise forms; the new points are the next prediction's."""
    kept, changed = range_noise_filter(MerweScaledWeights(0.5)), range_noise_filter(MerweScaledWeights(0.5))
    for f in (kept, changed):
        f.predict()
    changed.points_fn = SimplexWeights()
    for f in (kept, changed):
        if how == "update":
            f.update([2.5])
        else:
            X = f.ask_update()
            assert X.shape == (7, 3)  # 2 states + 1 noise, Merwe's 2 * 3 + 1 points
            f.tell_update(np.array([f.hx(x[:2], x[2:]) for x in X]), [2.5])
    np.testing.assert_array_equal(changed.x, kept.x)
    np.testing.assert_array_equal(changed.P, kept.P)
    fresh = range_noise_filter(SimplexWeights())
    for f in (changed, fresh):
        f.predict()
    assert changed.sigmas_f.shape == fresh.sigmas_f.shape != kept.sigmas_f.shape
