"""Transactions: a call that fails changes nothing, and the filter goes on from where it was.

A bad in-place edit raises at the next call and leaves the filter as before; a failed assignment
keeps a pending edit; a bad hook result, a bad value told or a model function that raises leaves
the step where it was, so that it can be completed. (The fault matrix of tests/test_errors.py
checks the same for every bad input; the fleet's own transactions are in tests/test_fleet.py.)
"""

from __future__ import annotations

import numpy as np
import pytest
from models import (
    CV_Z,
    assert_filter_state,
    assert_fleet_state,
    assert_same_estimate,
    ct_fx,
    ct_hx,
    ct_measurements,
    ct_negative_weight_filter,
    cv3_zs,
    cv_filter,
    filter_state,
    fleet_state,
    make_cv3_fleet,
    step,
)

from squkf import (
    NonFiniteError,
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
    ("P", np.full((4, 4), np.nan), NonFiniteError),
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
    assert ukf._state.phase == "prior"


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
