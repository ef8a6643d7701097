"""The square-root unscented RTS smoother (squkf.smoother): one filter's and a fleet's, and their inputs.

The single filter's smoother against the textbook unscented RTS smoother and filterpy's Kalman
smoother, from factors and from covariances; its inputs validated like the filter's, naming the
argument and the step; ``Fleet.rts_smoother``, the same backward recursion for K filters at once,
against K single smoothers, with one filter's failure isolated.
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter, MerweScaledSigmaPoints
from models import (
    CT_Q,
    CTF_K,
    CTF_T,
    CV3_K,
    CV3_NX,
    CV3_NZ,
    LIN2_Q,
    LIN2_T,
    assert_results_equal,
    assert_smoother_matches_single,
    counting,
    ct_fleet_measurements,
    ct_fx,
    ct_fx_stacked,
    ct_merwe_filter,
    ct_per_filter_Q,
    ct_simulate,
    lin2_F,
    lin2_filter,
    lin2_fx,
    make_ct_fleet,
    make_ct_single,
    make_cv3_fleet,
    near_filter,
    range_bearing_hx,
    rel_unfloored,
)

from squkf import (
    CubatureWeights,
    Fleet,
    FleetStepError,
    JulierWeights,
    MerweScaledWeights,
    NonFiniteError,
    NotPositiveDefiniteError,
    ParameterError,
    ShapeError,
    SimplexWeights,
    SquareRootUKF,
    SqukfValueError,
)
from squkf.angles import AngleAdd, AngleMean, AngleResidual, wrap

# == the single filter's smoother ==================================================================


def textbook_urts(f, xs, Ps, Qs, dts):
    """Särkkä (2008) unscented RTS smoother in covariance form, written from the equations."""
    pts = MerweScaledSigmaPoints(5, 0.3, 2.0, -2.0)
    xs_s, Ps_s = xs.copy(), Ps.copy()
    for k in range(len(xs) - 2, -1, -1):
        X = pts.sigma_points(xs[k], Ps[k])
        Fx = np.array([ct_fx(s, dts[k + 1]) for s in X])
        m = pts.Wm @ Fx
        dF, dX = Fx - m, X - xs[k]
        Pp = (dF.T * pts.Wc) @ dF + Qs[k + 1]
        C = (dX.T * pts.Wc) @ dF
        G = C @ np.linalg.inv(Pp)
        xs_s[k] = xs[k] + G @ (xs_s[k + 1] - m)
        Ps_s[k] = Ps[k] + G @ (Ps_s[k + 1] - Pp) @ G.T
    return xs_s, Ps_s


def test_smoother_equals_textbook_unscented_rts_with_time_varying_Qs():
    zs, truth = ct_simulate()
    T = len(zs)
    rng = np.random.default_rng(7)
    Qs = [CT_Q * rng.uniform(0.5, 20.0) for _ in range(T)]
    dts = [1.0] * T
    f = ct_merwe_filter(SquareRootUKF)
    means, covs = f.batch_filter(zs, Qs=Qs, dts=dts)
    xs, Ps, Ks = f.rts_smoother(means, covs, Qs=Qs, dts=dts)
    xs_ref, Ps_ref = textbook_urts(f, means, covs, Qs, dts)
    # both are the same equations; differences are rounding amplified by cond(P) ~ 1e8
    assert np.max(np.abs(xs - xs_ref)) / np.max(np.abs(xs_ref)) < 1e-8
    for k in range(T):
        assert np.max(np.abs(Ps[k] - Ps_ref[k])) / np.max(np.abs(Ps_ref[k])) < 1e-8
    # ignoring Qs (filterpy's UKF smoother does) gives a visibly different answer
    xs_noq, _, _ = f.rts_smoother(means, covs, dts=dts)
    assert np.max(np.abs(xs_noq - xs)) > 1e-3
    # and smoothing helps: RMSE of positions falls
    err_f = np.sqrt(np.mean((means[:, [0, 2]] - truth[:, [0, 2]]) ** 2))
    err_s = np.sqrt(np.mean((xs[:, [0, 2]] - truth[:, [0, 2]]) ** 2))
    assert err_s < err_f


def test_smoother_from_factors_equals_covariance_form():
    zs, _ = ct_simulate(30)
    f = ct_merwe_filter(SquareRootUKF)
    means, factors = f.batch_filter(zs, return_factors=True)
    xs1, S, _ = f.rts_smoother_factors(means, factors)
    xs2, Ps, _ = f.rts_smoother(means, factors @ np.swapaxes(factors, 1, 2))
    np.testing.assert_allclose(xs1, xs2, rtol=1e-12)
    np.testing.assert_allclose(S @ np.swapaxes(S, 1, 2), Ps, rtol=1e-9, atol=1e-12)
    assert np.all(np.triu(S, 1) == 0) and np.all(np.diagonal(S, axis1=1, axis2=2) > 0)


def test_smoother_equals_kalman_rts_on_linear_model():
    rng = np.random.default_rng(3)
    F = np.array([[1.0, 1.0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 1.0], [0, 0, 0, 1.0]])
    H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    kf = KalmanFilter(4, 2)
    kf.F, kf.H, kf.Q, kf.R = F, H, np.eye(4) * 0.02, np.eye(2) * 2.0
    for scheme in ("redrawn", "augmented"):
        kf.x, kf.P = np.zeros(4), np.eye(4) * 10
        u = SquareRootUKF(
            4, 2, 1.0, lambda x: H @ x, lambda x, dt: F @ x, MerweScaledWeights(0.5), scheme=scheme
        )
        u.Q, u.R, u.P, u.x = kf.Q, kf.R, kf.P, np.zeros(4)
        zs = [np.array([k, -k]) + rng.standard_normal(2) for k in range(80)]
        Qs = [np.eye(4) * q for q in rng.uniform(0.001, 0.1, 80)]
        m, P, _, _ = kf.batch_filter(zs, Qs=Qs)
        xs, Ps, _, _ = kf.rts_smoother(m, P, Qs=Qs)
        mu, Pu = u.batch_filter(zs, Qs=Qs)
        xu, Psu, _ = u.rts_smoother(mu, Pu, Qs=Qs)
        # exact transform of a linear model: equal to rounding (cond(P) < 1e4)
        assert np.max(np.abs(xu - xs.reshape(80, 4))) / np.max(np.abs(xs)) < 1e-9
        assert np.max(np.abs(Psu - Ps)) / np.max(np.abs(Ps)) < 1e-9


# == the smoother's inputs =========================================================================


@pytest.fixture(scope="module")
def lin2_filtered():
    rng = np.random.default_rng(5)
    zs = np.arange(LIN2_T) + rng.normal(0.0, 0.7, LIN2_T)
    means, covs = lin2_filter().batch_filter(zs)
    _, factors = lin2_filter().batch_filter(zs, return_factors=True)
    return means, covs, factors


@pytest.mark.parametrize(
    "dts", [[0.0] * LIN2_T, [1.0, 0.0, 0.5, 0.0, 0.0, 2.0, 1.0, 0.0, 0.3, 0.0, 1.0, 0.0]]
)
def test_zero_time_steps_are_accepted_and_agree_with_the_kalman_smoother(lin2_filtered, dts):
    means, covs, _ = lin2_filtered
    Qs = [LIN2_Q * s for s in np.linspace(0.5, 2.0, LIN2_T)]
    xs, Ps, Ks = lin2_filter().rts_smoother(means, covs, Qs=Qs, dts=dts)
    kf = KalmanFilter(2, 1)
    x_ref, P_ref, K_ref, _ = kf.rts_smoother(means, covs, Fs=[lin2_F(dt) for dt in dts], Qs=Qs)
    # a linear model: the unscented transform is exact, so the two agree to rounding
    np.testing.assert_allclose(xs, x_ref, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(Ps, P_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(Ks[:-1], K_ref[:-1], rtol=1e-9, atol=1e-12)


def test_a_scalar_dt_of_zero(lin2_filtered):
    means, covs, _ = lin2_filtered
    assert_results_equal(
        lin2_filter().rts_smoother(means, covs, dts=0.0),
        lin2_filter().rts_smoother(means, covs, dts=[0.0] * LIN2_T),
    )


def test_scalar_and_single_matrix_Qs_mean_every_step(lin2_filtered):
    means, covs, _ = lin2_filtered
    expected = lin2_filter().rts_smoother(means, covs, Qs=[0.03 * np.eye(2)] * LIN2_T)
    assert_results_equal(lin2_filter().rts_smoother(means, covs, Qs=0.03), expected)
    assert_results_equal(lin2_filter().rts_smoother(means, covs, Qs=0.03 * np.eye(2)), expected)


def test_lists_generators_and_column_vectors(lin2_filtered):
    means, covs, factors = lin2_filtered
    expected = lin2_filter().rts_smoother(means, covs)
    assert_results_equal(lin2_filter().rts_smoother(list(means), [P for P in covs]), expected)
    assert_results_equal(lin2_filter().rts_smoother((x for x in means), iter(covs)), expected)
    assert_results_equal(lin2_filter().rts_smoother(means[:, :, None], covs), expected)
    expected = lin2_filter().rts_smoother_factors(means, factors)
    assert_results_equal(lin2_filter().rts_smoother_factors(iter(means), list(factors)), expected)


def test_a_negative_diagonal_is_a_sign_of_its_column(lin2_filtered):
    means, _, factors = lin2_filtered
    flipped = factors.copy()
    flipped[4][:, 1] *= -1  # the same covariance
    flipped[7] *= -1
    xs, S, _ = lin2_filter().rts_smoother_factors(means, flipped)
    xs_ref, S_ref, _ = lin2_filter().rts_smoother_factors(means, factors)
    np.testing.assert_allclose(xs, xs_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(S, S_ref, rtol=1e-10, atol=1e-12)
    assert np.all(np.diagonal(S, axis1=1, axis2=2) > 0)


@pytest.mark.parametrize("method", ["rts_smoother", "rts_smoother_factors"])
@pytest.mark.parametrize("n", [0, 1])
def test_empty_and_single_step(lin2_filtered, method, n):
    means, covs, factors = lin2_filtered
    second = covs if method == "rts_smoother" else factors
    Xs, Ps = (means[:n], second[:n]) if n else ([], [])
    xs, Ps_s, Ks = getattr(lin2_filter(), method)(Xs, Ps)
    assert xs.shape == (n, 2) and Ps_s.shape == (n, 2, 2) and Ks.shape == (n, 2, 2)
    if n:
        np.testing.assert_array_equal(xs, means[:1])
        np.testing.assert_allclose(Ps_s, second[:1], rtol=1e-14)
        assert not np.any(Ks)


def _corrupt(lin2_filtered, what):
    means, covs, factors = (a.copy() for a in lin2_filtered)
    kwargs = {}
    if what == "factor above the diagonal":
        factors[3][0, 1] = 0.5
    elif what == "factor zero diagonal":
        factors[3][1, 1] = 0.0
    elif what == "factor nan":
        factors[3][1, 0] = np.nan
    elif what == "mean inf":
        means[3][1] = np.inf
    elif what == "numeric text dt":  # a negative dt is a step, as for predict
        kwargs["dts"] = [1.0] * 3 + ["0.5"] + [1.0] * (LIN2_T - 4)
    elif what == "nan dt":
        kwargs["dts"] = [1.0] * 3 + [np.nan] + [1.0] * (LIN2_T - 4)
    elif what == "inf dt":
        kwargs["dts"] = [1.0] * 3 + [np.inf] + [1.0] * (LIN2_T - 4)
    elif what == "text dt":
        kwargs["dts"] = [1.0] * 3 + ["one"] + [1.0] * (LIN2_T - 4)
    elif what == "fx_args entry":
        kwargs["fx_args"] = [{}] * 3 + [5] + [{}] * (LIN2_T - 4)
    return means, factors, kwargs


@pytest.mark.parametrize(
    "what, error, match",
    [
        ("factor above the diagonal", SqukfValueError, r"P1_2s\[3\] must be lower triangular"),
        ("factor zero diagonal", NotPositiveDefiniteError, r"P1_2s\[3\] has a zero on its diagonal"),
        ("factor nan", NonFiniteError, r"P1_2s\[3\] \(step 3\) contains NaN or inf"),
        ("mean inf", NonFiniteError, r"Xs\[3\] \(step 3\) contains NaN or inf"),
        ("numeric text dt", ParameterError, r"dts\[3\] must be a finite number"),
        ("nan dt", ParameterError, r"dts\[3\]"),
        ("inf dt", ParameterError, r"dts\[3\]"),
        ("text dt", ParameterError, r"dts\[3\]"),
        ("fx_args entry", ParameterError, r"fx_args\[3\] must be a dict"),
    ],
)
def test_bad_factor_inputs_are_named_with_their_step(lin2_filtered, what, error, match):
    means, factors, kwargs = _corrupt(lin2_filtered, what)
    counted, calls = counting(lin2_fx)
    f = lin2_filter(fx=counted)
    before = copy.deepcopy(f)
    with pytest.raises(error, match=match):
        f.rts_smoother_factors(means, factors, **kwargs)
    assert calls == []  # found before the backward pass
    np.testing.assert_array_equal(f.x, before.x)
    np.testing.assert_array_equal(f.P1_2, before.P1_2)


@pytest.mark.parametrize(
    "change, error, match",
    [
        ("nan", NonFiniteError, r"Ps\[4\] \(step 4\) contains NaN"),
        ("asymmetric", SqukfValueError, r"Ps\[4\] is not symmetric"),
        ("indefinite", NotPositiveDefiniteError, r"Ps\[4\]"),
    ],
)
def test_bad_covariances_are_named_with_their_step(lin2_filtered, change, error, match):
    means, covs, _ = lin2_filtered
    covs = covs.copy()
    if change == "nan":
        covs[4][0, 0] = np.nan
    elif change == "asymmetric":
        covs[4][0, 1] += 1.0
    else:
        covs[4] = np.array([[1.0, 2.0], [2.0, 1.0]])
    with pytest.raises(error, match=match):
        lin2_filter().rts_smoother(means, covs)


@pytest.mark.parametrize("name", ["Qs", "dts", "fx_args"])
@pytest.mark.parametrize("method", ["rts_smoother", "rts_smoother_factors"])
def test_per_step_lengths_must_match(lin2_filtered, name, method):
    means, covs, factors = lin2_filtered
    second = covs if method == "rts_smoother" else factors
    entry = {"Qs": LIN2_Q, "dts": 1.0, "fx_args": {}}[name]
    for n in (LIN2_T - 1, LIN2_T + 1):
        with pytest.raises(ShapeError, match=f"^{name} has {n} entries but Xs has {LIN2_T}$"):
            getattr(lin2_filter(), method)(means, second, **{name: [entry] * n})


def test_shapes_and_lengths_of_the_filtered_results(lin2_filtered):
    means, covs, factors = lin2_filtered
    f = lin2_filter()
    with pytest.raises(ShapeError, match=f"Ps has {LIN2_T - 1} entries but Xs has {LIN2_T}"):
        f.rts_smoother(means, covs[:-1])
    with pytest.raises(ShapeError, match=f"P1_2s has {LIN2_T + 1} entries but Xs has {LIN2_T}"):
        f.rts_smoother_factors(means, np.concatenate([factors, factors[:1]]))
    with pytest.raises(ShapeError, match=r"Xs has shape \(12, 3\), expected \(T, 2\)"):
        f.rts_smoother(np.zeros((LIN2_T, 3)), covs)
    with pytest.raises(ShapeError, match=r"P1_2s has shape \(12, 3, 3\), expected \(T, 2, 2\)"):
        f.rts_smoother_factors(means, np.zeros((LIN2_T, 3, 3)))
    with pytest.raises(ShapeError, match="Xs must be an array"):
        f.rts_smoother([[1.0, 2.0], [1.0]], covs[:2])
    with pytest.raises(ShapeError, match="Ps must be an array"):
        f.rts_smoother(means, None)
    with pytest.raises(ShapeError, match="Xs must be an array"):
        f.rts_smoother("abc", covs)
    with pytest.raises(ParameterError, match="fx_args must be None, a dict"):
        f.rts_smoother(means, covs, fx_args=3)
    with pytest.raises(ParameterError, match="UT must be a callable"):
        f.rts_smoother_factors(means, factors, UT="merwe")


def test_a_failure_in_the_backward_pass_names_the_step(lin2_filtered):
    means, _, factors = lin2_filtered
    fx_args = [{}] * LIN2_T
    fx_args[6] = {"bad": True}  # the prediction into step 6, used by smoothing step 5
    with pytest.raises(NonFiniteError, match=r"^at smoothing step 5 \(Qs\[6\], dts\[6\], fx_args\[6\]\): "):
        lin2_filter().rts_smoother_factors(means, factors, fx_args=fx_args)
    Qs = [LIN2_Q] * LIN2_T
    Qs[9] = np.eye(3)
    with pytest.raises(ShapeError, match=r"^at smoothing step 8 \(Qs\[9\]"):
        lin2_filter().rts_smoother_factors(means, factors, Qs=Qs)


def test_the_smoother_leaves_the_filter_alone(lin2_filtered):
    means, covs, _ = lin2_filtered
    f = lin2_filter()
    f.predict()
    before = copy.deepcopy(f)
    f.rts_smoother(means, covs, Qs=[LIN2_Q] * LIN2_T, fx_args={})
    for name in ("x", "P1_2", "x_prior", "P1_2_prior"):
        np.testing.assert_array_equal(getattr(f, name), getattr(before, name))


@pytest.mark.parametrize(
    "points",
    [MerweScaledWeights(0.5), MerweScaledWeights(1e-3), JulierWeights(), SimplexWeights(), CubatureWeights()],
    ids=["merwe", "merwe-small-alpha", "julier", "simplex", "cubature"],
)
def test_each_filter_equals_the_single_smoother(points):
    # with alpha = 1e-3 the weights are ~1e6 and the fleet's and the single filter's *filtering*
    # already differ by ~1e-8 (rounding, amplified): the smoothers then differ by as much
    small_alpha = isinstance(points, MerweScaledWeights) and points.alpha < 0.01
    assert_smoother_matches_single(points, chained_tol=1e-6 if small_alpha else 1e-10)


@pytest.mark.parametrize("scheme", ["augmented", "propagated"])
def test_each_filter_equals_the_single_smoother_other_schemes(scheme):
    assert_smoother_matches_single(MerweScaledWeights(0.5), scheme)


@pytest.mark.parametrize("points", [MerweScaledWeights(0.5), JulierWeights()], ids=["merwe", "julier"])
def test_per_filter_Q_and_varying_dts(points):
    dts = np.linspace(0.5, 1.5, CTF_T)
    assert_smoother_matches_single(points, Q=ct_per_filter_Q(), dts=dts)


def test_smoothing_differs_from_filtering_and_per_filter_Q_matters():
    fleet, result, (means, _, _) = assert_smoother_matches_single(
        MerweScaledWeights(0.5), Q=ct_per_filter_Q()
    )
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
    zs = np.empty((CTF_K, CTF_T, 3))
    for k in range(CTF_K):
        x = x0.copy()
        for t in range(CTF_T):
            x = fx(x, 1.0)
            zs[k, t] = hx(x) + rng.normal(size=3) * [0.5, 0.05, 0.05]
    Q = np.diag([0.01, 0.01, 0.01, 1e-4, 1e-3])
    R = np.diag([0.25, 0.0025, 0.0025])
    P = np.diag([1.0, 0.1, 0.1, 0.01, 0.05])
    fleet = Fleet(CTF_K, 5, 3, 1.0, hx, fx, MerweScaledWeights(0.5), **hooks)
    fleet.x, fleet.P, fleet.Q, fleet.R = x0, P, Q, R
    result = fleet.batch_filter(zs)
    seen.clear()
    means, factors, _ = fleet.rts_smoother(result)
    assert seen and set(seen) == {(5,)}  # one filter's vector at a time
    assert np.any(np.abs(means[..., 4]) > 3.0)  # the angle crossed +/-pi
    assert np.all(np.abs(means[..., 4]) <= np.pi)
    for k in range(CTF_K):
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
    fleet = Fleet(CTF_K, 4, 2, 1.0, lambda X: X @ H.T, lambda X, dt: X @ F.T, MerweScaledWeights(0.5))
    fleet.x, fleet.P, fleet.Q, fleet.R = np.zeros(4), np.eye(4) * 10, Qs, R
    zs = np.array([[[t, -t] for t in range(60)]] * CTF_K, dtype=float) + rng.standard_normal((CTF_K, 60, 2))
    means, factors, gains = fleet.rts_smoother(fleet.batch_filter(zs))
    Ps = factors @ np.swapaxes(factors, -1, -2)
    for k in range(CTF_K):
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

    fleet = make_ct_fleet(MerweScaledWeights(0.5))
    fleet.fx = fx
    dts = np.linspace(0.5, 1.5, CTF_T)
    result = fleet.batch_filter(ct_fleet_measurements(dts=dts), dts=dts)
    calls.clear()
    fleet.rts_smoother(result, dts=dts)
    N = 2 * 5 + 1
    assert [c[0] for c in calls] == [(CTF_K, N, 5)] * (CTF_T - 1)
    # backward step k predicts into k + 1, with that prediction's time step
    np.testing.assert_array_equal([c[1] for c in calls], dts[:0:-1])


def test_the_fleet_is_not_changed():
    fleet = make_ct_fleet(MerweScaledWeights(0.5), Q=ct_per_filter_Q())
    result = fleet.batch_filter(ct_fleet_measurements())
    before = {name: getattr(fleet, name) for name in ("x", "P1_2", "Q1_2", "R1_2", "failed")}
    means = result.means.copy()
    fleet.rts_smoother(result)
    for name, value in before.items():
        np.testing.assert_array_equal(getattr(fleet, name), value)
    np.testing.assert_array_equal(result.means, means)


def test_result_unpacks_and_carries_the_failures():
    fleet = make_ct_fleet(MerweScaledWeights(0.5))
    out = fleet.rts_smoother(fleet.batch_filter(ct_fleet_measurements()))
    means, factors, gains = out
    assert out.means is means and out.P1_2s is factors and out.Gs is gains
    assert means.shape == (CTF_K, CTF_T, 5) and factors.shape == gains.shape == (CTF_K, CTF_T, 5, 5)
    np.testing.assert_allclose(out.Ps, factors @ np.swapaxes(factors, -1, -2))
    assert out.failed.shape == (CTF_K,) and not out.failed.any()
    back = pickle.loads(pickle.dumps(out))
    np.testing.assert_array_equal(back.means, means)
    np.testing.assert_array_equal(back.failed, out.failed)


def test_one_step_is_returned_as_filtered():
    fleet = make_ct_fleet(MerweScaledWeights(0.5))
    result = fleet.batch_filter(ct_fleet_measurements()[:, :1])
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
    zs = ct_fleet_measurements()
    fleet = make_ct_fleet(points)
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
        f = make_ct_single(points, k)
        m, S = f.batch_filter(list(zs[k]), return_factors=True)
        one = {name: v[k] for name, v in fx_args.items()}
        xs, Ss, _ = f.rts_smoother_factors(m, S, Qs=fleet.Q, fx_args=one)
        assert rel_unfloored(out.means[k], xs) < 1e-10
        assert rel_unfloored(out.P1_2s[k], Ss) < 1e-10


def test_with_on_error_raise_a_failure_raises():
    fleet = make_ct_fleet(MerweScaledWeights(0.5), on_error="raise")
    result = fleet.batch_filter(ct_fleet_measurements())
    with pytest.raises(FleetStepError) as info:
        fleet.rts_smoother(result, fx_args={"poison": np.array([0.0, 0.0, np.inf])})
    assert info.value.filters == (2,)


def test_filters_flagged_in_the_result_are_returned_unsmoothed():
    points = MerweScaledWeights(0.5)
    zs = ct_fleet_measurements()
    fleet = make_ct_fleet(points)
    fleet.fx = lambda X, dt: ct_fx_stacked(
        X, dt, poison=np.where(np.arange(CTF_K) == 0, np.nan, 0.0)[:, None]
    )
    result = fleet.batch_filter(zs)
    assert result.failed.tolist() == [True, False, False]
    fleet.fx = ct_fx_stacked
    out = fleet.rts_smoother(result)
    np.testing.assert_array_equal(out.failed, result.failed)
    assert out.failure[0]
    np.testing.assert_array_equal(out.means[0], result.means[0])
    np.testing.assert_array_equal(out.P1_2s[0], result.P1_2s[0])
    for k in (1, 2):
        f = make_ct_single(points, k)
        m, S = f.batch_filter(list(zs[k]), return_factors=True)
        assert rel_unfloored(out.means[k], f.rts_smoother_factors(m, S)[0]) < 1e-10


# -- invalid input ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fleet_filtered():
    fleet = make_ct_fleet(MerweScaledWeights(0.5))
    return fleet, fleet.batch_filter(ct_fleet_measurements())


@pytest.mark.parametrize("keep", ["diagonals", "means", "final"])
def test_result_without_factors_is_refused(keep):
    fleet = make_ct_fleet(MerweScaledWeights(0.5))
    result = fleet.batch_filter(ct_fleet_measurements(), keep=keep)
    with pytest.raises(ParameterError, match="keep='all'"):
        fleet.rts_smoother(result)


def test_not_a_fleet_result_is_refused(fleet_filtered):
    fleet, result = fleet_filtered
    with pytest.raises(ParameterError, match="FleetResult"):
        fleet.rts_smoother((result.means, result.P1_2s))


def test_result_of_another_fleet_size_is_refused(fleet_filtered):
    _, result = fleet_filtered
    other = Fleet(CTF_K + 1, 5, 2, 1.0, range_bearing_hx, ct_fx_stacked, MerweScaledWeights(0.5))
    with pytest.raises(ShapeError, match="result.means"):
        other.rts_smoother(result)


def test_non_finite_or_non_triangular_result_is_refused(fleet_filtered):
    fleet, result = fleet_filtered
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
        ({"dts": np.ones(CTF_T - 1)}, ShapeError, "dts"),
        ({"dts": np.full(CTF_T, np.nan)}, ParameterError, "dt"),
        ({"dts": "1.0"}, ParameterError, "dts"),
        ({"fx_args": [{}]}, ParameterError, "fx_args"),
    ],
)
def test_bad_arguments_are_refused(fleet_filtered, kwargs, error, match):
    fleet, result = fleet_filtered
    with pytest.raises(error, match=match):
        fleet.rts_smoother(result, **kwargs)


def test_fx_values_of_the_wrong_shape_name_the_step(fleet_filtered):
    fleet, result = fleet_filtered
    broken = Fleet(CTF_K, 5, 2, 1.0, range_bearing_hx, lambda X, dt: X[..., :4], MerweScaledWeights(0.5))
    with pytest.raises(ShapeError, match="at smoothing step 18"):
        broken.rts_smoother(result)
    assert fleet.rts_smoother(result).means.shape == (CTF_K, CTF_T, 5)


# == a zero-step result ============================================================================


# -- 8. the fleet's smoother of a zero-step result: empty arrays ----------------------------------


def test_the_fleet_smoother_of_no_steps_returns_empty_arrays():
    fl = make_cv3_fleet()
    res = fl.batch_filter(np.zeros((CV3_K, 0, CV3_NZ)))
    means, P1_2s, Gs = out = fl.rts_smoother(res)
    assert means.shape == (CV3_K, 0, CV3_NX) and P1_2s.shape == Gs.shape == (CV3_K, 0, CV3_NX, CV3_NX)
    assert out.failed.shape == (CV3_K,) and not out.failed.any()
    # as the single filter's smoother does
    f = near_filter()
    xs, Ps, Ks = f.rts_smoother(*f.batch_filter(np.zeros((0, 2))))
    assert xs.shape == (0, 5) and Ps.shape == Ks.shape == (0, 5, 5)
