"""One filter's step in halves: ask for the sigma points, tell their images.

``ask_predict`` and ``tell_predict``, ``ask_update`` and ``tell_update`` are squkf's own (filterpy
has no such halves): a program that evaluates its model elsewhere (another process, a simulator, a
batch of requests) asks for the points, evaluates them, and tells the images; the engine's pending
step holds what lies between, and a half that fails changes nothing. A whole ``predict`` or
``update`` (:class:`squkf.SquareRootUKF`) is the same step with the model called in between.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from . import checks
from .errors import NonFiniteError
from .noise import handed_points
from .ukf_state import FilterState

__all__ = ["AskTell"]


class AskTell(FilterState):
    """``ask_predict``, ``tell_predict``, ``ask_update``, ``tell_update`` of one filter.

    A base class of :class:`squkf.SquareRootUKF`, holding no state of its own.
    """

    __slots__ = ()

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

    # -- what is handed out -----------------------------------------------------------

    def _asked(self, X: np.ndarray, xi: np.ndarray | None, name: str) -> np.ndarray:
        """What ``ask_*`` hands out: a copy of the points, with their noise part if any."""
        factor = None if xi is None else self._noise_factor(None, name, xi.shape[1])
        return handed_points(X, xi, factor, ())
