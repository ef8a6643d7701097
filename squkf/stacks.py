"""A fleet's step, a chunk of filters at a time: the engine's route on each chunk, failures flagged alone.

A step of K filters runs chunk by chunk, at most ``Fleet.chunk`` filters each
(by default :func:`default_chunk`, :data:`CHUNK` on one thread): a chunk's
first set is drawn, the model is called with the chunk's points, and the
chunk's prior computed (a prediction); or its second set is drawn, the model
called, and its posterior computed (an update). Each is a phase of the
engine's :class:`~squkf.engine.Route` on a block of the chunk's filters, the
same kernels as one filter's step. The step's temporary arrays are then the
size of a chunk, not of the fleet, and the chunks can run on the threads of
:func:`squkf.set_num_threads`. Each filter's arithmetic is its own, so its
numbers are the same, bit for bit, whatever chunk or thread it is in.

A filter's numerical failure is its own: the kernels report a status per
filter, and a filter that fails (or whose images are not finite) is flagged
with the reason a single filter would give (:func:`squkf.statuses.failure`),
keeps its state, and the others go on. The routes through the hooks or a
``UT`` raise instead; their chunk is then run again a filter at a time
(:func:`run_isolated`) to find the failing ones.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable, Mapping
from typing import NamedTuple

import numpy as np

from .boundary.records import log_det as log_det_of
from .checks import describe_nonfinite, finite_images, stacked_shape
from .engine import Buffers, Route, Scratch
from .errors import NonFiniteError, NotPositiveDefiniteError, SqukfError
from .generators import SigmaSet
from .kernels.table import kernel_array
from .kernels.threads import enter_step, exit_step, thread_map
from .rows import RowForm
from .statuses import failure

__all__ = [
    "BLOCK",
    "CHUNK",
    "CHUNK_BYTES",
    "Posteriors",
    "Prior",
    "chunks",
    "default_chunk",
    "numerical",
    "predict",
    "rows_of",
    "run_isolated",
    "take_set",
    "update",
]

#: Filters per chunk of a fleet's step on one thread (their arrays stay in cache; see the module docstring).
CHUNK = 2048

#: Filters computed together in one block of a route that raises (bounds the temporary arrays).
BLOCK = 4096

#: The fewest filters per chunk the default gives (below it, the step's Python per chunk would dominate).
MIN_CHUNK = 64

#: Bytes of a chunk's largest array per model call (its points or images), at most, in a chunk of
#: :data:`CHUNK` filters (twice as many on threads: twice this): larger chunks outgrow the caches
#: (``benchmarks/chunk_sizes.py --model n10``: at n = 10, 2048 filters a chunk took 1.11x the time of
#: 624, the size this gives; at n = 4 the bound is not reached).
CHUNK_BYTES = 1 << 20


def fixed_mmap_threshold(environ: Mapping[str, str] = os.environ) -> int | None:
    """glibc's mmap threshold in bytes when the environment fixes it, else None.

    Setting ``MALLOC_TRIM_THRESHOLD_`` (as ``distributed`` does for a Dask
    worker, 65536) or ``MALLOC_MMAP_THRESHOLD_`` stops glibc from raising its
    mmap threshold as a program frees large blocks: every array of at least
    the threshold (128 KiB unless ``MALLOC_MMAP_THRESHOLD_`` says otherwise)
    is then mapped on allocation and unmapped when freed, its pages faulted
    in anew each time. A model function's arrays of a chunk are made and
    freed at every step, so :func:`default_chunk` keeps them under it.

    Parameters
    ----------
    environ : mapping, optional
        The environment read (default: this process's).

    Returns
    -------
    int or None
    """
    if not sys.platform.startswith("linux"):
        return None
    mmap = environ.get("MALLOC_MMAP_THRESHOLD_")
    if mmap is not None:
        try:
            return max(int(mmap), 0)
        except ValueError:
            return None
    return 128 * 1024 if "MALLOC_TRIM_THRESHOLD_" in environ else None


_MMAP_THRESHOLD = fixed_mmap_threshold()


def default_chunk(threads: int, K: int, row_bytes: int = 0) -> int:
    """Filters per chunk when the fleet leaves it to the library: :data:`CHUNK`, or twice on threads.

    On several threads what stays serial is the step's Python per chunk,
    which holds the GIL; chunks twice as large halve it per filter, which
    pays once every thread has at least four of them. Below that, larger
    chunks only leave threads idle, and on one thread :data:`CHUNK` is the
    faster size (``benchmarks/chunk_sizes.py``; the figures in
    ARCHITECTURE.md, "Measured").

    A model with large points has fewer filters a chunk: its largest array
    per call of the model, ``row_bytes`` per filter, stays within
    :data:`CHUNK_BYTES` (twice that for chunks twice as large), and, where
    the environment fixes glibc's mmap threshold (:func:`fixed_mmap_threshold`:
    a Dask worker), under that threshold: a larger one is mapped and faulted
    in at every call (``benchmarks/fleet.py`` measures the difference). A
    chunk has at least :data:`MIN_CHUNK` filters.

    Parameters
    ----------
    threads : int
        The thread count of :func:`squkf.set_num_threads`.
    K : int
        Filters in the step.
    row_bytes : int, optional
        Bytes per filter of the largest array a model call makes (its points
        or images); 0: not known.

    Returns
    -------
    int
    """
    big = 2 * CHUNK
    size = big if threads > 1 and K >= 4 * threads * big else CHUNK
    if row_bytes:
        limit = CHUNK_BYTES * (size // CHUNK)
        if _MMAP_THRESHOLD is not None:
            limit = min(limit, _MMAP_THRESHOLD - 1)
        size = min(size, max(MIN_CHUNK, limit // row_bytes))
    return size


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
    one: Callable[[slice], dict[int, str]], K: int, size: int | None, fails: dict[int, str], row_bytes: int
) -> None:
    """``one`` over the chunks of a step of ``K`` filters, on the threads of :func:`squkf.set_num_threads`.

    The step holds the thread count it starts with (:func:`squkf.kernels.threads.enter_step`):
    its chunks are cut for it and run on its threads whatever the count is set to meanwhile.
    """
    held, own = enter_step()
    try:
        threads = held.n
        if size is None:
            size = default_chunk(threads, K, row_bytes)
        if K <= size:  # one chunk: on this thread
            found = one(slice(0, K))
            if found:
                fails.update(found)
            return
        for part in thread_map(one, chunks(K, size, threads)):
            fails.update(part)
    finally:
        exit_step(held, own)


class _Spare(threading.local):
    """This thread's chunk arrays that no running chunk holds: a stack of :class:`Scratch`.

    A chunk takes the last one (a new one if none is left) and gives it back when it ends; nothing of a
    chunk's outlives it. A fleet stepped inside another's model function on the same thread (a nested
    step) takes another while the outer chunk holds its own, so neither writes the other's arrays; each
    chunk gets the same one at every step (the outer's is given back last), made once for its largest
    chunk. A chunk that raises drops its own (the next chunk makes another).
    """

    def __init__(self) -> None:
        self.free: list[Scratch] = []


_spare = _Spare()


def _estimates(K: int, n: int) -> tuple:
    """A step's new estimates ``(K, n)``, ``(K, n, n)``: the prediction's and the update's in turn."""
    return np.empty((K, n)), np.empty((K, n, n))


def _propagated(K: int, N: int, n: int) -> tuple:
    """A prediction's images where the update reads them, ``(K, N, n)``."""
    return (np.empty((K, N, n)),)


def _update_records(K: int, m: int) -> tuple:
    """A fleet update's records besides the estimate: ``y``, log-likelihoods, NIS, ``rejected``, the
    whitened innovations and ``log det S1_2``."""
    return (
        np.empty((K, m)), np.empty(K), np.empty(K), np.empty((K, m), dtype=bool),
        np.empty((K, m)), np.empty(K),
    )  # fmt: skip


def _second_size(plan, Q1_2) -> int:
    """Points in a second set, as far as the plan knows them (a user's generator: as many as the first).

    The augmented set is the propagated points and the noise's; with no process noise (``Q1_2`` None)
    it is the propagated points alone.
    """
    fused, N = plan.fused_draw, plan.xi1.shape[0]
    if fused is None or (fused.augmented and Q1_2 is None):
        return N
    return fused.xi.shape[0] + (N if fused.augmented else 0)


def _as_kernels_take(x: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The estimates as the kernels take them (float64, C-contiguous, writeable): so are their chunks.

    :func:`squkf.kernels.table.kernel_array` of each, with the usual case (both already so) in one call.
    """
    fx, fS = x.flags, S.flags
    if fx.c_contiguous and fx.writeable and fS.c_contiguous and fS.writeable and x.dtype == S.dtype == float:
        return x, S
    return kernel_array(x), kernel_array(S)


def _statuses(k: int) -> tuple:
    return (np.empty(k, dtype=np.int64),)


def _chunk_update(k: int, n: int, m: int) -> tuple:
    """The joint kernel's outputs a chunk does not keep: ``zp, Sy, L21, dx, status``."""
    return (
        np.empty((k, m)), np.empty((k, m, m)), np.empty((k, n, m)), np.empty((k, n)),
        np.empty(k, dtype=np.int64),
    )  # fmt: skip


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


def take_set(sset: SigmaSet, idx) -> SigmaSet:
    """The sigma-point set of the filters ``idx`` (rows of every stacked field)."""
    offsets = None if sset.offsets is None else sset.offsets[idx]
    return sset._replace(sigmas=sset.sigmas[idx], offsets=offsets)


# -- failures -------------------------------------------------------------------------------


def numerical(exc: BaseException) -> bool:
    """Whether ``exc`` is a failure of one filter's arithmetic (not bad input or a broken model)."""
    return isinstance(exc, (NotPositiveDefiniteError, NonFiniteError)) or (
        isinstance(exc, SqukfError) and getattr(exc, "errno", None) in (301, 302, 303)
    )


def _said(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


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


def _describe(fn: Callable, k: int, exc: SqukfError) -> str:
    """Why filter ``k`` failed, in the words of that filter alone (``fn(k)``: no batch axis), as
    ``SquareRootUKF`` would say it; otherwise ``exc`` as it is."""
    try:
        fn(k)
    except SqukfError as alone:
        if type(alone) is type(exc):
            return _said(alone)
    except Exception:  # noqa: BLE001  # fn may need a batch axis: keep the stack's own words
        pass
    return _said(exc)


def _block(fn: Callable, idx: np.ndarray, rows: slice | None, fails: dict[int, str]):
    try:
        return idx, fn(idx if rows is None else rows)
    except SqukfError as exc:
        if not numerical(exc):
            raise
    good, parts = [], []
    for k in idx.tolist():
        try:
            parts.append(fn(np.array([k])))
            good.append(k)
        except SqukfError as exc:
            if not numerical(exc):
                raise
            fails.setdefault(k, _describe(fn, k, exc))
    if not good:
        return np.array([], dtype=int), None
    return np.array(good), tuple(np.concatenate([p[i] for p in parts]) for i in range(len(parts[0])))


def _flag(status: np.ndarray, on: np.ndarray, found: dict[int, str], form, what: str, images, name: str):
    """The filters ``on`` whose ``status`` is a success; the others added to ``found`` with their reason,
    in a single filter's words (:func:`squkf.statuses.failure`; images that are not finite described by
    their own rows).

    Parameters
    ----------
    status : ndarray of int, shape (B,)
    on : ndarray of bool, shape (B,)
    found : dict
    form : RowForm or None
        The rows the kernel's status refers to.
    what : {"prior", "update"}
    images : ndarray, shape (B, N, d)
    name : str
        What the images are called.

    Returns
    -------
    ndarray of bool, shape (B,)
    """
    bad = on & (status != 0)
    for k in np.flatnonzero(bad).tolist():
        code = int(status[k])
        exc = (
            NonFiniteError(describe_nonfinite(images[k], name)) if code == 306 else failure(code, form, what)
        )
        found.setdefault(k, _said(exc))
    return on & ~bad


# -- the prediction -------------------------------------------------------------------------------


class Prior(NamedTuple):
    """The priors of a fleet's prediction (in the fleet's buffers where given, else new arrays).

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


def predict(
    route: Route,
    x: np.ndarray,
    S: np.ndarray,
    Q1_2: np.ndarray | None,
    active: np.ndarray,
    images: Callable[[slice, np.ndarray], object],
    fails: dict[int, str],
    first: np.ndarray | None = None,
    size: int | None = None,
    buffers: Buffers | None = None,
    held: tuple = (),
) -> Prior:
    """The prediction of a stack of filters, a chunk at a time, failing filters flagged alone.

    Parameters
    ----------
    route : Route
        The fleet's (``single`` False).
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
    buffers : Buffers, optional
        The fleet's: the results are written into its spare sets (the caller commits them), the
        estimates into a set none of whose arrays is one of ``held`` (:meth:`Buffers.spare`).
    held : tuple of ndarray
        The arrays the fleet's records hold (its estimate, prior and posterior).

    Returns
    -------
    Prior
    """
    K, n = x.shape
    x, S = _as_kernels_take(x, S)
    plan = route.plan
    N = plan.xi1.shape[0]
    keep = plan.keeps_propagated

    if buffers is None:
        x_new, S_new = _estimates(K, n)
        propagated = _propagated(K, N, n)[0] if keep else None
    else:
        x_new, S_new = buffers.spare(held, _estimates, K, n)
        propagated = buffers.take(_propagated, K, N, n)[0] if keep else None
    form = plan.first.rows.best
    none = route.no_set

    def one(rows: slice) -> dict[int, str]:
        found: dict[int, str] = {}
        xs, Ss = x[rows], S[rows]  # (the fleet's own C-contiguous arrays: their rows are as the kernels take)
        free = _spare.free
        scratch = free.pop() if free else Scratch()  # this chunk's alone, until given back (_Spare)
        X = route.first_points(xs, Ss, scratch) if first is None else first[rows]
        label = "fx values" if rows.stop - rows.start == K else _label("fx values", rows, K)
        F = stacked_shape(images(rows, X), X.shape, label, False, ("fx", X.shape))
        F = kernel_array(F)  # (a model's array of another layout: copied once, as kernels take it)
        on = active[rows]
        Qr = Q1_2 if Q1_2 is None or Q1_2.ndim == 2 else Q1_2[rows]
        xo, So = x_new[rows], S_new[rows]
        if route.plain_x:  # the kernel checks the images and reports each filter's failure
            k = xs.shape[0]
            status = scratch.take(_statuses, k)[0]
            route.prior(F, Qr, None, False, out=(xo, So, status, none, none))  # into the step's results
            good = _flag(status, on, found, form, "prior", F, "fx values")
            if not good.all():  # a failing or inactive filter keeps its estimate
                bad = ~good
                xo[bad], So[bad] = xs[bad], Ss[bad]
        else:  # the hooks raise: the chunk is run again a filter at a time to find the failing ones
            finite = finite_images(F, "fx values", on, found)

            def prior(ix):
                r, ix = _one_or_all(route, ix)  # one filter (an int): as a single filter says its failure
                mean, Sm, _, _ = r.prior(F[ix], rows_of(Qr, ix, 2), None, False)
                return mean, Sm

            good_ix, res = run_isolated(prior, np.flatnonzero(on & finite), xs.shape[0], found)
            xo[...], So[...] = xs, Ss
            if res is not None:
                xo[good_ix], So[good_ix] = res
        if propagated is not None:
            propagated[rows] = F
        free.append(scratch)
        return {rows.start + i: why for i, why in found.items()} if found and rows.start else found

    _map_chunks(one, K, size, fails, 8 * N * n)
    return Prior(x_new, S_new, propagated)


# -- the update ------------------------------------------------------------------------------


class Posteriors(NamedTuple):
    """The records of a fleet's update (in the fleet's buffers where given, else new arrays; a filter not
    updated keeps its prior).

    Attributes
    ----------
    x : ndarray, shape (K, n)
    S : ndarray, shape (K, n, n)
    y : ndarray, shape (K, m)
        Innovations (NaN where a component was missing or the filter not updated).
    log_likelihood, nis : ndarray, shape (K,)
        (The Mahalanobis distance is ``sqrt(nis)``.)
    rejected : ndarray of bool, shape (K, m)
    y_whitened : ndarray, shape (K, m)
        ``S1_2^-1 y`` (NaN as ``y``).
    log_det_S1_2 : ndarray, shape (K,)
        Of the measured block (0 where a filter was not updated).
    """

    x: np.ndarray
    S: np.ndarray
    y: np.ndarray
    log_likelihood: np.ndarray
    nis: np.ndarray
    rejected: np.ndarray
    y_whitened: np.ndarray
    log_det_S1_2: np.ndarray


def update(
    route: Route,
    x: np.ndarray,
    S: np.ndarray,
    sset: SigmaSet | None,
    propagated: np.ndarray | None,
    Q1_2: np.ndarray | None,
    z: np.ndarray,
    R1_2: np.ndarray,
    active: np.ndarray,
    images: Callable[[slice, SigmaSet], object],
    fails: dict[int, str],
    size: int | None = None,
    buffers: Buffers | None = None,
    held: tuple = (),
) -> Posteriors:
    """The update of a stack of filters, a chunk at a time, failing filters flagged alone.

    Parameters
    ----------
    route : Route
    x : ndarray, shape (K, n)
    S : ndarray, shape (K, n, n)
        The priors.
    sset : SigmaSet or None
        Their second sets ``(K, N2, n)`` (handed out by ``ask_update``), or None
        to draw them here a chunk at a time.
    propagated : ndarray, shape (K, N, n), or None
        The prediction's images, for a second set that reads them.
    Q1_2 : ndarray or None
        The prediction's process-noise factor (for the augmented set).
    z : ndarray, shape (K, m)
        Measurements, NaN where missing.
    R1_2 : ndarray, shape (m, m) or (K, m, m)
        Measurement noise factor, shared or per filter.
    active : ndarray of bool, shape (K,)
        The filters not flagged; those of them with a measurement in ``z``
        are updated (the others keep their prior, with no innovation).
    images : callable
        ``images(rows, sset)``: the model at the second sets ``sset`` of the
        filters ``rows`` (a slice), shape ``(k, N2, m)``.
    fails, size, buffers, held
        As for :func:`predict`.

    Returns
    -------
    Posteriors
    """
    K, m = z.shape
    n = x.shape[1]
    x, S = _as_kernels_take(x, S)

    if buffers is None:
        out = Posteriors(*_estimates(K, n), *_update_records(K, m))
    else:
        out = Posteriors(*buffers.spare(held, _estimates, K, n), *buffers.take(_update_records, K, m))

    def one(rows: slice) -> dict[int, str]:
        found: dict[int, str] = {}
        xs, Ss = x[rows], S[rows]  # (the fleet's own C-contiguous arrays: their rows are as the kernels take)
        free = _spare.free
        scratch = free.pop() if free else Scratch()  # this chunk's alone, until given back (_Spare)
        if sset is not None:
            s = take_set(sset, rows)
        else:
            prop = None if propagated is None else propagated[rows]
            s = route.second_set(xs, Ss, prop, rows_of(Q1_2, rows, 2), scratch)
        shape = s.sigmas.shape[:-1] + (m,)
        label = "hx values" if rows.stop - rows.start == K else _label("hx values", rows, K)
        H = kernel_array(stacked_shape(images(rows, s), shape, label, False, ("hx", s.sigmas.shape)))
        zr = _measured_rows(z, rows, scratch)
        obs = ~np.isnan(zr)
        on = active[rows] & obs.any(axis=1)
        Rr = R1_2 if R1_2.ndim == 2 else R1_2[rows]
        joint = route.update_route(s, None)
        plain = joint is not None
        if joint is not None and route.gate is None and obs.all():  # the usual case: straight into the step's
            part = out if rows.stop - rows.start == K else [a[rows] for a in out]
            _whole_chunk(route, joint.form, s, xs, Ss, H, zr, Rr, on, found, part, scratch)
            free.append(scratch)
            return {rows.start + i: why for i, why in found.items()} if found and rows.start else found
        if not plain:  # the hooks raise: non-finite images flagged first
            on = on & finite_images(H, "hx values", on, found)
        records = _posteriors(route, s, xs, Ss, H, zr, obs, Rr, on, found)
        for record, rows_record in zip(out, records):
            record[rows] = rows_record
        free.append(scratch)
        return {rows.start + i: why for i, why in found.items()} if found and rows.start else found

    _map_chunks(one, K, size, fails, 8 * _second_size(route.plan, Q1_2) * max(n, m))
    return out


def _measured_rows(z: np.ndarray, rows: slice, scratch: Scratch) -> np.ndarray:
    """The chunk's rows of ``z`` in its own array, read once and checked as read.

    A chunk's copy, not the step's: the step never holds a second ``(K, m)`` array, and what the
    kernels use is what was checked, even if the model functions wrote into the caller's ``z``.
    """
    zr = scratch.take(_rows_of_z, rows.stop - rows.start, z.shape[1])[0]
    np.copyto(zr, z[rows])
    if np.isinf(zr).any():
        k = rows.start + int(np.flatnonzero(np.isinf(zr).any(axis=1))[0])
        raise NonFiniteError(f"z contains inf (row {k}; NaN means a missing component)")
    return zr


def _rows_of_z(k: int, m: int) -> tuple:
    return (np.empty((k, m)),)


def _whole_chunk(
    route: Route, form: RowForm, sset, x0, S0, H, z, R1_2, on, found, out, scratch: Scratch
) -> None:
    """A chunk's update with every component measured and no gate, the joint kernel writing the step's
    arrays ``out`` (``x, S, y, loglik, nis, rejected, y_whitened, log_det_S1_2`` rows) directly; a failing
    or inactive filter keeps its prior, with no innovation and no likelihood. ``form``: the joint route's
    rows (a failure's words)."""
    x, S, y, ll, nis, rejected, w, log_det = out
    k, m = z.shape
    n = x0.shape[1]
    zp, Sy, L21, dx, status = scratch.take(_chunk_update, k, n, m)
    kernel_out = (zp, y, w, Sy, L21, dx, x, S, ll, nis, status, route.no_set)
    _, status, _ = route.posterior(
        sset, x0, S0, H, z, None, R1_2, None, False, buffers=scratch, out=kernel_out
    )  # (the scratch: the angle kernel's rows, for squkf's angle hooks)
    log_det_of(Sy, out=log_det)
    good = _flag(status, on, found, form, "update", H, "hx values")
    rejected[...] = False
    if not good.all():
        bad = ~good
        x[bad], S[bad] = x0[bad], S0[bad]
        y[bad], ll[bad], nis[bad], w[bad], log_det[bad] = np.nan, 0.0, 0.0, np.nan, 0.0


def _posteriors(route: Route, sset, x0, S0, H, z, observed, R1_2, todo, found) -> tuple:
    """A chunk's gated updates, grouped by their missing components; a filter no update reaches keeps its
    prior, with no innovation and no likelihood. The records ``x, S, y, loglik, nis, rejected, y_whitened,
    log_det_S1_2``."""
    k, m = z.shape
    if todo.all() and observed.all():  # the usual case: every filter, every component, one group
        groups: list[tuple[np.ndarray | slice, np.ndarray | None]] = [(slice(None), None)]
    else:
        todo_idx = np.flatnonzero(todo)
        patterns, which = np.unique(observed[todo], axis=0, return_inverse=True)
        which = which.reshape(-1)
        groups = [(todo_idx[which == p], None if obs.all() else obs) for p, obs in enumerate(patterns)]
    records = None
    for ix, mask in groups:
        part = _gated_group(route, sset, x0, S0, H, z, R1_2, ix, mask, found)
        if isinstance(ix, slice) and part[8].all():
            return part[:8]  # every filter, all measured, all good: the kernels' arrays as they are
        if records is None:
            records = _unchanged(x0, S0, m)
        x, S, y, ll, nis, rej, w, log_det = records
        good = part[8]
        gi = np.arange(k)[ix][good]
        x[gi], S[gi] = part[0][good], part[1][good]
        ll[gi], nis[gi], log_det[gi] = part[3][good], part[4][good], part[7][good]
        if mask is None:
            y[gi], rej[gi], w[gi] = part[2][good], part[5][good], part[6][good]
        else:
            cols = np.ix_(gi, np.flatnonzero(mask))
            y[cols], rej[cols], w[cols] = part[2][good], part[5][good], part[6][good]
    return _unchanged(x0, S0, m) if records is None else records


def _unchanged(x0: np.ndarray, S0: np.ndarray, m: int) -> tuple:
    """The records of filters that keep their prior: no innovation, no likelihood."""
    k = x0.shape[0]
    return (
        x0.copy(), S0.copy(), np.full((k, m), np.nan), np.zeros(k), np.zeros(k), np.zeros((k, m), dtype=bool),
        np.full((k, m), np.nan), np.zeros(k),
    )  # fmt: skip


def _gated_group(route: Route, sset, x0, S0, H, z, R1_2, ix, mask, found):
    """The gated update of the filters ``ix`` of a chunk (one pattern of missing components ``mask``).

    Returns ``x, S, y, loglik, nis, rejected, y_whitened, log_det_S1_2`` over ``ix`` (the measured
    components of ``mask``) and the mask of the filters that succeeded.
    """
    s = sset if isinstance(ix, slice) else take_set(sset, ix)
    xi, Si, Hi, zi, Ri = x0[ix], S0[ix], H[ix], z[ix], rows_of(R1_2, ix, 2)
    B = xi.shape[0]
    found_rows: dict[int, str] = {}
    if route.update_route(s, None) is not None:  # the kernels report each filter's failure
        post, status, _ = route.posterior(s, xi, Si, Hi, zi, mask, Ri, None, False)
        upd, status = route.gated(post, status, s, xi, Si, Hi, zi, mask, Ri, None)
        form = route.form_of(s, None)
        good = _flag(status, np.ones(B, dtype=bool), found_rows, form, "update", Hi, "hx values")
        _renumber(found_rows, ix, found)
        return (*_records_of(upd), good)

    def posterior(j):  # the hooks or a generator's set raise: a filter at a time after a failure
        r, j = _one_or_all(route, j)
        sub, Rj = take_set(s, j), rows_of(Ri, j, 2)
        post, _, _ = r.posterior(sub, xi[j], Si[j], Hi[j], zi[j], mask, Rj, None, False)
        ok = np.zeros(xi[j].shape[0], dtype=np.int64)
        upd, _ = r.gated(post, ok, sub, xi[j], Si[j], Hi[j], zi[j], mask, Rj, None)
        return _records_of(upd)

    good_idx, res = run_isolated(posterior, np.arange(B), B, found_rows)
    _renumber(found_rows, ix, found)
    n = xi.shape[-1]
    mo = Hi.shape[-1] if mask is None else int(mask.sum())
    full = (np.zeros((B, n)), np.zeros((B, n, n)), np.zeros((B, mo)), np.zeros(B), np.zeros(B),
            np.zeros((B, mo), dtype=bool), np.zeros((B, mo)), np.zeros(B))  # fmt: skip
    good = np.zeros(B, dtype=bool)
    good[good_idx] = True
    if res is not None:
        for a, r in zip(full, res):
            a[good_idx] = r
    return (*full, good)


def _records_of(upd) -> tuple:
    """A group's update as its records (over its measured components)."""
    return upd.x, upd.S, upd.y, upd.log_likelihood, upd.nis, upd.rejected, upd.w, log_det_of(upd.Sy)


def _one_or_all(route: Route, ix):
    """The route and rows for ``ix``: a filter alone (an int, :func:`run_isolated` describing its failure)
    runs as a single filter's block of one, so that its hooks see its own arrays and its error reads as
    that filter's; a slice or index array runs as it is."""
    if isinstance(ix, (int, np.integer)):
        return Route(route.plan, route.hooks, route.gate, single=True), slice(int(ix), int(ix) + 1)
    return route, ix


def _renumber(found_rows: dict[int, str], ix, found: dict[int, str]) -> None:
    """Failures of a group's filters (numbered within the group) as the chunk's."""
    for j, why in found_rows.items():
        k = j if isinstance(ix, slice) else int(ix[j])
        found.setdefault(k, why)
