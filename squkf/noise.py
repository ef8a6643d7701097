"""Noise that enters the model functions: ``fx(x, w, dt)`` and ``hx(x, v)`` (the augmented UKF).

With ``fx_noise=dim_w`` the first sigma-point set is drawn over the augmented
state ``[x, w]`` with mean ``[x, 0]`` and the block-diagonal factor
``diag(S, Q1_2)`` (``Q`` is w's covariance, ``dim_w x dim_w``); ``fx`` maps
each pair ``(x_i, w_i)`` to a state, and the prior is the weighted mean and
factor of those images with no noise added. With ``hx_noise=dim_v`` the
second set is drawn over ``[x, v]`` with ``diag(S_prior, R1_2)``, and the
update is the joint QR of the images' and the state part's deviations with no
noise rows. Every family weighs these sets at dimension ``n + dim_w`` (or
``n + dim_v``); the state part of each point is ``x + xi[:n] S^T`` and the
noise part ``xi[n:] Q1_2^T``, so the augmented factor is never formed
(:meth:`squkf.generators.UnitSet.augmented`).

This module holds what both front ends check and compute at their boundary
for it: the noise dimensions, the model functions' signatures, the noise
points, and the call itself.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable

import numpy as np

from .checks import note_on_user_error
from .errors import ParameterError
from .kernels import wrappers

__all__ = ["check_noise_dim", "check_accepts_noise", "noise_points", "handed_points", "call_model"]


def check_noise_dim(value, name: str) -> int:
    """``fx_noise`` / ``hx_noise`` as given: None (additive noise) or a positive integer.

    Returns
    -------
    int
        0 for additive noise.

    Raises
    ------
    ParameterError
        Anything else, naming the argument and the value.
    """
    if value is None:
        return 0
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ParameterError(
            f"{name} must be None (additive noise) or a positive integer, the dimension of the noise"
            f" the function takes as its second argument; got {name}={value!r}"
        )
    return int(value)


def check_accepts_noise(fn: Callable | None, name: str, dim: int, positional: int) -> None:
    """Refuse a model function that cannot take the noise as its second argument.

    Parameters
    ----------
    fn : callable or None
        ``fx`` (called ``fx(x, w, dt)``: 3 positional arguments) or ``hx``
        (``hx(x, v)``: 2); None (a function given per call) is not checked.
    name : str
        ``"fx"`` or ``"hx"``.
    dim : int
        The noise dimension given (0: additive, nothing to check).
    positional : int

    Raises
    ------
    ParameterError
        ``fn``'s signature does not accept that many positional arguments.
    """
    if not dim or not callable(fn):
        return
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):  # a builtin or C function: nothing to read
        return
    try:
        sig.bind(*range(positional))
    except TypeError:
        what = "fx(x, w, dt)" if name == "fx" else "hx(x, v)"
        raise ParameterError(
            f"{name}_noise={dim} means {name} is called as {what}, with the noise as its second"
            f" argument, but {name}{sig} does not take {positional} positional arguments"
        ) from None


def noise_points(xi: np.ndarray, factor: np.ndarray | None, batch: tuple[int, ...]) -> np.ndarray:
    """The noise part of an augmented sigma-point set, ``xi @ factor.T`` for each filter.

    Parameters
    ----------
    xi : ndarray, shape (N, d)
        The unit points' noise part (:attr:`squkf.plan.Plan.w_xi`, ``v_xi``).
    factor : ndarray, shape (d, d) or (..., d, d), or None
        Lower factor of the noise covariance (None: no noise, the points are 0).
    batch : tuple of int
        The filters' batch shape (``()`` for one filter).

    Returns
    -------
    ndarray, shape (batch..., N, d)
        A fresh array (the model function may keep it).
    """
    N, d = xi.shape
    if factor is None:
        return np.zeros(batch + (N, d))
    factor = np.broadcast_to(factor, batch + (d, d))
    _, offsets = wrappers.sigma_points(np.zeros(batch + (d,)), factor, xi, 0.0)
    assert offsets is not None
    return offsets


def handed_points(sigmas: np.ndarray, xi: np.ndarray | None, factor, batch: tuple[int, ...]) -> np.ndarray:
    """What ``ask_*`` hands out: a copy of the sigma points, with their noise part beside them if any.

    Parameters
    ----------
    sigmas : ndarray, shape (batch..., N, n)
    xi : ndarray, shape (N, d), or None
        The unit points' noise part (None: additive noise, the points alone).
    factor : ndarray, shape (d, d) or (batch..., d, d), or None
        Lower factor of the noise covariance.
    batch : tuple of int

    Returns
    -------
    ndarray, shape (batch..., N, n) or (batch..., N, n + d)
        A fresh array: the augmented points ``[x_i, w_i]``.
    """
    if xi is None:
        return sigmas.copy()
    return np.concatenate([sigmas, noise_points(xi, factor, batch)], axis=-1)


def call_model(
    fn: Callable,
    name: str,
    dim: int,
    X: np.ndarray,
    noise: np.ndarray,
    args: tuple,
    kwargs: dict,
    vectorized: bool,
):
    """``fn(X, noise, *args, **kwargs)``: a model function with the noise as its second argument.

    An exception ``fn`` raises propagates unchanged (the same object), as
    every exception from ``fx``/``hx`` does; on Python >= 3.11 it carries a
    note naming ``{name}_noise`` and the shape of the noise given
    (:func:`squkf.checks.note_on_user_error`).

    Parameters
    ----------
    fn : callable
    name : str
        ``"fx"`` or ``"hx"``.
    dim : int
        The noise dimension.
    X : ndarray, shape (N, n)
        Sigma points (state part).
    noise : ndarray, shape (N, dim)
        Their noise part.
    args, kwargs
        The rest of the call (``dt``, ``fx_args``...).
    vectorized : bool
        Call ``fn`` once with all points, else once per point ``fn(X[i], noise[i], ...)``.

    Returns
    -------
    object
        What ``fn`` returned (vectorised), or the list of its ``N`` results.
    """
    try:
        if vectorized:
            return fn(X, noise, *args, **kwargs)
        return [fn(x, w, *args, **kwargs) for x, w in zip(X, noise)]
    except Exception as exc:
        each = f"{noise.shape}" if vectorized else f"{noise.shape[1:]} at each sigma point"
        note_on_user_error(
            exc, f"squkf: {name} was called with noise of dimension {name}_noise={dim}, shape {each}"
        )
        raise
