"""The fleet's step a chunk of filters at a time.

A step of K filters runs chunk by chunk, at most ``Fleet.chunk`` filters
each (by default :func:`default_chunk`, :data:`CHUNK` on one thread): a
chunk's first set is drawn, the model function is called with the chunk's
points, and the chunk's prior is computed (a prediction); or its second set
is drawn, the model called, and its posterior computed (an update). The
step's temporary arrays (points, images, the kernels' scratch and results)
are then the size of a chunk, not of the fleet: they stay in the processor's
cache, the step's memory does not grow with K beyond its results, and the
chunks can run on the threads of :func:`squkf.set_num_threads`. Each
filter's arithmetic is its own, so its numbers are the same, bit for bit,
whatever chunk or thread it is in (``tests/test_kernels.py``). Within a
chunk, a numerical failure is isolated per filter (:mod:`squkf.isolate`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from . import kernels
from . import step as steps
from .boundary.inputs import finite_images, stacked_shape
from .generators import SigmaSet
from .isolate import BLOCK, isolated_posterior, isolated_prior, rows_of, take_set
from .plan import Hooks, Plan

__all__ = ["CHUNK", "default_chunk", "chunks", "stacked_prior", "stacked_posterior", "Prior", "Posteriors"]

#: Filters per chunk of a fleet's step on one thread (their arrays stay in cache; see the module docstring).
CHUNK = 2048


def default_chunk(threads: int, K: int) -> int:
    """Filters per chunk when the fleet leaves it to the library: :data:`CHUNK`, or twice on threads.

    On several threads what stays serial is the step's Python per chunk,
    which holds the GIL; chunks twice as large halve it per filter, which
    pays once every thread has at least four of them. Below that, larger
    chunks only leave threads idle, and on one thread :data:`CHUNK` is the
    faster size (``benchmarks/chunk_sizes.py``; the figures in
    ARCHITECTURE.md, "Measured").

    Parameters
    ----------
    threads : int
        The thread count of :func:`squkf.set_num_threads`.
    K : int
        Filters in the step.

    Returns
    -------
    int
    """
    big = 2 * CHUNK
    return big if threads > 1 and K >= 4 * threads * big else CHUNK


def chunks(K: int, size: int = CHUNK, parts: int = 1) -> list[slice]:
    """The chunks of ``K`` filters, at most ``size`` each, as slices in order.

    With ``parts == 1``, ``size`` each and the last one shorter. With more
    parts (the threads they are run on) and more than one chunk, their count
    is rounded up to a multiple of ``parts`` and their sizes differ by one at
    most, so that every thread gets as many filters (10^4 filters on two
    threads: six chunks of 1666 or 1667, not 2048 * 4 + 1808, three on one
    thread).
    """
    count = -(-K // size)
    if parts > 1 and count > 1:
        count = min(K, -(-count // parts) * parts)
        q, r = divmod(K, count)  # the first r chunks get one filter more
        cuts = [i * q + min(i, r) for i in range(count + 1)]
        return [slice(lo, hi) for lo, hi in zip(cuts[:-1], cuts[1:])]
    return [slice(lo, min(lo + size, K)) for lo in range(0, K, size)]


def _label(name: str, rows: slice, K: int) -> str:
    """``name`` as said in a shape error: with the chunk's filters when it is not the whole fleet."""
    if rows.start == 0 and rows.stop == K:
        return name
    return f"{name} of filters {rows.start} to {rows.stop - 1} (one call of {rows.stop - rows.start})"


def _map_chunks(
    one: Callable[[slice], dict[int, str]], K: int, size: int | None, fails: dict[int, str]
) -> None:
    """``one`` over the chunks of a step of ``K`` filters, on the threads of :func:`squkf.set_num_threads`.

    The step holds the thread count it starts with (:func:`squkf.kernels.step_threads`):
    its chunks are cut for it and run on its threads whatever the count is set to meanwhile.
    """
    with kernels.step_threads() as threads:
        cut = chunks(K, default_chunk(threads, K) if size is None else size, threads)
        for part in kernels.thread_map(one, cut):
            fails.update(part)


class Prior(NamedTuple):
    """The priors of a fleet's prediction (fresh arrays).

    Attributes
    ----------
    x : ndarray, shape (K, n)
    S : ndarray, shape (K, n, n)
        A failing or inactive filter keeps its estimate.
    propagated : ndarray, shape (K, N, n), or None
        The first sets' images, when the plan's second set reads them.
    """

    x: np.ndarray
    S: np.ndarray
    propagated: np.ndarray | None


def stacked_prior(
    plan: Plan,
    hooks: Hooks,
    x: np.ndarray,
    S: np.ndarray,
    Q1_2: np.ndarray | None,
    active: np.ndarray,
    images: Callable[[slice, np.ndarray], object],
    fails: dict[int, str],
    first: np.ndarray | None = None,
    size: int | None = None,
) -> Prior:
    """The prediction of a stack of filters, a chunk at a time, failing filters isolated.

    Parameters
    ----------
    plan : Plan
    hooks : Hooks
    x : ndarray, shape (K, n)
    S : ndarray, shape (K, n, n)
    Q1_2 : ndarray, shape (d, d) or (K, d, d), or None
        Additive process noise factor, shared or per filter (None: none added).
    active : ndarray of bool, shape (K,)
        The filters to step (the others keep their estimate).
    images : callable
        ``images(rows, X)``: the model at the first sets ``X`` ``(k, N, n)`` of
        the filters ``rows`` (a slice), shape ``(k, N, n)``.
    fails : dict
        Filled with ``filter -> reason`` for the filters that fail.
    first : ndarray, shape (K, N, n), optional
        The first sets already handed out (``ask_predict``); default: drawn per chunk.
    size : int, optional
        Filters per chunk, at most (default: :func:`default_chunk` of the thread count and ``K``).

    Returns
    -------
    Prior
    """
    K = x.shape[0]
    x_new, S_new = np.empty_like(x), np.empty_like(S)
    propagated = np.empty((K,) + plan.first.xi.shape) if plan.keeps_propagated else None

    def one(rows: slice) -> dict[int, str]:
        found: dict[int, str] = {}
        xs, Ss = x[rows], S[rows]
        if first is None:
            X = steps.ask_predict(steps.StepState(), plan, xs, Ss, hooks.state_add).sigmas
        else:
            X = first[rows]
        assert X is not None
        k = X.shape[0]
        F = stacked_shape(images(rows, X), X.shape, _label("fx values", rows, K), False, ("fx", X.shape))
        on = active[rows]
        finite = finite_images(F, "fx values", on, found)
        if not finite.all():
            F = np.where(finite[:, None, None], F, X)  # a failing filter's rows: harmless stand-ins
        good, res = isolated_prior(
            plan, hooks, X, F, rows_of(Q1_2, rows, 2), np.flatnonzero(on & finite), k, found, BLOCK
        )
        xo, So = x_new[rows], S_new[rows]
        if res is not None and good.size == k:
            xo[...], So[...] = res
        else:
            xo[...], So[...] = xs, Ss
            if res is not None:
                xo[good], So[good] = res
        if propagated is not None:
            propagated[rows] = F
        return {rows.start + i: why for i, why in found.items()}

    _map_chunks(one, K, size, fails)
    return Prior(x_new, S_new, propagated)


class Posteriors(NamedTuple):
    """The records of a fleet's update (fresh arrays; a filter not updated keeps its prior).

    Attributes
    ----------
    x : ndarray, shape (K, n)
    S : ndarray, shape (K, n, n)
    y : ndarray, shape (K, m)
        Innovations (NaN where a component was missing or the filter not updated).
    log_likelihood, nis : ndarray, shape (K,)
        (The Mahalanobis distance is ``sqrt(nis)``.)
    rejected : ndarray of bool, shape (K, m)
    """

    x: np.ndarray
    S: np.ndarray
    y: np.ndarray
    log_likelihood: np.ndarray
    nis: np.ndarray
    rejected: np.ndarray


def stacked_posterior(
    plan: Plan,
    hooks: Hooks,
    gate,
    pending: steps.StepState,
    z: np.ndarray,
    R1_2: np.ndarray,
    active: np.ndarray,
    images: Callable[[slice, SigmaSet], object],
    fails: dict[int, str],
    size: int | None = None,
) -> Posteriors:
    """The update of a stack of filters, a chunk at a time, failing filters isolated.

    Parameters
    ----------
    plan, hooks, fails, size
        As for :func:`stacked_prior`.
    gate : Gate or None
    pending : StepState
        From :func:`squkf.step.pending_update`: the priors ``(K, ...)`` and
        their second sets, or None to draw them here a chunk at a time.
    z : ndarray, shape (K, m)
        Measurements, NaN where missing.
    R1_2 : ndarray, shape (m, m) or (K, m, m)
        Measurement noise factor, shared or per filter.
    active : ndarray of bool, shape (K,)
        The filters to update (the others keep their prior, with no innovation).
    images : callable
        ``images(rows, sset)``: the model at the second sets ``sset`` of the
        filters ``rows`` (a slice), shape ``(k, N2, m)``.

    Returns
    -------
    Posteriors
    """
    x, S = pending.prior  # type: ignore[misc]
    K, m = z.shape
    out = Posteriors(
        np.empty_like(x), np.empty_like(S), np.empty((K, m)), np.empty(K), np.empty(K),
        np.empty((K, m), dtype=bool),
    )  # fmt: skip
    sset, propagated, Q1_2 = pending.sset, pending.propagated, pending.Q1_2

    def one(rows: slice) -> dict[int, str]:
        found: dict[int, str] = {}
        xs, Ss = x[rows], S[rows]
        if sset is not None:
            s = take_set(sset, rows)
        else:
            prop = None if propagated is None else propagated[rows]
            s = plan.second.draw(xs, Ss, prop, rows_of(Q1_2, rows, 2), hooks.state_add)
        shape = s.sigmas.shape[:-1] + (m,)
        H = stacked_shape(images(rows, s), shape, _label("hx values", rows, K), False, ("hx", s.sigmas.shape))
        on = active[rows]
        finite = finite_images(H, "hx values", on, found)
        sub = steps.StepState(steps.UPDATING, None, None, None, s, (xs, Ss))
        records = isolated_posterior(
            sub, H, z[rows], rows_of(R1_2, rows, 2), on & finite, hooks, gate, found, BLOCK
        )
        for whole, part in zip(out, records):
            whole[rows] = part
        return {rows.start + i: why for i, why in found.items()}

    _map_chunks(one, K, size, fails)
    return out
