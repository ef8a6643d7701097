"""Records handed out: arrays read from a filter or fleet are the caller's, and edits in place are taken.

filterpy code reads arrays and keeps them (a ``Saver``, a plot's list), edits covariances in
place, copies and pickles filters in the middle of a step. Every array read is a fresh one that
the filter never rewrites, an edit in place of ``x``, ``P``, ``Q`` or ``R`` takes effect at the
next call (single filter and fleet), and a 1-element covariance reads back as assigned. Each test
compares with an untouched twin filter, a freshly built reference or filterpy.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import pickle
import warnings

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise, Saver
from models import (
    CV_DT,
    CV_Q,
    CV_R,
    CV_Z,
    FILTER_STATE,
    assert_filter_state,
    assert_fleet_state,
    assert_same_estimate,
    ct_hx,
    cv3_zs,
    cv_filter,
    cv_fx,
    cv_measurements,
    edited_pair,
    filter_state,
    fleet_batch_setup,
    fleet_state,
    l96_fx,
    l96_hx,
    linear_pair,
    make_cv3_fleet,
    near_filter,
    near_measurements,
    one_d,
    one_d_filterpy,
    positions_hx,
    step,
)

from squkf import (
    Fleet,
    Gate,
    JulierWeights,
    MerweScaledWeights,
    NonFiniteError,
    ParameterError,
    SquareRootUKF,
    fleet_batch,
)
from squkf.batch import BatchResult
from squkf.boundary import loop, records

# == the single filter's records ===================================================================

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
    # (sigmas_f is not among them: filterpy's update uses the set a program writes there, and so does
    # squkf's: test_ukf.py's test_a_sigmas_f_changed_in_place_is_the_set_of_the_next_update_only)
    for name in ("P1_2_prior", "P1_2_post", "P1_2", "x_prior", "x_post"):
        a = getattr(f, name)
        a *= 3.0  # in place, on what the filter handed out
    f.update(CV_Z[1])
    twin.update(CV_Z[1])
    assert_same_estimate(f, twin, records=False)  # x_prior is a record the test edited
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


@pytest.mark.parametrize("kind", ["copy", "deepcopy", "pickle"])
@pytest.mark.parametrize(("scheme", "Q"), [("propagated", 1e-3), ("augmented", 0.0), ("redrawn", 1e-3)])
def test_a_fleet_copied_mid_update_is_its_own(kind, scheme, Q):
    """A fleet copied between ask_update and tell_update finishes its update as the original would have,
    however the original steps meanwhile (the pending second set may be the prediction's images, which
    live in the original's buffers)."""
    zs = cv3_zs(4)

    def asked():
        fl = make_cv3_fleet(scheme=scheme)
        fl.Q = Q * np.eye(4)
        fl.predict()
        return fl, fl.ask_update()

    ref, Y = asked()
    ref.tell_update(positions_hx(Y), zs[:, 0])
    f, Y = asked()
    c = {"copy": copy.copy, "deepcopy": copy.deepcopy, "pickle": lambda a: pickle.loads(pickle.dumps(a))}[
        kind
    ](f)
    f.tell_update(positions_hx(Y), zs[:, 0])
    for t in (1, 2):  # the original goes on, writing its buffers
        f.predict()
        f.update(zs[:, t])
    c.tell_update(positions_hx(Y), zs[:, 0])
    assert_fleet_state(c, fleet_state(ref))


#: Every array a fleet hands out as a record or its state.
FLEET_RECORDS = (
    "x", "P", "P1_2", "Q", "R", "x_prior", "P_prior", "P1_2_prior", "x_post", "P_post", "P1_2_post", "y",
    "log_likelihood", "likelihood", "mahalanobis", "nis", "rejected", "failed", "failure",
)  # fmt: skip


@pytest.mark.parametrize("scheme", ["redrawn", "augmented", "propagated"])
def test_a_fleets_records_are_the_callers(scheme):
    """What a fleet hands out is never written by its later steps (its buffers are used in turn)."""
    zs = cv3_zs(4)
    fl = make_cv3_fleet(scheme=scheme)
    fl.predict()
    fl.update(zs[:, 0])
    kept = {name: getattr(fl, name) for name in FLEET_RECORDS}
    copies = {name: a.copy() for name, a in kept.items()}
    for t in (1, 2, 3):
        fl.predict()
        fl.update(zs[:, t])
    for name, a in kept.items():
        np.testing.assert_array_equal(a, copies[name], err_msg=name)


def test_a_fleet_batch_filter_that_fails_keeps_the_pending_update():
    """The transaction of batch_filter puts back the fleet with its pending second set as it was."""
    zs = cv3_zs(3)
    ref = make_cv3_fleet(scheme="propagated")
    ref.predict()
    Y = ref.ask_update()
    ref.tell_update(positions_hx(Y), zs[:, 0])
    f = make_cv3_fleet(scheme="propagated")
    f.predict()
    Y = f.ask_update()
    calls = []

    def fails_at_the_second_update(X):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("hx fails")
        return positions_hx(X)

    f.hx = fails_at_the_second_update
    with pytest.raises(RuntimeError, match="hx fails"):
        f.batch_filter(zs)
    f.hx = positions_hx
    f.tell_update(positions_hx(Y), zs[:, 0])
    assert_fleet_state(f, fleet_state(ref))


class _CountingResidual:
    """A hook with a state of its own: it counts its calls."""

    def __init__(self):
        self.calls = 0

    def __call__(self, a, b):
        self.calls += 1
        return a - b


@pytest.mark.parametrize("where", ["idle", "after ask_update"])
def test_a_deep_copy_steps_with_its_own_hooks(where):
    f = cv_filter(residual_z=_CountingResidual())
    step(f, CV_Z[0])
    Y = None
    if where == "after ask_update":
        f.predict()
        Y = f.ask_update()
    g = copy.deepcopy(f)
    assert g.residual_z is not f.residual_z
    calls = f.residual_z.calls
    if Y is not None:
        g.tell_update([ct_hx(s) for s in Y], CV_Z[1])
    step(g, CV_Z[2])
    assert f.residual_z.calls == calls and g.residual_z.calls > calls


@pytest.mark.parametrize("kind", ["copy", "deepcopy", "pickle"])
def test_a_copy_has_the_gain_of_its_last_update(kind):
    """The gain formed for an earlier update is never handed out for a later one, copied or not."""
    f = cv_filter()
    step(f, CV_Z[0])
    _ = f.K  # formed for the first update, and kept
    step(f, CV_Z[1])
    c = _copies(f)[kind]
    np.testing.assert_array_equal(c.K, f.K)


def test_a_failed_batch_filter_keeps_an_assigned_gain():
    f = cv_filter()
    step(f, CV_Z[0])
    f.K = np.full((4, 2), 7.0)
    zs = [CV_Z[1], CV_Z[2], np.array([np.inf, 0.0])]
    with pytest.raises(NonFiniteError):
        f.batch_filter(zs)
    np.testing.assert_array_equal(f.K, np.full((4, 2), 7.0))


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


#: The public keys a filterpy ``Saver`` collects from a filter (its properties and ``__dict__``), as at
#: 0cdce8e, before the engine: unchanged by it.
SAVER_KEYS = set(
    "K P P1_2 P1_2_post P1_2_prior P_post P_prior Q Q1_2 R R1_2 S S1_2 SI Wc Wm dim_x dim_z fx fx_noise"
    " gate hx hx_noise inv likelihood log_det_S1_2 log_likelihood mahalanobis msqrt nis points_fn rejected"
    " residual_x residual_z scheme sigmas_f sigmas_h state_add vectorized x x_mean x_post x_prior y"
    " y_whitened z z_mean".split()
)


def _engine_arrays(f) -> list[np.ndarray]:
    """Every array the filter's engine holds: its state, its records, its buffers."""
    found: list[np.ndarray] = []

    def walk(v):
        if isinstance(v, np.ndarray):
            found.append(v)
        elif isinstance(v, (tuple, list)):
            for a in v:
                walk(a)
        elif isinstance(v, dict):
            for a in v.values():
                walk(a)

    e = f._engine
    for name in type(e).__slots__:
        v = getattr(e, name, None)
        walk(v.sets if name == "_buffers" else v)
    return found


def test_a_savers_history_has_the_same_keys_and_no_engine_buffer():
    """The records are formed when read: a Saver's rows are fresh arrays, none of them the engine's."""
    f = cv_filter()
    s = Saver(f)
    for z in CV_Z[:4]:
        step(f, z)
        s.save()
    assert {k for k in s.keys if not k.startswith("_")} == SAVER_KEYS
    engine = _engine_arrays(f)
    assert len(engine) > 10
    for key in s.keys:
        for row in s[key]:
            if isinstance(row, np.ndarray) and row.size:
                assert not any(np.shares_memory(row, a) for a in engine), key
    # what was saved is what the filter showed then, and stays so after more steps
    x3, P3, K3 = f.x.copy(), f.P.copy(), f.K.copy()
    np.testing.assert_array_equal(s.x[-1], x3)
    np.testing.assert_array_equal(s.P[-1], P3)
    np.testing.assert_array_equal(s.K[-1], K3)
    for z in CV_Z[4:7]:
        step(f, z)
    np.testing.assert_array_equal(s.x[3], x3)
    np.testing.assert_array_equal(s.K[3], K3)


def test_a_fleets_saver_rows_hold_no_engine_buffer():
    """A Saver on a fleet: no row is (or shares memory with) the arrays its later steps write."""
    zs = cv3_zs(4)
    fl = make_cv3_fleet()
    s = Saver(fl)
    for t in range(2):
        fl.predict()
        fl.update(zs[:, t])
        s.save()
    saved = {
        key: [np.array(row, copy=True) for row in s[key] if isinstance(row, np.ndarray)] for key in s.keys
    }
    assert saved["x"] and saved["P_post"] and "_buffers" not in s.keys
    buffers = [
        a
        for sets in fl._engine._buffers.sets.values()
        for group in sets
        for a in (group if isinstance(group, (list, tuple)) else [group])
        if isinstance(a, np.ndarray)
    ]
    for key in s.keys:
        for row in s[key]:
            if isinstance(row, np.ndarray) and row.size:
                assert not any(np.shares_memory(row, a) for a in buffers), key
    for t in (2, 3):
        fl.predict()
        fl.update(zs[:, t])
    for key, rows in saved.items():
        kept = [row for row in s[key] if isinstance(row, np.ndarray)]
        for a, b in zip(kept, rows):
            np.testing.assert_array_equal(a, b, err_msg=key)


def test_a_pickle_is_no_larger_than_before_the_engine():
    """Copies and pickles carry the state and a half-done step, not the engine's buffers (the sizes of
    these pickles at 0cdce8e: 6673, 7359 and 7369 bytes, a fleet's 5722)."""
    f = cv_filter()
    for z in CV_Z[:3]:
        step(f, z)
    assert len(pickle.dumps(f)) <= 6673
    f.predict()
    assert len(pickle.dumps(f)) <= 7359
    f.ask_update()
    assert len(pickle.dumps(f)) <= 7369
    fleet = make_cv3_fleet()
    fleet.predict()
    fleet.update(cv3_zs(1)[:, 0])
    assert len(pickle.dumps(fleet)) <= 5722


def test_a_filter_pickled_in_four_parts_loads():
    """A filter pickled as ``(__dict__, carried slots, engine, gain)`` (before both faces shared one
    pickle layout) loads with its written record, its gain and its edits pending, and steps as the
    filter it was pickled from."""
    f = cv_filter("augmented")
    for z in CV_Z[:2]:
        step(f, z)
    f.K = f.K * 2.0
    f.y = f.y + 1.0
    f.predict()
    f.P[0, 0] += 0.5  # an edit in place, taken at the next call
    state = copy.deepcopy(f).__getstate__()
    engine, (_, gain) = state.pop("_engine"), state.pop("_gain_of")
    own = {k: state.pop(k) for k in list(state) if k in type(f).__slots__}
    old = SquareRootUKF.__new__(SquareRootUKF)
    old.__setstate__((state, own, engine, gain))
    for name in ("P", "K", "y"):
        np.testing.assert_array_equal(getattr(old, name), getattr(f, name), err_msg=name)
    f.update(CV_Z[2])
    old.update(CV_Z[2])
    assert_filter_state(old, filter_state(f))
    np.testing.assert_array_equal(old.K, f.K)


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


# == an edit of x between predict and update =======================================================


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


# == K, 1-element covariances and the fleet's edits in place (issue 20's promises) =================

# -- 1. K is a fresh array on each read -------------------------------------------------------


def test_K_is_a_fresh_array_on_each_read():
    f = near_filter()
    f.predict()
    f.update(near_measurements(1)[0])
    first = f.K
    expected = first.copy()
    first[:] = 123.0
    np.testing.assert_array_equal(f.K, expected)
    assert f.K is not f.K


def test_a_savers_K_history_is_never_rewritten():
    f = near_filter()
    saver = Saver(f)
    for z in near_measurements(4):
        f.predict()
        saver.save()  # K of the previous update, read twice: two entries
        f.update(z)
        saver.save()
    Ks = saver["K"]
    assert len({id(k) for k in Ks}) == len(Ks)
    kept = [k.copy() for k in Ks]
    Ks[1][:] = np.nan  # editing one saved entry changes no other, nor the filter's K
    for j in (0, 2, 3):
        np.testing.assert_array_equal(Ks[j], kept[j])
    np.testing.assert_array_equal(f.K, kept[-1])
    f.predict()
    f.update(near_measurements(5)[4])
    for j in range(2, len(Ks)):
        np.testing.assert_array_equal(Ks[j], kept[j])


# -- 3. a 1-element covariance reads back as assigned (filterpy stores what it is given) ----------


@pytest.mark.parametrize("name", ["R", "Q", "P"])
def test_a_one_element_covariance_reads_back_as_assigned(name):
    ours, theirs = one_d(SquareRootUKF), one_d_filterpy()
    for f in (ours, theirs):
        setattr(f, name, np.array([0.25]))
    assert getattr(ours, name).shape == getattr(theirs, name).shape == (1,)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "conversion of an array with ndim > 0 to a scalar"
        value = getattr(ours, name)[0]
        assert np.ndim(value) == 0 and value == 0.25
        if name == "R":
            ours.P[0, 0] = ours.R[0]  # a client program's line
            theirs.P[0, 0] = theirs.R[0]
    # an edit in place takes effect, as for a matrix
    getattr(ours, name)[0] = 0.5
    getattr(theirs, name)[0] = 0.5
    for f in (ours, theirs):
        f.predict()
        f.update(np.array([1.0]))
    np.testing.assert_allclose(ours.x, theirs.x, rtol=1e-12)
    np.testing.assert_allclose(np.atleast_2d(ours.P), np.atleast_2d(theirs.P), rtol=1e-12)
    # as filterpy, a step assigns P a matrix; Q and R keep what was assigned
    assert ours.P.shape == theirs.P.shape == (1, 1)
    if name != "P":
        assert getattr(ours, name).shape == (1,)


def test_a_one_element_covariance_survives_copies_and_pickles():
    import pickle

    f = one_d(SquareRootUKF)
    f.R = np.array([0.25])
    for g in (copy.copy(f), copy.deepcopy(f), pickle.loads(pickle.dumps(f))):
        assert g.R.shape == (1,) and g.R[0] == 0.25
        g.R[0] = 4.0
        assert f.R[0] == 0.25
        np.testing.assert_array_equal(g.R1_2, [[2.0]])


# -- 10. an in-place edit of fleet.x, P, Q or R is never lost: taken at the next call --------------


EDITS = {
    "x": lambda fl: fl.x.__setitem__((1, 0), 5.0),
    "P": lambda fl: fl.P.__setitem__((2, 0, 0), 4.0),
    "P *=": lambda fl: fl.P.__imul__(2.0),
    "Q": lambda fl: fl.Q.__setitem__((1, 1), 0.5),
    "R": lambda fl: fl.R.__setitem__((0, 0), 2.0),
}


@pytest.mark.parametrize("name", list(EDITS))
def test_an_edit_in_place_of_a_fleet_attribute_takes_effect(name):
    plain = make_cv3_fleet()
    fl, ref = edited_pair(EDITS[name])
    zs = cv3_zs(3)
    for f in (fl, ref, plain):
        f.predict()
        f.update(zs[:, 0])
    np.testing.assert_array_equal(fl.x, ref.x)
    np.testing.assert_array_equal(fl.P1_2, ref.P1_2)
    assert not np.array_equal(fl.P1_2, plain.P1_2) or not np.array_equal(fl.x, plain.x)


def test_several_edits_in_place_and_every_route_sees_them():
    zs = cv3_zs(3)
    fl = make_cv3_fleet()
    fl.R[0, 0] = 2.0  # two statements on the same attribute: both kept
    fl.R[1, 1] = 3.0
    fl.x[0] += 1.0
    assert fl.R[0, 0] == 2.0 and fl.R[1, 1] == 3.0
    ref = make_cv3_fleet()
    ref.R = np.diag([2.0, 3.0])
    x = np.array(ref.x)
    x[0] += 1.0
    ref.x = x
    np.testing.assert_array_equal(fl.batch_filter(zs).means, ref.batch_filter(zs).means)
    for route in (lambda f: f.subset(slice(None)).x, lambda f: f[0].x, lambda f: copy.copy(f).x):
        fl, ref = edited_pair(EDITS["x"])
        np.testing.assert_array_equal(route(fl), route(ref))
    sd = pytest.importorskip("squkf.dask")
    fl, ref = edited_pair(EDITS["P"])
    got = sd.compute(sd.batch_filter(fl, zs), scheduler="synchronous")
    np.testing.assert_array_equal(got.means, ref.batch_filter(zs).means)


def test_arrays_read_before_a_step_are_never_rewritten():
    fl = make_cv3_fleet()
    x, P = fl.x, fl.P
    kept = x.copy(), P.copy()
    fl.predict()
    fl.update(cv3_zs(1)[:, 0])
    np.testing.assert_array_equal(x, kept[0])
    np.testing.assert_array_equal(P, kept[1])
    assert fl.x is not x and not np.array_equal(fl.x, x)


# -- the whitened innovations and log det S1_2: the records the likelihood is made of -----------------


def _whitened_oracle(f):
    """``S1_2^-1 y`` and ``log det S1_2`` from filterpy's records ``S`` and ``y`` (measured components)."""
    obs = ~np.isnan(f.S.diagonal())
    S, y = f.S[np.ix_(obs, obs)], f.y[obs]
    L = np.linalg.cholesky(S)
    w = np.full(f.dim_z, np.nan)
    w[obs] = np.linalg.solve(L, y)
    return w, 0.5 * np.linalg.slogdet(S)[1]


@pytest.mark.parametrize("z", [[10.5, 0.4], [np.nan, 0.4], [10.5, np.nan]])
def test_whitened_innovation_and_log_det_are_the_innovations_and_make_the_likelihood(z):
    f = cv_filter()
    assert np.array_equal(f.y_whitened, np.zeros(2)) and f.log_det_S1_2 == 0.0  # before any update
    f.predict()
    f.update(np.array(z))
    w, log_det = _whitened_oracle(f)
    obs = ~np.isnan(np.array(z))
    # a triangular solve of a 2x2 against numpy's: a few ulps of the innovation
    assert np.array_equal(np.isnan(f.y_whitened), ~obs)
    assert np.allclose(f.y_whitened[obs], w[obs], rtol=1e-12, atol=1e-14)
    assert math.isclose(f.log_det_S1_2, log_det, rel_tol=1e-12, abs_tol=1e-14)
    assert math.isclose(float(np.nansum(f.y_whitened**2)), f.nis, rel_tol=1e-12)
    mo = int(obs.sum())
    ll = -0.5 * (mo * math.log(2 * math.pi) + f.nis) - f.log_det_S1_2
    assert math.isclose(ll, f.log_likelihood, rel_tol=1e-12)
    w_read = f.y_whitened
    w_read[:] = 99.0  # a fresh array: the record is not the caller's to change
    assert not np.any(f.y_whitened == 99.0)


def test_batch_filter_keeps_each_steps_whitened_innovation_and_log_det():
    f, g = cv_filter(), cv_filter()
    zs = np.array(cv_measurements(6))
    zs[2] = np.nan  # a step without a measurement
    zs[4, 1] = np.nan
    result = f.batch_filter(zs)
    assert result.y_whitened.shape == (6, 2) and result.log_det_S1_2.shape == (6,)
    for t, z in enumerate(zs):
        g.predict()
        if np.isnan(z).all():
            g.update(None)
            assert np.isnan(result.y_whitened[t]).all() and result.log_det_S1_2[t] == 0.0
            continue
        g.update(z)
        assert np.array_equal(result.y_whitened[t], g.y_whitened, equal_nan=True)
        assert result.log_det_S1_2[t] == g.log_det_S1_2
    again = pickle.loads(pickle.dumps(result))
    assert np.array_equal(again.y_whitened, result.y_whitened, equal_nan=True)
    assert np.array_equal(again.log_det_S1_2, result.log_det_S1_2)


@pytest.mark.parametrize("gate", [None, Gate(0.9, per_component=True)], ids=repr)
def test_a_fleets_whitened_records_equal_its_single_filters_bit_for_bit(gate):
    fleet, singles, zs = fleet_batch_setup(K=3, T=7)
    fleet.gate = gate
    for f in singles:
        f.gate = gate
    result = fleet.subset(slice(None)).batch_filter(zs, keep=("means", "whitened"))
    assert result.y_whitened.shape == (3, 7, 2) and result.log_det_S1_2.shape == (3, 7)
    for k, f in enumerate(singles):
        one = f.batch_filter(zs[k])
        assert np.array_equal(result.y_whitened[k], one.y_whitened, equal_nan=True)
        assert np.array_equal(result.log_det_S1_2[k], one.log_det_S1_2)
    # the fleet's own records after a step (fresh filters: the singles above have run)
    fleet, singles, zs = fleet_batch_setup(K=3, T=7)
    fleet.gate = gate
    for f in singles:
        f.gate = gate
    fleet.batch_filter(zs[:, :3])
    fleet.predict()
    fleet.update(zs[:, 3])
    for k, f in enumerate(singles):
        f.batch_filter(zs[k, :3])
        f.predict()
        f.update(zs[k, 3])
        assert np.array_equal(fleet.y_whitened[k], f.y_whitened, equal_nan=True)
        assert fleet.log_det_S1_2[k] == f.log_det_S1_2
    assert fleet.subset([2]).y_whitened[0].tolist() == fleet.y_whitened[2].tolist()


def _log_det_as_the_likelihood_sums_it(S1_2) -> float:
    """``sum log|S1_2_ii|`` over the measured block, in the order and with the ``log`` of the update
    kernel's log-likelihood (Python's ``math.log`` is numba's; numpy's ``log`` and its sum's order differ
    in the last bits)."""
    total = 0.0
    for d in np.abs(np.diagonal(S1_2)).tolist():
        if not math.isnan(d):  # (a component not measured)
            total += math.log(d)
    return total


@pytest.mark.parametrize("route", ["joint", "hooks", "downdate", "partial"])
def test_log_det_is_the_update_kernels_own_sum_on_both_faces(route):
    """``log_det_S1_2`` is the update kernel's ``sum log|Sy_ii|``, the sum its log-likelihood takes, not a
    second one in numpy; a fleet's equals its single filters' bit for bit, on every update route (m = 10:
    numpy sums 8 terms or more in another order)."""
    n, m, K = 20, 10, 4
    rng = np.random.default_rng(7)
    hooks = {"hooks": {"residual_z": np.subtract}, "downdate": {"residual_x": np.subtract}}.get(route, {})

    def one():
        f = SquareRootUKF(n, m, 0.05, l96_hx, l96_fx, MerweScaledWeights(alpha=0.5), vectorized=True, **hooks)
        f.x, f.P, f.Q = 8.0 + rng.normal(size=n), np.eye(n), 0.01 * np.eye(n)
        f.R = np.diag(np.exp(rng.uniform(-4.0, 4.0, size=m)))  # (log|Sy_ii| of either sign)
        return f

    singles = [one() for _ in range(K)]
    fleet = Fleet.from_filters(singles)
    zs = 8.0 + rng.normal(size=(6, K, m))
    if route == "partial":
        zs[:, :, 1] = np.nan
    for z in zs:
        fleet.predict()
        fleet.update(z)
        for k, f in enumerate(singles):
            f.predict()
            f.update(z[k])
            assert f.log_det_S1_2 == _log_det_as_the_likelihood_sums_it(f.S1_2)
            assert fleet.log_det_S1_2[k] == f.log_det_S1_2


def test_whitened_records_are_kept_only_when_asked_and_keep_is_checked():
    fleet, _, zs = fleet_batch_setup(K=2, T=4)
    assert fleet.subset(slice(None)).batch_filter(zs).y_whitened is None
    assert fleet.subset(slice(None)).batch_filter(zs, keep="means").log_det_S1_2 is None
    for bad in ("whitened", ("final", "whitened"), ("means", "all"), ("means", "whitened", "x"), ["means"]):
        before = fleet.x
        with pytest.raises(ParameterError, match="keep"):
            fleet.batch_filter(zs, keep=bad)
        assert np.array_equal(fleet.x, before)


# == the registry of per-step records: one declaration reaches both faces and every result ============

#: A record added to the registry by a test alone: an existing field of the engine's update under a new
#: name and keep word (one number per filter, and one per component), declared as a record is declared.
NIS_AGAIN = records.StepRecord("nis_again", "nis", False, 0.0, "again")
Y_AGAIN = records.StepRecord("y_again", "y", True, np.nan, "again")


@dataclasses.dataclass
class _AgainResult(records.FleetResult):
    """``FleetResult`` with the test's records' typed fields, declared as a record's are."""

    nis_again: np.ndarray | None = None
    y_again: np.ndarray | None = None


def _same(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


def _delivered(record: records.StepRecord, K: int = 3, T: int = 7) -> None:
    """``record`` on both faces after each update (a fleet's equal to its single filters' bit for bit),
    in ``batch_filter``'s result ``(T, ...)``, in ``FleetResult`` with its keep word (None without it), and
    in ``squkf.dask``'s results, all equal."""
    fleet, singles, zs = fleet_batch_setup(K=K, T=T)  # (missing rows, components and a whole step)
    m = fleet.dim_z
    before = getattr(singles[0], record.name)
    assert _same(before, np.zeros(m) if record.per_component else 0.0)
    assert _same(getattr(fleet, record.name), np.zeros((K, m) if record.per_component else K))
    mine = fleet.subset(slice(None))
    for t in range(T):
        mine.predict()
        mine.update(zs[:, t])
        for k, f in enumerate(singles):
            f.predict()
            f.update(zs[k, t])
            # (nothing measured: a single filter keeps its last update's records, as filterpy's; a fleet's
            # filter not updated has the record's missing value, as batch_filter keeps for that step)
            expected = record.missing(m) if np.isnan(zs[k, t]).all() else getattr(f, record.name)
            assert _same(getattr(mine, record.name)[k], expected), (t, k)
    one = [g.batch_filter(zs[k]) for k, g in enumerate(fleet_batch_setup(K=K, T=T)[1])]
    shape = record.shape((T,), m)
    assert all(getattr(r, record.name).shape == shape for r in one)
    kept = fleet.subset(slice(None)).batch_filter(zs, keep=("means", record.keep))
    assert getattr(kept, record.name).shape == record.shape((K, T), m)
    for k in range(K):
        assert _same(getattr(kept, record.name)[k], getattr(one[k], record.name)), k
    assert getattr(fleet.subset(slice(None)).batch_filter(zs, keep="means"), record.name) is None
    assert getattr(pickle.loads(pickle.dumps(one[0])), record.name).shape == shape
    da = pytest.importorskip("dask.array")
    import squkf.dask as sd

    lazy = sd.batch_filter(fleet, da.from_array(zs, chunks=(2, -1, -1)), keep=("means", record.keep))
    assert _same(getattr(sd.compute(lazy, scheduler="synchronous"), record.name), getattr(kept, record.name))
    none = sd.compute(sd.batch_filter(fleet, da.from_array(zs), keep="means"), scheduler="synchronous")
    assert getattr(none, record.name) is None


@pytest.mark.parametrize("record", records.STEP_RECORDS, ids=lambda r: r.name)
def test_every_registry_record_is_on_both_faces_and_in_every_result(record):
    _delivered(record)


def test_a_record_added_to_the_registry_reaches_both_faces_and_every_result(monkeypatch):
    """The registry's entry and the faces' attribute (what ``squkf/boundary/records.py`` declares) are all
    a record needs: ``keep``, both faces, ``BatchResult``, ``FleetResult`` and ``squkf.dask`` take it."""
    monkeypatch.setattr(records, "STEP_RECORDS", (*records.STEP_RECORDS, NIS_AGAIN, Y_AGAIN))
    for record in (NIS_AGAIN, Y_AGAIN):
        attribute = records.StepProperty(f"The last update's {record.name}.", record)
        monkeypatch.setattr(records.StepRecords, record.name, attribute, raising=False)
    import squkf.dask as sd

    for module in (records, fleet_batch, sd):  # (its typed fields: where FleetResult is made)
        monkeypatch.setattr(module, "FleetResult", _AgainResult)
    for record in (NIS_AGAIN, Y_AGAIN):
        _delivered(record)
    # what it reads, and beside the others: one keep word adds both records, with another word too
    f = cv_filter()
    step(f, CV_Z[0])
    assert f.nis_again == f.nis and _same(f.y_again, f.y)
    assert {"nis_again", "y_again"} <= set(dict(Saver(f).properties))  # (a Saver collects them)
    fleet, _, zs = fleet_batch_setup(K=2, T=4)
    result = fleet.subset(slice(None)).batch_filter(zs, keep=("means", "again", "whitened"))
    assert _same(result.nis_again, result.nis) and result.y_whitened is not None
    assert np.array_equal(np.isnan(result.y_again), np.isnan(zs))  # (NaN where not measured)
    with pytest.raises(ParameterError, match="keep"):
        fleet.batch_filter(zs, keep=("final", "again"))
    with pytest.raises(ParameterError, match="keep"):
        fleet.batch_filter(zs, keep=("means", "again", "again"))


def test_keep_words_are_the_registrys_and_refused_as_before():
    state, words = loop.check_keep(("means", "whitened"))
    assert (state, words) == ("means", ("whitened",))
    assert loop.check_keep("all") == ("all", ())
    for bad in ("whitened", ("final", "whitened"), ("means", "whitened", "whitened"), ("means", "nis")):
        with pytest.raises(ParameterError, match="keep"):
            loop.check_keep(bad)


def test_a_batch_result_pickled_with_its_records_in_the_registrys_order_loads():
    """A ``BatchResult`` pickles its records positionally, in the registry's order (as before it moved)."""
    means, covs = np.zeros((2, 1)), np.ones((2, 1, 1))
    rej, nis, ll, w, ld = (
        np.zeros((2, 1), bool),
        np.ones(2),
        np.full(2, -1.0),
        np.full((2, 1), 0.5),
        np.ones(2),
    )
    result = records.BatchResult(means, covs, rej, nis, ll, w, ld)
    assert BatchResult is records.BatchResult  # (squkf.batch's name: older pickles find it there)
    assert _same(result.y_whitened, w) and _same(result.log_det_S1_2, ld)
    again = pickle.loads(pickle.dumps(result))
    assert _same(again[0], means) and _same(again.y_whitened, w) and _same(again.log_det_S1_2, ld)
    assert _same(records.BatchResult(means, covs, rej, nis, ll, log_det_S1_2=ld).log_det_S1_2, ld)
    with pytest.raises(TypeError, match="nis_again"):
        records.BatchResult(means, covs, rej, nis, ll, nis_again=nis)
    with pytest.raises(TypeError, match="'y_whitened' twice"):
        records.BatchResult(means, covs, rej, nis, ll, w, y_whitened=w)
    with pytest.raises(TypeError, match="keeps 2 per-step records"):
        records.BatchResult(means, covs, rej, nis, ll, w, ld, ld)


def test_each_registry_record_is_declared_in_every_result_and_documented():
    """Each record's typed field in ``FleetResult`` (its last fields, in the registry's order, so that it
    takes them positionally as ``BatchResult`` does), ``BatchResult``'s annotation, both results' docs and
    the faces' attribute with its own docstring, read-only with its name in the error."""
    names = [r.name for r in records.STEP_RECORDS]
    fields = [f.name for f in dataclasses.fields(records.FleetResult)]
    assert fields[-len(names) :] == names
    for name in names:
        assert name in records.BatchResult.__annotations__
        for result in (records.FleetResult, records.BatchResult):
            assert f"\n    {name} : ndarray" in result.__doc__, (result, name)
        for face in (SquareRootUKF, Fleet):
            attribute = getattr(face, name)
            assert isinstance(attribute, property) and "last update" in attribute.__doc__
        f = cv_filter()
        with pytest.raises(AttributeError, match=f"SquareRootUKF.{name} is a record"):
            setattr(f, name, 0.0)
        with pytest.raises(AttributeError, match=f"SquareRootUKF.{name} is a record"):
            delattr(f, name)


def test_a_property_declared_for_a_record_the_registry_lacks_says_so():
    with pytest.raises((LookupError, RuntimeError)) as err:

        class Faulty(records.StepRecords):
            y_typo = records.StepProperty("A typo.")

    found = err.value if isinstance(err.value, LookupError) else err.value.__cause__  # (3.11 wraps it)
    assert "Faulty.y_typo: no record 'y_typo'" in str(found)


def test_a_filter_pickled_before_the_kernel_wrote_log_det_reads_it_with_its_written_records():
    """A last update pickled without ``log det S1_2`` has it formed from its factor when loaded, and what
    was current with that update (a written ``y``, an assigned gain) is current still."""
    f = cv_filter()
    for z in CV_Z[:2]:
        step(f, z)
    f.K = f.K * 2.0
    f.y = f.y + 1.0
    state = copy.deepcopy(f).__getstate__()
    last = state["_engine"].last
    old = state["_engine"].last = last._replace(log_det_S1_2=None)
    state["_written"] = {
        k: (old, *held[1:]) if held[0] is last else held for k, held in state["_written"].items()
    }
    state["_gain_of"] = (old, state["_gain_of"][1])
    g = SquareRootUKF.__new__(SquareRootUKF)
    g.__setstate__(pickle.loads(pickle.dumps(state)))
    assert math.isclose(g.log_det_S1_2, f.log_det_S1_2, rel_tol=1e-12)
    for name in ("y", "K", "x", "P"):
        np.testing.assert_array_equal(getattr(g, name), getattr(f, name), err_msg=name)
    step(f, CV_Z[2])
    step(g, CV_Z[2])
    assert_filter_state(g, filter_state(f))
    assert g.log_det_S1_2 == f.log_det_S1_2
