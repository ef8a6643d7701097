"""A filter's attributes as filterpy keeps them: covariances carried as factors, and edits in place.

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
  :func:`squkf.checks.as_matrix` and :func:`~squkf.checks.as_lower_factor`
  validate what is assigned.
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
from ..checks import (
    as_lower_factor,
    as_matrix,
    check_callable,
    check_flag,
    given_noise_factors,
    noise_factors,
)
from ..errors import SqukfValueError
from ..linalg import factor_covariance
from ..plan import Hooks

__all__ = [
    "Checked",
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


class FactorSlot:
    """One covariance (``P``, ``Q`` or ``R``) held as its lower factor: one filter's, or a fleet's noise.

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
    filters : int or None
        A fleet's noise (``Q`` or ``R`` of ``filters`` filters): shared ``(dim, dim)`` or per filter
        ``(filters, dim, dim)``, assigned through :func:`~squkf.checks.noise_factors` and
        :func:`~squkf.checks.given_noise_factors`. The fleet hands the matrix out and takes its edits
        itself (its :class:`HandOut`): :meth:`matrix` forms it afresh, and the fleet reads the factor as
        the attribute ``S`` (no call in a step). None: one filter's covariance, as described above.
    zero : bool
        A fleet's zero covariance kept as a zero factor, not None (the fleet's ``R``, which every update
        adds).
    """

    def __init__(
        self,
        name: str,
        dim: int | None,
        semidefinite: bool,
        factor: np.ndarray | None,
        filters: int | None = None,
        zero: bool = False,
    ):
        self.name = name
        self.dim = dim
        self.semidefinite = semidefinite
        self.filters, self.zero = filters, zero
        #: the factor as held (None: a zero covariance), edits in place of the matrix not yet looked for
        self.S = factor
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

    def __setstate__(self, state: dict) -> None:
        if "_factor" in state:  # pickled when the factor was private
            state["S"] = state.pop("_factor")
        state.setdefault("filters", None)
        state.setdefault("zero", False)
        self.__dict__.update(state)

    def rows(self, idx) -> FactorSlot:
        """A fleet's noise for the filters ``idx``: a per-filter factor cut, a shared one shared."""
        new = copy.copy(self)
        S = self.S
        if S is not None and S.ndim == 3:
            new.S = S[idx]
        new.filters = len(np.arange(self.filters or 0)[idx])
        return new

    def _size(self) -> int:
        if self.S is not None:
            return self.S.shape[-1]
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
        return self.S

    def _take_matrix(self, A: np.ndarray) -> None:
        self.S = self._factor_of(as_matrix(A, self.name, self.dim))

    def _kept(self, S: np.ndarray | None) -> np.ndarray | None:
        """A fleet's factor as kept: a zero one None, or zeros ``(dim, dim)`` where ``zero``."""
        if self.zero:
            return np.zeros((self._size(),) * 2) if S is None else S
        return S

    def _factor_of(self, A: np.ndarray) -> np.ndarray | None:
        if self.semidefinite and not np.any(A):
            return None
        return factor_covariance(A, self.name, semidefinite=self.semidefinite)

    def matrix(self) -> np.ndarray:
        """The covariance ``S @ S.T``; edits to the returned array take effect at the next step.

        ``(dim, dim)``, or ``(1,)`` when a 1-element vector was assigned (:meth:`set_matrix`). A fleet's
        is formed afresh at each call, ``(dim, dim)`` or ``(filters, dim, dim)``.
        """
        if self.filters is not None:
            S = self.S
            return np.zeros((self._size(),) * 2) if S is None else S @ np.swapaxes(S, -1, -2)
        if self._view is None:
            A = self._assigned
            if A is None:
                S = self.S
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
        matrix is formed ``(dim, dim)``. A fleet's: one matrix for all, or one per filter.
        """
        if self.filters is not None:
            S = noise_factors(value, self.name, self._size(), self.filters)
            self.S = self._kept(S) if self.zero else None if S is None or not np.any(S) else S
            return
        if value is None:
            if not self.semidefinite:
                raise SqukfValueError(f"{self.name} cannot be None")
            self.S, self._view, self._assigned = None, None, None
            return
        A = as_matrix(value, self.name, self.dim)
        S = self._factor_of(A)
        if np.ndim(value) == 1:  # a 1-element vector (dimension 1): handed out as assigned, as filterpy
            A = A.reshape(1)  # does, so that ``R[0]`` is a number; edits in place still reach it
        self.S, self._view, self._assigned = S, None, A

    def set_factor(self, value) -> None:
        """Assign from a lower-triangular factor (validated; a copy is kept)."""
        if self.filters is not None:
            n = self._size()
            self.S = self._kept(given_noise_factors(value, f"{self.name}1_2", n, self.filters))
            return
        if value is None and self.semidefinite:
            self.S, self._view, self._assigned = None, None, None
            return
        S: np.ndarray | None = as_lower_factor(
            value, f"{self.name}1_2", self.dim, singular_ok=self.semidefinite
        )
        if self.semidefinite and not np.any(S):
            S = None
        self.S, self._view, self._assigned = S, None, None

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
    as the same array (with its record, in the instance's :class:`HandOut` ``_handed``) until the next one;
    an assignment is validated by the filter (``_assign_x``, ``_assign_P``). See :class:`Covariance`."""

    def __set_name__(self, owner, name: str):
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        d = obj.__dict__
        value = d[self.name]
        if type(value) is Unformed:
            value = d[self.name] = value.form()
            obj._handed.held[self.name] = Handed(value)
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
    """An option that is on or off (``vectorized``): ``True`` or ``False`` (``checks.check_flag``)."""

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
