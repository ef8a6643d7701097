"""``squkf.dask``: a fleet of filters fanned out over Dask (``pip install "squkf[dask]"``).

Each chunk of filters (a block of rows along the filters axis) is filtered by
a :class:`squkf.Fleet` holding that chunk's rows of the template fleet's
state and noise (:meth:`squkf.Fleet.subset`); the template is not changed.
Every filter's arithmetic is independent of the others', so the results are
bit-identical to :meth:`squkf.Fleet.batch_filter` in one process, whatever
the chunking and whichever scheduler runs the graph (threads, processes, a
``distributed.Client``, whose scheduler reruns the tasks of a lost worker).

Importing :mod:`squkf` never imports this module or Dask.

- :func:`batch_filter`: a ``dask.array`` of measurements ``(K, T, dim_z)``
  in, a :class:`squkf.FleetResult` of lazy dask arrays out.
- :func:`filter_frame`: long-format data in a ``dask.dataframe`` (one row per
  series and time step), filtered per series, estimates out as a dask
  dataframe aligned with the input.

The model functions travel to the workers with the template fleet, so for a
process-based scheduler they must be importable there (module-level functions
of an installed module).

Worker processes started by a Dask nanny (``LocalCluster``, ``dask worker``)
should get :func:`worker_environ`'s environment (:func:`local_cluster` starts
a ``LocalCluster`` with it): under dask's default one the fleet's step runs
about 1.6 times slower there than in a plain process.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

try:
    import dask
    import dask.array as da
    import dask.dataframe as dd
    import pandas as pd
except ImportError as exc:  # say which extra brings them
    raise ModuleNotFoundError(
        f'squkf.dask needs its extra: pip install "squkf[dask]" ({exc})', name=exc.name
    ) from exc

from . import checks
from .batch import model_kwargs, per_step
from .boundary import records
from .boundary.loop import check_keep
from .checks import as_measurements
from .errors import ParameterError, ShapeError
from .fleet import Fleet, FleetResult

if TYPE_CHECKING:
    import distributed

__all__ = [
    "batch_filter", "compute", "filter_frame", "fit_noise", "local_cluster", "worker_environ",
    "MMAP_THRESHOLD",
]  # fmt: skip

MMAP_THRESHOLD = 16 * 2**20
"""Bytes from which glibc's malloc maps fresh pages, in :func:`worker_environ` (16 MiB)."""


def _fields() -> list[str]:
    """``FleetResult``'s fields: its own, then the per-step records' (the registry's, read now)."""
    steps = [r.name for r in records.STEP_RECORDS]
    return [f.name for f in dataclasses.fields(FleetResult) if f.name not in steps] + steps


def worker_environ() -> dict[str, Any]:
    """Dask's ``distributed.nanny.pre-spawn-environ``, with the allocator setting the fleet needs.

    Dask's nanny starts each worker process with ``MALLOC_TRIM_THRESHOLD_``
    set (65536: freed memory goes back to the system soon). Under glibc,
    setting it also fixes the size from which ``malloc`` maps fresh pages for
    every allocation at 128 KiB, where glibc would otherwise raise it as a
    program reuses larger blocks. A model function's arrays for a chunk of
    2048 filters are larger than that, so in such a worker each of them is a
    new mapping, zero-filled page by page at every step; a fleet left to
    choose its chunk then cuts smaller chunks to keep them under the threshold
    (:func:`squkf.stacks.default_chunk`). Adding ``MALLOC_MMAP_THRESHOLD_``
    (16 MiB, :data:`MMAP_THRESHOLD`) serves them from the heap again, and the
    chunks keep their full size; the trimming stays. Other allocators ignore
    both variables.

    Returns
    -------
    dict
        The current ``distributed.nanny.pre-spawn-environ`` with
        ``MALLOC_MMAP_THRESHOLD_`` added (a value already configured is kept).

    Examples
    --------
    Start the workers of a ``LocalCluster`` with it (a nanny reads the
    setting when it is created, and keeps it for the workers it restarts)::

        with dask.config.set({"distributed.nanny.pre-spawn-environ": squkf.dask.worker_environ()}):
            cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1)

    For ``dask worker`` on other machines, set ``MALLOC_MMAP_THRESHOLD_=16777216``
    in the environment that starts it.
    """
    env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", default={}) or {})
    env.setdefault("MALLOC_MMAP_THRESHOLD_", MMAP_THRESHOLD)
    return env


def local_cluster(n_workers: int | None = None, **kwargs: Any) -> distributed.LocalCluster:
    """A ``distributed.LocalCluster`` for fleets on this machine: one thread per worker process.

    Its workers are started with :func:`worker_environ`'s environment.

    Parameters
    ----------
    n_workers : int, optional
        Worker processes (default: distributed's, one per core).
    **kwargs
        Passed to ``distributed.LocalCluster`` (``threads_per_worker`` defaults
        to 1 and ``processes`` to True: the step is numpy on small matrices,
        and processes do not share the GIL).

    Returns
    -------
    distributed.LocalCluster
        Close it (or use it as a context manager) when done.

    Examples
    --------
    ::

        with squkf.dask.local_cluster(2) as cluster, distributed.Client(cluster) as client:
            result = squkf.dask.compute(squkf.dask.batch_filter(fleet, zs, keep="means"))
    """
    import distributed

    kwargs.setdefault("threads_per_worker", 1)
    kwargs.setdefault("processes", True)
    with dask.config.set({"distributed.nanny.pre-spawn-environ": worker_environ()}):
        return distributed.LocalCluster(n_workers=n_workers, **kwargs)


def _run_chunk(chunk: Fleet, block: np.ndarray, options: dict) -> FleetResult:
    return chunk.subset(slice(None)).batch_filter(block, **options)  # the task's input stays as it was


def batch_filter(
    fleet: Fleet,
    zs,
    *,
    keep: str | tuple[str, ...] = "all",
    dts=None,
    fx_args: dict | None = None,
    hx_args: dict | None = None,
) -> FleetResult:
    """Filter every series of a dask array with the template ``fleet``, one task per chunk of filters.

    Parameters
    ----------
    fleet : Fleet
        The template: its configuration, and each filter's initial state and
        noise (row ``k`` for series ``k``). It is not changed.
    zs : dask.array.Array or array_like, shape (K, T, dim_z)
        Measurements, NaN (or masked: a ``numpy.ma.MaskedArray``, or a dask
        array of masked chunks) where missing. Chunked along the filters axis; any
        chunking of the other two axes is merged into one chunk (the time
        recursion runs through all steps of a filter in one task).
    keep : {"all", "diagonals", "means", "final"} or tuple
        What to store, as for :meth:`squkf.Fleet.batch_filter` (``"means"`` or
        ``"final"`` for runs too large to keep every factor; a per-step record's
        ``keep`` word in a tuple adds that record: ``"whitened"`` the whitened
        innovations and ``log det S1_2``).
    dts, fx_args, hx_args
        As for :meth:`squkf.Fleet.batch_filter`; a per-filter array (leading
        axis ``K``) is cut into the chunks' rows, so that each filter gets its
        own, as in one process.

    Returns
    -------
    FleetResult
        Whose arrays are lazy dask arrays chunked like ``zs`` along the
        filters axis. Compute the fields together (:func:`compute`, or
        ``dask.compute(result.means, result.log_likelihood)``): each chunk's
        task then runs once.

    Raises
    ------
    ShapeError, ParameterError
        Before anything is scheduled: ``zs`` not 3-D, its K or dim_z not the
        template's, an unknown ``keep``, a ``dts`` entry that is not a finite
        number (the rule of :meth:`squkf.Fleet.predict`: any finite real number),
        a shared array argument as long as a chunk (a chunk's fleet would read
        it as per filter).
    """
    if not isinstance(fleet, Fleet):
        raise ParameterError(f"fleet must be a squkf.Fleet, got {type(fleet).__name__}")
    state, words = check_keep(keep)
    steps = records.STEP_RECORDS
    # an array in memory is read here, before anything is scheduled: text refused, masked entries NaN
    Z = zs if isinstance(zs, da.Array) else da.from_array(as_measurements(zs, "zs"))
    if Z.ndim != 3:
        raise ShapeError(f"zs must have 3 axes (filters, time, measurement), got shape {Z.shape}")
    K, T, m = Z.shape
    if any(math_nan(v) for v in (K, T, m)):
        raise ShapeError("zs has unknown chunk sizes; call zs.compute_chunk_sizes() first")
    if K != fleet.n_filters:
        raise ShapeError(f"zs has {K} series but the template fleet has {fleet.n_filters} filters")
    if m != fleet.dim_z:
        raise ShapeError(f"zs has measurements of length {m} but the fleet's dim_z is {fleet.dim_z}")
    if not np.issubdtype(Z.dtype, np.number) or np.issubdtype(Z.dtype, np.complexfloating):
        raise ShapeError(f"zs must hold real numbers, got dtype {Z.dtype}")
    fx_args, hx_args = model_kwargs(fx_args, "fx_args"), model_kwargs(hx_args, "hx_args")
    dts = per_step(
        dts, T, "dts", "dt", default=fleet.configuration().dt, ref="zs"
    )  # checked here, not in a task
    if len(Z.chunks[1]) > 1 or len(Z.chunks[2]) > 1:
        Z = Z.rechunk({1: -1, 2: -1})
    Z = da.ma.filled(Z.astype(float), np.nan)  # masked chunks: missing where masked, as Fleet.batch_filter
    for name, args in (("fx_args", fx_args), ("hx_args", hx_args)):
        checks.check_chunk_args(args, name, K, Z.chunks[0])
    n = fleet.dim_x
    blocks = Z.to_delayed().reshape(-1)
    fields: dict[str, list] = {f: [] for f in _fields()}
    lo = 0
    for block, size in zip(blocks, Z.chunks[0]):
        # each task carries only its chunk's filters (not the whole template): a worker holds a few chunks
        chunk = fleet.subset(slice(lo, lo + size))
        rows = slice(lo, lo + size)
        fx_rows, hx_rows = checks.chunk_args(fx_args, K, rows), checks.chunk_args(hx_args, K, rows)
        options = {"keep": keep, "dts": dts, "fx_args": fx_rows, "hx_args": hx_rows}
        part = dask.delayed(_run_chunk, pure=True)(chunk, block, options)
        shapes = {
            "means": (size, T, n),
            "P1_2s": (size, T, n, n),
            "variances": (size, T, n),
            "log_likelihood": (size,) if state == "final" else (size, T),
            "failed": (size,),
            "x": (size, n),
            "P1_2": (size, n, n),
            "rejected": (size, m) if state == "final" else (size, T, m),
            "nis": (size, T),
            **{r.name: r.shape((size, T), m) for r in steps},
        }
        dtypes = {"failed": bool, "rejected": np.int64 if state == "final" else bool}
        for name, shape in shapes.items():
            dtype = dtypes.get(name, float)
            fields[name].append(da.from_delayed(getattr(part, name), shape, dtype=dtype))
        lo += size
    stored = {
        "means": state != "final",
        "P1_2s": state == "all",
        "variances": state in ("all", "diagonals"),
        "nis": state != "final",
        **{r.name: r.keep in words for r in steps},
    }
    out: dict[str, Any] = {}
    for name, parts in fields.items():
        out[name] = da.concatenate(parts, axis=0) if stored.get(name, True) else None
    return FleetResult(**out)


def _fit_chunk(ukf, block: np.ndarray, options: dict) -> list:
    from .tune import fit_noise as fit_in_process

    fits = fit_in_process(ukf, block, shared=False, **options)
    assert isinstance(fits, list)  # (shared=False: one fit a recording)
    return fits


def fit_noise(ukf, zs, *, recordings_per_task: int = 1000, **options) -> list:
    """:func:`squkf.tune.fit_noise` with ``shared=False`` over a Dask cluster, a task per chunk of recordings.

    Each task fits its recordings together (one fleet pass an iteration, as
    in one process) on a worker; the fits are those of one process, bit for
    bit, whatever the chunking (each recording's fit reads only its own
    filters), apart from the counts of passes and filter-steps, which are
    each task's.

    Parameters
    ----------
    ukf : SquareRootUKF
        The template (pickled to the workers: its model functions must be
        importable there by name). Never changed.
    zs : array_like, shape (S, T, dim_z), or a list of S recordings
        Checked here, before anything is scheduled.
    recordings_per_task : int
        Recordings a task fits.
    **options
        Of :func:`squkf.tune.fit_noise` (``Q``, ``R``, ``burn_in``, ``bounds``,
        ``prior``, ``maxiter``, ``max_filters``, ``dts``, ``fx_args``,
        ``hx_args``); not ``shared`` or ``method``.

    Returns
    -------
    list of S :class:`~squkf.tune.NoiseFit`
        In the recordings' order, computed on the scheduler in use (a
        ``distributed.Client``'s, or dask's default).
    """
    from .candidates import check_template, recordings

    for name in ("shared", "method", "progress"):
        if name in options:
            raise ParameterError(
                f"squkf.dask.fit_noise fits each recording on its own: {name}= is not an option"
            )
    if (
        isinstance(recordings_per_task, bool)
        or not isinstance(recordings_per_task, int)
        or recordings_per_task < 1
    ):
        raise ParameterError(f"recordings_per_task must be a positive integer, got {recordings_per_task!r}")
    Z, _ = recordings(zs, ukf.configuration().dim_z)
    check_template(ukf, options.get("burn_in", 0), Z.shape[1])
    parts = [
        dask.delayed(_fit_chunk, pure=True)(ukf, Z[i : i + recordings_per_task], options)
        for i in range(0, Z.shape[0], recordings_per_task)
    ]
    return [fit for part in dask.compute(*parts) for fit in part]


def math_nan(v) -> bool:
    """Whether a dask shape entry is unknown (NaN)."""
    return isinstance(v, float) and v != v


def compute(result: FleetResult, **kwargs) -> FleetResult:
    """Compute every lazy field of ``result`` at once (each chunk's task runs once).

    Parameters
    ----------
    result : FleetResult
        From :func:`batch_filter`.
    **kwargs
        Passed to ``dask.compute`` (e.g. ``scheduler="synchronous"``).

    Returns
    -------
    FleetResult
        With numpy arrays.
    """
    names = _fields()
    lazy = {k: getattr(result, k) for k in names if getattr(result, k, None) is not None}
    values = dask.compute(*lazy.values(), **kwargs)
    done = dict(zip(lazy, values))
    return FleetResult(**{k: done.get(k) for k in names})  # type: ignore[arg-type]


def filter_frame(
    frame,
    fleet: Fleet,
    *,
    key: str,
    time: str,
    columns: Sequence[str],
    x0=None,
    P0=None,
    state_names: Sequence[str] | None = None,
):
    """Filter each series of a long-format dask dataframe; estimates out, aligned with the input.

    Parameters
    ----------
    frame : dask.dataframe.DataFrame
        One row per series and time step. Its index is the series key, sorted
        with known divisions (``frame.set_index(key)``, or read partitioned by
        the key), so that no series is split across partitions.
    key : str
        The name of the series key (the frame's index).
    fleet : Fleet
        The template: its configuration, noise (shared ``Q`` and ``R``) and
        filter 0's state as the default initial state.
    time : str
        The time column (each series is filtered in its order; the fleet's
        ``dt`` is the step).
    columns : sequence of str
        The measurement columns, ``dim_z`` of them, of float, integer or bool
        dtype (numpy's, or pandas' nullable ones); NaN (or ``NA``) means
        missing.
    x0 : callable ``key -> (dim_x,)`` or pandas.DataFrame, optional
        Initial states per series (a frame indexed by key with ``dim_x``
        columns); default filter 0's state of the template.
    P0 : callable ``key -> (dim_x, dim_x)`` or array_like, optional
        Initial covariances per series, or one for all; default filter 0's.
    state_names : sequence of str, optional
        Output column names (default ``x0, x1, ...``); the standard deviations
        are ``std_<name>``.

    Returns
    -------
    dask.dataframe.DataFrame
        With the input's index and row order per partition, the state columns,
        their standard deviations and ``failed``: whether the series' filter
        failed numerically (its estimates from then on repeat its last good
        state, as in :class:`squkf.FleetResult`).

    Raises
    ------
    ParameterError, ShapeError
        Before anything is scheduled: unknown divisions, missing columns, a
        wrong number of measurement columns, a measurement column of another
        dtype (text, objects, categories, dates, durations, complex numbers),
        shared noise required.
    """
    if not isinstance(frame, dd.DataFrame):
        raise ParameterError(f"frame must be a dask.dataframe.DataFrame, got {type(frame).__name__}")
    if not isinstance(fleet, Fleet):
        raise ParameterError(f"fleet must be a squkf.Fleet, got {type(fleet).__name__}")
    columns = list(columns)
    if len(columns) != fleet.dim_z:
        raise ShapeError(f"{len(columns)} measurement columns given but the fleet's dim_z is {fleet.dim_z}")
    missing = [c for c in [time, *columns] if c not in frame.columns]
    if missing:
        raise ParameterError(f"frame has no column(s) {missing}")
    for column in columns:  # the frame's dtypes are known without computing anything
        _check_measurement_dtype(column, frame.dtypes[column])
    if frame.index.name != key or not frame.known_divisions:
        raise ParameterError(
            "filter_frame needs the series key as a sorted index with known divisions, so that no "
            "series is split across partitions: use frame.set_index(key) (or set_index(key, sorted=True))"
        )
    if fleet.Q.ndim != 2 or fleet.R.ndim != 2:
        raise ParameterError("filter_frame needs a template fleet with shared Q and R")
    names = list(state_names) if state_names is not None else [f"x{i}" for i in range(fleet.dim_x)]
    if len(names) != fleet.dim_x:
        raise ShapeError(f"{len(names)} state names given but dim_x is {fleet.dim_x}")
    if isinstance(x0, pd.DataFrame) and x0.shape[1] != fleet.dim_x:
        raise ShapeError(f"x0 has {x0.shape[1]} columns but dim_x is {fleet.dim_x}")
    meta = pd.DataFrame(
        {
            **{c: pd.Series(dtype=float) for c in names},
            **{f"std_{c}": pd.Series(dtype=float) for c in names},
            "failed": pd.Series(dtype=bool),
        }
    )
    meta.index = frame._meta.index
    template = fleet.subset([0])
    return frame.map_partitions(
        _filter_partition, template, time, columns, x0, P0, names, meta=meta, align_dataframes=False
    )


def _check_measurement_dtype(column: str, dtype) -> None:
    """Refuse a measurement column whose dtype is not float, integer or bool (``filter_frame``'s rule).

    Converting any other column to float would fail in a task (text), or give
    numbers that mean something else (nanoseconds, category codes, a real part).
    """
    if getattr(dtype, "kind", "O") not in "fiub":
        raise ParameterError(
            f"measurement column {column!r} must hold real numbers (float, integer or bool), "
            f"got dtype {dtype}"
        )


def _initial(spec, key, default: np.ndarray, name: str) -> np.ndarray:
    if spec is None:
        return default
    if callable(spec):
        return np.asarray(spec(key), dtype=float)
    if isinstance(spec, pd.DataFrame):
        if key not in spec.index:
            raise ParameterError(f"{name} has no row for series {key!r}")
        return spec.loc[key].to_numpy(dtype=float)
    return np.asarray(spec, dtype=float)


def _filter_partition(
    part: pd.DataFrame,
    template: Fleet,
    time: str,
    columns: list[str],
    x0: Callable | pd.DataFrame | None,
    P0,
    names: list[str],
) -> pd.DataFrame:
    out = pd.DataFrame(np.nan, index=part.index, columns=names + [f"std_{c}" for c in names])
    out["failed"] = False
    if len(part) == 0:
        return out
    keys = part.index.to_numpy()
    uniq, inverse = np.unique(keys, return_inverse=True)
    # position of each row within its series, in time order
    pos = np.empty(len(part), dtype=int)
    t_order = np.lexsort((part[time].to_numpy(), inverse))
    counts = np.bincount(inverse, minlength=uniq.size)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    pos[t_order] = np.arange(len(part)) - np.repeat(starts, counts)
    K, T, m = uniq.size, int(counts.max()), len(columns)
    Z = np.full((K, T, m), np.nan)
    Z[inverse, pos] = part[columns].to_numpy(dtype=float)
    fleet = template.subset(np.zeros(K, dtype=int))
    x_default, P_default = template.x[0], template.P[0]
    fleet.x = np.stack([_initial(x0, k, x_default, "x0") for k in uniq])
    fleet.P = np.stack([_initial(P0, k, P_default, "P0") for k in uniq])
    res = fleet.batch_filter(Z, keep="diagonals")
    assert res.means is not None and res.variances is not None
    out[names] = res.means[inverse, pos]
    out[[f"std_{c}" for c in names]] = np.sqrt(res.variances[inverse, pos])
    out["failed"] = res.failed[inverse]
    return out
