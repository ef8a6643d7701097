"""The kernel tables, and the arrays as their entries take them.

A filter's route (:class:`squkf.engine.Route`) holds its :class:`KernelTable`, given when it is
built; every phase of the route calls it, and so do the wrappers of
:mod:`squkf.kernels.wrappers` (the hooks' prediction, the factor of R's observed block, a gate's
gain, the smoother) and :mod:`squkf.linalg` when a route's phase hands them its table
(``kernels=``). :data:`KERNELS` is the table installed: a route built without a table takes the one
installed at that moment, and a wrapper called without one (a user's call of :mod:`squkf.linalg`)
the one installed when it is called. Another backend gives its own table to the routes of its filters
(``Route(..., kernels=...)``), or replaces the installed one by assigning a :class:`KernelTable`
with the same entries and arguments to ``squkf.kernels.table.KERNELS`` (as ``tests/test_engine.py``
does).

The entries take C-contiguous float64 stacks with the filter axis first (one
signature each): :func:`kernel_array` gives an array so, :func:`plan_array` a
plan's read-only data, and :func:`zeros_row`, :func:`no_points`,
:func:`no_set`, :func:`no_noise` the shared arrays that stand for nothing
given.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from . import phases

__all__ = [
    "CENTRAL",
    "MEAN",
    "GIVEN",
    "KERNELS",
    "KernelTable",
    "chosen",
    "kernel_array",
    "no_angles",
    "no_factor",
    "no_noise",
    "no_points",
    "no_set",
    "plan_array",
    "zeros_row",
]

#: Row forms (:mod:`squkf.kernels.phases`).
CENTRAL, MEAN, GIVEN = 0, 1, 2
#: What the kernels do with an angle component (bits): a circular mean, a wrapped residual
#: (:func:`phases.angle_rows_kernel`, and the state's in :func:`phases.downdate_update_kernel`), a wrapped
#: sum ``x + dx`` (the posterior mean, :func:`phases.downdate_update_kernel`).
CIRCULAR_MEAN, WRAPPED, WRAPPED_ADD = 1, 2, 4


class KernelTable(NamedTuple):
    """The kernels of the step, for a block of filters: what the engine calls (:mod:`squkf.engine`).

    Each entry takes C-contiguous float64 stacks with the filter axis first and writes its
    results into the outputs it is given (:mod:`squkf.kernels.phases` documents the arguments).
    A second table (another backend) gives the same entries with the same arguments. A route holds
    one and hands it to every wrapper its phases call (the smoother takes its filter's from the
    configuration), so two filters on two tables each call only their own.
    """

    points: Callable
    transform: Callable
    joint_update: Callable
    downdate_update: Callable
    finite_rows: Callable
    tria: Callable
    solve: Callable
    chol_update: Callable
    angle_rows: Callable


#: The CPU table: the numba kernels.
KERNELS = KernelTable(
    phases.points_kernel,
    phases.transform_kernel,
    phases.joint_update_kernel,
    phases.downdate_update_kernel,
    phases.finite_rows_kernel,
    phases.tria_kernel,
    phases.solve_kernel,
    phases.chol_update_kernel,
    phases.angle_rows_kernel,  # squkf's angle hooks as data (compiled on first use of one)
)


_ZEROS: dict[int, np.ndarray] = {}


def chosen(kernels: KernelTable | None) -> KernelTable:
    """The table a call takes: the one given (a route's), else the one installed as :data:`KERNELS` now."""
    return KERNELS if kernels is None else kernels


def zeros_row(d: int) -> np.ndarray:
    """A shared reference of zeros, shape ``(1, d)`` (the kernels never write their inputs)."""
    z = _ZEROS.get(d)
    if z is None:
        z = _ZEROS[d] = np.zeros((1, d))
    return z


def kernel_array(a: np.ndarray) -> np.ndarray:
    """``a`` itself if it is float64, C-contiguous and writeable (one kernel signature), else a copy."""
    f = a.flags
    if f.c_contiguous and f.writeable and a.dtype == np.float64:
        return a
    return np.array(a, dtype=np.float64, order="C")


_NO_POINTS: dict[int, np.ndarray] = {}
_NO_SET: dict[int, np.ndarray] = {}


def no_points(d: int) -> np.ndarray:
    """No unit points, shape ``(0, d)``, read-only: a kernel told to draw no set."""
    a = _NO_POINTS.get(d)
    if a is None:
        a = _NO_POINTS[d] = plan_array(np.empty((0, d)))
    return a


def no_set(d: int) -> np.ndarray:
    """No set to write, shape ``(0, 1, d)``: a kernel's set output when none is drawn."""
    a = _NO_SET.get(d)
    if a is None:
        a = _NO_SET[d] = np.empty((0, 1, d))
    return a


_NO_NOISE: dict[int, np.ndarray] = {}
_NO_FACTOR: dict[int, np.ndarray] = {}
_NO_ANGLES: dict[int, np.ndarray] = {}


def no_factor(d: int) -> np.ndarray:
    """No factor given, shape ``(0, d, d)``: the update kernel forms the innovation factor itself."""
    a = _NO_FACTOR.get(d)
    if a is None:
        a = _NO_FACTOR[d] = np.empty((0, d, d))
    return a


def no_angles(d: int) -> np.ndarray:
    """No angle component, shape ``(d,)`` of int64 zeros, read-only (a plan's array)."""
    a = _NO_ANGLES.get(d)
    if a is None:
        a = _NO_ANGLES[d] = np.zeros(d, dtype=np.int64)
        a.setflags(write=False)
    return a


def no_noise(d: int) -> np.ndarray:
    """No additive noise for the transform kernel, shape ``(1, d, 0)``."""
    a = _NO_NOISE.get(d)
    if a is None:
        a = _NO_NOISE[d] = np.zeros((1, d, 0))
    return a


def plan_array(a: np.ndarray) -> np.ndarray:
    """A plan's array as the kernels take it: float64, C-contiguous and read-only.

    numba types a read-only array apart from a writeable one; the plan's arrays are
    frozen, so handing every one over read-only keeps each kernel at one signature.
    """
    if a.flags.writeable or not a.flags.c_contiguous or a.dtype != np.float64:
        a = np.ascontiguousarray(a, dtype=np.float64).view()
        a.flags.writeable = False
    return a
