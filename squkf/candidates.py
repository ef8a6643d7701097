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

from .checks import as_float_array, as_matrix, as_measurements, symmetric_stack
from .errors import FleetStepError, NonFiniteError, ParameterError, ShapeError, SqukfError
from .fleet import Fleet
from .linalg import factor_covariance

__all__ = [
    "Candidates",
    "all_failed",
    "candidate_factors",
    "check_template",
    "recordings",
    "Evaluated",
    "evaluate",
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
    symmetric, bad = symmetric_stack(A, name, d)  # (the checks as arrays: a pass may hold thousands)
    for k in range(A.shape[0]):
        label = f"{name}[{k}]"
        try:
            factors[k] = factor_covariance(
                as_matrix(A[k], label, d) if bad[k] else symmetric[k], label, semidefinite=True
            )
        except SqukfError as exc:
            failures[k] = str(exc)
    return factors, failures


class Evaluated(NamedTuple):
    """What :func:`evaluate` gives: per candidate and recording (``(K, S, ...)``), or per candidate on its
    own recording (``paired``: ``(K, ...)``).

    Attributes
    ----------
    loglik : ndarray, shape (K, S) or (K,)
        Sums over the steps from ``burn_in`` (``-inf`` for a failed filter).
    y_whitened : ndarray, shape (K, S, T - burn_in, m) or (K, T - burn_in, m), or None
        The whitened innovations (NaN where nothing was measured, all NaN for a failed filter), kept with
        ``whitened=True``.
    log_det_S1_2 : ndarray, shape (K, S, T - burn_in) or (K, T - burn_in), or None
        ``log det S1_2`` (0 where nothing was measured, NaN for a failed filter), with ``y_whitened``.
    failures : dict of int to str
        Candidate -> why it (its first failing recording) failed.
    """

    loglik: np.ndarray
    y_whitened: np.ndarray | None
    log_det_S1_2: np.ndarray | None
    failures: dict[int, str]


def evaluate(
    ukf, Z: np.ndarray, c: Candidates, K: int, burn_in: int, kwargs: dict, *, paired: bool = False,
    whitened: bool = False,
) -> Evaluated:  # fmt: skip
    """K candidates on each of S recordings (``paired``: candidate ``k`` on recording ``Z[k]``), in one fleet
    pass of ``K * S`` filters (``K``), filter ``k * S + s`` candidate ``k`` on recording ``s``.

    Parameters
    ----------
    ukf : SquareRootUKF
        The template (read only).
    Z : ndarray, shape (S, T, m)
        The recordings (``paired``: one per candidate, ``S == K``).
    c : Candidates
        Of ``K`` candidates.
    K : int
        Number of candidates.
    burn_in : int
        Steps left out.
    kwargs : dict
        ``dts``, ``fx_args``, ``hx_args`` of the run.
    paired : bool
    whitened : bool
        Keep the whitened innovations and ``log det S1_2`` of each step too (what
        ``fit_noise(method="least_squares")`` takes as residuals: ``-log L = sum |w|^2 / 2 + log det S1_2``
        up to a constant).

    Returns
    -------
    Evaluated
    """
    S, T, m = Z.shape
    if paired:
        every, runs = c, Z
    else:
        every = Candidates(*(None if v is None else np.repeat(v, S, axis=0) for v in c))
        runs = np.tile(Z, (K, 1, 1))
    fleet = Fleet.from_template(ukf, runs.shape[0])
    for name, value in zip(("Q1_2", "R1_2", "x", "P1_2"), every):
        if value is not None:
            setattr(fleet, name, value)
    result = fleet.batch_filter(runs, keep=("means", "whitened") if whitened else "means", **kwargs)
    failed = {j: str(fleet.failure[j]) for j in np.flatnonzero(np.asarray(result.failed)).tolist()}
    loglik = np.asarray(result.log_likelihood)[:, burn_in:].sum(axis=1)
    w = None if result.y_whitened is None else result.y_whitened[:, burn_in:]
    log_det = None if result.log_det_S1_2 is None else result.log_det_S1_2[:, burn_in:]
    for j in failed:
        loglik[j] = -np.inf
        if w is not None and log_det is not None:
            w[j], log_det[j] = np.nan, np.nan
    if paired:
        return Evaluated(loglik, w, log_det, failed)
    failures: dict[int, str] = {}
    for j, why in failed.items():
        k = j // S
        loglik[j - j % S : j - j % S + S] = -np.inf  # the candidate fails on every recording
        if w is not None and log_det is not None:
            w[k * S : k * S + S], log_det[k * S : k * S + S] = np.nan, np.nan
        if k not in failures:
            failures[k] = f"recording {j % S}: {why}" if S > 1 else why
    return Evaluated(
        loglik.reshape(K, S),
        None if w is None else w.reshape(K, S, T - burn_in, m),
        None if log_det is None else log_det.reshape(K, S, T - burn_in),
        failures,
    )


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
