"""The compiled kernels: each phase of the square-root step over a stack of filters.

Every kernel takes C-contiguous float64 stacks with the filter axis first,
``(B, ...)``, loops over the filters inside, and writes its results into
output arrays it is given (one signature each: compiled once, cached on
disk). Inside, filters are taken a block of lanes at a time (below):
loaded into lane-last scratch, stepped in lock-step, stored back. A
filter's numbers never depend on the block, so a filter alone equals the
same filter in a fleet, bit for bit.

An array that may be shared by every filter (a noise factor, a prior mean)
is given with a leading axis of 1 and read for each filter from row 0.

Row forms (see :mod:`squkf.rows`), a number ``mode``:

0. central: row ``r < N - 1`` is ``P[r + 1] - P[0]``, row ``N - 1`` is
   ``mu = sum_{i>=1} wm[i] (P[i] - P[0])``; the mean is ``P[0] + mu``.
1. mean: the mean is ``P[0] + sum_{i>=1} wm[i] (P[i] - P[0])``; row ``r`` is
   ``P[r] - mean`` (state rows: ``X[r] - xref``).
2. given: the rows are the array itself (the user's hooks formed them in
   Python); the mean is the reference given.

Row ``r`` enters with weight ``sign[r] * scale[r]**2``: positive rows go
into one QR, each negative row is removed after it by a rank-1 downdate,
zero rows are left out.

Status codes per filter: 0 success; in :func:`transform_kernel`, ``r + 1``
when the downdate of negative row ``r`` failed and ``-(r + 1)`` when the
factor was already singular before it, 305 for a result that is not finite;
in the updates, g13ej's 301 (the innovation factor's downdate failed), 302
(singular innovation factor), 303 (the posterior could not be formed), 304
(the posterior factor has a zero on its diagonal); 306 in both for images
(the points transformed, the measurement function's values) that are not
finite.

The update kernels' outputs are declared here too, by name (:class:`JointUpdate`, the fields of
:class:`squkf.engine.Update` they are, and :func:`update_outputs`, their arrays): what a kernel writes
and what it is called are one edit.

Lanes
-----
The dense square-root linear algebra (Householder QR, triangular solves,
rank-1 updates) works on lanes: a block of small matrices in lock-step.
Every scratch array carries the *lane* axis last: ``At[c, r, b]`` is entry ``(r, c)``
of the row matrix of lane ``b``. A lane is one filter. Every inner loop runs
over the lanes (``for b in range(nb)``), so LLVM vectorises it across filters,
and each lane does exactly the same operations in the same order whatever the
other lanes hold and however many there are: a filter's numbers never depend
on the block it is computed in (one filter is a block of one).

Three things keep the vectoriser on (each measured on a prototype of these
kernels): ``error_model="numpy"`` (the default puts a
ZeroDivisionError branch on every division), a lane count known only at run
time (a constant one is unrolled into scalar code), and no index arithmetic
on global arrays inside a lane loop. No ``fastmath``: reassociation or FMA
contraction would make a lane's rounding depend on the vector width.

One filter is a block of one lane: the same code with ``nb`` 1 (no second,
one-lane copy of any helper: it doubled the compile time and saved nothing
measurable, the kernels being a small part of one filter's step). The
deviation buffers are point-major (``Pl[i, l, b]``, point ``i``, component
``l``): a filter's points load as they are, and a sum over the points runs
over every component at once (each component's sum still in the order of
the points).

Every compiled function lives in this one module on purpose: numba's disk
cache is keyed on the source file of the kernel called, not on the files of
the functions it calls, so a helper in another module could be edited and
its callers still load the old machine code. Nothing is compiled at import.

Compile time
------------
numba compiles each helper on its own (optimised, machine code made) and
links that module into every caller, whose module is optimised and made into
machine code again: a helper's code is compiled once for itself and once for
each function above it, up to each kernel. So the call graph is kept flat:
the kernels call the large helpers themselves (the QR, the triangular solve
and the rank-1 updates under at most one small helper), a piece with one
caller is written in that caller, and a helper has no Python or C wrapper (it
is only ever called from a kernel). Inlining helpers into their callers in
numba's IR (``inline="always"``) was measured slower: numba's own passes grow
faster than linearly with a function's size. A helper's number of copies is
what ``benchmarks/compile_time.py`` measures in the end.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import types
from numba.np.linalg import _LAPACK

from .cache import jit

__all__ = [
    "LAPACK_MIN_COLUMNS",
    "JointUpdate",
    "update_outputs",
    "tria_kernel",
    "solve_kernel",
    "chol_update_kernel",
    "points_kernel",
    "finite_rows_kernel",
    "transform_kernel",
    "joint_update_kernel",
    "downdate_update_kernel",
    "angle_rows_kernel",
]

_TINY = float(np.finfo(np.float64).tiny)
_LOG_2PI = math.log(2.0 * math.pi)
_PI = math.pi
_TWO_PI = 2.0 * math.pi


class JointUpdate(NamedTuple):
    """What an update kernel writes (:func:`joint_update_kernel`, :func:`downdate_update_kernel`): its
    outputs in their order, by the names of :class:`squkf.engine.Update`'s fields where they are one.

    Plain Python (not compiled): :func:`squkf.kernels.wrappers.update_stacks` gives it in the caller's
    batch shape, :func:`squkf.measurement.measurement_update` returns it, the engine takes it into an
    ``Update`` by name.

    Attributes
    ----------
    z_pred, y, w : ndarray, shape (..., m)
        Predicted measurement, innovation, ``Sy^-1 y``.
    Sy : ndarray, shape (..., m, m)
    L21 : ndarray, shape (..., n, m)
    dx, x : ndarray, shape (..., n)
        ``L21 w`` and the posterior mean ``x + dx``.
    S : ndarray, shape (..., n, n)
        The posterior factor.
    log_likelihood, nis, log_det_S1_2 : ndarray, shape (...)
        The measurement's Gaussian log-likelihood, its squared Mahalanobis distance ``w.w`` and
        ``log det Sy``.
    status : ndarray of int, shape (...)
        0, or g13ej's 301, 302, 303 (304: a zero on the posterior factor's diagonal; 306: images
        not finite).
    """

    z_pred: np.ndarray
    y: np.ndarray
    w: np.ndarray
    Sy: np.ndarray
    L21: np.ndarray
    dx: np.ndarray
    x: np.ndarray
    S: np.ndarray
    log_likelihood: np.ndarray
    nis: np.ndarray
    log_det_S1_2: np.ndarray
    status: np.ndarray


def update_outputs(B: int, n: int, m: int) -> JointUpdate:
    """New arrays for an update kernel's outputs over a stack of ``B`` filters (``n`` states, ``m``
    measured components), :class:`JointUpdate`'s fields in its order."""
    return JointUpdate(
        np.empty((B, m)), np.empty((B, m)), np.empty((B, m)), np.empty((B, m, m)), np.empty((B, n, m)),
        np.empty((B, n)), np.empty((B, n)), np.empty((B, n, n)), np.empty(B), np.empty(B), np.empty(B),
        np.empty(B, dtype=np.int64),
    )  # fmt: skip


#: The decorator of every kernel: compiled on first call, releases the GIL, cached on disk where numba has a
#: writable place, else in memory with a warning (:mod:`squkf.kernels.cache`). No C-callable wrapper: a
#: kernel is called from Python or from another kernel, never through a C pointer (the wrapper would only
#: add compile time).
kernel = jit(nogil=True, error_model="numpy", no_cfunc_wrapper=True)
#: The decorator of every helper: a kernel called only from other kernels, so with no Python wrapper either.
_helper = jit(nogil=True, error_model="numpy", no_cfunc_wrapper=True, no_cpython_wrapper=True)
#: Inlined into its caller (numba IR), so that it never compiles on its own (:func:`_unfold`).
_inline = jit(nogil=True, error_model="numpy", inline="always")
_LANES = 64
_SCRATCH = 32768  # entries of the largest lane scratch array (keeps a block's arrays in cache)


@_inline
def _unfold(v):
    """``v`` typed as a plain integer, not as the literal it is (a constant ``0`` handed to a helper):
    numba compiles a callee once per argument type and a literal is a type of its own, so a helper
    given ``0`` in one place and a variable in another would otherwise compile twice."""
    return v + 0


@_inline
def _wrap(a):
    """``(a + pi) % (2 pi) - pi``, as :func:`squkf.angles.wrap` (the same bits): the modulo, a division,
    skipped where ``a + pi`` is already in ``[0, 2 pi)``, where it would give ``a + pi`` itself (a NaN
    fails the test and takes the modulo)."""
    t = a + _PI
    if 0.0 <= t < _TWO_PI:
        return t - _PI
    return t % _TWO_PI - _PI


#: From this many columns on, each lane's QR is LAPACK's blocked ``dgeqrf`` (the routine numba's own
#: ``np.linalg.qr`` calls, through scipy's LAPACK), then a sign pass; below it, the Householder loops
#: across lanes. Chosen by the matrix's size alone, so a filter takes the same path alone or in a fleet.
LAPACK_MIN_COLUMNS = 16
_geqrf = _LAPACK().numba_ez_geqrf(types.float64)
_KIND = ord("d")


@_helper
def tria_lanes(At, c, r, nb, V):
    """Householder QR of ``nb`` row matrices ``A`` (``r x c``) held transposed.

    On return the lower triangle of ``At[:c, :min(c, r), b]`` is ``L`` with
    ``L @ L.T == A.T @ A`` and a non-negative diagonal (``L = R.T``): entry
    ``(l, j)`` of ``L``, ``l >= j``, is ``At[l, j, b]``. Above it ``At`` holds
    the reflectors.

    From ``LAPACK_MIN_COLUMNS`` columns on, each lane is one ``dgeqrf`` instead, then each row of
    ``R`` is made non-negative.

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
    if c >= LAPACK_MIN_COLUMNS:
        tau = np.empty(max(1, min(r, c)))
        F = np.empty(r * c)  # the lane's matrix in Fortran order
        for b in range(nb):
            for j in range(c):
                for i in range(r):
                    F[i + j * r] = At[j, i, b]
            _geqrf(_KIND, r, c, F.ctypes, r, tau.ctypes)
            for j in range(min(r, c)):
                s = -1.0 if F[j + j * r] < 0.0 else 1.0
                for l in range(j, c):
                    At[l, j, b] = s * F[j + l * r]
        return
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


@_helper
def solve_lower_lanes(L, y, n, nb, trans):
    """Solve ``L w = y`` (or ``L.T w = y``) in place for lower-triangular ``L``, on lanes.

    Parameters
    ----------
    L : ndarray, shape (>= n, >= n, >= nb)
        ``L[i, j, b]``, entry ``(i, j)`` of lane ``b``'s factor (read below the diagonal only).
    y : ndarray, shape (>= n, >= nb)
        The right-hand side; overwritten by the solution.
    n, nb : int
    trans : int
        Non-zero: solve with ``L.T``.
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


@_helper
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


@_helper
def _lanes(size, B):
    """Lanes per block for a scratch matrix of ``size`` entries per filter: 64 at most, and no
    more than the ``B`` filters there are (one filter's scratch is then contiguous)."""
    return max(1, min(_LANES, _SCRATCH // max(size, 1), B))


# Loads go through the block's slice ``a[k0:k0 + nb]`` with the lane loop innermost: twice as fast
# as a loop per filter (measured), with no index arithmetic in a lane loop. Stores of whole point
# sets stay a loop per filter (contiguous rows: faster there, measured).


@_helper
def _finite_lanes(Pl, N, d, nb, acc):
    """``acc[b] == 0`` exactly when lane ``b``'s ``N x d`` values are all finite (a NaN sum otherwise).

    ``x * 0`` is 0 for a finite ``x`` and NaN for an infinity or a NaN: one branch-free sum a lane,
    which the lane loop vectorises.
    """
    for b in range(nb):
        acc[b] = 0.0
    for i in range(N):
        for l in range(d):
            for b in range(nb):
                acc[b] += Pl[i, l, b] * 0.0


@_helper
def _load_vector(a, k0, nb, al):
    """``al[l, b] = a[k0 + b, l]``, or ``a[0, l]`` for a shared ``a``."""
    if a.shape[0] == 1:
        for l in range(a.shape[1]):
            c = a[0, l]
            for b in range(nb):
                al[l, b] = c
        return
    Q = a[k0 : k0 + nb]
    for l in range(a.shape[1]):
        for b in range(nb):
            al[l, b] = Q[b, l]


@_helper
def _load_matrix(a, k0, nb, al):
    """``al[i, j, b] = a[k0 + b, i, j]``, or ``a[0, i, j]`` for a shared ``a`` (a block of one filter's
    points too: point-major, its points are copied as they are)."""
    if a.shape[0] == 1:
        # a lane at a time: the same copies, and a third of the machine code (re-optimised in each
        # kernel that calls this, lane-innermost loops here were unrolled three times over)
        for b in range(nb):
            for i in range(a.shape[1]):
                for j in range(a.shape[2]):
                    al[i, j, b] = a[0, i, j]
        return
    Q = a[k0 : k0 + nb]
    for i in range(a.shape[1]):
        for j in range(a.shape[2]):
            for b in range(nb):
                al[i, j, b] = Q[b, i, j]


@_helper
def _store_lower(L, i0, n, k0, nb, out):
    """``out[k0 + b] = tril(L[i0:i0 + n, i0:i0 + n, b])``, a diagonal block of the lanes' factors."""
    Q = out[k0 : k0 + nb]
    for i in range(n):
        for j in range(n):
            if j <= i:
                for b in range(nb):
                    Q[b, i, j] = L[i0 + i, i0 + j, b]
            else:
                for b in range(nb):
                    Q[b, i, j] = 0.0


@_helper
def _deviations(Pl, N, d, nb, mode, wm, mean):
    """The rows of a form in place in ``Pl`` (``N x d x nb``) and the mean in ``mean`` (``d x nb``).

    Point by point, each over every component and lane, so that one filter's loops are long too; each
    component's sum still runs over the points in order. Mode 2 changes nothing: the rows are given and
    ``mean`` already holds the reference.
    """
    if mode == 2:
        return
    for l in range(d):
        for b in range(nb):
            mean[l, b] = 0.0
    for i in range(1, N):
        w = wm[i]
        if mode == 0:
            for l in range(d):
                for b in range(nb):
                    e = Pl[i, l, b] - Pl[0, l, b]
                    mean[l, b] += w * e
                    Pl[i, l, b] = e
        else:
            for l in range(d):
                for b in range(nb):
                    mean[l, b] += w * (Pl[i, l, b] - Pl[0, l, b])
    if mode == 0:
        for l in range(d):
            for b in range(nb):
                mu = mean[l, b]
                mean[l, b] = Pl[0, l, b] + mu
                Pl[0, l, b] = mu
    else:
        for l in range(d):
            for b in range(nb):
                mean[l, b] += Pl[0, l, b]
        for i in range(N):
            for l in range(d):
                for b in range(nb):
                    Pl[i, l, b] -= mean[l, b]


@_helper
def _state_rows(Xl, N, n, nb, mode, wm, xref):
    """State rows in place in ``Xl`` (``N x n x nb``): central (mode 0), ``X - xref`` (1), as given (2)."""
    if mode == 0:
        for l in range(n):
            for b in range(nb):
                xref[l, b] = 0.0
        for i in range(1, N):
            w = wm[i]
            for l in range(n):
                for b in range(nb):
                    e = Xl[i, l, b] - Xl[0, l, b]
                    Xl[i, l, b] = e
                    xref[l, b] += w * e
        for l in range(n):
            for b in range(nb):
                Xl[0, l, b] = xref[l, b]
    elif mode == 1:
        for i in range(N):
            for l in range(n):
                for b in range(nb):
                    Xl[i, l, b] -= xref[l, b]


@_helper
def _weighted_rows(D1, D2, N, nb, mode, scale, sign, noise, k0, At):
    """The positive rows and a noise factor's columns into ``At``, for one QR (the caller's).

    Each row is ``[D1[r], D2[r]]`` (``d1 + d2`` entries, row ``r`` of form ``mode`` in the
    deviation buffers ``D1``, ``D2``, ``(N, d, nb)`` each), entering with weight
    ``sign[r] * scale[r]**2``: the positive rows, scaled, then the noise's columns (padded with zeros
    to ``d1 + d2`` entries), then zero rows up to ``d1 + d2``: ``rows`` = the positive rows + ``q``.
    The caller factors them (:func:`tria_lanes`) and downdates the negative rows (:func:`_downdated_rows`).

    Parameters
    ----------
    D1, D2 : ndarray, shape (N, d1, >= nb), (N, d2, >= nb)
    N, nb, mode : int
    scale, sign : ndarray, shape (N,)
    noise : ndarray, shape (B or 1, dn, q)
        ``dn <= d1``.
    k0 : int
    At : ndarray, shape (d1 + d2, >= max(rows, d1 + d2), >= nb)
    """
    d1, d2 = D1.shape[1], D2.shape[1]
    d = d1 + d2
    dn, q = noise.shape[1], noise.shape[2]
    shared = noise.shape[0] == 1
    npos = 0
    for r in range(N):
        if sign[r] > 0.0:
            src = (r + 1 if r < N - 1 else 0) if mode == 0 else r  # central: mu is in slot 0
            c = scale[r]
            for l in range(d1):
                for b in range(nb):
                    At[l, npos, b] = c * D1[src, l, b]
            for l in range(d2):
                for b in range(nb):
                    At[d1 + l, npos, b] = c * D2[src, l, b]
            npos += 1
    rows = npos + q
    for b in range(nb):
        Nk = noise[0] if shared else noise[k0 + b]
        for l in range(d):
            for j in range(q):
                At[l, npos + j, b] = Nk[l, j] if l < dn else 0.0
    for i in range(d):  # fewer rows than columns: the factor's last columns are zero
        for j in range(rows, d):
            for b in range(nb):
                At[i, j, b] = 0.0


@_helper
def _downdated_rows(D1, D2, N, nb, mode, scale, sign, split, At, V, v, fl, st):
    """Each negative row of :func:`_weighted_rows`' form downdated from the factor ``L`` in ``At``.

    ``st[b]`` is set to 0, or for a failed downdate to the row ``r + 1`` (``split == 0``) or to
    g13ej's 301 when it failed in the first ``split`` columns and 303 after (the joint factor: its
    leading block is ``Sy``).

    Parameters
    ----------
    D1, D2, N, nb, mode, scale, sign
        As :func:`_weighted_rows`.
    split : int
    At : ndarray, shape (d1 + d2, >= d1 + d2, >= nb)
        ``L`` below its diagonal (read nowhere above it); downdated in place.
    V, v, fl, st : scratch, shape (>= 6, nb), (>= d1 + d2, nb), (nb,), (nb,)
    """
    d1, d2 = D1.shape[1], D2.shape[1]
    for b in range(nb):
        st[b] = 0
    for r in range(N):
        if sign[r] < 0.0:
            src = (r + 1 if r < N - 1 else 0) if mode == 0 else r
            c = scale[r]
            for b in range(nb):
                fl[b] = -1
            for l in range(d1):
                for b in range(nb):
                    v[l, b] = c * D1[src, l, b]
            for l in range(d2):
                for b in range(nb):
                    v[d1 + l, b] = c * D2[src, l, b]
            chol_update_lanes(At, v, d1 + d2, nb, -1.0, fl, V)
            for b in range(nb):
                code = r + 1 if split == 0 else (301 if fl[b] < split else 303)
                st[b] = code if (fl[b] >= 0 and st[b] == 0) else st[b]


@kernel
def tria_kernel(A, S):
    """``S[k]``: the lower factor (non-negative diagonal) of ``A[k].T @ A[k]``.

    Parameters
    ----------
    A : ndarray, shape (B, r, c)
    S : ndarray, shape (B, c, c)
        Output.
    """
    B, r, c = A.shape
    nl = _lanes(r * c, B)
    At = np.empty((c, max(r, 1), nl))
    V = np.empty((6, nl))
    for k0 in range(0, B, nl):
        nb = min(nl, B - k0)
        for b in range(nb):
            Ak = A[k0 + b]
            for i in range(r):
                for l in range(c):
                    At[l, i, b] = Ak[i, l]
        tria_lanes(At, c, r, nb, V)
        for b in range(nb):
            Sk = S[k0 + b]
            for i in range(c):
                for j in range(c):
                    Sk[i, j] = At[i, j, b] if (j <= i and j < r) else 0.0


@kernel
def solve_kernel(L, Y, trans, X, ok):
    """``X[k] = L[k]^-1 Y[k]`` (``L[k].T`` for ``trans``) by substitution; ``ok[k]``: no zero pivot.

    Parameters
    ----------
    L : ndarray, shape (B or 1, n, n)
        Lower triangular.
    Y : ndarray, shape (B, n, q)
    trans : int
    X : ndarray, shape (B, n, q)
        Output.
    ok : ndarray of bool, shape (B,)
        Output.
    """
    B, n, q = Y.shape
    nl = _lanes(n * n, B)
    Ll = np.empty((n, n, nl))
    y = np.empty((n, nl))
    for k0 in range(0, B, nl):
        nb = min(nl, B - k0)
        _load_matrix(L, k0, nb, Ll)
        for b in range(nb):
            good = True
            for i in range(n):
                good = good and Ll[i, i, b] != 0.0
            ok[k0 + b] = good
        for j in range(q):
            for b in range(nb):
                Yk = Y[k0 + b]
                for i in range(n):
                    y[i, b] = Yk[i, j]
            solve_lower_lanes(Ll, y, n, nb, trans)
            for b in range(nb):
                Xk = X[k0 + b]
                for i in range(n):
                    Xk[i, j] = y[i, b]


@kernel
def chol_update_kernel(L, v, sign, out, fail):
    """``out[k] @ out[k].T == L[k] @ L[k].T + sign * outer(v[k], v[k])``; ``fail[k]``: failing column or -1.

    Parameters
    ----------
    L : ndarray, shape (B, n, n)
    v : ndarray, shape (B, n)
    sign : float
    out : ndarray, shape (B, n, n)
        Output.
    fail : ndarray of int64, shape (B,)
        Output.
    """
    B, n = v.shape
    nl = _lanes(n * n, B)
    Ll = np.empty((n, n, nl))
    vl = np.empty((n, nl))
    V = np.empty((3, nl))
    fl = np.empty(nl, dtype=np.int64)
    for k0 in range(0, B, nl):
        nb = min(nl, B - k0)
        _load_matrix(L, k0, nb, Ll)
        _load_vector(v, k0, nb, vl)
        for b in range(nb):
            fl[b] = -1
        chol_update_lanes(Ll, vl, n, nb, sign, fl, V)
        for b in range(nb):
            fail[k0 + b] = fl[b]
        _store_lower(Ll, _unfold(0), n, k0, nb, out)


@kernel
def points_kernel(x, S, xi, gamma, X, dX):
    """Sigma points ``X[k, i] = x[k] + dX[k, i]`` with offsets ``dX[k, i] = xi[i] @ S[k].T``.

    Parameters
    ----------
    x : ndarray, shape (B or 1, n)
    S : ndarray, shape (B or 1, n, n)
        Lower factors.
    xi : ndarray, shape (N, n)
        Unit points.
    gamma : float
        Non-zero when ``xi`` is ``[0; gamma I; -gamma I]`` or ``[gamma I; -gamma I]``:
        the offsets are then ``+/- gamma`` times the columns of ``S`` (the same
        numbers as the product, in O(n^2)).
    X : ndarray, shape (B, N, n)
        Output.
    dX : ndarray, shape (B, N, n), or (0, N, n)
        Output; with no rows the offsets are not written (only the points are wanted).
    """
    B, N, n = X.shape
    offsets = dX.shape[0] == B
    if gamma != 0.0:
        # Axis points, O(n^2) a filter, no product: one filter at a time, the columns of its factor
        # times +/- gamma straight into its rows. Each point is its centre plus its offset, x + s and
        # x + (-s), the same sums as the general route's x + dX.
        o = N - 2 * n  # 1 with the central point, else 0
        shared = x.shape[0] == 1
        shared_S = S.shape[0] == 1
        for k in range(B):
            xk = x[0] if shared else x[k]
            Sk, Xk = S[0] if shared_S else S[k], X[k]
            Dk = dX[k] if offsets else Xk  # never written when the offsets are not wanted
            if o == 1:
                for l in range(n):
                    Xk[0, l] = xk[l] + 0.0
                    if offsets:
                        Dk[0, l] = 0.0
            for j in range(n):
                for l in range(n):
                    s = gamma * Sk[l, j] if j <= l else 0.0
                    Xk[o + j, l] = xk[l] + s
                    Xk[o + n + j, l] = xk[l] + (-s)
                    if offsets:
                        Dk[o + j, l] = s
                        Dk[o + n + j, l] = -s
        return
    nl = _lanes(N * n, B)
    Sl = np.empty((n, n, nl))
    xl = np.empty((n, nl))
    Dl = np.empty((N, n, nl))
    for k0 in range(0, B, nl):
        nb = min(nl, B - k0)
        _load_matrix(S, k0, nb, Sl)
        _load_vector(x, k0, nb, xl)
        # the offsets Dl[i, l, b] = (xi[i] @ S_b.T)[l], point-major: one filter's offsets are its rows
        for i in range(N):
            for l in range(n):
                for b in range(nb):
                    Dl[i, l, b] = 0.0
                for j in range(l + 1):
                    c = xi[i, j]
                    for b in range(nb):
                        Dl[i, l, b] += c * Sl[l, j, b]
        for b in range(nb):
            Xk = X[k0 + b]
            for i in range(N):
                for l in range(n):
                    Xk[i, l] = xl[l, b] + Dl[i, l, b]
            if offsets:
                Dk = dX[k0 + b]
                for i in range(N):
                    for l in range(n):
                        Dk[i, l] = Dl[i, l, b]


@kernel
def finite_rows_kernel(A, ok):
    """``ok[k]``: every entry of row ``A[k]`` is finite.

    A double is an infinity or a NaN exactly when its 11 exponent bits are all ones: the test is on
    the bits, an integer OR over the row, which LLVM vectorises (a floating-point reduction it may not
    reorder).

    Parameters
    ----------
    A : ndarray, shape (B, r)
    ok : ndarray of bool, shape (B,)
        Output.
    """
    B, r = A.shape
    bits = A.view(np.int64)
    for k in range(B):
        row = bits[k]
        special = 0
        for i in range(r):
            special |= (((row[i] >> 52) & 0x7FF) + 1) >> 11  # 1 when the exponent is 0x7FF
        ok[k] = special == 0


@kernel
def transform_kernel(P, ref, mode, wm, scale, sign, noise, mean, S, status, draw, xi2, gamma2, X2, D2):
    """Weighted mean and lower factor of points' covariance plus additive noise; then, optionally,
    the next sigma-point set (a prediction's second set: the step's prior and its set in one call).

    ``S[k] @ S[k].T = sum_r sign[r] scale[r]**2 D_r D_r^T + noise[k] @ noise[k].T``
    with the rows ``D_r`` of form ``mode`` (module docstring). ``status[k]`` is 306 when ``P[k]``
    holds a value that is not finite, else 305 when the mean or the factor is not finite (and
    nothing else failed).

    Parameters
    ----------
    P : ndarray, shape (B, N, d)
        Points (modes 0 and 1) or rows (mode 2).
    ref : ndarray, shape (B or 1, d)
        The mean for mode 2 (read only there).
    mode : int
    wm : ndarray, shape (N,)
        Mean weights (``wm[0]`` is not read).
    scale, sign : ndarray, shape (N,)
    noise : ndarray, shape (B or 1, d, q)
        A square root of the additive noise (``q = 0``: none).
    mean : ndarray, shape (B, d)
    S : ndarray, shape (B, d, d)
    status : ndarray of int64, shape (B,)
        Outputs.
    draw : int
        0: no set drawn. 1: the set ``mean + xi2 @ S.T`` (the redrawn second set), into ``X2`` with
        its offsets in ``D2`` (when ``D2`` has ``B`` rows), as :func:`points_kernel` draws it. 2: the
        augmented set, ``P`` itself followed by ``P[:, 0] + xi2 @ noise.T`` (``noise`` a lower factor,
        ``d`` columns; with none, ``P`` alone).
    xi2 : ndarray, shape (N2, d)
        Unit points of the set drawn (rows ``N`` on for ``draw == 2``).
    gamma2 : float
        As :func:`points_kernel`'s ``gamma`` for ``xi2``.
    X2 : ndarray, shape (B, N2, d), or (0, N2, d) when nothing is drawn
    D2 : ndarray, shape (B, N2, d), or (0, N2, d)
        Outputs.
    """
    B, N, d = P.shape
    npos = 0
    for r in range(N):
        if sign[r] > 0.0:
            npos += 1
    rows = npos + noise.shape[2]
    nl = _lanes(d * max(rows, N), B)
    Pl = np.empty((N, d, nl))
    none = np.empty((N, 0, nl))
    At = np.empty((d, max(rows, d, 1), nl))  # the rows, then their factor in place
    ml = np.empty((d, nl))
    v = np.empty((d, nl))
    V = np.empty((6, nl))
    fl = np.empty(nl, dtype=np.int64)
    st = np.empty(nl, dtype=np.int64)
    fin = np.empty(nl)
    for k0 in range(0, B, nl):
        nb = min(nl, B - k0)
        _load_matrix(P, k0, nb, Pl)
        _finite_lanes(Pl, N, d, nb, fin)
        if mode == 2:
            _load_vector(ref, k0, nb, ml)
        _deviations(Pl, N, d, nb, mode, wm, ml)
        _weighted_rows(Pl, none, N, nb, mode, scale, sign, noise, k0, At)
        tria_lanes(At, d, rows, nb, V)  # L = At below the diagonal
        _downdated_rows(Pl, none, N, nb, mode, scale, sign, _unfold(0), At, V, v, fl, st)
        for b in range(nb):
            mk = mean[k0 + b]
            good = True
            for l in range(d):
                mk[l] = ml[l, b]
                good = good and math.isfinite(ml[l, b])
                for j in range(l + 1):
                    good = good and math.isfinite(At[l, j, b])
            code = st[b] if (st[b] != 0 or good) else 305
            status[k0 + b] = code if fin[b] == 0.0 else 306
        _store_lower(At, _unfold(0), d, k0, nb, S)
    if draw == 1:
        points_kernel(mean, S, xi2, gamma2, X2, D2)
    elif draw == 2:
        # g13ej's augmented second set: X2[k] = [P[k]; P[k, 0] + xi2 @ noise[k].T] (no noise: P alone)
        for k in range(B):
            Xk, Fk = X2[k], P[k]
            for i in range(N):
                for l in range(d):
                    Xk[i, l] = Fk[i, l]
        N2 = X2.shape[1]
        if N2 > N:
            centre = np.empty((B, d))
            for k in range(B):
                for l in range(d):
                    centre[k, l] = P[k, 0, l]
            extra = np.empty((B, N2 - N, d))
            points_kernel(centre, noise, xi2, gamma2, extra, np.empty((0, N2 - N, d)))
            for k in range(B):
                Xk, Ek = X2[k], extra[k]
                for i in range(N2 - N):
                    for l in range(d):
                        Xk[N + i, l] = Ek[i, l]


@_helper
def _pair_sums(Hl, R1_2, k0, nb, N, m, c, mus, Zt):
    """The rows of ``T`` for axis points (``joint_update_kernel``'s ``pair``) into ``Zt``: each pair's
    sum ``c (e+ + e-)`` (no state part), ``mus mu`` and ``R1_2^T``, to be triangularised.

    ``Hl`` holds the central form's deviations (``mu`` in slot 0); pair ``j`` is points ``1 + j`` and
    ``1 + h + j`` (``h = (N - 1) / 2``).
    """
    h = (N - 1) // 2
    shared = R1_2.shape[0] == 1
    for j in range(h):
        for l in range(m):
            for b in range(nb):
                Zt[l, j, b] = c * (Hl[1 + j, l, b] + Hl[1 + h + j, l, b])
    for l in range(m):
        for b in range(nb):
            Zt[l, h, b] = mus * Hl[0, l, b]
    for b in range(nb):
        Rk = R1_2[0] if shared else R1_2[k0 + b]
        for l in range(m):
            for q in range(m):
                Zt[l, h + 1 + q, b] = Rk[l, q]


@_helper
def _pair_differences(Hl, Xl, N, m, n, nb, c, Zt, At):
    """The rotated joint rows of axis points into ``At`` (``m + n`` columns): each pair's difference
    ``c (e+ - e-)``, then ``T^T`` from :func:`_pair_sums`' rows triangularised in ``Zt`` (lower:
    ``Zt[l, i]`` for ``i <= l``), then zero rows up to ``m + n``."""
    h = (N - 1) // 2
    for j in range(h):
        for l in range(m):
            for b in range(nb):
                At[l, j, b] = c * (Hl[1 + j, l, b] - Hl[1 + h + j, l, b])
        for l in range(n):
            for b in range(nb):
                At[m + l, j, b] = c * (Xl[1 + j, l, b] - Xl[1 + h + j, l, b])
    for l in range(m):
        for i in range(m):
            for b in range(nb):
                At[l, h + i, b] = Zt[l, i, b] if i <= l else 0.0
    for l in range(n):
        for i in range(m):
            for b in range(nb):
                At[m + l, h + i, b] = 0.0
    for i in range(m + n):  # fewer rows than columns: the factor's last columns are zero
        for j in range(h + m, m + n):
            for b in range(nb):
                At[i, j, b] = 0.0


@kernel
def joint_update_kernel(
    H,
    zref,
    X,
    xref,
    z,
    R1_2,
    x,
    mode,
    wm,
    scale,
    sign,
    pair,
    zp,
    y,
    w,
    Sy,
    L21,
    dx,
    xpost,
    Spost,
    ll,
    ww,
    ld,
    status,
    xi1,
    gamma1,
    X1,
):
    """The measurement update by one QR of the joint rows (the square-root array form); then,
    optionally, the next prediction's sigma points from the posterior (the step's update and the next
    first set in one call).

    ``tria([[Dz, Dx], [R1_2^T, 0]]) = [[Sy, 0], [L21, L22]]``, then each
    negative row's downdate of the joint factor; ``w = Sy^-1 y``,
    ``dx = L21 w``, ``xpost = x + dx``, ``Spost = L22``. Valid when the set
    reproduces the prior's moments.

    Parameters
    ----------
    H : ndarray, shape (B, N, m)
        Images of the second set (modes 0, 1) or their rows (mode 2).
    zref : ndarray, shape (B or 1, m)
        The predicted measurement for mode 2.
    X : ndarray, shape (B, N, n)
        The second set (mode 0), its points or offsets (mode 1, with
        ``xref`` their reference), or its state rows (mode 2).
    xref : ndarray, shape (B or 1, n)
    z : ndarray, shape (B, m)
        The measurement (modes 0, 1) or the innovation itself (mode 2).
    R1_2 : ndarray, shape (B or 1, m, m)
    x : ndarray, shape (B or 1, n)
        The prior mean.
    mode : int
    wm, scale, sign : ndarray, shape (N,)
    pair : float
        Non-zero for axis points in the central form with one weight for every
        ``+/-`` row and none negative: that row scale over ``sqrt(2)``. Each
        pair's joint rows are rotated by 45 degrees (the same Gram matrix): the
        sums ``pair (e+ + e-)`` have no state part (the offsets are exactly
        opposite) and are triangularised first, with ``mu`` and ``R1_2^T``, into
        ``T`` (``m x m``); the joint QR is then of the differences and ``T^T``,
        ``n + m`` rows instead of ``2n + 1 + m``.
    zp, y, w : ndarray, shape (B, m)
        Outputs: predicted measurement, innovation, ``Sy^-1 y``.
    Sy : ndarray, shape (B, m, m)
    L21 : ndarray, shape (B, n, m)
    dx, xpost : ndarray, shape (B, n)
    Spost : ndarray, shape (B, n, n)
    ll, ww, ld : ndarray, shape (B,)
        The log-likelihood of the measurement, the squared Mahalanobis distance ``w.w`` and
        ``log det Sy`` (``sum log|Sy_ii|``, the sum the log-likelihood takes).
    status : ndarray of int64, shape (B,)
        Outputs (306 when ``H[k]`` holds a value that is not finite).
    xi1 : ndarray, shape (N1, n)
        Unit points of the set drawn from the posterior.
    gamma1 : float
        As :func:`points_kernel`'s ``gamma`` for ``xi1``.
    X1 : ndarray, shape (B, N1, n), or (0, N1, n) when no set is drawn
        Output: ``xpost + xi1 @ Spost.T``, as :func:`points_kernel` draws it.
    """
    B, N, m = H.shape
    n = X.shape[2]
    c = m + n
    npos = 0
    for r in range(N):
        if sign[r] > 0.0:
            npos += 1
    rows = npos + m
    nl = _lanes(c * max(rows, N), B)
    Hl = np.empty((N, m, nl))
    Xl = np.empty((N, n, nl))
    At = np.empty((c, max(rows, c), nl))  # the joint rows, then their factor in place (below)
    L = At
    zl = np.empty((m, nl))
    yl = np.empty((m, nl))
    wl = np.empty((m, nl))
    xl = np.empty((n, nl))
    xr = np.empty((n, nl))
    v = np.empty((c, nl))
    V = np.empty((6, nl))
    fl = np.empty(nl, dtype=np.int64)
    st = np.empty(nl, dtype=np.int64)
    half = (N - 1) // 2
    Zt = np.empty((m, half + 1 + m if pair != 0.0 else 1, nl))
    fin = np.empty(nl)
    for k0 in range(0, B, nl):
        nb = min(nl, B - k0)
        _load_matrix(H, k0, nb, Hl)
        _finite_lanes(Hl, N, m, nb, fin)
        _load_matrix(X, k0, nb, Xl)
        if mode == 2:
            _load_vector(zref, k0, nb, zl)
        if mode == 1:
            _load_vector(xref, k0, nb, xr)
        _deviations(Hl, N, m, nb, mode, wm, zl)
        _state_rows(Xl, N, n, nb, mode, wm, xr)
        _load_vector(z, k0, nb, yl)
        if mode != 2:
            for l in range(m):
                for b in range(nb):
                    yl[l, b] -= zl[l, b]
        if pair != 0.0:
            _pair_sums(Hl, R1_2, k0, nb, N, m, pair, scale[N - 1], Zt)
            tria_lanes(Zt, m, half + 1 + m, nb, V)  # T, lower: Zt[l, i] for i <= l
            _pair_differences(Hl, Xl, N, m, n, nb, pair, Zt, At)
            tria_lanes(At, c, half + m, nb, V)
            for b in range(nb):
                st[b] = 0
        else:
            _weighted_rows(Hl, Xl, N, nb, mode, scale, sign, R1_2, k0, At)
            tria_lanes(At, c, rows, nb, V)
            _downdated_rows(Hl, Xl, N, nb, mode, scale, sign, m, At, V, v, fl, st)
        _innovation(L, L, m, yl, wl, xr, m, n, k0, nb, st, ll, ww, ld)
        _load_vector(x, k0, nb, xl)
        _finish(L, m, n, xl, xr, st, k0, nb, dx, xpost)
        for b in range(nb):
            status[k0 + b] = st[b] if fin[b] == 0.0 else 306
            zk, yk, wk, Lk = zp[k0 + b], y[k0 + b], w[k0 + b], L21[k0 + b]
            for l in range(m):
                zk[l] = zl[l, b]
                yk[l] = yl[l, b]
                wk[l] = wl[l, b]
            for l in range(n):
                for j in range(m):
                    Lk[l, j] = L[m + l, j, b]
        _store_lower(L, _unfold(0), m, k0, nb, Sy)
        _store_lower(L, m, n, k0, nb, Spost)
    if X1.shape[0] == B:
        points_kernel(xpost, Spost, xi1, gamma1, X1, np.empty((0, X1.shape[1], n)))


@_helper
def _innovation(Sy, L21, r0, yl, wl, dxl, m, n, k0, nb, st, ll, ww, ld):
    """From the innovation factor: g13ej's 302 unless ``Sy`` is regular, ``w = Sy^-1 y``, ``ww = w.w``,
    ``ld = log det Sy = sum log|Sy_ii|`` and the Gaussian log-likelihood ``-(m log 2 pi + 2 ld + w.w) / 2``,
    and ``dx = L21 w`` with ``L21`` the rows ``r0 .. r0 + n`` of its buffer."""
    for b in range(nb):
        good = True
        for i in range(m):
            good = good and (_TINY < abs(Sy[i, i, b]) < math.inf)
        st[b] = 302 if (not good and st[b] == 0) else st[b]
    for l in range(m):
        for b in range(nb):
            wl[l, b] = yl[l, b]
    solve_lower_lanes(Sy, wl, m, nb, _unfold(0))
    for b in range(nb):
        s = 0.0
        logdet = 0.0
        for i in range(m):
            s += wl[i, b] * wl[i, b]
            logdet += math.log(abs(Sy[i, i, b]))
        ww[k0 + b] = s
        ld[k0 + b] = logdet
        ll[k0 + b] = -0.5 * (m * _LOG_2PI + 2.0 * logdet + s)
    for l in range(n):
        for b in range(nb):
            dxl[l, b] = 0.0
        for j in range(m):
            for b in range(nb):
                dxl[l, b] += L21[r0 + l, j, b] * wl[j, b]


@_helper
def _finish(L, i0, n, xl, dxl, st, k0, nb, dx, xpost):
    """``xpost = x + dx``; 303 unless it and the posterior factor ``L[i0:, i0:]`` are finite.

    304 if they are, but the factor has a zero on its diagonal (the caller decides whether the
    covariance may be singular: see ``squkf.measurement``).
    """
    for b in range(nb):
        good = True
        full = True
        dk, xk = dx[k0 + b], xpost[k0 + b]
        for l in range(n):
            d = dxl[l, b]
            xp = xl[l, b] + d
            dk[l] = d
            xk[l] = xp
            good = good and math.isfinite(xp)
            for j in range(l + 1):
                good = good and math.isfinite(L[i0 + l, i0 + j, b])
            full = full and L[i0 + l, i0 + l, b] != 0.0
        if st[b] == 0:
            st[b] = 303 if not good else (304 if not full else 0)


@kernel
def downdate_update_kernel(
    H,
    zref,
    X,
    xref,
    z,
    R1_2,
    Syin,
    S,
    x,
    mode,
    wm,
    wc,
    scale,
    sign,
    xkind,
    zp,
    y,
    w,
    Sy,
    L21,
    dx,
    xpost,
    Spost,
    ll,
    ww,
    ld,
    status,
):
    """g13ej's measurement update for a set whose covariance need not be the prior's (the downdate form).

    The innovation factor ``Sy`` from the rows of the images (form ``mode``, as
    :func:`transform_kernel` forms them, with ``R1_2``; or given, ``Syin``),
    ``Pxy = sum_i wc[i] (X_i - xref)(H_i - zp)^T``, ``L21 = Pxy Sy^-T``,
    ``w = Sy^-1 y``, ``xpost = x + L21 w``, and the posterior factor is the
    prior's ``S`` downdated by each column of ``L21``: filterpy's
    ``P - K Sy Sy^T K^T`` whatever the set's rows.

    squkf's state angle hooks as data (``xkind``, per state component): bit 2 wraps the state
    deviation ``X_i - xref`` (``residual_x=AngleResidual``), bit 4 the posterior mean ``x + dx``
    (``state_add=AngleAdd``), as :func:`squkf.angles.wrap` (the same bits).

    Parameters
    ----------
    H : ndarray, shape (B, N, m)
        The second set's images (modes 0, 1) or their rows ``H_i - zp`` (mode 2).
    zref : ndarray, shape (B or 1, m)
        The predicted measurement for mode 2.
    X : ndarray, shape (B, N, n)
        The second set, or its offsets (``xref`` zero), or its deviations.
    xref : ndarray, shape (B or 1, n)
    z : ndarray, shape (B, m)
        The measurement (modes 0, 1) or the innovation itself (mode 2).
    R1_2 : ndarray, shape (B or 1, m, m)
        The measurement noise's lower factor (not read when ``Syin`` is given).
    Syin : ndarray, shape (B, m, m), or (0, m, m)
        The innovation factor given (a user's ``UT``); with no rows, formed here.
    S : ndarray, shape (B, n, n)
        The prior factor.
    x : ndarray, shape (B or 1, n)
    mode : int
    wm, wc, scale, sign : ndarray, shape (N,)
        Mean and covariance weights, and the rows' scales and signs of ``Sy``'s form.
    xkind : ndarray of int64, shape (n,)
    zp, y, w : ndarray, shape (B, m)
    Sy : ndarray, shape (B, m, m)
    L21 : ndarray, shape (B, n, m)
    dx, xpost : ndarray, shape (B, n)
    Spost : ndarray, shape (B, n, n)
    ll, ww, ld : ndarray, shape (B,)
    status : ndarray of int64, shape (B,)
        Outputs, as :func:`joint_update_kernel`'s (306 when ``H[k]`` is not finite; 301 when a
        negative row's downdate of ``Sy`` failed).
    """
    B, N, m = H.shape
    n = X.shape[2]
    given = Syin.shape[0] == B
    npos = 0
    for r in range(N):
        if sign[r] > 0.0:
            npos += 1
    rows = npos + m
    nl = _lanes(max(n, m) * max(N, n, m, rows), B)
    Hl = np.empty((N, m, nl))
    Dz = np.empty((N, m, nl)) if mode != 2 else Hl
    none = np.empty((N, 0, nl))
    Xl = np.empty((N, n, nl))
    At = np.empty((m, max(rows, m), nl))
    Syl = np.empty((m, m, nl))
    Sl = np.empty((n, n, nl))
    Ll = np.empty((n, m, nl))
    zl = np.empty((m, nl))
    xr = np.empty((n, nl))
    xl = np.empty((n, nl))
    t = np.empty((max(n, m), nl))
    wl = np.empty((m, nl))
    yl = np.empty((m, nl))
    V = np.empty((6, nl))
    fl = np.empty(nl, dtype=np.int64)
    st = np.empty(nl, dtype=np.int64)
    fin = np.empty(nl)
    for k0 in range(0, B, nl):
        nb = min(nl, B - k0)
        _load_matrix(H, k0, nb, Hl)
        _finite_lanes(Hl, N, m, nb, fin)
        if mode != 2:
            _load_matrix(H, k0, nb, Dz)
        else:
            _load_vector(zref, k0, nb, zl)
        _deviations(Hl, N, m, nb, mode, wm, zl)
        if given:
            _load_matrix(Syin, k0, nb, Syl)
            for b in range(nb):
                st[b] = 0
        else:  # the rows' factor with the noise, as the transform kernel forms it
            _weighted_rows(Hl, none, N, nb, mode, scale, sign, R1_2, k0, At)
            tria_lanes(At, m, rows, nb, V)
            _downdated_rows(Hl, none, N, nb, mode, scale, sign, _unfold(0), At, V, t, fl, st)
            for b in range(nb):
                st[b] = 301 if st[b] != 0 else 0
            for i in range(m):
                for j in range(m):
                    for b in range(nb):
                        Syl[i, j, b] = At[i, j, b] if j <= i else 0.0
        if mode != 2:  # the images' deviations from the predicted measurement
            for i in range(N):
                for j in range(m):
                    for b in range(nb):
                        Dz[i, j, b] = Dz[i, j, b] - zl[j, b]
        _load_matrix(X, k0, nb, Xl)
        _load_vector(xref, k0, nb, xr)
        for l in range(n):  # the state deviations, wrapped where residual_x wraps
            if xkind[l] & 2:
                for i in range(N):
                    for b in range(nb):
                        Xl[i, l, b] = _wrap(Xl[i, l, b] - xr[l, b])
            else:
                for i in range(N):
                    for b in range(nb):
                        Xl[i, l, b] = Xl[i, l, b] - xr[l, b]
        _load_matrix(S, k0, nb, Sl)
        for l in range(n):  # row l of L21 = Sy^-1 (row l of Pxy)
            for j in range(m):
                for b in range(nb):
                    t[j, b] = 0.0
                for i in range(N):
                    c = wc[i]
                    for b in range(nb):
                        t[j, b] += c * Xl[i, l, b] * Dz[i, j, b]
            solve_lower_lanes(Syl, t, m, nb, _unfold(0))
            for j in range(m):
                for b in range(nb):
                    Ll[l, j, b] = t[j, b]
        _load_vector(z, k0, nb, yl)
        if mode != 2:
            for l in range(m):
                for b in range(nb):
                    yl[l, b] -= zl[l, b]
        _innovation(Syl, Ll, _unfold(0), yl, wl, xr, m, n, k0, nb, st, ll, ww, ld)
        _load_vector(x, k0, nb, xl)
        for b in range(nb):
            fl[b] = -1
        for j in range(m):
            for l in range(n):
                for b in range(nb):
                    t[l, b] = Ll[l, j, b]
            chol_update_lanes(Sl, t, n, nb, -1.0, fl, V)
        for b in range(nb):
            st[b] = 303 if (fl[b] >= 0 and st[b] == 0) else st[b]
        _finish(Sl, _unfold(0), n, xl, xr, st, k0, nb, dx, xpost)
        for b in range(nb):
            status[k0 + b] = st[b] if fin[b] == 0.0 else 306
            zk, yk, wk, Lk, xk = zp[k0 + b], y[k0 + b], w[k0 + b], L21[k0 + b], xpost[k0 + b]
            for l in range(n):  # x + dx, wrapped where state_add wraps
                if xkind[l] & 4:
                    xk[l] = _wrap(xk[l])
            for j in range(m):
                zk[j] = zl[j, b]
                yk[j] = yl[j, b]
                wk[j] = wl[j, b]
            for l in range(n):
                for j in range(m):
                    Lk[l, j] = Ll[l, j, b]
        _store_lower(Syl, _unfold(0), m, k0, nb, Sy)
        _store_lower(Sl, _unfold(0), n, k0, nb, Spost)


@kernel
def angle_rows_kernel(H, z, wm, ref, kind, zp, D, y):
    """squkf's angle hooks on the measurement as data: the predicted measurement, the rows and the
    innovation that ``z_mean_fn=AngleMean``, ``residual_z=AngleResidual`` would give, for the joint
    update's given rows (mode 2).

    Component ``l`` of filter ``k``: the mean is circular where ``kind[l] & 1``, about the point
    ``ref`` (the largest ``|wm|``): ``a = H[k, ref, l]``, ``zp = wrap(a + sum_i wm[i] wrap(H[k, i, l] - a))``
    (no sine, cosine or arctangent: a filter's bits never depend on the block); else the plain mean
    ``H[k, 0, l] + sum_{i>=1} wm[i] (H[k, i, l] - H[k, 0, l])``. The rows ``D[k, i] = H[k, i] - zp[k]``
    and the innovation ``y[k] = z[k] - zp[k]`` are wrapped where ``kind[l] & 2``. ``wrap(a)`` is
    ``(a + pi) % (2 pi) - pi``, as :func:`squkf.angles.wrap` (the same bits). Values that are not
    finite go through (NaN where ``z`` is missing); the joint kernel reports rows that are not finite.

    Parameters
    ----------
    H : ndarray, shape (B, N, m)
        The second set's images.
    z : ndarray, shape (B, m), or (0, m)
        The measurement; with no rows, no innovation is formed (``y`` not written: a prediction's
        images, ``x_mean_fn=AngleMean``, ``residual_x=AngleResidual``).
    wm : ndarray, shape (N,)
        Mean weights.
    ref : int
        The point the circular means are taken about.
    kind : ndarray of int64, shape (m,)
        Per component: 1 a circular mean, 2 a wrapped residual, 3 both, 0 neither.
    zp, y : ndarray, shape (B, m)
    D : ndarray, shape (B, N, m)
        Outputs.
    """
    B, N, m = H.shape
    innovation = z.shape[0] == B
    for k in range(B):
        Hk, pk, Dk = H[k], zp[k], D[k]
        zk, yk = (z[k], y[k]) if innovation else (zp[k], zp[k])  # (no measurement: no innovation)
        for l in range(m):
            code = kind[l]
            if code & 1:
                a = Hk[ref, l]
                s = 0.0
                for i in range(N):
                    s += wm[i] * _wrap(Hk[i, l] - a)
                mean = _wrap(a + s)
            else:
                a = Hk[0, l]
                s = 0.0
                for i in range(1, N):
                    s += wm[i] * (Hk[i, l] - a)
                mean = s + a
            pk[l] = mean
            if code & 2:
                for i in range(N):
                    Dk[i, l] = _wrap(Hk[i, l] - mean)
                if innovation:
                    yk[l] = _wrap(zk[l] - mean)
            else:
                for i in range(N):
                    Dk[i, l] = Hk[i, l] - mean
                if innovation:
                    yk[l] = zk[l] - mean
