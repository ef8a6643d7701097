"""The Python a filter's step runs in squkf's own files: calls, depth and modules per step.

    python benchmarks/python_per_step.py            # the tables, and the issue's targets
    python benchmarks/python_per_step.py --calls    # also every function called, with its count
    python benchmarks/python_per_step.py --ref 0cdce8e   # the fleet's reference revision (default)

One ``SquareRootUKF`` ``predict()`` + ``update(z)`` of the g13ej robot (``benchmarks/models.py``,
Merwe(1, 2, 0), the redrawn second set), in steady state (after warm-up steps), traced with
``sys.setprofile``:

* calls: the ``call`` events whose code lives under the ``squkf/`` package, comprehensions and
  generators included (a model function of the benchmark is not squkf's);
* depth: the most squkf frames on the stack at once, the public method counting as 1;
* modules: how many of squkf's modules the step enters.

Vectorised and per point. The issue's per-point targets are the vectorised ones plus one call per
model evaluation; a model function's calls are not counted here (it is not squkf's code), so the
same limits apply to the counts shown. Counts, not times: they do not depend on the machine's load.

A fleet's step, in the same way: ``Fleet.predict()`` + ``update(z)`` of 2048 filters of a constant
velocity model with a range-bearing sensor (one chunk), its calls in the package's files, against
the same step of the revision ``--ref`` (its ``squkf`` package extracted beside this run,
``against_revision.revision_folder``). The issue's target: at most half the reference's Python per chunk.
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from models import Robot  # noqa: E402

import squkf  # noqa: E402

ROOT = os.path.dirname(os.path.abspath(squkf.__file__)) + os.sep
TARGETS = {"calls": 50, "depth": 5, "modules": 8}


def robot_filter(vectorized: bool) -> tuple[squkf.SquareRootUKF, list[np.ndarray]]:
    sc = Robot()
    if vectorized:

        def fx(X, dt):
            th = X[..., 2]
            return np.stack([X[..., 0] + np.cos(th) * sc.t1, X[..., 1] + np.sin(th) * sc.t1, th + sc.t3], -1)

        def hx(X):
            return np.stack([sc.Delta - X[..., 0] * sc.cA - X[..., 1] * sc.sA, X[..., 2] - sc.A], -1)

    else:
        fx, hx = sc.fx, sc.hx
    f = squkf.SquareRootUKF(
        3, 2, sc.dt, hx, fx, squkf.MerweScaledWeights(sc.alpha, sc.beta, sc.kappa), vectorized=vectorized
    )
    f.x, f.P, f.Q, f.R = sc.x0, sc.P0, sc.Q, sc.R
    _, zs = sc.simulate(50, 1)
    return f, [np.asarray(z, dtype=float) for z in zs]


def trace_step(f, z, root: str = ROOT) -> dict:
    """One predict + update, traced: the calls in the package at ``root``, their deepest nesting and the
    modules entered."""
    depth = 0
    deepest = 0
    calls: collections.Counter = collections.Counter()
    modules: set[str] = set()

    def profile(frame, event, arg):
        nonlocal depth, deepest
        if event not in ("call", "return"):
            return
        code = frame.f_code
        if not code.co_filename.startswith(root):
            return
        if event == "call":
            depth += 1
            deepest = max(deepest, depth)
            module = code.co_filename[len(root) :].removesuffix(".py").replace(os.sep, ".")
            calls[(module, code.co_name)] += 1
            modules.add(module)
        else:
            depth -= 1

    sys.setprofile(profile)
    try:
        f.predict()
        f.update(z)
    finally:
        sys.setprofile(None)
    # predict and update are each the public method at depth 1
    return {"calls": sum(calls.values()), "depth": deepest, "modules": len(modules), "by_function": calls}


def measure(steps: int = 10) -> dict[str, dict]:
    """``trace_step`` of the vectorised and the per-point robot filter after ``steps`` warm-up steps."""
    found = {}
    for vectorized in (True, False):
        f, zs = robot_filter(vectorized)
        for z in zs[:steps]:  # steady state: the routes decided, the kernels loaded
            f.predict()
            f.update(z)
        found["vectorised" if vectorized else "per point"] = trace_step(f, zs[steps])
    return found


FLEET_K = 2048  # one chunk of the default size


def fleet_calls(package) -> dict:
    """``trace_step`` of one steady step of a fleet of :data:`FLEET_K` filters built with ``package``
    (this squkf, or a reference revision's)."""

    def fx(X, dt):
        return np.stack([X[..., 0] + dt * X[..., 1], X[..., 1], X[..., 2] + dt * X[..., 3], X[..., 3]], -1)

    def hx(X):
        return np.stack([np.hypot(X[..., 0], X[..., 2]), np.arctan2(X[..., 2], X[..., 0])], -1)

    x0 = np.array([1000.0, 5.0, 1500.0, -3.0])
    f = package.Fleet(FLEET_K, 4, 2, 1.0, hx, fx, package.MerweScaledWeights())
    f.x, f.P, f.Q, f.R = x0, np.diag([900.0, 4, 900, 4]), 0.01 * np.eye(4), np.diag([25.0, 4e-6])
    z = np.broadcast_to(hx(x0), (FLEET_K, 2)).copy()
    for _ in range(3):
        f.predict()
        f.update(z)
    return trace_step(f, z, os.path.dirname(os.path.abspath(package.__file__)) + os.sep)


def fleet_table(now: dict, ref: dict | None, rev: str) -> list[str]:
    """The fleet's counts beside the reference's, and the target (at most half the reference's calls)."""
    lines = [
        f"| Fleet step, K = {FLEET_K} (one chunk) | calls in the package | deepest frames | modules |",
        "|---|---|---|---|",
        f"| this revision | {now['calls']} | {now['depth']} | {now['modules']} |",
    ]
    if ref is None:
        return [*lines, "", "- the reference revision was not measured: target not measured"]
    ratio = now["calls"] / ref["calls"]
    met = "met" if ratio <= 0.5 else "not met"
    return [
        *lines,
        f"| {rev} | {ref['calls']} | {ref['depth']} | {ref['modules']} |",
        "",
        f"- fleet: calls per chunk {now['calls']} / {ref['calls']} = {ratio:.2f} of {rev}'s (<= 0.5: {met})",
    ]


def reference_fleet_calls(rev: str) -> dict | None:
    """:func:`fleet_calls` of the revision ``rev``'s package, or None where it cannot be extracted."""
    from against_revision import revision_folder

    try:
        folder = revision_folder(rev)
    except Exception as exc:  # no git, or the revision is not in this clone
        print(f"(the fleet's reference {rev} could not be extracted: {exc})", file=sys.stderr)
        return None
    sys.path.insert(0, str(folder))
    import squkf_ref

    return fleet_calls(squkf_ref)


def table(found: dict[str, dict]) -> list[str]:
    """The counts as a markdown table, and each target of the vectorised step beside its count."""
    lines = [
        "| route | squkf calls per step | deepest squkf frames | squkf modules entered |",
        "|---|---|---|---|",
    ]
    lines += [f"| {name} | {r['calls']} | {r['depth']} | {r['modules']} |" for name, r in found.items()]
    lines.append("")
    # per point the target adds one call per model evaluation, and the model functions are not
    # squkf's files: the counts above do not include them, so the limits are the same
    for name, r in found.items():
        reached = ", ".join(
            f"{key} {r[key]} (<= {limit}: {'met' if r[key] <= limit else 'not met'})"
            for key, limit in TARGETS.items()
        )
        lines.append(f"- {name}: {reached}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", action="store_true", help="list every function called")
    parser.add_argument("--ref", default="0cdce8e", help="the fleet's reference revision ('' for none)")
    args = parser.parse_args()
    print(f"Python {sys.version.split()[0]}, numpy {np.__version__}; squkf at {ROOT}")
    print()
    found = measure()
    print("\n".join(table(found)))
    fleet_now = fleet_calls(squkf)
    fleet_ref = reference_fleet_calls(args.ref) if args.ref else None
    print()
    print("\n".join(fleet_table(fleet_now, fleet_ref, args.ref)))
    if args.calls:
        found = {**found, "fleet": fleet_now}
        for name, r in found.items():
            print(f"\n{name}:")
            for (module, fn), count in sorted(r["by_function"].items(), key=lambda kv: -kv[1]):
                print(f"  {count:4d}  {module}.{fn}")


if __name__ == "__main__":
    main()
