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

Inputs are checked before the backward pass: the filtered means and factors
must be finite, the factors lower triangular with a non-zero diagonal, and
the per-step arguments (see :mod:`squkf.batch`) must have one entry per step;
``dts`` entries must be finite and not negative (``dt = 0``, a prediction of
zero length, is accepted, as by the filter).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from .batch import per_step
from .covariance import FactorSlot, as_lower_factor
from .errors import NonFiniteError, ParameterError, ShapeError, SqukfError
from .generators import _identity_moments, sigma_points_from_factor
from .linalg import chol_downdate_columns, kalman_gain, tria
from .rows import weight_rows
from .transform import deviations, factor_rows, sqrt_unscented_transform
from .validate import check_values

__all__ = ["rts_smoother", "rts_smoother_factors"]


def _as_stack(value, name: str, tail: tuple[int, ...], T: int | None = None) -> np.ndarray:
    """``value`` as a finite float array of shape ``(T, *tail)``, or a ShapeError/NonFiniteError naming it."""
    expected = f"(T, {', '.join(map(str, tail))})"
    if isinstance(value, (str, bytes, Mapping)) or value is None:
        raise ShapeError(f"{name} must be an array of shape {expected}, got {type(value).__name__}")
    if not hasattr(value, "__len__") and isinstance(value, Iterable):
        value = list(value)  # a generator: the backward pass needs all of it
    try:
        A = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name} must be an array of shape {expected}: {exc}") from None
    if A.ndim == 1 and A.size == 0:
        A = A.reshape((0, *tail))
    if len(tail) == 1 and A.ndim == 3 and A.shape[2] == 1:  # filterpy's column vectors
        A = A[:, :, 0]
    if A.ndim != 1 + len(tail) or A.shape[1:] != tail:
        raise ShapeError(f"{name} has shape {A.shape}, expected {expected}")
    if T is not None and A.shape[0] != T:
        raise ShapeError(f"{name} has {A.shape[0]} entries but Xs has {T}: they must be the same length")
    finite = np.isfinite(A).all(axis=tuple(range(1, A.ndim)))
    if not finite.all():
        k = int(np.flatnonzero(~finite)[0])
        raise NonFiniteError(f"{name}[{k}] (step {k}) contains NaN or inf: {A[k]!r}")
    return A


def _check_UT(UT) -> None:
    if UT is not None and not callable(UT):
        raise ParameterError(f"UT must be a callable (or None), got {UT!r}")


def rts_smoother(
    ukf,
    Xs,
    Ps,
    Qs=None,
    dts=None,
    UT: Callable | None = None,
    *,
    fx_args: Mapping[str, Any] | Iterable[Mapping[str, Any] | None] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Square-root unscented RTS smoother with filterpy's signature.

    Parameters
    ----------
    ukf : SquareRootUKF
        Supplies ``fx``, the sigma-point family, the hooks and the defaults.
    Xs : array_like, shape (T, dim_x) or (T, dim_x, 1)
        Filtered means (``batch_filter``'s first output).
    Ps : array_like, shape (T, dim_x, dim_x)
        Filtered covariances; each is checked (symmetric, positive definite)
        and factored once.
    Qs : None, scalar, ndarray of shape (dim_x, dim_x), or T entries, optional
        ``Qs[k]``: process noise of the prediction into step ``k`` (a scalar
        ``q`` means ``q * I`` at every step; default ``ukf.Q``).
    dts : None, float, or T floats, optional
        ``dts[k]``: time step of the prediction into step ``k`` (default: the
        filter's ``dt``). Finite and not negative; ``0`` is accepted.
    UT : callable, optional
        Square-root transform (see :func:`squkf.sqrt_unscented_transform`).
    fx_args : None, dict, or T dicts, optional
        Keyword arguments of ``fx`` for the prediction into step ``k``.

    Returns
    -------
    xs : ndarray, shape (T, dim_x)
        Smoothed means.
    Ps : ndarray, shape (T, dim_x, dim_x)
        Smoothed covariances.
    Ks : ndarray, shape (T, dim_x, dim_x)
        Smoother gains (the last is zero).

    Raises
    ------
    ShapeError
        ``Xs``, ``Ps`` or a per-step argument of the wrong shape or length.
    NonFiniteError
        NaN or inf in ``Xs[k]`` or ``Ps[k]`` (the message names ``k``).
    SqukfValueError, NotPositiveDefiniteError
        ``Ps[k]`` not symmetric or not positive definite.
    ParameterError
        A negative or non-finite ``dts`` entry, ``fx_args`` not dicts.
    """
    n = ukf.dim_x
    Xs = _as_stack(Xs, "Xs", (n,))
    Ps = _as_stack(Ps, "Ps", (n, n), len(Xs))
    slot = FactorSlot("Ps[k]", n, semidefinite=False, factor=None)
    factors = np.empty_like(Ps)
    for k, P in enumerate(Ps):
        slot.name = f"Ps[{k}]"
        slot.set_matrix(P)
        factors[k] = slot.factor()
    xs, S, Ks = rts_smoother_factors(ukf, Xs, factors, Qs=Qs, dts=dts, UT=UT, fx_args=fx_args)
    return xs, S @ np.swapaxes(S, 1, 2), Ks


def rts_smoother_factors(
    ukf,
    Xs,
    P1_2s,
    Qs=None,
    dts=None,
    UT: Callable | None = None,
    *,
    fx_args: Mapping[str, Any] | Iterable[Mapping[str, Any] | None] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The smoother on lower factors: ``(xs, P1_2s, Ks)`` from filtered means and factors.

    Parameters
    ----------
    ukf : SquareRootUKF
    Xs : array_like, shape (T, dim_x) or (T, dim_x, 1)
        Filtered means.
    P1_2s : array_like, shape (T, dim_x, dim_x)
        Lower factors of the filtered covariances (``batch_filter(...,
        return_factors=True)``): each must be lower triangular with no zero on
        its diagonal (a negative diagonal entry is accepted and its column
        negated, which leaves ``S @ S.T`` unchanged, as the ``P1_2`` setter
        does).
    Qs, dts, UT, fx_args
        As for :func:`rts_smoother`.

    Returns
    -------
    xs : ndarray, shape (T, dim_x)
    P1_2s : ndarray, shape (T, dim_x, dim_x)
        Lower factors of the smoothed covariances.
    Ks : ndarray, shape (T, dim_x, dim_x)

    Raises
    ------
    ShapeError, NonFiniteError, ParameterError
        As for :func:`rts_smoother`, naming the argument and the step.
    SqukfValueError
        ``P1_2s[k]`` is not lower triangular.
    NotPositiveDefiniteError
        ``P1_2s[k]`` has a zero on its diagonal.
    SqukfError
        Raised during the backward pass at step ``k`` (e.g. by ``fx`` values,
        or ``Qs[k + 1]`` of the wrong size): its message starts with
        ``"at smoothing step k"``.
    """
    n = ukf.dim_x
    Xs = _as_stack(Xs, "Xs", (n,))
    T = len(Xs)
    S_in = _as_stack(P1_2s, "P1_2s", (n, n), T)
    for k in range(T):
        S_in[k] = as_lower_factor(S_in[k], f"P1_2s[{k}]", n, singular_ok=False)
    _check_UT(UT)
    dts = per_step(dts, T, "dts", "dt", default=ukf._dt)
    fx_args = per_step(fx_args, T, "fx_args", "kwargs")
    Q_list = per_step(Qs, T, "Qs", "noise")
    family = ukf._family
    xi = family.unit_sigma_points(n)
    Wm, Wc = family.weights(n)
    exact = _identity_moments(family, n)
    mean_rows = weight_rows(Wm, Wc).mean_form
    hooks = ukf._hooks()
    residual_x = hooks.residual_x
    state_add = hooks.state_add
    ut = sqrt_unscented_transform if UT is None else UT

    xs = Xs.copy()
    Ss = S_in.copy()
    Ks = np.zeros((T, n, n))
    k = T - 2
    try:
        for k in range(T - 2, -1, -1):
            Q1_2 = ukf._noise_factor(Q_list[k + 1], "Q", n)
            x, S = Xs[k], S_in[k]
            X = sigma_points_from_factor(x, S, xi, state_add)
            F = check_values(ukf._evaluate(ukf.fx, X, (dts[k + 1],), fx_args[k + 1]), X.shape, "fx values")
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
    except SqukfError as exc:
        msg = exc.args[0] if exc.args else ""
        exc.args = (f"at smoothing step {k} (Qs[{k + 1}], dts[{k + 1}], fx_args[{k + 1}]): {msg}",)
        raise
    return xs, Ss, Ks
