"""SquareRootUKF's attributes behave as filterpy's: what a filterpy program does to them works.

filterpy code reads arrays and keeps them (a ``Saver``, a plot's list), edits covariances in
place, copies and pickles filters in the middle of a step and runs filters inside filterpy's
banks. Each test compares with an untouched twin filter, a freshly built reference or filterpy.
"""

from __future__ import annotations

import copy
import math
import pickle
import warnings

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise, Saver
from filterpy.kalman import IMMEstimator, MerweScaledSigmaPoints, MMAEFilterBank, UnscentedKalmanFilter
from models import (
    CV_DT,
    CV_P0,
    CV_Q,
    CV_R,
    CV_X0,
    CV_Z,
    FILTER_STATE,
    assert_filter_state,
    assert_same_estimate,
    ct_hx,
    cv_filter,
    cv_fx,
    filter_state,
    one_d_measured,
    step,
)

from squkf import (
    CallSequenceError,
    JulierWeights,
    MerweScaledWeights,
    NonFiniteError,
    ParameterError,
    ShapeError,
    SquareRootUKF,
    SqukfError,
    SqukfValueError,
)

RECORDS = (
    "x",
    "P",
    "x_prior",
    "P_prior",
    "x_post",
    "P_post",
    "P1_2",
    "P1_2_prior",
    "P1_2_post",
    "K",
    "y",
    "S",
    "SI",
    "sigmas_f",
    "sigmas_h",
)


# -- fresh arrays -----------------------------------------------------------------------------


def test_every_step_assigns_fresh_arrays():
    f, twin = cv_filter(), cv_filter()
    step(f, CV_Z[0])
    step(twin, CV_Z[0])
    before = {k: getattr(f, k) for k in RECORDS}
    kept = {k: v.copy() for k, v in before.items()}
    step(f, CV_Z[1])
    step(twin, CV_Z[1])
    for k in RECORDS:
        # the step did not write into what was read before it ...
        np.testing.assert_array_equal(before[k], kept[k], err_msg=k)
        assert getattr(f, k) is not before[k], k
    # ... and editing what was read before the step changes nothing now
    for k in RECORDS:
        before[k][...] = 123.0
    assert_filter_state(f, filter_state(twin))
    step(f, CV_Z[2])
    step(twin, CV_Z[2])
    assert_same_estimate(f, twin)


@pytest.mark.parametrize("scheme", ["redrawn", "augmented", "propagated"])
def test_editing_factor_records_changes_nothing(scheme):
    f, twin = cv_filter(scheme), cv_filter(scheme)
    step(f, CV_Z[0])
    step(twin, CV_Z[0])
    f.predict()
    twin.predict()
    for name in ("P1_2_prior", "P1_2_post", "P1_2", "x_prior", "x_post", "sigmas_f"):
        a = getattr(f, name)
        a *= 3.0  # in place, on what the filter handed out
    f.update(CV_Z[1])
    twin.update(CV_Z[1])
    assert_same_estimate(f, twin, records=False)  # x_prior and sigmas_f are records the test edited
    for name in ("x_post", "P1_2_post", "y", "K", "S1_2", "sigmas_h"):
        np.testing.assert_array_equal(getattr(f, name), getattr(twin, name), err_msg=name)
    assert f.log_likelihood == twin.log_likelihood


@pytest.mark.parametrize("scheme", ["redrawn", "augmented", "propagated"])
def test_arrays_of_ask_and_tell_are_not_read_back(scheme):
    f, twin = cv_filter(scheme), cv_filter(scheme)
    step(twin, CV_Z[0])
    X = f.ask_predict()
    F = [cv_fx(s, CV_DT) for s in X]
    X[...] = 0.0  # edited between ask and tell: the filter keeps its own set
    F = np.array(F)
    xp, Sp = f.tell_predict(F)
    F[...] = np.nan
    xp[...] = np.nan
    Sp[...] = np.nan
    Y = f.ask_update()
    H = np.array([ct_hx(s) for s in Y])
    Y[...] = 1e6
    z = CV_Z[0].copy()
    xq, Sq = f.tell_update(H, z)
    for a in (H, z, xq, Sq):
        a[...] = np.nan
    assert_same_estimate(f, twin)
    step(f, CV_Z[1])
    step(twin, CV_Z[1])
    assert_same_estimate(f, twin)


@pytest.mark.parametrize("scheme", ["redrawn", "augmented", "propagated"])
@pytest.mark.parametrize("vectorized", [False, True])
def test_model_functions_that_scribble_on_their_points_change_nothing(scheme, vectorized):
    """fx and hx may overwrite the points they are given (and return them): the step is unchanged."""

    def fx_scribble(X, dt):
        out = np.stack([cv_fx(s, dt) for s in X]) if vectorized else cv_fx(X, dt)
        X[...] = out  # the images written over the points, and the points' own array returned
        return X

    def hx_scribble(X):
        out = np.stack([ct_hx(s) for s in X]) if vectorized else ct_hx(X)
        X[...] = -1e9
        return out

    fxv = (lambda X, dt: np.stack([cv_fx(s, dt) for s in X])) if vectorized else cv_fx
    hxv = (lambda X: np.stack([ct_hx(s) for s in X])) if vectorized else ct_hx
    f = cv_filter(scheme, vectorized=vectorized)
    twin = cv_filter(scheme, vectorized=vectorized)
    f.fx, f.hx, twin.fx, twin.hx = fx_scribble, hx_scribble, fxv, hxv
    for z in CV_Z[:3]:
        step(f, z)
        step(twin, z)
        assert_same_estimate(f, twin)
        for name in ("sigmas_f", "sigmas_h"):
            np.testing.assert_array_equal(getattr(f, name), getattr(twin, name), err_msg=name)


# -- in-place edits ---------------------------------------------------------------------------


def test_multi_statement_symmetric_edit_equals_assignment():
    f, twin = cv_filter(), cv_filter()
    q = 0.003
    f.Q[0, 1] = f.Q[1, 0] = q
    Q = CV_Q.copy()
    Q[0, 1] = Q[1, 0] = q
    twin.Q = Q
    f.R[0, 0] *= 2.0
    R = CV_R.copy()
    R[0, 0] *= 2.0
    twin.R = R
    for z in CV_Z[:3]:
        step(f, z)
        step(twin, z)
        assert_same_estimate(f, twin, exact=False)
    np.testing.assert_array_equal(f.Q, twin.Q)


@pytest.mark.parametrize("edit", ["P *= 4", "P[0,0] = 9", "x[1] = 2"])
def test_in_place_edits_of_state_take_effect(edit):
    f, twin = cv_filter(), cv_filter()
    step(f, CV_Z[0])
    step(twin, CV_Z[0])
    if edit == "P *= 4":
        f.P *= 4
        twin.P = 4 * twin.P
    elif edit == "P[0,0] = 9":
        f.P[0, 0] = 9.0
        P = twin.P.copy()
        P[0, 0] = 9.0
        twin.P = P
    else:
        f.x[1] = 2.0
        x = twin.x.copy()
        x[1] = 2.0
        twin.x = x
    step(f, CV_Z[1])
    step(twin, CV_Z[1])
    assert_same_estimate(f, twin, exact=False)


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


# -- copies and pickles -------------------------------------------------------------------------


def _copies(f):
    return {
        "copy": copy.copy(f),
        "deepcopy": copy.deepcopy(f),
        "pickle": pickle.loads(pickle.dumps(f)),
    }


def _stopped_at(where):
    """An augmented filter after one step, stopped ``where`` in the next, its twin, and the points asked."""
    f, ref = cv_filter("augmented"), cv_filter("augmented")
    step(f, CV_Z[0])
    step(ref, CV_Z[0])
    X = None
    if where == "after ask_predict":
        X = f.ask_predict()
    elif where == "after tell_predict":
        f.tell_predict([cv_fx(s, CV_DT) for s in f.ask_predict()])
    return f, ref, X


def _finish_step(g, where, X):
    """Finish the step :func:`_stopped_at` stopped, with the update by ``Z[1]``."""
    if where == "after ask_predict":
        g.tell_predict([cv_fx(s, CV_DT) for s in X])
    elif where == "idle":
        g.predict()
    g.update(CV_Z[1])


@pytest.mark.parametrize("kind", ["copy", "deepcopy", "pickle"])
@pytest.mark.parametrize("where", ["idle", "after ask_predict", "after tell_predict"])
def test_editing_a_copy_in_place_does_not_touch_the_original(kind, where):
    f, ref, X = _stopped_at(where)
    c = _copies(f)[kind]
    c.P *= 10.0
    c.Q[0, 0] += 1.0
    c.R *= 3.0
    c.x[0] = -99.0
    c.predict()  # and running the copy does not either
    c.update(CV_Z[3])
    _finish_step(f, where, X)
    step(ref, CV_Z[1])
    assert_same_estimate(f, ref)
    assert not np.allclose(c.x, f.x)


@pytest.mark.parametrize("kind", ["copy", "deepcopy", "pickle"])
@pytest.mark.parametrize("where", ["idle", "after ask_predict", "after tell_predict"])
def test_copy_mid_step_finishes_the_step(kind, where):
    f, ref, X = _stopped_at(where)
    c = _copies(f)[kind]
    for g in (c, f):  # the copy first: it must not disturb the original
        _finish_step(g, where, X)
        step(g, CV_Z[2])
    step(ref, CV_Z[1])
    step(ref, CV_Z[2])
    assert_same_estimate(c, ref)
    assert_same_estimate(f, ref)


# -- Saver -----------------------------------------------------------------------------------


def test_saver_history_is_never_rewritten():
    f = cv_filter()
    s = Saver(f)
    saved_x, saved_P = [], []
    for z in CV_Z[:3]:
        step(f, z)
        s.save()
        saved_x.append(f.x.copy())
        saved_P.append(f.P.copy())
        f.P *= 4.0  # edits after the save
        f.x[0] = 5.0
        f.Q[0, 0] *= 1.1
    assert len(s.x) == len(s.P) == 3
    for k in range(3):
        np.testing.assert_array_equal(s.x[k], saved_x[k])
        np.testing.assert_array_equal(s.P[k], saved_P[k])
    s.to_array()
    assert s.x.shape == (3, 4) and s.P.shape == (3, 4, 4)


# -- schemes with a propagated set: edits between predict and update ---------------------------


@pytest.mark.parametrize("scheme", ["augmented", "propagated"])
@pytest.mark.parametrize("edit", ["P *= 2", "P[0,0] += 1", "x[0] += 1", "P = P", "none"])
def test_edit_between_predict_and_update_takes_effect(scheme, edit):
    f = cv_filter(scheme)
    step(f, CV_Z[0])
    f.predict()
    if edit == "P *= 2":
        f.P *= 2.0
    elif edit == "P[0,0] += 1":
        f.P[0, 0] += 1.0
    elif edit == "x[0] += 1":
        f.x[0] += 1.0
    elif edit == "P = P":
        f.P[0, 0] = f.P[0, 0]  # an edit that changes nothing
    f.update(CV_Z[1])
    if edit in ("P = P", "none"):
        # no change: the propagated set is used, as by a twin that made no edit
        t = cv_filter(scheme)
        step(t, CV_Z[0])
        step(t, CV_Z[1])
        assert_same_estimate(f, t)
        return
    # the reference: a fresh filter set to the edited prior and updated (a set redrawn from it)
    t = cv_filter(scheme)
    step(t, CV_Z[0])
    t.predict()
    x, P = t.x.copy(), t.P.copy()
    if edit == "P *= 2":
        P *= 2.0
    elif edit == "P[0,0] += 1":
        P[0, 0] += 1.0
    else:
        x[0] += 1.0
    g = cv_filter(scheme)
    g.x, g.P = x, P
    g.update(CV_Z[1])
    np.testing.assert_allclose(f.x, g.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(f.P, g.P, rtol=1e-12, atol=1e-12)
    t.update(CV_Z[1])  # and it is not what the unedited prior gives
    assert not np.allclose(f.x, t.x)


def test_replacing_points_between_ask_and_tell_uses_the_handed_out_set():
    f, twin = cv_filter(), cv_filter()
    step(f, CV_Z[0])
    step(twin, CV_Z[0])
    X = f.ask_predict()
    f.points_fn = JulierWeights(kappa=1.0)
    xp, Sp = f.tell_predict([cv_fx(s, CV_DT) for s in X])
    twin.predict()
    np.testing.assert_array_equal(xp, twin.x_prior)
    np.testing.assert_array_equal(Sp, twin.P1_2_prior)
    # from now on the new points are used
    assert f.Wm.shape[0] == 9 and not np.array_equal(f.Wm, twin.Wm)


def _scaled_residual(a, b):
    return 1.1 * np.subtract(a, b)


def _half_step_add(x, dx):
    return x + 0.5 * dx


def _shifted_mean(sigmas, Wm):
    return Wm @ sigmas + 0.01


@pytest.mark.parametrize(
    "hook, value, default",
    [
        ("residual_z", _scaled_residual, np.subtract),
        ("residual_x", _scaled_residual, np.subtract),
        ("state_add", _half_step_add, np.add),
        ("x_mean", _shifted_mean, None),
        ("z_mean", _shifted_mean, None),
    ],
)
def test_a_hook_assigned_between_steps_is_used_from_the_next_step(hook, value, default):
    """filterpy's hooks are plain attributes: assigning one after some steps changes the next steps.

    Each hook here deliberately changes the numbers, so that a hook left unused shows.
    """
    f, plain = cv_filter(), cv_filter()
    step(f, CV_Z[0])
    step(plain, CV_Z[0])
    setattr(f, hook, value)
    ref = cv_filter(**{{"x_mean": "x_mean_fn", "z_mean": "z_mean_fn"}.get(hook, hook): value})
    ref.x, ref.P = f.x, f.P
    assert getattr(f, hook) is value
    for z in CV_Z[1:3]:
        step(f, z)
        step(ref, z)
        step(plain, z)
    np.testing.assert_allclose(f.x, ref.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(f.P, ref.P, rtol=1e-12, atol=1e-12)
    assert not np.allclose(f.x, plain.x, rtol=1e-6, atol=0)
    # and set back, the plain operation is used again
    setattr(f, hook, default)
    back = cv_filter()
    back.x, back.P = f.x, f.P
    step(f, CV_Z[3])
    step(back, CV_Z[3])
    np.testing.assert_allclose(f.x, back.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(f.P, back.P, rtol=1e-12, atol=1e-12)


# -- conventions --------------------------------------------------------------------------------


def test_dt_conventions():
    seen = []

    def rec_fx(x, dt):
        seen.append(dt)
        return cv_fx(x, dt)

    f = SquareRootUKF(4, 2, CV_DT, ct_hx, rec_fx, MerweScaledWeights())
    f.x, f.P = CV_X0, CV_P0
    f.predict(dt=0)
    assert set(seen) == {0.0}
    np.testing.assert_allclose(f.x, CV_X0, atol=1e-12)
    seen.clear()
    f.predict(dt=-1.0)
    assert set(seen) == {-1.0}
    for bad in (np.nan, np.inf, -np.inf, 1 + 2j, np.complex128(1.0), np.array(1 + 0j), "1.0x", [1.0, 2.0]):
        snap = filter_state(f)
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # refused, not cast with a ComplexWarning
            with pytest.raises(ParameterError):
                f.predict(dt=bad)
        assert_filter_state(f, snap)


def _bank_pair():
    """Two SquareRootUKFs and two filterpy UKFs, the same models (different process noise)."""
    ours, theirs = [], []
    for q in (0.01, 1.0):
        Q = Q_discrete_white_noise(2, dt=CV_DT, var=q, block_size=2) + 1e-6 * np.eye(4)
        for lst, cls in ((ours, SquareRootUKF), (theirs, UnscentedKalmanFilter)):
            f = cls(4, 2, CV_DT, ct_hx, cv_fx, MerweScaledSigmaPoints(4, 0.5, 2.0, 0.0))
            f.x, f.P, f.Q, f.R = CV_X0.copy(), CV_P0.copy(), Q.copy(), CV_R.copy()
            lst.append(f)
    return ours, theirs


def test_mmae_filter_bank_runs_with_squkf():
    ours, theirs = _bank_pair()
    a = MMAEFilterBank(ours, [0.5, 0.5], 4)
    b = MMAEFilterBank(theirs, [0.5, 0.5], 4)
    for z in CV_Z:
        a.predict()  # filterpy's bank calls f.predict(0): dt = 0
        b.predict()
        a.update(z)
        b.update(z)
        np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(a.P, b.P, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(a.p, b.p, rtol=1e-9, atol=1e-12)
    assert not np.allclose(a.p, 0.5)


def test_imm_estimator_runs_with_squkf():
    ours, theirs = _bank_pair()
    M = np.array([[0.95, 0.05], [0.05, 0.95]])
    a = IMMEstimator(ours, [0.5, 0.5], M)
    b = IMMEstimator(theirs, [0.5, 0.5], M)
    for z in CV_Z:
        a.predict()
        b.predict()
        a.update(z)
        b.update(z)
        np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(a.P, b.P, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(a.mu, b.mu, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("value", [2.2e-5, np.array([2.2e-5]), np.array([[2.2e-5]]), np.float64(2.2e-5)])
def test_scalar_and_one_element_noise_in_one_dimension(value):
    f = one_d_measured()
    f.R = value
    f.Q = value
    # read back as assigned, as filterpy: a 1-element vector stays one (f.R[0] is a number)
    shape = (1,) if np.ndim(value) == 1 else (1, 1)
    np.testing.assert_array_equal(f.R, np.full(shape, 2.2e-5))
    np.testing.assert_array_equal(f.Q, np.full(shape, 2.2e-5))
    g = one_d_measured()
    g.R, g.Q = np.array([[2.2e-5]]), np.array([[2.2e-5]])
    for h in (f, g):
        h.predict()
        h.update(1.3)
    np.testing.assert_array_equal(f.x, g.x)
    np.testing.assert_array_equal(f.P, g.P)


def test_scalar_noise_means_a_multiple_of_identity():
    f, g = cv_filter(), cv_filter()
    f.R = 0.3
    g.R = 0.3 * np.eye(2)
    step(f, CV_Z[0])
    step(g, CV_Z[0])
    assert_same_estimate(f, g)


@pytest.mark.parametrize("name", ["R", "Q", "P"])
def test_one_d_array_of_length_above_one_is_an_error_naming_np_diag(name):
    f = cv_filter()
    snap = filter_state(f)
    with pytest.raises(ShapeError, match=r"np\.diag"):
        setattr(f, name, np.ones(4 if name != "R" else 2))
    assert_filter_state(f, snap)


@pytest.mark.parametrize(
    "z",
    [
        None,
        np.nan,
        np.array([np.nan]),
        np.ma.masked_all(1),
        np.ma.masked_array([1.0], mask=[True]),
    ],
    ids=["None", "nan", "[nan]", "masked_all", "masked"],
)
def test_no_measurement_in_one_dimension(z):
    f = one_d_measured()
    f.R = 0.1
    f.predict()
    f.update(z)
    assert f._state.phase == "idle"
    np.testing.assert_array_equal(f.x_post, f.x_prior)
    np.testing.assert_array_equal(f.P1_2_post, f.P1_2_prior)
    np.testing.assert_array_equal(f.x, f.x_prior)


@pytest.mark.parametrize(
    "z",
    [None, np.array([np.nan, np.nan]), np.ma.masked_all(2), np.ma.masked_array([1.0, 2.0], mask=[1, 1])],
    ids=["None", "all-nan", "masked_all", "masked"],
)
def test_no_measurement(z):
    f, twin = cv_filter(), cv_filter()
    step(f, CV_Z[0])
    step(twin, CV_Z[0])
    f.predict()
    f.update(z)
    assert f._state.phase == "idle"
    np.testing.assert_array_equal(f.x_post, f.x_prior)
    np.testing.assert_array_equal(f.P1_2_post, f.P1_2_prior)
    # and the next step is an ordinary one from that prior
    twin.predict()
    twin.update(None)
    step(f, CV_Z[1])
    step(twin, CV_Z[1])
    assert_same_estimate(f, twin)


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


# -- factors accepted back ------------------------------------------------------------------------


def test_a_singular_noise_has_a_factor_accepted_back():
    f = cv_filter()
    f.R = np.diag([1.0, 0.0])
    f.Q = Q_discrete_white_noise(2, dt=CV_DT, var=0.1, block_size=2)  # rank 2 of 4
    R, Q = f.R.copy(), f.Q.copy()
    f.R1_2 = f.R1_2
    f.Q1_2 = f.Q1_2
    np.testing.assert_allclose(f.R, R, rtol=0, atol=1e-15)
    np.testing.assert_allclose(f.Q, Q, rtol=0, atol=1e-15 * np.abs(Q).max() * 16)
    Q1 = Q_discrete_white_noise(2, dt=CV_DT, var=0.1)  # 2x2 of rank 1 in a 2-state filter
    g = SquareRootUKF(
        2, 1, CV_DT, lambda x: x[:1], lambda x, dt: np.array([x[0] + dt * x[1], x[1]]), MerweScaledWeights()
    )
    g.Q = Q1
    g.Q1_2 = g.Q1_2
    np.testing.assert_allclose(g.Q, Q1, rtol=0, atol=1e-15)
    step(f, CV_Z[0])
    assert np.all(np.isfinite(f.P))


def test_records_list_is_complete():
    # the helpers compare what a failed call must keep; they read each record without error
    f = cv_filter()
    step(f, CV_Z[0])
    for k in FILTER_STATE:
        assert np.all(np.isfinite(np.asarray(getattr(f, k), dtype=float))), k
    assert math.isfinite(f.log_likelihood)
