"""Partial measurements: NaN (or masked) components of ``z`` are missing, the others are used.

On a linear model the UKF is the Kalman filter (the unscented transform of a linear function is
exact), so the reference is filterpy's ``KalmanFilter`` given only the observed rows:
``H[obs]``, ``R[obs][:, obs]`` and ``z[obs]``. The two agree to rounding; ``RTOL`` allows for
a few hundred roundings on matrices of condition number ~1e2 (measured differences: ~1e-14).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from models import (
    LIN4_DT,
    LIN4_H,
    LIN4_P0,
    LIN4_Q,
    LIN4_R,
    LIN4_T,
    LIN4_X0,
    lin4_fx,
    lin4_kf,
    lin4_measurements,
    lin4_ukf,
)

from squkf import MerweScaledWeights, SquareRootUKF

RTOL = 1e-9
ZS = lin4_measurements()


def close(a, b, what):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    scale = max(1.0, float(np.max(np.abs(b))))
    np.testing.assert_allclose(a, b, rtol=0, atol=RTOL * scale, err_msg=what)


def with_missing(z, observed, masked):
    if masked:
        return np.ma.masked_array(z, mask=~observed)
    out = z.copy()
    out[~observed] = np.nan
    return out


patterns = st.lists(st.lists(st.booleans(), min_size=3, max_size=3), min_size=LIN4_T, max_size=LIN4_T)


@settings(max_examples=40, deadline=None)
@given(pattern=patterns, masked=st.booleans())
def test_missing_components_equal_kalman_filter_on_observed_rows(pattern, masked):
    ukf, kf = lin4_ukf(), lin4_kf()
    for z, obs in zip(ZS, pattern):
        obs = np.array(obs)
        ukf.predict()
        kf.predict()
        ukf.update(with_missing(z, obs, masked))
        if not obs.any():
            kf.update(None)
            np.testing.assert_array_equal(ukf.x_post, ukf.x_prior)
        else:
            kf.update(z[obs], R=LIN4_R[np.ix_(obs, obs)], H=LIN4_H[obs])
            close(ukf.y[obs], kf.y, "y")
            close(ukf.S[np.ix_(obs, obs)], kf.S, "S")
            close(ukf.K[:, obs], kf.K, "K")
            close(ukf.log_likelihood, kf.log_likelihood, "log_likelihood")
            close(ukf.mahalanobis, kf.mahalanobis, "mahalanobis")
        close(ukf.x, kf.x, "x")
        close(ukf.P, kf.P, "P")


@pytest.mark.parametrize("missing", [[0], [1], [2], [0, 2], [1, 2]])
def test_record_conventions_at_missing_components(missing):
    ukf = lin4_ukf()
    ukf.predict()
    z = ZS[0].copy()
    z[missing] = np.nan
    ukf.update(z)
    obs = np.ones(3, bool)
    obs[missing] = False
    assert np.all(np.isnan(ukf.y[~obs])) and np.all(np.isfinite(ukf.y[obs]))
    for name in ("S1_2", "S", "SI"):
        A = getattr(ukf, name)
        assert A.shape == (3, 3), name
        assert np.all(np.isnan(A[~obs, :])) and np.all(np.isnan(A[:, ~obs])), name
        assert np.all(np.isfinite(A[np.ix_(obs, obs)])), name
    np.testing.assert_array_equal(ukf.K[:, ~obs], 0.0)
    assert np.all(np.any(ukf.K[:, obs] != 0.0, axis=0))  # each observed column is a real gain
    # SI is the inverse of the observed block of S
    So, SIo = ukf.S[np.ix_(obs, obs)], ukf.SI[np.ix_(obs, obs)]
    close(SIo @ So, np.eye(obs.sum()), "SI @ S")
    # the likelihood and the distance are those of the observed components alone
    yo = ukf.y[obs]
    d2 = float(yo @ np.linalg.solve(So, yo))
    close(ukf.mahalanobis, np.sqrt(d2), "mahalanobis")
    k = obs.sum()
    ll = -0.5 * (k * np.log(2 * np.pi) + np.linalg.slogdet(So)[1] + d2)
    close(ukf.log_likelihood, ll, "log_likelihood")


def test_a_full_measurement_after_a_partial_one_has_full_records():
    ukf = lin4_ukf()
    ukf.predict()
    ukf.update(np.array([ZS[0][0], np.nan, ZS[0][2]]))
    ukf.predict()
    ukf.update(ZS[1])
    for name in ("y", "S1_2", "S", "SI", "K"):
        assert np.all(np.isfinite(getattr(ukf, name))), name
    assert np.all(ukf.K != 0.0)


def test_batch_filter_with_nan_entries_equals_the_step_loop():
    rng = np.random.default_rng(5)
    zs = np.array(ZS)
    zs[rng.random(zs.shape) < 0.35] = np.nan
    zs[3] = np.nan  # a step with no measurement at all
    a, b = lin4_ukf(), lin4_ukf()
    means, covs = a.batch_filter(zs)
    for k, z in enumerate(zs):
        b.predict()
        b.update(z)
        np.testing.assert_array_equal(means[k], b.x)
        np.testing.assert_array_equal(covs[k], b.P)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P, b.P)
    # and the loop is the Kalman filter on the observed rows
    kf = lin4_kf()
    for z in zs:
        obs = ~np.isnan(z)
        kf.predict()
        kf.update(z[obs] if obs.any() else None, R=LIN4_R[np.ix_(obs, obs)], H=LIN4_H[obs])
    close(b.x, kf.x, "x")
    close(b.P, kf.P, "P")


def test_missing_components_with_the_augmented_set():
    """The augmented set's update on the observed components equals a filter measuring those only."""
    obs = np.array([True, False, True])
    a = lin4_ukf()
    a.scheme = "augmented"
    b = SquareRootUKF(
        4,
        2,
        LIN4_DT,
        lambda x: (LIN4_H @ x)[obs],
        lin4_fx,
        MerweScaledWeights(alpha=1.0, beta=2.0, kappa=0.0),
    )
    b.scheme = "augmented"
    b.x, b.P, b.Q, b.R = LIN4_X0, LIN4_P0, LIN4_Q, LIN4_R[np.ix_(obs, obs)]
    for z in ZS:
        a.predict()
        b.predict()
        a.update(np.where(obs, z, np.nan))
        b.update(z[obs])
        close(a.x, b.x, "x")
        close(a.P, b.P, "P")
        close(a.log_likelihood, b.log_likelihood, "log_likelihood")
