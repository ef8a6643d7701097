"""One filter's step at its boundary: the state (edits taken), the model's images, the noise, the commit.

:class:`OneFilter` is the base of :class:`squkf.SquareRootUKF`, which holds
the public face (filterpy's attributes and methods, ask/tell) and calls these
to run the step's pure transitions (:mod:`squkf.step`) on its private state.
Each ``_tell_*`` finishes a half step and commits every new value at once, so
a call that fails changes nothing. The attributes live in the instance
``__dict__`` as :mod:`squkf.boundary.attributes` lays them out.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import cast

import numpy as np

from .. import blas
from .. import step as steps
from ..covariance import FactorSlot
from ..errors import NonFiniteError
from ..gating import Gate
from ..generators import sigma_points_from_factor
from ..noise import call_model, handed_points, noise_points
from ..plan import Hooks, Plan, build_plan
from ..transform import cross_covariance
from ..validate import as_float_array, check_time_step, check_values
from . import inputs
from .attributes import InDictCopies, commit_estimate, current_state, hooks_of
from .config import Config
from .factors import noise_factor
from .model_form import ModelForm
from .records import LastUpdate, update_records

__all__ = ["OneFilter"]

_one_blas_thread = blas.one_thread_method(lambda self: self._dim_x)

# what repr shows, in order
_SHOWN = (
    "x P1_2 x_prior P1_2_prior Q1_2 R1_2 S1_2 K y log_likelihood likelihood mahalanobis sigmas_f sigmas_h"
    " Wm Wc points_fn scheme vectorized gate fx_noise hx_noise residual_x residual_z state_add hx fx"
    " x_mean z_mean"
).split()
_LABELS = {"log_likelihood": "log-likelihood"}


class OneFilter(ModelForm, InDictCopies):
    """The single filter's step internals; :class:`squkf.SquareRootUKF` is the face on top."""

    _dim_x: int
    _dim_z: int
    _dt: float
    fx: Callable
    hx: Callable
    _plan: Plan
    _step_plan: Plan  # the plan of the pending step (the one its points were drawn with)
    _state: steps.StepState
    _gate: Gate | None
    _noise_cache: dict
    _last: LastUpdate
    _P: FactorSlot
    _Q: FactorSlot
    _R: FactorSlot
    _points: object
    _family: object
    _generator: object
    _num_sigmas: int
    vectorized: bool
    # the records of the last prediction and update (plain attributes, as filterpy's)
    x_prior: np.ndarray
    P1_2_prior: np.ndarray
    x_post: np.ndarray
    P1_2_post: np.ndarray
    sigmas_f: np.ndarray
    sigmas_h: np.ndarray
    y: np.ndarray
    z: np.ndarray

    def _covariance_assigned(self, name: str) -> None:
        """An assignment to ``x``, ``P``, ``Q`` or ``R`` succeeded (hook for subclasses)."""

    def _build_plan(self, family, generator) -> Plan:
        return build_plan(family, generator, self._dim_x, self._fx_noise, self._hx_noise)

    def _set_points(self, points) -> None:
        """``points_fn = points``: checked, and the plan built again (once the scheme is set)."""
        family, num = inputs.sigma_family(points, self._dim_x, self._fx_noise)
        plan = self._build_plan(family, self._generator) if self._generator is not None else None
        self._points = points
        self._family = family
        self._num_sigmas = num
        self._plan = cast(Plan, plan)  # None only while __init__ has not set the scheme yet

    def _set_scheme(self, value) -> None:
        """``scheme = value``: the second-set generator checked, and the plan built again."""
        gen = inputs.second_set(value, self._dim_x, self._family, self._hx_noise)
        plan = self._build_plan(self._family, gen)
        self._generator = gen
        self._plan = plan

    def _configuration(self) -> Config:
        hooks = self._hooks()  # the hooks as given, None where filterpy's default is meant
        return Config(
            self._dim_x, self._dim_z, self._dt, self.hx, self.fx, self._points, self._family, self._generator,
            *hooks, self._gate, self.fx_noise, self.hx_noise, self.vectorized,
            self._plan, hooks, self._Q.factor(), self._R.factor(), self._state.phase,
        )  # fmt: skip

    def _describe(self, title: str) -> str:
        """The ``repr``: filterpy's layout of the attributes (``pretty_str``)."""
        from filterpy.common import pretty_str

        factors = {"P1_2": self._P.factor(), "Q1_2": self._Q.factor(), "R1_2": self._R.factor()}
        rows = [(_LABELS.get(a, a), factors[a] if a in factors else getattr(self, a)) for a in _SHOWN]
        return "\n".join([title] + [pretty_str(label, v) for label, v in rows])

    def _hooks(self) -> Hooks:
        return hooks_of(self.__dict__)

    def _current(self) -> tuple[np.ndarray, np.ndarray]:
        """The current mean and factor, with in-place edits of ``x`` and ``P`` validated."""
        return current_state(self.__dict__, self._dim_x)

    def _noise_factor(self, value, name: str, dim: int) -> np.ndarray | None:
        """Lower factor of ``Q`` or ``R`` (``value`` for this call, else the attribute's); None: zero."""
        return noise_factor(value, name, dim, self.__dict__["_" + name].factor, self._noise_cache)

    def _noise_points(self, xi: np.ndarray, value, name: str) -> np.ndarray:
        """The noise part of an augmented set from ``Q``/``R`` (this call's ``value``, else the attribute)."""
        return noise_points(xi, self._noise_factor(value, name, xi.shape[1]), ())

    def _images(self, fn: Callable, which: str, X, args: tuple, kwargs: dict, noise=None, UT=None):
        """``fn`` (``"fx"`` or ``"hx"``) at the points ``X``, with noise points if the noise enters it."""
        plan = self._plan
        fx = which == "fx"
        xi, name, dim = (plan.w_xi, "Q", self._fx_noise) if fx else (plan.v_xi, "R", self._hx_noise)
        if xi is None:
            return inputs.evaluate(fn, X, args, kwargs, self.vectorized)
        inputs.refuse_noise_args(xi, name, None, UT)
        W = self._noise_points(xi, noise, name)
        return call_model(fn, which, dim, X, W, args, kwargs, self.vectorized)

    def _handed_points(self, state: steps.StepState, xi: np.ndarray | None, name: str) -> np.ndarray:
        """What ``ask_*`` hands out: a copy of the state's points, with their noise part if any."""
        factor = None if xi is None else self._noise_factor(None, name, xi.shape[1])
        return handed_points(state.sigmas, xi, factor, ())  # type: ignore[arg-type]  # set by ask_*

    def _ask_predict(self) -> np.ndarray:
        x, S = self._current()
        plan = self._plan
        state = steps.ask_predict(self._state, plan, x, S, self._hooks().state_add)
        self._state, self._step_plan = state, plan
        return self._handed_points(state, plan.w_xi, "Q")

    def _ask_update(self) -> np.ndarray:
        x, S = self._current()
        plan = self._plan
        state = steps.ask_update(self._state, plan, x, S, self._hooks().state_add)
        self._state = state
        return self._handed_points(state, plan.v_xi, "R")

    def _predict(self, dt, UT, fx: Callable | None, Q, fx_args: dict) -> None:
        """A whole prediction: ``dt`` checked, the points, ``fx`` at them, the prior committed."""
        dt = self._dt if dt is None else check_time_step(dt)
        fx = self.fx if fx is None else fx
        x, S = self._current()
        plan = self._plan
        hooks = self._hooks()
        state = steps.ask_predict(self._state, plan, x, S, hooks.state_add)
        # the points not copied: they are never read again (the step keeps only their shape)
        values = self._images(fx, "fx", state.sigmas, (dt,), fx_args, Q, UT)  # type: ignore[arg-type]  # set by ask_*
        self._tell_predict(state, plan, values, Q, UT, hooks)

    def _update(self, z, R, UT, hx: Callable | None, hx_args: dict) -> None:
        """A whole update: ``z`` checked, the points, ``hx`` at them, the posterior committed."""
        meas = self._as_measurement(z, R)
        if meas is None:
            self._skip_update()
            return
        hx = self.hx if hx is None else hx
        x, S = self._current()
        hooks = self._hooks()
        plan = self._plan
        state = steps.ask_update(self._state, plan, x, S, hooks.state_add)
        X = state.sigmas.copy()  # type: ignore[union-attr]  # set by ask_*
        values = self._images(hx, "hx", X, (), hx_args, R, UT)
        self._tell_update(state, values, meas[0], meas[1], R, UT, hooks)

    def _told_update(self, values, z, R, UT) -> None:
        """``tell_update``: the arguments checked, the update finished and committed."""
        inputs.refuse_noise_args(self._plan.v_xi, "R", R, UT)
        meas = self._as_measurement(z, R)
        if meas is None:
            raise NonFiniteError(
                "tell_update needs a measurement, but z holds none (all NaN, masked or None)"
            )
        self._tell_update(self._state, values, meas[0], meas[1], R, UT, self._hooks())

    def _process_sigmas(self, dt, fx: Callable | None, fx_args: dict) -> None:
        """``compute_process_sigmas``: ``sigmas_f``, the first set through ``fx`` (the state unchanged)."""
        dt = check_time_step(dt)
        fx = self.fx if fx is None else fx
        x, S = self._current()
        sigmas = sigma_points_from_factor(x, S, self._plan.first.xi, self._hooks().state_add)
        values = self._images(fx, "fx", sigmas, (dt,), fx_args)
        self.sigmas_f = check_values(values, sigmas.shape, "fx values")

    def _cross_variance(self, x, z, sigmas_f, sigmas_h) -> np.ndarray:
        """``cross_variance``, with the weights of the set that has as many points as ``sigmas_f``."""
        sigmas_f = as_float_array(sigmas_f, "sigmas_f")
        sigmas_h = np.atleast_2d(as_float_array(sigmas_h, "sigmas_h"))
        sset = self._state.sset
        Wcs = (self._plan.first.rows.Wc, None if sset is None else sset.Wc)
        return cross_covariance(sigmas_f, sigmas_h, x, z, Wcs, self._hooks())

    def _refuse_smoother(self) -> None:
        inputs.refuse_smoother_noise(self._fx_noise, "filter")

    def _as_measurement(self, z, R) -> tuple[np.ndarray, np.ndarray | None] | None:
        """``z`` checked, as ``(z, observed)`` (the mask of the measured components, or None: all)."""
        return inputs.measurement(z, R, self._dim_z, self._R_dim, self._hx_noise)

    def _R_dim(self) -> int:
        return self._R.factor_or_zeros().shape[0]

    @_one_blas_thread
    def _tell_predict(self, state, plan: Plan, values, Q, UT, hooks: Hooks) -> None:
        """Finish a prediction and commit it (nothing is changed if anything fails)."""
        # noise entering fx is in the points: no noise is added to the prior
        Q1_2 = None if plan.w_xi is not None else self._noise_factor(Q, "Q", self._dim_x)
        state, x, S = steps.tell_predict(state, plan, values, Q1_2, hooks, UT)
        state = steps.draw_second_set(state, plan, x, S, hooks.state_add)
        # commit
        self._state, self._step_plan = state, plan
        commit_estimate(self.__dict__, x, S)
        self.x_prior = x.copy()
        self.P1_2_prior = S.copy()
        self.sigmas_f = state.sset.sigmas.copy()  # filterpy shows the second set once the prediction is done

    @_one_blas_thread
    def _tell_update(self, state, values, z: np.ndarray, observed, R, UT, hooks: Hooks) -> None:
        """Finish an update and commit it (nothing is changed if anything fails)."""
        # noise entering hx is in the points: the update adds none
        R1_2 = None if self._plan.v_xi is not None else self._noise_factor(R, "R", z.shape[0])
        if R1_2 is None:
            R1_2 = np.zeros((z.shape[0], z.shape[0]))
        state, gated, H = steps.gated_update(state, values, z, R1_2, observed, hooks, UT, self._gate)
        y, last = update_records(gated, observed, self._dim_x, z.shape[0])
        # commit
        self._state = state
        commit_estimate(self.__dict__, gated.x, gated.S)
        self.x_post = gated.x.copy()
        self.P1_2_post = gated.S.copy()
        self.y, self.z, self.sigmas_h = y, z, H
        self._last = last

    def _skip_update(self) -> None:
        """An update without a measurement: the prior is kept as the posterior."""
        state = steps.skip_update(self._state)
        x, S = self._current()
        self._state = state
        self.z = np.array([[None] * self._dim_z]).T  # the last update's records stay, as filterpy's
        self.x_post = x.copy()
        self.P1_2_post = S.copy()
