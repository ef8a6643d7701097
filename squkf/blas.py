"""One BLAS thread while a step runs: the filter's matrices are too small to share.

A UKF step factors matrices of a few hundred rows at most. A threaded BLAS
splits such a QR across cores and then waits for them; on a busy or virtual
machine that wait can cost ten times the work (measured here: a 301 x 100 QR
took 0.4 ms on one thread and 3 ms on two). So, for a state of
:data:`MIN_DIM` variables or more, :func:`one_blas_thread` holds every BLAS
library that threadpoolctl finds loaded (OpenBLAS, MKL, BLIS; ``user_api="blas"``)
to one thread while the filter's own numerics run: the second half of a
prediction or an update, a ``UT=`` transform included. Your ``fx`` and ``hx``
run before it, with the BLAS as you set it.

threadpoolctl is a dependency of squkf, so the hold is on by default. It is
imported, and the loaded libraries are looked up (a few milliseconds), at the
first hold, once: a BLAS library loaded after that is left alone. Importing
squkf does not import it. On a busy 2-core machine a step at n = 81 takes
about as long with the BLAS at its default threads as with
``OPENBLAS_NUM_THREADS=1`` (``benchmarks/blas_threads.py``,
``benchmarks/results/blas_threads.md``).

The rules of the hold:

* It never writes back a stale count. On exit a library's count is restored
  only if it still is 1, the value the hold set; a count someone else changed
  while the step ran is left as they set it.
* A library with one thread count for the whole process (OpenBLAS on its own
  threads, BLIS) is held process-wide: while any Python thread is inside a
  hold it runs on one thread for every thread, including another thread's
  ``fx``. Holders are counted under a lock; the first one limits, the last one
  restores, so filters stepped in several Python threads at once leave the
  count as they found it. A library whose count is per calling thread
  (OpenBLAS built on OpenMP; MKL, or any library threadpoolctl does not say
  is process-wide) is held and restored by each thread for itself.
* threadpoolctl 3.8 and later let one Python thread at a time change a
  process-wide OpenBLAS. When another thread holds that right (inside its own
  ``threadpool_limits`` block), the hold leaves that library alone for the step.
* A ``threadpool_limits`` block entered while a step holds the BLAS records 1 as
  the count to put back, and threadpoolctl puts it back when the block ends:
  limit the BLAS around the filter, not alongside it, or set
  ``squkf.blas.MIN_DIM = None`` to leave the BLAS alone.

:data:`MIN_DIM` is where the hold pays, measured with ``benchmarks/blas_hold.py``
(Lorenz-96, numpy's and scipy's OpenBLAS at their default two threads on a
busy 2-core machine). Up to n = 64 it gained nothing and cost 15 to 25 us per
enter and exit (both libraries set and restored; 5 us when they already run
on one thread), 0.1 to 0.4 ms on a step. From n = 65 the step's operations
thread, and a step took 15 to 50 ms without the hold (n = 65 to 80), 5 ms
with it. So ``MIN_DIM = 65``; rerun the script when the step's matrices
change. Fastest of all is the BLAS on one thread for the whole loop
(``threadpool_limits(1)`` around it, or ``OPENBLAS_NUM_THREADS=1``): with
the hold a step of 65 to 100 variables still took 0.7 to 2.3 ms more.
"""

from __future__ import annotations

import functools
import threading
import warnings
from collections.abc import Callable
from types import TracebackType
from typing import Any

__all__ = ["MIN_DIM", "one_blas_thread", "one_thread_method"]

#: States of this many variables or more run their steps on one BLAS thread
#: (below it OpenBLAS does not thread the step's operations anyway; measured). None: never.
MIN_DIM: int | None = 65

# (process-wide libraries, per-thread libraries, threadpoolctl's release of OpenBLAS control or None)
_Found = tuple[tuple[Any, ...], tuple[Any, ...], Callable[[], None] | None]
_NOTHING: _Found = ((), (), None)

_lock = threading.Lock()  # guards _found's lookup, _holders and _saved, and every get/set of a count
_found: _Found | None = None
_holders = 0  # Python threads' holds now open on the process-wide libraries
_saved: list[tuple[Any, int]] = []  # (library, count before the hold) of the process-wide ones the hold set


def _process_wide(lib: Any) -> bool:
    """Whether ``lib``'s thread count is one for the whole process (else: treated as per thread)."""
    api = getattr(lib, "internal_api", None)
    if api == "openblas":
        return getattr(lib, "threading_layer", None) != "openmp"
    return api == "blis"


def _discover() -> _Found:
    import threadpoolctl  # a dependency, imported at the first hold (not at ``import squkf``)

    try:
        libs = list(threadpoolctl.ThreadpoolController().select(user_api="blas").lib_controllers)
    except Exception as exc:  # a failed inspection must not fail the filter's step
        warnings.warn(
            f"squkf.blas: threadpoolctl could not inspect the BLAS libraries ({exc!r}); they are left alone",
            RuntimeWarning,
            stacklevel=4,
        )
        return _NOTHING
    release = getattr(getattr(threadpoolctl, "OpenBLASController", None), "clear_controlling_thread", None)
    shared = tuple(lib for lib in libs if _process_wide(lib))
    return shared, tuple(lib for lib in libs if not _process_wide(lib)), release


def _libraries() -> _Found:
    global _found
    found = _found
    if found is None:
        with _lock:
            if _found is None:
                _found = _discover()
            found = _found
    return found


def _limit(libs: tuple[Any, ...], release: Callable[[], None] | None) -> list[tuple[Any, int]]:
    """Set each of ``libs`` to one thread; the ``(library, count before)`` of those it changed."""
    changed = []
    for lib in libs:
        n = lib.get_num_threads()
        if n is None or n == 1:
            continue
        lib.set_num_threads(1)
        # threadpoolctl >= 3.8 ignores the call when another Python thread controls this OpenBLAS
        if lib.get_num_threads() == 1:
            changed.append((lib, n))
    if changed and release is not None:
        release()  # give up the control the call took, so the user's threads can still set counts
    return changed


def _restore(changed: list[tuple[Any, int]], release: Callable[[], None] | None) -> None:
    """Put back each count of ``changed`` that is still the hold's 1 (another value is someone's change)."""
    for lib, n in changed:
        if lib.get_num_threads() == 1:
            lib.set_num_threads(n)
    if changed and release is not None:
        release()


class _Hold:
    """One entry into the hold (see :func:`one_blas_thread`); not reusable."""

    __slots__ = ("_found", "_local")

    def __enter__(self) -> None:
        global _holders, _saved
        found = self._found = _libraries()
        shared, local, release = found
        if not (shared or local):
            return
        with _lock:
            if shared:
                if _holders == 0:
                    _saved = _limit(shared, release)
                _holders += 1
            self._local = _limit(local, release)

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        global _holders, _saved
        shared, local, release = self._found
        if not (shared or local):
            return
        with _lock:
            _restore(self._local, release)
            if shared:
                _holders -= 1
                if _holders == 0:
                    saved, _saved = _saved, []
                    _restore(saved, release)


def one_blas_thread() -> _Hold:
    """Hold the loaded BLAS libraries to one thread inside the ``with`` block.

    Safe to nest and to enter from several Python threads at once. See the
    module's notes for what is held and when a count is put back.

    Returns
    -------
    context manager
        ``with one_blas_thread(): ...``; it yields None.
    """
    return _Hold()


def one_thread_method(dim_of: Callable[[Any], int]) -> Callable[[Callable], Callable]:
    """A decorator: the method runs on one BLAS thread when ``dim_of(self)`` is :data:`MIN_DIM` or more.

    Parameters
    ----------
    dim_of : callable
        ``dim_of(self) -> int``, the state dimension of the object.

    Returns
    -------
    callable
        The decorator; the decorated method takes positional arguments only
        (packing keywords too costs a microsecond a step).
    """

    def decorate(method: Callable) -> Callable:
        @functools.wraps(method)
        def run(self, *args):
            if MIN_DIM is not None and dim_of(self) >= MIN_DIM:
                with one_blas_thread():
                    return method(self, *args)
            return method(self, *args)

        return run

    return decorate
