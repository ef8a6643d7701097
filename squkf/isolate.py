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
from typing import Any

import numpy as np

from . import step as steps
from .errors import NonFiniteError, NotPositiveDefiniteError, SqukfError
from .generators import SigmaSet
from .plan import Hooks, Plan

__all__ = [
    "BLOCK",
    "isolated_posterior",
    "isolated_prior",
    "numerical",
    "rows_of",
    "run_isolated",
    "take_set",
]

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
        The filters to run, in increasing order, each once.
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
    every = idx.size == K  # increasing and distinct in range(K): all of them, in order
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


def rows_of(a: np.ndarray | None, idx, core: int) -> np.ndarray | None:
    """``a[idx]`` when ``a`` is per filter (more than ``core`` axes), else ``a`` (shared).

    Parameters
    ----------
    a : ndarray, shape (K, *core_shape) or core_shape, or None
    idx : index array or slice of filters
    core : int
        Number of axes of one filter's value (2 for a factor).

    Returns
    -------
    ndarray or None
    """
    return a if a is None or a.ndim == core else a[idx]


def take_set(sset: SigmaSet, idx: np.ndarray | slice) -> SigmaSet:
    """The sigma-point set of the filters ``idx`` (rows of every stacked field)."""
    if isinstance(idx, slice) and idx == slice(None):
        return sset
    offsets = None if sset.offsets is None else sset.offsets[idx]
    return sset._replace(sigmas=sset.sigmas[idx], offsets=offsets)


def isolated_prior(plan: Plan, hooks: Hooks, X: np.ndarray, F: np.ndarray, Q1_2, idx, K: int, fails, block):
    """The priors of the filters ``idx`` from their propagated points, failing filters isolated.

    Parameters
    ----------
    plan : Plan
    hooks : Hooks
    X : ndarray, shape (K, N, n)
        The first sets.
    F : ndarray, shape (K, N, n)
        ``fx`` at them, float64, checked: finite for the filters ``idx``.
    Q1_2 : ndarray, shape (d, d) or (K, d, d), or None
        Process noise factor, shared or per filter (None: none added).
    idx : ndarray of int
        The filters to step.
    K : int
    fails : dict
        Filled with ``filter -> reason`` for the filters that fail.
    block : int
        Filters per block (:func:`run_isolated`).

    Returns
    -------
    good : ndarray of int
    result : (x (G, n), S (G, n, n)) or None
        The priors of ``good``.
    """

    def prior(ix):
        sub = steps.StepState(steps.PREDICTING, X[ix])
        _, x, S = steps.tell_predict(sub, plan, F[ix], rows_of(Q1_2, ix, 2), hooks, checked=True)
        return x, S

    return run_isolated(prior, idx, K, fails, block)


def isolated_posterior(state: steps.StepState, H, z, R1_2, todo, hooks: Hooks, gate, fails, block):
    """The gated updates of the filters ``todo``, grouped by their missing components, failing ones isolated.

    Filters with the same missing components are updated together (one
    stacked update each); a filter that no update reaches keeps its prior,
    with no innovation and no likelihood.

    Parameters
    ----------
    state : StepState
        The pending update of ``K`` filters (its second sets and priors).
    H : ndarray, shape (K, N2, m)
        ``hx`` at the second sets, float64, checked: finite for the filters ``todo``.
    z : ndarray, shape (K, m)
        Measurements, NaN where missing.
    R1_2 : ndarray, shape (m, m) or (K, m, m)
        Measurement noise factor, shared or per filter.
    todo : ndarray of bool, shape (K,)
        The filters to update.
    hooks : Hooks
    gate : Gate or None
    fails : dict
        Filled with ``filter -> reason`` for the filters that fail.
    block : int

    Returns
    -------
    tuple
        ``x (K, n)``, ``S (K, n, n)``, ``y (K, m)``, ``loglik (K,)``,
        ``nis (K,)``, ``rejected (K, m)``: fresh arrays.
    """
    sset = state.sset
    x0, S0 = state.prior  # type: ignore[misc]
    K, m = z.shape
    observed = ~np.isnan(z)

    def unchanged():
        """The records of filters that no update reaches: the prior, no innovation, no likelihood."""
        return (
            x0.copy(), S0.copy(), np.full((K, m), np.nan), np.zeros(K), np.zeros(K),
            np.zeros((K, m), dtype=bool),
        )  # fmt: skip

    # made at the first update that needs them
    x_new: Any = None
    S_new: Any = None
    y: Any = None
    loglik: Any = None
    nis: Any = None
    rejected: Any = None
    todo_idx = np.flatnonzero(todo)
    groups: list[tuple[np.ndarray, np.ndarray | None]] = [(todo_idx, None)]  # the usual case: one group
    if not (observed.all() or observed[todo].all()):
        patterns, which = np.unique(observed[todo], axis=0, return_inverse=True)
        which = which.reshape(-1)
        groups = [(todo_idx[which == p], None if obs.all() else obs) for p, obs in enumerate(patterns)]
    for group, mask in groups:

        def posterior(ix, mask=mask):
            sub = steps.StepState(steps.UPDATING, None, None, None, take_set(sset, ix), (x0[ix], S0[ix]))  # type: ignore[arg-type]
            _, g, _ = steps.gated_update(
                sub, H[ix], z[ix], rows_of(R1_2, ix, 2), mask, hooks, None, gate, checked=True
            )
            post = g.tested
            return g.x, g.S, post.y, g.log_likelihood, post.nis, g.rejected

        good, res = run_isolated(posterior, group, K, fails, block)
        if res is not None and good.size == K and mask is None:
            # every filter, in order, all measured: the kernels' fresh arrays as they are
            x_new, S_new, y, loglik, nis, rejected = res
        elif res is not None:
            if x_new is None:
                x_new, S_new, y, loglik, nis, rejected = unchanged()
            x_new[good], S_new[good] = res[0], res[1]
            if mask is None:
                y[good], rejected[good] = res[2], res[5]
            else:
                cols = np.ix_(good, np.flatnonzero(mask))
                y[cols], rejected[cols] = res[2], res[5]
            loglik[good], nis[good] = res[3], res[4]
    if x_new is None:
        return unchanged()
    return x_new, S_new, y, loglik, nis, rejected
