"""The smoothers' inputs: validated like the filter's, naming the argument and the step."""

import copy

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from models import LIN2_Q, LIN2_T, assert_results_equal, counting, lin2_F, lin2_filter, lin2_fx

from squkf import (
    NonFiniteError,
    NotPositiveDefiniteError,
    ParameterError,
    ShapeError,
    SqukfValueError,
)


@pytest.fixture(scope="module")
def filtered():
    rng = np.random.default_rng(5)
    zs = np.arange(LIN2_T) + rng.normal(0.0, 0.7, LIN2_T)
    means, covs = lin2_filter().batch_filter(zs)
    _, factors = lin2_filter().batch_filter(zs, return_factors=True)
    return means, covs, factors


@pytest.mark.parametrize(
    "dts", [[0.0] * LIN2_T, [1.0, 0.0, 0.5, 0.0, 0.0, 2.0, 1.0, 0.0, 0.3, 0.0, 1.0, 0.0]]
)
def test_zero_time_steps_are_accepted_and_agree_with_the_kalman_smoother(filtered, dts):
    means, covs, _ = filtered
    Qs = [LIN2_Q * s for s in np.linspace(0.5, 2.0, LIN2_T)]
    xs, Ps, Ks = lin2_filter().rts_smoother(means, covs, Qs=Qs, dts=dts)
    kf = KalmanFilter(2, 1)
    x_ref, P_ref, K_ref, _ = kf.rts_smoother(means, covs, Fs=[lin2_F(dt) for dt in dts], Qs=Qs)
    # a linear model: the unscented transform is exact, so the two agree to rounding
    np.testing.assert_allclose(xs, x_ref, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(Ps, P_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(Ks[:-1], K_ref[:-1], rtol=1e-9, atol=1e-12)


def test_a_scalar_dt_of_zero(filtered):
    means, covs, _ = filtered
    assert_results_equal(
        lin2_filter().rts_smoother(means, covs, dts=0.0),
        lin2_filter().rts_smoother(means, covs, dts=[0.0] * LIN2_T),
    )


def test_scalar_and_single_matrix_Qs_mean_every_step(filtered):
    means, covs, _ = filtered
    expected = lin2_filter().rts_smoother(means, covs, Qs=[0.03 * np.eye(2)] * LIN2_T)
    assert_results_equal(lin2_filter().rts_smoother(means, covs, Qs=0.03), expected)
    assert_results_equal(lin2_filter().rts_smoother(means, covs, Qs=0.03 * np.eye(2)), expected)


def test_lists_generators_and_column_vectors(filtered):
    means, covs, factors = filtered
    expected = lin2_filter().rts_smoother(means, covs)
    assert_results_equal(lin2_filter().rts_smoother(list(means), [P for P in covs]), expected)
    assert_results_equal(lin2_filter().rts_smoother((x for x in means), iter(covs)), expected)
    assert_results_equal(lin2_filter().rts_smoother(means[:, :, None], covs), expected)
    expected = lin2_filter().rts_smoother_factors(means, factors)
    assert_results_equal(lin2_filter().rts_smoother_factors(iter(means), list(factors)), expected)


def test_a_negative_diagonal_is_a_sign_of_its_column(filtered):
    means, _, factors = filtered
    flipped = factors.copy()
    flipped[4][:, 1] *= -1  # the same covariance
    flipped[7] *= -1
    xs, S, _ = lin2_filter().rts_smoother_factors(means, flipped)
    xs_ref, S_ref, _ = lin2_filter().rts_smoother_factors(means, factors)
    np.testing.assert_allclose(xs, xs_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(S, S_ref, rtol=1e-10, atol=1e-12)
    assert np.all(np.diagonal(S, axis1=1, axis2=2) > 0)


@pytest.mark.parametrize("method", ["rts_smoother", "rts_smoother_factors"])
@pytest.mark.parametrize("n", [0, 1])
def test_empty_and_single_step(filtered, method, n):
    means, covs, factors = filtered
    second = covs if method == "rts_smoother" else factors
    Xs, Ps = (means[:n], second[:n]) if n else ([], [])
    xs, Ps_s, Ks = getattr(lin2_filter(), method)(Xs, Ps)
    assert xs.shape == (n, 2) and Ps_s.shape == (n, 2, 2) and Ks.shape == (n, 2, 2)
    if n:
        np.testing.assert_array_equal(xs, means[:1])
        np.testing.assert_allclose(Ps_s, second[:1], rtol=1e-14)
        assert not np.any(Ks)


def _corrupt(filtered, what):
    means, covs, factors = (a.copy() for a in filtered)
    kwargs = {}
    if what == "factor above the diagonal":
        factors[3][0, 1] = 0.5
    elif what == "factor zero diagonal":
        factors[3][1, 1] = 0.0
    elif what == "factor nan":
        factors[3][1, 0] = np.nan
    elif what == "mean inf":
        means[3][1] = np.inf
    elif what == "numeric text dt":  # a negative dt is a step, as for predict
        kwargs["dts"] = [1.0] * 3 + ["0.5"] + [1.0] * (LIN2_T - 4)
    elif what == "nan dt":
        kwargs["dts"] = [1.0] * 3 + [np.nan] + [1.0] * (LIN2_T - 4)
    elif what == "inf dt":
        kwargs["dts"] = [1.0] * 3 + [np.inf] + [1.0] * (LIN2_T - 4)
    elif what == "text dt":
        kwargs["dts"] = [1.0] * 3 + ["one"] + [1.0] * (LIN2_T - 4)
    elif what == "fx_args entry":
        kwargs["fx_args"] = [{}] * 3 + [5] + [{}] * (LIN2_T - 4)
    return means, factors, kwargs


@pytest.mark.parametrize(
    "what, error, match",
    [
        ("factor above the diagonal", SqukfValueError, r"P1_2s\[3\] must be lower triangular"),
        ("factor zero diagonal", NotPositiveDefiniteError, r"P1_2s\[3\] has a zero on its diagonal"),
        ("factor nan", NonFiniteError, r"P1_2s\[3\] \(step 3\) contains NaN or inf"),
        ("mean inf", NonFiniteError, r"Xs\[3\] \(step 3\) contains NaN or inf"),
        ("numeric text dt", ParameterError, r"dts\[3\] must be a finite number"),
        ("nan dt", ParameterError, r"dts\[3\]"),
        ("inf dt", ParameterError, r"dts\[3\]"),
        ("text dt", ParameterError, r"dts\[3\]"),
        ("fx_args entry", ParameterError, r"fx_args\[3\] must be a dict"),
    ],
)
def test_bad_factor_inputs_are_named_with_their_step(filtered, what, error, match):
    means, factors, kwargs = _corrupt(filtered, what)
    counted, calls = counting(lin2_fx)
    f = lin2_filter(fx=counted)
    before = copy.deepcopy(f)
    with pytest.raises(error, match=match):
        f.rts_smoother_factors(means, factors, **kwargs)
    assert calls == []  # found before the backward pass
    np.testing.assert_array_equal(f.x, before.x)
    np.testing.assert_array_equal(f.P1_2, before.P1_2)


@pytest.mark.parametrize(
    "change, error, match",
    [
        ("nan", NonFiniteError, r"Ps\[4\] \(step 4\) contains NaN"),
        ("asymmetric", SqukfValueError, r"Ps\[4\] is not symmetric"),
        ("indefinite", NotPositiveDefiniteError, r"Ps\[4\]"),
    ],
)
def test_bad_covariances_are_named_with_their_step(filtered, change, error, match):
    means, covs, _ = filtered
    covs = covs.copy()
    if change == "nan":
        covs[4][0, 0] = np.nan
    elif change == "asymmetric":
        covs[4][0, 1] += 1.0
    else:
        covs[4] = np.array([[1.0, 2.0], [2.0, 1.0]])
    with pytest.raises(error, match=match):
        lin2_filter().rts_smoother(means, covs)


@pytest.mark.parametrize("name", ["Qs", "dts", "fx_args"])
@pytest.mark.parametrize("method", ["rts_smoother", "rts_smoother_factors"])
def test_per_step_lengths_must_match(filtered, name, method):
    means, covs, factors = filtered
    second = covs if method == "rts_smoother" else factors
    entry = {"Qs": LIN2_Q, "dts": 1.0, "fx_args": {}}[name]
    for n in (LIN2_T - 1, LIN2_T + 1):
        with pytest.raises(ShapeError, match=f"^{name} has {n} entries but Xs has {LIN2_T}$"):
            getattr(lin2_filter(), method)(means, second, **{name: [entry] * n})


def test_shapes_and_lengths_of_the_filtered_results(filtered):
    means, covs, factors = filtered
    f = lin2_filter()
    with pytest.raises(ShapeError, match=f"Ps has {LIN2_T - 1} entries but Xs has {LIN2_T}"):
        f.rts_smoother(means, covs[:-1])
    with pytest.raises(ShapeError, match=f"P1_2s has {LIN2_T + 1} entries but Xs has {LIN2_T}"):
        f.rts_smoother_factors(means, np.concatenate([factors, factors[:1]]))
    with pytest.raises(ShapeError, match=r"Xs has shape \(12, 3\), expected \(T, 2\)"):
        f.rts_smoother(np.zeros((LIN2_T, 3)), covs)
    with pytest.raises(ShapeError, match=r"P1_2s has shape \(12, 3, 3\), expected \(T, 2, 2\)"):
        f.rts_smoother_factors(means, np.zeros((LIN2_T, 3, 3)))
    with pytest.raises(ShapeError, match="Xs must be an array"):
        f.rts_smoother([[1.0, 2.0], [1.0]], covs[:2])
    with pytest.raises(ShapeError, match="Ps must be an array"):
        f.rts_smoother(means, None)
    with pytest.raises(ShapeError, match="Xs must be an array"):
        f.rts_smoother("abc", covs)
    with pytest.raises(ParameterError, match="fx_args must be None, a dict"):
        f.rts_smoother(means, covs, fx_args=3)
    with pytest.raises(ParameterError, match="UT must be a callable"):
        f.rts_smoother_factors(means, factors, UT="merwe")


def test_a_failure_in_the_backward_pass_names_the_step(filtered):
    means, _, factors = filtered
    fx_args = [{}] * LIN2_T
    fx_args[6] = {"bad": True}  # the prediction into step 6, used by smoothing step 5
    with pytest.raises(NonFiniteError, match=r"^at smoothing step 5 \(Qs\[6\], dts\[6\], fx_args\[6\]\): "):
        lin2_filter().rts_smoother_factors(means, factors, fx_args=fx_args)
    Qs = [LIN2_Q] * LIN2_T
    Qs[9] = np.eye(3)
    with pytest.raises(ShapeError, match=r"^at smoothing step 8 \(Qs\[9\]"):
        lin2_filter().rts_smoother_factors(means, factors, Qs=Qs)


def test_the_smoother_leaves_the_filter_alone(filtered):
    means, covs, _ = filtered
    f = lin2_filter()
    f.predict()
    before = copy.deepcopy(f)
    f.rts_smoother(means, covs, Qs=[LIN2_Q] * LIN2_T, fx_args={})
    for name in ("x", "P1_2", "x_prior", "P1_2_prior"):
        np.testing.assert_array_equal(getattr(f, name), getattr(before, name))
