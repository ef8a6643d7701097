"""Lower bounds for the library's own time per step, measured on this machine.

    python benchmarks/floor.py              # check the inlined step against SquareRootUKF, bit for bit

Two references, neither of them a filter anyone should use:

- ``qr_ms``: the two QR factorisations a square-root step needs (the prior's
  ``(N + n) x n`` rows and the update's joint ``(N + m) x (m + n)`` rows),
  timed alone on fresh random rows with LAPACK's ``dgeqrfp``.
- ``inline_impls``: the library's default step (redrawn Merwe points, the
  fused route of :mod:`squkf.engine`) written as one straight function: the
  same two kernels of :data:`squkf.kernels.table.KERNELS` called directly (after
  ``fx``, the transform kernel gives the prior and the second set; after
  ``hx``, the joint-update kernel gives the posterior and the next first set)
  into buffers allocated once, with no validation, no error handling, no
  bookkeeping of filterpy's attributes and no support for anything else.
  It gives the same numbers as ``SquareRootUKF``, bit for bit, so the gap
  between the two is the price of the library's checks and interface, and the
  gap between it and filterpy is all the library can win with these kernels.

``step_profile`` splits one ``SquareRootUKF`` step into the same kernel calls,
the checks of what the model functions and the caller bring, and the rest.
"""

from __future__ import annotations

import argparse
import sys
import time
from types import SimpleNamespace

import numpy as np
from peers import Impl
from scipy.linalg import lapack

_geqrfp = lapack.get_lapack_funcs("geqrfp", dtype=np.float64)  # R with a non-negative diagonal


def qr_ms(n: int, m: int, N: int, reps: int = 300) -> float:
    """Milliseconds for the step's two QR factorisations (median of ``reps``)."""
    rng = np.random.default_rng(0)
    A = np.asfortranarray(rng.standard_normal((N + n, n)))
    M = np.asfortranarray(rng.standard_normal((N + m, m + n)))
    times = []
    for _ in range(reps):
        a, b = A.copy(order="F"), M.copy(order="F")  # fresh rows: QR overwrites its input
        t = time.perf_counter()
        _geqrfp(a, overwrite_a=1)
        _geqrfp(b, overwrite_a=1)
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def library_filter(sc, fx, hx, vectorized: bool):
    """The ``SquareRootUKF`` of scenario ``sc`` (default scheme), set up as the benchmark's."""
    from squkf import MerweScaledWeights, SquareRootUKF

    pts = MerweScaledWeights(sc.alpha, sc.beta, sc.kappa)
    f = SquareRootUKF(sc.dim_x, sc.dim_z, sc.dt, hx, fx, pts, vectorized=vectorized)
    f.x, f.P, f.Q, f.R = sc.x0.copy(), sc.P0.copy(), sc.Q.copy(), sc.R.copy()
    return f


def fused_route(f) -> SimpleNamespace:
    """The kernel arguments of ``f``'s default (fused) step, read once from its plan and route.

    ``f`` is a ``SquareRootUKF`` with the redrawn second set and no hooks; the buffers are a
    block of one filter, allocated here, and the state is ``f``'s current estimate.
    """
    from squkf.generators import SigmaSet
    from squkf.kernels.table import KERNELS, kernel_array, no_set, zeros_row

    plan, engine = f._plan, f._engine
    route = engine.route
    n, m, N = plan.n, f.dim_z, plan.num_sigmas
    fused = plan.fused_draw
    if fused is None or fused.augmented or route.hooks.state_add is not None:
        raise ValueError("the inlined step is the redrawn scheme's fused route only")
    N2 = fused.xi.shape[0]
    r = SimpleNamespace(n=n, m=m, N=N, N2=N2, plan=plan, fused=fused, kernels=KERNELS)
    r.zeros_n, r.zeros_m = zeros_row(n), zeros_row(m)
    r.Q = kernel_array(f._Q.factor()[None])
    r.R = kernel_array(f._R.factor()[None])
    # the prediction's outputs: the prior, its status, the second set and its offsets
    r.mean, r.S, r.status = np.empty((1, n)), np.empty((1, n, n)), np.empty(1, dtype=np.int64)
    r.X2, r.D2 = np.empty((1, N2, n)), np.empty((1, N2, n))
    # the update's outputs: records, the posterior and the next first set
    r.zp, r.y, r.w, r.Sy = np.empty((1, m)), np.empty((1, m)), np.empty((1, m)), np.empty((1, m, m))
    r.L21, r.dx, r.x, r.Spost = np.empty((1, n, m)), np.empty((1, n)), np.empty((1, n)), np.empty((1, n, n))
    r.ll, r.ww, r.ld, r.ustatus = np.empty(1), np.empty(1), np.empty(1), np.empty(1, dtype=np.int64)
    r.X1 = np.empty((1, N, n))
    rows = fused.rows
    sset = SigmaSet(r.X2, rows.Wm, rows.Wc, fused.exact, r.D2, rows, fused.axis)
    joint = route.update_route(sset, None)  # the joint-QR route the library takes with this set
    if joint is None:
        raise ValueError("the library's update does not take the joint-QR route here")
    r.joint = joint
    r.Xs = r.D2 if joint.offsets else r.X2
    r.xref = r.mean if joint.xref else r.zeros_n
    # the first set of the current estimate, as the library draws it
    KERNELS.points(engine.x, engine.S, plan.xi1, plan.gamma1, r.X1, no_set(n))
    r.x[...], r.Spost[...] = engine.x, engine.S
    return r


def prior(r, F: np.ndarray) -> None:
    """The prior and the second set from the first set's images ``F`` ``(1, N, n)`` (one kernel)."""
    p, fused = r.plan, r.fused
    r.kernels.transform(
        F, r.zeros_n, p.mode1, p.wm1, p.scale1, p.sign1, r.Q, r.mean, r.S, r.status,
        1, fused.xi, fused.gamma, r.X2, r.D2,
    )  # fmt: skip


def posterior(r, H: np.ndarray, z: np.ndarray) -> None:
    """The posterior and the next first set from the second set's images ``H`` ``(1, N2, m)``."""
    j, p = r.joint, r.plan
    r.kernels.joint_update(
        H, r.zeros_m, r.Xs, r.xref, z, r.R, r.mean, j.mode, j.wm, j.scale, j.sign, j.pair,
        r.zp, r.y, r.w, r.Sy, r.L21, r.dx, r.x, r.Spost, r.ll, r.ww, r.ld, r.ustatus, p.xi1, p.gamma1, r.X1,
    )  # fmt: skip


def _block(a) -> np.ndarray:
    """A model function's ``(N, d)`` images as the kernels take them: ``(1, N, d)``, float64, C order."""
    if type(a) is not np.ndarray or a.dtype != np.float64 or not a.flags.c_contiguous:
        a = np.ascontiguousarray(a, dtype=np.float64)
    return a[None]


class InlineStep:
    """The default step, inlined over the library's two kernels; see the module docstring."""

    def __init__(self, sc, fx, hx, vectorized: bool):
        # the plan, the noise factors and the initial factor are the library's, taken once
        self.r = fused_route(library_filter(sc, fx, hx, vectorized))
        self.fx, self.hx, self.vec, self.dt = fx, hx, vectorized, sc.dt
        self.z = np.empty((1, sc.dim_z))

    def step(self, z):
        r, fx, hx, dt = self.r, self.fx, self.hx, self.dt
        X = r.X1[0]
        prior(r, _block(fx(X, dt) if self.vec else [fx(s, dt) for s in X]))
        X = r.X2[0]
        self.z[0] = z
        posterior(r, _block(hx(X) if self.vec else [hx(s) for s in X]), self.z)

    @property
    def x(self) -> np.ndarray:
        return self.r.x[0]

    @property
    def S(self) -> np.ndarray:
        return self.r.Spost[0]


def inline_impls() -> list[Impl]:
    """The hand-inlined step, with per-point and with vectorised model functions."""

    def state(f):
        return f.x, f.S @ f.S.T

    return [
        Impl(
            f"reference: inlined step, no checks {'vectorised' if vec else 'per-point'}",
            lambda sc, fx, hx, vec=vec: InlineStep(sc, fx, hx, vec),
            lambda f, z: f.step(z),
            state,
            vec,
        )
        for vec in (False, True)
    ]


def _median_us(fn, reps: int) -> float:
    for _ in range(20):
        fn()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e6 * float(np.median(times))


def step_profile(sc, reps: int = 1000) -> dict[str, float]:
    """Where one predict+update of ``SquareRootUKF`` spends its time, in microseconds.

    The step runs vectorised with cheap linear model functions of the
    scenario's sizes, so that the library's own time dominates. Each part is
    then timed alone on the inputs of one such step (the kernels as
    :class:`InlineStep` calls them); the facade's and engine's share is what
    remains of the whole step's time.
    """
    from squkf import checks
    from squkf.engine import _images

    n, m = sc.dim_x, sc.dim_z
    A, C = np.eye(n) * 0.99, np.eye(m, n)

    def fx(X, dt):
        return X.dot(A.T)

    def hx(X):
        return X.dot(C.T)

    f = library_filter(sc, fx, hx, True)
    z = hx(sc.x0[None])[0] + 0.1

    def step():
        f.predict()
        f.update(z)

    total = _median_us(step, reps)
    r = fused_route(f)
    X1, dt = r.X1[0].copy(), sc.dt
    F = _block(fx(X1, dt))
    prior(r, F)
    X2 = r.X2[0].copy()
    H = _block(hx(X2))
    zb = z[None].copy()
    shape_f, shape_h = (1, r.N, n), (1, r.N2, m)
    parts = {
        "model functions (cheap, linear)": _median_us(lambda: (fx(X1, dt), hx(X2)), reps),
        "prior and second set (transform kernel)": _median_us(lambda: prior(r, F), reps),
        "posterior and next first set (joint-update kernel)": _median_us(lambda: posterior(r, H, zb), reps),
        "checks of what fx, hx and z bring": _median_us(
            lambda: (
                _images(F[0], shape_f, "fx values", False, True),
                _images(H[0], shape_h, "hx values", True, True),
                checks.measurement(z, None, m, f._R_dim, 0),
            ),
            reps,
        ),
    }
    parts["facade and engine (edit checks, routes, commit, filterpy's attributes)"] = total - sum(
        parts.values()
    )
    parts["whole step"] = total
    return parts


def same_as_library(sc, vectorized: bool, steps: int) -> bool:
    """Whether :class:`InlineStep` and ``SquareRootUKF`` give the same ``x`` and ``P1_2``, bit for bit,
    at every one of ``steps`` steps of scenario ``sc``."""
    fx, hx = (sc.fx_vec, sc.hx_vec) if vectorized else (sc.fx, sc.hx)
    f, g = library_filter(sc, fx, hx, vectorized), InlineStep(sc, fx, hx, vectorized)
    _, zs = sc.simulate(steps, 1)
    for z in zs:
        f.predict()
        f.update(z)
        g.step(z)
        if not (np.array_equal(f.x, g.x) and np.array_equal(np.asarray(f.P1_2), g.S)):
            return False
    return True


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="The inlined step against SquareRootUKF, bit for bit")
    ap.add_argument("--steps", type=int, default=50)
    args = ap.parse_args(argv)
    from models import SCENARIOS

    print("| scenario | model functions | inlined step and SquareRootUKF |")
    print("|---|---|---|")
    ok = True
    for sc in SCENARIOS():
        for vectorized in (True, False):
            same = same_as_library(sc, vectorized, args.steps)
            ok &= same
            kind = "vectorised" if vectorized else "per point"
            print(f"| {sc.name} | {kind} | {'the same, bit for bit' if same else 'DIFFERENT'} |")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
