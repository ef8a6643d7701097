"""The square-root measurement update, as a pure function."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .errors import PosteriorFactorError
from .generators import SigmaSet
from .linalg import chol_downdate_columns, kalman_gain
from .transform import deviations, factor_from_deviations, mean_and_deviations

__all__ = ["Posterior", "measurement_update"]


@dataclass(frozen=True)
class Posterior:
    """Everything a measurement update produces.

    Attributes
    ----------
    x : ndarray, shape (n,)
        Posterior mean.
    S : ndarray, shape (n, n)
        Lower factor of the posterior covariance.
    K : ndarray, shape (n, m)
        Kalman gain.
    y : ndarray, shape (m,)
        Innovation ``residual_z(z, z_pred)``.
    z_pred : ndarray, shape (m,)
        Predicted measurement.
    Sy : ndarray, shape (m, m)
        Lower factor of the innovation covariance.
    Pxy : ndarray, shape (n, m)
        State-measurement cross-covariance.
    """

    x: np.ndarray
    S: np.ndarray
    K: np.ndarray
    y: np.ndarray
    z_pred: np.ndarray
    Sy: np.ndarray
    Pxy: np.ndarray


def measurement_update(
    x: np.ndarray,
    S: np.ndarray,
    sset: SigmaSet,
    sigmas_h: np.ndarray,
    z: np.ndarray,
    R1_2: np.ndarray,
    *,
    z_mean_fn: Callable | None = None,
    residual_x: Callable | None = None,
    residual_z: Callable | None = None,
    state_add: Callable | None = None,
    UT: Callable | None = None,
) -> Posterior:
    """Square-root measurement update from the second set and its images.

    Parameters
    ----------
    x : ndarray, shape (n,)
        Prior mean.
    S : ndarray, shape (n, n)
        Lower factor of the prior covariance.
    sset : SigmaSet
        The second sigma-point set (``N`` points) and its weights.
    sigmas_h : ndarray, shape (N, m)
        The measurement function's values at ``sset.sigmas``.
    z : ndarray, shape (m,)
        The measurement.
    R1_2 : ndarray, shape (m, m)
        Lower factor of the measurement noise covariance.
    z_mean_fn, residual_x, residual_z, state_add : callable, optional
        filterpy's hooks for non-additive quantities (angles).
    UT : callable, optional
        Replaces the transform of ``sigmas_h`` into ``(z_pred, Sy)``; same
        signature as :func:`squkf.sqrt_unscented_transform`.

    Returns
    -------
    Posterior

    Raises
    ------
    DowndateError
        A negative weight's downdate of the innovation factor failed (IFAIL 301).
    GainError
        The innovation factor is singular (IFAIL 302).
    PosteriorFactorError
        The posterior factor could not be formed (IFAIL 303).

    Notes
    -----
    With ``E[i] = dx[i] - K dz[i]`` the posterior covariance is
    ``sum_i Wc[i] E[i] E[i]^T + K R K^T`` whenever the second set's weighted
    covariance is exactly the prior's (``sset.moments_exact``). That form is a
    QR factorisation plus one downdate per negative weight, and never fails
    while the posterior is positive definite. Otherwise the posterior factor
    is the prior's downdated by the columns of ``K @ Sy`` (g13ej's form).
    """
    Wm, Wc = sset.Wm, sset.Wc
    if UT is None:
        z_pred, dz = mean_and_deviations(sigmas_h, Wm, z_mean_fn, residual_z)
        Sy = factor_from_deviations(dz, Wc, R1_2, errno=301)
    else:
        z_pred, Sy = UT(sigmas_h, Wm, Wc, R1_2, z_mean_fn, residual_z)
        z_pred = np.asarray(z_pred, dtype=float).reshape(-1)
        dz = deviations(sigmas_h, z_pred, residual_z)
    dx = deviations(sset.sigmas, x, residual_x)
    Pxy = (dx.T * Wc) @ dz
    K = kalman_gain(Pxy, Sy)
    y = z - z_pred if residual_z is None else np.asarray(residual_z(z, z_pred), dtype=float).reshape(-1)
    dxk = K @ y
    x_post = x + dxk if state_add is None else np.asarray(state_add(x, dxk), dtype=float).reshape(-1)
    if sset.moments_exact:
        S_post = factor_from_deviations(dx - dz @ K.T, Wc, K @ R1_2, errno=303, error=PosteriorFactorError)
    else:
        S_post = chol_downdate_columns(S, K @ Sy, errno=303, error=PosteriorFactorError)
    if not (np.isfinite(S_post).all() and np.isfinite(x_post).all()):
        raise PosteriorFactorError("the posterior mean or factor is not finite", errno=303)
    return Posterior(x_post, S_post, K, y, z_pred, Sy, Pxy)
