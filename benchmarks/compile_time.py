"""Compile time of the numba core on an empty cache, and the first step of a new process with the cache.

    python benchmarks/compile_time.py              # results in benchmarks/results/compile.md
    python benchmarks/compile_time.py --reps 5     # more repetitions of the cached runs
    python benchmarks/compile_time.py --out DIR
    python benchmarks/compile_time.py --ref 0cdce8e --cold-reps 3   # and cold compiles against a revision

Each measurement is a fresh Python process (this script run as a child) with
``NUMBA_CACHE_DIR`` pointed at a temporary directory, so the package's own
cache (beside the installed package) is neither read nor written:

* cold cache: the directory is new and empty. The child imports squkf, builds
  a default ``SquareRootUKF`` (Merwe's points with their defaults, the redrawn
  scheme, per-point model functions) or a default ``Fleet`` (the same, K
  filters), and runs its first ``predict`` + ``update``: every kernel the step
  needs is compiled then, and written to the directory.
* cached: new processes on the same, now filled, directory (``--reps`` of
  them; the table gives medians). The kernels are loaded from the cache.
* the Fleet once more on the directory the filter alone filled: whether a
  fleet finds the kernels a single filter compiled.
* first uses (``firsts``): one process on a new empty cache runs the default
  filter's first step (filling the cache), then, one after the other, the
  first step with squkf's angle hooks on the measurement, the first
  ``batch_filter``, the first ``Fleet`` step and the first smoother (the
  issue's "at most 2 s more in all"), then routes outside that sum: the
  first update in the downdate form (a user's ``UT``, as a ``residual_x``,
  ``state_add`` or the propagated scheme take it) and the first partial
  measurement. Each row names the kernels it compiled; "angle code compiles
  only on first use" is the default step's list, without ``angle_rows_kernel``.

Times inside a child: ``import squkf`` (in a process that has imported nothing
else, so it includes numpy, scipy and numba), building the filter, the first
predict + update, and the second one (compiled code only). "Process" is the
child's wall time seen from this script, interpreter start-up and exit
included. The model is the fleet benchmark's constant-velocity target with a
range-bearing sensor (n = 4, m = 2). BLAS is held to one thread.

With ``--ref REV`` (any number of times) the cold compiles are also measured
against earlier revisions in the same run: each revision's ``squkf`` package
is taken from git (``git archive``) into a temporary folder, and a child
process imports it from there (``PYTHONPATH``). ``--cold-reps`` rounds, each
running every tree's filter and fleet once on a new empty cache, this tree
first, so that a machine that slows for a while slows all alike. The table
gives each tree's median build + first predict + update, and the median over
rounds of this tree's time divided by the revision's; each round also runs
each tree's first uses (above) on a new empty cache.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from against_revision import export_package  # noqa: E402

THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")
COLD_TARGET_S, CACHED_TARGET_S = 30.0, 1.0


def radar():
    """The children's model, a constant-velocity target seen by a range-bearing radar (n = 4, m = 2):
    ``fx``, ``hx`` (per point for a filter, ``(K, N, n)`` for a fleet), ``x0``, ``P0``, ``Q``, ``R`` and a
    first measurement ``z``. Imports numpy itself: a child times ``import squkf`` before it."""
    import numpy as np

    def fx(x, dt):
        return np.stack([x[..., 0] + dt * x[..., 1], x[..., 1], x[..., 2] + dt * x[..., 3], x[..., 3]], -1)

    def hx(x):
        return np.stack([np.hypot(x[..., 0], x[..., 2]), np.arctan2(x[..., 2], x[..., 0])], -1)

    x0 = np.array([1000.0, 5.0, 1500.0, -3.0])
    P0 = np.diag([30.0**2, 2.0**2, 30.0**2, 2.0**2])
    Q = np.kron(np.eye(2), 0.05 * np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]]))
    R = np.diag([5.0**2, 2e-3**2])
    return fx, hx, x0, P0, Q, R, hx(x0) + np.array([3.0, 1e-3])


def child(kind: str, K: int) -> None:
    """One measurement in this (fresh) process; prints a JSON line."""
    t0 = time.perf_counter()
    import squkf

    t1 = time.perf_counter()
    import numpy as np

    fx, hx, x0, P0, Q, R, z = radar()
    t2 = time.perf_counter()
    if kind == "filter":
        f = squkf.SquareRootUKF(4, 2, 1.0, hx, fx, squkf.MerweScaledWeights())
    else:
        f = squkf.Fleet(K, 4, 2, 1.0, hx, fx, squkf.MerweScaledWeights())
        z = np.broadcast_to(z, (K, 2)).copy()
    f.x, f.P, f.Q, f.R = x0, P0, Q, R
    t3 = time.perf_counter()
    f.predict()
    t4 = time.perf_counter()
    f.update(z)
    t5 = time.perf_counter()
    f.predict()
    f.update(z)
    t6 = time.perf_counter()
    print(
        json.dumps(
            {
                "import_s": t1 - t0,
                "build_s": t3 - t2,
                "first_predict_s": t4 - t3,
                "first_update_s": t5 - t4,
                "first_step_s": t5 - t3,
                "to_first_step_end_s": (t1 - t0) + (t5 - t2),
                "second_step_ms": 1e3 * (t6 - t5),
            }
        )
    )


#: The first uses after the default filter's first step, in order; the first four are the issue's sum.
FIRSTS = (
    "angle hooks", "batch_filter", "Fleet", "smoother", "a user's residual_z", "downdate form (a user's UT)",
    "partial z",
)  # fmt: skip
IN_SUM = FIRSTS[:4]


def firsts_child() -> None:
    """The default filter's first step on an empty cache, then each first use; prints a JSON line."""
    import numpy as np

    import squkf
    from squkf.angles import AngleMean, AngleResidual

    try:  # which kernels each first use compiled (squkf's compile counter, where the revision has one)
        from squkf.kernels.cache import compiled
    except ImportError:
        compiled = dict

    fx, hx, x0, P0, Q, R, z = radar()
    zs = [z + 0.1 * k for k in range(5)]

    def made(cls=squkf.SquareRootUKF, *first, **hooks):
        f = cls(*first, 4, 2, 1.0, hx, fx, squkf.MerweScaledWeights(), **hooks)
        f.x, f.P, f.Q, f.R = x0, P0, Q, R
        return f

    def step(f, zk=z, **kw):
        f.predict(**kw)
        f.update(zk, **kw)

    def users_ut(*args):
        return squkf.sqrt_unscented_transform(*args)

    def users_residual_z(a, b):  # a radar user's first addition: the bearing wrapped
        d = np.subtract(a, b)
        d[..., 1] = (d[..., 1] + np.pi) % (2 * np.pi) - np.pi
        return d

    def fleet():
        step(made(squkf.Fleet, 1000), np.broadcast_to(z, (1000, 2)).copy())

    def smoother():
        f = made()
        f.rts_smoother(*f.batch_filter(zs)[:2])

    uses = {
        "default filter": lambda: step(made()),
        "angle hooks": lambda: step(made(z_mean_fn=AngleMean([1]), residual_z=AngleResidual([1]))),
        "batch_filter": lambda: made().batch_filter(zs),
        "Fleet": fleet,
        "smoother": smoother,
        "a user's residual_z": lambda: step(made(residual_z=users_residual_z)),
        "downdate form (a user's UT)": lambda: step(made(), UT=users_ut),
        "partial z": lambda: step(made(), np.array([np.nan, z[1]])),
    }
    out = {}
    for label, use in uses.items():
        before = compiled()
        t = time.perf_counter()
        use()
        seconds = time.perf_counter() - t
        after = compiled()
        kernels = sorted(k for k in after if k.endswith("_kernel") and after[k] > before.get(k, 0))
        out[label] = {"s": seconds, "kernels": kernels}
    print(json.dumps(out))


def run_child(kind: str, K: int, cache: Path, tree: Path | None = None) -> dict:
    """One child on ``cache``; ``tree``: a folder with the ``squkf`` package to import instead of this one."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    env.update({v: "1" for v in THREAD_VARS})
    if tree is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(tree), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", kind, "--K", str(K)]
    env.setdefault("SQUKF_QUIET_COMPILE", "1")
    t = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=str(HERE))
    wall = time.perf_counter() - t
    if p.returncode:
        raise RuntimeError(f"child {kind} failed:\n{p.stderr[-4000:]}")
    out = json.loads(p.stdout.strip().splitlines()[-1])
    out["process_s"] = wall
    return out


def cold_against(refs: list[str], rounds: int, K: int, log) -> tuple[list, dict[str, list[dict]]]:
    """Cold compiles (build + first predict + update, s) of this tree and of each revision, alternating;
    and each tree's first uses (:func:`firsts_child`) per round."""
    trees: list[tuple[str, Path | None]] = [("this tree", None)]
    with tempfile.TemporaryDirectory(prefix="squkf_revisions_") as tmp:
        for rev in refs:
            trees.append((rev, export_package(rev, Path(tmp) / rev)))
        times: dict[str, dict[str, list[float]]] = {label: {"filter": [], "fleet": []} for label, _ in trees}
        firsts: dict[str, list[dict]] = {label: [] for label, _ in trees}
        for i in range(rounds):
            for label, tree in trees:
                cache = Path(tempfile.mkdtemp(prefix="squkf_numba_cache_firsts_"))
                try:
                    firsts[label].append(run_child("firsts", K, cache, tree))
                finally:
                    shutil.rmtree(cache, ignore_errors=True)
                log(f"round {i + 1}, {label}, first uses: {json.dumps(firsts[label][-1])}")
                for kind in ("filter", "fleet"):
                    cache = Path(tempfile.mkdtemp(prefix=f"squkf_numba_cache_{kind}_"))
                    try:
                        r = run_child(kind, K, cache, tree)
                    finally:
                        shutil.rmtree(cache, ignore_errors=True)
                    times[label][kind].append(r["build_s"] + r["first_step_s"])
                    log(f"round {i + 1}, {label}, {kind}, cold: {times[label][kind][-1]:.2f} s")
    return list(times.items()), firsts


def firsts_markdown(firsts: dict[str, list[dict]]) -> list[str]:
    """The first uses after the default filter's first step, per tree: medians over rounds (ranges)."""
    labels = list(firsts)
    rounds = len(firsts[labels[0]])
    lines = [
        "",
        f"## First uses after the default filter's first step ({rounds} rounds, one new empty cache each)",
        "",
        "One process per tree and round: the default filter's first step fills the cache, then each first "
        "use in this order, timed (s; median over rounds, range in brackets) with the kernels it compiled. "
        f"The sum is of the first four ({', '.join(IN_SUM)}); issue 36's target: at most 2 s.",
        "",
        "| first use | " + " | ".join(f"{label} s | {label}: kernels compiled" for label in labels) + " |",
        "|---|" + "---|---|" * len(labels),
    ]

    def cell(label: str, key: str) -> str:
        values = [r[key]["s"] for r in firsts[label]]
        kernels = sorted({k for r in firsts[label] for k in r[key]["kernels"]})
        span = f"{statistics.median(values):.2f} ({min(values):.2f}-{max(values):.2f})"
        return f"{span} | {', '.join(kernels) or 'none'}"

    for key in ("default filter", *FIRSTS):
        lines.append(f"| {key} | " + " | ".join(cell(label, key) for label in labels) + " |")
    sums = []
    for label in labels:
        values = [sum(r[k]["s"] for k in IN_SUM) for r in firsts[label]]
        sums.append(f"{statistics.median(values):.2f} ({min(values):.2f}-{max(values):.2f}) | ")
    lines.append(f"| sum of {', '.join(IN_SUM)} | " + " | ".join(sums) + " |")
    return lines


def against_markdown(table: list[tuple[str, dict[str, list[float]]]], K: int) -> list[str]:
    """The table of :func:`cold_against`: medians, and this tree's time over each revision's."""
    rounds = len(table[0][1]["filter"])
    lines = [
        "",
        f"## Cold compile against earlier revisions ({rounds} alternating rounds)",
        "",
        "Build + first predict + update on an empty cache, median over the rounds; the ratio is the median "
        "over rounds of this tree's time divided by the revision's in that round.",
        "",
        f"| tree | default SquareRootUKF s | ratio | default Fleet, K = {K:,} s | ratio |",
        "|---|---|---|---|---|",
    ]
    mine = table[0][1]
    for label, times in table:
        cells = []
        for kind in ("filter", "fleet"):
            ratio = statistics.median(a / b for a, b in zip(mine[kind], times[kind]))
            cells += [f"{statistics.median(times[kind]):.2f}", f"{ratio:.2f}"]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines


def cache_files(cache: Path) -> tuple[int, float]:
    files = [p for p in cache.rglob("*") if p.is_file()]
    return len(files), sum(p.stat().st_size for p in files) / 1e6


def median_run(runs: list[dict]) -> dict:
    return {k: statistics.median(r[k] for r in runs) for k in runs[0]}


def versions() -> str:
    import numba
    import numpy as np

    sys.path.insert(0, str(HERE))
    from machine import cpu_name

    return (
        f"Machine: {cpu_name()}, {os.cpu_count()} cores; Python {platform.python_version()}, "
        f"numpy {np.__version__}, numba {numba.__version__}; BLAS threads: 1."
    )


def write_markdown(
    out: Path, rows: list[tuple[str, str, int, dict]], files: dict, command: str, extra: list[str]
) -> str:
    lines = [
        "# Compile time and the first step of a new process",
        "",
        f"Produced by `{command}`; {versions()}",
        "",
        "Each row is a fresh process with `NUMBA_CACHE_DIR` set to a temporary directory (see the "
        "docstring of `benchmarks/compile_time.py`). Cached rows are medians over their processes. "
        '"import to end of first step" is `import squkf` + building the filter + its first predict + '
        'update; "process" adds the interpreter\'s start-up and exit.',
        "",
        "| configuration | cache | processes | import squkf s | build s | first predict s | first update s "
        "| first predict + update s | import to end of first step s | process s | second step ms |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for config, cache, n, r in rows:
        lines.append(
            f"| {config} | {cache} | {n} | {r['import_s']:.2f} | {r['build_s']:.3f} | "
            f"{r['first_predict_s']:.2f} | {r['first_update_s']:.2f} | {r['first_step_s']:.2f} | "
            f"{r['to_first_step_end_s']:.2f} | {r['process_s']:.2f} | {r['second_step_ms']:.2f} |"
        )
    lines += ["", "Cache directories after the cold runs: "]
    lines[-1] += "; ".join(f"{k}: {n} files, {mb:.1f} MB" for k, (n, mb) in files.items()) + "."
    lines += [
        "",
        "## Targets",
        "",
        "| target | measured | met |",
        "|---|---|---|",
    ]
    for config, cache, _, r in rows:
        if cache == "cold (empty)":
            v = r["first_step_s"] + r["build_s"]
            lines.append(
                f"| {config}, cold cache: build + first predict + update <= {COLD_TARGET_S:g} s "
                f"| {v:.1f} s | {'yes' if v <= COLD_TARGET_S else 'no'} |"
            )
        elif cache == "cached":
            step, v = r["first_step_s"], r["to_first_step_end_s"]
            lines.append(
                f"| {config}, with the cache: the first predict + update of a new process <= "
                f"{CACHED_TARGET_S:g} s (issue 21) | {step:.2f} s "
                f"| {'yes' if step <= CACHED_TARGET_S else 'no'} |"
            )
            lines.append(
                f"| {config}, with the cache, stricter: import + build + first predict + update <= "
                f"{CACHED_TARGET_S:g} s | {v:.2f} s (`import squkf` {r['import_s']:.2f} s: numpy, scipy, "
                f"numba) | {'yes' if v <= CACHED_TARGET_S else 'no'} |"
            )
    text = "\n".join(lines + extra) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    (out / "compile.md").write_text(text)
    return text


def main(argv) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(HERE / "results"))
    ap.add_argument("--reps", type=int, default=3, help="processes per cached measurement")
    ap.add_argument("--K", type=int, default=1000, help="filters in the Fleet")
    ap.add_argument("--ref", action="append", default=[], help="also this git revision, cold")
    ap.add_argument("--cold-reps", type=int, default=3, help="alternating rounds against --ref")
    ap.add_argument("--child", choices=("filter", "fleet", "firsts"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child == "firsts":
        firsts_child()
        return 0
    if args.child:
        child(args.child, args.K)
        return 0
    log = lambda s: print(s, flush=True)  # noqa: E731
    fleet_label = f"default Fleet, K = {args.K:,}"
    rows, files, tmp = [], {}, []
    try:
        for kind, label in (("filter", "default SquareRootUKF"), ("fleet", fleet_label)):
            cache = Path(tempfile.mkdtemp(prefix=f"squkf_numba_cache_{kind}_"))
            tmp.append(cache)
            r = run_child(kind, args.K, cache)
            log(f"{label}, cold cache: {json.dumps(r)}")
            rows.append((label, "cold (empty)", 1, r))
            files[kind] = cache_files(cache)
            runs = []
            for _ in range(args.reps):
                runs.append(run_child(kind, args.K, cache))
                log(f"{label}, cached: {json.dumps(runs[-1])}")
            rows.append((label, "cached", args.reps, median_run(runs)))
        # the fleet on the cache that the filter alone filled
        r = run_child("fleet", args.K, tmp[0])
        log(f"{fleet_label}, the filter's cache: {json.dumps(r)}")
        rows.append((fleet_label, "filled by the filter alone", 1, r))
    finally:
        for d in tmp:
            shutil.rmtree(d, ignore_errors=True)
    extra: list[str] = []
    if args.ref:
        table, firsts = cold_against(args.ref, args.cold_reps, args.K, log)
        extra = against_markdown(table, args.K) + firsts_markdown(firsts)
    command = "python benchmarks/compile_time.py" + "".join(
        f" --{k} {v}" for k, v in (("reps", args.reps), ("K", args.K)) if v != ap.get_default(k)
    )
    command += "".join(f" --ref {rev}" for rev in args.ref)
    if args.ref and args.cold_reps != ap.get_default("cold_reps"):
        command += f" --cold-reps {args.cold_reps}"
    print(write_markdown(Path(args.out), rows, files, command, extra))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
