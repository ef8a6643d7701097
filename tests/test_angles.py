"""``squkf.angles`` as data, and a fleet's vectorised hooks.

squkf's own measurement hooks (exact ``AngleMean``, ``AngleResidual`` as ``z_mean_fn``,
``residual_z``) are read when assigned and done by the kernels (``angle_rows_kernel`` and the joint
kernel's given rows), with no Python call per point. Their oracle is the same hooks as subclasses,
which stay on the Python route (called per filter and point): the two agree to rounding
(``ROUNDING`` of each record's terms: the kernels sum in their own order where numpy's dot and matmul
sum in theirs).
filterpy's UKF with the same hooks agrees to 1e-8 (another algorithm: the covariance form). A fleet
equals its single filters bit for bit on this route: plain-arithmetic models here (numpy's
transcendental functions may round differently by the array's length), every chunk size and 1 and
2 threads (with the kernels' own blocks: ``tests/test_kernels.py``).
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from hypothesis import given
from hypothesis import strategies as st
from models import (
    RBH_P0,
    RBH_Q,
    RBH_R,
    RBH_TURNING_P0,
    RBH_TURNING_X0,
    RBH_X0,
    counting,
    counting_kernels,
    cv_fleet,
    cv_single,
    plain_fx,
    plain_hx,
    plain_scenario,
    range_bearing_heading_hx,
    rbh_fleet_and_singles,
    rbh_hooks,
    rbh_measurements,
    rbh_single,
    rbh_state_hooks,
    rbh_turning,
    rbh_turning_measurements,
    rel,
    turn_fx_stacked,
)

from squkf import (
    Fleet,
    JulierWeights,
    MerweScaledWeights,
    ParameterError,
    SimplexWeights,
    SqukfError,
)
from squkf.angles import AngleAdd, AngleMean, AngleResidual, wrap
from squkf.kernels import threads as kernel_threads

#: The kernels' route against the Python hooks', each record in units of the terms it is formed from
#: (:func:`rounding_of_terms`): measured at most 3.3e-13 over these runs (every family, scheme and hook,
#: 8 steps each), the largest with filterpy's Merwe set at alpha = 0.3, whose W0 is -10.1. Against
#: 55f2ed6 itself, from the same inputs: ``python benchmarks/angle_rounding.py``. A real difference (a
#: component not wrapped, a wrong weight) is 1e-3 or more.
ROUNDING = 1e-12

FAMILIES = {
    "merwe-0.5": lambda: MerweScaledWeights(alpha=0.5),
    "merwe-negative-rows": lambda: MerweScaledWeights(alpha=0.5, beta=0.1, kappa=0.0),
    "julier": lambda: JulierWeights(kappa=1.0),
    "simplex": lambda: SimplexWeights(),
    "filterpy-merwe": lambda: MerweScaledSigmaPoints(4, 0.3, 2.0, 0.0),
}
AUGMENTABLE = ("merwe-0.5", "julier", "filterpy-merwe")


def _step(f, z):
    f.predict()
    f.update(None if np.isnan(z).all() else z)


def _records(f) -> dict:
    return {"x": f.x, "P": f.P, "S": f.S, "y": f.y, "log_likelihood": f.log_likelihood, "K": f.K}


def rounding_of_terms(python, data, z, x_prior) -> dict[str, float]:
    """Each record's difference between the two filters in units of the terms it is formed from.

    The kernels and numpy sum in different orders, so each sum rounds differently by about
    ``eps * sum |W| * |terms|``, and a difference is measured against those terms, not the result:

    - ``y = z - z_pred``: each component against its measurement ``|z_i|`` (a range of 100 predicted to
      1e-13 leaves an innovation of 0.01 with 1e-11 of its own size);
    - ``x = x_prior + K y``: against ``max(|x_prior|, |K y|)``;
    - the log-likelihood: against ``|log L| + ||S^-1 y|| max |z|``, what ``y``'s rounding moves it by
      (its gradient in ``y`` is ``-S^-1 y``);
    - ``P``, ``S``, ``K``: normwise.
    """
    out = {}
    for name, value in _records(python).items():
        got, value = np.asarray(_records(data)[name], dtype=float), np.asarray(value, dtype=float)
        ok = ~np.isnan(value)
        if not np.array_equal(np.isnan(got), ~ok):  # (NaN in one route only: no rounding)
            out[name] = np.inf
            continue
        diff = np.max(np.abs(got[ok] - value[ok]), initial=0.0)
        scale = np.max(np.abs(value[ok]), initial=0.0)
        measured = ~np.isnan(z)
        if name == "y":  # per component: each against its own measurement
            d = np.abs(got - value)[ok]
            out[name] = np.max(d / np.fmax(np.abs(z[ok]), np.abs(value[ok])), initial=0.0)
            continue
        if name == "x":
            scale = max(np.abs(x_prior).max(), np.abs(value - x_prior).max())
        elif name == "log_likelihood" and measured.any():
            S = python.S[np.ix_(measured, measured)]
            y = python.y[measured]
            scale = abs(float(value)) + np.abs(np.linalg.solve(S, y)).sum() * np.abs(z[measured]).max()
        out[name] = diff / max(scale, 1e-300)
    return out


def _updated_alike(data, python, z, t: int) -> bool:
    """Update both filters with ``z``: both fail alike (False: stop there; the plain mean of angles either
    side of pi may make P indefinite) or every record agrees to ``ROUNDING`` of its terms (True)."""
    failed = []
    x_prior = python.x.copy()
    for f in (data, python):
        try:
            f.update(None if np.isnan(z).all() else z)
            failed.append(None)
        except SqukfError as exc:
            failed.append((type(exc), exc.errno))
    assert failed[0] == failed[1], t
    if failed[0]:
        return False
    for name, r in rounding_of_terms(python, data, z, x_prior).items():
        assert r <= ROUNDING, f"{name} at step {t}: {r:.2e}"
    return True


EDGES = [0.0, -0.0, np.pi, -np.pi, 2 * np.pi, -2 * np.pi, np.nextafter(np.pi, 0), np.nextafter(-np.pi, 0),
         1e300, -1e300, 5e-324, np.inf, -np.inf, np.nan]  # fmt: skip


@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=1, max_size=50))
def test_the_kernels_wrap_is_wrap_bit_for_bit(values):
    """The kernels' wrap skips the modulo where it would change nothing: the same bits as
    :func:`squkf.angles.wrap` for every float, the edges of its range, NaN and inf included."""
    from squkf.kernels.phases import _wrap

    a = np.array(values + EDGES, dtype=float)
    with np.errstate(invalid="ignore"):  # (inf)
        expected = wrap(a)
    got = np.array([_wrap(v) for v in a])
    same = (got.view(np.int64) == expected.view(np.int64)) | (np.isnan(got) & np.isnan(expected))
    assert same.all(), (a[~same], got[~same], expected[~same])


# -- the route: the kernels, no Python call per point ---------------------------------------------


@pytest.fixture
def no_python_hooks(monkeypatch):
    """squkf's hooks refuse to be called: the route must not call them."""

    def refuse(self, *args):
        raise AssertionError(f"{self!r} called in Python")

    for cls in (AngleMean, AngleResidual):
        monkeypatch.setattr(cls, "__call__", refuse)


@pytest.mark.parametrize("which", ["residual", "mean", "both"])
def test_the_measurements_angle_hooks_are_done_by_the_kernels(no_python_hooks, which, monkeypatch):
    """No Python call of the hooks on either face; one angle kernel and one joint kernel an update."""
    calls = counting_kernels(monkeypatch)
    zs = rbh_measurements(3, 4)
    f = rbh_single(rbh_hooks(which))
    fleet, _ = rbh_fleet_and_singles(3, rbh_hooks(which))
    for t in range(4):
        _step(f, zs[0, t])
        fleet.predict()
        fleet.update(zs[:, t])
    assert not fleet.failed.any()
    calls.clear()
    f.predict()
    f.update(zs[0, 3])
    assert calls == ["transform", "angle_rows", "joint_update"]


def test_a_subclass_or_a_python_hook_beside_them_keeps_the_python_route(monkeypatch):
    f = rbh_single(rbh_hooks("both", python=True))
    mean_calls, residual_calls = [], []
    monkeypatch.setattr(
        type(f.z_mean), "__call__", lambda s, *a: mean_calls.append(1) or AngleMean.__call__(s, *a)
    )
    monkeypatch.setattr(
        type(f.residual_z),
        "__call__",
        lambda s, *a: residual_calls.append(1) or AngleResidual.__call__(s, *a),
    )
    f.predict()
    f.update(range_bearing_heading_hx(RBH_X0))
    N = f.sigmas_f.shape[0]
    assert len(mean_calls) == 1 and len(residual_calls) == N + 1  # per point, and the innovation


# -- the numbers: the Python route's to rounding, filterpy's, a fleet's bit for bit -----------------


# (the augmented set takes symmetric points with no negative rows to keep the prior)
SCHEMES = [(f, s) for f in FAMILIES for s in ("redrawn", "augmented") if s == "redrawn" or f in AUGMENTABLE]


@pytest.mark.parametrize("which", ["residual", "mean", "both"])
@pytest.mark.parametrize(("family", "scheme"), SCHEMES)
def test_the_kernels_route_is_the_python_hooks_route_to_rounding(family, scheme, which):
    """Every record of 8 steps (a missing range, a missing bearing, no measurement) to rounding."""
    zs = rbh_measurements(3, 8)[0]
    data = rbh_single(rbh_hooks(which), FAMILIES[family](), scheme=scheme)
    python = rbh_single(rbh_hooks(which, python=True), FAMILIES[family](), scheme=scheme)
    wrapped = 0
    for t, z in enumerate(zs):
        for f in (data, python):
            f.predict()
        wrapped += np.ptp(range_bearing_heading_hx(data.sigmas_f)[:, 1]) > np.pi
        if not _updated_alike(data, python, z, t):
            return
    assert wrapped  # the points' bearings passed pi: the hooks mattered


@pytest.mark.parametrize("gate", [None, 0.99])
def test_the_kernels_route_with_a_gate_and_missing_components(gate):
    zs = rbh_measurements(3, 8, seed=3)[2]
    zs[4, 1] = wrap(zs[4, 1] + 1.0)  # a wild bearing
    data = rbh_single(rbh_hooks("both"), gate=gate)
    python = rbh_single(rbh_hooks("both", python=True), gate=gate)
    for t, z in enumerate(zs):
        for f in (data, python):
            _step(f, z)
        assert rel(data.x, python.x) <= ROUNDING and rel(data.P, python.P) <= ROUNDING, t
        np.testing.assert_array_equal(data.rejected, python.rejected)
    assert gate is None or python.rejected.any() or data.nis >= 0


def test_the_kernels_route_is_filterpys_ukf_with_a_wrapping_residual():
    """filterpy's UKF with the same hooks (it calls them per point): x and P to 1e-8."""
    zs = rbh_measurements(1, 10, seed=5)[0]
    zs = zs[~np.isnan(zs).any(axis=1)]
    sq = rbh_single(rbh_hooks("both"), MerweScaledWeights(alpha=0.5, beta=2.0, kappa=0.0))
    fp = UnscentedKalmanFilter(
        4, 3, 1.0, range_bearing_heading_hx, turn_fx_stacked, MerweScaledSigmaPoints(4, 0.5, 2.0, 0.0),
        z_mean_fn=AngleMean([1]), residual_z=AngleResidual([1]),
    )  # fmt: skip
    fp.x, fp.P, fp.Q, fp.R = RBH_X0.copy(), RBH_P0.copy(), RBH_Q, RBH_R
    wrapped = 0
    for z in zs:
        for f in (sq, fp):
            f.predict()
        wrapped += np.ptp(range_bearing_heading_hx(fp.sigmas_f)[:, 1]) > np.pi
        for f in (sq, fp):
            f.update(z)
        assert rel(sq.x, fp.x) <= 1e-8 and rel(sq.P, fp.P) <= 1e-8
        assert abs(sq.log_likelihood - fp.log_likelihood) <= 1e-8 * abs(fp.log_likelihood)
    assert wrapped  # the points' bearings passed pi


PLAIN_HOOKS = {"z_mean_fn": AngleMean([1]), "residual_z": AngleResidual([1])}


def _plain_fleet(K, chunk=None, **hooks):
    x0, P0, Q, R, zs = plain_scenario(K, T=5, seed=2)
    fleet = Fleet(K, 4, 2, 0.1, plain_hx, plain_fx, MerweScaledWeights(0.5), chunk=chunk, **hooks)
    fleet.x, fleet.P, fleet.Q, fleet.R = x0, P0, Q, R
    return fleet, zs


def test_a_radar_fleet_equals_its_single_filters():
    fleet, singles = rbh_fleet_and_singles(5, rbh_hooks("both"))
    zs = rbh_measurements(5, 6)
    for t in range(6):
        fleet.predict()
        fleet.update(zs[:, t])
        for k, f in enumerate(singles):
            _step(f, zs[k, t])
            assert rel(fleet.x[k], f.x) <= 1e-12 and rel(fleet.P[k], f.P) <= 1e-12
    assert not fleet.failed.any()


def test_a_failing_filter_on_the_kernels_route_is_flagged_and_the_others_go_on():
    """Filter 2's images are not finite at step 1: it is flagged, the others are a fleet without it."""
    K = 5
    zs = rbh_measurements(K, 4)

    def hx(X, bad=None):
        H = range_bearing_heading_hx(X)
        return H if bad is None else H + bad[..., None]  # (a per-filter argument comes as (k, 1))

    fleet, _ = rbh_fleet_and_singles(K, rbh_hooks("both"))
    fleet.hx = hx
    keep = np.array([0, 1, 3, 4])
    small, _ = rbh_fleet_and_singles(K, rbh_hooks("both"))
    small = small.subset(keep)
    poison = np.zeros(K)
    for t in range(4):
        poison[2] = np.nan if t == 1 else 0.0
        fleet.predict()
        fleet.update(zs[:, t], bad=poison)
        small.predict()
        small.update(zs[keep, t])
    assert fleet.failed.tolist() == [False, False, True, False, False]
    assert "hx values" in fleet.failure[2]
    np.testing.assert_array_equal(fleet.x[keep], small.x)
    np.testing.assert_array_equal(fleet.P[keep], small.P)


# -- the indices: a read-only tuple, checked when built and when assigned ------------------------


@pytest.mark.parametrize("bad", ["12", 1, [1.0], [True], [None], [[1]]])
def test_angle_indices_must_be_integers(bad):
    for cls in (AngleMean, AngleResidual, AngleAdd):
        with pytest.raises(ParameterError, match="angle_indices"):
            cls(bad)


def test_angle_indices_are_a_read_only_tuple_kept_by_copies_and_pickles():
    hook = AngleResidual(np.array([1, 3]))
    assert hook.angle_indices == (1, 3) and all(type(i) is int for i in hook.angle_indices)
    with pytest.raises(AttributeError):
        hook.angle_indices = (0,)
    for other in (pickle.loads(pickle.dumps(hook)), copy.deepcopy(hook)):
        assert type(other) is AngleResidual and other.angle_indices == (1, 3)
    old = AngleResidual.__new__(AngleResidual)
    old.__setstate__({"angle_indices": [2]})  # a pickle from before: its __dict__ held a list
    assert old.angle_indices == (2,)
    assert repr(hook) == "AngleResidual([1, 3])"


@pytest.mark.parametrize(
    ("name", "hook"),
    [("residual_z", AngleResidual([3])), ("z_mean_fn", AngleMean([-4])), ("state_add", AngleAdd([4])),
     ("residual_x", AngleResidual([0, 9])), ("x_mean_fn", AngleMean([-5]))],
)  # fmt: skip
def test_an_index_out_of_range_is_refused_when_the_hook_is_given(name, hook):
    for make in (
        lambda **kw: cv_single(MerweScaledWeights(), **kw),
        lambda **kw: cv_fleet(3, MerweScaledWeights(), **kw),
    ):
        with pytest.raises(ParameterError, match=f"{name}=.*out of range for dim_"):
            make(**{name: hook})
        f = make()
        attribute = name.removesuffix("_fn")
        before = getattr(f, attribute)
        with pytest.raises(ParameterError, match=f"{attribute}=.*out of range for dim_"):
            setattr(f, attribute, hook)
        assert getattr(f, attribute) is before  # refused: the filter is as it was


def test_negative_indices_count_from_the_end():
    zs = rbh_measurements(1, 5)[0]
    a, b = rbh_single({"residual_z": AngleResidual([-2])}), rbh_single({"residual_z": AngleResidual([1])})
    for z in zs:
        for f in (a, b):
            _step(f, z)
        np.testing.assert_array_equal(a.x, b.x)


# -- a user's hooks on a fleet: once per chunk when vectorised ------------------------------------


def _wrap_bearing(a, b):  # a user's residual: elementwise, so it serves one point and stacked points
    d = a - b
    d[..., 1] = (d[..., 1] + np.pi) % (2 * np.pi) - np.pi
    return d


def _circular_mean(sigmas, Wm):  # a user's mean: the reference-point form, any leading axes
    m = np.tensordot(Wm, sigmas, axes=(0, -2)) if sigmas.ndim == 2 else np.einsum("i,...id->...d", Wm, sigmas)
    ref = sigmas[..., 0, 1]
    m[..., 1] = wrap(ref + np.einsum("i,...i->...", Wm, wrap(sigmas[..., 1] - ref[..., None])))
    return m


def _add_heading(x, dx):
    s = x + dx
    s[..., 2] = wrap(s[..., 2])
    return s


def _residual_heading(a, b):
    d = a - b
    d[..., 2] = wrap(d[..., 2])
    return d


@pytest.mark.parametrize("x_hooks", [False, True], ids=["z-hooks", "x-and-z-hooks"])
def test_vectorised_hooks_are_called_once_per_chunk(x_hooks):
    """K = 10 in chunks of 4: three calls of each hook per phase that uses it; the same numbers as the
    fleet that calls them per point, to rounding (a user's arithmetic may depend on the array's length)."""
    K, T = 10, 4
    mean, mean_calls = counting(_circular_mean)
    residual, residual_calls = counting(_wrap_bearing)
    hooks = {"z_mean_fn": mean, "residual_z": residual}
    plain = {"z_mean_fn": _circular_mean, "residual_z": _wrap_bearing}
    if x_hooks:
        add, add_calls = counting(_add_heading)
        hooks |= {"state_add": add, "residual_x": _residual_heading}
        plain |= {"state_add": _add_heading, "residual_x": _residual_heading}
    fast, _ = rbh_fleet_and_singles(K, hooks, chunk=4, vectorized_hooks=True)
    slow, _ = rbh_fleet_and_singles(K, plain, chunk=4)
    assert fast.vectorized_hooks and not slow.vectorized_hooks
    zs = rbh_measurements(K, T)
    zs[:, 1] = np.where(np.isnan(zs[:, 1]), 0.0, zs[:, 1])  # (every filter measured at step 1)
    for t in range(T):
        for f in (fast, slow):
            f.predict()
        mean_calls.clear(), residual_calls.clear()
        for f in (fast, slow):
            f.update(zs[:, t])
        if t == 1:
            assert len(mean_calls) == 3 and len(residual_calls) == 3
        assert rel(fast.x, slow.x) <= 1e-12 and rel(fast.P, slow.P) <= 1e-12
    if x_hooks:
        add_calls.clear()
        fast.predict()
        assert len(add_calls) == 3  # the first sets' points, a chunk at a time
    assert not fast.failed.any() and not slow.failed.any()


def test_a_vectorised_hooks_failure_is_one_filters():
    """A hook whose result is not finite for filter 3: it alone is flagged (the chunk run again a
    filter at a time, the hook then given one filter's stacked arrays)."""
    K = 6

    def residual(a, b):
        d = _wrap_bearing(a, b)
        bad = np.abs(a[..., 0] - 1e6) < 1.0  # filter 3's range, set below
        d[bad] = np.nan
        return d

    fleet, _ = rbh_fleet_and_singles(K, {"residual_z": residual}, vectorized_hooks=True)
    x = fleet.x
    x[3, :2] = [1e6, 0.0]
    fleet.x = x
    fleet.predict()
    fleet.update(np.tile(range_bearing_heading_hx(RBH_X0), (K, 1)))
    assert fleet.failed.tolist() == [False, False, False, True, False, False]
    assert "residual_z" in fleet.failure[3]


def test_vectorized_hooks_is_an_option_of_the_fleet_only():
    with pytest.raises(ParameterError, match="vectorized_hooks"):
        cv_fleet(2, MerweScaledWeights(), vectorized_hooks=1)
    fleet = cv_fleet(2, MerweScaledWeights(), residual_z=_wrap_bearing, vectorized_hooks=True)
    with pytest.raises(ParameterError, match="vectorized_hooks"):
        fleet.vectorized_hooks = "yes"
    assert fleet.vectorized_hooks
    again = Fleet.from_filters([fleet[0], fleet[1]])
    assert not again.vectorized_hooks and not Fleet.from_template(fleet[0], 3).vectorized_hooks
    assert pickle.loads(pickle.dumps(fleet)).vectorized_hooks and copy.copy(fleet).vectorized_hooks


# -- the state's angle hooks as data: the prediction's angle kernel, the downdate kernel's wraps -----

STATE_HOOKS = {"x_mean_fn": AngleMean([1]), "residual_x": AngleResidual([1]), "state_add": AngleAdd([1])}


@pytest.fixture
def no_python_state_hooks(monkeypatch):
    """squkf's hooks, the state's too, refuse to be called: the route must not call them."""

    def refuse(self, *args):
        raise AssertionError(f"{self!r} called in Python")

    for cls in (AngleMean, AngleResidual, AngleAdd):
        monkeypatch.setattr(cls, "__call__", refuse)


def test_the_states_angle_hooks_are_done_by_the_kernels(no_python_state_hooks, monkeypatch):
    """Every hook squkf has, on both faces: no Python call; an update is the angle kernel and the
    downdate kernel, a prediction the angle kernel and the transform kernel (and the points drawn)."""
    calls = counting_kernels(monkeypatch)
    zs = rbh_turning_measurements(5)
    f = rbh_turning(rbh_state_hooks())
    fleet, _ = rbh_fleet_and_singles(3, rbh_state_hooks())
    for z in zs:
        _step(f, z)
        fleet.predict()
        fleet.update(np.where(np.isnan(z), np.nan, z)[None].repeat(3, axis=0))
    assert not fleet.failed.any()
    calls.clear()
    f.predict()
    assert calls == ["points", "angle_rows", "transform", "points"]  # (the first set, the prior, the second)
    calls.clear()
    f.update(zs[0])
    assert calls == ["angle_rows", "downdate_update"]


@pytest.mark.parametrize(("family", "scheme"), SCHEMES)
def test_the_states_angle_hooks_are_the_python_hooks_route_to_rounding(family, scheme):
    """Every record of 8 steps of a heading that wraps (a missing range, no measurement) to rounding."""
    zs = rbh_turning_measurements(8)
    data = rbh_turning(rbh_state_hooks(), FAMILIES[family](), scheme=scheme)
    python = rbh_turning(rbh_state_hooks(python=True), FAMILIES[family](), scheme=scheme)
    wrapped = 0
    for t, z in enumerate(zs):
        for f in (data, python):
            f.predict()
        wrapped += np.ptp(data.sigmas_f[:, 2]) > np.pi
        if not _updated_alike(data, python, z, t):
            return
    assert wrapped  # the points' headings passed pi: the hooks mattered


def test_the_states_angle_hooks_are_filterpys_ukf():
    """filterpy's UKF with the same hooks (its points drawn with ``subtract=residual_x``, as AngleAdd
    adds): x and P to 1e-8."""
    zs = rbh_turning_measurements(10, seed=5)
    zs = zs[~np.isnan(zs).any(axis=1)]
    hooks = rbh_state_hooks()
    sq = rbh_turning(hooks, MerweScaledWeights(alpha=0.5, beta=2.0, kappa=0.0))
    fp = UnscentedKalmanFilter(
        4, 3, 1.0, range_bearing_heading_hx, turn_fx_stacked,
        MerweScaledSigmaPoints(4, 0.5, 2.0, 0.0, subtract=AngleResidual([2])), **hooks,
    )  # fmt: skip
    fp.x, fp.P, fp.Q, fp.R = RBH_TURNING_X0.copy(), RBH_TURNING_P0.copy(), RBH_Q, RBH_R
    wrapped = 0
    for z in zs:
        for f in (sq, fp):
            f.predict()
        wrapped += np.ptp(fp.sigmas_f[:, 2]) > np.pi
        for f in (sq, fp):
            f.update(z)
        assert rel(sq.x, fp.x) <= 1e-8 and rel(sq.P, fp.P) <= 1e-8
        assert abs(sq.log_likelihood - fp.log_likelihood) <= 1e-8 * abs(fp.log_likelihood)
    assert wrapped  # the points' headings passed pi


HOOK_SETS = {"measurement": PLAIN_HOOKS, "state": STATE_HOOKS, "both": {**STATE_HOOKS, **PLAIN_HOOKS}}


@pytest.mark.parametrize("hooks", list(HOOK_SETS))
@pytest.mark.parametrize("gate", [None, 0.9])
def test_a_fleet_on_the_angle_kernels_is_its_single_filters_bit_for_bit(gate, hooks):
    """Plain arithmetic models (component 1 of the measurement, of the state or both taken as an angle),
    missing components, a gate."""
    from squkf import SquareRootUKF

    chosen = HOOK_SETS[hooks]
    K = 7
    fleet, zs = _plain_fleet(K, gate=gate, **chosen)
    x0, P0, Q, R, _ = plain_scenario(K, T=5, seed=2)
    singles = []
    for k in range(K):
        f = SquareRootUKF(4, 2, 0.1, plain_hx, plain_fx, MerweScaledWeights(0.5), vectorized=True, gate=gate,
                          **chosen)  # fmt: skip
        f.x, f.P, f.Q, f.R = x0[k], P0[k], Q, R[k]
        singles.append(f)
    for z in zs:
        fleet.predict()
        fleet.update(z)
        for k, f in enumerate(singles):
            _step(f, z[k])
            np.testing.assert_array_equal(fleet.x[k], f.x)
            np.testing.assert_array_equal(fleet.P[k], f.P)
            if not np.isnan(z[k]).all():
                assert fleet.log_likelihood[k] == f.log_likelihood
    assert not fleet.failed.any()


@pytest.mark.parametrize("which", ["measurement", "both"])
def test_a_fleet_on_the_angle_kernels_does_not_depend_on_chunks_or_threads(monkeypatch, which):
    K = 23
    hooks = HOOK_SETS[which]
    reference, zs = _plain_fleet(K, **hooks)
    for z in zs:
        reference.predict()
        reference.update(z)
    monkeypatch.setattr(kernel_threads, "usable_cores", lambda: 2)
    for chunk, threads in ((1, 1), (2, 2), (5, 1), (5, 2), (K, 1), (K, 2)):
        fleet, _ = _plain_fleet(K, chunk=chunk, **hooks)
        kernel_threads.set_num_threads(threads)
        try:
            for z in zs:
                fleet.predict()
                fleet.update(z)
        finally:
            kernel_threads.set_num_threads(1)
        np.testing.assert_array_equal(fleet.x, reference.x, err_msg=f"chunk {chunk}, {threads} threads")
        np.testing.assert_array_equal(fleet.P, reference.P, err_msg=f"chunk {chunk}, {threads} threads")
        np.testing.assert_array_equal(fleet.log_likelihood, reference.log_likelihood)
