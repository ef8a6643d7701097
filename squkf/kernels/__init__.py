"""The compiled numerical core: one kernel per phase of the step, over a stack of filters.

The functions here are the library's only implementation of the step's
numerics. Each takes arrays with any leading batch shape (numpy's
``np.linalg`` convention: one filter has none, a fleet ``(K,)``), flattens it
to a stack, calls its kernel (:mod:`squkf.kernels.phases`) and gives the
results back in that shape. One filter is a stack of one, computed by the
same kernel as a fleet, so a filter alone and the same filter in a fleet get
the same numbers, bit for bit.

Kernels are compiled on first use (on an empty cache, about 11 s for the default
``SquareRootUKF`` or ``Fleet`` on the 2-core benchmark machine:
``python benchmarks/compile_time.py``, ``benchmarks/results/compile.md``) and
cached on disk beside the package (numba's ``cache=True``); a new process
loads them in a fraction of a second. Importing squkf compiles nothing, and
is refused with ``NUMBA_DISABLE_JIT`` set (the kernels are never run as
Python).

Failures are not raised here: each function returns a status per filter
(see :mod:`squkf.kernels.phases`), which the callers turn into squkf's
exceptions (:mod:`squkf.linalg`, :mod:`squkf.transform`,
:mod:`squkf.measurement`).
"""

from __future__ import annotations

import os
import threading
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any, NamedTuple, TypeVar

import numba
import numpy as np

from ..errors import ParameterError, UnsupportedEnvironmentError
from . import phases

__all__ = [
    "tria",
    "solve_lower",
    "chol_update",
    "sigma_points",
    "transform",
    "joint_update",
    "downdate_update",
    "JointUpdate",
    "CENTRAL",
    "MEAN",
    "GIVEN",
    "set_num_threads",
    "get_num_threads",
    "usable_cores",
    "enter_step",
    "exit_step",
    "thread_map",
]

#: Row forms (:mod:`squkf.kernels.phases`).
CENTRAL, MEAN, GIVEN = 0, 1, 2
#: What :func:`phases.angle_rows_kernel` does with a component (bits): a circular mean, a wrapped residual.
CIRCULAR_MEAN, WRAPPED = 1, 2

#: Below this many filters a stack is never split between threads (the hand-off costs more).
MIN_FILTERS_PER_THREAD = 2048


def _refuse_interpreted_kernels() -> None:
    """Raise when numba's compiler is switched off: the kernels would run as Python and give wrong numbers.

    Run as Python, a kernel loses what it relies on being compiled (LAPACK's
    ``dgeqrf`` called through raw pointers, from 16 columns on), so the
    setting is refused rather than run.
    """
    disabled = numba.config.DISABLE_JIT  # type: ignore[attr-defined]  # numba's config is set at run time
    if disabled:
        raise UnsupportedEnvironmentError(
            f"NUMBA_DISABLE_JIT is set (numba.config.DISABLE_JIT={disabled!r}), and squkf "
            "does not support it: its kernels rely on being compiled by numba, and run as Python they give "
            "wrong numbers (the QR from 16 columns on calls LAPACK's dgeqrf through raw pointers). "
            "Unset NUMBA_DISABLE_JIT to use squkf."
        )


_refuse_interpreted_kernels()


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


def _call(kernel: Any, B: int, *args, plan: tuple[int, ...] = ()) -> None:
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


def _batch(*arrays: tuple[np.ndarray | None, int]) -> tuple[int, ...]:
    shape: tuple[int, ...] = ()
    for a, core in arrays:
        if a is not None and a.ndim > core:
            lead = a.shape[: a.ndim - core]
            shape = lead if not shape or lead == shape else np.broadcast_shapes(shape, lead)
    return shape


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


def _stack(a: np.ndarray, batch: tuple[int, ...], core: int) -> np.ndarray:
    """``a`` as a stack ``(B, *core shape)`` over ``batch``, as the kernels take it."""
    if not batch and a.ndim == core:  # one filter: a view with a leading axis of one
        return kernel_array(a[None])
    tail = a.shape[a.ndim - core :]
    if a.shape[: a.ndim - core] != batch:
        a = np.broadcast_to(a, batch + tail)
    return kernel_array(a.reshape((-1,) + tail))


def _unstack(a: np.ndarray, batch: tuple[int, ...]) -> np.ndarray:
    """A kernel's output stack ``(B, ...)`` in the caller's batch shape, a view (:func:`_stack` undone)."""
    if not batch:  # one filter: the stack of one's row, 0-d for a scalar
        return a[0, ...]
    if len(batch) == 1:
        return a
    return a.reshape(batch + a.shape[1:])


def _shared(a: np.ndarray, batch: tuple[int, ...], core: int) -> np.ndarray:
    """Like :func:`_stack`, but an ``a`` with no batch axis is passed once (leading axis 1)."""
    if a.ndim == core:
        return kernel_array(a[None])
    return _stack(a, batch, core)


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


class KernelTable(NamedTuple):
    """The kernels of the step, for a block of filters: what the engine calls (:mod:`squkf.engine`).

    Each entry takes C-contiguous float64 stacks with the filter axis first and writes its
    results into the outputs it is given (:mod:`squkf.kernels.phases` documents the arguments).
    A second table (another backend) gives the same entries with the same arguments. Every
    numerical route reads the table when it runs (the engine, and the wrappers below, which
    the hooks' routes, the smoother and :mod:`squkf.linalg` call), so the table installed as
    :data:`KERNELS` serves them all.
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

_NO_NOISE: dict[int, np.ndarray] = {}


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


def tria(rows: np.ndarray) -> np.ndarray:
    """Lower factor with a non-negative diagonal of ``rows.T @ rows``, by Householder QR.

    Parameters
    ----------
    rows : ndarray, shape (..., k, n)

    Returns
    -------
    S : ndarray, shape (..., n, n)
        ``S @ S.T == rows.T @ rows``; if ``k < n`` the last ``n - k`` columns are zero.
    """
    batch = rows.shape[:-2]
    k, n = rows.shape[-2:]
    A = _stack(rows, batch, 2)
    S = np.empty((A.shape[0], n, n))
    _call(KERNELS.tria, A.shape[0], A, S)
    return _unstack(S, batch)


def solve_lower(L: np.ndarray, b: np.ndarray, trans: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``L x = b`` (``L.T x = b`` for ``trans``) for lower-triangular ``L``.

    Parameters
    ----------
    L : ndarray, shape (..., n, n)
    b : ndarray, shape (..., n) or (..., n, q)
        A stack of vectors when ``b.ndim == L.ndim - 1``.
    trans : bool

    Returns
    -------
    x : ndarray, same shape as ``b`` (broadcast with ``L``'s batch)
    ok : ndarray of bool, shape (...)
        False where ``L`` has a zero on its diagonal (``x`` is then not finite).
    """
    vector = b.ndim == L.ndim - 1
    B_ = b[..., None] if vector else b
    batch = _batch((L, 2), (B_, 2))
    n, q = B_.shape[-2:]
    Y = _stack(B_, batch, 2)
    X = np.empty(Y.shape)
    ok = np.empty(Y.shape[0], dtype=np.bool_)
    _call(KERNELS.solve, Y.shape[0], _shared(L, batch, 2), Y, 1 if trans else 0, X, ok)
    X = _unstack(X, batch)
    return (X[..., 0] if vector else X), _unstack(ok, batch)


def chol_update(S: np.ndarray, v: np.ndarray, sign: float) -> tuple[np.ndarray, np.ndarray]:
    """Rank-1 update (``sign > 0``) or downdate of lower factors, O(n^2) each.

    Parameters
    ----------
    S : ndarray, shape (..., n, n)
    v : ndarray, shape (..., n)
    sign : float

    Returns
    -------
    S1 : ndarray, shape (..., n, n)
        ``S1 @ S1.T == S @ S.T + sign * outer(v, v)`` where it succeeded.
    fail : ndarray of int, shape (...)
        The first column whose rotation failed, or -1.
    """
    batch = _batch((S, 2), (v, 1))
    L = _stack(S, batch, 2)
    out = np.empty(L.shape)
    fail = np.empty(L.shape[0], dtype=np.int64)
    _call(KERNELS.chol_update, L.shape[0], L, _stack(v, batch, 1), float(sign), out, fail)
    return _unstack(out, batch), _unstack(fail, batch)


def sigma_points(x: np.ndarray, S: np.ndarray, xi: np.ndarray, gamma: float = 0.0, offsets: bool = True):
    """Sigma points ``x + xi @ S.T`` and their offsets ``xi @ S.T``.

    Parameters
    ----------
    x : ndarray, shape (..., n)
    S : ndarray, shape (..., n, n)
        Lower factors.
    xi : ndarray, shape (N, n)
        Unit points.
    gamma : float
        Non-zero when ``xi`` is ``[0; gamma I; -gamma I]`` or ``[gamma I; -gamma I]`` (offsets in O(n^2)).
    offsets : bool
        Whether the offsets are wanted (not written otherwise).

    Returns
    -------
    sigmas : ndarray, shape (..., N, n)
    offsets : ndarray, shape (..., N, n), or None
        None when not wanted.
    """
    batch = _batch((x, 1), (S, 2))
    N, n = xi.shape
    Ss = _stack(S, batch, 2)
    X = np.empty((Ss.shape[0], N, n))
    dX = np.empty(X.shape if offsets else (0, N, n))
    _call(
        KERNELS.points,
        Ss.shape[0],
        _shared(x, batch, 1),
        Ss,
        plan_array(xi),
        float(gamma),
        X,
        dX,
        plan=(2,),
    )
    return _unstack(X, batch), (_unstack(dX, batch) if offsets else None)


def finite_rows(A: np.ndarray) -> np.ndarray:
    """Which filters' values are all finite.

    Parameters
    ----------
    A : ndarray, shape (K, ...)

    Returns
    -------
    ndarray of bool, shape (K,)
    """
    rows = kernel_array(A.reshape(A.shape[0], -1))
    ok = np.empty(rows.shape[0], dtype=np.bool_)
    _call(KERNELS.finite_rows, rows.shape[0], rows, ok)
    return ok


def transform(
    P: np.ndarray,
    mode: int,
    wm: np.ndarray,
    scale: np.ndarray,
    sign: np.ndarray,
    noise: np.ndarray | None = None,
    ref: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and lower factor of weighted rows plus additive noise (one QR, a downdate per negative row).

    Parameters
    ----------
    P : ndarray, shape (..., N, d)
        Points (``CENTRAL``, ``MEAN``) or rows (``GIVEN``).
    mode : int
        The row form.
    wm, scale, sign : ndarray, shape (N,)
        Mean weights; each row's ``sqrt(|weight|)`` and sign.
    noise : ndarray, shape (..., d, q), optional
        A square root of the additive noise.
    ref : ndarray, shape (..., d), optional
        The mean, for ``GIVEN``.

    Returns
    -------
    mean : ndarray, shape (..., d)
    S : ndarray, shape (..., d, d)
    status : ndarray of int, shape (...)
        0, or ``r + 1`` (``-(r + 1)``) where negative row ``r``'s downdate failed
        (found the factor singular).
    """
    batch = _batch((P, 2), (noise, 2), (ref, 1))
    N, d = P.shape[-2:]
    Ps = _stack(P, batch, 2)
    B = Ps.shape[0]
    Nz = no_noise(d) if noise is None else _shared(noise, batch, 2)
    R = zeros_row(d) if ref is None else _shared(ref, batch, 1)
    mean = np.empty((B, d))
    S = np.empty((B, d, d))
    status = np.empty(B, dtype=np.int64)
    nothing = no_set(d)
    _call(
        KERNELS.transform,
        B,
        Ps,
        R,
        mode,
        plan_array(wm),
        plan_array(scale),
        plan_array(sign),
        Nz,
        mean,
        S,
        status,
        0,
        no_points(d),
        0.0,
        nothing,
        nothing,
        plan=(3, 4, 5, 11),
    )
    return _unstack(mean, batch), _unstack(S, batch), _unstack(status, batch)


class JointUpdate(NamedTuple):
    """What an update kernel gives, in the caller's batch shape.

    Attributes
    ----------
    z_pred, y, w : ndarray, shape (..., m)
        Predicted measurement (None from :func:`downdate_update`), innovation, ``Sy^-1 y``.
    Sy : ndarray, shape (..., m, m)
    L21 : ndarray, shape (..., n, m)
    dx, x : ndarray, shape (..., n)
        ``L21 w`` and the posterior mean ``x + dx``.
    S : ndarray, shape (..., n, n)
        The posterior factor.
    log_likelihood, nis : ndarray, shape (...)
        The measurement's Gaussian log-likelihood and its squared Mahalanobis distance ``w.w``.
    status : ndarray of int, shape (...)
        0, or g13ej's 301, 302, 303.
    """

    z_pred: np.ndarray | None
    y: np.ndarray
    w: np.ndarray
    Sy: np.ndarray
    L21: np.ndarray
    dx: np.ndarray
    x: np.ndarray
    S: np.ndarray
    log_likelihood: np.ndarray
    nis: np.ndarray
    status: np.ndarray


def joint_update(
    H: np.ndarray,
    X: np.ndarray,
    z: np.ndarray,
    R1_2: np.ndarray,
    x: np.ndarray,
    mode: int,
    wm: np.ndarray,
    scale: np.ndarray,
    sign: np.ndarray,
    xref: np.ndarray | None = None,
    zref: np.ndarray | None = None,
    pair: float = 0.0,
) -> JointUpdate:
    """The measurement update by one QR of the joint rows (see :func:`phases.joint_update_kernel`).

    Parameters
    ----------
    H : ndarray, shape (..., N, m)
    X : ndarray, shape (..., N, n)
    z : ndarray, shape (..., m)
        The measurement, or for ``GIVEN`` the innovation.
    R1_2 : ndarray, shape (..., m, m)
    x : ndarray, shape (..., n)
        The prior mean.
    mode : int
    wm, scale, sign : ndarray, shape (N,)
    xref : ndarray, shape (..., n), optional
        The reference of ``X`` for ``MEAN`` (default: zero, ``X`` are offsets).
    zref : ndarray, shape (..., m), optional
        The predicted measurement for ``GIVEN``.
    pair : float
        The rotation of axis points' ``+/-`` pairs (``CENTRAL``, offsets as ``X``; see the kernel).

    Returns
    -------
    JointUpdate
    """
    if H.ndim == 2 and X.ndim == 2 and z.ndim == 1 and R1_2.ndim == 2 and x.ndim == 1:
        batch: tuple[int, ...] = _batch((xref, 1), (zref, 1))  # one filter, as a rule
    else:
        batch = _batch((H, 2), (X, 2), (z, 1), (R1_2, 2), (x, 1), (xref, 1), (zref, 1))
    N, m = H.shape[-2:]
    n = X.shape[-1]
    Hs = _stack(H, batch, 2)
    B = Hs.shape[0]
    out: list[np.ndarray] = [np.empty((B, m)), np.empty((B, m)), np.empty((B, m)), np.empty((B, m, m))]
    out += [np.empty((B, n, m)), np.empty((B, n)), np.empty((B, n)), np.empty((B, n, n))]
    out += [np.empty(B), np.empty(B), np.empty(B, dtype=np.int64)]
    _call(
        KERNELS.joint_update,
        B,
        Hs,
        zeros_row(m) if zref is None else _shared(zref, batch, 1),
        _stack(X, batch, 2),
        zeros_row(n) if xref is None else _shared(xref, batch, 1),
        _stack(z, batch, 1),
        _shared(R1_2, batch, 2),
        _shared(x, batch, 1),
        mode,
        plan_array(wm),
        plan_array(scale),
        plan_array(sign),
        float(pair),
        *out,
        no_points(n),
        0.0,
        no_set(n),
        plan=(8, 9, 10, 23),
    )
    return JointUpdate(*(_unstack(a, batch) for a in out))


def downdate_update(
    H: np.ndarray,
    z_pred: np.ndarray,
    X: np.ndarray,
    xref: np.ndarray,
    y: np.ndarray,
    Sy: np.ndarray,
    S: np.ndarray,
    x: np.ndarray,
    wc: np.ndarray,
) -> JointUpdate:
    """g13ej's update for a set whose covariance is not the prior's (:func:`phases.downdate_update_kernel`).

    Parameters
    ----------
    H : ndarray, shape (..., N, m)
    z_pred : ndarray, shape (..., m)
        The reference of ``H`` (the predicted measurement; zero for given deviations).
    X : ndarray, shape (..., N, n)
    xref : ndarray, shape (..., n)
    y : ndarray, shape (..., m)
    Sy : ndarray, shape (..., m, m)
    S : ndarray, shape (..., n, n)
    x : ndarray, shape (..., n)
    wc : ndarray, shape (N,)

    Returns
    -------
    JointUpdate
        With ``z_pred`` None.
    """
    batch = _batch((H, 2), (z_pred, 1), (X, 2), (xref, 1), (y, 1), (Sy, 2), (S, 2), (x, 1))
    N, m = H.shape[-2:]
    n = X.shape[-1]
    Hs = _stack(H, batch, 2)
    B = Hs.shape[0]
    L21, w = np.empty((B, n, m)), np.empty((B, m))
    dx, xp, Sp, status = np.empty((B, n)), np.empty((B, n)), np.empty((B, n, n)), np.empty(B, dtype=np.int64)
    ll, ww = np.empty(B), np.empty(B)
    ys = _stack(y, batch, 1)
    Sys = _stack(Sy, batch, 2)
    _call(
        KERNELS.downdate_update,
        B,
        Hs,
        _shared(z_pred, batch, 1),
        _stack(X, batch, 2),
        _shared(xref, batch, 1),
        ys,
        Sys,
        _stack(S, batch, 2),
        _shared(x, batch, 1),
        plan_array(wc),
        L21,
        w,
        dx,
        xp,
        Sp,
        ll,
        ww,
        status,
        plan=(8,),
    )
    out = (ys, w, Sys, L21, dx, xp, Sp, ll, ww, status)
    return JointUpdate(None, *(_unstack(a, batch) for a in out))
