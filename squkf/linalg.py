"""Square-root linear algebra: the pure functions the filter is built from.

Convention: a covariance ``P`` is carried as a lower-triangular factor ``S``
with ``P = S @ S.T`` and a non-negative diagonal (NAG's ST).  Nothing here
forms ``S @ S.T`` in order to factor it again.

The LAPACK routines are called directly (no ``check_finite`` pass, no argument
re-validation): every input reaching these functions has been validated once
at the boundary of the library.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import lapack

from .errors import DowndateError, GainError, NotPositiveDefiniteError

__all__ = [
    "all_finite",
    "tria",
    "chol_update",
    "chol_downdate_columns",
    "solve_lower",
    "kalman_gain",
    "factor_covariance",
]

_dgeqrfp = lapack.get_lapack_funcs("geqrfp", dtype=np.float64)
_dtrtrs = lapack.get_lapack_funcs("trtrs", dtype=np.float64)
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


def tria(rows: np.ndarray) -> np.ndarray:
    """Lower-triangular factor of ``rows.T @ rows``, by one QR factorisation.

    Parameters
    ----------
    rows : ndarray, shape (..., k, n)
        Each row is one weighted column of a square root: the result ``S``
        satisfies ``S @ S.T == rows.T @ rows`` (for every leading index). A
        single matrix is factored by LAPACK's ``dgeqrfp`` in place (give it in
        Fortran order to avoid a copy); a stack by numpy's stacked QR.

    Returns
    -------
    S : ndarray, shape (..., n, n)
        Lower triangular with a non-negative diagonal. If ``k < n`` the last
        ``n - k`` columns are zero.
    """
    k, n = rows.shape[-2:]
    if rows.ndim == 2:
        # dgeqrfp: R with a non-negative diagonal, so no sign pass (which cost more than the QR
        # itself on a small matrix). LAPACK's blocked QR needs a workspace of n * block size;
        # below ~16 columns the unblocked code (scipy's default workspace) is faster
        if n >= 16:
            qr, _, info = _dgeqrfp(rows, lwork=32 * n, overwrite_a=1)
        else:
            qr, _, info = _dgeqrfp(rows, overwrite_a=1)
        if info != 0:  # pragma: no cover - LAPACK argument error, cannot happen here
            raise RuntimeError(f"LAPACK dgeqrfp failed with info={info}")
        # below R's diagonal LAPACK leaves its Householder vectors: keep the triangle only
        if k >= n:
            return qr[:n].T * _lower_mask(n)
        S = np.zeros((n, n))
        S[:, :k] = qr.T
        S *= _lower_mask(n)
        return S
    R = np.linalg.qr(rows, mode="r")  # (..., min(k, n), n), upper triangular
    if k >= n:
        S = np.swapaxes(R, -1, -2)
    else:
        S = np.zeros(rows.shape[:-2] + (n, n))
        S[..., :k] = np.swapaxes(R, -1, -2)
    return S * np.copysign(1.0, np.diagonal(S, axis1=-2, axis2=-1))[..., None, :]


_LOWER_MASKS: dict[int, np.ndarray] = {}


def _lower_mask(n: int) -> np.ndarray:
    mask = _LOWER_MASKS.get(n)
    if mask is None:
        mask = _LOWER_MASKS[n] = np.tril(np.ones((n, n)))
    return mask


def solve_lower(S: np.ndarray, b: np.ndarray, trans: bool = False) -> np.ndarray:
    """Solve ``S @ x = b`` (or ``S.T @ x = b``) for lower-triangular ``S``.

    Parameters
    ----------
    S : ndarray, shape (..., n, n)
        Lower triangular, non-singular.
    b : ndarray, shape (..., n) or (..., n, k)
        Right-hand side(s); a stack of vectors when ``b.ndim == S.ndim - 1``.
    trans : bool
        Solve with ``S.T`` instead of ``S``.

    Returns
    -------
    x : ndarray, same shape as ``b``

    Raises
    ------
    numpy.linalg.LinAlgError
        If ``S`` has a zero on its diagonal.
    """
    if S.ndim == 2:
        x, info = _dtrtrs(S, b, lower=1, trans=1 if trans else 0)
        if info > 0:
            raise np.linalg.LinAlgError(f"triangular factor is singular: diagonal element {info - 1} is zero")
        return x
    vector = b.ndim == S.ndim - 1
    B = b[..., None] if vector else b
    d = np.diagonal(S, axis1=-2, axis2=-1)
    if not np.all(d != 0):
        raise np.linalg.LinAlgError("triangular factor is singular: a diagonal element is zero")
    n = S.shape[-1]
    X = np.empty(np.broadcast_shapes(S.shape[:-2], B.shape[:-2]) + B.shape[-2:])
    # substitution row by row, each step vectorised over the stack and the right-hand sides
    order = range(n - 1, -1, -1) if trans else range(n)
    done: list[int] = []
    for i in order:
        coef = S[..., done, i] if trans else S[..., i, done]  # (..., len(done))
        acc = B[..., i, :] - np.einsum("...j,...jk->...k", coef, X[..., done, :]) if done else B[..., i, :]
        X[..., i, :] = acc / d[..., i, None]
        done.append(i)
    return X[..., 0] if vector else X


def chol_update(S: np.ndarray, v: np.ndarray, sign: float = 1.0) -> np.ndarray:
    """Rank-1 update or downdate of a lower Cholesky factor in O(n^2).

    Returns ``S1`` with ``S1 @ S1.T == S @ S.T + sign * outer(v, v)``.

    The factor of ``I + sign * p p^T`` with ``p = S^{-1} v`` is a structured
    triangular matrix whose entries follow from the partial sums of ``p**2``
    (Gill, Golub, Murray & Saunders 1974, method C1); multiplying ``S`` by it
    needs one triangular solve and a reverse cumulative sum, all vectorised.

    Parameters
    ----------
    S : ndarray, shape (..., n, n)
        Lower triangular with a positive diagonal. Not modified.
    v : ndarray, shape (..., n)
        The update vector.
    sign : float
        ``+1`` for an update, ``-1`` for a downdate.

    Returns
    -------
    S1 : ndarray, shape (..., n, n)
        Lower triangular with a positive diagonal.

    Raises
    ------
    DowndateError
        For a downdate whose result would not be positive definite
        (``||S^{-1} v|| >= 1``), or if ``S`` is singular (g13ej IFAIL 301).
    """
    n = S.shape[-1]
    try:
        p = solve_lower(S, v)
    except np.linalg.LinAlgError as exc:
        raise DowndateError(f"cannot modify a singular factor: {exc}", errno=301) from None
    sigma = 1.0 if sign > 0 else -1.0
    # c[j] = 1/sigma_j, with sigma_1 = sign and 1/sigma_{j+1} = 1/sigma_j + p_j^2.
    c = np.empty(p.shape[:-1] + (n + 1,))
    c[..., 0] = sigma
    np.cumsum(p * p, axis=-1, out=c[..., 1:])
    c[..., 1:] += sigma
    if sigma < 0 and not np.all(c[..., n] < 0.0):
        worst = float(np.max(1.0 + c[..., n]))
        raise DowndateError(
            f"rank-1 downdate would lose positive-definiteness: ||S^-1 v||^2 = {worst:.17g} >= 1",
            errno=301,
        )
    d = np.sqrt(c[..., 1:] / c[..., :-1])
    beta = p / (c[..., :-1] * d)
    # tail[..., :, j] = sum_{i > j} p_i S[..., :, i]
    Sp = S * p[..., None, :]
    tail = np.zeros_like(Sp)
    if n > 1:
        tail[..., :-1] = np.cumsum(Sp[..., :0:-1], axis=-1)[..., ::-1]
    # column j of S and of tail vanish above row j, so S1 is lower triangular as computed
    S1 = S * d[..., None, :]
    S1 += tail * beta[..., None, :]
    if not np.isfinite(S1).all():
        raise DowndateError("rank-1 modification produced a non-finite factor", errno=301)
    return S1


def chol_downdate_columns(
    S: np.ndarray, U: np.ndarray, errno: int = 303, error: type = DowndateError
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
            S = chol_update(S, U[..., j], -1.0)
        except DowndateError as exc:
            raise error(f"downdate by column {j}: {exc}", errno=errno) from None
    return S


def kalman_gain(Pxy: np.ndarray, Sy: np.ndarray) -> np.ndarray:
    """Kalman gain ``K = Pxy @ inv(Sy @ Sy.T)`` by two triangular solves.

    Parameters
    ----------
    Pxy : ndarray, shape (..., n, m)
        State-measurement cross-covariance.
    Sy : ndarray, shape (..., m, m)
        Lower-triangular factor of the innovation covariance.

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
    W = solve_lower(Sy, np.ascontiguousarray(np.swapaxes(Pxy, -1, -2)))
    return np.swapaxes(solve_lower(Sy, W, trans=True), -1, -2)


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
