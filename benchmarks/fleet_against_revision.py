"""The fleet of this squkf against an earlier revision's, interleaved in one process.

    python benchmarks/fleet_against_revision.py --ref REV                # n = 4 and 10, K = 10^4
    python benchmarks/fleet_against_revision.py --ref REV --K 1000 --reps 11

Both revisions' ``Fleet`` run the same measurements of ``fleet.py``'s models,
one after the other in each repetition (the earlier revision's package is
imported as ``squkf_ref``, as in ``against_revision.py``); the ratio of their
times in each repetition is reported, median and range over repetitions, so
a machine that slows down for a while slows both alike. BLAS is held to one
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
    ap.add_argument("--ref", required=True)
    ap.add_argument("--K", type=int, default=10_000)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--models", nargs="+", choices=("n4", "n10"), default=["n4", "n10"])
    args = ap.parse_args(argv)

    import numpy as np
    from against_revision import load_revision
    from fleet import ALPHA, BETA, KAPPA, ConstantVelocity, Oscillators, simulate

    import squkf

    def run(lib, model, zs):
        f = lib.Fleet(
            zs.shape[0],
            model.n,
            model.m,
            model.dt,
            model.hx,
            model.fx,
            lib.MerweScaledWeights(ALPHA, BETA, KAPPA),
        )
        f.x, f.P, f.Q, f.R = model.x0, model.P0, model.Q, model.R
        t0 = time.perf_counter()
        for t in range(zs.shape[1]):
            f.predict()
            f.update(zs[:, t])
        return (time.perf_counter() - t0) / zs.shape[0] / zs.shape[1]

    with tempfile.TemporaryDirectory() as tmp:
        ref = load_revision(args.ref, Path(tmp))
        print(f"| model | K | now µs/filter-step | {args.ref} µs/filter-step | now / {args.ref} (min-max) |")
        print("|---|---|---|---|---|")
        models = {"n4": ConstantVelocity, "n10": Oscillators}
        for key in args.models:
            model = models[key]()
            _, zs = simulate(model, args.K, args.steps, seed=1)
            run(squkf, model, zs[:, :2])  # compile or load the kernels of both
            run(ref, model, zs[:, :2])
            now, earlier = [], []
            for _ in range(args.reps):
                now.append(run(squkf, model, zs))
                earlier.append(run(ref, model, zs))
            r = np.divide(now, earlier)
            print(
                f"| {model.name} | {args.K} | {1e6 * np.median(now):.2f} | {1e6 * np.median(earlier):.2f} | "
                f"{np.median(r):.3f} ({r.min():.3f}-{r.max():.3f}) |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
