"""The ask/tell API: one code path with predict/update, and misuse caught without losing state."""

import copy
import pickle

import numpy as np
import pytest
from models import assert_filter_state, ct_filter, ct_fx, ct_hx, ct_measurements, filter_state

from squkf import CallSequenceError, MerweScaledWeights, NonFiniteError, ShapeError


def make(scheme="redrawn", vectorized=False):
    """The far coordinated-turn radar, Merwe points with alpha 0.1 (a negative central weight)."""
    return ct_filter(MerweScaledWeights(alpha=0.1, beta=2.0, kappa=0.0), scheme=scheme, vectorized=vectorized)


@pytest.mark.parametrize("scheme", ["redrawn", "augmented"])
def test_ask_tell_equals_predict_update(scheme):
    a, b = make(scheme), make(scheme)
    for z in ct_measurements():
        a.predict()
        a.update(z)
        X = b.ask_predict()
        b.tell_predict([ct_fx(x, 1.0) for x in X])
        Y = b.ask_update()
        b.tell_update(np.array([ct_hx(y) for y in Y]), z)
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(a.P1_2, b.P1_2)


def test_vectorized_ask_tell_equals_per_point():
    a, b = make(), make(vectorized=True)
    for z in ct_measurements(10):
        a.predict()
        a.update(z)
        X = b.ask_predict()
        b.tell_predict(b.fx(X, 1.0))
        b.tell_update(b.hx(b.ask_update()), z)
        np.testing.assert_allclose(a.x, b.x, rtol=1e-14)
        np.testing.assert_allclose(a.P1_2, b.P1_2, rtol=1e-12, atol=1e-15)


def test_telling_twice_and_without_asking():
    ukf = make()
    snap = filter_state(ukf)
    with pytest.raises(CallSequenceError, match="tell_predict"):
        ukf.tell_predict(np.zeros((11, 5)))
    assert_filter_state(ukf, snap)
    X = ukf.ask_predict()
    F = [ct_fx(x, 1.0) for x in X]
    ukf.tell_predict(F)
    snap = filter_state(ukf)
    with pytest.raises(CallSequenceError, match="already told"):
        ukf.tell_predict(F)
    assert_filter_state(ukf, snap)
    with pytest.raises(CallSequenceError, match="tell_update"):
        ukf.tell_update(np.zeros((11, 2)), np.zeros(2))
    assert_filter_state(ukf, snap)
    Y = ukf.ask_update()
    H = [ct_hx(y) for y in Y]
    ukf.tell_update(H, ct_measurements(1)[0])
    snap = filter_state(ukf)
    with pytest.raises(CallSequenceError, match="already told"):
        ukf.tell_update(H, ct_measurements(1)[0])
    assert_filter_state(ukf, snap)


def test_asking_for_update_before_prediction_is_told():
    ukf = make()
    ukf.ask_predict()
    snap = filter_state(ukf)
    with pytest.raises(CallSequenceError, match="prediction is pending"):
        ukf.ask_update()
    assert_filter_state(ukf, snap)


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
    ref, ukf = make(), make()
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


@pytest.mark.parametrize("copier", [copy.deepcopy, lambda u: pickle.loads(pickle.dumps(u))])
def test_filter_pickles_between_ask_and_tell(copier):
    ukf = make()
    X = ukf.ask_predict()
    twin = copier(ukf)
    F = [ct_fx(x, 1.0) for x in X]
    ukf.tell_predict(F)
    twin.tell_predict(F)
    z = ct_measurements(1)[0]
    for f in (ukf, twin):
        f.tell_update([ct_hx(y) for y in f.ask_update()], z)
    np.testing.assert_array_equal(ukf.x, twin.x)
    np.testing.assert_array_equal(ukf.P1_2, twin.P1_2)


def test_predict_restores_the_step_when_fx_raises():
    ukf = make()
    snap = filter_state(ukf)

    def broken(x, dt):
        raise ZeroDivisionError("user model failed")

    with pytest.raises(ZeroDivisionError, match="user model failed"):
        ukf.predict(fx=broken)
    assert_filter_state(ukf, snap)
    ukf.predict()
    assert ukf._state.phase == "prior"
