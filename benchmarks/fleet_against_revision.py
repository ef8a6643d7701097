"""``Fleet`` against an earlier revision of itself, in one process (the additive, ungated step).

    python benchmarks/fleet_against_revision.py --ref 0e7465f
    python benchmarks/fleet_against_revision.py --ref REV --K 10000 --steps 20 --reps 9

The earlier revision's package is imported beside this one as ``squkf_ref``
(:func:`against_revision.load_revision`). Both run the fleet benchmark's
constant-velocity, range-bearing model (n = 4, m = 2; ``fleet.ConstantVelocity``)
on the same measurements, one ``predict`` and one ``update`` per step,
interleaved over repetitions (their order alternated); the table gives each
one's median time per filter-step and the median of the per-repetition
ratios, which is what a shared machine's load cancels out of. BLAS on one
thread (set before numpy is imported).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS"):
    os.environ[_var] = "1"

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default="0e7465f")
    ap.add_argument("--K", type=int, default=10_000)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--reps", type=int, default=9)
    args = ap.parse_args(argv)

    import numpy as np
    from against_revision import load_revision
    from fleet import ALPHA, BETA, KAPPA, ConstantVelocity, simulate

    import squkf

    model = ConstantVelocity()
    _, zs = simulate(model, args.K, args.steps, seed=1)
    with tempfile.TemporaryDirectory() as tmp:
        ref = load_revision(args.ref, Path(tmp))

        def run(lib) -> float:
            f = lib.Fleet(
                args.K,
                model.n,
                model.m,
                model.dt,
                model.hx,
                model.fx,
                lib.MerweScaledWeights(ALPHA, BETA, KAPPA),
            )
            f.x, f.P, f.Q, f.R = model.x0, model.P0, model.Q, model.R
            t0 = time.perf_counter()
            for t in range(args.steps):
                f.predict()
                f.update(zs[:, t])
            return (time.perf_counter() - t0) / (args.K * args.steps)

        run(squkf), run(ref)  # kernels compiled or loaded, pages touched
        now, earlier = [], []
        for rep in range(args.reps):
            pair = (squkf, ref) if rep % 2 == 0 else (ref, squkf)
            times = {id(lib): run(lib) for lib in pair}
            now.append(times[id(squkf)])
            earlier.append(times[id(ref)])
    print(f"| K | this revision, µs per filter-step | {args.ref} | this / {args.ref} |")
    print("|---|---|---|---|")
    print(
        f"| {args.K} | {1e6 * np.median(now):.3f} | {1e6 * np.median(earlier):.3f} |"
        f" {np.median(np.divide(now, earlier)):.3f} |"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
