"""``Fleet``: K filters in one array step equal K ``SquareRootUKF`` run alone, and fail alone.

The reference for every filter of a fleet is :class:`squkf.SquareRootUKF` with
``vectorized=True`` on the same data, stepped on its own. The fleet's stacked
arrays go through numpy's stacked QR and matmul while a single filter calls LAPACK
directly (see tests/test_step.py), so they agree to rounding, not bit for bit:
measured at most 1e-13 relative on these models (filterpy's points with alpha 0.3,
weights near 1e1). ``models.FLEET_RTOL = 1e-10`` leaves a margin of 1000 and is far below any real
difference (a wrong weight, a dropped row, filters mixed up: 1e-3 or more).

Failure isolation is bit for bit: a fleet with a failing filter ``k`` is compared with
``np.array_equal`` against a fleet of the other K-1 filters on the same data.
"""

from __future__ import annotations

import copy
import pickle
import sys

import numpy as np
import pytest
from filterpy.kalman import JulierSigmaPoints
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from models import (
    FLEET_DT,
    FLEET_FAMILIES,
    FLEET_N_X,
    FLEET_N_Z,
    FLEET_P0,
    SCHEMES,
    assert_close,
    assert_fleet_state,
    cv_fleet,
    cv_fleet_and_measurements,
    cv_fx_stacked,
    cv_single,
    fleet_and_singles,
    fleet_angle_hooks,
    fleet_batch_setup,
    fleet_data,
    fleet_state,
    fleet_with_and_without,
    nested_filters,
    range_bearing_hx,
    run_and_compare,
    turn_fx_stacked,
    wide_covariance_form_update,
    wide_heading_fleet,
    wide_measurements,
    wrapped_pair_filter,
    wrapped_pair_fleet,
    xy_radar_hx_stacked,
)

import squkf.fleet
import squkf.stacks
from squkf import (
    Augmented,
    CallSequenceError,
    Fleet,
    FleetResult,
    FleetStepError,
    JulierWeights,
    MerweScaledWeights,
    NonFiniteError,
    NotPositiveDefiniteError,
    ParameterError,
    ShapeError,
    SimplexWeights,
    SquareRootUKF,
    SqukfError,
    SqukfValueError,
)
from squkf.angles import AngleMean, AngleResidual

SYMMETRIC = {"merwe", "merwe-alpha0.3", "julier", "filterpy-merwe"}


# -- every filter equals the SquareRootUKF run alone ----------------------------------------


CONFIGS = [
    (name, scheme)
    for name in FLEET_FAMILIES
    for scheme in SCHEMES
    if scheme != "augmented" or name in SYMMETRIC
]


@pytest.mark.parametrize("per_filter", [True, False], ids=["per-filter-QR", "shared-QR"])
@pytest.mark.parametrize(("name", "scheme"), CONFIGS)
def test_each_filter_equals_squareroot_ukf(name, scheme, per_filter):
    K = 4
    fleet, singles, zs = fleet_and_singles(K, name, scheme, per_filter=per_filter)
    zs[1, 2] = np.nan  # filter 1 has no measurement at step 2
    zs[2, 3, 0] = np.nan  # filter 2 misses the range at step 3
    zs[0, 3, 1] = np.nan  # filter 0 misses the bearing at step 3 (another pattern)
    zs[3, 4, 1] = np.nan
    zs[:, 5] = np.nan  # nobody measures at step 5
    run_and_compare(fleet, singles, zs)


@pytest.mark.parametrize(("name", "scheme"), CONFIGS)
def test_each_filter_equals_squareroot_ukf_with_angle_hooks(name, scheme):
    K = 3
    model = "turn"
    fleet, singles, zs = fleet_and_singles(K, name, scheme, model, hooks=fleet_angle_hooks(model), T=8)
    zs[1, 3] = np.nan
    run_and_compare(fleet, singles, zs)
    # the hooks mattered: the heading went round past pi and was wrapped by state_add
    assert np.all(np.abs(fleet.x[:, 2]) <= np.pi)


def test_angle_hooks_on_measurement_only():
    fleet, singles, zs = fleet_and_singles(3, "merwe", "redrawn", hooks=fleet_angle_hooks("cv"))
    zs[2, 1] = np.nan
    run_and_compare(fleet, singles, zs)


@pytest.mark.parametrize("state_add", [False, True], ids=["residual_x", "state_add"])
@pytest.mark.parametrize("scheme", ["redrawn", "augmented"])
def test_wrapped_residual_x_fleet_equals_its_single_filters_bit_for_bit(scheme, state_add):
    """A residual_x whose deviations wrap (the downdate form): each filter of the fleet, stepped or in
    batch_filter, is its single filter bit for bit, and its P is P_prior - K S K^T (filterpy's update
    written out on the single filter's set and images) to 1e-10 of |P|."""
    K = 3
    family = MerweScaledWeights(1.0, 2.0, 0.0)
    fleet, singles = wide_heading_fleet(K, family, state_add, scheme)
    Wm, Wc = family.augmented(3).weights(6) if scheme == "augmented" else family.weights(3)
    batch = copy.deepcopy(fleet)
    zs = wide_measurements(5)
    for t, z in enumerate(zs):
        fleet.predict()
        fleet.update(np.broadcast_to(z, (K, 3)))
        for k, f in enumerate(singles):
            f.predict()
            x_prior, P_prior, sigmas = f.x, f.P, f.sigmas_f
            f.update(z)
            for name in ("x", "P1_2", "x_prior", "P1_2_prior", "y"):
                np.testing.assert_array_equal(
                    getattr(fleet, name)[k], getattr(f, name), f"{name} t={t} k={k}"
                )
            assert fleet.log_likelihood[k] == f.log_likelihood
            _, P = wide_covariance_form_update(x_prior, P_prior, sigmas, f.sigmas_h, Wm, Wc, z, state_add)
            np.testing.assert_allclose(
                fleet.P[k], P, rtol=0, atol=1e-10 * np.abs(P).max(), err_msg=f"t={t} k={k}"
            )
    assert not fleet.failed.any()
    res = batch.batch_filter(np.broadcast_to(zs, (K,) + zs.shape))
    np.testing.assert_array_equal(res.x, fleet.x)
    np.testing.assert_array_equal(res.P1_2, fleet.P1_2)


def test_a_failing_downdate_flags_that_filter_and_the_others_step_as_alone():
    """Filter 1's sensor is precise enough that filterpy's P_prior - K S K^T is indefinite: it is
    flagged (error 303), left as it was, and the others step as their single filters do."""
    K, k = 3, 1
    R = [1.0, 0.1, 2.0]
    fleet = wrapped_pair_fleet(K, JulierSigmaPoints(2, kappa=1), R)
    fleet.predict()
    x_k, S_k = fleet.x[k].copy(), fleet.P1_2[k].copy()
    fleet.update(np.full((K, 1), 0.3))
    assert fleet.failed.tolist() == [j == k for j in range(K)]
    assert "PosteriorFactorError" in fleet.failure[k]
    np.testing.assert_array_equal(fleet.x[k], x_k)
    np.testing.assert_array_equal(fleet.P1_2[k], S_k)
    for j in (0, 2):
        one = wrapped_pair_filter(SquareRootUKF, JulierSigmaPoints(2, kappa=1), R=R[j])
        one.predict()
        one.update([0.3])
        np.testing.assert_array_equal(fleet.x[j], one.x)
        np.testing.assert_array_equal(fleet.P1_2[j], one.P1_2)


def test_augmented_needs_pairs_as_for_one_filter():
    for name in ("simplex", "cubature"):
        with pytest.raises(ParameterError):
            cv_single(FLEET_FAMILIES[name](), "augmented")
        with pytest.raises(ParameterError):
            cv_fleet(3, FLEET_FAMILIES[name](), "augmented")


def test_update_R_argument_shared_and_per_filter():
    K = 3
    fleet, singles, zs = fleet_and_singles(K, "merwe", "redrawn")
    R_step = np.stack([np.diag([0.2, 0.05]) * (k + 1) for k in range(K)])
    run_and_compare(fleet, singles, zs[:, :3], R_step=R_step)
    run_and_compare(fleet, singles, zs[:, 3:], R_step=np.diag([0.3, 0.01]))


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    K=st.integers(1, 5),
    seed=st.integers(0, 2**16),
    scheme=st.sampled_from(SCHEMES),
    missing=st.lists(st.tuples(st.integers(0, 4), st.integers(0, 3), st.integers(0, 2)), max_size=6),
)
def test_equals_single_filters_property(K, seed, scheme, missing):
    """Any fleet size, data, scheme and pattern of missing rows (2) and components (0, 1)."""
    fleet, singles, zs = fleet_and_singles(K, "merwe", scheme, seed=seed, T=4)
    for k, t, what in missing:
        if k < K:
            if what == 2:
                zs[k, t] = np.nan
            else:
                zs[k, t, what] = np.nan
    run_and_compare(fleet, singles, zs)


def test_per_filter_fx_args_reach_fx_with_a_point_axis():
    K = 4
    fleet, singles, zs = fleet_and_singles(K, "merwe", "redrawn")
    u = np.random.default_rng(3).normal(0, 1.0, (K, 2))
    seen = []

    def fx(X, dt, u=None):
        seen.append(np.shape(u))
        return cv_fx_stacked(X, dt, u=u)

    fleet.fx = fx
    run_and_compare(fleet, singles, zs[:, :3], fx_args={"u": u})
    assert seen and all(s == (K, 1, 2) for s in seen)
    # the control changed the result (it reached fx): the fleet without it differs
    other, _, _ = fleet_and_singles(K, "merwe", "redrawn")
    for t in range(3):
        other.predict()
        other.update(zs[:, t])
    assert np.abs(other.x - fleet.x).max() > 1e-3


def test_per_filter_hx_args_and_shared_scalars():
    K = 3
    fleet, singles, zs = fleet_and_singles(K, "merwe", "redrawn")
    scale = np.array([1.0, 1.1, 0.9])
    singles_scaled = singles
    run_and_compare(fleet, singles_scaled, zs[:, :2] * scale[:, None, None], hx_args={"scale": scale})
    # a scalar argument is passed as it is to every filter
    run_and_compare(fleet, singles, zs[:, 2:4], hx_args={"scale": 1.0})


# -- state and noise, per filter or shared -------------------------------------------------


def test_state_assignment_broadcasts_and_checks():
    K = 3
    fleet = cv_fleet(K, MerweScaledWeights())
    fleet.x = np.arange(4.0)
    np.testing.assert_array_equal(fleet.x, np.tile(np.arange(4.0), (K, 1)))
    fleet.P = FLEET_P0
    np.testing.assert_allclose(fleet.P, np.broadcast_to(FLEET_P0, (K, 4, 4)), rtol=1e-14)
    S = np.linalg.cholesky(FLEET_P0)
    for k in range(K):
        np.testing.assert_allclose(fleet.P1_2[k], S, rtol=1e-14)
    Ps = np.stack([FLEET_P0 * (k + 1) for k in range(K)])
    fleet.P = Ps
    np.testing.assert_allclose(fleet.P, Ps, rtol=1e-14)
    Ss = np.stack([S * (k + 1) for k in range(K)])
    fleet.P1_2 = Ss
    np.testing.assert_array_equal(fleet.P1_2, Ss)
    fleet.P1_2 = S
    np.testing.assert_array_equal(fleet.P1_2, np.broadcast_to(S, (K, 4, 4)))
    # the factors are fresh copies: editing one changes nothing; x and P edited in place are taken
    # (issue 20: an edit is never lost; tests/test_records.py)
    fleet.P1_2[0, 0, 0] = 99.0
    assert fleet.P1_2[0, 0, 0] == S[0, 0]
    fleet.x[0, 0] = 99.0
    fleet.P[0, 0, 0] = 99.0
    assert fleet.x[0, 0] == 99.0 and fleet.P1_2[0, 0, 0] == np.sqrt(99.0)
    fleet.x, fleet.P1_2 = np.arange(4.0), S  # back as before the edits

    x_before, S_before = fleet.x, fleet.P1_2
    for attr, bad, exc in [
        ("x", np.zeros(3), ShapeError),
        ("x", np.zeros((K + 1, 4)), ShapeError),
        ("x", np.r_[0.0, np.nan, 0, 0], NonFiniteError),  # (all NaN is a placeholder: not set yet)
        ("x", np.r_[0.0, np.inf, 0, 0], NonFiniteError),
        ("P", np.eye(3), ShapeError),
        ("P", -np.eye(4), NotPositiveDefiniteError),
        ("P", np.stack([FLEET_P0, FLEET_P0, -FLEET_P0]), NotPositiveDefiniteError),
        ("P", np.where(np.eye(4) > 0, np.nan, 0.0), NonFiniteError),
        ("P1_2", np.ones((4, 4)), SqukfValueError),  # not lower triangular
        ("P1_2", np.zeros((K, 4, 4)), SqukfError),  # singular
        ("P1_2", np.eye(5), ShapeError),
    ]:
        with pytest.raises(exc):
            setattr(fleet, attr, bad)
        np.testing.assert_array_equal(fleet.x, x_before)
        np.testing.assert_array_equal(fleet.P1_2, S_before)


def test_noise_shared_or_per_filter():
    K = 3
    fleet = cv_fleet(K, MerweScaledWeights())
    Q = np.diag([0.1, 0.2, 0.3, 0.4])
    fleet.Q = Q
    assert fleet.Q.shape == (4, 4) and fleet.Q1_2.shape == (4, 4)
    np.testing.assert_allclose(fleet.Q, Q, rtol=1e-14)
    Qs = np.stack([Q * (k + 1) for k in range(K)])
    fleet.Q = Qs
    np.testing.assert_allclose(fleet.Q, Qs, rtol=1e-14)
    fleet.Q = np.zeros((4, 4))
    np.testing.assert_array_equal(fleet.Q, np.zeros((4, 4)))
    np.testing.assert_array_equal(fleet.Q1_2, np.zeros((4, 4)))
    fleet.Q1_2 = np.linalg.cholesky(Qs)
    np.testing.assert_allclose(fleet.Q, Qs, rtol=1e-14)
    Rs = np.stack([np.diag([0.1, 0.01]) * (k + 1) for k in range(K)])
    fleet.R = Rs
    np.testing.assert_allclose(fleet.R, Rs, rtol=1e-14)
    np.testing.assert_allclose(fleet.R1_2, np.linalg.cholesky(Rs), rtol=1e-14)
    fleet.R1_2 = np.diag([0.5, 0.2])
    np.testing.assert_allclose(fleet.R, np.diag([0.25, 0.04]), rtol=1e-14)
    for attr, bad in [
        ("Q", np.eye(3)),
        ("Q", np.ones((K + 1, 4, 4))),
        ("R", np.eye(3)),
        ("R", np.ones((K - 1, 2, 2))),
        ("R1_2", np.ones((K, 3, 3))),
    ]:
        before = getattr(fleet, attr)
        with pytest.raises(ShapeError):
            setattr(fleet, attr, bad)
        np.testing.assert_array_equal(getattr(fleet, attr), before)
    with pytest.raises(SqukfError):
        fleet.R = np.stack([np.eye(2), -np.eye(2), np.eye(2)])
    np.testing.assert_allclose(fleet.R, np.diag([0.25, 0.04]), rtol=1e-14)


BAD_FLEET_ARGUMENTS = [
    pytest.param({"n_filters": 0}, id="n_filters-0"),
    pytest.param({"n_filters": True}, id="n_filters-True"),
    pytest.param({"n_filters": 2.0}, id="n_filters-float"),
    pytest.param({"dim_x": 0}, id="dim_x-0"),
    pytest.param({"dim_z": -1}, id="dim_z-negative"),
    pytest.param({"on_error": "ignore"}, id="on_error-ignore"),
    pytest.param({"scheme": "nope"}, id="scheme-nope"),
    *[pytest.param({"dt": dt}, id=f"dt-{dt!r}") for dt in (np.nan, np.inf, "a", 1j)],  # (None: a placeholder)
]


@pytest.mark.parametrize("kw", BAD_FLEET_ARGUMENTS)
def test_constructor_refuses(kw):
    args = {"n_filters": 2, "dim_x": 4, "dim_z": 2, "dt": FLEET_DT} | kw
    options = {k: v for k, v in kw.items() if k in ("on_error", "scheme")}
    with pytest.raises(ParameterError):
        Fleet(
            args["n_filters"],
            args["dim_x"],
            args["dim_z"],
            args["dt"],
            range_bearing_hx,
            cv_fx_stacked,
            MerweScaledWeights(),
            **options,
        )


def test_constructor_checks():
    fleet = cv_fleet(3, MerweScaledWeights())
    assert (fleet.n_filters, fleet.dim_x, fleet.dim_z, len(fleet)) == (3, 4, 2, 3)


# -- failure isolation -------------------------------------------------------------------------


def assert_rows_equal(big, small, keep, what):
    """Filters ``keep`` of ``big`` are bit for bit those of ``small``."""
    for a in ("x", "P1_2", "x_prior", "P1_2_prior", "x_post", "P1_2_post", "log_likelihood", "mahalanobis"):
        np.testing.assert_array_equal(getattr(big, a)[keep], getattr(small, a), err_msg=f"{a} {what}")
    np.testing.assert_array_equal(big.y[keep], small.y, err_msg=f"y {what}")
    np.testing.assert_array_equal(big.failed[keep], small.failed)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(K=st.integers(2, 5), data_=st.data(), scheme=st.sampled_from(SCHEMES))
def test_nan_fx_isolated_and_frozen(K, data_, scheme):
    k = data_.draw(st.integers(0, K - 1))
    big, small, keep, zs = fleet_with_and_without(K, k, scheme)
    bad = np.zeros(K, dtype=bool)
    for t in range(2):  # two good steps
        big.predict(bad=bad)
        big.update(zs[:, t])
        small.predict()
        small.update(zs[keep, t])
    assert_rows_equal(big, small, keep, "before the failure")
    x_k, S_k = big.x[k], big.P1_2[k]
    bad[k] = True
    big.predict(bad=bad)
    small.predict()
    assert big.failed[k] and big.failed.sum() == 1
    assert "fx" in big.failure[k] and all(big.failure[j] == "" for j in keep)
    np.testing.assert_array_equal(big.x[k], x_k)
    np.testing.assert_array_equal(big.P1_2[k], S_k)
    big.update(zs[:, 2])
    small.update(zs[keep, 2])
    assert_rows_equal(big, small, keep, "at the failure")
    np.testing.assert_array_equal(big.x[k], x_k)
    np.testing.assert_array_equal(big.P1_2[k], S_k)
    assert big.log_likelihood[k] == 0.0
    # later steps leave it frozen, even with good fx values
    bad[k] = False
    for t in range(3, 5):
        big.predict(bad=bad)
        big.update(zs[:, t])
        small.predict()
        small.update(zs[keep, t])
        assert_rows_equal(big, small, keep, f"after the failure t={t}")
        np.testing.assert_array_equal(big.x[k], x_k)
        np.testing.assert_array_equal(big.P1_2[k], S_k)
        assert big.failed[k]
    # reset: the flag goes, the filter resumes from the state given, as a single filter would
    x_new, P_new = small.x[0] if K > 1 else x_k, 2.0 * FLEET_P0
    big.reset(k, x_new, P_new)
    assert not big.failed.any() and big.failure[k] == ""
    np.testing.assert_array_equal(big.x[k], x_new)
    one = big[k]
    big.predict(bad=bad)
    big.update(zs[:, 5])
    small.predict()
    small.update(zs[keep, 5])
    one.predict()
    one.update(zs[k, 5])
    assert not big.failed.any()
    assert_rows_equal(big, small, keep, "after the reset")
    assert_close(big.x[k], one.x, "x after reset")
    assert_close(big.P1_2[k], one.P1_2, "P1_2 after reset")


@pytest.mark.parametrize("scheme", SCHEMES)
def test_chunks_call_the_model_per_chunk_and_a_failure_in_one_is_that_filters_alone(scheme):
    """``chunk=2`` over 5 filters: fx and hx see the chunks' points and per-filter arguments cut to them.

    Filter 3 (in the second chunk) fails; the others are the fleet of 4 without it, bit for bit.
    """
    K, k = 5, 3
    big, small, keep, zs = fleet_with_and_without(K, k, scheme)
    big.chunk = 2
    fx, hx, seen = big.fx, big.hx, []

    def fx_seen(X, dt, bad=None):
        seen.append(("fx", X.shape[0], np.shape(bad)))
        return fx(X, dt, bad=bad)

    def hx_seen(X, **kw):
        seen.append(("hx", X.shape[0]))
        return hx(X, **kw)

    big.fx, big.hx = fx_seen, hx_seen
    good, bad = np.zeros(K, dtype=bool), np.zeros(K, dtype=bool)
    bad[k] = True
    for t, flags in enumerate((good, bad, good)):
        big.predict(bad=flags)
        big.update(zs[:, t])
        small.predict()
        small.update(zs[keep, t])
    assert big.failed.tolist() == [j == k for j in range(K)]
    assert "fx" in big.failure[k]
    assert_rows_equal(big, small, keep, "after the failure")
    assert seen[:6] == [
        ("fx", 2, (2, 1)),
        ("fx", 2, (2, 1)),
        ("fx", 1, (1, 1)),
        ("hx", 2),
        ("hx", 2),
        ("hx", 1),
    ]


def test_a_chunks_wrong_fx_shape_names_its_filters_and_changes_nothing():
    fleet = cv_fleet(5, MerweScaledWeights())
    fleet.chunk = 2
    before = fleet_state(fleet)
    fx = fleet.fx
    fleet.fx = lambda X, dt: fx(X, dt)[:, :-1] if X.shape[0] == 1 else fx(X, dt)
    with pytest.raises(ShapeError, match="filters 4 to 4"):
        fleet.predict()
    assert_fleet_state(fleet, before)


def test_a_z_written_to_inf_by_hx_mid_step_is_refused_and_changes_nothing():
    """The step reads each chunk's rows of z after that chunk's hx, and checks what it read: an hx that
    writes inf into the caller's z (a later chunk's rows) cannot slip it into the kernels."""
    fleet, zs = cv_fleet_and_measurements(5, 2)
    fleet.chunk = 2
    fleet.predict()
    fleet.update(zs[:, 0])
    fleet.predict()
    before = fleet_state(fleet)
    z = zs[:, 1].copy()
    hx = fleet.hx

    def hostile_hx(X):
        z[4, 1] = np.inf
        return hx(X)

    fleet.hx = hostile_hx
    with pytest.raises(NonFiniteError, match=r"row 4"):
        fleet.update(z)
    fleet.hx = hx
    assert_fleet_state(fleet, before)


def test_steps_yielded_in_one_reused_array_are_each_the_step_read():
    """batch_filter given an iterator that writes every step into the same array (a reader's buffer)
    filters each step as yielded, as it does the whole array."""
    fleet, zs = cv_fleet_and_measurements(3, 4)
    other = copy.deepcopy(fleet)

    def reader():
        buffer = np.empty((3, FLEET_N_Z))
        for t in range(zs.shape[1]):
            buffer[...] = zs[:, t]
            yield buffer

    expected = fleet.batch_filter(zs)
    got = other.batch_filter(reader())
    np.testing.assert_array_equal(got.x, expected.x)
    np.testing.assert_array_equal(got.P1_2, expected.P1_2)


def test_a_copy_keeps_its_own_failures():
    """The reasons of flagged filters are the fleet's own: a copy's are not changed by the original's
    later failures, and a pickle or a fleet of some rows keeps them."""
    fleet, zs = cv_fleet_and_measurements(4, 3)
    bad = np.zeros(4, dtype=bool)
    bad[1] = True
    fleet.predict(bad=bad)
    twin = copy.copy(fleet)
    bad[:] = [False, False, False, True]
    fleet.predict(bad=bad)
    assert list(fleet.failed) == [False, True, False, True] and "fx" in fleet.failure[3]
    assert list(twin.failed) == [False, True, False, False]
    assert list(twin.failure == "") == [True, False, True, True]
    back = pickle.loads(pickle.dumps(fleet))
    assert list(back.failure) == list(fleet.failure)
    some = fleet.subset([3, 0, 1])
    assert list(some.failure == "") == [False, True, False] and some.failure[0] == fleet.failure[3]
    fleet.reset(1)
    assert list(fleet.failure == "") == [True, True, True, False] and "fx" in fleet.failure[3]


@pytest.mark.parametrize("bad", [0, -2, 1.5, "8", True, "auto"])
def test_chunk_must_be_a_positive_integer(bad):
    with pytest.raises(ParameterError, match="chunk"):
        cv_fleet(3, MerweScaledWeights(), chunk=bad)


@pytest.mark.parametrize(("K", "threads", "chunk", "calls"), [
    (5000, 1, None, [2048, 2048, 904]),  # the default: CHUNK
    (5000, 2, None, [1250] * 4),  # on threads cut evenly, a multiple of their count
    (40_000, 2, None, [4000] * 10),  # twice CHUNK once each thread gets four such chunks
    (5000, 2, 1000, [834, 834, 833, 833, 833, 833]),  # given: at most that many
    (5000, 1, 3000, [3000, 2000]),
])  # fmt: skip
def test_chunk_none_is_the_librarys_size_for_the_thread_count(K, threads, chunk, calls):
    fleet = cv_fleet(K, MerweScaledWeights(), chunk=chunk)
    assert fleet.chunk == chunk
    seen = []

    def fx(X, dt):
        seen.append(X.shape[0])
        return cv_fx_stacked(X, dt)

    fleet.fx = fx
    squkf.set_num_threads(threads)
    try:
        fleet.predict()
    finally:
        squkf.set_num_threads(1)
    assert sorted(seen, reverse=True) == calls
    fleet.chunk = 7
    fleet.chunk = None  # back to the library's choice
    assert fleet.chunk is None


@pytest.mark.parametrize(
    ("environ", "threshold"),
    [
        ({}, None),
        ({"MALLOC_TRIM_THRESHOLD_": "65536"}, 128 * 1024),  # a Dask worker's: glibc's default, fixed
        ({"MALLOC_TRIM_THRESHOLD_": "65536", "MALLOC_MMAP_THRESHOLD_": "40000"}, 40000),
        ({"MALLOC_MMAP_THRESHOLD_": "not a number"}, None),  # glibc ignores it too
    ],
)
def test_the_mmap_threshold_is_read_from_the_environment(environ, threshold):
    if not sys.platform.startswith("linux"):
        threshold = None
    assert squkf.stacks.fixed_mmap_threshold(environ) == threshold


@pytest.mark.parametrize("scheme", ["redrawn", "augmented"])
def test_under_a_fixed_mmap_threshold_the_models_arrays_stay_below_it(monkeypatch, scheme):
    """A Dask worker's setting: the default chunk keeps each model call's points and images under the
    threshold (none is mapped and faulted in at every step), and changes no number."""
    K, threshold = 700, 128 * 1024
    expected = cv_fleet(K, MerweScaledWeights(), scheme)
    monkeypatch.setattr(squkf.stacks, "_MMAP_THRESHOLD", threshold)
    fleet = cv_fleet(K, MerweScaledWeights(), scheme)
    nbytes: list[int] = []  # of every array a model call is given or gives back
    filters: list[int] = []  # per call

    def fx(X, dt):
        F = cv_fx_stacked(X, dt)
        nbytes.extend([X.nbytes, F.nbytes])
        filters.append(X.shape[0])
        return F

    def hx(X):
        H = range_bearing_hx(X)
        nbytes.extend([X.nbytes, H.nbytes])
        filters.append(X.shape[0])
        return H

    fleet.fx, fleet.hx = fx, hx
    z = np.tile(range_bearing_hx(np.array([10.0, 1.0, 20.0, -1.0])), (K, 1))
    for f in (expected, fleet):
        f.x, f.P, f.Q, f.R = [10.0, 1.0, 20.0, -1.0], np.eye(4), 0.01 * np.eye(4), np.diag([0.1, 1e-3])
        f.predict()
        f.update(z)
    assert max(nbytes) < threshold
    assert max(filters) < K and sum(filters) == 2 * K  # every filter in one call of each model
    assert_fleet_state(fleet, fleet_state(expected))


@pytest.mark.parametrize(("threads", "K", "row_bytes", "size"), [
    (1, 10**5, 0, 2048),  # rows not known: CHUNK
    (1, 10**5, 9 * 4 * 8, 2048),  # n = 4: a chunk's points 0.6 MB, within CHUNK_BYTES
    (1, 10**5, 21 * 10 * 8, (1 << 20) // (21 * 10 * 8)),  # n = 10: 624 filters, 1 MiB of points
    (2, 10**5, 9 * 4 * 8, 4096),  # on threads twice the filters, twice the bytes
    (2, 10**5, 21 * 10 * 8, (2 << 20) // (21 * 10 * 8)),
    (1, 10**5, 10**6, 64),  # never fewer than MIN_CHUNK
])  # fmt: skip
def test_a_model_with_large_points_gets_fewer_filters_a_chunk(threads, K, row_bytes, size):
    assert squkf.stacks.default_chunk(threads, K, row_bytes) == size


def test_a_fleets_chunks_hold_at_most_chunk_bytes_of_points():
    """End to end: a 30-state model's points are cut into chunks of at most CHUNK_BYTES per call."""
    n, K = 30, 400

    def fx(X, dt):
        seen.append(X.nbytes)
        return X

    def hx(X):
        seen.append(X.nbytes)
        return X[..., :1]

    seen: list[int] = []
    fleet = Fleet(K, n, 1, 1.0, hx, fx, MerweScaledWeights())
    fleet.predict()
    fleet.update(np.zeros((K, 1)))
    assert max(seen) <= squkf.stacks.CHUNK_BYTES and len(seen) > 2
    assert sum(seen) == 2 * K * (2 * n + 1) * n * 8  # every filter's points, once in each model


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize(("K", "k"), [(4, 2), (2, 0), (3, 2)])
def test_singular_innovation_isolated(scheme, K, k):
    """Filter k's R is zero and its hx constant: its innovation factor is singular.

    The stack fails, so the others are updated one by one: their numbers must still be those
    of the K-1 fleet updated as one stack (numpy's kernels treat a stack of one differently).
    """
    big, small, keep, zs = fleet_with_and_without(K, k, scheme)
    R = big.R
    R[k] = 0.0
    big.R = R
    scale = np.ones(K)
    scale[k] = 0.0
    for t in range(2):
        big.predict()
        small.predict()
        x_k, S_k = big.x[k], big.P1_2[k]
        big.update(zs[:, t], scale=scale)
        small.update(zs[keep, t], scale=scale[keep])
        assert_rows_equal(big, small, keep, f"t={t}")
        assert big.failed[k] and big.failed.sum() == 1
        assert "GainError" in big.failure[k]
        if t == 0:  # it keeps its prior, from before the failing update
            np.testing.assert_array_equal(big.x[k], x_k)
            np.testing.assert_array_equal(big.P1_2[k], S_k)
            frozen = big.x[k], big.P1_2[k]
        else:  # frozen through the later prediction and update
            np.testing.assert_array_equal(big.x[k], frozen[0])
            np.testing.assert_array_equal(big.P1_2[k], frozen[1])


@pytest.mark.parametrize("scheme", SCHEMES)
def test_two_filters_equal_one_bit_for_bit(scheme):
    """A fleet of 2 without a failure, against the fleet of its filter 0 alone (a stack of one)."""
    big, small, keep, zs = fleet_with_and_without(2, 1, scheme)
    zs[0, 2, 1] = np.nan
    for t in range(5):
        big.predict()
        small.predict()
        big.update(zs[:, t])
        small.update(zs[keep, t])
        assert_rows_equal(big, small, keep, f"t={t}")


def test_nan_hx_isolated_only_where_measured():
    K = 4
    big, small, keep, zs = fleet_with_and_without(K, 1)
    scale = np.array([1.0, np.nan, 1.0, np.nan])  # filters 1 and 3 give NaN images
    zs[3, 0] = np.nan  # filter 3 has no measurement: its images are not used
    big.predict()
    small.predict()
    x_1 = big.x[1]
    big.update(zs[:, 0], scale=scale)
    small.update(zs[keep, 0], scale=scale[keep])
    assert big.failed.tolist() == [False, True, False, False]
    assert "hx" in big.failure[1]
    np.testing.assert_array_equal(big.x[1], x_1)
    assert_rows_equal(big, small, keep, "nan hx")


def test_singular_innovation_with_missing_component_isolated():
    """Same, with filter k and some others missing a component (grouped updates)."""
    K, k = 5, 1
    big, small, keep, zs = fleet_with_and_without(K, k)
    R = big.R
    R[k] = 0.0
    big.R = R
    scale = np.ones(K)
    scale[k] = 0.0
    zs[[0, 1, 3], 0, 1] = np.nan
    big.predict()
    small.predict()
    big.update(zs[:, 0], scale=scale)
    small.update(zs[keep, 0], scale=scale[keep])
    assert_rows_equal(big, small, keep, "grouped")
    assert big.failed.tolist() == [j == k for j in range(K)]


def test_downdate_failure_isolated():
    """A negative weight (Merwe, beta 0) and points moved together: filter k's downdate fails."""
    K, k = 4, 3
    fam = lambda: MerweScaledWeights(alpha=0.3, beta=0.0)  # noqa: E731
    FAMILIES_LOCAL = {"merwe-beta0": fam}
    x0, Q, R, zs = fleet_data(K, 3, 4)
    keep = np.arange(K - 1)
    big = cv_fleet(K, FAMILIES_LOCAL["merwe-beta0"]())
    small = cv_fleet(K - 1, fam())
    for fl, idx in ((big, np.arange(K)), (small, keep)):
        fl.x, fl.P, fl.Q, fl.R = x0[idx], FLEET_P0, Q[idx], R[idx]
    kick = np.zeros(K)
    kick[k] = 5.0
    x_k, S_k = big.x[k], big.P1_2[k]
    big.predict(kick=kick)
    small.predict(kick=kick[keep])
    assert big.failed.tolist() == [False, False, False, True]
    assert "DowndateError" in big.failure[k]
    np.testing.assert_array_equal(big.x[k], x_k)
    np.testing.assert_array_equal(big.P1_2[k], S_k)
    big.update(zs[:, 0])
    small.update(zs[keep, 0])
    assert_rows_equal(big, small, keep, "downdate")
    # a single filter fails the same way
    one = cv_single(fam())
    one.x, one.P, one.Q = x0[k], FLEET_P0, Q[k]
    with pytest.raises(SqukfError):
        one.predict(kick=5.0)


def test_several_failures_at_once_and_reset_all():
    K = 5
    x0, Q, R, zs = fleet_data(K, 3, 2)
    fleet = cv_fleet(K, MerweScaledWeights())
    fleet.x, fleet.P, fleet.Q, fleet.R = x0, FLEET_P0, Q, R
    bad = np.array([True, False, True, False, False])
    fleet.predict(bad=bad)
    np.testing.assert_array_equal(fleet.failed, bad)
    fleet.update(zs[:, 0])
    fleet.reset()  # every flagged filter, state kept
    assert not fleet.failed.any() and all(r == "" for r in fleet.failure)
    np.testing.assert_array_equal(fleet.x[bad], x0[bad])
    fleet.predict()
    fleet.update(zs[:, 1])
    assert not fleet.failed.any()
    assert np.all(fleet.x[bad] != x0[bad])
    # reset with a mask and one x per filter
    fleet.predict(bad=bad)
    fleet.reset(bad, x=x0[bad] + 1.0)
    np.testing.assert_array_equal(fleet.x[bad], x0[bad] + 1.0)
    assert not fleet.failed.any()


def test_on_error_raise_downdate_names_the_filters():
    K = 4
    fam = MerweScaledWeights(alpha=0.3, beta=0.0)
    x0, Q, R, zs = fleet_data(K, 2, 4)
    fleet = cv_fleet(K, fam, on_error="raise")
    fleet.x, fleet.P, fleet.Q, fleet.R = x0, FLEET_P0, Q, R
    snap = fleet_state(fleet)
    kick = np.array([5.0, 0.0, 5.0, 0.0])
    with pytest.raises(FleetStepError) as info:
        fleet.predict(kick=kick)
    assert info.value.filters == (0, 2)
    assert all("DowndateError" in r for r in info.value.reasons)
    assert_fleet_state(fleet, snap)


def test_masked_z_and_scalar_measurement():
    K = 3
    x0, Q, R, zs = fleet_data(K, 2, 0)
    fleet = cv_fleet(K, MerweScaledWeights())
    fleet.x, fleet.Q, fleet.R = x0, Q, R
    other = copy.deepcopy(fleet)
    z = np.ma.masked_array(zs[:, 0], mask=[[False, False], [True, True], [False, True]])
    fleet.update(z)
    znan = zs[:, 0].copy()
    znan[1] = np.nan
    znan[2, 1] = np.nan
    other.update(znan)
    np.testing.assert_array_equal(fleet.x, other.x)
    np.testing.assert_array_equal(fleet.P1_2, other.P1_2)
    # dim_z 1: z may be given as (K,)
    f1 = Fleet(K, 2, 1, 1.0, lambda X: X[..., :1], lambda X, dt: X, MerweScaledWeights())
    f2 = copy.deepcopy(f1)
    f1.update(np.array([1.0, np.nan, -1.0]))
    f2.update(np.array([[1.0], [np.nan], [-1.0]]))
    np.testing.assert_array_equal(f1.x, f2.x)
    np.testing.assert_array_equal(f1.x[1], [0.0, 0.0])


# -- one filter and back ----------------------------------------------------------------------


@pytest.mark.parametrize(("name", "scheme"), [("merwe", "augmented"), ("filterpy-merwe", "propagated")])
def test_getitem_is_that_filter(name, scheme):
    K = 4
    fleet, singles, zs = fleet_and_singles(K, name, scheme)
    for t in range(2):
        fleet.predict()
        fleet.update(zs[:, t])
    for k in (0, 2, -1):
        f = fleet[k]
        kk = k % K
        assert isinstance(f, SquareRootUKF) and f.vectorized
        np.testing.assert_array_equal(f.x, fleet.x[kk])
        np.testing.assert_array_equal(f.P1_2, fleet.P1_2[kk])
        np.testing.assert_array_equal(f.Q1_2, fleet.Q1_2[kk])
        np.testing.assert_array_equal(f.R1_2, fleet.R1_2[kk])
        assert f.fx is fleet.fx and f.hx is fleet.hx and type(f.scheme) is type(fleet.scheme)
        assert (f.dim_x, f.dim_z) == (FLEET_N_X, FLEET_N_Z)
    ones = [fleet[k] for k in range(K)]
    run_and_compare(fleet, ones, zs[:, 2:])
    with pytest.raises(IndexError):
        fleet[K]


def test_getitem_shared_noise_and_no_process_noise():
    fleet, _, _ = fleet_and_singles(3, "merwe", "redrawn", per_filter=False)
    fleet.Q = np.zeros((4, 4))
    f = fleet[1]
    np.testing.assert_array_equal(f.Q, np.zeros((4, 4)))
    np.testing.assert_array_equal(f.R1_2, fleet.R1_2)


def test_from_filters_round_trip():
    K = 4
    _, singles, zs = fleet_and_singles(K, "julier", "augmented", hooks=fleet_angle_hooks("cv"))
    for k, f in enumerate(singles):
        f.predict()
        f.update(zs[k, 0])
    fleet = Fleet.from_filters(singles)
    assert fleet.n_filters == K and fleet.Q.shape == (K, 4, 4) and fleet.R.shape == (K, 2, 2)
    for k, f in enumerate(singles):
        g = fleet[k]
        np.testing.assert_array_equal(g.x, f.x)
        np.testing.assert_array_equal(g.P1_2, f.P1_2)
        np.testing.assert_array_equal(g.Q1_2, f.Q1_2)
        np.testing.assert_array_equal(g.R1_2, f.R1_2)
        assert g.z_mean is f.z_mean and g.residual_z is f.residual_z
    run_and_compare(fleet, singles, zs[:, 1:])
    # shared noise stays shared; zero Q gives no process noise
    for f in singles:
        f.Q = np.zeros((4, 4))
        f.R = np.eye(2) * 0.1
    fleet = Fleet.from_filters(singles, on_error="raise")
    assert fleet.Q.shape == (4, 4) and not fleet.Q.any() and fleet.R.shape == (2, 2)
    assert fleet.on_error == "raise"
    np.testing.assert_array_equal(Fleet.from_filters(singles[:1])[0].x, singles[0].x)


def test_from_filters_rejects_mixed_configurations():
    def single(**kw):
        args = {
            "points": MerweScaledWeights(),
            "scheme": "redrawn",
            "fx": cv_fx_stacked,
            "hx": range_bearing_hx,
            "dt": FLEET_DT,
        }
        args |= kw
        return SquareRootUKF(
            FLEET_N_X,
            FLEET_N_Z,
            args["dt"],
            args["hx"],
            args["fx"],
            args["points"],
            scheme=args["scheme"],
            vectorized=True,
        )

    base = single()
    others = [
        single(points=JulierWeights()),
        single(points=MerweScaledWeights(alpha=0.5)),
        single(scheme="augmented"),
        single(scheme=Augmented(weights=JulierWeights(kappa=0.0))),
        single(fx=turn_fx_stacked),
        single(hx=xy_radar_hx_stacked),
        single(dt=0.25),
        SquareRootUKF(
            FLEET_N_X, 1, FLEET_DT, range_bearing_hx, cv_fx_stacked, MerweScaledWeights(), vectorized=True
        ),
        SquareRootUKF(
            FLEET_N_X,
            FLEET_N_Z,
            FLEET_DT,
            range_bearing_hx,
            cv_fx_stacked,
            MerweScaledWeights(),
            residual_z=AngleResidual([1]),
            vectorized=True,
        ),
    ]
    for other in others:
        with pytest.raises(ParameterError):
            Fleet.from_filters([base, other])
    with pytest.raises(ParameterError):
        Fleet.from_filters(
            [
                SquareRootUKF(
                    FLEET_N_X, FLEET_N_Z, FLEET_DT, range_bearing_hx, cv_fx_stacked, MerweScaledWeights()
                )
            ]
        )
    with pytest.raises(ParameterError):
        Fleet.from_filters(
            [
                base,
                SquareRootUKF(
                    FLEET_N_X, FLEET_N_Z, FLEET_DT, range_bearing_hx, cv_fx_stacked, MerweScaledWeights()
                ),
            ]
        )
    with pytest.raises(ParameterError):
        Fleet.from_filters([])
    assert Fleet.from_filters([base, single()]).n_filters == 2

    # hooks: squkf's angle hooks of the same components are one configuration, others are not
    def hooked(**kw):
        return SquareRootUKF(
            FLEET_N_X,
            FLEET_N_Z,
            FLEET_DT,
            range_bearing_hx,
            cv_fx_stacked,
            MerweScaledWeights(),
            vectorized=True,
            **kw,
        )

    fs = [hooked(z_mean_fn=AngleMean([1]), residual_z=AngleResidual([1])) for _ in range(2)]
    assert Fleet.from_filters(fs).n_filters == 2
    with pytest.raises(ParameterError):
        Fleet.from_filters([fs[0], hooked(z_mean_fn=AngleMean([0]), residual_z=AngleResidual([1]))])
    with pytest.raises(ParameterError):
        Fleet.from_filters([hooked(residual_z=lambda a, b: a - b), hooked(residual_z=lambda a, b: a - b)])
    a, b = single(scheme=Augmented(weights=JulierWeights(kappa=0.0))), single(scheme="augmented")
    with pytest.raises(ParameterError):
        Fleet.from_filters([a, b])
    assert Fleet.from_filters([a, single(scheme=Augmented(weights=JulierWeights(kappa=0.0)))]).n_filters == 2


def test_from_filters_validates_pending_edits_and_takes_points_objects_equal_by_value():
    from filterpy.kalman import MerweScaledSigmaPoints

    f = cv_single(MerweScaledWeights())
    f.x[2] = np.nan  # an edit in place, pending: validated as an assignment would be
    with pytest.raises(NonFiniteError, match="x contains NaN"):
        Fleet.from_filters([cv_single(MerweScaledWeights()), f])
    f = cv_single(MerweScaledWeights())
    f.P[0, 1] = 5.0  # not symmetric
    with pytest.raises(SqukfError, match="not symmetric"):
        Fleet.from_filters([f])
    f = cv_single(MerweScaledWeights())
    f.P *= 4.0  # a valid edit is taken
    np.testing.assert_allclose(Fleet.from_filters([f]).P[0], 4.0 * np.eye(FLEET_N_X))
    # filterpy's points objects compare by identity: two built alike are one configuration
    fs = [cv_single(MerweScaledSigmaPoints(FLEET_N_X, 0.5, 2.0, 0.0)) for _ in range(2)]
    assert Fleet.from_filters(fs).n_filters == 2
    with pytest.raises(ParameterError, match="differs in configuration"):
        Fleet.from_filters([fs[0], cv_single(MerweScaledSigmaPoints(FLEET_N_X, 0.4, 2.0, 0.0))])


NOT_FILTERS = [
    pytest.param(None, r"^filters must be a sequence of squkf\.SquareRootUKF, got filters=None", id="None"),
    pytest.param(5, r"^filters must be a sequence of squkf\.SquareRootUKF, got filters=5", id="int"),
    pytest.param("ab", r"^filters must be a sequence", id="str"),
    pytest.param({0: "a"}, r"^filters must be a sequence", id="dict"),
    pytest.param([], r"^filters is empty", id="empty"),
    pytest.param(iter([]), r"^filters is empty", id="empty iterator"),
    pytest.param([None], r"^filters\[0\] is not a squkf\.SquareRootUKF: got None", id="[None]"),
    pytest.param(["x"], r"^filters\[0\] is not a squkf\.SquareRootUKF: got 'x'", id="['x']"),
    pytest.param("one and x", r"^filters\[1\] is not a squkf\.SquareRootUKF: got 'x'", id="[ukf, 'x']"),
]


@pytest.mark.parametrize("filters, match", NOT_FILTERS)
def test_from_filters_refuses_what_is_not_a_sequence_of_square_root_ukfs_naming_filters(filters, match):
    if filters == "one and x":
        filters = [cv_single(MerweScaledWeights()), "x"]
    with pytest.raises(ParameterError, match=match):
        Fleet.from_filters(filters)


def test_from_filters_given_filterpys_ukf_says_how_to_build_a_square_root_ukf_from_it():
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    points = MerweScaledSigmaPoints(FLEET_N_X, 0.5, 2.0, 0.0)
    theirs = UnscentedKalmanFilter(FLEET_N_X, FLEET_N_Z, FLEET_DT, range_bearing_hx, cv_fx_stacked, points)
    theirs.x, theirs.P = np.array([10.0, 1.0, 5.0, 0.5]), FLEET_P0
    ours = cv_single(MerweScaledWeights())
    for filters, k in (([theirs], 0), ([ours, theirs], 1)):
        with pytest.raises(
            ParameterError,
            match=rf"^filters\[{k}\] is filterpy's UnscentedKalmanFilter, not a squkf\.SquareRootUKF: build"
            r" each as squkf\.SquareRootUKF with the same arguments .* and vectorized=True, and give it"
            r" the filterpy filter's x, P, Q and R",
        ):
            Fleet.from_filters(filters)
    # what the message says, done
    g = SquareRootUKF(
        FLEET_N_X, FLEET_N_Z, FLEET_DT, range_bearing_hx, cv_fx_stacked, points, vectorized=True
    )
    g.x, g.P, g.Q, g.R = theirs.x, theirs.P, theirs.Q, theirs.R
    fleet = Fleet.from_filters([g])
    np.testing.assert_array_equal(fleet.x[0], theirs.x)
    np.testing.assert_allclose(fleet.P[0], theirs.P, rtol=1e-15)


@pytest.mark.parametrize("scheme", SCHEMES)
def test_one_filter_out_or_filters_in_between_predict_and_update_keep_the_step_or_raise(scheme):
    fleet, singles, zs = fleet_and_singles(3, "merwe", scheme)
    fleet.predict()
    for f in singles:
        f.predict()
    if scheme == "redrawn":  # the second set is the prior's alone: the copies take the same update
        ref = copy.copy(fleet)
        ref.update(zs[:, 0])
        one = fleet[1]
        one.update(zs[1, 0])
        np.testing.assert_array_equal(one.x, ref.x[1])
        back = Fleet.from_filters(singles)
        back.update(zs[:, 0])
        singles[1].update(zs[1, 0])
        np.testing.assert_array_equal(back.x[1], singles[1].x)
    else:  # the pending second set reads the propagated points, which a copy cannot carry
        with pytest.raises(CallSequenceError, match=r"fleet\[1\]: the step is pending"):
            fleet[1]
        with pytest.raises(CallSequenceError, match=r"filters\[0\]: the step is pending"):
            Fleet.from_filters(singles)
    fleet.ask_predict()  # points handed out and not told: refused whatever the scheme
    with pytest.raises(CallSequenceError, match=r"fleet\[0\]: the step is pending \(an ask"):
        fleet[0]


# -- batch_filter ---------------------------------------------------------------------------------


@pytest.mark.parametrize("scheme", SCHEMES)
def test_batch_filter_equals_loop_and_singles(scheme):
    K, T = 3, 7
    fleet, singles, zs = fleet_batch_setup(K, T, scheme)
    loop = copy.deepcopy(fleet)
    res = fleet.batch_filter(zs)
    assert isinstance(res, FleetResult)
    assert res.means.shape == (K, T, 4) and res.P1_2s.shape == (K, T, 4, 4)
    assert res.variances.shape == (K, T, 4) and res.log_likelihood.shape == (K, T)
    assert res.failed.shape == (K,) and not res.failed.any()
    lls = np.zeros((K, T))
    for t in range(T):
        loop.predict()
        loop.update(zs[:, t])
        np.testing.assert_array_equal(res.means[:, t], loop.x)
        np.testing.assert_array_equal(res.P1_2s[:, t], loop.P1_2)
        np.testing.assert_allclose(res.variances[:, t], np.diagonal(loop.P, axis1=1, axis2=2), rtol=1e-13)
        lls[:, t] = loop.log_likelihood
    np.testing.assert_array_equal(res.log_likelihood, lls)
    np.testing.assert_array_equal(res.x, loop.x)
    np.testing.assert_array_equal(res.P1_2, loop.P1_2)
    # the fleet is left as after the loop
    assert_fleet_state(fleet, fleet_state(loop))
    for k, f in enumerate(singles):
        means, factors = f.batch_filter(list(zs[k]), return_factors=True)
        assert_close(res.means[k], means, f"means[{k}]")
        assert_close(res.P1_2s[k], factors, f"P1_2s[{k}]")


def test_batch_filter_leaves_the_records_of_a_loop_when_the_last_step_has_no_measurement():
    fleet, _, zs = fleet_batch_setup(3, 5)
    zs[:, -1] = np.nan
    loop = copy.deepcopy(fleet)
    fleet.batch_filter(zs)
    for t in range(5):
        loop.predict()
        loop.update(zs[:, t])
    assert_fleet_state(fleet, fleet_state(loop))
    assert not fleet.log_likelihood.any() and np.isnan(fleet.y).all()


def test_batch_filter_keep():
    fleet, _, zs = fleet_batch_setup()
    full = copy.deepcopy(fleet).batch_filter(zs)
    for keep, present in [
        ("diagonals", ("means", "variances")),
        ("means", ("means",)),
        ("final", ()),
    ]:
        res = copy.deepcopy(fleet).batch_filter(zs, keep=keep)
        for field in ("means", "P1_2s", "variances"):
            if field in present:
                np.testing.assert_array_equal(getattr(res, field), getattr(full, field))
            else:
                assert getattr(res, field) is None, (keep, field)
        for field in ("failed", "x", "P1_2"):
            np.testing.assert_array_equal(getattr(res, field), getattr(full, field))
        if keep == "final":  # the run's total per filter, in the order the steps added it
            total = np.zeros(full.log_likelihood.shape[0])
            for t in range(full.log_likelihood.shape[1]):
                total += full.log_likelihood[:, t]
            np.testing.assert_array_equal(res.log_likelihood, total)
        else:
            np.testing.assert_array_equal(res.log_likelihood, full.log_likelihood)


def test_batch_filter_dts_args_and_failures():
    K, T = 4, 5
    fleet, _, zs = fleet_batch_setup(K, T)
    loop = copy.deepcopy(fleet)
    dts = np.array([0.5, 0.25, 0.5, 1.0, 0.5])
    bad = np.array([False, False, True, False])
    scale = np.array([1.0, 1.0, 1.0, 1.02])
    res = fleet.batch_filter(zs, dts=dts, fx_args={"bad": bad}, hx_args={"scale": scale})
    for t in range(T):
        loop.predict(dts[t], bad=bad)
        loop.update(zs[:, t], scale=scale)
        np.testing.assert_array_equal(res.means[:, t], loop.x)
    np.testing.assert_array_equal(res.failed, bad)
    # the failed filter's later entries repeat its last good state (here: the initial one)
    np.testing.assert_array_equal(res.means[2], np.broadcast_to(res.means[2, 0], (T, 4)))
    assert not res.log_likelihood[2].any()
    # a scalar dt for every step
    a, b = copy.deepcopy(loop), copy.deepcopy(loop)
    a.reset()
    b.reset()
    ra = a.batch_filter(zs, dts=0.3)
    rb = b.batch_filter(zs, dts=[0.3] * T)
    np.testing.assert_array_equal(ra.means, rb.means)


# -- ask / tell, copies, pickles ------------------------------------------------------------------


@pytest.mark.parametrize("scheme", SCHEMES)
def test_ask_tell_equals_predict_update(scheme):
    K = 3
    fleet, _, zs = fleet_and_singles(K, "merwe", scheme)
    ref = copy.deepcopy(fleet)
    N = 2 * FLEET_N_X + 1
    for t in range(3):
        X = fleet.ask_predict()
        assert X.shape == (K, N, FLEET_N_X)
        X[:] = 0.0  # a fresh array: the fleet's points are not changed through it
        X = fleet.ask_predict()
        fleet.tell_predict(cv_fx_stacked(X, FLEET_DT))
        X2 = fleet.ask_update()
        n2 = 4 * FLEET_N_X + 1 if scheme == "augmented" else N
        assert X2.shape == (K, n2, FLEET_N_X)
        fleet.tell_update(range_bearing_hx(X2), zs[:, t])
        ref.predict()
        ref.update(zs[:, t])
        assert_fleet_state(fleet, fleet_state(ref))
    with pytest.raises(CallSequenceError):
        fleet.tell_predict(np.zeros((K, N, FLEET_N_X)))
    fleet.ask_predict()
    with pytest.raises(CallSequenceError):
        fleet.ask_update()


def test_ask_update_without_prediction_redraws():
    fleet, singles, zs = fleet_and_singles(2, "merwe", "propagated")
    X = fleet.ask_update()
    fleet.tell_update(range_bearing_hx(X), zs[:, 0], R=np.eye(2) * 0.1)
    for k, f in enumerate(singles):
        f.update(zs[k, 0], R=np.eye(2) * 0.1)
        assert_close(fleet.x[k], f.x, "x")
        assert_close(fleet.P1_2[k], f.P1_2, "P1_2")


def advance(fleet, zs, t):
    fleet.predict()
    fleet.update(zs[:, t])


@pytest.mark.parametrize("how", ["pickle", "copy", "deepcopy"])
@pytest.mark.parametrize("phase", ["idle", "asked-predict", "told-predict", "asked-update"])
def test_copies_are_independent(how, phase):
    K = 3
    fleet, _, zs = fleet_and_singles(K, "merwe", "augmented")
    fleet.predict(bad=np.array([False, True, False]))  # with a flagged filter
    fleet.update(zs[:, 0])
    if phase != "idle":
        X = fleet.ask_predict()
        if phase != "asked-predict":
            fleet.tell_predict(cv_fx_stacked(X, FLEET_DT))
            if phase == "asked-update":
                fleet.ask_update()
    clone = {"pickle": lambda f: pickle.loads(pickle.dumps(f)), "copy": copy.copy, "deepcopy": copy.deepcopy}[
        how
    ](fleet)
    assert_fleet_state(clone, fleet_state(fleet))

    def finish(f):
        if phase == "asked-predict":
            f.tell_predict(cv_fx_stacked(f._engine.X, FLEET_DT))
        if phase in ("asked-predict", "told-predict"):
            f.ask_update()
        if phase != "idle":
            f.tell_update(range_bearing_hx(f._engine.sset.sigmas), zs[:, 1])

    finish(fleet)
    finish(clone)
    assert_fleet_state(clone, fleet_state(fleet))
    # changing one leaves the other alone
    snap = fleet_state(clone)
    fleet.x = np.zeros(4)
    fleet.R = np.eye(2)
    fleet.reset()
    advance(fleet, zs, 2)
    assert_fleet_state(clone, snap)
    assert clone.failed[1] and not fleet.failed[1]
    advance(clone, zs, 2)
    assert np.abs(clone.x - fleet.x).max() > 1e-3


@pytest.mark.parametrize("per_filter", [False, True])
def test_a_pickle_with_bare_noise_factors_loads(per_filter):
    """A fleet pickled when it kept its noise factors bare (``_Q1_2``, ``_R1_2``) loads with its noise,
    and steps as the fleet it was pickled from."""
    K = 3
    fleet, _, zs = fleet_and_singles(K, "merwe", "propagated")
    if per_filter:
        fleet.Q = np.stack([0.01 * (k + 1) * np.eye(FLEET_N_X) for k in range(K)])
    fleet.R = np.diag([4.0, 1e-4])
    advance(fleet, zs, 0)
    state = fleet.__getstate__()
    Q, R = state.pop("_Q"), state.pop("_R")
    state["_Q1_2"], state["_R1_2"] = Q.S, R.S
    old = squkf.Fleet.__new__(squkf.Fleet)
    old.__setstate__(state)
    assert np.array_equal(old.Q1_2, fleet.Q1_2) and np.array_equal(old.R1_2, fleet.R1_2)
    assert np.array_equal(old.Q, fleet.Q) and np.array_equal(old.R, fleet.R)
    old.Q = fleet.Q  # assignable as before
    for f in (fleet, old):
        advance(f, zs, 1)
    assert_fleet_state(old, fleet_state(fleet))


def test_a_pickle_from_before_the_engine_loads():
    """A fleet pickled before it held an engine (its state and records in its ``__dict__``, its failures
    a ``(K,)`` array of reasons, the points a plain attribute, no placeholders) loads idle with its state,
    records and failures, and steps as the fleet it was pickled from."""
    K = 3
    fleet, _, zs = fleet_and_singles(K, "merwe", "propagated")
    advance(fleet, zs, 0)
    fleet.x = fleet.x + np.array([[0.0], [np.nan], [0.0]])  # filter 1 flagged by the next step
    advance(fleet, zs, 1)
    state = copy.deepcopy(fleet).__getstate__()
    e, failure = state.pop("_engine"), fleet.failure
    last = e.last
    state.update(
        _x=e.x, _S=e.S, _x_prior=e.prior_record[0], _S_prior=e.prior_record[1], _x_post=e.post_record[0],
        _S_post=e.post_record[1], _y=last.y, _loglik=last.log_likelihood, _nis=last.nis,
        _rejected=last.rejected, _y_whitened=None, _log_det=None, _failure=failure,
        points_fn=state.pop("_points"),
    )  # fmt: skip
    for name in ("_unset_x", "_unset_P", "_vectorized_hooks"):
        del state[name]
    old = squkf.Fleet.__new__(squkf.Fleet)
    old.__setstate__(state)
    for name in ("x", "P1_2", "x_prior", "P1_2_post", "y", "nis", "log_likelihood", "failed", "failure"):
        np.testing.assert_array_equal(getattr(old, name), getattr(fleet, name), err_msg=name)
    assert np.isnan(old.y_whitened).all() and not old.log_det_S1_2.any()  # (pickled before the record)
    assert old.points_fn is fleet.points_fn
    for f in (fleet, old):
        advance(f, zs, 2)
    assert_fleet_state(old, fleet_state(fleet))


def test_noise_is_shared_or_per_filter():
    """``Q`` and ``R`` are one matrix for all or one per filter; their factors read back as assigned, a zero
    ``Q`` as zeros, and an edit in place is taken at the next step."""
    K = 3
    fleet, _, zs = fleet_and_singles(K, "merwe", "propagated")
    fleet.Q = 0
    assert np.array_equal(fleet.Q1_2, np.zeros((FLEET_N_X, FLEET_N_X)))
    Rs = np.stack([np.diag([1.0 + k, 1e-4]) for k in range(K)])
    fleet.R = Rs
    assert fleet.R.shape == (K, 2, 2) and fleet.R1_2.shape == (K, 2, 2)
    assert np.allclose(fleet.R, Rs)
    sub = fleet.subset([2, 0])
    assert np.array_equal(sub.R1_2, fleet.R1_2[[2, 0]])
    fleet.R1_2 = np.diag([2.0, 0.01])
    assert fleet.R1_2.shape == (2, 2)
    fleet.R[1, 1] = 4e-4  # in place: taken by the next read
    assert np.isclose(fleet.R1_2[1, 1], 0.02)
    with pytest.raises(ShapeError):
        fleet.Q1_2 = np.eye(FLEET_N_X + 1)
    assert np.array_equal(fleet.Q1_2, np.zeros((FLEET_N_X, FLEET_N_X)))  # a failed assignment changes nothing


def test_ask_tell_values_may_be_edited_by_the_caller():
    """The arrays handed out and told are the caller's: editing them later changes nothing."""
    fleet, _, zs = fleet_and_singles(2, "merwe", "propagated")
    ref = copy.deepcopy(fleet)
    X = fleet.ask_predict()
    F = cv_fx_stacked(X, FLEET_DT)
    fleet.tell_predict(F)
    F[:] = np.nan
    X2 = fleet.ask_update()
    H = range_bearing_hx(X2)
    z = zs[:, 0].copy()
    fleet.tell_update(H, z)
    H[:] = 0.0
    z[:] = 0.0
    ref.predict()
    ref.update(zs[:, 0])
    assert_fleet_state(fleet, fleet_state(ref))


@pytest.mark.parametrize("block", [2, 3, 5])
@pytest.mark.parametrize("scheme", SCHEMES)
def test_chunks_and_blocks_of_the_core_change_no_bit(monkeypatch, block, scheme):
    """A step runs a chunk of filters at a time (``chunk``), its core a block (chunks.BLOCK): same bits."""
    fleet, _, zs = fleet_batch_setup(K=11, T=6, scheme=scheme)
    whole = copy.deepcopy(fleet).batch_filter(zs)
    monkeypatch.setattr(squkf.stacks, "BLOCK", block)
    cut = copy.deepcopy(fleet)
    cut.chunk = block + 1
    blocked = cut.batch_filter(zs)
    for field in ("means", "P1_2s", "log_likelihood", "x", "P1_2"):
        assert np.array_equal(getattr(blocked, field), getattr(whole, field)), field


def test_batch_filter_takes_an_iterator_of_steps_and_reports_progress(capsys):
    fleet, _, zs = fleet_batch_setup(K=4, T=6)
    whole = copy.deepcopy(fleet).batch_filter(zs)
    seen = []
    steps = copy.deepcopy(fleet).batch_filter((zs[:, t] for t in range(zs.shape[1])), progress=seen.append)
    assert seen == list(range(zs.shape[1]))
    for field in ("means", "P1_2s", "log_likelihood", "x", "P1_2"):
        assert np.array_equal(getattr(steps, field), getattr(whole, field)), field
    tqdm = pytest.importorskip("tqdm")
    barred = copy.deepcopy(fleet).batch_filter(tqdm.tqdm(list(zs.transpose(1, 0, 2))), progress=True)
    assert np.array_equal(barred.means, whole.means)
    assert "6/6" in capsys.readouterr().err
    with pytest.raises(ParameterError):
        copy.deepcopy(fleet).batch_filter(zs, progress="yes")


def test_a_fleets_points_are_fixed_and_assigning_them_changes_nothing():
    """A fleet's configuration is fixed at construction: a new points object is refused by name (it used to
    be kept as an attribute while the step went on with the old points)."""
    fleet, zs = cv_fleet_and_measurements(3, 1)
    before = fleet_state(fleet)
    with pytest.raises(ParameterError, match="points_fn"):
        fleet.points_fn = SimplexWeights()
    assert isinstance(fleet.points_fn, MerweScaledWeights)
    assert_fleet_state(fleet, before)
    assert fleet.ask_predict().shape == (3, 9, FLEET_N_X)  # Merwe's 2n + 1 points, as built


@pytest.mark.parametrize(("scheme", "with_Q", "points"), [
    ("redrawn", True, 9),
    ("augmented", True, 9 + 8),  # the propagated points and Q's
    ("augmented", False, 9),  # no process noise: the propagated points alone
])  # fmt: skip
def test_a_chunks_size_counts_the_second_sets_points(scheme, with_Q, points):
    """The update's chunk is sized on its second set's points as the step draws it."""
    from squkf.generators import as_generator
    from squkf.plan import build_plan
    from squkf.weights import as_family

    plan = build_plan(as_family(MerweScaledWeights()), as_generator(scheme), FLEET_N_X)
    assert squkf.stacks._second_size(plan, np.eye(FLEET_N_X) if with_Q else None) == points


def nested_run(outer: str, inner: str, where: str, threads: int, played: bool) -> tuple:
    """The outer filter's estimate after its steps, the inner filters stepped inside its ``fx`` or ``hx``
    (or, ``played``, their results recorded outside first)."""
    f, zs, args, steps = nested_filters(outer, inner, where)
    if played:
        steps.record()
    squkf.set_num_threads(threads)
    try:
        for z in zs:
            f.predict(**args)
            f.update(z, **args)
    finally:
        squkf.set_num_threads(1)
    return f.x.copy(), f.P.copy(), f.x_prior.copy(), f.log_likelihood


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("where", ["fx", "hx"])
@pytest.mark.parametrize("inner", ["fleet", "copy"])
def test_a_fleet_stepped_inside_a_fleets_model_function_is_as_if_stepped_outside(inner, where, threads):
    """A fleet stepping another (of the same dim_x and chunk size, or a copy of itself) from its ``fx`` or
    ``hx``, on the same thread, has the numbers it has with the inner fleet's results recorded outside
    (issue 35: the two shared one per-thread scratch area, 6.35 off in fx, 0.45 in hx). On two threads
    the outer's chunks run on the pool's threads, each stepping its own inner fleet there."""
    nested = nested_run("fleet", inner, where, threads, played=False)
    outside = nested_run("fleet", inner, where, threads, played=True)
    for a, b in zip(nested, outside):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("where", ["fx", "hx"])
@pytest.mark.parametrize(("outer", "inner"), [
    ("single", "single"), ("single", "copy"), ("single", "fleet"), ("fleet", "single"),
])  # fmt: skip
def test_a_single_filter_nested_or_nesting_is_as_if_stepped_outside(outer, inner, where):
    """A ``SquareRootUKF`` stepping another (or its copy, or a fleet) inside its ``fx`` or ``hx``, and a
    fleet stepping a ``SquareRootUKF``, have the numbers of the inner filter stepped outside, bit for bit:
    a filter's buffers are its own."""
    nested = nested_run(outer, inner, where, 1, played=False)
    outside = nested_run(outer, inner, where, 1, played=True)
    for a, b in zip(nested, outside):
        np.testing.assert_array_equal(a, b)
