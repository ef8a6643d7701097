"""Speed, accuracy and robustness of SquareRootUKF against filterpy's UKF, in one run.

    python benchmarks/run.py            # full run, results in benchmarks/results/
    python benchmarks/run.py --quick    # smoke test (CI), a few seconds

Implementations are interleaved over repetitions in one process; times are
medians of time per predict+update step, and ratios to filterpy are taken per
repetition (median of the ratios). The time spent inside the user's fx and
hx is measured by wrapping them, and the library's own time is the rest.
Peers other than filterpy are used when installed (``pip install -e
".[bench]"``); those not installed are listed as skipped.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from models import SCENARIOS, near_singular  # noqa: E402
from peers import implementations  # noqa: E402


class Timed:
    """Wraps a model function and accumulates the time spent in it."""

    def __init__(self, fn):
        self.fn = fn
        self.seconds = 0.0

    def __call__(self, *args, **kwargs):
        t = time.perf_counter()
        try:
            return self.fn(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - t


def run_one(impl, sc, steps: int, seed: int) -> dict:
    """Filter one simulated run; time it; return time/step, model time/step, RMSE, NEES, failure."""
    truth, zs = sc.simulate(steps, seed)
    fx, hx = (Timed(sc.fx_vec), Timed(sc.hx_vec)) if impl.vectorized else (Timed(sc.fx), Timed(sc.hx))
    f = impl.make(sc, fx, hx)
    est, nees, failed = [], [], None
    t0 = time.perf_counter()
    for k, z in enumerate(zs):
        try:
            impl.step(f, z)
        except Exception as exc:  # noqa: BLE001 - a benchmark records every failure
            failed = (k, type(exc).__name__)
            break
        x, P = impl.state(f)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
            failed = (k, "non-finite")
            break
        est.append(x)
        e = x - truth[k]
        try:
            nees.append(float(e @ np.linalg.solve(P, e)))
        except np.linalg.LinAlgError:
            nees.append(np.inf)
    total = time.perf_counter() - t0
    done = max(len(est), 1)
    est = np.array(est) if est else np.zeros((0, truth.shape[1]))
    rmse = float(np.sqrt(np.mean((est - truth[: len(est)]) ** 2))) if len(est) else np.nan
    return {
        "t": total / done,
        "model": (fx.seconds + hx.seconds) / done,
        "rmse": rmse,
        "nees": float(np.mean(nees)) if nees else np.nan,
        "failed": failed,
    }


def compare(scenarios, impls, steps, reps) -> dict:
    """Interleave implementations over repetitions; per-repetition ratios to filterpy."""
    table = {}
    for sc in scenarios:
        rows = {impl.name: [] for impl in impls}
        for rep in range(reps):
            for impl in impls:
                rows[impl.name].append(run_one(impl, sc, steps, seed=rep))
        base = rows.get("filterpy UKF")
        for name, runs in rows.items():
            ratios = [r["t"] / b["t"] for r, b in zip(runs, base)] if base else [np.nan]
            table[(sc.name, name)] = {
                "t_ms": 1e3 * float(np.median([r["t"] for r in runs])),
                "own_ms": 1e3 * float(np.median([r["t"] - r["model"] for r in runs])),
                "ratio": float(np.median(ratios)),
                "rmse": float(np.median([r["rmse"] for r in runs])),
                "nees": float(np.median([r["nees"] for r in runs])),
                "failed": next((r["failed"] for r in runs if r["failed"]), None),
            }
    return table


def scaling(impls, dims, steps) -> dict:
    """Time per step against dim_x on Lorenz-96 (every other component observed)."""
    from models import Lorenz96

    out = {impl.name: [] for impl in impls}
    for n in dims:
        sc = Lorenz96(n)
        for impl in impls:
            r = run_one(impl, sc, steps, seed=0)
            out[impl.name].append(np.nan if r["failed"] else r["t"])
    return out


def sweep(impls, P0s, steps) -> dict:
    """Near-singular model: at which step (if any) each implementation fails, per P0."""
    out = {}
    for p0 in P0s:
        sc = near_singular(p0)
        for impl in impls:
            r = run_one(impl, sc, steps, seed=0)
            out[(p0, impl.name)] = r["failed"]
    return out


def header() -> str:
    import filterpy
    import scipy

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    threads = os.environ.get("OMP_NUM_THREADS", "default")
    return (
        f"Machine: {cpu}, {os.cpu_count()} cores; Python {platform.python_version()}, "
        f"numpy {np.__version__}, scipy {scipy.__version__}, filterpy {filterpy.__version__}; "
        f"BLAS threads: {threads}."
    )


def write_results(out: Path, table, scale, dims, swept, P0s, skipped, impls) -> None:
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# Benchmark results", "", header(), ""]
    if skipped:
        lines += ["Skipped peers: " + "; ".join(skipped), ""]
    lines += [
        "| scenario | implementation | ms/step | library ms/step | ratio to filterpy | RMSE | NEES "
        "| failed at |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for (sc, name), r in table.items():
        fail = "-" if not r["failed"] else f"step {r['failed'][0]} ({r['failed'][1]})"
        lines.append(
            f"| {sc} | {name} | {r['t_ms']:.3f} | {r['own_ms']:.3f} | {r['ratio']:.2f} | "
            f"{r['rmse']:.3g} | {r['nees']:.3g} | {fail} |"
        )
    lines += ["", "## Near-singular sweep (R = 1e-12 I, Q = 1e-14 I)", ""]
    lines += ["| P0 | " + " | ".join(i.name for i in impls) + " |", "|---" * (len(impls) + 1) + "|"]
    for p0 in P0s:
        cells = [
            "completed" if swept[(p0, i.name)] is None else f"failed at {swept[(p0, i.name)][0]}"
            for i in impls
        ]
        lines.append(f"| {p0:.0e} I | " + " | ".join(cells) + " |")
    lines += ["", "## Growth with dim_x (Lorenz-96)", ""]
    for name, ts in scale.items():
        ok = np.isfinite(ts)
        if ok.sum() >= 2:
            slope = np.polyfit(np.log(np.array(dims)[ok]), np.log(np.array(ts)[ok]), 1)[0]
            lines.append(f"- {name}: time ~ dim_x^{slope:.2f}")
    (out / "results.md").write_text("\n".join(lines) + "\n")
    _plots(out, scale, dims, swept, P0s, impls)


def _plots(out, scale, dims, swept, P0s, impls) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), dpi=90)
    for name, ts in scale.items():
        ts = np.array(ts)
        ok = np.isfinite(ts)
        label = name
        if ok.sum() >= 2:
            slope = np.polyfit(np.log(np.array(dims)[ok]), np.log(ts[ok]), 1)[0]
            label = f"{name} (slope {slope:.2f})"
        ax.loglog(np.array(dims)[ok], 1e3 * ts[ok], "o-", label=label)
    ax.set_xlabel("dim_x (Lorenz-96)")
    ax.set_ylabel("ms per predict+update")
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "scaling.png")
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 0.5 + 0.4 * len(impls)), dpi=90)
    grid = np.array([[0.0 if swept[(p, i.name)] is None else 1.0 for p in P0s] for i in impls])
    ax.imshow(grid, cmap="RdYlGn_r", vmin=0, vmax=1, aspect="auto")
    ax.set_xticks(range(len(P0s)), [f"{p:.0e}" for p in P0s])
    ax.set_yticks(range(len(impls)), [i.name for i in impls], fontsize=7)
    ax.set_xlabel("P0 (times I); red = failed, green = completed")
    fig.tight_layout()
    fig.savefig(out / "failure_map.png")
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes, for CI")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    args = ap.parse_args(argv)
    impls, skipped = implementations()
    if args.quick:
        steps, reps, dims, scale_steps, sweep_steps = 20, 2, [2, 4, 8], 5, 200
        scen = [sc for sc in SCENARIOS() if sc.name != "Lorenz-96 n=40"]
    else:
        steps, reps, dims, scale_steps, sweep_steps = 200, 7, [2, 4, 8, 16, 32, 64, 100], 20, 2000
        scen = SCENARIOS()
    P0s = [1e2, 1e3, 1e4, 1e5, 1e6]
    table = compare(scen, impls, steps, reps)
    scale = scaling(impls, dims, scale_steps)
    swept = sweep(impls, P0s, sweep_steps)
    write_results(Path(args.out), table, scale, dims, swept, P0s, skipped, impls)
    print((Path(args.out) / "results.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
