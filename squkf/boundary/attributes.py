"""One filter's attributes kept in its ``__dict__``, as filterpy keeps them: read, set, copied, pickled.

filterpy's ``Saver`` deep-copies a filter's ``__dict__`` at each step, so the
arrays a caller reads (``x``, ``P``, ``Q``, ``R``) and the hooks live there,
behind data descriptors (not properties, whose values a ``Saver`` would keep
by reference). The truth behind ``P``, ``Q``, ``R`` is a
:class:`~squkf.covariance.FactorSlot` (``_P``, ``_Q``, ``_R``); the truth
behind ``x`` is the validated state ``_xs``, with the array handed out and its
record in ``_x`` (:class:`~squkf.boundary.edits.Handed`): an edit in place is
taken at the next call (:func:`current_state`).

:class:`InDictCopies` copies, snapshots and pickles such a ``__dict__``.
"""

from __future__ import annotations

import copy

import numpy as np

from ..covariance import FactorSlot
from ..plan import Hooks
from .edits import Handed
from .inputs import as_state

__all__ = [
    "COVARIANCES",
    "Covariance",
    "Hook",
    "InDictCopies",
    "State",
    "Unformed",
    "commit_estimate",
    "current_state",
    "hooks_of",
    "initial",
    "set_factor",
    "set_state",
]

COVARIANCES = ("P", "Q", "R")


class Covariance:
    """``P``, ``Q`` or ``R``: a matrix kept in the instance's ``__dict__``, backed by a factor slot.

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
        value = obj.__dict__[self.name]
        if isinstance(value, Unformed):
            value = obj.__dict__[self.name] = value.slot.matrix()
        return value

    def __set__(self, obj, value):
        slot = obj.__dict__[self.slot]
        slot.set_matrix(value)
        obj.__dict__[self.name] = slot.matrix()
        obj._covariance_assigned(self.name)


class Unformed:
    """Stands in the ``__dict__`` for a matrix nobody has read since the step changed its factor.

    Reading the attribute forms the matrix (:class:`Covariance`); a deep copy
    of the ``__dict__`` (what filterpy's ``Saver`` takes) gets the matrix
    itself, so a saved history holds arrays, formed only when saved.
    """

    __slots__ = ("slot",)

    def __init__(self, slot: FactorSlot):
        self.slot = slot

    def __deepcopy__(self, memo):
        return self.slot.matrix().copy()

    def __copy__(self):
        return self.slot.matrix().copy()


class InDict:
    """A data descriptor over the instance's ``__dict__`` entry of its own name; subclasses set it."""

    def __set_name__(self, owner, name: str):
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        return obj.__dict__[self.name]


class State(InDict):
    """``x``: the state vector kept in the instance's ``__dict__`` (see :class:`Covariance`)."""

    def __set__(self, obj, value):
        set_state(obj.__dict__, as_state(value, "x", obj.dim_x))
        obj._covariance_assigned("x")


class Hook(InDict):
    """A hook (``residual_x``, ``state_add``, ...) kept in the instance's ``__dict__``, as filterpy's.

    Setting one drops the :class:`~squkf.plan.Hooks` tuple the filter built
    from them (:func:`hooks_of`), so that a step reads that tuple (twice a
    step) without gathering the five attributes again.
    """

    def __set__(self, obj, value):
        d = obj.__dict__
        d[self.name] = value
        d["_hooks_cache"] = None


def initial(d: dict, n: int, m: int, q: int, r: int, N: int) -> None:
    """Fill a new filter's ``__dict__``: ``x = 0``, ``P``, ``Q``, ``R`` identities, the records of no step.

    Parameters
    ----------
    d : dict
    n, m : int
        State and measurement dimensions.
    q, r : int
        The dimensions of ``Q`` and ``R`` (the noise's own when it enters ``fx``, ``hx``).
    N : int
        Number of sigma points of the first set (``sigmas_f``, ``sigmas_h``).
    """
    d["_P"] = FactorSlot("P", n, semidefinite=False, factor=np.eye(n))
    d["_Q"] = FactorSlot("Q", q, semidefinite=True, factor=np.eye(q))
    d["_R"] = FactorSlot("R", r, semidefinite=True, factor=np.eye(r))
    for name in COVARIANCES:
        d[name] = d["_" + name].matrix()
    set_state(d, np.zeros(n))
    d["x_prior"], d["P1_2_prior"] = np.zeros(n), np.eye(n)
    d["x_post"], d["P1_2_post"] = np.zeros(n), np.eye(n)
    d["sigmas_f"], d["sigmas_h"] = np.zeros((N, n)), np.zeros((N, m))
    d["y"], d["z"] = np.zeros(m), np.array([[None] * m]).T


def set_factor(d: dict, name: str, value) -> None:
    """Assign ``P1_2``, ``Q1_2`` or ``R1_2`` (``name``: ``"P"``, ``"Q"``, ``"R"``), validated."""
    slot = d["_" + name]
    slot.set_factor(value)
    d[name] = slot.matrix()


def hooks_of(d: dict) -> Hooks:
    """The filter's :class:`~squkf.plan.Hooks` from its ``__dict__`` (built once after a hook was set)."""
    hooks = d["_hooks_cache"]
    if hooks is None:
        rx, rz, add = d["residual_x"], d["residual_z"], d["state_add"]
        hooks = d["_hooks_cache"] = Hooks(
            d["x_mean"],
            d["z_mean"],
            None if rx is np.subtract else rx,
            None if rz is np.subtract else rz,
            None if add is np.add else add,
        )
    return hooks


def set_state(d: dict, x: np.ndarray) -> None:
    """Install the validated state ``x`` (kept, not copied) and hand out a copy of it as ``x``."""
    d["_xs"] = x
    handed = d["_x"] = Handed(x.copy())
    d["x"] = handed.array


def current_state(d: dict, dim_x: int) -> tuple[np.ndarray, np.ndarray]:
    """The current mean and factor, with the edits in place of ``x`` and ``P`` validated and taken.

    Parameters
    ----------
    d : dict
        The filter's ``__dict__``.
    dim_x : int

    Returns
    -------
    x : ndarray, shape (dim_x,)
    S : ndarray, shape (dim_x, dim_x)
        The filter's own arrays, to be read and not written.
    """
    d["_x"] = d["_x"].take(lambda a: d.__setitem__("_xs", as_state(a, "x", dim_x)))
    return d["_xs"], d["_P"].factor()


def commit_estimate(d: dict, x: np.ndarray, S: np.ndarray) -> None:
    """Install a mean and factor computed by the filter (fresh arrays handed out; ``P`` formed when read)."""
    set_state(d, x)
    slot = d["_P"]
    slot.set_trusted_factor(S)
    d["P"] = Unformed(slot)  # formed when read: most steps nobody reads P


class InDictCopies:
    """Copies, snapshots and pickles of a filter whose attributes live in its ``__dict__`` as laid out here.

    A base of :class:`squkf.SquareRootUKF`: ``copy.copy`` gives an independent
    filter (arrays and covariance slots copied, functions and configuration
    objects shared, as ``copy.copy`` of a filterpy filter shares them; an
    edit in place pending here is pending in the copy), ``copy.deepcopy`` a
    deep copy whose matrices are its own slots', a pickle leaves the caches
    and the matrices nobody formed out. ``_snapshot``/``_restore`` are what a
    transaction (:class:`squkf.boundary.loop.Transaction`) puts back.
    """

    def _snapshot(self) -> dict:
        # the filter's own arrays are replaced by each step, never changed in place; only
        # the covariance slots, whose matrices the caller may edit in place, are copied
        state = dict(self.__dict__)
        for name in COVARIANCES:
            slot = state["_" + name] = copy.copy(state["_" + name])
            if isinstance(state[name], Unformed):
                state[name] = Unformed(slot)
        return state

    def _restore(self, state: dict) -> None:
        self.__dict__.clear()
        self.__dict__.update(state)

    def __copy__(self):
        d = {}
        for key, value in self.__dict__.items():
            if isinstance(value, np.ndarray):
                value = value.copy()
            elif isinstance(value, FactorSlot):
                value = value.detached()  # the factor shared, the matrix handed out copied
            elif isinstance(value, Handed):
                value = value.copy()
            d[key] = value
        d["x"] = d["_x"].array
        for name in COVARIANCES:
            d[name] = d["_" + name].matrix()
        new = type(self).__new__(type(self))
        new.__dict__.update(d)
        return new

    def __deepcopy__(self, memo):
        new = type(self).__new__(type(self))
        memo[id(self)] = new
        d = copy.deepcopy(self.__dict__, memo)
        for name in COVARIANCES:
            if isinstance(self.__dict__[name], Unformed):  # the copy's matrix is its slot's
                d[name] = d["_" + name].matrix()
        new.__dict__.update(d)
        return new

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_noise_cache"] = {}
        for name in COVARIANCES:
            if isinstance(state[name], Unformed):
                del state[name]  # formed again from the slot when unpickled
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        for name in COVARIANCES:
            self.__dict__[name] = self.__dict__["_" + name].matrix()
