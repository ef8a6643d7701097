"""``SquareRootUKF``: g13ej's square-root UKF behind filterpy's ``UnscentedKalmanFilter`` API.

A thin facade over the step (:mod:`squkf.step`): each call validates its
inputs at the boundary, runs the step's pure transitions on the filter's
private state, and commits every new value at once when the whole call
succeeded. What it hands out is the caller's (fresh arrays), and what the
caller may edit in place (``x``, ``P``, ``Q``, ``R``) is validated at the next
call.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from typing import cast

import numpy as np

from . import smoother
from . import step as steps
from .batch import batch_filter
from .boundary import attributes, inputs
from .boundary.attributes import Covariance, Hook, State
from .boundary.config import Config
from .boundary.loop import Transaction
from .boundary.one_filter import OneFilter
from .boundary.records import LastUpdate, embed, innovation_inverse
from .gating import Gate
from .plan import Plan
from .validate import as_float_array, check_time_step

__all__ = ["SquareRootUKF"]

_LOG_TINY = math.log(sys.float_info.min)


class SquareRootUKF(OneFilter):
    """Square-root Unscented Kalman Filter with filterpy's interface.

    The model is ``x[k+1] = fx(x[k], dt) + v``, ``z[k] = hx(x[k]) + w`` with
    additive Gaussian noise ``v ~ N(0, Q)``, ``w ~ N(0, R)``. The covariance
    is carried as its lower Cholesky factor ``P1_2`` (``P = P1_2 @ P1_2.T``)
    and propagated by QR factorisations and rank-1 updates (NAG's g13ej), so
    it stays symmetric positive definite where the covariance form breaks.

    Replacing ``from filterpy.kalman import UnscentedKalmanFilter`` with
    ``from squkf import SquareRootUKF as UnscentedKalmanFilter`` runs the same
    program; with filterpy's default (redrawn) sigma points the numbers agree
    to rounding.

    Parameters
    ----------
    dim_x : int
        Number of state variables.
    dim_z : int
        Default number of measurement variables (``update`` accepts other
        sizes when given a matching ``R``).
    dt : float
        Default time step passed to ``fx``.
    hx : callable
        ``hx(x, **hx_args) -> (dim_z,)``; with ``vectorized=True``
        ``hx(sigmas, **hx_args)`` maps ``(N, dim_x)`` to ``(N, dim_z)``.
    fx : callable
        ``fx(x, dt, **fx_args) -> (dim_x,)``; with ``vectorized=True``
        ``fx(sigmas, dt, **fx_args)`` maps ``(N, dim_x)`` to ``(N, dim_x)``.
    points : sigma-point family or filterpy points object
        The first set's points and weights, e.g. ``MerweScaledWeights()`` or
        filterpy's ``MerweScaledSigmaPoints(n, alpha, beta, kappa)``.
    sqrt_fn : callable, optional
        Accepted for compatibility and stored as ``msqrt``; unused, since the
        filter carries the Cholesky factor itself.
    x_mean_fn, z_mean_fn : callable ``(sigmas, Wm) -> mean``, optional
    residual_x, residual_z : callable ``(a, b) -> a - b``, optional
    state_add : callable ``(x, dx) -> x + dx``, optional
        filterpy's hooks for angles and other non-additive quantities.
    scheme : {"redrawn", "augmented", "propagated"} or generator, keyword-only
        How the second sigma-point set is formed (g13ej's ROPT(1)); a
        generator object may carry its own weights (ROPT(5..7)).
    vectorized : bool, keyword-only
        Call ``fx`` and ``hx`` once with all sigma points.
    gate : None, float or Gate, keyword-only
        Outlier gating (off by default): a chi-square probability such as
        ``0.999``, or a :class:`~squkf.Gate` (a squared Mahalanobis distance,
        per-component tests). A rejected measurement is treated as missing
        (see :mod:`squkf.gating`); ``rejected`` and ``nis`` tell what happened.
    fx_noise, hx_noise : int, keyword-only
        Noise that enters the model (the augmented UKF, :mod:`squkf.noise`):
        ``fx(x, w, dt, **fx_args)`` and ``hx(x, v, **hx_args)`` take the noise
        as their second argument (with ``vectorized=True``, ``(N, dim_w)`` and
        ``(N, dim_v)`` noise points). ``Q`` is then w's covariance
        ``(dim_w, dim_w)``, ``R`` v's ``(dim_v, dim_v)``. Default None:
        additive noise. Needs the redrawn second set.

    Attributes
    ----------
    x : ndarray, shape (dim_x,)
    P, Q : ndarray, shape (dim_x, dim_x)
        Read as matrices, stored as factors; assignments and edits in place as
        :ref:`promise-edits` says, fresh arrays as :ref:`promise-records`.
    R : ndarray, shape (dim_z, dim_z)
    x_prior, P1_2_prior, x_post, P1_2_post : ndarray
        Records of the last prediction and update (also ``P_prior``,
        ``P_post`` and the last update's records below).
    y : ndarray, shape (dim_z,)
        Innovation; NaN in components that were not measured.
    z : ndarray
    sigmas_f, sigmas_h : ndarray

    Examples
    --------
    A constant-velocity target whose position is measured once per second:

    >>> import numpy as np
    >>> from squkf import MerweScaledWeights, SquareRootUKF
    >>> def fx(x, dt):
    ...     return np.array([x[0] + dt * x[1], x[1]])
    >>> def hx(x):
    ...     return x[:1]
    >>> ukf = SquareRootUKF(dim_x=2, dim_z=1, dt=1.0, hx=hx, fx=fx, points=MerweScaledWeights(alpha=0.5))
    >>> ukf.P *= 10.0
    >>> ukf.Q = np.diag([1e-4, 1e-2])
    >>> ukf.R = [[0.25]]
    >>> for z in [1.1, 1.9, 3.2, 3.9, 5.1]:
    ...     ukf.predict()
    ...     ukf.update([z])
    >>> print(np.round(ukf.x, 4))
    [5.037  1.0003]
    >>> print(np.round(ukf.P1_2, 4))
    [[0.3904 0.    ]
     [0.1401 0.1546]]

    The same step in halves (ask for sigma points, tell their images):

    >>> X = ukf.ask_predict()
    >>> X.shape
    (5, 2)
    >>> x_prior, P1_2_prior = ukf.tell_predict([fx(x, 1.0) for x in X])
    >>> Y = ukf.ask_update()
    >>> x_post, P1_2_post = ukf.tell_update([hx(y) for y in Y], [6.0])
    >>> print(np.round(x_post, 4))
    [6.0168 0.9937]
    """

    x = State()
    P = Covariance()
    Q = Covariance()
    R = Covariance()
    x_mean = Hook()
    z_mean = Hook()
    residual_x = Hook()
    residual_z = Hook()
    state_add = Hook()

    def __init__(
        self,
        dim_x: int,
        dim_z: int,
        dt: float,
        hx: Callable,
        fx: Callable,
        points,
        sqrt_fn: Callable | None = None,
        x_mean_fn: Callable | None = None,
        z_mean_fn: Callable | None = None,
        residual_x: Callable | None = None,
        residual_z: Callable | None = None,
        state_add: Callable | None = None,
        *,
        scheme="redrawn",
        vectorized: bool = False,
        gate: float | Gate | None = None,
        fx_noise: int | None = None,
        hx_noise: int | None = None,
    ):
        n, m = inputs.check_sizes(dim_x=dim_x, dim_z=dim_z)
        self._dim_x = n
        self._dim_z = m
        self._fx_noise, self._hx_noise = inputs.model_noise(fx, hx, fx_noise, hx_noise)
        self._dt = check_time_step(dt)
        self._plan = cast(Plan, None)  # the scheme setter below sets it
        self._family = None
        self._generator = None
        self.hx = hx
        self.fx = fx
        self.points_fn = points
        self.scheme = scheme
        self.msqrt = sqrt_fn
        self.x_mean = x_mean_fn
        self.z_mean = z_mean_fn
        self.residual_x = np.subtract if residual_x is None else residual_x
        self.residual_z = np.subtract if residual_z is None else residual_z
        self.state_add = np.add if state_add is None else state_add
        self.vectorized = bool(vectorized)
        self.gate = gate
        self.inv = np.linalg.inv

        # x, P, Q (the noise's own dimension when it enters fx), R; the records of no step yet
        attributes.initial(self.__dict__, n, m, self._fx_noise or n, self._hx_noise or m, self._num_sigmas)
        self._state = steps.StepState()
        self._step_plan = self._plan
        self._noise_cache = {}
        self._last = LastUpdate.none(n, m)

    # -- configuration -----------------------------------------------------

    @property
    def points_fn(self):
        """The sigma-point family (or filterpy points object) of the first set."""
        return self._points

    @points_fn.setter
    def points_fn(self, points):
        self._set_points(points)

    @property
    def scheme(self):
        """The second-set generator (``Redrawn()``, ``Augmented()`` or your own)."""
        return self._generator

    @scheme.setter
    def scheme(self, value):
        self._set_scheme(value)

    @property
    def dim_x(self) -> int:
        """Number of state variables."""
        return self._dim_x

    @property
    def dim_z(self) -> int:
        """Default number of measurement variables."""
        return self._dim_z

    @property
    def Wm(self) -> np.ndarray:
        """Mean weights of the first sigma-point set, shape ``(N,)`` (a copy)."""
        return self._plan.first.rows.Wm.copy()

    @property
    def Wc(self) -> np.ndarray:
        """Covariance weights of the first sigma-point set, shape ``(N,)`` (a copy)."""
        return self._plan.first.rows.Wc.copy()

    # -- state and covariances ---------------------------------------------

    @property
    def P1_2(self) -> np.ndarray:
        """Lower Cholesky factor of ``P`` (a fresh copy; assign to change)."""
        return cast(np.ndarray, self._P.factor()).copy()  # P is never singular, so never None

    @P1_2.setter
    def P1_2(self, value):
        attributes.set_factor(self.__dict__, "P", value)

    @property
    def Q1_2(self) -> np.ndarray:
        """Lower factor of ``Q`` (zeros when there is no process noise; a fresh copy)."""
        return self._Q.factor_or_zeros().copy()

    @Q1_2.setter
    def Q1_2(self, value):
        attributes.set_factor(self.__dict__, "Q", value)

    @property
    def R1_2(self) -> np.ndarray:
        """Lower factor of ``R`` (a fresh copy)."""
        return self._R.factor_or_zeros().copy()

    @R1_2.setter
    def R1_2(self, value):
        attributes.set_factor(self.__dict__, "R", value)

    @property
    def P_prior(self) -> np.ndarray:
        """Covariance after the last prediction (a fresh array)."""
        return self.P1_2_prior @ self.P1_2_prior.T

    @property
    def P_post(self) -> np.ndarray:
        """Covariance after the last update (a fresh array)."""
        return self.P1_2_post @ self.P1_2_post.T

    # -- the last update's records ------------------------------------------

    @property
    def S1_2(self) -> np.ndarray:
        """Lower factor of the last innovation covariance (NaN where a component was missing)."""
        return embed(self._last.Sy, self._last.observed, np.nan)

    @property
    def S(self) -> np.ndarray:
        """Innovation covariance of the last update, ``S1_2 @ S1_2.T`` (NaN where missing)."""
        last = self._last
        return embed(last.Sy @ last.Sy.T, last.observed, np.nan)

    @property
    def SI(self) -> np.ndarray:
        """Inverse of ``S``, by triangular solves with ``S1_2`` (or by ``self.inv`` if replaced)."""
        if self.inv is not np.linalg.inv:
            return self.inv(self.S)
        return innovation_inverse(self._last.Sy, self._last.observed)

    @property
    def K(self) -> np.ndarray:
        """Kalman gain of the last update, shape ``(dim_x, dim_z)`` (zero columns where missing).

        Formed once per update; a fresh copy on each read (:ref:`promise-records`).
        """
        if self._last.K is None:
            self._last = self._last.with_gain(self._dim_x)
        return self._last.K.copy()  # type: ignore[union-attr]  # formed above

    @K.setter
    def K(self, value):
        self._last = self._last.replace(K=as_float_array(value, "K"))  # a private copy: read as fresh ones

    @property
    def log_likelihood(self) -> float:
        """Log-likelihood of the last measurement (the components it used), from the innovation factor.

        0 when a gate rejected them all (``likelihood`` 1).
        """
        return self._last.log_likelihood if self._last.measured else _LOG_TINY

    @property
    def likelihood(self) -> float:
        """``exp(log_likelihood)``, never below ``sys.float_info.min``."""
        return max(math.exp(self.log_likelihood), sys.float_info.min)

    @property
    def mahalanobis(self) -> float:
        """Mahalanobis distance of the last innovation, ``||S1_2^-1 y||`` (measured components)."""
        return math.sqrt(self._last.nis) if self._last.measured else 0.0

    @property
    def nis(self) -> float:
        """Normalised innovation squared of the last update, ``y^T S^-1 y`` (measured components).

        What a gate tests.
        """
        return self._last.nis if self._last.measured else 0.0

    @property
    def rejected(self) -> np.ndarray:
        """Which components of the last measurement the gate rejected, shape ``(dim_z,)`` (a fresh array).

        After a gated update ``y``, ``S``, ``S1_2`` are the tested innovation's,
        ``K`` the gain applied (zero columns for rejected components).
        """
        return self._last.rejected.copy()

    # -- ask/tell: the step in halves ----------------------------------------

    def ask_predict(self) -> np.ndarray:
        """First half of a prediction: the sigma points to propagate.

        Returns
        -------
        sigmas : ndarray, shape (N, dim_x)
            One point per row (a fresh array); evaluate the state transition
            at each and pass the results to :meth:`tell_predict`.

        Examples
        --------
        >>> import numpy as np
        >>> from squkf import MerweScaledWeights, SquareRootUKF
        >>> ukf = SquareRootUKF(
        ...     2, 1, 1.0, hx=lambda x: x[:1], fx=lambda x, dt: x, points=MerweScaledWeights()
        ... )
        >>> X = ukf.ask_predict()  # x = 0, P = I: the unit points, gamma = sqrt(3)
        >>> print(np.round(X, 4))
        [[ 0.      0.    ]
         [ 1.7321  0.    ]
         [ 0.      1.7321]
         [-1.7321  0.    ]
         [ 0.     -1.7321]]
        >>> x_prior, P1_2_prior = ukf.tell_predict(X)  # the identity model: the prior adds Q = I
        >>> print(np.round(P1_2_prior @ P1_2_prior.T, 6))
        [[2. 0.]
         [0. 2.]]
        """
        return self._ask_predict()

    def tell_predict(self, sigmas_f, Q=None, UT: Callable | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Second half of a prediction: the propagated points give the prior.

        Parameters
        ----------
        sigmas_f : array_like, shape (N, dim_x)
            The state transition at each point from :meth:`ask_predict`
            (with ``fx_noise``, at each augmented point ``[x_i, w_i]`` it gave).
        Q : ndarray, shape (dim_x, dim_x), optional
            Process noise for this step only (default ``self.Q``); not with
            ``fx_noise``, where the noise is in the points already.
        UT : callable, optional
            Square-root transform with the signature of
            :func:`squkf.sqrt_unscented_transform`.

        Returns
        -------
        x_prior : ndarray, shape (dim_x,)
        P1_2_prior : ndarray, shape (dim_x, dim_x)
            Fresh arrays.
        """
        inputs.refuse_noise_args(self._step_plan.w_xi, "Q", Q, UT)
        self._tell_predict(self._state, self._step_plan, sigmas_f, Q, UT, self._hooks())
        return self.x_prior.copy(), self.P1_2_prior.copy()

    def ask_update(self) -> np.ndarray:
        """First half of an update: the sigma points to pass through the measurement function.

        Returns
        -------
        sigmas : ndarray, shape (N2, dim_x)
            The second set (redrawn from the prior, or augmented; a fresh
            array); evaluate ``hx`` at each and pass the results to
            :meth:`tell_update`.
        """
        return self._ask_update()

    def tell_update(self, sigmas_h, z, R=None, UT: Callable | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Second half of an update: measurement-function values and ``z`` give the posterior.

        Parameters
        ----------
        sigmas_h : array_like, shape (N2, dim_z)
            The measurement function at each point from :meth:`ask_update`.
        z : array_like, shape (dim_z,)
            The measurement (missing components: :ref:`promise-missing`); its
            length may differ from ``dim_z`` if ``R`` has the matching size.
        R : ndarray, optional
            Measurement noise for this update only (default ``self.R``); a
            scalar means ``R * I``.
        UT : callable, optional

        Returns
        -------
        x_post : ndarray, shape (dim_x,)
        P1_2_post : ndarray, shape (dim_x, dim_x)
            Fresh arrays.
        """
        self._told_update(sigmas_h, z, R, UT)
        return self.x_post.copy(), self.P1_2_post.copy()

    # -- filterpy's methods ---------------------------------------------------

    def predict(self, dt=None, UT=None, fx=None, Q=None, **fx_args) -> None:
        """Predict the state one step ahead: ``x``, ``P`` become the prior.

        Parameters
        ----------
        dt : float, optional
            Time step for this prediction (default: the constructor's ``dt``),
            as :ref:`promise-dt` says.
        UT : callable, optional
            Square-root transform, signature of :func:`squkf.sqrt_unscented_transform`.
        fx : callable, optional
            State transition for this step (default ``self.fx``).
        Q : ndarray, shape (dim_x, dim_x), optional
            Process noise for this step only (default ``self.Q``).
        **fx_args
            Passed to ``fx``.
        """
        self._predict(dt, UT, fx, Q, fx_args)

    def update(self, z, R=None, UT=None, hx=None, **hx_args) -> None:
        """Update the estimate with measurement ``z``: ``x``, ``P`` become the posterior.

        Parameters
        ----------
        z : array_like, shape (dim_z,), or None
            The measurement; ``None`` and missing components as
            :ref:`promise-missing` says.
        R : ndarray or float, optional
            Measurement noise for this update (default ``self.R``). With a
            ``z`` of another length (a second sensor), give ``R`` and ``hx``.
        UT : callable, optional
        hx : callable, optional
            Measurement function for this update (default ``self.hx``).
        **hx_args
            Passed to ``hx``.
        """
        self._update(z, R, UT, hx, hx_args)

    def compute_process_sigmas(self, dt, fx=None, **fx_args) -> None:
        """Set ``sigmas_f`` to the first set propagated through ``fx`` (state unchanged)."""
        self._process_sigmas(dt, fx, fx_args)

    def cross_variance(self, x, z, sigmas_f, sigmas_h) -> np.ndarray:
        """Cross-covariance ``sum Wc[i] (sigmas_f[i] - x)(sigmas_h[i] - z)^T``.

        The weights are those of the set with as many points as ``sigmas_f``
        (the second set after a prediction, else the first).
        """
        return self._cross_variance(x, z, sigmas_f, sigmas_h)

    def batch_filter(
        self,
        zs,
        Rs=None,
        dts=None,
        UT=None,
        saver=None,
        Qs=None,
        *,
        fx_args=None,
        hx_args=None,
        return_factors: bool = False,
        progress=False,
    ):
        """Filter a whole sequence of measurements: :func:`squkf.batch.batch_filter` on this filter."""
        return batch_filter(
            self, zs, Rs, dts, UT, saver, Qs=Qs, fx_args=fx_args, hx_args=hx_args,
            return_factors=return_factors, progress=progress,
        )  # fmt: skip

    def rts_smoother(self, Xs, Ps, Qs=None, dts=None, UT=None, *, fx_args=None):
        """Square-root unscented RTS smoother: :func:`squkf.smoother.rts_smoother` on this filter."""
        self._refuse_smoother()
        return smoother.rts_smoother(self, Xs, Ps, Qs=Qs, dts=dts, UT=UT, fx_args=fx_args)

    def rts_smoother_factors(self, Xs, P1_2s, Qs=None, dts=None, UT=None, *, fx_args=None):
        """The smoother on lower factors: :func:`squkf.smoother.rts_smoother_factors` on this filter."""
        self._refuse_smoother()
        return smoother.rts_smoother_factors(self, Xs, P1_2s, Qs=Qs, dts=dts, UT=UT, fx_args=fx_args)

    # -- configuration and transactions (copies and pickles: InDictCopies) ------

    def configuration(self) -> Config:
        """The filter's configuration and noise factors (``squkf.boundary.Config``).

        What ``Fleet.from_filters`` and the smoother read; the arrays are the
        filter's own, to be read and not written.
        """
        return self._configuration()

    def transaction(self) -> Transaction:
        """A context manager that puts the filter back as it was on entry if anything inside raises.

        What :meth:`batch_filter` runs its steps in (``squkf.boundary.loop.Transaction``).
        """
        return Transaction(self._snapshot, self._restore)

    def __repr__(self) -> str:
        return self._describe("SquareRootUKF object")
