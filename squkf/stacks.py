"""A fleet's step, a chunk of filters at a time: the runner of a fleet's engine, failures flagged alone.

A fleet's :class:`~squkf.engine.Engine` keeps its pending step and commits;
how its phases run is :class:`Chunks` (:data:`CHUNKS`). A step of K filters
runs chunk by chunk, at most ``Fleet.chunk`` filters each (by default
:func:`default_chunk`, :data:`CHUNK` on one thread): a chunk's first set is
drawn, the model is called with the chunk's points, and the chunk's prior
computed (a prediction); or its second set is drawn, the model called, and
its posterior computed (an update). Each is a phase of the engine's
:class:`~squkf.engine.Route` on a block of the chunk's filters, the same
kernels as one filter's step. The step's temporary arrays are then the
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

import operator
import os
import sys
import threading
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import numpy as np

from .boundary import records
from .boundary.records import failures_error
from .checks import describe_nonfinite, finite_images, stacked_shape
from .engine import POSTERIOR_OUT, Buffers, Route, Scratch, Update
from .errors import NonFiniteError, NotPositiveDefiniteError, SqukfError
from .generators import SigmaSet
from .kernels.table import kernel_array
from .kernels.threads import enter_step, exit_step, thread_map
from .statuses import failure

__all__ = [
    "BLOCK",
    "CHUNK",
    "CHUNK_BYTES",
    "CHUNKS",
    "KEPT",
    "Chunks",
    "Step",
    "chunks",
    "default_chunk",
    "not_updated",
    "numerical",
    "rows_of",
    "run_isolated",
    "take_set",
]

_FLOAT64 = np.dtype(np.float64)

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


#: The fields of an :class:`Update` a fleet writes per filter, in the order of a step's arrays: the
#: estimate, then the records (a fleet keeps no innovation factor or gain; ``observed``, ``m``: the block's)
KEPT = tuple(f for f in Update._fields if f not in ("Sy", "L21", "observed", "K", "m"))

#: The records' own: per measurement component or not, and the value of a filter not updated
_OWN = {"y": (True, np.nan), "log_likelihood": (False, 0.0), "nis": (False, 0.0), "rejected": (True, False)}


def _record_of(field: str) -> tuple[bool, float]:
    """Whether ``field`` is per component, and its value where a filter was not updated: the registry's for
    a per-step record's field (:data:`squkf.boundary.records.STEP_RECORDS`)."""
    if field in _OWN:
        return _OWN[field]
    for r in records.STEP_RECORDS:
        if r.field == field:
            return r.per_component, r.fill
    raise LookupError(f"Update.{field}: neither a fleet's own record nor a per-step record's (STEP_RECORDS)")


_KINDS = tuple(_record_of(f) for f in KEPT[2:])
#: The value of each record of a filter not updated (``KEPT[2:]``)
_FILLS = tuple(fill for _, fill in _KINDS)
#: Which of ``KEPT`` are per measurement component (written in a group's measured columns)
_PER_COMPONENT = (False, False, *(per for per, _ in _KINDS))
#: A group's update as its fields ``KEPT`` (a tuple)
_kept_of = operator.attrgetter(*KEPT)
#: The update kernel's outputs (``engine.POSTERIOR_OUT``) from a step's arrays (``KEPT``) and a chunk's
#: (``_SCRATCH``), in that order
_SCRATCH = ("z_pred", "Sy", "L21", "dx", "status", "X1")
assert not set(KEPT) & set(_SCRATCH)  # (each kernel output found in one place)
_kernel_out = operator.itemgetter(*((*KEPT, *_SCRATCH).index(name) for name in POSTERIOR_OUT))
#: The fields of ``KEPT`` the kernel does not write (``rejected``: none, with no gate), by position: copied
#: from the update the route returns
_NOT_WRITTEN = tuple((i, f) for i, f in enumerate(KEPT) if f not in POSTERIOR_OUT)
#: The fields of a fleet's update that it does not keep
_NOT_KEPT: dict[str, Any] = {f: None for f in Update._fields if f not in KEPT and f != "m"}


def _update_records(K: int, m: int) -> tuple:
    """A fleet update's records besides the estimate (``KEPT[2:]``): ``(K, m)`` per component, ``(K,)`` per
    filter, of bool for ``rejected`` (its value of a filter not updated is False), else float64 (the
    kernels write float64, a registry record's fill is a float)."""
    return tuple(
        np.empty((K, m) if per else K, dtype=bool if fill is False else float) for per, fill in _KINDS
    )


def not_updated(x: np.ndarray, S: np.ndarray, m: int) -> Update:
    """A fleet's update in which no filter was updated: the estimates ``x (K, n)``, ``S (K, n, n)`` kept
    (these arrays), each record its value of a filter not updated."""
    out = (x, S, *_update_records(x.shape[0], m))
    for a, fill in zip(out[2:], _FILLS):
        a[...] = fill
    return Update(**dict(zip(KEPT, out)), **_NOT_KEPT, m=m)


def _second_size(plan, Q1_2) -> int:
    """Points in a second set, as far as the plan knows them (a user's generator: as many as the first).

    The augmented set is the propagated points and the noise's; with no process noise (``Q1_2`` None)
    it is the propagated points alone.
    """
    fused, N = plan.fused_draw, plan.xi1.shape[0]
    if fused is None or (fused.augmented and Q1_2 is None):
        return N
    return fused.xi.shape[0] + (N if fused.augmented else 0)


def _chunk_prior(k: int, N: int, n: int) -> tuple:
    """A chunk's first set ``(k, N, n)`` and the transform kernel's statuses."""
    return np.empty((k, N, n)), np.empty(k, dtype=np.int64)


def _chunk_update(k: int, n: int, m: int) -> tuple:
    """A chunk's rows of ``z``, and the joint kernel's outputs it does not keep: ``zp, Sy, L21, dx,
    status``."""
    return (
        np.empty((k, m)), np.empty((k, m)), np.empty((k, m, m)), np.empty((k, n, m)), np.empty((k, n)),
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


# -- the runner -------------------------------------------------------------------------------------


class Step(NamedTuple):
    """A fleet's call as its runner takes it, in place of a block's images (:class:`Chunks`).

    Attributes
    ----------
    images : callable
        The model at a chunk: ``images(rows, X)`` for a prediction, with the first sets ``X``
        ``(k, N, n)`` of the filters ``rows`` (a slice); ``images(rows, sset)`` for an update, with
        their second sets. Shape ``(k, N, d)``.
    active : ndarray of bool, shape (K,)
        The filters to step (the others keep their estimate; for an update, those of them with a
        measurement).
    fails : dict
        Filled with ``filter -> reason`` for the filters that fail.
    size : int or None
        Filters per chunk, at most (None: :func:`default_chunk` of the thread count and ``K``).
    raises : bool
        A failing filter raises :class:`~squkf.errors.FleetStepError` for them all (nothing committed)
        instead of being flagged.
    """

    images: Callable
    active: np.ndarray
    fails: dict[int, str]
    size: int | None
    raises: bool


class Chunks:
    """How a fleet's phases run: a chunk of filters at a time, on threads, failing filters flagged alone.

    The runner of a fleet's :class:`~squkf.engine.Engine` (:data:`CHUNKS`), with the methods of
    :class:`squkf.engine.Block`: the engine keeps the pending step and commits; here each phase is the
    route's on a chunk's block, its temporaries the chunk's (:class:`_Spare`), its results written
    into the step's ``(K, ...)`` arrays (the engine's buffers: the estimates in a set none of whose
    arrays the records hold, :meth:`~squkf.engine.Buffers.spare`).
    """

    __slots__ = ()
    defers = True  # the second set is drawn at the update, a chunk at a time: no (K, N2, n) set is kept

    def __reduce__(self) -> str:
        return "CHUNKS"  # the one runner, by name

    @staticmethod
    def prior(route: Route, x, S, step: Step, first, Q1_2, UT, name: str, buffers: Buffers, held: tuple):
        """The prediction of the fleet's filters, a chunk at a time (nothing committed).

        Parameters
        ----------
        route : Route
            The fleet's (``single`` False).
        x : ndarray, shape (K, n)
        S : ndarray, shape (K, n, n)
        step : Step
            ``step.images(rows, X)``: ``fx`` at the first sets ``X`` of the filters ``rows``.
        first : ndarray, shape (K, N, n), or None
            The first sets already handed out (``ask_predict``); None: drawn per chunk.
        Q1_2 : ndarray, shape (d, d) or (K, d, d), or None
            Additive process noise factor, shared or per filter (None: none added).
        UT : None
        name : str
        buffers : Buffers
        held : tuple of ndarray
            What the records hold: the estimates go to a set of none of them.

        Returns
        -------
        x, S : ndarray
            The priors (a failing or inactive filter keeps its estimate).
        sset : None
            (Drawn at the update.)
        later : tuple
            ``(propagated, Q1_2)``: the first sets' images ``(K, N, n)`` where the plan's second set
            reads them (else None), and the noise factor.
        """
        K, n = x.shape
        plan = route.plan
        N = plan.xi1.shape[0]
        x_new, S_new = buffers.spare(held, _estimates, K, n)
        propagated = buffers.take(_propagated, K, N, n)[0] if plan.keeps_propagated else None
        images, active, found_all = step.images, step.active, step.fails
        form = plan.first.rows.best
        none = route.no_set

        def one(rows: slice) -> dict[int, str]:
            found: dict[int, str] = {}
            xs, Ss = x[rows], S[rows]  # (the engine's C-contiguous arrays: their rows are as kernels take)
            free = _spare.free
            scratch = free.pop() if free else Scratch()  # this chunk's alone, until given back (_Spare)
            X, status = scratch.take(_chunk_prior, xs.shape[0], N, n)
            X = route.first_points(xs, Ss, X) if first is None else first[rows]
            F = images(rows, X)
            f = F.flags if type(F) is np.ndarray and F.dtype == _FLOAT64 and F.shape == X.shape else None
            if f is None or not (f.c_contiguous and f.writeable):  # checked, copied once as kernels take it
                label = "fx values" if rows.stop - rows.start == K else _label("fx values", rows, K)
                F = kernel_array(stacked_shape(F, X.shape, label, False, ("fx", X.shape)))
            on = active[rows]
            Qr = Q1_2 if Q1_2 is None or Q1_2.ndim == 2 else Q1_2[rows]
            xo, So = x_new[rows], S_new[rows]
            if route.plain_x:  # the kernel checks the images and reports each filter's failure
                route.prior(F, Qr, None, False, out=(xo, So, status, none, none))  # into the step's results
                if np.count_nonzero(status) or not on.all():
                    bad = ~_flag(status, on, found, form, "prior", F, "fx values")
                    xo[bad], So[bad] = xs[bad], Ss[bad]  # a failing or inactive filter keeps its estimate
            else:  # the hooks raise: the chunk is run again a filter at a time to find the failing ones
                finite = finite_images(F, "fx values", on, found, kernels=route.kernels)

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

        _map_chunks(one, K, step.size, found_all, 8 * N * n)
        if found_all and step.raises:
            raise failures_error(found_all)
        return x_new, S_new, None, (propagated, Q1_2)

    @staticmethod
    def posterior(route: Route, pending: tuple, step: Step, z, observed, R1_2, UT, name: str, buffers, held):
        """The update of the fleet's filters, a chunk at a time, through the gate (nothing committed).

        Parameters
        ----------
        route : Route
        pending : tuple
            The engine's pending update ``((x, S), sset, later)``: the priors ``(K, n)``, ``(K, n, n)``;
            their second sets ``(K, N2, n)`` (handed out by ``ask_update``), or None to draw them here a
            chunk at a time from what ``later`` holds (the prediction's images and noise factor).
        step : Step
            ``step.images(rows, sset)``: ``hx`` at the second sets of the filters ``rows``.
        z : ndarray, shape (K, m)
            Measurements, NaN where missing (each chunk's rows read once, checked as read).
        observed : None
            (Each filter's measured components are those of its row of ``z``.)
        R1_2 : ndarray, shape (m, m) or (K, m, m)
            Measurement noise factor, shared or per filter.
        UT : None
        name : str
        buffers : Buffers
        held : tuple of ndarray

        Returns
        -------
        update : Update
            Of every filter: ``y`` ``(K, m)`` NaN where a component was missing or the filter not
            updated (which keeps its prior, log-likelihood and NIS 0); no innovation factor kept.
        X1 : None
        H : None
            (The images are a chunk's: not kept.)
        """
        (x, S), sset, later = pending
        K, m = z.shape
        n = x.shape[1]
        propagated, Q1_2 = (None, None) if later is None else later
        out = (*buffers.spare(held, _estimates, K, n), *buffers.take(_update_records, K, m))
        images, active, found_all = step.images, step.active, step.fails

        def one(rows: slice) -> dict[int, str]:
            found: dict[int, str] = {}
            k = rows.stop - rows.start
            xs, Ss = x[rows], S[rows]  # (the engine's C-contiguous arrays: their rows are as kernels take)
            free = _spare.free
            scratch = free.pop() if free else Scratch()  # this chunk's alone, until given back (_Spare)
            if sset is not None:
                s = take_set(sset, rows)
            else:
                prop = None if propagated is None else propagated[rows]
                Qr = Q1_2 if Q1_2 is None or Q1_2.ndim == 2 else Q1_2[rows]
                s = route.second_set(xs, Ss, prop, Qr, scratch)
            shape = s.sigmas.shape[:-1] + (m,)
            H = images(rows, s)
            f = H.flags if type(H) is np.ndarray and H.dtype == _FLOAT64 and H.shape == shape else None
            if f is None or not (f.c_contiguous and f.writeable):  # checked, copied once as kernels take it
                label = "hx values" if k == K else _label("hx values", rows, K)
                H = kernel_array(stacked_shape(H, shape, label, False, ("hx", s.sigmas.shape)))
            # the chunk's rows of z in its own array, checked as read: what the kernels use is what
            # was checked, even if the model functions wrote into the caller's z (and no (K, m) copy)
            zr, zp, Sy, L21, dx, status = scratch.take(_chunk_update, k, n, m)
            np.copyto(zr, z[rows])
            if np.isinf(zr).any():
                i = rows.start + int(np.flatnonzero(np.isinf(zr).any(axis=1))[0])
                raise NonFiniteError(f"z contains inf (row {i}; NaN means a missing component)")
            obs = ~np.isnan(zr)
            on = active[rows] & obs.any(axis=1)
            Rr = R1_2 if R1_2.ndim == 2 else R1_2[rows]
            part = out if k == K else [a[rows] for a in out]
            # the usual case, one kernel call: a kernel's update route (as update_route decides it, from
            # the route's and the set's attributes; kept in posterior), no gate, every component measured
            if route.kernel_update and s.rows is not None and route.gate is None and obs.all():
                # the kernel writes into the step's records (part) and the chunk's own arrays
                kernel_out = _kernel_out((*part, zp, Sy, L21, dx, status, route.no_set))
                # (the scratch: the angle kernel's rows, for squkf's angle hooks)
                done, _, _ = route.posterior(
                    s, xs, Ss, H, zr, None, Rr, None, False, buffers=scratch, out=kernel_out
                )
                for i, field in _NOT_WRITTEN:
                    part[i][...] = getattr(done, field)
                if np.count_nonzero(status) or not on.all():  # a failing or inactive filter keeps its prior
                    form = route.form_of(s, None)
                    bad = ~_flag(status, on, found, form, "update", H, "hx values")
                    xo, So = part[0], part[1]  # (KEPT: the estimate first)
                    xo[bad], So[bad] = xs[bad], Ss[bad]
                    for a, fill in zip(part[2:], _FILLS):
                        a[bad] = fill
            else:
                _grouped(route, route.update_route(s, None), s, xs, Ss, H, zr, obs, Rr, on, found, part)
            free.append(scratch)
            return {rows.start + i: why for i, why in found.items()} if found and rows.start else found

        _map_chunks(one, K, step.size, found_all, 8 * _second_size(route.plan, Q1_2) * max(n, m))
        if found_all and step.raises:
            raise failures_error(found_all)
        return Update(**dict(zip(KEPT, out)), **_NOT_KEPT, m=m), None, None


#: The runner of a fleet's engine.
CHUNKS = Chunks()


def _grouped(route: Route, joint, sset, x0, S0, H, z, observed, R1_2, todo, found, out) -> None:
    """A chunk's update through the gate or with missing components (or on a route that raises),
    written into its rows ``out`` of the step's records (``KEPT``: the estimate, ``y``, ...): the filters
    grouped by their measured components, each group through :meth:`Route.posterior` and
    :meth:`Route.gated` as one filter's update is; a filter no update reaches keeps its prior, with no
    innovation and no likelihood. ``joint``: the set's update route (None: the hooks' or a ``UT``'s)."""
    if joint is None:  # the hooks raise: images that are not finite flagged first
        todo = todo & finite_images(H, "hx values", todo, found, kernels=route.kernels)
    out[0][...], out[1][...] = x0, S0
    for a, fill in zip(out[2:], _FILLS):
        a[...] = fill
    groups: list[tuple[np.ndarray, np.ndarray | slice, np.ndarray | None]]
    if todo.all() and observed.all():  # (a gate's usual chunk: one group, the chunk's arrays as they are)
        groups = [(np.arange(todo.size), slice(None), None)]
    else:
        todo_idx = np.flatnonzero(todo)
        patterns, which = np.unique(observed[todo], axis=0, return_inverse=True)
        which = which.reshape(-1)
        groups = []
        for p, obs in enumerate(patterns):
            ix = todo_idx[which == p]
            groups.append((ix, ix, None if obs.all() else obs))
    for ix, sel, mask in groups:
        s = sset if isinstance(sel, slice) else take_set(sset, ix)
        xi, Si, Hi, zi, Ri = x0[sel], S0[sel], H[sel], z[sel], rows_of(R1_2, sel, 2)
        found_rows: dict[int, str] = {}
        if joint is not None:  # the kernels report each filter's failure
            post, status, _ = route.posterior(s, xi, Si, Hi, zi, mask, Ri, None, False)
            upd, status = route.gated(post, status, s, xi, Si, Hi, zi, mask, Ri, None)
            good = _flag(
                status, np.ones(ix.size, dtype=bool), found_rows, joint.form, "update", Hi, "hx values"
            )
            good_ix = np.flatnonzero(good)
            res = tuple(a[good_ix] for a in _kept_of(upd))
        else:  # the hooks or a generator's set raise: a filter at a time after a failure
            good_ix, res = _isolated(route, s, xi, Si, Hi, zi, mask, Ri, found_rows)
        for j, why in found_rows.items():
            found.setdefault(int(ix[j]), why)
        if res is None:
            continue
        gi = ix[good_ix]
        cols = gi if mask is None else np.ix_(gi, np.flatnonzero(mask))  # (a record per component's)
        for a, value, per in zip(out, res, _PER_COMPONENT):
            a[cols if per else gi] = value


def _isolated(route: Route, s, x0, S0, H, z, mask, R1_2, found: dict[int, str]):
    """The update of a group of filters on a route that raises, run again a filter at a time after a
    failure (:func:`run_isolated`): the filters that succeeded, and their records (``KEPT``)."""

    def posterior(j):
        r, j = _one_or_all(route, j)
        sub, Rj = take_set(s, j), rows_of(R1_2, j, 2)
        post, _, _ = r.posterior(sub, x0[j], S0[j], H[j], z[j], mask, Rj, None, False)
        ok = np.zeros(x0[j].shape[0], dtype=np.int64)
        return _kept_of(r.gated(post, ok, sub, x0[j], S0[j], H[j], z[j], mask, Rj, None)[0])

    return run_isolated(posterior, np.arange(x0.shape[0]), x0.shape[0], found)


def _one_or_all(route: Route, ix):
    """The route and rows for ``ix``: a filter alone (an int, :func:`run_isolated` describing its failure)
    runs as a single filter's block of one, so that its hooks see its own arrays and its error reads as
    that filter's; a slice or index array runs as it is."""
    if isinstance(ix, (int, np.integer)):
        one = Route(route.plan, route.hooks, route.gate, single=True, kernels=route.kernels)
        return one, slice(int(ix), int(ix) + 1)
    return route, ix
