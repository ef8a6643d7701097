"""Errors: every bad input raises a specific, documented squkf exception and loses nothing.

The fault matrix (bad measurements, matrices, factors, model functions, weights, dt; failed
downdates, singular innovations) on the single filter, each error checked to leave the filter as
it was and able to go on; the fleet's errors naming the rows or describing the failing filter's
own values; complex and text input; junk input (property-based). g13ej's IFAIL numbers are
checked in tests/test_nag.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from models import (
    CV3_K,
    CV3_NZ,
    CV_DT,
    CV_P0,
    CV_R,
    CV_X0,
    CV_Z,
    assert_filter_state,
    assert_fleet_state,
    assert_same_estimate,
    ct_fx,
    ct_hx,
    ct_mid_step_filter,
    cv3_zs,
    cv_filter,
    cv_fx,
    filter_state,
    fleet_state,
    make_cv3_fleet,
    step,
)

from squkf import (
    CallSequenceError,
    CubatureWeights,
    DowndateError,
    GainError,
    MerweScaledWeights,
    NonFiniteError,
    NotPositiveDefiniteError,
    ParameterError,
    ShapeError,
    SquareRootUKF,
    SqukfError,
    SqukfValueError,
)

# == the fault matrix of the single filter =========================================================


def still_works(f):
    f.update(ct_hx(f.x) + 0.5)
    f.predict()
    assert np.all(np.isfinite(f.x)) and np.all(np.diag(np.asarray(f.P1_2)) > 0)


def check(f, action, error, match=None):
    snap = filter_state(f)
    with pytest.raises(error, match=match) as info:
        action(f)
    assert isinstance(info.value, SqukfError) or error not in (SqukfError,)
    assert_filter_state(f, snap)
    still_works(f)
    return info.value


@pytest.mark.parametrize(
    "z, error, match",
    [
        (np.zeros(3), ShapeError, "length 3"),
        (np.zeros((2, 2)), ShapeError, "shape"),
        (np.array([np.inf, 1.0]), NonFiniteError, "z contains"),
        (np.array([np.nan, -np.inf]), NonFiniteError, "z contains"),
        ("abc", ShapeError, "z could not"),
        (np.array([1.0 + 1j, 2.0]), ShapeError, "complex"),
    ],
)
def test_bad_measurements(z, error, match):
    check(ct_mid_step_filter(), lambda f: f.update(z), error, match)


BAD_MATRICES = [
    (np.array([[1.0, 0.5], [0.0, 1.0]]), "wrong shape", ShapeError),
    (np.diag([1.0, 2.0, 3.0, 4.0, np.nan]), "nan", NonFiniteError),
    (np.eye(5) + np.triu(np.ones((5, 5)), 1) * 0.1, "not symmetric", SqukfValueError),
    (-np.eye(5), "negative definite", NotPositiveDefiniteError),
]


@pytest.mark.parametrize("name", ["P", "Q"])
@pytest.mark.parametrize("value, label, error", BAD_MATRICES, ids=[b[1] for b in BAD_MATRICES])
def test_bad_state_matrices(name, value, label, error):
    e = check(ct_mid_step_filter(), lambda f: setattr(f, name, value), error)
    assert name in str(e)


def test_singular_P_rejected_but_singular_Q_accepted():
    check(
        ct_mid_step_filter(),
        lambda f: setattr(f, "P", np.diag([1.0, 1, 1, 1, 0])),
        NotPositiveDefiniteError,
        "P",
    )
    f = ct_mid_step_filter()
    f.Q = np.diag([1.0, 1, 0, 0, 0])  # lower-rank process noise (Q_discrete_white_noise) is fine
    f.update(ct_hx(f.x))
    f.predict()
    assert np.all(np.isfinite(f.P))


BAD_R = [
    (np.eye(3), ShapeError),
    (np.array([[1.0, np.inf], [np.inf, 1.0]]), NonFiniteError),
    (np.array([[1.0, 0.3], [0.0, 1.0]]), SqukfValueError),
    (-np.eye(2), NotPositiveDefiniteError),
]


@pytest.mark.parametrize("value, error", BAD_R)
def test_bad_R_as_attribute_and_per_call(value, error):
    check(ct_mid_step_filter(), lambda f: setattr(f, "R", value), error, "R")
    if value.shape == (2, 2):
        check(ct_mid_step_filter(), lambda f: f.update(ct_hx(f.x), R=value), error, "R")


@pytest.mark.parametrize("value, error", [(np.eye(4), ShapeError), (-np.eye(5), NotPositiveDefiniteError)])
def test_bad_Q_per_call(value, error):
    check(ct_mid_step_filter(), lambda f: f.predict(Q=value), error, "Q")


@pytest.mark.parametrize("name", ["P1_2", "R1_2"])
def test_bad_factors(name):
    n = 5 if name == "P1_2" else 2
    upper = np.eye(n)
    upper[0, 1] = 0.5
    check(ct_mid_step_filter(), lambda f: setattr(f, name, upper), SqukfValueError, "lower triangular")
    if name == "P1_2":  # a singular R is a valid noise model, and so is its factor
        zero_diag = np.eye(n)
        zero_diag[1, 1] = 0.0
        check(
            ct_mid_step_filter(),
            lambda f: setattr(f, name, zero_diag),
            NotPositiveDefiniteError,
            "zero on its diagonal",
        )
    check(ct_mid_step_filter(), lambda f: setattr(f, name, np.eye(n + 1)), ShapeError)


@pytest.mark.parametrize("vectorized", [False, True])
@pytest.mark.parametrize("where", ["fx", "hx"])
@pytest.mark.parametrize("fault", ["shape", "nan", "inf", "raises"])
def test_bad_model_functions(vectorized, where, fault):
    f = ct_mid_step_filter(vectorized)
    good = getattr(f, where)

    def bad(*args):
        if fault == "raises":
            raise KeyError("user model failed")
        out = np.array(good(*args), dtype=float)
        if fault == "shape":
            return out[..., :-1]
        out.flat[-1] = np.nan if fault == "nan" else np.inf
        return out

    error = {"shape": ShapeError, "nan": NonFiniteError, "inf": NonFiniteError, "raises": KeyError}[fault]
    if where == "fx":
        check(f, lambda g: g.predict(fx=bad), error)
    else:
        check(f, lambda g: g.update(ct_hx(g.x), hx=bad), error)


@pytest.mark.parametrize(
    "dim_x, points, kw, match",
    [
        pytest.param(5, lambda: MerweScaledWeights(alpha=0.0), {}, "alpha", id="alpha-zero"),
        pytest.param(5, lambda: MerweScaledWeights(kappa=-5.0), {}, "kappa", id="kappa-below-minus-n"),
        pytest.param(5, CubatureWeights, {"scheme": "augmented"}, "augmented", id="cubature-augmented"),
        pytest.param(5, MerweScaledWeights, {"scheme": "sideways"}, "scheme", id="unknown-scheme"),
        pytest.param(0, MerweScaledWeights, {}, "dim_x", id="dim_x-zero"),
    ],
)
def test_weight_parameters_out_of_domain(dim_x, points, kw, match):
    """The points (built inside the check: some refuse at construction), scheme or size refused."""
    with pytest.raises(ParameterError, match=match):
        SquareRootUKF(dim_x, 2, 1.0, ct_hx, ct_fx, points(), **kw)


def test_failed_negative_weight_downdate():
    # beta = 0 keeps Wc[0] close to Wm[0] = -17.5: moving the centre alone makes the weighted
    # "covariance" Wc0 (1 - Wm0)^2 d^2 + Wm0 (1 - Wm0) d^2 negative along that axis
    f = ct_mid_step_filter(points=MerweScaledWeights(0.3, 0.0, -2.0))
    f.Q = None
    f.update(ct_hx(f.x))
    X = f.ask_predict()
    F = np.array([ct_fx(x, 1.0) for x in X])
    F[0] += [5e4, 0, 0, 0, 0]  # the central point far from the rest: Wc[0] < 0 dominates
    snap = filter_state(f)
    with pytest.raises(DowndateError) as info:
        f.tell_predict(F)
    assert info.value.errno == 301 and isinstance(info.value, np.linalg.LinAlgError)
    assert_filter_state(f, snap)
    f.tell_predict([ct_fx(x, 1.0) for x in X])


def test_singular_innovation():
    f = ct_mid_step_filter(points=MerweScaledWeights())  # positive weights: no downdate before the gain
    f.R = np.zeros((2, 2))
    e = check(f, lambda g: g.update(np.zeros(2), hx=lambda x: np.array([1.0, 2.0])), GainError)
    assert e.errno == 302


@pytest.mark.parametrize("dt", [np.nan, np.inf, "x", 1j])
def test_bad_dt(dt):
    check(ct_mid_step_filter(), lambda f: f.predict(dt=dt), ParameterError, "dt")


def test_call_sequence_errors_are_runtime_errors():
    f = ct_mid_step_filter()
    f.ask_predict()
    with pytest.raises(CallSequenceError) as info:
        f.ask_update()
    assert isinstance(info.value, RuntimeError)


def test_integer_and_float32_inputs_compute_in_float64():
    a, b = ct_mid_step_filter(), ct_mid_step_filter()
    a.x = np.array([2000, 10, 3000, -5, 0], dtype=np.int64)
    b.x = np.array([2000, 10, 3000, -5, 0], dtype=np.float64)
    a.P = np.diag([400, 4, 400, 4, 1]).astype(np.float32)
    b.P = np.diag([400.0, 4, 400, 4, 1])
    for f in (a, b):
        f.update(np.array([3605, 1], dtype=np.int32) if f is a else np.array([3605.0, 1.0]))
    assert a.x.dtype == np.float64 and np.asarray(a.P1_2).dtype == np.float64
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P1_2, b.P1_2)


# == one-dimensional arrays, complex and text input, update(None) mid-step =========================


@pytest.mark.parametrize("name", ["R", "Q", "P"])
def test_one_d_array_of_length_above_one_is_an_error_naming_np_diag(name):
    f = cv_filter()
    snap = filter_state(f)
    with pytest.raises(ShapeError, match=r"np\.diag"):
        setattr(f, name, np.ones(4 if name != "R" else 2))
    assert_filter_state(f, snap)


COMPLEX_OR_TEXT = [
    ("z", np.array([1.0 + 1e-3j, 0.2])),
    ("z", ["a", "b"]),
    ("z", np.array(["1.0", "2.0"])),
    ("x", CV_X0 + 0j),
    ("x", ["1", "2", "3", "4"]),
    ("P", CV_P0 + 0j),
    ("P", np.array([["1"] * 4] * 4)),
    ("R", CV_R.astype(complex)),
    ("Q", [[object()] * 4] * 4),
]


@pytest.mark.parametrize("name,value", COMPLEX_OR_TEXT, ids=lambda v: type(v).__name__)
def test_complex_or_non_numeric_input_is_a_shape_error(name, value):
    f = cv_filter()
    step(f, CV_Z[0])
    f.predict()
    snap = filter_state(f)
    with pytest.raises(ShapeError):
        if name == "z":
            f.update(value)
        else:
            setattr(f, name, value)
    assert_filter_state(f, snap)


def test_update_none_during_a_pending_prediction_is_a_call_sequence_error():
    f, twin = cv_filter(), cv_filter()
    step(f, CV_Z[0])
    step(twin, CV_Z[0])
    X = f.ask_predict()
    snap = filter_state(f)
    with pytest.raises(CallSequenceError):
        f.update(None)
    assert_filter_state(f, snap)
    f.tell_predict([cv_fx(s, CV_DT) for s in X])  # the prediction is still pending
    twin.predict()
    f.update(CV_Z[1])
    twin.update(CV_Z[1])
    assert_same_estimate(f, twin)


# == junk input (property-based) ===================================================================


JUNK_INPUTS = st.one_of(
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
    value=JUNK_INPUTS,
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


# == the fleet: a subset of no filters, a failing filter described by its own values ===============


# -- 7. a subset of no filters is an error ---------------------------------------------------------


NO_ROWS = [[], np.array([], dtype=int), np.zeros(CV3_K, dtype=bool), slice(0, 0)]


@pytest.mark.parametrize("rows", NO_ROWS, ids=repr)
def test_a_subset_of_no_filters_is_an_error_naming_rows(rows):
    fl = make_cv3_fleet()
    snap = fleet_state(fl)
    with pytest.raises(ParameterError, match="rows"):
        fl.subset(rows)
    assert_fleet_state(fl, snap)
    assert len(fl.subset([2])) == 1


# -- 9. a flagged filter's failure describes its own values, as the single filter's error does ----


def single_error(f: SquareRootUKF, call) -> str:
    with pytest.raises(SqukfError) as info:
        call(f)
    return f"{type(info.value).__name__}: {info.value}"


def test_a_singular_innovation_is_described_by_the_failing_filters_own_values():
    fl = make_cv3_fleet()
    R = np.stack([0.1 * np.eye(CV3_NZ)] * CV3_K)
    R[1] = 0.0
    fl.R = R
    fl.predict()
    one = fl[1]  # filter 1 alone, as it is now
    scale = np.array([1.0, 0.0, 1.0])  # filter 1's hx is constant: with R = 0, Sy is singular
    z = cv3_zs(1)[:, 0]
    fl.update(z, scale=scale)
    assert fl.failed.tolist() == [False, True, False]
    expected = single_error(one, lambda f: f.update(z[1], scale=0.0))
    assert fl.failure[1] == expected


def test_non_finite_images_are_described_by_the_failing_filters_own_values():
    fl = make_cv3_fleet()
    one = fl[2]
    fl.predict(bad=np.array([False, False, True]))
    assert fl.failed.tolist() == [False, False, True]
    assert fl.failure[2] == single_error(one, lambda f: f.predict(bad=True))
