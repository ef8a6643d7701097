"""Every check of what a caller hands squkf, each written once, for one filter and for a stack.

What the callers and their functions hand to the filter crosses into the core
through here:

- single values: an array of reals (:func:`as_float_array`), measurements
  (:func:`as_measurements`, masked entries missing), a time step
  (:func:`check_time_step`), the images of the model functions
  (:func:`check_values`, per-point values of a near shape included), what a
  user's hook returns (:func:`check_hook_result`), a function or a flag given
  (:func:`check_callable`, :func:`check_flag`), and the wording of a value that
  is not finite (:func:`describe_nonfinite`);
- a call's inputs, for one filter (batch shape ``()``) and for a stack
  (``(K,)``): sizes, states, measurements and the series ``zs``
  (:func:`iter_measurements`), model functions' arguments and images, and
  every covariance or factor the caller gives, as its lower factor (shared or
  per filter, factored once by :func:`squkf.linalg.factor_covariance`; the step
  itself only ever sees factors; a per-filter value's messages name the
  filter, ``R[3]``): :func:`as_matrix`, :func:`as_lower_factor` and the
  functions built on them.

Each raises a specific :mod:`squkf.errors` exception naming the argument (or
the function) and the value; none keeps a reference to its input. The module
imports only the errors, :mod:`squkf.linalg` and the kernels' ``finite_rows``,
so every layer above checks through it; how a configuration's parts fit each
other (the family, the second set, the noise entering the model) is checked by
:mod:`squkf.boundary.config`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Set

import numpy as np

from .errors import (
    NonFiniteError,
    NotPositiveDefiniteError,
    ParameterError,
    ShapeError,
    SqukfError,
    SqukfValueError,
)
from .kernels import wrappers
from .kernels.table import KernelTable
from .linalg import all_finite, factor_covariance

_FLOAT64 = np.dtype(np.float64)  # numpy's native float64 dtype is one object: compared by identity

__all__ = [
    "as_float_array",
    "as_measurements",
    "check_callable",
    "check_flag",
    "check_time_step",
    "check_values",
    "point_value",
    "describe_nonfinite",
    "check_hook_result",
    "call_hook",
    "note_on_user_error",
    "short_repr",
    "REAL",
    "as_lower_factor",
    "as_matrix",
    "lower_factor_stack",
    "symmetric_stack",
    "as_state",
    "check_chunk_args",
    "check_sizes",
    "chunk_args",
    "covariance_factors",
    "evaluate",
    "finite_images",
    "given_noise_factors",
    "is_per_filter",
    "iter_measurements",
    "lower_factors",
    "measurement",
    "measurement_series",
    "measurements",
    "model_function",
    "model_functions",
    "noise_factor",
    "noise_factors",
    "note_stack_call",
    "per_filter",
    "placeholder",
    "written_record",
    "refuse_noise_args",
    "refuse_smoother_noise",
    "reset_rows",
    "stack_call_note",
    "stacked_shape",
    "with_filter_axis",
]


def as_float_array(value, name: str, bools: bool = True) -> np.ndarray:
    """``value`` as a new float64 array; complex or non-numeric input is an error.

    Parameters
    ----------
    value : array_like
    name : str
        Used in the error message.
    bools : bool
        Whether booleans are read as numbers (0 and 1), as numpy reads them
        (the default); False refuses them, in an array or among numbers.

    Returns
    -------
    ndarray, float64, a private copy

    Raises
    ------
    ShapeError
        ``value`` is not a real numeric array (complex, strings, ragged, objects).
        Text is refused in every form, numeric text (``"1.0"``) and an object
        array holding some included; with ``bools=False``, booleans too.
    NonFiniteError
        ``value`` holds a number beyond float64's range (a Python integer
        such as ``10**400``), which would be infinite.
    """
    kinds = "fiub" if bools else "fiu"
    if isinstance(value, np.ndarray) and value.dtype.kind in kinds:
        return np.array(value, dtype=float)
    if not bools and isinstance(value, (list, tuple)) and _holds_bool(value):
        # before numpy, which reads [True, 2.0] as [1.0, 2.0]
        raise _bool_error(name, value)
    try:
        probe = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name} could not be read as a real float array: {exc}") from None
    if probe.dtype is _FLOAT64 and isinstance(value, (list, tuple)):
        return probe  # built from a list: already a new array (per-point images), no second copy
    if probe.dtype.kind == "c":
        raise ShapeError(f"{name} is complex ({probe.dtype}); squkf works in real float64")
    if probe.dtype.kind == "b" and not bools:
        raise _bool_error(name, value)
    if probe.dtype.kind not in "fiub":
        if probe.dtype.kind == "O" and not any(isinstance(v, (str, bytes)) for v in probe.flat):
            if not bools and any(isinstance(v, (bool, np.bool_)) for v in probe.flat):
                raise _bool_error(name, value)
            # objects that are numbers (None, Fractions, 0-d arrays): read as floats; text never,
            # not even "1.0", which numpy's astype(float) would parse
            try:
                return as_float_array(probe.astype(float), name)
            except OverflowError:
                raise NonFiniteError(_too_large(probe, name)) from None
            except (TypeError, ValueError):
                pass
        raise ShapeError(f"{name} could not be read as a real float array (dtype {probe.dtype}): {value!r}")
    return np.array(probe, dtype=float)


def _holds_bool(value: list | tuple) -> bool:
    """Whether a (nested) list or tuple holds a bool, or a bool array (arrays are not walked)."""
    for v in value:
        if type(v) is float:  # the usual entry: nothing to look into
            continue
        if isinstance(v, (list, tuple)):
            if _holds_bool(v):
                return True
        elif isinstance(v, (bool, np.bool_)) or (isinstance(v, np.ndarray) and v.dtype.kind == "b"):
            return True
    return False


def _bool_error(name: str, value) -> ShapeError:
    return ShapeError(f"{name} holds booleans ({short_repr(value)}): it takes numbers, not True or False")


def _too_large(probe: np.ndarray, name: str) -> str:
    """What is said of an object array holding a number beyond float64's range (a huge Python int)."""
    for v in probe.flat:
        try:
            float(v)
        except OverflowError:
            return (
                f"{name} holds {short_repr(v)}, beyond float64's largest number"
                f" ({np.finfo(float).max:.4g}): it would be infinite"
            )
        except (TypeError, ValueError):
            continue
    return f"{name} holds a number beyond float64's largest: it would be infinite"


def short_repr(value, limit: int = 60) -> str:
    """``repr(value)``, cut short for a message: a huge integer by its first digits and length.

    Parameters
    ----------
    value : object
    limit : int
        The longest text kept whole.

    Returns
    -------
    str
    """
    text = repr(value)
    if len(text) <= limit:
        return text
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        digits = len(str(abs(int(value))))
        return f"{text[:12]}... (an integer of {digits} digits)"
    return text[: limit - 3] + "..."


def as_measurements(value, name: str) -> np.ndarray:
    """Measurements as a new float64 array, masked entries (``numpy.ma``) as NaN: missing.

    The one reading of measurements for every route (``update``, the batch
    filters, :func:`squkf.dask.batch_filter`): a masked entry means missing,
    as NaN does, whatever value it hides.

    Parameters
    ----------
    value : array_like or numpy.ma.MaskedArray
    name : str
        Used in the error message.

    Returns
    -------
    ndarray, float64, a private copy

    Raises
    ------
    ShapeError
        As :func:`as_float_array` (the data of a masked array is read the same way);
        booleans (a bool array, or ``True``/``False`` among the numbers) too:
        a measurement of ``True`` is a mistake, not the number 1.
    NonFiniteError
        As :func:`as_float_array`: a number beyond float64's range.
    """
    if isinstance(value, np.ma.MaskedArray):
        data = as_float_array(np.ma.getdata(value), name, bools=False)
        mask = np.ma.getmaskarray(value)
        if mask.shape != data.shape:
            mask = np.broadcast_to(mask, data.shape)
        data[mask] = np.nan
        return data
    return as_float_array(value, name, bools=False)


def check_values(
    values, shape: tuple[int, ...], name: str, private: bool = True, finite: bool = True
) -> np.ndarray:
    """Validate the images of a sigma-point set returned by the caller.

    Parameters
    ----------
    values : array_like or list
        What the model function returned (or the caller told): one array
        ``shape`` (``(N, d, 1)`` and, for ``d == 1``, ``(N,)`` are taken too),
        or, from the per-point route, a list of ``N`` values, each read by
        :func:`point_value`.
    shape : tuple (..., N, d)
        Expected shape: one row per sigma point (after any batch axes).
    name : str
        Used in the error message.
    private : bool
        Return a private copy (the default). With False a float64 array is
        returned as it is (maybe the caller's own): for values read within
        the call only, never kept.
    finite : bool
        Refuse values that are not finite (the default); False leaves that to
        the caller (a kernel that reports it per filter).

    Returns
    -------
    values : ndarray, shape ``shape``, float64
        A private copy, unless ``private=False`` and ``values`` was already
        a float64 array: then ``values`` itself.

    Raises
    ------
    ShapeError, NonFiniteError
    """
    if not private and type(values) is np.ndarray and values.dtype is _FLOAT64:
        arr = values
    else:
        try:
            arr = as_float_array(values, name)
        except ShapeError:
            if not _one_per_point(values, shape):
                raise
            arr = None  # per-point values of different shapes (ragged): read one by one below
    if arr is None or arr.shape != shape:
        arr = _as_rows(values, arr, shape, name)
    if finite and not all_finite(arr):
        raise NonFiniteError(describe_nonfinite(arr, name))
    return arr


def _one_per_point(values, shape: tuple[int, ...]) -> bool:
    """Whether ``values`` is a list of one filter's per-point values (``shape`` is ``(N, d)``)."""
    return isinstance(values, (list, tuple)) and len(shape) == 2 and len(values) == shape[0]


def _as_rows(values, arr: np.ndarray | None, shape: tuple[int, ...], name: str) -> np.ndarray:
    """``values`` (read as ``arr``, None if ragged) of a shape other than ``shape``, as ``shape``.

    Called only when ``values`` did not stack to ``shape``: per-point values
    that are rows ``(d,)`` cost nothing more than the stacking.
    """
    if arr is not None and (arr.shape == shape + (1,) or (shape[-1] == 1 and arr.shape == shape[:-1])):
        # column vectors, or scalars for a 1-d measurement
        return arr.reshape(shape)
    if _one_per_point(values, shape):
        return np.stack([point_value(v, shape[-1], name, i) for i, v in enumerate(values)])
    assert arr is not None
    raise ShapeError(f"{name} has shape {arr.shape}, expected {shape} (one row per sigma point)")


def point_value(value, d: int, name: str, i: int) -> np.ndarray:
    """One sigma point's model value as a row ``(d,)``: the per-point rule.

    numpy's rule for ``rows[i] = value`` (filterpy's), less its silent
    broadcast of a single number: a value of shape ``(d,)``, ``(1, d)`` or
    any other with leading axes of length 1, or a column ``(d, 1)``; a scalar
    or a one-element array only when ``d == 1``.

    Parameters
    ----------
    value : array_like
        What the model function returned at sigma point ``i``.
    d : int
        Length of a row (``dim_x`` for ``fx``, the measurement's for ``hx``).
    name : str
        The values' name (``"fx values"``), for the message.
    i : int
        The sigma point, for the message.

    Returns
    -------
    ndarray, shape (d,), float64

    Raises
    ------
    ShapeError
        Any other shape; not real numbers.
    """
    arr = as_float_array(value, f"{name} at sigma point {i}")
    if arr.size == d and (d == 1 or arr.shape[-1] == d or arr.shape == (d, 1)):
        return arr.reshape(d)
    raise ShapeError(
        f"{name} at sigma point {i} has shape {arr.shape}, expected ({d},): per point a model function"
        f" returns a row ({d},), (1, {d}) or a column ({d}, 1)"
        + (", not a single number" if arr.size == 1 else "")
    )


def describe_nonfinite(values: np.ndarray, name: str) -> str:
    """What is said of images that are not finite: the first such entry, by sigma point and column.

    The one wording for a single filter (``values`` of shape ``(N, d)``) and
    for one filter of a fleet (its own rows, ``values[k]``), so that a fleet's
    ``failure`` reads as the single filter's error; for a stack ``(..., N, d)``
    the filter's index is added.

    Parameters
    ----------
    values : ndarray, shape (..., N, d), holding at least one NaN or inf
    name : str
        What the values are (``"fx values"``), for the message.

    Returns
    -------
    str
    """
    idx = tuple(int(i) for i in np.argwhere(~np.isfinite(values))[0])
    return (
        f"{name} is not finite: row {idx[-2]} (sigma point {idx[-2]}), column {idx[-1]} holds {values[idx]}"
        + (f" (filter {idx[:-2]})" if len(idx) > 2 else "")
    )


def check_hook_result(value, shape: tuple[int, ...], hook: str) -> np.ndarray:
    """Validate what a user's hook returned: its shape and that it is finite.

    Parameters
    ----------
    value : array_like
        The hook's return value.
    shape : tuple
        The shape it must have (a ``(1,)`` result may also be a scalar).
    hook : str
        The hook's name (``"state_add"``, ``"residual_x"``, ...), for the message.

    Returns
    -------
    ndarray, shape ``shape``, float64, a private copy

    Raises
    ------
    ShapeError, NonFiniteError
    """
    arr = as_float_array(value, f"what {hook} returned")
    if arr.shape != shape:
        if arr.size == int(np.prod(shape)) and (arr.ndim <= 1 or arr.shape == shape + (1,)):
            arr = arr.reshape(shape)
        else:
            raise ShapeError(f"{hook} returned shape {arr.shape}, expected {shape}")
    if not all_finite(arr):
        raise NonFiniteError(f"{hook} returned a non-finite value: {arr!r}")
    return arr


def call_hook(fn: Callable, args: tuple, shape: tuple[int, ...], hook: str) -> np.ndarray:
    """Call a user's hook and validate its result (see :func:`check_hook_result`)."""
    return check_hook_result(fn(*args), shape, hook)


def check_time_step(dt, name: str = "dt") -> float:
    """A time step as a float: any finite real number, the one rule of every route.

    ``SquareRootUKF.predict``, ``Fleet.predict``, the ``dts`` of every
    ``batch_filter`` and ``rts_smoother`` (single filter, fleet, and
    :func:`squkf.dask.batch_filter`) and the constructors' ``dt`` all take a
    time step through here. As in filterpy, a step may have any sign: ``0`` is
    a step of zero length (``fx(x, 0)``) and a negative ``dt`` is passed to
    ``fx`` as it is (a step backwards in time, if the model allows it).

    Parameters
    ----------
    dt : float
        A real number (a Python or numpy number, or a 0-d real array).
    name : str
        The argument, for the message (``"dt"``, ``"dts[3]"``).

    Returns
    -------
    float

    Raises
    ------
    ParameterError
        ``dt`` is a string (numeric or not), a bool, complex, not a number,
        NaN, infinite, or beyond float64's range (``10**400``).
    """
    if isinstance(dt, (str, bytes)) or (isinstance(dt, np.ndarray) and dt.dtype.kind not in "fiub"):
        # before float(), which would read "0.1" as a number
        raise ParameterError(f"{name} must be a finite number, got {name}={dt!r} ({type(dt).__name__})")
    if isinstance(dt, (bool, np.bool_)) or (isinstance(dt, np.ndarray) and dt.dtype.kind == "b"):
        # before float(), which would read True as a step of 1
        raise ParameterError(f"{name} must be a finite number, not a bool: got {name}={dt!r}")
    if np.iscomplexobj(dt):  # before float(), which would drop the imaginary part with a warning
        raise ParameterError(f"{name} must be a finite real number, got {name}={dt!r}")
    try:
        value = float(dt)
    except OverflowError:
        raise ParameterError(
            f"{name} must be a finite number, got {name}={short_repr(dt)}: beyond float64's range"
        ) from None
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a finite number, got {name}={short_repr(dt)}") from None
    if not math.isfinite(value):
        raise ParameterError(f"{name} must be a finite number, got {name}={short_repr(dt)}")
    return value


def check_callable(value, name: str, optional: bool = True, why: str = ""):
    """A model function or hook as given: callable, or None where ``optional``.

    Parameters
    ----------
    value : callable or None
    name : str
        The argument, for the message (``"fx"``, ``"residual_z"``).
    optional : bool
        Whether None is taken (filterpy's placeholder, or a hook's default).
    why : str
        Why it is needed, for the message (``"a fleet needs fx and hx"``).

    Returns
    -------
    callable or None
        ``value`` itself.

    Raises
    ------
    ParameterError
        ``value`` is neither callable nor (where taken) None.
    """
    if value is None and optional:
        return value
    if not callable(value):
        what = "a callable or None" if optional else "a callable"
        raise ParameterError(
            f"{name} must be {what}, got {name}={short_repr(value)} ({type(value).__name__})"
            + (f": {why}" if why else "")
        )
    return value


def check_flag(value, name: str) -> bool:
    """An option that is on or off (``vectorized``): ``True`` or ``False``, a numpy bool too.

    Parameters
    ----------
    value : bool
    name : str
        The argument, for the message.

    Returns
    -------
    bool

    Raises
    ------
    ParameterError
        Anything else: ``"no"`` is not False, nor is ``0`` read as it.
    """
    if not isinstance(value, (bool, np.bool_)):
        raise ParameterError(f"{name} must be True or False, got {name}={short_repr(value)}")
    return bool(value)


def note_on_user_error(exc: BaseException, note: str) -> None:
    """Add ``note`` to an exception a user's function raised, which then propagates unchanged.

    The exception stays the same object, of the same type and message; on
    Python >= 3.11 its traceback shows ``note`` (``add_note``). squkf's own
    exceptions, which say what they mean, get none.

    Parameters
    ----------
    exc : BaseException
    note : str
        How squkf called the function (the shapes it gave it).
    """
    if not isinstance(exc, SqukfError) and hasattr(exc, "add_note"):
        exc.add_note(note)


def check_sizes(**sizes) -> tuple[int, ...]:
    """The sizes given (``dim_x``, ``dim_z``, ``n_filters``), each a positive integer.

    Parameters
    ----------
    **sizes : int
        Name and value, in the order they are checked.

    Returns
    -------
    tuple of int
        The values as Python integers, in the order given.

    Raises
    ------
    ParameterError
        A value is not an integer (a bool is not), or is below 1.
    """
    for name, v in sizes.items():
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ParameterError(f"{name} must be a positive integer, got {name}={v!r}")
    return tuple(int(v) for v in sizes.values())


class _Real:
    """What :func:`placeholder` returns for a value that is not a placeholder (one object, by ``is``)."""

    __slots__ = ()

    def __repr__(self) -> str:
        return "REAL"


REAL = _Real()


def placeholder(value, name: str, shape: tuple[int, ...]):
    """A placeholder for ``x`` or ``P`` not set yet (``None``, or an array all NaN), as programs write.

    Parameters
    ----------
    value : object
        What is assigned.
    name : str
        For messages.
    shape : tuple of int
        The attribute's shape, ``(n,)`` (a column ``(n, 1)`` is taken too) or ``(n, n)``.

    Returns
    -------
    None, ndarray or REAL
        ``None`` for ``None``; a copy of an all-NaN array (``shape``, as
        given); :data:`REAL` for anything else, which the attribute's own
        validation then reads (a partly NaN array is its NonFiniteError).

    Raises
    ------
    ShapeError
        An all-NaN array of another shape.
    """
    if value is None:
        return None
    if isinstance(value, np.ndarray) and value.dtype.kind != "f":
        return REAL  # (only a float array holds NaN: an integer state is converted once, by its setter)
    A = as_float_array(value, name)
    if A.size == 0 or not math.isnan(A.flat[0]) or not np.isnan(A).all():
        return REAL
    if A.shape != shape and not (len(shape) == 1 and A.shape == shape + (1,)):
        raise ShapeError(f"{name} is a placeholder (all NaN) of shape {A.shape}, expected {shape}")
    return A.copy()


def written_record(value, name: str, ndim: int) -> np.ndarray:
    """A record a program writes (``x_prior``, ``S``, ``sigmas_f``, ...), as the private copy kept.

    Parameters
    ----------
    value : array_like
    name : str
        The record's name, for messages.
    ndim : int
        The record's number of axes (1 for a vector, 2 for a matrix or a set of points).

    Returns
    -------
    ndarray, float64, a copy (NaN and inf kept: a record is read back, not stepped from)

    Raises
    ------
    ShapeError
        ``value`` has another number of axes.
    """
    A = np.array(as_float_array(value, name), dtype=np.float64)
    if A.ndim != ndim:
        want = "a vector" if ndim == 1 else "a matrix"
        raise ShapeError(f"{name} must be {want} ({ndim}-D), got shape {A.shape}")
    return A


def model_functions(optional: bool, **functions) -> None:
    """The model functions and hooks a constructor was given, each callable (or None where taken).

    Parameters
    ----------
    optional : bool
        Whether ``fx`` and ``hx`` may be None (filterpy's placeholder, a
        function given per call: one filter), or are needed (a fleet).
        The hooks and ``sqrt_fn`` may always be None.
    **functions : callable or None
        Name (the constructor's argument) and value, checked in order.

    Raises
    ------
    ParameterError
        A value that is neither callable nor (where taken) None, naming it.
    """
    for name, fn in functions.items():
        needed = not optional and name in ("fx", "hx")
        check_callable(fn, name, not needed, "a fleet needs fx and hx" if needed else "")


def model_function(given, own, name: str, call: str, per_call: bool = True) -> Callable:
    """The model function of a call: the one ``given`` to it, else the filter's ``own``.

    Parameters
    ----------
    given : callable or None
        The call's (``predict(fx=...)``).
    own : callable or None
        The filter's (None: filterpy's placeholder, never set).
    name : {"fx", "hx"}
    call : str
        The call, for the message (``"predict"``, ``"rts_smoother"``).
    per_call : bool
        Whether ``call`` takes the function as an argument (said in the message).

    Returns
    -------
    callable

    Raises
    ------
    ParameterError
        Neither is callable: nothing was changed.
    """
    if given is not None:
        return check_callable(given, name, optional=False)
    if own is None:
        how = f"pass {call}({name}=...) or assign" if per_call else "assign"
        raise ParameterError(
            f"{call} needs {name}, but the filter's {name} is None (never set):"
            f" {how} a function to ukf.{name}"
        )
    return own


def as_state(value, name: str, dim: int) -> np.ndarray:
    """One filter's state, shape ``(dim,)`` (a column ``(dim, 1)`` is taken too), finite.

    Parameters
    ----------
    value : array_like, shape (dim,) or (dim, 1)
    name : str
        For messages.
    dim : int

    Returns
    -------
    x : ndarray, shape (dim,)
    """
    x = as_float_array(value, name)
    if x.shape not in ((dim,), (dim, 1)):
        raise ShapeError(f"{name} has shape {x.shape}, expected ({dim},)")
    x = x.reshape(dim)
    if not np.all(np.isfinite(x)):
        raise NonFiniteError(f"{name} contains NaN or inf: {x!r}")
    return x


def per_filter(value, name: str, K: int, shape: tuple[int, ...], placeholders: bool = False):
    """``value`` as ``(K, *shape)``: one value broadcast to every filter, or one per filter; finite.

    Parameters
    ----------
    value : array_like, shape ``shape`` or ``(K, *shape)``
    name : str
        For messages.
    K : int
        Number of filters.
    shape : tuple of int
        One filter's shape, ``(n,)`` for a state, ``(n, n)`` for a factor.
    placeholders : bool
        Accept a filter's value all NaN, a placeholder for a value not set
        yet (``Fleet.x``, ``Fleet.P``).

    Returns
    -------
    ndarray, shape (K, *shape)
        A new array.
    unset : ndarray of bool, shape (K,)
        With ``placeholders`` only: the filters whose value is all NaN.
    """
    a = as_float_array(value, name)
    if a.shape == shape:
        a = np.broadcast_to(a, (K,) + shape).copy()
    if a.shape != (K,) + shape:
        raise ShapeError(f"{name} has shape {a.shape}, expected {shape} or {(K,) + shape}")
    unset = np.zeros(K, dtype=bool)
    if not np.all(np.isfinite(a)):
        rows = a.reshape(K, -1)
        if placeholders:
            unset = np.isnan(rows).all(axis=1)
        bad = np.flatnonzero(~np.isfinite(rows).all(axis=1) & ~unset)
        if bad.size:
            raise NonFiniteError(f"{name} contains NaN or inf (filters {bad[:10].tolist()})")
    return (a, unset) if placeholders else a


def measurement(
    z, R, dim_z: int, R_dim: Callable[[], int], hx_noise: int
) -> tuple[np.ndarray, np.ndarray | None] | None:
    """One filter's measurement ``z`` checked, as ``(z, observed)``; None when it holds none.

    Parameters
    ----------
    z : array_like, shape (m,), (1, m), (m, 1) or scalar, or None
        NaN (or masked) components are missing; inf is an error.
    R : object or None
        This call's measurement noise (only whether it is given is read).
    dim_z : int
        The filter's measurement size.
    R_dim : callable
        The size of the filter's own ``R``, asked only for a ``z`` of another
        length given without ``R``.
    hx_noise : int
        Dimension of the noise entering ``hx`` (0: additive).

    Returns
    -------
    (z, observed) or None
        ``z`` of shape ``(m,)``; ``observed`` the mask of the measured
        components, or None when all are.
    """
    if z is None:
        return None
    if type(z) is np.ndarray and z.dtype is _FLOAT64 and z.shape == (dim_z,):  # the usual z: read as it is
        arr = z.copy()
        s = np.vdot(arr, arr)  # a NaN or an infinity makes it NaN or inf (and so may a huge value)
        if math.isfinite(s):
            return arr, None
    else:
        arr = as_measurements(z, "z")
    if arr.ndim != 1:
        if arr.ndim == 0:
            arr = arr.reshape(1)
        elif arr.ndim == 2 and 1 in arr.shape:
            arr = arr.reshape(-1)
        else:
            raise ShapeError(f"z has shape {np.shape(z)}, expected ({dim_z},)")
    observed = None
    if not all_finite(arr):
        finite = np.isfinite(arr)
        nan = np.isnan(arr)
        if not (finite | nan).all():
            raise NonFiniteError(f"z contains inf (NaN means a missing component): {arr!r}")
        if nan.all():
            return None
        observed = ~nan
    if R is None and arr.shape[0] != dim_z and not hx_noise:
        Rdim = R_dim()
        if Rdim != arr.shape[0]:
            raise ShapeError(
                f"z has length {arr.shape[0]} but dim_z is {dim_z} and R is {Rdim}x{Rdim};"
                " pass R= (and hx=) for a measurement of another size"
            )
    return arr, observed


def measurements(z, K: int, m: int, name: str = "z") -> np.ndarray:
    """One step's measurements of ``K`` filters, ``(K, m)`` (``(K,)`` too when ``m`` is 1).

    Parameters
    ----------
    z : array_like, shape (K, m)
        NaN rows: no measurement for that filter; NaN (or masked) entries
        are missing components; inf is an error.
    K, m : int
        Number of filters and measurement size.
    name : str
        For messages (``zs[3]`` for a step of a run).

    Returns
    -------
    ndarray, shape (K, m)
    """
    if z is None:
        raise ShapeError(
            f"{name} is None: a fleet's step needs a ({K}, {m}) array"
            " (NaN rows for filters without a measurement)"
        )
    if type(z) is np.ndarray and z.dtype == np.float64 and z.shape == (K, m):
        zz = z  # (the usual step: read as it is; each chunk copies its rows, checked again as read)
    else:
        zz = as_measurements(z, name)
    if zz.shape == (K,) and m == 1:
        zz = zz[:, None]
    if zz.shape != (K, m):
        raise ShapeError(f"{name} has shape {zz.shape}, expected ({K}, {m})")
    if np.isinf(zz).any():
        k = int(np.flatnonzero(np.isinf(zz).any(axis=1))[0])
        raise NonFiniteError(f"{name} contains inf (row {k}; NaN means a missing component)")
    return zz


def iter_measurements(zs) -> Iterator:
    """An iterator over the steps of ``zs``, after checking that ``zs`` is an ordered iterable.

    The one check of what ``zs`` itself may be, for ``SquareRootUKF.batch_filter``
    and ``Fleet.batch_filter`` alike; what each step yields is checked by the
    filter, naming the step.

    Parameters
    ----------
    zs : iterable
        A list, a tuple, an array (one row per step), a generator, ``tqdm(...)``.

    Returns
    -------
    iterator

    Raises
    ------
    ShapeError
        ``zs`` is a string, bytes, a dict or a set (no steps in an order), or
        not iterable at all.
    """
    if isinstance(zs, (str, bytes, Mapping, Set)):
        raise ShapeError(
            "zs must be an iterable of measurements in step order (a list, an array, a generator), "
            f"got {type(zs).__name__}: {zs!r:.100}"
        )
    try:
        return iter(zs)
    except TypeError:
        raise ShapeError(
            f"zs must be an iterable of measurements (a list, an array, a generator), "
            f"got {type(zs).__name__}: {zs!r:.200}"
        ) from None


def measurement_series(zs, K: int, m: int) -> np.ndarray:
    """A run's measurements of ``K`` filters, ``(K, T, m)``.

    Parameters
    ----------
    zs : array_like, shape (K, T, m) or (K, T) when ``m`` is 1, or an iterable of (K, m) arrays
        Lists, tuples and any object numpy reads as an array (``__array__``:
        a dask or xarray array, ...) are read as the array; any other
        iterable yields one step at a time, each checked by
        :func:`measurements` (naming it ``zs[t]``).
    K, m : int
        Number of filters and measurement size.

    Returns
    -------
    Z : ndarray, shape (K, T, m)
    """
    if not isinstance(zs, (np.ndarray, list, tuple)) and not hasattr(zs, "__array__"):  # MaskedArray: ndarray
        # a generator, an iterator, tqdm(...): one (K, dim_z) array per step, each checked
        it = iter_measurements(zs)
        # each step's own copy: an iterator may yield one array, written again for every step
        steps_read = [measurements(z, K, m, f"zs[{t}]").copy() for t, z in enumerate(it)]
        zs = np.stack(steps_read, axis=1) if steps_read else np.zeros((K, 0, m))
    Z = as_measurements(zs, "zs")
    if Z.ndim == 2 and m == 1:
        Z = Z[..., None]
    if Z.ndim != 3 or Z.shape[0] != K or Z.shape[2] != m:
        raise ShapeError(f"zs has shape {Z.shape}, expected ({K}, T, {m})")
    if np.isinf(Z).any():
        k, t = (int(i[0]) for i in np.nonzero(np.isinf(Z).any(axis=2)))
        raise NonFiniteError(f"zs contains inf (filter {k}, step {t}; NaN means a missing component)")
    return Z


def with_filter_axis(kwargs: dict, K: int) -> dict:
    """Per-filter array arguments (leading axis ``K``) get a sigma-point axis, to broadcast against X.

    Parameters
    ----------
    kwargs : dict
        Keyword arguments of a model function; an ndarray of shape
        ``(K, ...)`` becomes ``(K, 1, ...)``.
    K : int

    Returns
    -------
    dict
        A new dict.
    """
    out = {}
    for key, v in kwargs.items():
        if is_per_filter(v, K):
            v = v.reshape((K, 1) + v.shape[1:])
        out[key] = v
    return out


def is_per_filter(v, K: int) -> bool:
    """Whether a model function's argument is per filter in a fleet of ``K`` (an ndarray, leading axis K)."""
    return isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == K


def chunk_args(kwargs: dict, K: int, rows: slice) -> dict:
    """The model functions' arguments of a chunk of a fleet of ``K``: per-filter arrays cut to ``rows``.

    Parameters
    ----------
    kwargs : dict
    K : int
    rows : slice
        The chunk's filters.

    Returns
    -------
    dict
        A new dict (the arrays cut are views).
    """
    return {key: v[rows] if is_per_filter(v, K) else v for key, v in kwargs.items()}


def check_chunk_args(kwargs: dict, name: str, K: int, sizes) -> None:
    """Refuse a shared array argument as long as a chunk: that chunk's fleet would read it per filter.

    Parameters
    ----------
    kwargs : dict
    name : str
        ``"fx_args"`` or ``"hx_args"``, for the message.
    K : int
        Number of filters.
    sizes : sequence of int
        The chunks' sizes.
    """
    for key, v in kwargs.items():
        if isinstance(v, np.ndarray) and v.ndim >= 1 and not is_per_filter(v, K) and v.shape[0] in sizes:
            raise ParameterError(
                f"{name}[{key!r}] has a leading axis of {v.shape[0]}, the size of a chunk of filters but "
                f"not their number ({K}): a chunk's fleet would read it per filter; rechunk zs"
            )


def evaluate(fn: Callable, sigmas: np.ndarray, args: tuple, kwargs: dict, vectorized: bool) -> object:
    """A model function at sigma points ``(N, n)``: once with all of them, or once per point.

    Parameters
    ----------
    fn : callable
        ``fn(sigmas, *args, **kwargs)`` when ``vectorized``, else ``fn(sigma, *args, **kwargs)``.
    sigmas : ndarray, shape (N, n)
    args : tuple
        ``(dt,)`` for ``fx``, ``()`` for ``hx``.
    kwargs : dict
    vectorized : bool

    Returns
    -------
    object
        What ``fn`` returned (vectorised), or the list of its ``N`` results.
    """
    if vectorized:
        return fn(sigmas, *args, **kwargs)
    # one call per point: spelled out for the common cases, since unpacking *args and
    # **kwargs at every call costs more than the loop itself
    if kwargs:
        return [fn(s, *args, **kwargs) for s in sigmas]
    if not args:
        return [fn(s) for s in sigmas]
    if len(args) == 1:
        dt = args[0]
        return [fn(s, dt) for s in sigmas]
    return [fn(s, *args) for s in sigmas]


def stacked_shape(
    values, shape: tuple, name: str, copy: bool, called: tuple[str, tuple] | None = None
) -> np.ndarray:
    """A stack's model-function images as a float64 array of the expected shape.

    Parameters
    ----------
    values : array_like
    shape : tuple of int
        What ``values`` must be.
    name : str
        For messages.
    copy : bool
        Whether a float64 ndarray is copied (values a caller told, which it
        may go on writing) or taken as it is (a model function's images,
        read within the chunk's step; the step copies them only if it keeps
        them).
    called : (str, tuple), optional
        The model function that returned ``values`` (``"fx"``, ``"hx"``) and
        the shape ``(k, N, n)`` of the stack of points it was called with;
        None for values a caller told. A wrong shape then says how a fleet
        calls its functions (:func:`stack_call_note`).

    Returns
    -------
    ndarray, shape ``shape``

    Raises
    ------
    ShapeError, ParameterError
        The wrong shape; not numbers.
    """
    if not copy and isinstance(values, np.ndarray) and values.dtype == np.float64:
        A = values
    else:
        A = as_float_array(values, name)
    if A.shape != shape:
        how = "" if called is None else f": {stack_call_note(*called)}, of shape {shape}"
        raise ShapeError(f"{name} have shape {A.shape}, expected {shape}{how}")
    return A


def stack_call_note(fn: str, points: tuple) -> str:
    """How a fleet calls ``fn`` with the stack of points ``(k, N, n)``: for messages and notes.

    Parameters
    ----------
    fn : {"fx", "hx"}
    points : tuple of int
        The shape of the stack ``X`` of the call, ``(k, N, n)``.

    Returns
    -------
    str
    """
    k, N, n = points
    return (
        f"a fleet calls {fn} once with the stack X of shape {points} ({k} filters, {N} sigma points each,"
        f" dim_x={n}; component i of every point is X[..., i], shape {(k, N)}), not once per point,"
        f" and {fn} returns the stack of their values"
    )


def note_stack_call(exc: BaseException, name: str, X: np.ndarray, noise: np.ndarray | None) -> None:
    """Note on an exception a fleet's model function raised how it was called, before it propagates.

    The fleet calls ``fn(X, *args, **kwargs)``, or ``fn(X, noise, ...)``, on a
    stack of points; the exception propagates unchanged, with a note saying so
    (:func:`note_on_user_error`): a function written for one point fails on a
    stack.

    Parameters
    ----------
    exc : BaseException
    name : {"fx", "hx"}
    X : ndarray, shape (k, N, n)
        The chunk's points.
    noise : ndarray, shape (k, N, d), or None
        Their noise part, with noise entering ``fn`` (``fx_noise``, ``hx_noise``).
    """
    note = f"squkf: {stack_call_note(name, X.shape)}"
    if noise is not None:
        note += f"; the noise W ({name}_noise={noise.shape[-1]}) is its second argument, shape {noise.shape}"
    note_on_user_error(exc, note)


def finite_images(
    A: np.ndarray, name: str, active, fails: dict, *, kernels: KernelTable | None = None
) -> np.ndarray:
    """Which filters' images ``A`` ``(K, N, d)`` are finite; an active filter's that are not is a failure.

    Parameters
    ----------
    A : ndarray, shape (K, N, d)
    name : {"fx values", "hx values"}
    active : ndarray of bool, shape (K,)
        The filters whose images count (not flagged, measured).
    fails : dict
        An active filter with a non-finite image is added, ``filter -> reason``,
        described by its own rows (as one filter's error would say it).
    kernels : KernelTable, optional
        The kernel table to call (the fleet's route's); default the installed one.

    Returns
    -------
    ndarray of bool, shape (K,)
    """
    finite = wrappers.finite_rows(A, kernels=kernels)
    for k in np.flatnonzero(active & ~finite).tolist():
        fails.setdefault(int(k), f"NonFiniteError: {describe_nonfinite(A[k], name)}")
    return finite


def refuse_smoother_noise(fx_noise: int, who: str) -> None:
    """The RTS smoothers take additive process noise only: refuse a ``filter`` or ``fleet`` with ``fx_noise``.

    Parameters
    ----------
    fx_noise : int
        Dimension of the noise entering ``fx`` (0: additive).
    who : {"filter", "fleet"}
        For the message.
    """
    if fx_noise:
        raise ParameterError(
            f"the RTS smoother takes additive process noise only; this {who} has fx_noise={fx_noise}"
        )


def refuse_noise_args(noise_xi, name: str, value, UT) -> None:
    """With noise entering the model, ``Q``/``R`` are in the points: refuse them in a call (and a ``UT``).

    Parameters
    ----------
    noise_xi : ndarray or None
        The plan's noise part of the unit points (None: additive noise, nothing refused).
    name : {"Q", "R"}
    value : object
        The call's ``Q`` or ``R`` (None: not given).
    UT : callable or None
    """
    if noise_xi is None:
        return
    which = "fx_noise" if name == "Q" else "hx_noise"
    if value is not None:
        raise ParameterError(
            f"with {which} the noise is in the sigma points handed out by ask_*: assign ukf.{name}"
            f" before asking, not {name}={value!r} here"
        )
    if UT is not None:
        raise ParameterError(f"UT cannot be given with {which}: the transform has no noise to add")


def _finite_square(value, name: str, dim: int | None) -> np.ndarray:
    """``value`` as a finite square float64 matrix of size ``dim``: a scalar is ``value * I``, a 1-element
    array a 1x1 matrix when ``dim`` allows; a longer 1-D array is a ShapeError (``np.diag`` is meant)."""
    A = as_float_array(value, name)
    if A.ndim == 1 and A.shape[0] == 1 and dim in (None, 1):
        A = A.reshape(1, 1)
    if A.ndim == 0 and dim is not None:
        if not np.isfinite(A):
            raise NonFiniteError(f"{name} is not finite: {float(A)!r}")
        A = A * np.eye(dim)
    if A.ndim == 1 and A.shape[0] > 1:
        raise ShapeError(
            f"{name} is a 1-D array of length {A.shape[0]}, not a matrix: for a diagonal one"
            f" use np.diag({name})"
        )
    if A.ndim != 2 or A.shape[0] != A.shape[1] or (dim is not None and A.shape[0] != dim):
        want = f"({dim}, {dim})" if dim is not None else "square"
        raise ShapeError(f"{name} has shape {A.shape}, expected {want}")
    if not np.all(np.isfinite(A)):
        raise NonFiniteError(f"{name} contains NaN or inf: {A!r}")
    return A


def as_matrix(value, name: str, dim: int | None) -> np.ndarray:
    """Validate a covariance given as a matrix (or a scalar meaning ``value * I``).

    Parameters
    ----------
    value : array_like or float
        A square matrix; a scalar (``value * I``); for ``dim == 1`` also a
        1-element array.
    name : str
        Argument name for messages.
    dim : int or None
        Required size; ``None`` accepts any square matrix (a scalar then
        needs ``dim``).

    Returns
    -------
    A : ndarray, shape (dim, dim), float64, symmetrised copy

    Raises
    ------
    ShapeError, NonFiniteError, SqukfValueError (not symmetric)
    """
    A = _finite_square(value, name, dim)
    scale = float(np.max(np.abs(A))) if A.size else 0.0
    asym = float(np.max(np.abs(A - A.T))) if A.size else 0.0
    if asym > 1e-9 * scale:
        raise SqukfValueError(
            f"{name} is not symmetric: max |{name} - {name}.T| = {asym:.3g} (max |{name}| = {scale:.3g})"
        )
    return 0.5 * A + 0.5 * A.T  # halves first: A + A.T overflows for entries near the largest float


def as_lower_factor(value, name: str, dim: int | None, singular_ok: bool) -> np.ndarray:
    """Validate a lower-triangular factor given directly.

    A negative diagonal entry is made positive by flipping its column (the
    covariance ``S @ S.T`` is unchanged).

    Parameters
    ----------
    value : array_like
        A lower-triangular matrix; a scalar (``value * I``); for ``dim == 1``
        also a 1-element array.
    name : str
    dim : int or None
    singular_ok : bool
        Accept zeros on the diagonal (a covariance of lower rank).

    Returns
    -------
    S : ndarray, shape (dim, dim), float64 copy

    Raises
    ------
    ShapeError, NonFiniteError (also when the covariance ``S @ S.T`` is beyond
    float64's range: read as a matrix it would hold inf), SqukfValueError (not
    lower triangular), NotPositiveDefiniteError (zero on the diagonal)
    """
    S = _finite_square(value, name, dim)
    upper = np.triu(S, 1)
    if np.any(upper != 0):
        i, j = np.argwhere(upper != 0)[0]
        raise SqukfValueError(
            f"{name} must be lower triangular, but {name}[{i}, {j}] = {S[i, j]!r} is above the diagonal"
        )
    with np.errstate(over="ignore"):  # overflow is what is checked here
        # the diagonal of S @ S.T, its largest entries (Cauchy-Schwarz): finite iff the matrix is
        norms = np.einsum("ij,ij->i", S, S)
    if not all_finite(norms):
        i = int(np.flatnonzero(~np.isfinite(norms))[0])
        raise NonFiniteError(
            f"{name} stands for a covariance {name} @ {name}.T beyond float64's range: its entry [{i}, {i}]"
            f" overflows (the largest entry of {name} is {float(np.max(np.abs(S))):.3g})"
        )
    d = S.diagonal()
    if not singular_ok and np.any(d == 0):
        raise NotPositiveDefiniteError(
            f"{name} has a zero on its diagonal (at {int(np.flatnonzero(d == 0)[0])}): "
            "the covariance it stands for is singular"
        )
    neg = d < 0
    if neg.any():
        S[:, neg] *= -1.0
    return S


def lower_factor_stack(a: np.ndarray, name: str, dim: int, singular_ok: bool) -> np.ndarray:
    """:func:`as_lower_factor` of each filter's factor of a stack ``(K, dim, dim)`` at once (the checks and
    the column flips as arrays, not a Python call a filter): the same factors, and for the first filter
    that fails a check, the same error (naming ``name[k]``).

    Parameters
    ----------
    a : ndarray, shape (K, dim, dim)
    name : str
    dim : int
    singular_ok : bool

    Returns
    -------
    S : ndarray, shape (K, dim, dim), float64 copy
    """
    S = np.array(a, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):  # overflow is what is checked here
        norms = np.einsum("kij,kij->ki", S, S)
    d = np.diagonal(S, axis1=1, axis2=2)
    bad = ~np.isfinite(norms).all(axis=1) | (np.triu(S, 1) != 0).any(axis=(1, 2))
    if not singular_ok:
        bad |= (d == 0).any(axis=1)
    if bad.any():  # (a NaN or inf entry makes its norm non-finite)
        k = int(np.flatnonzero(bad)[0])
        as_lower_factor(S[k], f"{name}[{k}]", dim, singular_ok)  # raises, naming it
        raise AssertionError(f"{name}[{k}] failed a check here that as_lower_factor passed")
    neg = d < 0
    if neg.any():
        S *= np.where(neg, -1.0, 1.0)[:, None, :]  # the columns of a negative diagonal entry flipped
    return S


def symmetric_stack(A: np.ndarray, name: str, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`as_matrix` of each matrix of a stack ``(K, dim, dim)`` at once: the symmetrised copies, and
    which of them failed its checks (their entries unspecified: :func:`as_matrix` of one says why).

    Returns
    -------
    A : ndarray, shape (K, dim, dim)
    bad : ndarray of bool, shape (K,)
    """
    A = np.asarray(A, dtype=float)
    At = np.swapaxes(A, 1, 2)
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(A).all(axis=(1, 2))
        scale = np.abs(A).max(axis=(1, 2), initial=0.0)
        asym = np.abs(A - At).max(axis=(1, 2), initial=0.0)
    bad = ~finite | (asym > 1e-9 * scale)
    return 0.5 * A + 0.5 * At, bad


def noise_factor(
    value, name: str, dim: int, default: Callable[[], np.ndarray | None], cache: dict
) -> np.ndarray | None:
    """One filter's ``Q`` or ``R`` factor: this call's ``value``, else the filter's own (``default()``).

    Parameters
    ----------
    value : array_like, shape (dim, dim), scalar, or None
        This call's covariance (a scalar ``r`` is ``r * I``); None: the filter's.
    name : {"Q", "R"}
    dim : int
        The size the step needs (the state's or the measurement's).
    default : callable
        The factor of the filter's own covariance (None: zero), e.g. a
        :class:`~squkf.boundary.attributes.FactorSlot`'s ``factor``.
    cache : dict
        ``name -> (array, its copy, factor)``: an ndarray given again unchanged
        is not factored again.

    Returns
    -------
    ndarray, shape (dim, dim), or None
        The lower factor; None for a zero covariance.
    """
    if value is None:
        S = default()
        if S is not None and S.shape[0] != dim:
            raise ShapeError(
                f"{name} is {S.shape[0]}x{S.shape[0]} but the {'measurement' if name == 'R' else 'state'}"
                f" has length {dim}; pass {name}= for a model of another size"
            )
        return S
    cached = cache.get(name)
    if cached is not None and cached[0] is value and np.array_equal(cached[1], value):
        return cached[2]
    A = as_matrix(value, name, dim)
    S = factor_covariance(A, name, semidefinite=True) if np.any(A) else None  # zero: no noise
    if isinstance(value, np.ndarray):
        cache[name] = (value, value.copy(), S)
    return S


def _noise_one(a, name: str, dim: int) -> np.ndarray:
    A = as_matrix(a, name, dim)
    if not np.any(A):
        return np.zeros((dim, dim))
    return factor_covariance(A, name, semidefinite=True)


def noise_factors(value, name: str, dim: int, K: int) -> np.ndarray | None:
    """A stack's ``Q`` or ``R``, shared ``(dim, dim)`` or per filter ``(K, dim, dim)``, as lower factors.

    Parameters
    ----------
    value : array_like, shape (dim, dim) or (K, dim, dim), scalar, or None
    name : {"Q", "R"}
    dim : int
    K : int

    Returns
    -------
    ndarray, shape (dim, dim) or (K, dim, dim), or None
        Zeros for a zero covariance; None when ``value`` is None.
    """
    if value is None:
        return None
    a = as_float_array(value, name)
    if a.ndim == 3:
        if a.shape != (K, dim, dim):
            raise ShapeError(f"{name} has shape {a.shape}, expected ({dim}, {dim}) or ({K}, {dim}, {dim})")
        return np.stack([_noise_one(a[k], f"{name}[{k}]", dim) for k in range(K)])
    return _noise_one(a, name, dim)


def given_noise_factors(value, name: str, dim: int, K: int) -> np.ndarray | None:
    """A stack's ``Q1_2`` or ``R1_2`` as given, shared ``(dim, dim)`` or per filter ``(K, dim, dim)``.

    Parameters
    ----------
    value : array_like, shape (dim, dim) or (K, dim, dim), or scalar
        Lower-triangular factors (singular ones allowed).
    name : {"Q1_2", "R1_2"}
    dim, K : int

    Returns
    -------
    ndarray, shape (dim, dim) or (K, dim, dim), or None
        None for one shared zero factor.
    """
    a = as_float_array(value, name)
    if a.ndim == 3:
        if a.shape != (K, dim, dim):
            raise ShapeError(f"{name} has shape {a.shape}, expected ({dim}, {dim}) or ({K}, {dim}, {dim})")
        return lower_factor_stack(a, name, dim, singular_ok=True)
    S = as_lower_factor(a, name, dim, singular_ok=True)
    return S if np.any(S) else None


def covariance_factors(value, name: str, n: int, K: int, placeholders: bool = False):
    """A stack's ``P``, one matrix for all (factored once) or one per filter, as ``(K, n, n)`` factors.

    Parameters
    ----------
    value : array_like, shape (n, n) or (K, n, n)
    name : str
    n, K : int
    placeholders : bool
        Accept a filter's matrix all NaN (not set yet): its factor is all NaN.

    Returns
    -------
    ndarray, shape (K, n, n)
        Lower factors with a positive diagonal.
    unset : ndarray of bool, shape (K,)
        With ``placeholders`` only: the filters whose matrix is all NaN.
    """
    a = as_float_array(value, name)
    if a.shape == (n, n) and not (placeholders and np.isnan(a).all()):  # one matrix for all: factored once
        S = factor_covariance(as_matrix(a, name, n), name)
        S = np.broadcast_to(S, (K, n, n)).copy()
        return (S, np.zeros(K, dtype=bool)) if placeholders else S
    A, unset = per_filter(a, name, K, (n, n), placeholders=True)
    if unset.any() and not placeholders:
        raise NonFiniteError(f"{name} contains NaN or inf (filters {np.flatnonzero(unset)[:10].tolist()})")
    S = np.full((K, n, n), np.nan)
    for k in np.flatnonzero(~unset).tolist():
        S[k] = factor_covariance(as_matrix(A[k], f"{name}[{k}]", n), f"{name}[{k}]")
    return (S, unset) if placeholders else S


def lower_factors(value, name: str, n: int, K: int) -> np.ndarray:
    """A stack's ``P1_2`` as given, one for every filter or one per filter, ``(K, n, n)``.

    Parameters
    ----------
    value : array_like, shape (n, n) or (K, n, n)
        Lower-triangular factors, non-singular.
    name : str
    n, K : int

    Returns
    -------
    ndarray, shape (K, n, n)
    """
    return lower_factor_stack(per_filter(value, name, K, (n, n)), name, n, singular_ok=False)


def reset_rows(x, P, idx: np.ndarray, x_now: np.ndarray, S_now: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A stack's states and factors with the filters ``idx`` given a new ``x`` and ``P`` (``Fleet.reset``).

    Parameters
    ----------
    x : array_like, shape (n,) or (len(idx), n), or None
        None: the states are kept.
    P : array_like, shape (n, n) or (len(idx), n, n), or None
        Factored filter by filter (messages name ``P[k]``); None: kept.
    idx : ndarray of int
        The filters.
    x_now : ndarray, shape (K, n)
    S_now : ndarray, shape (K, n, n)

    Returns
    -------
    x : ndarray, shape (K, n)
    S : ndarray, shape (K, n, n)
        New arrays.
    """
    new_x, new_S = x_now.copy(), S_now.copy()
    n = x_now.shape[-1]
    if x is not None:
        xs = as_float_array(x, "x")
        if xs.shape not in ((n,), (idx.size, n)):
            raise ShapeError(f"x has shape {xs.shape}, expected ({n},) or ({idx.size}, {n})")
        new_x[idx] = xs
        if not np.all(np.isfinite(new_x[idx])):
            raise NonFiniteError("x contains NaN or inf")
    if P is not None:
        Ps = as_float_array(P, "P")
        shape = (n, n)
        if Ps.shape not in (shape, (idx.size,) + shape):
            raise ShapeError(f"P has shape {Ps.shape}, expected {shape} or {(idx.size,) + shape}")
        Ps = np.broadcast_to(Ps, (idx.size,) + shape)
        for j, k in enumerate(idx):
            new_S[k] = factor_covariance(as_matrix(Ps[j], f"P[{k}]", n), f"P[{k}]")
    return new_x, new_S
