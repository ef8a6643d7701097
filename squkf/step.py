"""One filter step as reverse communication: the algorithm lives here once.

:class:`StepMachine` hands out the first sigma-point set, takes its images
under the state transition and forms the prior; hands out the second set,
takes its images under the measurement function and forms the posterior.
It holds only plain arrays and a phase name between calls (so the filter
that owns it pickles and deep-copies), and each call either completes or
raises leaving the machine exactly as it was.

The mean and factor themselves belong to the caller (a facade): the machine
returns new values and the caller commits them.

Phases::

    idle --ask_predict--> predicting --tell_predict--> prior
    prior | idle --ask_update--> updating --tell_update--> idle

``ask_predict`` may be called from any phase (it starts a new step and
drops whatever was pending); ``ask_update`` from ``idle`` redraws from the
current estimate (a second sensor at the same time).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .errors import CallSequenceError, NonFiniteError, ShapeError
from .generators import SigmaSet, sigma_points_from_factor
from .lane import Lane
from .linalg import all_finite
from .measurement import Posterior, measurement_update
from .transform import transform_factor, weight_plan

__all__ = ["StepMachine", "check_values"]

IDLE = "idle"
PREDICTING = "predicting"
PRIOR = "prior"
UPDATING = "updating"


def check_values(values, shape: tuple[int, int], name: str) -> np.ndarray:
    """Validate the images of a sigma-point set returned by the caller.

    Parameters
    ----------
    values : array_like
        What the model function returned (or the caller told).
    shape : tuple (N, d)
        Expected shape: one row per sigma point.
    name : str
        Used in the error message.

    Returns
    -------
    values : ndarray, shape (N, d), float64, a private copy

    Raises
    ------
    ShapeError, NonFiniteError
    """
    try:
        arr = np.array(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name} could not be read as a float array of shape {shape}: {exc}") from None
    if arr.shape != shape:
        # per-point functions returning column vectors, or scalars for a 1-d measurement
        if arr.shape == shape + (1,) or (shape[1] == 1 and arr.shape == shape[:1]):
            arr = arr.reshape(shape)
        else:
            raise ShapeError(f"{name} has shape {arr.shape}, expected {shape} (one row per sigma point)")
    if not all_finite(arr):
        i, j = np.argwhere(~np.isfinite(arr))[0]
        raise NonFiniteError(f"{name} is not finite: row {i} (sigma point {i}), column {j} holds {arr[i, j]}")
    return arr


class StepMachine:
    """Reverse-communication state of one filter (see the module docstring).

    Attributes
    ----------
    phase : str
        ``"idle"``, ``"predicting"``, ``"prior"`` or ``"updating"``.
    sigmas : ndarray or None
        The points handed out by the last ask, shape ``(N, n)``.
    """

    def __init__(self):
        self.phase = IDLE
        self.sigmas = None
        self._first_weights = None  # (Wm, Wc) of the pending first set
        self._propagated = None  # first-set images, for the augmented set
        self._Q1_2 = None  # process noise of the last prediction
        self._sset = None  # second set drawn (at tell_predict, or by ask_update)
        self._sset_lane = None  # the lane that drew it, if any
        self._prior = None  # (x, S) that set was drawn from (x a private copy)
        self.sigmas_h = None  # images of the last second set told

    def snapshot(self) -> dict:
        """The machine's state, for :meth:`restore` (shallow: arrays are never mutated)."""
        return dict(self.__dict__)

    def restore(self, snap: dict) -> None:
        """Put back a state taken by :meth:`snapshot`."""
        self.__dict__.clear()
        self.__dict__.update(snap)

    def forget_propagated(self) -> None:
        """Drop the propagated set (the caller changed the prior it belongs to)."""
        self._propagated = None
        if self.phase == PRIOR:
            self.phase = IDLE

    # -- prediction ---------------------------------------------------------

    def ask_predict(
        self, x: np.ndarray, S: np.ndarray, family, state_add=None, lane: Lane | None = None
    ) -> np.ndarray:
        """Start a step: the first sigma-point set around ``(x, S)``.

        Parameters
        ----------
        x : ndarray, shape (n,)
        S : ndarray, shape (n, n)
            Lower factor of the current covariance.
        family : sigma-point family
        state_add : callable, optional
        lane : Lane, optional
            The plain step's kernel for this family (no ``state_add``).

        Returns
        -------
        sigmas : ndarray, shape (N, n)
            ``[x, x + g S[:, j], x - g S[:, j]]`` for a symmetric family.
        """
        n = x.shape[0]
        if lane is not None:
            sigmas = lane.first_set(x, S)
            weights = lane.plan1.Wm, lane.plan1.Wc
        else:
            sigmas = sigma_points_from_factor(x, S, family.unit_sigma_points(n), state_add)
            weights = family.weights(n)
        self.phase = PREDICTING
        self.sigmas = sigmas
        self._first_weights = weights
        self._sset = None
        self._prior = None
        return sigmas

    def tell_predict(
        self,
        values,
        Q1_2: np.ndarray | None,
        *,
        x_mean_fn: Callable | None = None,
        residual_x: Callable | None = None,
        UT: Callable | None = None,
        name: str = "fx values",
        lane: Lane | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Finish the prediction from the first set's images.

        Parameters
        ----------
        values : array_like, shape (N, n)
            ``fx`` at each point of the first set, one row per point.
        Q1_2 : ndarray, shape (n, n), or None
            Lower factor of the process noise (None: no noise).
        x_mean_fn, residual_x : callable, optional
        UT : callable, optional
            Square-root transform replacing the default (same signature as
            :func:`squkf.sqrt_unscented_transform`).
        name : str
            How to call ``values`` in error messages.
        lane : Lane, optional
            The plain step's kernel (only without hooks and ``UT``).

        Returns
        -------
        x_prior : ndarray, shape (n,)
        S_prior : ndarray, shape (n, n)
        """
        if self.phase != PREDICTING:
            raise CallSequenceError(
                f"tell_predict needs a pending ask_predict, but the step is {self.phase!r}"
                + (" (the prediction was already told)" if self.phase == PRIOR else "")
            )
        N, n = self.sigmas.shape
        F = check_values(values, (N, n), name)
        Wm, Wc = self._first_weights
        if lane is not None:
            x, S = lane.prior(F, Q1_2)
        elif UT is None:
            x, S = transform_factor(F, weight_plan(Wm, Wc), Q1_2, x_mean_fn, residual_x, errno=301)
        else:
            x, S = UT(F, Wm, Wc, Q1_2, x_mean_fn, residual_x)
            x = np.asarray(x, dtype=float).reshape(n)
            S = np.asarray(S, dtype=float).reshape(n, n)
        if lane is None and not (all_finite(x) and all_finite(S)):
            raise NonFiniteError("the predicted mean or factor is not finite")
        self.phase = PRIOR
        self._propagated = F
        self._Q1_2 = Q1_2
        return x, S

    def draw_second_set(
        self, x: np.ndarray, S: np.ndarray, family, generator, state_add=None, lane: Lane | None = None
    ) -> SigmaSet:
        """Draw the second set for ``(x, S)`` now (``ask_update`` hands it out if they are unchanged).

        Called by the facade straight after :meth:`tell_predict`, since filterpy
        shows the second set in ``sigmas_f`` as soon as the prediction is done.

        Parameters
        ----------
        x : ndarray, shape (n,)
        S : ndarray, shape (n, n)
        family : sigma-point family of the first set
        generator : second-set generator
        state_add : callable, optional
        lane : Lane, optional
            The plain step's kernel for this generator (draws the same set).

        Returns
        -------
        SigmaSet
        """
        if lane is not None:
            sset = lane.second_set(x, S)
        else:
            propagated = self._propagated if self.phase in (PRIOR, UPDATING) else None
            sset = generator.second_set(
                x, S, family=family, propagated=propagated, Q1_2=self._Q1_2, state_add=state_add
            )
        self._sset = sset
        self._sset_lane = lane
        self._prior = (x.copy(), S)  # a copy: the caller's x may be edited in place
        return sset

    # -- measurement update -------------------------------------------------

    def ask_update(
        self, x: np.ndarray, S: np.ndarray, family, generator, state_add=None, lane: Lane | None = None
    ) -> SigmaSet:
        """The second sigma-point set for the measurement update.

        Parameters
        ----------
        x : ndarray, shape (n,)
        S : ndarray, shape (n, n)
            The prior (after a prediction) or the current estimate.
        family : sigma-point family of the first set
        generator : second-set generator
        state_add : callable, optional
        lane : Lane, optional
            The plain step's kernel for this generator.

        Returns
        -------
        SigmaSet
        """
        if self.phase == PREDICTING:
            raise CallSequenceError(
                "ask_update called while a prediction is pending: tell_predict the fx values first"
            )
        drawn = self._prior
        if not (
            self.phase in (PRIOR, UPDATING)
            and drawn is not None
            and drawn[1] is S
            and drawn[0].shape == x.shape
            and drawn[0].tobytes() == x.tobytes()
        ):
            self.draw_second_set(x, S, family, generator, state_add, lane)
        self.phase = UPDATING
        self.sigmas = self._sset.sigmas
        return self._sset

    def tell_update(
        self,
        values,
        z: np.ndarray,
        R1_2: np.ndarray,
        *,
        z_mean_fn: Callable | None = None,
        residual_x: Callable | None = None,
        residual_z: Callable | None = None,
        state_add: Callable | None = None,
        UT: Callable | None = None,
        name: str = "hx values",
        lane: Lane | None = None,
    ) -> Posterior:
        """Finish the update from the second set's images and the measurement.

        Parameters
        ----------
        values : array_like, shape (N, m)
            ``hx`` at each point of the second set, one row per point.
        z : ndarray, shape (m,)
        R1_2 : ndarray, shape (m, m)
        z_mean_fn, residual_x, residual_z, state_add, UT : callable, optional
        name : str
        lane : Lane, optional
            The plain step's kernel (only without hooks and ``UT``); used when
            it is the one that drew the pending set.

        Returns
        -------
        Posterior
        """
        if self.phase != UPDATING:
            raise CallSequenceError(
                f"tell_update needs a pending ask_update, but the step is {self.phase!r}"
                + (" (the update was already told)" if self.phase == IDLE else "")
            )
        m = z.shape[0]
        H = check_values(values, (self._sset.sigmas.shape[0], m), name)
        x, S = self._prior
        if lane is not None and lane is self._sset_lane:
            post = lane.posterior(H, x, S, z, R1_2)
        else:
            post = measurement_update(
                x,
                S,
                self._sset,
                H,
                z,
                R1_2,
                z_mean_fn=z_mean_fn,
                residual_x=residual_x,
                residual_z=residual_z,
                state_add=state_add,
                UT=UT,
            )
        self.phase = IDLE
        self._propagated = None
        self._sset = None
        self._prior = None
        self.sigmas_h = H
        return post

    def skip_update(self) -> None:
        """End the step without a measurement (the prior becomes the posterior)."""
        self.phase = IDLE
        self._propagated = None
        self._sset = None
        self._prior = None
