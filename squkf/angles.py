"""Helpers for angle-valued states and measurements (filterpy's hooks, ready-made).

The hooks are small picklable objects that remember which components are
angles (in radians). Pass them to :class:`squkf.SquareRootUKF` as filterpy's
hooks: ``x_mean_fn``/``z_mean_fn=AngleMean(idx)``,
``residual_x``/``residual_z=AngleResidual(idx)`` and
``state_add=AngleAdd(idx)``.

Examples
--------
A bearing measured in the second component of ``z``:

>>> import numpy as np
>>> from squkf.angles import AngleMean, AngleResidual
>>> z_mean, residual_z = AngleMean([1]), AngleResidual([1])
>>> sigmas = np.array([[1.0, 3.1], [2.0, -3.1], [3.0, 3.0]])
>>> print(np.round(z_mean(sigmas, np.array([0.5, 0.25, 0.25])), 4))
[1.75   3.0958]
>>> print(np.round(residual_z([0.0, 3.1], [0.0, -3.1]), 4))
[ 0.     -0.0832]
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["wrap", "circular_mean", "AngleMean", "AngleResidual", "AngleAdd"]


def wrap(a):
    """Angles wrapped into ``[-pi, pi)``.

    Parameters
    ----------
    a : array_like
        Angles in radians, any shape.

    Returns
    -------
    ndarray
        Same shape as ``a``.

    Examples
    --------
    >>> import numpy as np
    >>> from squkf.angles import wrap
    >>> print(np.round(wrap([3.5, -4.0, 7.0]), 4))
    [-2.7832  2.2832  0.7168]
    """
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

    Examples
    --------
    Angles either side of ``pi`` average near ``pi``, not near 0 as their
    plain weighted mean (1.525) would:

    >>> import numpy as np
    >>> from squkf.angles import circular_mean
    >>> round(circular_mean(np.array([3.1, -3.1, 3.0]), np.array([0.5, 0.25, 0.25])), 4)
    3.0958

    Negative weights (Merwe's points with a small alpha) are fine:

    >>> angles = np.array([3.1, -3.1, 3.0, -3.0, 3.1])
    >>> round(circular_mean(angles, np.array([-3.0, 1.0, 1.0, 1.0, 1.0])), 4)
    -3.0168
    """
    angles = np.asarray(angles, dtype=float)
    ref = angles[int(np.argmax(np.abs(W)))] if reference is None else reference
    return float(wrap(ref + np.dot(W, wrap(angles - ref))))


class AngleHook:
    """Base of the picklable angle hooks: remembers which components are angles."""

    def __init__(self, angle_indices: Sequence[int]):
        self.angle_indices = [int(i) for i in angle_indices]

    def __repr__(self):
        return f"{type(self).__name__}({self.angle_indices})"


class AngleMean(AngleHook):
    """``x_mean_fn``/``z_mean_fn``: weighted mean with circular means of the angle components."""

    def __call__(self, sigmas: np.ndarray, Wm: np.ndarray) -> np.ndarray:
        sigmas = np.asarray(sigmas, dtype=float)
        m = Wm @ sigmas
        for i in self.angle_indices:
            m[i] = circular_mean(sigmas[:, i], Wm)
        return m


class AngleResidual(AngleHook):
    """``residual_x``/``residual_z``: ``a - b`` with the angle components wrapped."""

    def __call__(self, a, b) -> np.ndarray:
        d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
        d[self.angle_indices] = wrap(d[self.angle_indices])
        return d


class AngleAdd(AngleHook):
    """``state_add``: ``x + dx`` with the angle components wrapped.

    Examples
    --------
    >>> import numpy as np
    >>> from squkf.angles import AngleAdd
    >>> print(np.round(AngleAdd([1])([0.0, 3.1], [1.0, 0.2]), 4))
    [ 1.     -2.9832]
    """

    def __call__(self, x, dx) -> np.ndarray:
        s = np.asarray(x, dtype=float) + np.asarray(dx, dtype=float)
        s[self.angle_indices] = wrap(s[self.angle_indices])
        return s
