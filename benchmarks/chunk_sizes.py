"""A fleet's time per filter-step against its chunk size, on one thread and on two, in one process.

    python benchmarks/chunk_sizes.py                      # K = 10^4 and 10^5, chunks 1024 .. 4096
    python benchmarks/chunk_sizes.py --Ks 100000 --sizes 2048 4096 --reps 9
    python benchmarks/chunk_sizes.py --model n10 --Ks 100000 --sizes 512 1024 2048 --threads 1

The basis of ``squkf.stacks.default_chunk`` (2048 filters a chunk on one
thread, 4096 on more, fewer for a model with large points: ``CHUNK_BYTES``).
The model is ``fleet.py``'s n = 4 constant velocity with range and bearing,
or (``--model n10``) its five oscillators with cubic sensors. Every
(threads, chunk) pair is run once per repetition, in turn, and the process is
pinned to two CPUs with BLAS on one thread. The speed-up column divides the
time on the first thread count (one by default) with chunks of 2048 by each
run's time, repetition by repetition (median), so a machine that slows down
for a while slows both alike.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fleet import ConstantVelocity, Oscillators, points, simulate  # noqa: E402

from squkf import Fleet, set_num_threads  # noqa: E402


def seconds_per_filter_step(model, zs: np.ndarray, threads: int, chunk: int) -> float:
    """One run of T steps of a fresh fleet: seconds per filter-step."""
    K, T = zs.shape[:2]
    set_num_threads(threads)
    try:
        fleet = Fleet(K, model.n, model.m, model.dt, model.hx, model.fx, points(), chunk=chunk)
        fleet.x, fleet.P, fleet.Q, fleet.R = model.x0, model.P0, model.Q, model.R
        start = time.perf_counter()
        for t in range(T):
            fleet.predict()
            fleet.update(zs[:, t])
        return (time.perf_counter() - start) / (K * T)
    finally:
        set_num_threads(1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--Ks", type=int, nargs="+", default=[10_000, 100_000])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1024, 2048, 3072, 4096])
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--model", choices=("n4", "n10"), default="n4")
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="thread counts (default 1 2)")
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity") and len(os.sched_getaffinity(0)) > 2:
        os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:2])
    model = ConstantVelocity() if args.model == "n4" else Oscillators()
    command = " ".join(["python benchmarks/chunk_sizes.py", *sys.argv[1:]])
    print(f"Produced by `{command}`; model {args.model}, {args.steps} steps, {args.reps} repetitions.\n")
    base_size = 2048 if 2048 in args.sizes else args.sizes[0]
    base_run = f"{args.threads[0]} thread(s), chunk {base_size}"
    print(f"| K | threads | chunk | µs per filter-step | speed-up over {base_run} |")
    print("|---|---|---|---|---|")
    for K in args.Ks:
        _, zs = simulate(model, K, args.steps, 0)
        runs = [(threads, size) for threads in args.threads for size in args.sizes]
        for run in runs:  # untimed: kernels loaded, pool started
            seconds_per_filter_step(model, zs[:, :1], *run)
        times: dict[tuple[int, int], list[float]] = {run: [] for run in runs}
        for r in range(args.reps):
            for run in runs[r % len(runs) :] + runs[: r % len(runs)]:
                times[run].append(seconds_per_filter_step(model, zs, *run))
        base = np.array(times[(args.threads[0], base_size)])
        for threads, size in runs:
            t = np.array(times[(threads, size)])
            print(f"| {K} | {threads} | {size} | {np.median(t) * 1e6:.3f} | {np.median(base / t):.3f} |")


if __name__ == "__main__":
    main()
