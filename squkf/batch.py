"""Batch filtering over a sequence of measurements."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .errors import ShapeError

__all__ = ["batch_filter", "per_step"]


def per_step(value, n: int, name: str, scalar_ok: bool = False) -> list:
    """Expand ``None``, one value, or a sequence of ``n`` values into a list of ``n``.

    Parameters
    ----------
    value : None, scalar/array, or sequence of length n
    n : int
    name : str
        For the error message.
    scalar_ok : bool
        Treat a scalar as one value for every step (``dts``).

    Returns
    -------
    list of length n
    """
    if value is None:
        return [None] * n
    if scalar_ok and np.ndim(value) == 0:
        return [value] * n
    if isinstance(value, np.ndarray) and value.ndim == 2 and not scalar_ok:
        return [value] * n  # one matrix for every step
    if isinstance(value, dict):
        return [value] * n
    if len(value) != n:
        raise ShapeError(f"{name} has {len(value)} entries but there are {n} measurements")
    return list(value)


def batch_filter(
    ukf,
    zs: Sequence,
    Rs=None,
    dts=None,
    UT=None,
    saver=None,
    Qs=None,
    fx_args=None,
    hx_args=None,
    return_factors: bool = False,
):
    """Run ``predict`` and ``update`` over all measurements ``zs``.

    The same as a loop of ``ukf.predict(dt=dts[k], Q=Qs[k], **fx_args[k])``
    and ``ukf.update(zs[k], R=Rs[k], **hx_args[k])``, with filterpy's return
    values. If a step raises, the filter is restored to its state before the
    call.

    Parameters
    ----------
    ukf : SquareRootUKF
    zs : sequence of length T
        Measurements; ``None`` or an all-NaN entry means no measurement at
        that step (predict only).
    Rs : None, matrix, or sequence of T matrices
        Measurement noise per step (default ``ukf.R``).
    dts : None, float, or sequence of T floats
        Time step of the prediction into each step (default ``ukf._dt``).
    UT : callable, optional
        Square-root transform (see :func:`squkf.sqrt_unscented_transform`).
    saver : filterpy.common.Saver, optional
        ``saver.save()`` is called after every step.
    Qs : None, matrix, or sequence of T matrices
        Process noise of the prediction into each step (default ``ukf.Q``).
    fx_args, hx_args : None, dict, or sequence of T dicts
        Keyword arguments for ``fx`` and ``hx`` at each step.
    return_factors : bool
        Return the lower factors ``P1_2`` instead of the covariances.

    Returns
    -------
    means : ndarray, shape (T, dim_x)
        Posterior means.
    covariances : ndarray, shape (T, dim_x, dim_x)
        Posterior covariances (or their lower factors with ``return_factors``).
    """
    try:
        T = len(zs)
    except TypeError:
        raise ShapeError(f"zs must be a sequence of measurements, got {type(zs).__name__}") from None
    Rs = per_step(Rs, T, "Rs")
    Qs = per_step(Qs, T, "Qs")
    dts = per_step(dts, T, "dts", scalar_ok=True)
    fx_args = per_step(fx_args, T, "fx_args")
    hx_args = per_step(hx_args, T, "hx_args")
    n = ukf.dim_x
    means = np.zeros((T, n))
    covs = np.zeros((T, n, n))
    saved = ukf._snapshot()
    try:
        for k in range(T):
            ukf.predict(dt=dts[k], UT=UT, Q=Qs[k], **(fx_args[k] or {}))
            ukf.update(zs[k], R=Rs[k], UT=UT, **(hx_args[k] or {}))
            means[k] = ukf.x
            S = ukf._P.factor()
            covs[k] = S if return_factors else S @ S.T
            if saver is not None:
                saver.save()
    except BaseException:
        ukf._restore(saved)
        raise
    return means, covs
