"""Module-level model functions for the Dask tests (worker processes import them by name)."""

from __future__ import annotations

import time

import numpy as np


def cv_fx(X, dt):
    """Constant velocity in 1-D: ``[p, v]``, vectorised over any leading axes."""
    out = X.copy()
    out[..., 0] = X[..., 0] + dt * X[..., 1]
    return out


def range_hx(X):
    """Range to a point one unit off the line, and the velocity."""
    return np.stack([np.hypot(X[..., 0], 1.0), X[..., 1]], axis=-1)


def slow_fx(X, dt):
    """``cv_fx`` that takes a while (so that a worker can be killed mid-chunk)."""
    time.sleep(0.02)
    return cv_fx(X, dt)


def nan_for_big_fx(X, dt):
    """``cv_fx``, but NaN for filters whose position exceeds 1e6 (an injected failure)."""
    out = cv_fx(X, dt)
    bad = np.abs(X[..., 0]).max(axis=-1) > 1e6
    out[bad] = np.nan
    return out
