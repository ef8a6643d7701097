"""One filter step as reverse communication, as pure transitions over plain data.

The step state (:class:`StepState`) is a plain record: the phase, the points
last handed out, the propagated first set, the pending second set and the
prior it was drawn from. Each transition takes a state, a plan
(:mod:`squkf.plan`) and the caller's values and returns a *new* state with
its results; it never changes its inputs. A facade commits the new state
only when the whole call succeeded, so a failed call leaves everything as it
was. Arrays may carry leading batch axes (one filter: none).

Phases::

    idle --ask_predict--> predicting --tell_predict--> prior
    prior | idle --ask_update--> updating --tell_update--> idle

``ask_predict`` may be called from any phase (it starts a new step and
drops whatever was pending); ``ask_update`` from ``idle`` redraws from the
current estimate (a second sensor at the same time).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .errors import CallSequenceError, NonFiniteError
from .generators import SigmaSet, sigma_points_from_factor
from .linalg import all_finite
from .measurement import Posterior, measurement_update
from .plan import Hooks, Plan
from .transform import transform_factor
from .validate import check_hook_result, check_values

__all__ = [
    "StepState",
    "IDLE",
    "PREDICTING",
    "PRIOR",
    "UPDATING",
    "ask_predict",
    "tell_predict",
    "draw_second_set",
    "pending_update",
    "ask_update",
    "tell_update",
    "GatedUpdate",
    "gated_update",
    "take_filters",
    "skip_update",
    "check_values",
]

IDLE = "idle"
PREDICTING = "predicting"
PRIOR = "prior"
UPDATING = "updating"

_NO_HOOKS = Hooks()


@dataclass
class StepState:
    """The reverse-communication state between calls (plain data; pickles).

    Treated as immutable: every transition returns a new state and never
    changes the one it was given (not ``frozen=True``, whose ``__init__``
    costs a few microseconds a step).

    Attributes
    ----------
    phase : str
        ``"idle"``, ``"predicting"``, ``"prior"`` or ``"updating"``.
    sigmas : ndarray or None
        The points handed out by the last ask, shape ``(..., N, n)``.
    propagated : ndarray or None
        The first set's images after ``tell_predict`` (for the augmented set).
    Q1_2 : ndarray or None
        The process-noise factor of that prediction.
    sset : SigmaSet or None
        The second set drawn for the pending update (None with a ``prior``:
        not drawn yet; :func:`ask_update` draws it).
    prior : tuple (x, S) or None
        The mean and factor ``sset`` was, or is to be, drawn from.
    """

    phase: str = IDLE
    sigmas: np.ndarray | None = None
    propagated: np.ndarray | None = None
    Q1_2: np.ndarray | None = None
    sset: SigmaSet | None = None
    prior: tuple[np.ndarray, np.ndarray] | None = None


def ask_predict(
    state: StepState, plan: Plan, x: np.ndarray, S: np.ndarray, state_add: Callable | None = None
) -> StepState:
    """Start a step: the first sigma-point set around ``(x, S)`` (in ``.sigmas`` of the result).

    Parameters
    ----------
    state : StepState
        Any phase: a new step drops whatever was pending.
    plan : Plan
    x : ndarray, shape (..., n)
    S : ndarray, shape (..., n, n)
        Lower factor of the current covariance.
    state_add : callable, optional

    Returns
    -------
    StepState
        Phase ``"predicting"``; ``sigmas`` ``(..., N, n)`` is
        ``[x, x + g S[:, j], x - g S[:, j]]`` for a symmetric family.
    """
    first = plan.first
    sigmas = sigma_points_from_factor(x, S, first.xi, state_add, first.gamma)
    return StepState(PREDICTING, sigmas)


def tell_predict(
    state: StepState,
    plan: Plan,
    values,
    Q1_2: np.ndarray | None,
    hooks: Hooks = _NO_HOOKS,
    UT: Callable | None = None,
    name: str = "fx values",
    checked: bool = False,
) -> tuple[StepState, np.ndarray, np.ndarray]:
    """Finish the prediction from the first set's images.

    Parameters
    ----------
    state : StepState
        Phase ``"predicting"``.
    plan : Plan
    values : array_like, shape (..., N, n)
        ``fx`` at each point of the first set, one row per point.
    Q1_2 : ndarray, shape (..., n, n), or None
        Lower factor of the process noise (None: no noise).
    hooks : Hooks
        ``x_mean_fn`` and ``residual_x`` are used.
    UT : callable, optional
        Square-root transform replacing the default (same signature as
        :func:`squkf.sqrt_unscented_transform`).
    name : str
        How to call ``values`` in error messages.
    checked : bool
        ``values`` is a float64 array of the right shape, found finite, that
        nothing else writes during the call (a fleet's chunk checks its
        images per filter first): taken as it is.

    Returns
    -------
    state : StepState
        Phase ``"prior"``.
    x_prior : ndarray, shape (..., n)
    S_prior : ndarray, shape (..., n, n)
    """
    if state.phase != PREDICTING:
        raise CallSequenceError(
            f"tell_predict needs a pending ask_predict, but the step is {state.phase!r}"
            + (" (the prediction was already told)" if state.phase == PRIOR else "")
        )
    shape = state.sigmas.shape  # type: ignore[union-attr]  # set in phase PREDICTING
    keep = plan.keeps_propagated
    F = values if checked else check_values(values, shape, name, private=keep)
    rows = plan.first.rows
    if UT is None:
        x, S = transform_factor(
            F, rows, Q1_2, hooks.x_mean_fn, hooks.residual_x, errno=301, hooks=("x_mean_fn", "residual_x")
        )
    else:
        x, S = UT(F, rows.Wm, rows.Wc, Q1_2, hooks.x_mean_fn, hooks.residual_x)
        x = check_hook_result(x, shape[:-2] + shape[-1:], "UT")
        S = check_hook_result(S, shape[:-2] + (shape[-1], shape[-1]), "UT")
    if not (all_finite(x) and all_finite(S)):
        raise NonFiniteError("the predicted mean or factor is not finite")
    return StepState(PRIOR, None, F if keep else None, Q1_2), x, S


def draw_second_set(
    state: StepState, plan: Plan, x: np.ndarray, S: np.ndarray, state_add: Callable | None = None
) -> StepState:
    """Draw the second set for ``(x, S)`` now (``ask_update`` hands it out if they are unchanged).

    The facade calls it straight after :func:`tell_predict`, since filterpy
    shows the second set in ``sigmas_f`` as soon as the prediction is done.

    Parameters
    ----------
    state : StepState
        After a prediction (``"prior"``), the propagated set is used; in any
        other phase the set is drawn from ``(x, S)`` alone.
    plan : Plan
    x : ndarray, shape (..., n)
    S : ndarray, shape (..., n, n)
    state_add : callable, optional

    Returns
    -------
    StepState
        With ``sset`` and ``prior`` set.
    """
    propagated = state.propagated if state.phase in (PRIOR, UPDATING) else None
    sset = plan.second.draw(x, S, propagated, state.Q1_2, state_add)
    if not plan.keeps_propagated:
        propagated = None  # not kept where the second set never reads it (memory, for a fleet)
    return StepState(state.phase, state.sigmas, propagated, state.Q1_2, sset, (x, S))


def pending_update(state: StepState, x: np.ndarray, S: np.ndarray) -> StepState:
    """The update pending for the estimate ``(x, S)``, its second set drawn or not yet.

    Parameters
    ----------
    state : StepState
        Not ``"predicting"``.
    x : ndarray, shape (..., n)
    S : ndarray, shape (..., n, n)
        The prior (after a prediction) or the current estimate.

    Returns
    -------
    StepState
        Phase ``"updating"``, ``sigmas`` None. When ``(x, S)`` is the prior
        that ``state``'s set was (or is to be) drawn from, ``state``'s
        propagated set, noise factor and second set (None: not drawn yet);
        otherwise (the caller changed the estimate) nothing of ``state``: a
        set to draw from ``(x, S)`` alone.
    """
    if state.phase == PREDICTING:
        raise CallSequenceError(
            "ask_update called while a prediction is pending: tell_predict the fx values first"
        )
    drawn = state.prior
    if (
        state.phase in (PRIOR, UPDATING)
        and drawn is not None
        and drawn[1] is S
        and (drawn[0] is x or (drawn[0].shape == x.shape and np.array_equal(drawn[0], x)))
    ):
        return StepState(UPDATING, None, state.propagated, state.Q1_2, state.sset, drawn)
    return StepState(UPDATING, None, None, None, None, (x, S))


def ask_update(
    state: StepState, plan: Plan, x: np.ndarray, S: np.ndarray, state_add: Callable | None = None
) -> StepState:
    """The second sigma-point set for the measurement update (in ``.sigmas`` of the result).

    Parameters
    ----------
    state, x, S
        As for :func:`pending_update`: when ``(x, S)`` is not what the
        pending set was drawn from (the caller changed it), the set is
        redrawn from it, without the propagated set.
    plan : Plan
    state_add : callable, optional

    Returns
    -------
    StepState
        Phase ``"updating"``.
    """
    state = pending_update(state, x, S)
    if state.sset is None:
        state = draw_second_set(state, plan, x, S, state_add)
    sset: SigmaSet = state.sset  # type: ignore[assignment]  # drawn just now or with the prior
    return StepState(UPDATING, sset.sigmas, state.propagated, state.Q1_2, sset, state.prior)


def tell_update(
    state: StepState,
    values,
    z: np.ndarray,
    R1_2: np.ndarray,
    observed: np.ndarray | None = None,
    hooks: Hooks = _NO_HOOKS,
    UT: Callable | None = None,
    name: str = "hx values",
    checked: bool = False,
) -> tuple[StepState, Posterior, np.ndarray]:
    """Finish the update from the second set's images and the measurement.

    Parameters
    ----------
    state : StepState
        Phase ``"updating"``.
    values : array_like, shape (..., N, m)
        ``hx`` at each point of the second set, one row per point.
    z : ndarray, shape (..., m)
        The measurement (missing components may hold anything).
    R1_2 : ndarray, shape (..., m, m)
    observed : ndarray of bool, shape (m,), optional
        The components of ``z`` that were measured (default: all). The update
        uses those only: their columns of the images, and the factor of R's
        observed block; the hooks and ``UT`` see whole vectors, and the update
        takes the observed components of what they return.
    hooks : Hooks
    UT : callable, optional
    name : str
    checked : bool
        As for :func:`tell_predict`.

    Returns
    -------
    state : StepState
        Phase ``"idle"``.
    post : Posterior
        Of the observed components.
    H : ndarray, shape (..., N, m)
        The images, checked (a private array; with ``checked``, ``values`` itself).
    """
    if state.phase != UPDATING:
        raise CallSequenceError(
            f"tell_update needs a pending ask_update, but the step is {state.phase!r}"
            + (" (the update was already told)" if state.phase == IDLE else "")
        )
    m = z.shape[-1]
    sset: SigmaSet = state.sset  # type: ignore[assignment]  # set in phase UPDATING, as is the prior
    sigmas = sset.sigmas
    H = values if checked else check_values(values, sigmas.shape[:-1] + (m,), name)
    x, S = state.prior  # type: ignore[misc]
    post = measurement_update(
        x,
        S,
        sset,
        H,
        z,
        R1_2,
        observed=observed,
        z_mean_fn=hooks.z_mean_fn,
        residual_x=hooks.residual_x,
        residual_z=hooks.residual_z,
        state_add=hooks.state_add,
        UT=UT,
    )
    return StepState(), post, H


class GatedUpdate(NamedTuple):
    """An update through an outlier gate: what the gate saw and what was applied.

    Attributes
    ----------
    tested : Posterior
        The update with every measured component (the innovation, its factor
        and NIS are what the gate tested).
    rejected : ndarray of bool, shape (..., m_obs)
        The measured components the gate rejected (all False without a gate).
    x : ndarray, shape (..., n)
    S : ndarray, shape (..., n, n)
        The posterior after the components that passed: ``tested``'s where
        none was rejected, the prior where all were.
    log_likelihood : ndarray, shape (...)
        Of the components that passed (0 where none did: nothing measured).
    K : ndarray, shape (..., n, m_obs), or None
        The gain that was applied (zero columns for rejected components);
        None when nothing was rejected (it is ``tested.gain()``).
    """

    tested: Posterior
    rejected: np.ndarray
    x: np.ndarray
    S: np.ndarray
    log_likelihood: np.ndarray
    K: np.ndarray | None


def take_filters(state: StepState, idx: np.ndarray) -> StepState:
    """The pending update of the filters ``idx`` of a stack (flattened to one batch axis).

    Parameters
    ----------
    state : StepState
        Phase ``"updating"``, of a stack with any batch shape.
    idx : ndarray of int
        Indices into the flattened batch.

    Returns
    -------
    StepState
        Of batch shape ``(len(idx),)``.
    """
    sset: SigmaSet = state.sset  # type: ignore[assignment]  # set in phase UPDATING, as is the prior
    x, S = state.prior  # type: ignore[misc]
    n = x.shape[-1]
    N = sset.sigmas.shape[-2]

    def rows(a, core):
        return None if a is None else a.reshape((-1,) + a.shape[a.ndim - core :])[idx]

    sub = sset._replace(sigmas=rows(sset.sigmas, 2), offsets=rows(sset.offsets, 2))
    assert sub.sigmas.shape[1:] == (N, n)
    return StepState(UPDATING, None, None, None, sub, (rows(x, 1), rows(S, 2)))


@functools.lru_cache(maxsize=64)
def _none_rejected(shape: tuple[int, ...]) -> np.ndarray:
    """All False, read-only: the record of an update without a gate (made once per shape)."""
    a = np.zeros(shape, dtype=bool)
    a.setflags(write=False)
    return a


def gated_update(
    state: StepState,
    values,
    z: np.ndarray,
    R1_2: np.ndarray,
    observed: np.ndarray | None,
    hooks: Hooks,
    UT: Callable | None,
    gate,
    name: str = "hx values",
    checked: bool = False,
) -> tuple[StepState, GatedUpdate, np.ndarray]:
    """:func:`tell_update` through an outlier gate (:mod:`squkf.gating`).

    The update is computed with every measured component; the gate's
    rejections are then treated as missing components: a filter whose whole
    measurement is rejected keeps its prior (and measured nothing), one with
    some components rejected is updated again with the others. Filters of a
    stack are decided each on its own.

    Parameters
    ----------
    state, values, z, R1_2, observed, hooks, UT, name, checked
        As for :func:`tell_update`; ``R1_2`` is ``(m, m)`` or per filter
        ``(..., m, m)``.
    gate : Gate or None
        None: no gating (``rejected`` all False).

    Returns
    -------
    state : StepState
        Phase ``"idle"``.
    update : GatedUpdate
    H : ndarray, shape (..., N, m)
        The images, checked (a private array; with ``checked``, ``values`` itself).
    """
    new, post, H = tell_update(state, values, z, R1_2, observed, hooks, UT, name, checked)
    if gate is None:
        return (
            new,
            GatedUpdate(post, _none_rejected(post.y.shape), post.x, post.S, post.log_likelihood, None),
            H,
        )
    rejected = gate.reject(post.y, post.Sy, post.nis)
    if not rejected.any():
        return new, GatedUpdate(post, rejected, post.x, post.S, post.log_likelihood, None), H
    batch, n, mo = post.x.shape[:-1], post.x.shape[-1], post.y.shape[-1]
    B = math.prod(batch)
    m = z.shape[-1]
    obs_idx = np.arange(m) if observed is None else np.flatnonzero(observed)
    x0, S0 = state.prior  # type: ignore[misc]
    x = post.x.reshape(B, n).copy()
    S = post.S.reshape(B, n, n).copy()
    ll = np.asarray(post.log_likelihood, dtype=float).reshape(B).copy()
    K = post.gain().reshape(B, n, mo).copy()
    rej = rejected.reshape(B, mo)
    none_left = rej.all(axis=1)
    x[none_left], S[none_left] = x0.reshape(B, n)[none_left], S0.reshape(B, n, n)[none_left]
    ll[none_left], K[none_left] = 0.0, 0.0
    some = rej.any(axis=1) & ~none_left
    if some.any():
        Hf, zf = H.reshape((B,) + H.shape[-2:]), z.reshape(B, m)
        Rf = R1_2.reshape((-1, m, m)) if R1_2.ndim > 2 else R1_2
        patterns, which = np.unique(rej[some], axis=0, return_inverse=True)
        some_idx = np.flatnonzero(some)
        for p, pattern in enumerate(patterns):
            ix = some_idx[which.reshape(-1) == p]
            mask = np.zeros(m, dtype=bool)
            mask[obs_idx[~pattern]] = True
            R_ix = Rf[ix] if Rf.ndim > 2 else Rf
            _, part, _ = tell_update(take_filters(state, ix), Hf[ix], zf[ix], R_ix, mask, hooks, UT, name)
            x[ix], S[ix], ll[ix] = part.x, part.S, part.log_likelihood
            Kp = np.zeros((ix.size, n, mo))
            Kp[:, :, ~pattern] = part.gain()
            K[ix] = Kp
    x, S, ll, K = (
        x.reshape(batch + (n,)),
        S.reshape(batch + (n, n)),
        ll.reshape(batch),
        K.reshape(batch + (n, mo)),
    )
    return new, GatedUpdate(post, rejected, x, S, ll, K), H


def skip_update(state: StepState) -> StepState:
    """End the step without a measurement (the prior becomes the posterior).

    Raises
    ------
    CallSequenceError
        While a prediction is pending (``"predicting"``): tell it first.
    """
    if state.phase == PREDICTING:
        raise CallSequenceError(
            "update without a measurement called while a prediction is pending: "
            "tell_predict the fx values first"
        )
    return StepState()
