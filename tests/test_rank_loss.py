"""A posterior that lost rank to rounding is an error (303), not a singular covariance committed.

Found by the junk-input property test: ``Q`` of 8e256 everywhere makes the
prior's small directions vanish below rounding, and the update then gave a
factor with a zero diagonal, which the filter committed as its ``P``.
"""

import numpy as np
import pytest
from models import tanh_filter

from squkf import Fleet, MerweScaledWeights, PosteriorFactorError, SquareRootUKF


def test_rank_lost_to_rounding_raises_and_changes_nothing():
    f = tanh_filter()
    f.predict()
    x, S = f.x.copy(), f.P1_2.copy()
    with pytest.raises(PosteriorFactorError) as info:
        f.update(np.ones(2))
    assert info.value.errno == 303
    np.testing.assert_array_equal(f.x, x)
    np.testing.assert_array_equal(f.P1_2, S)
    assert np.all(np.diag(f.P1_2) > 0)


def test_in_a_fleet_only_that_filter_is_flagged():
    fleet = Fleet(3, 3, 2, 1.0, lambda X: np.tanh(X[..., :2]), lambda X, dt: X + dt, MerweScaledWeights())
    fleet.x, fleet.R = np.ones(3), np.eye(2)
    Q = np.stack([np.eye(3) * 0.1, np.full((3, 3), 8.071510225007634e256), np.eye(3) * 0.1])
    fleet.Q = Q
    fleet.predict()
    fleet.update(np.ones((3, 2)))
    np.testing.assert_array_equal(fleet.failed, [False, True, False])
    assert "303" in fleet.failure[1] or "rank" in fleet.failure[1]


def test_an_exactly_measured_component_may_have_zero_variance():
    """With a singular R the posterior is singular by right: no error."""
    f = SquareRootUKF(2, 2, 1.0, lambda x: x, lambda x, dt: x, MerweScaledWeights())
    f.R = np.diag([0.5, 0.0])
    f.Q = np.zeros((2, 2))
    f.predict()
    f.update(np.array([0.3, 0.7]))
    assert f.P[1, 1] == pytest.approx(0.0, abs=1e-15)
    assert f.x[1] == pytest.approx(0.7)
