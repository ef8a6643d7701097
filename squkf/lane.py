"""The plain step: the default configuration's constants and buffers, prepared once.

With the redrawn second set, no angle hooks and no user ``UT``, and weights
whose central form has no negative row (Merwe's points with ``beta >=
alpha**2``, filterpy's default; Julier's, cubature and simplex points have
``sum(Wc) - 2 < 0`` and take the general step), a step is the same
sequence of array operations every time. A :class:`Lane` holds everything
that does not change between steps: the unit points, the central form's
row scales, the QR buffers, and the second set's state rows as a constant
matrix ``G`` (so that they are one product ``G S^T``), and performs the
step's numerics with them. It computes what
:func:`squkf.transform.transform_factor` and
:func:`squkf.measurement.measurement_update` compute for this configuration,
by the same formulas up to the order of some roundings (``tests/test_lane.py``
compares them), with about half the array operations.

The redrawn set is ``x + xi @ S.T``, so its deviations from its central
point are ``(xi[1:] - xi[0]) @ S.T`` exactly, whatever the size of ``x``.
The joint rows of the update are then::

    [ s_k (h_k - h_0),  s_k (xi_k - xi_0) S^T ]      k = 1 .. N-1
    [ c mu_z,           c (sum_k Wm_k (xi_k - xi_0)) S^T ]
    [ R1_2^T,           0 ]

with ``s_k = sqrt(Wc_k)``, ``c = sqrt(sum(Wc) - 2)`` and ``mu_z`` the
central form's mean offset of the images (see :mod:`squkf.transform`).

For larger states (``n >= 32``) with Merwe's axis points ``xi = [0; g I; -g I]``
two things change. The sets are built as ``x +/- g S^T``, O(n^2) instead of
the O(n^3) product, with the same numbers. And each ``+/-`` pair of joint rows
is rotated by 45 degrees (:meth:`Lane._paired_joint`), an orthogonal change of
rows (the same Gram matrix, other roundings) that leaves ``n`` rows with no
state part; those are triangularised first, so the joint QR has ``n + m``
rows instead of ``2n + 1 + m`` (about 40% fewer flops in the update's QR at
``n = 100``).
"""

from __future__ import annotations

import numpy as np

from .errors import NonFiniteError, PosteriorFactorError
from .generators import Redrawn, SigmaSet, _identity_moments
from .linalg import all_finite, solve_lower, tria
from .measurement import Posterior, check_gain
from .transform import _cacheable, central_rows, transform_factor, weight_plan

__all__ = ["Lane", "lane_for"]

_SQRT2 = float(np.sqrt(2.0))
# From this dimension on, the symmetric sets are built as x +/- gamma S^T (O(n^2)) rather than by
# the product xi @ S^T (O(n^3)); below it the one product is fewer array operations (measured).
_AXIS_MIN_N = 32


def _axis_gamma(xi: np.ndarray) -> float | None:
    """``gamma`` if ``xi`` is ``[0; gamma I; -gamma I]`` (Merwe's and Julier's unit points), else None."""
    N, n = xi.shape
    if N != 2 * n + 1 or n < _AXIS_MIN_N:
        return None
    gamma = float(xi[1, 0])
    axes = np.vstack([np.zeros((1, n)), gamma * np.eye(n), -gamma * np.eye(n)])
    return gamma if np.array_equal(xi, axes) else None


def _axis_points(x: np.ndarray, D: np.ndarray) -> np.ndarray:
    """The rows ``[x, x + D, x - D]`` for ``D = gamma S^T``, shape ``(2n + 1, n)``."""
    n = x.shape[0]
    X = np.empty((2 * n + 1, n))
    X[0] = x
    np.add(x, D, out=X[1 : n + 1])
    np.subtract(x, D, out=X[n + 1 :])
    return X


class Lane:
    """Constants and buffers of the plain step for one state dimension.

    Build it with :func:`lane_for`, which returns None for a configuration
    the lane does not serve.

    Parameters
    ----------
    n : int
        State dimension.
    xi1 : ndarray, shape (N1, n)
        Unit points of the first set.
    plan1 : WeightPlan
        The first set's weights (``plan1.fast``).
    family2 : sigma-point family
        The second set's family (its unit points and weights for ``n``
        give a set with the prior's mean and covariance, ``plan.fast``).
    """

    def __init__(self, n: int, xi1: np.ndarray, plan1, family2):
        self.n = n
        self.xi1 = xi1
        self.plan1 = plan1
        self.family2 = family2
        self.xi2 = family2.unit_sigma_points(n)
        self.plan2 = weight_plan(*family2.weights(n))
        form = self.plan2.best
        G = np.empty((self.xi2.shape[0], n))
        central_rows(self.xi2, self.plan2, G)  # the rows of the unit points: x + xi S^T gives G S^T
        self.G2 = G
        # with axis points every product with xi is a multiple of S^T (the same roundings)
        self.gamma1 = _axis_gamma(xi1)
        self.gamma2 = _axis_gamma(self.xi2)
        # for axis points G2 = [gs I; -gs I; 0]: the update's state rows are +/- gs S^T
        self.gs2 = None if self.gamma2 is None else float(G[0, 0])
        if self.gs2 is not None:
            tail = form.scale[:-1]
            if not np.all(tail == tail[0]):  # pairs of equal weight are what the rotation needs
                self.gs2 = None
            self.pair_scale = float(tail[0]) / _SQRT2
        self._prior_rows: dict[int, np.ndarray] = {}
        self._joint_rows: dict[int, np.ndarray] = {}
        self._z_rows: dict[int, np.ndarray] = {}
        self._paired_rows: dict[int, np.ndarray] = {}

    def __getstate__(self):
        state = self.__dict__.copy()
        for key in ("_prior_rows", "_joint_rows", "_z_rows", "_paired_rows"):
            state[key] = {}
        return state

    def first_set(self, x: np.ndarray, S: np.ndarray) -> np.ndarray:
        """The first set ``x + xi1 @ S.T``, shape ``(N1, n)``."""
        if self.gamma1 is not None:
            return _axis_points(x, self.gamma1 * S.T)
        return self.xi1.dot(S.T) + x

    def prior(self, F: np.ndarray, Q1_2: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Predicted mean and lower factor from the first set's images.

        Parameters
        ----------
        F : ndarray, shape (N1, n)
            ``fx`` at the first set (checked finite).
        Q1_2 : ndarray, shape (n, k), or None
            Square root of the process noise.

        Returns
        -------
        x : ndarray, shape (n,)
        S : ndarray, shape (n, n)

        Raises
        ------
        NonFiniteError
            The result overflowed.
        """
        N = F.shape[0]
        extra = 0 if Q1_2 is None else Q1_2.shape[1]
        rows = self._buffer(self._prior_rows, extra, (N + extra, self.n))
        x, S = transform_factor(F, self.plan1, Q1_2, rows=rows)
        if not (all_finite(S) and all_finite(x)):
            raise NonFiniteError("the predicted mean or factor is not finite (overflow)")
        return x, S

    def second_set(self, x: np.ndarray, S: np.ndarray) -> SigmaSet:
        """The redrawn set ``x + xi2 @ S.T`` (exact moments; offsets are not needed)."""
        Wm, Wc = self.plan2.Wm, self.plan2.Wc
        if self.gamma2 is not None:
            return SigmaSet(_axis_points(x, self.gamma2 * S.T), Wm, Wc, True)
        return SigmaSet(self.xi2.dot(S.T) + x, Wm, Wc, True)

    def posterior(
        self, H: np.ndarray, x: np.ndarray, S: np.ndarray, z: np.ndarray, R1_2: np.ndarray
    ) -> Posterior:
        """The measurement update by one joint QR (see the module docstring).

        Parameters
        ----------
        H : ndarray, shape (N2, m)
            ``hx`` at the second set (checked finite).
        x : ndarray, shape (n,)
        S : ndarray, shape (n, n)
            The prior the second set was drawn from.
        z : ndarray, shape (m,)
        R1_2 : ndarray, shape (m, m)

        Returns
        -------
        Posterior

        Raises
        ------
        GainError
            The innovation factor is singular (IFAIL 302).
        PosteriorFactorError
            The posterior is not finite (IFAIL 303).
        """
        N, m = H.shape
        n = self.n
        if self.gs2 is not None:
            z_pred, L = self._paired_joint(H, S, R1_2)
        else:
            M = self._buffer(self._joint_rows, m, (N + m, m + n))
            z_pred = central_rows(H, self.plan2, M[:, :m])
            M[:N, m:] = self.G2.dot(S.T)
            M[N:, m:] = 0.0
            M[N:, :m] = R1_2.T
            L = tria(M)
        Sy = L[:m, :m]
        check_gain(Sy)
        L21 = L[m:, :m]
        y = z - z_pred
        w = solve_lower(Sy, y)
        x_post = x + L21.dot(w)
        if not (all_finite(L) and all_finite(x_post)):
            raise PosteriorFactorError("the posterior mean or factor is not finite", errno=303)
        return Posterior(x_post, L[m:, m:], y, z_pred, Sy, L21, w)

    @staticmethod
    def _buffer(cache: dict, m: int, shape: tuple[int, int]) -> np.ndarray:
        rows = cache.get(m)
        if rows is None:
            rows = cache[m] = np.empty(shape, order="F")  # LAPACK's layout: QR works in place
        return rows

    def _paired_joint(self, H: np.ndarray, S: np.ndarray, R1_2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``z_pred`` and the joint factor for axis points, each ``+/-`` pair rotated by 45 degrees.

        The pair's rows ``[s e+, gs S^T_i]`` and ``[s e-, -gs S^T_i]`` (``e = h - h_0``) have the
        same Gram matrix as ``[s (e+ + e-) / sqrt2, 0]`` and ``[s (h+ - h-) / sqrt2, sqrt2 gs S^T_i]``.
        The rows without a state part are triangularised first, with ``mu`` and ``R1_2^T``, into
        ``T`` (``m x m``); then the joint QR has ``n + m`` rows instead of ``2n + 1 + m``.
        """
        n = self.n
        m = H.shape[1]
        Z = self._buffer(self._z_rows, m, (n + 1 + m, m))
        M = self._buffer(self._paired_rows, m, (n + m, m + n))
        h0 = H[0]
        E = H[1:] - h0
        mu = self.plan2.wm_tail.dot(E)
        np.add(E[:n], E[n:], out=Z[:n])
        Z[:n] *= self.pair_scale
        np.multiply(mu, self.plan2.mu_scale, out=Z[n])
        Z[n + 1 :] = R1_2.T
        T = tria(Z)
        B = M[:n, :m]
        np.subtract(H[1 : n + 1], H[n + 1 :], out=B)
        B *= self.pair_scale
        np.multiply(S.T, self.gs2 * _SQRT2, out=M[:n, m:])
        M[n:, :m] = T.T
        M[n:, m:] = 0.0
        return h0 + mu, tria(M)


def lane_for(n: int, family, generator) -> Lane | None:
    """The lane for ``family`` and ``generator`` at dimension ``n``, or None if it does not apply.

    It applies to the :class:`~squkf.generators.Redrawn` generator (not a
    subclass, which may draw differently) with families whose cached,
    read-only weights have a central form without negative rows, and whose
    second set reproduces the prior's moments.
    """
    if type(generator) is not Redrawn:
        return None
    xi1 = family.unit_sigma_points(n)
    Wm1, Wc1 = family.weights(n)
    family2 = generator.family_for(family)
    xi2 = family2.unit_sigma_points(n)
    Wm2, Wc2 = family2.weights(n)
    if not _cacheable(xi1, Wm1, Wc1, xi2, Wm2, Wc2):
        return None  # a family that may hand out other arrays next time
    plan1, plan2 = weight_plan(Wm1, Wc1), weight_plan(Wm2, Wc2)
    if not (plan1.fast and plan2.fast and _identity_moments(family2, n)):
        return None
    return Lane(n, xi1, plan1, family2)
