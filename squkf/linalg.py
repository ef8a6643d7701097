"""Square-root linear algebra: the pure functions the filter is built from.

Convention: a covariance ``P`` is carried as a lower-triangular factor ``S``
with ``P = S @ S.T`` and a non-negative diagonal (NAG's ST).  Nothing here
forms ``S @ S.T`` in order to factor it again.

The factorisations, solves and rank-1 modifications are the compiled kernels
of :mod:`squkf.kernels` (no ``check_finite`` pass, no argument re-validation:
every input reaching these functions has been validated once at the boundary
of the library); these functions turn the kernels' status into squkf's
exceptions. Each takes the kernel table to call (``kernels``: a filter's route's,
when one of its phases calls it); without one, the table installed as
:data:`squkf.kernels.table.KERNELS` when it is called.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import lapack

from .errors import DowndateError, GainError, NotPositiveDefiniteError
from .kernels import wrappers
from .kernels.table import KernelTable

__all__ = [
    "all_finite",
    "tria",
    "chol_update",
    "chol_downdate_columns",
    "solve_lower",
    "kalman_gain",
    "factor_covariance",
]

_dpotrf = lapack.get_lapack_funcs("potrf", dtype=np.float64)
_TINY = np.finfo(float).tiny
_DOT_MAX = 4096  # OpenBLAS threads a dot product from 10000 entries on


def all_finite(a: np.ndarray) -> bool:
    """Whether every entry of ``a`` is finite.

    One reduction decides in the usual case: a NaN or an infinity makes
    ``a . a`` (or the sum of ``a``) non-finite. Only when that overflows is
    every entry tested. Small arrays use the BLAS dot product, the cheapest
    call; from ``_DOT_MAX`` entries on, numpy's own sum, because a threaded
    BLAS wakes its threads for a long dot product, which on a busy or
    virtual machine costs milliseconds.

    Parameters
    ----------
    a : ndarray of float

    Returns
    -------
    bool
    """
    s = np.vdot(a, a) if a.size <= _DOT_MAX else a.sum()  # vdot: no overflow warning, unlike ndarray.dot
    return math.isfinite(s) or bool(np.isfinite(a).all())


def tria(rows: np.ndarray, *, kernels: KernelTable | None = None) -> np.ndarray:
    """Lower-triangular factor of ``rows.T @ rows``, by one QR factorisation.

    Parameters
    ----------
    rows : ndarray, shape (..., k, n)
        Each row is one weighted column of a square root: the result ``S``
        satisfies ``S @ S.T == rows.T @ rows`` (for every leading index).
        Factored by the compiled Householder QR of :mod:`squkf.kernels`.
    kernels : KernelTable, optional
        The kernel table to call (a filter's route's); default the installed one.

    Returns
    -------
    S : ndarray, shape (..., n, n)
        Lower triangular with a non-negative diagonal. If ``k < n`` the last
        ``n - k`` columns are zero.
    """
    return wrappers.tria(rows, kernels=kernels)


def solve_lower(
    S: np.ndarray, b: np.ndarray, trans: bool = False, *, kernels: KernelTable | None = None
) -> np.ndarray:
    """Solve ``S @ x = b`` (or ``S.T @ x = b``) for lower-triangular ``S``.

    Parameters
    ----------
    S : ndarray, shape (..., n, n)
        Lower triangular, non-singular.
    b : ndarray, shape (..., n) or (..., n, k)
        Right-hand side(s); a stack of vectors when ``b.ndim == S.ndim - 1``.
    trans : bool
        Solve with ``S.T`` instead of ``S``.
    kernels : KernelTable, optional
        The kernel table to call (a filter's route's); default the installed one.

    Returns
    -------
    x : ndarray, same shape as ``b``

    Raises
    ------
    numpy.linalg.LinAlgError
        If ``S`` has a zero on its diagonal.
    """
    x, ok = wrappers.solve_lower(S, b, trans, kernels=kernels)
    if not ok.all():
        raise np.linalg.LinAlgError("triangular factor is singular: a diagonal element is zero")
    return x


def chol_update(
    S: np.ndarray, v: np.ndarray, sign: float = 1.0, *, kernels: KernelTable | None = None
) -> np.ndarray:
    """Rank-1 update or downdate of a lower Cholesky factor in O(n^2).

    Returns ``S1`` with ``S1 @ S1.T == S @ S.T + sign * outer(v, v)``, by one
    rotation per column (:func:`squkf.kernels.wrappers.chol_update`).

    Parameters
    ----------
    S : ndarray, shape (..., n, n)
        Lower triangular with a positive diagonal. Not modified.
    v : ndarray, shape (..., n)
        The update vector.
    sign : float
        ``+1`` for an update, ``-1`` for a downdate.
    kernels : KernelTable, optional
        The kernel table to call (a filter's route's); default the installed one.

    Returns
    -------
    S1 : ndarray, shape (..., n, n)
        Lower triangular with a positive diagonal.

    Raises
    ------
    DowndateError
        For a downdate whose result would not be positive definite
        (``||S^{-1} v|| >= 1``), a singular ``S``, or a result that is not
        finite (g13ej IFAIL 301).
    """
    S1, fail = wrappers.chol_update(S, v, -1.0 if sign < 0 else 1.0, kernels=kernels)
    if (fail >= 0).any():
        d = np.diagonal(S, axis1=-2, axis2=-1)
        if not (d > 0).all():
            raise DowndateError(
                "cannot modify a singular factor: a diagonal element is not positive", errno=301
            )
        col = int(fail[fail >= 0].flat[0])
        if sign < 0:
            raise DowndateError(
                f"rank-1 downdate would lose positive-definiteness (at column {col}): ||S^-1 v|| >= 1",
                errno=301,
            )
        raise DowndateError(f"rank-1 modification produced a non-finite factor (at column {col})", errno=301)
    return S1


def chol_downdate_columns(
    S: np.ndarray,
    U: np.ndarray,
    errno: int = 303,
    error: type = DowndateError,
    *,
    kernels: KernelTable | None = None,
) -> np.ndarray:
    """Downdate a lower factor by every column of ``U``.

    Returns ``S1`` with ``S1 @ S1.T == S @ S.T - U @ U.T``.

    Parameters
    ----------
    S : ndarray, shape (..., n, n)
        Lower triangular with a positive diagonal.
    U : ndarray, shape (..., n, m)
        Columns to downdate by, one at a time.
    errno : int
        g13ej error number to attach if a downdate fails.
    error : exception class
        Raised when a downdate fails (a :class:`DowndateError` subclass).
    kernels : KernelTable, optional
        The kernel table to call (a filter's route's); default the installed one.

    Returns
    -------
    S1 : ndarray, shape (..., n, n)

    Raises
    ------
    DowndateError
        If the result would not be positive definite.
    """
    for j in range(U.shape[-1]):
        try:
            S = chol_update(S, U[..., j], -1.0, kernels=kernels)
        except DowndateError as exc:
            raise error(f"downdate by column {j}: {exc}", errno=errno) from None
    return S


def kalman_gain(Pxy: np.ndarray, Sy: np.ndarray, *, kernels: KernelTable | None = None) -> np.ndarray:
    """Kalman gain ``K = Pxy @ inv(Sy @ Sy.T)`` by two triangular solves.

    Parameters
    ----------
    Pxy : ndarray, shape (..., n, m)
        State-measurement cross-covariance.
    Sy : ndarray, shape (..., m, m)
        Lower-triangular factor of the innovation covariance.
    kernels : KernelTable, optional
        The kernel table to call (a filter's route's); default the installed one.

    Returns
    -------
    K : ndarray, shape (..., n, m)

    Raises
    ------
    GainError
        If ``Sy`` is singular (g13ej IFAIL 302).
    """
    d = np.abs(np.diagonal(Sy, axis1=-2, axis2=-1))
    if not (d > _TINY).all() or not np.isfinite(d).all():
        raise GainError(
            f"innovation factor is singular (diagonal {np.array2string(d, precision=3)}): "
            "cannot form the Kalman gain",
            errno=302,
        )
    # K^T = Sy^-T Sy^-1 Pxy^T
    W = solve_lower(Sy, np.ascontiguousarray(np.swapaxes(Pxy, -1, -2)), kernels=kernels)
    return np.swapaxes(solve_lower(Sy, W, trans=True, kernels=kernels), -1, -2)


def factor_covariance(A: np.ndarray, name: str, semidefinite: bool = False) -> np.ndarray:
    """Lower factor of a covariance matrix supplied by the user.

    This is the only place a covariance is factored: a matrix the user gave
    (``P``, ``Q`` or ``R``), once, when it is assigned.

    Parameters
    ----------
    A : ndarray, shape (n, n)
        Symmetric (already checked), finite.
    name : str
        The argument's name, for the error message.
    semidefinite : bool
        Accept a singular positive semi-definite matrix (a process noise of
        lower rank, e.g. ``Q_discrete_white_noise``). Its factor is lower
        triangular with zeros where the rank is missing.

    Returns
    -------
    S : ndarray, shape (n, n)

    Raises
    ------
    NotPositiveDefiniteError
        If ``A`` is not positive definite (or, with ``semidefinite``, has a
        clearly negative eigenvalue).
    """
    n = A.shape[0]
    c, info = _dpotrf(A, lower=1, clean=1, overwrite_a=0)
    if info == 0:
        return c
    if semidefinite:
        w, V = np.linalg.eigh(A)
        scale = max(float(np.max(np.abs(w))), np.finfo(float).tiny)
        tol = 16 * n * np.finfo(float).eps * scale
        if w[0] >= -tol:
            w = np.clip(w, 0.0, None)
            return tria(np.ascontiguousarray((V * np.sqrt(w)).T))
        raise NotPositiveDefiniteError(
            f"{name} is not positive semi-definite: smallest eigenvalue {w[0]:.6g} (largest {w[-1]:.6g})"
        )
    raise NotPositiveDefiniteError(
        f"{name} is not positive definite: leading minor {info} of the {n}x{n} matrix is not positive"
    )
