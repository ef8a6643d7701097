"""Outlier gating (``gate=``): decisions against an independent chi-square test, and its records.

The reference is filterpy's UKF with the same points, gated by hand from its
own innovation covariance ``S`` (``y^T S^-1 y`` by ``np.linalg.solve``).
The two filters follow the same path as long as every decision agrees, so
the states are compared to the agreement of the two filters without a gate
(1e-9 relative: the same arithmetic in another order, on a nonlinear model).
"""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
from filterpy.common import Saver
from hypothesis import given, settings
from hypothesis import strategies as st
from models import (
    radar_filterpy,
    radar_fleet,
    radar_squkf,
    radar_track,
    range_bearing_heading_hx,
    range_bearing_hx,
    rbh_filter,
)
from scipy.stats import chi2

import squkf
from squkf import Fleet, Gate, ParameterError
from squkf.angles import wrap
from squkf.batch import BatchResult

# the paths here end in documented errors or decisions: no numpy RuntimeWarning may escape squkf
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")


def filterpy_gated_step(ref, z, probability, per_component):
    """One step of filterpy's UKF with a hand-rolled gate; returns the rejected mask and the NIS."""
    ref.predict()
    # filterpy's own innovation covariance and innovation for this z, before deciding
    sigmas_h = np.array([range_bearing_hx(s) for s in ref.sigmas_f])
    from filterpy.kalman import unscented_transform

    zp, S = unscented_transform(sigmas_h, ref.Wm, ref.Wc, ref.R)
    y = z - zp
    nis = float(y @ np.linalg.solve(S, y))
    if per_component:
        stat = y**2 / np.diag(S)
        rejected = stat > chi2.ppf(probability, 1)
        margin = np.min(np.abs(stat - chi2.ppf(probability, 1)))
    else:
        rejected = np.full(2, nis > chi2.ppf(probability, 2))
        margin = abs(nis - chi2.ppf(probability, 2))
    keep = ~rejected
    if keep.all():
        ref.update(z)
    elif keep.any():
        R = ref.R
        ref.update(z[keep], R=R[np.ix_(keep, keep)], hx=lambda x: range_bearing_hx(x)[keep])
        ref.R = R
    else:
        ref.update(None)
    return rejected, nis, margin


@pytest.mark.parametrize("per_component", [False, True], ids=["whole", "per-component"])
def test_decisions_equal_a_chi_square_test_on_filterpys_S(per_component):
    p = 0.99
    _, zs = radar_track(120, seed=3, wild=0.1)
    ref = radar_filterpy()
    ukf = radar_squkf(Gate(p, per_component=per_component))
    decisions = []
    for z in zs:
        rejected, nis, margin = filterpy_gated_step(ref, z, p, per_component)
        # a decision this close to the threshold could go either way by rounding alone
        assert margin > 1e-6
        ukf.predict()
        ukf.update(z)
        np.testing.assert_array_equal(ukf.rejected, rejected)
        assert ukf.nis == pytest.approx(nis, rel=1e-9)
        np.testing.assert_allclose(ukf.x, ref.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(ukf.P, ref.P, rtol=1e-8, atol=1e-12)
        decisions.append(rejected)
    decisions = np.array(decisions)
    # the run exercises the gate: some steps rejected, most accepted (and, per component, mixed steps)
    assert 3 <= decisions.any(axis=1).sum() <= 40
    if per_component:
        assert (decisions.any(axis=1) & ~decisions.all(axis=1)).any()


def test_rejected_measurement_is_a_missing_one():
    _, zs = radar_track(40, seed=5, wild=0.0)
    gated, plain = radar_squkf(Gate(nis=1e-12)), radar_squkf(None)  # this gate rejects everything
    for z in zs[:5]:
        gated.predict()
        plain.predict()
        x_prior, P_prior = gated.x.copy(), gated.P.copy()
        gated.update(z)
        plain.update(z)
        assert gated.rejected.all()
        np.testing.assert_array_equal(gated.x, x_prior)
        np.testing.assert_array_equal(gated.P, P_prior)
        assert gated.log_likelihood == 0.0 and gated.likelihood == 1.0
        np.testing.assert_array_equal(gated.K, np.zeros((4, 2)))
        # what the gate tested is reported: the innovation and its covariance, as without a gate
        np.testing.assert_array_equal(gated.y, plain.y)
        np.testing.assert_array_equal(gated.S, plain.S)
        assert gated.nis == plain.nis == pytest.approx(gated.mahalanobis**2, rel=1e-15)
        plain.x, plain.P = gated.x, gated.P  # follow the gated filter


def test_component_rejection_updates_with_the_rest_as_a_partial_measurement():
    _, zs = radar_track(10, seed=7, wild=0.0)
    gated = radar_squkf(Gate(0.999, per_component=True))
    partial = radar_squkf(None)
    for k, z in enumerate(zs):
        wild = z.copy()
        if k % 2:
            wild[1] += 3.0  # a bearing far off: rejected alone
        gated.predict()
        partial.predict()
        gated.update(wild)
        partial.update(np.where([False, k % 2 == 1], np.nan, wild))
        np.testing.assert_array_equal(gated.rejected, [False, k % 2 == 1])
        np.testing.assert_array_equal(gated.x, partial.x)
        np.testing.assert_array_equal(gated.P1_2, partial.P1_2)
        assert gated.log_likelihood == partial.log_likelihood
        np.testing.assert_array_equal(gated.K, partial.K)


def test_gate_sees_only_the_measured_components():
    """A NaN component is missing before gating: the chi-square threshold has one degree of freedom."""
    ref = radar_squkf(None)
    ref.predict()
    zp = range_bearing_hx(ref.x)
    ref.update(np.array([zp[0] + 1.0, np.nan]))
    # an offset whose NIS lies between the 0.99 quantiles for one and for two degrees of freedom
    d2 = 0.5 * (chi2.ppf(0.99, 1) + chi2.ppf(0.99, 2))
    z_pred = zp[0] + 1.0 - ref.y[0]  # the transform's predicted range
    z = np.array([z_pred + math.sqrt(d2 * ref.S[0, 0]), np.nan])
    ukf = radar_squkf(0.99)
    ukf.predict()
    ukf.update(z)
    assert ukf.nis == pytest.approx(d2, rel=1e-6)
    np.testing.assert_array_equal(ukf.rejected, [True, False])
    np.testing.assert_array_equal(ukf.x, ukf.x_prior)


@pytest.mark.parametrize("gate", [Gate(0.99), Gate(0.995, per_component=True), Gate(nis=9.0)], ids=repr)
def test_fleet_filter_equals_its_single_filter_bit_for_bit(gate):
    K, T = 12, 40
    zs = np.stack([radar_track(T, seed=100 + k, wild=0.15)[1] for k in range(K)])
    zs[2, 5] = np.nan  # missing measurements and components mix with the gate's decisions
    zs[4, 7, 1] = np.nan
    fleet = radar_fleet(K, gate, per_filter_R=True)
    singles = [fleet[k] for k in range(K)]
    result = fleet.batch_filter(zs)
    assert result.rejected.shape == (K, T, 2) and result.nis.shape == (K, T)
    assert result.rejected.any()
    for k, f in enumerate(singles):
        out = f.batch_filter(zs[k])
        np.testing.assert_array_equal(out[0], result.means[k])
        np.testing.assert_array_equal(out.rejected, result.rejected[k])
        np.testing.assert_array_equal(out.nis, result.nis[k])
        np.testing.assert_array_equal(out.log_likelihood, result.log_likelihood[k])
    np.testing.assert_array_equal(fleet.rejected, result.rejected[:, -1])
    np.testing.assert_array_equal(fleet.nis, result.nis[:, -1])


def test_fleet_keep_final_counts_rejections():
    K, T = 6, 30
    zs = np.stack([radar_track(T, seed=200 + k, wild=0.2)[1] for k in range(K)])
    full = radar_fleet(K, 0.99).batch_filter(zs)
    final = radar_fleet(K, 0.99).batch_filter(zs, keep="final")
    np.testing.assert_array_equal(final.rejected, full.rejected.sum(axis=1))
    assert final.nis is None
    np.testing.assert_array_equal(final.x, full.x)


def test_gate_travels_with_the_filters():
    fleet = radar_fleet(3, Gate(0.9, per_component=True))
    assert fleet[1].gate == Gate(0.9, per_component=True)
    back = Fleet.from_filters([fleet[k] for k in range(3)])
    assert back.gate == fleet.gate
    mixed = [fleet[0], fleet[1]]
    mixed[1].gate = 0.5
    with pytest.raises(ParameterError, match="differs in configuration"):
        Fleet.from_filters(mixed)
    assert pickle.loads(pickle.dumps(fleet.gate)) == fleet.gate
    assert fleet.subset([0, 2]).gate == fleet.gate


def test_batch_result_is_filterpys_pair():
    _, zs = radar_track(20, seed=9, wild=0.2)
    zs = list(zs)
    zs[3] = None
    ukf = radar_squkf(0.99)
    saver = Saver(ukf)
    result = ukf.batch_filter(zs, saver=saver)
    means, covs = result
    assert isinstance(result, tuple) and len(result) == 2 and isinstance(result, BatchResult)
    assert means.shape == (20, 4) and covs.shape == (20, 4, 4)
    assert result.rejected.shape == (20, 2) and result.rejected.any()
    assert not result.rejected[3].any() and result.nis[3] == 0.0 and result.log_likelihood[3] == 0.0
    np.testing.assert_array_equal(np.array(saver["rejected"]), result.rejected)
    back = pickle.loads(pickle.dumps(result))
    np.testing.assert_array_equal(back.rejected, result.rejected)
    np.testing.assert_array_equal(back[0], means)
    # the record is the caller's: reading it twice gives two arrays
    assert ukf.rejected is not ukf.rejected


BAD_GATES = [
    (0.0, "open interval"),
    (1.0, "open interval"),
    (1.5, r"Gate\(nis=1.5\)"),
    (16, r"Gate\(nis=16\)"),
    (-0.1, "open interval"),
    (float("nan"), "open interval"),
    ("0.99", "gate must be"),
    (True, "gate must be"),
    ([0.9], "gate must be"),
]


@pytest.mark.parametrize("value, message", BAD_GATES, ids=[repr(v) for v, _ in BAD_GATES])
@pytest.mark.parametrize("front", ["ukf", "fleet", "assign"])
def test_bad_gate_is_a_parameter_error_naming_the_value(front, value, message):
    with pytest.raises(ParameterError, match=message) as info:
        if front == "ukf":
            radar_squkf(value)
        elif front == "fleet":
            radar_fleet(2, value)
        else:
            f = radar_squkf(0.9)
            try:
                f.gate = value
            finally:
                assert f.gate == Gate(0.9)  # a refused assignment changes nothing
    assert "gate" in str(info.value)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({}, "exactly one threshold"),
        ({"probability": 0.9, "nis": 3.0}, "exactly one threshold"),
        ({"nis": 0.0}, "positive finite"),
        ({"nis": float("inf")}, "positive finite"),
        ({"nis": -2.0}, "positive finite"),
        ({"nis": "3"}, "real number"),
        ({"probability": 2.0}, "open interval"),
        ({"probability": 0.9, "per_component": "yes"}, "per_component"),
    ],
    ids=lambda v: repr(v),
)
def test_bad_gate_object(kwargs, message):
    with pytest.raises(ParameterError, match=message):
        Gate(**kwargs)


def test_gate_is_read_only():
    gate = Gate(0.9)
    with pytest.raises(AttributeError):
        gate.probability = 5.0  # type: ignore[misc]
    assert squkf.Gate is Gate


@settings(max_examples=60, deadline=None)
@given(
    st.integers(1, 4),
    st.integers(0, 2**32 - 1),
    st.floats(0.05, 0.9999),
)
def test_whole_gate_decides_by_the_nis(m, seed, probability):
    """Gate.reject on (y, Sy) equals the chi-square test on y^T (Sy Sy^T)^-1 y by a dense solve."""
    rng = np.random.default_rng(seed)
    Sy = np.tril(rng.normal(size=(m, m))) + 3 * np.eye(m)
    y = rng.normal(size=m) * rng.choice([0.5, 2.0, 5.0])
    nis = float(y @ np.linalg.solve(Sy @ Sy.T, y))
    limit = chi2.ppf(probability, m)
    if abs(nis - limit) < 1e-9 * max(1.0, limit):
        return  # too close to call by rounding alone
    got = Gate(probability).reject(y, Sy, np.array(nis))
    np.testing.assert_array_equal(got, np.full(m, nis > limit))
    per = Gate(probability, per_component=True).reject(y, Sy, np.array(nis))
    np.testing.assert_array_equal(per, y**2 / np.diag(Sy @ Sy.T) > chi2.ppf(probability, 1))


@pytest.mark.parametrize("keep", ["all", "final"])
def test_dask_gives_the_fleets_gate_records(keep):
    da = pytest.importorskip("dask.array")
    import squkf.dask as sd

    K, T = 10, 25
    zs = np.stack([radar_track(T, seed=300 + k, wild=0.2)[1] for k in range(K)])
    want = radar_fleet(K, Gate(0.99, per_component=True)).batch_filter(zs, keep=keep)
    lazy = sd.batch_filter(
        radar_fleet(K, Gate(0.99, per_component=True)), da.from_array(zs, chunks=(3, T, 2)), keep=keep
    )
    got = sd.compute(lazy, scheduler="synchronous")
    np.testing.assert_array_equal(got.rejected, want.rejected)
    assert got.rejected.dtype == want.rejected.dtype
    if keep == "all":
        np.testing.assert_array_equal(got.nis, want.nis)
    else:
        assert got.nis is None
    np.testing.assert_array_equal(got.x, want.x)


# == hooks see the whole z through a gate (issue 29, item 5) ======================================


def test_a_rejected_range_leaves_the_bearings_hook_at_its_index():
    """Per-component gating drops a wild range of a [range, bearing, heading] sensor; the bearing,
    still index 1 for ``AngleResidual([1])``, is wrapped: the update equals the sensor without the
    range (its hooks at index 0) fed the bearing and the heading (1e-12: another arithmetic order).
    """
    gated, oracle = rbh_filter(Gate(nis=9.0, per_component=True)), rbh_filter(m=2)
    for _ in range(3):
        gated.predict()
        oracle.predict()
        z = range_bearing_heading_hx(gated.x) + np.array([60.0, 0.002, -0.004])  # a range far off
        z[1] = wrap(z[1])
        gated.update(z)
        oracle.update(z[1:])
        np.testing.assert_array_equal(gated.rejected, [True, False, False])
        np.testing.assert_allclose(gated.x, oracle.x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(gated.P, oracle.P, rtol=1e-10, atol=1e-14)


# == one record, one update (issue 29, item 6) =====================================================


def last_update_records(f) -> dict:
    return {
        name: np.array(getattr(f, name), dtype=float)
        for name in ("nis", "mahalanobis", "rejected", "y", "S", "log_likelihood", "likelihood")
    }


@pytest.mark.parametrize("nothing", [None, np.array([np.nan, np.nan])], ids=["None", "all-nan"])
def test_an_update_without_measurement_keeps_the_last_updates_records(nothing):
    """``nis``, ``rejected``, ``y``, ``S`` and the likelihoods all describe the last update, as filterpy
    keeps ``mahalanobis`` and the likelihoods after ``update(None)``."""
    _, zs = radar_track(3, seed=5, wild=0.0)
    f = radar_squkf(Gate(0.999, per_component=True))
    f.predict()
    wild = zs[0] + np.array([0.0, 3.0])  # the bearing rejected
    f.update(wild)
    assert f.rejected.tolist() == [False, True]
    before = last_update_records(f)
    f.predict()
    f.update(nothing)
    after = last_update_records(f)
    for name, value in before.items():
        np.testing.assert_array_equal(after[name], value, err_msg=name)
    # filterpy's own rule, for the record
    ref = radar_filterpy()
    ref.predict()
    ref.update(zs[0])
    kept = (ref.mahalanobis, ref.log_likelihood, ref.likelihood)
    ref.predict()
    ref.update(None)
    assert (ref.mahalanobis, ref.log_likelihood, ref.likelihood) == kept


def test_a_step_with_nothing_measured_records_nis_zero_and_nothing_rejected():
    """batch_filter's and a fleet's per-step records of a step with no measurement: NIS 0, none rejected."""
    _, zs = radar_track(4, seed=5, wild=0.0)
    zs = list(zs)
    zs[1] = zs[1] + np.array([0.0, 3.0])  # the bearing rejected at step 1
    zs[2] = None  # and nothing measured at step 2
    result = radar_squkf(Gate(0.999, per_component=True)).batch_filter(zs)
    assert result.rejected[1].tolist() == [False, True]
    assert result.rejected[2].tolist() == [False, False]
    assert result.nis[2] == 0.0 and result.log_likelihood[2] == 0.0
    # a fleet: filter 0 rejects a bearing, then has no measurement while filter 1 has one
    fleet = radar_fleet(2, Gate(0.999, per_component=True))
    fleet.predict()
    fleet.update(np.array([zs[1], zs[0]]))
    assert fleet.rejected[0].tolist() == [False, True]
    fleet.predict()
    fleet.update(np.array([[np.nan, np.nan], zs[3]]))
    assert fleet.rejected[0].tolist() == [False, False]
    assert fleet.nis[0] == 0.0 and fleet.log_likelihood[0] == 0.0 and fleet.nis[1] > 0.0
    run = radar_fleet(2, Gate(0.999, per_component=True)).batch_filter(
        np.array([[zs[0], zs[1], [np.nan, np.nan]], [zs[0], zs[0], zs[3]]])
    )
    assert run.rejected[0, 1].tolist() == [False, True]
    assert run.rejected[0, 2].tolist() == [False, False] and run.nis[0, 2] == 0.0
