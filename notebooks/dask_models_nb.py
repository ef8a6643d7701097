"""Model functions and a simulator for ``07_dask.ipynb`` (the cluster's worker processes import them by name).

A target moving with constant velocity in the plane, ``x = [east, north,
v_east, v_north]`` (m, m/s), seen by a radar at the origin that measures
range (m) and bearing (rad, from east towards north). Targets stay in the
half-plane east > 0, so the bearing never crosses the ±π cut.
"""

from __future__ import annotations

import numpy as np

DT = 1.0  # s
RANGE_SD, BEARING_SD, ACCEL_SD = 0.5, 0.005, 0.05  # m, rad, m/s per step


def cv_fx(X, dt):
    """Constant velocity, vectorised over leading axes: ``(..., 4) -> (..., 4)``."""
    out = X.copy()
    out[..., 0] += dt * X[..., 2]
    out[..., 1] += dt * X[..., 3]
    return out


def range_bearing_hx(X):
    """Range and bearing from the origin: ``(..., 4) -> (..., 2)``."""
    return np.stack([np.hypot(X[..., 0], X[..., 1]), np.arctan2(X[..., 1], X[..., 0])], axis=-1)


def simulate(K: int, T: int, seed: int) -> np.ndarray:
    """Truth and measurements of K targets over T steps, ``(K, T, 6)``.

    ``[..., :4]`` is the true state, ``[..., 4:]`` the measured range and
    bearing. Targets start 500-1500 m out within ±60° of east, with
    velocities of about 5 m/s per axis that take white noise each step.
    """
    rng = np.random.default_rng(seed)
    r0 = rng.uniform(500.0, 1500.0, K)
    b0 = rng.uniform(-np.pi / 3, np.pi / 3, K)
    x = np.stack([r0 * np.cos(b0), r0 * np.sin(b0), rng.normal(0, 5, K), rng.normal(0, 5, K)], axis=1)
    out = np.empty((K, T, 6))
    for t in range(T):
        x = cv_fx(x, DT)
        x[:, 2:] += ACCEL_SD * rng.standard_normal((K, 2))
        out[:, t, :4] = x
    out[..., 4:] = range_bearing_hx(out[..., :4])
    out[..., 4] += RANGE_SD * rng.standard_normal((K, T))
    out[..., 5] += BEARING_SD * rng.standard_normal((K, T))
    return out


def first_fix(z0: np.ndarray) -> np.ndarray:
    """Initial states ``(K, 4)`` from first measurements ``(K, 2)``: the measured position, zero velocity."""
    r, b = z0[:, 0], z0[:, 1]
    return np.stack([r * np.cos(b), r * np.sin(b), np.zeros_like(r), np.zeros_like(r)], axis=1)
