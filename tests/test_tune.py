"""``squkf.tune.log_likelihood``: K candidate noise settings in one fleet pass (issue 37, in part).

A candidate's total equals the same filter run alone bit for bit (a fleet equals its single
filters), and the sum of filterpy's per-step ``log_likelihood`` to 1e-9 relative (the two
arithmetics differ by rounding at each of T steps).
"""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from models import assert_filter_state, filter_state

from squkf import (
    CallSequenceError,
    FleetStepError,
    MerweScaledWeights,
    NonFiniteError,
    ParameterError,
    ShapeError,
    SquareRootUKF,
    simulate,
    tune,
)

T = 60
Q0 = Q_discrete_white_noise(2, 1.0, 1.0, block_size=2)


def cv_fx(x, dt):
    F = np.kron(np.eye(2), [[1.0, dt], [0.0, 1.0]])
    return F @ x


def range_bearing(x):
    return np.array([np.hypot(x[0], x[2]), np.arctan2(x[2], x[0])])


def template(cls=SquareRootUKF, **kw):
    points = MerweScaledSigmaPoints(4, 0.5, 2.0, 0.0)
    f = cls(4, 2, 1.0, range_bearing, cv_fx, points, **kw)
    f.x = np.array([50.0, 1.0, 30.0, -1.0])
    f.P = np.diag([4.0, 1.0, 4.0, 1.0])
    f.Q = 0.1 * Q0
    f.R = np.diag([1.0, 1e-4])
    return f


@pytest.fixture(scope="module")
def recordings():
    return simulate(template(), T, 3, seed=7)[1]


CANDIDATES_Q = np.stack([s * 0.1 * Q0 for s in (0.3, 1.0, 3.0)])
CANDIDATES_R = np.stack([np.diag([r, 1e-4]) for r in (0.5, 1.0, 2.0)])


def alone(Q, R, z, burn_in=0):
    f = template()
    f.Q, f.R = Q, R
    return float(np.sum(f.batch_filter(z).log_likelihood[burn_in:]))


def test_each_candidate_is_its_filter_alone_bit_for_bit(recordings):
    values, failures = tune.log_likelihood(template(), recordings[0], Qs=CANDIDATES_Q, Rs=CANDIDATES_R)
    assert failures == {} and values.shape == (3,)
    for k in range(3):
        assert values[k] == alone(CANDIDATES_Q[k], CANDIDATES_R[k], recordings[0])


def test_each_candidate_is_filterpys_sum_of_log_likelihoods(recordings):
    values, _ = tune.log_likelihood(template(), recordings[0], Rs=CANDIDATES_R)
    for k in range(3):
        f = template(UnscentedKalmanFilter)
        f.R = CANDIDATES_R[k]
        total = 0.0
        for z in recordings[0]:
            f.predict()
            f.update(z)
            total += f.log_likelihood
        assert values[k] == pytest.approx(total, rel=1e-9)


def test_several_recordings_give_one_column_each_and_burn_in_leaves_steps_out(recordings):
    values, _ = tune.log_likelihood(template(), recordings, Qs=CANDIDATES_Q, burn_in=5)
    assert values.shape == (3, 3)
    for k in range(3):
        for s in range(3):
            assert values[k, s] == alone(CANDIDATES_Q[k], template().R, recordings[s], burn_in=5)


def test_recordings_of_different_lengths_are_nan_padded(recordings):
    short = [recordings[0], recordings[1][:40]]
    padded = recordings[:2].copy()
    padded[1, 40:] = np.nan
    a, _ = tune.log_likelihood(template(), short, Rs=CANDIDATES_R)
    b, _ = tune.log_likelihood(template(), padded, Rs=CANDIDATES_R)
    np.testing.assert_array_equal(a, b)
    assert a[1, 1] == alone(template().Q, CANDIDATES_R[1], recordings[1][:40])


def test_a_candidate_that_is_not_a_covariance_gets_minus_inf_and_the_others_go_on(recordings):
    Rs = CANDIDATES_R.copy()
    Rs[1] = np.diag([-1.0, 1e-4])
    values, failures = tune.log_likelihood(template(), recordings[0], Rs=Rs)
    assert values[1] == -np.inf and list(failures) == [1] and "Rs[1]" in failures[1]
    assert values[0] == alone(template().Q, Rs[0], recordings[0])
    assert values[2] == alone(template().Q, Rs[2], recordings[0])


def test_a_candidate_that_fails_numerically_gets_minus_inf_and_its_reason(recordings):
    def fragile(x, dt):  # a model that breaks far from where the data are
        out = cv_fx(x, dt)
        return np.where(np.abs(out) > 1e4, np.nan, out)

    f = template()
    f.fx = fragile
    Qs = np.stack([0.1 * Q0, 1e9 * Q0])
    values, failures = tune.log_likelihood(f, recordings[0], Qs=Qs)
    assert np.isfinite(values[0]) and values[1] == -np.inf and list(failures) == [1]
    assert "fx" in failures[1]
    with pytest.raises(FleetStepError, match="every candidate failed"):
        tune.log_likelihood(f, recordings[0], Qs=Qs[1:])


def test_bad_input_is_named_and_the_template_is_unchanged(recordings):
    f = template()
    f.batch_filter(recordings[0][:3])
    snap = filter_state(f)
    for kwargs, exc, match in [
        ({"zs": recordings[0][:, :1]}, ShapeError, "zs"),
        ({"zs": "abc"}, ShapeError, "zs"),
        ({"zs": np.full((T, 2), np.nan)}, NonFiniteError, "zs"),
        ({"zs": recordings[0], "Qs": np.eye(4)}, ShapeError, "Qs"),
        ({"zs": recordings[0], "Qs": CANDIDATES_Q, "Rs": CANDIDATES_R[:2]}, ShapeError, "Rs"),
        ({"zs": recordings[0], "burn_in": T}, ParameterError, "burn_in"),
        ({"zs": recordings[0], "burn_in": -1}, ParameterError, "burn_in"),
    ]:
        with pytest.raises(exc, match=match):
            tune.log_likelihood(f, **kwargs)
        assert_filter_state(f, snap)
    f.gate = 0.99
    with pytest.raises(ParameterError, match="gate"):
        tune.log_likelihood(f, recordings[0])
    f.gate = None
    f.ask_predict()
    with pytest.raises(CallSequenceError):
        tune.log_likelihood(f, recordings[0])


def test_the_maximum_is_near_the_truth():
    """On a linear-Gaussian recording of 2,000 steps the likelihood peaks at the R that made it."""
    f = SquareRootUKF(
        2, 1, 1.0, lambda x: x[:1], lambda x, dt: np.array([x[0] + x[1], x[1]]), MerweScaledWeights()
    )
    f.Q, f.R = np.diag([0.0, 0.01]), [[1.0]]
    zs = simulate(f, 2000, 1, seed=3)[1][0]
    grid = np.array([0.7, 0.85, 1.0, 1.15, 1.3])
    values, _ = tune.log_likelihood(f, zs, Rs=grid[:, None, None])
    assert grid[np.argmax(values)] == 1.0
