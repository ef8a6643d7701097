"""Where a fleet's filter-step goes: the kernels, the model functions, the rest (squkf's Python, numpy).

    python benchmarks/fleet_profile.py [--K 10000] [--steps 30] [--reps 5]

The fleet of ``benchmarks/fleet.py``'s first model shape (n = 4, constant velocity, range-bearing), one
thread, in steady state. Each entry of the kernel table and each model call is wrapped in a timer (the
table is the engine's seam, so every kernel call of the step is timed); the rest is the whole step
less those. Microseconds per filter-step, the fastest of ``--reps`` runs of ``--steps`` steps.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import squkf
from squkf.kernels import table


def fx(X, dt):
    return np.stack([X[..., 0] + dt * X[..., 1], X[..., 1], X[..., 2] + dt * X[..., 3], X[..., 3]], -1)


def hx(X):
    return np.stack([np.hypot(X[..., 0], X[..., 2]), np.arctan2(X[..., 2], X[..., 0])], -1)


def split(K: int, steps: int, reps: int) -> dict[str, float]:
    """Microseconds per filter-step in the kernels, the model functions, the rest and the whole step."""
    spent = {"kernels": 0.0, "model": 0.0}

    def timed(fn, key):
        def call(*args, **kwargs):
            t = time.perf_counter()
            out = fn(*args, **kwargs)
            spent[key] += time.perf_counter() - t
            return out

        return call

    x0 = np.array([1000.0, 5.0, 1500.0, -3.0])
    # the timed table installed before the fleet is built: its route takes the installed table then
    real = table.KERNELS
    table.KERNELS = table.KernelTable(*(timed(k, "kernels") for k in real))
    best: dict[str, float] | None = None
    try:
        fleet = squkf.Fleet(K, 4, 2, 1.0, timed(hx, "model"), timed(fx, "model"), squkf.MerweScaledWeights())
        fleet.x, fleet.P, fleet.Q, fleet.R = (
            x0,
            np.diag([900.0, 4, 900, 4]),
            0.01 * np.eye(4),
            np.diag([25.0, 4e-6]),
        )
        z = np.broadcast_to(hx(x0), (K, 2)).copy()
        for _ in range(3):  # the kernels loaded, the buffers made
            fleet.predict()
            fleet.update(z)
        for _ in range(reps):
            spent["kernels"] = spent["model"] = 0.0
            t = time.perf_counter()
            for _ in range(steps):
                fleet.predict()
                fleet.update(z)
            whole = time.perf_counter() - t
            row = {key: value / (K * steps) * 1e6 for key, value in spent.items()}
            row["whole"] = whole / (K * steps) * 1e6
            if best is None or row["whole"] < best["whole"]:
                best = row
    finally:
        table.KERNELS = real
    assert best is not None
    best["rest"] = best["whole"] - best["kernels"] - best["model"]
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--K", type=int, default=10_000)
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--reps", type=int, default=5)
    args = parser.parse_args()
    row = split(args.K, args.steps, args.reps)
    print(f"K = {args.K:,}, n = 4, one thread: microseconds per filter-step")
    print("| kernels | model functions | the rest (squkf's Python and numpy) | whole step |")
    print("|---|---|---|---|")
    print(f"| {row['kernels']:.3f} | {row['model']:.3f} | {row['rest']:.3f} | {row['whole']:.3f} |")


if __name__ == "__main__":
    main()
