"""A large filter's step, the BLAS at its default threads against ``OPENBLAS_NUM_THREADS=1``, a core busy.

    python benchmarks/blas_threads.py              # results in benchmarks/results/blas_threads.md
    python benchmarks/blas_threads.py --quick      # a few seconds, to --out only
    python benchmarks/blas_threads.py --out DIR --reps 7 --steps 200

squkf holds the BLAS to one thread while a filter of ``squkf.blas.MIN_DIM``
(65) variables or more runs its own numerics (``squkf/blas.py``), through
threadpoolctl, a runtime dependency. This measures what a user sees with
nothing set: a step at n = 81 with the BLAS libraries at their default thread
count, against the same step in a process started with
``OPENBLAS_NUM_THREADS=1`` (the BLAS on one thread for the whole process), on
a machine where another process keeps one core busy. A third arm, the default
threads with the hold switched off (``squkf.blas.MIN_DIM = None``), shows what
the hold saves (what a squkf without threadpoolctl did).

Each arm is a fresh child process (the ``*_NUM_THREADS`` variables are read when
numpy loads its BLAS, so they cannot change inside one process); the children
run interleaved, arm after arm, ``--reps`` times, while one busy-looping process
runs beside them. A child imports squkf (its kernels from the cache: run it
once first, or let the warm-up compile), builds a ``SquareRootUKF`` on
Lorenz-96 with n = 81 (Merwe's points, alpha = 0.5, kappa = 3 - n, every
other component measured, a vectorised ``fx``, so the step is mostly squkf's
numerics), runs warm-up steps and then times ``--steps`` predict + update
pairs one by one (at most ``--budget`` seconds). Its time is the median step;
an arm's figure is the median over its children, and the ratio of the
default arm to the one-thread arm is taken per repetition, then its median.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from machine import cpu_name  # noqa: E402

THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")
TARGET = 1.3  # the default threads' step within 1.3x of the one-thread step (issue 35)
N = 81

#: What a child runs: argv[1:] = steps, warm-up steps, budget s, "hold" or "nohold"; prints one JSON line.
CHILD = """
import json, statistics, sys, time
sys.path.insert(0, {here!r})
import numpy as np
import threadpoolctl
from models import Lorenz96
from squkf import MerweScaledWeights, SquareRootUKF, blas

steps, warm, budget, hold = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
if hold == "nohold":
    blas.MIN_DIM = None
sc = Lorenz96({n})
f = SquareRootUKF(
    sc.dim_x, sc.dim_z, sc.dt, sc.hx_vec, sc.fx_vec, MerweScaledWeights(sc.alpha, sc.beta, sc.kappa),
    vectorized=True,
)
f.x, f.P, f.Q, f.R = sc.x0.copy(), sc.P0.copy(), sc.Q.copy(), sc.R.copy()
_, zs = sc.simulate(steps + warm, seed=1)
for z in zs[:warm]:
    f.predict()
    f.update(z)
times = []
start = time.perf_counter()
for z in zs[warm:]:
    t = time.perf_counter()
    f.predict()
    f.update(z)
    times.append(time.perf_counter() - t)
    if t - start > budget:
        break
libs = threadpoolctl.ThreadpoolController().select(user_api="blas").lib_controllers
print(json.dumps({{
    "median_ms": 1e3 * statistics.median(times),
    "mean_ms": 1e3 * statistics.fmean(times),
    "max_ms": 1e3 * max(times),
    "steps": len(times),
    "blas": [[lib.internal_api, lib.version, lib.get_num_threads()] for lib in libs],
    "numpy": np.__version__,
}}))
"""

#: arm -> (extra environment, the child's hold argument)
ARMS = {
    "default threads (squkf's hold on)": ({}, "hold"),
    "OPENBLAS_NUM_THREADS=1": ({"OPENBLAS_NUM_THREADS": "1"}, "hold"),
    "default threads, hold off (MIN_DIM = None)": ({}, "nohold"),
}
DEFAULT, ONE, NO_HOLD = ARMS


def busy(stop: float) -> None:
    """Keep one core busy until ``time.time()`` passes ``stop`` (the other process on the machine)."""
    x = 0
    while time.time() < stop:
        for _ in range(100_000):
            x += 1


def run_child(arm: str, steps: int, warm: int, budget: float) -> dict:
    extra, hold = ARMS[arm]
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARS}
    env.update(extra, PYTHONPATH=os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]))
    env.setdefault("SQUKF_QUIET_COMPILE", "1")
    code = CHILD.format(here=str(HERE), n=N)
    out = subprocess.run(
        [sys.executable, "-c", code, str(steps), str(warm), str(budget), hold],
        env=env,
        capture_output=True,
        text=True,
        check=True,
        timeout=600,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a smoke test (not written to results/)")
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--warm", type=int, default=10)
    ap.add_argument("--budget", type=float, default=8.0, help="seconds of timed steps per child at most")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.quick:
        args.reps, args.steps, args.warm, args.budget = 1, 10, 2, 2.0
    out = args.out or (None if args.quick else HERE / "results")
    if out is None:
        ap.error("--quick writes nowhere by default: give --out")

    run_child(ONE, 2, 1, 1.0)  # compiles the kernels into the cache if they are not there yet
    stop = time.time() + 3600
    load = multiprocessing.get_context("spawn").Process(target=busy, args=(stop,), daemon=True)
    load.start()
    got: dict[str, list[dict]] = {arm: [] for arm in ARMS}
    try:
        time.sleep(0.5)
        for rep in range(args.reps):
            for arm in ARMS:
                got[arm].append(run_child(arm, args.steps, args.warm, args.budget))
                print(f"rep {rep + 1}/{args.reps} {arm}: {got[arm][-1]['median_ms']:.2f} ms", flush=True)
    finally:
        load.terminate()
        load.join()

    med = {arm: statistics.median(r["median_ms"] for r in runs) for arm, runs in got.items()}
    ratios = [d["median_ms"] / o["median_ms"] for d, o in zip(got[DEFAULT], got[ONE])]
    ratio = statistics.median(ratios)
    freed = [h["median_ms"] / o["median_ms"] for h, o in zip(got[NO_HOLD], got[ONE])]
    mean_of = {arm: statistics.fmean(r["mean_ms"] for r in runs) for arm, runs in got.items()}
    blas_default = got[DEFAULT][0]["blas"]
    blas_one = got[ONE][0]["blas"]
    lines = [
        "# A large filter's step: the BLAS at its default threads against one thread, one core busy",
        "",
        f"Produced by `python benchmarks/blas_threads.py{' --quick' if args.quick else ''}`"
        f" (--reps {args.reps} --steps {args.steps}); machine: {cpu_name()}, {os.cpu_count()} cores; "
        f"Python {platform.python_version()}, numpy {got[DEFAULT][0]['numpy']}; "
        f"BLAS libraries (api, version, threads) with nothing set: {blas_default}; "
        f"with `OPENBLAS_NUM_THREADS=1`: {blas_one}.",
        "",
        f"Lorenz-96, n = {N}, Merwe's points, vectorised `fx`, one `predict` + `update` per step, with "
        "another process keeping one core busy. Each row's children ran interleaved with the others' "
        "(see the docstring of `benchmarks/blas_threads.py`); ms per step, the median step of each child, "
        "then the median over children.",
        "",
        "| arm | median ms per step | children's medians | children's means | slowest step ms |",
        "|---|---|---|---|---|",
    ]
    for arm, runs in got.items():
        medians = ", ".join(f"{r['median_ms']:.2f}" for r in runs)
        means = ", ".join(f"{r['mean_ms']:.2f}" for r in runs)
        slowest = max(r["max_ms"] for r in runs)
        lines.append(f"| {arm} | {med[arm]:.2f} | {medians} | {means} | {slowest:.1f} |")
    met = "met" if ratio <= TARGET else "**not met**"
    lines += [
        "",
        "## Target",
        "",
        "| target | measured | met |",
        "|---|---|---|",
        f"| a step at n = {N} with default threads within {TARGET}x of its time with "
        f"`OPENBLAS_NUM_THREADS=1` (one core busy) | {ratio:.2f}x (per repetition: "
        f"{', '.join(f'{r:.2f}' for r in ratios)}) | {met} |",
        "",
        f"The mean step (slow steps included, when the busy core and the machine's other work delay one), "
        f"over all children: {mean_of[DEFAULT]:.2f} ms with default threads, {mean_of[ONE]:.2f} ms with "
        f"one thread ({mean_of[DEFAULT] / mean_of[ONE]:.2f}x).",
        "",
        f"Without the hold (`squkf.blas.MIN_DIM = None`, what a squkf without threadpoolctl did) the same "
        f"step took {statistics.median(freed):.2f}x the one-thread time (median; per repetition: "
        f"{', '.join(f'{r:.2f}' for r in freed)}), and its mean step {mean_of[NO_HOLD]:.2f} ms "
        f"({mean_of[NO_HOLD] / mean_of[ONE]:.1f}x the one-thread mean).",
        "",
    ]
    out.mkdir(parents=True, exist_ok=True)
    (out / "blas_threads.md").write_text("\n".join(lines), encoding="utf-8")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
