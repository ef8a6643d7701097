"""The records handed out: a fleet's run (:class:`FleetResult`), and those formed from one filter's update.

Also the arrays a fleet's run fills and the error of its failing filters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..errors import FleetStepError
from ..linalg import solve_lower

__all__ = [
    "FleetResult",
    "Records",
    "embed",
    "failures_error",
    "innovation_inverse",
    "new_records",
    "log_det",
    "whitened",
]


@dataclass
class FleetResult:
    """What :meth:`Fleet.batch_filter` returns.

    Attributes
    ----------
    means : ndarray, shape (K, T, n), or None
        Posterior means (None with ``keep="final"``).
    P1_2s : ndarray, shape (K, T, n, n), or None
        Posterior lower factors (only with ``keep="all"``).
    variances : ndarray, shape (K, T, n), or None
        The diagonals of the posterior covariances (with ``keep="all"`` or ``"diagonals"``).
    log_likelihood : ndarray, shape (K, T), or (K,) with ``keep="final"``
        Of each step's measurement (0 where a filter had no measurement or had
        failed); with ``keep="final"`` their sum over the run.
    failed : ndarray of bool, shape (K,)
        Filters flagged by the end of the run (their later entries repeat their last good state).
    x, P1_2 : ndarray, shapes (K, n) and (K, n, n)
        The final state.
    rejected : ndarray, shape (K, T, m) of bool, or (K, m) of int with ``keep="final"``
        The measurement components each filter's gate rejected at each step
        (with ``keep="final"``: how many steps each component was rejected).
        All False (zero) without a gate.
    nis : ndarray, shape (K, T), or None with ``keep="final"``
        Each step's normalised innovation squared (0 where a filter had no
        measurement or had failed).
    y_whitened : ndarray, shape (K, T, m), or None
        Each step's whitened innovation ``S1_2^-1 y`` (NaN where a component was
        not measured or a filter not updated), kept when ``keep`` names
        ``"whitened"``: with ``log_det_S1_2`` the log-likelihood as residuals
        (what :func:`squkf.tune.fit_noise` reads).
    log_det_S1_2 : ndarray, shape (K, T), or None
        Each step's ``log det S1_2`` of the measured block (0 where none), kept
        with ``y_whitened``.
    """

    means: np.ndarray | None
    P1_2s: np.ndarray | None
    variances: np.ndarray | None
    log_likelihood: np.ndarray
    failed: np.ndarray
    x: np.ndarray
    P1_2: np.ndarray
    rejected: np.ndarray | None = None
    nis: np.ndarray | None = None
    y_whitened: np.ndarray | None = None
    log_det_S1_2: np.ndarray | None = None


class Records(NamedTuple):
    """The arrays a fleet's batch run fills, step by step (None: not kept)."""

    means: np.ndarray | None
    factors: np.ndarray | None
    variances: np.ndarray | None
    loglik: np.ndarray
    rejected: np.ndarray
    nis: np.ndarray | None
    y_whitened: np.ndarray | None
    log_det: np.ndarray | None

    def keep(self, t: int, update) -> None:
        """Keep step ``t``'s update: its estimates ``x (K, n)``, ``S (K, n, n)`` and its records.

        ``update`` is the engine's record of the step (:class:`squkf.engine.Update`, a block of K).
        With ``keep="final"`` (no ``nis``), the log-likelihoods and rejections are summed over the run.
        """
        x, S = update.x, update.S
        if self.nis is None:
            self.loglik[...] += update.log_likelihood
            self.rejected[...] += update.rejected
        else:
            self.loglik[:, t], self.rejected[:, t], self.nis[:, t] = (
                update.log_likelihood, update.rejected, update.nis,
            )  # fmt: skip
        if self.y_whitened is not None and self.log_det is not None:
            self.y_whitened[:, t], self.log_det[:, t] = update.w, update.log_det_S1_2
        if self.means is not None:
            self.means[:, t] = x
        if self.factors is not None:
            self.factors[:, t] = S
        if self.variances is not None:
            self.variances[:, t] = np.einsum("kij,kij->ki", S, S)

    def so_far(self, t: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The means ``(K, t, n)`` and factors ``(K, t, n, n)`` before step ``t`` (copies, or None)."""
        return (
            None if self.means is None else self.means[:, :t].copy(),
            None if self.factors is None else self.factors[:, :t].copy(),
        )


def new_records(keep: str, K: int, T: int, n: int, m: int, whitened: bool = False) -> Records:
    """The arrays of a run of ``T`` steps of ``K`` filters that ``keep`` asks for.

    Parameters
    ----------
    keep : {"all", "diagonals", "means", "final"}
    K, T, n, m : int
        Filters, steps, state and measurement sizes.
    whitened : bool
        Keep the whitened innovations ``(K, T, m)`` and ``log det S1_2`` ``(K, T)`` too.

    Returns
    -------
    Records
        ``means (K, T, n)``, ``factors (K, T, n, n)``, ``variances (K, T, n)``,
        ``loglik (K, T)`` (``(K,)`` with ``"final"``), ``rejected (K, T, m)``
        of bool (``(K, m)`` counts with ``"final"``), ``nis (K, T)``.
    """
    means = None if keep == "final" else np.empty((K, T, n))
    factors = np.empty((K, T, n, n)) if keep == "all" else None
    variances = np.empty((K, T, n)) if keep in ("all", "diagonals") else None
    loglik = np.zeros((K, T)) if keep != "final" else np.zeros(K)
    rejected = np.zeros((K, T, m), dtype=bool) if keep != "final" else np.zeros((K, m), dtype=np.int64)
    nis = np.zeros((K, T)) if keep != "final" else None
    w = np.empty((K, T, m)) if whitened else None
    log_det = np.empty((K, T)) if whitened else None
    return Records(means, factors, variances, loglik, rejected, nis, w, log_det)


def failures_error(fails: dict[int, str], during: str = "") -> FleetStepError:
    """The error of a step (or a smoothing run) in which the filters ``fails`` failed numerically.

    Parameters
    ----------
    fails : dict
        Filter index -> the reason it failed.
    during : str
        Appended to "failed numerically" (``" while smoothing"``).

    Returns
    -------
    FleetStepError
        Naming the first five filters; ``filters`` and ``reasons`` hold all.
    """
    ks = sorted(fails)
    return FleetStepError(
        f"{len(ks)} filter(s) failed numerically{during}: "
        + "; ".join(f"filter {k}: {fails[k]}" for k in ks[:5])
        + (" ..." if len(ks) > 5 else ""),
        ks,
        [fails[k] for k in ks],
    )


def embed(block: np.ndarray, observed: np.ndarray | None, fill: float) -> np.ndarray:
    """A one-filter ``(m, m)`` record of the last update from its observed block (``fill`` elsewhere).

    Parameters
    ----------
    block : ndarray, shape (o, o)
        Over the measured components.
    observed : ndarray of bool, shape (m,), or None
        The measured components (None: all, ``o == m``).
    fill : float

    Returns
    -------
    ndarray, shape (m, m)
        A new array.
    """
    if observed is None:
        return block.copy()
    out = np.full((observed.shape[0], observed.shape[0]), fill)
    out[np.ix_(observed, observed)] = block
    return out


def innovation_inverse(Sy: np.ndarray, observed: np.ndarray | None) -> np.ndarray:
    """``S^-1`` of one filter's last update from its innovation factor, by triangular solves.

    Parameters
    ----------
    Sy : ndarray, shape (o, o)
        The innovation factor over the measured components.
    observed : ndarray of bool, shape (m,), or None

    Returns
    -------
    ndarray, shape (m, m)
        NaN outside the measured block; all NaN-embedded zeros for a singular factor.
    """
    m = Sy.shape[0]
    if not np.all(Sy.diagonal() != 0):
        return embed(np.zeros((m, m)), observed, np.nan)
    W = solve_lower(Sy, np.eye(m))
    return embed(W.T @ W, observed, np.nan)


def whitened(w: np.ndarray, observed: np.ndarray | None, m: int) -> np.ndarray:
    """The whitened innovations ``Sy^-1 y`` of an update in the measured components' places.

    Parameters
    ----------
    w : ndarray, shape (B, o)
        Over the ``o`` measured components.
    observed : ndarray of bool, shape (m,), or None
        The measured components (None: all).
    m : int

    Returns
    -------
    ndarray, shape (B, m)
        NaN where a component was not measured (a new array).
    """
    if observed is None:
        return w.copy()
    full = np.full((w.shape[0], m), np.nan)
    full[:, observed] = w
    return full


def log_det(Sy: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``log det Sy`` of each innovation factor (over its measured block: 0 for an empty one).

    Parameters
    ----------
    Sy : ndarray, shape (B, o, o)
        Triangular.
    out : ndarray, shape (B,), optional
        Where to write it.

    Returns
    -------
    ndarray, shape (B,)
        (``-inf`` for a singular factor: a failed filter's, which its caller replaces.)
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(np.abs(np.diagonal(Sy, axis1=1, axis2=2))).sum(axis=1, out=out)
