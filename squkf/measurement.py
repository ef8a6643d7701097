"""The square-root measurement update, as a pure function on stacked arrays.

The update triangularises the joint rows of the measurement and the state
(the "array form" of the square-root Kalman filter)::

    tria([[Dz, Dx], [R1_2^T, 0]]) = [[Sy, 0], [L21, L22]]

where ``Dz``, ``Dx`` are the signed rows (see :mod:`squkf.rows`) of the
second set's images and of the second set itself. Then ``Sy`` is the
innovation factor, ``L21 = Pxy Sy^-T`` (so the gain is ``K = L21 Sy^-1`` and
``K y = L21 (Sy^-1 y)``), and ``L22 L22^T = Pxx - K Pyy K^T`` is the
posterior covariance whenever the set's covariance ``Pxx`` is the prior's
(``SigmaSet.moments_exact``). That is one QR and two triangular solves, and
no downdate. Every configuration whose set reproduces the prior takes it.

For axis points ``[x, x + gamma S^T, x - gamma S^T]`` with equal pair weights
(``SigmaSet.drawn``) each ``+/-`` pair of joint rows is first rotated by 45
degrees, an orthogonal change of rows (the same Gram matrix, other
roundings) that leaves ``n`` rows with no state part; those are
triangularised first, so the joint QR has ``n + m`` rows instead of
``2n + 1 + m``.

Two fallbacks, each named:

- :func:`_gain_form_posterior`: a user's ``UT`` with a set that reproduces the
  prior. ``Sy`` comes from the ``UT``; the posterior factor is the QR of the
  rows ``Dx - Dz K^T`` and ``K R1_2`` (Joseph form, no downdate).
- :func:`_downdate_posterior`: a set whose covariance is not the prior's (the
  propagated set with process noise, a user's generator). The posterior is
  g13ej's: the prior factor downdated by the columns of ``L21 = K Sy``.

Every array may carry leading batch axes ``(...)``: one filter has none.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple, cast

import numpy as np

from .errors import DowndateError, GainError, PosteriorFactorError
from .generators import SigmaSet
from .linalg import all_finite, chol_downdate_columns, chol_update, solve_lower, tria
from .rows import WeightRows, weight_rows
from .transform import (
    batch_shape,
    central_rows,
    deviations,
    factor_rows,
    signed_rows,
    swap_last,
    transform_factor,
    weighted_mean,
)
from .validate import call_hook, check_hook_result

__all__ = ["Posterior", "measurement_update", "gain_from_factors", "check_gain", "observed_noise_factor"]

_TINY = np.finfo(float).tiny
_INF = float("inf")


class Posterior(NamedTuple):
    """Everything a measurement update produces.

    Attributes
    ----------
    x : ndarray, shape (..., n)
        Posterior mean.
    S : ndarray, shape (..., n, n)
        Lower factor of the posterior covariance.
    y : ndarray, shape (..., m)
        Innovation ``residual_z(z, z_pred)``.
    z_pred : ndarray, shape (..., m)
        Predicted measurement.
    Sy : ndarray, shape (..., m, m)
        Lower factor of the innovation covariance.
    L21 : ndarray, shape (..., n, m)
        ``Pxy Sy^-T`` (equivalently ``K Sy``); :meth:`gain` forms ``K`` from it.
    w : ndarray, shape (..., m)
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
        """The Kalman gain ``K = L21 Sy^-1``, shape ``(..., n, m)`` (one triangular solve)."""
        return gain_from_factors(self.Sy, self.L21)


def gain_from_factors(Sy: np.ndarray, L21: np.ndarray) -> np.ndarray:
    """Kalman gain ``K = L21 Sy^-1`` from the blocks of the joint factor.

    Parameters
    ----------
    Sy : ndarray, shape (..., m, m)
        Lower factor of the innovation covariance.
    L21 : ndarray, shape (..., n, m)
        ``Pxy Sy^-T``.

    Returns
    -------
    K : ndarray, shape (..., n, m)
    """
    Kt = solve_lower(Sy, np.ascontiguousarray(np.swapaxes(L21, -1, -2)), trans=True)
    return np.swapaxes(Kt, -1, -2)


def observed_noise_factor(R1_2: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """Lower factor of the observed block of ``R = R1_2 R1_2^T``, by one QR.

    The block ``R[obs][:, obs]`` is ``R1_2[obs] R1_2[obs]^T``: the rows of the
    factor for the observed components, triangularised (no covariance formed).

    Parameters
    ----------
    R1_2 : ndarray, shape (..., m, m)
    observed : ndarray of bool, shape (m,)

    Returns
    -------
    ndarray, shape (..., m_obs, m_obs)
    """
    rows = np.swapaxes(R1_2[..., observed, :], -1, -2)
    return tria(rows.copy(order="F") if rows.ndim == 2 else rows.copy())


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
    x : ndarray, shape (..., n)
        Prior mean.
    S : ndarray, shape (..., n, n)
        Lower factor of the prior covariance.
    sset : SigmaSet
        The second sigma-point set (``N`` points) and its weights.
    sigmas_h : ndarray, shape (..., N, m)
        The measurement function's values at ``sset.sigmas``.
    z : ndarray, shape (..., m)
        The measurement.
    R1_2 : ndarray, shape (..., m, m)
        Lower factor of the measurement noise covariance.
    z_mean_fn, residual_x, residual_z, state_add : callable, optional
        filterpy's hooks for non-additive quantities (angles), called per
        filter; what they return is checked.
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
    rows = sset.rows if sset.rows is not None else weight_rows(sset.Wm, sset.Wc)
    m = z.shape[-1]
    L22 = None
    if UT is None and sset.moments_exact:
        z_pred, Sy, L21, L22 = _joint_factor(
            sset, rows, sigmas_h, x, S, R1_2, z_mean_fn, residual_x, residual_z
        )
        Dx = Dz = None
    else:
        if UT is None:
            z_pred, Sy = transform_factor(
                sigmas_h, rows, R1_2, z_mean_fn, residual_z, errno=301, hooks=("z_mean_fn", "residual_z")
            )
        else:
            z_pred, Sy = UT(sigmas_h, sset.Wm, sset.Wc, R1_2, z_mean_fn, residual_z)
            z_pred = check_hook_result(z_pred, sigmas_h.shape[:-2] + (m,), "UT")
            Sy = check_hook_result(Sy, sigmas_h.shape[:-2] + (m, m), "UT")
        check_gain(Sy)
        Dz = deviations(sigmas_h, z_pred, residual_z, "residual_z")
        Dx = _state_deviations(sset, x, residual_x)
        Pxy = np.matmul(np.swapaxes(Dx, -1, -2) * sset.Wc, Dz)
        L21 = np.swapaxes(solve_lower(Sy, np.ascontiguousarray(np.swapaxes(Pxy, -1, -2))), -1, -2)
    y = z - z_pred if residual_z is None else _per_filter(residual_z, z, z_pred, "residual_z")
    w = solve_lower(Sy, y)
    dx = L21.dot(w) if L21.ndim == 2 else np.matmul(L21, w[..., None])[..., 0]
    x_post = x + dx if state_add is None else _per_filter(state_add, x, dx, "state_add")
    if L22 is not None:
        S_post = L22
    elif sset.moments_exact:
        S_post = _gain_form_posterior(Sy, L21, Dx, Dz, rows, R1_2)
    else:
        S_post = _downdate_posterior(S, L21)
    if not (all_finite(S_post) and all_finite(x_post)):
        raise PosteriorFactorError("the posterior mean or factor is not finite", errno=303)
    return Posterior(x_post, S_post, y, z_pred, Sy, L21, w)


def _per_filter(fn: Callable, a: np.ndarray, b: np.ndarray, hook: str) -> np.ndarray:
    """The user's hook for ``a + b`` or ``a - b``, called and checked per filter."""
    out: np.ndarray = np.empty(np.broadcast_shapes(a.shape, b.shape))
    d = out.shape[-1]
    for idx in np.ndindex(out.shape[:-1]):
        out[idx] = call_hook(fn, (a[idx] if a.ndim > 1 else a, b[idx] if b.ndim > 1 else b), (d,), hook)
    return out


def _gain_form_posterior(Sy, L21, Dx, Dz, rows: WeightRows, R1_2) -> np.ndarray:
    """Posterior factor as the QR of ``Dx - Dz K^T`` and ``K R1_2`` (a user's UT, exact set)."""
    K = gain_from_factors(Sy, L21)
    return factor_rows(
        Dx - np.matmul(Dz, np.swapaxes(K, -1, -2)),
        rows.mean_form,
        np.matmul(K, R1_2),
        errno=303,
        error=PosteriorFactorError,
    )


def _downdate_posterior(S, L21) -> np.ndarray:
    """g13ej's posterior factor: the prior's downdated by the columns of ``L21 = K Sy``."""
    return chol_downdate_columns(S, L21, errno=303, error=PosteriorFactorError)


def _joint_factor(sset, rows, sigmas_h, x, S, R1_2, z_mean_fn, residual_x, residual_z) -> tuple:
    """``z_pred`` and the blocks ``Sy``, ``L21``, ``L22`` of the joint factor (module docstring).

    Only for a set whose mean and covariance are the prior's: then the
    central form (deviations from the central points) and the mean form
    (deviations from the prior mean and the predicted measurement) agree.
    """
    hooks = z_mean_fn is not None or residual_x is not None or residual_z is not None
    points = sset.sigmas if sset.offsets is None else sset.offsets
    N, m = sigmas_h.shape[-2:]
    n = points.shape[-1]
    batch = batch_shape(sigmas_h, points, R1_2)
    neg: tuple | np.ndarray = ()
    drawn = sset.drawn if not hooks and rows.fast else None
    if drawn is not None and drawn[0].gamma is not None and rows.pair_scale is not None:
        z_pred, L = _paired_joint(sigmas_h, (drawn[0].gamma, drawn[1]), rows, R1_2, batch)
    else:
        if not hooks and rows.fast:
            # every row enters the QR: write them straight into the buffer
            npos = N
            M = np.zeros(batch + (N + m, m + n))  # zeros: the block below the state rows stays 0
            z_pred = central_rows(sigmas_h, rows, M[..., :m])
            if drawn is not None:  # the rows of x + xi S^T are G S^T (one product)
                G, ST, rows_x = drawn[0].G, swap_last(drawn[1]), M[..., :N, m:]
                if ST.ndim == 2:
                    rows_x[...] = G.dot(ST)  # one matrix: BLAS, then a copy, beats matmul into a view
                else:
                    np.matmul(G, ST, out=rows_x)  # a stack: no temporary of the stack's size
            else:
                central_rows(points, rows, M[..., m:])
        else:
            if not hooks and rows.best.central:
                z_pred, Dz, form = signed_rows(sigmas_h, rows)
                _, Dx, _ = signed_rows(points, rows)
            else:
                form = rows.mean_form
                z_pred = weighted_mean(sigmas_h, rows.Wm, z_mean_fn, "z_mean_fn")
                Dz = deviations(sigmas_h, z_pred, residual_z, "residual_z")
                Dx = _state_deviations(sset, x, residual_x)
            pos, neg = form.pos, form.neg
            scale = (form.scale if pos is None else form.scale[pos])[:, None]
            npos = scale.shape[0]
            M = np.zeros(batch + (npos + m, m + n))
            np.multiply(Dz if pos is None else Dz[..., pos, :], scale, out=M[..., :npos, :m])
            np.multiply(Dx if pos is None else Dx[..., pos, :], scale, out=M[..., :npos, m:])
        M[..., npos:, :m] = swap_last(R1_2)
        L = tria(M)
        for k in neg:
            v = form.scale[k] * np.concatenate([Dz[..., k, :], Dx[..., k, :]], axis=-1)
            L = _downdate_joint(L, v, m, form.weights[k])
    Sy = L[..., :m, :m]
    check_gain(Sy)
    # the posterior factor as its own array: checked and read as a whole, never as a strided view
    return z_pred, Sy, L[..., m:, :m], L[..., m:, m:].copy()


def _paired_joint(H, axis, rows: WeightRows, R1_2, batch):
    """``z_pred`` and the joint factor for axis points, each ``+/-`` pair rotated by 45 degrees.

    The pair's rows ``[s e+, s g S^T_i]`` and ``[s e-, -s g S^T_i]`` (``e = h - h_0``) have the
    same Gram matrix as ``[s (e+ + e-) / sqrt2, 0]`` and ``[s (h+ - h-) / sqrt2, sqrt2 s g S^T_i]``.
    The rows without a state part are triangularised first, with ``mu`` and ``R1_2^T``, into
    ``T`` (``m x m``); then the joint QR has ``n + m`` rows instead of ``2n + 1 + m``.
    """
    gamma, S = axis
    n = S.shape[-1]
    m = H.shape[-1]
    c = cast(float, rows.pair_scale)  # not None: the caller checked
    Z = np.empty(batch + (n + 1 + m, m))
    M = np.zeros(batch + (n + m, m + n))  # the block below the state rows stays 0
    h0 = H[..., 0, :]
    E = H[..., 1:, :] - h0[..., None, :]
    mu = rows.wm_tail.dot(E) if E.ndim == 2 else np.matmul(rows.wm_tail, E)
    np.add(E[..., :n, :], E[..., n:, :], out=Z[..., :n, :])
    Z[..., :n, :] *= c
    np.multiply(mu, rows.mu_scale, out=Z[..., n, :])
    Z[..., n + 1 :, :] = swap_last(R1_2)
    T = tria(Z)
    B = M[..., :n, :m]
    np.subtract(H[..., 1 : n + 1, :], H[..., n + 1 :, :], out=B)
    B *= c
    np.multiply(swap_last(S), 2.0 * c * gamma, out=M[..., :n, m:])
    M[..., n:, :m] = swap_last(T)
    return h0 + mu, tria(M)


def _state_deviations(sset: SigmaSet, x: np.ndarray, residual_x: Callable | None) -> np.ndarray:
    """Deviations of the second set from the prior mean (its exact offsets where known)."""
    if sset.offsets is not None and residual_x is None:
        return sset.offsets
    return deviations(sset.sigmas, x, residual_x, "residual_x")


def _downdate_joint(L: np.ndarray, v: np.ndarray, m: int, weight: float) -> np.ndarray:
    """Downdate the joint factor by one negative-weight row, naming the block that failed."""
    try:
        return chol_update(L, v, -1.0)
    except DowndateError as exc:
        try:  # the leading block alone decides whether the innovation factor failed
            chol_update(L[..., :m, :m], v[..., :m], -1.0)
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
    diag = Sy.diagonal() if Sy.ndim == 2 else np.diagonal(Sy, axis1=-2, axis2=-1)
    if Sy.ndim == 2:  # one small matrix: a Python loop beats numpy's reductions
        ok = True
        for v in diag.tolist():
            if not _TINY < abs(v) < _INF:  # a NaN fails too
                ok = False
                break
    else:
        d = np.abs(diag)
        ok = bool(np.all(d > _TINY) and np.all(d < _INF))
    if not ok:
        raise GainError(
            f"innovation factor is singular (diagonal {np.array2string(diag, precision=3)}): "
            "cannot form the Kalman gain",
            errno=302,
        )
