"""The plain step's kernel (``squkf.lane``) against the general step it stands in for.

The lane computes the same quantities as ``transform_factor`` and
``measurement_update`` by the same formulas; only the order of some roundings
differs (the state rows are ``G S^T`` rather than ``sqrt(w) (xi S^T)``). A QR
factorisation is backward stable: the computed factor of rows ``M`` is exact for
rows ``M + dM`` with ``|dM| <= gamma_k |M|`` (Higham, Thm 19.4), so the two
paths' Gram matrices differ by a few ``gamma_k ||M||^2`` with ``k`` the number
of rows; the tolerances below are 64 ``k eps ||M||^2``.
"""

import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from squkf import (
    CubatureWeights,
    JulierWeights,
    MerweScaledWeights,
    Redrawn,
    SimplexWeights,
    SquareRootUKF,
)
from squkf.errors import GainError, NonFiniteError
from squkf.lane import Lane

EPS = np.finfo(float).eps


def _model(n, m, seed):
    rng = np.random.default_rng(seed)
    A = np.eye(n) + 0.3 * rng.standard_normal((n, n))
    H = rng.standard_normal((m, n))

    def fx(x, dt):
        return A @ x + 0.1 * np.sin(x)

    def hx(x):
        return H @ x + 0.05 * x[0] ** 2

    return fx, hx, rng


def _filter(n, m, points, seed, x0, plain=True):
    fx, hx, rng = _model(n, m, seed)
    f = SquareRootUKF(n, m, 1.0, hx, fx, points)
    f.x = x0
    L = np.tril(rng.standard_normal((n, n)), -1) * 0.2 + np.diag(rng.uniform(0.5, 2.0, n))
    f.P1_2 = L
    f.Q = np.eye(n) * 0.01
    f.R = np.eye(m) * 0.1
    if not plain:
        f._lane = False  # the general step (the lane is built lazily and cached here)
    return f, rng


FAMILIES = [
    MerweScaledWeights(1.0, 2.0, 0.0),
    MerweScaledWeights(0.1, 2.0, 0.0),  # large weights of both signs: still no negative row
    MerweScaledWeights(1e-3, 2.0, 0.0),
    MerweScaledWeights(0.5, 0.25, 1.0),  # beta == alpha**2: no mu row at all
]


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(1, 6),
    m=st.integers(1, 4),
    fam=st.sampled_from(range(len(FAMILIES))),
    seed=st.integers(0, 2**31),
    offset=st.sampled_from([0.0, 1e3, 1e8]),
)
def test_lane_equals_general_step(n, m, fam, seed, offset):
    _compare_one_step(n, m, FAMILIES[fam], seed, offset)


@pytest.mark.parametrize("n", [32, 40])
def test_lane_axis_points_for_large_n(n):
    # from n = 32 the lane builds Merwe's sets as x +/- gamma S^T, without the product xi S^T
    fast = _compare_one_step(n, 7, MerweScaledWeights(0.5, 2.0, 3.0 - n), seed=n, offset=1e3)
    assert fast._lane.gamma1 is not None and fast._lane.gs2 is not None


def _compare_one_step(n, m, points, seed, offset):
    x0 = np.full(n, offset)
    fast, rng = _filter(n, m, points, seed, x0)
    slow, _ = _filter(n, m, points, seed, x0, plain=False)
    z = rng.standard_normal(m)
    for f in (fast, slow):
        f.predict()
    assert isinstance(fast._lane, Lane) and slow._lane is False
    # the prior is the same function of the same rows (central_rows, one QR): identical bits,
    # and so are both sets of sigma points and the images hx gets to see
    assert np.array_equal(fast.P1_2, slow.P1_2) and np.array_equal(fast.x, slow.x)
    assert np.array_equal(fast.sigmas_f, slow.sigmas_f)
    S_scale = np.linalg.norm(slow.P1_2) ** 2
    for f in (fast, slow):
        f.update(z)
    assert np.array_equal(fast.sigmas_h, slow.sigmas_h)
    # the update's state rows are G S^T here and sqrt(w) (xi S^T) there: a rounding apart
    Sy2 = np.linalg.norm(slow.S1_2) ** 2
    k = slow._num_sigmas + m
    gram = 64 * k * EPS * (S_scale + Sy2)
    assert np.allclose(fast.S, slow.S, rtol=0, atol=gram)
    assert np.allclose(fast.P, slow.P, rtol=0, atol=gram)
    # the factors' entries are off by about k eps ||M|| each (M the joint rows); solves with Sy
    # magnify that by its condition number (estimated from its diagonal) over its smallest pivot
    d = slow.S1_2.diagonal()
    w = np.linalg.solve(slow.S1_2, slow.y)
    M_norm = (S_scale + Sy2) ** 0.5
    rel = 64 * k * EPS * M_norm * (d.max() / d.min()) / d.min()
    assert np.allclose(
        fast.x, slow.x, rtol=0, atol=64 * k * EPS * np.abs(slow.x).max() + rel * M_norm * (1 + w @ w)
    )
    assert np.allclose(fast.K, slow.K, rtol=0, atol=rel * (1 + np.abs(slow.K).max()))
    # log|Sy| moves by sum(dSy_ii / Sy_ii) and w.w by about 2 |w|^2 times the relative change
    assert abs(fast.log_likelihood - slow.log_likelihood) <= rel * (m + 2 * w @ w + 1)
    return fast


@pytest.mark.parametrize(
    "points, scheme, hooks, expected",
    [
        (MerweScaledWeights(1.0, 2.0, 0.0), "redrawn", {}, True),
        (MerweScaledWeights(1.0, 2.0, 0.0), Redrawn(MerweScaledWeights(0.5, 2.0, 1.0)), {}, True),
        (MerweScaledWeights(1.0, 2.0, 0.0), "augmented", {}, False),
        (MerweScaledWeights(0.5, 0.0, 0.0), "redrawn", {}, False),  # beta < alpha**2: a negative row
        (JulierWeights(), "redrawn", {}, False),  # sum(Wc) - 2 = -1: the mean form serves it
        (CubatureWeights(), "redrawn", {}, False),
        (SimplexWeights(), "redrawn", {}, False),
        (MerweScaledWeights(1.0, 2.0, 0.0), "redrawn", {"residual_x": lambda a, b: a - b}, False),
        (MerweScaledWeights(1.0, 2.0, 0.0), "redrawn", {"x_mean_fn": lambda s, w: w @ s}, False),
    ],
)
def test_lane_is_used_only_where_it_applies(points, scheme, hooks, expected):
    f = SquareRootUKF(2, 1, 1.0, lambda x: x[:1], lambda x, dt: x, points, scheme=scheme, **hooks)
    assert (f._plain_lane(None) is not None) is expected
    f.predict()
    f.update([0.3])
    assert np.all(np.isfinite(f.x)) and np.all(np.isfinite(f.P))


def test_lane_follows_a_changed_second_family():
    f = SquareRootUKF(2, 1, 1.0, lambda x: x[:1], lambda x, dt: x, MerweScaledWeights(1.0, 2.0, 0.0))
    first = f._plain_lane(None)
    f.scheme.weights = MerweScaledWeights(0.3, 2.0, 1.0)  # a generator edited in place
    second = f._plain_lane(None)
    assert second is not first and second.family2 is f.scheme.weights
    f.predict()
    assert f.sigmas_f.shape == (5, 2)


def test_lane_errors_leave_the_filter_as_it_was():
    f = SquareRootUKF(2, 2, 1.0, lambda x: x, lambda x, dt: x, MerweScaledWeights(1.0, 2.0, 0.0))
    f.R = np.zeros((2, 2))
    f.predict()
    before = (f.x.copy(), f.P.copy(), f.sigmas_f.copy())
    f.hx = lambda x: np.array([1.0, 2.0])  # constant images and no noise: Sy = 0
    with pytest.raises(GainError):
        f.update([0.0, 0.0])
    assert np.array_equal(f.x, before[0]) and np.array_equal(f.P, before[1])
    f.hx = lambda x: x
    f.update([0.1, 0.2])  # the same prior still updates
    f.fx = lambda x, dt: x * np.inf
    x, P = f.x.copy(), f.P.copy()
    with pytest.raises(NonFiniteError, match="fx values"):
        f.predict()
    assert np.array_equal(f.x, x) and np.array_equal(f.P, P)


def _fx_sin(x, dt):
    return x + 0.1 * np.sin(x)


def _hx_sq(x):
    return x[:2] + 0.05 * x[0] ** 2


def test_lane_survives_pickling_mid_step():
    f = SquareRootUKF(3, 2, 1.0, _hx_sq, _fx_sin, MerweScaledWeights(1.0, 2.0, 0.0))
    f.predict()
    g = pickle.loads(pickle.dumps(f))
    f.update([0.1, -0.2])
    g.update([0.1, -0.2])
    assert isinstance(g._lane, Lane) and g._machine._sset_lane is g._lane
    assert np.array_equal(f.x, g.x) and np.array_equal(f.P1_2, g.P1_2)
