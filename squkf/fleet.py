"""``Fleet``: K independent square-root UKFs with one model, advanced in one array step.

Every filter of a fleet runs the same step as :class:`squkf.SquareRootUKF`
(the transitions of :mod:`squkf.step` over a plan of :mod:`squkf.plan`), on
arrays with a leading filter axis: states ``(K, n)``, factors ``(K, n, n)``,
sigma points ``(K, N, n)``, a chunk of filters at a time (:mod:`squkf.chunks`).
The model functions are called once per chunk with the points of its
filters; a function written with ``X[..., i]`` indexing serves a fleet and
``SquareRootUKF(vectorized=True)`` alike. The step's internals are
:class:`squkf.boundary.stacked_filter.StackedFilter`, this class's base.

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

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from . import step as steps
from .boundary import inputs
from .boundary.config import Config, filter_kwargs
from .boundary.factors import (
    covariance_factors,
    given_noise_factors,
    lower_factors,
)
from .boundary.records import FleetResult
from .boundary.stacked_filter import StackedFilter
from .boundary.stacking import filter_of, stacked
from .errors import FleetStepError, ParameterError
from .gating import Gate
from .noise import handed_points
from .smoother import fleet_rts_smoother
from .ukf import SquareRootUKF
from .validate import check_time_step

__all__ = ["Fleet", "FleetResult", "FleetStepError"]


class Fleet(StackedFilter):
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
    points : sigma-point family or filterpy points object
        As for :class:`squkf.SquareRootUKF`.
    scheme : {"redrawn", "augmented", "propagated"} or generator
        How the second sigma-point set is formed.
    x_mean_fn, z_mean_fn, residual_x, residual_z, state_add : callable, optional
        filterpy's hooks (e.g. :mod:`squkf.angles`), called per filter.
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
        filters at a time (:mod:`squkf.chunks`), so its temporary arrays stay
        in cache and its memory does not grow with K; the model functions
        get ``(k, N, d)`` points with ``k <= chunk``, and per-filter
        ``fx_args``/``hx_args`` cut to the same filters. On several threads
        (:func:`squkf.set_num_threads`) the chunks are cut evenly between
        them. Default (None): 2048, or 4096 on several threads when each
        thread gets at least four such chunks
        (:func:`squkf.chunks.default_chunk`). The numbers do not depend on it.

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

    def __init__(
        self,
        n_filters: int,
        dim_x: int,
        dim_z: int,
        dt: float,
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
    ):
        K, n, m = inputs.check_sizes(n_filters=n_filters, dim_x=dim_x, dim_z=dim_z)
        hooks = (x_mean_fn, z_mean_fn, residual_x, residual_z, state_add)
        self._init_stack(K, n, m, dt, hx, fx, points, scheme, hooks, on_error, gate, fx_noise, hx_noise)
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

    @property
    def scheme(self):
        """The second-set generator."""
        return self._generator

    # -- state and noise: handed out (edits in place taken by boundary.edits.HandOut) -------

    @property
    def x(self) -> np.ndarray:
        """States, shape ``(K, dim_x)``."""
        return self._handed.array("x", self._x.copy)

    @x.setter
    def x(self, value):
        self._x = inputs.per_filter(value, "x", self._K, (self._n,))
        self._state = steps.StepState()

    @property
    def P1_2(self) -> np.ndarray:
        """Lower factors of the covariances, shape ``(K, dim_x, dim_x)`` (fresh; assign to change)."""
        self._take_edits()
        return self._S.copy()

    @P1_2.setter
    def P1_2(self, value):
        self._S = lower_factors(value, "P1_2", self._n, self._K)
        self._state = steps.StepState()

    @property
    def P(self) -> np.ndarray:
        """Covariances, shape ``(K, dim_x, dim_x)``."""
        return self._handed.array("P", lambda: self._S @ np.swapaxes(self._S, -1, -2))

    @P.setter
    def P(self, value):
        self._S = covariance_factors(value, "P", self._n, self._K)
        self._state = steps.StepState()

    @property
    def Q(self) -> np.ndarray:
        """Process noise, shared ``(d, d)`` or per filter ``(K, d, d)``.

        ``d`` is ``dim_x``, or ``fx_noise`` when the noise enters ``fx`` (then ``Q`` is w's covariance).
        """
        S, d = self._Q1_2, self._qd
        return self._handed.array("Q", lambda: np.zeros((d, d)) if S is None else S @ np.swapaxes(S, -1, -2))

    @Q.setter
    def Q(self, value):
        S = self._noise(value, "Q", self._qd)
        self._Q1_2 = None if S is None or not np.any(S) else S

    @property
    def Q1_2(self) -> np.ndarray:
        """Lower factor(s) of ``Q`` (fresh; assign to change)."""
        self._take_edits()
        return np.zeros((self._qd, self._qd)) if self._Q1_2 is None else self._Q1_2.copy()

    @Q1_2.setter
    def Q1_2(self, value):
        self._Q1_2 = given_noise_factors(value, "Q1_2", self._qd, self._K)

    @property
    def R(self) -> np.ndarray:
        """Measurement noise, shared ``(m, m)`` or per filter ``(K, m, m)``."""
        return self._handed.array("R", lambda: self._R1_2 @ np.swapaxes(self._R1_2, -1, -2))

    @R.setter
    def R(self, value):
        S = self._noise(value, "R", self._rd)
        self._R1_2 = np.zeros((self._rd, self._rd)) if S is None else S

    @property
    def R1_2(self) -> np.ndarray:
        """Lower factor(s) of ``R`` (fresh; assign to change)."""
        self._take_edits()
        return self._R1_2.copy()

    @R1_2.setter
    def R1_2(self, value):
        S = given_noise_factors(value, "R1_2", self._rd, self._K)
        self._R1_2 = np.zeros((self._rd, self._rd)) if S is None else S

    @property
    def chunk(self) -> int | None:
        """Filters per call of ``fx`` and ``hx`` in a step, at most (:mod:`squkf.chunks`); assign to change.

        None: the library's choice for the thread count (:func:`squkf.chunks.default_chunk`).
        """
        return self._chunk

    @chunk.setter
    def chunk(self, value) -> None:
        (self._chunk,) = (None,) if value is None else inputs.check_sizes(chunk=value)

    @property
    def failed(self) -> np.ndarray:
        """Which filters are flagged, shape ``(K,)`` (a copy)."""
        return self._failed.copy()

    @property
    def failure(self) -> np.ndarray:
        """Why each flagged filter failed ("" for the others), shape ``(K,)`` (a copy)."""
        return self._failure.copy()

    @property
    def log_likelihood(self) -> np.ndarray:
        """Log-likelihood of each filter's last measurement, shape ``(K,)``."""
        return self._loglik.copy()

    @property
    def likelihood(self) -> np.ndarray:
        """``exp(log_likelihood)``, never below the smallest normal float, shape ``(K,)``."""
        return np.maximum(np.exp(self._loglik), np.finfo(float).tiny)

    @property
    def mahalanobis(self) -> np.ndarray:
        """Mahalanobis distance of each filter's last innovation, shape ``(K,)``."""
        return np.sqrt(self._nis)

    @property
    def nis(self) -> np.ndarray:
        """Normalised innovation squared of each filter's last update, shape ``(K,)`` (a copy)."""
        return self._nis.copy()

    @property
    def rejected(self) -> np.ndarray:
        """The components the gate rejected in the last update, shape ``(K, dim_z)`` (a copy)."""
        return self._rejected.copy()

    def reset(self, filters=None, x=None, P=None) -> None:
        """Clear the flag of ``filters`` (default: every flagged one), optionally setting their state.

        Parameters
        ----------
        filters : int, sequence of int or bool mask, optional
        x : array_like, shape (dim_x,) or (len(filters), dim_x), optional
        P : array_like, shape (dim_x, dim_x) or (len(filters), dim_x, dim_x), optional
        """
        self._reset(filters, x, P)

    # -- the step ---------------------------------------------------------------

    def ask_predict(self) -> np.ndarray:
        """First half of a prediction: the first sigma-point sets, shape ``(K, N, dim_x)`` (fresh)."""
        self._take_edits()
        state = steps.ask_predict(self._state, self._plan, self._x, self._S, self.state_add)
        self._state = state
        return handed_points(state.sigmas, self._plan.w_xi, self._Q1_2, (self._K,))  # type: ignore[arg-type]

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
        self._take_edits()
        self._predict(self._fx_images(dt, fx_args), None)

    def tell_predict(self, sigmas_f) -> None:
        """Second half of a prediction: ``fx`` at the points from :meth:`ask_predict`, ``(K, N, dim_x)``."""
        self._take_edits()
        X = self._told(steps.PREDICTING, "tell_predict").sigmas
        assert X is not None
        F = inputs.stacked_shape(sigmas_f, X.shape, "fx values", copy=False)
        self._predict(lambda rows, X: F[rows], X)

    def ask_update(self) -> np.ndarray:
        """First half of an update: the second sigma-point sets, shape ``(K, N2, dim_x)`` (fresh)."""
        self._take_edits()
        state = steps.ask_update(self._state, self._plan, self._x, self._S, self.state_add)
        self._state = state
        return handed_points(state.sigmas, self._plan.v_xi, self._R1_2, (self._K,))  # type: ignore[arg-type]

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
        zz = self._as_measurements(z)
        self._take_edits()
        R1_2 = self._R1_2 if R is None else self._noise(R, "R", self._rd)
        pending = steps.pending_update(self._state, self._x, self._S)
        self._update(pending, self._hx_images(R1_2, hx_args), zz, R1_2)

    def tell_update(self, sigmas_h, z, R=None) -> None:
        """Second half of an update: ``hx`` at the points from :meth:`ask_update`, and ``z`` (K, dim_z)."""
        zz = self._as_measurements(z)
        self._take_edits()
        if self._plan.v_xi is not None and R is not None:
            raise ParameterError(
                f"with hx_noise the noise is in the sigma points handed out by ask_update: assign fleet.R"
                f" before asking, not R={R!r:.60} here"
            )
        R1_2 = self._R1_2 if R is None else self._noise(R, "R", self._rd)
        state = self._told(steps.UPDATING, "tell_update")
        shape = state.sset.sigmas.shape[:-1] + (self._m,)  # type: ignore[union-attr]
        H = inputs.stacked_shape(sigmas_h, shape, "hx values", copy=True)
        self._update(state, lambda rows, sset: H[rows], zz, R1_2)

    # -- many steps ---------------------------------------------------------------

    def batch_filter(
        self, zs, *, dts=None, keep: str = "all", fx_args=None, hx_args=None, progress=False
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
        keep : {"all", "diagonals", "means", "final"}
            What to store: everything; means and the covariances' diagonals;
            means only; or only the final state (for long runs).
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
        return self._batch(zs, dts, keep, fx_args, hx_args, progress)

    # -- one filter and back --------------------------------------------------------

    def __getitem__(self, k: int):
        """Filter ``k`` as a :class:`squkf.SquareRootUKF` (vectorised, with its state and configuration)."""
        k = int(np.arange(self._K)[k])
        return filter_of(SquareRootUKF, self.configuration(), k, self._x, self._S, self._state.phase)

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
            self._Q1_2, self._R1_2,
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
        return self._subset(rows)

    @classmethod
    def from_filters(cls, filters: Sequence[Any], *, on_error: str = "flag") -> Fleet:
        """Stack :class:`squkf.SquareRootUKF` filters of one configuration into a fleet.

        The filters must share dimensions, ``dt``, model functions (which must
        be vectorised: ``vectorized=True``), sigma-point family, scheme and hooks.

        Raises
        ------
        ParameterError
            If the filters differ in configuration.
        """
        c, x, P1_2, Q1_2, R1_2 = stacked(list(filters))
        fleet = cls(
            len(x), c.dim_x, c.dim_z, c.dt, c.hx, c.fx, c.points, on_error=on_error, **filter_kwargs(c)
        )
        fleet.x, fleet.P1_2, fleet.Q1_2, fleet.R1_2 = x, P1_2, Q1_2, R1_2  # validated by the setters
        return fleet

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
        inputs.refuse_smoother_noise(self._fx_noise, "fleet")
        return fleet_rts_smoother(self, result, dts=dts, fx_args=fx_args)
