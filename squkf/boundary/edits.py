"""Edits in place of the arrays handed out: seen at the next call, and taken through the validating setter.

filterpy code edits a filter's arrays in place as often as it assigns them
(``ukf.P *= 10``, ``ukf.Q[2:4, 2:4] = ...``, ``fleet.x[3] = ...``, also over
several statements). Both faces hand such an array out once and keep it, with
a record of it (:class:`Handed`: its shape, dtype and bytes when handed out or
last taken). At the next call that needs the value behind it, an array that no
longer matches its record was edited: it is given to the attribute's
validating setter, as an assignment would be. If that raises, nothing changes
and the edit stays pending; if it succeeds, the array stays handed out (so
later edits are taken too) with a fresh record.

Used by :class:`squkf.covariance.FactorSlot` (``P``, ``Q``, ``R`` of one
filter), by :class:`squkf.SquareRootUKF`'s ``x`` and, through
:class:`HandOut`, by :class:`squkf.Fleet`'s ``x``, ``P``, ``Q`` and ``R``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable

import numpy as np

__all__ = ["HandOut", "Handed"]


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
    ``drop(name)`` forgets it (the value changed: the array is history);
    ``take(assign)`` gives each edited array to ``assign(name, array)``.
    """

    __slots__ = ("_held",)

    def __init__(self, held: dict[str, Handed] | None = None):
        self._held: dict[str, Handed] = {} if held is None else held

    def array(self, name: str, form: Callable[[], np.ndarray]) -> np.ndarray:
        """The array handed out for ``name``, formed by ``form()`` if none is."""
        held = self._held.get(name)
        if held is None:
            held = self._held[name] = Handed(form())
        return held.array

    def drop(self, name: str) -> None:
        """The value behind ``name`` changed: the array handed out is no longer its."""
        self._held.pop(name, None)

    def take(self, names: Iterable[str], assign: Callable[[str, np.ndarray], object]) -> None:
        """Take the edits in place, in the order of ``names``, through ``assign(name, array)``.

        ``assign`` validates (as an assignment) and may raise: the edits not
        yet taken stay pending. The array stays handed out after its edit is
        taken, even when ``assign`` dropped it.
        """
        held = self._held
        for name in names:
            h = held.get(name)
            if h is not None:
                held[name] = h.take(functools.partial(assign, name))

    def copy(self) -> HandOut:
        """The records as they are now (the arrays the same): what a transaction puts back."""
        return HandOut(dict(self._held))

    def detached(self) -> HandOut:
        """An independent copy: each array copied, pending edits kept (:meth:`Handed.copy`)."""
        return HandOut({name: h.copy() for name, h in self._held.items()})

    def __bool__(self) -> bool:
        return bool(self._held)
