"""Missing data: NaN, masked or ``None`` measurements (or components of one) are missing, the others used.

On a linear model the UKF is the Kalman filter (the unscented transform of a linear function is
exact), so the reference is filterpy's ``KalmanFilter`` given only the observed rows:
``H[obs]``, ``R[obs][:, obs]`` and ``z[obs]``. The two agree to rounding; ``RTOL`` allows for
a few hundred roundings on matrices of condition number ~1e2 (measured differences: ~1e-14).
Also: no measurement at all (``None``, all-NaN, fully masked), and masked measurements on every
route of the fleet and of squkf.dask.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from models import (
    CV_Z,
    LIN4_DT,
    LIN4_H,
    LIN4_P0,
    LIN4_Q,
    LIN4_R,
    LIN4_T,
    LIN4_X0,
    assert_same_estimate,
    cv3_zs,
    cv_filter,
    lin4_fx,
    lin4_kf,
    lin4_measurements,
    lin4_ukf,
    make_cv3_fleet,
    one_d_measured,
    range_bearing_heading_hx,
    rbh_filter,
    step,
)

import squkf
from squkf import (
    Fleet,
    MerweScaledWeights,
    SquareRootUKF,
)
from squkf.angles import wrap

# == partial measurements: the Kalman filter on the observed rows ==================================

RTOL = 1e-9
ZS = lin4_measurements()


def close(a, b, what):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    scale = max(1.0, float(np.max(np.abs(b))))
    np.testing.assert_allclose(a, b, rtol=0, atol=RTOL * scale, err_msg=what)


def with_missing(z, observed, masked):
    if masked:
        return np.ma.masked_array(z, mask=~observed)
    out = z.copy()
    out[~observed] = np.nan
    return out


patterns = st.lists(st.lists(st.booleans(), min_size=3, max_size=3), min_size=LIN4_T, max_size=LIN4_T)


@settings(max_examples=40, deadline=None)
@given(pattern=patterns, masked=st.booleans())
def test_missing_components_equal_kalman_filter_on_observed_rows(pattern, masked):
    ukf, kf = lin4_ukf(), lin4_kf()
    for z, obs in zip(ZS, pattern):
        obs = np.array(obs)
        ukf.predict()
        kf.predict()
        ukf.update(with_missing(z, obs, masked))
        if not obs.any():
            kf.update(None)
            np.testing.assert_array_equal(ukf.x_post, ukf.x_prior)
        else:
            kf.update(z[obs], R=LIN4_R[np.ix_(obs, obs)], H=LIN4_H[obs])
            close(ukf.y[obs], kf.y, "y")
            close(ukf.S[np.ix_(obs, obs)], kf.S, "S")
            close(ukf.K[:, obs], kf.K, "K")
            close(ukf.log_likelihood, kf.log_likelihood, "log_likelihood")
            close(ukf.mahalanobis, kf.mahalanobis, "mahalanobis")
        close(ukf.x, kf.x, "x")
        close(ukf.P, kf.P, "P")


@pytest.mark.parametrize("missing", [[0], [1], [2], [0, 2], [1, 2]])
def test_record_conventions_at_missing_components(missing):
    ukf = lin4_ukf()
    ukf.predict()
    z = ZS[0].copy()
    z[missing] = np.nan
    ukf.update(z)
    obs = np.ones(3, bool)
    obs[missing] = False
    assert np.all(np.isnan(ukf.y[~obs])) and np.all(np.isfinite(ukf.y[obs]))
    for name in ("S1_2", "S", "SI"):
        A = getattr(ukf, name)
        assert A.shape == (3, 3), name
        assert np.all(np.isnan(A[~obs, :])) and np.all(np.isnan(A[:, ~obs])), name
        assert np.all(np.isfinite(A[np.ix_(obs, obs)])), name
    np.testing.assert_array_equal(ukf.K[:, ~obs], 0.0)
    assert np.all(np.any(ukf.K[:, obs] != 0.0, axis=0))  # each observed column is a real gain
    # SI is the inverse of the observed block of S
    So, SIo = ukf.S[np.ix_(obs, obs)], ukf.SI[np.ix_(obs, obs)]
    close(SIo @ So, np.eye(obs.sum()), "SI @ S")
    # the likelihood and the distance are those of the observed components alone
    yo = ukf.y[obs]
    d2 = float(yo @ np.linalg.solve(So, yo))
    close(ukf.mahalanobis, np.sqrt(d2), "mahalanobis")
    k = obs.sum()
    ll = -0.5 * (k * np.log(2 * np.pi) + np.linalg.slogdet(So)[1] + d2)
    close(ukf.log_likelihood, ll, "log_likelihood")


def test_a_full_measurement_after_a_partial_one_has_full_records():
    ukf = lin4_ukf()
    ukf.predict()
    ukf.update(np.array([ZS[0][0], np.nan, ZS[0][2]]))
    ukf.predict()
    ukf.update(ZS[1])
    for name in ("y", "S1_2", "S", "SI", "K"):
        assert np.all(np.isfinite(getattr(ukf, name))), name
    assert np.all(ukf.K != 0.0)


def test_batch_filter_with_nan_entries_equals_the_step_loop():
    rng = np.random.default_rng(5)
    zs = np.array(ZS)
    zs[rng.random(zs.shape) < 0.35] = np.nan
    zs[3] = np.nan  # a step with no measurement at all
    a, b = lin4_ukf(), lin4_ukf()
    means, covs = a.batch_filter(zs)
    for k, z in enumerate(zs):
        b.predict()
        b.update(z)
        np.testing.assert_array_equal(means[k], b.x)
        np.testing.assert_array_equal(covs[k], b.P)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P, b.P)
    # and the loop is the Kalman filter on the observed rows
    kf = lin4_kf()
    for z in zs:
        obs = ~np.isnan(z)
        kf.predict()
        kf.update(z[obs] if obs.any() else None, R=LIN4_R[np.ix_(obs, obs)], H=LIN4_H[obs])
    close(b.x, kf.x, "x")
    close(b.P, kf.P, "P")


def test_missing_components_with_the_augmented_set():
    """The augmented set's update on the observed components equals a filter measuring those only."""
    obs = np.array([True, False, True])
    a = lin4_ukf()
    a.scheme = "augmented"
    b = SquareRootUKF(
        4,
        2,
        LIN4_DT,
        lambda x: (LIN4_H @ x)[obs],
        lin4_fx,
        MerweScaledWeights(alpha=1.0, beta=2.0, kappa=0.0),
    )
    b.scheme = "augmented"
    b.x, b.P, b.Q, b.R = LIN4_X0, LIN4_P0, LIN4_Q, LIN4_R[np.ix_(obs, obs)]
    for z in ZS:
        a.predict()
        b.predict()
        a.update(np.where(obs, z, np.nan))
        b.update(z[obs])
        close(a.x, b.x, "x")
        close(a.P, b.P, "P")
        close(a.log_likelihood, b.log_likelihood, "log_likelihood")


# == no measurement ================================================================================


@pytest.mark.parametrize(
    "z",
    [
        None,
        np.nan,
        np.array([np.nan]),
        np.ma.masked_all(1),
        np.ma.masked_array([1.0], mask=[True]),
    ],
    ids=["None", "nan", "[nan]", "masked_all", "masked"],
)
def test_no_measurement_in_one_dimension(z):
    f = one_d_measured()
    f.R = 0.1
    f.predict()
    f.update(z)
    assert f._engine.phase == "idle"
    np.testing.assert_array_equal(f.x_post, f.x_prior)
    np.testing.assert_array_equal(f.P1_2_post, f.P1_2_prior)
    np.testing.assert_array_equal(f.x, f.x_prior)


@pytest.mark.parametrize(
    "z",
    [None, np.array([np.nan, np.nan]), np.ma.masked_all(2), np.ma.masked_array([1.0, 2.0], mask=[1, 1])],
    ids=["None", "all-nan", "masked_all", "masked"],
)
def test_no_measurement(z):
    f, twin = cv_filter(), cv_filter()
    step(f, CV_Z[0])
    step(twin, CV_Z[0])
    f.predict()
    f.update(z)
    assert f._engine.phase == "idle"
    np.testing.assert_array_equal(f.x_post, f.x_prior)
    np.testing.assert_array_equal(f.P1_2_post, f.P1_2_prior)
    # and the next step is an ordinary one from that prior
    twin.predict()
    twin.update(None)
    step(f, CV_Z[1])
    step(twin, CV_Z[1])
    assert_same_estimate(f, twin)


# == masked measurements on every route (issue 20's promises) ======================================


# -- 6. masked measurements are missing where masked, on every route ----------------------------


def masked_fleet_zs(T: int = 5) -> tuple[np.ma.MaskedArray, np.ndarray]:
    zs = cv3_zs(T)
    mask = np.zeros(zs.shape, dtype=bool)
    mask[0, 1] = True  # a whole row
    mask[2, 3, 1] = True  # one component
    data = zs.copy()
    data[mask] = 1e6  # what a masked entry holds must never be read
    return np.ma.masked_array(data, mask=mask), np.where(mask, np.nan, zs)


def test_a_masked_zs_is_missing_where_masked_for_a_fleet():
    masked, nan = masked_fleet_zs()
    expected = make_cv3_fleet().batch_filter(nan)
    got = make_cv3_fleet().batch_filter(masked)
    np.testing.assert_array_equal(got.means, expected.means)
    np.testing.assert_array_equal(got.log_likelihood, expected.log_likelihood)
    steps = make_cv3_fleet().batch_filter(masked[:, t] for t in range(masked.shape[1]))
    np.testing.assert_array_equal(steps.means, expected.means)


def test_a_masked_zs_is_missing_where_masked_on_dask():
    sd = pytest.importorskip("squkf.dask")
    da = pytest.importorskip("dask.array")
    masked, nan = masked_fleet_zs()
    expected = make_cv3_fleet().batch_filter(nan)
    for zs in (masked, da.ma.masked_array(da.from_array(masked.data, chunks=(2, -1, -1)), mask=masked.mask)):
        got = sd.compute(sd.batch_filter(make_cv3_fleet(), zs), scheduler="synchronous")
        np.testing.assert_array_equal(got.means, expected.means)


# == hooks see the whole z (issue 29, item 5) ========================================================


def rbh_z(f) -> np.ndarray:
    """A measurement of the [range, bearing, heading] sensor near the prior's prediction."""
    z = range_bearing_heading_hx(f.x)
    return np.array([z[0] + 0.7, wrap(z[1] + 0.02), z[2] - 0.01])


def test_z_hooks_see_the_whole_vector_with_a_missing_component():
    """A missing range: AngleResidual([1]) still wraps the bearing (index 1 of the whole z).

    The oracle is the filter of the sensor without the range (its hooks at index 0), fed
    the bearing and heading: the same update in another arithmetic order (R's observed
    block factored by a QR of R1_2's rows there, by Cholesky here), so 1e-12.
    """
    full, oracle = rbh_filter(), rbh_filter(m=2)
    for _ in range(3):
        full.predict()
        oracle.predict()
        z = rbh_z(full)
        full.update(np.array([np.nan, z[1], z[2]]))
        oracle.update(z[1:])
        np.testing.assert_allclose(full.x, oracle.x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(full.P, oracle.P, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(full.y[1:], oracle.y, rtol=1e-10, atol=1e-14)
        assert np.isnan(full.y[0])
        assert full.log_likelihood == pytest.approx(oracle.log_likelihood, rel=1e-12)


def test_a_ut_sees_the_whole_vector_with_a_missing_component():
    """A user's UT is called with every component (and the whole R); the update takes the measured ones."""
    seen = []

    def UT(sigmas, Wm, Wc, noise_sqrt, mean_fn, residual_fn):
        seen.append((sigmas.shape, noise_sqrt.shape))
        return squkf.sqrt_unscented_transform(sigmas, Wm, Wc, noise_sqrt, mean_fn, residual_fn)

    with_ut, plain = rbh_filter(), rbh_filter()
    for f in (with_ut, plain):
        f.predict()
    z = rbh_z(plain)
    z[0] = np.nan
    with_ut.update(z, UT=UT)
    plain.update(z)
    assert seen == [((9, 3), (3, 3))]
    np.testing.assert_allclose(with_ut.x, plain.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(with_ut.P1_2, plain.P1_2, rtol=1e-10, atol=1e-14)


def test_a_fleet_with_z_hooks_and_missing_components_equals_its_filters():
    """A fleet's filters with hooks and a missing range each equal the single filter, bit for bit."""
    singles = [rbh_filter(vectorized=True) for _ in range(3)]
    fleet = Fleet.from_filters(singles)
    for t in range(2):
        zs = []
        for k, f in enumerate(singles):
            f.predict()
            z = rbh_z(f)
            if (k + t) % 2:
                z[0] = np.nan
            f.update(z)
            zs.append(z)
        fleet.predict()
        fleet.update(np.array(zs))
    for k, f in enumerate(singles):
        np.testing.assert_array_equal(fleet.x[k], f.x)
        np.testing.assert_array_equal(fleet.P1_2[k], f.P1_2)
