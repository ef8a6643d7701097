"""Covariances carried as factors, read and written as matrices, and edits in place of what is handed out.

filterpy code reads and writes a filter's arrays as matrices, and edits them
in place as often as it assigns them (``ukf.P *= 10``, ``ukf.Q[2:4, 2:4] = ...``,
``fleet.x[3] = ...``, also over several statements). Three pieces, one idea:

- :class:`Handed` and :class:`HandOut`: an array handed out is kept with a
  record of it (shape, dtype, bytes); at the next call that needs the value
  behind it, an array that no longer matches its record was edited, and is
  given to the attribute's validating setter, as an assignment would be (if
  that raises, nothing changes and the edit stays pending).
- :class:`FactorSlot`: a covariance (``Q``, ``R`` of one filter; a ``P``
  being assigned, validated and factored) held as its lower factor, the
  truth, and handed out as a matrix formed when read;
  :func:`as_matrix` and :func:`as_lower_factor` validate what is assigned.
- one filter's attributes in its ``__dict__``, as filterpy keeps them
  (filterpy's ``Saver`` deep-copies the ``__dict__``): data descriptors
  (:class:`Estimate` for ``x`` and ``P``, :class:`Covariance` for ``Q`` and
  ``R``, :class:`Hook`, :class:`ModelFunction` for ``fx`` and ``hx``), and
  :class:`Unformed`, an array not formed since the value behind it changed.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from ..angles import check_angle_hook
from ..errors import NonFiniteError, NotPositiveDefiniteError, ShapeError, SqukfValueError
from ..linalg import all_finite, factor_covariance
from ..plan import Hooks
from ..validate import as_float_array, check_callable, check_flag

__all__ = [
    "as_lower_factor",
    "Checked",
    "as_matrix",
    "Covariance",
    "Estimate",
    "FactorSlot",
    "Flag",
    "Handed",
    "HandOut",
    "Hook",
    "hooks_of",
    "ModelFunction",
    "initial",
    "NOISES",
    "set_factor",
    "Unformed",
]


class Handed:
    """An array handed out for editing in place, with its record when handed out (or last taken).

    Immutable apart from the array itself: taking an edit makes a new record.

    Parameters
    ----------
    array : ndarray
        The array as the caller holds it (not copied).
    """

    __slots__ = ("array", "_record")

    def __init__(self, array: np.ndarray):
        self.array = array
        self._record = (array.shape, array.dtype, array.tobytes())

    def edited(self) -> bool:
        """Whether the array was changed in place (values, shape or dtype) since its record."""
        a = self.array
        shape, dtype, data = self._record
        return a.shape != shape or a.dtype != dtype or a.tobytes() != data

    def take(self, assign: Callable[[np.ndarray], object]) -> Handed:
        """``self`` if not edited, else ``assign(array)`` (validating; may raise) and a fresh record.

        Parameters
        ----------
        assign : callable
            The attribute's validating setter, given the edited array.

        Returns
        -------
        Handed
            The record to keep: ``self`` (unchanged, or if ``assign`` raised
            nothing is returned and the edit stays pending) or a new one.
        """
        if not self.edited():
            return self
        assign(self.array)
        return Handed(self.array)

    def copy(self) -> Handed:
        """The same record over a copy of the array (an edit pending here is pending in the copy)."""
        new = Handed.__new__(Handed)
        new.array, new._record = self.array.copy(), self._record
        return new


class HandOut:
    """The arrays of named attributes handed out, each until the value behind it changes (:class:`Handed`).

    ``array(name, form)`` hands out ``form()`` once and then the same array;
    ``drop(*names)`` forgets them (the values changed: the arrays are history);
    ``take(assign)`` gives each edited array to ``assign(name, array)``.
    ``held`` maps each name handed out to its :class:`Handed` (empty: nothing is).
    """

    __slots__ = ("held",)

    def __init__(self, held: dict[str, Handed] | None = None):
        self.held: dict[str, Handed] = {} if held is None else held

    def array(self, name: str, form: Callable[[], np.ndarray]) -> np.ndarray:
        """The array handed out for ``name``, formed by ``form()`` if none is."""
        held = self.held.get(name)
        if held is None:
            held = self.held[name] = Handed(form())
        return held.array

    def drop(self, *names: str) -> None:
        """The values behind ``names`` changed: the arrays handed out are no longer theirs."""
        held = self.held
        for name in names:
            held.pop(name, None)

    def take(self, names: Iterable[str], assign: Callable[[str, np.ndarray], object]) -> None:
        """Take the edits in place, in the order of ``names``, through ``assign(name, array)``.

        ``assign`` validates (as an assignment) and may raise: the edits not
        yet taken stay pending. The array stays handed out after its edit is
        taken, even when ``assign`` dropped it.
        """
        held = self.held
        for name in names:
            h = held.get(name)
            if h is not None:
                held[name] = h.take(functools.partial(assign, name))

    def copy(self) -> HandOut:
        """The records as they are now (the arrays the same): what a transaction puts back."""
        return HandOut(dict(self.held))

    def detached(self) -> HandOut:
        """An independent copy: each array copied, pending edits kept (:meth:`Handed.copy`)."""
        return HandOut({name: h.copy() for name, h in self.held.items()})


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


class FactorSlot:
    """One covariance (``P``, ``Q`` or ``R``) held as its lower factor.

    The factor is the truth. The matrix is formed when first read and then
    handed out as the same array until the factor changes, so that edits in
    place (also several statements of them) reach it; they are validated and
    factored when the factor is next needed (:meth:`factor`). An assignment is
    validated at once, and one that fails changes nothing, pending in-place
    edits included.

    Parameters
    ----------
    name : str
        ``"P"``, ``"Q"`` or ``"R"``, used in messages.
    dim : int or None
        Fixed size, or None for any size.
    semidefinite : bool
        Whether a singular covariance is acceptable (noise) or not (``P``).
        A factor given directly is accepted exactly when its covariance is.
    factor : ndarray or None
        Initial lower factor; None means a zero covariance (no noise).
    """

    def __init__(self, name: str, dim: int | None, semidefinite: bool, factor: np.ndarray | None):
        self.name = name
        self.dim = dim
        self.semidefinite = semidefinite
        self._factor = factor
        self._view: Handed | None = None  # the matrix handed out, and its record when it matched the factor
        self._assigned: np.ndarray | None = None  # the matrix assigned, handed out when first read

    def detached(self) -> FactorSlot:
        """A copy for an independent filter: the factor shared (never changed in place), the matrix copied.

        A pending step recognises the shared factor as the prior its second
        set was drawn from; the matrix handed out (and its pending edits) is
        the copy's own.
        """
        new = copy.copy(self)
        if new._view is not None:
            new._view = new._view.copy()  # pending edits stay pending in the copy
        if new._assigned is not None:
            new._assigned = new._assigned.copy()
        return new

    def _size(self) -> int:
        if self._factor is not None:
            return self._factor.shape[0]
        return self.dim if self.dim is not None else 0

    def factor(self) -> np.ndarray | None:
        """The current lower factor (None: zero covariance), after validating in-place edits.

        The array returned is the slot's own: callers inside the library only
        read it, and hand out copies.

        Raises
        ------
        SqukfValueError, NotPositiveDefiniteError
            The edited matrix is not a valid covariance; the edit stays pending.
        """
        if self._view is not None:
            self._view = self._view.take(self._take_matrix)
        return self._factor

    def _take_matrix(self, A: np.ndarray) -> None:
        self._factor = self._factor_of(as_matrix(A, self.name, self.dim))

    def _factor_of(self, A: np.ndarray) -> np.ndarray | None:
        if self.semidefinite and not np.any(A):
            return None
        return factor_covariance(A, self.name, semidefinite=self.semidefinite)

    def matrix(self) -> np.ndarray:
        """The covariance ``S @ S.T``; edits to the returned array take effect at the next step.

        ``(dim, dim)``, or ``(1,)`` when a 1-element vector was assigned (:meth:`set_matrix`).
        """
        if self._view is None:
            A = self._assigned
            if A is None:
                S = self._factor
                A = S @ S.T if S is not None else np.zeros((self._size(),) * 2)
            # handed out from now on: edits in place are looked for at each use of the factor
            self._view, self._assigned = Handed(A), None
        return self._view.array

    def set_matrix(self, value) -> None:
        """Assign from a covariance matrix (validated, factored once; a copy is kept).

        The copy handed out by :meth:`matrix` has the shape assigned: a
        ``(dim, dim)`` matrix, or for dimension 1 also a 1-element vector
        ``(1,)`` (filterpy keeps what it is given, so ``R[0]`` is a number). A
        scalar ``s`` is the matrix ``s * I``. After :meth:`set_factor` the
        matrix is formed ``(dim, dim)``.
        """
        if value is None:
            if not self.semidefinite:
                raise SqukfValueError(f"{self.name} cannot be None")
            self._factor, self._view, self._assigned = None, None, None
            return
        A = as_matrix(value, self.name, self.dim)
        S = self._factor_of(A)
        if np.ndim(value) == 1:  # a 1-element vector (dimension 1): handed out as assigned, as filterpy
            A = A.reshape(1)  # does, so that ``R[0]`` is a number; edits in place still reach it
        self._factor, self._view, self._assigned = S, None, A

    def set_factor(self, value) -> None:
        """Assign from a lower-triangular factor (validated; a copy is kept)."""
        if value is None and self.semidefinite:
            self._factor, self._view, self._assigned = None, None, None
            return
        S: np.ndarray | None = as_lower_factor(
            value, f"{self.name}1_2", self.dim, singular_ok=self.semidefinite
        )
        if self.semidefinite and not np.any(S):
            S = None
        self._factor, self._view, self._assigned = S, None, None

    def factor_or_zeros(self) -> np.ndarray:
        """The factor, with an absent (zero) covariance shown as zeros."""
        S = self.factor()
        if S is None:
            n = self._size()
            return np.zeros((n, n))
        return S


NOISES = ("Q", "R")


class Unformed:
    """Stands in the ``__dict__`` for an array nobody has read since the step changed it.

    Reading the attribute forms it (:class:`Covariance`, :class:`Estimate`); a deep
    copy of the ``__dict__`` (what filterpy's ``Saver`` takes) gets the array
    itself, so a saved history holds arrays, formed only when saved.

    Parameters
    ----------
    form : callable
        ``form()``: the array as it would be handed out now.
    """

    __slots__ = ("form",)

    def __init__(self, form: Callable[[], np.ndarray]):
        self.form = form

    def __deepcopy__(self, memo):
        return self.form().copy()

    def __copy__(self):
        return self.form().copy()


class Covariance:
    """``Q`` or ``R``: a matrix kept in the instance's ``__dict__``, backed by a factor slot (the
    instance's attribute ``_Q`` or ``_R``, kept outside the ``__dict__``).

    Not a ``property``, on purpose: filterpy's ``Saver`` deep-copies the
    instance's ``__dict__`` (so a saved matrix is a copy, as for filterpy's
    own filters) but would keep a property's value by reference.
    """

    def __set_name__(self, owner, name: str):
        self.name = name
        self.slot = "_" + name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        d = obj.__dict__
        value = d[self.name]
        if type(value) is Unformed:
            value = d[self.name] = getattr(obj, self.slot).matrix()
        return value

    def __set__(self, obj, value):
        slot = getattr(obj, self.slot)
        slot.set_matrix(value)
        obj.__dict__[self.name] = Unformed(slot.matrix)


class Estimate:
    """``x`` or ``P``: formed from the filter's estimate when first read after a step, and handed out
    as the same array (with its record, the instance's attribute ``_x`` or ``_Ph``) until the next one;
    an assignment is validated by the filter (``_assign_x``, ``_assign_P``). See :class:`Covariance`."""

    def __set_name__(self, owner, name: str):
        self.name = name
        self.record = "_x" if name == "x" else "_Ph"

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        d = obj.__dict__
        value = d[self.name]
        if type(value) is Unformed:
            value = d[self.name] = value.form()
            setattr(obj, self.record, Handed(value))
        return value

    def __set__(self, obj, value):
        getattr(obj, "_assign_" + self.name)(value)


class Checked:
    """An attribute kept in the instance's ``__dict__`` (filterpy's layout: a ``Saver`` sees it), checked
    when assigned by :meth:`check`, which the kinds below define."""

    def __set_name__(self, owner, name: str):
        self.name = name

    def __get__(self, obj, owner=None) -> Any:
        if obj is None:
            return self
        return obj.__dict__[self.name]

    def __set__(self, obj, value) -> None:
        obj.__dict__[self.name] = self.check(value)

    def check(self, value):
        """``value`` as kept (raises, naming the attribute, for what it does not take)."""
        return value


class Hook(Checked):
    """A hook (``residual_x``, ``state_add``, ...): callable or None.

    Setting one tells the filter (``_hooks_assigned``), which builds its
    :class:`~squkf.plan.Hooks` again. squkf's own angle hooks have their
    indices checked against the filter's ``dim_x`` or ``dim_z`` first.
    """

    def __set__(self, obj, value) -> None:
        value = self.check(value)
        axis = "z" if self.name in ("z_mean", "residual_z") else "x"
        check_angle_hook(value, self.name, getattr(obj, "dim_" + axis), "dim_" + axis)
        obj.__dict__[self.name] = value
        obj._hooks_assigned()

    def check(self, value):
        return check_callable(value, self.name)


class ModelFunction(Checked):
    """``fx`` or ``hx``: callable (or None where ``optional``).

    Parameters
    ----------
    optional : bool
        Whether None is taken: filterpy's placeholder for a function given
        per call (``predict(fx=...)``), which a call given none refuses.
    why : str
        Why it is needed where None is not taken, for the message.
    """

    def __init__(self, optional: bool, why: str = ""):
        self.optional, self.why = optional, why

    def check(self, value):
        return check_callable(value, self.name, self.optional, self.why)


class Flag(Checked):
    """An option that is on or off (``vectorized``): ``True`` or ``False`` (``validate.check_flag``)."""

    def check(self, value):
        return check_flag(value, self.name)


def initial(obj, m: int, q: int, r: int) -> None:
    """Set a new filter's ``Q``, ``R`` (identities, in their slots ``_Q``, ``_R``) and ``z`` (``x`` and ``P``
    are the engine's).

    Parameters
    ----------
    obj : SquareRootUKF
    m : int
        Measurement dimension.
    q, r : int
        The dimensions of ``Q`` and ``R`` (the noise's own when it enters ``fx``, ``hx``).
    """
    d = obj.__dict__
    for name, dim in (("Q", q), ("R", r)):
        slot = FactorSlot(name, dim, semidefinite=True, factor=np.eye(dim))
        setattr(obj, "_" + name, slot)
        d[name] = Unformed(slot.matrix)
    d["z"] = np.array([[None] * m]).T


def set_factor(obj, name: str, value) -> None:
    """Assign ``Q1_2`` or ``R1_2`` (``name``: ``"Q"``, ``"R"``) of the filter ``obj``, validated."""
    slot = getattr(obj, "_" + name)
    slot.set_factor(value)
    obj.__dict__[name] = Unformed(slot.matrix)


def hooks_of(d: dict) -> Hooks:
    """The filter's :class:`~squkf.plan.Hooks` from its ``__dict__`` (None: filterpy's default)."""
    rx, rz, add = d["residual_x"], d["residual_z"], d["state_add"]
    return Hooks(
        d["x_mean"],
        d["z_mean"],
        None if rx is np.subtract else rx,
        None if rz is np.subtract else rz,
        None if add is np.add else add,
    )
