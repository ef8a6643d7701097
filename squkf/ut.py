"""``unscented_transform``: the square-root unscented transform of a user function."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .checks import as_lower_factor, check_values
from .errors import ShapeError
from .generators import sigma_points_from_factor
from .transform import deviations, sqrt_unscented_transform
from .weights import MerweScaledWeights, as_family

__all__ = ["unscented_transform"]


def unscented_transform(
    fn: Callable,
    x,
    P1_2,
    points=None,
    noise_sqrt=None,
    *,
    mean_fn: Callable | None = None,
    residual_fn: Callable | None = None,
    residual_x: Callable | None = None,
    state_add: Callable | None = None,
    vectorized: bool = False,
    return_cross: bool = False,
    args: tuple = (),
    kwargs: dict | None = None,
):
    """Mean and lower factor of ``fn(X)`` for ``X ~ (x, P1_2 @ P1_2.T)``, by sigma points.

    Parameters
    ----------
    fn : callable
        ``fn(x, *args, **kwargs) -> (m,)`` per point, or with ``vectorized=True``
        ``fn(sigmas, *args, **kwargs)`` mapping ``(N, n)`` to ``(N, m)``.
    x : array_like, shape (n,)
        Mean of the input.
    P1_2 : array_like, shape (n, n)
        Lower Cholesky factor of the input covariance.
    points : sigma-point family or filterpy points object, optional
        Default ``MerweScaledWeights()`` (g13ej's defaults).
    noise_sqrt : array_like, shape (m, m), optional
        Lower factor of additive noise on the output.
    mean_fn : callable ``mean_fn(sigmas, Wm)``, optional
        Mean of the output points (e.g. circular).
    residual_fn : callable ``residual_fn(a, b)``, optional
        Difference of two outputs.
    residual_x : callable, optional
        Difference of two inputs (for the cross-covariance).
    state_add : callable ``state_add(x, dx)``, optional
        Adds a deviation to the input when forming the sigma points.
    vectorized : bool
        Call ``fn`` once with all sigma points.
    return_cross : bool
        Also return the cross-covariance of input and output.
    args, kwargs
        Extra arguments for ``fn``.

    Returns
    -------
    mean : ndarray, shape (m,)
    S : ndarray, shape (m, m)
        Lower factor of the output covariance.
    Pxy : ndarray, shape (n, m)
        Only with ``return_cross``.

    Examples
    --------
    A linear map is transformed exactly: mean ``A x``, covariance
    ``A P A^T`` and cross-covariance ``P A^T``.

    >>> import numpy as np
    >>> from squkf import unscented_transform
    >>> A = np.array([[1.0, 1.0], [0.0, 1.0]])
    >>> P1_2 = np.diag([1.0, 0.5])  # P = diag(1, 0.25)
    >>> mean, S, Pxy = unscented_transform(lambda x: A @ x, [1.0, 2.0], P1_2, return_cross=True)
    >>> print(np.round(mean, 6))
    [3. 2.]
    >>> print(np.round(S @ S.T, 6))
    [[1.25 0.25]
     [0.25 0.25]]
    >>> print(np.round(Pxy, 6))
    [[1.   0.  ]
     [0.25 0.25]]

    With ``vectorized=True`` the function receives all points at once, one per row:

    >>> mean, S = unscented_transform(lambda X: X @ A.T, [1.0, 2.0], P1_2, vectorized=True)
    >>> print(np.round(mean, 6))
    [3. 2.]
    """
    x = np.asarray(x, dtype=float).reshape(-1)
    n = x.shape[0]
    S = as_lower_factor(P1_2, "P1_2", n, singular_ok=False)
    family = as_family(MerweScaledWeights() if points is None else points)
    kwargs = {} if kwargs is None else kwargs
    sigmas = sigma_points_from_factor(x, S, family.unit_sigma_points(n), state_add)
    Wm, Wc = family.weights(n)
    if vectorized:
        values = fn(sigmas, *args, **kwargs)
    else:
        values = [np.atleast_1d(fn(s, *args, **kwargs)) for s in sigmas]
    values = np.asarray(values, dtype=float)
    if values.ndim == 1:
        values = values[:, None]
    if values.ndim != 2 or values.shape[0] != sigmas.shape[0]:
        raise ShapeError(f"fn returned shape {values.shape}, expected ({sigmas.shape[0]}, m)")
    m = values.shape[1]
    values = check_values(values, (sigmas.shape[0], m), "fn values")
    noise = None if noise_sqrt is None else as_lower_factor(noise_sqrt, "noise_sqrt", m, singular_ok=True)
    mean, Sy = sqrt_unscented_transform(values, Wm, Wc, noise, mean_fn, residual_fn)
    if not return_cross:
        return mean, Sy
    dx = deviations(sigmas, x, residual_x)
    return mean, Sy, (dx.T * Wc) @ deviations(values, mean, residual_fn)
