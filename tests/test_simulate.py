"""``squkf.simulate``: runs drawn from a template filter's own model (issue 37, in part).

Checked against a hand-written loop drawing the same numbers in the same order (bit for bit), and
by moments over many runs (a sample covariance of ``N`` draws is off by about ``sqrt(2 / N)``
relative: 2,000 runs of 100 steps put that near 0.3%, so 3% is a wide margin).
"""

from __future__ import annotations

import numpy as np
import pytest
from models import assert_filter_state, filter_state, line_cv_fx, line_cv_template

from squkf import (
    MerweScaledWeights,
    NonFiniteError,
    ParameterError,
    ShapeError,
    SquareRootUKF,
    UnsetError,
    simulate,
)

F_CV = np.array([[1.0, 1.0], [0.0, 1.0]])


def hand_loop(f, steps, runs, seed):
    """The model drawn by hand, in simulate's documented order: x0, then per step w, v."""
    rng = np.random.default_rng(seed)
    S0, Q1_2, R1_2 = np.linalg.cholesky(f.P), np.linalg.cholesky(f.Q), np.linalg.cholesky(f.R)
    x = f.x + rng.standard_normal((runs, 2)) @ S0.T
    truth, zs = np.empty((runs, steps, 2)), np.empty((runs, steps, 1))
    for t in range(steps):
        w = rng.standard_normal((runs, 2)) @ Q1_2.T
        v = rng.standard_normal((runs, 1)) @ R1_2.T
        x = np.array([line_cv_fx(xi, 1.0) for xi in x]) + w
        truth[:, t], zs[:, t] = x, x[:, :1] + v
    return truth, zs


@pytest.mark.parametrize("vectorized", [False, True])
def test_simulate_is_the_model_drawn_by_hand(vectorized):
    f = line_cv_template(vectorized)
    truth, zs = simulate(f, 20, 7, seed=11)
    want_truth, want_zs = hand_loop(line_cv_template(), 20, 7, 11)
    np.testing.assert_allclose(truth, want_truth, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(zs, want_zs, rtol=1e-14, atol=1e-14)


def test_the_moments_are_the_models():
    f = line_cv_template(vectorized=True)
    truth, zs = simulate(f, 100, 2000, seed=5)
    increments = truth[:, 1:] - truth[:, :-1] @ F_CV.T
    np.testing.assert_allclose(np.cov(increments.reshape(-1, 2).T), f.Q, rtol=0.03, atol=0.003)
    np.testing.assert_allclose(np.var(zs[..., 0] - truth[..., 0]), 4.0, rtol=0.03)
    # the first state is F x0 + w, x0 ~ N(x, P): its mean F x (a standard error of about 0.05)
    np.testing.assert_allclose(truth[:, 0].mean(axis=0), F_CV @ f.x, atol=0.15)


def test_noise_that_enters_the_model_is_drawn_from_q_and_r():
    G = np.array([[0.5], [1.0]])

    def fx(x, w, dt):
        return F_CV @ x + G @ w

    def hx(x, v):
        return x[:1] * np.exp(v)  # a multiplicative sensor error

    f = SquareRootUKF(2, 1, 1.0, hx, fx, MerweScaledWeights(), fx_noise=1, hx_noise=1)
    f.Q, f.R = [[0.3]], [[0.01]]
    truth, zs = simulate(f, 50, 2000, seed=2)
    increments = truth[:, 1:] - truth[:, :-1] @ F_CV.T
    np.testing.assert_allclose(np.cov(increments.reshape(-1, 2).T), 0.3 * G @ G.T, rtol=0.03, atol=1e-3)
    ratio = np.log(zs[..., 0] / truth[..., 0])
    np.testing.assert_allclose(np.var(ratio), 0.01, rtol=0.03)


def test_per_step_dts_and_arguments_reach_the_model():
    seen = []

    def fx(x, dt, u=0.0):
        seen.append((dt, u))
        return x + u

    f = SquareRootUKF(1, 1, None, lambda x: x, fx, MerweScaledWeights())
    f.Q = 0.0
    simulate(f, 3, 1, seed=0, dts=[0.1, 0.2, 0.3], fx_args=[{"u": 1.0}, {"u": 2.0}, {"u": 3.0}])
    assert seen == [(0.1, 1.0), (0.2, 2.0), (0.3, 3.0)]
    seen.clear()
    simulate(f, 2, 1, seed=0)
    assert [dt for dt, _ in seen] == [None, None]  # the template's dt=None, as predict would pass


def test_the_same_seed_gives_the_same_runs_and_the_template_is_unchanged():
    f = line_cv_template()
    snap = filter_state(f)
    a, b, c = simulate(f, 5, 3, seed=9), simulate(f, 5, 3, seed=9), simulate(f, 5, 3, seed=10)
    np.testing.assert_array_equal(a[0], b[0])
    assert not np.array_equal(a[0], c[0])
    assert_filter_state(f, snap)


def test_bad_input_is_named_and_changes_nothing():
    f = line_cv_template()
    snap = filter_state(f)
    with pytest.raises(ParameterError, match="steps"):
        simulate(f, 0, 3)
    with pytest.raises(ParameterError, match="runs"):
        simulate(f, 3, -1)
    with pytest.raises(ShapeError, match="dts"):
        simulate(f, 3, 2, dts=[1.0, 1.0])
    bad = SquareRootUKF(2, 1, 1.0, lambda x: x[:1], lambda x, dt: x[:1], MerweScaledWeights())
    with pytest.raises(ShapeError, match="fx values at step 0"):
        simulate(bad, 3, 2)
    nan = SquareRootUKF(2, 1, 1.0, lambda x: x[:1] * np.nan, line_cv_fx, MerweScaledWeights())
    with pytest.raises(NonFiniteError, match="hx values at step 0"):
        simulate(nan, 3, 2)
    assert_filter_state(f, snap)
    f.x = None
    with pytest.raises(UnsetError, match="x"):
        simulate(f, 3, 2)
    no_fx = SquareRootUKF(2, 1, 1.0, lambda x: x[:1], None, MerweScaledWeights())
    with pytest.raises(ParameterError, match="fx"):
        simulate(no_fx, 3, 2)
