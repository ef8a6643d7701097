"""Speed, accuracy and robustness of SquareRootUKF against filterpy's UKF and its peers, in one run.

    python benchmarks/run.py            # full run (a few minutes), results in benchmarks/results/
    python benchmarks/run.py --quick    # smoke test (CI), well under a minute
    python benchmarks/run.py --figures [scaling|sweep]  # only those (both by default), a few minutes
    python benchmarks/run.py --replot   # redraw both figures from results/figures.json, no measuring
    python benchmarks/run.py --hooks    # only the angle hooks' table (hooks_bench.py), a minute

Implementations are interleaved over repetitions in one process; times are
medians of time per predict+update step, and ratios to filterpy are taken per
repetition (median of the ratios). Only the steps are timed (reading the
state for RMSE and NEES is not). Each implementation first runs a few untimed
steps of each scenario, so that compiling or loading squkf's numba kernels
(``compile_time.py`` measures that) is not in the tables. The time spent
inside the user's fx and hx is measured by wrapping them, and the library's
own time is the rest.

BLAS is pinned to one thread for the main tables (``--threads 1``, set before
numpy is imported); a second speed table is measured in a subprocess with the
BLAS library's default threading, with the largest Lorenz-96 state too. Peers
are used when installed (``pip install -e ".[bench]"``); those not installed
are listed as skipped. Beside them run two references from ``floor.py``: the
step's QRs alone and the same step inlined with no checks (the library's two
kernels called directly), and a profile of one squkf step split into its
parts; ``python_per_step.py`` counts the Python one step runs in squkf's files.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
import warnings
from pathlib import Path

HERE = Path(__file__).resolve().parent
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")

FILTERPY, KALMAN = "filterpy UKF", "kalman-py UKF (vectorised)"
# targets of issue 30 for squkf's default (redrawn) step: (scenario, kind, reference, largest ratio)
TARGETS = (
    ("g13ej robot n=3", "per-point", FILTERPY, 0.35),
    ("g13ej robot n=3", "vectorised", FILTERPY, 0.2),
    ("coordinated turn n=5", "per-point", FILTERPY, 0.35),
    ("coordinated turn n=5", "vectorised", FILTERPY, 0.2),
    ("Lorenz-96 n=40", "per-point", FILTERPY, 0.72),
    ("Lorenz-96 n=40", "vectorised", KALMAN, 1.0),
)


def _parse(argv):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes, for CI")
    ap.add_argument("--out", default=str(HERE / "results"))
    ap.add_argument("--threads", default="1", help="BLAS threads: a number, or 'default' (leave as is)")
    ap.add_argument("--speed-only", action="store_true", help="only the speed table, as JSON on stdout")
    ap.add_argument(
        "--figures",
        nargs="?",
        const="both",
        choices=("both", "scaling", "sweep"),
        help="measure only the scaling curve and/or the near-singular sweep: redraw their figures and "
        "rewrite their sections of results.md, leaving the other tables as they are",
    )
    ap.add_argument("--replot", action="store_true", help="redraw the figures from figures.json only")
    ap.add_argument(
        "--hooks",
        action="store_true",
        help="measure only the angle hooks' table (hooks_bench.py) and rewrite its section of results.md",
    )
    ap.add_argument("--ref", default="0cdce8e", help="the fleet's Python per chunk: its reference")
    return ap.parse_args(argv)


ARGS = _parse(sys.argv[1:]) if __name__ == "__main__" else None
if ARGS is not None and ARGS.threads != "default":
    for var in THREAD_VARS:  # must happen before numpy loads its BLAS
        os.environ[var] = ARGS.threads

import numpy as np  # noqa: E402

sys.path.insert(0, str(HERE))

from floor import inline_impls, qr_ms, step_profile  # noqa: E402
from machine import cpu_name  # noqa: E402
from models import SCENARIOS, Lorenz96, near_singular  # noqa: E402
from peers import implementations  # noqa: E402
from python_per_step import fleet_calls, fleet_table, reference_fleet_calls  # noqa: E402
from python_per_step import measure as python_per_step  # noqa: E402
from python_per_step import table as python_per_step_table  # noqa: E402


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


def run_one(impl, sc, steps: int, seed: int, warned: list | None = None) -> dict:
    """Filter one simulated run; time the steps; return time/step, model time/step, RMSE, NEES, failure.

    With a list as ``warned``, each warning a step raises is recorded in it as (step, category name)
    instead of being shown (for the sweep, which is not timed).
    """
    truth, zs = sc.simulate(steps, seed)
    fx, hx = (Timed(sc.fx_vec), Timed(sc.hx_vec)) if impl.vectorized else (Timed(sc.fx), Timed(sc.hx))
    f = impl.make(sc, fx, hx)
    est, nees, failed = [], [], None
    total = 0.0
    for k, z in enumerate(zs):
        t0 = time.perf_counter()
        try:
            if warned is None:
                impl.step(f, z)
            else:
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    impl.step(f, z)
                warned.extend((k, w.category.__name__) for w in caught)
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
        for impl in impls:  # untimed: numba's kernels are compiled or loaded from the cache on first use
            run_one(impl, sc, 3, seed=reps)
        for rep in range(reps):
            for impl in impls:
                rows[impl.name].append(run_one(impl, sc, steps, seed=rep))
        base, kalman = rows.get(FILTERPY), rows.get(KALMAN)
        for name, runs in rows.items():
            ratios = [r["t"] / b["t"] for r, b in zip(runs, base)] if base else [np.nan]
            to_kalman = [r["t"] / b["t"] for r, b in zip(runs, kalman)] if kalman else [np.nan]
            table[(sc.name, name)] = {
                "t_ms": 1e3 * float(np.median([r["t"] for r in runs])),
                "own_ms": 1e3 * float(np.median([r["t"] - r["model"] for r in runs])),
                "ratio": float(np.median(ratios)),
                "ratio_kalman": float(np.median(to_kalman)),
                "rmse": float(np.median([r["rmse"] for r in runs])),
                "nees": float(np.median([r["nees"] for r in runs])),
                "failed": next((r["failed"] for r in runs if r["failed"]), None),
            }
    return table


def scaling(impls, dims, steps, reps, ratios: dict | None = None) -> dict:
    """Median time per step against dim_x on Lorenz-96 (every other component observed).

    With a dict as ``ratios``, ``ratios[n][name]`` is set to the medians over repetitions of that
    implementation's time over filterpy's and over kalman-py's in the same repetition.
    """
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
        if ratios is not None:
            ratios[n] = {
                name: {
                    ref: float(np.median(np.array(ts) / np.array(times[ref]))) if ref in times else np.nan
                    for ref in (FILTERPY, KALMAN)
                }
                for name, ts in times.items()
            }
    return out


def sweep(impls, P0s, steps) -> tuple[dict, dict]:
    """Near-singular model, per P0: at which step (if any) each implementation fails, and its warnings.

    Returns ``(failed, warned)``: ``failed[(p0, name)]`` is None or (step, exception name);
    ``warned[(p0, name)]`` is None or (first step that warned, its category, number of warnings).
    """
    failed, warned = {}, {}
    for p0 in P0s:
        sc = near_singular(p0)
        for impl in impls:
            caught = []
            r = run_one(impl, sc, steps, seed=0, warned=caught)
            failed[(p0, impl.name)] = r["failed"]
            warned[(p0, impl.name)] = (*caught[0], len(caught)) if caught else None
    return failed, warned


def header(threads: str) -> str:
    import filterpy
    import scipy

    cpu = cpu_name()
    return (
        f"Machine: {cpu}, {os.cpu_count()} cores; Python {platform.python_version()}, "
        f"numpy {np.__version__}, scipy {scipy.__version__}, filterpy {filterpy.__version__}; "
        f"BLAS threads: {threads}."
    )


# Below about n = 16 the time per step is mostly fixed overhead and barely grows; a power law
# fitted over all sizes would average that flat part with the real growth at large n.
FIT_FROM = 16


def _slope(dims, ts, n_min: int = FIT_FROM) -> float | None:
    """Exponent of a power law fitted to time against dim_x over the sizes >= n_min (None: < 2 sizes)."""
    dims, ts = np.asarray(dims, dtype=float), np.asarray(ts, dtype=float)
    ok = np.isfinite(ts) & (dims >= n_min)
    if ok.sum() < 2:
        return None
    return float(np.polyfit(np.log(dims[ok]), np.log(ts[ok]), 1)[0])


def _local_slopes(dims, ts, n_min: int = FIT_FROM) -> list[float]:
    """Exponents between successive measured sizes >= n_min (how straight the fitted stretch is)."""
    dims, ts = np.asarray(dims, dtype=float), np.asarray(ts, dtype=float)
    ok = np.isfinite(ts) & (dims >= n_min)
    d, t = np.log(dims[ok]), np.log(ts[ok])
    return [float(v) for v in np.diff(t) / np.diff(d)]


def targets_section(table) -> list[str]:
    """Each target of issue 30 beside the ratio reached (squkf's default redrawn scheme).

    A target whose scenario was not run (``--quick`` leaves Lorenz-96 out) is left out; one whose
    reference is not installed is listed as not measured.
    """
    lines = [
        "## Targets (squkf redrawn, the default; time over the reference's in the same repetition)",
        "",
        "| scenario | squkf | reference | target | reached |",
        "|---|---|---|---|---|",
    ]
    for sc, kind, ref, most in TARGETS:
        r = table.get((sc, f"squkf redrawn {kind}"))
        if r is None:
            continue
        if (sc, ref) not in table:
            lines.append(f"| {sc} | {kind} | {ref} | <= {most:g} | not measured ({ref} not installed) |")
            continue
        v = r["ratio"] if ref == FILTERPY else r["ratio_kalman"]
        lines.append(
            f"| {sc} | {kind} | {ref} | <= {most:g} | {v:.2f} ({'met' if v <= most else 'not met'}) |"
        )
    return lines + [""]


def ratios_section(table, large: dict) -> list[str]:
    """squkf's time over filterpy's and over kalman-py's, per scenario, and at the largest Lorenz-96."""
    lines = [
        "## squkf over filterpy and kalman-py (medians of per-repetition ratios)",
        "",
        f"| scenario | implementation | over {FILTERPY} | over {KALMAN} |",
        "|---|---|---|---|",
    ]
    for (sc, name), r in table.items():
        if name.startswith("squkf"):
            lines.append(f"| {sc} | {name} | {r['ratio']:.2f} | {r['ratio_kalman']:.2f} |")
    for n, rows in large.items():
        for name, r in rows.items():
            if name.startswith("squkf"):
                lines.append(
                    f"| Lorenz-96 n={n} (scaling runs) | {name} | {r[FILTERPY]:.2f} | {r[KALMAN]:.2f} |"
                )
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


def python_section(found) -> list[str]:
    """The Python one step runs in squkf's files (benchmarks/python_per_step.py): counts, not times."""
    lines = [
        "## Python per step (squkf redrawn, g13ej robot; benchmarks/python_per_step.py)",
        "",
        f"Counted with `sys.setprofile` on Python {platform.python_version()}, in steady state: the calls "
        "of code in squkf's files, the most squkf frames on the stack at once (the public method "
        "counting as 1) and squkf's modules entered, in one predict + update. The model functions are "
        "not squkf's code and are not counted. A fleet's step of one chunk, counted the same way, "
        "beside the revision the issue compares it with (`--ref`; not in a quick run).",
        "",
    ]
    fleet = fleet_table(found["fleet"], found.get("fleet ref"), found["ref"])
    singles = {name: r for name, r in found.items() if name in ("vectorised", "per point")}
    return lines + python_per_step_table(singles) + [""] + fleet + [""]


def write_results(
    out: Path, table, scale, dims, swept, P0s, skipped, impls, threaded, qr, profile, large, pycalls
) -> None:
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
    lines += [""] + targets_section(table) + ratios_section(table, large)
    lines += floor_section(table, qr) + profile_section(profile) + python_section(pycalls)
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
    lines += figure_sections(scale, dims, swept, P0s, [i.name for i in impls])
    (out / "results.md").write_text("\n".join(lines) + "\n")
    _save_figure_data(out, scale, dims, swept, P0s, [i.name for i in impls])
    _plots(out, scale, dims, swept, P0s, [i.name for i in impls])


def _sweep_cell(failed, warned) -> str:
    if failed is not None:
        return f"failed at {failed[0]}" + ("" if warned is None else f" (warned from {warned[0]})")
    if warned is not None:
        return f"completed, warned from step {warned[0]} ({warned[2]} {warned[1]})"
    return "completed"


def figure_sections(scale, dims, swept, P0s, names) -> list[str]:
    """The near-singular sweep and the growth with dim_x: the last two sections of results.md.

    ``swept`` is ``(failed, warned)`` as returned by ``sweep``.
    """
    return sweep_section(swept, P0s, names) + [""] + growth_section(scale, dims)


def sweep_section(swept, P0s, names) -> list[str]:
    failed, warned = swept
    lines = ["## Near-singular sweep (R = 1e-12 I, Q = 1e-14 I)", ""]
    lines += ["| P0 | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for p0 in P0s:
        cells = [_sweep_cell(failed[(p0, n)], warned[(p0, n)]) for n in names]
        lines.append(f"| {p0:.0e} I | " + " | ".join(cells) + " |")
    return lines


def growth_section(scale, dims) -> list[str]:
    lines = [
        "## Growth with dim_x (Lorenz-96)",
        "",
        f"Power law fitted over dim_x >= {FIT_FROM} (below it the time per step is mostly fixed "
        "overhead); in brackets the exponents between successive sizes.",
        "",
    ]
    for name, ts in scale.items():
        slope = _slope(dims, ts)
        if slope is not None:
            local = ", ".join(f"{v:.2f}" for v in _local_slopes(dims, ts))
            lines.append(f"- {name}: time ~ dim_x^{slope:.2f} ({local})")
    if all(_slope(dims, ts) is None for ts in scale.values()):
        lines.append(f"- no two sizes >= {FIT_FROM} measured: no fit")
    return lines


def _save_figure_data(out: Path, scale, dims, swept, P0s, names) -> None:
    """What the two figures are drawn from, so that they can be redrawn without measuring (--replot)."""
    failed, warned = swept
    data = {
        "dims": list(dims),
        "scale_seconds": {k: [None if not np.isfinite(v) else v for v in ts] for k, ts in scale.items()},
        "P0s": list(P0s),
        "names": list(names),
        "sweep": [
            {"P0": p, "name": n, "failed": failed[(p, n)], "warned": warned[(p, n)]}
            for p in P0s
            for n in names
        ],
    }
    (out / "figures.json").write_text(json.dumps(data, indent=1) + "\n")


def _load_figure_data(out: Path):
    data = json.loads((out / "figures.json").read_text())
    scale = {k: [np.nan if v is None else v for v in ts] for k, ts in data["scale_seconds"].items()}
    failed = {(r["P0"], r["name"]): r["failed"] for r in data["sweep"]}
    warned = {(r["P0"], r["name"]): r["warned"] for r in data["sweep"]}
    return scale, data["dims"], (failed, warned), data["P0s"], data["names"]


# colour-blind-safe colours, one per line: Okabe-Ito's (yellow left out, too light on white), then
# three of Paul Tol's; each line has its own marker too
COLOURS = ["#000000", "#0072B2", "#56B4E9", "#D55E00", "#E69F00", "#999999", "#009E73", "#CC79A7"]
COLOURS += ["#882255", "#999933", "#332288", "#44AA99"]
MARKERS = ["o", "s", "^", "v", "D", "P", "X", "*", "h", "<", ">", "p"]
# the sweep's three outcomes, light to dark (readable in grey too), each with a text colour that contrasts
OUTCOMES = {
    "completed": ("#EEEEEE", "black"),
    "completed with warnings": ("#DDCC77", "black"),
    "failed": ("#882255", "white"),
}


def _plots(out, scale, dims, swept, P0s, names) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401 - loads the submodule used by _scaling_plot

    if scale:
        _scaling_plot(out, scale, dims, plt)
    if swept[0]:
        _failure_map(out, swept, P0s, names, plt)


def _scaling_plot(out, scale, dims, plt) -> None:
    import matplotlib

    dims = np.asarray(dims, dtype=float)
    fig, ax = plt.subplots(figsize=(10, 5), dpi=90)
    for i, (name, ts) in enumerate(scale.items()):
        ts = np.asarray(ts, dtype=float)
        ok = np.isfinite(ts)
        slope = _slope(dims, ts)
        label = name if slope is None else f"{name}: ~n^{slope:.2f}"
        colour = COLOURS[i % len(COLOURS)]
        style = "-" if name.startswith("squkf") else "--"
        ax.loglog(
            dims[ok], 1e3 * ts[ok], style, marker=MARKERS[i % len(MARKERS)], color=colour, ms=5, label=label
        )
    if any(_slope(dims, ts) is not None for ts in scale.values()):
        ax.axvspan(FIT_FROM, dims.max(), color="#999999", alpha=0.12, lw=0)
        ax.text(
            FIT_FROM * 1.05,
            0.98,
            f"power law fitted\nfor n >= {FIT_FROM}",
            transform=ax.get_xaxis_transform(),
            va="top",
            fontsize=9,
        )
    ax.set_xticks(dims, [f"{d:g}" for d in dims])
    ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
    ax.yaxis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1, 2, 5)))
    ax.yaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
    ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel("n = dim_x (Lorenz-96, every other component observed)", fontsize=10)
    ax.set_ylabel("ms per predict + update (median)", fontsize=10)
    ax.tick_params(labelsize=9)
    ax.legend(
        fontsize=9,
        loc="upper left",
        bbox_to_anchor=(1.01, 1),
        title="time ~ n^k for n >= " + str(FIT_FROM),
        title_fontsize=9,
    )
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "scaling.png")
    plt.close(fig)


def _failure_map(out, swept, P0s, names, plt) -> None:
    import matplotlib
    from matplotlib.patches import Patch

    failed, warned = swept
    fig, ax = plt.subplots(figsize=(10, 1.3 + 0.42 * len(names)), dpi=90)
    kinds = list(OUTCOMES)
    grid = np.zeros((len(names), len(P0s)))
    for i, name in enumerate(names):
        for j, p in enumerate(P0s):
            f, w = failed[(p, name)], warned[(p, name)]
            kind = "failed" if f is not None else "completed with warnings" if w is not None else "completed"
            grid[i, j] = kinds.index(kind)
            text = {"failed": f"failed at step {f[0]}" if f else "", "completed": "ok"}.get(
                kind, f"ok, warned\nfrom step {w[0]}" if w else ""
            )
            ax.text(j, i, text, ha="center", va="center", fontsize=9, color=OUTCOMES[kind][1])
    cmap = matplotlib.colors.ListedColormap([OUTCOMES[k][0] for k in kinds])
    ax.imshow(grid, cmap=cmap, vmin=-0.5, vmax=len(kinds) - 0.5, aspect="auto")
    ax.set_xticks(range(len(P0s)), [f"{p:.0e} I" for p in P0s], fontsize=9)
    ax.set_yticks(range(len(names)), names, fontsize=9)
    ax.set_xticks(np.arange(len(P0s) + 1) - 0.5, minor=True)
    ax.set_yticks(np.arange(len(names) + 1) - 0.5, minor=True)
    ax.grid(which="minor", color="white", lw=2)
    ax.tick_params(which="minor", length=0)
    ax.set_xlabel("initial covariance P0", fontsize=10)
    ax.set_title(
        "Near-singular model (R = 1e-12 I, Q = 1e-14 I): first failing or warning step (counted from 0)",
        fontsize=10,
    )
    handles = [Patch(facecolor=OUTCOMES[k][0], edgecolor="#666666", label=k) for k in kinds]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1), fontsize=9)
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


def _replace_section(text: str, lines: list[str]) -> str:
    """``text`` with the section that starts like ``lines[0]`` (up to the next "## ") set to ``lines``."""
    title = lines[0].split(" (")[0]
    new = "\n".join(lines) + "\n"
    if title not in text:
        return text.rstrip("\n") + "\n\n" + new
    before, rest = text.split(title, 1)
    after = rest.split("\n## ", 1)[1] if "\n## " in rest else None
    return before + new + ("" if after is None else "\n## " + after)


def figures_only(out: Path, impls, size, part: str) -> None:
    """Measure the scaling curve and/or the sweep (``part``: both, scaling or sweep); redraw the
    figures and rewrite their sections of results.md. The part not measured is kept from figures.json."""
    names, dims, P0s = [i.name for i in impls], size["dims"], [1e2, 1e3, 1e4, 1e5, 1e6]
    scale, swept = {}, ({}, {})
    if (out / "figures.json").exists():
        scale, dims_old, swept, P0s_old, names_old = _load_figure_data(out)
        if part == "sweep":
            dims = dims_old
        if part == "scaling":
            P0s, names = P0s_old, names_old
    md = out / "results.md"
    text = md.read_text() if md.exists() else "# Benchmark results\n"
    if part in ("both", "scaling"):
        scale = scaling(impls, dims, size["scale_steps"], size["scale_reps"])
        text = _replace_section(text, growth_section(scale, dims))
    if part in ("both", "sweep"):
        swept = sweep(impls, P0s, size["sweep"])
        text = _replace_section(text, sweep_section(swept, P0s, names))
    out.mkdir(parents=True, exist_ok=True)
    md.write_text(text)
    _save_figure_data(out, scale, dims, swept, P0s, names)
    _plots(out, scale, dims, swept, P0s, names)


def hooks_only(out: Path, quick: bool) -> None:
    """Measure one filter with a wrapping bearing (``hooks_bench.single``) and rewrite its section of
    results.md, the other tables kept."""
    import hooks_bench

    steps, reps = (20, 1) if quick else (300, 9)
    lines = hooks_bench.single_section(hooks_bench.single(steps, reps), steps, reps)
    md = out / "results.md"
    text = md.read_text() if md.exists() else "# Benchmark results\n"
    out.mkdir(parents=True, exist_ok=True)
    md.write_text(_replace_section(text, lines))


def main() -> int:
    args = ARGS
    if args.hooks:
        hooks_only(Path(args.out), args.quick)
        print((Path(args.out) / "results.md").read_text())
        return 0
    if args.replot:
        _plots(Path(args.out), *_load_figure_data(Path(args.out)))
        return 0
    impls, skipped = implementations()
    size = _sizes(args.quick)
    if args.figures:
        figures_only(Path(args.out), impls, size, args.figures)
        print((Path(args.out) / "results.md").read_text())
        return 0
    scenarios = _scenarios(args.quick)
    table = compare(scenarios, impls + inline_impls(), size["steps"], size["reps"])
    if args.speed_only:
        # the largest state of the scaling plot too: where a threaded BLAS matters most
        ratios: dict = {}
        large = scaling(impls, size["dims"][-1:], size["scale_steps"], size["scale_reps"], ratios)
        rows = {f"{sc} || {name}": r for (sc, name), r in table.items()}
        out = {"table": rows, "largest": {k: v[0] for k, v in large.items()}, "largest_ratios": ratios}
        print(json.dumps(out))
        return 0
    threaded = _threaded_table(args.quick) if args.threads != "default" else {"table": {}, "largest": {}}
    large: dict = {}
    scale = scaling(impls, size["dims"], size["scale_steps"], size["scale_reps"], large)
    large = {n: large[n] for n in size["dims"][-1:]}  # the largest state
    P0s = [1e2, 1e3, 1e4, 1e5, 1e6]
    swept = sweep(impls, P0s, size["sweep"])
    qr = {sc.name: qr_ms(sc.dim_x, sc.dim_z, 2 * sc.dim_x + 1) for sc in scenarios}
    profile = {sc.name: step_profile(sc, 200 if args.quick else 2000) for sc in scenarios}
    import squkf

    pycalls: dict = {**python_per_step(), "fleet": fleet_calls(squkf), "ref": args.ref}
    if not args.quick:
        pycalls["fleet ref"] = reference_fleet_calls(args.ref)
    write_results(
        Path(args.out),
        table, scale, size["dims"], swept, P0s, skipped, impls, threaded, qr, profile, large, pycalls,
    )  # fmt: skip
    hooks_only(Path(args.out), args.quick)
    print((Path(args.out) / "results.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
