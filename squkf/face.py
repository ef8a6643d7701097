"""The face core: what :class:`squkf.SquareRootUKF` and :class:`squkf.Fleet` share, written once.

Both faces hold an :class:`~squkf.engine.Engine` (one filter a block of one, a fleet a block of K) and
derive from :class:`Face`, which reads the engine's records for them:

- the records of the last prediction and update (``x_prior``, ``P_prior``, ``x_post``, ``P_post``,
  their factors, ``y``, ``nis``, the likelihoods, ``rejected``) as properties (a filterpy ``Saver``
  collects properties), each read from the engine's ``(B, ...)`` record and handed out fresh: a fleet's
  ``(K, ...)``, one filter's with the block axis dropped (scalars as Python floats); the per-step
  records of the registry (``y_whitened``, ``log_det_S1_2``: ``squkf.boundary.records.STEP_RECORDS``)
  are its base's, :class:`~squkf.boundary.records.StepRecords`, read the same way;
- the records filterpy lets a program write (:func:`written_record`: on one filter an assignment
  reads back until the step that makes the record again; a fleet's are read-only);
- the configuration both faces read alike (``fx_noise``, ``hx_noise``, ``gate``, the hooks) and
  :meth:`Face.transaction`;
- copies, deep copies, pickles and the transaction's snapshot, one skeleton for both faces
  (:meth:`Face._copy`, ``__getstate__``, ``__setstate__``, ``_snapshot``, ``_restore``): what each face
  carries, copies, shares or forms again is said by its hooks (``_CARRIED``, ``_dict_for``,
  ``_carried``, ``_unpickled``, ``_rebind``).

A face says what it is by its class attributes ``ONE`` (one filter: the block axis dropped) and
``NO_LOG_LIKELIHOOD`` (the log-likelihood read before any update), and provides ``dim_x``, ``dim_z``
and ``_hooks()`` (the hooks as given).
"""

from __future__ import annotations

import copy
import math
import sys
from collections.abc import Callable
from typing import Any, ClassVar, Literal

import numpy as np

from . import checks
from .boundary.attributes import FactorSlot, HandOut, Hook, Unformed
from .boundary.config import Config
from .boundary.loop import Transaction
from .boundary.records import StepRecord, StepRecords
from .engine import Engine, Route, Update
from .gating import Gate, as_gate
from .kernels.table import KernelTable
from .plan import IDLE, Hooks, Plan
from .weights import WrittenWeights

__all__ = ["Face", "How", "STAMPS", "noise_factor", "own_copy", "restamped", "written_record"]

_TINY = sys.float_info.min

#: what a face's state is taken for: a copy, a deep copy, a pickle, or a transaction's snapshot (which
#: keeps the caller's arrays as they are: a failed call puts back what it may have replaced)
How = Literal["copy", "deep", "pickle", "snapshot"]


def written_record(stamp: str, ndim: int) -> Callable[[Callable], property]:
    """A record filterpy lets a program write, as a ``property`` (a ``Saver`` collects it).

    On one filter an assignment (validated, a private copy kept in ``_written``) reads back, as fresh
    copies, until the step that makes the record again: the engine's attribute ``stamp``
    (``prior_record``, ``post_record``, ``last``) is replaced by that step and nothing else. A fleet's
    record is read-only.

    Parameters
    ----------
    stamp : str
        The engine's attribute the record is current with.
    ndim : int
        The axes an assigned value has (one filter's record).
    """

    def make(form: Callable) -> property:
        name = form.__name__

        def get(self):
            if self.ONE:
                held = self._written.get(name)
                if held is not None and held[0] is getattr(self._engine, stamp):
                    return held[1].copy()
            return form(self)

        def set_(self, value) -> None:
            if not self.ONE:
                raise AttributeError(f"{type(self).__name__}.{name} is a record of the last step: read-only")
            self._written[name] = (getattr(self._engine, stamp), checks.written_record(value, name, ndim))

        return property(get, set_, doc=form.__doc__)

    return make


#: the engine's attribute each written record (or set handed out, one filter's ``sigmas_f`` and
#: ``sigmas_h``) is current with: its stamp
STAMPS = {
    "x_prior": "prior_record", "P_prior": "prior_record", "x_post": "post_record", "P_post": "post_record",
    "y": "last", "S": "last", "SI": "last", "sigmas_f": "shown_f", "sigmas_h": "H",
}  # fmt: skip


def restamped(held: dict, old: Engine, new: Engine, copy_value: Callable | None = None) -> dict:
    """Records written (or sets handed out) of a face on engine ``old``, for its copy on engine ``new``.

    Those still current, each with the copy's stamp and its value through ``copy_value`` (None: the
    same value, as a transaction's snapshot keeps it).
    """
    out = {}
    for name, (stamp, value, *rest) in held.items():
        attr = STAMPS[name]
        if stamp is getattr(old, attr):
            out[name] = (getattr(new, attr), value if copy_value is None else copy_value(value), *rest)
    return out


def own_copy(value: Any, copies: dict[int, np.ndarray]) -> Any:
    """A copy's own value of a face's attribute (what both faces' copies carry).

    An array is copied (once: two attributes that share one share its copy, ``copies`` maps ``id`` to
    copy), the arrays handed out (:class:`~squkf.boundary.attributes.HandOut`) and a noise store
    (:class:`~squkf.boundary.attributes.FactorSlot`) detached, pending edits included; a set or dict
    copied. The rest (the configuration, never changed in place) is shared.
    """
    if isinstance(value, np.ndarray):
        got = copies.get(id(value))
        if got is None:
            got = copies[id(value)] = value.copy()
        return got
    if isinstance(value, (HandOut, FactorSlot)):
        return value.detached()
    if isinstance(value, (set, dict)):
        return type(value)(value)
    return value


def noise_factor(name: str) -> property:
    """``Q1_2`` or ``R1_2`` (``name``: ``"Q"``, ``"R"``), read from and assigned to the face's noise store
    (its :class:`~squkf.boundary.attributes.FactorSlot` ``_Q`` or ``_R``)."""
    slot = "_" + name

    def get(self) -> np.ndarray:
        self._noise_edits()
        return getattr(self, slot).factor_or_zeros().copy()

    def set_(self, value) -> None:
        getattr(self, slot).set_factor(value)  # validated: a failure changes nothing
        self._noise_assigned(name)

    doc = (
        f"Lower factor of ``{name}``, ``(d, d)`` (a fleet's shared, or per filter ``(K, d, d)``); zeros when"
        " there is none (a fresh copy; assign to change)."
    )
    return property(get, set_, doc=doc)


class Face(StepRecords):
    """The core of both faces: the records read from the engine, the shared configuration, the transaction.

    Not for use alone: a face (:class:`squkf.SquareRootUKF`, :class:`squkf.Fleet`) derives from it and
    sets the class attributes below.
    """

    __slots__ = ()

    #: one filter (a block of one whose records drop the block axis), or a fleet's block of K
    ONE: ClassVar[bool]
    #: the log-likelihood read before any update
    NO_LOG_LIKELIHOOD: ClassVar[float]

    _engine: Engine
    _handed: HandOut
    _gate: Gate | None
    _points: Any
    _family: Any
    _generator: Any
    _plan: Plan
    _dt: float | None
    _fx_noise: int
    _hx_noise: int
    _written: dict
    _Q: FactorSlot
    _R: FactorSlot
    dim_x: Any
    dim_z: Any
    hx: Any
    fx: Any
    vectorized: Any  # (one filter's option; a fleet's model functions always take stacked points)

    # -- reading the engine's records ----------------------------------------------

    def _rows(self, a: np.ndarray) -> np.ndarray:
        """A ``(B, ...)`` record as handed out: a copy, one filter's without the block axis."""
        return a[0].copy() if self.ONE else a.copy()

    def _covariance(self, S: np.ndarray) -> np.ndarray:
        """``S @ S.T`` of a ``(B, n, n)`` stack of factors, one filter's without the block axis."""
        if self.ONE:
            s = S[0]
            return s @ s.T
        return S @ np.swapaxes(S, -1, -2)

    def _before_update(self, shape: tuple = (), dtype: Any = float) -> np.ndarray:
        """A record before any update: zeros of ``shape`` per filter (one filter's: of ``shape``)."""
        lead = () if self.ONE else (self._engine.x.shape[0],)
        return np.zeros(lead + shape, dtype=dtype)

    def _scalar(self, a: np.ndarray | None, before: float):
        """A per-filter record ``(B,)`` as handed out (one filter's a float; ``before``: before an update)."""
        if self.ONE:
            return before if a is None else float(a[0])
        return np.full(self._engine.x.shape[0], before) if a is None else a.copy()

    def _in_place(self, a: np.ndarray, observed: np.ndarray | None, m: int, fill) -> np.ndarray:
        """The record ``a`` ``(B, mo)`` of the observed components, in their places of ``m`` (``fill``
        elsewhere), as handed out."""
        if observed is None:
            return self._rows(a)
        out = np.full((a.shape[0], m), fill, dtype=a.dtype)
        out[:, observed] = a
        return out[0] if self.ONE else out

    def _step_record(self, record: StepRecord):
        """A per-step record of the registry (:class:`~squkf.boundary.records.StepRecord`) of the last
        update, as handed out: its observed components in their places (``record.fill`` elsewhere), or one
        number per filter; zeros before any update."""
        last: Update | None = self._engine.last
        if last is None:
            return self._before_update((self.dim_z,)) if record.per_component else self._scalar(None, 0.0)
        value = getattr(last, record.field)
        if value is None:  # (every update holds it: an old pickle's is filled when it loads, old_pickles)
            raise LookupError(f"the last update holds no {record.field!r} for {record.name!r}")
        if record.per_component:
            return self._in_place(value, last.observed, last.m, record.fill)
        return self._scalar(value, 0.0)

    # -- the records of the last prediction and update (formed when read, fresh) -------------

    @written_record("prior_record", 1)
    def x_prior(self) -> np.ndarray:
        """State after the last prediction, ``(dim_x,)`` (a fleet's ``(K, dim_x)``; fresh; one filter's
        writable, as filterpy's)."""
        return self._rows(self._engine.prior_record[0])

    @property
    def P1_2_prior(self) -> np.ndarray:
        """Lower factor of the covariance after the last prediction, ``(..., dim_x, dim_x)`` (fresh)."""
        return self._rows(self._engine.prior_record[1])

    @written_record("prior_record", 2)
    def P_prior(self) -> np.ndarray:
        """Covariance after the last prediction, ``(..., dim_x, dim_x)`` (fresh; one filter's writable)."""
        return self._covariance(self._engine.prior_record[1])

    @written_record("post_record", 1)
    def x_post(self) -> np.ndarray:
        """State after the last update, ``(..., dim_x)`` (fresh; one filter's writable)."""
        return self._rows(self._engine.post_record[0])

    @property
    def P1_2_post(self) -> np.ndarray:
        """Lower factor of the covariance after the last update, ``(..., dim_x, dim_x)`` (fresh)."""
        return self._rows(self._engine.post_record[1])

    @written_record("post_record", 2)
    def P_post(self) -> np.ndarray:
        """Covariance after the last update, ``(..., dim_x, dim_x)`` (fresh; one filter's writable)."""
        return self._covariance(self._engine.post_record[1])

    @written_record("last", 1)
    def y(self) -> np.ndarray:
        """Innovation of the last update, ``(..., dim_z)``; NaN where not measured (fresh; one filter's
        writable). Zeros before any update."""
        last: Update | None = self._engine.last
        if last is None:
            return self._before_update((self.dim_z,))
        return self._in_place(last.y, last.observed, last.m, np.nan)

    @property
    def log_likelihood(self):
        """Log-likelihood of the last measurement (the components it used), from the innovation factor.

        One filter's a float, a fleet's ``(K,)``; 0 when a gate rejected every component, and where a
        fleet's filter had no measurement.
        """
        last = self._engine.last
        return self._scalar(None if last is None else last.log_likelihood, self.NO_LOG_LIKELIHOOD)

    @property
    def likelihood(self):
        """``exp(log_likelihood)``, never below the smallest normal float."""
        if self.ONE:
            return max(math.exp(self.log_likelihood), _TINY)
        last = self._engine.last
        ll = self._before_update() if last is None else last.log_likelihood
        return np.maximum(np.exp(ll), _TINY)

    @property
    def nis(self):
        """Normalised innovation squared of the last update, ``y^T S^-1 y`` (measured components).

        What a gate tests; one filter's a float, a fleet's ``(K,)``; 0 before any update.
        """
        last = self._engine.last
        return self._scalar(None if last is None else last.nis, 0.0)

    @property
    def mahalanobis(self):
        """Mahalanobis distance of the last innovation, ``||S1_2^-1 y||`` (measured components)."""
        if self.ONE:
            return math.sqrt(self.nis)
        last = self._engine.last
        return np.sqrt(self._before_update() if last is None else last.nis)

    @property
    def rejected(self) -> np.ndarray:
        """Which components of the last measurement the gate rejected, ``(..., dim_z)`` (fresh).

        After a gated update ``y``, ``S``, ``S1_2`` are the tested innovation's,
        ``K`` the gain applied (zero columns for rejected components).
        """
        last = self._engine.last
        if last is None:
            return self._before_update((self.dim_z,), bool)
        return self._in_place(last.rejected, last.observed, last.m, False)

    # -- the configuration both faces read alike -------------------------------------

    @property
    def points_fn(self):
        """The sigma-point family (or filterpy points object) of the first set (a fleet's fixed when it is
        built)."""
        return self._points

    @points_fn.setter
    def points_fn(self, points) -> None:
        self._set_points(points)

    @property
    def scheme(self):
        """The second-set generator (``Redrawn()``, ``Augmented()`` or your own; one filter's assignable)."""
        return self._generator

    @scheme.setter
    def scheme(self, value) -> None:
        self._set_scheme(value)

    def _set_points(self, points) -> None:
        raise NotImplementedError

    def _set_scheme(self, value) -> None:
        raise AttributeError(f"{type(self).__name__}.scheme is fixed when it is built")

    @property
    def fx_noise(self) -> int | None:
        """Dimension of the noise ``fx`` takes as its second argument (None: additive noise)."""
        return self._fx_noise or None

    @property
    def hx_noise(self) -> int | None:
        """Dimension of the noise ``hx`` takes as its second argument (None: additive noise)."""
        return self._hx_noise or None

    @property
    def gate(self) -> Gate | None:
        """The outlier gate (None: every measurement is used); assign a probability or a Gate."""
        return self._gate

    @gate.setter
    def gate(self, value) -> None:
        self._gate = as_gate(value)  # type: ignore[misc]  # (each face keeps it: a slot, or its __dict__)
        self._configured()

    def _configured(self) -> None:
        """The plan, a hook or the gate changed: the engine's route is built again (a pending step keeps
        the route it was drawn with)."""
        self._engine.configure(self._new_route())

    def _new_route(self, kernels: KernelTable | None = None) -> Route:
        """This configuration's route, as constants (:class:`~squkf.engine.Route`), on ``kernels`` (None:
        the table of the route it replaces, so that a filter keeps its table through changes and copies;
        the installed one for a new filter)."""
        if kernels is None:
            engine = getattr(self, "_engine", None)  # (none yet while a face's __init__ builds it)
            kernels = None if engine is None else engine.route.kernels
        return Route(self._plan, self._step_hooks(), self._gate, single=self.ONE, kernels=kernels)

    def _use_kernels(self, kernels: KernelTable | None) -> None:
        """This face's phases on the kernel table ``kernels`` (a configuration's, ``Config.kernels``; None:
        as it is)."""
        if kernels is not None:
            self._engine.configure(self._new_route(kernels))

    def _step_hooks(self) -> Hooks:
        """The hooks as the step calls them (a fleet's ``vectorized_hooks`` wrap a user's)."""
        return self._hooks()

    def _hooks(self) -> Hooks:
        """The hooks as given (each face's: one filter's None where filterpy's default is meant)."""
        raise NotImplementedError

    def configuration(self) -> Config:
        """The configuration and noise factors (``squkf.boundary.Config``), edits in place taken.

        What ``Fleet.from_filters``, ``fleet[k]``, the smoother and :mod:`squkf.dask` read; its arrays
        are the face's own, to be read and not written. A fleet's ``step`` is left idle.
        """
        self._noise_edits()
        hooks, family = self._hooks(), self._family
        return Config(
            self.dim_x, self.dim_z, self._dt, self.hx, self.fx,
            family if isinstance(family, WrittenWeights) else self._points,  # (weights written)
            family, self._generator, *hooks, self._gate, self.fx_noise, self.hx_noise,
            self.vectorized if self.ONE else True, self._plan, hooks, self._Q.factor(), self._R.factor(),
            self._engine.phase if self.ONE else IDLE, self._engine.route.kernels,
        )  # fmt: skip

    # -- edits in place: the arrays handed out, taken back at the next call ----------------------

    #: the attributes whose arrays handed out are taken back (validated) at the next call, in order
    _HANDED: ClassVar[tuple[str, ...]]

    def _take_edits(self) -> None:
        """The edits in place of the arrays handed out (``_handed``), validated and taken through
        :meth:`_take_edit`; either may raise, and what is not taken stays pending."""
        if self._handed.held:
            self._handed.take(self._HANDED, self._take_edit)

    def _take_edit(self, name: str, array: np.ndarray) -> None:
        """An array handed out as ``name`` was edited in place: taken as an assignment (may raise)."""
        setattr(self, name, array)

    # -- the noise store: Q and R, each a FactorSlot (one filter's; a fleet's shared or per filter) -------

    Q1_2 = noise_factor("Q")
    R1_2 = noise_factor("R")

    def _noise_edits(self) -> None:
        """Edits in place that reading a noise factor takes first (one filter's slots take their own)."""

    def _noise_assigned(self, name: str) -> None:
        """``Q`` or ``R`` (``name``) was assigned through its factor: the matrix handed out is history."""
        raise NotImplementedError

    # -- the hooks: filterpy's, kept in the __dict__; assigning one builds the engine's route again -----

    x_mean = Hook()
    z_mean = Hook()
    residual_x = Hook()
    residual_z = Hook()
    state_add = Hook()

    def _hooks_assigned(self) -> None:
        try:
            self._engine  # noqa: B018  (not while a face's __init__ sets the hooks: no engine yet)
        except AttributeError:
            return
        self._configured()

    # -- copies, pickles and the transaction of a call: one skeleton, each face's hooks ----------

    #: the slots besides ``_engine`` that copies, pickles and snapshots carry (one filter keeps its
    #: configuration, noise stores and hand-outs in slots; a fleet keeps them in its ``__dict__``)
    _CARRIED: ClassVar[tuple[str, ...]] = ()

    def __copy__(self) -> Any:
        return self._copy(copy.copy(self._engine), "copy")

    def __deepcopy__(self, memo: dict) -> Any:
        return self._copy(None, "deep", memo)

    def _copy(self, engine: Engine | None, how: How, memo: dict | None = None) -> Any:
        """A copy of this face on ``engine`` (None: a deep copy of this face's, through ``memo``).

        Its ``__dict__`` is :meth:`_dict_for`'s, its carried slots :meth:`_carried`'s, and what is formed
        from its own engine and stores is made by :meth:`_rebind`. The engine's copy carries the state and
        any half-done step, its arrays the copy's own (:class:`~squkf.engine.Engine`).
        """
        new = type(self).__new__(type(self))
        if memo is not None:
            memo[id(self)] = new
        d = self._dict_for(how, memo)
        if engine is None:
            engine = copy.deepcopy(self._engine, memo)
        new._engine = engine  # type: ignore[misc]  # (each face's slot)
        new.__dict__.update(d)
        for name, value in self._carried(engine, how).items():
            setattr(new, name, value)
        new._rebind(how)
        return new

    def __getstate__(self) -> dict:
        # the __dict__ (what is formed when read left out), the carried slots, the engine (without buffers)
        state = {k: v for k, v in self.__dict__.items() if type(v) is not Unformed}
        state.update(self._carried(self._engine, "pickle"))
        state["_engine"] = self._engine
        return state

    def __setstate__(self, state: Any) -> None:
        state = self._unpickled(state)
        slots = {name: state.pop(name) for name in ("_engine", *self._CARRIED) if name in state}
        self.__dict__.update(state)
        for name, value in slots.items():
            setattr(self, name, value)
        self._rebind("pickle")

    def transaction(self) -> Transaction:
        """A context manager that puts the filter back as it was on entry if anything inside raises.

        What ``batch_filter`` runs its steps in (``squkf.boundary.loop.Transaction``).
        """
        return Transaction(self._snapshot, self._restore)

    def _snapshot(self) -> tuple[dict, dict, Engine]:
        # the engine's arrays are replaced by each step, never changed in place: its copy keeps them
        engine = copy.copy(self._engine)
        return self._dict_for("snapshot", None), self._carried(engine, "snapshot"), engine

    def _restore(self, saved: tuple[dict, dict, Engine]) -> None:
        d, kept, engine = saved
        self.__dict__.clear()
        self.__dict__.update(d)
        for name, value in kept.items():
            setattr(self, name, value)
        self._engine = engine  # type: ignore[misc]  # (each face's slot)
        self._rebind("snapshot")

    # the hooks of the skeleton (a fleet's here: everything in its __dict__, nothing formed again)

    def _dict_for(self, how: How, memo: dict | None) -> dict:
        """The ``__dict__`` of a copy (``how``) or of a snapshot: each value :func:`own_copy`'s (a deep copy
        too: the model functions and hooks shared), the arrays handed out by a snapshot kept as they are
        (:meth:`~squkf.boundary.attributes.HandOut.copy`)."""
        copies: dict[int, np.ndarray] = {}
        snapshot = how == "snapshot"
        return {
            k: v.copy() if snapshot and type(v) is HandOut else own_copy(v, copies)
            for k, v in self.__dict__.items()
        }

    def _carried(self, engine: Engine, how: How) -> dict:
        """The carried slots (``_CARRIED``) by name, as a copy, a pickle or a snapshot (``how``) on ``engine``
        takes them: a copy's :func:`own_copy`'s, a pickle's and a snapshot's as they are."""
        own = {name: getattr(self, name) for name in self._CARRIED}
        if how in ("pickle", "snapshot"):
            return own
        copies: dict[int, np.ndarray] = {}
        return {name: own_copy(value, copies) for name, value in own.items()}

    def _unpickled(self, state: Any) -> dict:
        """A pickle's state as :meth:`__getstate__` makes it today (an older layout converted)."""
        return state

    def _rebind(self, how: How | None = None) -> None:
        """After construction (``how`` None), a copy, a pickle loaded or a snapshot put back: what is formed
        from this face's own engine and stores, made again."""
