"""A fleet's ``x``, ``P``, ``Q`` and ``R`` as it hands them out: ``(K, ...)`` arrays, edits in place taken.

What :class:`squkf.Fleet` hands out of its estimates (the engine's ``(K, ...)`` state) and noise
(its ``FactorSlot`` stores, shared ``(d, d)`` or per filter ``(K, d, d)``): each read through the
fleet's :class:`~squkf.boundary.attributes.HandOut`, so the array handed out is the same until the
state changes and an edit in place is taken (validated) at the next call (:ref:`promise-edits`); an
assignment of one row's shape is given to every filter, and an all-NaN row of ``x`` or ``P`` is a
placeholder that the next step flags (one filter's counterpart: :mod:`squkf.ukf_state`).
"""

from __future__ import annotations

import numpy as np

from . import checks
from .checks import covariance_factors, lower_factors
from .face import Face

__all__ = ["FleetState"]


class FleetState(Face):
    """A fleet's ``x``, ``P1_2``, ``P``, ``Q`` and ``R``: handed out, assigned, edited in place.

    A base class of :class:`squkf.Fleet`, holding no state of its own: what it reads and writes
    (``_engine``, ``_handed``, ``_Q``, ``_R``, ``_unset_x``, ``_unset_P``) is the fleet's.
    """

    __slots__ = ()

    _K: int
    _n: int
    _unset_x: np.ndarray
    _unset_P: np.ndarray

    @property
    def x(self) -> np.ndarray:
        """States, shape ``(K, dim_x)``."""
        return self._handed.array("x", self._engine.x.copy)

    @x.setter
    def x(self, value):
        x, self._unset_x = checks.per_filter(value, "x", self._K, (self._n,), placeholders=True)
        self._engine.assign(x=x, idle=True)
        self._handed.drop("x")  # the array handed out is history

    @property
    def P1_2(self) -> np.ndarray:
        """Lower factors of the covariances, shape ``(K, dim_x, dim_x)`` (fresh; assign to change)."""
        self._take_edits()
        return self._engine.S.copy()

    @P1_2.setter
    def P1_2(self, value):
        self._engine.assign(S=lower_factors(value, "P1_2", self._n, self._K), idle=True)
        self._unset_P = np.zeros(self._K, dtype=bool)
        self._handed.drop("P")

    @property
    def P(self) -> np.ndarray:
        """Covariances, shape ``(K, dim_x, dim_x)``."""
        S = self._engine.S
        return self._handed.array("P", lambda: S @ np.swapaxes(S, -1, -2))

    @P.setter
    def P(self, value):
        S, self._unset_P = covariance_factors(value, "P", self._n, self._K, placeholders=True)
        self._engine.assign(S=S, idle=True)
        self._handed.drop("P")

    @property
    def Q(self) -> np.ndarray:
        """Process noise, shared ``(d, d)`` or per filter ``(K, d, d)``.

        ``d`` is ``dim_x``, or ``fx_noise`` when the noise enters ``fx`` (then ``Q`` is w's covariance).
        """
        return self._handed.array("Q", self._Q.matrix)

    @Q.setter
    def Q(self, value):
        self._Q.set_matrix(value)
        self._handed.drop("Q")

    @property
    def R(self) -> np.ndarray:
        """Measurement noise, shared ``(m, m)`` or per filter ``(K, m, m)``."""
        return self._handed.array("R", self._R.matrix)

    @R.setter
    def R(self, value):
        self._R.set_matrix(value)
        self._handed.drop("R")

    def _noise_edits(self) -> None:
        self._take_edits()

    def _noise_assigned(self, name: str) -> None:
        self._handed.drop(name)
