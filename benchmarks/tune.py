"""Tuning and Monte Carlo at fleet speed, against the loops a filterpy user writes today.

    python benchmarks/tune.py --out benchmarks/results    # a few minutes
    python benchmarks/tune.py --quick --out DIR           # under a minute: a check that it runs

In one process, side by side (issue 37's speed targets; the ratios count, this machine is shared):

1. One fit of 3 parameters (``Q``'s scale, ``R``'s two variances) to one recording of the g13ej robot
   (T = 400, its example's ``Q`` and ``R`` the truth, the template started at ``3 Q`` and ``R / 3``):
   ``tune.fit_noise`` against ``scipy.optimize.minimize(method="Nelder-Mead")`` over the summed
   ``log_likelihood`` of filterpy's UKF and of one ``SquareRootUKF`` (each evaluation one filter run),
   from the same start in the same log-parametrisation, ``xatol = fatol = 1e-4``. Each reaches its
   optimum's log-likelihood, reported.
2. 100 recordings fitted each on its own (``shared=False``) against 100 filterpy Nelder-Mead fits,
   measured on 3 and scaled linearly (said so in the table).
3. ``consistency.monte_carlo`` of 4 configurations, 1,000 runs of T = 200, against a loop of filterpy
   filters over the same runs, measured on 10 runs a configuration and scaled linearly.

The robot's bearing wraps at 2 pi, so both filters treat it as an angle: its residual wrapped and its
mean circular. The squkf filters take ``AngleResidual([1])`` as ``residual_z`` and ``AngleMean([1])`` as
``z_mean_fn`` (done by the kernels: squkf's angle hooks are data), filterpy's a wrapping function and the
same ``AngleMean([1])``, so both fit the same model. (With a plain mean, the mean of sigma points on both
sides of the wrap is wrong, and the log-likelihood is rough along ``R``: each local method then stops at
its own local optimum.) squkf's model functions are written for a stack of points (``X[..., i]``,
``vectorized=True``), as a squkf user writes them; filterpy's take one point, as it calls them. Written to
``tune.md`` in ``--out``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from scipy.optimize import minimize

from squkf import JulierWeights, SquareRootUKF, consistency, simulate, tune
from squkf.angles import AngleMean, AngleResidual
from squkf.examples import g13ej_example as ex

HERE = Path(__file__).resolve().parent
DATA = ex.load_data()
R_WHEEL, D_AXLE, DELTA, A_WALL = (DATA["model"][k] for k in ("r", "d", "Delta", "A"))


def fx(x, dt, phi_r=0.4, phi_l=0.1):
    t1 = 0.5 * R_WHEEL * (phi_r + phi_l)
    t3 = (R_WHEEL / D_AXLE) * (phi_r - phi_l)
    return np.array([x[0] + np.cos(x[2]) * t1, x[1] + np.sin(x[2]) * t1, x[2] + t3])


def hx(x):
    return np.array([DELTA - x[0] * np.cos(A_WALL) - x[1] * np.sin(A_WALL), (x[2] - A_WALL) % (2 * np.pi)])


def wrap_residual(a, b):
    d = np.asarray(a, dtype=float) - b
    d[1] = (d[1] + np.pi) % (2 * np.pi) - np.pi
    return d


Q_TRUE = np.array(DATA["lx"]) @ np.array(DATA["lx"]).T
R_TRUE = np.array(DATA["ly"]) @ np.array(DATA["ly"]).T
P0 = np.array(DATA["st0"]) @ np.array(DATA["st0"]).T
X0 = np.array(DATA["x0"], dtype=float)


def fx_stacked(X, dt, phi_r=0.4, phi_l=0.1):
    """``fx`` at a stack of points ``(..., 3)``."""
    t1 = 0.5 * R_WHEEL * (phi_r + phi_l)
    t3 = (R_WHEEL / D_AXLE) * (phi_r - phi_l)
    heading = X[..., 2]
    return np.stack([X[..., 0] + np.cos(heading) * t1, X[..., 1] + np.sin(heading) * t1, heading + t3], -1)


def hx_stacked(X):
    """``hx`` at a stack of points ``(..., 3)``."""
    distance = DELTA - X[..., 0] * np.cos(A_WALL) - X[..., 1] * np.sin(A_WALL)
    return np.stack([distance, (X[..., 2] - A_WALL) % (2 * np.pi)], -1)


def squkf_filter(q_scale=1.0, r=(1.0, 1.0), points=None, scheme="redrawn", wrap=True):
    f = SquareRootUKF(3, 2, 1.0, hx_stacked, fx_stacked, points or MerweScaledSigmaPoints(3, 1.0, 2.0, 0.0),
                      scheme=scheme, vectorized=True, residual_z=AngleResidual([1]) if wrap else None,
                      z_mean_fn=AngleMean([1]) if wrap else None)  # fmt: skip
    f.x, f.P = X0, P0
    f.Q, f.R = q_scale * Q_TRUE, np.diag(np.asarray(r) * np.diag(R_TRUE))
    return f


def filterpy_filter(theta):
    f = UnscentedKalmanFilter(3, 2, 1.0, hx, fx, MerweScaledSigmaPoints(3, 1.0, 2.0, 0.0),
                              residual_z=wrap_residual, z_mean_fn=AngleMean([1]))  # fmt: skip
    f.x, f.P = X0.copy(), P0.copy()
    f.Q = np.exp(theta[0]) * 3 * Q_TRUE
    f.R = np.diag(np.exp(theta[1:]) * np.diag(R_TRUE) / 3)
    return f


def summed_loglik(f, zs) -> float:
    """A filterpy filter's ``log_likelihood`` summed over a recording (-inf where it breaks)."""
    total = 0.0
    try:
        for z in zs:
            f.predict()
            f.update(z)
            total += f.log_likelihood
    except np.linalg.LinAlgError:
        return -np.inf
    return total


def filterpy_loglik(theta, zs):
    return summed_loglik(filterpy_filter(theta), zs)


def squkf_loglik(theta, zs):
    f = squkf_filter(3 * np.exp(theta[0]), np.exp(theta[1:]) / 3)
    try:
        return float(np.sum(f.batch_filter(zs).log_likelihood))
    except Exception:
        return -np.inf


def nelder_mead(loglik, zs, restarted=False):
    """scipy's Nelder-Mead from the template's values; ``restarted``: run again from where it stopped
    until a run gains less than 1e-4 (Nelder-Mead's simplex can collapse on a flat ridge short of the
    optimum; a restart gives it a fresh one). Returns the time, the best log-likelihood, the evaluations."""
    t = time.perf_counter()
    theta, best, nfev = np.zeros(3), -np.inf, 0
    while True:
        res = minimize(lambda th: -loglik(th, zs), theta, method="Nelder-Mead",
                       options={"xatol": 1e-4, "fatol": 1e-4})  # fmt: skip
        nfev += res.nfev
        gained, theta, best = -res.fun - best, res.x, max(best, -res.fun)
        if not restarted or gained < 1e-4:
            return time.perf_counter() - t, best, nfev


def template():
    return squkf_filter(3.0, (1 / 3, 1 / 3))


def fit(zs, shared=True):
    t = time.perf_counter()
    out = tune.fit_noise(template(), zs, Q=tune.Scaled(), R=tune.Diagonal(), shared=shared)
    return time.perf_counter() - t, out


def monte_carlo_loop(configs, truth, zs, runs):
    """The filterpy loop over ``runs`` runs of each configuration (RMSE and NEES by hand)."""
    t = time.perf_counter()
    for points in configs:
        for r in range(runs):
            f = UnscentedKalmanFilter(
                3, 2, 1.0, hx, fx, points, residual_z=wrap_residual, z_mean_fn=AngleMean([1])
            )
            f.x, f.P, f.Q, f.R = X0.copy(), P0.copy(), Q_TRUE.copy(), R_TRUE.copy()
            err = []
            for k, z in enumerate(zs[r]):
                f.predict()
                f.update(z)
                e = truth[r, k] - f.x
                err.append(e @ np.linalg.solve(f.P, e))
    return time.perf_counter() - t


F_CV = np.kron(np.eye(2), [[1.0, 1.0], [0.0, 1.0]])
Q_CV = np.kron(np.eye(2), [[0.25, 0.5], [0.5, 1.0]])  # Q_discrete_white_noise(2, 1, 1, block_size=2)


def cv_squkf(q, r1, r2, points=None):
    f = SquareRootUKF(4, 2, 1.0, lambda X: X[..., ::2], lambda X, dt: X @ F_CV.T,
                      points or MerweScaledSigmaPoints(4, 1.0, 2.0, 0.0), vectorized=True)  # fmt: skip
    f.x, f.P, f.Q, f.R = np.array([0.0, 1.0, 0.0, 1.0]), np.eye(4), q * Q_CV, np.diag([r1, r2])
    return f


def cv_filterpy_loglik(theta, zs):
    f = UnscentedKalmanFilter(4, 2, 1.0, lambda x: x[::2], lambda x, dt: F_CV @ x,
                              MerweScaledSigmaPoints(4, 1.0, 2.0, 0.0))  # fmt: skip
    f.x, f.P = np.array([0.0, 1.0, 0.0, 1.0]), np.eye(4)
    f.Q, f.R = np.exp(theta[0]) * Q_CV, np.diag(np.exp(theta[1:]))
    return summed_loglik(f, zs)


def cv_case(quick: bool):
    """Shared=False fits and a Monte Carlo study on the constant-velocity model (no hook)."""
    B, B_fp, M, M_fp = (20, 2, 100, 4) if quick else (100, 3, 1000, 10)
    _, zs = simulate(cv_squkf(0.1, 1.0, 4.0), 300, B, seed=3)
    t = time.perf_counter()
    tune.fit_noise(cv_squkf(1.0, 1.0, 1.0), zs, Q=tune.Scaled(), R=tune.Diagonal(), shared=False)
    t_fit = time.perf_counter() - t
    t_fp = sum(nelder_mead(cv_filterpy_loglik, zs[b])[0] for b in range(B_fp)) * B / B_fp
    truth, zs_mc = simulate(cv_squkf(0.1, 1.0, 4.0), 200, M, seed=4)
    configs = {
        "Merwe": cv_squkf(0.1, 1.0, 4.0),
        "Julier": cv_squkf(0.1, 1.0, 4.0, JulierWeights()),
        "q x 10": cv_squkf(1.0, 1.0, 4.0),
        "R x 4": cv_squkf(0.1, 4.0, 16.0),
    }
    t = time.perf_counter()
    consistency.monte_carlo(configs, truth, zs_mc)
    t_mc = time.perf_counter() - t
    t = time.perf_counter()
    for _ in range(4):
        for r in range(M_fp):
            f = UnscentedKalmanFilter(4, 2, 1.0, lambda x: x[::2], lambda x, dt: F_CV @ x,
                                      MerweScaledSigmaPoints(4, 1.0, 2.0, 0.0))  # fmt: skip
            f.x, f.P, f.Q, f.R = np.array([0.0, 1.0, 0.0, 1.0]), np.eye(4), 0.1 * Q_CV, np.diag([1.0, 4.0])
            for k, z in enumerate(zs_mc[r]):
                f.predict()
                f.update(z)
                e = truth[r, k] - f.x
                e @ np.linalg.solve(f.P, e)
    t_mc_fp = (time.perf_counter() - t) * M / M_fp
    rows = [
        (f"{B} recordings of 300 steps, shared=False", t_fit, ""),
        (f"{B} filterpy Nelder-Mead fits (measured on {B_fp}, scaled)", t_fp, ""),
        (f"monte_carlo, 4 configurations x {M} runs of 200", t_mc, ""),
        (f"filterpy loop (measured on {M_fp} runs a configuration, scaled)", t_mc_fp, ""),
    ]
    ratios = [
        (f"{B} fits shared=False / {B} filterpy fits", t_fit / t_fp, 1 / 300),
        ("monte_carlo / filterpy loop", t_mc / t_mc_fp, 1 / 100),
    ]
    return rows, ratios


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(HERE / "results"))
    args = ap.parse_args(argv)
    T, B, B_fp, M, T_mc, M_fp = (60, 6, 2, 40, 40, 4) if args.quick else (400, 100, 3, 1000, 200, 10)
    truth_filter = squkf_filter(wrap=False)
    _, zs = simulate(truth_filter, T, B, seed=1)
    rows = []
    # warm up: every kernel the runs below call loaded from numba's cache (about 0.2 s in a new process)
    # and filterpy's code run once, before anything is timed
    tune.fit_noise(template(), zs[0, :20], Q=tune.Scaled(), R=tune.Diagonal(), maxiter=2)
    squkf_loglik(np.zeros(3), zs[0, :20])
    filterpy_loglik(np.zeros(3), zs[0, :20])

    t_fit, one = fit(zs[0])
    t_nm_fp, ll_fp, n_fp = nelder_mead(filterpy_loglik, zs[0])
    t_nm_sq, ll_sq, n_sq = nelder_mead(squkf_loglik, zs[0])
    t_nm_re, ll_re, n_re = nelder_mead(squkf_loglik, zs[0], restarted=True)
    rows.append(("one fit, 3 parameters: fit_noise", t_fit, one.log_likelihood, f"{one.passes} fleet passes"))
    rows.append(("Nelder-Mead over filterpy's UKF", t_nm_fp, ll_fp, f"{n_fp} evaluations"))
    rows.append(("Nelder-Mead over one SquareRootUKF", t_nm_sq, ll_sq, f"{n_sq} evaluations"))
    rows.append(("the same, restarted until a run gains < 1e-4", t_nm_re, ll_re, f"{n_re} evaluations"))
    same = max(one.log_likelihood, ll_fp, ll_sq, ll_re) - min(one.log_likelihood, ll_fp, ll_sq, ll_re)

    t_each, fits = fit(zs, shared=False)
    t_fp_each = sum(nelder_mead(filterpy_loglik, zs[b])[0] for b in range(B_fp)) * B / B_fp
    rows.append((f"{B} recordings, shared=False", t_each, float(np.mean([f.log_likelihood for f in fits])),
                 f"{fits[0].passes} fleet passes"))  # fmt: skip
    rows.append((f"{B} filterpy fits (measured on {B_fp}, scaled)", t_fp_each, float("nan"), ""))

    truth, zs_mc = simulate(truth_filter, T_mc, M, seed=2)
    configs = {
        "Merwe": squkf_filter(),
        "Julier": squkf_filter(points=JulierWeights()),
        "Merwe augmented": squkf_filter(scheme="augmented"),
        "Merwe, R x 4": squkf_filter(r=(4.0, 4.0)),
    }
    t = time.perf_counter()
    consistency.monte_carlo(configs, truth, zs_mc)
    t_mc = time.perf_counter() - t
    fp_points = [MerweScaledSigmaPoints(3, 1.0, 2.0, 0.0)] * 4
    t_mc_fp = monte_carlo_loop(fp_points, truth, zs_mc, M_fp) * M / M_fp
    rows.append((f"monte_carlo, 4 configurations x {M} runs of {T_mc}", t_mc, float("nan"), ""))
    rows.append(
        (f"filterpy loop (measured on {M_fp} runs a configuration, scaled)", t_mc_fp, float("nan"), "")
    )

    # the same comparisons on a model with no hook: the 2-D constant-velocity model of the tests
    cv_rows, cv_ratios = cv_case(args.quick)

    ratios = [
        ("fit_noise / Nelder-Mead over filterpy", t_fit / t_nm_fp, 1 / 20),
        ("fit_noise / Nelder-Mead over one SquareRootUKF", t_fit / t_nm_sq, 1 / 4),
        (f"{B} fits shared=False / {B} filterpy fits", t_each / t_fp_each, 1 / 300),
        ("monte_carlo / filterpy loop", t_mc / t_mc_fp, 1 / 100),
    ]
    lines = [
        "# Tuning and Monte Carlo against the loops written today (g13ej robot)",
        "",
        f"`python benchmarks/tune.py{' --quick' if args.quick else ''}`, one process; T = {T} for the fits.",
        "",
        "| what | seconds | log-likelihood | |",
        "|---|---|---|---|",
    ]
    for what, sec, ll, note in rows:
        lines.append(f"| {what} | {sec:.3g} | {'' if np.isnan(ll) else f'{ll:.4f}'} | {note} |")
    lines += [
        "",
        f"The four optima agree to {same:.2g} in log-likelihood"
        + (" (issue 37 asks for 1e-3)." if same <= 1e-3 else f": Nelder-Mead run once stops {same:.2g} short"
           f" of the restarted one and of fit_noise, which agree to {abs(one.log_likelihood - ll_re):.2g}."),
        "The ratios are against Nelder-Mead run once (its time to the optimum, restarted, is longer).",
    ]  # fmt: skip
    lines += ["", "| ratio | value | target | |", "|---|---|---|---|"]
    for what, value, target in ratios:
        lines.append(f"| {what} | {value:.4f} | <= {target:.4f} | {'met' if value <= target else 'missed'} |")
    lines += [
        "",
        "The same comparisons on the 2-D constant-velocity model (positions measured, no hook;",
        "`tests/models.py`'s `tune_cv_*`), q, r1, r2 fitted from q = 1, R = I:",
        "",
        "| what | seconds | |",
        "|---|---|---|",
    ]
    for what, sec, note in cv_rows:
        lines.append(f"| {what} | {sec:.3g} | {note} |")
    lines += ["", "| ratio | value | target | |", "|---|---|---|---|"]
    for what, value, target in cv_ratios:
        lines.append(f"| {what} | {value:.4f} | <= {target:.4f} | {'met' if value <= target else 'missed'} |")
    text = "\n".join(lines) + "\n"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "tune.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
