"""SquareRootUKF agrees with filterpy 2.0.0's UnscentedKalmanFilter given the same points object.

Both filters run the same algorithm (filterpy redraws the second set from the
predicted mean and covariance, as g13ej's default does); they differ only in
arithmetic: covariances versus QR/rank-1 factor updates. Each step introduces
relative differences of order eps * cond(P) (~1e-16 * 1e4 here); the
measurement updates contract them, so after hundreds of steps the normwise
relative difference stays many orders below the 1e-8 asserted.
"""

import numpy as np
import pytest
from filterpy.kalman import (
    JulierSigmaPoints,
    MerweScaledSigmaPoints,
    SimplexSigmaPoints,
    UnscentedKalmanFilter,
)
from models import CT_P0, CT_Q, CT_R, CT_X0, Robot, ct_filter, ct_fx, ct_hx, example_data, l96_fx, l96_hx, rel

from squkf import SquareRootUKF

RTOL = 1e-8


def run_pair(points, fx, hx, dim_x, dim_z, dt, x0, P0, Q, R, truth_fn, steps, seed, fx_args=None):
    rng = np.random.default_rng(seed)
    fp = UnscentedKalmanFilter(dim_x, dim_z, dt, hx, fx, points)
    sq = SquareRootUKF(dim_x, dim_z, dt, hx, fx, points)
    for f in (fp, sq):
        f.x = x0.copy()
        f.P = P0
        f.Q = Q
        f.R = R
    xt = truth_fn.x0.copy()
    worst = 0.0
    for _ in range(steps):
        xt = truth_fn.step(xt, rng)
        z = hx(xt) + rng.multivariate_normal(np.zeros(dim_z), R)
        for f in (fp, sq):
            f.predict(**(fx_args or {}))
        worst = max(worst, rel(sq.x_prior, fp.x_prior), rel(sq.P_prior, fp.P_prior))
        for f in (fp, sq):
            f.update(z)
        worst = max(worst, rel(sq.x, fp.x), rel(sq.P, fp.P))
        assert worst < RTOL
    return worst


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
    assert worst < RTOL


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
    assert worst < RTOL


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
    assert worst < RTOL


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
