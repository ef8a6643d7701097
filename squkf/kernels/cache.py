"""Where the kernels' machine code is kept, and the one line said when squkf compiles it.

:mod:`squkf.kernels.phases` makes its kernels with :func:`jit`: numba's
``njit`` with its disk cache where numba has a writable place for the
module's file, and compiled in memory (with one ``RuntimeWarning``) where it
has none. numba makes that search itself when ``njit(cache=True)`` decorates a
function (its locators, in order: ``NUMBA_CACHE_DIR``, the ``__pycache__``
beside the source, the user-wide cache directory) and raises when every one
fails; :func:`cache_directory` makes the same search once, with numba's own
code, before anything is decorated, so ``import squkf`` never raises for it.

A listener on numba's ``"numba:compile"`` event writes one line on stderr the
first time in a process that one of these kernels is really compiled (not
when it is loaded from the cache, and never for other numba functions),
unless ``SQUKF_QUIET_COMPILE`` is set: :ref:`first use <first-use>`. Nothing here
compiles anything.
"""

from __future__ import annotations

import inspect
import os
import sys
import threading
import warnings
from collections import Counter
from collections.abc import Callable
from typing import Any

import numba
from numba.core import event
from numba.core.caching import FunctionCache

__all__ = ["jit", "cache_directory", "cache_label", "is_kernel", "compiled", "QUIET_VARIABLE"]

#: Set to anything but ``""`` or ``"0"`` to silence the line said on a compile (read when it is due).
QUIET_VARIABLE = "SQUKF_QUIET_COMPILE"

_directories: dict[str, str | None] = {}  # source file -> numba's cache directory for it, None: in memory
_functions: set[Callable] = set()  # the Python functions of the kernels made by jit
_lock = threading.Lock()  # guards the two below (compiles run on any thread)
_said = False
_compiled: Counter[str] = Counter()  # kernel name -> compiles in this process


def _in_memory_warning(reason: str) -> str:
    return (
        f"squkf compiles its kernels in memory, again in every new process: numba has no writable cache "
        f"location for them ({reason}). Set NUMBA_CACHE_DIR to a writable directory to keep them on disk"
    )


def cache_directory(py_func: Callable) -> str | None:
    """The directory numba caches ``py_func``'s machine code in, or None where it has none.

    Decided once per source file, by numba's own search (the cache object
    ``njit(cache=True)`` would make for the function). Where the search fails
    (every location unwritable), a ``RuntimeWarning`` naming
    ``NUMBA_CACHE_DIR`` says so, once.

    Parameters
    ----------
    py_func : callable
        A plain Python function of the module whose kernels are meant.

    Returns
    -------
    str or None
        An absolute directory, or None: compile in memory.
    """
    source = inspect.getfile(py_func)
    if source not in _directories:
        try:
            path: str | None = os.path.abspath(FunctionCache(py_func).cache_path)
        except RuntimeError as exc:  # numba's "no locator available": no writable place, or a bad list
            path = None
            warnings.warn(_in_memory_warning(str(exc)), RuntimeWarning, stacklevel=3)
        _directories[source] = path
    return _directories[source]


def jit(**options: Any) -> Callable[[Callable], Any]:
    """numba's ``njit(**options)``, cached on disk where :func:`cache_directory` finds a place.

    Parameters
    ----------
    **options
        numba's options (``nogil``, ``error_model``, ``inline``...); not ``cache``.

    Returns
    -------
    callable
        A decorator; the dispatchers it makes are squkf's kernels for :func:`is_kernel`.
    """

    def decorate(py_func: Callable) -> Any:
        on_disk = cache_directory(py_func) is not None
        _functions.add(py_func)
        return numba.njit(cache=on_disk, **options)(py_func)

    return decorate


def is_kernel(dispatcher: Any) -> bool:
    """Whether a numba dispatcher is one of the kernels made by :func:`jit`."""
    return getattr(dispatcher, "py_func", None) in _functions


def cache_label(py_func: Callable) -> str:
    """Where ``py_func``'s kernels are cached, in words: the directory, or ``"in memory"``."""
    path = cache_directory(py_func)
    return "in memory" if path is None else path


def compiled() -> dict[str, int]:
    """How many times each kernel (by name) was compiled in this process; loads from the cache not counted."""
    with _lock:
        return dict(_compiled)


def _quiet() -> bool:
    return os.environ.get(QUIET_VARIABLE, "") not in ("", "0")


def _compiling_line(py_func: Callable) -> str:
    where = cache_label(py_func)
    if where == "in memory":
        where = "in memory, no writable cache location: set NUMBA_CACHE_DIR"
    return f"squkf: compiling its numba kernels on first use (cache: {where}); {QUIET_VARIABLE}=1 hides this"


class _CompileListener(event.Listener):
    """Counts the compiles of squkf's kernels and says the first one on stderr."""

    def on_start(self, ev: event.Event) -> None:
        global _said
        dispatcher = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
        if dispatcher is None or not is_kernel(dispatcher):
            return
        with _lock:
            _compiled[dispatcher.py_func.__name__] += 1
            say, _said = not _said, True
        if say and not _quiet():
            print(_compiling_line(dispatcher.py_func), file=sys.stderr, flush=True)

    def on_end(self, ev: event.Event) -> None:
        pass


event.register("numba:compile", _CompileListener())
