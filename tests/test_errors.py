"""The fault matrix: every bad input raises a specific, documented exception and loses nothing."""

import numpy as np
import pytest
from models import assert_filter_state, ct_filter, ct_fx, ct_hx, filter_state

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


def make(vectorized=False, points=None, **kw):
    """The far coordinated-turn radar (Merwe alpha 0.3, kappa -2), stopped mid-step: a prior pending."""
    points = MerweScaledWeights(0.3, 2.0, -2.0) if points is None else points
    f = ct_filter(points, vectorized=vectorized, **kw)
    f.predict()
    f.update(ct_hx(f.x) + 1.0)
    f.predict()  # mid-step: a prior is pending
    return f


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
    check(make(), lambda f: f.update(z), error, match)


BAD_MATRICES = [
    (np.array([[1.0, 0.5], [0.0, 1.0]]), "wrong shape", ShapeError),
    (np.diag([1.0, 2.0, 3.0, 4.0, np.nan]), "nan", NonFiniteError),
    (np.eye(5) + np.triu(np.ones((5, 5)), 1) * 0.1, "not symmetric", SqukfValueError),
    (-np.eye(5), "negative definite", NotPositiveDefiniteError),
]


@pytest.mark.parametrize("name", ["P", "Q"])
@pytest.mark.parametrize("value, label, error", BAD_MATRICES, ids=[b[1] for b in BAD_MATRICES])
def test_bad_state_matrices(name, value, label, error):
    e = check(make(), lambda f: setattr(f, name, value), error)
    assert name in str(e)


def test_singular_P_rejected_but_singular_Q_accepted():
    check(make(), lambda f: setattr(f, "P", np.diag([1.0, 1, 1, 1, 0])), NotPositiveDefiniteError, "P")
    f = make()
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
    check(make(), lambda f: setattr(f, "R", value), error, "R")
    if value.shape == (2, 2):
        check(make(), lambda f: f.update(ct_hx(f.x), R=value), error, "R")


@pytest.mark.parametrize("value, error", [(np.eye(4), ShapeError), (-np.eye(5), NotPositiveDefiniteError)])
def test_bad_Q_per_call(value, error):
    check(make(), lambda f: f.predict(Q=value), error, "Q")


@pytest.mark.parametrize("name", ["P1_2", "R1_2"])
def test_bad_factors(name):
    n = 5 if name == "P1_2" else 2
    upper = np.eye(n)
    upper[0, 1] = 0.5
    check(make(), lambda f: setattr(f, name, upper), SqukfValueError, "lower triangular")
    if name == "P1_2":  # a singular R is a valid noise model, and so is its factor
        zero_diag = np.eye(n)
        zero_diag[1, 1] = 0.0
        check(make(), lambda f: setattr(f, name, zero_diag), NotPositiveDefiniteError, "zero on its diagonal")
    check(make(), lambda f: setattr(f, name, np.eye(n + 1)), ShapeError)


@pytest.mark.parametrize("vectorized", [False, True])
@pytest.mark.parametrize("where", ["fx", "hx"])
@pytest.mark.parametrize("fault", ["shape", "nan", "inf", "raises"])
def test_bad_model_functions(vectorized, where, fault):
    f = make(vectorized)
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


def test_weight_parameters_out_of_domain():
    with pytest.raises(ParameterError, match="alpha"):
        SquareRootUKF(5, 2, 1.0, ct_hx, ct_fx, MerweScaledWeights(alpha=0.0))
    with pytest.raises(ParameterError, match="kappa"):
        SquareRootUKF(5, 2, 1.0, ct_hx, ct_fx, MerweScaledWeights(kappa=-5.0))
    with pytest.raises(ParameterError, match="augmented"):
        SquareRootUKF(5, 2, 1.0, ct_hx, ct_fx, CubatureWeights(), scheme="augmented")
    with pytest.raises(ParameterError, match="scheme"):
        SquareRootUKF(5, 2, 1.0, ct_hx, ct_fx, MerweScaledWeights(), scheme="sideways")
    with pytest.raises(ParameterError, match="dim_x"):
        SquareRootUKF(0, 2, 1.0, ct_hx, ct_fx, MerweScaledWeights())


def test_failed_negative_weight_downdate():
    # beta = 0 keeps Wc[0] close to Wm[0] = -17.5: moving the centre alone makes the weighted
    # "covariance" Wc0 (1 - Wm0)^2 d^2 + Wm0 (1 - Wm0) d^2 negative along that axis
    f = make(points=MerweScaledWeights(0.3, 0.0, -2.0))
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
    f = make(points=MerweScaledWeights())  # positive weights: no downdate before the gain
    f.R = np.zeros((2, 2))
    e = check(f, lambda g: g.update(np.zeros(2), hx=lambda x: np.array([1.0, 2.0])), GainError)
    assert e.errno == 302


@pytest.mark.parametrize("dt", [np.nan, np.inf, "x", 1j])
def test_bad_dt(dt):
    check(make(), lambda f: f.predict(dt=dt), ParameterError, "dt")


def test_call_sequence_errors_are_runtime_errors():
    f = make()
    f.ask_predict()
    with pytest.raises(CallSequenceError) as info:
        f.ask_update()
    assert isinstance(info.value, RuntimeError)


def test_integer_and_float32_inputs_compute_in_float64():
    a, b = make(), make()
    a.x = np.array([2000, 10, 3000, -5, 0], dtype=np.int64)
    b.x = np.array([2000, 10, 3000, -5, 0], dtype=np.float64)
    a.P = np.diag([400, 4, 400, 4, 1]).astype(np.float32)
    b.P = np.diag([400.0, 4, 400, 4, 1])
    for f in (a, b):
        f.update(np.array([3605, 1], dtype=np.int32) if f is a else np.array([3605.0, 1.0]))
    assert a.x.dtype == np.float64 and np.asarray(a.P1_2).dtype == np.float64
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P1_2, b.P1_2)
