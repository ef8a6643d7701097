"""``squkf.tune.log_likelihood``: K candidate noise settings in one fleet pass (issue 37, in part).

A candidate's total equals the same filter run alone bit for bit (a fleet equals its single
filters), and the sum of filterpy's per-step ``log_likelihood`` to 1e-9 relative (the two
arithmetics differ by rounding at each of T steps).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from models import (
    TUNE_Q0,
    TUNE_TRUE,
    assert_filter_state,
    filter_state,
    robot_tune_filter,
    tune_cv_filter,
    tune_cv_fx,
)

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


# == fit_noise ======================================================================================
# The 2-D constant-velocity model (tests/models.py: tune_cv_*), Q = q Q0 and R = diag(r1, r2) unknown.

TRUTH_THETA = np.log([TUNE_TRUE["q"], TUNE_TRUE["r1"], TUNE_TRUE["r2"]])


def tune_template():
    """The filter to fit: the true model's shape, started off at q = 1, R = I."""
    return tune_cv_filter(q=1.0, r1=1.0, r2=1.0)


@pytest.fixture(scope="module")
def cv_recordings():
    return simulate(tune_cv_filter(), 300, 200, seed=11)[1]


def test_intervals_cover_the_truth_at_their_level_and_the_errors_are_small(cv_recordings):
    """200 recordings of T = 300 steps, each its own fit (shared=False, all in the same fleet passes):
    each 95% interval covers its true value in 88-99% of them, and the median relative error of each
    variance is under 15%."""
    f = tune_template()
    snap = filter_state(f)
    fits = tune.fit_noise(f, cv_recordings, Q=tune.Scaled(), R=tune.Diagonal(), shared=False)
    assert len(fits) == 200 and np.mean([fit.success for fit in fits]) >= 0.95
    truth = [TUNE_TRUE["q"], TUNE_TRUE["r1"], TUNE_TRUE["r2"]]
    intervals = [fit.intervals() for fit in fits]  # (estimate, low, high) of each quantity
    estimate, low, high = (
        np.array([[iv["Q"]["scale"][j], *iv["R"]["variances"][j]] for iv in intervals]) for j in range(3)
    )
    covered = (low <= truth) & (truth <= high)
    assert np.all((covered.mean(axis=0) >= 0.88) & (covered.mean(axis=0) <= 0.99)), covered.mean(axis=0)
    assert np.all(np.median(np.abs(estimate / truth - 1), axis=0) < 0.15)
    assert_filter_state(f, snap)


@pytest.mark.parametrize("method", ["quasi_newton", "differential_evolution"])
def test_every_method_reaches_the_same_optimum(cv_recordings, method):
    z = cv_recordings[0]
    best = tune.fit_noise(tune_template(), z, R=tune.Diagonal())
    fit = tune.fit_noise(tune_template(), z, R=tune.Diagonal(), method=method, seed=2)
    assert abs(fit.log_likelihood - best.log_likelihood) < 1e-3
    alone = tune.fit_noise(tune_template(), [z], R=tune.Diagonal(), shared=False)[0]
    assert abs(alone.log_likelihood - best.log_likelihood) < 1e-3
    # the reported log-likelihood is exact: the template run with the fitted Q and R
    g = tune_template()
    fit.apply(g)
    assert fit.log_likelihood == pytest.approx(float(np.sum(g.batch_filter(z).log_likelihood)), rel=1e-12)


def test_a_grid_keeps_its_surface_and_finds_its_best_point(cv_recordings):
    z = cv_recordings[1]
    grid = np.array(
        [[a, b, c] for a in np.log([0.05, 0.1, 0.2]) for b in (0.0,) for c in np.log([2.0, 4.0, 8.0])]
    )
    fit = tune.fit_noise(tune_template(), z, R=tune.Diagonal(), method="grid", grid=grid, max_filters=4)
    thetas, values = fit.surface
    np.testing.assert_array_equal(thetas, grid)
    expected, _ = tune.log_likelihood(
        tune_template(), z, Qs=np.exp(grid[:, 0])[:, None, None] * TUNE_Q0,
        Rs=np.stack([np.diag(np.exp(t[1:])) for t in grid]),
    )  # fmt: skip
    np.testing.assert_allclose(values, expected, rtol=1e-12)
    np.testing.assert_array_equal(fit.theta, grid[np.argmax(expected)])
    assert fit.passes >= 3  # (4 filters a pass: the 9 points and the start in 3 passes, and the Hessian's)


def test_theta_cov_is_the_inverse_of_the_observed_information(cv_recordings):
    """Against a Hessian of -log L formed from separate log_likelihood calls, with another step."""
    z = cv_recordings[2]
    fit = tune.fit_noise(tune_template(), z, R=tune.Diagonal())

    def minus_loglik(theta):
        Rs = np.diag(np.exp(theta[1:]))[None]
        return -tune.log_likelihood(tune_template(), z, Qs=np.exp(theta[0]) * TUNE_Q0[None], Rs=Rs)[0][0]

    h, p = 2e-3, 3
    H = np.empty((p, p))
    for i in range(p):
        for j in range(p):
            ei, ej = np.eye(p)[i] * h, np.eye(p)[j] * h
            H[i, j] = (
                minus_loglik(fit.theta + ei + ej) - minus_loglik(fit.theta + ei - ej)
                - minus_loglik(fit.theta - ei + ej) + minus_loglik(fit.theta - ei - ej)
            ) / (4 * h * h)  # fmt: skip
    np.testing.assert_allclose(fit.theta_cov, np.linalg.inv(H), rtol=2e-2, atol=1e-6)
    assert fit.identifiable


def test_a_direction_the_data_do_not_fix_is_named():
    f = tune_template()
    zs = simulate(tune_cv_filter(), 100, 1, seed=5)[1][0]
    R0 = np.diag([1.0, 4.0])
    # a second parameter the likelihood never reads: its information is exactly zero
    R = tune.Custom(lambda t: np.exp(t[0]) * R0, [0.0, 0.0], names=["a", "b"])
    fit = tune.fit_noise(f, zs, Q=tune.Fixed(), R=R)
    assert not fit.identifiable
    (weak,) = fit.weak_directions
    assert set(weak["direction"]) == {"b"}
    assert np.isinf(fit.theta_cov[1]).all() and np.isfinite(fit.theta_cov[0, 0])
    assert "not identifiable" in repr(fit)


def test_full_custom_and_prior():
    zs = simulate(tune_cv_filter(), 300, 1, seed=8)[1][0]
    full = tune.fit_noise(tune_template(), zs, Q=tune.Fixed(), R=tune.Full())
    M, low, high = full.intervals()["R"]["matrix"]
    np.testing.assert_allclose(M, full.R)
    assert np.all(low <= M) and np.all(M <= high)
    # the initial state fitted through Custom (its x only: P stays the template's)
    f = tune_template()
    f.x = np.array([5.0, 1.0, 5.0, 1.0])
    x0 = tune.Custom(lambda t: {"x": np.array([t[0], 1.0, t[1], 1.0])}, [5.0, 5.0], names=["px0", "py0"])
    fit = tune.fit_noise(f, zs, Q=tune.Fixed(), R=x0)
    assert np.all(np.abs(fit.x[::2]) < 3.0)  # back near the true start (0, 0), from 5
    np.testing.assert_array_equal(fit.R, f.R)
    # a strong prior at the template's value holds the fit there
    free = tune.fit_noise(tune_template(), zs, R=tune.Fixed())
    held = tune.fit_noise(tune_template(), zs, R=tune.Fixed(), prior=lambda t: 1e3 * t)
    assert abs(held.theta[0]) < 0.01 < abs(free.theta[0])


def test_noise_that_enters_fx_is_fitted_as_its_own_covariance():
    G = np.array([[0.5], [1.0]])

    def fx(x, w, dt):
        return np.array([x[0] + x[1], x[1]]) + G @ w

    def make(q):
        f = SquareRootUKF(2, 1, 1.0, lambda x: x[:1], fx, MerweScaledWeights(), fx_noise=1)
        f.x, f.P, f.Q, f.R = np.zeros(2), np.eye(2), [[q]], [[1.0]]
        return f

    zs = simulate(make(0.2), 400, 1, seed=4)[1][0]
    fit = tune.fit_noise(make(1.0), zs, R=tune.Fixed())
    lo, hi = fit.intervals()["Q"]["scale"][1:]
    assert lo < 0.2 < hi


def test_an_interrupt_leaves_the_template_as_it_was():
    calls = {"n": 0}

    def fx(X, dt):
        calls["n"] += 1
        if calls["n"] == 40:
            raise KeyboardInterrupt
        return tune_cv_fx(X, dt)

    f = tune_template()
    f.fx = fx
    snap = filter_state(f)
    zs = simulate(tune_cv_filter(), 50, 1, seed=1)[1][0]
    with pytest.raises(KeyboardInterrupt):
        tune.fit_noise(f, zs)
    assert_filter_state(f, snap)


def test_fit_noise_refuses_bad_input_naming_it_and_changes_nothing(cv_recordings):
    f = tune_template()
    snap = filter_state(f)
    z = cv_recordings[0]
    for kwargs, exc, match in [
        ({"method": "nelder"}, ParameterError, "method"),
        ({"Q": tune.Fixed(), "R": tune.Fixed()}, ParameterError, "nothing to fit"),
        ({"method": "grid"}, ParameterError, "grid"),
        ({"method": "grid", "grid": np.zeros((3, 5))}, ParameterError, "grid"),
        ({"bounds": [(1.0, 2.0), (1.0, 2.0)]}, ParameterError, "bounds"),
        ({"bounds": [(-1.0, 1.0), (1.0, 2.0)]}, ParameterError, "outside bounds"),
        ({"shared": False, "method": "grid"}, ParameterError, "shared=False"),
        ({"shared": "no"}, ParameterError, "shared"),
        ({"R": tune.Custom(lambda t: np.eye(3), [0.0])}, ShapeError, "R"),
        ({"max_filters": 0}, ParameterError, "max_filters"),
    ]:
        with pytest.raises(exc, match=match):
            tune.fit_noise(f, z, **kwargs)
        assert_filter_state(f, snap)
    with pytest.raises(NonFiniteError, match="zs"):
        tune.fit_noise(f, np.full((20, 2), np.nan))
    f.gate = 0.99
    with pytest.raises(ParameterError, match="gate"):
        tune.fit_noise(f, z)


def test_a_failing_candidate_is_a_wall_and_every_failure_is_an_error(cv_recordings):
    # R's scale through a Custom that is not a covariance below 0: the optimiser stays above
    R = tune.Custom(lambda t: (t[0] - 0.2) * np.diag([1.0, 4.0]), [1.0], names=["r"])
    fit = tune.fit_noise(tune_template(), cv_recordings[0], Q=tune.Fixed(), R=R, method="grid",
                         grid=np.array([[0.0], [0.5], [1.0], [1.5]]))  # fmt: skip
    assert len(fit.failures) == 1 and fit.theta[0] > 0.2
    with pytest.raises(FleetStepError, match="every grid point failed"):
        tune.fit_noise(
            tune_template(), cv_recordings[0], Q=tune.Fixed(), R=R, method="grid", grid=np.array([[0.0]])
        )
    # a start that fails: the least-squares fit and the per-recording fits say so, and nothing else
    bad = tune.Custom(lambda t: (t[0] - 0.2) * np.diag([1.0, 4.0]), [0.0], names=["r"])
    for shared in (True, False):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # (no numpy warning on the way)
            with pytest.raises(FleetStepError, match="start|recording"):
                tune.fit_noise(tune_template(), cv_recordings[:2], Q=tune.Fixed(), R=bad, shared=shared)


def test_progress_is_called_after_every_fleet_pass(cv_recordings):
    seen = []
    fit = tune.fit_noise(tune_template(), cv_recordings[0], progress=seen.append)
    assert seen == list(range(fit.passes))
    with pytest.raises(ParameterError, match="progress"):
        tune.fit_noise(tune_template(), cv_recordings[0], progress="yes")


def test_fit_noise_refuses_a_template_between_ask_and_tell_and_bad_parametrisations(cv_recordings):
    z = cv_recordings[0]
    f = tune_template()
    f.ask_predict()
    snap = filter_state(f)
    with pytest.raises(CallSequenceError):
        tune.fit_noise(f, z)
    assert_filter_state(f, snap)
    with pytest.raises(ParameterError, match="theta0"):
        tune.Custom(lambda t: np.eye(2), [np.nan])
    with pytest.raises(ParameterError, match="callable"):
        tune.Custom("not a function", [0.0])
    # a parametrisation giving values that are not finite: that candidate fails, the fit goes on around it
    R = tune.Custom(
        lambda t: np.diag([1.0, 4.0]) * (np.nan if t[0] > 0.5 else np.exp(t[0])), [0.0], names=["r"]
    )
    fit = tune.fit_noise(tune_template(), z, Q=tune.Fixed(), R=R, method="grid", grid=[[-0.5], [0.0], [1.0]])
    assert fit.surface[1][2] == -np.inf and any("not finite" in why for why in fit.failures.values())
    for level in (0.0, 1.0, 1.5, "high"):
        with pytest.raises(ParameterError, match="level"):
            fit.intervals(level)


# -- the least-squares form -------------------------------------------------------------------------


def test_the_whitened_records_are_the_log_likelihood_of_each_candidate(recordings):
    """``log L = sum -(|w|^2 + m log 2 pi) / 2 - log det S1_2`` over the updates, per candidate and
    recording: the residuals the least-squares fit minimises are the likelihood, to rounding."""
    from squkf.candidates import Candidates, candidate_factors, evaluate

    (Q1_2, _), (R1_2, _) = candidate_factors(CANDIDATES_Q, "Qs", 4), candidate_factors(CANDIDATES_R, "Rs", 2)
    c = Candidates(Q1_2=Q1_2, R1_2=R1_2)
    z = recordings.copy()
    z[0, 5, 1] = np.nan  # a missing component and a missing step: no residuals of theirs
    z[1, 7] = np.nan
    loglik, W, L, failures = evaluate(template(), z, c, 3, 2, {}, whitened=True)
    assert np.array_equal(evaluate(template(), z, c, 3, 2, {}).loglik, loglik)  # the same pass without them
    assert not failures and W.shape == (3, 3, T - 2, 2) and L.shape == (3, 3, T - 2)
    measured = ~np.isnan(z[:, 2:])
    assert np.array_equal(~np.isnan(W[0]), measured)
    mo = measured.sum(axis=-1)
    from_records = (-0.5 * (np.nansum(W**2, axis=-1) + mo * np.log(2 * np.pi)) - L).sum(axis=-1)
    # T sums of terms of size about 1: a relative 1e-12 of the total
    np.testing.assert_allclose(from_records, loglik, rtol=1e-12)


def test_least_squares_restarts_with_a_larger_constant_and_reaches_the_optimum(cv_recordings, monkeypatch):
    """With no margin above the start's ``-2 log det S1_2`` the first smaller innovation factor makes a
    root imaginary: the solver restarts from its best point with a larger constant, to the same optimum."""
    from squkf import noise_fit

    z = cv_recordings[2]
    best = tune.fit_noise(tune_template(), z, R=tune.Diagonal(), method="quasi_newton")
    f = tune_cv_filter(q=1.0, r1=10.0, r2=40.0)  # the start's factors larger than the optimum's
    calls = []
    restart = noise_fit._RestartError.__init__

    def counted(self, c):
        calls.append(c)
        restart(self, c)

    monkeypatch.setattr(noise_fit, "C_MARGIN", 0.0)
    monkeypatch.setattr(noise_fit._RestartError, "__init__", counted)
    snap = filter_state(f)
    fit = tune.fit_noise(f, z, R=tune.Diagonal())
    assert calls, "no restart: the test no longer reaches a smaller innovation factor"
    assert fit.method == "least_squares" and fit.success
    assert abs(fit.log_likelihood - best.log_likelihood) < 1e-3
    assert_filter_state(f, snap)


def test_a_candidate_already_run_costs_no_pass(cv_recordings):
    """The objective keeps the exact log-likelihood of every candidate it has run (by theta and
    recording): asked again, it answers the same numbers without a pass, and runs only those it has not."""
    from squkf import noise_fit

    fit = tune.fit_noise(tune_template(), cv_recordings[0], R=tune.Diagonal())
    Z = cv_recordings[:2]
    kwargs = {"dts": None, "fx_args": None, "hx_args": None}
    objective = noise_fit._Objective(tune_template(), Z, 0, fit._parts, None, kwargs, 10_000)
    thetas = np.vstack([fit.theta, fit.theta + 0.1])
    first = objective.loglik(thetas)  # each summed over both recordings
    assert objective.passes == 1
    assert np.array_equal(objective.loglik(thetas[::-1]), first[::-1]) and objective.passes == 1
    both = objective.loglik(np.vstack([thetas, fit.theta - 0.1]))
    assert objective.passes == 2 and objective.filter_steps == (2 + 1) * Z.shape[0] * Z.shape[1]
    assert np.array_equal(both[:2], first)
    # on one recording each, the same theta is another candidate: run, and the two make the sum
    own = objective.loglik(np.vstack([fit.theta, fit.theta]), np.array([0, 1]))
    assert objective.passes == 3 and own[0] + own[1] == first[0]
    assert np.array_equal(objective.loglik(fit.theta[None], np.array([1])), own[1:])
    assert objective.passes == 3


def test_the_optimum_s_information_is_newton_s_last_pass(cv_recordings):
    """The fit ends with Newton's method, whose last stencil is at the optimum: the observed information
    there and the reported log-likelihoods run no pass after it (every pass is the optimiser's)."""
    from squkf import noise_fit

    seen: list[tuple[int, int]] = []
    objective_passes = noise_fit._Objective._passes

    def counted(self, thetas, rec, whitened):
        before = self.passes
        out = objective_passes(self, thetas, rec, whitened)
        seen.append((before, self.passes))
        return out

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(noise_fit._Objective, "_passes", counted)
        fit = tune.fit_noise(tune_template(), cv_recordings[3], R=tune.Diagonal())
    assert fit.success and "Newton" in fit.message
    # the last two asks (the Hessian's stencil, the optimum's value) ran nothing: the one before them,
    # Newton's last, ran the last pass
    assert [after - before for before, after in seen[-2:]] == [0, 0]
    assert seen[-3][1] == fit.passes


def test_newton_s_method_reaches_an_optimum_held_by_a_bound():
    """A quadratic whose optimum in the box has one parameter at its lower bound, the two coupled: the
    step of the free parameter alone reaches it (a clipped whole step would predict no gain there and
    stop at the start, calling it converged)."""
    from squkf import noise_fit

    H, g0 = np.array([[1.0, 0.9], [0.9, 1.0]]), np.array([0.955, 0.85])

    def objective(points, rec=None):
        return np.array([g0 @ t + 0.5 * t @ H @ t for t in points])

    lo, hi = np.array([0.0, -10.0]), np.array([10.0, 10.0])
    theta, success = noise_fit._batched_newton(objective, np.zeros((1, 2)), None, (lo, hi), 50)
    assert success[0]
    np.testing.assert_allclose(theta[0], [0.0, -0.85], atol=1e-6)
    # and the least-squares phase's hand-over reads the same decrement: none left at that optimum
    assert noise_fit._decrement(theta[0], g0 + H @ theta[0], H, lo, hi) < 1e-12


def test_on_the_robot_one_fit_reaches_the_same_optimum_from_every_start():
    """The g13ej robot (T = 400), Q's scale and R's two variances fitted from four starts: every fit
    reaches the same log-likelihood to 1e-3 (the issue's agreement between methods), although R is
    barely fixed by the data (along it the likelihood is flat, and one variance may go to its bound)."""
    truth = robot_tune_filter()
    z = simulate(truth, 400, 1, seed=7)[1][0]
    fits = [
        tune.fit_noise(robot_tune_filter(q, (r, r)), z, Q=tune.Scaled(), R=tune.Diagonal())
        for q, r in ((3.0, 1 / 3), (3.0, 3.0), (1 / 3, 3.0), (1.0, 1.0))
    ]
    values = np.array([fit.log_likelihood for fit in fits])
    assert np.all([fit.success for fit in fits])
    assert np.ptp(values) < 1e-3, values
    assert all(fit.passes <= 25 for fit in fits), [fit.passes for fit in fits]


@pytest.mark.slow
def test_on_the_robot_q_is_fitted_within_20_percent_and_r_is_reported_as_not_fixed_by_the_data():
    """The g13ej robot, its example's Q and R the truth, 24 recordings of T = 400, each its own fit from
    3 Q and R / 3: the median relative error of Q's scale is under 20%.

    R is not: its standard deviations (0.01) are a tenth of Q's, so over 400 steps an innovation carries
    almost nothing of R (the observed information of log r1 at the truth, measured over 40 recordings, is
    about 0.08 a recording: a standard error of 3.4 in log r1, a factor of 30; of log r2, 0.9; the fits'
    own standard errors of log r1 have a median of about 6.6). No estimator reaches 20% there; what the
    fit must do is say so: its standard error of log r1 is large
    (above 0.5, or infinite where the direction is not fixed at all), that of Q's scale small. (The
    observed information of log r2 at each fit's own optimum, often near r2 = 0, varies too much from one
    recording to the next for a bound on it.)"""
    f = robot_tune_filter()
    _, zs = simulate(f, 400, 24, seed=5)
    template = robot_tune_filter(3.0, (1 / 3, 1 / 3))
    snap = filter_state(template)
    fits = tune.fit_noise(template, zs, Q=tune.Scaled(), R=tune.Diagonal(), shared=False)
    q = np.array([fit.Q[0, 0] / f.Q[0, 0] for fit in fits])
    assert np.median(np.abs(q - 1)) < 0.2, q
    sd = np.sqrt(np.array([np.diagonal(fit.theta_cov) for fit in fits]))
    assert np.median(sd[:, 0]) < 0.2, sd[:, 0]
    assert np.median(sd[:, 1]) > 0.5, sd[:, 1]
    assert_filter_state(template, snap)
