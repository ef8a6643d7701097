"""Batch filtering over a sequence of measurements, and the per-step arguments it shares with the smoother.

Conventions for a per-step argument (``Rs``, ``Qs``, ``dts``, ``fx_args``,
``hx_args``, here and in :mod:`squkf.smoother`):

- ``None``: the filter's default at every step;
- one value for every step: a scalar or one matrix (an ndarray of 2
  dimensions) for ``Rs``/``Qs`` (a scalar ``r`` means ``r * I``), a number
  for ``dts``, a dict for ``fx_args``/``hx_args``;
- otherwise one entry per step: a list, a tuple, an ndarray (shape ``(T,)``
  of scalars or ``(T, d, d)`` of matrices for ``Rs``/``Qs``), or any other
  iterable, read in step with the measurements.

A per-step argument whose length differs from the number of measurements is a
:class:`~squkf.errors.ShapeError` naming it; when both lengths are known this
is found before any step is run, otherwise as soon as one runs out.
"""

from __future__ import annotations

import numbers
from collections.abc import Callable, Iterable, Mapping, Set, Sized
from typing import Any, cast

import numpy as np

from .boundary import records
from .boundary.loop import run_steps
from .boundary.records import BatchResult  # (defined with the per-step records; found here too)
from .checks import check_time_step, iter_measurements
from .errors import ParameterError, ShapeError

__all__ = ["batch_filter", "model_kwargs", "per_step"]

# predict()/update() take these themselves, so they cannot be passed through to fx/hx
_RESERVED = {"fx_args": ("dt", "UT", "fx", "Q"), "hx_args": ("z", "R", "UT", "hx")}
_END = object()


def _is_scalar(value) -> bool:
    return isinstance(value, numbers.Number) or (isinstance(value, np.ndarray) and value.ndim == 0)


def _check_kwargs(value, name: str, reserved: tuple[str, ...]) -> dict:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ParameterError(
            f"{name} must be a dict of keyword arguments (or None),"
            f" got {type(value).__name__}: {value!r:.100}"
        )
    for key in value:
        if not isinstance(key, str):
            raise ParameterError(f"{name} has the key {key!r}; keyword names must be strings")
        if key in reserved:
            raise ParameterError(
                f"{name} has the key {key!r}, which is an argument of the filter step itself,"
                f" not of the model function; give it as its own argument"
            )
    return dict(value)


def model_kwargs(value, name: str) -> dict:
    """``fx_args`` or ``hx_args`` given once for every step: a dict for the model function only.

    The one check of every front end (``SquareRootUKF``'s and ``Fleet``'s
    ``batch_filter`` and smoothers, :func:`squkf.dask.batch_filter`): the keys
    are passed to ``fx`` or ``hx`` and to nothing else, so a key that names an
    argument of the step itself (``dt``, ``UT``, ``fx``, ``Q`` for ``fx_args``;
    ``z``, ``R``, ``UT``, ``hx`` for ``hx_args``) is refused rather than taken
    as, say, the measurement noise.

    Parameters
    ----------
    value : None or mapping
    name : {"fx_args", "hx_args"}

    Returns
    -------
    dict
        A new dict (empty for None).

    Raises
    ------
    ParameterError
        ``value`` is not a mapping, a key is not a string, or a key is one of
        the step's own arguments.
    """
    return _check_kwargs(value, name, _RESERVED[name])


class _Steps:
    """One per-step argument: the same value at every step, or the ``k``-th entry of a sequence or iterable.

    Parameters
    ----------
    value : None, one value, sequence or iterable
    name : str
        The argument's name, for messages.
    kind : {"noise", "dt", "kwargs"}
    T : int or None
        The number of steps if known (checked against a sequence's length now).
    default : object
        The value of ``None`` at every step (already valid).
    ref : str
        What the steps are counted in, for messages (``"zs"`` or ``"Xs"``).
    """

    def __init__(self, value, name: str, kind: str, T: int | None, default=None, ref: str = "zs"):
        self.name, self.kind, self.ref = name, kind, ref
        self.const, self.seq, self.it = default, None, None
        self.n = 0  # the sequence's length; read only when seq is set
        if value is None:
            if kind == "kwargs":
                self.const = {}
            return
        if kind == "noise":
            if isinstance(value, np.ndarray) and value.ndim not in (0, 1, 2, 3):
                raise ShapeError(
                    f"{name} has shape {value.shape}: expected a scalar, one matrix (d, d),"
                    " or one per step, (T,) or (T, d, d)"
                )
            single = _is_scalar(value) or (isinstance(value, np.ndarray) and value.ndim == 2)
        elif kind == "dt":
            if isinstance(value, np.ndarray) and value.ndim > 1:
                raise ShapeError(f"{name} has shape {value.shape}: expected a number or one per step, (T,)")
            single = _is_scalar(value)
        else:
            single = isinstance(value, Mapping)
        if single:
            self.const = self._check(value, name)
            return
        if isinstance(value, (str, bytes, Mapping, Set)) or not isinstance(value, Iterable):
            raise ParameterError(f"{name} must be {self._what()}, got {type(value).__name__}: {value!r:.200}")
        if hasattr(value, "__len__") and hasattr(value, "__getitem__"):
            self.n = len(cast(Sized, value))  # it has __len__ (checked above)
            if T is not None and self.n != T:
                raise ShapeError(f"{name} has {self.n} entries but {ref} has {T}")
            # entries checked once, before any step (noise matrices are checked by the filter as used)
            if kind == "noise":
                self.seq = value
            else:
                self.seq = [self._check(v, f"{name}[{k}]") for k, v in enumerate(value)]
        else:
            self.it = iter(value)

    def _what(self) -> str:
        return {
            "noise": "None, a scalar, a matrix, or a sequence with one per step",
            "dt": "None, a number, or a sequence with one per step",
            "kwargs": "None, a dict, or a sequence of dicts with one per step",
        }[self.kind]

    def _check(self, value, name: str):
        if self.kind == "dt":
            return check_time_step(value, name)
        if self.kind == "kwargs":
            return _check_kwargs(value, name, _RESERVED.get(self.name, ()))
        return value

    def at(self, k: int):
        """The value for step ``k`` (an iterable is read once, in order)."""
        if self.seq is not None:
            if k >= self.n:
                raise ShapeError(f"{self.name} has {self.n} entries but {self.ref} has more")
            return self.seq[k]
        if self.it is not None:
            value = next(self.it, _END)
            if value is _END:
                raise ShapeError(f"{self.name} ran out after {k} entries but {self.ref} has more")
            return self._check(value, f"{self.name}[{k}]")
        return self.const

    def finish(self, T: int) -> None:
        """Check, after the last of ``T`` measurements, that no entries are left over."""
        if self.seq is not None and self.n != T:
            raise ShapeError(f"{self.name} has {self.n} entries but {self.ref} had {T}")
        if self.it is not None and next(self.it, _END) is not _END:
            raise ShapeError(f"{self.name} has more entries than the {T} in {self.ref}")

    def as_list(self, T: int) -> list:
        """All ``T`` values (for the smoother, which reads them backwards)."""
        values = [self.at(k) for k in range(T)]
        self.finish(T)
        return values


def per_step(value, T: int, name: str, kind: str, default=None, ref: str = "Xs") -> list:
    """Expand a per-step argument into a list of ``T`` validated values.

    Parameters
    ----------
    value : None, one value, sequence or iterable
        See the module docstring.
    T : int
        Number of steps.
    name : str
        Argument name, for messages.
    kind : {"noise", "dt", "kwargs"}
        ``Rs``/``Qs``-like, ``dts``-like or ``fx_args``-like.
    default : object, optional
        The value at every step when ``value`` is None.
    ref : str, optional
        The argument that fixes ``T``, for messages.

    Returns
    -------
    list of length T

    Raises
    ------
    ShapeError
        ``value`` does not have ``T`` entries.
    ParameterError
        ``value`` is of the wrong kind, or an entry is invalid (naming it, e.g. ``dts[3]``).
    """
    return _Steps(value, name, kind, T, default, ref).as_list(T)


class _Rows:
    """Rows of a result array collected as they come (the count may be unknown beforehand)."""

    def __init__(self, shape: tuple[int, ...], capacity: int | None):
        self.buf = np.empty((capacity if capacity is not None else 64, *shape))
        self.n = 0

    def append(self, row: np.ndarray) -> None:
        if self.n == self.buf.shape[0]:
            grown = np.empty((2 * self.n + 1, *self.buf.shape[1:]))
            grown[: self.n] = self.buf
            self.buf = grown
        self.buf[self.n] = row
        self.n += 1

    def result(self) -> np.ndarray:
        if self.n == self.buf.shape[0]:
            return self.buf
        return self.buf[: self.n].copy()


def _known_length(zs) -> int | None:
    if not hasattr(zs, "__len__"):
        return None
    try:
        n = len(zs)
    except TypeError:  # e.g. tqdm over a generator without a total
        return None
    return n if isinstance(n, int) else None


def _stack_rows(rows: list, width: int, dtype) -> np.ndarray:
    """Per-step records of one length each as ``(T, width)`` (a step of another size: object rows)."""
    if all(r.shape == (width,) for r in rows):
        return np.array(rows, dtype=dtype).reshape(len(rows), width)
    out = np.empty(len(rows), dtype=object)
    out[:] = rows
    return out


def batch_filter(
    ukf,
    zs: Iterable,
    Rs=None,
    dts=None,
    UT: Callable | None = None,
    saver=None,
    *,
    Qs=None,
    fx_args: Mapping[str, Any] | Iterable[Mapping[str, Any] | None] | None = None,
    hx_args: Mapping[str, Any] | Iterable[Mapping[str, Any] | None] | None = None,
    return_factors: bool = False,
    progress: bool | Callable[[int], object] = False,
) -> BatchResult:
    """Run ``predict`` and ``update`` over all measurements ``zs``.

    The same as a loop of ``ukf.predict(dt=dts[k], UT=UT, Q=Qs[k], **fx_args[k])``
    and ``ukf.update(zs[k], R=Rs[k], UT=UT, **hx_args[k])``, with filterpy's
    positional arguments and return values. The measurements are read one at a
    time, so ``zs`` may be a generator or a ``tqdm`` wrapper; the results are
    collected as they come.

    Parameters
    ----------
    ukf : SquareRootUKF
    zs : iterable of T measurements
        A list, tuple, array (one row per step), generator, ``tqdm(...)``...
        Each is a vector of shape ``(dim_z,)`` (or a scalar when ``dim_z == 1``);
        ``None`` or an all-NaN vector means no measurement at that step
        (predict only). Strings and dicts are rejected.
    Rs : None, scalar, ndarray of shape (dim_z, dim_z), or T entries, optional
        Measurement noise per step (default ``ukf.R``). A scalar ``r`` means
        ``r * I`` at every step; a 2-D array is the same matrix at every step;
        a list, a tuple, an array of shape ``(T,)`` or ``(T, dim_z, dim_z)``,
        or an iterable gives one per step (each a matrix or a scalar).
    dts : None, float, or T floats, optional
        Time step of the prediction into each step (default: the constructor's
        ``dt``), as :ref:`promise-dt` says; checked before the first step when
        ``dts`` is a sequence.
    UT : callable, optional
        Square-root transform (see :func:`squkf.sqrt_unscented_transform`).
    saver : filterpy.common.Saver, optional
        ``saver.save()`` is called after every step.
    Qs : None, scalar, ndarray of shape (dim_x, dim_x), or T entries, optional
        Process noise of the prediction into each step (default ``ukf.Q``),
        in the same forms as ``Rs``.
    fx_args, hx_args : None, dict, or T dicts (or None), optional
        Keyword arguments for ``fx`` and ``hx``: one dict for every step, or
        one per step. Keys must be strings and must not be the step's own
        arguments (``dt``, ``UT``, ``fx``, ``Q`` for ``fx_args``; ``z``, ``R``,
        ``UT``, ``hx`` for ``hx_args``).
    return_factors : bool, optional
        Return the lower factors ``P1_2`` instead of the covariances.
    progress : bool or callable, optional
        ``True`` shows a tqdm progress bar on stderr (needs the optional extra
        ``squkf[progress]``; without tqdm a :class:`~squkf.errors.ParameterError`
        is raised before any step is run). A callable is called as
        ``progress(k)`` after step ``k`` (0-based) has completed, including the
        ``saver``; an exception it raises fails step ``k`` like any other.
        Default False.

    Returns
    -------
    BatchResult
        The pair ``(means, covariances)``:

        - means : ndarray, shape (T, dim_x). Posterior means. ``T = 0`` (no
          measurements) gives shape ``(0, dim_x)`` and leaves the filter as it was.
        - covariances : ndarray, shape (T, dim_x, dim_x). Posterior covariances
          (or their lower factors with ``return_factors``).

        and, as attributes, ``rejected`` ``(T, dim_z)`` (what the filter's gate
        rejected at each step), ``nis`` ``(T,)`` and ``log_likelihood`` ``(T,)``.

    Raises
    ------
    ShapeError
        ``zs`` is not an ordered iterable of measurements (a string, a dict or
        a set is not), or a per-step argument does not have one entry per
        measurement (the message names it).
    ParameterError
        An option of the wrong kind, e.g. ``hx_args`` not a dict, a ``dts``
        entry that is not a finite number (a string among them), ``progress=True``
        without tqdm.
    SqukfError
        Any squkf error raised at step ``k`` (a bad measurement, a covariance
        that lost positive-definiteness, ...), with the same type and
        ``errno`` and its message starting with ``"at step k: "``.

    Notes
    -----
    If anything fails during the run, the filter is put back exactly as it
    was before the call, and the exception (whatever its type, including
    ``KeyboardInterrupt``) carries

    - ``exc.partial``: ``(means, covariances)`` as this function would return
      them, for the steps completed before the failure (shape ``(k, ...)``);
    - ``exc.step``: the step ``k`` that failed (``None`` when the failure is
      found after the last step, e.g. ``dts`` longer than a generator ``zs``).

    Exceptions that are not squkf's (for example raised by ``fx`` or ``hx``)
    keep their message; on Python 3.11+ they get a note naming the step.
    ``partial`` and ``step`` are not pickled with the exception.

    Examples
    --------
    ``None`` marks a step without a measurement; ``return_factors`` gives the
    lower factors of the covariances:

    >>> import numpy as np
    >>> from squkf import MerweScaledWeights, SquareRootUKF
    >>> F = np.array([[1.0, 1.0], [0.0, 1.0]])
    >>> ukf = SquareRootUKF(
    ...     2, 1, 1.0, hx=lambda x: x[:1], fx=lambda x, dt: F @ x, points=MerweScaledWeights()
    ... )
    >>> ukf.Q, ukf.R = np.diag([0.01, 0.01]), [[0.25]]
    >>> zs = [[1.1], [1.9], None, [3.9], [5.1]]
    >>> means, covs = ukf.batch_filter(zs)
    >>> print(np.round(means, 4))
    [[0.9783 0.4867]
     [1.8145 0.7188]
     [2.5332 0.7188]
     [3.8137 0.9172]
     [4.9662 0.9901]]
    >>> ukf.x, ukf.P = np.zeros(2), np.eye(2)
    >>> means2, P1_2s = ukf.batch_filter(zs, return_factors=True)
    >>> bool(np.allclose(means2, means)), bool(np.allclose(P1_2s @ np.swapaxes(P1_2s, 1, 2), covs))
    (True, True)

    ``Qs[k]`` is the process noise of the prediction into step ``k``:

    >>> ukf.x, ukf.P = np.zeros(2), np.eye(2)
    >>> Qs = [np.diag([0.01, 0.01])] * 2 + [np.eye(2)] + [np.diag([0.01, 0.01])] * 2
    >>> means, covs = ukf.batch_filter(zs, Qs=Qs)
    >>> print(np.round(np.sqrt(covs[:, 0, 0]), 4))
    [0.4715 0.4481 1.2974 0.4835 0.4488]
    """
    it = iter_measurements(zs)
    T = _known_length(zs)
    if UT is not None and not callable(UT):
        raise ParameterError(f"UT must be a callable (or None), got {UT!r}")
    if saver is not None and not callable(getattr(saver, "save", None)):
        raise ParameterError(f"saver must have a save() method (a filterpy Saver), got {saver!r}")
    if not isinstance(return_factors, (bool, np.bool_)):
        raise ParameterError(f"return_factors must be True or False, got {return_factors!r}")
    steps = [
        _Steps(Rs, "Rs", "noise", T),
        _Steps(Qs, "Qs", "noise", T),
        _Steps(dts, "dts", "dt", T),
        _Steps(fx_args, "fx_args", "kwargs", T),
        _Steps(hx_args, "hx_args", "kwargs", T),
    ]
    R_k, Q_k, dt_k, fx_k, hx_k = steps
    n = ukf.dim_x
    means = _Rows((n,), T)
    covs = _Rows((n, n), T)
    rejected: list[np.ndarray] = []
    nis: list[float] = []
    loglik: list[float] = []
    kept = records.STEP_RECORDS  # (the per-step records: each step's value, or of nothing measured)
    rows: list[list] = [[] for _ in kept]

    def step(k: int, z) -> None:
        ukf.predict(dt=dt_k.at(k), UT=UT, Q=Q_k.at(k), **fx_k.at(k))
        ukf.update(z, R=R_k.at(k), UT=UT, **hx_k.at(k))
        measured = ukf.z.dtype != object  # update(None) leaves filterpy's column of Nones
        # a step's own records: of nothing measured, nothing rejected and NIS 0
        rejected.append(ukf.rejected if measured else np.zeros(ukf.dim_z, dtype=bool))
        nis.append(ukf.nis if measured else 0.0)
        loglik.append(ukf.log_likelihood if measured else 0.0)
        for r, got in zip(kept, rows):
            got.append(getattr(ukf, r.name) if measured else r.missing(ukf.dim_z))
        means.append(ukf.x)
        S = ukf.P1_2
        covs.append(S if return_factors else S @ S.T)
        if saver is not None:
            saver.save()

    def finish(T: int) -> None:  # (a per-step argument longer than a generator's zs)
        for s in steps:
            s.finish(T)

    def partial(k: int) -> tuple[np.ndarray, np.ndarray]:
        return means.result()[:k], covs.result()[:k]

    try:
        run_steps(ukf.transaction(), it, step, partial, progress, T, finish)
    finally:
        if it is not zs and hasattr(it, "close"):  # an iterator we made, e.g. tqdm's: let it finish
            it.close()
    m = ukf.dim_z
    return BatchResult(
        means.result(), covs.result(), _stack_rows(rejected, m, bool), np.array(nis), np.array(loglik),
        *(_stack_rows(got, m, float) if r.per_component else np.array(got) for r, got in zip(kept, rows)),
    )  # fmt: skip
