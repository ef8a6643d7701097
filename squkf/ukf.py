"""``SquareRootUKF``: g13ej's square-root UKF behind filterpy's ``UnscentedKalmanFilter`` API."""

from __future__ import annotations

import copy
import functools
import math
import sys
from collections.abc import Callable

import numpy as np

from . import blas
from .covariance import FactorSlot
from .errors import NonFiniteError, ParameterError, ShapeError
from .generators import as_generator, sigma_points_from_factor
from .lane import Lane, lane_for
from .linalg import all_finite, solve_lower
from .measurement import gain_from_factors
from .step import PRIOR, StepMachine, check_values
from .transform import deviations
from .weights import as_family

__all__ = ["SquareRootUKF"]

_LOG_TINY = math.log(sys.float_info.min)
_LOG_2PI = math.log(2.0 * math.pi)


def _readonly(a: np.ndarray | None) -> np.ndarray | None:
    if a is None:
        return None
    v = a.view()
    v.flags.writeable = False
    return v


def _one_blas_thread(method):
    """Run ``method`` on one BLAS thread for states of ``blas.MIN_DIM`` or more (see :mod:`squkf.blas`)."""

    @functools.wraps(method)
    def run(self, *args, **kwargs):
        if blas.MIN_DIM is not None and self._dim_x >= blas.MIN_DIM:
            with blas.one_blas_thread():
                return method(self, *args, **kwargs)
        return method(self, *args, **kwargs)

    return run


class SquareRootUKF:
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
    scheme : {"redrawn", "augmented"} or generator, keyword-only
        How the second sigma-point set is formed (g13ej's ROPT(1)); a
        generator object may carry its own weights (ROPT(5..7)).
    vectorized : bool, keyword-only
        Call ``fx`` and ``hx`` once with all sigma points.

    Attributes
    ----------
    x : ndarray, shape (dim_x,)
    P, Q : ndarray, shape (dim_x, dim_x)
        Read as matrices, stored as factors; assignment (and in-place edits)
        are validated and factored once.
    R : ndarray, shape (dim_z, dim_z)
    P1_2, Q1_2, R1_2 : ndarray
        The lower factors themselves (read-only arrays; assign to change).
    x_prior, P_prior, P1_2_prior, x_post, P_post, P1_2_post
    K : ndarray, shape (dim_x, dim_z)
    y : ndarray, shape (dim_z,)
    z : ndarray
    S, SI : ndarray, shape (dim_z, dim_z)
        Innovation covariance and its inverse (formed on request, SI by
        triangular solves); ``S1_2`` is the innovation factor.
    sigmas_f, sigmas_h : ndarray
    Wm, Wc : ndarray
        Weights of the first sigma-point set.
    log_likelihood, likelihood, mahalanobis : float
    """

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
    ):
        for name, v in (("dim_x", dim_x), ("dim_z", dim_z)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ParameterError(f"{name} must be a positive integer, got {name}={v!r}")
        self._dim_x = int(dim_x)
        self._dim_z = int(dim_z)
        self._dt = self._check_dt(dt)
        self.hx = hx
        self.fx = fx
        self.points_fn = points
        self.msqrt = sqrt_fn
        self.x_mean = x_mean_fn
        self.z_mean = z_mean_fn
        self.residual_x = np.subtract if residual_x is None else residual_x
        self.residual_z = np.subtract if residual_z is None else residual_z
        self.state_add = np.add if state_add is None else state_add
        self.scheme = scheme
        self.vectorized = bool(vectorized)
        self.inv = np.linalg.inv

        n, m = self._dim_x, self._dim_z
        self._x = np.zeros(n)
        self._x_bytes = b""  # the bytes of x when it was last found valid
        self._P = FactorSlot("P", n, semidefinite=False, factor=np.eye(n))
        self._Q = FactorSlot("Q", n, semidefinite=True, factor=np.eye(n))
        self._R = FactorSlot("R", m, semidefinite=True, factor=np.eye(m), singular_factor_ok=False)
        self._machine = StepMachine()
        self._noise_cache = {}

        self.x_prior = self._x.copy()
        self.P1_2_prior = np.eye(n)
        self.x_post = self._x.copy()
        self.P1_2_post = np.eye(n)
        self.sigmas_f = np.zeros((self._num_sigmas, n))
        self.sigmas_h = np.zeros((self._num_sigmas, m))
        self._K = np.zeros((n, m))
        self._L21 = None  # K @ S1_2 of the last update: K is formed from it on request
        self.y = np.zeros(m)
        self.z = np.array([[None] * m]).T
        self.S1_2 = np.zeros((m, m))
        self._log_likelihood = _LOG_TINY
        self._likelihood = sys.float_info.min
        self._mahalanobis = None

    # -- configuration -----------------------------------------------------

    @property
    def points_fn(self):
        """The sigma-point family (or filterpy points object) of the first set."""
        return self._points

    @points_fn.setter
    def points_fn(self, points):
        family = as_family(points)
        n = self._dim_x
        try:
            num = family.num_sigmas(n)
            family.unit_sigma_points(n)
            family.weights(n)
        except ParameterError:
            raise
        except Exception as exc:  # a user's family that cannot serve this dimension
            raise ParameterError(f"points cannot give sigma points for dim_x={n}: {exc}") from exc
        self._points = points
        self._family = family
        self._num_sigmas = num
        self._lane = None  # built on first use

    @property
    def scheme(self):
        """The second-set generator (``Redrawn()``, ``Augmented()`` or your own)."""
        return self._generator

    @scheme.setter
    def scheme(self, value):
        gen = as_generator(value)
        if hasattr(gen, "num_sigmas"):
            gen.num_sigmas(self._dim_x, self._family)  # fails now, not at the first update
        self._generator = gen
        self._lane = None  # built on first use

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
        """Mean weights of the first sigma-point set, shape ``(N,)``."""
        return self._family.weights(self._dim_x)[0]

    @property
    def Wc(self) -> np.ndarray:
        """Covariance weights of the first sigma-point set, shape ``(N,)``."""
        return self._family.weights(self._dim_x)[1]

    # -- state and covariances ---------------------------------------------

    @property
    def x(self) -> np.ndarray:
        """State estimate, shape ``(dim_x,)``; editable in place."""
        return self._x

    @x.setter
    def x(self, value):
        self._x = self._as_state(value, "x")
        self._machine.forget_propagated()

    def _as_state(self, value, name) -> np.ndarray:
        try:
            x = np.array(value, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ShapeError(f"{name} must be a float vector of length {self._dim_x}: {exc}") from None
        if x.shape not in ((self._dim_x,), (self._dim_x, 1)):
            raise ShapeError(f"{name} has shape {x.shape}, expected ({self._dim_x},)")
        x = x.reshape(self._dim_x)
        if not np.all(np.isfinite(x)):
            raise NonFiniteError(f"{name} contains NaN or inf: {x!r}")
        return x

    @property
    def P(self) -> np.ndarray:
        """State covariance ``P1_2 @ P1_2.T``; assignment and in-place edits are factored once."""
        return self._P.matrix()

    @P.setter
    def P(self, value):
        self._P.set_matrix(value)
        self._machine.forget_propagated()

    @property
    def P1_2(self) -> np.ndarray:
        """Lower Cholesky factor of ``P`` (read-only array; assign to change)."""
        return _readonly(self._P.factor())

    @P1_2.setter
    def P1_2(self, value):
        self._P.set_factor(value)
        self._machine.forget_propagated()

    @property
    def Q(self) -> np.ndarray:
        """Process noise covariance; ``None`` or zeros mean no process noise."""
        return self._Q.matrix()

    @Q.setter
    def Q(self, value):
        self._Q.set_matrix(value)

    @property
    def Q1_2(self) -> np.ndarray:
        """Lower factor of ``Q`` (zeros when there is no process noise)."""
        return _readonly(self._Q.factor_or_zeros())

    @Q1_2.setter
    def Q1_2(self, value):
        self._Q.set_factor(value)

    @property
    def R(self) -> np.ndarray:
        """Measurement noise covariance (default for ``update``)."""
        return self._R.matrix()

    @R.setter
    def R(self, value):
        self._R.set_matrix(value)

    @property
    def R1_2(self) -> np.ndarray:
        """Lower factor of ``R``."""
        return _readonly(self._R.factor_or_zeros())

    @R1_2.setter
    def R1_2(self, value):
        self._R.set_factor(value)

    @property
    def P_prior(self) -> np.ndarray:
        """Covariance after the last prediction (a copy)."""
        return self.P1_2_prior @ self.P1_2_prior.T

    @property
    def P_post(self) -> np.ndarray:
        """Covariance after the last update (a copy)."""
        return self.P1_2_post @ self.P1_2_post.T

    @property
    def S(self) -> np.ndarray:
        """Innovation covariance of the last update, ``S1_2 @ S1_2.T``."""
        return self.S1_2 @ self.S1_2.T

    @property
    def SI(self) -> np.ndarray:
        """Inverse of ``S``, by triangular solves with ``S1_2`` (or by ``self.inv`` if replaced)."""
        if self.inv is not np.linalg.inv:
            return self.inv(self.S)
        m = self.S1_2.shape[0]
        if not np.all(self.S1_2.diagonal() != 0):
            return np.zeros((m, m))
        W = solve_lower(self.S1_2, np.eye(m))
        return W.T @ W

    @property
    def K(self) -> np.ndarray:
        """Kalman gain of the last update, shape ``(dim_x, dim_z)`` (formed on request)."""
        if self._K is None:
            self._K = gain_from_factors(self.S1_2, self._L21)
        return self._K

    @K.setter
    def K(self, value):
        self._K = value

    # -- likelihood ---------------------------------------------------------

    def _whitened_innovation(self) -> np.ndarray:
        return solve_lower(self.S1_2, np.asarray(self.y, dtype=float).reshape(-1))

    @property
    def log_likelihood(self) -> float:
        """Log-likelihood of the last measurement, from the innovation factor."""
        if self._log_likelihood is None:
            w = self._whitened_innovation()
            logdet = 2.0 * float(np.sum(np.log(np.abs(self.S1_2.diagonal()))))
            self._log_likelihood = -0.5 * (w.size * _LOG_2PI + logdet + float(w @ w))
        return self._log_likelihood

    @property
    def likelihood(self) -> float:
        """``exp(log_likelihood)``, never below ``sys.float_info.min``."""
        if self._likelihood is None:
            self._likelihood = max(math.exp(self.log_likelihood), sys.float_info.min)
        return self._likelihood

    @property
    def mahalanobis(self) -> float:
        """Mahalanobis distance of the last innovation, ``||S1_2^-1 y||``."""
        if self._mahalanobis is None:
            if not np.any(self.S1_2):
                return 0.0
            w = self._whitened_innovation()
            self._mahalanobis = float(math.sqrt(w @ w))
        return self._mahalanobis

    # -- helpers ------------------------------------------------------------

    @staticmethod
    def _check_dt(dt) -> float:
        try:
            value = float(dt)
        except (TypeError, ValueError):
            raise ParameterError(f"dt must be a positive finite number, got dt={dt!r}") from None
        if not (math.isfinite(value) and value > 0):
            raise ParameterError(f"dt must be a positive finite number, got dt={dt!r}")
        return value

    def _noise_factor(self, value, slot: FactorSlot, name: str, dim: int) -> np.ndarray | None:
        """Factor of a per-call noise matrix (cached for repeated identical arrays)."""
        if value is None:
            S = slot.factor()
            if S is not None and S.shape[0] != dim:
                raise ShapeError(
                    f"{name} is {S.shape[0]}x{S.shape[0]} but the {'measurement' if name == 'R' else 'state'}"
                    f" has length {dim}; pass {name}= for a model of another size"
                )
            return S
        cached = self._noise_cache.get(name)
        if cached is not None and cached[0] is value and np.array_equal(cached[1], value):
            return cached[2]
        tmp = FactorSlot(name, dim, semidefinite=True, factor=None)
        tmp.set_matrix(value)
        S = tmp.factor()
        if isinstance(value, np.ndarray):
            self._noise_cache[name] = (value, value.copy(), S)
        return S

    def _set_trusted_x(self, x: np.ndarray) -> None:
        """Install a mean computed by the filter itself (already checked)."""
        self._x = x
        self._x_bytes = x.tobytes()

    def _current(self) -> tuple[np.ndarray, np.ndarray]:
        """The current mean and factor, with in-place edits of ``x`` and ``P`` checked."""
        x = self._x
        if x.tobytes() != self._x_bytes:  # assigned or edited in place since last checked
            if x.dtype != np.float64 or x.shape != (self._dim_x,):
                x = self._x = self._as_state(x, "x")
            elif not all_finite(x):
                raise NonFiniteError(f"x contains NaN or inf: {x!r}")
            self._x_bytes = x.tobytes()
        return x, self._P.factor()

    def _evaluate(self, fn: Callable, sigmas: np.ndarray, args: tuple, kwargs: dict) -> object:
        if self.vectorized:
            return fn(sigmas, *args, **kwargs)
        # one call per point: spelled out for the common cases, since unpacking *args and
        # **kwargs at every call costs more than the loop itself
        if kwargs:
            return [fn(s, *args, **kwargs) for s in sigmas]
        if not args:
            return [fn(s) for s in sigmas]
        if len(args) == 1:
            dt = args[0]
            return [fn(s, dt) for s in sigmas]
        return [fn(s, *args) for s in sigmas]

    @staticmethod
    def _hook(fn, default):
        return None if fn is default else fn

    def _plain_lane(self, UT) -> Lane | None:
        """The plain step's kernel, when the configuration is plain (no hooks, no ``UT``)."""
        if not (
            UT is None
            and self.x_mean is None
            and self.z_mean is None
            and self.residual_x is np.subtract
            and self.residual_z is np.subtract
            and self.state_add is np.add
        ):
            return None
        lane = self._lane
        if lane is None:
            lane = self._lane = lane_for(self._dim_x, self._family, self._generator) or False
        elif lane is not False and lane.family2 is not self._generator.family_for(self._family):
            lane = self._lane = lane_for(self._dim_x, self._family, self._generator) or False
        return lane or None

    # -- ask/tell: the step in halves ----------------------------------------

    def ask_predict(self) -> np.ndarray:
        """First half of a prediction: the sigma points to propagate.

        Returns
        -------
        sigmas : ndarray, shape (N, dim_x)
            One point per row; evaluate the state transition at each and pass
            the results to :meth:`tell_predict`.
        """
        return self._ask_predict(self._plain_lane(None))

    def _ask_predict(self, lane: Lane | None) -> np.ndarray:
        x, S = self._current()
        return self._machine.ask_predict(x, S, self._family, self._hook(self.state_add, np.add), lane)

    def tell_predict(self, sigmas_f, Q=None, UT: Callable | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Second half of a prediction: the propagated points give the prior.

        Parameters
        ----------
        sigmas_f : array_like, shape (N, dim_x)
            The state transition at each point from :meth:`ask_predict`.
        Q : ndarray, shape (dim_x, dim_x), optional
            Process noise for this step only (default ``self.Q``).
        UT : callable, optional
            Square-root transform with the signature of
            :func:`squkf.sqrt_unscented_transform`.

        Returns
        -------
        x_prior : ndarray, shape (dim_x,)
        P1_2_prior : ndarray, shape (dim_x, dim_x)
        """
        snap = self._machine.snapshot()
        try:
            x, S = self._tell_predict(sigmas_f, Q, UT, self._plain_lane(UT))
        except BaseException:
            self._machine.restore(snap)
            raise
        return x, _readonly(S)

    @_one_blas_thread
    def _tell_predict(self, sigmas_f, Q, UT, lane: Lane | None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`tell_predict` without the snapshot (the caller restores the machine on failure)."""
        Q1_2 = self._noise_factor(Q, self._Q, "Q", self._dim_x)
        machine = self._machine
        if lane is not None:
            x, S = machine.tell_predict(sigmas_f, Q1_2, lane=lane)
            preview = machine.draw_second_set(x, S, self._family, self._generator, None, lane)
        else:
            x, S = machine.tell_predict(
                sigmas_f,
                Q1_2,
                x_mean_fn=self.x_mean,
                residual_x=self._hook(self.residual_x, np.subtract),
                UT=UT,
            )
            preview = machine.draw_second_set(
                x, S, self._family, self._generator, self._hook(self.state_add, np.add)
            )
        self._set_trusted_x(x)
        self._P.set_trusted_factor(S)
        self.x_prior = x.copy()
        self.P1_2_prior = S
        self.sigmas_f = preview.sigmas  # filterpy shows the second set once the prediction is done
        return self.x_prior, S

    def ask_update(self) -> np.ndarray:
        """First half of an update: the sigma points to pass through the measurement function.

        Returns
        -------
        sigmas : ndarray, shape (N2, dim_x)
            The second set (redrawn from the prior, or augmented); evaluate
            ``hx`` at each and pass the results to :meth:`tell_update`.
        """
        return self._ask_update(self._plain_lane(None))

    def _ask_update(self, lane: Lane | None) -> np.ndarray:
        x, S = self._current()
        hook = None if lane is not None else self._hook(self.state_add, np.add)
        return self._machine.ask_update(x, S, self._family, self._generator, hook, lane).sigmas

    def tell_update(self, sigmas_h, z, R=None, UT: Callable | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Second half of an update: measurement-function values and ``z`` give the posterior.

        Parameters
        ----------
        sigmas_h : array_like, shape (N2, dim_z)
            The measurement function at each point from :meth:`ask_update`.
        z : array_like, shape (dim_z,)
            The measurement (its length may differ from ``dim_z`` if ``R``
            has the matching size).
        R : ndarray, optional
            Measurement noise for this update only (default ``self.R``); a
            scalar means ``R * I``.
        UT : callable, optional

        Returns
        -------
        x_post : ndarray, shape (dim_x,)
        P1_2_post : ndarray, shape (dim_x, dim_x)
        """
        x, S = self._tell_update(sigmas_h, self._as_measurement(z, R), R, UT, self._plain_lane(UT))
        return x, _readonly(S)

    @_one_blas_thread
    def _tell_update(self, sigmas_h, z: np.ndarray, R, UT, lane: Lane | None) -> tuple[np.ndarray, ...]:
        """:meth:`tell_update` with ``z`` already validated (a fresh array, kept as ``self.z``)."""
        R1_2 = self._noise_factor(R, self._R, "R", z.shape[0])
        if R1_2 is None:
            R1_2 = np.zeros((z.shape[0], z.shape[0]))
        if lane is not None:
            post = self._machine.tell_update(sigmas_h, z, R1_2, lane=lane)
        else:
            post = self._machine.tell_update(
                sigmas_h,
                z,
                R1_2,
                z_mean_fn=self.z_mean,
                residual_x=self._hook(self.residual_x, np.subtract),
                residual_z=self._hook(self.residual_z, np.subtract),
                state_add=self._hook(self.state_add, np.add),
                UT=UT,
            )
        self._set_trusted_x(post.x)
        self._P.set_trusted_factor(post.S)
        self._K = None
        self._L21 = post.L21
        self.y = post.y
        self.S1_2 = post.Sy
        self.sigmas_h = self._machine.sigmas_h
        self.z = z
        self.x_post = post.x.copy()
        self.P1_2_post = post.S
        self._log_likelihood = None
        self._likelihood = None
        self._mahalanobis = None
        return self.x_post, post.S

    def _as_measurement(self, z, R, missing_ok: bool = False) -> np.ndarray | None:
        """``z`` as a float vector, checked; with ``missing_ok`` an all-NaN ``z`` gives None."""
        try:
            arr = np.array(z, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ShapeError(f"z must be a float vector: {exc}") from None
        if arr.ndim != 1:
            if arr.ndim == 0:
                arr = arr.reshape(1)
            elif arr.ndim == 2 and 1 in arr.shape:
                arr = arr.reshape(-1)
            else:
                raise ShapeError(f"z has shape {np.shape(z)}, expected ({self._dim_z},)")
        if not all_finite(arr):
            if missing_ok and np.isnan(arr).all():
                return None
            raise NonFiniteError(f"z contains NaN or inf: {arr!r}")
        if R is None and arr.shape[0] != self._dim_z:
            Rdim = self._R.factor_or_zeros().shape[0]
            if Rdim != arr.shape[0]:
                raise ShapeError(
                    f"z has length {arr.shape[0]} but dim_z is {self._dim_z} and R is {Rdim}x{Rdim};"
                    " pass R= (and hx=) for a measurement of another size"
                )
        return arr

    # -- filterpy's methods ---------------------------------------------------

    def predict(self, dt=None, UT=None, fx=None, Q=None, **fx_args) -> None:
        """Predict the state one step ahead: ``x``, ``P`` become the prior.

        Parameters
        ----------
        dt : float, optional
            Time step for this prediction (default: the constructor's ``dt``).
        UT : callable, optional
            Square-root transform, signature of :func:`squkf.sqrt_unscented_transform`.
        fx : callable, optional
            State transition for this step (default ``self.fx``).
        Q : ndarray, shape (dim_x, dim_x), optional
            Process noise for this step only (default ``self.Q``).
        **fx_args
            Passed to ``fx``.
        """
        dt = self._dt if dt is None else self._check_dt(dt)
        fx = self.fx if fx is None else fx
        lane = self._plain_lane(UT)
        snap = self._machine.snapshot()
        try:
            sigmas = self._ask_predict(lane)
            values = self._evaluate(fx, sigmas, (dt,), fx_args)
            self._tell_predict(values, Q, UT, lane)
        except BaseException:
            self._machine.restore(snap)
            raise

    def update(self, z, R=None, UT=None, hx=None, **hx_args) -> None:
        """Update the estimate with measurement ``z``: ``x``, ``P`` become the posterior.

        Parameters
        ----------
        z : array_like, shape (dim_z,), or None
            ``None`` (or all-NaN) means no measurement: the prior is kept as
            the posterior.
        R : ndarray or float, optional
            Measurement noise for this update (default ``self.R``). With a
            ``z`` of another length (a second sensor), give ``R`` and ``hx``.
        UT : callable, optional
        hx : callable, optional
            Measurement function for this update (default ``self.hx``).
        **hx_args
            Passed to ``hx``.
        """
        zz = None if z is None else self._as_measurement(z, R, missing_ok=np.ndim(z) > 0)
        if zz is None:
            self._machine.skip_update()
            self.z = np.array([[None] * self._dim_z]).T
            self.x_post = self._x.copy()
            self.P1_2_post = self._P.factor()
            return
        hx = self.hx if hx is None else hx
        lane = self._plain_lane(UT)
        snap = self._machine.snapshot()
        try:
            sigmas = self._ask_update(lane)
            values = self._evaluate(hx, sigmas, (), hx_args)
            self._tell_update(values, zz, R, UT, lane)
        except BaseException:
            self._machine.restore(snap)
            raise

    def compute_process_sigmas(self, dt, fx=None, **fx_args) -> None:
        """Set ``sigmas_f`` to the first set propagated through ``fx`` (state unchanged)."""
        dt = self._check_dt(dt)
        fx = self.fx if fx is None else fx
        x, S = self._current()
        sigmas = sigma_points_from_factor(
            x, S, self._family.unit_sigma_points(self._dim_x), self._hook(self.state_add, np.add)
        )
        values = self._evaluate(fx, sigmas, (dt,), fx_args)
        self.sigmas_f = check_values(values, sigmas.shape, "fx values")

    def cross_variance(self, x, z, sigmas_f, sigmas_h) -> np.ndarray:
        """Cross-covariance ``sum Wc[i] (sigmas_f[i] - x)(sigmas_h[i] - z)^T``.

        The weights are those of the set with as many points as ``sigmas_f``
        (the second set after a prediction, else the first).
        """
        sigmas_f = np.asarray(sigmas_f, dtype=float)
        sigmas_h = np.atleast_2d(np.asarray(sigmas_h, dtype=float))
        N = sigmas_f.shape[0]
        Wc = self.Wc
        if Wc.shape[0] != N and self._machine.phase == PRIOR:
            Wc = self._generator.second_set(
                self._x,
                self._P.factor(),
                family=self._family,
                propagated=self._machine._propagated,
                Q1_2=self._machine._Q1_2,
            ).Wc
        if Wc.shape[0] != N:
            raise ShapeError(f"sigmas_f has {N} points but the sigma-point sets have {Wc.shape[0]}")
        dx = deviations(sigmas_f, np.asarray(x, dtype=float), self._hook(self.residual_x, np.subtract))
        dz = deviations(sigmas_h, np.asarray(z, dtype=float), self._hook(self.residual_z, np.subtract))
        return (dx.T * Wc) @ dz

    def batch_filter(self, zs, Rs=None, dts=None, UT=None, saver=None, Qs=None, **kwargs):
        """Filter a whole sequence of measurements; see :func:`squkf.batch.batch_filter`.

        Returns ``(means, covariances)`` as filterpy does; also accepts ``Qs``
        (per-step process noise), ``fx_args``/``hx_args`` and ``return_factors``.
        """
        from .batch import batch_filter

        return batch_filter(self, zs, Rs=Rs, dts=dts, UT=UT, saver=saver, Qs=Qs, **kwargs)

    def rts_smoother(self, Xs, Ps, Qs=None, dts=None, UT=None, **kwargs):
        """Square-root unscented RTS smoother; see :func:`squkf.smoother.rts_smoother`.

        Returns ``(xs, Ps, Ks)`` as filterpy does. ``Qs[k]`` and ``dts[k]`` are
        those of the prediction into step ``k`` (the lists given to
        ``batch_filter``); ``fx_args`` may be given the same way.
        """
        from .smoother import rts_smoother

        return rts_smoother(self, Xs, Ps, Qs=Qs, dts=dts, UT=UT, **kwargs)

    def rts_smoother_factors(self, Xs, P1_2s, Qs=None, dts=None, UT=None, **kwargs):
        """The smoother on lower factors; see :func:`squkf.smoother.rts_smoother_factors`."""
        from .smoother import rts_smoother_factors

        return rts_smoother_factors(self, Xs, P1_2s, Qs=Qs, dts=dts, UT=UT, **kwargs)

    def _snapshot(self) -> dict:
        """Everything a failed multi-step call must put back (arrays are replaced, never mutated)."""
        state = dict(self.__dict__)
        for key in ("_P", "_Q", "_R", "_machine"):
            state[key] = copy.deepcopy(state[key])
        state["_x"] = self._x.copy()
        return state

    def _restore(self, state: dict) -> None:
        self.__dict__.clear()
        self.__dict__.update(state)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_noise_cache"] = {}
        return state

    def __repr__(self) -> str:
        from filterpy.common import pretty_str

        return "\n".join(
            [
                "SquareRootUKF object",
                pretty_str("x", self.x),
                pretty_str("P1_2", self._P.factor()),
                pretty_str("x_prior", self.x_prior),
                pretty_str("P1_2_prior", self.P1_2_prior),
                pretty_str("Q1_2", self._Q.factor()),
                pretty_str("R1_2", self._R.factor()),
                pretty_str("S1_2", self.S1_2),
                pretty_str("K", self.K),
                pretty_str("y", self.y),
                pretty_str("log-likelihood", self.log_likelihood),
                pretty_str("likelihood", self.likelihood),
                pretty_str("mahalanobis", self.mahalanobis),
                pretty_str("sigmas_f", self.sigmas_f),
                pretty_str("sigmas_h", self.sigmas_h),
                pretty_str("Wm", self.Wm),
                pretty_str("Wc", self.Wc),
                pretty_str("points_fn", self.points_fn),
                pretty_str("scheme", self.scheme),
                pretty_str("vectorized", self.vectorized),
                pretty_str("residual_x", self.residual_x),
                pretty_str("residual_z", self.residual_z),
                pretty_str("state_add", self.state_add),
                pretty_str("hx", self.hx),
                pretty_str("fx", self.fx),
                pretty_str("x_mean", self.x_mean),
                pretty_str("z_mean", self.z_mean),
            ]
        )
