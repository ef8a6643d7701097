"""What a wrapping bearing costs: squkf's angle hooks against no hook, a Python hook and filterpy's.

Imported by ``run.py`` (one filter) and ``fleet.py`` (a fleet of 1,000), which write its tables into
their results (``--hooks``: only these, the rest of the results file kept). The model is a
constant-velocity target seen by a range-bearing radar (n = 4, m = 2; the bearing is ``z[1]``),
Merwe's points (alpha = 1, beta = 2, kappa = 0), the redrawn scheme. The implementations are
interleaved over repetitions in one process; times are medians and ratios are medians of the
per-repetition ratios.

- one filter: ``SquareRootUKF`` with ``residual_z=AngleResidual([1])`` (squkf's hook: data to the
  kernels), with no hook, with the same wrapping written as a user's Python function; against
  filterpy's ``UnscentedKalmanFilter`` with that Python ``residual_z`` (filterpy's own way to wrap a
  bearing). squkf vectorised and per point, filterpy per point.
- a fleet of K: ``Fleet`` with ``AngleResidual([1])``, with no hook, with the Python residual called
  per filter and point, and with the same residual as a vectorised hook (``vectorized_hooks=True``,
  called once per chunk); and with the state's ``residual_x=AngleResidual([])`` (the route a state's
  angle takes: the downdate kernel, no Python call; no component wrapped, this model having no angle).
"""

from __future__ import annotations

import math
import time

import numpy as np

DT = 1.0
Q = np.kron(np.eye(2), 0.05 * np.array([[DT**3 / 3, DT**2 / 2], [DT**2 / 2, DT]]))
R = np.diag([5.0**2, 2e-3**2])
X0 = np.array([-1500.0, 5.0, 20.0, -3.0])  # the bearing near pi: the points' bearings wrap
P0 = np.diag([30.0**2, 2.0**2, 30.0**2, 2.0**2])


def fx(X, dt):
    return np.stack([X[..., 0] + dt * X[..., 1], X[..., 1], X[..., 2] + dt * X[..., 3], X[..., 3]], axis=-1)


def hx(X):
    return np.stack([np.hypot(X[..., 0], X[..., 2]), np.arctan2(X[..., 2], X[..., 0])], axis=-1)


def fx_point(x, dt):
    x0, x1, x2, x3 = x.tolist()
    return np.array([x0 + dt * x1, x1, x2 + dt * x3, x3])


def hx_point(x):
    x0, x2 = float(x[0]), float(x[2])
    return np.array([math.hypot(x0, x2), math.atan2(x2, x0)])


def residual_z(a, b):
    """A user's wrapping residual (filterpy's way): ``a - b`` with the bearing wrapped; any leading axes."""
    y = a - b
    y[..., 1] = (y[..., 1] + np.pi) % (2 * np.pi) - np.pi
    return y


def measurements(K: int, T: int, seed: int = 0) -> np.ndarray:
    """``(K, T, 2)`` noisy range-bearing measurements of K tracks starting about ``X0``."""
    rng = np.random.default_rng(seed)
    x = X0 + rng.normal(size=(K, 4)) * np.sqrt(np.diag(P0)) * 0.3
    zs = []
    for _ in range(T):
        x = fx(x, DT) + rng.normal(size=(K, 4)) * 0.05
        z = hx(x) + rng.normal(size=(K, 2)) * np.sqrt(np.diag(R))
        z[:, 1] = (z[:, 1] + np.pi) % (2 * np.pi) - np.pi
        zs.append(z)
    return np.stack(zs, axis=1)


def _single(kind: str):
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    from squkf import MerweScaledWeights, SquareRootUKF
    from squkf.angles import AngleResidual

    if kind == "filterpy":
        f = UnscentedKalmanFilter(
            4, 2, DT, hx_point, fx_point, MerweScaledSigmaPoints(4, 1.0, 2.0, 0.0), residual_z=residual_z
        )
    else:
        vectorized = kind.endswith("vectorised")
        hook = {
            "none": {},
            "angle": {"residual_z": AngleResidual([1])},
            "python": {"residual_z": residual_z},
            "state": {"residual_x": AngleResidual([])},  # (as the fleet's "state", below)
        }
        h, f_ = (hx, fx) if vectorized else (hx_point, fx_point)
        f = SquareRootUKF(
            4, 2, DT, h, f_, MerweScaledWeights(1.0, 2.0, 0.0), vectorized=vectorized, **hook[kind.split()[0]]
        )
    f.x, f.P, f.Q, f.R = X0.copy(), P0.copy(), Q, R
    return f


SINGLE = (
    "angle vectorised",
    "none vectorised",
    "python vectorised",
    "angle per-point",
    "none per-point",
    "filterpy",
    "state vectorised",
)
SINGLE_LABELS = {
    "angle vectorised": "squkf, AngleResidual([1]), vectorised",
    "none vectorised": "squkf, no hook, vectorised",
    "python vectorised": "squkf, the Python residual_z, vectorised",
    "angle per-point": "squkf, AngleResidual([1]), per point",
    "none per-point": "squkf, no hook, per point",
    "filterpy": "filterpy UKF, the Python residual_z",
    "state vectorised": "squkf, residual_x=AngleResidual([]) (the state's hook as data), vectorised",
}


def single(steps: int, reps: int) -> dict:
    """Microseconds per predict + update of one filter, and each ratio to filterpy's time."""
    zs = measurements(1, steps + 5)[0]
    times: dict[str, list[float]] = {k: [] for k in SINGLE}
    for r in range(reps + 1):
        for kind in SINGLE[r % len(SINGLE) :] + SINGLE[: r % len(SINGLE)]:
            f = _single(kind)
            for z in zs[:5]:  # compiled or loaded, warm
                f.predict()
                f.update(z)
            t0 = time.perf_counter()
            for z in zs[5:]:
                f.predict()
                f.update(z)
            if r:  # the first round warms every implementation
                times[kind].append((time.perf_counter() - t0) / steps)
    ref = np.array(times["filterpy"])
    return {
        k: {"us": 1e6 * float(np.median(v)), "ratio": float(np.median(np.array(v) / ref))}
        for k, v in times.items()
    }


FLEET = ("angle", "none", "python", "vectorised", "state")
FLEET_LABELS = {
    "angle": "AngleResidual([1])",
    "state": "no hook on z; residual_x=AngleResidual([]) (the state's hook as data: the downdate form)",
    "none": "no hook",
    "python": "the Python residual_z, per filter and point",
    "vectorised": "the Python residual_z, vectorized_hooks=True (once per chunk)",
}


def _fleet(kind: str, K: int):
    from squkf import Fleet, MerweScaledWeights
    from squkf.angles import AngleResidual

    hook = {
        "none": {},
        "angle": {"residual_z": AngleResidual([1])},
        "python": {"residual_z": residual_z},
        "vectorised": {"residual_z": residual_z, "vectorized_hooks": True},
        # the state's hook: no component of this model is an angle (its deviations pass pi), so none is
        # wrapped; the route is the one an angle takes (the downdate kernel, the state's kinds read)
        "state": {"residual_x": AngleResidual([])},
    }[kind]
    f = Fleet(K, 4, 2, DT, hx, fx, MerweScaledWeights(1.0, 2.0, 0.0), **hook)
    f.x, f.P, f.Q, f.R = X0, P0, Q, R
    return f


def fleet(K: int, steps: int, reps: int, python_steps: int = 2) -> dict:
    """Microseconds per filter-step of a fleet of K, and each ratio to the fleet with no hook."""
    zs = measurements(K, steps + 2)
    times: dict[str, list[float]] = {k: [] for k in FLEET}
    for r in range(reps + 1):
        for kind in FLEET[r % len(FLEET) :] + FLEET[: r % len(FLEET)]:
            f = _fleet(kind, K)
            for t in range(2):
                f.predict()
                f.update(zs[:, t])
            n = python_steps if kind == "python" else steps  # (the Python hooks' step takes seconds)
            t0 = time.perf_counter()
            for t in range(2, 2 + n):
                f.predict()
                f.update(zs[:, t])
            if r:
                times[kind].append((time.perf_counter() - t0) / (n * K))
    ref = np.array(times["none"])
    return {
        k: {"us": 1e6 * float(np.median(v)), "ratio": float(np.median(np.array(v) / ref))}
        for k, v in times.items()
    }


def single_section(res: dict, steps: int, reps: int) -> list[str]:
    return _table(
        "Angle hooks: one filter with a wrapping bearing (n = 4, range-bearing radar)",
        f"`hooks_bench.single`: {steps} steps x {reps} interleaved repetitions, one process; a "
        "filter's `residual_z=AngleResidual([1])` is data to the kernels (no Python call per point). "
        "Target (issue 36): squkf with AngleResidual at most 0.5x filterpy's time with its own "
        "wrapping residual_z.",
        ("implementation", "us/step", "ratio to filterpy"),
        {SINGLE_LABELS[k]: (f"{r['us']:.1f}", r["ratio"]) for k, r in res.items()},
    )


def fleet_section(res: dict, K: int, steps: int, reps: int) -> list[str]:
    return _table(
        f"Angle hooks: a fleet of {K:,} with a wrapping bearing (n = 4, range-bearing radar)",
        f"`hooks_bench.fleet`: {steps} steps x {reps} interleaved repetitions, one process (the "
        "per-point Python hook fewer steps). Target (issue 36): with AngleResidual at most 1.3x the "
        "time of the same fleet with no hook.",
        ("hook", "us/filter-step", "ratio to no hook"),
        {FLEET_LABELS[k]: (f"{r['us']:.3g}", r["ratio"]) for k, r in res.items()},
    )


def _table(title: str, how: str, columns: tuple[str, str, str], rows: dict) -> list[str]:
    """A markdown section: its title, how it was measured, and a row per implementation (time, ratio)."""
    lines = [f"## {title}", "", how, "", f"| {' | '.join(columns)} |", "|---|---|---|"]
    lines += [f"| {label} | {us} | {ratio:.2f} |" for label, (us, ratio) in rows.items()]
    return lines + [""]
