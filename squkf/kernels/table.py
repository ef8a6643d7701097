"""The kernel table every numerical route reads, and the arrays as its entries take them.

:data:`KERNELS` is the table installed: the engine reads an entry at each
call (``table.KERNELS.points(...)``), and so do the wrappers of
:mod:`squkf.kernels.wrappers`, which the hooks' routes, the smoother and
:mod:`squkf.linalg` call. Another backend replaces it by assigning a
:class:`KernelTable` with the same entries and arguments to
``squkf.kernels.table.KERNELS`` (as ``tests/test_engine.py`` does); nothing
keeps a reference to the table itself, so no face changes.

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
    A second table (another backend) gives the same entries with the same arguments. Every
    numerical route reads the table when it runs (the engine, and the wrappers of
    :mod:`squkf.kernels.wrappers`, which the hooks' routes, the smoother and :mod:`squkf.linalg`
    call), so the table installed as :data:`KERNELS` serves them all.
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
