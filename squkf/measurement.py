"""The square-root measurement update, as a pure function.

The update triangularises the joint rows of the measurement and the state
(the "array form" of the square-root Kalman filter)::

    tria([[Dz, Dx], [R1_2^T, 0]]) = [[Sy, 0], [L21, L22]]

where ``Dz``, ``Dx`` are the signed rows (see :mod:`squkf.transform`) of the
second set's images and of the second set itself. Then ``Sy`` is the
innovation factor, ``L21 = Pxy Sy^-T`` (so the gain is ``K = L21 Sy^-1`` and
``K y = L21 (Sy^-1 y)``), and ``L22 L22^T = Pxx - K Pyy K^T`` is the
posterior covariance whenever the set's covariance ``Pxx`` is the prior's
(``SigmaSet.moments_exact``). That is one QR and two triangular solves, and
no downdate. Otherwise the posterior factor is the prior's downdated by the
columns of ``L21 = K Sy`` (g13ej's form).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from .errors import DowndateError, GainError, PosteriorFactorError
from .generators import SigmaSet
from .linalg import all_finite, chol_downdate_columns, chol_update, solve_lower, tria
from .transform import (
    central_rows,
    deviations,
    factor_rows,
    signed_rows,
    transform_factor,
    weight_plan,
    weighted_mean,
)

__all__ = ["Posterior", "measurement_update", "gain_from_factors", "check_gain"]

_TINY = np.finfo(float).tiny
_INF = float("inf")


class Posterior(NamedTuple):
    """Everything a measurement update produces.

    Attributes
    ----------
    x : ndarray, shape (n,)
        Posterior mean.
    S : ndarray, shape (n, n)
        Lower factor of the posterior covariance.
    y : ndarray, shape (m,)
        Innovation ``residual_z(z, z_pred)``.
    z_pred : ndarray, shape (m,)
        Predicted measurement.
    Sy : ndarray, shape (m, m)
        Lower factor of the innovation covariance.
    L21 : ndarray, shape (n, m)
        ``Pxy Sy^-T`` (equivalently ``K Sy``); :meth:`gain` forms ``K`` from it.
    w : ndarray, shape (m,)
        Whitened innovation ``Sy^-1 y`` (for the likelihood).
    """

    x: np.ndarray
    S: np.ndarray
    y: np.ndarray
    z_pred: np.ndarray
    Sy: np.ndarray
    L21: np.ndarray
    w: np.ndarray

    def gain(self) -> np.ndarray:
        """The Kalman gain ``K = L21 Sy^-1``, shape ``(n, m)`` (one triangular solve)."""
        return gain_from_factors(self.Sy, self.L21)


def gain_from_factors(Sy: np.ndarray, L21: np.ndarray) -> np.ndarray:
    """Kalman gain ``K = L21 Sy^-1`` from the blocks of the joint factor.

    Parameters
    ----------
    Sy : ndarray, shape (m, m)
        Lower factor of the innovation covariance.
    L21 : ndarray, shape (n, m)
        ``Pxy Sy^-T``.

    Returns
    -------
    K : ndarray, shape (n, m)
    """
    return solve_lower(Sy, np.ascontiguousarray(L21.T), trans=True).T


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
    """
    plan = weight_plan(sset.Wm, sset.Wc)
    m = z.shape[0]
    if UT is None and sset.moments_exact:
        z_pred, Sy, L21, L22 = _joint_factor(sset, plan, sigmas_h, x, R1_2, z_mean_fn, residual_x, residual_z)
    else:
        if UT is None:
            z_pred, Sy = transform_factor(sigmas_h, plan, R1_2, z_mean_fn, residual_z, errno=301)
        else:
            z_pred, Sy = UT(sigmas_h, sset.Wm, sset.Wc, R1_2, z_mean_fn, residual_z)
            z_pred = np.asarray(z_pred, dtype=float).reshape(m)
            Sy = np.asarray(Sy, dtype=float).reshape(m, m)
        check_gain(Sy)
        Dz = deviations(sigmas_h, z_pred, residual_z)
        Dx = _state_deviations(sset, x, residual_x)
        Pxy = (Dx.T * sset.Wc) @ Dz
        L21 = solve_lower(Sy, np.ascontiguousarray(Pxy.T)).T
        L22 = None
    y = z - z_pred if residual_z is None else np.asarray(residual_z(z, z_pred), dtype=float).reshape(m)
    w = solve_lower(Sy, y)
    dx = L21 @ w
    x_post = x + dx if state_add is None else np.asarray(state_add(x, dx), dtype=float).reshape(-1)
    if L22 is not None:
        S_post = L22
    elif sset.moments_exact:  # a user's UT: the QR form with the gain
        K = gain_from_factors(Sy, L21)
        S_post = factor_rows(Dx - Dz @ K.T, plan.mean_form, K @ R1_2, errno=303, error=PosteriorFactorError)
    else:
        S_post = chol_downdate_columns(S, L21, errno=303, error=PosteriorFactorError)
    if not (all_finite(S_post) and all_finite(x_post)):
        raise PosteriorFactorError("the posterior mean or factor is not finite", errno=303)
    return Posterior(x_post, S_post, y, z_pred, Sy, L21, w)


def _joint_factor(sset, plan, sigmas_h, x, R1_2, z_mean_fn, residual_x, residual_z):
    """``z_pred`` and the blocks ``Sy``, ``L21``, ``L22`` of the joint factor (module docstring).

    Only for a set whose mean and covariance are the prior's: then the
    central form (deviations from the central points) and the mean form
    (deviations from the prior mean and the predicted measurement) agree.
    """
    hooks = z_mean_fn is not None or residual_x is not None or residual_z is not None
    points = sset.sigmas if sset.offsets is None else sset.offsets
    N, m = sigmas_h.shape
    n = points.shape[1]
    if not hooks and plan.fast:
        # every row enters the QR: write them straight into the buffer
        npos, neg = N, ()
        M = np.empty((N + m, m + n), order="F")  # LAPACK's layout: no copy in tria
        z_pred = central_rows(sigmas_h, plan, M[:, :m])
        central_rows(points, plan, M[:, m:])
    else:
        if not hooks and plan.best.central:
            z_pred, Dz, form = signed_rows(sigmas_h, plan)
            _, Dx, _ = signed_rows(points, plan)
        else:
            form = plan.mean_form
            z_pred = weighted_mean(sigmas_h, plan.Wm, z_mean_fn)
            Dz = deviations(sigmas_h, z_pred, residual_z)
            Dx = _state_deviations(sset, x, residual_x)
        pos, neg = form.pos, form.neg
        scale = (form.scale if pos is None else form.scale[pos])[:, None]
        npos = scale.shape[0]
        M = np.empty((npos + m, m + n), order="F")
        np.multiply(Dz if pos is None else Dz[pos], scale, out=M[:npos, :m])
        np.multiply(Dx if pos is None else Dx[pos], scale, out=M[:npos, m:])
    M[npos:, :m] = R1_2.T
    M[npos:, m:] = 0.0
    L = tria(M)
    for k in neg:
        L = _downdate_joint(L, form.scale[k] * np.concatenate([Dz[k], Dx[k]]), m, form.weights[k])
    Sy = L[:m, :m]
    check_gain(Sy)
    return z_pred, Sy, L[m:, :m], L[m:, m:]


def _state_deviations(sset: SigmaSet, x: np.ndarray, residual_x: Callable | None) -> np.ndarray:
    """Deviations of the second set from the prior mean (its exact offsets where known)."""
    if sset.offsets is not None and residual_x is None:
        return sset.offsets
    return deviations(sset.sigmas, x, residual_x)


def _downdate_joint(L: np.ndarray, v: np.ndarray, m: int, weight: float) -> np.ndarray:
    """Downdate the joint factor by one negative-weight row, naming the block that failed."""
    try:
        return chol_update(L, v, -1.0)
    except DowndateError as exc:
        try:  # the leading block alone decides whether the innovation factor failed
            chol_update(L[:m, :m], v[:m], -1.0)
        except DowndateError:
            raise DowndateError(
                f"weight {weight:.6g} is negative and the innovation factor's downdate failed: {exc}",
                errno=301,
            ) from None
        raise PosteriorFactorError(
            f"weight {weight:.6g} is negative and the posterior factor's downdate failed: {exc}", errno=303
        ) from None


def check_gain(Sy: np.ndarray) -> None:
    """Raise GainError (IFAIL 302) unless each diagonal entry of ``Sy`` is finite and above ``tiny``."""
    if not all(_TINY < abs(v) < _INF for v in Sy.diagonal().tolist()):  # a NaN fails too; m is small
        raise GainError(
            f"innovation factor is singular (diagonal {np.array2string(Sy.diagonal(), precision=3)}): "
            "cannot form the Kalman gain",
            errno=302,
        )
