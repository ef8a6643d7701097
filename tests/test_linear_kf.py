"""On linear-Gaussian models the square-root UKF is the Kalman filter.

The unscented transform of a linear map is exact for every family whose unit
points have weighted mean 0 and weighted covariance I, so SquareRootUKF must
equal filterpy's KalmanFilter up to rounding. The models are well conditioned
(cond(P) < 1e3), so 100 steps of O(eps * cond) per-step differences stay far
below the asserted 1e-9 relative.
"""

import numpy as np
import pytest
from filterpy.kalman import JulierSigmaPoints, KalmanFilter, MerweScaledSigmaPoints, SimplexSigmaPoints
from models import random_linear_model

from squkf import (
    Augmented,
    CubatureWeights,
    JulierWeights,
    MerweScaledWeights,
    Redrawn,
    SimplexWeights,
    SquareRootUKF,
)

RTOL = 1e-9


def run(points, scheme, seed=0, steps=100, n=4, m=2, vectorized=False):
    F, H, Q, R = random_linear_model(seed, n, m)
    rng = np.random.default_rng(seed + 100)
    kf = KalmanFilter(n, m)
    kf.F, kf.H, kf.Q, kf.R = F, H, Q, R
    kf.P = np.eye(n) * 2.0
    kf.x = np.ones(n)
    if vectorized:
        ukf = SquareRootUKF(
            n, m, 1.0, lambda X: X @ H.T, lambda X, dt: X @ F.T, points, scheme=scheme, vectorized=True
        )
    else:
        ukf = SquareRootUKF(n, m, 1.0, lambda x: H @ x, lambda x, dt: F @ x, points, scheme=scheme)
    ukf.x = np.ones(n)
    ukf.P = kf.P
    ukf.Q, ukf.R = Q, R
    worst = 0.0
    for k in range(steps):
        z = rng.standard_normal(m) * 2.0
        kf.predict()
        ukf.predict()
        kf.update(z)
        ukf.update(z)
        for a, b in ((ukf.x, kf.x), (ukf.P, kf.P)):
            worst = max(worst, np.max(np.abs(a - b)) / np.max(np.abs(b)))
        assert worst < RTOL, (k, worst)
    return worst


FAMILIES = {
    "merwe-default": lambda n: MerweScaledWeights(),
    "merwe-small-alpha": lambda n: MerweScaledWeights(alpha=0.1, beta=2.0, kappa=0.0),
    "julier": lambda n: JulierWeights(kappa=1.0),
    "simplex": lambda n: SimplexWeights(),
    "cubature": lambda n: CubatureWeights(),
    "filterpy-merwe": lambda n: MerweScaledSigmaPoints(n, 0.3, 2.0, 3.0 - n),
    "filterpy-julier": lambda n: JulierSigmaPoints(n, 0.5),
    "filterpy-simplex": lambda n: SimplexSigmaPoints(n),
}
SYMMETRIC = ["merwe-default", "merwe-small-alpha", "julier", "filterpy-merwe", "filterpy-julier"]


@pytest.mark.parametrize("family", list(FAMILIES))
def test_redrawn_equals_kalman_filter(family):
    run(FAMILIES[family](4), "redrawn")


@pytest.mark.parametrize("family", SYMMETRIC)
def test_augmented_equals_kalman_filter(family):
    run(FAMILIES[family](4), "augmented")


def test_vectorized_equals_kalman_filter():
    run(MerweScaledWeights(alpha=0.5), "redrawn", vectorized=True)
    run(MerweScaledWeights(alpha=0.5), "augmented", vectorized=True)


def test_second_set_with_its_own_weights_equals_kalman_filter():
    # g13ej's ROPT(5..7): a second set with its own kappa/alpha/beta
    run(MerweScaledWeights(), Redrawn(weights=MerweScaledWeights(alpha=0.2, beta=1.0, kappa=1.0)))
    run(MerweScaledWeights(), Redrawn(weights=CubatureWeights()))


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
    run(MerweScaledWeights(), "redrawn", n=1, m=1)
    run(MerweScaledWeights(), "augmented", n=1, m=1)


def test_more_measurements_than_states():
    run(MerweScaledWeights(), "redrawn", n=2, m=5)
