"""Candidate settings of one template filter, run in one fleet pass (what :mod:`squkf.tune` evaluates).

Each (candidate, recording) pair is one filter of a :class:`~squkf.Fleet` built
from the template (:meth:`Fleet.from_template`), filter ``k * S + s`` candidate
``k`` on recording ``s``; a candidate may set the process and measurement
noise (as lower factors) and the initial state. A candidate whose values are
not valid, or whose filter fails numerically on a recording, is a failure:
``-inf`` and its reason, and the others go on.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .checks import as_float_array, as_matrix, as_measurements
from .errors import FleetStepError, NonFiniteError, ParameterError, ShapeError, SqukfError
from .fleet import Fleet
from .linalg import factor_covariance

__all__ = [
    "Candidates",
    "all_failed",
    "candidate_factors",
    "check_template",
    "recordings",
    "run",
    "run_paired",
    "run_whitened",
    "run_whitened_paired",
]


class Candidates(NamedTuple):
    """K candidate settings; None where the template's value is kept.

    Attributes
    ----------
    Q1_2 : ndarray, shape (K, q, q), or None
    R1_2 : ndarray, shape (K, r, r), or None
        Lower factors of the noise covariances (``q``, ``r``: the noise's dimensions).
    x : ndarray, shape (K, n), or None
    P1_2 : ndarray, shape (K, n, n), or None
        Initial state and the lower factor of its covariance.
    """

    Q1_2: np.ndarray | None = None
    R1_2: np.ndarray | None = None
    x: np.ndarray | None = None
    P1_2: np.ndarray | None = None


def recordings(zs, m: int) -> tuple[np.ndarray, bool]:
    """``zs`` as ``(S, T, m)`` recordings, NaN-padded to the longest (missing measurements), and whether
    it was one recording ``(T, m)``.

    Raises
    ------
    ShapeError, NonFiniteError
        Not recordings of ``m`` components; inf; no measurement at all.
    """
    single = False
    if isinstance(zs, (list, tuple)) and zs and all(np.ndim(z) == 2 for z in zs):
        parts = [as_measurements(z, f"zs[{s}]") for s, z in enumerate(zs)]
        T = max(p.shape[0] for p in parts)
        Z = np.full((len(parts), T, m), np.nan)
        for s, p in enumerate(parts):
            if p.shape[1:] != (m,):
                raise ShapeError(f"zs[{s}] has shape {p.shape}, expected (T, dim_z={m})")
            Z[s, : p.shape[0]] = p
    else:
        Z = as_measurements(zs, "zs")
        single = Z.ndim == 2
        if single:
            Z = Z[None]
        if Z.ndim != 3 or Z.shape[2] != m or Z.shape[1] == 0:
            raise ShapeError(f"zs has shape {Z.shape}, expected (T, dim_z={m}) or (S, T, dim_z={m})")
    if np.isinf(Z).any():
        raise NonFiniteError("zs holds inf (a missing measurement is NaN)")
    if np.isnan(Z).all():
        raise NonFiniteError("zs holds no measurement: every entry is NaN")
    return Z, single


def candidate_factors(value, name: str, d: int) -> tuple[np.ndarray, dict[int, str]]:
    """Candidate covariances ``(K, d, d)`` as lower factors (zeros where one is not a covariance), and
    the candidates that are not, with the reason.

    Raises
    ------
    ShapeError
        Not ``(K, d, d)``.
    """
    A = as_float_array(value, name)
    if A.ndim != 3 or A.shape[1:] != (d, d) or A.shape[0] == 0:
        raise ShapeError(f"{name} has shape {A.shape}, expected (K, {d}, {d}): one covariance per candidate")
    factors = np.zeros_like(A)
    failures: dict[int, str] = {}
    for k in range(A.shape[0]):
        label = f"{name}[{k}]"
        try:
            factors[k] = factor_covariance(as_matrix(A[k], label, d), label, semidefinite=True)
        except SqukfError as exc:
            failures[k] = str(exc)
    return factors, failures


def run(
    ukf, Z: np.ndarray, c: Candidates, K: int, burn_in: int, kwargs: dict
) -> tuple[np.ndarray, dict[int, str]]:
    """Each candidate's log-likelihood on each recording, in one fleet pass of ``K * S`` filters.

    Parameters
    ----------
    ukf : SquareRootUKF
        The template (read only).
    Z : ndarray, shape (S, T, m)
    c : Candidates
    K : int
        Number of candidates.
    burn_in : int
        Steps left out of the sums.
    kwargs : dict
        ``dts``, ``fx_args``, ``hx_args`` of the run.

    Returns
    -------
    loglik : ndarray, shape (K, S)
        Sums over the steps from ``burn_in`` (``-inf`` for a failed filter).
    failures : dict of int to str
        Candidate -> why its first failing recording failed.
    """
    S = Z.shape[0]
    every = Candidates(*(None if v is None else np.repeat(v, S, axis=0) for v in c))
    values, failed = run_paired(ukf, np.tile(Z, (K, 1, 1)), every, burn_in, kwargs)
    loglik = values.reshape(K, S)
    failures: dict[int, str] = {}
    for j, why in failed.items():
        k = j // S
        loglik[k] = -np.inf
        if k not in failures:
            failures[k] = f"recording {j % S}: {why}" if S > 1 else why
    return loglik, failures


def run_paired(
    ukf, Z: np.ndarray, c: Candidates, burn_in: int, kwargs: dict
) -> tuple[np.ndarray, dict[int, str]]:
    """Candidate ``k`` on recording ``Z[k]``, every one in one fleet pass of ``K`` filters.

    Parameters
    ----------
    ukf : SquareRootUKF
    Z : ndarray, shape (K, T, m)
        Each candidate's own recording.
    c : Candidates
        Of ``K`` candidates.
    burn_in : int
    kwargs : dict

    Returns
    -------
    loglik : ndarray, shape (K,)
        ``-inf`` for a failed filter.
    failures : dict of int to str
    """
    result, failures = _pass(ukf, Z, c, "means", kwargs)
    loglik = np.asarray(result.log_likelihood)[:, burn_in:].sum(axis=1)
    for j in failures:
        loglik[j] = -np.inf
    return loglik, failures


def run_whitened(
    ukf, Z: np.ndarray, c: Candidates, K: int, burn_in: int, kwargs: dict
) -> tuple[np.ndarray, np.ndarray, dict[int, str]]:
    """Each candidate's whitened innovations and ``log det S1_2`` on each recording, in one fleet pass.

    The records the log-likelihood is made of (``-log L = sum |w|^2 / 2 + log det S1_2 + const``):
    what ``fit_noise(method="least_squares")`` takes as residuals.

    Parameters
    ----------
    ukf, Z, c, K, burn_in, kwargs
        As :func:`run`.

    Returns
    -------
    y_whitened : ndarray, shape (K, S, T - burn_in, m)
        NaN where nothing was measured; all NaN for a failed candidate.
    log_det_S1_2 : ndarray, shape (K, S, T - burn_in)
        0 where nothing was measured; NaN for a failed candidate.
    failures : dict of int to str
        As :func:`run`'s.
    """
    S, T, m = Z.shape
    every = Candidates(*(None if v is None else np.repeat(v, S, axis=0) for v in c))
    w, log_det, failed = run_whitened_paired(ukf, np.tile(Z, (K, 1, 1)), every, burn_in, kwargs)
    w, log_det = w.reshape(K, S, T - burn_in, m), log_det.reshape(K, S, T - burn_in)
    failures: dict[int, str] = {}
    for j, why in failed.items():
        k = j // S
        w[k], log_det[k] = np.nan, np.nan
        if k not in failures:
            failures[k] = f"recording {j % S}: {why}" if S > 1 else why
    return w, log_det, failures


def run_whitened_paired(
    ukf, Z: np.ndarray, c: Candidates, burn_in: int, kwargs: dict
) -> tuple[np.ndarray, np.ndarray, dict[int, str]]:
    """Candidate ``k``'s whitened innovations and ``log det S1_2`` on its own recording ``Z[k]``, every one
    in one fleet pass of ``K`` filters.

    Returns
    -------
    y_whitened : ndarray, shape (K, T - burn_in, m)
    log_det_S1_2 : ndarray, shape (K, T - burn_in)
        NaN for a failed filter.
    failures : dict of int to str
    """
    result, failures = _pass(ukf, Z, c, ("means", "whitened"), kwargs)
    assert result.y_whitened is not None and result.log_det_S1_2 is not None
    w, log_det = result.y_whitened[:, burn_in:], result.log_det_S1_2[:, burn_in:]
    for j in failures:
        w[j], log_det[j] = np.nan, np.nan
    return w, log_det, failures


def _pass(ukf, Z: np.ndarray, c: Candidates, keep, kwargs: dict):
    """One fleet of ``K`` filters from the template, candidate ``k`` on ``Z[k]``, run: its result and the
    filters that failed, with their reasons."""
    fleet = Fleet.from_template(ukf, Z.shape[0])
    for name, value in zip(("Q1_2", "R1_2", "x", "P1_2"), c):
        if value is not None:
            setattr(fleet, name, value)
    result = fleet.batch_filter(Z, keep=keep, **kwargs)
    failures = {j: str(fleet.failure[j]) for j in np.flatnonzero(np.asarray(result.failed)).tolist()}
    return result, failures


def all_failed(failures: dict[int, str], what: str = "candidate") -> FleetStepError:
    """The error when every candidate failed, naming the first reasons (``filters``, ``reasons``: all)."""
    order = sorted(failures)
    reasons = "; ".join(f"{what} {k}: {failures[k]}" for k in order[:5])
    return FleetStepError(f"every {what} failed ({reasons})", order, [failures[k] for k in order])


def check_template(ukf, burn_in: int, T: int) -> None:
    """Refuse a template with a gate and a ``burn_in`` that is not a count of steps before ``T``."""
    c = ukf.configuration()
    if c.gate is not None:
        raise ParameterError(
            f"the template has a gate ({c.gate!r}): a gated likelihood, which leaves out the measurements"
            " it rejects, is not the model's; tune a filter without one (ukf.gate = None)"
        )
    if isinstance(burn_in, bool) or not isinstance(burn_in, (int, np.integer)) or burn_in < 0:
        raise ParameterError(f"burn_in must be a non-negative integer, got burn_in={burn_in!r}")
    if burn_in >= T:
        raise ParameterError(f"burn_in={burn_in} leaves none of the recordings' {T} steps")
