"""This squkf against an earlier revision of itself, ratio to filterpy, in one process.

    python benchmarks/against_revision.py                 # against 6e83c62 (before the one-step core)
    python benchmarks/against_revision.py --ref REV --reps 15
    python benchmarks/against_revision.py --ref REV --scheme augmented --only 40 100

The earlier revision's ``squkf`` package is taken from git (``git archive``),
renamed ``squkf_ref`` in a temporary folder and imported beside this one (its
imports are all relative). Both run the same scenarios (``models.py``), per
point and vectorised, interleaved with filterpy's UKF over repetitions; each
repetition's time per step is divided by filterpy's in that repetition and
the median of those ratios is reported, so a machine that slows down for a
while slows all three alike. The last two columns divide this revision's
time by the earlier one's in each repetition (median over repetitions).
BLAS is held to one thread (set before numpy is imported).
"""

from __future__ import annotations

import argparse
import io
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS"):
    os.environ[_var] = "1"

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def export_package(rev: str, where: Path) -> Path:
    """Git revision ``rev``'s ``squkf`` package unpacked as ``where/squkf``; ``where`` returned."""
    data = subprocess.run(
        ["git", "archive", rev, "squkf"], cwd=HERE.parent, check=True, capture_output=True
    ).stdout
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(where, filter="data")
    return where


def _extract(rev: str, where: Path) -> None:
    """The ``squkf`` package of git revision ``rev`` as ``where/squkf_ref``."""
    export_package(rev, where)
    (where / "squkf").rename(where / "squkf_ref")


def load_revision(rev: str, where: Path):
    """Import the ``squkf`` package of git revision ``rev`` as ``squkf_ref``."""
    _extract(rev, where)
    sys.path.insert(0, str(where))
    import squkf_ref

    return squkf_ref


def revision_folder(rev: str) -> Path:
    """A folder holding ``squkf_ref``, the ``squkf`` package of ``rev``, extracted once per commit.

    It is kept in the system's temporary folder under the commit's name, so that numba's cache of
    its kernels (written beside them) serves the next run too; put the folder on ``sys.path`` and
    ``import squkf_ref``.
    """
    sha = subprocess.run(
        ["git", "rev-parse", "--verify", f"{rev}^{{commit}}"],
        cwd=HERE.parent,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    where = Path(tempfile.gettempdir()) / f"squkf_ref_{sha[:12]}"
    if not (where / "squkf_ref").is_dir():
        tmp = Path(tempfile.mkdtemp(prefix="squkf_ref_part_"))
        _extract(sha, tmp)
        try:
            tmp.rename(where)  # whole or not at all (another run may have made it meanwhile)
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
    return where


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default="6e83c62")
    ap.add_argument("--reps", type=int, default=11)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--scheme", default="redrawn", choices=("redrawn", "augmented"), help="the second set")
    ap.add_argument("--only", type=int, nargs="+", metavar="N", help="only these state dimensions")
    args = ap.parse_args(argv)

    import numpy as np
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
    from models import CoordinatedTurn, Lorenz96, Robot

    import squkf

    with tempfile.TemporaryDirectory() as tmp:
        ref = load_revision(args.ref, Path(tmp))

        def make(lib, sc, vectorized):
            if lib is None:
                pts = MerweScaledSigmaPoints(sc.dim_x, sc.alpha, sc.beta, sc.kappa)
                f = UnscentedKalmanFilter(sc.dim_x, sc.dim_z, sc.dt, sc.hx, sc.fx, pts)
            else:
                fx, hx = (sc.fx_vec, sc.hx_vec) if vectorized else (sc.fx, sc.hx)
                pts = lib.MerweScaledWeights(sc.alpha, sc.beta, sc.kappa)
                f = lib.SquareRootUKF(
                    sc.dim_x, sc.dim_z, sc.dt, hx, fx, pts, scheme=args.scheme, vectorized=vectorized
                )
            f.x, f.P, f.Q, f.R = sc.x0.copy(), sc.P0.copy(), sc.Q.copy(), sc.R.copy()
            return f

        def time_run(f, zs):
            t0 = time.perf_counter()
            for z in zs:
                f.predict()
                f.update(z)
            return (time.perf_counter() - t0) / len(zs)

        impls = [
            ("squkf per point", squkf, False),
            ("squkf vectorised", squkf, True),
            (f"{args.ref} per point", ref, False),
            (f"{args.ref} vectorised", ref, True),
        ]
        scenarios = [Robot(), CoordinatedTurn(), Lorenz96(40), Lorenz96(100)]
        if args.only:
            scenarios = [sc for sc in scenarios if sc.dim_x in args.only]
        heads = [name for name, _, _ in impls] + ["now / earlier, per point", "now / earlier, vectorised"]
        print(f"| scenario | {' | '.join(heads)} | filterpy µs/step |")
        print("|---|" + "---|" * (len(heads) + 1))
        for sc in scenarios:
            steps = args.steps if sc.dim_x < 100 else max(10, args.steps // 5)
            _, zs = sc.simulate(steps, seed=1)
            ratios = {name: [] for name, _, _ in impls}
            base = []
            for _ in range(args.reps):
                t_fp = time_run(make(None, sc, False), zs)
                base.append(t_fp)
                for name, lib, vec in impls:
                    ratios[name].append(time_run(make(lib, sc, vec), zs) / t_fp)
            cells = [f"{np.median(ratios[name]):.3f}" for name, _, _ in impls]
            for now, earlier in ((impls[0][0], impls[2][0]), (impls[1][0], impls[3][0])):
                # the two revisions' times in the same repetition, divided: filterpy's noise drops out
                cells.append(f"{np.median(np.divide(ratios[now], ratios[earlier])):.3f}")
            print(f"| {sc.name} | {' | '.join(cells)} | {1e6 * np.median(base):.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
