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

from .errors import ParameterError

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
    """Base of the picklable angle hooks: remembers which components are angles.

    Parameters
    ----------
    angle_indices : sequence of int
        The components that are angles (radians). Kept as a read-only tuple; a negative index counts
        from the end, as numpy's do. Whether each is in range is checked when the hook is given to a
        filter (its ``dim_x`` or ``dim_z``).

    Raises
    ------
    ParameterError
        ``angle_indices`` is not a sequence of integers.

    Notes
    -----
    The exact classes :class:`AngleMean`, :class:`AngleResidual` and :class:`AngleAdd` are data to a
    filter: it reads their indices when they are assigned and its compiled kernels wrap the residuals
    and sums and take the circular means themselves, with no Python call per point (the measurement's
    hooks ``z_mean_fn`` and ``residual_z``, the state's ``x_mean_fn``, ``residual_x`` and
    ``state_add``). A subclass is called as any user's hook is.
    """

    def __init__(self, angle_indices: Sequence[int]):
        self._indices = _as_indices(angle_indices)

    @property
    def angle_indices(self) -> tuple[int, ...]:
        """The components that are angles (read-only)."""
        return self._indices

    def __setstate__(self, state) -> None:
        state = dict(state)
        if "angle_indices" in state:  # a pickle from before the indices were a tuple (a list in __dict__)
            state["_indices"] = _as_indices(state.pop("angle_indices"))
        self.__dict__.update(state)

    def __repr__(self):
        return f"{type(self).__name__}({list(self._indices)})"


def _as_indices(angle_indices) -> tuple[int, ...]:
    """``angle_indices`` as a tuple of ints; ParameterError naming it unless it is a sequence of integers."""
    said = f"{angle_indices!r:.100}"
    try:
        items = list(angle_indices)
    except TypeError:
        items = None
    if (
        isinstance(angle_indices, (str, bytes))
        or items is None
        or not all(isinstance(i, (int, np.integer)) and not isinstance(i, (bool, np.bool_)) for i in items)
    ):
        raise ParameterError(f"angle_indices must be a sequence of integers, got angle_indices={said}")
    return tuple(int(i) for i in items)


def is_data(hook) -> bool:
    """Whether ``hook`` is an exact :class:`AngleMean`, :class:`AngleResidual` or :class:`AngleAdd`."""
    return type(hook) in (AngleMean, AngleResidual, AngleAdd)


def check_angle_hook(hook, name: str, dim: int, dim_name: str) -> None:
    """Refuse squkf's angle hook ``hook``, given as ``name``, if an index is out of range for ``dim``.

    Parameters
    ----------
    hook : object
        Anything but an exact squkf angle hook passes (:func:`is_data`).
    name : str
        The argument or attribute it was given as (``"residual_z"``), for the message.
    dim : int
        The dimension it indexes.
    dim_name : str
        That dimension's name (``"dim_z"``).

    Raises
    ------
    ParameterError
    """
    if not is_data(hook):
        return
    bad = [i for i in hook.angle_indices if not -dim <= i < dim]
    if bad:
        raise ParameterError(
            f"{name}={hook!r}: angle index {bad[0]} is out of range for {dim_name}={dim}"
            f" (an index is in {-dim}..{dim - 1})"
        )


def check_angle_hooks(dim_x: int, dim_z: int, **hooks) -> None:
    """:func:`check_angle_hook` for each of a constructor's hooks, by its argument's name.

    Parameters
    ----------
    dim_x, dim_z : int
    **hooks
        ``x_mean_fn``, ``z_mean_fn``, ``residual_x``, ``residual_z``, ``state_add``, any of them.

    Raises
    ------
    ParameterError
    """
    for name, hook in hooks.items():
        if name in ("z_mean_fn", "residual_z"):
            check_angle_hook(hook, name, dim_z, "dim_z")
        else:
            check_angle_hook(hook, name, dim_x, "dim_x")


def measurement_hooks_are_data(z_mean_fn, residual_z) -> bool:
    """Whether the measurement's hooks are squkf's (an exact :class:`AngleMean`, :class:`AngleResidual`,
    or None), at least one of them given: the kernels then do what they would (:func:`measurement_angles`)."""
    if z_mean_fn is None and residual_z is None:
        return False
    return (z_mean_fn is None or type(z_mean_fn) is AngleMean) and (
        residual_z is None or type(residual_z) is AngleResidual
    )


def measurement_angles(z_mean_fn, residual_z, m: int) -> np.ndarray | None:
    """What the kernels do with each measured component, when the measurement's hooks are data.

    Parameters
    ----------
    z_mean_fn, residual_z : callable or None
    m : int
        The measurement's dimension.

    Returns
    -------
    ndarray of int64, shape (m,), or None
        Per component, 1 for a circular mean (``z_mean_fn``'s angles), plus 2 for a wrapped residual
        (``residual_z``'s); None when a hook is neither None nor an exact :class:`AngleMean`,
        :class:`AngleResidual` respectively, or both are None (nothing to do).
    """
    if not measurement_hooks_are_data(z_mean_fn, residual_z):
        return None
    kind = np.zeros(m, dtype=np.int64)
    if z_mean_fn is not None:
        kind[list(z_mean_fn.angle_indices)] |= 1
    if residual_z is not None:
        kind[list(residual_z.angle_indices)] |= 2
    return kind


def state_hooks_are_data(x_mean_fn, residual_x, state_add) -> bool:
    """Whether the state's hooks are squkf's (an exact :class:`AngleMean`, :class:`AngleResidual`,
    :class:`AngleAdd`, or None each), at least one of them given: the kernels then do what they would
    (:func:`state_angles`)."""
    if x_mean_fn is None and residual_x is None and state_add is None:
        return False
    return (
        (x_mean_fn is None or type(x_mean_fn) is AngleMean)
        and (residual_x is None or type(residual_x) is AngleResidual)
        and (state_add is None or type(state_add) is AngleAdd)
    )


def state_angles(x_mean_fn, residual_x, state_add, n: int) -> np.ndarray | None:
    """What the kernels do with each state component, when the state's hooks are data.

    Parameters
    ----------
    x_mean_fn, residual_x, state_add : callable or None
    n : int
        The state's dimension.

    Returns
    -------
    ndarray of int64, shape (n,), read-only, or None
        Per component, 1 for a circular mean (``x_mean_fn``'s angles), plus 2 for a wrapped residual
        (``residual_x``'s), plus 4 for a wrapped sum (``state_add``'s); None unless
        :func:`state_hooks_are_data`.
    """
    if not state_hooks_are_data(x_mean_fn, residual_x, state_add):
        return None
    kind = np.zeros(n, dtype=np.int64)
    for hook, bit in ((x_mean_fn, 1), (residual_x, 2), (state_add, 4)):
        if hook is not None:
            kind[list(hook.angle_indices)] |= bit
    kind.setflags(write=False)  # (a plan's array, as the kernels take it)
    return kind


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
        idx = list(self.angle_indices)  # (the first axis: filterpy's points objects pass (n, N) arrays)
        d[idx] = wrap(d[idx])
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
        idx = list(self.angle_indices)
        s[idx] = wrap(s[idx])
        return s
