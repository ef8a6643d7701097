"""Module-level model functions for the Dask benchmark (worker processes import them by name).

A target moving with constant velocity in the plane, ``x = [px, py, vx, vy]``
(n = 4), seen by a radar at the origin measuring range and bearing (m = 2).
The targets stay in the half-plane ``px > 0``, so the bearing never crosses
the ±π cut and needs no angle wrapping.
"""

from __future__ import annotations

import numpy as np

DT = 1.0


def cv_fx(X, dt):
    """Constant velocity, vectorised over any leading axes: ``(..., 4) -> (..., 4)``."""
    out = X.copy()
    out[..., 0] += dt * X[..., 2]
    out[..., 1] += dt * X[..., 3]
    return out


def range_bearing_hx(X):
    """Range and bearing from the origin: ``(..., 4) -> (..., 2)``."""
    return np.stack([np.hypot(X[..., 0], X[..., 1]), np.arctan2(X[..., 1], X[..., 0])], axis=-1)


P0_SD = np.array([10.0, 10.0, 5.0, 5.0])  # initial errors: the filters start at truth + N(0, diag(P0_SD**2))


def _start(K: int, seed: int):
    rng = np.random.default_rng(seed)
    r0 = rng.uniform(500.0, 1500.0, K)
    b0 = rng.uniform(-np.pi / 3, np.pi / 3, K)
    truth0 = np.stack([r0 * np.cos(b0), r0 * np.sin(b0), rng.normal(0, 5, K), rng.normal(0, 5, K)], axis=1)
    x0 = truth0 + P0_SD * rng.standard_normal((K, 4))
    return truth0, x0, rng


def initial_states(K: int, seed: int) -> np.ndarray:
    """The filters' initial states ``(K, 4)`` for the targets of :func:`simulated_block` with this seed."""
    return _start(K, seed)[1]


def simulated_block(K: int, T: int, seed: int, q: float = 0.05, sr: float = 0.5, sb: float = 0.005):
    """Truth and measurements of K targets ``(K, T, 6)``: ``[..., :4]`` truth, ``[..., 4:]`` range, bearing.

    Targets start 500-1500 m out at bearings within ±60°, with velocities of
    about 5 m/s per axis; each step (1 s) the velocity takes white noise of
    standard deviation ``q`` m/s; range noise ``sr`` m, bearing noise ``sb`` rad.
    """
    x, _, rng = _start(K, seed)
    out = np.empty((K, T, 6))
    for t in range(T):
        x = cv_fx(x, DT)
        x[:, 2:] += q * rng.standard_normal((K, 2))
        out[:, t, :4] = x
    out[..., 4:] = range_bearing_hx(out[..., :4])
    out[..., 4] += sr * rng.standard_normal((K, T))
    out[..., 5] += sb * rng.standard_normal((K, T))
    return out


def worker_rss() -> int:
    """This process's resident set size in bytes (run on the workers with ``client.run``)."""
    import psutil

    return psutil.Process().memory_info().rss
