"""Helpers for angle-valued states and measurements (filterpy's hooks, ready-made)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["wrap", "circular_mean", "AngleMean", "AngleResidual", "AngleAdd"]


def wrap(a):
    """Angles wrapped into ``[-pi, pi)``."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def circular_mean(angles: np.ndarray, W: np.ndarray, reference: float | None = None) -> float:
    """Weighted mean of angles as a reference plus the weighted mean of wrapped offsets.

    ``atan2(sum W sin, sum W cos)`` fails when weights are negative (Merwe's
    alpha < 1 gives a large negative central weight): the weighted sums of
    sines and cosines no longer describe a point on the circle. Averaging the
    offsets ``wrap(a_i - ref)`` about a reference point (by default the angle
    with the largest ``|W|``, the central sigma point) is exact for points
    spread less than pi about it, for weights of any sign.

    Parameters
    ----------
    angles : ndarray, shape (N,)
    W : ndarray, shape (N,)
        Weights summing to 1.
    reference : float, optional

    Returns
    -------
    float
        The mean, wrapped into ``[-pi, pi)``.
    """
    angles = np.asarray(angles, dtype=float)
    ref = angles[int(np.argmax(np.abs(W)))] if reference is None else reference
    return float(wrap(ref + np.dot(W, wrap(angles - ref))))


class _AngleHook:
    """Base of the picklable angle hooks: remembers which components are angles."""

    def __init__(self, angle_indices: Sequence[int]):
        self.angle_indices = [int(i) for i in angle_indices]

    def __repr__(self):
        return f"{type(self).__name__}({self.angle_indices})"


class AngleMean(_AngleHook):
    """``x_mean_fn``/``z_mean_fn``: weighted mean with circular means of the angle components."""

    def __call__(self, sigmas: np.ndarray, Wm: np.ndarray) -> np.ndarray:
        sigmas = np.asarray(sigmas, dtype=float)
        m = Wm @ sigmas
        for i in self.angle_indices:
            m[i] = circular_mean(sigmas[:, i], Wm)
        return m


class AngleResidual(_AngleHook):
    """``residual_x``/``residual_z``: ``a - b`` with the angle components wrapped."""

    def __call__(self, a, b) -> np.ndarray:
        d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
        d[self.angle_indices] = wrap(d[self.angle_indices])
        return d


class AngleAdd(_AngleHook):
    """``state_add``: ``x + dx`` with the angle components wrapped."""

    def __call__(self, x, dx) -> np.ndarray:
        s = np.asarray(x, dtype=float) + np.asarray(dx, dtype=float)
        s[self.angle_indices] = wrap(s[self.angle_indices])
        return s
