"""What a kernel's call costs from Python: 27 positional arguments against named records of them.

    python benchmarks/kernel_call.py            # results in benchmarks/results/kernel_call.md
    python benchmarks/kernel_call.py --quick

numba's dispatcher types every argument at each call before it finds the compiled code. An array
or a number is typed in C; a tuple (a named tuple of arrays among them) is typed element by element
through numba's Python ``typeof``. This script measures that difference in one process, on the
arguments of :func:`squkf.kernels.phases.joint_update_kernel` for one filter at n = 3, m = 2:

* ``positional``: a compiled function taking the 27 arguments as the kernel does;
* ``records``: the same function taking four named tuples (the inputs, the route's data, the
  outputs, the next first set) and unpacking them;
* ``kernel``: the real ``joint_update_kernel`` (its call and its arithmetic), for scale.

The two stand-ins have the same trivial body (one element written), so their difference is the
call alone. They are compiled in memory here (no cache), once, before anything is timed.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numba import njit

HERE = Path(__file__).resolve().parent


class Inputs(NamedTuple):
    H: np.ndarray
    zref: np.ndarray
    X: np.ndarray
    xref: np.ndarray
    z: np.ndarray
    R1_2: np.ndarray
    x: np.ndarray


class RouteData(NamedTuple):
    mode: int
    wm: np.ndarray
    scale: np.ndarray
    sign: np.ndarray
    pair: float


class Outputs(NamedTuple):
    zp: np.ndarray
    y: np.ndarray
    w: np.ndarray
    Sy: np.ndarray
    L21: np.ndarray
    dx: np.ndarray
    xpost: np.ndarray
    Spost: np.ndarray
    ll: np.ndarray
    ww: np.ndarray
    ld: np.ndarray
    status: np.ndarray


class FirstSet(NamedTuple):
    xi1: np.ndarray
    gamma1: float
    X1: np.ndarray


@njit(error_model="numpy")
def positional(H, zref, X, xref, z, R1_2, x, mode, wm, scale, sign, pair, zp, y, w, Sy, L21, dx, xpost, Spost,
               ll, ww, ld, status, xi1, gamma1, X1):  # fmt: skip
    status[0] = mode


@njit(error_model="numpy")
def records(inp, route, out, first):
    out.status[0] = route.mode


def arguments(n: int = 3, m: int = 2) -> tuple[Inputs, RouteData, Outputs, FirstSet]:
    """One filter's arguments of the joint update (read-only route data, as the plan hands them)."""
    N = 2 * n + 1
    rng = np.random.default_rng(0)

    def ro(a):
        a = np.ascontiguousarray(a, dtype=np.float64)
        a.setflags(write=False)
        return a

    inp = Inputs(
        rng.normal(size=(1, N, m)), np.zeros((1, m)), rng.normal(size=(1, N, n)), np.zeros((1, n)),
        rng.normal(size=(1, m)), np.eye(m)[None] * 0.1, rng.normal(size=(1, n)),
    )  # fmt: skip
    wm = np.full(N, 1.0 / N)
    route = RouteData(1, ro(wm), ro(np.sqrt(wm)), ro(np.ones(N)), 0.0)
    B = 1
    out = Outputs(
        np.empty((B, m)), np.empty((B, m)), np.empty((B, m)), np.empty((B, m, m)), np.empty((B, n, m)),
        np.empty((B, n)), np.empty((B, n)), np.empty((B, n, n)), np.empty(B), np.empty(B), np.empty(B),
        np.empty(B, dtype=np.int64),
    )  # fmt: skip
    first = FirstSet(ro(np.vstack([np.zeros(n), np.eye(n), -np.eye(n)])), 0.0, np.empty((B, N, n)))
    return inp, route, out, first


def per_call(fn, args: tuple, calls: int) -> float:
    """Seconds per call of ``fn(*args)``, over ``calls`` calls."""
    t0 = time.perf_counter()
    for _ in range(calls):
        fn(*args)
    return (time.perf_counter() - t0) / calls


def measure(calls: int, rounds: int) -> dict[str, list[float]]:
    from squkf.kernels.phases import joint_update_kernel

    inp, route, out, first = arguments()
    flat = (*inp, *route, *out, *first)
    # the real kernel: a mean-form update with no set drawn
    n = inp.X.shape[2]
    real = (*inp, *route, *out, first.xi1, first.gamma1, np.empty((0, first.X1.shape[1], n)))
    cases = {
        "positional": (positional, flat),
        "records": (records, (inp, route, out, first)),
        "kernel": (joint_update_kernel, real),
    }
    for fn, args in cases.values():  # compiled (or loaded) before timing
        fn(*args)
    times: dict[str, list[float]] = {k: [] for k in cases}
    for _ in range(rounds):  # interleaved rounds: a machine that slows for a while slows all alike
        for name, (fn, args) in cases.items():
            times[name].append(per_call(fn, args, calls))
    return times


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="a short run (smoke test)")
    p.add_argument("--out", type=Path, default=HERE / "results")
    a = p.parse_args(argv)
    calls, rounds = (2_000, 3) if a.quick else (50_000, 11)
    times = measure(calls, rounds)
    med = {k: statistics.median(v) * 1e6 for k, v in times.items()}
    lines = [
        "# A kernel's call from Python: positional arguments against named records",
        "",
        f"`python benchmarks/kernel_call.py{' --quick' if a.quick else ''}`: {calls} calls a round,"
        f" {rounds} interleaved rounds, median per call (µs). One filter, n = 3, m = 2.",
        "",
        "| call | µs | over positional |",
        "|---|---|---|",
    ]
    for k, v in med.items():
        lines.append(f"| {k} | {v:.3f} | {v / med['positional']:.2f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if not a.quick:
        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / "kernel_call.md").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
