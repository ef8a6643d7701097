"""The compiled numerical core: one kernel per phase of the step, over a stack of filters.

The package is four modules:

- :mod:`squkf.kernels.phases`: every compiled function (numba), the lane
  primitives and the entry kernels, each with a status per filter;
- :mod:`squkf.kernels.table`: the kernel table :data:`~squkf.kernels.table.KERNELS`
  that every numerical route reads when it runs, and the arrays as its
  entries take them (the row forms, :func:`~squkf.kernels.table.kernel_array`,
  :func:`~squkf.kernels.table.plan_array`, ...);
- :mod:`squkf.kernels.wrappers`: the kernels in numpy's batch convention
  (``tria``, ``solve_lower``, ``chol_update``, ``sigma_points``,
  ``finite_rows``, ``transform``, ``joint_update``, ``downdate_update``), which
  the public entry points call;
- :mod:`squkf.kernels.threads`: the thread pool (``set_num_threads``,
  ``thread_map``, a step's hold on its count, a large stack's kernel call cut
  between the threads);

with :mod:`squkf.kernels.cache`, where numba's cache goes. Callers import from
these modules directly.

Kernels are compiled on first use (on an empty cache, about 11 s for the default
``SquareRootUKF`` or ``Fleet`` on the 2-core benchmark machine:
``python benchmarks/compile_time.py``, ``benchmarks/results/compile.md``) and
cached on disk beside the package (numba's ``cache=True``); a new process
loads them in a fraction of a second. Importing squkf compiles nothing, and
is refused with ``NUMBA_DISABLE_JIT`` set (the kernels are never run as
Python): this package's import refuses it, before any of its modules.

Failures are not raised here: each kernel returns a status per filter
(see :mod:`squkf.kernels.phases`), which the callers turn into squkf's
exceptions (:mod:`squkf.linalg`, :mod:`squkf.transform`,
:mod:`squkf.measurement`).
"""

from __future__ import annotations

import numba

from ..errors import UnsupportedEnvironmentError

__all__: list[str] = []


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
