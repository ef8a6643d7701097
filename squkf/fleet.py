"""``Fleet``: K independent square-root UKFs with one model, advanced in one array step.

Every filter of a fleet runs the same step as :class:`squkf.SquareRootUKF`
(the engine's route, :class:`squkf.engine.Route`, over a plan of
:mod:`squkf.plan`), on arrays with a leading filter axis: states ``(K, n)``,
factors ``(K, n, n)``, sigma points ``(K, N, n)``, a chunk of filters at a
time (:mod:`squkf.stacks`). The model functions are called once per chunk
with the points of its filters; a function written with ``X[..., i]``
indexing serves a fleet and ``SquareRootUKF(vectorized=True)`` alike.

Failure isolation
-----------------
Bad *input* (shapes, an infinite ``z``, a bad ``R``) raises for the whole call
and changes nothing, as for one filter. A *numerical* failure of one filter
in a step (its images are not finite, a factor would lose positive
definiteness, its innovation factor is singular, its result is not finite)
is that filter's alone: it keeps its state from before the step, it is
flagged in :attr:`Fleet.failed` with the reason in :attr:`Fleet.failure`, and
every other filter completes the step, bit for bit as in a fleet without the
failing filter (each filter's arithmetic never depends on the others').

A flagged filter is frozen: later steps leave it as it is (its model images
are still computed with the others', and ignored) until it is reset with
:meth:`Fleet.reset`, which clears the flag and, optionally, sets its state.
With ``on_error="raise"`` a step with a failing filter instead raises
:class:`FleetStepError`, naming the filters, and changes no filter.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from . import checks
from .angles import check_angle_hooks, is_data
from .batch import model_kwargs, per_step
from .boundary.attributes import FactorSlot, HandOut, Hook, ModelFunction
from .boundary.config import Config, check_pending, filter_kwargs, filter_of, model_noise, stacked
from .boundary.loop import annotate_step, check_keep, check_progress, progress_callback
from .boundary.records import FleetResult, Records, new_records
from .checks import (
    check_flag,
    check_time_step,
    covariance_factors,
    lower_factors,
    noise_factors,
    reset_rows,
    short_repr,
)
from .engine import Engine, Route, Update
from .errors import FleetStepError, ParameterError, UnsetError
from .face import Face, own_copy
from .gating import Gate, as_gate
from .generators import as_generator
from .noise import handed_points, noise_points
from .plan import PREDICTING, UPDATING, Hooks, build_plan
from .smoother import fleet_rts_smoother
from .stacks import CHUNKS, Step, rows_of
from .transform import StackedHook
from .ukf import SquareRootUKF
from .weights import as_family

__all__ = ["Fleet", "FleetResult", "FleetStepError"]

# the attributes handed out for editing in place
HANDED = ("x", "P", "Q", "R")

# what a fleet pickled before it held an engine kept in its __dict__
_BEFORE_ENGINE = (
    "_x", "_S", "_pending", "_route", "_x_prior", "_S_prior", "_x_post", "_S_post", "_y", "_loglik", "_nis",
    "_rejected", "_y_whitened", "_log_det",
)  # fmt: skip


def _as_filters(filters) -> list[SquareRootUKF]:
    """``Fleet.from_filters``'s ``filters`` as a list of :class:`squkf.SquareRootUKF`, or a ParameterError."""
    if filters is None or isinstance(filters, (str, bytes, Mapping)) or not isinstance(filters, Iterable):
        raise ParameterError(
            f"filters must be a sequence of squkf.SquareRootUKF, got filters={short_repr(filters)}"
            f" ({type(filters).__name__})"
        )
    filters = list(filters)
    for k, f in enumerate(filters):
        if isinstance(f, SquareRootUKF):
            continue
        kind = type(f).__name__
        if type(f).__module__.split(".")[0] == "filterpy":
            how = (
                " build each as squkf.SquareRootUKF with the same arguments (dim_x, dim_z, dt, hx, fx,"
                " points, the hooks) and vectorized=True, and give it the filterpy filter's x, P, Q and R"
                " (g.x, g.P, g.Q, g.R = f.x, f.P, f.Q, f.R)"
                if kind == "UnscentedKalmanFilter"
                else " a fleet stacks square-root UKFs only"
            )
            raise ParameterError(f"filters[{k}] is filterpy's {kind}, not a squkf.SquareRootUKF:{how}")
        raise ParameterError(f"filters[{k}] is not a squkf.SquareRootUKF: got {short_repr(f)} ({kind})")
    return filters


class PerPoint:
    """A per-point model function called on a fleet's stacked points, point by point.

    ``fx(x, dt, **kw)``, ``hx(x, **kw)``, or with a noise argument ``fx(x, w, dt)``, ``hx(x, v)``
    (``noise``), as a filter with ``vectorized=False`` calls them; the fleet gives ``(..., N, d)``
    points (and noise points) and gets ``(..., N, d_out)`` values. A class, so a fleet of it pickles
    where the function does.

    Parameters
    ----------
    fn : callable
    noise : bool
        The first argument after the points is their noise points.
    """

    def __init__(self, fn: Callable, noise: bool):
        self.fn, self.noise = fn, noise

    def __call__(self, X: np.ndarray, *args, **kwargs) -> np.ndarray:
        lead = X.shape[:-1]
        points = X.reshape(-1, X.shape[-1])
        if self.noise:
            W, rest = args[0], args[1:]
            noise = W.reshape(-1, W.shape[-1])
            values = [self.fn(x, w, *rest, **kwargs) for x, w in zip(points, noise)]
        else:
            values = [self.fn(x, *args, **kwargs) for x in points]
        try:
            return np.asarray(values, dtype=float).reshape(lead + (-1,))
        except (TypeError, ValueError):  # values of different shapes, or not numbers: said by the step
            return np.asarray(values, dtype=object)


class Fleet(Face):
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
        What a numerical failure of some filters does (module docstring).
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

    def _configured(self) -> None:
        self._engine.configure(self._new_route())

    def _new_route(self) -> Route:
        """The engine's route of this configuration (built again when a hook, the gate or
        ``vectorized_hooks`` changes)."""
        hooks = self._hooks()
        if self._vectorized_hooks:  # a user's hooks called once per chunk (squkf's angle hooks: data)
            hooks = Hooks(*(h if h is None or is_data(h) else StackedHook(h) for h in hooks))
        return Route(self._plan, hooks, self._gate, single=False)

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

    # the hooks: assigning one builds the engine's route again
    x_mean = Hook()
    z_mean = Hook()
    residual_x = Hook()
    residual_z = Hook()
    state_add = Hook()

    def _hooks_assigned(self) -> None:
        if "_gate" in self.__dict__:  # (not while __init__ sets the hooks: the engine is built after)
            self._configured()

    # -- state and noise: handed out (edits in place taken by boundary.attributes.HandOut) -------

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

    def _take_edits(self) -> None:
        """Take the edits in place of ``x``, ``P``, ``Q``, ``R`` through their setters (which may raise)."""
        if self._handed.held:
            self._handed.take(HANDED, lambda name, a: setattr(self, name, a))

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
        K, m = self._K, self._m
        e = self._engine
        # the record's own copies: the estimate may live in the arrays the next prediction writes
        none = Update(
            e.x.copy(), e.S.copy(), np.full((K, m), np.nan), None, None, np.zeros(K), np.zeros(K), None,
            np.zeros((K, m), dtype=bool), None, m, np.full((K, m), np.nan), np.zeros(K),
        )  # fmt: skip
        e.skip_update(none)

    # -- many steps ---------------------------------------------------------------

    def batch_filter(
        self, zs, *, dts=None, keep: str | tuple[str, ...] = "all", fx_args=None, hx_args=None, progress=False
    ) -> FleetResult:
        """Filter ``T`` steps of measurements for every filter.

        Parameters
        ----------
        zs : array_like, shape (K, T, dim_z), or an iterable of (K, dim_z) arrays
            NaN rows and entries are missing measurements, as are masked ones
            (a ``numpy.ma.MaskedArray``), as for :meth:`update`.
            Any other iterable (a generator, ``tqdm(...)``) yields one step's
            measurements at a time, each checked as for :meth:`update` (a wrong
            shape, ``None`` or text is a ShapeError naming the step, ``zs[t]``);
            it is read to its end before the run starts. Lists and tuples are
            read as the ``(K, T, dim_z)`` array; a string, a dict or a set is a
            ShapeError.
        dts : float or array_like of shape (T,), optional
            Time step of each prediction (default: the constructor's), as
            :ref:`promise-dt` says.
        keep : {"all", "diagonals", "means", "final"} or tuple
            What to store: everything; means and the covariances' diagonals;
            means only; or only the final state (for long runs). A tuple of
            one of the first three and ``"whitened"`` (``("means", "whitened")``)
            keeps each step's whitened innovations and ``log det S1_2`` too
            (``FleetResult.y_whitened``, ``log_det_S1_2``).
        fx_args, hx_args : dict, optional
            Passed to ``fx`` and ``hx`` at every step, and to nothing else: a
            key that names an argument of the step (``dt``, ``z``, ``R``, ...,
            see :func:`squkf.batch.model_kwargs`) is a ParameterError.
        progress : bool or callable
            ``True`` shows a tqdm bar (the ``progress`` extra); a callable is
            called with the step index after each step.

        Returns
        -------
        FleetResult
            The fleet itself is left after the last step, as after a loop of
            ``predict`` and ``update``; an error leaves it as it was before the call.
        """
        state, whitened = check_keep(keep)
        check_progress(progress)
        Z = checks.measurement_series(zs, self._K, self._m)
        T = Z.shape[1]
        # step-major: each step's (K, m) contiguous, read by the kernels as it is (no copy per step)
        Z = np.ascontiguousarray(np.swapaxes(Z, 0, 1))
        dt_list = per_step(dts, T, "dts", "dt", default=self._dt, ref="zs")
        fx_args, hx_args = model_kwargs(fx_args, "fx_args"), model_kwargs(hx_args, "hx_args")
        records = new_records(state, self._K, T, self._n, self._m, whitened)
        self._take_edits()
        bar, callback = progress_callback(progress, T)
        t = 0
        try:
            with self.transaction():  # an error at any step leaves the fleet as it was before the call
                for t in range(T):
                    self._step(t, Z[t], dt_list[t], fx_args, hx_args, records)
                    if callback is not None:
                        callback(t)
        except BaseException as exc:
            annotate_step(exc, t, records.so_far(t), True)
            raise
        finally:
            if bar is not None:
                bar.close()
        r = records
        return FleetResult(
            r.means, r.factors, r.variances, r.loglik, self._failed.copy(), self._engine.x.copy(),
            self._engine.S.copy(),
            r.rejected, r.nis, r.y_whitened, r.log_det,
        )  # fmt: skip

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

    def _snapshot(self) -> tuple[Fleet, HandOut]:
        # a copy: the step's results live in buffers that later steps write again
        return copy.copy(self), self._handed.copy()

    def _restore(self, saved: tuple[Fleet, HandOut]) -> None:
        before, handed = saved
        self.__dict__.update(before.__dict__)
        self._engine = before._engine
        self.__dict__["_handed"] = handed  # the arrays handed out stay the caller's, still current

    # -- one filter and back --------------------------------------------------------

    def __getitem__(self, k: int):
        """Filter ``k`` as a :class:`squkf.SquareRootUKF` (vectorised, with its state and configuration)."""
        k = int(np.arange(self._K)[k])
        e = self._engine
        return filter_of(SquareRootUKF, self.configuration(), k, e.x, e.S, e.phase)

    def configuration(self) -> Config:
        """The fleet's configuration and noise factors (``squkf.boundary.Config``), edits taken.

        What ``fleet[k]``, the smoother and :mod:`squkf.dask` read; its arrays
        are the fleet's own, to be read and not written.
        """
        self._take_edits()
        return Config(
            self._n, self._m, self._dt, self.hx, self.fx, self.points_fn, self._family, self._generator,
            self.x_mean, self.z_mean, self.residual_x, self.residual_z, self.state_add, self._gate,
            self._fx_noise or None, self._hx_noise or None, True, self._plan, self._hooks(),
            self._Q.S, self._R.S, kernels=self._engine.route.kernels,
        )  # fmt: skip

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
        new = self._with(self._engine.rows(idx))
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
        c, x, P1_2, Q1_2, R1_2 = stacked(_as_filters(filters))
        fleet = cls(
            len(x), c.dim_x, c.dim_z, c.dt, c.hx, c.fx, c.points, on_error=on_error, **filter_kwargs(c)
        )
        fleet.x, fleet.P1_2, fleet.Q1_2, fleet.R1_2 = x, P1_2, Q1_2, R1_2  # validated by the setters
        return fleet

    @classmethod
    def from_template(cls, ukf: SquareRootUKF, n_filters: int, *, on_error: str = "flag") -> Fleet:
        """A fleet of ``n_filters`` copies of one filter: its configuration, ``x``, ``P``, ``Q`` and ``R``.

        What a Monte Carlo study or a noise fit starts from (:mod:`squkf.consistency`,
        :mod:`squkf.tune`). Unlike :meth:`from_filters` the template may be per point
        (``vectorized=False``): its ``fx`` and ``hx`` are then called point by point on the
        fleet's stacked points (``squkf.fleet.PerPoint``), with ``fx_args`` and ``hx_args`` as given.

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
        f = _as_filters([ukf])[0]
        c = f.configuration()
        check_pending(c.step, c.plan, "the template")
        for name in ("x", "P"):
            value = getattr(f, name)
            if value is None or np.isnan(value).all():
                raise UnsetError(f"a fleet of the template needs its {name}, but {name} was never set")
        fx, hx = c.fx, c.hx
        if fx is None or hx is None:
            missing = "fx" if fx is None else "hx"
            raise ParameterError(f"a fleet needs fx and hx, but the template has {missing}=None")
        if not c.vectorized:
            fx, hx = PerPoint(fx, bool(c.fx_noise)), PerPoint(hx, bool(c.hx_noise))
        kwargs = filter_kwargs(c)
        fleet = cls(n_filters, c.dim_x, c.dim_z, c.dt, hx, fx, c.points, on_error=on_error, **kwargs)
        fleet.x, fleet.P1_2, fleet.Q1_2, fleet.R1_2 = f.x, f.P1_2, f.Q1_2, f.R1_2
        return fleet

    def __copy__(self) -> Fleet:
        # the engine's copy carries its state and any half-done step, its arrays the copy's own
        return self._with(copy.copy(self._engine))

    def _with(self, engine: Engine) -> Fleet:
        """A fleet of this configuration with its own copies of the arrays in ``__dict__``, on ``engine``."""
        new = type(self).__new__(type(self))
        copies: dict[int, np.ndarray] = {}
        new.__dict__.update({key: own_copy(v, copies) for key, v in self.__dict__.items()})
        new._engine = engine
        return new

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_engine": self._engine}  # (the engine pickles without its buffers)

    def __setstate__(self, state: dict) -> None:
        if "points_fn" in state:  # pickled when the points were a plain attribute
            state = {("_points" if k == "points_fn" else k): v for k, v in state.items()}
        state.setdefault("_unset_x", np.zeros(state["_K"], dtype=bool))  # pickled before placeholders
        state.setdefault("_unset_P", np.zeros(state["_K"], dtype=bool))
        state.setdefault("_vectorized_hooks", False)  # pickled before the option
        engine = state.pop("_engine", None)
        if "_Q1_2" in state:  # pickled when the noise factors were kept bare
            Q, R, K = state.pop("_Q1_2"), state.pop("_R1_2"), state["_K"]
            state["_Q"] = FactorSlot("Q", state.get("_qd", state["_n"]), True, Q, filters=K)
            state["_R"] = FactorSlot("R", state.get("_rd", state["_m"]), True, R, filters=K, zero=True)
        old = {k: state.pop(k, None) for k in _BEFORE_ENGINE}
        self.__dict__.update(state)
        if engine is None:  # pickled before the fleet held an engine: its state and records, idle
            engine = Engine(self._new_route(), old["_x"], old["_S"], None, None, CHUNKS)
            engine.prior_record = (old["_x_prior"], old["_S_prior"])
            engine.post_record = (old["_x_post"], old["_S_post"])
            m = self._m
            w, ld = old["_y_whitened"], old["_log_det"]  # (pickled before the record: NaN and 0)
            engine.last = Update(
                old["_x_post"], old["_S_post"], old["_y"], None, None, old["_loglik"], old["_nis"], None,
                old["_rejected"], None, m, np.full(old["_y"].shape, np.nan) if w is None else w,
                np.zeros(self._K) if ld is None else ld,
            )  # fmt: skip
        self._engine = engine
        if isinstance(self._failure, np.ndarray):  # pickled before the reasons were kept as a dict
            self._failure = {int(k): str(self._failure[k]) for k in np.flatnonzero(self._failure != "")}

    def __deepcopy__(self, memo):
        new = copy.copy(self)
        memo[id(self)] = new
        return new

    # -- smoothing --------------------------------------------------------------------

    def rts_smoother(self, result: FleetResult, dts=None, fx_args=None):
        """Square-root unscented RTS smoother for every filter at once.

        The same backward recursion as :meth:`squkf.SquareRootUKF.rts_smoother_factors`
        (one function, ``squkf.smoother._backward``, on stacked arrays), with
        ``fx`` called once per backward step with the points of all filters,
        ``(K, N, dim_x)``, and the fleet's ``Q`` (shared or per filter). The fleet
        itself is not changed.

        Parameters
        ----------
        result : FleetResult
            From :meth:`batch_filter` with ``keep="all"`` (its means and factors).
        dts : float or array_like of shape (T,), optional
            ``dts[k]``: time step of the prediction into step ``k``, as given to
            :meth:`batch_filter` (default: the constructor's), as
            :ref:`promise-dt` says.
        fx_args : dict, optional
            Passed to ``fx`` at every step (per-filter arrays as for :meth:`predict`).

        Returns
        -------
        FleetSmoothed
            Unpacks as ``(means, P1_2s, Gs)`` of shapes ``(K, T, dim_x)``,
            ``(K, T, dim_x, dim_x)`` (lower factors) and ``(K, T, dim_x, dim_x)``
            (gains, zero at the last step); ``failed`` ``(K,)`` and ``failure``
            are attached. A filter flagged in ``result.failed``, or one that fails
            numerically while smoothing, is returned unsmoothed (its filtered
            values, zero gains) and flagged; the others are unaffected. With
            ``on_error="raise"``, a smoothing failure raises instead.

        Raises
        ------
        ParameterError
            ``result`` is not a FleetResult, or was kept without factors (``keep``
            other than ``"all"``); ``fx_args`` not a dict; a non-finite ``dts`` entry.
        ShapeError, NonFiniteError
            ``result`` does not fit this fleet, or holds NaN or inf; ``dts`` of
            the wrong length; ``fx`` values of the wrong shape.
        FleetStepError
            With ``on_error="raise"``, if some filters failed numerically.
        """
        checks.refuse_smoother_noise(self._fx_noise, "fleet")
        return fleet_rts_smoother(self, result, dts=dts, fx_args=fx_args)
