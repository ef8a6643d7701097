"""The square-root unscented transform of a set of weighted points.

Pure functions: points in, mean and lower factor out. Points are rows,
``(n_sigma, dim)``, as filterpy stores ``sigmas_f``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .errors import DowndateError, NonFiniteError, ShapeError
from .linalg import chol_update, tria

__all__ = [
    "weighted_mean",
    "mean_and_deviations",
    "deviations",
    "factor_from_deviations",
    "sqrt_unscented_transform",
]


def weighted_mean(sigmas: np.ndarray, Wm: np.ndarray, mean_fn: Callable | None = None) -> np.ndarray:
    """Weighted mean of the rows of ``sigmas``.

    The plain mean is formed as ``sigmas[0] + Wm @ (sigmas - sigmas[0])``:
    with a small alpha the weights are large and of both signs, and summing
    offsets from a reference point avoids the cancellation of summing the
    points themselves.

    Parameters
    ----------
    sigmas : ndarray, shape (N, d)
    Wm : ndarray, shape (N,)
        Mean weights, summing to 1.
    mean_fn : callable ``mean_fn(sigmas, Wm) -> (d,)``, optional
        Replaces the weighted sum (e.g. a circular mean for angles).

    Returns
    -------
    mean : ndarray, shape (d,)
    """
    if mean_fn is None:
        ref = sigmas[0]
        return ref + Wm @ (sigmas - ref)
    mean = np.asarray(mean_fn(sigmas, Wm), dtype=float).reshape(-1)
    if mean.shape != (sigmas.shape[1],):
        raise ShapeError(f"mean function returned shape {mean.shape}, expected ({sigmas.shape[1]},)")
    return mean


def mean_and_deviations(
    sigmas: np.ndarray,
    Wm: np.ndarray,
    mean_fn: Callable | None = None,
    residual_fn: Callable | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean of the rows of ``sigmas`` and each row's deviation from it.

    Parameters
    ----------
    sigmas : ndarray, shape (N, d)
    Wm : ndarray, shape (N,)
    mean_fn : callable ``mean_fn(sigmas, Wm)``, optional
    residual_fn : callable ``residual_fn(a, b)``, optional

    Returns
    -------
    mean : ndarray, shape (d,)
    dev : ndarray, shape (N, d)
    """
    if mean_fn is None and (residual_fn is None or residual_fn is np.subtract):
        ref = sigmas[0]
        dev = sigmas - ref
        offset = Wm @ dev
        dev -= offset
        return ref + offset, dev
    mean = weighted_mean(sigmas, Wm, mean_fn)
    return mean, deviations(sigmas, mean, residual_fn)


def deviations(sigmas: np.ndarray, mean: np.ndarray, residual_fn: Callable | None = None) -> np.ndarray:
    """Rows ``residual_fn(sigmas[i], mean)`` (plain differences by default).

    Parameters
    ----------
    sigmas : ndarray, shape (N, d)
    mean : ndarray, shape (d,)
    residual_fn : callable ``residual_fn(a, b) -> (d,)``, optional
        Called once per row, with 1-D arrays, as filterpy calls it.

    Returns
    -------
    dev : ndarray, shape (N, d)
    """
    if residual_fn is None or residual_fn is np.subtract:
        return sigmas - mean
    dev = np.empty_like(sigmas)
    for i, s in enumerate(sigmas):
        dev[i] = residual_fn(s, mean)
    return dev


def factor_from_deviations(
    dev: np.ndarray,
    Wc: np.ndarray,
    noise_sqrt: np.ndarray | None = None,
    errno: int = 301,
    error: type[DowndateError] | type = DowndateError,
) -> np.ndarray:
    """Lower factor of ``sum_i Wc[i] dev[i] dev[i]^T + noise_sqrt @ noise_sqrt.T``.

    Rows with a positive weight enter one QR factorisation together with the
    noise factor's columns (for a positive central weight this is the rank-1
    update of g13ej done inside the QR: the same factor, one LAPACK call);
    each row with a negative weight is then removed by an O(n^2) rank-1
    downdate.

    Parameters
    ----------
    dev : ndarray, shape (N, d)
        Deviations from the mean.
    Wc : ndarray, shape (N,)
        Covariance weights, of either sign.
    noise_sqrt : ndarray, shape (d, k), optional
        A square root (any ``k`` columns) of additive noise.
    errno : int
        g13ej error number for a failed downdate.
    error : exception class
        Raised for a failed downdate (a :class:`DowndateError` subclass).

    Returns
    -------
    S : ndarray, shape (d, d)

    Raises
    ------
    DowndateError
        If a negative weight's downdate would lose positive-definiteness.
    """
    pos, sqrt_pos, neg = _weight_split(Wc)
    npos, d = pos.shape[0], dev.shape[1]
    extra = 0 if noise_sqrt is None else noise_sqrt.shape[1]
    rows = np.empty((npos + extra, d), order="F")  # LAPACK's layout: no copy in tria
    np.multiply(sqrt_pos[:, None], dev[pos], out=rows[:npos])
    if extra:
        rows[npos:] = noise_sqrt.T
    S = tria(rows)
    for i in neg:
        if not (S.diagonal() > 0).all():
            raise error(
                f"weight Wc[{i}] = {Wc[i]:.6g} is negative and the factor to downdate is singular",
                errno=errno,
            )
        try:
            S = chol_update(S, np.sqrt(-Wc[i]) * dev[i], -1.0)
        except DowndateError as exc:
            raise error(
                f"weight Wc[{i}] = {Wc[i]:.6g} is negative and its downdate failed: {exc}",
                errno=errno,
            ) from None
    return S


_SPLITS: dict[int, tuple] = {}


def _weight_split(Wc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices of the positive weights, their square roots, and indices of the negative ones.

    Cached per weight array: families hand out the same read-only arrays every step.
    """
    entry = _SPLITS.get(id(Wc))
    if entry is not None and entry[0] is Wc:
        return entry[1]
    pos = np.flatnonzero(Wc > 0)
    split = (pos, np.sqrt(Wc[pos]), np.flatnonzero(Wc < 0))
    if not Wc.flags.writeable:
        if len(_SPLITS) > 256:
            _SPLITS.clear()
        _SPLITS[id(Wc)] = (Wc, split)
    return split


def sqrt_unscented_transform(
    sigmas: np.ndarray,
    Wm: np.ndarray,
    Wc: np.ndarray,
    noise_sqrt: np.ndarray | None = None,
    mean_fn: Callable | None = None,
    residual_fn: Callable | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Square-root unscented transform of propagated sigma points.

    The square-root counterpart of filterpy's ``unscented_transform``: same
    arguments, but the noise is given by its lower factor and the result is
    a lower factor instead of a covariance. A function with this signature
    can be passed as ``UT`` to :meth:`SquareRootUKF.predict` and ``update``.

    Parameters
    ----------
    sigmas : ndarray, shape (N, d)
        Propagated sigma points, one per row.
    Wm, Wc : ndarray, shape (N,)
        Mean and covariance weights.
    noise_sqrt : ndarray, shape (d, d), optional
        Lower factor of the additive noise covariance.
    mean_fn : callable ``mean_fn(sigmas, Wm)``, optional
    residual_fn : callable ``residual_fn(a, b)``, optional

    Returns
    -------
    mean : ndarray, shape (d,)
    S : ndarray, shape (d, d)
        Lower factor of the transformed covariance.
    """
    mean, dev = mean_and_deviations(sigmas, Wm, mean_fn, residual_fn)
    if not np.isfinite(dev).all():
        raise NonFiniteError("sigma-point deviations contain NaN or inf")
    return mean, factor_from_deviations(dev, Wc, noise_sqrt)
