"""Fleet.rts_smoother: the single filter's backward recursion for K filters at once."""

import pickle

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from models import CT_P0, CT_Q, CT_R, CT_X0, ct_fx_stacked, range_bearing_hx, rel_unfloored

from squkf import (
    CubatureWeights,
    Fleet,
    FleetStepError,
    JulierWeights,
    MerweScaledWeights,
    NonFiniteError,
    ParameterError,
    ShapeError,
    SimplexWeights,
    SquareRootUKF,
)
from squkf.angles import AngleAdd, AngleMean, AngleResidual, wrap

K, T = 3, 20


def measurements(seed=0, dts=None):
    """``(K, T, 2)`` noisy range-bearing measurements of K coordinated-turn tracks, a few missing."""
    rng = np.random.default_rng(seed)
    dts = np.ones(T) if dts is None else dts
    zs = np.empty((K, T, 2))
    for k in range(K):
        x = CT_X0 + rng.normal(size=5) * [20, 1, 20, 1, 0.005]
        for t in range(T):
            x = ct_fx_stacked(x, dts[t]) + rng.multivariate_normal(np.zeros(5), CT_Q)
            zs[k, t] = range_bearing_hx(x) + rng.multivariate_normal(np.zeros(2), CT_R)
    zs[0, 4] = np.nan  # no measurement
    zs[1, 9, 1] = np.nan  # a missing component
    return zs


def per_filter_Q():
    return np.stack([CT_Q * s for s in (0.5, 1.0, 3.0)])


def make_fleet(points, scheme="redrawn", Q=CT_Q, **kw):
    fleet = Fleet(K, 5, 2, 1.0, range_bearing_hx, ct_fx_stacked, points, scheme=scheme, **kw)
    fleet.x, fleet.P, fleet.Q, fleet.R = CT_X0, CT_P0, Q, CT_R
    return fleet


def make_single(points, k, scheme="redrawn", Q=CT_Q, **kw):
    """Filter ``k`` of :func:`make_fleet`, built independently (fx called once per point)."""
    f = SquareRootUKF(5, 2, 1.0, range_bearing_hx, ct_fx_stacked, points, scheme=scheme, **kw)
    f.x, f.P, f.Q, f.R = CT_X0.copy(), CT_P0, (Q if Q.ndim == 2 else Q[k]), CT_R
    return f


def assert_matches_single(points, scheme="redrawn", Q=CT_Q, dts=None, chained_tol=1e-10, **kw):
    """Each filter of the fleet's smoother against the single filter's, on the same and on its own input."""
    zs = measurements(dts=dts)
    fleet = make_fleet(points, scheme, Q, **kw)
    result = fleet.batch_filter(zs, dts=dts)
    out = fleet.rts_smoother(result, dts=dts)
    means, factors, gains = out
    assert not result.failed.any() and not out.failed.any()
    for k in range(K):
        f = make_single(points, k, scheme, Q, **kw)
        # the same filtered input: only the smoothers' arithmetic differs (stacked QR against LAPACK's)
        xs, Ss, Gs = f.rts_smoother_factors(result.means[k], result.P1_2s[k], dts=dts)
        assert rel_unfloored(means[k], xs) < 1e-10
        assert rel_unfloored(factors[k], Ss) < 1e-10
        assert rel_unfloored(gains[k], Gs) < 1e-10
        # the single filter's own batch_filter output
        m, S = f.batch_filter(list(zs[k]), dts=dts, return_factors=True)
        xs, Ss, Gs = f.rts_smoother_factors(m, S, dts=dts)
        assert rel_unfloored(means[k], xs) < chained_tol
        assert rel_unfloored(factors[k], Ss) < chained_tol
        assert rel_unfloored(gains[k], Gs) < chained_tol
        np.testing.assert_array_equal(gains[k, -1], 0.0)
        # the smoothed factors are lower factors, as the single filter's
        assert np.all(np.triu(factors[k], 1) == 0)
        assert np.all(np.diagonal(factors[k], axis1=-2, axis2=-1) > 0)
    return fleet, result, out


@pytest.mark.parametrize(
    "points",
    [MerweScaledWeights(0.5), MerweScaledWeights(1e-3), JulierWeights(), SimplexWeights(), CubatureWeights()],
    ids=["merwe", "merwe-small-alpha", "julier", "simplex", "cubature"],
)
def test_each_filter_equals_the_single_smoother(points):
    # with alpha = 1e-3 the weights are ~1e6 and the fleet's and the single filter's *filtering*
    # already differ by ~1e-8 (rounding, amplified): the smoothers then differ by as much
    small_alpha = isinstance(points, MerweScaledWeights) and points.alpha < 0.01
    assert_matches_single(points, chained_tol=1e-6 if small_alpha else 1e-10)


@pytest.mark.parametrize("scheme", ["augmented", "propagated"])
def test_each_filter_equals_the_single_smoother_other_schemes(scheme):
    assert_matches_single(MerweScaledWeights(0.5), scheme)


@pytest.mark.parametrize("points", [MerweScaledWeights(0.5), JulierWeights()], ids=["merwe", "julier"])
def test_per_filter_Q_and_varying_dts(points):
    dts = np.linspace(0.5, 1.5, T)
    assert_matches_single(points, Q=per_filter_Q(), dts=dts)


def test_smoothing_differs_from_filtering_and_per_filter_Q_matters():
    fleet, result, (means, _, _) = assert_matches_single(MerweScaledWeights(0.5), Q=per_filter_Q())
    assert np.max(np.abs(means[:, :-1] - result.means[:, :-1])) > 1e-3
    np.testing.assert_array_equal(means[:, -1], result.means[:, -1])
    fleet.Q = CT_Q  # a shared Q gives other smoothed values for the filters whose Q differed
    other = fleet.rts_smoother(result)
    assert np.max(np.abs(other.means[0] - means[0])) > 1e-6
    assert np.max(np.abs(other.means[2] - means[2])) > 1e-6


def test_angle_hooks_are_called_per_filter():
    """A bearing state (component 4 holds an angle near +/-pi) with filterpy's hooks, as one filter does."""

    def fx(X, dt, scale=1.0, poison=0.0):
        Y = X.copy()
        Y[..., 0] += dt * X[..., 1]
        Y[..., 4] = wrap(X[..., 4] + dt * X[..., 3])
        return Y

    def hx(X):
        return np.stack([X[..., 0], np.cos(X[..., 4]), np.sin(X[..., 4])], axis=-1)

    seen = []

    def residual_x(a, b):
        seen.append(np.shape(a))
        return AngleResidual([4])(a, b)

    hooks = dict(x_mean_fn=AngleMean([4]), residual_x=residual_x, state_add=AngleAdd([4]))
    rng = np.random.default_rng(5)
    x0 = np.array([0.0, 1.0, 0.0, 0.05, np.pi - 0.1])
    zs = np.empty((K, T, 3))
    for k in range(K):
        x = x0.copy()
        for t in range(T):
            x = fx(x, 1.0)
            zs[k, t] = hx(x) + rng.normal(size=3) * [0.5, 0.05, 0.05]
    Q = np.diag([0.01, 0.01, 0.01, 1e-4, 1e-3])
    R = np.diag([0.25, 0.0025, 0.0025])
    P = np.diag([1.0, 0.1, 0.1, 0.01, 0.05])
    fleet = Fleet(K, 5, 3, 1.0, hx, fx, MerweScaledWeights(0.5), **hooks)
    fleet.x, fleet.P, fleet.Q, fleet.R = x0, P, Q, R
    result = fleet.batch_filter(zs)
    seen.clear()
    means, factors, _ = fleet.rts_smoother(result)
    assert seen and set(seen) == {(5,)}  # one filter's vector at a time
    assert np.any(np.abs(means[..., 4]) > 3.0)  # the angle crossed +/-pi
    assert np.all(np.abs(means[..., 4]) <= np.pi)
    for k in range(K):
        f = SquareRootUKF(5, 3, 1.0, hx, fx, MerweScaledWeights(0.5), **hooks)
        f.x, f.P, f.Q, f.R = x0.copy(), P, Q, R
        m, S = f.batch_filter(list(zs[k]), return_factors=True)
        xs, Ss, _ = f.rts_smoother_factors(m, S)
        assert rel_unfloored(means[k], xs) < 1e-10
        assert rel_unfloored(factors[k], Ss) < 1e-10


def test_linear_gaussian_equals_filterpy_kalman_rts():
    rng = np.random.default_rng(3)
    F = np.array([[1.0, 1.0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 1.0], [0, 0, 0, 1.0]])
    H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    Qs = np.stack([np.eye(4) * q for q in (0.002, 0.02, 0.2)])
    R = np.eye(2) * 2.0
    fleet = Fleet(K, 4, 2, 1.0, lambda X: X @ H.T, lambda X, dt: X @ F.T, MerweScaledWeights(0.5))
    fleet.x, fleet.P, fleet.Q, fleet.R = np.zeros(4), np.eye(4) * 10, Qs, R
    zs = np.array([[[t, -t] for t in range(60)]] * K, dtype=float) + rng.standard_normal((K, 60, 2))
    means, factors, gains = fleet.rts_smoother(fleet.batch_filter(zs))
    Ps = factors @ np.swapaxes(factors, -1, -2)
    for k in range(K):
        kf = KalmanFilter(4, 2)
        kf.F, kf.H, kf.Q, kf.R, kf.x, kf.P = F, H, Qs[k], R, np.zeros(4), np.eye(4) * 10
        m, P, _, _ = kf.batch_filter(list(zs[k]))
        xs, Ps_ref, Ks, _ = kf.rts_smoother(m, P)
        # the unscented transform of a linear model is exact: equal to rounding (cond(P) < 1e4)
        assert rel_unfloored(means[k], xs.reshape(60, 4)) < 1e-9
        assert rel_unfloored(Ps[k], Ps_ref) < 1e-9
        assert rel_unfloored(gains[k, :-1], Ks[:-1]) < 1e-9


def test_fx_is_called_once_per_backward_step_with_every_filter():
    calls = []

    def fx(X, dt, scale=1.0, poison=0.0):
        calls.append((X.shape, dt))
        return ct_fx_stacked(X, dt)

    fleet = make_fleet(MerweScaledWeights(0.5))
    fleet.fx = fx
    dts = np.linspace(0.5, 1.5, T)
    result = fleet.batch_filter(measurements(dts=dts), dts=dts)
    calls.clear()
    fleet.rts_smoother(result, dts=dts)
    N = 2 * 5 + 1
    assert [c[0] for c in calls] == [(K, N, 5)] * (T - 1)
    # backward step k predicts into k + 1, with that prediction's time step
    np.testing.assert_array_equal([c[1] for c in calls], dts[:0:-1])


def test_the_fleet_is_not_changed():
    fleet = make_fleet(MerweScaledWeights(0.5), Q=per_filter_Q())
    result = fleet.batch_filter(measurements())
    before = {name: getattr(fleet, name) for name in ("x", "P1_2", "Q1_2", "R1_2", "failed")}
    means = result.means.copy()
    fleet.rts_smoother(result)
    for name, value in before.items():
        np.testing.assert_array_equal(getattr(fleet, name), value)
    np.testing.assert_array_equal(result.means, means)


def test_result_unpacks_and_carries_the_failures():
    fleet = make_fleet(MerweScaledWeights(0.5))
    out = fleet.rts_smoother(fleet.batch_filter(measurements()))
    means, factors, gains = out
    assert out.means is means and out.P1_2s is factors and out.Gs is gains
    assert means.shape == (K, T, 5) and factors.shape == gains.shape == (K, T, 5, 5)
    np.testing.assert_allclose(out.Ps, factors @ np.swapaxes(factors, -1, -2))
    assert out.failed.shape == (K,) and not out.failed.any()
    back = pickle.loads(pickle.dumps(out))
    np.testing.assert_array_equal(back.means, means)
    np.testing.assert_array_equal(back.failed, out.failed)


def test_one_step_is_returned_as_filtered():
    fleet = make_fleet(MerweScaledWeights(0.5))
    result = fleet.batch_filter(measurements()[:, :1])
    means, factors, gains = fleet.rts_smoother(result)
    np.testing.assert_array_equal(means, result.means)
    np.testing.assert_array_equal(factors, result.P1_2s)
    np.testing.assert_array_equal(gains, 0.0)


# -- failures: one filter's alone -----------------------------------------------------------


@pytest.mark.parametrize(
    "fx_args, reason",
    [
        ({"poison": np.array([0.0, np.nan, 0.0])}, "not finite"),
        # filter 1's images collapse to one point and Q is zero: its predicted factor is singular
        ({"scale": np.array([1.0, 0.0, 1.0])}, "GainError"),
    ],
    ids=["non-finite-images", "singular-prediction"],
)
def test_a_numerical_failure_is_isolated(fx_args, reason):
    points = MerweScaledWeights(0.5)
    zs = measurements()
    fleet = make_fleet(points)
    result = fleet.batch_filter(zs)
    if "scale" in fx_args:
        fleet.Q = np.zeros((5, 5))
    out = fleet.rts_smoother(result, fx_args=fx_args)
    np.testing.assert_array_equal(out.failed, [False, True, False])
    assert reason in out.failure[1] and "at smoothing step 18" in out.failure[1]
    assert out.failure[0] == out.failure[2] == ""
    # the failing filter: its filtered values, unsmoothed
    np.testing.assert_array_equal(out.means[1], result.means[1])
    np.testing.assert_array_equal(out.P1_2s[1], result.P1_2s[1])
    np.testing.assert_array_equal(out.Gs[1], 0.0)
    # the others: as if it were absent
    for k in (0, 2):
        f = make_single(points, k)
        m, S = f.batch_filter(list(zs[k]), return_factors=True)
        one = {name: v[k] for name, v in fx_args.items()}
        xs, Ss, _ = f.rts_smoother_factors(m, S, Qs=fleet.Q, fx_args=one)
        assert rel_unfloored(out.means[k], xs) < 1e-10
        assert rel_unfloored(out.P1_2s[k], Ss) < 1e-10


def test_with_on_error_raise_a_failure_raises():
    fleet = make_fleet(MerweScaledWeights(0.5), on_error="raise")
    result = fleet.batch_filter(measurements())
    with pytest.raises(FleetStepError) as info:
        fleet.rts_smoother(result, fx_args={"poison": np.array([0.0, 0.0, np.inf])})
    assert info.value.filters == (2,)


def test_filters_flagged_in_the_result_are_returned_unsmoothed():
    points = MerweScaledWeights(0.5)
    zs = measurements()
    fleet = make_fleet(points)
    fleet.fx = lambda X, dt: ct_fx_stacked(X, dt, poison=np.where(np.arange(K) == 0, np.nan, 0.0)[:, None])
    result = fleet.batch_filter(zs)
    assert result.failed.tolist() == [True, False, False]
    fleet.fx = ct_fx_stacked
    out = fleet.rts_smoother(result)
    np.testing.assert_array_equal(out.failed, result.failed)
    assert out.failure[0]
    np.testing.assert_array_equal(out.means[0], result.means[0])
    np.testing.assert_array_equal(out.P1_2s[0], result.P1_2s[0])
    for k in (1, 2):
        f = make_single(points, k)
        m, S = f.batch_filter(list(zs[k]), return_factors=True)
        assert rel_unfloored(out.means[k], f.rts_smoother_factors(m, S)[0]) < 1e-10


# -- invalid input ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def filtered():
    fleet = make_fleet(MerweScaledWeights(0.5))
    return fleet, fleet.batch_filter(measurements())


@pytest.mark.parametrize("keep", ["diagonals", "means", "final"])
def test_result_without_factors_is_refused(keep):
    fleet = make_fleet(MerweScaledWeights(0.5))
    result = fleet.batch_filter(measurements(), keep=keep)
    with pytest.raises(ParameterError, match="keep='all'"):
        fleet.rts_smoother(result)


def test_not_a_fleet_result_is_refused(filtered):
    fleet, result = filtered
    with pytest.raises(ParameterError, match="FleetResult"):
        fleet.rts_smoother((result.means, result.P1_2s))


def test_result_of_another_fleet_size_is_refused(filtered):
    _, result = filtered
    other = Fleet(K + 1, 5, 2, 1.0, range_bearing_hx, ct_fx_stacked, MerweScaledWeights(0.5))
    with pytest.raises(ShapeError, match="result.means"):
        other.rts_smoother(result)


def test_non_finite_or_non_triangular_result_is_refused(filtered):
    fleet, result = filtered
    bad = result.means.copy()
    bad[2, 7, 1] = np.nan
    with pytest.raises(NonFiniteError, match=r"result.means\[2, 7\]"):
        fleet.rts_smoother(type(result)(**{**vars(result), "means": bad}))
    S = result.P1_2s.copy()
    S[1, 3, 0, 4] = 1.0
    with pytest.raises(ParameterError, match=r"result.P1_2s\[1, 3\]"):
        fleet.rts_smoother(type(result)(**{**vars(result), "P1_2s": S}))


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        ({"dts": np.ones(T - 1)}, ShapeError, "dts"),
        ({"dts": np.full(T, np.nan)}, ParameterError, "dt"),
        ({"dts": "1.0"}, ParameterError, "dts"),
        ({"fx_args": [{}]}, ParameterError, "fx_args"),
    ],
)
def test_bad_arguments_are_refused(filtered, kwargs, error, match):
    fleet, result = filtered
    with pytest.raises(error, match=match):
        fleet.rts_smoother(result, **kwargs)


def test_fx_values_of_the_wrong_shape_name_the_step(filtered):
    fleet, result = filtered
    broken = Fleet(K, 5, 2, 1.0, range_bearing_hx, lambda X, dt: X[..., :4], MerweScaledWeights(0.5))
    with pytest.raises(ShapeError, match="at smoothing step 18"):
        broken.rts_smoother(result)
    assert fleet.rts_smoother(result).means.shape == (K, T, 5)
