"""Speed, accuracy and robustness of SquareRootUKF against filterpy's UKF and its peers, in one run.

    python benchmarks/run.py            # full run (a few minutes), results in benchmarks/results/
    python benchmarks/run.py --quick    # smoke test (CI), well under a minute

Implementations are interleaved over repetitions in one process; times are
medians of time per predict+update step, and ratios to filterpy are taken per
repetition (median of the ratios). Only the steps are timed (reading the
state for RMSE and NEES is not). The time spent inside the user's fx and hx is
measured by wrapping them, and the library's own time is the rest.

BLAS is pinned to one thread for the main tables (``--threads 1``, set before
numpy is imported); a second speed table is measured in a subprocess with the
BLAS library's default threading, with the largest Lorenz-96 state too. Peers
are used when installed (``pip install -e ".[bench]"``); those not installed
are listed as skipped. Beside them run two references from ``floor.py``: the
step's QRs alone and the same step inlined with no checks, and a profile of
one squkf step split into its parts.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")

# targets of issue 6, as ratios to filterpy: (per-point, vectorised) per scenario
TARGETS = {
    "g13ej robot n=3": (0.4, 0.25),
    "coordinated turn n=5": (0.4, 0.25),
    "Lorenz-96 n=40": (0.7, 0.05),
}


def _parse(argv):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes, for CI")
    ap.add_argument("--out", default=str(HERE / "results"))
    ap.add_argument("--threads", default="1", help="BLAS threads: a number, or 'default' (leave as is)")
    ap.add_argument("--speed-only", action="store_true", help="only the speed table, as JSON on stdout")
    return ap.parse_args(argv)


ARGS = _parse(sys.argv[1:]) if __name__ == "__main__" else None
if ARGS is not None and ARGS.threads != "default":
    for var in THREAD_VARS:  # must happen before numpy loads its BLAS
        os.environ[var] = ARGS.threads

import numpy as np  # noqa: E402

sys.path.insert(0, str(HERE))

from floor import inline_impls, qr_ms, step_profile  # noqa: E402
from models import SCENARIOS, Lorenz96, near_singular  # noqa: E402
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
    """Filter one simulated run; time the steps; return time/step, model time/step, RMSE, NEES, failure."""
    truth, zs = sc.simulate(steps, seed)
    fx, hx = (Timed(sc.fx_vec), Timed(sc.hx_vec)) if impl.vectorized else (Timed(sc.fx), Timed(sc.hx))
    f = impl.make(sc, fx, hx)
    est, nees, failed = [], [], None
    total = 0.0
    for k, z in enumerate(zs):
        t0 = time.perf_counter()
        try:
            impl.step(f, z)
        except Exception as exc:  # noqa: BLE001 - a benchmark records every failure
            failed = (k, type(exc).__name__)
            break
        total += time.perf_counter() - t0
        x, P = impl.state(f)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
            failed = (k, "non-finite")
            break
        est.append(np.array(x, dtype=float))
        e = est[-1] - truth[k]
        try:
            nees.append(float(e @ np.linalg.solve(P, e)))
        except np.linalg.LinAlgError:
            nees.append(np.inf)
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


def scaling(impls, dims, steps, reps) -> dict:
    """Median time per step against dim_x on Lorenz-96 (every other component observed)."""
    out = {impl.name: [] for impl in impls}
    for n in dims:
        sc = Lorenz96(n)
        times = {impl.name: [] for impl in impls}
        for rep in range(reps):
            for impl in impls:
                r = run_one(impl, sc, steps, seed=rep)
                times[impl.name].append(np.nan if r["failed"] else r["t"])
        for name, ts in times.items():
            out[name].append(float(np.median(ts)))
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


def header(threads: str) -> str:
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
    return (
        f"Machine: {cpu}, {os.cpu_count()} cores; Python {platform.python_version()}, "
        f"numpy {np.__version__}, scipy {scipy.__version__}, filterpy {filterpy.__version__}; "
        f"BLAS threads: {threads}."
    )


def _slope(dims, ts) -> float | None:
    ts = np.asarray(ts, dtype=float)
    ok = np.isfinite(ts)
    if ok.sum() < 2:
        return None
    return float(np.polyfit(np.log(np.asarray(dims)[ok]), np.log(ts[ok]), 1)[0])


def targets_section(table) -> list[str]:
    """Each target of the issue beside the ratio reached (squkf's default redrawn scheme)."""
    lines = [
        "## Targets (ratio to filterpy; squkf redrawn, the default)",
        "",
        "| scenario | per-point target | reached | vectorised target | reached |",
        "|---|---|---|---|---|",
    ]
    for sc, (t_pp, t_vec) in TARGETS.items():
        pp = table.get((sc, "squkf redrawn per-point"))
        vec = table.get((sc, "squkf redrawn vectorised"))
        if pp is None or vec is None:
            continue

        def cell(r, t):
            return f"{r['ratio']:.2f} ({'met' if r['ratio'] <= t else 'not met'})"

        lines.append(f"| {sc} | <= {t_pp} | {cell(pp, t_pp)} | <= {t_vec} | {cell(vec, t_vec)} |")
    return lines + [""]


def floor_section(table, qr) -> list[str]:
    """squkf's own time beside the two QRs alone and a hand-inlined step with no checks (floor.py)."""
    inl = "reference: inlined step, no checks"
    lines = [
        "## Where the library's time goes (squkf redrawn; see benchmarks/floor.py)",
        "",
        "| scenario | two QRs alone, ms | library ms/step: squkf / inlined, vectorised "
        "| ratio per-point: squkf / inlined | ratio vectorised: squkf / inlined |",
        "|---|---|---|---|---|",
    ]
    for sc, q in qr.items():
        row = {k: table.get((sc, k)) for k in ("squkf redrawn per-point", "squkf redrawn vectorised")}
        row |= {k: table.get((sc, f"{inl} {k}")) for k in ("per-point", "vectorised")}
        if any(v is None for v in row.values()):
            continue
        sv, iv = row["squkf redrawn vectorised"], row["vectorised"]
        sp, ip = row["squkf redrawn per-point"], row["per-point"]
        lines.append(
            f"| {sc} | {q:.3f} | {sv['own_ms']:.3f} / {iv['own_ms']:.3f} "
            f"| {sp['ratio']:.2f} / {ip['ratio']:.2f} | {sv['ratio']:.2f} / {iv['ratio']:.2f} |"
        )
    return lines + [""]


def profile_section(profile) -> list[str]:
    """One step of squkf (vectorised, cheap linear models) split into its parts (floor.step_profile)."""
    names = list(profile)
    lines = [
        "## Profile of one step (squkf redrawn, vectorised, cheap linear fx/hx; microseconds)",
        "",
        "| part | " + " | ".join(names) + " |",
        "|---" * (len(names) + 1) + "|",
    ]
    for part in next(iter(profile.values())):
        lines.append(f"| {part} | " + " | ".join(f"{profile[sc][part]:.1f}" for sc in names) + " |")
    return lines + [""]


def write_results(out: Path, table, scale, dims, swept, P0s, skipped, impls, threaded, qr, profile) -> None:
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# Benchmark results", "", header(ARGS.threads if ARGS else "1"), ""]
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
    lines += [""] + targets_section(table) + floor_section(table, qr) + profile_section(profile)
    if threaded["table"]:
        lines += [
            "## Default BLAS threading (same runs, measured in a subprocess)",
            "",
            "| scenario | implementation | ms/step, default threads | ratio to filterpy, default threads |",
            "|---|---|---|---|",
        ]
        for key, r in threaded["table"].items():
            sc, name = key.split(" || ")
            lines.append(f"| {sc} | {name} | {r['t_ms']:.3f} | {r['ratio']:.2f} |")
        lines += [
            "",
            f"Lorenz-96 with n = {dims[-1]} (the scaling plot's largest state), ms per step:",
            "",
            "| implementation | BLAS on one thread | default threading |",
            "|---|---|---|",
        ]
        for name, t in threaded["largest"].items():
            pinned = scale.get(name, [np.nan])[-1]
            lines.append(f"| {name} | {1e3 * pinned:.2f} | {1e3 * t:.2f} |")
        lines.append("")
    lines += ["## Near-singular sweep (R = 1e-12 I, Q = 1e-14 I)", ""]
    lines += ["| P0 | " + " | ".join(i.name for i in impls) + " |", "|---" * (len(impls) + 1) + "|"]
    for p0 in P0s:
        cells = [
            "completed" if swept[(p0, i.name)] is None else f"failed at {swept[(p0, i.name)][0]}"
            for i in impls
        ]
        lines.append(f"| {p0:.0e} I | " + " | ".join(cells) + " |")
    lines += ["", "## Growth with dim_x (Lorenz-96)", ""]
    for name, ts in scale.items():
        slope = _slope(dims, ts)
        if slope is not None:
            lines.append(f"- {name}: time ~ dim_x^{slope:.2f}")
    (out / "results.md").write_text("\n".join(lines) + "\n")
    _plots(out, scale, dims, swept, P0s, impls)


def _plots(out, scale, dims, swept, P0s, impls) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5), dpi=90)
    for name, ts in scale.items():
        ts = np.array(ts)
        ok = np.isfinite(ts)
        slope = _slope(dims, ts)
        label = name if slope is None else f"{name} (slope {slope:.2f})"
        style = "o-" if name.startswith("squkf") else "s--"
        ax.loglog(np.array(dims)[ok], 1e3 * ts[ok], style, label=label, ms=4)
    ax.set_xlabel("dim_x (Lorenz-96, every other component observed)")
    ax.set_ylabel("ms per predict+update")
    ax.legend(fontsize=6)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "scaling.png")
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 0.6 + 0.35 * len(impls)), dpi=90)
    grid = np.array([[0.0 if swept[(p, i.name)] is None else 1.0 for p in P0s] for i in impls])
    ax.imshow(grid, cmap="RdYlGn_r", vmin=0, vmax=1, aspect="auto")
    for i, impl in enumerate(impls):
        for j, p in enumerate(P0s):
            f = swept[(p, impl.name)]
            ax.text(j, i, "ok" if f is None else f"step {f[0]}", ha="center", va="center", fontsize=6)
    ax.set_xticks(range(len(P0s)), [f"{p:.0e}" for p in P0s])
    ax.set_yticks(range(len(impls)), [i.name for i in impls], fontsize=7)
    ax.set_xlabel("P0 (times I); red = failed, green = completed")
    fig.tight_layout()
    fig.savefig(out / "failure_map.png")
    plt.close(fig)


def _sizes(quick: bool) -> dict:
    if quick:
        return {"steps": 20, "reps": 2, "dims": [2, 4, 8], "scale_steps": 5, "scale_reps": 1, "sweep": 200}
    return {
        "steps": 200,
        "reps": 11,
        "dims": [2, 4, 8, 16, 32, 64, 100],
        "scale_steps": 20,
        "scale_reps": 3,
        "sweep": 2000,
    }


def _scenarios(quick: bool):
    return [sc for sc in SCENARIOS() if not (quick and sc.name.startswith("Lorenz"))]


def _threaded_table(quick: bool) -> dict:
    """The speed table measured with the BLAS library's default threading (a subprocess)."""
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARS}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--threads", "default", "--speed-only"]
    if quick:
        cmd.append("--quick")
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> int:
    args = ARGS
    impls, skipped = implementations()
    size = _sizes(args.quick)
    scenarios = _scenarios(args.quick)
    table = compare(scenarios, impls + inline_impls(), size["steps"], size["reps"])
    if args.speed_only:
        # the largest state of the scaling plot too: where a threaded BLAS matters most
        large = scaling(impls, size["dims"][-1:], size["scale_steps"], size["scale_reps"])
        rows = {f"{sc} || {name}": r for (sc, name), r in table.items()}
        print(json.dumps({"table": rows, "largest": {k: v[0] for k, v in large.items()}}))
        return 0
    threaded = _threaded_table(args.quick) if args.threads != "default" else {"table": {}, "largest": {}}
    scale = scaling(impls, size["dims"], size["scale_steps"], size["scale_reps"])
    P0s = [1e2, 1e3, 1e4, 1e5, 1e6]
    swept = sweep(impls, P0s, size["sweep"])
    qr = {sc.name: qr_ms(sc.dim_x, sc.dim_z, 2 * sc.dim_x + 1) for sc in scenarios}
    profile = {sc.name: step_profile(sc, 200 if args.quick else 2000) for sc in scenarios}
    write_results(
        Path(args.out), table, scale, size["dims"], swept, P0s, skipped, impls, threaded, qr, profile
    )
    print((Path(args.out) / "results.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
