"""``SquareRootUKF``: g13ej's square-root UKF behind filterpy's ``UnscentedKalmanFilter`` API.

The face of one filter over an engine (:mod:`squkf.engine`, a block of one):
each public method reads like filterpy's, with the step in its body: the
inputs checked, ``fx`` or ``hx`` called at the engine's points, the engine's
half step told. The engine commits only when the whole call succeeded, so a
call that fails changes nothing. What is handed out is the caller's (fresh
arrays, the records formed from the engine's factors when read), and what
the caller may edit in place (``x``, ``P``, ``Q``, ``R``) is validated at the
next call.
"""

from __future__ import annotations

import copy
import math
import sys
from collections.abc import Callable

import numpy as np

from . import checks, smoother
from .angles import check_angle_hooks
from .batch import batch_filter
from .boundary.attributes import (
    NOISES,
    Covariance,
    Estimate,
    FactorSlot,
    Flag,
    Handed,
    HandOut,
    Hook,
    ModelFunction,
    Unformed,
    hooks_of,
    initial,
)
from .boundary.config import Config, model_noise, second_set, sigma_family
from .boundary.records import embed, innovation_inverse
from .checks import as_float_array, as_lower_factor, check_time_step, check_values, noise_factor
from .engine import Engine, Route, Update
from .errors import NonFiniteError, ParameterError, ShapeError, UnsetError
from .face import Face, own_copy, restamped, written_record
from .gating import Gate, as_gate
from .generators import sigma_points_from_factor
from .measurement import gain_from_factors
from .noise import call_model, handed_points, noise_points
from .plan import Plan, build_plan
from .transform import cross_covariance
from .weights import WrittenWeights

__all__ = ["SquareRootUKF"]

_LOG_TINY = math.log(sys.float_info.min)
_REAL = checks.REAL

# What lives outside the __dict__ (see the class): the engine and the gain formed from its last update,
# the configuration, the noise slots, and what was handed out or written: the arrays ``x``, ``P`` handed
# out (``_handed``, a HandOut, as a fleet's), which of them is a placeholder (``_unset``), the records
# written (``_written``), the sigma points handed out (``_sigmas``).
_SLOTS = (
    "_engine", "_gain_of", "_unformed", "_points", "_family", "_generator", "_plan", "_gate", "_fx_noise",
    "_hx_noise", "_noise_cache", "_Q", "_R", "_handed", "_unset", "_written", "_sigmas",
)  # fmt: skip
# the slots a copy or a pickle carries (the others are formed again: _unformed, and _gain_of from _engine)
_CARRIED = _SLOTS[3:]

# what repr shows, in order
_SHOWN = (
    "x P1_2 x_prior P1_2_prior Q1_2 R1_2 S1_2 K y log_likelihood likelihood mahalanobis sigmas_f sigmas_h"
    " Wm Wc points_fn scheme vectorized gate fx_noise hx_noise residual_x residual_z state_add hx fx"
    " x_mean z_mean"
).split()
_LABELS = {"log_likelihood": "log-likelihood"}


class SquareRootUKF(Face):
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
    x_mean = Hook()
    z_mean = Hook()
    residual_x = Hook()
    residual_z = Hook()
    state_add = Hook()

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
        route = Route(plan, hooks_of(d), gate_, single=True)
        self._engine = Engine(
            route, np.zeros((1, n)), np.eye(n)[None], np.zeros((1, num, n)), np.zeros((1, num, m))
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
        self._family, self._plan = written, plan
        self._configured()

    def _configured(self) -> None:
        """The plan, hooks or gate changed: the engine's routes are decided again."""
        self._engine.configure(Route(self._plan, hooks_of(self.__dict__), self._gate, single=True))

    def _hooks_assigned(self) -> None:
        if "_dim_x" in self.__dict__:  # (not while __init__ sets the hooks)
            self._configured()

    # -- state and covariances ---------------------------------------------

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

    def _take_edits(self) -> None:
        """The edits in place of ``x`` and ``P`` validated and taken into the engine (either may raise).

        Each array stays handed out, with a fresh record; an invalid edit raises and stays pending.
        A placeholder edited in place is an assignment too (still all NaN: still not set).
        """
        self._handed.take(("x", "P"), self._take_edit)

    def _take_edit(self, name: str, array: np.ndarray) -> None:
        """An array handed out as ``x`` or ``P`` was edited in place: validated and taken (may raise)."""
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

    # -- the records of the last prediction and update (formed when read) --------------------

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
            self._gain_of = (last, K)
        return K.copy()

    @K.setter
    def K(self, value):
        self._gain_of = (self._last(), checks.written_record(value, "K", 2))  # read as fresh copies

    def _gain(self, last: Update | None) -> np.ndarray:
        n = self._dim_x
        if last is None:
            return np.zeros((n, self._dim_z))
        assert last.Sy is not None and last.L21 is not None  # (one filter's update keeps its factors)
        K = last.K[0] if last.K is not None else gain_from_factors(last.Sy[0], last.L21[0])
        if last.observed is None:
            return K
        full = np.zeros((n, last.m))
        full[:, last.observed] = K
        return full

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
        self._ready("ask_predict")
        X = self._engine.ask_predict()[0]
        return self._asked(X, self._plan.w_xi, "Q")

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
        self._refuse_unset("tell_predict")  # (assigned a placeholder since the ask)
        e = self._engine
        w_xi = e.step_route.plan.w_xi
        checks.refuse_noise_args(w_xi, "Q", Q, UT)
        # noise entering fx is in the points: no noise is added to the prior
        e.tell_predict(sigmas_f, None if w_xi is not None else self._Q1_2(Q), UT)
        self._stepped()
        return e.x[0].copy(), e.S[0].copy()

    def ask_update(self) -> np.ndarray:
        """First half of an update: the sigma points to pass through the measurement function.

        Returns
        -------
        sigmas : ndarray, shape (N2, dim_x)
            The second set (redrawn from the prior, or augmented; a fresh
            array); evaluate ``hx`` at each and pass the results to
            :meth:`tell_update`.
        """
        self._ready("ask_update")
        e = self._engine
        X = e.ask_update()[0]
        return self._asked(X, e.step_route.plan.v_xi, "R")  # (the plan that drew the set)

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
        self._refuse_unset("tell_update")  # (assigned a placeholder since the ask)
        e = self._engine
        v_xi = e.step_route.plan.v_xi  # the noise of the set handed out (drawn by the step's route)
        checks.refuse_noise_args(v_xi, "R", R, UT)
        meas = checks.measurement(z, R, self._dim_z, self._R_dim, self._hx_noise)
        if meas is None:
            raise NonFiniteError(
                "tell_update needs a measurement, but z holds none (all NaN, masked or None)"
            )
        z, observed = meas
        m = z.shape[0]
        # noise entering hx is in the points: the update adds none
        R1_2 = np.zeros((m, m)) if v_xi is not None else self._R1_2(R, m)
        e.tell_update(sigmas_h, z, observed, R1_2, UT)
        self.__dict__["z"] = z
        self._stepped()
        return e.x[0].copy(), e.S[0].copy()

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
            values = (
                fx(sigmas[0], dt, **fx_args)
                if self.vectorized
                else self._per_point(fx, sigmas[0], (dt,), fx_args)
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
            values = hx(sigmas, **hx_args) if self.vectorized else self._per_point(hx, sigmas, (), hx_args)
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
        sigmas = sigma_points_from_factor(e.x[0], e.S[0], first.xi, hooks_of(self.__dict__).state_add)
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
        return cross_covariance(sigmas_f, sigmas_h, x, z, Wcs, hooks_of(self.__dict__))

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

    def _asked(self, X: np.ndarray, xi: np.ndarray | None, name: str) -> np.ndarray:
        """What ``ask_*`` hands out: a copy of the points, with their noise part if any."""
        factor = None if xi is None else self._noise_factor(None, name, xi.shape[1])
        return handed_points(X, xi, factor, ())

    def _per_point(self, fn: Callable, X: np.ndarray, args: tuple, kwargs: dict):
        """``fn`` at each point of ``X``: ``fx(x, dt)`` (``args``: ``(dt,)``, a ``dt`` of None too), or
        ``hx(x)`` (``args``: ``()``), as filterpy calls them."""
        return checks.evaluate(fn, X, args, kwargs, False)

    def _R_dim(self) -> int:
        return self._R.factor_or_zeros().shape[0]

    # -- configuration, transactions, copies ------------------------------------

    def configuration(self) -> Config:
        """The filter's configuration and noise factors (``squkf.boundary.Config``).

        What ``Fleet.from_filters`` and the smoother read; the arrays are the
        filter's own, to be read and not written.
        """
        d = self.__dict__
        hooks = hooks_of(d)  # the hooks as given, None where filterpy's default is meant
        return Config(
            self._dim_x, self._dim_z, self._dt, self.hx, self.fx,
            self._family if isinstance(self._family, WrittenWeights) else self._points,  # (weights written)
            self._family, self._generator,
            *hooks, self._gate, self.fx_noise, self.hx_noise, self.vectorized,
            self._plan, hooks, self._Q.factor(), self._R.factor(), self._engine.phase,
            self._engine.route.kernels,
        )  # fmt: skip

    def _snapshot(self):
        # the engine's arrays are replaced by each step, never changed in place: a shallow copy keeps
        # them; the covariance slots, whose matrices the caller may edit in place, are copied
        state = dict(self.__dict__)
        own = self._carried()
        for name in NOISES:
            slot = own["_" + name] = copy.copy(own["_" + name])
            if type(state[name]) is Unformed:
                state[name] = Unformed(slot.matrix)
        engine = copy.copy(self._engine)
        own["_unset"] = set(self._unset)
        own["_handed"] = self._handed.copy()  # (a step clears the records in place)
        for name in ("_written", "_sigmas"):  # the same records, current with the engine put back
            own[name] = restamped(own[name], self._engine, engine)
        return state, own, engine, self._kept_gain()

    def _restore(self, saved) -> None:
        state, own, engine, gain = saved
        self.__dict__.clear()
        self.__dict__.update(state)
        for name, value in own.items():
            setattr(self, name, value)
        self._engine, self._gain_of = engine, (engine.last, gain)

    def _carried(self) -> dict:
        """The slots a copy or a pickle carries, by name (the values themselves)."""
        return {name: getattr(self, name) for name in _CARRIED}

    def _kept_gain(self) -> np.ndarray | None:
        """The gain formed (or assigned) for the last update, or None (never written in place)."""
        last, K = self._gain_of
        return K if last is self._engine.last else None

    def __copy__(self):
        new = type(self).__new__(type(self))
        d = {k: v.copy() if isinstance(v, np.ndarray) else v for k, v in self.__dict__.items()}
        engine = new._engine = copy.copy(self._engine)
        new._gain_of = (engine.last, self._kept_gain())  # never written in place: shared
        new.__dict__.update(d)
        self._carry_to(new, engine, lambda v: v.copy())
        new._rebind()
        return new

    def _carry_to(self, new: SquareRootUKF, engine: Engine, copy_value: Callable) -> None:
        """Give the copy ``new`` (on ``engine``) this filter's carried slots: the configuration shared
        (never changed in place), the noise slots, the placeholders, what was written or handed out its
        own (``copy_value`` copies an array or a :class:`Handed`)."""
        copies: dict[int, np.ndarray] = {}
        for name, value in self._carried().items():
            if name == "_noise_cache":
                value = {}
            elif name in ("_written", "_sigmas"):
                value = restamped(value, self._engine, engine, copy_value)
            else:  # the noise slots: the factor shared, the matrix handed out copied
                value = own_copy(value, copies)
            setattr(new, name, value)

    def __deepcopy__(self, memo):
        new = type(self).__new__(type(self))
        memo[id(self)] = new
        d = copy.deepcopy({k: v for k, v in self.__dict__.items() if type(v) is not Unformed}, memo)
        engine = new._engine = copy.deepcopy(self._engine, memo)
        new._gain_of = (engine.last, copy.deepcopy(self._kept_gain(), memo))
        new.__dict__.update(d)
        self._carry_to(new, engine, lambda v: v.copy())
        # the copy's routes run the copy's own hooks (the pending step's route too: it is the copy's)
        pending_own_route = engine.step_route is engine.route
        new._configured()
        if pending_own_route:
            engine.step_route = engine.route
        new._rebind()
        return new

    def __getstate__(self):
        state = {k: v for k, v in self.__dict__.items() if type(v) is not Unformed}
        own = self._carried()
        own["_noise_cache"] = {}
        # what was written or handed out is current with this engine: pickled with it, the stamps stay its
        return state, own, self._engine, self._kept_gain()

    def __setstate__(self, saved):
        state, own, engine, gain = saved
        self.__dict__.update(state)
        for name, value in own.items():
            setattr(self, name, value)
        self._engine = engine
        self._gain_of = (engine.last, gain)
        self._rebind()

    def _rebind(self) -> None:
        """After construction or a copy: ``x``, ``P``, ``Q``, ``R`` formed from this filter's own engine and
        slots, the arrays handed out (``_handed``) its own; a placeholder as assigned."""
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
