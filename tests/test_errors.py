"""Errors: every bad input raises a specific, documented squkf exception and loses nothing.

The fault matrix (bad measurements, matrices, factors, model functions, weights, dt; failed
downdates, singular innovations) on the single filter, each error checked to leave the filter as
it was and able to go on; the fleet's errors naming the rows or describing the failing filter's
own values; complex and text input; junk input (property-based). g13ej's IFAIL numbers are
checked in tests/test_nag.py. Issue 35: model functions and hooks are callable (``fx`` and ``hx``
may be None, filterpy's placeholder, for one filter given them per call; a fleet needs both).
"""

from __future__ import annotations

import sys

import numpy as np
import pytest
from hypothesis import assume, given, settings
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
    cv_fx_stacked,
    cv_placeholder_filter,
    filter_state,
    fleet_state,
    make_cv3_fleet,
    positions_hx,
    radar_gated_filter,
    raising,
    step,
)

from squkf import (
    CallSequenceError,
    CubatureWeights,
    DowndateError,
    Fleet,
    GainError,
    Gate,
    MerweScaledWeights,
    NonFiniteError,
    NotPositiveDefiniteError,
    ParameterError,
    ShapeError,
    SquareRootUKF,
    SqukfError,
    SqukfValueError,
    UnsetError,
)

# every test here ends in a documented error or decision: no numpy RuntimeWarning may escape squkf
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")


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
    except UnsetError:  # a placeholder (None, all NaN) was assigned: it reads back, and a step refuses
        shown = getattr(f, target)
        assert target in ("x", "P") and (shown is None or np.isnan(shown).all())
        return
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


# == issue 29, 14. a fleet given per-point model functions ==========================================


def test_a_per_point_fx_or_hx_of_a_wrong_shape_is_told_the_fleet_calls_it_with_stacks():
    fl = Fleet(5, 4, 2, 1.0, positions_hx, cv_fx, MerweScaledWeights())  # cv_fx stacks X[0..3]
    snap = fleet_state(fl)
    with pytest.raises(
        ShapeError,
        match=r"^fx values have shape \(4, 9, 4\), expected \(5, 9, 4\): a fleet calls fx once with the"
        r" stack X of shape \(5, 9, 4\) \(5 filters, 9 sigma points each, dim_x=4; component i of every"
        r" point is X\[\.\.\., i\], shape \(5, 9\)\), not once per point",
    ):
        fl.predict()
    assert_fleet_state(fl, snap)
    # in chunks of 3: the chunk's own stack
    fl = Fleet(5, 4, 2, 1.0, ct_hx, cv_fx_stacked, MerweScaledWeights(), chunk=3)
    fl.predict()
    snap = fleet_state(fl)
    with pytest.raises(
        ShapeError,
        match=r"^hx values of filters 0 to 2 \(one call of 3\) have shape \(2, 9, 4\), expected \(3, 9, 2\):"
        r" a fleet calls hx once with the stack X of shape \(3, 9, 4\) \(3 filters,",
    ):
        fl.update(np.ones((5, 2)))
    assert_fleet_state(fl, snap)


def notes(exc: BaseException) -> list[str]:
    return getattr(exc, "__notes__", [])


@pytest.mark.parametrize("chunk", [None, 2])
def test_an_exception_inside_a_fleets_fx_or_hx_propagates_unchanged(chunk):
    exc = ValueError("the user's own")
    fl = Fleet(3, 4, 2, 1.0, positions_hx, raising(exc), MerweScaledWeights(), chunk=chunk)
    snap = fleet_state(fl)
    with pytest.raises(ValueError) as info:
        fl.predict()
    assert info.value is exc  # the very object
    assert_fleet_state(fl, snap)
    k = 3 if chunk is None else 2
    if sys.version_info >= (3, 11):
        assert notes(exc) == [
            f"squkf: a fleet calls fx once with the stack X of shape ({k}, 9, 4) ({k} filters, 9 sigma points"
            f" each, dim_x=4; component i of every point is X[..., i], shape ({k}, 9)), not once per point,"
            " and fx returns the stack of their values"
        ]
    # a function written for one point: its own error, as it raised it
    fl = Fleet(2, 4, 2, 1.0, ct_hx, cv_fx_stacked, MerweScaledWeights(), chunk=chunk)
    fl.predict()
    snap = fleet_state(fl)
    with pytest.raises(IndexError) as info:  # ct_hx reads X[2] of a stack of 2 filters
        fl.update(np.ones((2, 2)))
    assert_fleet_state(fl, snap)
    if sys.version_info >= (3, 11):
        assert "a fleet calls hx once with the stack X of shape (2, 9, 4)" in notes(info.value)[0]


def test_squkfs_own_exception_from_a_fleets_fx_gets_no_note():
    exc = NonFiniteError("raised by the model through squkf")
    fl = Fleet(3, 4, 2, 1.0, positions_hx, raising(exc), MerweScaledWeights())
    with pytest.raises(NonFiniteError) as info:
        fl.predict()
    assert info.value is exc and notes(exc) == []


# == issue 29, 15. no RuntimeWarning on a path that ends in a documented error or decision ===========
#
# This file runs with RuntimeWarning as an error (pytestmark above): the junk input, and these.


@pytest.mark.parametrize("name", ["P1_2", "Q1_2", "R1_2"])
@pytest.mark.parametrize("front", ["filter", "fleet"])
def test_a_factor_whose_covariance_overflows_float64_is_refused(name, front):
    f = make_cv3_fleet() if front == "fleet" else cv_filter()
    state, check = (
        (fleet_state, assert_fleet_state) if front == "fleet" else (filter_state, assert_filter_state)
    )
    dim = (CV3_NZ if front == "fleet" else 2) if name == "R1_2" else 4
    snap = state(f)
    with pytest.raises(
        NonFiniteError, match=rf"^{name}(\[0\])? stands for a covariance .* beyond float64's range"
    ):
        setattr(f, name, 2.0**512 * np.eye(dim))  # 2**1024 overflows; the largest float is just below
    check(f, snap)
    setattr(f, name, 2.0**511 * np.eye(dim))
    cov = getattr(f, name[0])
    assert np.all(np.isfinite(cov)) and cov[(0,) * cov.ndim] == 2.0**1022


@pytest.mark.parametrize("front", ["filter", "fleet"])
@pytest.mark.parametrize("outlier", [1e200, -1e300, np.finfo(float).max])
def test_a_huge_outlier_is_rejected_alone_by_a_per_component_gate(front, outlier):
    gated, partial = radar_gated_filter(front), radar_gated_filter(front)
    z = np.array([outlier, 0.67])
    missing = np.array([np.nan, 0.67])
    if front == "fleet":
        z, missing = np.stack([z, z]), np.stack([missing, missing])
    for f in (gated, partial):
        f.predict()
    gated.update(z)
    partial.update(missing)
    np.testing.assert_array_equal(gated.rejected, np.broadcast_to([True, False], gated.rejected.shape))
    np.testing.assert_array_equal(gated.x, partial.x)
    np.testing.assert_array_equal(gated.P1_2, partial.P1_2)


@settings(max_examples=100, deadline=None)
@given(
    y=st.lists(st.floats(-50.0, 50.0), min_size=3, max_size=3),
    diag=st.lists(st.floats(0.1, 10.0), min_size=3, max_size=3),
    below=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
    power=st.integers(0, 1016),  # y and Sy stay below the largest float
)
def test_the_per_component_decision_keeps_to_the_scale_of_y_and_Sy(y, diag, below, power):
    """Scaled by 2**power, as far as the largest float: the same decisions, no overflow on the way."""
    gate = Gate(0.95, per_component=True)
    Sy = np.diag(diag) + np.tril(np.outer(below, np.ones(3)), -1)
    y = np.array(y)
    stat = y * y / np.einsum("jk,jk->j", Sy, Sy)
    assume(np.all(np.abs(stat - gate.threshold(3)) > 1e-9 * gate.threshold(3)))
    scale = 2.0**power
    want = gate.reject(y, Sy, np.zeros(()))
    np.testing.assert_array_equal(gate.reject(y * scale, Sy * scale, np.zeros(())), want)


# == issue 35, 7. model functions and hooks: callable, or None where filterpy takes a placeholder ==


def test_fx_and_hx_may_be_none_and_given_per_call_as_in_filterpy():
    f, twin = cv_placeholder_filter(), cv_filter()
    for z in CV_Z[:3]:
        f.predict(fx=cv_fx)
        f.update(z, hx=ct_hx)
        step(twin, z)
    assert_same_estimate(f, twin)
    # a call given none is refused, naming the function, and changes nothing
    snap = filter_state(f)
    with pytest.raises(ParameterError, match=r"^predict needs fx, but the filter's fx is None"):
        f.predict()
    with pytest.raises(ParameterError, match=r"^compute_process_sigmas needs fx"):
        f.compute_process_sigmas(CV_DT)
    with pytest.raises(ParameterError, match=r"^at step 0: predict needs fx"):
        f.batch_filter(CV_Z[:2])
    with pytest.raises(ParameterError, match=r"^rts_smoother needs fx"):
        f.rts_smoother(np.stack([f.x] * 2), np.stack([f.P] * 2))
    assert_filter_state(f, snap)
    f.predict(fx=cv_fx)
    snap = filter_state(f)
    with pytest.raises(ParameterError, match=r"^update needs hx, but the filter's hx is None"):
        f.update(CV_Z[3])
    assert_filter_state(f, snap)
    f.update(None)  # no measurement: no hx wanted, as in filterpy
    # the halves of a step call neither
    X = f.ask_predict()
    f.tell_predict([cv_fx(x, CV_DT) for x in X])
    Y = f.ask_update()
    f.tell_update([ct_hx(y) for y in Y], CV_Z[3])
    # assigned later, they serve every call
    f.fx, f.hx = cv_fx, ct_hx
    step(f, CV_Z[4])
    assert np.all(np.isfinite(f.x))


@pytest.mark.parametrize("value", [5, "fx", np.eye(2)], ids=["int", "str", "array"])
def test_a_model_function_given_per_call_that_is_not_callable_is_refused(value):
    check(
        ct_mid_step_filter(),
        lambda f: f.predict(fx=value),
        ParameterError,
        r"^fx must be a callable, got fx=",
    )
    check(
        ct_mid_step_filter(),
        lambda f: f.update(ct_hx(f.x), hx=value),
        ParameterError,
        r"^hx must be a callable, got hx=",
    )


NOT_CALLABLE = [pytest.param(5, id="int"), pytest.param("a", id="str"), pytest.param(np.eye(2), id="array")]
CONSTRUCTOR_FUNCTIONS = [
    "hx",
    "fx",
    "sqrt_fn",
    "x_mean_fn",
    "z_mean_fn",
    "residual_x",
    "residual_z",
    "state_add",
]


@pytest.mark.parametrize("value", NOT_CALLABLE)
@pytest.mark.parametrize("name", CONSTRUCTOR_FUNCTIONS)
def test_a_model_function_or_hook_that_is_not_callable_is_refused_at_construction(name, value):
    single = {"hx": ct_hx, "fx": cv_fx, name: value}
    with pytest.raises(ParameterError, match=rf"^{name} must be a callable or None, got {name}="):
        SquareRootUKF(4, 2, CV_DT, points=MerweScaledWeights(), **single)
    if name == "sqrt_fn":  # (a fleet takes none)
        return
    fleet = {"hx": positions_hx, "fx": cv_fx_stacked, name: value}
    with pytest.raises(ParameterError, match=rf"^{name} must be a callable"):
        Fleet(CV3_K, 4, 2, 1.0, points=MerweScaledWeights(), **fleet)


@pytest.mark.parametrize("value", NOT_CALLABLE)
@pytest.mark.parametrize("name", ["fx", "hx", "x_mean", "z_mean", "residual_x", "residual_z", "state_add"])
def test_assigning_a_model_function_or_hook_that_is_not_callable_is_refused(name, value):
    f = ct_mid_step_filter()
    before = getattr(f, name)
    check(f, lambda g: setattr(g, name, value), ParameterError, rf"^{name} must be a callable or None, got")
    assert getattr(f, name) is before
    fl = make_cv3_fleet()
    before = getattr(fl, name)
    snap = fleet_state(fl)
    with pytest.raises(ParameterError, match=rf"^{name} must be a callable"):
        setattr(fl, name, value)
    assert getattr(fl, name) is before
    assert_fleet_state(fl, snap)


@pytest.mark.parametrize("name", ["fx", "hx"])
def test_a_fleet_needs_fx_and_hx(name):
    match = rf"^{name} must be a callable, got {name}=None .*: a fleet needs fx and hx"
    with pytest.raises(ParameterError, match=match):
        Fleet(
            CV3_K,
            4,
            2,
            1.0,
            points=MerweScaledWeights(),
            **{"hx": positions_hx, "fx": cv_fx_stacked, name: None},
        )
    fl = make_cv3_fleet()
    before = getattr(fl, name)
    snap = fleet_state(fl)
    with pytest.raises(ParameterError, match=match):
        setattr(fl, name, None)
    assert getattr(fl, name) is before
    assert_fleet_state(fl, snap)
    one = {"hx": positions_hx, "fx": cv_fx_stacked, name: None}
    f = SquareRootUKF(4, 2, 1.0, points=MerweScaledWeights(), vectorized=True, **one)
    with pytest.raises(ParameterError, match=match):
        Fleet.from_filters([f])
