"""Property-based tests (hypothesis): linear models, smooth nonlinear models, junk inputs."""

import numpy as np
from filterpy.kalman import KalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from models import spd

from squkf import MerweScaledWeights, SquareRootUKF, SqukfError

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


JUNK = st.one_of(
    st.none(),
    st.floats(allow_nan=True, allow_infinity=True),
    st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), max_size=6),
    st.builds(
        lambda a, b, v: np.full((a, b), v),
        st.integers(0, 4),
        st.integers(0, 4),
        st.floats(allow_nan=True, allow_infinity=True),
    ),
    st.text(max_size=3),
)


@settings(max_examples=200, deadline=None)
@given(
    target=st.sampled_from(["x", "P", "Q", "R", "P1_2", "Q1_2", "R1_2", "z", "dt", "Qcall", "Rcall"]),
    value=JUNK,
)
def test_junk_inputs_raise_documented_errors_or_are_harmless(target, value):
    f = SquareRootUKF(3, 2, 1.0, lambda x: np.tanh(x[:2]), lambda x, dt: x + dt, MerweScaledWeights())
    f.x, f.P, f.Q, f.R = np.ones(3), np.eye(3), np.eye(3) * 0.1, np.eye(2)
    try:
        if target == "z":
            f.predict()
            f.update(value)
        elif target == "dt":
            f.predict(dt=value)
        elif target == "Qcall":
            f.predict(Q=value)
        elif target == "Rcall":
            f.predict()
            f.update(np.ones(2), R=value)
        else:
            setattr(f, target, value)
            f.predict()
            f.update(np.ones(2))
    except SqukfError:
        pass
    # whatever happened, the filter holds no NaN and a valid factor
    S = np.asarray(f.P1_2)
    assert np.all(np.isfinite(f.x)) and np.all(np.isfinite(S))
    assert np.all(np.diag(S) > 0) and np.all(np.triu(S, 1) == 0)
