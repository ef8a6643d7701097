"""The engine (squkf.engine, squkf.plan): its contract, and a block of 3 filters equal to each alone.

Every configuration goes through the engine's step (:class:`squkf.engine.Engine` over a
:class:`squkf.engine.Route` of a plan from :func:`squkf.plan.build_plan`), once as a block of 3
and once per filter as a single filter (no batch axis for its hooks, ``UT`` and generator), and
the filters are compared. The engine's contract: a call that fails leaves it as it was, the
default route is two kernel calls a step, a route is decided once per key, and the kernel table
is read from one place (a second table slots in).

Bit for bit. Every phase's numerics is a compiled kernel (:mod:`squkf.kernels`) that computes
each filter in its own lane, with the same operations in the same order whatever the other lanes
hold and however many there are; one filter is a stack of one. So the slices are compared for
equality, not to a tolerance: this is the promise that a filter in a fleet equals the same filter
alone. (The linalg functions' stacked forms: tests/test_linalg.py.)
"""

from __future__ import annotations

import copy
import os
import sys

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints
from models import (
    counted_table,
    counting_kernels,
    cv_fleet,
    cv_single,
    heading_fx,
    l96_fx,
    l96_hx,
    range_bearing_hx,
    turn_fx_stacked,
    xy_radar_hx,
    xy_radar_hx_stacked,
)

import squkf
from squkf import (
    Augmented,
    CubatureWeights,
    Fleet,
    GainError,
    Gate,
    JulierWeights,
    MerweScaledWeights,
    NonFiniteError,
    Propagated,
    Redrawn,
    SigmaSet,
    SimplexWeights,
    SquareRootUKF,
    sqrt_unscented_transform,
)
from squkf.angles import AngleAdd, AngleMean, AngleResidual
from squkf.engine import Engine, Route, Scratch
from squkf.kernels import table
from squkf.measurement import measurement_update
from squkf.plan import Hooks, build_plan
from squkf.transform import transform_factor
from squkf.weights import as_family

B = 3  # the batch size


def assert_slices_equal(stacked, single, what):
    """``stacked[k]`` equals ``single[k]`` bit for bit."""
    stacked = np.asarray(stacked)
    for k, one in enumerate(single):
        one = np.asarray(one)
        assert stacked[k].shape == one.shape, what
        assert np.array_equal(stacked[k], one, equal_nan=True), (
            f"{what}[{k}]: max difference {float(np.nanmax(np.abs(stacked[k] - one))):.3g}"
        )


# -- models -------------------------------------------------------------------------


class Model:
    def __init__(self, n, fx, hx, m, x0, P0, Q, R, truth_seed=0):
        self.n, self.fx, self.hx, self.m = n, fx, hx, m
        rng = np.random.default_rng(truth_seed)
        # three filters: different starting means, covariances and measurements
        self.x0 = np.array([x0 + rng.normal(0, 0.1, n) * np.sqrt(np.diag(P0)) for _ in range(B)])
        self.S0 = np.array([np.linalg.cholesky(P0 * (1.0 + 0.3 * k)) for k in range(B)])
        self.Q1_2 = np.linalg.cholesky(Q)
        self.R1_2 = np.linalg.cholesky(R)
        # per-filter noise factors, for the (B, d, d) cases
        self.Q1_2s = np.array([self.Q1_2 * (1.0 + 0.2 * k) for k in range(B)])
        self.R1_2s = np.array([self.R1_2 * (1.0 + 0.5 * k) for k in range(B)])
        steps_z = []
        xt = self.x0.copy()
        for _ in range(3):
            xt = np.array([fx(v) for v in xt])
            steps_z.append(np.array([hx(v) for v in xt]) + rng.normal(0, 1, (B, m)) @ self.R1_2.T)
        self.zs = steps_z


TURN = Model(
    4,
    heading_fx,
    xy_radar_hx,
    2,
    np.array([30.0, 40.0, 0.4, 2.0]),
    np.diag([1.0, 1.0, 0.05, 0.1]),
    np.diag([0.01, 0.01, 1e-3, 1e-3]),
    np.array([[0.25, 0.001], [0.001, 1e-4]]),
)

L96 = Model(
    33,
    lambda x: l96_fx(x, 0.01),
    l96_hx,
    17,
    8.0 + np.sin(np.arange(33.0)),
    0.5 * np.eye(33) + 0.1 * np.diag(np.ones(32), 1) + 0.1 * np.diag(np.ones(32), -1),
    0.01 * np.eye(33),
    0.2 * np.eye(17),
    truth_seed=1,
)

ANGLES = Hooks(
    x_mean_fn=AngleMean([2]),
    z_mean_fn=AngleMean([1]),
    residual_x=AngleResidual([2]),
    residual_z=AngleResidual([1]),
    state_add=AngleAdd([2]),
)

# name: (model, family, generator, hooks, UT)
CONFIGS = {
    "merwe-redrawn": (TURN, MerweScaledWeights(), Redrawn(), Hooks(), None),
    "julier": (TURN, JulierWeights(kappa=1.0), Redrawn(), Hooks(), None),
    "simplex": (TURN, SimplexWeights(), Redrawn(), Hooks(), None),
    "cubature": (TURN, CubatureWeights(), Redrawn(), Hooks(), None),
    "filterpy-points": (TURN, as_family(MerweScaledSigmaPoints(4, 0.3, 2.0, 0.0)), Redrawn(), Hooks(), None),
    # beta < alpha**2 and alpha < 1: negative rows in both forms, removed by (stacked) downdates
    "merwe-negative-rows": (
        TURN,
        MerweScaledWeights(alpha=0.5, beta=0.1, kappa=0.0),
        Redrawn(),
        Hooks(),
        None,
    ),
    "angles": (TURN, MerweScaledWeights(alpha=0.5, beta=2.0, kappa=0.0), Redrawn(), ANGLES, None),
    "augmented": (TURN, MerweScaledWeights(alpha=0.5, beta=2.0, kappa=0.0), Augmented(), Hooks(), None),
    "propagated": (TURN, MerweScaledWeights(alpha=0.5, beta=2.0, kappa=0.0), Propagated(), Hooks(), None),
    "user-UT": (TURN, MerweScaledWeights(), Redrawn(), Hooks(), sqrt_unscented_transform),
    "axis-n33": (L96, MerweScaledWeights(alpha=1.0, beta=2.0, kappa=0.0), Redrawn(), Hooks(), None),
}


def apply(fn, sigmas):
    """``fn`` at every point of ``sigmas`` (``(..., N, n)``)."""
    flat = sigmas.reshape(-1, sigmas.shape[-1])
    out = np.array([fn(s) for s in flat])
    return out.reshape(sigmas.shape[:-1] + out.shape[-1:])


def engine(plan, hooks, x, S, single, gate=None):
    """An engine at ``(x, S)``: a block of filters, or one filter (``single``: ``x`` ``(n,)``)."""
    block = (x[None], S[None]) if single else (x, S)
    N, n = plan.xi1.shape
    B = block[0].shape[0]
    return Engine(Route(plan, hooks, gate, single), *block, np.zeros((B, N, n)), np.zeros((B, N, 1)))


def run(plan, model, hooks, UT, x, S, Q1_2, R1_2, zs, single=False):
    """Three predict/update steps through the engine's halves; every intermediate result."""
    e = engine(plan, hooks, x, S, single)
    one = (lambda a: a[0]) if single else (lambda a: a)
    out = []
    for z in zs:
        sig_f = one(e.ask_predict()).copy()
        e.tell_predict(apply(model.fx, sig_f), Q1_2, UT)
        x_prior, S_prior = one(e.x), one(e.S)
        sig_h = one(e.ask_update()).copy()
        e.tell_update(apply(model.hx, sig_h), z, None, R1_2, UT)
        assert e.phase == "idle"
        last = e.last
        out.append(
            dict(
                sig_f=sig_f,
                x_prior=x_prior,
                S_prior=S_prior,
                sig_h=sig_h,
                x=one(e.x),
                S=one(e.S),
                y=one(last.y),
                Sy=one(last.Sy),
                L21=one(last.L21),
            )
        )
    return out


@pytest.mark.parametrize("noise", ["shared", "per-filter"])
@pytest.mark.parametrize("name", list(CONFIGS))
def test_stacked_equals_each_filter_alone(name, noise):
    model, family, generator, hooks, UT = CONFIGS[name]
    plan = build_plan(family, generator, model.n)
    if name == "axis-n33":
        # the configuration must take the axis points' O(n^2) offsets, or this case tests nothing new
        assert plan.first.gamma is not None
    if name == "merwe-negative-rows":
        assert plan.first.rows.best.neg.size > 0
    Q1_2, R1_2 = (model.Q1_2, model.R1_2) if noise == "shared" else (model.Q1_2s, model.R1_2s)
    stacked = run(plan, model, hooks, UT, model.x0, model.S0, Q1_2, R1_2, model.zs)
    alone = [
        run(
            plan,
            model,
            hooks,
            UT,
            model.x0[k],
            model.S0[k],
            Q1_2 if noise == "shared" else Q1_2[k],
            R1_2 if noise == "shared" else R1_2[k],
            [z[k] for z in model.zs],
            single=True,
        )
        for k in range(B)
    ]
    for t, rec in enumerate(stacked):
        for key, value in rec.items():
            assert_slices_equal(value, [alone[k][t][key] for k in range(B)], f"step {t} {key}")
    # and the filters differ from each other, so a slice mixed up with another would show
    assert not np.allclose(stacked[-1]["x"][0], stacked[-1]["x"][1])


def test_transform_and_measurement_update_stacked():
    """The two building blocks called directly: transform_factor and measurement_update."""
    model = TURN
    plan = build_plan(MerweScaledWeights(alpha=0.5, beta=0.1, kappa=0.0), Redrawn(), model.n)
    x, S = model.x0, model.S0
    sset = plan.second.draw(x, S, None, None, None)
    H = apply(model.hx, sset.sigmas)
    F = apply(model.fx, sset.sigmas)
    z = model.zs[0]
    mean, SF = transform_factor(F, plan.first.rows, model.Q1_2s)
    post = measurement_update(x, S, sset, H, z, model.R1_2s)
    for k in range(B):
        sset_k = plan.second.draw(x[k], S[k], None, None, None)
        m_k, SF_k = transform_factor(F[k], plan.first.rows, model.Q1_2s[k])
        p_k = measurement_update(x[k], S[k], sset_k, H[k], z[k], model.R1_2s[k])
        assert_slices_equal(mean[k : k + 1], [m_k], "mean")
        assert_slices_equal(SF[k : k + 1], [SF_k], "S")
        for field in ("x", "S", "y", "Sy", "L21", "w"):
            assert_slices_equal(getattr(post, field)[k : k + 1], [getattr(p_k, field)], field)


# == the engine's contract ===========================================================================


def counting_table(monkeypatch, f):
    """The kernel table with each entry wrapped to count its calls (a second table, as a backend gives),
    made the table of the filter ``f``'s route."""
    counting, calls = counted_table(f._engine.route.kernels)
    monkeypatch.setattr(f._engine.route, "kernels", counting)
    return calls


def merwe_turn_filter(points, scheme, gate=None, vectorized=True):
    model = TURN
    fx = (lambda X, dt: np.stack([heading_fx(x) for x in X])) if vectorized else (lambda x, dt: heading_fx(x))
    hx = (lambda X: np.stack([xy_radar_hx(x) for x in X])) if vectorized else xy_radar_hx
    f = SquareRootUKF(4, 2, 1.0, hx, fx, points, scheme=scheme, gate=gate, vectorized=vectorized)
    f.x, f.P1_2, f.Q1_2, f.R1_2 = model.x0[0], model.S0[0], model.Q1_2, model.R1_2
    return f


STEP_CONFIGS = {
    "merwe": (MerweScaledWeights(alpha=0.5), "redrawn", None),
    "julier": (JulierWeights(kappa=1.0), "redrawn", None),
    "simplex": (SimplexWeights(), "redrawn", None),
    "cubature": (CubatureWeights(), "redrawn", None),
    "filterpy-points": (MerweScaledSigmaPoints(4, 0.3, 2.0, 0.0), "redrawn", None),
    "second-family": (MerweScaledWeights(), Redrawn(MerweScaledWeights(alpha=0.4)), None),
    "augmented": (MerweScaledWeights(alpha=0.5), "augmented", None),
    "gate": (MerweScaledWeights(alpha=0.5), "redrawn", Gate(0.9999)),
}


@pytest.mark.parametrize("partial", [False, True], ids=["whole-z", "partial-z"])
@pytest.mark.parametrize("name", list(STEP_CONFIGS))
def test_a_step_is_two_kernel_calls(monkeypatch, name, partial):
    """After fx, one kernel gives the prior and the second set; after hx, one the posterior and the next
    first set: two calls a step, for every family, both schemes, a gate, and a repeated partial z."""
    points, scheme, gate = STEP_CONFIGS[name]
    f = merwe_turn_filter(points, scheme, gate)
    z = xy_radar_hx(TURN.x0[0])
    if partial:
        z[1] = np.nan
    f.predict()
    f.update(z)  # the first step draws its first set, and the partial z's factor of R is formed once
    calls = counting_table(monkeypatch, f)
    for _ in range(3):
        f.predict()
        f.update(z)
    assert calls == ["transform", "joint_update"] * 3
    assert not f.rejected.any()


def test_the_route_is_decided_when_it_is_built(monkeypatch):
    """The update routes are decided when the route is built (the filter built, its configuration
    changed); a step decides nothing. (A configuration's routes are made once and shared by the filters
    built after: the prepared configurations are emptied first, so that this filter's are made here.)"""
    import squkf.plan

    monkeypatch.setattr(squkf.plan, "_PREPARED", {})
    made = []
    real = Route._classify
    monkeypatch.setattr(Route, "_classify", lambda self, *kind: made.append(1) or real(self, *kind))
    f = merwe_turn_filter(MerweScaledWeights(alpha=0.5), "redrawn")
    built = len(made)
    assert built > 0
    for _ in range(4):
        f.predict()
        f.update(xy_radar_hx(TURN.x0[0]))
    assert len(made) == built
    f.points_fn = JulierWeights()  # a new configuration: its routes are decided anew, when it is built
    rebuilt = len(made)
    assert rebuilt > built
    for _ in range(3):
        f.predict()
        f.update(xy_radar_hx(TURN.x0[0]))
    assert len(made) == rebuilt
    again = len(made)
    merwe_turn_filter(MerweScaledWeights(alpha=0.5), "redrawn")  # the same configuration: shared, not made
    assert len(made) == again


@pytest.mark.parametrize("when", ["prior", "posterior"])
def test_a_failed_half_leaves_the_engine_as_it_was(when):
    """A kernel's failure (or a NaN image) raises and commits nothing: the next call works."""
    plan = build_plan(MerweScaledWeights(alpha=0.5), Redrawn(), 4)
    e = engine(plan, Hooks(), TURN.x0[0], TURN.S0[0], single=True)
    X = e.ask_predict()[0]
    if when == "prior":
        before = (e.x, e.S, e.phase, e.prior_record)
        bad = apply(TURN.fx, X)
        bad[2, 1] = np.nan
        with pytest.raises(NonFiniteError):
            e.tell_predict(bad, TURN.Q1_2)
        assert (e.x, e.S, e.phase, e.prior_record) == before
        e.tell_predict(apply(TURN.fx, X), TURN.Q1_2)
        assert e.phase == "prior"
        return
    e.tell_predict(apply(TURN.fx, X), TURN.Q1_2)
    Y = e.ask_update()[0]
    before = (e.x, e.S, e.phase, e.last, e.post_record)
    with pytest.raises(GainError):  # no noise and constant images: a singular innovation factor
        e.tell_update(np.zeros((Y.shape[0], 2)), np.ones(2), None, np.zeros((2, 2)))
    assert (e.x, e.S, e.phase, e.last, e.post_record) == before
    e.tell_update(apply(TURN.hx, Y), TURN.zs[0][0], None, TURN.R1_2)
    assert e.phase == "idle" and e.last is not None


def _array_ids(sets) -> set[int]:
    found: set[int] = set()

    def walk(v):
        if isinstance(v, np.ndarray):
            found.add(id(v))
        elif isinstance(v, (tuple, list)):
            for item in v:
                walk(item)

    for v in sets.values():
        walk(v)
    return found


def test_a_steady_step_allocates_its_buffers_once():
    """The block's outputs are made once per configuration and size and used again: after the first
    steps, neither a filter's buffers nor a fleet's (nor its chunks' scratch) make a new array,
    nothing is kept per step, and a fleet keeps no more estimates than its records need."""
    import squkf.stacks as stacks

    def fx(X, dt):  # any leading axes: the filter's points and the fleet's stack of them
        return np.apply_along_axis(heading_fx, -1, X)

    def hx(X):
        return np.apply_along_axis(xy_radar_hx, -1, X)

    f = SquareRootUKF(4, 2, 1.0, hx, fx, MerweScaledWeights(alpha=0.5), vectorized=True)
    f.x, f.P1_2, f.Q1_2, f.R1_2 = TURN.x0[0], TURN.S0[0], TURN.Q1_2, TURN.R1_2
    fleet = Fleet.from_filters([f, f, f])
    z = xy_radar_hx(TURN.x0[0])
    for _ in range(2):
        f.predict()
        f.update(z)
        fleet.predict()
        fleet.update(np.tile(z, (3, 1)))
    scratch = stacks._spare.free[-1]  # the chunk arrays this thread's next chunk takes
    before = (
        _array_ids(f._engine._buffers.sets),
        _array_ids(fleet._engine._buffers.sets),
        _array_ids(scratch.sets),
    )
    for _ in range(5):
        f.predict()
        f.update(z)
        fleet.predict()
        fleet.update(np.tile(z, (3, 1)))
    after = (
        _array_ids(f._engine._buffers.sets),
        _array_ids(fleet._engine._buffers.sets),
        _array_ids(scratch.sets),
    )
    assert after == before and all(before)
    assert f._engine._buffers.taken == [] and fleet._engine._buffers.taken == [] and scratch.taken == []
    # the fleet's estimates in three sets, as many as a step held before the engine: the posterior it
    # starts from, the prior it keeps as a record, and the new one
    estimates = [sets for key, sets in fleet._engine._buffers.sets.items() if key[0] == "spare"]
    assert [len(sets) for sets in estimates] == [3]


def _two_outputs(B: int, n: int) -> tuple:
    return np.empty((B, n)), np.empty((0, 1, n))  # (a block's array, and one without a block axis)


def test_scratch_serves_a_smaller_block_from_the_leading_rows_of_its_set():
    """A fleet's last, shorter chunk costs no second set of chunk arrays: it gets the leading rows of
    the set made for the full chunks, C-contiguous as the kernels take them; a larger block replaces the
    set."""
    scratch = Scratch()
    full = scratch.take(_two_outputs, 8, 3)
    assert scratch.take(_two_outputs, 8, 3) is full
    last = scratch.take(_two_outputs, 5, 3)
    assert last[0].shape == (5, 3) and last[0].flags.c_contiguous and np.shares_memory(last[0], full[0])
    assert last[1] is full[1]
    larger = scratch.take(_two_outputs, 12, 3)
    assert larger[0].shape == (12, 3) and not np.shares_memory(larger[0], full[0])
    assert scratch.take(_two_outputs, 8, 3)[0].base is larger[0] and len(scratch.sets) == 1


class _VaryingWeights:
    """A user's generator whose weights change from draw to draw (an exact set with no rows of its own)."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)

    def second_set(self, x, S, *, family, propagated=None, Q1_2=None, state_add=None):
        weights = MerweScaledWeights(alpha=float(self.rng.choice([0.3, 0.6, 1.0])), beta=2.0)
        n = x.shape[0]
        return SigmaSet(x + weights.unit_sigma_points(n) @ S.T, *weights.weights(n), moments_exact=True)


class _PythonResidual(AngleResidual):
    """A user's residual_x (a subclass: called in Python, not data)."""


@pytest.mark.parametrize(
    "hooks, downdate",
    [
        (Hooks(), False),
        (Hooks(x_mean_fn=AngleMean([2])), False),
        (Hooks(z_mean_fn=AngleMean([1]), residual_z=AngleResidual([1])), False),
        (Hooks(residual_x=AngleResidual([2])), True),
        (Hooks(state_add=AngleAdd([2])), True),
        (ANGLES, True),
        (Hooks(residual_x=_PythonResidual([2])), True),
    ],
)
def test_the_downdate_form_is_decided_with_the_route(hooks, downdate):
    """A residual_x or state_add: the route's updates keep the prior factor (the downdate form, never
    the joint QR), decided once from the hooks; a rewritten set takes that form on any route. squkf's
    angle hooks are data (a kernel route, joint or downdate); a Python hook takes the general route."""
    plan = build_plan(MerweScaledWeights(alpha=0.5), Redrawn(), 4)
    route = Route(plan, hooks, None, single=False)
    assert route.downdate is downdate
    sset = route.second_set(TURN.x0, TURN.S0, None, None)
    kernel_route = route.update_route(sset, None)
    python = type(hooks.residual_x) is _PythonResidual
    assert (kernel_route is None) is python
    z_angles = hooks.z_mean_fn is not None
    if not python:
        assert kernel_route.downdate is downdate and kernel_route.angles is z_angles
    rewritten = route.update_route(sset.rewritten(sset.sigmas.copy()), None)
    assert rewritten is None if python else rewritten.downdate
    assert route.update_route(sset, sqrt_unscented_transform) is None  # a user's UT: the general route


@pytest.mark.parametrize("gate", [None, Gate(0.9999)])
def test_a_rewritten_pending_set_is_updated_in_the_downdate_form(gate):
    """A pending set whose points the caller rewrote (``SigmaSet.rewritten``): the engine's update keeps
    the prior factor, ``P_prior - K S K^T`` with the written points, through the gate too."""
    plan = build_plan(MerweScaledWeights(alpha=1.0, beta=2.0, kappa=0.0), Redrawn(), 4)
    e = engine(plan, Hooks(), TURN.x0[0], TURN.S0[0], single=True, gate=gate)
    e.tell_predict(apply(TURN.fx, e.ask_predict()[0]), TURN.Q1_2)
    (x, S), sset, _ = e.pending_update()
    written = sset.rewritten(sset.sigmas + 0.05 * np.random.default_rng(1).standard_normal(sset.sigmas.shape))
    H = apply(TURN.hx, written.sigmas[0])
    z = TURN.zs[0][0]
    e.tell_update(H, z, None, TURN.R1_2, None, ((x, S), written, None))
    dz = H - written.Wm @ H
    dx = written.sigmas[0] - x[0]
    Pzz = (dz.T * written.Wc) @ dz + TURN.R1_2 @ TURN.R1_2.T
    K = np.linalg.solve(Pzz, ((dx.T * written.Wc) @ dz).T).T
    P = S[0] @ S[0].T - K @ Pzz @ K.T
    assert np.linalg.eigvalsh(P).min() > 1e-3 * np.abs(P).max()
    np.testing.assert_allclose(e.S[0] @ e.S[0].T, P, rtol=0, atol=1e-10 * np.abs(P).max())
    np.testing.assert_allclose(e.x[0], x[0] + K @ (z - written.Wm @ H), rtol=1e-12)


@pytest.mark.parametrize("scheme", ["redrawn", "augmented", "propagated"])
@pytest.mark.parametrize("gate", [None, Gate(0.9999)])
def test_a_routes_update_routes_are_fixed_when_it_is_built(monkeypatch, scheme, gate):
    """squkf's generators: every set they draw (with and without process noise, a rewritten set, a
    partial z, through a gate) takes an update route fixed when the route was built; nothing is
    classified while the filter steps."""
    f = merwe_turn_filter(MerweScaledWeights(alpha=0.5), scheme, gate)
    route = f._engine.route
    fixed = [r for _, routes in route._fixed for r in routes.values()]
    assert fixed and [rows for rows, _ in route._fixed] == [r.rows for r in route.plan.set_routes]

    def classified(*args):
        raise AssertionError("an update route classified after the route was built")

    monkeypatch.setattr(Route, "_classify", classified)
    z = xy_radar_hx(TURN.x0[0])
    partial = z.copy()
    partial[1] = np.nan
    for Q in (TURN.Q1_2, np.zeros((4, 4))):
        f.Q1_2 = Q
        for zz in (z, partial):
            f.predict()
            sset = f._engine.sset
            assert any(route.update_route(sset, None) is r for r in fixed)
            f.update(zz)
    f.predict()
    f.sigmas_f = f.sigmas_f + 1e-3  # a written set: the downdate form, fixed too
    f.update(z)
    f.update(z)  # no prediction between: a set drawn from the estimate alone


def test_a_user_generators_set_is_classified_at_each_draw():
    """A user's generator: no route is fixed for it, each set is classified by its own rows when it
    comes, so rows made afresh at every draw (whose ids Python reuses) never run with an earlier set's
    weights: the numbers equal those of a route built anew before every update (the oracle)."""

    def fx(x, dt):
        return np.array([x[0] + dt * x[1], x[1]])

    def hx(x):
        return np.array([np.hypot(x[0], 2.0)])

    kept, fresh = (
        SquareRootUKF(2, 1, 1.0, hx, fx, MerweScaledWeights(), scheme=_VaryingWeights(1)) for _ in "ab"
    )
    assert kept._engine.route._fixed == ()
    for f in (kept, fresh):
        f.x, f.R, f.Q = [0.0, 1.0], [[0.01]], 0.1 * np.eye(2)
    for t in range(300):
        z = [np.hypot(t * 1.0, 2.0) + 0.3 * np.sin(t)]
        for f in (kept, fresh):
            f.predict()
        r = fresh._engine.route
        fresh._engine.route = Route(r.plan, r.hooks, r.gate, r.single)  # decided anew: the oracle
        for f in (kept, fresh):
            f.update(z)
        np.testing.assert_array_equal(kept.x, fresh.x)
        np.testing.assert_array_equal(kept.P1_2, fresh.P1_2)


def _python_mean(sigmas, Wm):
    """A user's ``x_mean_fn``: the weighted mean in Python (the hooks' route of the prediction)."""
    return np.dot(Wm, sigmas)


@pytest.mark.parametrize(
    "hooks, gate",
    [
        (Hooks(), None),
        (Hooks(residual_z=lambda a, b: a - b, x_mean_fn=_python_mean), None),
        (Hooks(), Gate(0.99, per_component=True)),
        (Hooks(residual_z=lambda a, b: a - b), Gate(0.99, per_component=True)),
        (Hooks(state_add=lambda x, dx: x + dx), None),
    ],
    ids=["default", "hooks", "gate", "hooks-gate", "state_add"],
)
def test_the_kernel_table_is_the_routes(monkeypatch, hooks, gate):
    """Two filters side by side, one built on its own table (as a filter on another backend would be):
    each table serves every phase of its own filter and nothing of the other's (the default route and
    the hooks' prediction and update, a partial z's factor of R's observed block, a gate's gain and
    its update again with the components it kept, the smoother); the numbers are the same."""
    own, calls = counted_table(table.KERNELS)  # (of the numba kernels themselves)
    installed = counting_kernels(monkeypatch)  # the table installed when the filters are built: b's
    z = xy_radar_hx(TURN.x0[0])
    partial, wild = z.copy(), z.copy()
    partial[1] = np.nan
    wild[0] += 50.0  # the gate rejects this component alone
    a, b = (merwe_turn_filter(MerweScaledWeights(alpha=0.5), "redrawn", gate) for _ in "ab")
    for f in (a, b):
        f.residual_z, f.x_mean_fn, f.state_add = hooks.residual_z, hooks.x_mean_fn, hooks.state_add
    r = a._engine.route
    a._engine.configure(Route(r.plan, r.hooks, r.gate, r.single, kernels=own))
    assert a._engine.route.kernel_update is (hooks.residual_z is None and hooks.state_add is None)
    assert a._engine.route.kernels is own and b._engine.route.kernels is table.KERNELS
    out = {}
    for f, mine, other in ((a, calls, installed), (b, installed, calls)):
        mine.clear()
        other.clear()
        for zz in (z, partial, wild):
            f.predict()
            f.update(zz)
        if gate is not None:  # (the wild component rejected, the filter updated again with the other)
            assert f.rejected.tolist() == [True, False]
        means, covariances = f.batch_filter([z, partial, wild, wild])[:2]
        smoothed = f.rts_smoother(means, covariances)[:2]
        assert other == []  # nothing of the other filter's table
        assert {"tria", "solve", "chol_update"} & set(mine)  # R's observed block, the gain, the smoother
        out[f] = (f.x, f.P1_2, f.log_likelihood, means, covariances, *smoothed)
    for x, y in zip(out[a], out[b]):
        np.testing.assert_array_equal(x, y)
    assert copy.deepcopy(a._engine.route).kernels == own  # a copied route keeps its table
    # and so does the filter: copied, deep-copied, given another hook or gate, made a fleet
    kept = [copy.copy(a), copy.deepcopy(a)]
    a.gate = 0.95
    a.residual_x = lambda u, v: u - v
    fleet = Fleet.from_filters([a, a])
    kept += [a, fleet, fleet[1]]
    assert all(f._engine.route.kernels == own for f in kept)


@pytest.mark.parametrize("hooks", [{}, {"residual_z": lambda a, b: a - b}], ids=["default", "hooks"])
def test_a_fleets_kernel_table_is_its_routes(monkeypatch, hooks):
    """A fleet on its own table beside one on the installed table: its chunks (the checks of what the
    model gives included), its gated and partial updates and its smoother call its table alone; the
    numbers are the same."""
    own, calls = counted_table(table.KERNELS)
    installed = counting_kernels(monkeypatch)
    z = xy_radar_hx(TURN.x0[0])
    partial, wild = z.copy(), z.copy()
    partial[1] = np.nan
    wild[0] += 50.0
    zs = np.stack([np.stack([z, partial, wild, wild])] * 3)  # (3 filters, 4 steps, m)
    out = []
    for mine, other, kernels in ((calls, installed, own), (installed, calls, None)):
        fleet = Fleet(
            3, 4, 2, 1.0, xy_radar_hx_stacked, turn_fx_stacked, MerweScaledWeights(alpha=0.5),
            gate=Gate(0.99, per_component=True), **hooks,
        )  # fmt: skip
        fleet.x, fleet.P1_2, fleet.Q1_2, fleet.R1_2 = TURN.x0[0], TURN.S0[0], TURN.Q1_2, TURN.R1_2
        if kernels is not None:
            r = fleet._engine.route
            fleet._engine.configure(Route(r.plan, r.hooks, r.gate, r.single, kernels=kernels))
        mine.clear()
        other.clear()
        result = fleet.batch_filter(zs)
        smoothed = fleet.rts_smoother(result)
        assert other == [] and {"finite_rows", "solve", "tria"} <= set(mine)
        assert result.rejected[:, 2].tolist() == [[True, False]] * 3
        out.append((result.means, result.P1_2s, result.log_likelihood, *smoothed))
    for x, y in zip(*out):
        np.testing.assert_array_equal(x, y)


def test_the_routes_table_serves_the_default_step_alone():
    """On the default route and the hooks' update, a step's kernel calls are the route's table's."""
    own, calls = counted_table(table.KERNELS)
    z = xy_radar_hx(TURN.x0[0])
    for hooks in (Hooks(), Hooks(residual_z=lambda a, b: a - b)):  # the default route, the hooks' route
        a = merwe_turn_filter(MerweScaledWeights(alpha=0.5), "redrawn")
        a.residual_z = hooks.residual_z
        r = a._engine.route
        a._engine.configure(Route(r.plan, r.hooks, r.gate, r.single, kernels=own))
        calls.clear()
        for _ in range(2):
            a.predict()
            a.update(z)
        first = [] if hooks.residual_z is None else ["points"]  # (the hooks' route draws no first set ahead)
        assert calls == ["points", "transform", "joint_update", *first, "transform", "joint_update"]


def _every_route(f_hooks, fleet):
    """Steps through every kind of route: the default and the hooks', each scheme, a gate, a partial z,
    a user's UT, the smoother, a fleet, and squkf.linalg; returns their numbers."""
    from squkf.linalg import chol_update, solve_lower, tria

    out = []
    z = xy_radar_hx(TURN.x0[0])
    partial = z.copy()
    partial[1] = np.nan
    for scheme in ("redrawn", "augmented", "propagated"):
        for gate in (None, Gate(0.9999)):
            f = merwe_turn_filter(MerweScaledWeights(alpha=0.5), scheme, gate)
            for zz in (z, partial):
                f.predict()
                f.update(zz)
            f.predict(UT=sqrt_unscented_transform)
            f.update(z, UT=sqrt_unscented_transform)
            out += [f.x, f.P1_2]
    g = f_hooks()
    means, covariances = g.batch_filter([z, partial, z])[:2]
    xs, Ps, _ = g.rts_smoother(means, covariances)
    out += [xs, Ps]
    fleet.predict()
    fleet.update(np.tile(z, (3, 1)))
    out += [fleet.x, fleet.P1_2]
    S = TURN.S0[0]
    out += [tria(np.ones((4, 6))), solve_lower(S, np.ones(4)), chol_update(S, 0.1 * np.ones(4))]
    return out


def test_every_route_reads_the_kernel_table(monkeypatch):
    """The seam: with the numba kernels reachable only through the installed table, every route runs
    (a second backend's table serves them all) and gives the same numbers."""
    from squkf.kernels import phases

    def hooked():
        f = SquareRootUKF(
            4, 2, 1.0, xy_radar_hx, lambda x, dt: heading_fx(x), MerweScaledWeights(alpha=0.5),
            residual_z=np.subtract, x_mean_fn=AngleMean([2]),
        )  # fmt: skip
        f.x, f.P1_2, f.Q1_2, f.R1_2 = TURN.x0[0], TURN.S0[0], TURN.Q1_2, TURN.R1_2
        return f

    def fleet():
        def fx(X, dt):
            return np.apply_along_axis(heading_fx, -1, X)

        def hx(X):
            return np.apply_along_axis(xy_radar_hx, -1, X)

        f = SquareRootUKF(
            4, 2, 1.0, hx, fx, MerweScaledWeights(alpha=0.5), vectorized=True, residual_z=np.subtract
        )
        f.x, f.P1_2, f.Q1_2, f.R1_2 = TURN.x0[0], TURN.S0[0], TURN.Q1_2, TURN.R1_2
        return Fleet.from_filters([f, f, f])

    expected = _every_route(hooked, fleet())  # (and every kernel compiled or loaded)
    real = table.KERNELS
    installed = table.KernelTable(*real)  # the same kernels, reachable only here
    for name in real._fields:

        def gone(*args, _name=name):
            raise AssertionError(f"{_name} called around the kernel table")

        monkeypatch.setattr(phases, f"{name}_kernel", gone)
    monkeypatch.setattr(table, "KERNELS", installed)  # the default of the routes built from now on
    for a, b in zip(_every_route(hooked, fleet()), expected):
        np.testing.assert_array_equal(a, b)


def _python_calls(step) -> list[str]:
    """The Python calls ``step()`` makes in squkf's own files (``sys.setprofile``'s call events), by name."""
    root = os.path.dirname(os.path.abspath(squkf.__file__)) + os.sep
    calls: list[str] = []

    def profile(frame, event, arg):
        code = frame.f_code
        if event == "call" and code.co_filename.startswith(root):
            calls.append(code.co_name)

    sys.setprofile(profile)
    try:
        step()
    finally:
        sys.setprofile(None)
    return calls


def test_a_steady_step_makes_few_python_calls():
    """Counted, not timed: one filter's vectorised predict + update makes at most 32 calls in squkf's
    files, and a fleet's step of one chunk at most 40 (both faces on the engine, issue 36;
    ``benchmarks/python_per_step.py`` says where they go)."""
    x0 = np.array([1000.0, 5.0, 1500.0, -3.0])
    f, fleet = cv_single(MerweScaledWeights()), cv_fleet(500, MerweScaledWeights())
    for g in (f, fleet):
        g.x, g.P, g.Q, g.R = x0, np.diag([900.0, 4, 900, 4]), 0.01 * np.eye(4), np.diag([25.0, 4e-6])
    z = range_bearing_hx(x0)
    zs = np.tile(z, (500, 1))

    def single():
        f.predict()
        f.update(z)

    def many():
        fleet.predict()
        fleet.update(zs)

    for _ in range(3):  # the routes decided, the buffers made
        single()
        many()
    one, chunk = _python_calls(single), _python_calls(many)
    assert len(one) <= 32, " ".join(one)
    assert len(chunk) <= 40, " ".join(chunk)
