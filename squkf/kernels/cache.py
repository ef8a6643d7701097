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
when it is loaded from the cache, and never for other numba functions), and
one more when that compile has ended (no compile of squkf's for
:data:`QUIET_PERIOD` seconds, or the process exits, or :func:`end_of_compile`),
with the time it took, unless ``SQUKF_QUIET_COMPILE`` is set:
:ref:`first use <first-use>`. A later compile in the same process (a route
first used after the default step's kernels were compiled or loaded: the
downdate form of a ``UT`` or ``residual_x``, a partial measurement, the
smoother) is said too, by a shorter line naming its kernel, and its end, so
that no pause of seconds goes unexplained; not under :func:`squkf.precompile`,
whose one line covers every kernel. Nothing here compiles anything.
"""

from __future__ import annotations

import atexit
import inspect
import os
import sys
import threading
import time
import warnings
from collections import Counter
from collections.abc import Callable
from types import FrameType
from typing import Any

import numba
from numba.core import event
from numba.core.caching import FunctionCache

__all__ = [
    "jit", "cache_directory", "cache_label", "is_kernel", "compiled", "compiling_all", "end_of_compile",
    "QUIET_VARIABLE", "QUIET_PERIOD",
]  # fmt: skip

#: Set to anything but ``""`` or ``"0"`` to silence the lines said on a compile (read when it is due).
QUIET_VARIABLE = "SQUKF_QUIET_COMPILE"

#: Seconds without a compile of squkf's kernels after which the compile that was said has ended (the
#: kernels of one step compile one after another, with only the step's Python between them).
QUIET_PERIOD = 1.0

_PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # squkf's folder

_directories: dict[str, str | None] = {}  # source file -> numba's cache directory for it, None: in memory
_functions: set[Callable] = set()  # the Python functions of the kernels made by jit
_lock = threading.Lock()  # guards the two below (compiles run on any thread)
_said = False
_compiled: Counter[str] = Counter()  # kernel name -> compiles in this process
_running = 0  # compiles of squkf's kernels now running (a kernel's helpers compile inside it)
_said_start: float | None = None  # when the compile that was said began; None once its end is said
_said_last = 0.0  # when the last compile since then ended
_timer: threading.Timer | None = None  # says the end after QUIET_PERIOD with no compile
_all = False  # squkf.precompile is running: the line says that every kernel compiles


def _user_stacklevel() -> int:
    """``warnings.warn``'s ``stacklevel`` for its caller that names the first frame outside squkf.

    Counted as ``warnings`` counts (importlib's own frames skipped), so a warning raised while
    ``import squkf`` runs points at the user's ``import`` line, not at squkf's source.
    """
    frame: FrameType | None = sys._getframe(2)  # the caller of warnings.warn's caller
    level = 2
    while frame is not None:
        name = frame.f_code.co_filename
        if not ("importlib" in name and "_bootstrap" in name):
            if not name.startswith(_PACKAGE + os.sep):
                return level
            level += 1
        frame = frame.f_back
    return level


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
            warnings.warn(_in_memory_warning(str(exc)), RuntimeWarning, stacklevel=_user_stacklevel())
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
    if _all:
        what = "compiling every kernel of every route"
        where = f"cache: {where}" if where != "in memory" else "in memory: no writable cache location"
    elif where == "in memory":
        what = "compiling its numba kernels, typically 10-60 s, again in every new process"
        where = "in memory: no writable cache location, set NUMBA_CACHE_DIR"
    else:
        what = (
            "compiling its numba kernels, typically 10-60 s, once; a UT, residual_x or state_add, angle "
            "hooks, a partial z or the smoother may compile once more unless `python -m squkf precompile`"
            " was run"
        )
        where = f"cache: {where}"
    return f"squkf: {what} ({where}); {QUIET_VARIABLE}=1 hides this"


def _later_line(py_func: Callable) -> str:
    where = cache_label(py_func)
    kept = "again in every new process" if where == "in memory" else "once"
    return (
        f"squkf: compiling {py_func.__name__} for a route first used in this process, typically 1-10 s, "
        f"{kept}; `python -m squkf precompile` compiles every route ahead; {QUIET_VARIABLE}=1 hides this"
    )


def compiling_all(on: bool) -> None:
    """Whether :func:`squkf.precompile` is running: the line said on a compile then says so."""
    global _all
    _all = on


def end_of_compile() -> None:
    """Say now that the compile that was said has ended, with its time, if it has not been said yet."""
    global _said_start, _timer
    with _lock:
        if _said_start is None or _running:
            return
        seconds = _said_last - _said_start
        _said_start = None
        if _timer is not None:
            _timer.cancel()
            _timer = None
    print(f"squkf: compiled in {seconds:.1f} s", file=sys.stderr, flush=True)


class _CompileListener(event.Listener):
    """Counts the compiles of squkf's kernels and says the first one, and its end, on stderr."""

    def on_start(self, ev: event.Event) -> None:
        global _said, _running, _timer, _said_start
        dispatcher = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
        if dispatcher is None or not is_kernel(dispatcher):
            return
        with _lock:
            _compiled[dispatcher.py_func.__name__] += 1
            _running += 1
            if _timer is not None:
                _timer.cancel()
                _timer = None
            first = not _said
            # a later compile is said when the one before has been said to end (a kernel's helpers, and
            # the kernels of one step, compile while it runs)
            later = _said and _said_start is None and _running == 1 and not _all
            _said = True
            say = (first or later) and not _quiet()
            if say:
                _said_start = time.perf_counter()
        if say:
            line = _compiling_line if first else _later_line
            print(line(dispatcher.py_func), file=sys.stderr, flush=True)

    def on_end(self, ev: event.Event) -> None:
        global _running, _said_last, _timer
        dispatcher = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
        if dispatcher is None or not is_kernel(dispatcher):
            return
        with _lock:
            _running -= 1
            if _running or _said_start is None:
                return
            _said_last = time.perf_counter()
            _timer = threading.Timer(QUIET_PERIOD, end_of_compile)
            _timer.daemon = True  # the process may end first: atexit says it then
            _timer.start()


event.register("numba:compile", _CompileListener())
atexit.register(end_of_compile)
