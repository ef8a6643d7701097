"""Noise settings judged by likelihood, many candidates in one fleet pass: ``squkf.tune``.

The building block of fitting ``Q`` and ``R`` by maximum likelihood:
:func:`log_likelihood` runs K candidate settings of a template filter on one
recording or S recordings, every (candidate, recording) pair a filter of one
:class:`~squkf.Fleet`, and returns each candidate's total innovation
log-likelihood. A candidate whose covariance is not a covariance, or whose
filter fails numerically, gets ``-inf`` and its reason; the others go on, so
an optimiser driving it (``scipy.optimize``, a grid, a population) sees a
candidate it should avoid, not an exception.

:func:`fit_noise` drives its own optimisers over it and returns a
:class:`NoiseFit` (:mod:`squkf.noise_fit`), with the parametrisations of
:mod:`squkf.parametrise` (``Fixed``, ``Scaled``, ``Diagonal``, ``Full``,
``Custom``), all importable from here.
"""

from __future__ import annotations

import numpy as np

from .candidates import Candidates, all_failed, candidate_factors, check_template, evaluate, recordings
from .errors import ShapeError
from .noise_fit import NoiseFit, fit_noise
from .parametrise import Custom, Diagonal, Fixed, Full, Scaled

__all__ = ["log_likelihood", "fit_noise", "NoiseFit", "Fixed", "Scaled", "Diagonal", "Full", "Custom"]


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
    Z, single = recordings(zs, c.dim_z)
    check_template(ukf, burn_in, Z.shape[1])
    q, r = c.fx_noise or c.dim_x, c.hx_noise or c.dim_z
    Q1_2, failures = candidate_factors(Qs, "Qs", q) if Qs is not None else (None, {})
    R1_2, failed_r = candidate_factors(Rs, "Rs", r) if Rs is not None else (None, {})
    K_q, K_r = (0 if A is None else A.shape[0] for A in (Q1_2, R1_2))
    if K_q and K_r and K_q != K_r:
        raise ShapeError(f"Qs has {K_q} candidates but Rs has {K_r}")
    K = K_q or K_r or 1
    for k, why in failed_r.items():
        failures[k] = f"{failures[k]}; {why}" if k in failures else why
    if len(failures) == K:  # (a candidate that is not a covariance runs with no noise, and is dropped)
        raise all_failed(failures)
    kwargs = {"dts": dts, "fx_args": fx_args, "hx_args": hx_args}
    loglik, _, _, failed = evaluate(ukf, Z, Candidates(Q1_2, R1_2), K, burn_in, kwargs)
    for k, why in failed.items():
        failures.setdefault(k, why)
    for k in failures:
        loglik[k] = -np.inf
    if len(failures) == K:
        raise all_failed(failures)
    return (loglik[:, 0] if single else loglik), dict(sorted(failures.items()))
