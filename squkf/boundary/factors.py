"""A covariance or factor the caller gave, as its lower factor: for one filter, or shared or per filter.

Every covariance a caller gives is factored here, once, by
:func:`squkf.linalg.factor_covariance` (through :mod:`squkf.covariance`);
the step itself only ever sees factors. For a stack of ``K`` filters a
value is shared ``(d, d)`` or per filter ``(K, d, d)``, and a per-filter
value's messages name the filter (``R[3]``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..covariance import FactorSlot, as_lower_factor, as_matrix
from ..errors import NonFiniteError, ShapeError
from ..linalg import factor_covariance
from ..validate import as_float_array
from .inputs import per_filter

__all__ = [
    "covariance_factors",
    "given_noise_factors",
    "lower_factors",
    "noise_factor",
    "noise_factors",
    "reset_rows",
]


def noise_factor(
    value, name: str, dim: int, default: Callable[[], np.ndarray | None], cache: dict
) -> np.ndarray | None:
    """One filter's ``Q`` or ``R`` factor: this call's ``value``, else the filter's own (``default()``).

    Parameters
    ----------
    value : array_like, shape (dim, dim), scalar, or None
        This call's covariance (a scalar ``r`` is ``r * I``); None: the filter's.
    name : {"Q", "R"}
    dim : int
        The size the step needs (the state's or the measurement's).
    default : callable
        The factor of the filter's own covariance (None: zero), e.g. a
        :class:`~squkf.covariance.FactorSlot`'s ``factor``.
    cache : dict
        ``name -> (array, its copy, factor)``: an ndarray given again unchanged
        is not factored again.

    Returns
    -------
    ndarray, shape (dim, dim), or None
        The lower factor; None for a zero covariance.
    """
    if value is None:
        S = default()
        if S is not None and S.shape[0] != dim:
            raise ShapeError(
                f"{name} is {S.shape[0]}x{S.shape[0]} but the {'measurement' if name == 'R' else 'state'}"
                f" has length {dim}; pass {name}= for a model of another size"
            )
        return S
    cached = cache.get(name)
    if cached is not None and cached[0] is value and np.array_equal(cached[1], value):
        return cached[2]
    tmp = FactorSlot(name, dim, semidefinite=True, factor=None)
    tmp.set_matrix(value)
    S = tmp.factor()
    if isinstance(value, np.ndarray):
        cache[name] = (value, value.copy(), S)
    return S


def _noise_one(a, name: str, dim: int) -> np.ndarray:
    A = as_matrix(a, name, dim)
    if not np.any(A):
        return np.zeros((dim, dim))
    return factor_covariance(A, name, semidefinite=True)


def noise_factors(value, name: str, dim: int, K: int) -> np.ndarray | None:
    """A stack's ``Q`` or ``R``, shared ``(dim, dim)`` or per filter ``(K, dim, dim)``, as lower factors.

    Parameters
    ----------
    value : array_like, shape (dim, dim) or (K, dim, dim), scalar, or None
    name : {"Q", "R"}
    dim : int
    K : int

    Returns
    -------
    ndarray, shape (dim, dim) or (K, dim, dim), or None
        Zeros for a zero covariance; None when ``value`` is None.
    """
    if value is None:
        return None
    a = as_float_array(value, name)
    if a.ndim == 3:
        if a.shape != (K, dim, dim):
            raise ShapeError(f"{name} has shape {a.shape}, expected ({dim}, {dim}) or ({K}, {dim}, {dim})")
        return np.stack([_noise_one(a[k], f"{name}[{k}]", dim) for k in range(K)])
    return _noise_one(a, name, dim)


def given_noise_factors(value, name: str, dim: int, K: int) -> np.ndarray | None:
    """A stack's ``Q1_2`` or ``R1_2`` as given, shared ``(dim, dim)`` or per filter ``(K, dim, dim)``.

    Parameters
    ----------
    value : array_like, shape (dim, dim) or (K, dim, dim), or scalar
        Lower-triangular factors (singular ones allowed).
    name : {"Q1_2", "R1_2"}
    dim, K : int

    Returns
    -------
    ndarray, shape (dim, dim) or (K, dim, dim), or None
        None for one shared zero factor.
    """
    a = as_float_array(value, name)
    if a.ndim == 3:
        if a.shape != (K, dim, dim):
            raise ShapeError(f"{name} has shape {a.shape}, expected ({dim}, {dim}) or ({K}, {dim}, {dim})")
        return np.stack([as_lower_factor(a[k], f"{name}[{k}]", dim, singular_ok=True) for k in range(K)])
    S = as_lower_factor(a, name, dim, singular_ok=True)
    return S if np.any(S) else None


def covariance_factors(value, name: str, n: int, K: int) -> np.ndarray:
    """A stack's ``P``, one matrix for all (factored once) or one per filter, as ``(K, n, n)`` factors.

    Parameters
    ----------
    value : array_like, shape (n, n) or (K, n, n)
    name : str
    n, K : int

    Returns
    -------
    ndarray, shape (K, n, n)
        Lower factors with a positive diagonal.
    """
    a = as_float_array(value, name)
    if a.shape == (n, n):  # one matrix for all: factored once
        S = factor_covariance(as_matrix(a, name, n), name)
        return np.broadcast_to(S, (K, n, n)).copy()
    A = per_filter(a, name, K, (n, n))
    return np.stack([factor_covariance(as_matrix(A[k], f"{name}[{k}]", n), f"{name}[{k}]") for k in range(K)])


def lower_factors(value, name: str, n: int, K: int) -> np.ndarray:
    """A stack's ``P1_2`` as given, one for every filter or one per filter, ``(K, n, n)``.

    Parameters
    ----------
    value : array_like, shape (n, n) or (K, n, n)
        Lower-triangular factors, non-singular.
    name : str
    n, K : int

    Returns
    -------
    ndarray, shape (K, n, n)
    """
    S = per_filter(value, name, K, (n, n))
    return np.stack([as_lower_factor(S[k], f"{name}[{k}]", n, singular_ok=False) for k in range(K)])


def reset_rows(x, P, idx: np.ndarray, x_now: np.ndarray, S_now: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A stack's states and factors with the filters ``idx`` given a new ``x`` and ``P`` (``Fleet.reset``).

    Parameters
    ----------
    x : array_like, shape (n,) or (len(idx), n), or None
        None: the states are kept.
    P : array_like, shape (n, n) or (len(idx), n, n), or None
        Factored filter by filter (messages name ``P[k]``); None: kept.
    idx : ndarray of int
        The filters.
    x_now : ndarray, shape (K, n)
    S_now : ndarray, shape (K, n, n)

    Returns
    -------
    x : ndarray, shape (K, n)
    S : ndarray, shape (K, n, n)
        New arrays.
    """
    new_x, new_S = x_now.copy(), S_now.copy()
    n = x_now.shape[-1]
    if x is not None:
        xs = as_float_array(x, "x")
        if xs.shape not in ((n,), (idx.size, n)):
            raise ShapeError(f"x has shape {xs.shape}, expected ({n},) or ({idx.size}, {n})")
        new_x[idx] = xs
        if not np.all(np.isfinite(new_x[idx])):
            raise NonFiniteError("x contains NaN or inf")
    if P is not None:
        Ps = as_float_array(P, "P")
        shape = (n, n)
        if Ps.shape not in (shape, (idx.size,) + shape):
            raise ShapeError(f"P has shape {Ps.shape}, expected {shape} or {(idx.size,) + shape}")
        Ps = np.broadcast_to(Ps, (idx.size,) + shape)
        for j, k in enumerate(idx):
            new_S[k] = factor_covariance(as_matrix(Ps[j], f"P[{k}]", n), f"P[{k}]")
    return new_x, new_S
