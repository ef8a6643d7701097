"""The implementations compared: SquareRootUKF variants, filterpy's UKF, and installed peers.

Adapters for kalman-py, nrl-tracker and Stone Soup are in ``peers_external.py``.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass
class Impl:
    name: str
    make: Callable  # (scenario, fx, hx) -> filter
    step: Callable  # (filter, z) -> None
    state: Callable  # filter -> (x, P)
    vectorized: bool = False


def _filterpy_like(module_name: str, label: str) -> Impl:
    kalman = importlib.import_module(f"{module_name}.kalman")

    def make(sc, fx, hx):
        pts = kalman.MerweScaledSigmaPoints(sc.dim_x, sc.alpha, sc.beta, sc.kappa)
        f = kalman.UnscentedKalmanFilter(sc.dim_x, sc.dim_z, sc.dt, hx, fx, pts)
        f.x, f.P, f.Q, f.R = sc.x0.copy(), sc.P0.copy(), sc.Q.copy(), sc.R.copy()
        return f

    def step(f, z):
        f.predict()
        f.update(z)

    return Impl(label, make, step, lambda f: (f.x, f.P))


def _squkf(scheme: str, vectorized: bool) -> Impl:
    from squkf import MerweScaledWeights, SquareRootUKF

    def make(sc, fx, hx):
        pts = MerweScaledWeights(sc.alpha, sc.beta, sc.kappa)
        f = SquareRootUKF(sc.dim_x, sc.dim_z, sc.dt, hx, fx, pts, scheme=scheme, vectorized=vectorized)
        f.x, f.P, f.Q, f.R = sc.x0.copy(), sc.P0.copy(), sc.Q.copy(), sc.R.copy()
        return f

    def step(f, z):
        f.predict()
        f.update(z)

    def state(f):
        S = np.asarray(f.P1_2)
        return f.x, S @ S.T

    kind = "vectorised" if vectorized else "per-point"
    return Impl(f"squkf {scheme} {kind}", make, step, state, vectorized)


def implementations() -> tuple[list[Impl], list[str]]:
    """The implementations available here, and the peers skipped (not installed)."""
    from peers_external import external_impls

    impls = [_filterpy_like("filterpy", "filterpy UKF")]
    for scheme in ("redrawn", "augmented"):
        for vec in (False, True):
            impls.append(_squkf(scheme, vec))
    skipped = []
    if importlib.util.find_spec("bayesian_filters") is not None:
        impls.append(_filterpy_like("bayesian_filters", "bayesian-filters UKF"))
    else:
        skipped.append("bayesian-filters (not installed)")
    more, missing = external_impls()
    return impls + more, skipped + missing
