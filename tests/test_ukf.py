"""``SquareRootUKF``, the filterpy-compatible front end: its results and its API.

Results: NAG's published g13ej example, the Kalman filter on linear-Gaussian models, filterpy's UKF
given the same points, long and ill-conditioned runs, property-based checks. API: filterpy's
conventions beyond predict/update (CKF, Saver, pickling, repr, several sensors, angles, dt, banks),
ask/tell, hooks, and the hot path's promises (matrices factored once). Records handed out, failed
calls, missing measurements and errors have files of their own (see tests/README.md).
"""

from __future__ import annotations

import copy
import pickle
import warnings

import numpy as np
import pytest
from filterpy.common import Saver
from filterpy.kalman import (
    CubatureKalmanFilter,
    IMMEstimator,
    JulierSigmaPoints,
    KalmanFilter,
    MerweScaledSigmaPoints,
    MMAEFilterBank,
    SimplexSigmaPoints,
    UnscentedKalmanFilter,
)
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from models import (
    CT_P0,
    CT_Q,
    CT_R,
    CT_X0,
    CV_DT,
    CV_P0,
    CV_X0,
    CV_Z,
    FILTERPY_RTOL,
    PRECISE_F,
    PRECISE_H,
    PRECISE_Q,
    PRECISE_R,
    WIDE_FAMILIES,
    Robot,
    assert_filter_state,
    assert_same_estimate,
    bank_pair,
    ct_filter,
    ct_fx,
    ct_hx,
    ct_measurements,
    ct_negative_weight_filter,
    ct_simulate,
    cv_filter,
    cv_fx,
    example_data,
    filter_state,
    l96_fx,
    l96_hx,
    linear_pair,
    one_d_measured,
    precise_filter,
    precise_fx,
    precise_fx_rows,
    precise_hx,
    precise_hx_rows,
    random_linear_model,
    rel,
    run_against_kf,
    run_g13ej,
    run_pair,
    spd,
    spinning_heading,
    spinning_heading_filter,
    step,
    two_updates,
    wide_covariance_form_update,
    wide_heading_filter,
    wide_measurements,
    wrapped_pair_filter,
)
from scipy.linalg import solve_discrete_are
from scipy.stats import chi2

import squkf.boundary.attributes
from squkf import (
    Augmented,
    CallSequenceError,
    CubatureWeights,
    JulierWeights,
    MerweScaledWeights,
    NotPositiveDefiniteError,
    ParameterError,
    PosteriorFactorError,
    Propagated,
    Redrawn,
    SimplexWeights,
    SquareRootUKF,
)
from squkf.angles import AngleAdd, AngleMean, AngleResidual, circular_mean, wrap

# == the g13ej example: NAG's published results ====================================================

DATA = example_data()


@pytest.mark.parametrize("vectorized", [False, True])
def test_published_state_estimates(vectorized):
    xs, _ = run_g13ej("redrawn", vectorized)
    published = np.array(DATA["published_state_estimates"]["x"])
    # NAG prints 3 decimals: our values must round to exactly the printed ones.
    np.testing.assert_array_equal(np.round(xs, 3), published)


def test_published_final_factor():
    _, st = run_g13ej("redrawn")
    rows = DATA["published_final_st"]["rows"]
    for i, row in enumerate(rows):
        for j, printed in enumerate(row):
            # printed with 3 significant digits (%10.2e)
            assert float(f"{st[i, j]:.2e}") == pytest.approx(printed, rel=1e-12), (i, j, st[i, j])
    assert np.all(np.triu(st, 1) == 0)
    assert np.all(np.diag(st) > 0)


def test_augmented_runs_to_completion_and_stays_close():
    xs_a, st_a = run_g13ej("augmented")
    xs_r, _ = run_g13ej("redrawn")
    assert np.all(np.isfinite(xs_a)) and np.all(np.isfinite(st_a))
    assert np.all(np.diag(st_a) > 0) and np.all(np.triu(st_a, 1) == 0)
    # The schemes differ only in higher moments; on this mildly nonlinear example the
    # estimates stay within a few of the posterior standard deviations (~0.2) of each other.
    assert np.max(np.abs(xs_a - xs_r)) < 0.5
    truth = np.c_[
        DATA["true_positions"]["xi"], DATA["true_positions"]["eta"], DATA["true_positions"]["theta"]
    ]
    rmse = np.sqrt(np.mean((xs_a - truth[1:]) ** 2))
    assert rmse < 0.5


# == linear-Gaussian models: the Kalman filter =====================================================
#
# The unscented transform of a linear map is exact for every family whose unit
# points have weighted mean 0 and weighted covariance I, so SquareRootUKF must
# equal filterpy's KalmanFilter up to rounding. The models are well conditioned
# (cond(P) < 1e3), so 100 steps of O(eps * cond) per-step differences stay far
# below the asserted 1e-9 relative.

KF_FAMILIES = {
    "merwe-default": lambda n: MerweScaledWeights(),
    "merwe-small-alpha": lambda n: MerweScaledWeights(alpha=0.1, beta=2.0, kappa=0.0),
    "julier": lambda n: JulierWeights(kappa=1.0),
    "simplex": lambda n: SimplexWeights(),
    "cubature": lambda n: CubatureWeights(),
    "filterpy-merwe": lambda n: MerweScaledSigmaPoints(n, 0.3, 2.0, 3.0 - n),
    "filterpy-julier": lambda n: JulierSigmaPoints(n, 0.5),
    "filterpy-simplex": lambda n: SimplexSigmaPoints(n),
}
KF_SYMMETRIC = ["merwe-default", "merwe-small-alpha", "julier", "filterpy-merwe", "filterpy-julier"]


@pytest.mark.parametrize("family", list(KF_FAMILIES))
def test_redrawn_equals_kalman_filter(family):
    run_against_kf(KF_FAMILIES[family](4), "redrawn")


@pytest.mark.parametrize("family", KF_SYMMETRIC)
def test_augmented_equals_kalman_filter(family):
    run_against_kf(KF_FAMILIES[family](4), "augmented")


def test_vectorized_equals_kalman_filter():
    run_against_kf(MerweScaledWeights(alpha=0.5), "redrawn", vectorized=True)
    run_against_kf(MerweScaledWeights(alpha=0.5), "augmented", vectorized=True)


def test_second_set_with_its_own_weights_equals_kalman_filter():
    # g13ej's ROPT(5..7): a second set with its own kappa/alpha/beta
    run_against_kf(MerweScaledWeights(), Redrawn(weights=MerweScaledWeights(alpha=0.2, beta=1.0, kappa=1.0)))
    run_against_kf(MerweScaledWeights(), Redrawn(weights=CubatureWeights()))


def test_augmented_with_own_weights_follows_the_covariance_equations():
    """With alpha' != alpha the augmented set no longer reproduces the prior's covariance,
    so the filter is not the Kalman filter; it must still follow g13ej's equations
    (8)-(12) with the second set's weights and the prior P from step (c). Checked
    against those equations in covariance form, one step at a time."""
    F, H, Q, R = random_linear_model(1)
    fam2 = MerweScaledWeights(alpha=0.8, beta=2.0, kappa=-1.0)
    ukf = SquareRootUKF(
        4, 2, 1.0, lambda x: H @ x, lambda x, dt: F @ x, MerweScaledWeights(), scheme=Augmented(weights=fam2)
    )
    ukf.x, ukf.P, ukf.Q, ukf.R = np.ones(4), np.eye(4) * 2.0, Q, R
    rng = np.random.default_rng(5)
    for _ in range(5):
        ukf.predict()
        xbar, Pbar, Y = ukf.x.copy(), ukf.P.copy(), ukf.sigmas_f.copy()
        Wm, Wc = fam2.weights(8)
        HY = Y @ H.T
        yhat = Wm @ HY
        dz, dx = HY - yhat, Y - xbar
        Pyy = (dz.T * Wc) @ dz + R
        Pxy = (dx.T * Wc) @ dz
        K = Pxy @ np.linalg.inv(Pyy)
        z = rng.standard_normal(2)
        ukf.update(z)
        np.testing.assert_allclose(ukf.x, xbar + K @ (z - yhat), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(ukf.P, Pbar - K @ Pyy @ K.T, rtol=1e-9, atol=1e-12)


def test_one_dimensional_state():
    run_against_kf(MerweScaledWeights(), "redrawn", n=1, m=1)
    run_against_kf(MerweScaledWeights(), "augmented", n=1, m=1)


def test_more_measurements_than_states():
    run_against_kf(MerweScaledWeights(), "redrawn", n=2, m=5)


# == filterpy's UnscentedKalmanFilter given the same points ========================================
#
# Both filters run the same algorithm (filterpy redraws the second set from the
# predicted mean and covariance, as g13ej's default does); they differ only in
# arithmetic: covariances versus QR/rank-1 factor updates. Each step introduces
# relative differences of order eps * cond(P) (~1e-16 * 1e4 here); the
# measurement updates contract them, so after hundreds of steps the normwise
# relative difference stays many orders below the 1e-8 asserted.


class Truth:
    def __init__(self, x0, step):
        self.x0 = np.asarray(x0, dtype=float)
        self.step = step


def test_robot_agrees_with_filterpy():
    data = example_data()
    robot = Robot(data)
    points = MerweScaledSigmaPoints(3, alpha=1.0, beta=2.0, kappa=0.0)
    Q = np.eye(3) * 0.01
    R = np.eye(2) * 1e-4
    # a smaller turn keeps the heading away from the wrap in hx (filterpy has no residual hook here)
    worst = run_pair(
        points,
        lambda x, dt: robot.fx(x, dt, 0.3, 0.29),
        robot.hx,
        3,
        2,
        1.0,
        np.array([0.0, 0.0, 1.0]),
        np.eye(3) * 0.01,
        Q,
        R,
        Truth([0.0, 0.0, 1.0], lambda x, rng: robot.fx(x, 1.0, 0.3, 0.29) + rng.normal(0, 0.02, 3)),
        300,
        1,
    )
    assert worst < FILTERPY_RTOL


def test_coordinated_turn_negative_central_weight():
    points = MerweScaledSigmaPoints(5, alpha=0.1, beta=2.0, kappa=0.0)
    assert points.Wc[0] < 0  # the downdate path is exercised at every step
    worst = run_pair(
        points,
        ct_fx,
        ct_hx,
        5,
        2,
        1.0,
        CT_X0 + np.array([20.0, 1.0, -20.0, 1.0, 0.0]),
        CT_P0,
        CT_Q,
        CT_R,
        Truth(CT_X0, lambda x, rng: ct_fx(x, 1.0) + rng.multivariate_normal(np.zeros(5), CT_Q)),
        400,
        2,
    )
    assert worst < FILTERPY_RTOL


@pytest.mark.parametrize(
    "make_points",
    [
        lambda n: MerweScaledSigmaPoints(n, 0.5, 2.0, 3 - n),
        lambda n: JulierSigmaPoints(n, 1.0),
        lambda n: SimplexSigmaPoints(n),
    ],
    ids=["merwe", "julier", "simplex"],
)
def test_lorenz96_agrees_with_filterpy(make_points):
    n = 20
    Q = np.eye(n) * 0.01
    R = np.eye(n // 2) * 0.1
    x0 = np.full(n, 8.0)
    x0[0] += 0.5
    worst = run_pair(
        make_points(n),
        l96_fx,
        l96_hx,
        n,
        n // 2,
        0.05,
        np.full(n, 8.0) + 0.01,
        np.eye(n) * 0.5,
        Q,
        R,
        Truth(x0, lambda x, rng: l96_fx(x, 0.05) + rng.multivariate_normal(np.zeros(n), Q)),
        300,
        3,
    )
    assert worst < FILTERPY_RTOL


def test_filterpy_outputs_match_attribute_by_attribute():
    """K, y, S, SI, log-likelihood, mahalanobis, sigmas_f and sigmas_h mean the same things."""
    points = MerweScaledSigmaPoints(5, alpha=0.3, beta=2.0, kappa=-2.0)
    fp = ct_filter(points, cls=UnscentedKalmanFilter)
    sq = ct_filter(points)
    for f in (fp, sq):
        f.predict()
    assert rel(sq.sigmas_f, fp.sigmas_f) < 1e-12
    z = ct_hx(fp.x) + np.array([3.0, -0.001])
    for f in (fp, sq):
        f.update(z)
    for name in ("x", "P", "K", "y", "S", "SI", "sigmas_h", "x_post", "P_post"):
        assert rel(np.asarray(getattr(sq, name)), np.asarray(getattr(fp, name))) < 1e-9, name
    assert sq.log_likelihood == pytest.approx(fp.log_likelihood, rel=1e-9)
    assert sq.likelihood == pytest.approx(fp.likelihood, rel=1e-8)
    assert sq.mahalanobis == pytest.approx(fp.mahalanobis, rel=1e-9)
    Pxz = sq.cross_variance(sq.x_prior, fp.sigmas_h.T @ fp.Wm, fp.sigmas_f, fp.sigmas_h)
    assert rel(Pxz, fp.cross_variance(fp.x_prior, fp.sigmas_h.T @ fp.Wm, fp.sigmas_f, fp.sigmas_h)) < 1e-12


def test_compute_process_sigmas_is_filterpys_and_changes_no_state():
    """filterpy's ``compute_process_sigmas(dt, fx, **fx_args)``: ``sigmas_f`` set to the first set
    propagated through ``fx`` (the one given, with its arguments), the estimate left as it was."""
    points = MerweScaledSigmaPoints(5, alpha=0.3, beta=2.0, kappa=-2.0)
    fp, sq = ct_filter(points, cls=UnscentedKalmanFilter), ct_filter(points)
    x0, P0 = sq.x.copy(), sq.P.copy()

    def slowed(x, dt, factor):
        return ct_fx(x, factor * dt)

    for f in (fp, sq):
        f.compute_process_sigmas(2.0, slowed, factor=0.5)
    assert rel(sq.sigmas_f, fp.sigmas_f) < 1e-12
    np.testing.assert_array_equal(sq.x, x0)
    np.testing.assert_array_equal(sq.P, P0)
    sq.compute_process_sigmas(1.0)  # the filter's own fx
    assert rel(sq.sigmas_f, fp.sigmas_f) < 1e-12


# == where filterpy's UKF fails ====================================================================


@pytest.mark.parametrize("P0", [1e4, 1e6])
def test_precise_sensor_breaks_filterpy_not_squkf(P0):
    rng = np.random.default_rng(0)
    fp, sq = precise_filter(UnscentedKalmanFilter, P0), precise_filter(SquareRootUKF, P0)
    xt = np.array([0.0, 1.0])
    failed_at = None
    for k in range(2000):
        xt = PRECISE_F @ xt
        z = xt[:1] + rng.normal(0.0, 1e-6, 1)
        if failed_at is None:
            try:
                fp.predict()
                fp.update(z)
            except np.linalg.LinAlgError:
                # the covariance filterpy was left with is no covariance: squkf refuses it
                with pytest.raises(NotPositiveDefiniteError):
                    precise_filter(SquareRootUKF, P0).P = fp.P
                failed_at = k
        sq.predict()
        sq.update(z)
        S = np.asarray(sq.P1_2)
        assert np.all(np.isfinite(S)) and np.all(np.diag(S) > 0) and np.all(np.triu(S, 1) == 0)
    assert failed_at is not None and failed_at < 10  # filterpy dies almost at once
    # the square-root filter tracks to within a few sensor standard deviations (1e-6)
    assert abs(sq.x[0] - xt[0]) < 1e-5
    assert np.sqrt(sq.P[0, 0]) < 1e-5


# == long ill-conditioned runs and Monte-Carlo consistency =========================================


@pytest.mark.slow
def test_near_singular_model_for_100000_steps():
    steps = 100_000
    rng = np.random.default_rng(11)
    f = SquareRootUKF(
        2,
        1,
        1.0,
        precise_hx_rows,
        precise_fx_rows,
        MerweScaledWeights(0.1, 2.0, 0.0),
        vectorized=True,
    )
    f.x, f.P, f.Q, f.R = np.array([0.0, 1.0]), np.eye(2) * 1e6, PRECISE_Q, PRECISE_R
    fp = UnscentedKalmanFilter(2, 1, 1.0, precise_hx, precise_fx, MerweScaledSigmaPoints(2, 0.1, 2.0, 0.0))
    fp.x, fp.P, fp.Q, fp.R = np.array([0.0, 1.0]), np.eye(2) * 1e6, PRECISE_Q, PRECISE_R
    x = np.array([0.0, 1.0])
    fp_failed = None
    for k in range(steps):
        x = PRECISE_F @ x
        z = x[:1] + rng.normal(0.0, 1e-6, 1)
        f.predict()
        f.update(z)
        if fp_failed is None and k < 100:
            try:
                fp.predict()
                fp.update(z)
            except np.linalg.LinAlgError:
                fp_failed = (k, fp.P.copy())
    S = np.asarray(f.P1_2)
    assert np.all(np.isfinite(S)) and np.all(np.diag(S) > 0) and S[0, 1] == 0
    # filterpy's covariance-form UKF dies at the second step on this model, its covariance no longer
    # positive definite (checked below: squkf refuses it)
    assert fp_failed is not None and fp_failed[0] <= 2
    # steady state of the Kalman filter, computed independently from the Riccati equation
    Pp = solve_discrete_are(PRECISE_F.T, PRECISE_H.T, PRECISE_Q, PRECISE_R)
    Pss = Pp - Pp @ PRECISE_H.T @ np.linalg.solve(PRECISE_H @ Pp @ PRECISE_H.T + PRECISE_R, PRECISE_H @ Pp)
    # The sigma points x +/- gamma S are formed at |x| ~ 1e5 while gamma sqrt(P) ~ 1e-7: their
    # deviations carry only eps |x| / (gamma sqrt(P)) ~ 2.2e-16 * 1e5 / 8e-8 ~ 3e-4 relative
    # precision, so that is the accuracy float64 allows for P here (any UKF); we ask for 1e-3.
    np.testing.assert_allclose(f.P, Pss, rtol=1e-3)
    assert abs(f.x[0] - x[0]) < 10 * np.sqrt(Pss[0, 0])
    with pytest.raises(NotPositiveDefiniteError):
        f.P = fp_failed[1]


def test_tracking_nees_over_100_monte_carlo_runs():
    """Average NEES of 100 runs x 40 steps of the coordinated-turn model inside its 95% band."""
    runs, T, n = 100, 40, 5
    total, count = 0.0, 0
    for seed in range(runs):
        rng = np.random.default_rng(seed)
        x, P0 = CT_X0.copy(), CT_P0
        f = SquareRootUKF(n, 2, 1.0, ct_hx, ct_fx, MerweScaledWeights(1.0, 2.0, 0.0))
        f.x, f.P, f.Q, f.R = x + rng.multivariate_normal(np.zeros(n), P0), P0, CT_Q, CT_R
        for _ in range(T):
            x = ct_fx(x, 1.0) + rng.multivariate_normal(np.zeros(n), CT_Q)
            f.predict()
            f.update(ct_hx(x) + rng.multivariate_normal(np.zeros(2), CT_R))
            e = f.x - x
            w = np.linalg.solve(np.asarray(f.P1_2), e)
            total += w @ w
            count += 1
    mean = total / count
    lo, hi = chi2.ppf([0.025, 0.975], n * count) / count
    assert lo < mean < hi, (lo, mean, hi)


# == property-based: linear and smooth nonlinear models ============================================

EPS = np.finfo(float).eps


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(n=st.integers(1, 8), m=st.integers(1, 4), log10_cond=st.floats(0, 10), seed=st.integers(0, 2**31))
def test_linear_models_equal_the_kalman_filter(n, m, log10_cond, seed):
    rng = np.random.default_rng(seed)
    F = np.eye(n) + 0.2 * rng.standard_normal((n, n)) / np.sqrt(n)
    H = rng.standard_normal((m, n))
    P0 = spd(rng, n, log10_cond) * 10
    Q = spd(rng, n, 2) * 0.1
    R = spd(rng, m, 2)
    kf = KalmanFilter(n, m)
    kf.F, kf.H, kf.Q, kf.R, kf.P, kf.x = F, H, Q, R, P0, np.zeros(n)
    f = SquareRootUKF(n, m, 1.0, lambda x: H @ x, lambda x, dt: F @ x, MerweScaledWeights(0.5))
    f.x, f.P, f.Q, f.R = np.zeros(n), P0, Q, R
    # Both filters lose about eps * cond(P) per step (filterpy's covariance form more), so the
    # tolerance follows the conditioning: 1e3 * eps * cond(P0) * steps, at least 1e-9.
    tol = max(1e-9, 1e3 * EPS * 10**log10_cond * 5)
    for _ in range(5):
        z = rng.standard_normal(m)
        kf.predict()
        kf.update(z)
        f.predict()
        f.update(z)
        scale = max(np.abs(kf.P).max(), 1e-300)
        assert np.abs(f.P - kf.P).max() / scale < tol
        assert np.abs(f.x - kf.x).max() / max(np.abs(kf.x).max(), 1.0) < tol


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 6), seed=st.integers(0, 2**31), alpha=st.floats(0.2, 1.0))
def test_smooth_nonlinear_models_equal_filterpy(n, seed, alpha):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n)) / np.sqrt(n)
    H = rng.standard_normal((2, n))

    def fx(x, dt):
        return x + 0.1 * np.sin(A @ x)

    def hx(x):
        return np.tanh(H @ x) + 0.5 * H @ x

    P0 = spd(rng, n, 2)
    fp = UnscentedKalmanFilter(n, 2, 1.0, hx, fx, MerweScaledSigmaPoints(n, alpha, 2.0, 3.0 - n))
    sq = SquareRootUKF(n, 2, 1.0, hx, fx, MerweScaledSigmaPoints(n, alpha, 2.0, 3.0 - n))
    for f in (fp, sq):
        f.x, f.P, f.Q, f.R = rng.standard_normal(n) * 0 + 0.3, P0, np.eye(n) * 0.01, np.eye(2) * 0.1
    for _ in range(10):
        z = rng.standard_normal(2)
        try:
            fp.predict()
            fp.update(z)
        except np.linalg.LinAlgError:
            assume(False)  # compare only where filterpy completes
        sq.predict()
        sq.update(z)
        # cond(P) <= 1e2 here: rounding differences stay near 1e-14; 1e-8 is the contract
        assert np.abs(sq.x - fp.x).max() / max(np.abs(fp.x).max(), 1.0) < 1e-8
        assert np.abs(sq.P - fp.P).max() / np.abs(fp.P).max() < 1e-8


# == filterpy compatibility beyond predict/update: CKF, Saver, pickling, repr, sensors, angles =====


def zs_ct(T=50, seed=0):
    """T noisy measurements of the far coordinated-turn radar, none missing."""
    return ct_simulate(T, seed, missing=())[0]


def test_cubature_reproduces_filterpy_ckf():
    """filterpy's CKF reuses the propagated cubature points for the update: scheme='propagated'."""
    ckf = CubatureKalmanFilter(5, 2, 1.0, ct_hx, ct_fx)
    sq = SquareRootUKF(5, 2, 1.0, ct_hx, ct_fx, CubatureWeights(), scheme=Propagated())
    for f in (ckf, sq):
        f.x, f.P, f.Q, f.R = CT_X0.copy(), CT_P0, CT_Q, CT_R
    ckf.x = CT_X0.reshape(5, 1)  # filterpy's CKF works with column vectors
    for z in zs_ct():
        ckf.predict()
        sq.predict()
        ckf.update(z.reshape(2, 1))
        sq.update(z)
        assert np.max(np.abs(sq.x - ckf.x.ravel())) / np.max(np.abs(ckf.x)) < 1e-8
        assert np.max(np.abs(sq.P - ckf.P)) / np.max(np.abs(ckf.P)) < 1e-8


def test_saver_records_a_run():
    f = SquareRootUKF(5, 2, 1.0, ct_hx, ct_fx, MerweScaledWeights(0.3))
    f.x, f.P, f.Q, f.R = CT_X0.copy(), CT_P0, CT_Q, CT_R
    saver = Saver(f)
    zs = zs_ct(10)
    means, covs = f.batch_filter(zs, saver=saver)
    saver.to_array()
    np.testing.assert_array_equal(saver.x, means)
    np.testing.assert_allclose(saver.P, covs)
    assert saver.P1_2.shape == (10, 5, 5)
    assert np.all(np.isfinite(saver.log_likelihood))


@pytest.mark.parametrize("copier", [copy.deepcopy, lambda f: pickle.loads(pickle.dumps(f))])
def test_pickle_and_deepcopy_continue_identically(copier):
    hooks = dict(residual_x=AngleResidual([4]), state_add=AngleAdd([4]), x_mean_fn=AngleMean([4]))
    f = SquareRootUKF(5, 2, 1.0, ct_hx, ct_fx, MerweScaledWeights(0.3), **hooks)
    f.x, f.P, f.Q, f.R = CT_X0.copy(), CT_P0, CT_Q, CT_R
    zs = zs_ct(6)
    for z in zs[:3]:
        f.predict()
        f.update(z)
    g = copier(f)
    for z in zs[3:]:
        for h in (f, g):
            h.predict()
            h.update(z)
    np.testing.assert_array_equal(f.x, g.x)
    np.testing.assert_array_equal(f.P1_2, g.P1_2)


def test_repr_shows_the_state():
    f = SquareRootUKF(5, 2, 1.0, ct_hx, ct_fx, MerweScaledWeights(0.3))
    f.x = CT_X0
    text = repr(f)
    assert text.startswith("SquareRootUKF object")
    for name in ("x = ", "P1_2 = ", "Q1_2 = ", "R1_2 = ", "K = ", "scheme = "):
        assert name in text
    assert "2.e+03" in text


def test_alternating_sensors_of_different_dimension():
    """A position sensor (2-d) and a range-only sensor (1-d) on one filter: each update equals
    the covariance-form equations applied to the redrawn points, written out here."""
    F = np.array([[1, 1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 1.0]])

    def h_pos(x):
        return x[[0, 2]]

    def h_rng(x):
        return np.array([np.hypot(x[0], x[2])])

    R_pos, R_rng = np.eye(2) * 4.0, np.eye(1) * 0.25
    f = SquareRootUKF(4, 2, 1.0, h_pos, lambda x, dt: F @ x, MerweScaledWeights(0.5, 2.0, 0.0))
    f.x, f.P, f.Q, f.R = np.array([100.0, 1, 50, -1]), np.eye(4) * 10, np.eye(4) * 0.01, R_pos
    fam = MerweScaledWeights(0.5, 2.0, 0.0)
    rng = np.random.default_rng(2)
    for k in range(20):
        f.predict()
        hx, Rk = (h_pos, R_pos) if k % 2 == 0 else (h_rng, R_rng)
        x, P = f.x.copy(), f.P.copy()
        Y = x + fam.unit_sigma_points(4) @ np.linalg.cholesky(P).T
        Wm, Wc = fam.weights(4)
        HY = np.array([hx(y) for y in Y])
        zp = Wm @ HY
        dz, dx = HY - zp, Y - x
        Pzz = (dz.T * Wc) @ dz + Rk
        K = ((dx.T * Wc) @ dz) @ np.linalg.inv(Pzz)
        z = hx(x) + rng.normal(0, 1.0, len(zp))
        if k % 2 == 0:
            f.update(z)
        else:
            f.update(z, R=R_rng, hx=h_rng)
        np.testing.assert_allclose(f.x, x + K @ (z - zp), rtol=1e-10)
        np.testing.assert_allclose(f.P, P - K @ Pzz @ K.T, rtol=1e-8, atol=1e-10)
        assert f.K.shape == (4, len(zp))


def test_two_sensors_equal_one_stacked_update_on_a_linear_model():
    """For a linear model two sequential updates (redrawing between them) are the stacked KF update."""
    H1, H2 = np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0], [0, 0, 1.0]])
    R1, R2 = np.eye(1) * 0.5, np.diag([0.2, 0.3])
    f = SquareRootUKF(3, 1, 1.0, lambda x: H1 @ x, lambda x, dt: x, MerweScaledWeights())
    f.x, f.P, f.Q, f.R = np.zeros(3), np.eye(3) * 2 + 0.5, np.eye(3) * 0.1, R1
    kf = KalmanFilter(3, 3)
    kf.x, kf.P, kf.Q, kf.F = np.zeros(3), np.eye(3) * 2 + 0.5, np.eye(3) * 0.1, np.eye(3)
    kf.H, kf.R = np.vstack([H1, H2]), np.block([[R1, np.zeros((1, 2))], [np.zeros((2, 1)), R2]])
    z1, z2 = np.array([1.0]), np.array([-0.5, 2.0])
    f.predict()
    f.update(z1)
    f.update(z2, R=R2, hx=lambda x: H2 @ x)
    kf.predict()
    kf.update(np.r_[z1, z2])
    np.testing.assert_allclose(f.x, kf.x, rtol=1e-12)
    np.testing.assert_allclose(f.P, kf.P, rtol=1e-12)


@pytest.mark.parametrize("model", ["readme", "range-bearing"])
def test_a_second_update_without_a_predict_is_filterpys_with_its_points_redrawn(model):
    """The principled difference (README, "What differs"; docs/guide/filterpy.rst): squkf draws a second
    update's points from the first update's posterior; filterpy reuses the prior's ``sigmas_f``. With
    ``ukf.sigmas_f = ukf.points_fn.sigma_points(ukf.x, ukf.P)`` before its second update, filterpy gives
    squkf's numbers to rounding; without it, it gives others (in the README's case a negative variance)."""
    ours = two_updates(SquareRootUKF, False, model)
    redrawn = two_updates(UnscentedKalmanFilter, True, model)
    theirs = two_updates(UnscentedKalmanFilter, False, model)
    scale = np.sqrt(np.outer(np.diag(ours.P), np.diag(ours.P)))
    np.testing.assert_allclose(ours.x, redrawn.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ours.P / scale, redrawn.P / scale, rtol=0, atol=1e-11)
    np.testing.assert_allclose(ours.log_likelihood, redrawn.log_likelihood, rtol=1e-10)
    assert np.all(np.linalg.eigvalsh(ours.P) > 0)
    assert not np.allclose(ours.P, theirs.P, rtol=1e-3)
    if model == "readme":
        assert theirs.P[0, 0] < 0 < ours.P[0, 0]
        np.testing.assert_allclose([theirs.P[0, 0], ours.P[0, 0]], [-10.415, 0.215], atol=5e-4)


def test_circular_mean_survives_negative_central_weight():
    fam = MerweScaledWeights(0.1, 2.0, 0.0)
    Wm, _ = fam.weights(1)
    assert Wm[0] < -10
    for centre in (np.pi - 0.01, -np.pi + 0.01, 0.3):
        pts = wrap(centre + np.array([0.0, 0.05, -0.05]))
        m = circular_mean(pts, Wm)
        assert abs(wrap(m - centre)) < 1e-12
        # the sin/cos form is broken by the negative weight when points straddle the cut
    naive = np.arctan2(Wm @ np.sin(pts), Wm @ np.cos(pts))
    assert np.isfinite(naive)


def test_angles_agree_with_filterpy_where_its_hooks_are_well_defined():
    # alpha = 1: all weights positive, so filterpy's hooks are well defined
    truth, zs, _, _ = spinning_heading(4)
    x0 = np.array([truth[0][0], 0.8])
    fp = spinning_heading_filter(
        UnscentedKalmanFilter, MerweScaledSigmaPoints(2, 1.0, 2.0, 1.0, subtract=AngleResidual([0])), x0
    )
    sq = spinning_heading_filter(SquareRootUKF, MerweScaledSigmaPoints(2, 1.0, 2.0, 1.0), x0)
    for z in zs:
        for f in (fp, sq):
            f.predict()
            f.update(z)
        assert np.max(np.abs(wrap(sq.x - fp.x))) < 1e-8
        assert np.max(np.abs(sq.P - fp.P)) / np.max(np.abs(fp.P)) < 1e-8


def test_angles_nees_consistent_across_the_cut():
    """Average NEES over 50 runs x 100 steps within its 95% chi-square band (dof 2 per step)."""
    runs, T = 50, 100
    nees = []
    for seed in range(runs):
        truth, zs, _, _ = spinning_heading(100 + seed, T)
        f = spinning_heading_filter(
            SquareRootUKF, MerweScaledWeights(0.1, 2.0, 0.0), np.array([truth[0][0], 0.8])
        )
        for z, xt in zip(zs, truth):
            f.predict()
            f.update(z)
            e = np.array([wrap(f.x[0] - xt[0]), f.x[1] - xt[1]])
            nees.append(e @ np.linalg.solve(f.P, e))
    nees = np.array(nees).reshape(runs, T)[:, 10:]  # skip the initial transient
    dof = 2 * nees.size
    lo, hi = chi2.ppf([0.025, 0.975], dof) / nees.size
    assert lo < nees.mean() < hi, (lo, nees.mean(), hi)


# == residual_x and state_add: P is filterpy's P_prior - K S K^T (the downdate form) ================

# Both sides compute P_prior - K S K^T from the same prior and points, squkf by downdating the prior's
# factor: the differences are rounding, near 1e-15 of |P| here (cond(P) < 1e4), so 1e-10 of |P| is a
# wide margin that still catches any other formula (the old one was off by 0.1 to 1 of |P|).
AGREE = 1e-10


def assert_P_agrees(P, ref, what=""):
    np.testing.assert_allclose(P, ref, rtol=0, atol=AGREE * np.abs(ref).max(), err_msg=what)


def test_wrapped_residual_x_gives_filterpys_P_on_the_issues_reproducer():
    """Julier kappa 1, fx = x, hx = x[1:], a residual_x wrapping x[0]: filterpy's P, to 1e-10."""
    fp = wrapped_pair_filter(UnscentedKalmanFilter, JulierSigmaPoints(2, kappa=1))
    sq = wrapped_pair_filter(SquareRootUKF, JulierSigmaPoints(2, kappa=1))
    for f in (fp, sq):
        f.predict()
        f.update([0.3])
    np.testing.assert_allclose(fp.P, [[4.952, 0.656], [0.656, 0.500]], rtol=0, atol=5e-4)
    assert_P_agrees(sq.P, fp.P)
    np.testing.assert_allclose(sq.x, fp.x, rtol=0, atol=1e-14)


def _wrapped(sigmas, x) -> bool:
    """Whether the heading's wrapped deviations differ from the plain ones (a point passed pi)."""
    plain = sigmas[:, 0] - x[0]
    return bool(np.any(np.abs(wrap(plain) - plain) > 1.0))


@pytest.mark.parametrize("state_add", [False, True], ids=["residual_x", "state_add"])
@pytest.mark.parametrize("name", list(WIDE_FAMILIES))
def test_wrapped_residual_x_gives_filterpys_P_for_every_family(name, state_add):
    """The wide heading (its points past pi at every step), six steps, the redrawn scheme."""
    family, filterpy_points = WIDE_FAMILIES[name]
    sq = wide_heading_filter(SquareRootUKF, family(), state_add)
    fp = wide_heading_filter(
        UnscentedKalmanFilter, filterpy_points(AngleResidual([0]) if state_add else None)
    )
    passed_pi = 0
    for t, z in enumerate(wide_measurements(6)):
        for f in (sq, fp):
            f.predict()
        passed_pi += _wrapped(fp.sigmas_f, fp.x)
        for f in (sq, fp):
            f.update(z)
        assert_P_agrees(sq.P, fp.P, f"P at step {t}")
        np.testing.assert_allclose(
            wrap(sq.x - fp.x), 0.0, atol=AGREE * np.abs(fp.x).max(), err_msg=f"x at {t}"
        )
        np.testing.assert_allclose(sq.K, fp.K, rtol=0, atol=AGREE * np.abs(fp.K).max(), err_msg=f"K at {t}")
    assert passed_pi >= 1


@pytest.mark.parametrize("state_add", [False, True], ids=["residual_x", "state_add"])
@pytest.mark.parametrize("scheme", ["augmented", "propagated"])
def test_wrapped_residual_x_gives_P_prior_minus_KSK_on_the_other_schemes(scheme, state_add):
    """filterpy has no other scheme: the oracle is its update written out on the scheme's second set.

    (The propagated set with process noise took the downdate form before too: this is its check.)
    """
    family = MerweScaledWeights(1.0, 2.0, 0.0)
    f = wide_heading_filter(SquareRootUKF, family, state_add, scheme=scheme)
    Wm, Wc = family.augmented(3).weights(6) if scheme == "augmented" else (f.Wm, f.Wc)
    passed_pi = 0
    for t, z in enumerate(wide_measurements(6)):
        f.predict()
        x_prior, P_prior, sigmas = f.x, f.P, f.sigmas_f
        passed_pi += _wrapped(sigmas, x_prior)
        f.update(z)
        x, P = wide_covariance_form_update(x_prior, P_prior, sigmas, f.sigmas_h, Wm, Wc, z, state_add)
        assert_P_agrees(f.P, P, f"P at step {t}")
        np.testing.assert_allclose(wrap(f.x - x), 0.0, atol=AGREE * np.abs(x).max(), err_msg=f"x at {t}")
    assert passed_pi >= 1


def test_a_downdate_that_fails_raises_and_changes_nothing():
    """Where filterpy's P_prior - K S K^T is indefinite (a sensor ten times as precise), error 303."""
    fp = wrapped_pair_filter(UnscentedKalmanFilter, JulierSigmaPoints(2, kappa=1), R=0.1)
    fp.predict()
    fp.update([0.3])
    assert np.linalg.eigvalsh(fp.P).min() < -0.01
    sq = wrapped_pair_filter(SquareRootUKF, JulierSigmaPoints(2, kappa=1), R=0.1)
    sq.predict()
    before = filter_state(sq)
    with pytest.raises(PosteriorFactorError) as err:
        sq.update([0.3])
    assert err.value.errno == 303
    assert_filter_state(sq, before)
    # and the filter goes on: a less precise measurement is taken
    sq.update([0.3], R=1.0)
    ok = wrapped_pair_filter(UnscentedKalmanFilter, JulierSigmaPoints(2, kappa=1))
    ok.predict()
    ok.update([0.3])
    assert_P_agrees(sq.P, ok.P)


# == filterpy's conventions: dt, filter banks, scalar noise, hooks assigned between steps ==========


def _scaled_residual(a, b):
    return 1.1 * np.subtract(a, b)


def _shrunk_residual(a, b):
    # (shrunk, not stretched: a residual_x stretched by 1.1 makes filterpy's P_prior - K S K^T
    # indefinite on this model, which the downdate form refuses)
    return 0.9 * np.subtract(a, b)


def _half_step_add(x, dx):
    return x + 0.5 * dx


def _shifted_mean(sigmas, Wm):
    return Wm @ sigmas + 0.01


@pytest.mark.parametrize(
    "hook, value, default",
    [
        ("residual_z", _scaled_residual, np.subtract),
        ("residual_x", _shrunk_residual, np.subtract),
        ("state_add", _half_step_add, np.add),
        ("x_mean", _shifted_mean, None),
        ("z_mean", _shifted_mean, None),
    ],
)
def test_a_hook_assigned_between_steps_is_used_from_the_next_step(hook, value, default):
    """filterpy's hooks are plain attributes: assigning one after some steps changes the next steps.

    Each hook here deliberately changes the numbers, so that a hook left unused shows.
    """
    f, plain = cv_filter(), cv_filter()
    step(f, CV_Z[0])
    step(plain, CV_Z[0])
    setattr(f, hook, value)
    ref = cv_filter(**{{"x_mean": "x_mean_fn", "z_mean": "z_mean_fn"}.get(hook, hook): value})
    ref.x, ref.P = f.x, f.P
    assert getattr(f, hook) is value
    for z in CV_Z[1:3]:
        step(f, z)
        step(ref, z)
        step(plain, z)
    np.testing.assert_allclose(f.x, ref.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(f.P, ref.P, rtol=1e-12, atol=1e-12)
    assert not np.allclose(f.x, plain.x, rtol=1e-6, atol=0)
    # and set back, the plain operation is used again
    setattr(f, hook, default)
    back = cv_filter()
    back.x, back.P = f.x, f.P
    step(f, CV_Z[3])
    step(back, CV_Z[3])
    np.testing.assert_allclose(f.x, back.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(f.P, back.P, rtol=1e-12, atol=1e-12)


#: Configuration assigned between a prediction and its update: the set's (the prediction keeps it for
#: its update) and what the update reads when it runs (as filterpy reads its attributes).
_SETS_CONFIGURATION = {"points_fn": JulierWeights(1.0), "scheme": "augmented"}
_UPDATES_CONFIGURATION = {"gate": 0.9, "residual_z": _scaled_residual, "z_mean": _shifted_mean}


@pytest.mark.parametrize("name", [*_SETS_CONFIGURATION, *_UPDATES_CONFIGURATION])
@pytest.mark.parametrize("halves", [False, True])
def test_configuration_changed_between_predict_and_update(name, halves):
    """docs/api/promises.rst, "Configuration changed between predict and update": ``points_fn`` and
    ``scheme`` leave the pending update on the set the prediction drew (the new ones apply from the next
    prediction); the gate and the measurement hooks apply to that update already."""
    value = {**_SETS_CONFIGURATION, **_UPDATES_CONFIGURATION}[name]
    z = CV_Z[1] + np.array([3.0, 0.0])  # far enough off for the gate to reject a component

    def run(when: str) -> SquareRootUKF:
        f = cv_filter()
        step(f, CV_Z[0])
        if when == "before":
            setattr(f, name, value)
        if halves:
            X = f.ask_predict()
            if when == "between":
                setattr(f, name, value)
            f.tell_predict([cv_fx(x, CV_DT) for x in X])
            Y = f.ask_update()
            f.tell_update([f.hx(y) for y in Y], z)
        else:
            f.predict()
            if when == "between":
                setattr(f, name, value)
            f.update(z)
        return f

    changed, unchanged, before = run("between"), run("never"), run("before")
    assert not np.allclose(unchanged.P, before.P, rtol=1e-9)  # the change matters to the numbers
    same = unchanged if name in _SETS_CONFIGURATION else before
    np.testing.assert_array_equal(changed.x, same.x)
    np.testing.assert_array_equal(changed.P, same.P)
    # from the next prediction on, the filter steps as one built with the new configuration
    fresh = cv_filter()
    setattr(fresh, name, value)
    fresh.x, fresh.P = changed.x, changed.P
    step(changed, CV_Z[2])
    step(fresh, CV_Z[2])
    np.testing.assert_allclose(changed.x, fresh.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(changed.P, fresh.P, rtol=1e-12, atol=1e-12)


# -- conventions --------------------------------------------------------------------------------


def test_dt_conventions():
    seen = []

    def rec_fx(x, dt):
        seen.append(dt)
        return cv_fx(x, dt)

    f = SquareRootUKF(4, 2, CV_DT, ct_hx, rec_fx, MerweScaledWeights())
    f.x, f.P = CV_X0, CV_P0
    f.predict(dt=0)
    assert set(seen) == {0.0}
    np.testing.assert_allclose(f.x, CV_X0, atol=1e-12)
    seen.clear()
    f.predict(dt=-1.0)
    assert set(seen) == {-1.0}
    for bad in (np.nan, np.inf, -np.inf, 1 + 2j, np.complex128(1.0), np.array(1 + 0j), "1.0x", [1.0, 2.0]):
        snap = filter_state(f)
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # refused, not cast with a ComplexWarning
            with pytest.raises(ParameterError):
                f.predict(dt=bad)
        assert_filter_state(f, snap)


def test_mmae_filter_bank_runs_with_squkf():
    ours, theirs = bank_pair()
    a = MMAEFilterBank(ours, [0.5, 0.5], 4)
    b = MMAEFilterBank(theirs, [0.5, 0.5], 4)
    for z in CV_Z:
        a.predict()  # filterpy's bank calls f.predict(0): dt = 0
        b.predict()
        a.update(z)
        b.update(z)
        np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(a.P, b.P, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(a.p, b.p, rtol=1e-9, atol=1e-12)
    assert not np.allclose(a.p, 0.5)


def test_imm_estimator_runs_with_squkf():
    ours, theirs = bank_pair()
    M = np.array([[0.95, 0.05], [0.05, 0.95]])
    a = IMMEstimator(ours, [0.5, 0.5], M)
    b = IMMEstimator(theirs, [0.5, 0.5], M)
    for z in CV_Z:
        a.predict()
        b.predict()
        a.update(z)
        b.update(z)
        np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(a.P, b.P, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(a.mu, b.mu, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("value", [2.2e-5, np.array([2.2e-5]), np.array([[2.2e-5]]), np.float64(2.2e-5)])
def test_scalar_and_one_element_noise_in_one_dimension(value):
    f = one_d_measured()
    f.R = value
    f.Q = value
    # read back as assigned, as filterpy: a 1-element vector stays one (f.R[0] is a number)
    shape = (1,) if np.ndim(value) == 1 else (1, 1)
    np.testing.assert_array_equal(f.R, np.full(shape, 2.2e-5))
    np.testing.assert_array_equal(f.Q, np.full(shape, 2.2e-5))
    g = one_d_measured()
    g.R, g.Q = np.array([[2.2e-5]]), np.array([[2.2e-5]])
    for h in (f, g):
        h.predict()
        h.update(1.3)
    np.testing.assert_array_equal(f.x, g.x)
    np.testing.assert_array_equal(f.P, g.P)


def test_scalar_noise_means_a_multiple_of_identity():
    f, g = cv_filter(), cv_filter()
    f.R = 0.3
    g.R = 0.3 * np.eye(2)
    step(f, CV_Z[0])
    step(g, CV_Z[0])
    assert_same_estimate(f, g)


# == ask/tell: one code path with predict/update ===================================================


@pytest.mark.parametrize("scheme", ["redrawn", "augmented"])
def test_ask_tell_equals_predict_update(scheme):
    a, b = ct_negative_weight_filter(scheme), ct_negative_weight_filter(scheme)
    for z in ct_measurements():
        a.predict()
        a.update(z)
        X = b.ask_predict()
        b.tell_predict([ct_fx(x, 1.0) for x in X])
        Y = b.ask_update()
        b.tell_update(np.array([ct_hx(y) for y in Y]), z)
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(a.P1_2, b.P1_2)


def test_vectorized_ask_tell_equals_per_point():
    a, b = ct_negative_weight_filter(), ct_negative_weight_filter(vectorized=True)
    for z in ct_measurements(10):
        a.predict()
        a.update(z)
        X = b.ask_predict()
        b.tell_predict(b.fx(X, 1.0))
        b.tell_update(b.hx(b.ask_update()), z)
        np.testing.assert_allclose(a.x, b.x, rtol=1e-14)
        np.testing.assert_allclose(a.P1_2, b.P1_2, rtol=1e-12, atol=1e-15)


def test_telling_twice_and_without_asking():
    ukf = ct_negative_weight_filter()
    snap = filter_state(ukf)
    with pytest.raises(CallSequenceError, match="tell_predict"):
        ukf.tell_predict(np.zeros((11, 5)))
    assert_filter_state(ukf, snap)
    X = ukf.ask_predict()
    F = [ct_fx(x, 1.0) for x in X]
    ukf.tell_predict(F)
    snap = filter_state(ukf)
    with pytest.raises(CallSequenceError, match="already told"):
        ukf.tell_predict(F)
    assert_filter_state(ukf, snap)
    with pytest.raises(CallSequenceError, match="tell_update"):
        ukf.tell_update(np.zeros((11, 2)), np.zeros(2))
    assert_filter_state(ukf, snap)
    Y = ukf.ask_update()
    H = [ct_hx(y) for y in Y]
    ukf.tell_update(H, ct_measurements(1)[0])
    snap = filter_state(ukf)
    with pytest.raises(CallSequenceError, match="already told"):
        ukf.tell_update(H, ct_measurements(1)[0])
    assert_filter_state(ukf, snap)


def test_asking_for_update_before_prediction_is_told():
    ukf = ct_negative_weight_filter()
    ukf.ask_predict()
    snap = filter_state(ukf)
    with pytest.raises(CallSequenceError, match="prediction is pending"):
        ukf.ask_update()
    assert_filter_state(ukf, snap)


@pytest.mark.parametrize("copier", [copy.deepcopy, lambda u: pickle.loads(pickle.dumps(u))])
def test_filter_pickles_between_ask_and_tell(copier):
    ukf = ct_negative_weight_filter()
    X = ukf.ask_predict()
    twin = copier(ukf)
    F = [ct_fx(x, 1.0) for x in X]
    ukf.tell_predict(F)
    twin.tell_predict(F)
    z = ct_measurements(1)[0]
    for f in (ukf, twin):
        f.tell_update([ct_hx(y) for y in f.ask_update()], z)
    np.testing.assert_array_equal(ukf.x, twin.x)
    np.testing.assert_array_equal(ukf.P1_2, twin.P1_2)


# == the hot path: the Kalman filter at tiny alpha, large states, matrices factored once ===========


def test_tiny_alpha_equals_the_kalman_filter():
    """alpha = 1e-3 makes the weights ~1e5 and of both signs; no downdate, still the KF.

    The rows scale as sqrt(W) * gamma * S = S / sqrt(2): no growth. Only the mean sums
    offsets with weights ~1/alpha^2 over offsets ~alpha: about 1e3 * eps per step.
    """
    kf, ukf, rng = linear_pair(alpha=1e-3)
    for _ in range(50):
        z = rng.standard_normal(2)
        kf.predict()
        ukf.predict()
        kf.update(z)
        ukf.update(z)
        np.testing.assert_allclose(ukf.x, kf.x, rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(ukf.P, kf.P, rtol=1e-9, atol=1e-12)


def test_a_large_state_keeps_its_covariance():
    """x[0] ~ 1e12 with P ~ 1: the update uses the redrawn set's exact offsets from x.

    x[0] is not measured but is correlated with what is, so the update changes its
    variance through the cross-covariance. Subtracting the rounded points (spacing 1.2e-4
    at 1e12) would perturb that by ~1e-4; the KF's P does not depend on x at all, and
    cond(P) < 10 leaves the factored update within ~1e-14 of it.
    """
    x0 = np.array([1e12, 0.5, -0.3])
    P0 = np.array([[2.0, 0.8, 0.0], [0.8, 1.0, 0.2], [0.0, 0.2, 1.5]])
    H = np.array([[0.0, 1.0, 0.0], [0.0, 0.5, 1.0]])
    R = 0.2 * np.eye(2)
    kf = KalmanFilter(3, 2)
    kf.H, kf.R, kf.P, kf.x = H, R, P0.copy(), x0.copy()
    ukf = SquareRootUKF(3, 2, 1.0, lambda x: H @ x, lambda x, dt: x, MerweScaledWeights())
    ukf.x, ukf.P, ukf.R = x0.copy(), P0.copy(), R
    z = np.array([0.9, -0.4])
    kf.update(z)
    ukf.update(z)
    assert abs(kf.P[0, 0] - P0[0, 0]) > 0.1  # the unmeasured variance did change
    np.testing.assert_allclose(ukf.P, kf.P, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(ukf.x, kf.x, rtol=1e-15)


def test_user_matrices_are_factored_once_not_per_step(monkeypatch):
    calls = []
    real = squkf.boundary.attributes.factor_covariance
    monkeypatch.setattr(
        squkf.boundary.attributes, "factor_covariance", lambda *a, **k: calls.append(a[1]) or real(*a, **k)
    )
    kf, ukf, rng = linear_pair()
    assert calls == ["P", "Q", "R"]  # assigned: factored once each
    calls.clear()
    _ = ukf.Q, ukf.R  # handing the matrices out must not make each step compare or refactor them
    for _ in range(20):
        ukf.predict()
        ukf.update(rng.standard_normal(2))
    assert calls == []
    ukf.Q[0, 0] *= 2.0  # an in-place edit is seen, and factored once
    ukf.predict()
    ukf.update(rng.standard_normal(2))
    ukf.predict()
    assert calls == ["Q"]
    np.testing.assert_allclose(ukf.Q1_2 @ ukf.Q1_2.T, np.diag([0.02, 0.01, 0.01]), rtol=1e-14)
