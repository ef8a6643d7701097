"""One filter's ``x``, ``P``, ``Q`` and ``R`` as filterpy's ``__dict__`` holds them.

:class:`squkf.SquareRootUKF` keeps its estimate in the engine (a block of one) and its noise in factor
slots, but a filterpy program (and filterpy's ``Saver``, which deep-copies the ``__dict__``) finds
``x``, ``P``, ``Q`` and ``R`` in the instance's ``__dict__``, behind the data descriptors of
:mod:`squkf.boundary.attributes`. :class:`FilterState` is what that layout needs of the filter: ``x``
and ``P`` formed from the engine when first read after a step (``Unformed`` until then) and handed
out as the same array until the next step, an assignment or an edit in place validated and taken into
the engine, a placeholder (``None``, all NaN) kept as given and refused by a step until it is
replaced (:ref:`promise-placeholders`), ``P1_2``, and the noise factors a step takes (the filter's, or
a call's own ``Q`` or ``R``).
"""

from __future__ import annotations

import numpy as np

from . import checks
from .boundary.attributes import FactorSlot, Handed, Unformed
from .checks import as_lower_factor, noise_factor
from .errors import UnsetError
from .face import Face

__all__ = ["FilterState"]

_REAL = checks.REAL


class FilterState(Face):
    """One filter's ``x``, ``P`` (hand-outs and placeholders), ``P1_2`` and noise factors.

    A base class of :class:`squkf.SquareRootUKF`, holding no state of its own: the slots it reads
    (``_engine``, ``_handed``, ``_unset``, ``_unformed``, ``_Q``, ``_R``, ``_noise_cache``) are the
    filter's.
    """

    __slots__ = ()

    _unset: set
    _unformed: tuple
    _noise_cache: dict
    _dim_x: int
    _dim_z: int

    def _formed_x(self) -> np.ndarray:
        """``x`` as handed out: a copy of the estimate."""
        return self._engine.x[0].copy()

    def _formed_P(self) -> np.ndarray:
        """``P`` as handed out: the estimate's covariance, formed from its factor."""
        S = self._engine.S[0]
        return S @ S.T

    def _stepped(self) -> None:
        """The engine has a new estimate: ``x`` and ``P`` are formed from it when read."""
        d = self.__dict__
        d["x"], d["P"] = self._unformed
        self._handed.held.clear()  # (the arrays handed out for the old estimate are history)

    def _assign_x(self, value) -> None:
        """``x = value``, validated: the engine's estimate, ``x`` formed again when read.

        ``None`` or an all-NaN array is a placeholder (:func:`checks.placeholder`): ``x`` is then not
        set, reads back as assigned, and a step refuses until it is.
        """
        kept = checks.placeholder(value, "x", (self._dim_x,))
        if kept is not _REAL:
            self._unset_as("x", kept)
            return
        x = checks.as_state(value, "x", self._dim_x)
        self._engine.assign(x=x[None])
        self.__dict__["x"] = self._unformed[0]
        self._handed.drop("x")
        self._unset.discard("x")

    def _assign_P(self, value) -> None:
        """``P = value``, validated and factored once; handed out as assigned (a copy).

        A placeholder (``None``, all NaN) leaves ``P`` not set, as :meth:`_assign_x` says.
        """
        kept = checks.placeholder(value, "P", (self._dim_x, self._dim_x))
        if kept is not _REAL:
            self._unset_as("P", kept)
            return
        slot = FactorSlot("P", self._dim_x, semidefinite=False, factor=None)
        slot.set_matrix(value)
        self._engine.assign(S=slot.factor()[None])  # type: ignore[index]  # P is never singular
        P = self.__dict__["P"] = slot.matrix()
        self._handed.held["P"] = Handed(P)
        self._unset.discard("P")

    def _unset_as(self, name: str, kept: np.ndarray | None) -> None:
        """``x`` or ``P`` is a placeholder, ``kept`` (None, or an all-NaN copy handed out for edits)."""
        self.__dict__[name] = kept
        if kept is None:
            self._handed.drop(name)
        else:
            self._handed.held[name] = Handed(kept)
        self._unset.add(name)

    def _take_edit(self, name: str, array: np.ndarray) -> None:
        """An array handed out as ``x`` or ``P`` was edited in place: validated and taken into the engine
        (may raise). The array stays handed out, with a fresh record; a placeholder edited in place is an
        assignment too (still all NaN: still not set)."""
        n = self._dim_x
        if checks.placeholder(array, name, (n,) if name == "x" else (n, n)) is not _REAL:
            self._unset.add(name)
            return
        if name == "x":
            x = checks.as_state(array, "x", n)
            self._engine.assign(x=x[None])
        else:
            slot = FactorSlot("P", n, semidefinite=False, factor=None)
            slot.set_matrix(array)
            self._engine.assign(S=slot.factor()[None])  # type: ignore[index]  # P is never singular
        self._unset.discard(name)

    def _ready(self, call: str) -> None:
        """Edits in place taken; refuse a step while ``x`` or ``P`` is a placeholder (changes nothing)."""
        if self._handed.held:  # handed out since the step: edits are taken
            self._take_edits()
        if self._unset:
            self._refuse_unset(call)

    def _refuse_unset(self, call: str) -> None:
        """Raise the UnsetError of a step that meets ``x`` or ``P`` not set (if one is not)."""
        if self._unset:
            name = "x" if "x" in self._unset else "P"
            raise UnsetError(
                f"{call} needs {name}, but {name} was never set: it holds the placeholder"
                f" {'None' if self.__dict__[name] is None else 'all NaN'}; assign the initial {name}"
                " first"
            )

    @property
    def P1_2(self) -> np.ndarray:
        """Lower Cholesky factor of ``P`` (a fresh copy; assign to change); all NaN while ``P`` is not set."""
        self._take_edits()
        if "P" in self._unset:
            return np.full((self._dim_x,) * 2, np.nan)
        return self._engine.S[0].copy()

    @P1_2.setter
    def P1_2(self, value):
        S = as_lower_factor(value, "P1_2", self._dim_x, singular_ok=False)
        self._engine.assign(S=S[None])
        self.__dict__["P"] = self._unformed[1]
        self._handed.drop("P")
        self._unset.discard("P")

    def _noise_assigned(self, name: str) -> None:
        self.__dict__[name] = Unformed(getattr(self, "_" + name).matrix)

    def _noise_factor(self, value, name: str, dim: int) -> np.ndarray | None:
        """Lower factor of ``Q`` or ``R`` (``value`` for this call, else the attribute's); None: zero."""
        return noise_factor(value, name, dim, getattr(self, "_" + name).factor, self._noise_cache)

    def _Q1_2(self, Q) -> np.ndarray | None:
        """The prediction's process-noise factor: this call's ``Q``, else the filter's (None: none added)."""
        if Q is None:
            return self._Q.factor()  # of the state's dimension: the slot's fixed size
        return self._noise_factor(Q, "Q", self._dim_x)

    def _R1_2(self, R, m: int) -> np.ndarray:
        """The update's measurement-noise factor ``(m, m)``: this call's ``R``, else the filter's."""
        S = self._R.factor() if (R is None and m == self._dim_z) else self._noise_factor(R, "R", m)
        return np.zeros((m, m)) if S is None else S

    def _R_dim(self) -> int:
        return self._R.factor_or_zeros().shape[0]
