"""The thread pool of the kernels: the thread count, a step's hold on it, and work cut between threads.

A fleet's step hands its chunks to the threads (:func:`thread_map`), holding
the count it starts with until it ends (:func:`enter_step`,
:func:`exit_step`); a large stack of any other kernel call is cut into
contiguous parts, one kernel call on its own thread each (:func:`split_call`:
the kernels release the GIL). Each filter's numbers are the same, bit for
bit, for any thread count.
"""

from __future__ import annotations

import os
import threading
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any, NamedTuple, TypeVar

import numpy as np

from ..errors import ParameterError

__all__ = [
    "MIN_FILTERS_PER_THREAD",
    "set_num_threads",
    "get_num_threads",
    "usable_cores",
    "enter_step",
    "exit_step",
    "thread_map",
    "split_call",
]

#: Below this many filters a stack is never split between threads (the hand-off costs more).
MIN_FILTERS_PER_THREAD = 2048


class _Threads(NamedTuple):
    """A thread count and its pool (None for one thread), as a running step holds them."""

    n: int
    pool: ThreadPoolExecutor | None


_SERIAL = _Threads(1, None)
_lock = threading.Lock()  # guards the three below
_threads = 1
_pool: ThreadPoolExecutor | None = None  # the pool of _threads, made on first use
_holders: dict[ThreadPoolExecutor, int] = {}  # pool -> running steps holding it (current or replaced)
_local = threading.local()  # .held: what this thread's running step holds (_SERIAL in a job of the pool)


def usable_cores() -> int:
    """The cores this process may run on: its CPU affinity where the system has one, else all."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


def _too_many(asked: str, cores: int) -> str:
    return f"{asked} asks for more threads than the {cores} cores this process may use; squkf uses {cores}"


def set_num_threads(n: int) -> None:
    """Use ``n`` threads for a fleet's step and large stacks; 1 (the default) runs serially.

    A fleet's step hands its chunks to the threads (:func:`thread_map`, model
    functions included; a multiple of ``n`` chunks of near equal sizes:
    :func:`squkf.stacks.chunks`); any other large stack is cut into ``n`` contiguous
    parts, each stepped by one kernel call on its own thread (the kernels
    release the GIL). Each filter's numbers are the same, bit for bit, for
    any thread count. What it takes, its cap at the usable cores, the
    environment variable ``SQUKF_NUM_THREADS`` and when a change takes effect:
    :ref:`the thread count <thread-rules>`.

    Parameters
    ----------
    n : int
        At least 1.

    Raises
    ------
    ParameterError
        If ``n`` is not a whole number of at least 1 (the count is left as it was).
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ParameterError(f"the thread count must be a whole number >= 1, got n={n!r}")
    cores = usable_cores()
    if n > cores:
        warnings.warn(_too_many(f"set_num_threads(n={n!r})", cores), RuntimeWarning, stacklevel=2)
    _set_threads(min(int(n), cores))


def get_num_threads() -> int:
    """The thread count of :func:`set_num_threads`."""
    return _threads


def _threads_from_environ(text: str) -> int:
    """The count ``SQUKF_NUM_THREADS=text`` asks for, capped at the usable cores; 1 if it is not a count.

    Either correction is said in a ``RuntimeWarning`` naming the variable; the import goes on.
    """
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        warnings.warn(
            f"SQUKF_NUM_THREADS={text!r} is not a whole number >= 1; squkf uses one thread",
            RuntimeWarning,
            stacklevel=2,
        )
        return 1
    cores = usable_cores()
    if n > cores:
        warnings.warn(_too_many(f"SQUKF_NUM_THREADS={text!r}", cores), RuntimeWarning, stacklevel=2)
    return min(n, cores)


def _set_threads(n: int) -> None:
    """Make ``n`` the count; the old count's pool is shut down once no running step holds it."""
    global _threads, _pool
    with _lock:
        if n == _threads:
            return
        old, _pool, _threads = _pool, None, n
        idle = old is not None and old not in _holders
    if old is not None and idle:
        old.shutdown()


def _hold() -> _Threads:
    """The current count and its pool, held (the pool made if need be) until :func:`_let_go`."""
    global _pool
    if _threads == 1:  # unlocked: a count set meanwhile is a step late, as it would be a moment later
        return _SERIAL
    with _lock:
        if _threads == 1:
            return _SERIAL
        if _pool is None:
            _pool = ThreadPoolExecutor(_threads, thread_name_prefix="squkf-kernel")
        _holders[_pool] = _holders.get(_pool, 0) + 1
        return _Threads(_threads, _pool)


def _let_go(held: _Threads) -> None:
    """Undo one :func:`_hold`; a pool replaced meanwhile is shut down when its last step lets go."""
    pool = held.pool
    if pool is None:
        return
    with _lock:
        left = _holders.pop(pool) - 1
        if left:
            _holders[pool] = left
        retired = not left and pool is not _pool
    if retired:
        pool.shutdown()  # every job of it has ended: its steps waited for them


@contextmanager
def _held() -> Iterator[_Threads]:
    """What the calling thread's running step holds; if none runs, the current count, held for the block."""
    outer = getattr(_local, "held", None)
    if outer is not None:
        yield outer
        return
    held = _hold()
    _local.held = held
    try:
        yield held
    finally:
        _local.held = None
        _let_go(held)


def enter_step() -> tuple[_Threads, bool]:
    """Hold the thread count (and its pool) for a step, until :func:`exit_step`.

    A step holds the count it starts with until it ends: a change of
    :func:`set_num_threads` meanwhile, from another thread or from a model
    function inside the step, takes effect at the next step, and the running
    one finishes on its threads. Its :func:`thread_map` and kernel calls use
    what it holds. Inside a job of the pool, or inside a step already held on
    this thread, it holds nothing more and returns what is held there.

    Returns
    -------
    held : (int, pool or None)
        The count held (``held.n``) and its pool (None: one thread).
    own : bool
        Whether this call took the hold (give both to :func:`exit_step`).
    """
    outer = getattr(_local, "held", None)
    if outer is not None:
        return outer, False
    held = _local.held = _SERIAL if _threads == 1 else _hold()
    return held, True


def exit_step(held: _Threads, own: bool) -> None:
    """End the hold of :func:`enter_step` (``held, own`` as it returned them)."""
    if own:
        _local.held = None
        if held.pool is not None:
            _let_go(held)


def _in_pool(fn: Callable, *args):
    _local.held = _SERIAL  # a job hands nothing on: what it calls runs on its own thread
    try:
        return fn(*args)
    finally:
        _local.held = None


def _results(jobs: list[Future]) -> list:
    """The jobs' results once every one has ended; the first one's exception (in their order) raised."""
    errors = [job.exception() for job in jobs]  # waits for every job
    for exc in errors:
        if exc is not None:
            raise exc
    return [job.result() for job in jobs]


_T = TypeVar("_T")


def thread_map(fn: Callable[[Any], _T], items: Sequence) -> list[_T]:
    """``[fn(item) for item in items]``, on the threads of :func:`set_num_threads`.

    With one thread, or one item, or when called from a job of the pool
    itself, the items are run in order on the calling thread. Otherwise
    they are handed to the pool; every job is waited for, and the first
    item's exception (in the order of ``items``) is raised, so no job still
    runs when this returns. The count used is the one held by the calling
    thread's step (:func:`enter_step`), else the current one, held until
    every item has run.

    Parameters
    ----------
    fn : callable
        Of one item; it must be safe to run on several threads at once (the
        compiled kernels and numpy's array functions are).
    items : sequence

    Returns
    -------
    list
        ``fn``'s results, in the order of ``items``.
    """
    with _held() as held:
        if held.pool is None or len(items) < 2:
            return [fn(item) for item in items]
        pool = held.pool
        return _results([pool.submit(_in_pool, fn, item) for item in items])


def _run(
    pool: ThreadPoolExecutor, kernel: Any, B: int, parts: int, args: tuple, per_filter: tuple[bool, ...]
) -> None:
    """Call ``kernel(*args)`` with its ``B`` filters cut into ``parts`` contiguous parts on ``pool``.

    ``per_filter[i]`` tells whether ``args[i]`` has one row per filter (cut) or is
    shared (a plan's data, a shared noise factor: passed whole).
    """
    cuts = [B * i // parts for i in range(parts + 1)]
    _results([
        pool.submit(kernel, *(a[lo:hi] if cut else a for a, cut in zip(args, per_filter)))
        for lo, hi in zip(cuts[:-1], cuts[1:])
    ])  # fmt: skip


def split_call(kernel: Any, B: int, *args, plan: tuple[int, ...] = ()) -> None:
    """``kernel(*args)`` over ``B`` filters; the arguments at ``plan`` are the plan's data, never cut.

    Every other array with ``B`` rows is one row per filter; a shared array has one row.
    A large stack is cut between the threads the calling thread's step holds (:func:`enter_step`).
    """
    if B < 2 * MIN_FILTERS_PER_THREAD:
        kernel(*args)
        return
    with _held() as held:
        parts = min(held.n, B // MIN_FILTERS_PER_THREAD)
        if held.pool is None or parts <= 1:
            kernel(*args)
            return
        cut = tuple(
            i not in plan and isinstance(a, np.ndarray) and a.ndim >= 1 and a.shape[0] == B
            for i, a in enumerate(args)
        )
        _run(held.pool, kernel, B, parts, args, cut)


_environ_threads = os.environ.get("SQUKF_NUM_THREADS")
if _environ_threads:
    _set_threads(_threads_from_environ(_environ_threads))
