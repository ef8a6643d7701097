"""filterpy's records of one filter's last step that are not the core's, and the weights it may write.

What a filterpy program reads of its ``UnscentedKalmanFilter`` besides the estimate, formed from the
engine's last records when read and handed out fresh (:ref:`promise-records`): the innovation's
factor ``S1_2``, ``S`` and ``SI``, the gain ``K`` (formed once per update), the sets ``sigmas_f`` and
``sigmas_h`` (one array per set, :ref:`promise-sigmas`), and the first set's weights ``Wm`` and
``Wc``. Each of them may be written, as in filterpy: ``S``, ``SI`` and ``K`` read back until the next
update; a ``sigmas_f`` written or changed in place is the set of the next update; weights written
serve every later step (a new plan built over them).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from . import checks
from .boundary.attributes import Handed
from .boundary.records import embed, innovation_inverse
from .checks import check_values
from .engine import Update
from .errors import NonFiniteError, ParameterError, ShapeError
from .face import Face, written_record
from .measurement import gain_from_factors
from .plan import build_plan
from .weights import WrittenWeights

__all__ = ["FilterRecords"]


class FilterRecords(Face):
    """One filter's ``S1_2``, ``S``, ``SI``, ``K``, ``sigmas_f``, ``sigmas_h``, ``Wm`` and ``Wc``.

    A base class of :class:`squkf.SquareRootUKF`, holding no state of its own: what was written or
    handed out lives in the filter's slots (``_written``, ``_sigmas``, ``_gain_of``).
    """

    __slots__ = ()

    _sigmas: dict
    _gain_of: tuple
    _dim_x: int
    _dim_z: int
    inv: Callable

    # -- the first set's weights, writable ------------------------------------------------

    @property
    def Wm(self) -> np.ndarray:
        """Mean weights of the first sigma-point set, shape ``(N,)`` (a copy).

        Writable, as filterpy's: the weights written are used by every later step (the family's unit
        points kept), or refused naming ``points`` where they cannot serve (:ref:`promise-records`).
        """
        return self._plan.first.rows.Wm.copy()

    @Wm.setter
    def Wm(self, value) -> None:
        self._write_weights(value, self._plan.first.rows.Wc)

    @property
    def Wc(self) -> np.ndarray:
        """Covariance weights of the first sigma-point set, shape ``(N,)`` (a copy; writable, as ``Wm``)."""
        return self._plan.first.rows.Wc.copy()

    @Wc.setter
    def Wc(self, value) -> None:
        self._write_weights(self._plan.first.rows.Wm, value)

    def _write_weights(self, Wm, Wc) -> None:
        """New weights of the first set (and of a redrawn second set that has none of its own)."""
        first = self._plan.first.rows
        N = first.Wm.shape[0]
        Wm, Wc = (checks.written_record(w, name, 1) for w, name in ((Wm, "Wm"), (Wc, "Wc")))
        for w, name in ((Wm, "Wm"), (Wc, "Wc")):
            if w.shape != (N,):
                raise ShapeError(f"{name} has shape {w.shape}, expected ({N},): one weight per sigma point")
            if not np.all(np.isfinite(w)):
                raise NonFiniteError(f"{name} contains NaN or inf: {w!r}")
        if np.array_equal(Wm, first.Wm) and np.array_equal(Wc, first.Wc):
            return  # (a program writing back the weights it read)
        family = self._family
        base = family.base if isinstance(family, WrittenWeights) else family
        written = WrittenWeights(base, self._dim_x, Wm, Wc)
        try:
            plan = build_plan(written, self._generator, self._dim_x, self._fx_noise, self._hx_noise)
        except ParameterError as exc:
            raise ParameterError(
                f"points={self._points!r} with the weights written as Wm and Wc cannot serve this filter"
                f" ({exc}); give points= a family with those weights"
            ) from None
        self._family, self._plan = written, plan  # type: ignore[misc]  # (the filter's slots)
        self._configured()

    # -- the records of the last update and the sets (formed when read) ------------------

    @property
    def sigmas_f(self) -> np.ndarray:
        """The second set after a prediction (filterpy's ``sigmas_f``), shape ``(N2, dim_x)``.

        The same array at every read until a step makes a new set (:ref:`promise-sigmas`); a set
        written here, or this array changed in place, is the set of the next ``update``.
        """
        return self._handed_sigmas("sigmas_f").array

    @sigmas_f.setter
    def sigmas_f(self, value) -> None:
        self._write_sigmas("sigmas_f", value)

    @property
    def sigmas_h(self) -> np.ndarray:
        """``hx`` at the second set in the last update, ``(N2, dim_z)``; one array until the next update."""
        return self._handed_sigmas("sigmas_h").array

    @sigmas_h.setter
    def sigmas_h(self, value) -> None:
        self._write_sigmas("sigmas_h", value)

    def _handed_sigmas(self, name: str) -> Handed:
        """The array handed out as ``sigmas_f`` or ``sigmas_h`` since the step that made the set (made now
        if none is), with the record it was handed out with."""
        e = self._engine
        stamp = e.shown_f if name == "sigmas_f" else e.H
        held = self._sigmas.get(name)
        if held is None or held[0] is not stamp:
            assert stamp is not None  # (one filter's engine keeps both sets)
            held = self._sigmas[name] = (stamp, Handed(stamp[0].copy()), False)
        return held[1]

    def _write_sigmas(self, name: str, value) -> None:
        e = self._engine
        stamp = e.shown_f if name == "sigmas_f" else e.H
        A = checks.written_record(value, name, 2)
        if name == "sigmas_f" and A.shape[1:] != (self._dim_x,):
            raise ShapeError(f"sigmas_f has shape {A.shape}, expected (N, dim_x={self._dim_x})")
        self._sigmas[name] = (stamp, Handed(A), True)

    def _given_set(self, expected: tuple) -> np.ndarray | None:
        """The set written as ``sigmas_f`` (or changed in place) since the prediction, for the update to
        use (validated: ``expected`` is the set's shape); None if it was not."""
        held = self._sigmas.get("sigmas_f")
        if held is None or held[0] is not self._engine.shown_f:
            return None
        stamp, handed, written = held
        if not (written or handed.edited()):
            return None
        return check_values(handed.array, expected, "sigmas_f")

    def _set_used(self) -> None:
        """The update used the set written as ``sigmas_f``: it reads back, and is not used again."""
        stamp, handed, _ = self._sigmas["sigmas_f"]
        self._sigmas["sigmas_f"] = (stamp, Handed(handed.array), False)

    def _last(self) -> Update | None:
        return self._engine.last

    def _Sy(self) -> tuple[np.ndarray, np.ndarray | None]:
        last = self._last()
        if last is None:
            m = self._dim_z
            return np.zeros((m, m)), None
        assert last.Sy is not None  # (one filter's update keeps its factors)
        return last.Sy[0], last.observed

    @property
    def S1_2(self) -> np.ndarray:
        """Lower factor of the last innovation covariance (NaN where a component was missing)."""
        Sy, observed = self._Sy()
        return embed(Sy, observed, np.nan)

    @written_record("last", 2)
    def S(self) -> np.ndarray:
        """Innovation covariance of the last update, ``S1_2 @ S1_2.T`` (NaN where missing)."""
        Sy, observed = self._Sy()
        return embed(Sy @ Sy.T, observed, np.nan)

    @written_record("last", 2)
    def SI(self) -> np.ndarray:
        """Inverse of ``S``, by triangular solves with ``S1_2`` (or by ``self.inv`` if replaced)."""
        if self.inv is not np.linalg.inv:
            return self.inv(self.S)
        Sy, observed = self._Sy()
        return innovation_inverse(Sy, observed)

    @property
    def K(self) -> np.ndarray:
        """Kalman gain of the last update, shape ``(dim_x, dim_z)`` (zero columns where missing).

        Formed once per update; a fresh copy on each read (:ref:`promise-records`).
        """
        last, K = self._gain_of
        if K is None or last is not self._last():
            last = self._last()
            K = self._gain(last)
            self._gain_of = (last, K)  # type: ignore[misc]  # (the filter's slot)
        return K.copy()

    @K.setter
    def K(self, value):
        self._gain_of = (self._last(), checks.written_record(value, "K", 2))  # read as fresh copies

    def _gain(self, last: Update | None) -> np.ndarray:
        n = self._dim_x
        if last is None:
            return np.zeros((n, self._dim_z))
        assert last.Sy is not None and last.L21 is not None  # (one filter's update keeps its factors)
        if last.K is not None:
            K = last.K[0]
        else:  # (the route's kernel table: a gain is a phase of this filter's step, read late)
            K = gain_from_factors(last.Sy[0], last.L21[0], kernels=self._engine.route.kernels)
        if last.observed is None:
            return K
        full = np.zeros((n, last.m))
        full[:, last.observed] = K
        return full
