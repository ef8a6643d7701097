"""The engine: the step of a block of B filters, its routes fixed by the plan, the kernels called directly.

One filter is a block of one (:class:`squkf.SquareRootUKF`); a fleet's chunk is
a block of B (:mod:`squkf.stacks`). The step, as data::

    x, S --points--> X --fx--> F --prior + second set--> Y --hx--> H --posterior + first set--> x, S

Every arrow but ``fx`` and ``hx`` is a kernel of the table :data:`squkf.kernels.KERNELS`.
On the default route (no hooks, no ``UT``, a second set that reproduces the
prior) a step is two kernel calls: after ``fx``, one gives the prior and the
second set; after ``hx``, one gives the posterior and the next first set. Other
routes (hooks, a user's ``UT`` or generator, the propagated set) are the same
kernels driven with the hooks' rows (:mod:`squkf.transform`,
:mod:`squkf.measurement`).

Which route a call takes is decided once per key (the plan, the hooks, ``UT``
given or not, the measurement's length and its observed components) and kept
in the engine (:meth:`Engine.update_route`), so a repeated key decides nothing.
A kernel reports a status per filter; :func:`failure` turns one into squkf's
exception, the one wording of both faces.

An :class:`Engine` computes into new arrays and assigns them only when the
whole call succeeded, so a call that fails leaves it as it was. Its phases
(``ask_*`` and ``tell_*`` are the halves of a prediction and an update)::

    idle --ask_predict--> predicting --tell_predict--> prior
    prior | idle --ask_update--> updating --tell_update--> idle
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from . import kernels
from .errors import (
    CallSequenceError,
    DowndateError,
    GainError,
    NonFiniteError,
    PosteriorFactorError,
    SqukfError,
)
from .generators import SigmaSet, sigma_points_from_factor
from .linalg import all_finite, tria
from .measurement import Posterior, measurement_update
from .plan import Hooks, Plan
from .rows import RowForm
from .transform import transform_factor
from .validate import check_hook_result, check_values, describe_nonfinite

__all__ = [
    "IDLE",
    "PREDICTING",
    "PRIOR",
    "UPDATING",
    "Engine",
    "Update",
    "failure",
    "prior_failure",
]

IDLE = "idle"
PREDICTING = "predicting"
PRIOR = "prior"
UPDATING = "updating"

_FLOAT64 = np.dtype(np.float64)
_K = kernels.KERNELS

# kernel status codes (squkf.kernels.phases)
NOT_FINITE = 305


class Update(NamedTuple):
    """The last update of a block: what the gate saw and what was applied (the records are formed from it).

    Attributes
    ----------
    x : ndarray, shape (B, n)
    S : ndarray, shape (B, n, n)
        The posterior (after the gate: the prior where it rejected everything).
    y : ndarray, shape (B, mo)
        The innovation of the observed components (what the gate tested).
    Sy : ndarray, shape (B, mo, mo)
    L21 : ndarray, shape (B, n, mo)
    log_likelihood : ndarray, shape (B,)
        Of the components that passed (0 where none did).
    nis : ndarray, shape (B,)
        Of the innovation tested.
    observed : ndarray of bool, shape (m,), or None
        The measured components (None: all).
    rejected : ndarray of bool, shape (B, mo)
        The observed components the gate rejected.
    K : ndarray, shape (B, n, mo), or None
        The gain applied when the gate rejected something (None: ``L21 Sy^-1``).
    m : int
        The measurement's length.
    """

    x: np.ndarray
    S: np.ndarray
    y: np.ndarray
    Sy: np.ndarray
    L21: np.ndarray
    log_likelihood: np.ndarray
    nis: np.ndarray
    observed: np.ndarray | None
    rejected: np.ndarray
    K: np.ndarray | None
    m: int


class _Joint(NamedTuple):
    """The route of an update by the joint QR kernel with no hook: fixed per set kind and measurement."""

    form: RowForm
    mode: int
    offsets: bool  # the set's offsets are the state rows (else its points, with xref = x for MEAN)
    xref: bool
    pair: float
    wm: np.ndarray
    scale: np.ndarray
    sign: np.ndarray


def _joint_route(sset: SigmaSet) -> _Joint:
    """Which rows of the set the joint kernel takes (the offsets where known) and how (mode, pair)."""
    rows = sset.rows
    assert rows is not None
    form = rows.best
    have = sset.offsets is not None
    if form.central:
        mode, xref = kernels.CENTRAL, False
        pair = rows.pair_scale if (sset.axis and have) else 0.0
    else:
        mode, xref, pair = kernels.MEAN, not have, 0.0
    return _Joint(form, mode, have, xref, pair, _ro(rows.Wm), _ro(form.scale), _ro(form.sign))


def _ro(a: np.ndarray) -> np.ndarray:
    return kernels.plan_array(a)


def failure(code: int, form: RowForm | None = None, what: str = "update") -> SqukfError:
    """The exception of a kernel's status ``code`` (not 0): the one wording of every route and face.

    Parameters
    ----------
    code : int
        From the transform kernel (``r + 1`` / ``-(r + 1)``: negative row ``r``'s downdate failed, or
        found the factor singular; 305: the result is not finite) or an update kernel (g13ej's 301,
        302, 303; 304 only where the posterior is not allowed to be singular).
    form : RowForm, optional
        The rows of the weights, for the negative weights' values.
    what : {"prior", "update"}
        Which phase.

    Returns
    -------
    SqukfError
    """
    negative = "" if form is None else ", ".join(f"{w:.6g}" for w in form.weights[form.neg])
    if what == "prior":
        if code == NOT_FINITE:
            return NonFiniteError("the predicted mean or factor is not finite")
        k = abs(code) - 1
        why = "the factor to downdate is singular" if code < 0 else "its downdate failed"
        w = form.weights[k] if form is not None else math.nan
        return DowndateError(f"weight {w:.6g} of row {k} is negative and {why}", errno=301)
    if code == 304:
        return PosteriorFactorError(
            "the posterior factor lost rank to rounding (a zero on its diagonal from positive definite P"
            " and R): the covariances' scales are too far apart for double precision",
            errno=303,
        )
    if code == 301:
        return DowndateError(f"weight {negative} is negative and the innovation factor's downdate failed", 301)
    if code == 302:
        return GainError("innovation factor is singular: cannot form the Kalman gain", errno=302)
    if negative and code == 303:
        return PosteriorFactorError(
            f"the posterior factor could not be formed (downdate failed, or not finite; negative weight "
            f"{negative})",
            errno=303,
        )
    return PosteriorFactorError("the posterior mean or factor is not finite, or its downdate failed", errno=303)


def prior_failure(code: int, form: RowForm | None) -> SqukfError:
    """:func:`failure` of a prediction's transform."""
    return failure(code, form, "prior")


def _singular_allowed(status: np.ndarray, S: np.ndarray, R1_2: np.ndarray) -> np.ndarray:
    """The status with each 304 that is the right answer cleared.

    A posterior factor with a zero on its diagonal from a positive definite prior factor ``S`` and
    noise factor ``R1_2`` is rank lost to rounding (an error); from a singular one (an exactly measured
    component) it is right.
    """
    definite = (np.diagonal(S, 0, -2, -1) != 0).all(axis=-1) & (np.diagonal(R1_2, 0, -2, -1) != 0).all(axis=-1)
    return np.where((status == 304) & ~definite, 0, status)


def first_status(status: np.ndarray) -> int:
    """The first non-zero status of a block (0 if none)."""
    if status.shape[0] == 1:
        return int(status[0])
    bad = np.flatnonzero(status)
    return int(status[bad[0]]) if bad.size else 0


class _ObservedR:
    """The factor of R's observed block, kept for the last (R, observed) pair: a repeated key forms nothing."""

    __slots__ = ("R", "key", "factor")

    def __init__(self):
        self.R = None
        self.key = b""
        self.factor = None

    def of(self, R1_2: np.ndarray, observed: np.ndarray) -> np.ndarray:
        key = observed.tobytes()
        if self.R is not R1_2 or self.key != key:
            rows = np.swapaxes(R1_2[..., observed, :], -1, -2)
            self.factor = tria(rows.copy(order="F") if rows.ndim == 2 else rows.copy())
            self.R, self.key = R1_2, key
        return self.factor  # type: ignore[return-value]


class Engine:
    """The step of a block of ``B`` filters of one plan: its state, its pending step, its last records.

    Parameters
    ----------
    plan : Plan
    hooks : Hooks
    gate : Gate or None
    x : ndarray, shape (B, n)
    S : ndarray, shape (B, n, n)
        The initial estimate (kept, not copied: never written in place).
    single : bool
        One filter with no batch axis (:class:`squkf.SquareRootUKF`): images, ``z`` and the noise
        factors are one filter's (``(N, d)``, ``(m,)``, ``(m, m)``), and the hooks, a ``UT`` and a
        user's generator see one filter's arrays, as filterpy's do. The engine's own arrays are a
        block of one.

    Attributes
    ----------
    x : ndarray, shape (B, n)
    S : ndarray, shape (B, n, n)
        The current estimate (replaced by each step, never written in place).
    phase : str
    prior : tuple (x, S) or None
        The last prediction's result (the estimate the pending second set is drawn from).
    sset : SigmaSet or None
        The second set of the pending or last update.
    last : Update or None
        The last update.
    H : ndarray, shape (B, N2, m), or None
        The last update's images.
    shown_f : ndarray or None
        What filterpy shows as ``sigmas_f``: the second set after a prediction.
    X : ndarray or None
        The points handed out by the pending ``ask_predict``.
    """

    __slots__ = (
        "plan", "hooks", "gate", "single", "x", "S", "phase", "prior", "sset", "last", "H", "shown_f", "X",
        "step_plan", "prior_record", "post_record", "_first", "_propagated", "_Q", "_routes", "_observed_R",
        "_plain_x", "_plain_add",
    )  # fmt: skip

    def __init__(self, plan: Plan, hooks: Hooks, gate, x: np.ndarray, S: np.ndarray, single: bool = False):
        self.single = single
        self.x, self.S = x, S
        self.phase = IDLE
        self.prior: tuple[np.ndarray, np.ndarray] | None = None
        self.sset: SigmaSet | None = None
        self.last: Update | None = None
        self.H: np.ndarray | None = None
        self.shown_f: np.ndarray | None = None
        self.X: np.ndarray | None = None
        self._first: np.ndarray | None = None  # the first set of (x, S), drawn ahead by the last update
        self._propagated: np.ndarray | None = None
        self._Q: np.ndarray | None = None
        self._observed_R = _ObservedR()
        self.step_plan = plan
        self.prior_record = self.post_record = (x, S)
        self.configure(plan, hooks, gate)

    def records_of_no_step(self, sigmas_f: np.ndarray, sigmas_h: np.ndarray, m: int) -> None:
        """The records before any step, as filterpy shows them (zeros, the initial estimate)."""
        self.shown_f, self.H = sigmas_f, sigmas_h
        self.prior_record = self.post_record = (self.x, self.S)

    def __getstate__(self):
        # the state and the pending step; not the routes' caches, nor the first set drawn ahead
        skip = ("_routes", "_observed_R", "_first")
        return {k: getattr(self, k) for k in self.__slots__ if k not in skip}

    def __setstate__(self, state) -> None:
        for k, v in state.items():
            object.__setattr__(self, k, v)
        self._observed_R = _ObservedR()
        self._routes = {}
        self._first = None

    # -- configuration ------------------------------------------------------------------------

    def configure(self, plan: Plan, hooks: Hooks, gate) -> None:
        """A new configuration, its routes decided anew (a pending step keeps the plan it was drawn with)."""
        self.plan, self.hooks, self.gate = plan, hooks, gate
        self._routes: dict = {}
        self._plain_x = hooks.x_mean_fn is None and hooks.residual_x is None
        self._plain_add = hooks.state_add is None
        self._first = None

    def assign(self, x: np.ndarray | None = None, S: np.ndarray | None = None) -> None:
        """A new estimate from the caller (validated; kept): the sets drawn for the old one are dropped."""
        if x is not None:
            self.x = x
        if S is not None:
            self.S = S
        self._first = None

    def _one(self, a):
        """``a`` as the hooks, a ``UT`` and a generator see it: one filter's (no batch axis) if single."""
        return a[0] if self.single and a is not None else a

    def _block(self, a):
        """One filter's result as a block of one (if single)."""
        return a[None] if self.single and a is not None else a

    # -- the prediction -------------------------------------------------------------------------

    def first_set(self) -> np.ndarray:
        """The first sigma-point set of the current estimate, ``(B, N, n)`` (nothing committed).

        The set the last update drew ahead, or drawn now. The array is the engine's and is
        used once: the caller may hand it to ``fx`` (which may write on it), never keep it.
        """
        X, self._first = self._first, None
        if X is None:
            first = self.plan.first
            add = self.hooks.state_add
            if add is None:
                X = sigma_points_from_factor(self.x, self.S, first.xi, None, first.gamma)
            else:  # the hook sees one filter's vectors
                X = self._block(sigma_points_from_factor(self._one(self.x), self._one(self.S), first.xi, add))
        return X

    def ask_predict(self) -> np.ndarray:
        """Start a step (from any phase): :meth:`first_set`, kept as the points of the pending prediction."""
        X = self.first_set()
        self.step_plan = self.plan
        self.X = X
        self.phase = PREDICTING
        return X

    def tell_predict(
        self, F, Q1_2: np.ndarray | None, UT: Callable | None = None, name: str = "fx values", points=None
    ) -> None:
        """Finish the prediction from the first set's images: the prior and the second set, committed.

        Parameters
        ----------
        F : array_like, shape (B, N, n) (single: (N, n))
            ``fx`` at the points of :meth:`ask_predict` (checked here).
        Q1_2 : ndarray, shape (n, n) or (B, n, n), or None
            Lower factor of the additive process noise (None: none added).
        UT : callable, optional
        name : str
            How the images are called in messages.
        points : ndarray, shape (B, N, n), optional
            The points of a whole prediction (:meth:`first_set`, with no ask pending); default:
            those of the pending :meth:`ask_predict`.
        """
        if points is None:
            if self.phase != PREDICTING:
                raise CallSequenceError(
                    f"tell_predict needs a pending ask_predict, but the step is {self.phase!r}"
                    + (" (the prediction was already told)" if self.phase == PRIOR else "")
                )
            plan, X = self.step_plan, self.X
        else:
            plan, X = self.plan, points
        assert X is not None
        F = self._images(F, X.shape, name, plan.keeps_propagated)
        hooks = self.hooks
        sset = None
        B, N, n = F.shape
        if UT is None and self._plain_x:
            draw = plan.fused_draw if self._plain_add else None
            if draw is not None and draw.augmented and Q1_2 is None:
                draw = None  # the augmented set without noise is the propagated set itself
            mean, S, status = np.empty((B, n)), np.empty((B, n, n)), np.empty(B, dtype=np.int64)
            if draw is None:
                X2 = D2 = kernels.no_set(n)
                code, xi2, gamma2 = 0, kernels.no_points(n), 0.0
            else:
                X2 = np.empty((B, draw.xi.shape[0] + (N if draw.augmented else 0), n))
                D2 = kernels.no_set(n) if draw.augmented else np.empty(X2.shape)
                code, xi2, gamma2 = (2 if draw.augmented else 1), draw.xi, draw.gamma
            form = plan.first.rows.best
            _K.transform(
                F, kernels.zeros_row(n), kernels.CENTRAL if form.central else kernels.MEAN, plan.wm1,
                plan.scale1, plan.sign1, _noise(Q1_2, n), mean, S, status, code, xi2, gamma2, X2, D2,
            )  # fmt: skip
            bad = first_status(status)
            if bad:
                raise prior_failure(bad, form)
            if draw is not None:
                rows = draw.rows
                offsets = None if draw.augmented else D2
                sset = SigmaSet(X2, rows.Wm, rows.Wc, draw.exact, offsets, rows, draw.axis)
        else:
            rows = plan.first.rows
            Fo, Qo = self._one(F), Q1_2
            if UT is None:
                mean, S = transform_factor(
                    Fo, rows, Qo, hooks.x_mean_fn, hooks.residual_x, errno=301, hooks=("x_mean_fn", "residual_x")
                )
            else:
                mean, S = UT(Fo, rows.Wm, rows.Wc, Qo, hooks.x_mean_fn, hooks.residual_x)
                shape = Fo.shape
                mean = check_hook_result(mean, shape[:-2] + shape[-1:], "UT")
                S = check_hook_result(S, shape[:-2] + (shape[-1], shape[-1]), "UT")
            if not (all_finite(mean) and all_finite(S)):
                raise NonFiniteError("the predicted mean or factor is not finite")
            mean, S = self._block(mean), self._block(S)
        propagated = F if plan.keeps_propagated else None
        if sset is None:
            sset = self._draw_second(plan, mean, S, propagated, Q1_2)
        # commit
        self.step_plan = plan
        self.x, self.S = mean, S
        self.prior = self.prior_record = (mean, S)
        self.sset = sset
        self.shown_f = sset.sigmas
        self._propagated, self._Q = (propagated, Q1_2) if plan.keeps_propagated else (None, None)
        self._first = None
        self.X = None
        self.phase = PRIOR

    def _draw_second(self, plan: Plan, x, S, propagated, Q1_2) -> SigmaSet:
        """The generator's second set for ``(x, S)`` (one filter's arrays to a user's generator and hooks)."""
        if not self.single:
            return plan.second.draw(x, S, propagated, Q1_2, self.hooks.state_add)
        one = self._one
        s = plan.second.draw(one(x), one(S), one(propagated), Q1_2, self.hooks.state_add)
        return s._replace(sigmas=s.sigmas[None], offsets=None if s.offsets is None else s.offsets[None])

    # -- the update ------------------------------------------------------------------------------

    def pending_update(self) -> tuple[tuple[np.ndarray, np.ndarray], SigmaSet]:
        """The prior and second set of the update pending for the current estimate (nothing committed).

        After a prediction, its prior and the set drawn with it; if the estimate was assigned since (or
        no prediction precedes), the estimate and a set drawn from it alone.
        """
        if self.phase == PREDICTING:
            raise CallSequenceError(
                "ask_update called while a prediction is pending: tell_predict the fx values first"
            )
        prior = self.prior
        if self.phase in (PRIOR, UPDATING) and prior is not None and prior[0] is self.x and prior[1] is self.S:
            return prior, self.sset  # type: ignore[return-value]  # drawn with the prior
        return (self.x, self.S), self._draw_second(self.plan, self.x, self.S, None, None)

    def ask_update(self) -> np.ndarray:
        """:meth:`pending_update`, kept as the pending update: its second set, ``(B, N2, n)`` (the engine's)."""
        prior, sset = self.pending_update()
        if sset is not self.sset:
            self._propagated = self._Q = None
        self.prior, self.sset = prior, sset
        self.phase = UPDATING
        return sset.sigmas

    def tell_update(
        self,
        H,
        z: np.ndarray,
        observed: np.ndarray | None,
        R1_2: np.ndarray,
        UT: Callable | None = None,
        name: str = "hx values",
        pending: tuple | None = None,
    ) -> None:
        """Finish the update from the second set's images and the measurement, through the gate; committed.

        Parameters
        ----------
        H : array_like, shape (B, N2, m) (single: (N2, m))
            ``hx`` at the points of :meth:`ask_update` (checked here).
        z : ndarray, shape (B, m) (single: (m,))
            The measurement (missing components hold NaN).
        observed : ndarray of bool, shape (m,), or None
            The measured components (None: all).
        R1_2 : ndarray, shape (m, m) or (B, m, m)
            Lower factor of the measurement noise (zeros: none).
        UT : callable, optional
        name : str
        pending : tuple, optional
            The prior and set of a whole update (:meth:`pending_update`, with no ask pending);
            default: those of the pending :meth:`ask_update`.
        """
        if pending is None:
            if self.phase != UPDATING:
                raise CallSequenceError(
                    f"tell_update needs a pending ask_update, but the step is {self.phase!r}"
                    + (" (the update was already told)" if self.phase == IDLE else "")
                )
            pending = (self.prior, self.sset)
        (xp, Sp), sset = pending
        m = z.shape[-1]
        H = self._images(H, sset.sigmas.shape[:-1] + (m,), name, True)
        if self.single:
            z = z[None]
        post, X1 = self._posterior(sset, xp, Sp, H, z, observed, R1_2, UT)
        update = self._gated(post, sset, xp, Sp, H, z, observed, R1_2, UT)
        # commit
        if sset is not self.sset:
            self._propagated = self._Q = None
        self.prior, self.sset = (xp, Sp), sset
        self.x, self.S = update.x, update.S
        self.post_record = (update.x, update.S)
        self.last = update
        self.H = H
        self._first = X1 if update.x is post.x else None  # a gate's change: not the set's posterior
        self.phase = IDLE

    def skip_update(self) -> None:
        """End the step without a measurement: the estimate stays, and the last update's records too."""
        if self.phase == PREDICTING:
            raise CallSequenceError(
                "update without a measurement called while a prediction is pending: "
                "tell_predict the fx values first"
            )
        self.post_record = (self.x, self.S)
        self.phase = IDLE

    # -- the routes ---------------------------------------------------------------------------

    def update_route(self, sset: SigmaSet, UT) -> _Joint | None:
        """The joint-QR route of an update with this set, or None for the general one (hooks, ``UT``).

        Decided once per key (the set's kind, ``UT`` given or not) and kept.
        """
        key = (id(sset.rows), sset.moments_exact, sset.offsets is None, sset.axis, UT is None)
        route = self._routes.get(key, False)
        if route is False:
            hooks = self.hooks
            plain = UT is None and sset.moments_exact and hooks.z_mean_fn is None and hooks.residual_z is None
            route = _joint_route(sset) if plain and self._plain_x and sset.rows is not None else None
            self._routes[key] = route
        return route  # type: ignore[return-value]

    def _posterior(self, sset, x, S, H, z, observed, R1_2, UT) -> tuple[Posterior, np.ndarray | None]:
        """The update with every measured component (what a gate tests), and the first set drawn from it."""
        route = self.update_route(sset, UT)
        if route is None or not self._plain_add:
            one = self._one
            hooks = self.hooks
            post = measurement_update(
                one(x), one(S), _one_set(sset) if self.single else sset, one(H), one(z), R1_2,
                observed=observed, z_mean_fn=hooks.z_mean_fn, residual_x=hooks.residual_x,
                residual_z=hooks.residual_z, state_add=hooks.state_add, UT=UT,
            )  # fmt: skip
            if self.single:
                post = Posterior(*(a[None] for a in post))
            return post, None
        Ro = R1_2
        if observed is not None and not observed.all():
            H, z = np.ascontiguousarray(H[..., observed]), np.ascontiguousarray(z[..., observed])
            Ro = self._observed_R.of(R1_2, observed)
        B, N, m = H.shape
        n = x.shape[-1]
        zp, y, w, Sy = np.empty((B, m)), np.empty((B, m)), np.empty((B, m)), np.empty((B, m, m))
        L21, dx, xo, So = np.empty((B, n, m)), np.empty((B, n)), np.empty((B, n)), np.empty((B, n, n))
        ll, ww, status = np.empty(B), np.empty(B), np.empty(B, dtype=np.int64)
        plan = self.plan
        draw = plan.w_xi is None  # the next first set drawn ahead (none with noise entering fx)
        X1 = np.empty((B,) + plan.xi1.shape) if draw else kernels.no_set(n)
        _K.joint_update(
            H, kernels.zeros_row(m), sset.offsets if route.offsets else sset.sigmas,
            x if route.xref else kernels.zeros_row(n), z, _stacked(Ro), x, route.mode, route.wm,
            route.scale, route.sign, route.pair, zp, y, w, Sy, L21, dx, xo, So, ll, ww, status,
            plan.xi1, plan.gamma1, X1,
        )  # fmt: skip
        bad = first_status(status)
        if bad:
            if (status == 304).any():
                status = _singular_allowed(status, S, _stacked(Ro))
                bad = first_status(status)
            if bad:
                raise failure(bad, route.form)
        return Posterior(xo, So, y, zp, Sy, L21, w, ll, ww), (X1 if draw else None)

    def _gated(self, post: Posterior, sset, x0, S0, H, z, observed, R1_2, UT) -> Update:
        """The gate's decision on the tested update, and the update applied (:mod:`squkf.gating`).

        Rejected components are missing: a filter whose whole measurement is rejected keeps its prior
        (log-likelihood 0), one with some rejected is updated again with the others.
        """
        m = z.shape[-1]
        gate = self.gate
        if gate is None:
            rejected = _none_rejected(post.y.shape)
        else:
            rejected = gate.reject(post.y, post.Sy, post.nis)
        if gate is None or not rejected.any():
            return Update(post.x, post.S, post.y, post.Sy, post.L21, post.log_likelihood, post.nis, observed,
                          rejected, None, m)  # fmt: skip
        n, mo = post.x.shape[-1], post.y.shape[-1]
        obs_idx = np.arange(m) if observed is None else np.flatnonzero(observed)
        x, S = post.x.copy(), post.S.copy()
        ll = np.array(post.log_likelihood, dtype=float)
        K = _gain(post.Sy, post.L21).copy()
        none_left = rejected.all(axis=1)
        x[none_left], S[none_left] = x0[none_left], S0[none_left]
        ll[none_left], K[none_left] = 0.0, 0.0
        some = rejected.any(axis=1) & ~none_left
        if some.any():
            patterns, which = np.unique(rejected[some], axis=0, return_inverse=True)
            some_idx = np.flatnonzero(some)
            for p, pattern in enumerate(patterns):
                ix = some_idx[which.reshape(-1) == p]
                mask = np.zeros(m, dtype=bool)
                mask[obs_idx[~pattern]] = True
                R_ix = R1_2[ix] if R1_2.ndim > 2 else R1_2
                sub = sset._replace(
                    sigmas=sset.sigmas[ix], offsets=None if sset.offsets is None else sset.offsets[ix]
                )
                part, _ = self._posterior(sub, x0[ix], S0[ix], H[ix], z[ix], mask, R_ix, UT)
                x[ix], S[ix], ll[ix] = part.x, part.S, part.log_likelihood
                Kp = np.zeros((ix.size, n, mo))
                Kp[:, :, ~pattern] = _gain(part.Sy, part.L21)
                K[ix] = Kp
        return Update(x, S, post.y, post.Sy, post.L21, ll, post.nis, observed, rejected, K, m)

    def _images(self, values, shape: tuple, name: str, private: bool) -> np.ndarray:
        """Model images checked against the block's ``shape`` (one filter's, if single); a block."""
        if self.single:
            return _images(values, shape[1:], name, private)[None]
        return _images(values, shape, name, private)


def _one_set(sset: SigmaSet) -> SigmaSet:
    """One filter's set of a block of one."""
    return sset._replace(sigmas=sset.sigmas[0], offsets=None if sset.offsets is None else sset.offsets[0])


def _gain(Sy: np.ndarray, L21: np.ndarray) -> np.ndarray:
    from .measurement import gain_from_factors

    return gain_from_factors(Sy, L21)


_NONE_REJECTED: dict[tuple, np.ndarray] = {}


def _none_rejected(shape: tuple) -> np.ndarray:
    """All False, read-only: the record of an update without a gate (made once per shape)."""
    a = _NONE_REJECTED.get(shape)
    if a is None:
        a = _NONE_REJECTED[shape] = np.zeros(shape, dtype=bool)
        a.setflags(write=False)
    return a


def _noise(Q1_2: np.ndarray | None, n: int) -> np.ndarray:
    """A noise factor as the transform kernel takes it: ``(1 or B, n, q)``, ``q = 0`` for none."""
    if Q1_2 is None:
        return kernels.no_noise(n)
    return _stacked(Q1_2)


def _stacked(a: np.ndarray) -> np.ndarray:
    """A shared ``(d, d)`` factor as a stack of one, or a per-filter stack as it is (float64, C order)."""
    if a.ndim == 2:
        a = a[None]
    return kernels.kernel_array(a)


def _images(values, shape: tuple, name: str, private: bool) -> np.ndarray:
    """Model images checked: float64, C-contiguous, of ``shape``, finite (a private copy when ``private``).

    The one check of every image a model function returns or a caller tells.
    """
    if (
        type(values) is np.ndarray
        and values.dtype is _FLOAT64
        and values.shape == shape
        and values.flags.c_contiguous
        and values.flags.writeable
    ):
        A = values.copy() if private else values
        if not all_finite(A):
            raise NonFiniteError(describe_nonfinite(A, name))
        return A
    A = check_values(values, shape, name)
    return np.ascontiguousarray(A)
