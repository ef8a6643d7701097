"""The measurement update (squkf.measurement): the joint-QR update is the published update.

The reference is the UKF's measurement update in covariance form, written out here; the user-UT
path agrees too. With a ``residual_x`` or ``state_add`` (or a rewritten set) the update is the
downdate form, filterpy's ``P_prior - K S K^T``, or error 303 where that is indefinite. Missing
measurements are in tests/test_missing_data.py.
"""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest
from hypothesis import assume, event, given, settings
from hypothesis import strategies as st

from squkf import MerweScaledWeights, PosteriorFactorError, sqrt_unscented_transform
from squkf.angles import AngleAdd, AngleResidual, wrap
from squkf.generators import Redrawn
from squkf.measurement import gain_from_factors, measurement_update


def covariance_form_update(x, S, sset, H, z, R, residual=None):
    """The UKF measurement update as published, in covariance form (no factors)."""
    zhat = sset.Wm @ H
    dz = H - zhat
    dx = sset.sigmas - x
    Pzz = (dz.T * sset.Wc) @ dz + R
    Pxz = (dx.T * sset.Wc) @ dz
    K = np.linalg.solve(Pzz, Pxz.T).T
    return x + K @ (z - zhat), S @ S.T - K @ Pzz @ K.T, K, Pzz


def random_update(n: int, m: int, alpha: float, seed: int) -> tuple:
    """A random prior ``(x, S)``, its redrawn Merwe set, images mildly nonlinear and bounded, ``z`` and
    ``R1_2``."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    S = np.linalg.cholesky(A @ A.T / n + 0.5 * np.eye(n))
    x = rng.standard_normal(n)
    B = rng.standard_normal((m, n))
    R1_2 = np.linalg.cholesky(np.eye(m) * 0.3 + 0.1 * np.ones((m, m)))
    sset = Redrawn().second_set(x, S, family=MerweScaledWeights(alpha, 2.0, 0.0))
    H = np.tanh(sset.sigmas @ B.T)
    z = rng.standard_normal(m)
    return x, S, sset, H, z, R1_2


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 6),
    m=st.integers(1, 4),
    alpha=st.floats(0.01, 1.0),
    seed=st.integers(0, 2**16),
)
def test_joint_qr_update_is_the_published_update(n, m, alpha, seed):
    x, S, sset, H, z, R1_2 = random_update(n, m, alpha, seed)
    post = measurement_update(x, S, sset, H, z, R1_2)
    x_ref, P_ref, K_ref, Pzz = covariance_form_update(x, S, sset, H, z, R1_2 @ R1_2.T)

    # cond(P) <= ~20 and cond(Pzz) <= ~40 here: rounding stays near 1e-13; 1e-9 is generous. The
    # reference's weighted sums, though, round to about eps * sum |Wc| of their largest entry, and a small
    # alpha makes that sum large (alpha = 0.01, n = 6: 2e4, and 7.5e-12 on an entry of 5e-3): each
    # comparison allows 64 times that as well
    def tol(A):
        return 64 * np.finfo(float).eps * np.sum(np.abs(sset.Wc)) * np.max(np.abs(A))

    np.testing.assert_allclose(post.Sy @ post.Sy.T, Pzz, rtol=1e-9, atol=max(1e-12, tol(Pzz)))
    K = gain_from_factors(post.Sy, post.L21)
    np.testing.assert_allclose(K, K_ref, rtol=1e-9, atol=max(1e-11, tol(K_ref)))
    np.testing.assert_allclose(post.x, x_ref, rtol=1e-9, atol=max(1e-11, tol(x_ref)))
    np.testing.assert_allclose(post.S @ post.S.T, P_ref, rtol=1e-9, atol=max(1e-11, tol(P_ref)))
    assert np.all(np.triu(post.S, 1) == 0) and np.all(np.diag(post.S) >= 0)
    # the user-UT path (cross-covariance, then the QR form with the gain) agrees too
    via_ut = measurement_update(x, S, sset, H, z, R1_2, UT=sqrt_unscented_transform)
    np.testing.assert_allclose(via_ut.x, post.x, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(via_ut.S @ via_ut.S.T, post.S @ post.S.T, rtol=1e-9, atol=1e-12)


# -- the downdate form: a residual_x or state_add, a rewritten set ---------------------------------


def residual_form_update(x, S, sset, H, z, R, residual_x, state_add=np.add):
    """filterpy's update in covariance form, its deviations ``residual_x(sigma, x)``: ``P - K S K^T``."""
    zhat = sset.Wm @ H
    dz = H - zhat
    dx = np.array([residual_x(s, x) for s in sset.sigmas])
    Pzz = (dz.T * sset.Wc) @ dz + R
    K = np.linalg.solve(Pzz, ((dx.T * sset.Wc) @ dz).T).T
    return state_add(x, K @ (z - zhat)), S @ S.T - K @ Pzz @ K.T


@settings(max_examples=80, deadline=None)
@given(
    n=st.integers(1, 4),
    m=st.integers(1, 3),
    alpha=st.sampled_from([0.5, 1.0]),
    spread=st.floats(0.5, 6.0),
    add=st.booleans(),
    ut=st.booleans(),
    seed=st.integers(0, 2**16),
)
def test_with_residual_x_the_update_is_P_prior_minus_KSK(n, m, alpha, spread, add, ut, seed):
    """Whatever the wrapped deviations (an angle whose points pass pi when ``spread`` is large), and
    with a user's UT too: the posterior is ``P_prior - K S K^T``, or error 303 where that is indefinite."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    S = np.linalg.cholesky(A @ A.T / n + 0.5 * np.eye(n))
    S[:, 0] *= spread  # the angle's spread (and its correlations)
    x = rng.uniform(-np.pi, np.pi, n)
    B = rng.standard_normal((m, n))
    R1_2 = np.linalg.cholesky(np.eye(m) * 0.3 + 0.1 * np.ones((m, m)))
    state_add = AngleAdd([0]) if add else None
    sset = Redrawn().second_set(x, S, family=MerweScaledWeights(alpha, 2.0, 0.0), state_add=state_add)
    H = np.tanh(np.c_[np.cos(sset.sigmas[:, :1]), sset.sigmas[:, 1:]] @ B.T)
    z = rng.standard_normal(m)
    x_ref, P_ref = residual_form_update(
        x, S, sset, H, z, R1_2 @ R1_2.T, AngleResidual([0]), state_add or np.add
    )
    call = partial(
        measurement_update, x, S, sset, H, z, R1_2, residual_x=AngleResidual([0]), state_add=state_add,
        UT=sqrt_unscented_transform if ut else None,
    )  # fmt: skip
    scale = np.abs(S @ S.T).max()
    lowest = np.linalg.eigvalsh(P_ref).min()
    if lowest < -1e-8 * scale:  # indefinite: filterpy would return it; the downdate refuses
        event("indefinite: error 303")
        with pytest.raises(PosteriorFactorError) as err:
            call()
        assert err.value.errno == 303
        return
    assume(lowest > 1e-6 * scale)  # (near singular: either answer is rounding)
    event("positive definite")
    post = call()
    # one downdate of the prior's factor per column of L21: rounding near 1e-15 of |P_prior|
    np.testing.assert_allclose(post.S @ post.S.T, P_ref, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(wrap(post.x - x_ref), 0.0, atol=1e-9 * max(1.0, np.abs(x_ref).max()))


def test_a_rewritten_set_takes_the_downdate_form():
    """A set whose points the caller wrote keeps the prior factor: ``P_prior - K S K^T`` with its points."""
    rng = np.random.default_rng(4)
    n, m = 3, 2
    A = rng.standard_normal((n, n))
    S = np.linalg.cholesky(A @ A.T / n + 0.5 * np.eye(n))
    x = rng.standard_normal(n)
    B = rng.standard_normal((m, n))
    R1_2 = np.linalg.cholesky(np.eye(m) * 0.3)
    drawn = Redrawn().second_set(x, S, family=MerweScaledWeights(1.0, 2.0, 0.0))
    written = drawn.rewritten(drawn.sigmas + 0.3 * rng.standard_normal(drawn.sigmas.shape))
    assert not written.moments_exact and written.offsets is None and written.rows is drawn.rows
    H = np.tanh(written.sigmas @ B.T)
    z = rng.standard_normal(m)
    post = measurement_update(x, S, written, H, z, R1_2)
    x_ref, P_ref = residual_form_update(x, S, written, H, z, R1_2 @ R1_2.T, np.subtract)
    np.testing.assert_allclose(post.S @ post.S.T, P_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(post.x, x_ref, rtol=0, atol=1e-12)
    # the array form on the written rows is another posterior: the downdate form is what was taken
    joint = measurement_update(x, S, drawn._replace(sigmas=written.sigmas, offsets=None), H, z, R1_2)
    assert np.abs(joint.S @ joint.S.T - P_ref).max() > 1e-3


#: A user's UT with a set that reproduces the prior takes the downdate form (filterpy's ``P - K S K^T``
#: with the UT's ``S``); it took the gain form before (the QR of ``Dx - Dz K^T`` and ``K R1_2``, the same
#: posterior in exact arithmetic when the UT's ``S`` is the images'). Measured over 300 random updates of
#: this test's kind (n <= 6, m <= 4, alpha down to 0.01): x, y, Sy and the likelihood the same bits, P
#: at most 7.1e-14 relative. 1e-11 leaves a margin far below a real difference.
UT_ROUNDING = 1e-11


def gain_form_update(x, sset, H, z, R1_2):
    """The gain form a user's UT took before (Joseph-like), in covariance form: ``sum Wc (Dx - Dz K^T)
    (Dx - Dz K^T)^T + K R K^T``, the UT being :func:`sqrt_unscented_transform`."""
    zp, Sy = sqrt_unscented_transform(H, sset.Wm, sset.Wc, R1_2)
    Dz, Dx = H - zp, sset.sigmas - x
    K = np.linalg.solve(Sy @ Sy.T, ((Dx.T * sset.Wc) @ Dz).T).T
    E = Dx - Dz @ K.T
    return x + K @ (z - zp), (E.T * sset.Wc) @ E + K @ R1_2 @ R1_2.T @ K.T


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 6), m=st.integers(1, 4), alpha=st.floats(0.01, 1.0), seed=st.integers(0, 2**16))
def test_a_users_UT_takes_the_downdate_form_the_gain_forms_posterior_to_rounding(n, m, alpha, seed):
    x, S, sset, H, z, R1_2 = random_update(n, m, alpha, seed)
    post = measurement_update(x, S, sset, H, z, R1_2, UT=sqrt_unscented_transform)
    x_ref, P_ref = gain_form_update(x, sset, H, z, R1_2)
    P = post.S @ post.S.T
    assert np.abs(P - P_ref).max() <= UT_ROUNDING * np.abs(P_ref).max()
    assert np.abs(post.x - x_ref).max() <= UT_ROUNDING * max(1.0, np.abs(x_ref).max())
    # ... and it is filterpy's formula with the UT's S: P_prior - K S K^T
    K = gain_from_factors(post.Sy, post.L21)
    np.testing.assert_allclose(P, S @ S.T - K @ post.Sy @ post.Sy.T @ K.T, rtol=0, atol=1e-12)
