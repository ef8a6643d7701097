"""Transactions: a call that fails changes nothing, and the filter goes on from where it was.

A bad in-place edit raises at the next call and leaves the filter as before; a failed assignment
keeps a pending edit; a bad hook result, a bad value told or a model function that raises leaves
the step where it was, so that it can be completed; a fleet given bad input, or failing with
``on_error='raise'``, changes no filter. (The fault matrix of tests/test_errors.py checks the same
for every bad input of the single filter.)
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from models import (
    CV_Z,
    FLEET_DT,
    assert_filter_state,
    assert_fleet_state,
    assert_same_estimate,
    ct_fx,
    ct_hx,
    ct_measurements,
    ct_negative_weight_filter,
    cv3_zs,
    cv_filter,
    cv_fleet,
    cv_fx_stacked,
    filter_state,
    fleet_and_singles,
    fleet_batch_setup,
    fleet_state,
    fleet_with_and_without,
    make_cv3_fleet,
    range_bearing_hx,
    step,
)

from squkf import (
    CallSequenceError,
    FleetStepError,
    MerweScaledWeights,
    NonFiniteError,
    NotPositiveDefiniteError,
    ParameterError,
    ShapeError,
    SqukfError,
    SqukfValueError,
)

# == in-place edits and assignments that fail ======================================================


BAD_EDITS = [
    ("Q", (0, 1), 0.5, SqukfValueError, "predict"),  # asymmetric
    ("Q", (2, 2), np.nan, NonFiniteError, "predict"),
    ("P", (0, 1), 0.5, SqukfValueError, "predict"),
    ("P", (1, 1), np.inf, NonFiniteError, "update"),
    ("P", (0, 0), -50.0, SqukfError, "predict"),  # not positive definite
    ("R", (0, 1), 0.3, SqukfValueError, "update"),
    ("R", (1, 1), np.nan, NonFiniteError, "update"),
    ("x", (2,), np.nan, NonFiniteError, "predict"),
    ("x", (0,), np.inf, NonFiniteError, "update"),
]


@pytest.mark.parametrize("name,idx,value,exc,call", BAD_EDITS)
def test_invalid_in_place_edit_raises_at_next_call_and_changes_nothing(name, idx, value, exc, call):
    f, twin = cv_filter(), cv_filter()
    step(f, CV_Z[0])
    step(twin, CV_Z[0])
    if call == "update":
        f.predict()
        twin.predict()
    snap = filter_state(f)
    arr = getattr(f, name)
    old = arr[idx]
    arr[idx] = value
    with pytest.raises(exc):
        f.predict() if call == "predict" else f.update(CV_Z[1])
    with pytest.raises(exc):  # still pending: raised again, not swallowed
        f.predict() if call == "predict" else f.update(CV_Z[1])
    arr[idx] = old  # undo the edit: the filter is as it was
    assert_filter_state(f, snap)
    if call == "predict":
        f.predict()
        twin.predict()
    f.update(CV_Z[1])
    twin.update(CV_Z[1])
    assert_same_estimate(f, twin)


BAD_ASSIGNMENTS = [
    ("P", np.array([[1.0, 0.5], [0.0, 1.0]]), ShapeError),
    ("P", np.diag([1.0, 1.0, -1.0, 1.0]), SqukfError),
    ("P", np.where(np.eye(4) > 0, np.nan, 0.0), NonFiniteError),  # (all NaN is a placeholder)
    ("P", np.triu(np.ones((4, 4))) + np.eye(4), SqukfValueError),
    ("Q", "big", ShapeError),
    ("R", np.array([1.0, 2.0]), ShapeError),
    ("x", np.zeros(3), ShapeError),
    ("x", np.array([1.0, np.nan, 0.0, 0.0]), NonFiniteError),
]


@pytest.mark.parametrize("name,bad,exc", BAD_ASSIGNMENTS)
def test_failed_assignment_keeps_pending_in_place_edit(name, bad, exc):
    f, twin = cv_filter(), cv_filter()
    step(f, CV_Z[0])
    step(twin, CV_Z[0])
    # a valid in-place edit, pending
    if name == "x":
        f.x[0] += 1.0
        x = twin.x.copy()
        x[0] += 1.0
        twin.x = x
    else:
        getattr(f, name)[0, 0] *= 2.0
        A = getattr(twin, name).copy()
        A[0, 0] *= 2.0
        setattr(twin, name, A)
    edited = getattr(f, name)
    with pytest.raises(exc):
        setattr(f, name, bad)
    assert getattr(f, name) is edited
    step(f, CV_Z[1])
    step(twin, CV_Z[1])
    assert_same_estimate(f, twin, exact=False)


# -- hooks ------------------------------------------------------------------------------------


def _good_residual(a, b):
    return np.subtract(a, b)


def _good_mean(sigmas, Wm):
    return np.dot(Wm, sigmas)


def _good_add(x, dx):
    return np.add(x, dx)


BAD_HOOKS = [
    ("state_add", lambda x, dx: 1.0, ShapeError, "predict"),
    ("state_add", lambda x, dx: np.append(x + dx, 0.0), ShapeError, "update"),
    ("residual_x", lambda a, b: (a - b)[:2], ShapeError, "predict"),
    ("residual_x", lambda a, b: np.full(4, np.nan), NonFiniteError, "update"),
    ("x_mean", lambda s, W: np.zeros(3), ShapeError, "predict"),
    ("x_mean", lambda s, W: np.full(4, np.inf), NonFiniteError, "predict"),
    ("z_mean", lambda s, W: np.zeros((2, 2)), ShapeError, "update"),
    ("z_mean", lambda s, W: np.array([np.nan, 0.0]), NonFiniteError, "update"),
    ("residual_z", lambda a, b: np.zeros(3), ShapeError, "update"),
    ("residual_z", lambda a, b: np.array([np.inf, 0.0]), NonFiniteError, "update"),
]


@pytest.mark.parametrize("hook,bad,exc,call", BAD_HOOKS)
def test_bad_hook_result_names_the_hook_and_changes_nothing(hook, bad, exc, call):
    f = cv_filter(
        x_mean_fn=_good_mean,
        z_mean_fn=_good_mean,
        residual_x=_good_residual,
        residual_z=_good_residual,
        state_add=_good_add,
    )
    step(f, CV_Z[0])
    if call == "update":
        f.predict()
    snap = filter_state(f)
    good = getattr(f, hook)
    setattr(f, hook, bad)
    name = {"x_mean": "x_mean_fn", "z_mean": "z_mean_fn"}.get(hook, hook)
    with pytest.raises(exc, match=name):
        f.predict() if call == "predict" else f.update(CV_Z[1])
    setattr(f, hook, good)
    assert_filter_state(f, snap)


# == ask/tell: bad values told, a model function that raises =======================================


def poison(A, kind):
    """A copy of A made wrong in one way."""
    if kind == "short":
        return A[:, :-1]
    if kind == "transposed":
        return A.T
    B = A.copy()
    B[2, 0] = np.nan if kind == "nan" else np.inf
    return B


@pytest.mark.parametrize(
    "kind, error",
    [("short", ShapeError), ("transposed", ShapeError), ("nan", NonFiniteError), ("inf", NonFiniteError)],
)
def test_bad_values_are_rejected_and_the_step_can_be_completed(kind, error):
    ref, ukf = ct_negative_weight_filter(), ct_negative_weight_filter()
    z = ct_measurements(1)[0]
    ref.predict()
    ref.update(z)
    X = ukf.ask_predict()
    F = np.array([ct_fx(x, 1.0) for x in X])
    snap = filter_state(ukf)
    with pytest.raises(error):
        ukf.tell_predict(poison(F, kind))
    assert_filter_state(ukf, snap)
    ukf.tell_predict(F)
    H = np.array([ct_hx(y) for y in ukf.ask_update()])
    snap = filter_state(ukf)
    with pytest.raises(error):
        ukf.tell_update(poison(H, kind), z)
    assert_filter_state(ukf, snap)
    ukf.tell_update(H, z)
    np.testing.assert_array_equal(ukf.x, ref.x)
    np.testing.assert_array_equal(ukf.P1_2, ref.P1_2)


def test_predict_restores_the_step_when_fx_raises():
    ukf = ct_negative_weight_filter()
    snap = filter_state(ukf)

    def broken(x, dt):
        raise ZeroDivisionError("user model failed")

    with pytest.raises(ZeroDivisionError, match="user model failed"):
        ukf.predict(fx=broken)
    assert_filter_state(ukf, snap)
    ukf.predict()
    assert ukf._engine.phase == "prior"


# == the fleet: an invalid edit in place ===========================================================


def test_an_invalid_edit_in_place_raises_at_the_next_call_and_changes_nothing():
    fl = make_cv3_fleet()
    fl.predict()
    snap = fleet_state(fl)
    P = fl.P
    P[1, 0, 0] = -1.0  # not positive definite
    with pytest.raises(SqukfError, match=r"P\[1\]"):
        fl.update(cv3_zs(1)[:, 0])
    P[1, 0, 0] = snap["P1_2"][1, 0, 0] ** 2  # put back: nothing had changed
    assert_fleet_state(fl, snap)


# == the fleet: bad input or on_error='raise' changes no filter ====================================


def test_reset_bad_input_changes_nothing():
    fleet = cv_fleet(3, MerweScaledWeights())
    fleet.x = np.arange(4.0)
    fleet.predict(bad=np.array([False, True, False]))
    snap = fleet_state(fleet)
    for kw, exc in [
        ({"x": np.zeros(3)}, ShapeError),
        ({"x": np.full(4, np.nan)}, NonFiniteError),
        ({"P": np.eye(3)}, ShapeError),
        ({"P": -np.eye(4)}, NotPositiveDefiniteError),
        ({"x": np.zeros(4), "P": -np.eye(4)}, NotPositiveDefiniteError),
    ]:
        with pytest.raises(exc):
            fleet.reset(1, **kw)
        assert_fleet_state(fleet, snap)


@pytest.mark.parametrize("where", ["predict", "update"])
def test_on_error_raise_changes_no_filter(where):
    K, k = 4, 1
    big, _, _, zs = fleet_with_and_without(K, k, on_error="raise")
    big.predict()
    big.update(zs[:, 0])
    bad = np.zeros(K, dtype=bool)
    bad[k] = True
    if where == "update":  # filter k's R zero and its hx constant: a singular innovation factor
        R = big.R
        R[k] = 0.0
        big.R = R
        big.predict()
    other = copy.deepcopy(big)
    snap = fleet_state(big)
    with pytest.raises(FleetStepError) as info:
        if where == "predict":
            big.predict(bad=bad)
        else:
            big.update(zs[:, 1], scale=np.where(bad, 0.0, 1.0))
    assert info.value.filters == (k,)
    assert len(info.value.reasons) == 1 and info.value.reasons[0]
    assert str(k) in str(info.value)
    assert isinstance(info.value, SqukfError) and isinstance(info.value, ArithmeticError)
    assert_fleet_state(big, snap)
    assert not big.failed.any()
    again = pickle.loads(pickle.dumps(info.value))
    assert again.filters == (k,) and again.reasons == info.value.reasons
    # the fleet goes on as if the failing call had not been made
    if where == "predict":
        big.predict()
        other.predict()
    else:
        big.update(zs[:, 1])
        other.update(zs[:, 1])
    assert_fleet_state(big, fleet_state(other))


# -- bad input raises for the whole call and changes nothing ------------------------------


def test_bad_input_changes_nothing():
    K = 3
    fleet, _, zs = fleet_and_singles(K, "merwe", "augmented")
    fleet.predict()
    fleet.update(zs[:, 0])
    fleet.predict()
    reference = copy.deepcopy(fleet)
    snap = fleet_state(fleet)
    z = zs[:, 1]
    z_inf = z.copy()
    z_inf[1, 0] = np.inf
    R_bad = np.stack([np.eye(2)] * K)
    R_bad[2] = -np.eye(2)
    calls = [
        (lambda: fleet.update(z[:2]), ShapeError),
        (lambda: fleet.update(z[:, :1]), ShapeError),
        (lambda: fleet.update(z.ravel()), ShapeError),
        (lambda: fleet.update(z_inf), NonFiniteError),
        (lambda: fleet.update(-z_inf), NonFiniteError),
        (lambda: fleet.update(z, R=np.eye(3)), ShapeError),
        (lambda: fleet.update(z, R=np.ones((K + 1, 2, 2))), ShapeError),
        (lambda: fleet.update(z, R=R_bad), SqukfError),
        (lambda: fleet.update(z, R=np.full((2, 2), np.nan)), NonFiniteError),
        (lambda: fleet.tell_update(np.zeros((K, 3, 2)), z), CallSequenceError),
        (lambda: fleet.tell_predict(np.zeros((K, 9, 4))), CallSequenceError),
    ]
    for call, exc in calls:
        with pytest.raises(exc):
            call()
        assert_fleet_state(fleet, snap)
    # the pending update still works, as in the fleet that never saw the bad calls
    fleet.update(z)
    reference.update(z)
    np.testing.assert_array_equal(fleet.x, reference.x)
    np.testing.assert_array_equal(fleet.P1_2, reference.P1_2)
    snap = fleet_state(fleet)
    for dt in (np.nan, np.inf, "a", 1j, np.complex128(1.0)):
        with pytest.raises(ParameterError):
            fleet.predict(dt)
        assert_fleet_state(fleet, snap)
    # tell_predict with values of the wrong shape, mid ask/tell
    X = fleet.ask_predict()
    snap = fleet_state(fleet)
    with pytest.raises(ShapeError):
        fleet.tell_predict(cv_fx_stacked(X, FLEET_DT)[:, :-1])
    assert_fleet_state(fleet, snap)
    fleet.tell_predict(cv_fx_stacked(X, FLEET_DT))
    X2 = fleet.ask_update()
    snap = fleet_state(fleet)
    with pytest.raises(ShapeError):
        fleet.tell_update(range_bearing_hx(X2)[..., :1], z)
    assert_fleet_state(fleet, snap)


def test_batch_filter_bad_input_changes_nothing():
    K, T = 3, 5
    fleet, _, zs = fleet_batch_setup(K, T)
    fleet.predict()
    snap = fleet_state(fleet)
    late_inf = zs.copy()
    late_inf[1, 3, 0] = np.inf
    calls = [
        (lambda: fleet.batch_filter(zs, keep="some"), ParameterError),
        (lambda: fleet.batch_filter(zs[:2]), ShapeError),
        (lambda: fleet.batch_filter(zs[..., :1]), ShapeError),
        (lambda: fleet.batch_filter(zs[0]), ShapeError),
        (lambda: fleet.batch_filter(zs, dts=[0.5, np.nan, 0.5, 0.5, 0.5]), ParameterError),
        (lambda: fleet.batch_filter(zs, fx_args=[1]), ParameterError),
        (lambda: fleet.batch_filter(zs, dts=[0.5] * (T + 1)), ShapeError),
        (lambda: fleet.batch_filter(zs, dts=np.ones((T, 1))), ShapeError),
        (lambda: fleet.batch_filter(late_inf), NonFiniteError),
    ]
    for call, exc in calls:
        with pytest.raises(exc):
            call()
        assert_fleet_state(fleet, snap)


def test_batch_filter_on_error_raise_changes_nothing():
    K, T = 3, 4
    fleet, _, zs = fleet_batch_setup(K, T)
    fleet.on_error = "raise"
    snap = fleet_state(fleet)

    def fx(X, dt):
        fx.calls += 1
        out = cv_fx_stacked(X, dt)
        if fx.calls == 3:  # the third prediction fails for filter 1
            out[1] = np.nan
        return out

    fx.calls = 0
    fleet.fx = fx
    with pytest.raises(FleetStepError) as info:
        fleet.batch_filter(zs)
    assert info.value.filters == (1,)
    assert_fleet_state(fleet, snap)
