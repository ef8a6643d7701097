"""One filter's attributes kept in its ``__dict__``, as filterpy keeps them, formed when read.

filterpy's ``Saver`` deep-copies a filter's ``__dict__`` at each step, so the
arrays a caller reads and may edit in place (``x``, ``P``, ``Q``, ``R``) and the
hooks live there, behind data descriptors (not properties, whose values a
``Saver`` would keep by reference). Until read, an array is :class:`Unformed`
there: formed when read (or when a ``Saver`` copies the ``__dict__``), and then
handed out as the same array until the value behind it changes, with a record
(:class:`~squkf.boundary.edits.Handed`) by which an edit in place is seen at
the next call. The truth behind ``x`` and ``P`` is the engine's estimate (the
records ``_x`` and ``_Ph``), the truth behind ``Q`` and ``R`` a
:class:`~squkf.covariance.FactorSlot` (``_Q``, ``_R``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..covariance import FactorSlot
from ..plan import Hooks
from .edits import Handed

__all__ = ["NOISES", "Covariance", "Estimate", "Hook", "Unformed", "hooks_of", "initial", "set_factor"]

NOISES = ("Q", "R")


class Unformed:
    """Stands in the ``__dict__`` for an array nobody has read since the step changed it.

    Reading the attribute forms it (:class:`Covariance`, :class:`State`); a deep
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
        d = obj.__dict__
        value = d[self.name]
        if type(value) is Unformed:
            value = d[self.name] = d[self.slot].matrix()
        return value

    def __set__(self, obj, value):
        d = obj.__dict__
        slot = d[self.slot]
        slot.set_matrix(value)
        d[self.name] = Unformed(slot.matrix)


class Estimate:
    """``x`` or ``P``: formed from the filter's estimate when first read after a step, and handed out
    as the same array (with its record, ``_x`` or ``_Ph``) until the next one; an assignment is
    validated by the filter (``_assign_x``, ``_assign_P``). See :class:`Covariance`."""

    def __set_name__(self, owner, name: str):
        self.name = name
        self.record = "_x" if name == "x" else "_Ph"

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        d = obj.__dict__
        value = d[self.name]
        if type(value) is Unformed:
            value = value.form()
            d[self.name], d[self.record] = value, Handed(value)
        return value

    def __set__(self, obj, value):
        getattr(obj, "_assign_" + self.name)(value)


class Hook:
    """A hook (``residual_x``, ``state_add``, ...) kept in the instance's ``__dict__``, as filterpy's.

    Setting one tells the filter (``_hooks_assigned``), which builds its
    :class:`~squkf.plan.Hooks` again.
    """

    def __set_name__(self, owner, name: str):
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        return obj.__dict__[self.name]

    def __set__(self, obj, value):
        obj.__dict__[self.name] = value
        obj._hooks_assigned()


def initial(d: dict, n: int, m: int, q: int, r: int) -> None:
    """Fill a new filter's ``__dict__``: ``Q``, ``R`` identities (``x`` and ``P`` are the engine's).

    Parameters
    ----------
    d : dict
    n, m : int
        State and measurement dimensions.
    q, r : int
        The dimensions of ``Q`` and ``R`` (the noise's own when it enters ``fx``, ``hx``).
    """
    for name, dim in (("Q", q), ("R", r)):
        slot = d["_" + name] = FactorSlot(name, dim, semidefinite=True, factor=np.eye(dim))
        d[name] = Unformed(slot.matrix)
    d["z"] = np.array([[None] * m]).T


def set_factor(d: dict, name: str, value) -> None:
    """Assign ``Q1_2`` or ``R1_2`` (``name``: ``"Q"``, ``"R"``), validated."""
    slot = d["_" + name]
    slot.set_factor(value)
    d[name] = Unformed(slot.matrix)


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
