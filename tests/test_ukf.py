"""filterpy compatibility beyond predict/update: CKF, Saver, pickling, repr, multiple sensors, angles."""

import copy
import pickle

import numpy as np
import pytest
from filterpy.common import Saver
from filterpy.kalman import CubatureKalmanFilter, KalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter
from models import (
    CT_P0,
    CT_Q,
    CT_R,
    CT_X0,
    ct_fx,
    ct_hx,
    ct_simulate,
    spinning_heading,
    spinning_heading_filter,
)
from scipy.stats import chi2

from squkf import CubatureWeights, MerweScaledWeights, Propagated, SquareRootUKF
from squkf.angles import AngleAdd, AngleMean, AngleResidual, circular_mean, wrap


def zs_ct(T=50, seed=0):
    """T noisy measurements of the far coordinated-turn radar, none missing."""
    return ct_simulate(T, seed, missing=())[0]


def test_cubature_reproduces_filterpy_ckf():
    """filterpy's CKF reuses the propagated cubature points for the update: scheme='propagated'."""
    ckf = CubatureKalmanFilter(5, 2, 1.0, ct_hx, ct_fx)
    sq = SquareRootUKF(5, 2, 1.0, ct_hx, ct_fx, CubatureWeights(), scheme=Propagated())
    for f in (ckf, sq):
        f.x, f.P, f.Q, f.R = CT_X0.copy(), CT_P0, CT_Q, CT_R
    ckf.x = CT_X0.reshape(5, 1)  # filterpy's CKF works with column vectors
    for z in zs_ct():
        ckf.predict()
        sq.predict()
        ckf.update(z.reshape(2, 1))
        sq.update(z)
        assert np.max(np.abs(sq.x - ckf.x.ravel())) / np.max(np.abs(ckf.x)) < 1e-8
        assert np.max(np.abs(sq.P - ckf.P)) / np.max(np.abs(ckf.P)) < 1e-8


def test_saver_records_a_run():
    f = SquareRootUKF(5, 2, 1.0, ct_hx, ct_fx, MerweScaledWeights(0.3))
    f.x, f.P, f.Q, f.R = CT_X0.copy(), CT_P0, CT_Q, CT_R
    saver = Saver(f)
    zs = zs_ct(10)
    means, covs = f.batch_filter(zs, saver=saver)
    saver.to_array()
    np.testing.assert_array_equal(saver.x, means)
    np.testing.assert_allclose(saver.P, covs)
    assert saver.P1_2.shape == (10, 5, 5)
    assert np.all(np.isfinite(saver.log_likelihood))


@pytest.mark.parametrize("copier", [copy.deepcopy, lambda f: pickle.loads(pickle.dumps(f))])
def test_pickle_and_deepcopy_continue_identically(copier):
    hooks = dict(residual_x=AngleResidual([4]), state_add=AngleAdd([4]), x_mean_fn=AngleMean([4]))
    f = SquareRootUKF(5, 2, 1.0, ct_hx, ct_fx, MerweScaledWeights(0.3), **hooks)
    f.x, f.P, f.Q, f.R = CT_X0.copy(), CT_P0, CT_Q, CT_R
    zs = zs_ct(6)
    for z in zs[:3]:
        f.predict()
        f.update(z)
    g = copier(f)
    for z in zs[3:]:
        for h in (f, g):
            h.predict()
            h.update(z)
    np.testing.assert_array_equal(f.x, g.x)
    np.testing.assert_array_equal(f.P1_2, g.P1_2)


def test_repr_shows_the_state():
    f = SquareRootUKF(5, 2, 1.0, ct_hx, ct_fx, MerweScaledWeights(0.3))
    f.x = CT_X0
    text = repr(f)
    assert text.startswith("SquareRootUKF object")
    for name in ("x = ", "P1_2 = ", "Q1_2 = ", "R1_2 = ", "K = ", "scheme = "):
        assert name in text
    assert "2.e+03" in text


def test_alternating_sensors_of_different_dimension():
    """A position sensor (2-d) and a range-only sensor (1-d) on one filter: each update equals
    the covariance-form equations applied to the redrawn points, written out here."""
    F = np.array([[1, 1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 1.0]])

    def h_pos(x):
        return x[[0, 2]]

    def h_rng(x):
        return np.array([np.hypot(x[0], x[2])])

    R_pos, R_rng = np.eye(2) * 4.0, np.eye(1) * 0.25
    f = SquareRootUKF(4, 2, 1.0, h_pos, lambda x, dt: F @ x, MerweScaledWeights(0.5, 2.0, 0.0))
    f.x, f.P, f.Q, f.R = np.array([100.0, 1, 50, -1]), np.eye(4) * 10, np.eye(4) * 0.01, R_pos
    fam = MerweScaledWeights(0.5, 2.0, 0.0)
    rng = np.random.default_rng(2)
    for k in range(20):
        f.predict()
        hx, Rk = (h_pos, R_pos) if k % 2 == 0 else (h_rng, R_rng)
        x, P = f.x.copy(), f.P.copy()
        Y = x + fam.unit_sigma_points(4) @ np.linalg.cholesky(P).T
        Wm, Wc = fam.weights(4)
        HY = np.array([hx(y) for y in Y])
        zp = Wm @ HY
        dz, dx = HY - zp, Y - x
        Pzz = (dz.T * Wc) @ dz + Rk
        K = ((dx.T * Wc) @ dz) @ np.linalg.inv(Pzz)
        z = hx(x) + rng.normal(0, 1.0, len(zp))
        if k % 2 == 0:
            f.update(z)
        else:
            f.update(z, R=R_rng, hx=h_rng)
        np.testing.assert_allclose(f.x, x + K @ (z - zp), rtol=1e-10)
        np.testing.assert_allclose(f.P, P - K @ Pzz @ K.T, rtol=1e-8, atol=1e-10)
        assert f.K.shape == (4, len(zp))


def test_two_sensors_equal_one_stacked_update_on_a_linear_model():
    """For a linear model two sequential updates (redrawing between them) are the stacked KF update."""
    H1, H2 = np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0], [0, 0, 1.0]])
    R1, R2 = np.eye(1) * 0.5, np.diag([0.2, 0.3])
    f = SquareRootUKF(3, 1, 1.0, lambda x: H1 @ x, lambda x, dt: x, MerweScaledWeights())
    f.x, f.P, f.Q, f.R = np.zeros(3), np.eye(3) * 2 + 0.5, np.eye(3) * 0.1, R1
    kf = KalmanFilter(3, 3)
    kf.x, kf.P, kf.Q, kf.F = np.zeros(3), np.eye(3) * 2 + 0.5, np.eye(3) * 0.1, np.eye(3)
    kf.H, kf.R = np.vstack([H1, H2]), np.block([[R1, np.zeros((1, 2))], [np.zeros((2, 1)), R2]])
    z1, z2 = np.array([1.0]), np.array([-0.5, 2.0])
    f.predict()
    f.update(z1)
    f.update(z2, R=R2, hx=lambda x: H2 @ x)
    kf.predict()
    kf.update(np.r_[z1, z2])
    np.testing.assert_allclose(f.x, kf.x, rtol=1e-12)
    np.testing.assert_allclose(f.P, kf.P, rtol=1e-12)


def test_circular_mean_survives_negative_central_weight():
    fam = MerweScaledWeights(0.1, 2.0, 0.0)
    Wm, _ = fam.weights(1)
    assert Wm[0] < -10
    for centre in (np.pi - 0.01, -np.pi + 0.01, 0.3):
        pts = wrap(centre + np.array([0.0, 0.05, -0.05]))
        m = circular_mean(pts, Wm)
        assert abs(wrap(m - centre)) < 1e-12
        # the sin/cos form is broken by the negative weight when points straddle the cut
    naive = np.arctan2(Wm @ np.sin(pts), Wm @ np.cos(pts))
    assert np.isfinite(naive)


def test_angles_agree_with_filterpy_where_its_hooks_are_well_defined():
    # alpha = 1: all weights positive, so filterpy's hooks are well defined
    truth, zs, _, _ = spinning_heading(4)
    x0 = np.array([truth[0][0], 0.8])
    fp = spinning_heading_filter(
        UnscentedKalmanFilter, MerweScaledSigmaPoints(2, 1.0, 2.0, 1.0, subtract=AngleResidual([0])), x0
    )
    sq = spinning_heading_filter(SquareRootUKF, MerweScaledSigmaPoints(2, 1.0, 2.0, 1.0), x0)
    for z in zs:
        for f in (fp, sq):
            f.predict()
            f.update(z)
        assert np.max(np.abs(wrap(sq.x - fp.x))) < 1e-8
        assert np.max(np.abs(sq.P - fp.P)) / np.max(np.abs(fp.P)) < 1e-8


def test_angles_nees_consistent_across_the_cut():
    """Average NEES over 50 runs x 100 steps within its 95% chi-square band (dof 2 per step)."""
    runs, T = 50, 100
    nees = []
    for seed in range(runs):
        truth, zs, _, _ = spinning_heading(100 + seed, T)
        f = spinning_heading_filter(
            SquareRootUKF, MerweScaledWeights(0.1, 2.0, 0.0), np.array([truth[0][0], 0.8])
        )
        for z, xt in zip(zs, truth):
            f.predict()
            f.update(z)
            e = np.array([wrap(f.x[0] - xt[0]), f.x[1] - xt[1]])
            nees.append(e @ np.linalg.solve(f.P, e))
    nees = np.array(nees).reshape(runs, T)[:, 10:]  # skip the initial transient
    dof = 2 * nees.size
    lo, hi = chi2.ppf([0.025, 0.975], dof) / nees.size
    assert lo < nees.mean() < hi, (lo, nees.mean(), hi)
