"""The measurement update (squkf.measurement): the joint-QR update is the published update.

The reference is the UKF's measurement update in covariance form, written out here; the user-UT
path agrees too. Missing measurements are in tests/test_missing_data.py.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from squkf import MerweScaledWeights, sqrt_unscented_transform
from squkf.generators import Redrawn
from squkf.measurement import measurement_update


def covariance_form_update(x, S, sset, H, z, R, residual=None):
    """The UKF measurement update as published, in covariance form (no factors)."""
    zhat = sset.Wm @ H
    dz = H - zhat
    dx = sset.sigmas - x
    Pzz = (dz.T * sset.Wc) @ dz + R
    Pxz = (dx.T * sset.Wc) @ dz
    K = np.linalg.solve(Pzz, Pxz.T).T
    return x + K @ (z - zhat), S @ S.T - K @ Pzz @ K.T, K, Pzz


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 6),
    m=st.integers(1, 4),
    alpha=st.floats(0.01, 1.0),
    seed=st.integers(0, 2**16),
)
def test_joint_qr_update_is_the_published_update(n, m, alpha, seed):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    S = np.linalg.cholesky(A @ A.T / n + 0.5 * np.eye(n))
    x = rng.standard_normal(n)
    B = rng.standard_normal((m, n))
    R1_2 = np.linalg.cholesky(np.eye(m) * 0.3 + 0.1 * np.ones((m, m)))
    family = MerweScaledWeights(alpha, 2.0, 0.0)
    sset = Redrawn().second_set(x, S, family=family)
    H = np.tanh(sset.sigmas @ B.T)  # mildly nonlinear, bounded
    z = rng.standard_normal(m)
    post = measurement_update(x, S, sset, H, z, R1_2)
    x_ref, P_ref, K_ref, Pzz = covariance_form_update(x, S, sset, H, z, R1_2 @ R1_2.T)
    # cond(P) <= ~20 and cond(Pzz) <= ~40 here: rounding stays near 1e-13; 1e-9 is generous
    np.testing.assert_allclose(post.Sy @ post.Sy.T, Pzz, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(post.gain(), K_ref, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(post.x, x_ref, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(post.S @ post.S.T, P_ref, rtol=1e-9, atol=1e-11)
    assert np.all(np.triu(post.S, 1) == 0) and np.all(np.diag(post.S) >= 0)
    # the user-UT path (cross-covariance, then the QR form with the gain) agrees too
    via_ut = measurement_update(x, S, sset, H, z, R1_2, UT=sqrt_unscented_transform)
    np.testing.assert_allclose(via_ut.x, post.x, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(via_ut.S @ via_ut.S.T, post.S @ post.S.T, rtol=1e-9, atol=1e-12)
