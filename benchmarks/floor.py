"""Lower bounds for the library's own time per step, measured on this machine.

Two references, neither of them a filter anyone should use:

- ``qr_ms``: the two QR factorisations a square-root step needs (the prior's
  ``(N + n) x n`` rows and the update's joint ``(N + m) x (m + n)`` rows),
  timed alone on fresh random rows.
- ``inline_impls``: the default step (redrawn Merwe points, ``beta >= alpha**2``)
  written as one straight function with no validation, no error handling,
  no bookkeeping of filterpy's attributes and no support for anything else.
  It is what a hand-tuned NumPy square-root UKF costs here, so the gap
  between it and ``SquareRootUKF`` is the price of the library's checks and
  interface, and the gap between it and filterpy is all a NumPy library can win.
"""

from __future__ import annotations

import math
import time

import numpy as np
from peers import Impl
from scipy.linalg import lapack

_geqrfp = lapack.get_lapack_funcs("geqrfp", dtype=np.float64)  # R with a non-negative diagonal
_trtrs = lapack.get_lapack_funcs("trtrs", dtype=np.float64)


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


class InlineStep:
    """The redrawn central-form step, inlined; see the module docstring."""

    def __init__(self, sc, fx, hx, vectorized: bool):
        from squkf import MerweScaledWeights

        n, m = sc.dim_x, sc.dim_z
        pts = MerweScaledWeights(sc.alpha, sc.beta, sc.kappa)
        self.xi = np.array(pts.unit_sigma_points(n))
        Wm, Wc = pts.weights(n)
        N = self.xi.shape[0]
        self.n, self.m, self.N, self.dt = n, m, N, sc.dt
        self.tail = np.array(Wm[1:])
        self.s = np.sqrt(Wc[1:])[:, None]
        self.c = math.sqrt(Wc.sum() - 2.0)
        self.G = self.xi[1:] * self.s
        self.QT = np.linalg.cholesky(sc.Q).T
        self.RT = np.linalg.cholesky(sc.R).T
        self.A = np.empty((N + n, n), order="F")
        self.M = np.empty((N + m, m + n), order="F")
        self.mask = np.tril(np.ones((n + m, n + m)))
        self.x, self.S = sc.x0.astype(float), np.linalg.cholesky(sc.P0)
        self.fx, self.hx, self.vec = fx, hx, vectorized

    def step(self, z):
        n, m, N, A, M = self.n, self.m, self.N, self.A, self.M
        X = self.xi.dot(self.S.T) + self.x
        F = self.fx(X, self.dt) if self.vec else np.array([self.fx(s, self.dt) for s in X])
        E = A[: N - 1]
        np.subtract(F[1:], F[0], out=E)
        mu = self.tail.dot(E)
        E *= self.s
        A[N - 1] = self.c * mu
        A[N:] = self.QT
        qr = _geqrfp(A, overwrite_a=1)[0]
        S = qr[:n].T * self.mask[:n, :n]
        x = F[0] + mu
        D = self.xi.dot(S.T)
        Z = self.hx(D + x) if self.vec else np.array([self.hx(s) for s in D + x])
        Ez = M[: N - 1, :m]
        np.subtract(Z[1:], Z[0], out=Ez)
        muz = self.tail.dot(Ez)
        Ez *= self.s
        M[N - 1, :m] = self.c * muz
        M[: N - 1, m:] = D[1:] * self.s
        M[N - 1 :, m:] = 0.0
        M[N:, :m] = self.RT
        qr = _geqrfp(M, overwrite_a=1)[0]
        L = qr[: m + n].T * self.mask
        w = _trtrs(L[:m, :m], z - (Z[0] + muz), lower=1)[0]
        self.x = x + L[m:, :m].dot(w)
        self.S = L[m:, m:]


def inline_impls() -> list[Impl]:
    """The hand-inlined step, with per-point and with vectorised model functions."""

    def state(f):
        return f.x, f.S @ f.S.T

    return [
        Impl(
            f"reference: inlined step, no checks {'vectorised' if vec else 'per-point'}",
            lambda sc, fx, hx, vec=vec: InlineStep(sc, fx, hx, vec),
            lambda f, z: f.step(np.asarray(z, dtype=float)),
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
    then timed alone on the inputs of one such step; the facade's share is
    what remains of the whole step's time.
    """
    from squkf import MerweScaledWeights, SquareRootUKF
    from squkf.generators import sigma_points_and_offsets
    from squkf.measurement import measurement_update
    from squkf.transform import transform_factor
    from squkf.validate import check_values

    n, m = sc.dim_x, sc.dim_z
    A, C = np.eye(n) * 0.99, np.eye(m, n)

    def fx(X, dt):
        return X.dot(A.T)

    def hx(X):
        return X.dot(C.T)

    f = SquareRootUKF(n, m, sc.dt, hx, fx, MerweScaledWeights(sc.alpha, sc.beta, sc.kappa), vectorized=True)
    f.x, f.P, f.Q, f.R = sc.x0, sc.P0, sc.Q, sc.R
    z = hx(sc.x0[None])[0] + 0.1

    def step():
        f.predict()
        f.update(z)

    total = _median_us(step, reps)
    plan = f._plan
    x, S, Q1_2, R1_2 = f.x.copy(), np.array(f.P1_2), f._Q.factor(), f._R.factor()
    first = plan.first
    X1 = sigma_points_and_offsets(x, S, first.xi, None, first.gamma)[0]
    F = fx(X1, sc.dt)
    xp, Sp = transform_factor(F, first.rows, Q1_2)
    sset = plan.second.draw(xp, Sp, None, None, None)
    X2 = sset.sigmas
    H = hx(X2)
    parts = {
        "model functions (cheap, linear)": _median_us(lambda: (fx(X1, sc.dt), hx(X2)), reps),
        "first set (points kernel)": _median_us(
            lambda: sigma_points_and_offsets(x, S, first.xi, None, first.gamma), reps
        ),
        "prior (transform kernel)": _median_us(lambda: transform_factor(F, first.rows, Q1_2), reps),
        "second set (points kernel)": _median_us(lambda: plan.second.draw(xp, Sp, None, None, None), reps),
        "update (joint-QR kernel)": _median_us(lambda: measurement_update(xp, Sp, sset, H, z, R1_2), reps),
        "checks of what fx, hx and z bring": _median_us(
            lambda: (
                check_values(F, F.shape, "fx"),
                check_values(H, H.shape, "hx"),
                f._as_measurement(z, None),
            ),
            reps,
        ),
    }
    parts["facade and step machine (edit checks, transaction, filterpy's attributes)"] = total - sum(
        parts.values()
    )
    parts["whole step"] = total
    return parts
