"""Dense square-root linear algebra on lanes: a block of small matrices stepped in lock-step.

Every array here carries the *lane* axis last: ``At[c, r, b]`` is entry ``(r, c)``
of the row matrix of lane ``b``. A lane is one filter. Every inner loop runs
over the lanes (``for b in range(nb)``), so LLVM vectorises it across filters,
and each lane does exactly the same operations in the same order whatever the
other lanes hold and however many there are: a filter's numbers never depend
on the block it is computed in (one filter is a block of one).

Three things keep the vectoriser on (each measured in the prototype of
``shared/prototypes/numba_step``): ``error_model="numpy"`` (the default puts a
ZeroDivisionError branch on every division), a lane count known only at run
time (a constant one is unrolled into scalar code), and no index arithmetic
on global arrays inside a lane loop. No ``fastmath``: reassociation or FMA
contraction would make a lane's rounding depend on the vector width.

These are helpers of the kernels in :mod:`squkf.kernels.phases`, inlined
there; nothing is compiled at import.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["kernel", "tria_lanes", "solve_lower_lanes", "chol_update_lanes"]

#: The decorator of every kernel and helper: compiled on first call, cached on disk, releases the GIL.
kernel = njit(cache=True, nogil=True, error_model="numpy")

_TINY = float(np.finfo(np.float64).tiny)


@kernel
def tria_lanes(At, c, r, nb, V):
    """Householder QR of ``nb`` row matrices ``A`` (``r x c``) held transposed.

    On return the lower triangle of ``At[:c, :min(c, r), b]`` is ``L`` with
    ``L @ L.T == A.T @ A`` and a non-negative diagonal (``L = R.T``): entry
    ``(l, j)`` of ``L``, ``l >= j``, is ``At[l, j, b]``. Above it ``At`` holds
    the reflectors.

    Each column is scaled by its largest entry before its norm is taken
    (no overflow or underflow for entries between 1e-300 and 1e300), and the
    reflector is Parlett's choice ``v0 = -sigma / (x0 + |x|)`` for ``x0 > 0``,
    so the diagonal comes out non-negative with no sign pass (as LAPACK's
    ``dgeqrfp``).

    Parameters
    ----------
    At : ndarray, shape (>= c, >= r, >= nb)
        Overwritten.
    c, r : int
        Columns and rows of each ``A``.
    nb : int
        Lanes in use.
    V : ndarray, shape (>= 6, >= nb)
        Scratch.
    """
    for j in range(min(c, r)):
        for b in range(nb):
            V[0, b] = 0.0
        for i in range(j, r):
            for b in range(nb):
                V[0, b] = max(V[0, b], abs(At[j, i, b]))
        for b in range(nb):
            big = V[0, b] > _TINY
            V[1, b] = 0.0
            V[2, b] = 1.0 / V[0, b] if big else 1.0  # scale s
            V[0, b] = V[0, b] if big else 1.0  # its inverse
        for i in range(j + 1, r):
            for b in range(nb):
                t = At[j, i, b] * V[2, b]
                V[1, b] += t * t
        for b in range(nb):
            sigma = V[1, b]
            x0 = At[j, j, b] * V[2, b]
            a = math.sqrt(x0 * x0 + sigma)
            v0 = x0 - a if x0 <= 0.0 else -sigma / (x0 + a)
            d = sigma + v0 * v0
            V[3, b] = 2.0 * (v0 * v0) / d if d > 0.0 else 0.0  # tau
            V[4, b] = V[2, b] / v0 if v0 != 0.0 else 0.0  # the reflector is [1, A[j+1:, j] s / v0]
            V[5, b] = a * V[0, b]  # R[j, j] >= 0
        for i in range(j + 1, r):
            for b in range(nb):
                At[j, i, b] *= V[4, b]
        for l in range(j + 1, c):
            for b in range(nb):
                V[1, b] = At[l, j, b]
            for i in range(j + 1, r):
                for b in range(nb):
                    V[1, b] += At[j, i, b] * At[l, i, b]
            for b in range(nb):
                V[1, b] *= V[3, b]
                At[l, j, b] -= V[1, b]
            for i in range(j + 1, r):
                for b in range(nb):
                    At[l, i, b] -= V[1, b] * At[j, i, b]
        for b in range(nb):
            At[j, j, b] = V[5, b]


@kernel
def solve_lower_lanes(L, y, n, nb, trans):
    """Solve ``L w = y`` (or ``L.T w = y``) in place for lower-triangular ``L``, on lanes.

    Parameters
    ----------
    L : ndarray, shape (>= n, >= n, >= nb)
        ``L[i, j, b]``, entry ``(i, j)`` of lane ``b``'s factor (read below the diagonal only).
    y : ndarray, shape (>= n, >= nb)
        The right-hand side; overwritten by the solution.
    n, nb : int
    trans : bool
        Solve with ``L.T``.
    """
    if not trans:
        for i in range(n):
            for j in range(i):
                for b in range(nb):
                    y[i, b] -= L[i, j, b] * y[j, b]
            for b in range(nb):
                y[i, b] /= L[i, i, b]
    else:
        for i in range(n - 1, -1, -1):
            for j in range(i + 1, n):
                for b in range(nb):
                    y[i, b] -= L[j, i, b] * y[j, b]
            for b in range(nb):
                y[i, b] /= L[i, i, b]


@kernel
def chol_update_lanes(L, v, n, nb, sign, fail, V):
    """Rank-1 update (``sign > 0``) or downdate of lower factors in place, in O(n^2), on lanes.

    ``L1 @ L1.T == L @ L.T + sign * outer(v, v)`` by one rotation per
    column (LINPACK's ``dchud``/``dchdd`` written for a lower factor). A
    column whose rotation does not exist (a downdate that would lose
    positive-definiteness, a singular ``L``, an overflow) is recorded in
    ``fail[b]`` (the first such column; ``fail[b] < 0`` is left alone only
    while none fails). A failed lane's ``L`` is meaningless.

    The leading ``k x k`` block of the result depends only on the leading
    ``k`` entries of ``v`` and block of ``L``: a failure at a column ``< k``
    is a failure of the leading block's own downdate.

    Parameters
    ----------
    L : ndarray, shape (>= n, >= n, >= nb)
        Lower triangular with a positive diagonal.
    v : ndarray, shape (>= n, >= nb)
        Overwritten.
    n, nb : int
    sign : float
    fail : ndarray of int64, shape (>= nb,)
    V : ndarray, shape (>= 3, >= nb)
        Scratch.
    """
    down = sign < 0.0
    for k in range(n):
        for b in range(nb):
            d = L[k, k, b]
            vk = v[k, b]
            q = d * d - vk * vk if down else d * d + vk * vk
            good = q > 0.0 and d > 0.0 and q < math.inf
            fail[b] = k if (not good and fail[b] < 0) else fail[b]
            rr = math.sqrt(q) if good else 1.0
            dd = d if good else 1.0
            V[0, b] = rr / dd  # c
            V[1, b] = vk / dd  # s
            V[2, b] = -V[1, b] if down else V[1, b]
            L[k, k, b] = rr
        for i in range(k + 1, n):
            for b in range(nb):
                Lik = (L[i, k, b] + V[2, b] * v[i, b]) / V[0, b]
                L[i, k, b] = Lik
                v[i, b] = V[0, b] * v[i, b] - V[1, b] * Lik
