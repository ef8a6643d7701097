"""Noise settings judged by likelihood, many candidates in one fleet pass: ``squkf.tune``.

The building block of fitting ``Q`` and ``R`` by maximum likelihood:
:func:`log_likelihood` runs K candidate settings of a template filter on one
recording or S recordings, every (candidate, recording) pair a filter of one
:class:`~squkf.Fleet`, and returns each candidate's total innovation
log-likelihood. A candidate whose covariance is not a covariance, or whose
filter fails numerically, gets ``-inf`` and its reason; the others go on, so
an optimiser driving it (``scipy.optimize``, a grid, a population) sees a
candidate it should avoid, not an exception.
"""

from __future__ import annotations

import numpy as np

from .boundary.covariance import as_matrix
from .errors import FleetStepError, NonFiniteError, ParameterError, ShapeError, SqukfError
from .fleet import Fleet
from .linalg import factor_covariance
from .validate import as_float_array, as_measurements

__all__ = ["log_likelihood"]


def log_likelihood(
    ukf, zs, *, Qs=None, Rs=None, dts=None, fx_args=None, hx_args=None, burn_in: int = 0
) -> tuple[np.ndarray, dict[int, str]]:
    """Total log-likelihood of K candidate noise settings of ``ukf`` on the recordings ``zs``.

    Parameters
    ----------
    ukf : SquareRootUKF
        The template: its model, configuration, ``x``, ``P`` and, where no
        candidates are given, ``Q`` and ``R``. Read, never changed.
    zs : array_like, shape (T, dim_z) or (S, T, dim_z), or a list of S arrays (T_s, dim_z)
        One recording, or S recordings (a list may hold recordings of
        different lengths: the shorter ones are padded with NaN, which counts
        as nothing measured, as in ``batch_filter``).
    Qs : array_like, shape (K, d, d), optional
        Candidate process noises (``d`` = ``dim_x``, or ``fx_noise``);
        default the template's ``Q`` for every candidate.
    Rs : array_like, shape (K, m, m), optional
        Candidate measurement noises (``m`` = ``dim_z``, or ``hx_noise``).
    dts, fx_args, hx_args : optional
        As :meth:`squkf.Fleet.batch_filter` takes them.
    burn_in : int
        The first steps, dominated by a diffuse ``P``, left out of the sum.

    Returns
    -------
    values : ndarray, shape (K,), or (K, S) for S recordings
        Each candidate's total log-likelihood on each recording (``-inf`` for a
        failed candidate).
    failures : dict of int to str
        Failed candidate -> why (its covariance, or the first failing
        recording's numerical failure).

    Raises
    ------
    ShapeError
        ``zs``, ``Qs`` or ``Rs`` of the wrong shape; ``Qs`` and ``Rs`` of
        different lengths.
    NonFiniteError
        ``zs`` holds no measurement at all.
    ParameterError
        A gated template (a gated likelihood is not the model's), a bad
        ``burn_in``; what :meth:`Fleet.from_template` refuses.
    FleetStepError
        Every candidate failed (naming the reasons).

    Examples
    --------
    >>> import numpy as np
    >>> from squkf import MerweScaledWeights, SquareRootUKF, simulate, tune
    >>> def fx(x, dt):
    ...     return np.array([x[0] + dt * x[1], x[1]])
    >>> ukf = SquareRootUKF(2, 1, 1.0, hx=lambda x: x[:1], fx=fx, points=MerweScaledWeights())
    >>> ukf.Q, ukf.R = np.diag([0.0, 0.01]), [[1.0]]
    >>> _, zs = simulate(ukf, steps=200, runs=1, seed=4)
    >>> Rs = np.array([[[r]] for r in (0.25, 1.0, 4.0)])
    >>> values, failures = tune.log_likelihood(ukf, zs[0], Rs=Rs)
    >>> int(np.argmax(values)), failures
    (1, {})
    """
    c = ukf.configuration()
    if c.gate is not None:
        raise ParameterError(
            f"the template has a gate ({c.gate!r}): a gated likelihood, which leaves out the measurements"
            " it rejects, is not the model's; tune a filter without one (ukf.gate = None)"
        )
    if isinstance(burn_in, bool) or not isinstance(burn_in, (int, np.integer)) or burn_in < 0:
        raise ParameterError(f"burn_in must be a non-negative integer, got burn_in={burn_in!r}")
    Z, single = _recordings(zs, c.dim_z)
    S, T = Z.shape[:2]
    if burn_in >= T:
        raise ParameterError(f"burn_in={burn_in} leaves none of the recordings' {T} steps")
    q, r = c.fx_noise or c.dim_x, c.hx_noise or c.dim_z
    Q1_2, K_q, failures = _candidates(Qs, "Qs", q)
    R1_2, K_r, failed_r = _candidates(Rs, "Rs", r)
    K = K_q or K_r or 1
    if K_q and K_r and K_q != K_r:
        raise ShapeError(f"Qs has {K_q} candidates but Rs has {K_r}")
    for k, why in failed_r.items():
        failures[k] = f"{failures[k]}; {why}" if k in failures else why
    fleet = Fleet.from_template(ukf, K * S)  # filter k * S + s: candidate k on recording s
    if Q1_2 is not None:
        fleet.Q1_2 = np.repeat(Q1_2, S, axis=0) if K_q else Q1_2
    if R1_2 is not None:
        fleet.R1_2 = np.repeat(R1_2, S, axis=0) if K_r else R1_2
    if len(failures) == K:  # (a candidate that is not a covariance runs with no noise, and is dropped)
        raise _all_failed(failures)
    Zs = np.tile(Z, (K, 1, 1))
    result = fleet.batch_filter(Zs, dts=dts, keep="means", fx_args=fx_args, hx_args=hx_args)
    loglik = np.asarray(result.log_likelihood)[:, burn_in:].sum(axis=1).reshape(K, S)
    for j in np.flatnonzero(np.asarray(result.failed)).tolist():
        k = j // S
        if k not in failures:
            failures[k] = f"recording {j % S}: {fleet.failure[j]}" if S > 1 else str(fleet.failure[j])
    for k in failures:
        loglik[k] = -np.inf
    if len(failures) == K:
        raise _all_failed(failures)
    return (loglik[:, 0] if single else loglik), dict(sorted(failures.items()))


def _recordings(zs, m: int) -> tuple[np.ndarray, bool]:
    """``zs`` as ``(S, T, m)`` recordings, NaN-padded to the longest (missing measurements), and whether
    it was one recording ``(T, m)``."""
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


def _candidates(value, name: str, d: int) -> tuple[np.ndarray | None, int, dict[int, str]]:
    """Candidate covariances ``(K, d, d)`` as lower factors (zeros for a failed one), K (0: none given),
    and the candidates that are not covariances, with the reason."""
    if value is None:
        return None, 0, {}
    A = as_float_array(value, name)
    if A.ndim != 3 or A.shape[1:] != (d, d) or A.shape[0] == 0:
        raise ShapeError(f"{name} has shape {A.shape}, expected (K, {d}, {d}): one covariance per candidate")
    factors = np.zeros_like(A)
    failures: dict[int, str] = {}
    for k in range(A.shape[0]):
        try:
            label = f"{name}[{k}]"
            factors[k] = factor_covariance(as_matrix(A[k], label, d), label, semidefinite=True)
        except SqukfError as exc:
            failures[k] = str(exc)
    return factors, A.shape[0], failures


def _all_failed(failures: dict[int, str]) -> FleetStepError:
    reasons = "; ".join(f"candidate {k}: {why}" for k, why in sorted(failures.items())[:5])
    order = sorted(failures)
    return FleetStepError(f"every candidate failed ({reasons})", order, [failures[k] for k in order])
