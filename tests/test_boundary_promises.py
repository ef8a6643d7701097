"""Promises at the boundary of the front ends (issue 20), one test (or more) per promise.

Each test failed on the code before its fix. Errors are squkf's own exceptions naming the
argument; a call that fails leaves the filter or fleet as it was.
"""

from __future__ import annotations

import numpy as np
from filterpy.common import Saver
from models import ct_fx, ct_hx

from squkf import Fleet, MerweScaledWeights, SquareRootUKF

DT = 1.0
X0 = np.array([-8.0, 0.5, 1.5, 2.0, 0.05])
P0 = np.diag([1.0, 0.1, 1.0, 0.1, 0.01])
Q0 = np.diag([1e-3, 1e-2, 1e-3, 1e-2, 1e-4])
R0 = np.diag([0.05, 0.01])


def make_ukf(**kw) -> SquareRootUKF:
    """The coordinated-turn radar of tests/models.py."""
    f = SquareRootUKF(5, 2, DT, ct_hx, ct_fx, MerweScaledWeights(alpha=0.5), **kw)
    f.x, f.P, f.Q, f.R = X0, P0, Q0, R0
    return f


def measurements(T: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x, out = X0.copy(), []
    for _ in range(T):
        x = ct_fx(x, DT)
        out.append(ct_hx(x) + rng.normal(0.0, [0.2, 0.1]))
    return np.array(out)


# -- a fleet of the same radar: the models written with X[..., i] ----------------------------


def v_fx(X, dt, u=None):
    """Constant velocity in two axes, state [px, vx, py, vy] (``u``: an offset of vx)."""
    out = np.stack([X[..., 0] + dt * X[..., 1], X[..., 1], X[..., 2] + dt * X[..., 3], X[..., 3]], axis=-1)
    if u is not None:
        out[..., 1] += u
    return out


def v_hx(X, scale=1.0):
    """Both positions, times ``scale``."""
    return scale * X[..., ::2]


K, NX, NZ = 3, 4, 2


def make_fleet(**kw) -> Fleet:
    fl = Fleet(K, NX, NZ, DT, v_hx, v_fx, MerweScaledWeights(alpha=0.5), **kw)
    fl.x = np.array([[0.0, 1.0, 0.0, -1.0], [1.0, 0.5, 2.0, 0.0], [-1.0, 0.0, 1.0, 1.0]])
    fl.P = np.diag([1.0, 0.1, 1.0, 0.1])
    fl.Q = 1e-3 * np.eye(NX)
    fl.R = 0.1 * np.eye(NZ)
    return fl


def fleet_zs(T: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.normal(0.0, 1.0, (K, T, NZ))


FLEET_STATE = ("x", "P1_2", "Q1_2", "R1_2", "x_prior", "x_post", "P1_2_prior", "P1_2_post", "y")


def fleet_state(fl: Fleet) -> dict:
    snap = {k: np.array(getattr(fl, k), copy=True) for k in FLEET_STATE}
    snap["failed"] = fl.failed.copy()
    snap["failure"] = list(fl.failure)
    snap["phase"] = fl._state.phase
    return snap


def assert_fleet_state(fl: Fleet, snap: dict) -> None:
    for k in FLEET_STATE:
        np.testing.assert_array_equal(np.asarray(getattr(fl, k)), snap[k], err_msg=k)
    np.testing.assert_array_equal(fl.failed, snap["failed"])
    assert list(fl.failure) == snap["failure"]
    assert fl._state.phase == snap["phase"]


# -- 1. K is a fresh array on each read -------------------------------------------------------


def test_K_is_a_fresh_array_on_each_read():
    f = make_ukf()
    f.predict()
    f.update(measurements(1)[0])
    first = f.K
    expected = first.copy()
    first[:] = 123.0
    np.testing.assert_array_equal(f.K, expected)
    assert f.K is not f.K


def test_a_savers_K_history_is_never_rewritten():
    f = make_ukf()
    saver = Saver(f)
    for z in measurements(4):
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
    f.update(measurements(5)[4])
    for j in range(2, len(Ks)):
        np.testing.assert_array_equal(Ks[j], kept[j])
