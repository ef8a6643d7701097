"""One filter's numerical failure is that filter's alone: the stacked core run with isolation.

Each filter's arithmetic in the stacked core is independent of the others',
so a failing filter can be found by running the others without it and get
the same numbers. :func:`run_isolated` runs a function of a set of filters
a block at a time (bounding the temporary arrays) and, when a block raises a
numerical error, runs that block's filters one at a time to find the failing
ones. The fleet's step and its smoother use it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .errors import NonFiniteError, NotPositiveDefiniteError, SqukfError

__all__ = ["BLOCK", "numerical", "run_isolated"]

#: Filters computed together in one block of the core's numerics (bounds the temporary arrays).
BLOCK = 4096


def numerical(exc: BaseException) -> bool:
    """Whether ``exc`` is a failure of one filter's arithmetic (not bad input or a broken model)."""
    return isinstance(exc, (NotPositiveDefiniteError, NonFiniteError)) or (
        isinstance(exc, SqukfError) and getattr(exc, "errno", None) in (301, 302, 303)
    )


def run_isolated(fn: Callable, idx: np.ndarray, K: int, fails: dict[int, str], block: int | None = None):
    """``fn`` over the filters ``idx`` (of ``K``), a block at a time; after a numerical error, one by one.

    Parameters
    ----------
    fn : callable
        ``fn(rows)`` with ``rows`` an index array or a slice of filters;
        returns a tuple of arrays with one leading entry per filter. For a
        failing filter ``k`` it is also called as ``fn(k)`` (no batch axis), to
        describe the failure by that filter's values alone.
    idx : ndarray of int
        The filters to run.
    K : int
        How many filters there are (when ``idx`` is all of them, ``fn`` gets slices: views, no copies).
    fails : dict
        Filled with ``filter -> reason`` for the filters that failed.
    block : int, optional
        Filters per block (default :data:`BLOCK`).

    Returns
    -------
    good : ndarray of int
        The filters that succeeded.
    results : tuple of ndarray, or None
        ``fn``'s results over ``good``.
    """
    if idx.size == 0:
        return idx, None
    size = BLOCK if block is None else block
    every = idx.size == K and bool(np.all(idx == np.arange(K)))
    cuts = list(range(0, idx.size, size)) + [idx.size]
    goods, parts = [], []
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        good, res = _block(fn, idx[lo:hi], slice(lo, hi) if every else None, fails)
        if res is not None:
            goods.append(good)
            parts.append(res)
    if not parts:
        return np.array([], dtype=int), None
    if len(parts) == 1:
        return goods[0], parts[0]
    joined = tuple(np.concatenate([p[i] for p in parts]) for i in range(len(parts[0])))
    return np.concatenate(goods), joined


def _run(fn: Callable, ix: np.ndarray, view: slice | None = None):
    # the compiled kernels compute each filter alone in its lane: a stack of one gives the numbers
    # the filter gets in any stack
    return fn(ix if view is None else view)


def _describe(fn: Callable, k: int, exc: SqukfError) -> str:
    """Why filter ``k`` failed, in the words of that filter alone.

    ``exc`` came from ``k`` computed as a stack of one (:func:`_run`), so a
    message quoting values (a diagonal, a matrix) would show the batch axis.
    ``fn`` at the bare index ``k`` computes the filter without a batch axis,
    as ``SquareRootUKF`` does; its error, when it fails the same way, is what
    the single filter would say. Otherwise ``exc`` is described as it is.
    """
    try:
        fn(k)
    except SqukfError as alone:
        if type(alone) is type(exc):
            return f"{type(alone).__name__}: {alone}"
    except Exception:  # noqa: BLE001  # fn may need a batch axis: keep the stack's own words
        pass
    return f"{type(exc).__name__}: {exc}"


def _block(fn: Callable, idx: np.ndarray, rows: slice | None, fails: dict[int, str]):
    try:
        return idx, _run(fn, idx, rows)
    except SqukfError as exc:
        if not numerical(exc):
            raise
    good, parts = [], []
    for k in idx.tolist():
        try:
            parts.append(_run(fn, np.array([k])))
            good.append(k)
        except SqukfError as exc:
            if not numerical(exc):
                raise
            fails.setdefault(k, _describe(fn, k, exc))
    if not good:
        return np.array([], dtype=int), None
    return np.array(good), tuple(np.concatenate([p[i] for p in parts]) for i in range(len(parts[0])))
