"""One BLAS thread while a step runs: the filter's matrices are too small to share.

A UKF step factors matrices of a few hundred rows at most. A threaded BLAS
splits such a QR across cores and then waits for them; on a busy or virtual
machine that wait can cost ten times the work (measured here: a 301 x 100 QR
took 0.4 ms on one thread and 3 ms on two). So, for a state of
:data:`MIN_DIM` variables or more, :func:`one_blas_thread` holds the OpenBLAS
libraries that numpy and scipy ship in their wheels to one thread while the
filter's own numerics run (the second half of a prediction or an update; your
``fx`` and ``hx`` run before it, with the BLAS as you set it), and puts their
thread count back when they return or raise.

OpenBLAS keeps one thread count per library, for the whole process: another
Python thread calling BLAS meanwhile also runs on one thread. Set
``squkf.blas.MIN_DIM = None`` to leave the BLAS alone. Other BLAS builds (MKL,
Accelerate, a system OpenBLAS numpy was compiled against) are not found and
are left alone.
"""

from __future__ import annotations

import ctypes
import glob
import os
from contextlib import contextmanager
from typing import cast

__all__ = ["MIN_DIM", "one_blas_thread", "blas_controls"]

#: States of this many variables or more run their steps on one BLAS thread
#: (below it OpenBLAS does not thread the step's operations anyway). None: never.
MIN_DIM: int | None = 16

_GET = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads", "openblas_get_num_threads")
_SET = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads")
_controls: list[tuple] | None = None


def _bundled_openblas() -> list[str]:
    import numpy
    import scipy

    paths = []
    for pkg in (numpy, scipy):
        root = os.path.dirname(cast(str, pkg.__file__))  # regular packages, so __file__ is set
        for folder in (root + ".libs", os.path.join(root, ".dylibs")):
            paths += sorted(glob.glob(os.path.join(folder, "*openblas*")))
    return paths


def _bind(lib, names, argtypes):
    for name in names:
        fn = getattr(lib, name, None)
        if fn is not None:
            fn.restype = ctypes.c_int if not argtypes else None
            fn.argtypes = argtypes
            return fn
    return None


def blas_controls() -> list[tuple]:
    """``(get, set)`` thread-count functions of the OpenBLAS libraries numpy and scipy loaded.

    Found once, by the libraries' paths inside the installed wheels (loading
    an already loaded library returns the same one); empty where there are none.
    """
    global _controls
    if _controls is None:
        found = []
        for path in _bundled_openblas():
            try:
                lib = ctypes.CDLL(path)
            except OSError:
                continue
            get, set_ = _bind(lib, _GET, []), _bind(lib, _SET, [ctypes.c_int])
            if get is not None and set_ is not None:
                found.append((get, set_))
        _controls = found
    return _controls


@contextmanager
def one_blas_thread():
    """Hold the bundled OpenBLAS libraries to one thread inside the ``with`` block."""
    changed = []
    for get, set_ in blas_controls():
        n = get()
        if n != 1:
            set_(1)
            changed.append((set_, n))
    try:
        yield
    finally:
        for set_, n in changed:
            set_(n)
