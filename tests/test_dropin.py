"""Habits of real filterpy programs (issue 35): placeholders, records a program writes, ``sigmas_f`` as
the set of the next update, weights written, and a ``Saver`` or a copy at filterpy's layout.

Each is checked against filterpy 2.0.0 doing the same, to rounding (the square-root arithmetic
differs from filterpy's covariance form by a few ulps per step: 1e-12 relative after a few steps),
and for refusals against the filter as it was, bit for bit.
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from filterpy.common import Saver
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter, unscented_transform
from hypothesis import given, settings
from hypothesis import strategies as st
from models import (
    CV_DT,
    CV_P0,
    CV_X0,
    CV_Z,
    FLEET_P0,
    assert_filter_state,
    ct_hx,
    ctrv_fx,
    ctrv_hx,
    ctrv_track,
    cv_filter,
    cv_fleet,
    cv_fx,
    cv_pair,
    cv_single,
    filter_state,
    step,
)

from squkf import (
    Augmented,
    Fleet,
    MerweScaledWeights,
    NonFiniteError,
    ParameterError,
    PosteriorFactorError,
    ShapeError,
    SquareRootUKF,
    UnsetError,
)
from squkf.plan import _PREPARED, build_plan
from squkf.weights import as_family

RTOL = 1e-12  # squkf against filterpy after a few steps (their arithmetic differs by ulps per step)


def assert_like_filterpy(s, f, rtol: float = RTOL, names=("x", "P")) -> None:
    for name in names:
        a, b = np.asarray(getattr(s, name), float), np.asarray(getattr(f, name), float)
        np.testing.assert_allclose(
            a, b, rtol=rtol, atol=rtol * max(1.0, float(np.max(np.abs(b)))), err_msg=name
        )


# == item 1: placeholders ==========================================================================

PLACEHOLDERS = {
    "x": [None, np.full(4, np.nan), np.full((4, 1), np.nan)],
    "P": [None, np.full((4, 4), np.nan)],
}
CALLS = {
    "predict": lambda f: f.predict(),
    "update": lambda f: f.update(CV_Z[0]),
    "update(None)": lambda f: f.update(None),
    "ask_predict": lambda f: f.ask_predict(),
    "ask_update": lambda f: f.ask_update(),
    "compute_process_sigmas": lambda f: f.compute_process_sigmas(CV_DT),
    "batch_filter": lambda f: f.batch_filter(CV_Z[:2]),
}


@pytest.mark.parametrize("call", list(CALLS))
@pytest.mark.parametrize("name,k", [(name, k) for name, vs in PLACEHOLDERS.items() for k in range(len(vs))])
def test_a_placeholder_reads_back_and_a_step_refuses_naming_it(name, k, call):
    value = PLACEHOLDERS[name][k]
    f = cv_filter()
    step(f, CV_Z[0])
    setattr(f, name, value)
    shown = getattr(f, name)
    if value is None:
        assert shown is None
    else:
        assert shown.shape == value.shape and np.isnan(shown).all() and shown is not value
    snap = filter_state(f)
    with pytest.raises(UnsetError, match=rf"\b{name} was never set"):
        CALLS[call](f)
    assert_filter_state(f, snap)
    assert getattr(f, name) is shown  # still the placeholder, as assigned


@pytest.mark.parametrize("half", ["predict", "update"])
def test_a_placeholder_assigned_between_ask_and_tell_is_refused_by_the_tell(half):
    f = cv_filter()
    X = f.ask_predict() if half == "predict" else (f.predict(), f.ask_update())[1]
    f.x = None
    snap = filter_state(f)
    with pytest.raises(UnsetError, match="tell_"):
        if half == "predict":
            f.tell_predict([cv_fx(s, CV_DT) for s in X])
        else:
            f.tell_update([ct_hx(s) for s in X], CV_Z[0])
    assert_filter_state(f, snap)


@pytest.mark.parametrize(
    "name,value", [("x", np.r_[1.0, np.nan, 0.0, 0.0]), ("P", np.where(np.eye(4) > 0, np.nan, 0.0))]
)
def test_a_partly_nan_value_is_still_refused(name, value):
    f = cv_filter()
    snap = filter_state(f)
    with pytest.raises(NonFiniteError, match=name):
        setattr(f, name, value)
    assert_filter_state(f, snap)


def test_a_placeholder_of_the_wrong_shape_is_refused():
    f = cv_filter()
    with pytest.raises(ShapeError, match="x"):
        f.x = np.full(3, np.nan)
    with pytest.raises(ShapeError, match="P"):
        f.P = np.full((3, 3), np.nan)


def test_a_placeholder_filled_in_place_or_assigned_is_the_value():
    assigned, edited = cv_filter(), cv_filter()
    edited.x, edited.P = np.full(4, np.nan), np.full((4, 4), np.nan)
    edited.x[:] = CV_X0  # filled in place, as a program fills a track's state from its first detection
    edited.P[...] = CV_P0
    step(assigned, CV_Z[0])
    step(edited, CV_Z[0])
    np.testing.assert_array_equal(edited.x, assigned.x)
    np.testing.assert_array_equal(edited.P, assigned.P)


def test_a_placeholder_survives_copies_and_pickles():
    f = cv_filter()
    f.x = None
    f.P = np.full((4, 4), np.nan)
    for g in (copy.copy(f), copy.deepcopy(f), pickle.loads(pickle.dumps(f))):
        assert g.x is None and np.isnan(g.P).all()
        with pytest.raises(UnsetError):
            g.predict()
        g.x, g.P = CV_X0, CV_P0
        step(g, CV_Z[0])
    with pytest.raises(UnsetError):  # the copies' assignments were theirs
        f.predict()


def test_a_track_started_from_placeholders_is_filterpys():
    """A CTRV car tracker as programs write it: dt=None, x and P None until the first detection."""
    zs = ctrv_track()
    pair = []
    for cls in (SquareRootUKF, UnscentedKalmanFilter):
        f = cls(5, 2, None, ctrv_hx, ctrv_fx, MerweScaledSigmaPoints(5, 0.3, 2.0, 0.0))
        f.x, f.P = None, None
        f.Q = np.diag([1e-3, 1e-3, 0.1, 1e-3, 0.05])
        f.R = np.eye(2) * 0.0225
        pair.append(f)
    for k, z in enumerate(zs):
        for f in pair:
            if k == 0:
                f.x, f.P = np.r_[z, 5.0, 0.0, 0.0], np.diag([0.1, 0.1, 1.0, 0.5, 0.5])
                continue
            f.predict() if k % 2 else f.predict(dt=0.1)  # fx takes dt=None as 0.1
            f.update(z)
    assert_like_filterpy(*pair, rtol=1e-11)


def test_a_predict_without_dt_gives_fx_none_when_the_filter_has_none():
    seen = []

    def fx(x, dt):
        seen.append(dt)
        return x

    f = SquareRootUKF(1, 1, None, lambda x: x, fx, MerweScaledWeights())
    f.predict()
    assert seen and all(dt is None for dt in seen)
    seen.clear()
    f.predict(dt=0.25)
    assert set(seen) == {0.25}


def test_a_fleets_placeholder_rows_flag_those_filters_and_the_others_step():
    K = 4
    fleet, twin = cv_fleet(K, MerweScaledWeights()), cv_fleet(K, MerweScaledWeights())
    x0 = np.array([[10.0, 1.0, 5.0, 0.5]] * K) + np.arange(K)[:, None]
    P0 = np.stack([FLEET_P0] * K)
    x, P = x0.copy(), P0.copy()
    x[1] = np.nan  # filter 1: x not set
    P[3] = np.nan  # filter 3: P not set
    fleet.x, fleet.P = x, P
    twin.x, twin.P = x0, P0
    assert np.isnan(fleet.x[1]).all() and np.isnan(fleet.P[3]).all()
    z = np.array([[12.0, 0.4]] * K)
    for fl in (fleet, twin):
        fl.predict()
        fl.update(z)
    assert fleet.failed.tolist() == [False, True, False, True]
    assert "x of filter 1 was never set" in fleet.failure[1]
    assert "P of filter 3 was never set" in fleet.failure[3]
    for k in (0, 2):
        np.testing.assert_array_equal(fleet.x[k], twin.x[k])
        np.testing.assert_array_equal(fleet.P[k], twin.P[k])
    assert np.isnan(fleet.x[1]).all() and np.isnan(fleet.P[3]).all()  # kept as assigned
    # set, then reset: they step again
    fleet.reset([1, 3], x=x0[[1, 3]], P=P0[[1, 3]])
    assert not fleet.failed.any()
    fleet.predict()
    assert not fleet.failed.any() and np.isfinite(fleet.x).all()


def test_a_fleets_partly_nan_row_is_still_refused():
    fleet = cv_fleet(3, MerweScaledWeights())
    x = np.zeros((3, 4))
    x[1, 2] = np.nan
    with pytest.raises(NonFiniteError, match="filters \\[1\\]"):
        fleet.x = x


# == item 2: records a program writes ===============================================================

RECORDS = {  # name: (the step that makes it again, a value to write)
    "x_prior": ("predict", np.arange(4.0)),
    "P_prior": ("predict", np.diag([1.0, 2.0, 3.0, 4.0])),
    "x_post": ("update", np.arange(4.0) + 1),
    "P_post": ("update", np.eye(4) * 5.0),
    "y": ("update", np.array([0.5, -0.5])),
    "S": ("update", np.eye(2) * 3.0),
    "SI": ("update", np.eye(2) / 3.0),
    "K": ("update", np.ones((4, 2))),
    "sigmas_h": ("update", np.ones((9, 2))),
}


@pytest.mark.parametrize("name", list(RECORDS))
def test_a_written_record_reads_back_until_the_step_that_makes_it(name):
    again, value = RECORDS[name]
    f, twin = cv_filter(), cv_filter()
    step(f, CV_Z[0])
    step(twin, CV_Z[0])
    value = value.copy()
    setattr(f, name, value)
    kept = value.copy()
    value[...] = -7.0  # the caller's array is not kept
    np.testing.assert_array_equal(getattr(f, name), kept)
    if name != "sigmas_h":  # (sigmas_h is one array between steps, as filterpy's: item 3's tests)
        getattr(f, name)[...] = -7.0  # nor what is read: a fresh copy
        np.testing.assert_array_equal(getattr(f, name), kept)
    for other in ("x", "P", "x_prior", "P_prior", "x_post", "P_post", "y", "S", "K", "sigmas_f"):
        if other != name:  # nothing else changed
            np.testing.assert_array_equal(getattr(f, other), getattr(twin, other), err_msg=other)
    written = getattr(f, name).copy()
    f.predict()
    twin.predict()
    if again == "update":  # a prediction does not make it: it still reads back
        np.testing.assert_array_equal(getattr(f, name), written)
    f.update(CV_Z[1])
    twin.update(CV_Z[1])
    np.testing.assert_array_equal(getattr(f, name), getattr(twin, name))  # made again by the step
    np.testing.assert_array_equal(f.x, twin.x)


@pytest.mark.parametrize("name", ["log_likelihood", "likelihood", "mahalanobis"])
def test_the_likelihoods_stay_read_only_as_in_filterpy(name):
    f, fp = cv_pair()
    for g in (f, fp):
        with pytest.raises(AttributeError):
            setattr(g, name, 1.0)


def test_a_written_record_of_the_wrong_number_of_axes_is_refused():
    f = cv_filter()
    snap = filter_state(f)
    with pytest.raises(ShapeError, match="x_prior"):
        f.x_prior = np.eye(4)
    with pytest.raises(ShapeError, match="P_post"):
        f.P_post = np.zeros(4)
    assert_filter_state(f, snap)


def test_written_records_travel_with_copies_and_pickles():
    f = cv_filter()
    step(f, CV_Z[0])
    f.x_prior, f.S = np.arange(4.0), np.eye(2)
    for g in (copy.copy(f), copy.deepcopy(f), pickle.loads(pickle.dumps(f))):
        np.testing.assert_array_equal(g.x_prior, np.arange(4.0))
        np.testing.assert_array_equal(g.S, np.eye(2))
        g.x_prior = np.zeros(4)  # the copy's own
    np.testing.assert_array_equal(f.x_prior, np.arange(4.0))


def test_a_transaction_puts_written_records_back_with_the_filter():
    f = cv_filter()
    step(f, CV_Z[0])
    f.x_post = np.arange(4.0)
    with pytest.raises(ShapeError):
        f.batch_filter([CV_Z[1], np.zeros(5)])  # fails at its second step, after an update
    np.testing.assert_array_equal(f.x_post, np.arange(4.0))


@pytest.mark.parametrize("which", ["Wm", "Wc", "both"])
def test_written_weights_are_used_by_every_later_step_as_in_filterpys(which):
    s, f = cv_pair()
    W = s.Wm
    Wm, Wc = W.copy(), s.Wc.copy()
    Wm[0] += 0.2
    Wm[1:] -= 0.2 / (W.size - 1)
    Wc[0] -= 0.3
    for g in (s, f):
        if which in ("Wm", "both"):
            g.Wm = Wm.copy()
        if which in ("Wc", "both"):
            g.Wc = Wc.copy()
    np.testing.assert_array_equal(s.Wm, f.Wm)
    np.testing.assert_array_equal(s.Wc, f.Wc)
    for z in CV_Z[:4]:
        for g in (s, f):
            step(g, z)
    assert_like_filterpy(s, f, rtol=1e-11)


def test_weights_written_back_as_read_change_nothing():
    s, twin = cv_filter(), cv_filter()
    s.Wm, s.Wc = s.Wm, s.Wc
    step(s, CV_Z[0])
    step(twin, CV_Z[0])
    np.testing.assert_array_equal(s.P, twin.P)


def test_weights_that_cannot_serve_are_refused_naming_points():
    f = cv_filter(scheme=Augmented())  # the augmented set is drawn in 2n: the written weights serve n
    snap = filter_state(f)
    W = f.Wm
    W[0] += 0.1
    with pytest.raises(ParameterError, match="points"):
        f.Wm = W
    assert_filter_state(f, snap)
    with pytest.raises(ShapeError, match="Wc"):
        f.Wc = np.ones(3)
    with pytest.raises(NonFiniteError, match="Wm"):
        f.Wm = np.full(f.Wm.size, np.nan)
    assert_filter_state(f, snap)


# == item 3: sigmas_f and sigmas_h, stable between steps, the set of the next update ==============


def test_sigmas_are_one_array_between_steps_and_a_step_makes_new_ones():
    f = cv_filter()
    step(f, CV_Z[0])
    a, h = f.sigmas_f, f.sigmas_h
    assert f.sigmas_f is a and f.sigmas_h is h
    a_copy, h_copy = a.copy(), h.copy()
    step(f, CV_Z[1])
    assert f.sigmas_f is not a and f.sigmas_h is not h
    np.testing.assert_array_equal(a, a_copy)  # what was read earlier is never rewritten
    np.testing.assert_array_equal(h, h_copy)


@pytest.mark.parametrize("how", ["in place", "assigned"])
def test_a_sigmas_f_changed_is_the_set_of_the_next_update_as_in_filterpy(how):
    s, f = cv_pair()
    for g in (s, f):
        step(g, CV_Z[0])
        g.predict()
    new = s.sigmas_f + np.array([0.01, 0.0, -0.02, 0.005])  # (P - K S K^T stays positive definite)
    for g in (s, f):
        if how == "in place":
            g.sigmas_f[...] = new
        else:
            g.sigmas_f = new.copy()
        g.update(CV_Z[1])
    assert_like_filterpy(s, f, names=("x", "P", "y", "S", "K"))


def test_a_sigmas_f_changed_in_place_is_the_set_of_the_next_update_only():
    f, twin = cv_filter(), cv_filter()
    for g in (f, twin):
        step(g, CV_Z[0])
        g.predict()
    f.sigmas_f[0] += 0.5
    f.update(CV_Z[1])
    twin.update(CV_Z[1])
    assert not np.array_equal(f.x, twin.x)
    f.x, f.P1_2 = twin.x, twin.P1_2
    f.update(CV_Z[2])  # a second update: the set is drawn from the estimate, not the one written
    twin.update(CV_Z[2])
    np.testing.assert_array_equal(f.x, twin.x)
    np.testing.assert_array_equal(f.P, twin.P)


def test_a_subclass_filling_sigmas_f_for_a_look_ahead_reads_what_it_wrote():
    """A video tracker's UKF subclass: it fills ``self.sigmas_f[i]`` and takes the transform of them."""

    def look_ahead(ukf):
        sigmas = ukf.points_fn.sigma_points(ukf.x, ukf.P)
        for i, s in enumerate(sigmas):
            ukf.sigmas_f[i] = cv_fx(s, CV_DT)
        return unscented_transform(ukf.sigmas_f, ukf.Wm, ukf.Wc, ukf.Q)

    s, f = cv_pair()
    for g in (s, f):
        step(g, CV_Z[0])
    (xs, Ps), (xf, Pf) = look_ahead(s), look_ahead(f)
    assert np.any(xs != 0)
    np.testing.assert_allclose(xs, xf, rtol=RTOL)
    np.testing.assert_allclose(Ps, Pf, rtol=1e-11)


def test_a_written_sigmas_f_of_the_wrong_shape_is_refused_at_the_update():
    f = cv_filter()
    f.predict()
    with pytest.raises(ShapeError, match="sigmas_f"):
        f.sigmas_f = np.ones((9, 3))
    f.sigmas_f = np.ones((5, 4))  # as many points as the set has not: said by the update
    snap = filter_state(f)
    with pytest.raises(ShapeError, match="sigmas_f"):
        f.update(CV_Z[0])
    assert_filter_state(f, snap)


@settings(max_examples=25, deadline=None)
@given(scale=st.floats(0.5, 1.5), shift=st.floats(-1.0, 1.0), row=st.integers(0, 8))
def test_any_written_set_updates_as_filterpy_does(scale, shift, row):
    s, f = cv_pair()
    for g in (s, f):
        step(g, CV_Z[0])
        g.predict()
        g.sigmas_f[row] = g.sigmas_f[row] * scale + shift
    f.update(CV_Z[1])
    if np.linalg.eigvalsh(f.P)[0] <= 1e-6 * np.abs(f.P).max():
        # filterpy's P - K S K^T is indefinite (or nearly): squkf's downdate refuses, changing nothing
        snap = filter_state(s)
        try:
            s.update(CV_Z[1])
        except PosteriorFactorError:
            assert_filter_state(s, snap)
        return
    s.update(CV_Z[1])
    assert_like_filterpy(s, f, rtol=1e-9)


# == item 10: Saver and copies at filterpy's layout; a new filter built once ====================


def test_a_savers_history_holds_no_squkf_internal_state():
    s, f = cv_pair()
    saves = [Saver(s), Saver(f)]
    for z in CV_Z[:3]:
        for g, sv in zip((s, f), saves):
            step(g, z)
            sv.save()
    private = [{k for k in sv.keys if k.startswith("_")} for sv in saves]
    assert private[0] <= private[1], private[0] - private[1]  # filterpy's own private keys, no more


def test_a_deepcopy_shares_no_array_with_the_filter_and_steps_alike():
    f = cv_filter()
    step(f, CV_Z[0])
    g = copy.deepcopy(f)
    for name in ("x", "P", "Q", "R", "sigmas_f", "sigmas_h"):
        assert not np.shares_memory(getattr(f, name), getattr(g, name)), name
    step(f, CV_Z[1])
    step(g, CV_Z[1])
    np.testing.assert_array_equal(f.P, g.P)


def test_equal_configurations_prepare_their_sets_once_and_others_their_own():
    _PREPARED.clear()
    a = build_plan(as_family(MerweScaledSigmaPoints(4, 0.5, 2.0, 0.0)), Augmented(), 4)
    b = build_plan(as_family(MerweScaledSigmaPoints(4, 0.5, 2.0, 0.0)), Augmented(), 4)
    assert a.first is b.first and a.second is b.second
    c = build_plan(as_family(MerweScaledSigmaPoints(4, np.float64(0.3), 2.0, 0.0)), Augmented(), 4)
    assert c.first is not a.first
    assert not np.array_equal(c.first.xi, a.first.xi)
    d = build_plan(MerweScaledWeights(0.5, 2.0, 0.0), Augmented(), 4)
    e = build_plan(MerweScaledWeights(0.5, 2.0, 0.0), Augmented(), 4)
    assert d.first is e.first
    assert d.family is not e.family or d.family == e.family  # each plan keeps its own family object


def test_filters_built_in_turn_equal_one_built_alone():
    """Prepared sets shared between filters of one configuration change no number."""
    _PREPARED.clear()
    alone = cv_filter(points=MerweScaledSigmaPoints(4, 0.5, 2.0, 0.0))
    step(alone, CV_Z[0])
    for _ in range(3):
        f = cv_filter(points=MerweScaledSigmaPoints(4, 0.5, 2.0, 0.0))
        step(f, CV_Z[0])
        np.testing.assert_array_equal(f.P, alone.P)


def test_filters_with_weights_written_stack_into_a_fleet_that_uses_them():
    filters = [cv_single(MerweScaledWeights(alpha=0.5)) for _ in range(3)]
    W = filters[0].Wm
    W[0] += 0.1
    W[1:] -= 0.1 / (W.size - 1)
    for k, f in enumerate(filters):
        f.Wm = W
        f.x, f.P = np.array([10.0, 1.0, 5.0, 0.5]) + k, FLEET_P0
    fleet = Fleet.from_filters(filters)
    fleet.predict()
    fleet.update(np.array([[11.0, 0.45]] * 3))
    for k, f in enumerate(filters):
        f.predict()
        f.update(np.array([11.0, 0.45]))
        np.testing.assert_array_equal(fleet.x[k], f.x)  # fleet = single, bit for bit
        np.testing.assert_array_equal(fleet.P1_2[k], f.P1_2)
    with pytest.raises(ParameterError, match="filters"):  # weights written differ: another configuration
        Fleet.from_filters([filters[0], cv_single(MerweScaledWeights(alpha=0.5))])
