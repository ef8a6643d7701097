"""The lean hot path: the row forms, the joint-QR update, exact offsets, nothing redone per step.

References are written out here in covariance form (the UKF equations as
published) or are filterpy's linear ``KalmanFilter``; tolerances follow from
the conditioning of each case (stated where it is set).
"""

import warnings
from fractions import Fraction

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from hypothesis import given, settings
from hypothesis import strategies as st
from models import linear_pair

import squkf.covariance
from squkf import MerweScaledWeights, SquareRootUKF, sqrt_unscented_transform
from squkf.errors import DowndateError
from squkf.generators import Redrawn
from squkf.linalg import all_finite
from squkf.measurement import measurement_update
from squkf.rows import weight_rows as weight_plan
from squkf.transform import transform_factor

EPS = np.finfo(float).eps


def weighted_cov(X, Wm, Wc):
    mean = Wm @ X
    D = X - mean
    return mean, (D.T * Wc) @ D


def exact_weighted_cov(X, Wm, Wc):
    """Weighted mean and covariance in exact rational arithmetic (the floats as given)."""
    Xf = [[Fraction(float(v)) for v in row] for row in X]
    Wmf, Wcf = [Fraction(float(w)) for w in Wm], [Fraction(float(w)) for w in Wc]
    d = len(Xf[0])
    mean = [sum(w * row[j] for w, row in zip(Wmf, Xf)) for j in range(d)]
    D = [[row[j] - mean[j] for j in range(d)] for row in Xf]
    P = [[sum(w * r[i] * r[j] for w, r in zip(Wcf, D)) for j in range(d)] for i in range(d)]
    return np.array([float(v) for v in mean]), np.array([[float(v) for v in r] for r in P])


def gram_tol(D, w, rho, Wc=None):
    """Rounding bound for sum_k w_k D_k D_k^T when each row is off by up to eps * rho.

    The rows hold a mean (or the central form's offset mu) summed from weights as large
    as 1/alpha^2 times offsets: rho = sum_i |Wm_i| |X_i - X_0| bounds that sum. Then
    each term is off by about eps |w_k| |D_k| (|D_k| + rho); a sum of N terms adds at most
    gamma_N ~ N eps of their sizes (Higham), so 16 N eps leaves a few gamma_N of slack.
    The central form's own weight c = sum(Wc) - 2 is a sum of weights too: off by up to
    N eps sum|Wc|, times mu mu^T (at most rho^2); pass Wc to include that.
    """
    size = np.abs(D).max(axis=1)
    gamma = 16 * D.shape[0] * EPS
    extra = 0.0 if Wc is None else float(np.abs(Wc).sum()) * rho**2
    return gamma * (float(np.abs(w) @ (size * (size + rho))) + extra)


def form_rows(X, Wm, form):
    """The mean and unscaled rows of a row form, written out plainly (the reference)."""
    if form.central:
        E = X[1:] - X[0]
        mu = Wm[1:] @ E
        return X[0] + mu, np.vstack([E, mu])
    mean = X[0] + Wm @ (X - X[0])
    return mean, X - mean


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 6),
    alpha=st.floats(1e-3, 1.0),
    beta=st.floats(0.0, 3.0),
    kappa=st.floats(-0.5, 3.0),
    seed=st.integers(0, 2**16),
)
def test_row_forms_reproduce_the_weighted_covariance(n, alpha, beta, kappa, seed):
    Wm, Wc = MerweScaledWeights(alpha, beta, kappa).weights(n)
    X = np.random.default_rng(seed).standard_normal((2 * n + 1, n))
    mean, P = exact_weighted_cov(X, Wm, Wc)
    plan = weight_plan(Wm, Wc)
    # Merwe: the central form's extra weight is beta - alpha**2, so it needs no downdate then
    assert plan.central_form is not None
    assert plan.central_form.weights[-1] == pytest.approx(beta - alpha**2, abs=1e-12 * np.abs(Wc).sum())
    if beta >= alpha**2:
        assert plan.best.central and plan.best.neg.size == 0 and plan.fast
    rho = float(np.abs(Wm) @ np.abs(X - X[0]).max(axis=1))
    mean_tol = 64 * EPS * (np.abs(X).max() + rho)
    form = plan.best  # the form the filter uses
    best_mean, D = form_rows(X, Wm, form)
    tol = gram_tol(D, form.weights, rho, Wc if form.central else None)
    np.testing.assert_allclose((D.T * form.weights) @ D, P, rtol=0, atol=tol)
    np.testing.assert_allclose(best_mean, mean, rtol=0, atol=mean_tol)
    # the kernel: the same rows, one QR and a downdate per negative row. Negative weights can
    # make the weighted sum indefinite; then no factor exists and the kernel must say so
    lowest = float(np.linalg.eigvalsh(P)[0])
    if lowest > n * tol:
        kernel_mean, S = transform_factor(X, plan)
        np.testing.assert_allclose(kernel_mean, mean, rtol=0, atol=mean_tol)
        np.testing.assert_allclose(S @ S.T, P, rtol=0, atol=4 * tol)
    elif lowest < -n * tol:
        with pytest.raises(DowndateError):
            transform_factor(X, plan)
    D, form = X - best_mean, plan.mean_form  # the mean form (what the hooks use)
    assert not form.central
    if alpha >= 0.1:
        # for tiny alpha the mean form cancels weights of +-1/alpha^2 and is off by ~1e-6
        # (which is why the filter prefers the central form); here the weights are <= ~1e2
        np.testing.assert_allclose((D.T * form.weights) @ D, P, rtol=0, atol=gram_tol(D, form.weights, rho))


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


def test_tiny_alpha_equals_the_kalman_filter():
    """alpha = 1e-3 makes the weights ~1e5 and of both signs; no downdate, still the KF.

    The rows scale as sqrt(W) * gamma * S = S / sqrt(2): no growth. Only the mean sums
    offsets with weights ~1/alpha^2 over offsets ~alpha: about 1e3 * eps per step.
    """
    kf, ukf, rng = linear_pair(alpha=1e-3)
    for _ in range(50):
        z = rng.standard_normal(2)
        kf.predict()
        ukf.predict()
        kf.update(z)
        ukf.update(z)
        np.testing.assert_allclose(ukf.x, kf.x, rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(ukf.P, kf.P, rtol=1e-9, atol=1e-12)


def test_a_large_state_keeps_its_covariance():
    """x[0] ~ 1e12 with P ~ 1: the update uses the redrawn set's exact offsets from x.

    x[0] is not measured but is correlated with what is, so the update changes its
    variance through the cross-covariance. Subtracting the rounded points (spacing 1.2e-4
    at 1e12) would perturb that by ~1e-4; the KF's P does not depend on x at all, and
    cond(P) < 10 leaves the factored update within ~1e-14 of it.
    """
    x0 = np.array([1e12, 0.5, -0.3])
    P0 = np.array([[2.0, 0.8, 0.0], [0.8, 1.0, 0.2], [0.0, 0.2, 1.5]])
    H = np.array([[0.0, 1.0, 0.0], [0.0, 0.5, 1.0]])
    R = 0.2 * np.eye(2)
    kf = KalmanFilter(3, 2)
    kf.H, kf.R, kf.P, kf.x = H, R, P0.copy(), x0.copy()
    ukf = SquareRootUKF(3, 2, 1.0, lambda x: H @ x, lambda x, dt: x, MerweScaledWeights())
    ukf.x, ukf.P, ukf.R = x0.copy(), P0.copy(), R
    z = np.array([0.9, -0.4])
    kf.update(z)
    ukf.update(z)
    assert abs(kf.P[0, 0] - P0[0, 0]) > 0.1  # the unmeasured variance did change
    np.testing.assert_allclose(ukf.P, kf.P, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(ukf.x, kf.x, rtol=1e-15)


def test_user_matrices_are_factored_once_not_per_step(monkeypatch):
    calls = []
    real = squkf.covariance.factor_covariance
    monkeypatch.setattr(
        squkf.covariance, "factor_covariance", lambda *a, **k: calls.append(a[1]) or real(*a, **k)
    )
    kf, ukf, rng = linear_pair()
    assert calls == ["P", "Q", "R"]  # assigned: factored once each
    calls.clear()
    _ = ukf.Q, ukf.R  # handing the matrices out must not make each step compare or refactor them
    for _ in range(20):
        ukf.predict()
        ukf.update(rng.standard_normal(2))
    assert calls == []
    ukf.Q[0, 0] *= 2.0  # an in-place edit is seen, and factored once
    ukf.predict()
    ukf.update(rng.standard_normal(2))
    ukf.predict()
    assert calls == ["Q"]
    np.testing.assert_allclose(ukf.Q1_2 @ ukf.Q1_2.T, np.diag([0.02, 0.01, 0.01]), rtol=1e-14)


def test_editing_x_in_place_between_predict_and_update_redraws():
    _, a, rng = linear_pair()
    _, b, _ = linear_pair()
    z = rng.standard_normal(2)
    a.predict()
    b.predict()
    a.x[1] += 0.5  # in place: the second set drawn at predict is stale now
    b.x = b.x + np.array([0.0, 0.5, 0.0])
    a.update(z)
    b.update(z)
    np.testing.assert_array_equal(a.sigmas_h, b.sigmas_h)  # hx saw the same, redrawn, points
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P1_2, b.P1_2)


def test_all_finite_is_exact_and_quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert all_finite(np.array([1e200, -1e200, 3.0]))  # the dot overflows; the entries are finite
        assert all_finite(np.zeros((0, 3)))
        for bad in (np.nan, np.inf, -np.inf):
            a = np.ones((4, 3))
            a[2, 1] = bad
            assert not all_finite(a)
            assert not all_finite(np.asfortranarray(a))


def test_negative_rows_are_downdated_when_no_form_avoids_them():
    """beta < alpha**2 with a negative central weight: both forms have a negative row."""
    Wm, Wc = MerweScaledWeights(1.0, 0.0, -1.0).weights(3)
    plan = weight_plan(Wm, Wc)
    assert plan.mean_form.neg.size == 1 and plan.best.neg.size == 1 and not plan.fast
    X = np.random.default_rng(0).standard_normal((7, 3))
    mean, P = weighted_cov(X, Wm, Wc)
    noise = np.eye(3) * 2.0  # keeps the result positive definite
    _, S = transform_factor(X, plan, noise)
    np.testing.assert_allclose(S @ S.T, P + noise @ noise.T, rtol=1e-12, atol=1e-12)
