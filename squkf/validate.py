"""Checks at the boundary: what callers and their functions hand to the filter.

Every value that crosses into the core goes through one of these: the images
of the model functions, what the user's hooks return, and arrays given as
arguments. Each raises a specific :mod:`squkf.errors` exception naming the
argument (or the function) and the value; none keeps a reference to its input.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .errors import NonFiniteError, ParameterError, ShapeError, SqukfError
from .linalg import all_finite

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
]

_FLOAT64 = np.dtype(np.float64)  # numpy's native float64 dtype is one object: compared by identity


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
