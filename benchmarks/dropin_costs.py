"""What a filterpy program pays for habits around the step: ``Saver.save()``, ``copy.deepcopy``, a new filter.

    python benchmarks/dropin_costs.py --out benchmarks/results    # about half a minute
    python benchmarks/dropin_costs.py --quick --out DIR           # a few seconds

Side by side in one process, filterpy 2.0.0's ``UnscentedKalmanFilter`` and
``squkf.SquareRootUKF`` on the same model (n = 3, one measurement, filterpy's
``MerweScaledSigmaPoints``), each figure the median over interleaved rounds:

- ``Saver.save()`` after a step (filterpy's ``Saver``, whose ``save`` reads
  every property and deep-copies the ``__dict__``);
- ``copy.deepcopy(ukf)`` (what IMM programs call);
- building a filter and its first predict and update, as a program that
  builds a filter per request does: the mean of builds 2 to 40 in one process.

Targets (issue 35, item 10): ``Saver.save()`` and a build with its first step at
most 2x filterpy's time. The ratios are what count: the machine is shared.
Written to ``dropin_costs.md`` in ``--out``.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from filterpy.common import Saver
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from squkf import SquareRootUKF

HERE = Path(__file__).resolve().parent
TARGET = 2.0


def fx(x, dt):
    return np.array([x[0] + dt * x[1], x[1] + dt * x[2], 0.95 * x[2]])


def hx(x):
    return np.array([np.hypot(x[0], 1.0)])


def build(cls):
    """A filter as a program builds one: its points, noise and first state assigned."""
    f = cls(3, 1, 0.5, hx, fx, MerweScaledSigmaPoints(3, 0.3, 2.0, 0.0))
    f.x = np.array([1.0, 0.2, 0.0])
    f.P *= 0.5
    f.Q = np.diag([1e-3, 1e-3, 1e-2])
    f.R = np.array([[0.04]])
    return f


def first_step(f) -> None:
    f.predict()
    f.update(np.array([1.5]))


def time_each(fn, reps: int) -> float:
    """Mean seconds of ``fn()`` over ``reps`` calls."""
    t0 = time.perf_counter()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - t0) / reps


def builds(cls, count: int) -> float:
    """Mean seconds of building a filter and its first step, builds 2 to ``count`` (the first left out)."""
    times = []
    for _ in range(count):
        t0 = time.perf_counter()
        first_step(build(cls))
        times.append(time.perf_counter() - t0)
    return statistics.fmean(times[1:])


def measure(rounds: int, reps: int, count: int) -> dict[str, dict[str, float]]:
    """Median seconds per figure and library, over ``rounds`` interleaved rounds."""
    libs = {"filterpy": UnscentedKalmanFilter, "squkf": SquareRootUKF}
    filters = {}
    savers = {}
    for name, cls in libs.items():
        f = build(cls)
        first_step(f)
        filters[name], savers[name] = f, Saver(f)
        first_step(build(cls))  # the first use compiles (squkf) and imports: not measured
    samples: dict[str, dict[str, list[float]]] = {
        what: {name: [] for name in libs} for what in ("save", "deepcopy", "build")
    }
    for _ in range(rounds):
        for name, cls in libs.items():
            samples["save"][name].append(time_each(savers[name].save, reps))
            samples["deepcopy"][name].append(time_each(lambda f=filters[name]: copy.deepcopy(f), reps))
            samples["build"][name].append(builds(cls, count))
    return {what: {name: statistics.median(v) for name, v in d.items()} for what, d in samples.items()}


def report(figures: dict[str, dict[str, float]], quick: bool) -> str:
    labels = {
        "save": "`Saver.save()` after a step",
        "deepcopy": "`copy.deepcopy(ukf)`",
        "build": "a new filter and its first step (mean of builds 2-40)",
    }
    lines = [
        "# What filterpy's habits around the step cost (n = 3)",
        "",
        f"`python benchmarks/dropin_costs.py{' --quick' if quick else ''}`: filterpy 2.0.0's UKF and"
        " squkf's SquareRootUKF side by side in one process, medians of interleaved rounds (this",
        "machine is shared and noisy: the ratios count). Target (issue 35): at most"
        f" {TARGET:g}x filterpy's time for `Saver.save()` and for a new filter with its first step.",
        "",
        "| what | filterpy (µs) | squkf (µs) | squkf / filterpy | target |",
        "|---|---|---|---|---|",
    ]
    for what, label in labels.items():
        fp, sq = figures[what]["filterpy"], figures[what]["squkf"]
        ratio = sq / fp
        target = f"<= {TARGET:g}x: {'met' if ratio <= TARGET else 'missed'}" if what != "deepcopy" else "-"
        lines.append(f"| {label} | {fp * 1e6:.0f} | {sq * 1e6:.0f} | {ratio:.2f} | {target} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="few rounds: a check that it runs")
    ap.add_argument("--out", default=str(HERE / "results"))
    args = ap.parse_args(argv)
    rounds, reps, count = (3, 50, 10) if args.quick else (15, 300, 40)
    text = report(measure(rounds, reps, count), args.quick)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "dropin_costs.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
