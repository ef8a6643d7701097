"""Long ill-conditioned runs and Monte-Carlo consistency."""

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from models import (
    CT_P0,
    CT_Q,
    CT_R,
    CT_X0,
    PRECISE_F,
    PRECISE_H,
    PRECISE_Q,
    PRECISE_R,
    ct_fx,
    ct_hx,
    precise_fx,
    precise_fx_rows,
    precise_hx,
    precise_hx_rows,
)
from scipy.linalg import solve_discrete_are
from scipy.stats import chi2

from squkf import MerweScaledWeights, NotPositiveDefiniteError, SquareRootUKF


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
