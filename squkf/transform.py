"""The square-root unscented transform of a set of weighted points, on stacked arrays.

Pure functions: points in, mean and lower factor out; the numerics are the
transform kernel of :mod:`squkf.kernels`. Points are rows,
``(..., N, d)`` with any leading batch shape (one filter: none; a fleet of
``K`` filters: ``(K,)``), as filterpy stores ``sigmas_f``. How a weight
vector becomes covariance rows is :mod:`squkf.rows`; the user's hooks
(``mean_fn``, ``residual_fn``) are called per filter and per point, as
filterpy calls them, and their results are checked.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .checks import as_float_array, call_hook
from .errors import DowndateError, NonFiniteError, NotPositiveDefiniteError, ShapeError
from .kernels import wrappers
from .kernels.table import CENTRAL, GIVEN, MEAN, KernelTable
from .linalg import all_finite
from .rows import RowForm, WeightRows, weight_rows

__all__ = [
    "StackedHook",
    "weighted_mean",
    "deviations",
    "cross_covariance",
    "factor_rows",
    "transform_factor",
    "sqrt_unscented_transform",
]


class StackedHook:
    """A user's hook called once on stacked arrays, as ``fx`` and ``hx`` are (``Fleet.vectorized_hooks``).

    Where filterpy calls a hook once per filter and point, the step calls the hook it wraps once per
    block of ``k`` filters (a fleet's chunk; a filter alone, ``k = 1``):

    - ``x_mean_fn(sigmas, Wm)``, ``z_mean_fn(sigmas, Wm)``: ``sigmas`` ``(k, N, d)``, ``Wm`` ``(N,)``;
      returns ``(k, d)``;
    - ``residual_x(a, b)``, ``residual_z(a, b)``: ``a`` ``(k, P, d)``, ``b`` ``(k, 1, d)``; returns
      ``a - b`` ``(k, P, d)`` (the rows of a set and, for ``residual_z``, the innovation as row ``P - 1``);
    - ``state_add(x, dx)``: ``x`` ``(k, 1, n)``, ``dx`` ``(k, P, n)``; returns ``(k, P, n)``.

    What it returns is checked as a hook's result is.

    Parameters
    ----------
    fn : callable
    """

    __slots__ = ("fn",)

    def __init__(self, fn: Callable):
        self.fn = fn

    def __call__(self, *args):
        return self.fn(*args)

    def __reduce__(self):
        return (StackedHook, (self.fn,))

    def __repr__(self) -> str:
        return f"StackedHook({self.fn!r})"


def _stacked(fn: StackedHook, args: tuple, shape: tuple[int, ...], hook: str) -> np.ndarray:
    """``fn(*args)`` on stacked arrays (leading axis ``k``), checked to be of ``shape``."""
    return call_hook(fn.fn, args, shape, hook)


def swap_last(a: np.ndarray) -> np.ndarray:
    """The transpose of the last two axes (``a.T`` for one matrix)."""
    return a.T if a.ndim == 2 else np.swapaxes(a, -1, -2)


def _batch(a: np.ndarray, core_ndim: int):
    """Indices over the leading batch axes of ``a`` (one empty index for no batch)."""
    return np.ndindex(a.shape[: a.ndim - core_ndim])


def weighted_mean(
    sigmas: np.ndarray, Wm: np.ndarray, mean_fn: Callable | None = None, hook: str = "mean_fn"
) -> np.ndarray:
    """Weighted mean of the rows of ``sigmas``.

    The plain mean is formed as ``sigmas[0] + Wm @ (sigmas - sigmas[0])``:
    with a small alpha the weights are large and of both signs, and summing
    offsets from a reference point avoids the cancellation of summing the
    points themselves.

    Parameters
    ----------
    sigmas : ndarray, shape (..., N, d)
    Wm : ndarray, shape (N,)
        Mean weights, summing to 1.
    mean_fn : callable ``mean_fn(sigmas, Wm) -> (d,)``, optional
        Replaces the weighted sum (e.g. a circular mean for angles); called
        once per filter with its ``(N, d)`` points (a :class:`StackedHook`:
        once, with every filter's, ``(k, N, d)``).
    hook : str
        The hook's name for error messages.

    Returns
    -------
    mean : ndarray, shape (..., d)
    """
    if mean_fn is None:
        ref = sigmas[..., 0, :]
        return ref + np.matmul(Wm, sigmas - ref[..., None, :])
    d = sigmas.shape[-1]
    if isinstance(mean_fn, StackedHook):
        N, lead = sigmas.shape[-2], sigmas.shape[:-2]
        k = int(np.prod(lead, dtype=np.int64))
        return _stacked(mean_fn, (sigmas.reshape(k, N, d), Wm), (k, d), hook).reshape(lead + (d,))
    mean = np.empty(sigmas.shape[:-2] + (d,))
    for idx in _batch(sigmas, 2):
        mean[idx] = call_hook(mean_fn, (sigmas[idx], Wm), (d,), hook)
    return mean


def deviations(
    sigmas: np.ndarray, mean: np.ndarray, residual_fn: Callable | None = None, hook: str = "residual_fn"
) -> np.ndarray:
    """Rows ``residual_fn(sigmas[i], mean)`` (plain differences by default).

    Parameters
    ----------
    sigmas : ndarray, shape (..., N, d)
    mean : ndarray, shape (..., d)
    residual_fn : callable ``residual_fn(a, b) -> (d,)``, optional
        Called once per row, with 1-D arrays, as filterpy calls it (a
        :class:`StackedHook`: once, ``(k, N, d)`` and ``(k, 1, d)``).
    hook : str
        The hook's name for error messages.

    Returns
    -------
    dev : ndarray, shape (..., N, d)
    """
    if residual_fn is None or residual_fn is np.subtract:
        return sigmas - mean[..., None, :]
    d = sigmas.shape[-1]
    shape = np.broadcast_shapes(sigmas.shape, mean.shape[:-1] + (1, d))
    if isinstance(residual_fn, StackedHook):
        N, lead = shape[-2], shape[:-2]
        k = int(np.prod(lead, dtype=np.int64))
        a = np.broadcast_to(sigmas, shape).reshape(k, N, d)
        b = np.broadcast_to(mean[..., None, :], lead + (1, d)).reshape(k, 1, d)
        return _stacked(residual_fn, (a, b), (k, N, d), hook).reshape(shape)
    dev = np.empty(shape)
    for idx in _batch(dev, 2):
        m = mean[idx] if mean.ndim > 1 else mean
        for i, s in enumerate(sigmas[idx] if sigmas.ndim > 2 else sigmas):
            dev[idx + (i,)] = call_hook(residual_fn, (s, m), (d,), hook)
    return dev


def cross_covariance(sigmas_f: np.ndarray, sigmas_h: np.ndarray, x, z, Wcs, hooks) -> np.ndarray:
    """``sum Wc[i] (sigmas_f[i] - x)(sigmas_h[i] - z)^T`` with the weights of the set of ``N`` points.

    Parameters
    ----------
    sigmas_f : ndarray, shape (N, n)
    sigmas_h : ndarray, shape (N, m)
    x : array_like, shape (n,)
    z : array_like, shape (m,)
    Wcs : sequence of ndarray or None
        Candidate covariance weights (the first set's, the second set's);
        the first of length ``N`` is used.
    hooks : squkf.plan.Hooks
        ``residual_x`` and ``residual_z`` give the deviations.

    Returns
    -------
    ndarray, shape (n, m)

    Raises
    ------
    ShapeError
        No set has ``N`` points.
    """
    N = sigmas_f.shape[0]
    sets = [w for w in Wcs if w is not None]
    Wc = next((w for w in sets if w.shape[0] == N), None)
    if Wc is None:
        raise ShapeError(f"sigmas_f has {N} points but the sigma-point sets have {sets[-1].shape[0]}")
    dx = deviations(sigmas_f, as_float_array(x, "x"), hooks.residual_x, "residual_x")
    dz = deviations(sigmas_h, as_float_array(z, "z"), hooks.residual_z, "residual_z")
    return (dx.T * Wc) @ dz


def _raise_status(
    status: np.ndarray, form: RowForm, errno: int, error: type[NotPositiveDefiniteError]
) -> None:
    """The exception for the first failed filter of a transform kernel's ``status`` (nothing if none)."""
    bad = status.ravel()
    bad = bad[(bad != 0) & (bad != 305) & (bad != 306)]  # not finite: the callers' own checks say it
    if bad.size == 0:
        return
    code = int(bad.flat[0])
    k = abs(code) - 1
    what = "the factor to downdate is singular" if code < 0 else "its downdate failed"
    raise error(f"weight {form.weights[k]:.6g} of row {k} is negative and {what}", errno=errno)


def factor_rows(
    D: np.ndarray,
    form: RowForm,
    noise_sqrt: np.ndarray | None = None,
    errno: int = 301,
    error: type[NotPositiveDefiniteError] = DowndateError,
    *,
    kernels: KernelTable | None = None,
) -> np.ndarray:
    """Lower factor of ``sum_k w_k D_k D_k^T + noise_sqrt @ noise_sqrt.T``.

    The positive rows enter one QR factorisation together with the noise
    factor's columns; each negative row is then removed by a rank-1 downdate
    (the transform kernel, with the rows given).

    Parameters
    ----------
    D : ndarray, shape (..., N, d)
        Unscaled rows (deviations formed by the caller, e.g. by the hooks).
    form : RowForm
        Their weights.
    noise_sqrt : ndarray, shape (..., d, k), optional
        A square root (any ``k`` columns) of additive noise.
    errno : int
        g13ej error number for a failed downdate.
    error : exception class
        Raised for a failed downdate (a :class:`NotPositiveDefiniteError` subclass).
    kernels : KernelTable, optional
        The kernel table to call (a filter's route's); default the installed one.

    Returns
    -------
    S : ndarray, shape (..., d, d)

    Raises
    ------
    DowndateError
        If a negative weight's downdate would lose positive-definiteness.
    """
    # given rows: the kernel reads no mean weights
    _, S, status = wrappers.transform(
        D, GIVEN, form.scale, form.scale, form.sign, noise_sqrt, kernels=kernels
    )
    _raise_status(status, form, errno, error)
    return S


def transform_factor(
    sigmas: np.ndarray,
    rows: WeightRows,
    noise_sqrt: np.ndarray | None = None,
    mean_fn: Callable | None = None,
    residual_fn: Callable | None = None,
    errno: int = 301,
    error: type[DowndateError] = DowndateError,
    hooks: tuple[str, str] = ("mean_fn", "residual_fn"),
    *,
    kernels: KernelTable | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean and lower factor of the points' covariance plus additive noise.

    With no hook, one kernel forms the rows of the best form
    (:mod:`squkf.rows`) from the points, factors them with the noise and
    removes the negative rows. The hooks (which force the mean form) are
    called in Python and their deviations handed to the same kernel.

    Parameters
    ----------
    sigmas : ndarray, shape (..., N, d)
    rows : WeightRows
    noise_sqrt : ndarray, shape (..., d, k), optional
    mean_fn, residual_fn : callable, optional
        filterpy's hooks (they force the mean form).
    errno : int
    error : exception class
        For a failed downdate.
    hooks : tuple of str
        The hooks' names for error messages.
    kernels : KernelTable, optional
        The kernel table to call (a filter's route's); default the installed one.

    Returns
    -------
    mean : ndarray, shape (..., d)
    S : ndarray, shape (..., d, d)
    """
    plain = mean_fn is None and (residual_fn is None or residual_fn is np.subtract)
    if plain:
        form = rows.best
        mode = CENTRAL if form.central else MEAN
        mean, S, status = wrappers.transform(
            sigmas, mode, rows.Wm, form.scale, form.sign, noise_sqrt, kernels=kernels
        )
    else:
        form = rows.mean_form
        mean = weighted_mean(sigmas, rows.Wm, mean_fn, hooks[0])
        D = deviations(sigmas, mean, residual_fn, hooks[1])
        _, S, status = wrappers.transform(
            D, GIVEN, rows.Wm, form.scale, form.sign, noise_sqrt, mean, kernels=kernels
        )
    _raise_status(status, form, errno, error)
    return mean, S


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
    sigmas : ndarray, shape (..., N, d)
        Propagated sigma points, one per row.
    Wm, Wc : ndarray, shape (N,)
        Mean and covariance weights.
    noise_sqrt : ndarray, shape (..., d, d), optional
        Lower factor of the additive noise covariance.
    mean_fn : callable ``mean_fn(sigmas, Wm)``, optional
    residual_fn : callable ``residual_fn(a, b)``, optional

    Returns
    -------
    mean : ndarray, shape (..., d)
    S : ndarray, shape (..., d, d)
        Lower factor of the transformed covariance.

    Examples
    --------
    Points of ``N(3, 4)`` and additive noise of variance 2.25 give variance
    ``4 + 2.25 = 6.25``, factor 2.5:

    >>> import numpy as np
    >>> from squkf import MerweScaledWeights, sqrt_unscented_transform
    >>> w = MerweScaledWeights()
    >>> Wm, Wc = w.weights(1)
    >>> sigmas = 3.0 + 2.0 * w.unit_sigma_points(1)
    >>> mean, S = sqrt_unscented_transform(sigmas, Wm, Wc, noise_sqrt=np.array([[1.5]]))
    >>> print(np.round(mean, 6), np.round(S, 6))
    [3.] [[2.5]]

    It is filterpy's ``unscented_transform`` on factors:

    >>> from filterpy.kalman import unscented_transform
    >>> sigmas = np.array([[1.0, 2.0], [2.0, 2.5], [0.5, 1.0]])
    >>> W = np.array([0.4, 0.3, 0.3])
    >>> mean, S = sqrt_unscented_transform(sigmas, W, W)
    >>> mean_fp, P_fp = unscented_transform(sigmas, W, W)
    >>> bool(np.allclose(mean, mean_fp)), bool(np.allclose(S @ S.T, P_fp))
    (True, True)
    """
    sigmas = as_float_array(sigmas, "sigmas")
    if not all_finite(sigmas):
        raise NonFiniteError("sigma points contain NaN or inf")
    return transform_factor(sigmas, weight_rows(Wm, Wc), noise_sqrt, mean_fn, residual_fn)
