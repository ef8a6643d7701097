"""How a covariance is fitted: small parametrisation objects for :func:`squkf.tune.fit_noise`.

Each maps an unconstrained parameter vector ``theta`` (what the optimiser
moves) to a covariance, given the template's own matrix ``M0``:

- :class:`Fixed`: no parameter, ``M = M0``;
- :class:`Scaled`: one, ``M = exp(theta) M0`` (an unknown variance behind a
  known shape, the usual ``Q_discrete_white_noise(..., var=?)``);
- :class:`Diagonal`: ``M = diag(exp(theta))``, log-variances;
- :class:`Full`: log-Cholesky, ``M = L L^T`` with ``L`` lower triangular,
  ``L_ii = exp(theta_i)`` and the rest of the lower triangle as given;
- :class:`Custom`: ``fn(theta)`` gives the matrix, or a dict that may set
  ``"Q"``, ``"R"``, ``"x"`` and ``"P"`` (the initial state fitted too).

The protocol (for a parametrisation of one's own): ``size(M0) -> int``,
``start(M0, S0) -> ndarray (p,)`` (``S0`` the template's lower factor of
``M0``), ``matrices(thetas (K, p), M0) -> ndarray (K, d, d)`` (or, as
:class:`Custom` may, a list of K dicts), ``names(label, M0) -> list of p
str``, and ``natural(theta (p,), cov (p, p), M0, z)``, the fitted
quantities on their natural scale with their interval (see
:meth:`squkf.tune.NoiseFit.intervals`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .errors import ParameterError

__all__ = ["Custom", "Diagonal", "Fixed", "Full", "Scaled"]


class Fixed:
    """The template's matrix, not fitted."""

    def size(self, M0: np.ndarray) -> int:
        return 0

    def start(self, M0: np.ndarray, S0: np.ndarray) -> np.ndarray:
        return np.zeros(0)

    def matrices(self, thetas: np.ndarray, M0: np.ndarray) -> np.ndarray:
        return np.broadcast_to(M0, (thetas.shape[0],) + M0.shape)

    def names(self, label: str, M0: np.ndarray) -> list[str]:
        return []

    def natural(self, theta, cov, M0, z) -> dict:
        return {}

    def __repr__(self) -> str:
        return "Fixed()"


class Scaled:
    """``M = s M0``, ``s = exp(theta)``: one variance scale of the template's matrix."""

    def size(self, M0: np.ndarray) -> int:
        return 1

    def start(self, M0: np.ndarray, S0: np.ndarray) -> np.ndarray:
        if not np.any(M0):
            raise ParameterError(
                "Scaled() scales the template's matrix, which is zero: give it a shape first"
            )
        return np.zeros(1)

    def matrices(self, thetas: np.ndarray, M0: np.ndarray) -> np.ndarray:
        return np.exp(thetas[:, 0])[:, None, None] * M0

    def names(self, label: str, M0: np.ndarray) -> list[str]:
        return [f"log scale of {label}"]

    def natural(self, theta, cov, M0, z) -> dict:
        half = z * np.sqrt(max(cov[0, 0], 0.0))
        t = float(theta[0])
        return {"scale": (math.exp(t), math.exp(t - half), math.exp(t + half))}

    def __repr__(self) -> str:
        return "Scaled()"


class Diagonal:
    """``M = diag(exp(theta))``: one log-variance per component (the template's off-diagonals dropped)."""

    def size(self, M0: np.ndarray) -> int:
        return M0.shape[0]

    def start(self, M0: np.ndarray, S0: np.ndarray) -> np.ndarray:
        d = np.diagonal(M0)
        if np.any(d <= 0):
            raise ParameterError(
                f"Diagonal() starts from the template's variances, but they include {d[d <= 0][0]!r}:"
                " give the template a positive diagonal"
            )
        return np.log(d)

    def matrices(self, thetas: np.ndarray, M0: np.ndarray) -> np.ndarray:
        out = np.zeros((thetas.shape[0],) + M0.shape)
        idx = np.arange(M0.shape[0])
        out[:, idx, idx] = np.exp(thetas)
        return out

    def names(self, label: str, M0: np.ndarray) -> list[str]:
        return [f"log {label}[{i}, {i}]" for i in range(M0.shape[0])]

    def natural(self, theta, cov, M0, z) -> dict:
        half = z * np.sqrt(np.maximum(np.diagonal(cov), 0.0))
        return {"variances": (np.exp(theta), np.exp(theta - half), np.exp(theta + half))}

    def __repr__(self) -> str:
        return "Diagonal()"


class Full:
    """Log-Cholesky: ``M = L L^T``, ``L_ii = exp(theta)``, the strict lower triangle as given (row by row).

    Its interval (:meth:`natural`) is the delta method's, entry by entry of ``M``.
    """

    def size(self, M0: np.ndarray) -> int:
        d = M0.shape[0]
        return d * (d + 1) // 2

    def start(self, M0: np.ndarray, S0: np.ndarray) -> np.ndarray:
        if not np.all(np.diagonal(S0) > 0):  # the template's own factor: no covariance factored again
            raise ParameterError(
                "Full() starts from the template's matrix, which is singular: it needs a variance"
            )
        rows, cols = np.tril_indices(M0.shape[0])
        theta = S0[rows, cols].copy()
        diag = rows == cols
        theta[diag] = np.log(theta[diag])
        return theta

    def matrices(self, thetas: np.ndarray, M0: np.ndarray) -> np.ndarray:
        d = M0.shape[0]
        rows, cols = np.tril_indices(d)
        L = np.zeros((thetas.shape[0], d, d))
        values = thetas.copy()
        diag = rows == cols
        values[:, diag] = np.exp(values[:, diag])
        L[:, rows, cols] = values
        return L @ np.swapaxes(L, -1, -2)

    def names(self, label: str, M0: np.ndarray) -> list[str]:
        rows, cols = np.tril_indices(M0.shape[0])
        return [f"log L{label}[{i}, {i}]" if i == j else f"L{label}[{i}, {j}]" for i, j in zip(rows, cols)]

    def natural(self, theta, cov, M0, z) -> dict:
        M = self.matrices(theta[None], M0)[0]
        h = 1e-6
        p = theta.shape[0]
        G = np.empty((p,) + M.shape)  # dM / dtheta_i, by central differences
        for i in range(p):
            e = np.zeros(p)
            e[i] = h
            G[i] = (self.matrices((theta + e)[None], M0)[0] - self.matrices((theta - e)[None], M0)[0]) / (
                2 * h
            )
        var = np.einsum("iab,ij,jab->ab", G, cov, G)
        half = z * np.sqrt(np.maximum(var, 0.0))
        return {"matrix": (M, M - half, M + half)}

    def __repr__(self) -> str:
        return "Full()"


class Custom:
    """Anything else: ``fn(theta)`` gives the covariance, or a dict setting any of ``"Q"``, ``"R"``, ``"x"``,
    ``"P"`` (the initial state and its covariance fitted too).

    Parameters
    ----------
    fn : callable
        ``fn(theta (p,)) -> ndarray (d, d)`` or ``dict``.
    theta0 : array_like, shape (p,)
        Where the fit starts.
    names : sequence of str, optional
        The parameters' names (default ``theta[i]``).
    """

    def __init__(self, fn: Callable, theta0, names=None):
        if not callable(fn):
            raise ParameterError(f"Custom needs a callable fn, got {fn!r}")
        t0 = np.asarray(theta0, dtype=float).reshape(-1)
        if t0.size == 0 or not np.all(np.isfinite(t0)):
            raise ParameterError(f"Custom's theta0 must be finite numbers, at least one, got {theta0!r}")
        self.fn, self.theta0 = fn, t0
        self._names = None if names is None else [str(n) for n in names]
        if self._names is not None and len(self._names) != t0.size:
            raise ParameterError(f"Custom has {t0.size} parameters but {len(self._names)} names")

    def size(self, M0: np.ndarray) -> int:
        return self.theta0.size

    def start(self, M0: np.ndarray, S0: np.ndarray) -> np.ndarray:
        return self.theta0.copy()

    def matrices(self, thetas: np.ndarray, M0: np.ndarray) -> list:
        return [self.fn(theta.copy()) for theta in thetas]

    def names(self, label: str, M0: np.ndarray) -> list[str]:
        return self._names or [f"theta[{i}] of {label}" for i in range(self.theta0.size)]

    def natural(self, theta, cov, M0, z) -> dict:
        half = z * np.sqrt(np.maximum(np.diagonal(cov), 0.0))
        return {"theta": (theta, theta - half, theta + half)}

    def __repr__(self) -> str:
        return f"Custom({getattr(self.fn, '__name__', self.fn)!r}, theta0={self.theta0.tolist()})"
