"""The unscented Rauch-Tung-Striebel smoother (Särkkä 2008) in square-root form.

Each backward step draws the first-set sigma points from the filtered
``(x[k], S[k])``, propagates them through ``fx`` with the time step and
process noise of the prediction *into* step ``k + 1`` (``dts[k+1]``,
``Qs[k+1]``: the same lists given to ``batch_filter``), and forms

- the predicted mean and factor ``x_pred``, ``S_pred`` (QR + rank-1 steps),
- the cross-covariance ``C = sum Wc_i dX_i dF_i^T`` and the gain
  ``G = C (S_pred S_pred^T)^-1`` by two triangular solves,
- ``x_s[k] = x[k] + G (x_s[k+1] - x_pred)``, and the smoothed factor as one
  QR of ``[sqrt(Wc_i) (dX_i - G dF_i), G Q1_2, G S_s[k+1]]`` (plus a
  downdate per negative weight): since the points reproduce ``P[k]``,
  ``P[k] - G P_pred G^T = sum Wc_i (dX_i - G dF_i)(...)^T + G Q G^T``.

No covariance is formed and re-factored. Note the difference from filterpy's
``UnscentedKalmanFilter.rts_smoother``, which ignores ``Qs`` (it always uses
``self.Q``) and propagates step ``k`` with ``dts[k]`` rather than the time
step of the prediction into ``k + 1``; filterpy's ``KalmanFilter.rts_smoother``
reads ``Qs`` the way this smoother does.
"""

from __future__ import annotations

import numpy as np

from .batch import per_step
from .covariance import FactorSlot
from .errors import ShapeError
from .generators import _identity_moments, sigma_points_from_factor
from .linalg import chol_downdate_columns, kalman_gain, tria
from .rows import weight_rows
from .step import check_values
from .transform import deviations, factor_rows, sqrt_unscented_transform

__all__ = ["rts_smoother", "rts_smoother_factors"]


def rts_smoother(ukf, Xs, Ps, Qs=None, dts=None, UT=None, fx_args=None):
    """Square-root unscented RTS smoother with filterpy's signature.

    Parameters
    ----------
    ukf : SquareRootUKF
        Supplies ``fx``, the sigma-point family, the hooks and the defaults.
    Xs : ndarray, shape (T, dim_x)
        Filtered means (``batch_filter``'s first output).
    Ps : ndarray, shape (T, dim_x, dim_x)
        Filtered covariances; each is factored once.
    Qs : None, matrix, or sequence of T matrices
        ``Qs[k]``: process noise of the prediction into step ``k``.
    dts : None, float, or sequence of T floats
        ``dts[k]``: time step of the prediction into step ``k``.
    UT : callable, optional
        Square-root transform (see :func:`squkf.sqrt_unscented_transform`).
    fx_args : None, dict, or sequence of T dicts
        Keyword arguments of ``fx`` for the prediction into step ``k``.

    Returns
    -------
    xs : ndarray, shape (T, dim_x)
        Smoothed means.
    Ps : ndarray, shape (T, dim_x, dim_x)
        Smoothed covariances.
    Ks : ndarray, shape (T, dim_x, dim_x)
        Smoother gains (the last is zero).
    """
    Xs = np.asarray(Xs, dtype=float)
    Ps = np.asarray(Ps, dtype=float)
    if Xs.ndim == 3 and Xs.shape[2] == 1:
        Xs = Xs[:, :, 0]
    if len(Xs) != len(Ps):
        raise ShapeError(f"Xs and Ps must have the same length, got {len(Xs)} and {len(Ps)}")
    slot = FactorSlot("Ps[k]", ukf.dim_x, semidefinite=False, factor=None)
    factors = np.empty_like(Ps)
    for k, P in enumerate(Ps):
        slot.name = f"Ps[{k}]"
        slot.set_matrix(P)
        factors[k] = slot.factor()
    xs, S, Ks = rts_smoother_factors(ukf, Xs, factors, Qs=Qs, dts=dts, UT=UT, fx_args=fx_args)
    return xs, S @ np.swapaxes(S, 1, 2), Ks


def rts_smoother_factors(ukf, Xs, P1_2s, Qs=None, dts=None, UT=None, fx_args=None):
    """The smoother on lower factors: ``(xs, P1_2s, Ks)`` from filtered means and factors.

    Parameters
    ----------
    ukf : SquareRootUKF
    Xs : ndarray, shape (T, dim_x)
    P1_2s : ndarray, shape (T, dim_x, dim_x)
        Lower factors of the filtered covariances (``batch_filter(...,
        return_factors=True)``).
    Qs, dts, UT, fx_args
        As for :func:`rts_smoother`.

    Returns
    -------
    xs : ndarray, shape (T, dim_x)
    P1_2s : ndarray, shape (T, dim_x, dim_x)
        Lower factors of the smoothed covariances.
    Ks : ndarray, shape (T, dim_x, dim_x)
    """
    Xs = np.array(Xs, dtype=float)
    S_in = np.asarray(P1_2s, dtype=float)
    T, n = Xs.shape
    if S_in.shape != (T, n, n):
        raise ShapeError(f"P1_2s has shape {S_in.shape}, expected ({T}, {n}, {n})")
    dts = per_step(ukf._dt if dts is None else dts, T, "dts", scalar_ok=True)
    fx_args = per_step(fx_args, T, "fx_args")
    Q_list = per_step(Qs, T, "Qs")
    family = ukf._family
    xi = family.unit_sigma_points(n)
    Wm, Wc = family.weights(n)
    exact = _identity_moments(family, n)
    mean_rows = weight_rows(Wm, Wc).mean_form
    hooks = ukf._hooks()
    residual_x = hooks.residual_x
    state_add = hooks.state_add

    xs = Xs.copy()
    Ss = S_in.copy()
    Ks = np.zeros((T, n, n))
    for k in range(T - 2, -1, -1):
        Q1_2 = ukf._noise_factor(Q_list[k + 1], "Q", n)
        x, S = Xs[k], S_in[k]
        X = sigma_points_from_factor(x, S, xi, state_add)
        F = check_values(ukf._evaluate(ukf.fx, X, (dts[k + 1],), fx_args[k + 1] or {}), X.shape, "fx values")
        ut = sqrt_unscented_transform if UT is None else UT
        x_pred, S_pred = ut(F, Wm, Wc, Q1_2, ukf.x_mean, residual_x)
        dF = deviations(F, x_pred, residual_x)
        dX = deviations(X, x, residual_x)
        C = (dX.T * Wc) @ dF
        G = kalman_gain(C, S_pred)
        diff = xs[k + 1] - x_pred if residual_x is None else residual_x(xs[k + 1], x_pred)
        step = G @ diff
        xs[k] = x + step if state_add is None else state_add(x, step)
        GS = G @ Ss[k + 1]
        if exact:
            extra = GS if Q1_2 is None else np.hstack([G @ Q1_2, GS])
            Ss[k] = factor_rows(dX - dF @ G.T, mean_rows, extra)
        else:
            base = chol_downdate_columns(S, G @ S_pred)
            Ss[k] = tria(np.vstack([base.T, GS.T]))
        Ks[k] = G
    return xs, Ss, Ks
