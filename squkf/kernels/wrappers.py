"""The kernels in numpy's batch convention: the numerics behind the public entry points.

Each function here takes arrays with any leading batch shape (numpy's
``np.linalg`` convention: one filter has none, a fleet ``(K,)``), flattens it
to a stack, calls its kernel from the table it is given (``kernels``: the
route's, when a filter's phase calls it), or else from the installed table
(:data:`squkf.kernels.table.KERNELS`, read at each call; a large stack cut
between the threads by :func:`squkf.kernels.threads.split_call`) and gives
the results back in that shape. One filter is a stack of one, computed by the
same kernel as a fleet, so a filter alone and the same filter in a fleet get
the same numbers, bit for bit.

Failures are not raised here: each function returns a status per filter
(see :mod:`squkf.kernels.phases`), which the callers turn into squkf's
exceptions (:mod:`squkf.linalg`, :mod:`squkf.transform`).

The update kernels are not called here: :func:`update_stacks` gives their
arguments as stacks, and :mod:`squkf.measurement` calls the kernel of its
route's table itself (one module fewer between ``z`` and the kernel).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import table
from .phases import JointUpdate, update_outputs
from .table import KernelTable, kernel_array, no_factor, no_noise, no_points, no_set, plan_array, zeros_row
from .threads import split_call

__all__ = [
    "tria",
    "solve_lower",
    "chol_update",
    "sigma_points",
    "finite_rows",
    "transform",
    "JointUpdate",
    "UpdateStacks",
    "update_stacks",
]


def _batch(*arrays: tuple[np.ndarray | None, int]) -> tuple[int, ...]:
    shape: tuple[int, ...] = ()
    for a, core in arrays:
        if a is not None and a.ndim > core:
            lead = a.shape[: a.ndim - core]
            shape = lead if not shape or lead == shape else np.broadcast_shapes(shape, lead)
    return shape


def _stack(a: np.ndarray, batch: tuple[int, ...], core: int) -> np.ndarray:
    """``a`` as a stack ``(B, *core shape)`` over ``batch``, as the kernels take it."""
    if not batch and a.ndim == core:  # one filter: a view with a leading axis of one
        return kernel_array(a[None])
    tail = a.shape[a.ndim - core :]
    if a.shape[: a.ndim - core] != batch:
        a = np.broadcast_to(a, batch + tail)
    return kernel_array(a.reshape((-1,) + tail))


def _unstack(a: np.ndarray, batch: tuple[int, ...]) -> np.ndarray:
    """A kernel's output stack ``(B, ...)`` in the caller's batch shape, a view (:func:`_stack` undone)."""
    if not batch:  # one filter: the stack of one's row, 0-d for a scalar
        return a[0, ...]
    if len(batch) == 1:
        return a
    return a.reshape(batch + a.shape[1:])


def _shared(a: np.ndarray, batch: tuple[int, ...], core: int) -> np.ndarray:
    """Like :func:`_stack`, but an ``a`` with no batch axis is passed once (leading axis 1)."""
    if a.ndim == core:
        return kernel_array(a[None])
    return _stack(a, batch, core)


def tria(rows: np.ndarray, *, kernels: KernelTable | None = None) -> np.ndarray:
    """Lower factor with a non-negative diagonal of ``rows.T @ rows``, by Householder QR.

    Parameters
    ----------
    rows : ndarray, shape (..., k, n)
    kernels : KernelTable, optional
        The table whose kernel is called (a route's); default the installed one.

    Returns
    -------
    S : ndarray, shape (..., n, n)
        ``S @ S.T == rows.T @ rows``; if ``k < n`` the last ``n - k`` columns are zero.
    """
    batch = rows.shape[:-2]
    k, n = rows.shape[-2:]
    A = _stack(rows, batch, 2)
    S = np.empty((A.shape[0], n, n))
    split_call(table.chosen(kernels).tria, A.shape[0], A, S)
    return _unstack(S, batch)


def solve_lower(
    L: np.ndarray, b: np.ndarray, trans: bool = False, *, kernels: KernelTable | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``L x = b`` (``L.T x = b`` for ``trans``) for lower-triangular ``L``.

    Parameters
    ----------
    L : ndarray, shape (..., n, n)
    b : ndarray, shape (..., n) or (..., n, q)
        A stack of vectors when ``b.ndim == L.ndim - 1``.
    trans : bool
    kernels : KernelTable, optional
        The table whose kernel is called (a route's); default the installed one.

    Returns
    -------
    x : ndarray, same shape as ``b`` (broadcast with ``L``'s batch)
    ok : ndarray of bool, shape (...)
        False where ``L`` has a zero on its diagonal (``x`` is then not finite).
    """
    vector = b.ndim == L.ndim - 1
    B_ = b[..., None] if vector else b
    batch = _batch((L, 2), (B_, 2))
    n, q = B_.shape[-2:]
    Y = _stack(B_, batch, 2)
    X = np.empty(Y.shape)
    ok = np.empty(Y.shape[0], dtype=np.bool_)
    split_call(table.chosen(kernels).solve, Y.shape[0], _shared(L, batch, 2), Y, 1 if trans else 0, X, ok)
    X = _unstack(X, batch)
    return (X[..., 0] if vector else X), _unstack(ok, batch)


def chol_update(
    S: np.ndarray, v: np.ndarray, sign: float, *, kernels: KernelTable | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Rank-1 update (``sign > 0``) or downdate of lower factors, O(n^2) each.

    Parameters
    ----------
    S : ndarray, shape (..., n, n)
    v : ndarray, shape (..., n)
    sign : float
    kernels : KernelTable, optional
        The table whose kernel is called (a route's); default the installed one.

    Returns
    -------
    S1 : ndarray, shape (..., n, n)
        ``S1 @ S1.T == S @ S.T + sign * outer(v, v)`` where it succeeded.
    fail : ndarray of int, shape (...)
        The first column whose rotation failed, or -1.
    """
    batch = _batch((S, 2), (v, 1))
    L = _stack(S, batch, 2)
    out = np.empty(L.shape)
    fail = np.empty(L.shape[0], dtype=np.int64)
    split_call(table.chosen(kernels).chol_update, L.shape[0], L, _stack(v, batch, 1), float(sign), out, fail)
    return _unstack(out, batch), _unstack(fail, batch)


def sigma_points(
    x: np.ndarray,
    S: np.ndarray,
    xi: np.ndarray,
    gamma: float = 0.0,
    offsets: bool = True,
    *,
    kernels: KernelTable | None = None,
):
    """Sigma points ``x + xi @ S.T`` and their offsets ``xi @ S.T``.

    Parameters
    ----------
    x : ndarray, shape (..., n)
    S : ndarray, shape (..., n, n)
        Lower factors.
    xi : ndarray, shape (N, n)
        Unit points.
    gamma : float
        Non-zero when ``xi`` is ``[0; gamma I; -gamma I]`` or ``[gamma I; -gamma I]`` (offsets in O(n^2)).
    offsets : bool
        Whether the offsets are wanted (not written otherwise).
    kernels : KernelTable, optional
        The table whose kernel is called (a route's); default the installed one.

    Returns
    -------
    sigmas : ndarray, shape (..., N, n)
    offsets : ndarray, shape (..., N, n), or None
        None when not wanted.
    """
    batch = _batch((x, 1), (S, 2))
    N, n = xi.shape
    Ss = _stack(S, batch, 2)
    X = np.empty((Ss.shape[0], N, n))
    dX = np.empty(X.shape if offsets else (0, N, n))
    split_call(
        table.chosen(kernels).points,
        Ss.shape[0],
        _shared(x, batch, 1),
        Ss,
        plan_array(xi),
        float(gamma),
        X,
        dX,
        plan=(2,),
    )
    return _unstack(X, batch), (_unstack(dX, batch) if offsets else None)


def finite_rows(A: np.ndarray, *, kernels: KernelTable | None = None) -> np.ndarray:
    """Which filters' values are all finite.

    Parameters
    ----------
    A : ndarray, shape (K, ...)
    kernels : KernelTable, optional
        The table whose kernel is called (a route's); default the installed one.

    Returns
    -------
    ndarray of bool, shape (K,)
    """
    rows = kernel_array(A.reshape(A.shape[0], -1))
    ok = np.empty(rows.shape[0], dtype=np.bool_)
    split_call(table.chosen(kernels).finite_rows, rows.shape[0], rows, ok)
    return ok


def transform(
    P: np.ndarray,
    mode: int,
    wm: np.ndarray,
    scale: np.ndarray,
    sign: np.ndarray,
    noise: np.ndarray | None = None,
    ref: np.ndarray | None = None,
    *,
    kernels: KernelTable | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and lower factor of weighted rows plus additive noise (one QR, a downdate per negative row).

    Parameters
    ----------
    P : ndarray, shape (..., N, d)
        Points (``CENTRAL``, ``MEAN``) or rows (``GIVEN``).
    mode : int
        The row form.
    wm, scale, sign : ndarray, shape (N,)
        Mean weights; each row's ``sqrt(|weight|)`` and sign.
    noise : ndarray, shape (..., d, q), optional
        A square root of the additive noise.
    ref : ndarray, shape (..., d), optional
        The mean, for ``GIVEN``.
    kernels : KernelTable, optional
        The table whose kernel is called (a route's); default the installed one.

    Returns
    -------
    mean : ndarray, shape (..., d)
    S : ndarray, shape (..., d, d)
    status : ndarray of int, shape (...)
        0, or ``r + 1`` (``-(r + 1)``) where negative row ``r``'s downdate failed
        (found the factor singular).
    """
    batch = _batch((P, 2), (noise, 2), (ref, 1))
    N, d = P.shape[-2:]
    Ps = _stack(P, batch, 2)
    B = Ps.shape[0]
    Nz = no_noise(d) if noise is None else _shared(noise, batch, 2)
    R = zeros_row(d) if ref is None else _shared(ref, batch, 1)
    mean = np.empty((B, d))
    S = np.empty((B, d, d))
    status = np.empty(B, dtype=np.int64)
    nothing = no_set(d)
    split_call(
        table.chosen(kernels).transform,
        B,
        Ps,
        R,
        mode,
        plan_array(wm),
        plan_array(scale),
        plan_array(sign),
        Nz,
        mean,
        S,
        status,
        0,
        no_points(d),
        0.0,
        nothing,
        nothing,
        plan=(3, 4, 5, 11),
    )
    return _unstack(mean, batch), _unstack(S, batch), _unstack(status, batch)


class UpdateStacks(NamedTuple):
    """An update kernel's inputs as stacks ``(B, ...)`` and the outputs it writes, for one call.

    The caller hands them to its kernel table's ``joint_update`` or ``downdate_update`` (the kernel its
    route takes, :mod:`squkf.measurement`) with the route's data, and reads :meth:`result`.

    Attributes
    ----------
    batch : tuple of int
        The callers' batch shape.
    H, zref, X, xref, z, R1_2, x : ndarray
        As the kernels take them (``zref``, ``xref``, ``R1_2``, ``x`` of one row where shared).
    S : ndarray, shape (B, n, n), or None
        The prior factor (the downdate kernel's; None: not given).
    Sy : ndarray, shape (B, m, m) or (0, m, m)
        The innovation factor given (a user's ``UT``), or none.
    out : tuple of ndarray
        The kernel's outputs, in its order: :class:`JointUpdate`'s fields.
    """

    batch: tuple[int, ...]
    H: np.ndarray
    zref: np.ndarray
    X: np.ndarray
    xref: np.ndarray
    z: np.ndarray
    R1_2: np.ndarray
    x: np.ndarray
    S: np.ndarray | None
    Sy: np.ndarray
    out: tuple

    def result(self) -> JointUpdate:
        """What the kernel wrote, in the callers' batch shape."""
        return JointUpdate(*(_unstack(a, self.batch) for a in self.out))


def update_stacks(
    H: np.ndarray,
    X: np.ndarray,
    z: np.ndarray,
    R1_2: np.ndarray,
    x: np.ndarray,
    xref: np.ndarray | None = None,
    zref: np.ndarray | None = None,
    S: np.ndarray | None = None,
    Sy: np.ndarray | None = None,
) -> UpdateStacks:
    """The arguments of an update kernel (:func:`phases.joint_update_kernel`,
    :func:`phases.downdate_update_kernel`) as stacks over any batch shape, and its outputs.

    Parameters
    ----------
    H : ndarray, shape (..., N, m)
        The images (``CENTRAL``, ``MEAN``) or their rows (``GIVEN``).
    X : ndarray, shape (..., N, n)
        The second set, its offsets or its state rows (as the route takes them).
    z : ndarray, shape (..., m)
        The measurement, or for ``GIVEN`` the innovation.
    R1_2 : ndarray, shape (..., m, m)
    x : ndarray, shape (..., n)
        The prior mean.
    xref : ndarray, shape (..., n), optional
        The reference of ``X`` (default: zero, ``X`` are offsets or deviations).
    zref : ndarray, shape (..., m), optional
        The predicted measurement for ``GIVEN``.
    S : ndarray, shape (..., n, n), optional
        The prior factor (the downdate form).
    Sy : ndarray, shape (..., m, m), optional
        The innovation factor given (a user's ``UT``; the downdate form); default: formed by the kernel.

    Returns
    -------
    UpdateStacks
    """
    batch = _batch((H, 2), (X, 2), (xref, 1), (z, 1), (R1_2, 2), (S, 2), (x, 1), (zref, 1), (Sy, 2))
    m = H.shape[-1]
    n = X.shape[-1]
    Hs = _stack(H, batch, 2)
    B = Hs.shape[0]
    out = tuple(update_outputs(B, n, m))
    return UpdateStacks(
        batch,
        Hs,
        zeros_row(m) if zref is None else _shared(zref, batch, 1),
        _stack(X, batch, 2),
        zeros_row(n) if xref is None else _shared(xref, batch, 1),
        _stack(z, batch, 1),
        _shared(R1_2, batch, 2),
        _shared(x, batch, 1),
        None if S is None else _stack(S, batch, 2),
        no_factor(m) if Sy is None else _stack(Sy, batch, 2),
        out,
    )
