"""``Fleet``: K independent square-root UKFs with one model, advanced in one array step.

Every filter of a fleet runs the same step as :class:`squkf.SquareRootUKF`
(the engine's route, :class:`squkf.engine.Route`, over a plan of
:mod:`squkf.plan`), on arrays with a leading filter axis: states ``(K, n)``,
factors ``(K, n, n)``, sigma points ``(K, N, n)``, a chunk of filters at a
time (:mod:`squkf.stacks`). The model functions are called once per chunk
with the points of its filters; a function written with ``X[..., i]``
indexing serves a fleet and ``SquareRootUKF(vectorized=True)`` alike.

A numerical failure of one filter is that filter's alone: it is flagged (:attr:`Fleet.failed`,
:attr:`Fleet.failure`), keeps its state, and the others go on (``docs/api/fleet.rst``, "Failure
isolation", says the whole rule).

This module holds the chunks, the flags (``failed``, ``reset``), ``subset``,
indexing and the step; the fleet's base classes hold its hand-outs of ``x``,
``P``, ``Q``, ``R`` (:mod:`squkf.fleet_state`), its runs over a recording
(:mod:`squkf.fleet_batch`) and what both faces share (:mod:`squkf.face`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from . import checks, old_pickles
from .angles import check_angle_hooks, is_data
from .boundary.attributes import FactorSlot, HandOut, ModelFunction
from .boundary.config import Config, filter_kwargs, filter_of, model_noise
from .boundary.records import FleetResult, Records
from .checks import (
    check_flag,
    check_time_step,
    noise_factors,
    reset_rows,
)
from .engine import Engine
from .errors import FleetStepError, ParameterError
from .fleet_batch import FleetBatch
from .fleet_from import PerPoint, stacked_filters, template  # noqa: F401  (old pickles name squkf.fleet.PerPoint)
from .fleet_state import FleetState
from .gating import Gate, as_gate
from .generators import as_generator
from .noise import handed_points, noise_points
from .plan import PREDICTING, UPDATING, Hooks, build_plan
from .stacks import CHUNKS, Step, not_updated, rows_of
from .transform import StackedHook
from .ukf import SquareRootUKF
from .weights import as_family

__all__ = ["Fleet", "FleetResult", "FleetStepError"]


class Fleet(FleetState, FleetBatch):
    """K independent square-root UKFs with one model and one configuration.

    Parameters
    ----------
    n_filters : int
        Number of filters ``K``.
    dim_x, dim_z : int
        State and measurement dimensions.
    dt : float
        Default time step passed to ``fx``.
    hx : callable
        ``hx(X, **hx_args)`` maps sigma points ``(K, N, dim_x)`` to ``(K, N, dim_z)``.
    fx : callable
        ``fx(X, dt, **fx_args)`` maps ``(K, N, dim_x)`` to ``(K, N, dim_x)``.
        A fleet needs both: None (filterpy's placeholder) is refused.
    points : sigma-point family or filterpy points object
        As for :class:`squkf.SquareRootUKF`.
    scheme : {"redrawn", "augmented", "propagated"} or generator
        How the second sigma-point set is formed.
    x_mean_fn, z_mean_fn, residual_x, residual_z, state_add : callable, optional
        filterpy's hooks for angles and other non-additive quantities. squkf's
        own (exact :class:`~squkf.angles.AngleMean`,
        :class:`~squkf.angles.AngleResidual` as ``z_mean_fn``, ``residual_z``)
        are data: the compiled update wraps and averages the angles itself, at
        the speed of a fleet without hooks. Any other hook is Python, called
        per filter and per sigma point as filterpy calls it (a ``residual_z``
        makes a step of a fleet of 1,000 tens of times slower), unless
        ``vectorized_hooks``.
    vectorized_hooks : bool
        The hooks take stacked arrays: each is called once per chunk, as
        ``fx`` and ``hx`` are (shapes: :class:`squkf.transform.StackedHook`;
        squkf's angle hooks are never wrapped). A filter then equals its single
        filter bit for bit only if its hooks' arithmetic does not depend on the
        array's length. ``fleet[k]``, ``from_filters`` and ``from_template``
        make filters and fleets that call them per point (False). Default False.
    on_error : {"flag", "raise"}
        What a numerical failure of some filters does (:ref:`fleet-failures`).
    gate : None, float or Gate
        Outlier gating, as for :class:`squkf.SquareRootUKF` (each filter
        decided on its own).
    fx_noise, hx_noise : int, optional
        Noise entering the model, as for :class:`squkf.SquareRootUKF`:
        ``fx(X, W, dt, **fx_args)`` with ``W`` ``(K, N, dim_w)`` and
        ``hx(X, V, **hx_args)`` with ``V`` ``(K, N2, dim_v)``; ``Q`` and ``R``
        are then w's and v's covariances (shared or per filter).
    chunk : int, optional
        Filters per call of ``fx`` and ``hx``, at most: a step runs a chunk of
        filters at a time (:mod:`squkf.stacks`), so its temporary arrays stay
        in cache and its memory does not grow with K; the model functions
        get ``(k, N, d)`` points with ``k <= chunk``, and per-filter
        ``fx_args``/``hx_args`` cut to the same filters. On several threads
        (:func:`squkf.set_num_threads`) the chunks are cut evenly between
        them. Default (None): 2048, or 4096 on several threads when each
        thread gets at least four such chunks
        (:func:`squkf.stacks.default_chunk`). The numbers do not depend on it.

    Attributes
    ----------
    x : ndarray, shape (K, dim_x)
    P, P1_2 : ndarray, shape (K, dim_x, dim_x)
        Assign to change (a single ``(dim_x,)`` or ``(dim_x, dim_x)`` value is
        given to every filter). ``x``, ``P``, ``Q`` and ``R`` may also be
        edited in place, as :ref:`promise-edits` says; what is read is the
        caller's (:ref:`promise-records`).
    Q, R, Q1_2, R1_2 : ndarray
        Shared ``(d, d)`` or per filter ``(K, d, d)``.
    x_prior, x_post, P1_2_prior, P1_2_post : ndarray
        Records of the last prediction and update (fresh on each read).
    y : ndarray, shape (K, dim_z)
        Innovations of the last update (NaN where a component was missing).
    log_likelihood, likelihood, mahalanobis : ndarray, shape (K,)
        Of the last update (0, 1 and 0 for a filter without measurement;
        the likelihood of the components the gate passed).
    nis : ndarray, shape (K,)
        The last update's normalised innovation squared (what a gate tests).
    rejected : ndarray of bool, shape (K, dim_z)
        The components of the last update's measurements that the gate rejected.
    failed : ndarray of bool, shape (K,)
    failure : ndarray of str, shape (K,)
        Why each flagged filter failed ("" for the others).

    Examples
    --------
    >>> import numpy as np
    >>> from squkf import Fleet, MerweScaledWeights
    >>> def fx(X, dt):
    ...     return X
    >>> def hx(X):
    ...     return X[..., :1]
    >>> fleet = Fleet(3, 2, 1, 1.0, hx, fx, MerweScaledWeights())
    >>> fleet.update(np.array([[1.0], [np.nan], [-1.0]]))  # filter 1 has no measurement
    >>> np.round(fleet.x[:, 0], 3)
    array([ 0.5,  0. , -0.5])
    """

    # the engine (the state, the pending step, the records and the step's buffers) lives outside
    # __dict__, as a filter's does: a Saver's rows never see its buffers, nor deep-copy them at each save
    __slots__ = ("_engine", "__dict__", "__weakref__")
    ONE = False  # a block of K: the records are (K, ...)
    _HANDED = ("x", "P", "Q", "R")  # (their edits in place taken through the setters)
    NO_LOG_LIKELIHOOD = 0.0  # (a filter without measurement: 0, as after an update that measured nothing)

    def __init__(
        self,
        n_filters: int,
        dim_x: int,
        dim_z: int,
        dt: float | None,
        hx: Callable,
        fx: Callable,
        points,
        *,
        scheme="redrawn",
        x_mean_fn: Callable | None = None,
        z_mean_fn: Callable | None = None,
        residual_x: Callable | None = None,
        residual_z: Callable | None = None,
        state_add: Callable | None = None,
        on_error: str = "flag",
        gate: float | Gate | None = None,
        fx_noise: int | None = None,
        hx_noise: int | None = None,
        chunk: int | None = None,
        vectorized_hooks: bool = False,
    ):
        K, n, m = checks.check_sizes(n_filters=n_filters, dim_x=dim_x, dim_z=dim_z)
        checks.model_functions(
            False, hx=hx, fx=fx, x_mean_fn=x_mean_fn, z_mean_fn=z_mean_fn, residual_x=residual_x,
            residual_z=residual_z, state_add=state_add,
        )  # fmt: skip
        check_angle_hooks(
            n, m, x_mean_fn=x_mean_fn, z_mean_fn=z_mean_fn, residual_x=residual_x, residual_z=residual_z,
            state_add=state_add,
        )  # fmt: skip
        if on_error not in ("flag", "raise"):
            raise ParameterError(f"on_error must be 'flag' or 'raise', got on_error={on_error!r}")
        self._fx_noise, self._hx_noise = model_noise(fx, hx, fx_noise, hx_noise)
        self._qd, self._rd = self._fx_noise or n, self._hx_noise or m  # the dimensions of Q and R
        self._handed = HandOut()  # x, P, Q, R: the arrays handed out, for edits in place
        self._K, self._n, self._m = K, n, m
        self._dt = None if dt is None else check_time_step(dt)  # None: every predict passes its own
        self.hx, self.fx = hx, fx
        self._points = points
        self._family = as_family(points)
        self._generator = as_generator(scheme)
        self._plan = build_plan(self._family, self._generator, n, self._fx_noise, self._hx_noise)
        self.x_mean, self.z_mean, self.residual_x, self.residual_z = (
            x_mean_fn,
            z_mean_fn,
            residual_x,
            residual_z,
        )
        self.state_add = state_add
        self.on_error = on_error
        self._gate = as_gate(gate)
        self._vectorized_hooks = check_flag(vectorized_hooks, "vectorized_hooks")
        # the state, the pending step and the records: a block of K run a chunk at a time (stacks.Chunks)
        S0 = np.broadcast_to(np.eye(n), (K, n, n)).copy()
        self._engine = Engine(self._new_route(), np.zeros((K, n)), S0, None, None, CHUNKS)
        # the noise, shared (d, d) or per filter (K, d, d): handed out and edited as x and P are
        self._Q = FactorSlot("Q", self._qd, True, np.eye(self._qd), filters=K)
        self._R = FactorSlot("R", self._rd, True, np.eye(self._rd), filters=K, zero=True)
        self._failed = np.zeros(K, dtype=bool)
        self._failure: dict[int, str] = {}  # filter -> why it is flagged (few: not a (K,) array)
        # filters whose x or P is a placeholder (an all-NaN row): a step flags them (_step_of)
        self._unset_x = np.zeros(K, dtype=bool)
        self._unset_P = np.zeros(K, dtype=bool)
        self.chunk = chunk

    # -- configuration and sizes ----------------------------------------------

    @property
    def n_filters(self) -> int:
        """Number of filters ``K``."""
        return self._K

    @property
    def dim_x(self) -> int:
        """State dimension."""
        return self._n

    @property
    def dim_z(self) -> int:
        """Measurement dimension."""
        return self._m

    def _set_points(self, points) -> None:
        raise ParameterError(
            f"a fleet's points are fixed when it is built (points_fn={points!r:.80}): build a Fleet with"
            " them, or step its filters apart (fleet[k]) and Fleet.from_filters"
        )

    def _hooks(self) -> Hooks:
        return Hooks(self.x_mean, self.z_mean, self.residual_x, self.residual_z, self.state_add)

    def _step_hooks(self) -> Hooks:
        hooks = self._hooks()
        if self._vectorized_hooks:  # a user's hooks called once per chunk (squkf's angle hooks: data)
            hooks = Hooks(*(h if h is None or is_data(h) else StackedHook(h) for h in hooks))
        return hooks

    @property
    def vectorized_hooks(self) -> bool:
        """Whether the hooks take stacked arrays, called once per chunk (see the class); assign to change."""
        return self._vectorized_hooks

    @vectorized_hooks.setter
    def vectorized_hooks(self, value) -> None:
        self._vectorized_hooks = check_flag(value, "vectorized_hooks")
        self._configured()

    # the model functions: a fleet needs both
    hx = ModelFunction(optional=False, why="a fleet needs fx and hx")
    fx = ModelFunction(optional=False, why="a fleet needs fx and hx")

    @property
    def chunk(self) -> int | None:
        """Filters per call of ``fx`` and ``hx`` in a step, at most (:mod:`squkf.stacks`); assign to change.

        None: the library's choice for the thread count and the allocator's setting
        (:func:`squkf.stacks.default_chunk`).
        """
        return self._chunk

    @chunk.setter
    def chunk(self, value) -> None:
        self._chunk: int | None = None if value is None else checks.check_sizes(chunk=value)[0]

    @property
    def failed(self) -> np.ndarray:
        """Which filters are flagged, shape ``(K,)`` (a copy)."""
        return self._failed.copy()

    @property
    def failure(self) -> np.ndarray:
        """Why each flagged filter failed ("" for the others), shape ``(K,)`` (a copy)."""
        failure = np.full(self._K, "", dtype=object)
        for k, why in self._failure.items():
            failure[k] = why
        return failure

    def reset(self, filters=None, x=None, P=None) -> None:
        """Clear the flag of ``filters`` (default: every flagged one), optionally setting their state.

        Parameters
        ----------
        filters : int, sequence of int or bool mask, optional
        x : array_like, shape (dim_x,) or (len(filters), dim_x), optional
        P : array_like, shape (dim_x, dim_x) or (len(filters), dim_x, dim_x), optional
        """
        self._take_edits()
        idx = np.flatnonzero(self._failed) if filters is None else np.arange(self._K)[filters]
        idx = np.atleast_1d(idx)
        e = self._engine
        new_x, new_S = reset_rows(x, P, idx, e.x, e.S)
        e.assign(new_x, new_S, idle=True)
        if x is not None:
            self._unset_x = self._unset_x.copy()
            self._unset_x[idx] = False
        if P is not None:
            self._unset_P = self._unset_P.copy()
            self._unset_P[idx] = False
        self._handed.drop("x", "P")
        self._failed[idx] = False
        self._failure = {k: why for k, why in self._failure.items() if self._failed[k]}

    # -- the step -----------------------------------------------------------------

    def ask_predict(self) -> np.ndarray:
        """First half of a prediction: the first sigma-point sets, shape ``(K, N, dim_x)`` (fresh)."""
        self._take_edits()
        X = self._engine.ask_predict()
        return handed_points(X, self._plan.w_xi, self._Q.S, (self._K,))

    def predict(self, dt=None, **fx_args) -> None:
        """Predict every filter one step ahead (flagged filters stay as they are).

        ``fx`` is called once per chunk of at most :attr:`chunk` filters, with
        their points ``(k, N, dim_x)`` (one call when ``K`` is no more).

        Parameters
        ----------
        dt : float, optional
            Time step (default: the constructor's), as :ref:`promise-dt` says.
        **fx_args
            Passed to ``fx``; arrays with a leading axis of length K are per
            filter and get a sigma-point axis (``u[k]`` becomes ``u[:, None]``),
            cut to the filters of each call.
        """
        dt = self._dt if dt is None else check_time_step(dt)
        if self._handed.held:
            self._take_edits()
        self._predict(self._fx_images(dt, fx_args), True)

    def tell_predict(self, sigmas_f) -> None:
        """Second half of a prediction: ``fx`` at the points from :meth:`ask_predict`, ``(K, N, dim_x)``."""
        self._take_edits()
        X = self._engine.X
        if self._engine.phase != PREDICTING or X is None:  # (the engine says why)
            self._engine.tell_predict(None, None)
        F = checks.stacked_shape(sigmas_f, X.shape, "fx values", copy=False)  # type: ignore[union-attr]
        self._predict(lambda rows, X: F[rows], False)

    def ask_update(self) -> np.ndarray:
        """First half of an update: the second sigma-point sets, shape ``(K, N2, dim_x)`` (fresh)."""
        self._take_edits()
        X = self._engine.ask_update()
        return handed_points(X, self._plan.v_xi, self._R.S, (self._K,))

    def update(self, z, R=None, **hx_args) -> None:
        """Update every filter with its measurement.

        ``hx`` is called once per chunk of at most :attr:`chunk` filters, as ``fx`` is by :meth:`predict`.

        Parameters
        ----------
        z : array_like, shape (K, dim_z)
            One row per filter; an all-NaN row means no measurement for that
            filter, NaN entries are missing components.
        R : array_like, optional
            Measurement noise for this update: ``(m, m)`` shared or ``(K, m, m)``.
        **hx_args
            Passed to ``hx`` (per-filter arrays as for :meth:`predict`).
        """
        zz = checks.measurements(z, self._K, self._m)
        if self._handed.held:
            self._take_edits()
        R1_2 = self._R.S if R is None else noise_factors(R, "R", self._rd, self._K)
        self._update(self._hx_images(R1_2, hx_args), zz, R1_2, self._engine.pending_update())

    def tell_update(self, sigmas_h, z, R=None) -> None:
        """Second half of an update: ``hx`` at the points from :meth:`ask_update`, and ``z`` (K, dim_z)."""
        zz = checks.measurements(z, self._K, self._m)
        self._take_edits()
        if self._plan.v_xi is not None and R is not None:
            raise ParameterError(
                f"with hx_noise the noise is in the sigma points handed out by ask_update: assign fleet.R"
                f" before asking, not R={R!r:.60} here"
            )
        R1_2 = self._R.S if R is None else noise_factors(R, "R", self._rd, self._K)
        sset = self._engine.sset
        if self._engine.phase != UPDATING or sset is None:  # (the engine says why)
            self._engine.tell_update(None, zz, None, self._R.S)  # type: ignore[arg-type]  # (R: never None)
        shape = sset.sigmas.shape[:-1] + (self._m,)  # type: ignore[union-attr]
        H = checks.stacked_shape(sigmas_h, shape, "hx values", copy=True)
        self._update(lambda rows, s: H[rows], zz, R1_2, None)

    # -- the step's parts -----------------------------------------------------------

    def _fx_images(self, dt: float, fx_args: dict) -> Callable:
        """``images(rows, X)``: ``fx`` at the first sets ``X`` of the filters ``rows``, arguments cut."""
        kwargs = checks.with_filter_axis(fx_args, self._K) if fx_args else fx_args
        K, plan, Q = self._K, self._plan, self._Q.S
        fx = self.__dict__["fx"]  # (as the descriptor reads it)

        def images(rows: slice, X: np.ndarray):
            kw = checks.chunk_args(kwargs, K, rows) if kwargs else kwargs
            # the points themselves: the step reads only their shape afterwards
            W = None if plan.w_xi is None else noise_points(plan.w_xi, rows_of(Q, rows, 2), (X.shape[0],))
            try:
                return fx(X, dt, **kw) if W is None else fx(X, W, dt, **kw)
            except Exception as exc:
                checks.note_stack_call(exc, "fx", X, W)
                raise

        return images

    def _hx_images(self, R1_2: np.ndarray | None, hx_args: dict) -> Callable:
        """``images(rows, sset)``: ``hx`` at the second sets of the filters ``rows``, arguments cut."""
        kwargs = checks.with_filter_axis(hx_args, self._K) if hx_args else hx_args
        K, plan = self._K, self._plan
        hx = self.__dict__["hx"]  # (as the descriptor reads it)

        def images(rows: slice, sset):
            kw = checks.chunk_args(kwargs, K, rows) if kwargs else kwargs
            k = sset.sigmas.shape[0]
            V = None if plan.v_xi is None else noise_points(plan.v_xi, rows_of(R1_2, rows, 2), (k,))
            X = sset.sigmas.copy()  # hx gets its own copy: the update reads the set
            try:
                return hx(X, **kw) if V is None else hx(X, V, **kw)
            except Exception as exc:
                checks.note_stack_call(exc, "hx", X, V)
                raise

        return images

    def _step_of(self, images: Callable) -> Step:
        """The engine's call for a half step (its runner's, ``stacks.Chunks``) when some ``x`` or ``P`` is not
        set (an all-NaN row): those filters are flagged, with the reason, and the others stepped."""
        unset = self._unset_x | self._unset_P
        fails: dict[int, str] = {}
        for k in np.flatnonzero(unset & ~self._failed).tolist():
            names = " and ".join(name for name, u in (("x", self._unset_x), ("P", self._unset_P)) if u[k])
            fails[k] = f"{names} of filter {k} was never set (a placeholder, all NaN): assign it, reset({k})"
        return Step(images, ~self._failed & ~unset, fails, self._chunk, self.on_error == "raise")

    def _predict(self, images: Callable, whole: bool) -> None:
        """A prediction (``whole``: its points drawn a chunk at a time; else those of the pending ask)."""
        if self._unset_x.any() or self._unset_P.any():
            step = self._step_of(images)
        else:  # (the usual step, built here)
            step = Step(images, ~self._failed, {}, self._chunk, self.on_error == "raise")
        Q = None if self._plan.w_xi is not None else self._Q.S  # noise entering fx is in the points already
        self._engine.tell_predict(step, Q, None, None, "fx values", whole)
        # committed: the arrays handed out for the old estimate are history, the failing filters flagged
        if self._handed.held:
            self._handed.drop("x", "P")
        for k, why in step.fails.items():
            self._failed[k] = True
            self._failure[int(k)] = why

    def _update(self, images: Callable, z: np.ndarray, R1_2, pending: tuple | None) -> None:
        """An update (``pending``: the engine's pending update of a whole call; None: the asked one)."""
        if self._unset_x.any() or self._unset_P.any():
            step = self._step_of(images)
        else:  # (the usual step, built here)
            step = Step(images, ~self._failed, {}, self._chunk, self.on_error == "raise")
        if self._plan.v_xi is not None:  # noise entering hx is in the points: the update adds none
            R1_2 = np.zeros((self._m, self._m))
        self._engine.tell_update(step, z, None, R1_2, None, pending)
        if self._handed.held:
            self._handed.drop("x", "P")
        for k, why in step.fails.items():
            self._failed[k] = True
            self._failure[int(k)] = why

    def _no_update(self) -> None:
        """The records of a step in which no filter had a measurement, as :meth:`update` would leave them."""
        e = self._engine
        # the record's own copies: the estimate may live in the arrays the next prediction writes
        e.skip_update(not_updated(e.x.copy(), e.S.copy(), self._m))

    def _step(self, t: int, z: np.ndarray, dt: float, fx_args: dict, hx_args: dict, records: Records) -> None:
        """Step ``t`` of :meth:`batch_filter`, its records kept."""
        self._take_edits()  # (a progress callback may have edited x, P, Q or R in place)
        self._predict(self._fx_images(dt, fx_args), True)
        if np.isnan(z).all():  # no measurement at all: as update() would leave it
            self._no_update()
        else:
            self._take_edits()
            self._update(self._hx_images(self._R.S, hx_args), z, self._R.S, self._engine.pending_update())
        records.keep(t, self._engine.last)  # type: ignore[arg-type]  # (an update or _no_update's)

    # -- one filter and back --------------------------------------------------------

    def __getitem__(self, k: int):
        """Filter ``k`` as a :class:`squkf.SquareRootUKF` (vectorised, with its state and configuration)."""
        k = int(np.arange(self._K)[k])
        e, c = self._engine, self.configuration()
        f = filter_of(SquareRootUKF, c, k, e.x, e.S, e.phase)
        f._use_kernels(c.kernels)  # (on the fleet's kernel table)
        return f

    def __len__(self) -> int:
        return self._K

    def subset(self, rows) -> Fleet:
        """A new fleet of the filters ``rows`` (a slice, indices or mask), with their state and noise.

        The configuration is shared; every array is the new fleet's own. A
        pending ask/tell step is not carried over.

        Raises
        ------
        ParameterError
            ``rows`` selects no filter (a fleet has at least one, as
            ``Fleet(n_filters=...)`` requires), or is not a valid index of
            the fleet's filters.
        """
        self._take_edits()
        try:
            idx = np.atleast_1d(np.arange(self._K)[rows])
        except (IndexError, TypeError, ValueError) as exc:
            raise ParameterError(
                f"rows is not an index of the {self._K} filters: rows={rows!r:.100} ({exc})"
            ) from None
        if idx.size == 0:
            raise ParameterError(
                f"rows selects no filter (rows={rows!r:.100}): a fleet has at least one filter"
            )
        new = self._copy(self._engine.rows(idx), "copy")
        new._K = int(idx.size)
        new._Q, new._R = self._Q.rows(idx), self._R.rows(idx)
        new._handed = HandOut()  # the arrays handed out are this fleet's
        new._failed = self._failed[idx]
        new._unset_x, new._unset_P = self._unset_x[idx], self._unset_P[idx]
        new._failure = {i: self._failure[k] for i, k in enumerate(idx.tolist()) if k in self._failure}
        return new

    @classmethod
    def from_filters(cls, filters: Sequence[Any], *, on_error: str = "flag") -> Fleet:
        """Stack :class:`squkf.SquareRootUKF` filters of one configuration into a fleet.

        The filters must share dimensions, ``dt``, model functions (which must
        be vectorised: ``vectorized=True``), sigma-point family, scheme and hooks.

        Raises
        ------
        ParameterError
            If ``filters`` is not a sequence of ``SquareRootUKF`` (filterpy's
            ``UnscentedKalmanFilter`` included: the message says how to build
            one from it), is empty, or the filters differ in configuration.
        """
        c, *state = stacked_filters(filters)
        return cls._built(c, len(state[0]), state, on_error)

    @classmethod
    def from_template(cls, ukf: SquareRootUKF, n_filters: int, *, on_error: str = "flag") -> Fleet:
        """A fleet of ``n_filters`` copies of one filter: its configuration, ``x``, ``P``, ``Q`` and ``R``.

        What a Monte Carlo study or a noise fit starts from (:mod:`squkf.consistency`,
        :mod:`squkf.tune`). Unlike :meth:`from_filters` the template may be per point
        (``vectorized=False``): its ``fx`` and ``hx`` are then called point by point on the
        fleet's stacked points (``squkf.fleet_from.PerPoint``), with ``fx_args`` and ``hx_args`` as given.

        Parameters
        ----------
        ukf : SquareRootUKF
            Read, never changed.
        n_filters : int
        on_error : {"flag", "raise"}

        Raises
        ------
        ParameterError
            ``ukf`` is not a ``SquareRootUKF``, or has no ``fx`` or ``hx``.
        UnsetError
            Its ``x`` or ``P`` is a placeholder.
        CallSequenceError
            It has a step pending that a fleet cannot carry (an ask not told).
        """
        c, state = template(ukf)
        return cls._built(c, n_filters, state, on_error)

    @classmethod
    def _built(cls, c: Config, K: int, state, on_error: str) -> Fleet:
        """A fleet of ``K`` filters of configuration ``c`` and their ``x``, ``P1_2``, ``Q1_2``, ``R1_2``
        (``state``, validated by the setters)."""
        fleet = cls(K, c.dim_x, c.dim_z, c.dt, c.hx, c.fx, c.points, on_error=on_error, **filter_kwargs(c))
        fleet.x, fleet.P1_2, fleet.Q1_2, fleet.R1_2 = state
        fleet._use_kernels(c.kernels)
        return fleet

    # the core's skeleton of copies, pickles and snapshots (face.Face): everything in the __dict__

    def _unpickled(self, state: dict) -> dict:
        state = old_pickles.fleet_state(state)
        if "_engine" not in state:  # pickled before the fleet held an engine: its state and records, idle
            before = state.pop("_before_engine")  # (not kept: what the engine is made of)
            self.__dict__.update(state)
            state["_engine"] = old_pickles.fleet_engine(self._new_route(), before)
        return state
