"""Truth and measurements drawn from a filter's own model: ``squkf.simulate``.

What a consistency check or a tuning study needs first: runs of the model a
template filter describes, ``x[0] ~ N(x, P)``, ``x[t] = fx(x[t-1], dt) + w``
with ``w ~ N(0, Q)``, ``z[t] = hx(x[t]) + v`` with ``v ~ N(0, R)`` (or, with
the noise forms, ``fx(x, w, dt)`` and ``hx(x, v)``), in the order a filter's
``batch_filter`` reads them: each measurement follows one prediction. The
template is read, never changed; the same seed gives the same runs.
"""

from __future__ import annotations

import numpy as np

from . import checks
from .batch import per_step
from .checks import check_values
from .errors import ParameterError, UnsetError

__all__ = ["simulate"]


def simulate(
    ukf, steps: int, runs: int, *, seed=None, dts=None, fx_args=None, hx_args=None
) -> tuple[np.ndarray, np.ndarray]:
    """Draw ``runs`` runs of ``steps`` steps from the model of the filter ``ukf``.

    Parameters
    ----------
    ukf : SquareRootUKF
        The template: its ``fx``, ``hx``, ``x``, ``P``, ``Q``, ``R``, ``dt``
        and noise forms (``fx_noise``, ``hx_noise``: ``Q`` and ``R`` are then
        the covariances of the noise the model functions take). With
        ``vectorized=True`` ``fx`` and ``hx`` are called once per step with
        every run's state, ``(runs, dim_x)``; otherwise once per run.
    steps, runs : int
        Positive.
    seed : None, int or numpy.random.Generator, optional
        As :func:`numpy.random.default_rng` takes it.
    dts : float or sequence of ``steps`` floats, optional
        Time steps (default: the template's ``dt``), as ``batch_filter``'s.
    fx_args, hx_args : dict or sequence of ``steps`` dicts, optional
        Keyword arguments of ``fx`` and ``hx``, as ``batch_filter``'s.

    Returns
    -------
    truth : ndarray, shape (runs, steps, dim_x)
        The state at each measurement.
    zs : ndarray, shape (runs, steps, dim_z)
        The measurements.

    Raises
    ------
    ParameterError
        ``steps`` or ``runs`` not a positive integer; a bad ``dts`` or
        argument sequence; no ``fx`` or ``hx`` on the template.
    UnsetError
        The template's ``x`` or ``P`` is a placeholder.
    NonFiniteError, ShapeError
        A model function returned values of the wrong shape or not finite
        (naming the function and the step).

    Examples
    --------
    >>> import numpy as np
    >>> from squkf import MerweScaledWeights, SquareRootUKF, simulate
    >>> def fx(x, dt):
    ...     return np.array([x[0] + dt * x[1], x[1]])
    >>> ukf = SquareRootUKF(2, 1, 1.0, hx=lambda x: x[:1], fx=fx, points=MerweScaledWeights())
    >>> truth, zs = simulate(ukf, steps=50, runs=3, seed=1)
    >>> truth.shape, zs.shape
    ((3, 50, 2), (3, 50, 1))
    """
    T, M = checks.check_sizes(steps=steps, runs=runs)
    c = ukf.configuration()
    n, m = c.dim_x, c.dim_z
    for name, fn in (("fx", c.fx), ("hx", c.hx)):
        if fn is None:
            raise ParameterError(f"simulate needs the template's {name}, but it has none ({name}=None)")
    x0 = ukf.x
    S0 = ukf.P1_2
    for name, value in (("x", x0), ("P", S0)):
        if value is None or np.isnan(np.asarray(value, dtype=float)).all():
            raise UnsetError(
                f"simulate needs the template's {name}, but {name} was never set (a placeholder)"
            )
    dt_list = per_step(dts, T, "dts", "dt", default=c.dt, ref="steps")
    fx_list = per_step(fx_args, T, "fx_args", "kwargs", ref="steps")
    hx_list = per_step(hx_args, T, "hx_args", "kwargs", ref="steps")
    w_dim, v_dim = c.fx_noise or n, c.hx_noise or m
    Q1_2 = np.zeros((w_dim, w_dim)) if c.Q1_2 is None else c.Q1_2
    R1_2 = np.zeros((v_dim, v_dim)) if c.R1_2 is None else c.R1_2
    rng = np.random.default_rng(seed)

    x = np.asarray(x0, dtype=float).reshape(n) + rng.standard_normal((M, n)) @ S0.T
    truth = np.empty((M, T, n))
    zs = np.empty((M, T, m))
    for t in range(T):
        w = rng.standard_normal((M, w_dim)) @ Q1_2.T
        v = rng.standard_normal((M, v_dim)) @ R1_2.T
        if c.fx_noise:
            x = _model(c.fx, "fx", t, x, (w, dt_list[t]), fx_list[t], c.vectorized, n)
        else:
            x = _model(c.fx, "fx", t, x, (dt_list[t],), fx_list[t], c.vectorized, n) + w
        if c.hx_noise:
            z = _model(c.hx, "hx", t, x, (v,), hx_list[t], c.vectorized, m)
        else:
            z = _model(c.hx, "hx", t, x, (), hx_list[t], c.vectorized, m) + v
        truth[:, t], zs[:, t] = x, z
    return truth, zs


def _model(fn, name: str, t: int, X: np.ndarray, args: tuple, kwargs: dict, vectorized: bool, d: int):
    """``fn`` at every run's state ``X`` ``(M, n)`` (a noise argument first in ``args`` is per run too),
    checked: ``(M, d)``, finite."""
    M = X.shape[0]
    if vectorized:
        values = fn(X, *args, **kwargs)
    else:
        per_run = [a for a in args if isinstance(a, np.ndarray)]
        rest = [a for a in args if not isinstance(a, np.ndarray)]
        values = [fn(X[i], *[a[i] for a in per_run], *rest, **kwargs) for i in range(M)]
    return check_values(values, (M, d), f"{name} values at step {t}")
