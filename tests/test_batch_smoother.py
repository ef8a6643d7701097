"""batch_filter and the square-root unscented RTS smoother."""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter
from models import CT_Q, ct_filter, ct_fx, ct_simulate

from squkf import MerweScaledWeights, ShapeError, SquareRootUKF


def make_ct(cls):
    """The far coordinated-turn radar in ``cls``, filterpy's Merwe points (alpha 0.3, kappa -2)."""
    return ct_filter(MerweScaledSigmaPoints(5, 0.3, 2.0, -2.0), cls=cls)


def test_batch_equals_loop_exactly():
    zs, _ = ct_simulate()
    a, b = make_ct(SquareRootUKF), make_ct(SquareRootUKF)
    means, covs = a.batch_filter(zs)
    for k, z in enumerate(zs):
        b.predict()
        b.update(z)
        np.testing.assert_array_equal(means[k], b.x)
        np.testing.assert_array_equal(covs[k], b.P)


def test_batch_equals_filterpy_with_missing_measurements():
    zs, _ = ct_simulate()
    nan_zs = [np.full(2, np.nan) if z is None else z for z in zs]
    m_fp, P_fp = make_ct(UnscentedKalmanFilter).batch_filter(zs)
    for data in (zs, nan_zs):
        m, P = make_ct(SquareRootUKF).batch_filter(data)
        # same algorithm, different arithmetic: O(eps cond) per step, contracted by updates
        assert np.max(np.abs(m - m_fp)) / np.max(np.abs(m_fp)) < 1e-8
        assert np.max(np.abs(P - P_fp) / np.abs(P_fp).max(axis=(1, 2))[:, None, None]) < 1e-8


def test_batch_is_transactional():
    zs, _ = ct_simulate(10)
    zs[6] = np.array([1.0, 2.0, 3.0])  # wrong length
    f = make_ct(SquareRootUKF)
    x, S = f.x.copy(), np.array(f.P1_2)
    with pytest.raises(ShapeError, match="length 3"):
        f.batch_filter(zs)
    np.testing.assert_array_equal(f.x, x)
    np.testing.assert_array_equal(f.P1_2, S)


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
    f = make_ct(SquareRootUKF)
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
    f = make_ct(SquareRootUKF)
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
