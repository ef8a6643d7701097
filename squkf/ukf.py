"""``SquareRootUKF``: g13ej's square-root UKF behind filterpy's ``UnscentedKalmanFilter`` API.

The face of one filter over an engine (:mod:`squkf.engine`, a block of one):
each public method reads like filterpy's, with the step in its body: the
inputs checked, ``fx`` or ``hx`` called at the engine's points, the engine's
half step told. The engine commits only when the whole call succeeded, so a
call that fails changes nothing. What is handed out is the caller's (fresh
arrays, the records formed from the engine's factors when read), and what
the caller may edit in place (``x``, ``P``, ``Q``, ``R``) is validated at the
next call.

This module holds filterpy's constructor, ``predict`` and ``update`` (the
model called per point, or vectorised), the configuration and the copy
hooks; the filter's base classes hold the rest: ``x``, ``P`` and the noise
factors (:mod:`squkf.ukf_state`), filterpy's other records and the weights
(:mod:`squkf.ukf_records`), the step in halves (:mod:`squkf.ask_tell`), and
what both faces share (:mod:`squkf.face`).
"""

from __future__ import annotations

import copy
import math
import sys
from collections.abc import Callable

import numpy as np

from . import checks, old_pickles, smoother
from .angles import check_angle_hooks
from .ask_tell import AskTell
from .batch import batch_filter
from .boundary.attributes import (
    NOISES,
    Covariance,
    Estimate,
    FactorSlot,
    Flag,
    HandOut,
    ModelFunction,
    Unformed,
    hooks_of,
    initial,
)
from .boundary.config import model_noise, second_set, sigma_family
from .checks import as_float_array, check_time_step, check_values
from .engine import Engine
from .face import own_copy, restamped
from .gating import Gate, as_gate
from .generators import sigma_points_from_factor
from .noise import call_model, noise_points
from .plan import Hooks, Plan, build_plan
from .transform import cross_covariance
from .ukf_records import FilterRecords

__all__ = ["SquareRootUKF"]

_LOG_TINY = math.log(sys.float_info.min)

# What lives outside the __dict__ (see the class): the engine and the gain formed from its last update,
# the configuration, the noise slots, and what was handed out or written: the arrays ``x``, ``P`` handed
# out (``_handed``, a HandOut, as a fleet's), which of them is a placeholder (``_unset``), the records
# written (``_written``), the sigma points handed out (``_sigmas``).
_SLOTS = (
    "_engine", "_unformed", "_gain_of", "_points", "_family", "_generator", "_plan", "_gate", "_fx_noise",
    "_hx_noise", "_noise_cache", "_Q", "_R", "_handed", "_unset", "_written", "_sigmas",
)  # fmt: skip
# the slots a copy, a pickle or a snapshot carries besides the engine (_unformed is formed again), and
# of them the configuration, noise slots, placeholders and hand-outs
_CARRIED = _SLOTS[2:]
_CONFIGURED = tuple(k for k in _CARRIED if k not in ("_gain_of", "_noise_cache", "_written", "_sigmas"))

# what repr shows, in order
_SHOWN = (
    "x P1_2 x_prior P1_2_prior Q1_2 R1_2 S1_2 K y log_likelihood likelihood mahalanobis sigmas_f sigmas_h"
    " Wm Wc points_fn scheme vectorized gate fx_noise hx_noise residual_x residual_z state_add hx fx"
    " x_mean z_mean"
).split()
_LABELS = {"log_likelihood": "log-likelihood"}


def _copy_of(value):
    """A copy's own record written or set handed out (an array, or a ``Handed``)."""
    return value.copy()


class SquareRootUKF(AskTell, FilterRecords):
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
    dt : float or None
        Default time step passed to ``fx``; None, as in filterpy, when every
        ``predict`` passes its own (one given none calls ``fx`` with ``dt=None``).
    hx : callable or None
        ``hx(x, **hx_args) -> (dim_z,)``; with ``vectorized=True``
        ``hx(sigmas, **hx_args)`` maps ``(N, dim_x)`` to ``(N, dim_z)``.
        None, as in filterpy, when every ``update`` is given ``hx=`` (an
        update given none then raises a ``ParameterError``).
    fx : callable or None
        ``fx(x, dt, **fx_args) -> (dim_x,)``; with ``vectorized=True``
        ``fx(sigmas, dt, **fx_args)`` maps ``(N, dim_x)`` to ``(N, dim_x)``.
        None, as in filterpy, when every ``predict`` is given ``fx=``.
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
        Call ``fx`` and ``hx`` once with all sigma points (``True`` or
        ``False``; anything else is refused).
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

    # The engine, the configuration, the noise slots and the arrays handed out live in slots: the
    # __dict__ (which a filterpy Saver deep-copies at each step, and a deepcopy copies) holds
    # filterpy's own keys alone.
    __slots__ = _SLOTS + ("__dict__", "__weakref__")
    ONE = True  # a block of one: the records drop the block axis
    _CARRIED = _CARRIED
    _HANDED = ("x", "P")
    NO_LOG_LIKELIHOOD = _LOG_TINY

    _engine: Engine
    _gain_of: tuple
    _unformed: tuple
    _points: object
    _family: object
    _generator: object
    _plan: Plan
    _gate: Gate | None
    _fx_noise: int
    _hx_noise: int
    _noise_cache: dict
    _Q: FactorSlot
    _R: FactorSlot
    _handed: HandOut
    _unset: set
    _written: dict
    _sigmas: dict

    # kept in the __dict__ (filterpy's layout), set in __init__
    _dim_x: int
    _dim_z: int
    _dt: float | None
    _num_sigmas: int
    vectorized = Flag()
    x = Estimate()
    P = Estimate()
    Q = Covariance()
    R = Covariance()
    hx = ModelFunction(optional=True)
    fx = ModelFunction(optional=True)

    def __init__(
        self,
        dim_x: int,
        dim_z: int,
        dt: float | None,
        hx: Callable | None,
        fx: Callable | None,
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
        n, m = checks.check_sizes(dim_x=dim_x, dim_z=dim_z)
        checks.model_functions(
            True, hx=hx, fx=fx, sqrt_fn=sqrt_fn, x_mean_fn=x_mean_fn, z_mean_fn=z_mean_fn,
            residual_x=residual_x, residual_z=residual_z, state_add=state_add,
        )  # fmt: skip
        check_angle_hooks(
            n, m, x_mean_fn=x_mean_fn, z_mean_fn=z_mean_fn, residual_x=residual_x, residual_z=residual_z,
            state_add=state_add,
        )  # fmt: skip
        fx_noise_, hx_noise_ = model_noise(fx, hx, fx_noise, hx_noise)
        dt_ = None if dt is None else check_time_step(dt)  # None: every predict passes its own
        family, num = sigma_family(points, n, fx_noise_)
        generator = second_set(scheme, n, family, hx_noise_)
        plan = build_plan(family, generator, n, fx_noise_, hx_noise_)
        gate_ = as_gate(gate)
        d = self.__dict__
        d.update(_dim_x=n, _dim_z=m, _dt=dt_, _num_sigmas=num)
        self._fx_noise, self._hx_noise = fx_noise_, hx_noise_
        self._points, self._family, self._generator = points, family, generator
        self._plan, self._gate = plan, gate_
        self._noise_cache = {}
        self._handed = HandOut()
        self._unset, self._written, self._sigmas = set(), {}, {}
        self._gain_of = (None, None)  # (the update, its gain) once formed
        self.hx = hx
        self.fx = fx
        self.msqrt = sqrt_fn
        d.update(x_mean=x_mean_fn, z_mean=z_mean_fn)
        d["residual_x"] = np.subtract if residual_x is None else residual_x
        d["residual_z"] = np.subtract if residual_z is None else residual_z
        d["state_add"] = np.add if state_add is None else state_add
        self.vectorized = vectorized  # (checked: True or False)
        self.inv = np.linalg.inv
        # P, Q (the noise's own dimension when it enters fx), R; x = 0; the records of no step yet
        initial(self, m, fx_noise_ or n, hx_noise_ or m)
        self._engine = Engine(
            self._new_route(), np.zeros((1, n)), np.eye(n)[None], np.zeros((1, num, n)), np.zeros((1, num, m))
        )
        self._rebind()

    # -- configuration -----------------------------------------------------

    def _set_points(self, points):
        family, num = sigma_family(points, self._dim_x, self._fx_noise)
        self._replan(family, self._generator, points)
        self.__dict__["_num_sigmas"] = num

    def _set_scheme(self, value):
        self._replan(self._family, second_set(value, self._dim_x, self._family, self._hx_noise), self._points)

    def _replan(self, family, generator, points) -> None:
        """New points or a new second set: the plan built again (may raise, changing nothing), then taken."""
        plan = build_plan(family, generator, self._dim_x, self._fx_noise, self._hx_noise)
        self._points, self._family, self._generator, self._plan = points, family, generator, plan
        self._configured()

    @property
    def dim_x(self) -> int:
        """Number of state variables."""
        return self._dim_x

    @property
    def dim_z(self) -> int:
        """Default number of measurement variables."""
        return self._dim_z

    def _hooks(self) -> Hooks:
        return hooks_of(self.__dict__)

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
        dt = self._dt if dt is None else check_time_step(dt)  # None, if the constructor's was: fx gets None
        fx = checks.model_function(fx, self.fx, "fx", "predict")
        self._ready("predict")
        e = self._engine
        sigmas = e.first_set()  # fx may write on them: the step reads only their shape
        if self._plan.w_xi is None:
            # (per point: fx(x, dt, **fx_args) at each point, as filterpy calls it)
            X = sigmas[0]
            values = (
                fx(X, dt, **fx_args) if self.vectorized else checks.evaluate(fx, X, (dt,), fx_args, False)
            )
            Q1_2 = self._Q1_2(Q)
        else:  # noise entering fx is in the points: no noise is added to the prior
            values, Q1_2 = self._model(fx, "fx", sigmas[0], (dt,), fx_args, Q, UT), None
        e.tell_predict(values, Q1_2, UT, sigmas)
        self.__dict__["x"], self.__dict__["P"] = self._unformed  # the new estimate: formed when read
        self._handed.held.clear()  # (the arrays handed out for the old estimate are history)

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
        meas = checks.measurement(z, R, self._dim_z, self._R_dim, self._hx_noise)
        if meas is not None:  # (as filterpy's, an update without a measurement needs no hx)
            hx = checks.model_function(hx, self.hx, "hx", "update")
        self._ready("update")
        d = self.__dict__
        e = self._engine
        if meas is None:  # no measurement: the prior stays, and the last update's records
            e.skip_update()
            d["z"] = np.array([[None] * self._dim_z]).T
            return
        z, observed = meas
        pending = e.pending_update()
        # the set's own plan: the prediction's (a configuration changed since applies from the next step)
        plan = (e.step_route if pending[1] is e.sset else e.route).plan
        given = self._given_set(pending[1].sigmas.shape[1:]) if self._sigmas else None
        if given is not None:  # a set the program wrote as sigmas_f: its spread is not the prior's
            pending = (pending[0], pending[1].rewritten(given[None]), None)
        sigmas = pending[1].sigmas[0].copy()  # hx gets its own copy: the update reads the set
        if plan.v_xi is None:
            values = (
                hx(sigmas, **hx_args) if self.vectorized else checks.evaluate(hx, sigmas, (), hx_args, False)
            )
            R1_2 = self._R1_2(R, z.shape[0])
        else:  # noise entering hx is in the points: the update adds none
            values = self._model(hx, "hx", sigmas, (), hx_args, R, UT, plan)
            R1_2 = np.zeros((z.shape[0],) * 2)
        e.tell_update(values, z, observed, R1_2, UT, pending)
        if given is not None:
            self._set_used()
        d["z"] = z
        d["x"], d["P"] = self._unformed
        self._handed.held.clear()  # (the arrays handed out for the old estimate are history)

    def compute_process_sigmas(self, dt, fx=None, **fx_args) -> None:
        """Set ``sigmas_f`` to the first set propagated through ``fx`` (state unchanged)."""
        dt = check_time_step(dt)
        fx = checks.model_function(fx, self.fx, "fx", "compute_process_sigmas")
        self._ready("compute_process_sigmas")
        e = self._engine
        first = self._plan.first
        sigmas = sigma_points_from_factor(
            e.x[0], e.S[0], first.xi, self._hooks().state_add, kernels=e.route.kernels
        )
        values = self._model(fx, "fx", sigmas, (dt,), fx_args)
        e.shown_f = check_values(values, sigmas.shape, "fx values")[None]

    def cross_variance(self, x, z, sigmas_f, sigmas_h) -> np.ndarray:
        """Cross-covariance ``sum Wc[i] (sigmas_f[i] - x)(sigmas_h[i] - z)^T``.

        The weights are those of the set with as many points as ``sigmas_f``
        (the second set after a prediction, else the first).
        """
        sigmas_f = as_float_array(sigmas_f, "sigmas_f")
        sigmas_h = np.atleast_2d(as_float_array(sigmas_h, "sigmas_h"))
        sset = self._engine.sset
        Wcs = (self._plan.first.rows.Wc, None if sset is None else sset.Wc)
        return cross_covariance(sigmas_f, sigmas_h, x, z, Wcs, self._hooks())

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
        checks.refuse_smoother_noise(self._fx_noise, "filter")
        return smoother.rts_smoother(self, Xs, Ps, Qs=Qs, dts=dts, UT=UT, fx_args=fx_args)

    def rts_smoother_factors(self, Xs, P1_2s, Qs=None, dts=None, UT=None, *, fx_args=None):
        """The smoother on lower factors: :func:`squkf.smoother.rts_smoother_factors` on this filter."""
        checks.refuse_smoother_noise(self._fx_noise, "filter")
        return smoother.rts_smoother_factors(self, Xs, P1_2s, Qs=Qs, dts=dts, UT=UT, fx_args=fx_args)

    # -- the step's parts -----------------------------------------------------

    def _model(
        self,
        fn: Callable,
        which: str,
        X: np.ndarray,
        args: tuple,
        kwargs: dict,
        noise=None,
        UT=None,
        plan=None,
    ):
        """``fn`` (``"fx"`` or ``"hx"``) at the points ``X``, with noise points if the noise enters it.

        ``plan``: the one that drew ``X`` (default: the filter's current one).
        """
        plan = self._plan if plan is None else plan
        xi, name, dim = (
            (plan.w_xi, "Q", self._fx_noise) if which == "fx" else (plan.v_xi, "R", self._hx_noise)
        )
        if xi is None:
            if self.vectorized:
                return fn(X, *args, **kwargs)
            return checks.evaluate(fn, X, args, kwargs, False)
        checks.refuse_noise_args(xi, name, noise, UT)
        W = noise_points(xi, self._noise_factor(noise, name, xi.shape[1]), ())
        return call_model(fn, which, dim, X, W, args, kwargs, self.vectorized)

    # -- configuration, transactions, copies ------------------------------------

    # the core's skeleton of copies, pickles and snapshots (face.Face) with this filter's hooks

    def _dict_for(self, how, memo):
        d = self.__dict__
        if how == "snapshot":  # (the caller's arrays kept as they are)
            return dict(d)
        if how == "copy":
            return {k: v.copy() if isinstance(v, np.ndarray) else v for k, v in d.items()}
        return copy.deepcopy({k: v for k, v in d.items() if type(v) is not Unformed}, memo)

    def _carried(self, engine, how):
        e = self._engine
        own = {name: getattr(self, name) for name in _CONFIGURED}
        if how in ("copy", "deep"):  # the configuration shared, the noise slots and hand-outs detached
            copies: dict[int, np.ndarray] = {}
            own = {name: own_copy(value, copies) for name, value in own.items()}
        elif how == "snapshot":  # the noise slots, placeholders and hand-outs as they are now
            own["_Q"], own["_R"] = copy.copy(self._Q), copy.copy(self._R)
            own["_unset"], own["_handed"] = set(self._unset), self._handed.copy()
        copy_value = None if how in ("pickle", "snapshot") else _copy_of
        for name in ("_written", "_sigmas"):  # those current, with the stamps of the engine carried
            own[name] = restamped(getattr(self, name), e, engine, copy_value)
        last, K = self._gain_of  # the gain formed (or assigned) for the last update: never written in place
        K = K if last is e.last else None
        own["_gain_of"] = (engine.last, K.copy() if how == "deep" and K is not None else K)
        own["_noise_cache"] = self._noise_cache if how == "snapshot" else {}
        return own

    def _unpickled(self, state):
        return old_pickles.filter_state(state)

    def _rebind(self, how=None) -> None:
        """After construction or a copy: ``x``, ``P``, ``Q``, ``R`` formed from this filter's own engine and
        slots, the arrays handed out (``_handed``) its own; a placeholder as assigned. A deep copy's routes
        run its own hooks (the pending step's route too: it is the copy's)."""
        if how == "deep":
            e = self._engine
            pending_own_route = e.step_route is e.route
            self._configured()
            if pending_own_route:
                e.step_route = e.route
        self._unformed = (Unformed(self._formed_x), Unformed(self._formed_P))
        d = self.__dict__
        for k, name in enumerate(("x", "P")):
            handed = self._handed.held.get(name)
            if handed is not None:
                d[name] = handed.array
            elif name in self._unset:
                d[name] = None
            else:
                d[name] = self._unformed[k]
        for name in NOISES:
            d[name] = Unformed(getattr(self, "_" + name).matrix)

    def __repr__(self) -> str:
        from filterpy.common import pretty_str

        factors = {"P1_2": self.P1_2, "Q1_2": self._Q.factor(), "R1_2": self._R.factor()}
        rows = [(_LABELS.get(a, a), factors[a] if a in factors else getattr(self, a)) for a in _SHOWN]
        return "\n".join(["SquareRootUKF object"] + [pretty_str(label, v) for label, v in rows])
