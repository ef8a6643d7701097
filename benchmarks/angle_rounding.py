"""squkf's angle hooks, done by the kernels, against an earlier revision's Python hooks, from the same inputs.

    python benchmarks/angle_rounding.py                   # against 55f2ed6 (hooks called in Python)
    python benchmarks/angle_rounding.py --ref REV --cases 30

Issue 36 lets the routes through squkf's own angle hooks (``AngleMean``, ``AngleResidual``,
``AngleAdd``) differ from 55f2ed6 by rounding only. Both packages (the earlier one imported as
``squkf_ref``, :func:`against_revision.revision_folder`) build the same filter from the same
floats, a [range, bearing, heading] radar whose bearing sits near pi (the points' bearings wrap),
take one ``predict`` and one ``update``, and every record is compared. A run over many steps would
compare the rounding of every earlier step too, amplified by the dynamics.

Two measures are printed for each family (the worst over its schemes, hook sets and cases):

- normwise relative, ``max |a - b| / max |b|``, of ``x``, ``P``, ``S``, ``y``, ``K`` and the
  log-likelihood;
- for ``x``, ``y`` and the log-likelihood, the difference relative to the terms they are formed
  from, as ``tests/test_angles.py::rounding_of_terms`` measures it: ``x = x_prior + K y`` against
  ``max(|x_prior|, |x - x_prior|)``; ``y = z - z_pred`` against ``max |z|``; the log-likelihood
  against ``|log L| + ||S^-1 y|| max |z|`` (what ``y``'s rounding moves it by). Each sum rounds by
  about ``eps * sum |W| * |terms|``; with filterpy's Merwe set at alpha = 0.3 (``sum |W|`` = 21) a
  range of 100 predicted to 5e-13 leaves an innovation of 0.3 with 2e-12 of its own size.

The results go to ``benchmarks/results/angle_rounding.md``.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

RECORDS = ("x", "P", "S", "y", "K", "log_likelihood")
R = np.diag([0.25, 0.003**2 * 100, 0.02**2])
Q = np.diag([0.1, 0.1, 1e-4, 0.01])


def hx(X: np.ndarray) -> np.ndarray:
    """Range and bearing of [px, py] and the heading, for ``X[..., i]``."""
    return np.stack([np.hypot(X[..., 0], X[..., 1]), np.arctan2(X[..., 1], X[..., 0]), X[..., 2]], axis=-1)


def fx(X: np.ndarray, dt: float) -> np.ndarray:
    """State [px, py, heading, speed], turning."""
    return np.stack(
        [
            X[..., 0] + dt * np.cos(X[..., 2]) * X[..., 3],
            X[..., 1] + dt * np.sin(X[..., 2]) * X[..., 3],
            X[..., 2] + 0.8 * dt,
            X[..., 3],
        ],
        axis=-1,
    )


def families(lib) -> dict:
    """The sigma-point families of ``tests/test_angles.py``, of package ``lib``."""
    from filterpy.kalman import MerweScaledSigmaPoints

    return {
        "Merwe alpha=0.5": lambda: lib.MerweScaledWeights(alpha=0.5),
        "Merwe, negative rows": lambda: lib.MerweScaledWeights(alpha=0.5, beta=0.1, kappa=0.0),
        "Julier": lambda: lib.JulierWeights(kappa=1.0),
        "simplex": lambda: lib.SimplexWeights(),
        "filterpy's Merwe alpha=0.3 (W0 = -10.1)": lambda: MerweScaledSigmaPoints(4, 0.3, 2.0, 0.0),
    }


AUGMENTABLE = ("Merwe alpha=0.5", "Julier", "filterpy's Merwe alpha=0.3 (W0 = -10.1)")
HOOKS = ("residual", "mean", "both", "state")


def hooks(angles, which: str) -> dict:
    """squkf's angle hooks of module ``angles``: the bearing's, or every hook on the heading too."""
    if which == "state":
        return {
            "x_mean_fn": angles.AngleMean([2]), "residual_x": angles.AngleResidual([2]),
            "state_add": angles.AngleAdd([2]), "z_mean_fn": angles.AngleMean([1, 2]),
            "residual_z": angles.AngleResidual([1, 2]),
        }  # fmt: skip
    out = {}
    if which in ("residual", "both"):
        out["residual_z"] = angles.AngleResidual([1])
    if which in ("mean", "both"):
        out["z_mean_fn"] = angles.AngleMean([1])
    return out


def cases(n: int, which: str, seed: int = 1):
    """``n`` starts, covariances and measurements near the bearing's wrap (the heading's too for the state's
    hooks)."""
    rng = np.random.default_rng(seed)
    head = np.pi - 0.82 if which == "state" else 0.1
    D = np.diag([1.0, 1.0, 0.1, 0.3])
    for _ in range(n):
        x0 = np.array([-100.0, 0.4, head, 2.0]) + rng.normal(size=4) * [1.0, 1.5, 0.1, 0.2]
        A = rng.normal(size=(4, 4)) * 0.2
        P0 = np.diag([4.0, 4.0, 0.04, 0.25]) + D @ A @ A.T @ D
        truth = fx(x0 + rng.normal(size=4) * np.sqrt(np.diag(P0)), 1.0)
        z = hx(truth) + rng.normal(size=3) * np.sqrt(np.diag(R))
        z[1] = (z[1] + np.pi) % (2 * np.pi) - np.pi
        yield x0, P0, z


def one_update(lib, family, scheme: str, which: str, x0, P0, z) -> dict | None:
    """The records of one predict and update by package ``lib`` (None: it failed)."""
    f = lib.SquareRootUKF(
        4, 3, 1.0, hx, fx, family(), vectorized=True, scheme=scheme, **hooks(lib.angles, which)
    )
    f.x, f.P, f.Q, f.R = x0, P0, Q, R
    try:
        f.predict()
        x_prior = f.x.copy()
        f.update(z)
    except lib.SqukfError:
        return None
    out = {name: np.asarray(getattr(f, name), dtype=float) for name in RECORDS}
    out["x_prior"] = x_prior
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default="55f2ed6")
    ap.add_argument("--cases", type=int, default=30, help="cases per family, scheme and hook set")
    args = ap.parse_args(argv)

    from against_revision import revision_folder

    sys.path.insert(0, str(revision_folder(args.ref)))
    import squkf_ref
    import squkf_ref.angles  # noqa: F401

    import squkf
    import squkf.angles  # noqa: F401

    worst: dict = defaultdict(float)
    compared = 0
    ours, theirs = families(squkf), families(squkf_ref)
    for name in ours:
        for scheme in ("redrawn", "augmented"):
            if scheme == "augmented" and name not in AUGMENTABLE:
                continue
            for which in HOOKS:
                for x0, P0, z in cases(args.cases, which):
                    a = one_update(squkf, ours[name], scheme, which, x0, P0, z)
                    b = one_update(squkf_ref, theirs[name], scheme, which, x0, P0, z)
                    assert (a is None) == (b is None), (name, scheme, which)
                    if a is None or b is None:
                        continue
                    compared += 1
                    for rec in RECORDS:
                        diff = float(np.max(np.abs(a[rec] - b[rec])))
                        worst[name, rec] = max(worst[name, rec], diff / float(np.max(np.abs(b[rec]))))
                    # the sums' terms: x = x_prior + K y, y = z - z_pred
                    terms = {
                        "x": max(np.abs(b["x_prior"]).max(), np.abs(b["x"] - b["x_prior"]).max()),
                        "y": np.abs(z).max(),
                        "log_likelihood": abs(float(b["log_likelihood"]))
                        + np.abs(np.linalg.solve(b["S"], b["y"])).sum() * np.abs(z).max(),
                    }
                    for rec, scale in terms.items():
                        diff = float(np.max(np.abs(a[rec] - b[rec])))
                        worst[name, f"{rec} of its terms"] = max(
                            worst[name, f"{rec} of its terms"], diff / scale
                        )
    columns = (*RECORDS, "x of its terms", "y of its terms", "log_likelihood of its terms")
    lines = [
        f"# squkf's angle hooks by the kernels against {args.ref}'s Python hooks",
        "",
        f"One predict and update from the same floats, {compared} updates ({args.cases} cases per family,"
        " scheme and hook set; `python benchmarks/angle_rounding.py`). The worst normwise relative"
        " difference of each record, and of `x`, `y` and the log-likelihood in units of their terms"
        " (`x_prior` and `K y`; `z`; `log L` and `||S^-1 y|| |z|`).",
        "",
        "| family | " + " | ".join(columns) + " |",
        "|---|" + "---|" * len(columns),
    ]
    for name in ours:
        lines.append(f"| {name} | " + " | ".join(f"{worst[name, c]:.1e}" for c in columns) + " |")
    text = "\n".join(lines) + "\n"
    print(text)
    (HERE / "results" / "angle_rounding.md").write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
