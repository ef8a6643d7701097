"""A stack of K filters' step at its boundary: the state (edits taken), the chunks' model images, the commit.

:class:`StackedFilter` is the base of :class:`squkf.Fleet`, which holds the
public face (the stacked attributes, the step's methods, ``subset``,
``from_filters``); it calls these to run the fleet's step a chunk at a time
(:mod:`squkf.chunks`) and commit every new value at once, so that a call
that fails changes nothing, and a filter that fails numerically is flagged
alone (``on_error="flag"``) or fails the call (``"raise"``).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable

import numpy as np

from .. import step as steps
from ..batch import model_kwargs, per_step
from ..chunks import stacked_posterior, stacked_prior
from ..errors import ParameterError
from ..gating import Gate, as_gate
from ..generators import as_generator
from ..isolate import rows_of
from ..noise import noise_points
from ..plan import Hooks, Plan, build_plan
from ..validate import check_time_step
from ..weights import as_family
from . import inputs
from .edits import HandOut
from .factors import noise_factors, reset_rows
from .loop import Transaction, annotate_step, check_keep, check_progress, progress_callback
from .model_form import ModelForm
from .records import FleetResult, Records, failures_error, new_records

__all__ = ["StackedFilter"]

# the internal array behind each attribute handed out for editing in place
HANDED = {"_x": "x", "_S": "P", "_Q1_2": "Q", "_R1_2": "R"}


def _record(name: str, doc: str, covariance: bool = False) -> property:
    """A read-only record of the last step: a copy of the array ``name`` (``S @ S.T`` for a covariance)."""

    def read(self) -> np.ndarray:
        a = getattr(self, name)
        return a @ np.swapaxes(a, -1, -2) if covariance else a.copy()

    return property(read, doc=doc)


class StackedFilter(ModelForm):
    """A fleet's step internals; :class:`squkf.Fleet` is the face on top."""

    _K: int
    _n: int
    _m: int
    _chunk: int | None
    _state: steps.StepState
    _gate: Gate | None

    def _init_stack(self, K: int, n: int, m: int, dt, hx, fx, points, scheme, hooks: tuple, on_error: str,
                    gate, fx_noise, hx_noise) -> None:  # fmt: skip
        """The state of ``K`` filters of one configuration: ``x = 0``, ``P = Q = R = I``, no step pending."""
        if on_error not in ("flag", "raise"):
            raise ParameterError(f"on_error must be 'flag' or 'raise', got on_error={on_error!r}")
        self._fx_noise, self._hx_noise = inputs.model_noise(fx, hx, fx_noise, hx_noise)
        self._qd, self._rd = self._fx_noise or n, self._hx_noise or m  # the dimensions of Q and R
        self._handed = HandOut()  # x, P, Q, R: the arrays handed out, for edits in place
        self._K, self._n, self._m = K, n, m
        self._dt = check_time_step(dt)
        self.hx, self.fx = hx, fx
        self.points_fn = points
        self._family = as_family(points)
        self._generator = as_generator(scheme)
        self._plan: Plan = build_plan(self._family, self._generator, n, self._fx_noise, self._hx_noise)
        self.x_mean, self.z_mean, self.residual_x, self.residual_z, self.state_add = hooks
        self.on_error = on_error
        self._gate = as_gate(gate)
        self._x = np.zeros((K, n))
        self._S = np.broadcast_to(np.eye(n), (K, n, n)).copy()
        self._Q1_2: np.ndarray | None = np.eye(self._qd)
        self._R1_2: np.ndarray = np.eye(self._rd)
        self._state = steps.StepState()
        self._failed = np.zeros(K, dtype=bool)
        self._failure = np.full(K, "", dtype=object)
        self._x_prior, self._x_post, self._S_prior, self._S_post = self._x, self._x, self._S, self._S
        self.y = np.zeros((K, m))
        self._loglik = np.zeros(K)
        self._nis = np.zeros(K)
        self._rejected = np.zeros((K, m), dtype=bool)

    # -- records of the last step (the arrays behind them are never written in place) ------

    x_prior = _record("_x_prior", "States after the last prediction, shape ``(K, dim_x)`` (fresh).")
    P1_2_prior = _record("_S_prior", "Lower factors after the last prediction, ``(K, n, n)`` (fresh).")
    P_prior = _record("_S_prior", "Covariances after the last prediction (fresh).", covariance=True)
    x_post = _record("_x_post", "States after the last update, shape ``(K, dim_x)`` (fresh).")
    P1_2_post = _record("_S_post", "Lower factors after the last update, ``(K, n, n)`` (fresh).")
    P_post = _record("_S_post", "Covariances after the last update (fresh).", covariance=True)

    # -- state and edits in place ------------------------------------------------------------

    def _hooks(self) -> Hooks:
        return Hooks(self.x_mean, self.z_mean, self.residual_x, self.residual_z, self.state_add)

    def __setattr__(self, name: str, value) -> None:
        object.__setattr__(self, name, value)
        handed = HANDED.get(name)
        if handed is not None and "_handed" in self.__dict__:  # the value behind it changed
            self._handed.drop(handed)  # the array handed out is history

    def _take_edits(self) -> None:
        """Take the edits in place of ``x``, ``P``, ``Q``, ``R`` through their setters (which may raise)."""
        if self._handed:
            self._handed.take(HANDED.values(), lambda name, a: setattr(self, name, a))

    def _noise(self, value, name: str, dim: int) -> np.ndarray | None:
        """A shared ``(dim, dim)`` or per-filter ``(K, dim, dim)`` covariance as its lower factor."""
        return noise_factors(value, name, dim, self._K)

    def _reset(self, filters, x, P) -> None:
        """Clear the flag of ``filters`` (None: every flagged one), optionally setting their state."""
        self._take_edits()
        idx = np.flatnonzero(self._failed) if filters is None else np.arange(self._K)[filters]
        idx = np.atleast_1d(idx)
        self._x, self._S = reset_rows(x, P, idx, self._x, self._S)
        self._failed[idx] = False
        self._failure[idx] = ""
        self._state = steps.StepState()

    # -- the step, a chunk at a time ----------------------------------------------------------

    def _fx_images(self, dt: float, fx_args: dict) -> Callable:
        """``images(rows, X)``: ``fx`` at the first sets ``X`` of the filters ``rows``, arguments cut."""
        kwargs, K, plan, Q = inputs.with_filter_axis(fx_args, self._K), self._K, self._plan, self._Q1_2

        def images(rows: slice, X: np.ndarray):
            kw = inputs.chunk_args(kwargs, K, rows)
            # the points themselves: the step reads only their shape afterwards
            W = None if plan.w_xi is None else noise_points(plan.w_xi, rows_of(Q, rows, 2), (X.shape[0],))
            return inputs.call_stack(self.fx, "fx", X, W, (dt,), kw)

        return images

    def _hx_images(self, R1_2: np.ndarray | None, hx_args: dict) -> Callable:
        """``images(rows, sset)``: ``hx`` at the second sets of the filters ``rows``, arguments cut."""
        kwargs, K, plan = inputs.with_filter_axis(hx_args, self._K), self._K, self._plan

        def images(rows: slice, sset):
            kw = inputs.chunk_args(kwargs, K, rows)
            V = (
                None
                if plan.v_xi is None
                else noise_points(plan.v_xi, rows_of(R1_2, rows, 2), (sset.sigmas.shape[0],))
            )
            return inputs.call_stack(self.hx, "hx", sset.sigmas.copy(), V, (), kw)

        return images

    def _told(self, phase: str, what: str) -> steps.StepState:
        """The pending ask of a ``tell_*`` (phase ``phase``), or a CallSequenceError."""
        state = self._state
        if state.phase != phase or (
            state.sigmas is None if phase == steps.PREDICTING else state.sset is None
        ):
            raise steps.CallSequenceError(
                f"{what} needs a pending {what.replace('tell', 'ask')}, but the step is {state.phase!r}"
            )
        return state

    def _commit_failures(self, fails: dict[int, str]) -> None:
        if not fails:
            return
        if self.on_error == "raise":
            raise failures_error(fails)

    def _predict(self, images: Callable, first: np.ndarray | None) -> None:
        plan, fails = self._plan, dict[int, str]()
        Q = None if plan.w_xi is not None else self._Q1_2  # noise entering fx is in the points already
        prior = stacked_prior(
            plan, self._hooks(), self._x, self._S, Q, ~self._failed, images, fails, first, self._chunk
        )
        self._commit_failures(fails)
        # commit; the second set is drawn by the update, a chunk at a time (memory)
        self._state = steps.StepState(steps.PRIOR, None, prior.propagated, Q, None, (prior.x, prior.S))
        self._x, self._S = prior.x, prior.S
        self._flag(fails)
        self._x_prior, self._S_prior = prior.x, prior.S  # never written in place: copied when read

    def _flag(self, fails: dict[int, str]) -> None:
        for k, why in fails.items():
            self._failed[k] = True
            self._failure[k] = why

    def _as_measurements(self, z, name: str = "z") -> np.ndarray:
        """One step's measurements ``(K, dim_z)`` checked (``name`` for messages, e.g. ``zs[3]``)."""
        return inputs.measurements(z, self._K, self._m, name)

    def _update(self, pending: steps.StepState, images: Callable, z: np.ndarray, R1_2) -> None:
        m, fails = self._m, dict[int, str]()
        active = ~self._failed & ~np.isnan(z).all(axis=1)
        if self._plan.v_xi is not None:  # noise entering hx is in the points: the update adds none
            R1_2 = np.zeros((m, m))
        post = stacked_posterior(
            self._plan, self._hooks(), self._gate, pending, z, R1_2, active, images, fails, self._chunk
        )
        self._commit_failures(fails)
        # commit
        self._state = steps.StepState()
        self._x, self._S = post.x, post.S
        self._flag(fails)
        self._x_post, self._S_post = post.x, post.S  # never written in place: copied when read
        self.y, self._loglik = post.y, post.log_likelihood
        self._nis, self._rejected = post.nis, post.rejected

    def _no_update(self) -> None:
        """The records of a step in which no filter had a measurement, as :meth:`update` would leave them."""
        K, m = self._K, self._m
        self._state = steps.StepState()
        self._x_post, self._S_post = self._x, self._S
        self.y, self._loglik = np.full((K, m), np.nan), np.zeros(K)
        self._nis, self._rejected = np.zeros(K), np.zeros((K, m), dtype=bool)

    # -- many steps ----------------------------------------------------------------------------

    def _batch(self, zs, dts, keep: str, fx_args, hx_args, progress) -> FleetResult:
        """``batch_filter``'s run: checked, then stepped inside :meth:`transaction`."""
        check_keep(keep)
        check_progress(progress)
        Z = inputs.measurement_series(zs, self._K, self._m)
        T = Z.shape[1]
        dt_list = per_step(dts, T, "dts", "dt", default=self._dt, ref="zs")
        fx_args, hx_args = model_kwargs(fx_args, "fx_args"), model_kwargs(hx_args, "hx_args")
        records = new_records(keep, self._K, T, self._n, self._m)
        self._take_edits()
        bar, callback = progress_callback(progress, T)
        t = 0
        try:
            with self.transaction():  # an error at any step leaves the fleet as it was before the call
                for t in range(T):
                    self._step(t, Z[:, t], dt_list[t], fx_args, hx_args, records)
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
            r.means, r.factors, r.variances, r.loglik, self._failed.copy(), self._x.copy(), self._S.copy(),
            r.rejected, r.nis,
        )  # fmt: skip

    def transaction(self) -> Transaction:
        """A context manager that puts the fleet back as it was on entry if anything inside raises.

        What ``batch_filter`` runs its steps in (``squkf.boundary.loop.Transaction``).
        """
        return Transaction(self._snapshot, self._restore)

    def _snapshot(self) -> tuple[StackedFilter, HandOut]:
        return copy.copy(self), self._handed.copy()

    def _restore(self, saved: tuple[StackedFilter, HandOut]) -> None:
        before, handed = saved
        self.__dict__.update(before.__dict__)
        self.__dict__["_handed"] = handed  # the arrays handed out stay the caller's, still current

    def _step(self, t: int, z: np.ndarray, dt: float, fx_args: dict, hx_args: dict, records: Records) -> None:
        """Step ``t`` of :meth:`batch_filter`, its records kept."""
        self._take_edits()  # (a progress callback may have edited x, P, Q or R in place)
        self._predict(self._fx_images(dt, fx_args), None)
        if np.isnan(z).all():  # no measurement at all: as update() would leave it
            self._no_update()
        else:
            self._take_edits()
            pending = steps.pending_update(self._state, self._x, self._S)
            self._update(pending, self._hx_images(self._R1_2, hx_args), z, self._R1_2)
        records.keep(t, self._x, self._S, self._loglik, self._rejected, self._nis)

    # -- copies and subsets ------------------------------------------------------------------

    def _subset(self, rows):
        """A copy holding the filters ``rows`` only (``Fleet.subset``)."""
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
        new = copy.copy(self)
        new._K = int(idx.size)
        new._x, new._S = self._x[idx], self._S[idx]
        new._Q1_2 = rows_of(self._Q1_2, idx, 2)
        new._R1_2 = rows_of(self._R1_2, idx, 2)  # type: ignore[assignment]
        new._failed, new._failure = self._failed[idx], self._failure[idx]
        new._state = steps.StepState()
        new._x_prior, new._x_post = self._x_prior[idx], self._x_post[idx]
        new._S_prior, new._S_post = self._S_prior[idx], self._S_post[idx]
        new.y, new._loglik = self.y[idx], self._loglik[idx]
        new._nis, new._rejected = self._nis[idx], self._rejected[idx]
        return new

    def __copy__(self) -> StackedFilter:
        new = type(self).__new__(type(self))
        copies: dict[int, np.ndarray] = {}
        d = {}
        for key, v in self.__dict__.items():
            if isinstance(v, np.ndarray):
                v = copies.setdefault(id(v), v.copy())
            d[key] = v
        # the copy's own arrays handed out, pending edits included
        d["_handed"] = self._handed.detached()
        state = self._state
        if state.prior is not None:
            # ask_update knows the pending second set by the identity of the estimate it was
            # drawn from: the copy's pending set must belong to the copy's estimate
            x, S = state.prior
            d["_state"] = dataclasses.replace(state, prior=(copies.get(id(x), x), copies.get(id(S), S)))
        new.__dict__.update(d)
        return new

    def __deepcopy__(self, memo):
        new = copy.copy(self)
        memo[id(self)] = new
        return new
