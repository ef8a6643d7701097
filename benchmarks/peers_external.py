"""Adapters for third-party UKF peers: kalman-py, nrl-tracker (pytcl) and Stone Soup.

Every adapter runs van der Merwe scaled sigma points with the scenario's own alpha, beta and kappa
(all three peers use filterpy's parametrisation, lambda = alpha^2 (n + kappa) - n), so the sigma
points and weights are the same as filterpy's ``MerweScaledSigmaPoints``. Like filterpy 2.0, all three
redraw the sigma points from the predicted (x, P) before the update, so on well-conditioned problems
they agree with filterpy's UKF to rounding (the square-root ones differ only in rounding too).
"""

from __future__ import annotations

import importlib

import numpy as np
from peers import Impl


def _kalman_py(square_root: bool) -> Impl:
    """kalman-py's ``UnscentedKalmanFilter`` (NumPy backend, step by step), vectorised model."""
    from kalman_py import UnscentedKalmanFilter

    def make(sc, fx, hx):
        f = UnscentedKalmanFilter(
            fx,
            hx,
            sc.Q,
            sc.R,
            sc.x0,
            sc.P0,
            alpha=sc.alpha,
            beta=sc.beta,
            kappa=sc.kappa,
            square_root=square_root,
            vectorized=True,  # fx(X, dt), hx(X) with one point per row, as ours
        )
        f.dt = sc.dt
        return f

    def step(f, z):
        f.predict(f.dt)
        f.update(z)

    # In square-root mode kalman-py itself keeps f.P = S S^T after every step.
    name = "kalman-py SR-UKF (vectorised)" if square_root else "kalman-py UKF (vectorised)"
    return Impl(name, make, step, lambda f: (f.x, f.P), vectorized=True)


class _PytclFilter:
    """State of an nrl-tracker square-root UKF: mean, lower Cholesky factor, noise factors."""

    def __init__(self, sc, fx, hx):
        self.x, self.S = sc.x0.astype(float), np.linalg.cholesky(sc.P0)
        self.S_Q, self.S_R = np.linalg.cholesky(sc.Q), np.linalg.cholesky(sc.R)
        self.params = (sc.alpha, sc.beta, sc.kappa)
        dt = sc.dt
        self.f = lambda x: fx(x, dt)  # pytcl's f takes the state only
        self.h = hx


def _nrl_tracker() -> Impl:
    """nrl-tracker's ``sr_ukf_predict`` / ``sr_ukf_update`` (functional API, per-point model).

    pytcl evaluates f and h one sigma point (column) at a time; it has no vectorised option. Note
    that when the central covariance weight is negative (small alpha) and a Cholesky downdate fails,
    pytcl silently keeps the un-downdated factor (prediction) or repairs P by adding to its
    eigenvalues (update) instead of failing.
    """
    from pytcl.dynamic_estimation.kalman import sr_ukf_predict, sr_ukf_update
    from pytcl.dynamic_estimation.kalman.matrix_utils import cholesky_update

    def make(sc, fx, hx):
        # Load numba's compiled rank-1 update/downdate now, not in the first timed step.
        cholesky_update(np.eye(2), np.array([0.1, 0.0]), 1.0)
        cholesky_update(np.eye(2), np.array([0.1, 0.0]), -1.0)
        return _PytclFilter(sc, fx, hx)

    def step(f, z):
        pred = sr_ukf_predict(f.x, f.S, f.f, f.S_Q, *f.params)
        upd = sr_ukf_update(pred.x, pred.S, z, f.h, f.S_R, *f.params)
        f.x, f.S = upd.x, upd.S

    return Impl("nrl-tracker sr-UKF", make, step, lambda f: (f.x, f.S @ f.S.T), vectorized=False)


def _stonesoup() -> Impl:
    """Stone Soup's ``UnscentedKalmanPredictor`` / ``UnscentedKalmanUpdater``, vectorised models.

    Stone Soup hands a model function all sigma points at once as ``StateVectors`` (one point per
    column); the custom models below transpose to our one-point-per-row fx/hx and back. Stone Soup
    needs timestamps: the time step is taken from the prediction interval, as Stone Soup intends.
    If P is not positive-definite, Stone Soup warns and draws sigma points from a regularised factor
    (``cholesky_eps``) instead of failing.
    """
    from datetime import datetime, timedelta

    from stonesoup.base import Property
    from stonesoup.models.base import GaussianModel, TimeVariantModel
    from stonesoup.models.measurement.base import MeasurementModel
    from stonesoup.models.transition.base import TransitionModel
    from stonesoup.predictor.kalman import UnscentedKalmanPredictor
    from stonesoup.types.array import CovarianceMatrix, StateVector, StateVectors
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import UnscentedKalmanUpdater

    class VectorisedTransition(GaussianModel, TransitionModel, TimeVariantModel):
        """x[k+1] = fx(x[k], dt) + v, v ~ N(0, Q), for all sigma points at once."""

        fx: object = Property(doc="fx(X, dt), one point per row")
        Q: CovarianceMatrix = Property(doc="process noise covariance")

        @property
        def ndim_state(self):
            return self.Q.shape[0]

        def function(self, state, noise=False, time_interval=None, **kwargs):
            X = np.asarray(state.state_vector)
            return StateVectors(self.fx(X.T, time_interval.total_seconds()).T)

        def covar(self, **kwargs):
            return self.Q

    class VectorisedMeasurement(GaussianModel, MeasurementModel):
        """z = hx(x) + w, w ~ N(0, R), for all sigma points at once."""

        hx: object = Property(doc="hx(X), one point per row")
        R: CovarianceMatrix = Property(doc="measurement noise covariance")

        @property
        def ndim_meas(self):
            return self.R.shape[0]

        def function(self, state, noise=False, **kwargs):
            return StateVectors(self.hx(np.asarray(state.state_vector).T).T)

        def covar(self, **kwargs):
            return self.R

    class Filter:
        pass

    def make(sc, fx, hx):
        f = Filter()
        sp = {"alpha": sc.alpha, "beta": sc.beta, "kappa": sc.kappa}  # kappa=None would mean 3 - n
        trans = VectorisedTransition(fx=fx, Q=CovarianceMatrix(sc.Q))
        meas = VectorisedMeasurement(
            hx=hx, R=CovarianceMatrix(sc.R), ndim_state=sc.dim_x, mapping=tuple(range(sc.dim_x))
        )
        f.predictor = UnscentedKalmanPredictor(trans, **sp)
        f.updater = UnscentedKalmanUpdater(meas, **sp)
        f.t, f.dt = datetime(2000, 1, 1), timedelta(seconds=sc.dt)
        f.state = GaussianState(StateVector(sc.x0), CovarianceMatrix(sc.P0), timestamp=f.t)
        return f

    def step(f, z):
        f.t = f.t + f.dt
        pred = f.predictor.predict(f.state, timestamp=f.t)
        det = Detection(StateVector(z), timestamp=f.t)
        f.state = f.updater.update(SingleHypothesis(pred, det))

    def state(f):
        return np.asarray(f.state.state_vector, dtype=float).ravel(), np.asarray(f.state.covar, dtype=float)

    return Impl("Stone Soup UKF", make, step, state, vectorized=True)


def external_impls() -> tuple[list[Impl], list[str]]:
    """The third-party UKF peers that import here, and the ones skipped (with the reason).

    Returns
    -------
    impls : list of Impl
        kalman-py UKF and SR-UKF (vectorised), nrl-tracker sr-UKF (per point), Stone Soup UKF
        (vectorised).
    skipped : list of str
        One line per peer that is not installed or fails to import.
    """
    impls, skipped = [], []
    peers = (
        ("kalman-py", "kalman_py", lambda: [_kalman_py(False), _kalman_py(True)]),
        ("nrl-tracker", "pytcl", lambda: [_nrl_tracker()]),
        ("Stone Soup", "stonesoup", lambda: [_stonesoup()]),
    )
    for label, module, build in peers:
        try:
            importlib.import_module(module)
            impls.extend(build())
        except ImportError as exc:
            skipped.append(f"{label} (import {module!r} failed: {exc})")
    return impls, skipped
