"""A model on which filterpy's UKF dies with "not positive definite" runs to the end here."""

import numpy as np
import pytest
from filterpy.kalman import UnscentedKalmanFilter
from models import PRECISE_F, precise_filter

from squkf import NotPositiveDefiniteError, SquareRootUKF


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
