"""What the one-BLAS-thread hold costs and what it saves: threadpoolctl hold against the old ctypes one.

    python benchmarks/blas_hold.py            # about a minute
    python benchmarks/blas_hold.py --quick    # a few seconds

Run with the BLAS library's default threading (no ``*_NUM_THREADS`` set). It
times entering and leaving :func:`squkf.blas.one_blas_thread` (the hold on
threadpoolctl) and the ctypes hold it replaced (``squkf/blas.py`` at
``--old-rev``, loaded from git), with the BLAS at its default count (the hold
sets and restores) and pinned to one thread (it only reads); then a whole
squkf step (predict + update, Lorenz-96, vectorised ``fx``) with no hold, the
old hold and the new one, and with the BLAS pinned to one thread and no hold,
for Lorenz-96 states from n = 8 to 100 (fewer steps from n = 64). Medians over
interleaved repetitions; the figures go to stdout as markdown.
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
OLD_REV = "bf18f7777fc785945b7ea5d746efb2255fa0d203"  # the last ctypes squkf/blas.py

from models import Lorenz96  # noqa: E402

import squkf  # noqa: E402
from squkf import MerweScaledWeights, SquareRootUKF, blas  # noqa: E402


def load_old(rev: str):
    """The ctypes ``squkf.blas`` of ``rev``, imported from a temporary file under another name."""
    src = subprocess.run(
        ["git", "show", f"{rev}:squkf/blas.py"], cwd=HERE.parent, capture_output=True, text=True, check=True
    ).stdout
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as fh:
        fh.write(src)
    spec = importlib.util.spec_from_file_location("squkf_blas_ctypes", fh.name)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def blas_libs():
    import threadpoolctl

    return threadpoolctl.ThreadpoolController().select(user_api="blas").lib_controllers


def set_counts(libs, counts) -> None:
    import threadpoolctl

    for lib, n in zip(libs, counts):
        lib.set_num_threads(n)
    release = getattr(threadpoolctl.OpenBLASController, "clear_controlling_thread", None)
    if release is not None:
        release()


def hold_us(hold, loops: int) -> float:
    """Microseconds per enter + exit of ``hold()``."""
    t = time.perf_counter()
    for _ in range(loops):
        with hold():
            pass
    return (time.perf_counter() - t) / loops * 1e6


def make_filter(sc: Lorenz96) -> SquareRootUKF:
    f = SquareRootUKF(
        sc.dim_x, sc.dim_z, sc.dt, sc.hx_vec, sc.fx_vec, MerweScaledWeights(sc.alpha, sc.beta, sc.kappa),
        vectorized=True,
    )  # fmt: skip
    f.x, f.P, f.Q, f.R = sc.x0.copy(), sc.P0.copy(), sc.Q.copy(), sc.R.copy()
    return f


def step_ms(sc: Lorenz96, zs, hold) -> float:
    """Milliseconds per predict + update over ``zs``, with ``hold`` as squkf's hold (None: no hold)."""
    saved = blas.MIN_DIM, blas.one_blas_thread
    blas.MIN_DIM = None if hold is None else 1
    if hold is not None:
        blas.one_blas_thread = hold
    try:
        f = make_filter(sc)
        t = time.perf_counter()
        for z in zs:
            f.predict()
            f.update(z)
        return (time.perf_counter() - t) / len(zs) * 1e3
    finally:
        blas.MIN_DIM, blas.one_blas_thread = saved


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--old-rev", default=OLD_REV)
    ap.add_argument("--dims", default="8,16,24,32,40,48,56,64,72,80,100", help="Lorenz-96 sizes (a,b,...)")
    args = ap.parse_args(argv)
    reps, loops, steps = (3, 2000, 20) if args.quick else (7, 20000, 200)
    dims = [int(d) for d in args.dims.split(",")]

    old = load_old(args.old_rev)
    new = blas.one_blas_thread
    libs = blas_libs()
    default = [lib.get_num_threads() for lib in libs]
    print(f"squkf {squkf.__file__}; numpy {np.__version__}")
    for lib in libs:
        print(f"- {lib.internal_api} {lib.version} ({getattr(lib, 'threading_layer', '?')}): {lib.filepath}")
    print(f"old hold finds {len(old.blas_controls())} libraries; new finds {len(libs)}\n")

    print("| hold, us per enter + exit | BLAS at default count " + str(default) + " | BLAS at 1 |")
    print("|---|---|---|")
    with new():  # the first hold looks the libraries up: not part of the per-step cost
        pass
    for name, hold in (("old (ctypes)", old.one_blas_thread), ("new (threadpoolctl)", new)):
        row = []
        for counts in (default, [1] * len(libs)):
            set_counts(libs, counts)
            row.append(statistics.median(hold_us(hold, loops) for _ in range(reps)))
        set_counts(libs, default)
        print(f"| {name} | {row[0]:.2f} | {row[1]:.2f} |")

    print(
        "\n| Lorenz-96 step, ms (vectorised fx) | no hold | old hold | new hold | new / no hold "
        "| BLAS pinned to 1, no hold |"
    )
    print("|---|---|---|---|---|---|")
    for n in dims:
        sc = Lorenz96(n)
        _, zs = sc.simulate(steps if n < 64 else max(steps // 5, 10), seed=1)
        holds = {"none": None, "old": old.one_blas_thread, "new": new, "pinned": None}
        times = {k: [] for k in holds}
        for _ in range(reps):
            for k, h in holds.items():
                if k == "pinned":
                    set_counts(libs, [1] * len(libs))
                try:
                    times[k].append(step_ms(sc, zs, h))
                finally:
                    set_counts(libs, default)
        med = {k: statistics.median(v) for k, v in times.items()}
        print(
            f"| n = {n} | {med['none']:.3f} | {med['old']:.3f} | {med['new']:.3f} | "
            f"{med['new'] / med['none']:.2f} | {med['pinned']:.3f} |"
        )
    print(f"\nMIN_DIM today: {blas.MIN_DIM}; counts at the end: {[lib.get_num_threads() for lib in libs]}")


if __name__ == "__main__":
    main()
