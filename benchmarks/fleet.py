"""K filters at once: ``squkf.Fleet`` against loops of filters and dynamax under ``jax.vmap`` + ``jax.jit``.

    python benchmarks/fleet.py            # full run (about ten minutes), results in benchmarks/results/
    python benchmarks/fleet.py --quick    # smoke test, well under 30 s
    python benchmarks/fleet.py --skip dynamax   # without the JAX peer
    python benchmarks/fleet.py --Ks 10000 --models n4 --out DIR   # one K of one model
    python benchmarks/fleet.py --cores 2  # the main tables with two CPUs (default: one)
    python benchmarks/fleet.py --ref REV  # the step's peak memory against REV's (default 0cdce8e)
    python benchmarks/fleet.py --hooks    # only the angle hooks' table (hooks_bench.py): fleet.md's section

Two models: a 2-D constant-velocity target seen by a range-bearing sensor
(n = 4, m = 2) and five independent 2-D oscillators seen through cubic sensors
``z_i = p_i + 0.05 p_i**3`` (n = 10, m = 5). Each of the K filters has its
own simulated truth and measurements.

Implementations, all Merwe's scaled points (alpha = 1, beta = 2, kappa = 0)
and the redrawn scheme (the second sigma-point set drawn from the prior):

* ``Fleet``: one ``predict`` and one ``update`` per step for all K filters;
* a loop of K ``SquareRootUKF(vectorized=True)`` with the same model functions;
* a loop of K filterpy ``UnscentedKalmanFilter`` with per-point ``math`` functions;
* dynamax's ``unscented_kalman_filter`` (a full-covariance UKF), ``jax.vmap``-ed
  over the filters and ``jax.jit``-ed, float64 on the CPU; compiled once per
  shape before timing. It updates before it predicts, so it starts from the
  prediction of the others' first step (exact here: both models' dynamics are
  linear) and runs the same T updates and T predictions.

Timing: the time per filter-step is a run's time divided by K * T (T steps of
K filters; only the steps are timed, not building the filters). At each K the
implementations are interleaved over repetitions in one process (their order
rotated); the table gives medians, and ratios are taken per repetition (median
of the ratios). A loop is run at a K only when its median at the previous K,
times K * T, is under ``--loop-budget`` seconds (20 s): what is not measured
is not reported. One thread: BLAS is held to one thread (set before numpy is
imported) and the process is pinned to one CPU (``os.sched_setaffinity``,
``--cores``), so that XLA, which dynamax runs on, has one core too.

Two threads: when ``squkf.Fleet`` has a thread setting (a ``threads=``
argument, or ``set_num_threads`` in ``squkf`` or ``squkf.kernels``), two
subprocesses on two CPUs time the n = 4 model at K >= 10^4: one the fleet on
one thread and on two, interleaved, with jax never imported (the speed-up);
the other the fleet on two threads and dynamax (XLA with both cores),
interleaved. They are apart because XLA's worker threads keep spinning for a
while after each dynamax call and take the CPU from the fleet's second thread
(measured: in one process with dynamax the fleet's speed-up on two threads fell
from 1.65x to 1.38x at K = 10^5). They run first, before this process calls
dynamax: its own spinning workers took a CPU from them too (1.54x then). With
no such setting there is no two-thread table, and the results say so.

Memory, two measures of one fleet ``predict`` + ``update`` (a warm step):

* the peak of allocations that ``tracemalloc`` sees (numpy reports its arrays
  to it) above what was allocated before the step, beside the fleet's own
  state (its arrays). Arrays that numba's kernels allocate (numba's runtime,
  NRT) are invisible to it, and so are XLA's buffers;
* the peak resident set size (``VmHWM`` of ``/proc/self/status``, reset before
  each step through ``/proc/self/clear_refs``) above the RSS before the step,
  in a fresh subprocess at the largest K (kernels compiled or loaded on a
  small fleet first): each of three steps. Before each step glibc's
  ``malloc_trim`` gives freed heap memory back, so that the temporaries of
  the step before do not hide this one's. This sees everything, numba's
  arrays included. For the third (steady) step also the peak above the RSS
  before the fleet was built: the state, what the fleet keeps between steps
  (buffers written in turn) and the step's temporaries; the memory target
  is judged on that, at the first step and the third.

Against an earlier revision (``--ref``, by default 0cdce8e, the revision
before the engine; none with ``--quick``): the same peak RSS of a step, of
this squkf and of that revision's package (taken from git,
:func:`against_revision.revision_folder`), in fresh subprocesses at the
largest K, interleaved (three runs each, medians).

Under a Dask worker's allocator setting: ``Fleet.batch_filter(keep="means")``
(n = 4, K = 12,500, T = 40; one untimed run first) in fresh subprocesses
pinned to one CPU, started with ``MALLOC_TRIM_THRESHOLD_=65536`` (what dask's
nanny sets) and without it, none of glibc's other ``MALLOC_*`` variables set,
interleaved over five pairs; the median and range of the pairs' ratios of
wall-clock time, and the same for the ``--ref`` revision. Like the two-thread
runs, these run before this process calls dynamax.

Accuracy: on a separate, untimed run, the fleet's estimates are compared with
the loop of ``SquareRootUKF`` (the same filter: RMSE equal to 1e-9 or the run
fails), with filterpy and with dynamax (the largest difference of an estimate
is reported; dynamax forms full covariances and solves with them, so it
agrees to rounding amplified by the conditioning, not bit for bit).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
import tracemalloc
from pathlib import Path

HERE = Path(__file__).resolve().parent
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")
PEERS = ("loop", "filterpy", "dynamax")
TWO_THREAD_KS = (10_000, 100_000)
REF = "0cdce8e"  # the revision before the engine (issue 30): its step's peak memory is the bound
# glibc's allocator settings a child of the MALLOC_TRIM_THRESHOLD_ comparison starts without
MALLOC_VARS = ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_ARENA_MAX")
DASK_TRIM = "65536"  # what dask's nanny sets for its workers


def _parse(argv):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes, for the smoke test")
    ap.add_argument("--out", default=str(HERE / "results"))
    ap.add_argument("--skip", nargs="*", default=[], choices=PEERS, help="peers not to run")
    ap.add_argument("--loop-budget", type=float, default=20.0, help="seconds per loop run, at most")
    ap.add_argument("--Ks", type=int, nargs="+", help="numbers of filters (default 1 to 10^5)")
    ap.add_argument("--models", nargs="+", choices=("n4", "n10"), default=["n4", "n10"])
    ap.add_argument("--cores", type=int, default=1, help="CPUs the process is pinned to (default 1)")
    ap.add_argument("--no-two-threads", action="store_true", help="no two-thread table")
    ap.add_argument(
        "--ref",
        help=f"the revision whose step's peak memory is measured beside this one's (default {REF}; "
        "none with --quick); 'none': not measured",
    )
    ap.add_argument("--no-malloc-trim", action="store_true", help="no MALLOC_TRIM_THRESHOLD_ comparison")
    ap.add_argument(
        "--hooks", action="store_true", help="only the angle hooks' table: its section of fleet.md rewritten"
    )
    ap.add_argument("--rss-child", nargs=2, metavar=("MODEL", "K"), help=argparse.SUPPRESS)
    ap.add_argument("--ref-folder", metavar="FOLDER", help=argparse.SUPPRESS)
    ap.add_argument("--malloc-child", nargs=3, metavar=("MODEL", "K", "T"), help=argparse.SUPPRESS)
    ap.add_argument("--threads-child", action="store_true", help=argparse.SUPPRESS)
    return ap.parse_args(argv)


def _pin(cores: int) -> None:
    """Pin this process (and the threads it will start) to its first ``cores`` CPUs."""
    if hasattr(os, "sched_setaffinity"):
        try:  # first widen to every CPU (a subprocess inherits its parent's pinning)
            os.sched_setaffinity(0, set(range(os.cpu_count() or 1)))
        except OSError:
            pass
        cpus = sorted(os.sched_getaffinity(0))
        os.sched_setaffinity(0, set(cpus[: max(1, cores)]))


ARGS = _parse(sys.argv[1:]) if __name__ == "__main__" else None
if ARGS is not None:
    for var in THREAD_VARS:  # must happen before numpy loads its BLAS
        os.environ[var] = "1"
    _pin(ARGS.cores)

import numpy as np  # noqa: E402

ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from machine import cpu_name  # noqa: E402

from squkf import Fleet, MerweScaledWeights, SquareRootUKF  # noqa: E402

ALPHA, BETA, KAPPA = 1.0, 2.0, 0.0
OKABE_ITO = {"fleet": "#0072B2", "loop": "#E69F00", "filterpy": "#009E73", "dynamax": "#CC79A7"}
LABELS = {
    "fleet": "squkf Fleet",
    "loop": "loop of SquareRootUKF (vectorized)",
    "filterpy": "loop of filterpy UKF",
    "dynamax": "dynamax UKF, vmap + jit",
    "fleet2": "squkf Fleet, two threads",
}


# -- models ---------------------------------------------------------------------------------------


class ConstantVelocity:
    """2-D constant velocity (white-noise acceleration), range and bearing from the origin."""

    name, n, m, dt = "CV range-bearing n=4", 4, 2, 1.0

    def __init__(self):
        q, dt = 0.05, self.dt
        blk = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        self.Q = np.kron(np.eye(2), blk)
        self.R = np.diag([5.0**2, 2e-3**2])
        self.x0 = np.array([1000.0, 5.0, 1500.0, -3.0])
        self.P0 = np.diag([30.0**2, 2.0**2, 30.0**2, 2.0**2])
        self.F = np.array([[1, dt, 0, 0], [0, 1, 0, 0], [0, 0, 1, dt], [0, 0, 0, 1.0]])

    @staticmethod
    def fx(X, dt):  # any leading axes: (n,), (N, n) or (K, N, n)
        return np.stack(
            [X[..., 0] + dt * X[..., 1], X[..., 1], X[..., 2] + dt * X[..., 3], X[..., 3]], axis=-1
        )

    @staticmethod
    def hx(X):
        return np.stack([np.hypot(X[..., 0], X[..., 2]), np.arctan2(X[..., 2], X[..., 0])], axis=-1)

    @staticmethod
    def fx_point(x, dt):
        x0, x1, x2, x3 = x.tolist()
        return np.array([x0 + dt * x1, x1, x2 + dt * x3, x3])

    @staticmethod
    def hx_point(x):
        x0, x2 = float(x[0]), float(x[2])
        return np.array([math.hypot(x0, x2), math.atan2(x2, x0)])

    def jax_functions(self):
        import jax.numpy as jnp

        dt = self.dt

        def f(x):
            return jnp.array([x[0] + dt * x[1], x[1], x[2] + dt * x[3], x[3]])

        def h(x):
            return jnp.array([jnp.hypot(x[0], x[2]), jnp.arctan2(x[2], x[0])])

        return f, h

    def measure(self, X):
        return self.hx(X)


class Oscillators:
    """Five independent undamped 2-D oscillators (position, velocity), each seen through a cubic sensor."""

    name, n, m, dt = "5 oscillators, cubic sensors n=10", 10, 5, 0.1
    c = 0.05

    def __init__(self):
        self.omega = np.array([0.5, 0.8, 1.1, 1.4, 1.7])
        dt, w = self.dt, self.omega
        self.cs, self.sn = np.cos(w * dt), np.sin(w * dt)
        self.F = np.zeros((10, 10))
        for i in range(5):
            self.F[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = [
                [self.cs[i], self.sn[i] / w[i]],
                [-w[i] * self.sn[i], self.cs[i]],
            ]
        self.Q = np.kron(np.eye(5), np.diag([1e-4, 1e-3]))
        self.R = np.eye(5) * 0.05**2
        self.x0 = np.tile([1.0, 0.0], 5)
        self.P0 = np.kron(np.eye(5), np.diag([0.3**2, 0.3**2]))
        self._cs, self._sw, self._ws = self.cs.tolist(), (self.sn / w).tolist(), (w * self.sn).tolist()

    def fx(self, X, dt):
        P, V = X[..., 0::2], X[..., 1::2]
        out = np.empty_like(X)
        out[..., 0::2] = self.cs * P + self.sn / self.omega * V
        out[..., 1::2] = -self.omega * self.sn * P + self.cs * V
        return out

    def hx(self, X):
        P = X[..., 0::2]
        return P + self.c * P**3

    def fx_point(self, x, dt):
        v = x.tolist()
        out = []
        for i in range(5):
            p, q = v[2 * i], v[2 * i + 1]
            out += [self._cs[i] * p + self._sw[i] * q, -self._ws[i] * p + self._cs[i] * q]
        return np.array(out)

    def hx_point(self, x):
        c = self.c
        return np.array([p + c * p * p * p for p in x[0::2].tolist()])

    def jax_functions(self):
        import jax.numpy as jnp

        F = jnp.asarray(self.F)
        c = self.c

        def f(x):
            return F @ x

        def h(x):
            p = x[0::2]
            return p + c * p**3

        return f, h

    def measure(self, X):
        return self.hx(X)


def simulate(model, K: int, T: int, seed: int):
    """Truths ``(K, T, n)`` and measurements ``(K, T, m)``; truth 0 is drawn from N(x0, P0)."""
    rng = np.random.default_rng(seed)
    LP, LQ, LR = (np.linalg.cholesky(a) for a in (model.P0, model.Q, model.R))
    x = model.x0 + rng.standard_normal((K, model.n)) @ LP.T
    truth = np.empty((K, T, model.n))
    zs = np.empty((K, T, model.m))
    for t in range(T):
        x = x @ model.F.T + rng.standard_normal((K, model.n)) @ LQ.T
        truth[:, t] = x
        zs[:, t] = model.measure(x) + rng.standard_normal((K, model.m)) @ LR.T
    return truth, zs


# -- implementations: each returns (seconds for the T steps of K filters, final/all estimates) --------


def points():
    return MerweScaledWeights(ALPHA, BETA, KAPPA)


def thread_control():
    """How to give the fleet a number of threads: ``(description, apply)`` or None (no setting).

    ``apply(threads)`` returns the keyword arguments for ``Fleet`` (after setting a global, if
    that is the form the library has).
    """
    import inspect

    import squkf

    params = inspect.signature(Fleet).parameters
    for name in ("threads", "num_threads", "n_threads"):
        if name in params:
            return f"Fleet(..., {name}=t)", lambda t, name=name: {name: t}
    for mod in (squkf, getattr(squkf, "kernels", None)):
        fn = getattr(mod, "set_num_threads", None)
        if callable(fn):
            return f"{mod.__name__}.set_num_threads(t)", lambda t, fn=fn: (fn(t), {})[1]
    return None


def run_fleet(model, zs, keep=False, threads=None):
    K, T, _ = zs.shape
    kw = {} if threads is None else thread_control()[1](threads)
    f = Fleet(K, model.n, model.m, model.dt, model.hx, model.fx, points(), **kw)
    f.x, f.P, f.Q, f.R = model.x0, model.P0, model.Q, model.R
    est = np.empty((K, T, model.n)) if keep else None
    t0 = time.perf_counter()
    for t in range(T):
        f.predict()
        f.update(zs[:, t])
        if est is not None:
            est[:, t] = f.x
    return time.perf_counter() - t0, est, f


def run_loop(model, zs, keep=False):
    K, T, _ = zs.shape
    filters = []
    for _ in range(K):
        g = SquareRootUKF(model.n, model.m, model.dt, model.hx, model.fx, points(), vectorized=True)
        g.x, g.P, g.Q, g.R = model.x0.copy(), model.P0.copy(), model.Q.copy(), model.R.copy()
        filters.append(g)
    return _time_loop(filters, zs, model.n, keep)


def _time_loop(filters, zs, n, keep):
    """Seconds for T steps of a loop over the filters (and their estimates, with ``keep``)."""
    K, T, _ = zs.shape
    est = np.empty((K, T, n)) if keep else None
    t0 = time.perf_counter()
    for t in range(T):
        for k, g in enumerate(filters):
            g.predict()
            g.update(zs[k, t])
            if est is not None:
                est[k, t] = g.x
    return time.perf_counter() - t0, est, None


def run_filterpy(model, zs, keep=False):
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    K, T, _ = zs.shape
    filters = []
    for _ in range(K):
        pts = MerweScaledSigmaPoints(model.n, ALPHA, BETA, KAPPA)
        g = UnscentedKalmanFilter(model.n, model.m, model.dt, model.hx_point, model.fx_point, pts)
        g.x, g.P, g.Q, g.R = model.x0.copy(), model.P0.copy(), model.Q.copy(), model.R.copy()
        filters.append(g)
    return _time_loop(filters, zs, model.n, keep)


class Dynamax:
    """dynamax's UKF, vmapped over filters and jitted; compiled once per (K, T) before timing."""

    def __init__(self):
        import jax

        jax.config.update("jax_enable_x64", True)
        jax.config.update("jax_platforms", "cpu")
        from dynamax.nonlinear_gaussian_ssm import ParamsNLGSSM, UKFHyperParams, unscented_kalman_filter

        self.jax = jax
        self.Params, self.Hyper, self.ukf = ParamsNLGSSM, UKFHyperParams, unscented_kalman_filter
        self.version = __import__("dynamax").__version__
        self._compiled: dict = {}

    def _fn(self, model, K, T):
        key = (model.name, K, T)
        if key not in self._compiled:
            jax, jnp = self.jax, self.jax.numpy
            f, h = model.jax_functions()
            # dynamax updates first: start it at the others' first prediction (exact: linear dynamics)
            m1 = model.F @ model.x0
            P1 = model.F @ model.P0 @ model.F.T + model.Q
            params = self.Params(
                initial_mean=jnp.asarray(m1),
                initial_covariance=jnp.asarray(P1),
                dynamics_function=f,
                dynamics_covariance=jnp.asarray(model.Q),
                emission_function=h,
                emission_covariance=jnp.asarray(model.R),
            )
            hyper = self.Hyper(alpha=ALPHA, beta=BETA, kappa=KAPPA)

            def one(z):
                return self.ukf(params, z, hyper, output_fields=["filtered_means"]).filtered_means

            fn = jax.jit(jax.vmap(one))
            fn(np.broadcast_to(model.measure(model.x0), (K, T, model.m)).copy()).block_until_ready()
            self._compiled[key] = fn
        return self._compiled[key]

    def run(self, model, zs, keep=False):
        K, T, _ = zs.shape
        fn = self._fn(model, K, T)
        z = self.jax.device_put(zs)
        t0 = time.perf_counter()
        out = fn(z).block_until_ready()
        dt = time.perf_counter() - t0
        return dt, (np.asarray(out) if keep else None), None


# -- measuring --------------------------------------------------------------------------------------


def rmse(est, truth):
    return float(np.sqrt(np.mean((est - truth) ** 2)))


def accuracy(model, impls, K: int, T: int, seed: int) -> dict:
    """RMSE of every implementation on the same runs, and the largest difference from the fleet."""
    truth, zs = simulate(model, K, T, seed)
    _, ref, _ = run_fleet(model, zs, keep=True)
    out = {"K": K, "T": T, "fleet": {"rmse": rmse(ref, truth)}}
    for name, fn in impls.items():
        if name == "fleet":
            continue
        _, est, _ = fn(model, zs, keep=True)
        out[name] = {"rmse": rmse(est, truth), "max_abs_diff": float(np.max(np.abs(est - ref)))}
    return out


def state_bytes(f) -> int:
    """The bytes of a fleet's own arrays, each counted once (a record may be the state's array)."""
    arrays = {id(v): v for v in vars(f).values() if isinstance(v, np.ndarray)}
    return sum(a.nbytes for a in arrays.values())


def fleet_memory(model, K: int, seed: int) -> dict:
    """tracemalloc peak during one predict + update of a K-filter fleet, above the allocations before it."""
    truth, zs = simulate(model, K, 2, seed)
    f = Fleet(K, model.n, model.m, model.dt, model.hx, model.fx, points())
    f.x, f.P, f.Q, f.R = model.x0, model.P0, model.Q, model.R
    f.predict()
    f.update(zs[:, 0])  # a warm step first (records, caches)
    z = zs[:, 1].copy()
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    tracemalloc.reset_peak()
    f.predict()
    f.update(z)
    current, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    state = state_bytes(f)
    return {"K": K, "peak_MB": (peak - before) / 1e6, "state_MB": state / 1e6}


def _status_mb() -> dict:
    out = {}
    with open("/proc/self/status") as fh:
        for line in fh:
            key, _, value = line.partition(":")
            if key in ("VmRSS", "VmHWM"):
                out[key] = int(value.split()[0]) * 1024 / 1e6  # kB -> MB
    return out


def _trim() -> None:
    """Give freed heap memory back to the system (glibc), so that RSS growth shows a step's own peak."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _reset_peak() -> bool:
    _trim()
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")  # VmHWM := VmRSS
        return True
    except OSError:
        return False


STEPS_MEASURED = 3


def rss_child(model, K: int, seed: int, lib=None) -> dict:
    """In this (fresh) process: the RSS of a built K-filter fleet and the peak RSS of three steps.

    Per step: the peak RSS growth above the RSS before the step (``stepN_peak_MB``), and the peak
    above the RSS before the fleet was built (``stepN_total_MB``: its state, whatever it keeps
    between steps, the step's temporaries).

    ``lib``: the package whose ``Fleet`` is measured (default: this squkf).
    """
    import resource

    import squkf

    lib = squkf if lib is None else lib

    def fleet(k):
        pts = lib.MerweScaledWeights(ALPHA, BETA, KAPPA)
        return lib.Fleet(k, model.n, model.m, model.dt, model.hx, model.fx, pts)

    _, zs = simulate(model, K, STEPS_MEASURED, seed)
    small = fleet(64)  # kernels: compile or load
    small.x, small.P, small.Q, small.R = model.x0, model.P0, model.Q, model.R
    small.predict()
    small.update(simulate(model, 64, 1, seed + 1)[1][:, 0])
    del small
    _trim()  # as before each step: the RSS the fleet's own is measured from
    r0 = _status_mb()["VmRSS"]
    f = fleet(K)
    f.x, f.P, f.Q, f.R = model.x0, model.P0, model.Q, model.R
    r1 = _status_mb()["VmRSS"]
    state = state_bytes(f) / 1e6
    out = {"K": K, "state_MB": state, "built_rss_MB": r1 - r0, "reset": True}
    for t in range(STEPS_MEASURED):
        out["reset"] &= _reset_peak()
        before = _status_mb()["VmRSS"]
        f.predict()
        f.update(zs[:, t])
        s = _status_mb()
        out[f"step{t + 1}_peak_MB"] = s["VmHWM"] - before
        out[f"step{t + 1}_after_MB"] = s["VmRSS"] - before
        # what the fleet holds at the step's peak: its state, any buffers kept between steps, temporaries
        out[f"step{t + 1}_total_MB"] = s["VmHWM"] - r0
    out["ru_maxrss_MB"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e6
    return out


def fleet_rss(mkey: str, K: int, ref: Path | None = None) -> dict:
    """``rss_child`` in a fresh subprocess (pinned to one CPU, BLAS on one thread).

    ``ref``: a folder holding ``squkf_ref`` (:func:`against_revision.revision_folder`), measured
    instead of this squkf.
    """
    import subprocess

    cmd = [sys.executable, str(Path(__file__).resolve()), "--rss-child", mkey, str(K), "--cores", "1"]
    cmd += [] if ref is None else ["--ref-folder", str(ref)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode:
        raise RuntimeError(f"RSS subprocess failed:\n{p.stderr[-3000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


# the first step's and a steady step's (the third: buffers used in turn have all been written) peak RSS
# with the fleet's whole footprint, and the steady step's growth
PEAKS = ("step1_total_MB", "step3_total_MB", "step3_peak_MB")


def rss_against(mkey: str, K: int, rev: str, reps: int, log) -> dict:
    """The peak RSS of a fleet step here and at revision ``rev``, in fresh subprocesses, interleaved.

    Returns the medians over ``reps`` runs of each (``now``, ``ref``: the first and the second
    step's peak RSS growth, MB) with every run's, or ``why`` it was not measured.
    """
    import subprocess

    from against_revision import revision_folder

    try:
        folder = revision_folder(rev)
    except (subprocess.CalledProcessError, OSError) as exc:
        return {"rev": rev, "K": K, "why": f"{rev} could not be taken from git ({type(exc).__name__})"}
    runs: dict[str, list] = {"now": [], "ref": []}
    for r in range(reps):
        for which in ("now", "ref") if r % 2 == 0 else ("ref", "now"):
            runs[which].append(fleet_rss(mkey, K, None if which == "now" else folder))
    out = {"rev": rev, "K": K, "reps": reps, "runs": runs}
    for which, rs in runs.items():
        out[which] = {key: float(np.median([r[key] for r in rs])) for key in PEAKS}
    log(f"  peak RSS at K={K:,}: now {json.dumps(out['now'])}, at {rev} {json.dumps(out['ref'])}")
    return out


def malloc_child(model, K: int, T: int, seed: int, lib=None) -> dict:
    """In this (fresh) process: ``Fleet.batch_filter(keep="means")`` timed, after one untimed run.

    ``lib``: the package whose ``Fleet`` is timed (default: this squkf). Returns the timed run's
    wall-clock, user and system seconds, and the allocator setting seen.
    """
    import resource

    import squkf

    lib = squkf if lib is None else lib
    _, zs = simulate(model, K, T, seed)

    def run():
        pts = lib.MerweScaledWeights(ALPHA, BETA, KAPPA)
        f = lib.Fleet(K, model.n, model.m, model.dt, model.hx, model.fx, pts)
        f.x, f.P, f.Q, f.R = model.x0, model.P0, model.Q, model.R
        return f.batch_filter(zs, keep="means")

    run()  # kernels loaded, the allocator in its steady state (a worker runs chunk after chunk)
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    run()
    wall, r1 = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_SELF)
    return {
        "wall_s": wall,
        "user_s": r1.ru_utime - r0.ru_utime,
        "sys_s": r1.ru_stime - r0.ru_stime,
        "trim": os.environ.get("MALLOC_TRIM_THRESHOLD_"),
    }


def _malloc_runs(K: int, T: int, reps: int, folder: Path | None) -> dict:
    """``reps`` interleaved pairs of ``malloc_child`` runs, unset and set; their medians and ratios."""
    import subprocess

    runs: dict[str, list] = {"unset": [], "set": []}
    for r in range(reps):
        for which in ("unset", "set") if r % 2 == 0 else ("set", "unset"):
            env = {k: v for k, v in os.environ.items() if k not in MALLOC_VARS}
            if which == "set":
                env["MALLOC_TRIM_THRESHOLD_"] = DASK_TRIM
            cmd = [sys.executable, str(Path(__file__).resolve()), "--malloc-child", "n4", str(K), str(T)]
            cmd += ["--cores", "1"] + ([] if folder is None else ["--ref-folder", str(folder)])
            p = subprocess.run(cmd, env=env, capture_output=True, text=True)
            if p.returncode:
                raise RuntimeError(f"MALLOC_TRIM_THRESHOLD_ subprocess failed:\n{p.stderr[-3000:]}")
            runs[which].append(json.loads(p.stdout.strip().splitlines()[-1]))
    ratios = [s["wall_s"] / u["wall_s"] for u, s in zip(runs["unset"], runs["set"])]
    out = {"runs": runs, "ratio": float(np.median(ratios)), "range": [float(min(ratios)), float(max(ratios))]}
    for which, rs in runs.items():
        out[which] = {key: float(np.median([r[key] for r in rs])) for key in ("wall_s", "user_s", "sys_s")}
    return out


def malloc_trim(quick: bool, log, rev: str | None = None) -> dict:
    """``malloc_child`` with ``MALLOC_TRIM_THRESHOLD_`` unset and set to dask's 65536, interleaved.

    Each run is a fresh subprocess (glibc reads the variable at start) pinned to one CPU, started
    with none of glibc's ``MALLOC_*`` settings but the one compared. Returns the medians of each
    side's seconds, the median and range of the per-pair ratios of wall-clock time (set / unset),
    and with ``rev`` the same of that revision's package (``ref``), measured after this one's.
    """
    import subprocess

    K, T, reps = (500, 4, 2) if quick else (12_500, 40, 5)
    out = {"K": K, "T": T, "reps": reps, **_malloc_runs(K, T, reps, None)}
    log(
        f"MALLOC_TRIM_THRESHOLD_={DASK_TRIM} over unset, K={K:,}, T={T}: {out['ratio']:.3f}x "
        f"({out['range'][0]:.3f}-{out['range'][1]:.3f}, {reps} pairs)"
    )
    if rev is not None:
        from against_revision import revision_folder

        try:
            folder = revision_folder(rev)
        except (subprocess.CalledProcessError, OSError) as exc:
            out["ref"] = {"rev": rev, "why": f"{rev} could not be taken from git ({type(exc).__name__})"}
            return out
        out["ref"] = {"rev": rev, **_malloc_runs(K, T, reps, folder)}
        log(f"  at {rev}: {out['ref']['ratio']:.3f}x")
    return out


def steps_for(K: int, quick: bool) -> int:
    if quick:
        return 4
    return 20 if K <= 100 else 10 if K <= 1000 else 2


def reps_for(K: int, quick: bool) -> int:
    if quick:
        return 2
    return 7 if K <= 1000 else 5


def timing(model, impls, Ks, quick: bool, budget: float, seed: int, log, longer: bool = False) -> dict:
    """Per K: the time per filter-step of each implementation (median) and the fleet's speed-up (median).

    ``longer``: five times the steps and three times the repetitions (the two-thread runs, which have
    no loops to wait for: a ratio of two fleet runs of 2 steps moved by 0.3 from run to run).
    """
    rows: dict = {}
    last: dict[str, float] = {}  # median seconds per filter-step at the previous K
    for K in Ks:
        T = steps_for(K, quick) * (5 if longer and not quick else 1)
        reps = reps_for(K, quick) * (3 if longer and not quick else 1)
        names = []
        for name in impls:
            if name == "dynamax":
                run = not (quick and K == 1)  # quick: one compilation less
            elif name.startswith("fleet"):
                run = True
            else:  # a loop: while its run at the previous K predicts a run under the budget
                run = (not rows and name not in last) or (name in last and last[name] * K * T < budget)
            if run:
                names.append(name)
        times: dict[str, list[float]] = {name: [] for name in names}
        for r in range(reps):
            _, zs = simulate(model, K, T, seed + r)
            order = names[r % len(names) :] + names[: r % len(names)]
            for name in order:
                seconds, _, _ = impls[name](model, zs)
                times[name].append(seconds / (K * T))
        row = {"T": T, "reps": reps}
        for name in names:
            row[name] = {"us": float(np.median(times[name]) * 1e6)}
            if name != "fleet":
                ratios = np.array(times[name]) / np.array(times["fleet"])
                row[name]["speedup"] = float(np.median(ratios))
                row[name]["speedup_range"] = [float(ratios.min()), float(ratios.max())]
            last[name] = float(np.median(times[name]))
        for name in impls:
            if name not in names:
                last.pop(name, None)
        rows[K] = row
        log(
            f"  K={K:>6}: "
            + ", ".join(f"{n} {row[n]['us']:.3g} us" for n in names)
            + (f"  (T={T}, {reps} reps)")
        )
    return rows


# -- reporting ----------------------------------------------------------------------------------------


def versions(impls) -> str:
    import filterpy
    import scipy

    parts = [
        f"Python {platform.python_version()}",
        f"numpy {np.__version__}",
        f"scipy {scipy.__version__}",
        f"filterpy {filterpy.__version__}",
    ]
    if "dynamax" in impls:
        import jax

        parts.append(f"jax {jax.__version__}, dynamax {__import__('dynamax').__version__}")
    cpu = cpu_name()
    return f"Machine: {cpu}, {os.cpu_count()} cores; " + ", ".join(parts) + "; BLAS threads: 1."


def two_threads_child(args) -> dict:
    """In this process (on two CPUs): the fleet on one and two threads (``--skip dynamax``: jax never
    imported), or the fleet on two threads and dynamax, interleaved."""
    model = ConstantVelocity()
    impls = {
        "fleet": lambda m, zs, keep=False: run_fleet(m, zs, keep, threads=1),
        "fleet2": lambda m, zs, keep=False: run_fleet(m, zs, keep, threads=2),
    }
    if "dynamax" not in args.skip:
        impls = {"fleet": impls["fleet2"]}  # the fleet on two threads, as the reference
        try:
            impls["dynamax"] = Dynamax().run
        except ImportError:  # no bench extra (as in CI): as the main run, without the peer
            pass
    accuracy(model, impls, 10, steps_for(10, True), 1)  # untimed: compile or load everything first
    Ks = [10] if args.quick else [K for K in (args.Ks or TWO_THREAD_KS) if K >= 10_000]
    log = lambda s: print(s, file=sys.stderr)  # noqa: E731
    return timing(model, impls, Ks, args.quick, args.loop_budget, 500, log, longer=True)


def two_threads(args, log) -> dict:
    """``two_threads_child`` in subprocesses pinned to two CPUs: the scaling (no jax), then dynamax.

    Returns ``{K: row}``: the scaling run's row (``fleet``, ``fleet2`` with its speed-up), with
    ``vs_dynamax`` (the other run's row: ``fleet`` on two threads and ``dynamax``) when dynamax ran.
    """
    import subprocess

    def child(with_dynamax: bool) -> dict:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--threads-child", "--cores", "2"]
        cmd += ["--quick"] if args.quick else []
        cmd += [] if with_dynamax else ["--skip", "dynamax"]
        cmd += ["--Ks", *map(str, args.Ks)] if args.Ks else []
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode:
            raise RuntimeError(f"two-thread subprocess failed:\n{p.stderr[-3000:]}")
        for line in p.stderr.splitlines():
            if line.startswith("  K="):
                log(("  two threads, with dynamax:" if with_dynamax else "  two threads:") + line[1:])
        return json.loads(p.stdout.strip().splitlines()[-1])

    rows = child(False)
    if "dynamax" not in args.skip:
        for K, row in child(True).items():
            if "dynamax" in row and K in rows:
                rows[K]["vs_dynamax"] = row
    return rows


def _fmt(x: float) -> str:
    return f"{x:.3g}" if x < 1000 else f"{x:,.0f}"


def _cpus(n: int) -> str:
    return "one CPU" if n == 1 else f"{n} CPUs"


def write_markdown(out: Path, results: dict, command: str) -> None:
    lines = [
        "# Fleet benchmark: K filters at once",
        "",
        f"Produced by `{command}`; {results['machine']}",
        "",
        "Time per filter-step is the time of T steps (predict + update) of K filters divided by K * T "
        "(medians over interleaved repetitions); a loop is measured only up to the K where a run takes "
        f"under {results['loop_budget']:g} s, and blank cells were not measured. Speed-up is the median "
        "over repetitions of (that implementation's time) / (the fleet's time) in the same repetition. "
        f"One thread: BLAS on one thread and the process pinned to {_cpus(results['cores'])}, so XLA "
        "(dynamax) had as many cores. Memory (first table) is tracemalloc's peak during one warm fleet "
        "predict + update above the allocations before it: numpy's arrays, not numba's (see the memory "
        "section for the resident set size).",
        "",
    ]
    if results["skipped"]:
        lines += ["Skipped: " + "; ".join(results["skipped"]) + ".", ""]
    for mname, res in results["models"].items():
        names = [n for n in ("fleet", "loop", "filterpy", "dynamax") if n in results["impls"]]
        lines += [f"## {mname}", ""]
        head = ["K", "T x reps"] + [f"{LABELS[n]} us/filter-step" for n in names]
        head += [f"speed-up vs {n}" for n in names if n != "fleet"]
        head += ["fleet step peak MB (tracemalloc)", "fleet state MB"]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for K, row in res["timing"].items():
            cells = [f"{int(K):,}", f"{row['T']} x {row['reps']}"]
            cells += [_fmt(row[n]["us"]) if n in row else "" for n in names]
            cells += [f"{row[n]['speedup']:.3g}" if n in row else "" for n in names if n != "fleet"]
            mem = res["memory"].get(str(K)) or res["memory"].get(K)
            cells += [f"{mem['peak_MB']:.3g}", f"{mem['state_MB']:.3g}"] if mem else ["", ""]
            lines.append("| " + " | ".join(cells) + " |")
        acc = res["accuracy"]
        lines += [
            "",
            f"Accuracy (untimed, K = {acc['K']}, T = {acc['T']}): fleet RMSE {acc['fleet']['rmse']:.6g}; "
            + "; ".join(
                f"{LABELS[n]} RMSE {acc[n]['rmse']:.6g} "
                f"(largest |estimate - fleet's| {acc[n]['max_abs_diff']:.2g})"
                for n in names
                if n != "fleet" and n in acc
            )
            + ".",
            "",
        ]
    lines += memory_section(results) + revision_section(results) + threads_section(results)
    lines += malloc_section(results)
    tg = results.get("targets")
    if tg:
        lines += ["## Targets (n = 4)", "", "| target | measured | met |", "|---|---|---|"]
        for t in tg:
            lines.append(f"| {t['target']} | {t['measured']} | {t['met']} |")
        lines.append("")
    (out / "fleet.md").write_text("\n".join(lines))


def memory_section(results: dict) -> list[str]:
    lines = [
        "## Peak memory of one fleet step",
        "",
        "Resident set size in a fresh process at the largest K (kernels compiled or loaded on a small "
        "fleet first): the built fleet's RSS growth; for each of three steps the peak RSS (VmHWM, reset "
        "before the step, after malloc_trim) above the RSS before it; and for the third (steady) step "
        "the peak above the RSS before the fleet was built: its state, what it keeps between steps "
        "(buffers) and the step's temporaries. tracemalloc's peak (warm step, numpy's allocations only) "
        "beside it.",
        "",
        "| model | K | fleet state MB | built fleet RSS MB | first step peak RSS MB "
        "| second step peak RSS MB | third step peak RSS MB | third step: the fleet's peak RSS MB "
        "| warm step peak, tracemalloc MB |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for mname, res in results["models"].items():
        r = res.get("rss")
        if not r:
            continue
        mem = res["memory"].get(str(r["K"])) or res["memory"].get(r["K"]) or {}
        note = "" if r["reset"] else " (peak not reset: upper bounds)"
        lines.append(
            f"| {mname} | {r['K']:,} | {r['state_MB']:.3g} | {r['built_rss_MB']:.3g} | "
            f"{r['step1_peak_MB']:.3g}{note} | {r['step2_peak_MB']:.3g} | {r['step3_peak_MB']:.3g} | "
            f"{r['step3_total_MB']:.3g} | {mem.get('peak_MB', float('nan')):.3g} |"
        )
    return lines + [""]


def threads_section(results: dict) -> list[str]:
    th = results.get("two_threads")
    lines = ["## Two threads (CV range-bearing n=4)", ""]
    if th is None or "rows" not in th:
        why = (th or {}).get("why", "not run")
        return lines + [f"Not measured: {why}.", ""]
    lines += [
        f"Subprocesses pinned to two CPUs, threads set with `{th['control']}`. Speed-up: the fleet on one "
        "thread and on two interleaved in a process that never imports jax; the median over repetitions of "
        "(one-thread time) / (two-thread time). Against dynamax: the fleet on two threads and dynamax (XLA "
        "with both cores) interleaved in another process (XLA's worker threads spin after each call and "
        "would take the CPU from the fleet's second thread in the first; see the docstring); the median of "
        "the per-repetition ratios.",
        "",
        "| K | T x reps | fleet, 1 thread us | fleet, 2 threads us | 2 threads: speed-up over 1 (range) "
        "| with dynamax: fleet 2 threads us | dynamax us | fleet 2 threads / dynamax time |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for K, row in th["rows"].items():
        two = row.get("fleet2")
        vs = row.get("vs_dynamax") or {}
        dyn = vs.get("dynamax")
        sp = f"{1 / two['speedup']:.3g} ({_speedup_range(two)})" if two else ""
        cells = (
            [_fmt(vs["fleet"]["us"]), _fmt(dyn["us"]), f"{1 / dyn['speedup']:.3g}"] if dyn else ["", "", ""]
        )
        lines.append(
            f"| {int(K):,} | {row['T']} x {row['reps']} | {_fmt(row['fleet']['us'])} | "
            f"{_fmt(two['us']) if two else ''} | {sp} | " + " | ".join(cells) + " |"
        )
    return lines + [""]


def _speedup_range(entry: dict) -> str:
    """The range over repetitions of a two-thread run's speed-up (``entry``'s ratios are time ratios)."""
    lo, hi = entry.get("speedup_range", (math.nan, math.nan))
    return f"{1 / hi:.3g}-{1 / lo:.3g}"


def revision_section(results: dict) -> list[str]:
    """The peak RSS of a fleet step here and at the reference revision (``rss_against``)."""
    rows = [(m, r["rss_ref"]) for m, r in results["models"].items() if r.get("rss_ref")]
    if not rows:
        return []
    rev = rows[0][1]["rev"]
    lines = [
        f"## Peak memory of one fleet step, this revision and {rev}",
        "",
        "The measures above, in fresh subprocesses pinned to one CPU, of this squkf and of the `squkf` "
        f"package of {rev} (taken from git), interleaved; medians over the runs. The fleet's peak RSS: "
        "above the RSS before it was built (state, buffers kept between steps, the step's temporaries).",
        "",
        f"| model | K | runs | first step: the fleet's peak RSS MB | at {rev} "
        f"| third step: the fleet's peak RSS MB | at {rev} | third step: peak RSS growth MB | at {rev} |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for mname, r in rows:
        if "why" in r:
            lines.append(f"| {mname} | {r['K']:,} | not measured: {r['why']} | | | | | | |")
            continue
        now, ref = r["now"], r["ref"]
        lines.append(
            f"| {mname} | {r['K']:,} | {r['reps']} | "
            + " | ".join(f"{now[k]:.3g} | {ref[k]:.3g}" for k in PEAKS)
            + " |"
        )
    return lines + [""]


def malloc_section(results: dict) -> list[str]:
    """``Fleet.batch_filter`` with dask's ``MALLOC_TRIM_THRESHOLD_`` and without (``malloc_trim``)."""
    mt = results.get("malloc_trim")
    lines = [f"## MALLOC_TRIM_THRESHOLD_={DASK_TRIM} (a Dask worker's setting), CV range-bearing n=4", ""]
    if not mt or "why" in mt:
        return lines + [f"Not measured: {(mt or {}).get('why', 'not run')}.", ""]
    unset, trim = mt["unset"], mt["set"]
    lines += [
        f'`Fleet.batch_filter(keep="means")`, K = {mt["K"]:,}, T = {mt["T"]}, one thread, timed after '
        "one untimed run in fresh subprocesses pinned to one CPU, started with none of glibc's "
        f"`MALLOC_*` variables (unset) or with `MALLOC_TRIM_THRESHOLD_={DASK_TRIM}` alone (set), the "
        f"two interleaved over {mt['reps']} pairs; medians.",
        "",
        "| | wall s | user s | system s |",
        "|---|---|---|---|",
        f"| unset | {unset['wall_s']:.3g} | {unset['user_s']:.3g} | {unset['sys_s']:.3g} |",
        f"| set | {trim['wall_s']:.3g} | {trim['user_s']:.3g} | {trim['sys_s']:.3g} |",
        "",
        f"Set over unset, wall-clock time: **{mt['ratio']:.3f}x** (median of the pairs' ratios; range "
        f"{mt['range'][0]:.3f}-{mt['range'][1]:.3f}).",
        "",
    ]
    return lines + _malloc_ref_lines(mt.get("ref"))


def _malloc_ref_lines(ref: dict | None) -> list[str]:
    """The same comparison of the reference revision's package, measured after this one's."""
    if not ref:
        return []
    if "why" in ref:
        return [f"At {ref['rev']}: not measured ({ref['why']}).", ""]
    unset, trim = ref["unset"], ref["set"]
    return [
        f"The same at {ref['rev']} (its `squkf` package, measured after this one's): wall "
        f"{unset['wall_s']:.3g} s unset, {trim['wall_s']:.3g} s set (system {unset['sys_s']:.3g} s, "
        f"{trim['sys_s']:.3g} s); set over unset **{ref['ratio']:.3f}x** "
        f"(range {ref['range'][0]:.3f}-{ref['range'][1]:.3f}).",
        "",
    ]


def _row(table: dict, K: int):
    return table.get(K) or table.get(str(K))


def targets(results: dict) -> list[dict]:
    """The fleet targets of issue 30 for the n = 4 model (and issue 21's against filterpy's loop)."""
    res = results["models"].get(ConstantVelocity.name)
    if res is None:
        return []
    out = []

    def add(target, measured, met):
        out.append({"target": target, "measured": measured, "met": met})

    row = _row(res["timing"], 10_000)
    t = "K = 10^4, one thread: fleet's time <= 0.5x dynamax + vmap + jit's"
    if row is not None and "dynamax" in row:
        r = 1 / row["dynamax"]["speedup"]  # speedup: dynamax time / fleet time
        lo, hi = row["dynamax"]["speedup_range"]
        spread = f" ({1 / hi:.3g}-{1 / lo:.3g} over {row['reps']} runs)"
        add(t, f"{r:.3g}x dynamax's time{spread}", "yes" if r <= 0.5 else "no")
    else:
        add(t, "not measured", "-")
    t = "K = 10^4, one thread: >= 200x faster than a loop of filterpy UKFs (issue 21)"
    if row is not None and "filterpy" in row:
        s = row["filterpy"]["speedup"]
        add(t, f"{s:.3g}x", "yes" if s >= 200 else "no")
    else:
        add(t, "not measured", "-")
    t = "K = 10^5: two threads >= 1.6x the one-thread speed (median of >= 5 interleaved runs)"
    th = results.get("two_threads") or {}
    row2 = _row(th.get("rows", {}), 100_000)
    if row2 is not None and "fleet2" in row2:
        s = 1 / row2["fleet2"]["speedup"]
        spread = f" (median of {row2['reps']} runs; {_speedup_range(row2['fleet2'])})"
        met = "yes" if s >= 1.6 and row2["reps"] >= 5 else "no"
        add(t, f"{s:.3f}x{spread}", met)  # three decimals: 1.596 is not 1.6
    else:
        add(t, f"not measured ({th.get('why', 'no K = 10^5 run')})", "-")
    rr = res.get("rss_ref")
    rev = (rr or {}).get("rev", REF)
    t = f"K = 10^5: one fleet step's peak memory no higher than at {rev}"
    if rr and "why" not in rr and rr["K"] == 100_000:
        now, ref = rr["now"], rr["ref"]
        measured = (
            f"the fleet's peak RSS, steady (third) step {now['step3_total_MB']:.3g} MB "
            f"({rev}: {ref['step3_total_MB']:.3g}), first step {now['step1_total_MB']:.3g} MB "
            f"({rev}: {ref['step1_total_MB']:.3g}); the steady step's growth {now['step3_peak_MB']:.3g} MB "
            f"({rev}: {ref['step3_peak_MB']:.3g})"
        )
        met = all(now[k] <= ref[k] for k in ("step1_total_MB", "step3_total_MB"))
        add(t, measured, "yes" if met else "no")
    else:
        add(t, f"not measured ({(rr or {}).get('why', 'no K = 10^5 run against a revision')})", "-")
    mt = results.get("malloc_trim")
    t = f"MALLOC_TRIM_THRESHOLD_={DASK_TRIM}: batch_filter's time within 1.1x of the time without it"
    if mt and "why" not in mt:
        lo, hi = mt["range"]
        measured = (
            f"{mt['ratio']:.3f}x (K = {mt['K']:,}, T = {mt['T']}; {lo:.3f}-{hi:.3f} over {mt['reps']} pairs)"
        )
        add(t, measured, "yes" if mt["ratio"] <= 1.1 else "no")
    else:
        add(t, f"not measured ({(mt or {}).get('why', 'not run')})", "-")
    return out


def plot(out: Path, results: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    models = list(results["models"])
    fig, axes = plt.subplots(1, len(models), figsize=(5.2 * len(models), 4.2), squeeze=False)
    for ax, mname in zip(axes[0], models):
        tm = results["models"][mname]["timing"]
        for name in ("fleet", "loop", "filterpy", "dynamax"):
            Ks = [int(K) for K, row in tm.items() if name in row]
            if not Ks:
                continue
            us = [tm[K][name]["us"] for K in tm if name in tm[K]]
            ax.loglog(Ks, us, "o-", color=OKABE_ITO[name], label=LABELS[name])
        ax.set_xlabel("number of filters K")
        ax.set_ylabel("time per filter-step (µs)")
        ax.set_title(mname)
        ax.grid(True, which="major", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Median time per predict + update of one filter (BLAS 1 thread)", fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "fleet.png", dpi=120)
    plt.close(fig)


def _ref_package(folder: str | None):
    """``squkf_ref`` from ``folder`` (:func:`against_revision.revision_folder`), or None (this squkf)."""
    if folder is None:
        return None
    sys.path.insert(0, folder)
    import squkf_ref

    return squkf_ref


def hooks_table(out: Path, quick: bool) -> dict:
    """A fleet of 1,000 with a wrapping bearing (``hooks_bench.fleet``), its section of fleet.md rewritten
    (the other sections kept) and its results under ``"hooks"`` in fleet.json."""
    import hooks_bench

    K, steps, reps = (50, 3, 1) if quick else (1000, 20, 7)
    res = hooks_bench.fleet(K, steps, reps, python_steps=1 if quick else 2)
    lines = hooks_bench.fleet_section(res, K, steps, reps)
    md = out / "fleet.md"
    text = md.read_text() if md.exists() else "# Fleet benchmark: K filters at once\n"
    title = lines[0].split(":")[0]
    if title in text:  # the section up to the next "## "
        before, rest = text.split(title, 1)
        after = rest.split("\n## ", 1)[1] if "\n## " in rest else None
        text = before + "\n".join(lines) + ("" if after is None else "\n## " + after)
    else:
        text = text.rstrip("\n") + "\n\n" + "\n".join(lines) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    md.write_text(text)
    js = out / "fleet.json"
    data = json.loads(js.read_text()) if js.exists() else {}
    data["hooks"] = {"K": K, "steps": steps, "reps": reps, "results": res}
    js.write_text(json.dumps(data, indent=1, default=str))
    return res


def main(args) -> int:
    models = {"n4": ConstantVelocity, "n10": Oscillators}
    if args.hooks:
        res = hooks_table(Path(args.out), args.quick)
        print(json.dumps(res, indent=1))
        return 0
    if args.rss_child:
        lib = _ref_package(args.ref_folder)
        print(json.dumps(rss_child(models[args.rss_child[0]](), int(args.rss_child[1]), 7, lib)))
        return 0
    if args.malloc_child:
        mkey, K, T = args.malloc_child
        print(json.dumps(malloc_child(models[mkey](), int(K), int(T), 3, _ref_package(args.ref_folder))))
        return 0
    if args.threads_child:
        print(json.dumps(two_threads_child(args)))
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log = lambda s: print(s, flush=True)  # noqa: E731
    control = thread_control()
    fleet_one = (
        run_fleet if control is None else (lambda m, zs, keep=False: run_fleet(m, zs, keep, threads=1))
    )
    impls = {"fleet": fleet_one, "loop": run_loop, "filterpy": run_filterpy}
    skipped = []
    for name in ("loop", "filterpy"):
        if name in args.skip:
            impls.pop(name)
            skipped.append(f"{LABELS[name]} (--skip)")
    if "dynamax" in args.skip:
        skipped.append(f"{LABELS['dynamax']} (--skip)")
    else:
        try:
            impls["dynamax"] = Dynamax().run
        except Exception as exc:  # noqa: BLE001 - any import problem: skip the peer, say why
            skipped.append(f"{LABELS['dynamax']} ({type(exc).__name__}: {exc})")
    Ks = args.Ks or ([1, 10] if args.quick else [1, 10, 100, 1000, 10_000, 100_000])
    results = {
        "machine": versions(impls),
        "quick": args.quick,
        "impls": list(impls),
        "skipped": skipped,
        "loop_budget": args.loop_budget,
        "cores": args.cores,
        "models": {},
    }
    # the two-thread subprocesses first: after this process's dynamax calls its XLA workers spin for a
    # while on the CPU the subprocesses share (1.54x measured then, 1.64-1.66x alone)
    if args.no_two_threads:
        two = {"why": "--no-two-threads"}
    elif control is None:
        two = {
            "why": "squkf.Fleet has no thread setting (no threads= argument, no set_num_threads in "
            "squkf or squkf.kernels), so the fleet runs on one thread only"
        }
    elif "n4" not in args.models:
        two = {"why": "the n = 4 model was not run"}
    else:
        two = {"control": control[0], "rows": two_threads(args, log)}
    # timed subprocesses on this process's CPU: before it calls dynamax too (XLA's workers spin)
    ref = args.ref or (None if args.quick else REF)
    ref = None if ref == "none" else ref
    results["malloc_trim"] = (
        {"why": "--no-malloc-trim"} if args.no_malloc_trim else malloc_trim(args.quick, log, ref)
    )
    ok = True
    for i, mkey in enumerate(args.models):
        model = models[mkey]()
        log(f"{model.name}")
        # quick: the accuracy run has the shape of the last timed one (one compilation less for dynamax)
        acc = accuracy(
            model, impls, 10 if args.quick else 50, steps_for(10, True) if args.quick else 30, 1000 + i
        )
        d = abs(acc["fleet"]["rmse"] - acc["loop"]["rmse"]) if "loop" in acc else None
        acc["fleet_equals_loop"] = None if d is None else d <= 1e-9  # None: the loop was not run
        ok &= d is None or acc["fleet_equals_loop"]
        log(f"  accuracy: {json.dumps(acc)}")
        mem = {K: fleet_memory(model, K, 7) for K in Ks}
        rss = fleet_rss(mkey, max(Ks))
        log(f"  RSS: {json.dumps(rss)}")
        rss_ref = None if ref is None else rss_against(mkey, max(Ks), ref, 1 if args.quick else 3, log)
        tm = timing(model, impls, Ks, args.quick, args.loop_budget, 100 * (i + 1), log)
        results["models"][model.name] = {
            "timing": tm, "memory": mem, "rss": rss, "rss_ref": rss_ref, "accuracy": acc,
        }  # fmt: skip
    results["two_threads"] = two
    results["targets"] = targets(results)
    command = "python benchmarks/fleet.py" + (" --quick" if args.quick else "")
    command += f" --skip {' '.join(args.skip)}" if args.skip else ""
    command += f" --Ks {' '.join(map(str, args.Ks))}" if args.Ks else ""
    command += f" --models {' '.join(args.models)}" if args.models != ["n4", "n10"] else ""
    command += f" --cores {args.cores}" if args.cores != 1 else ""
    command += " --no-two-threads" if args.no_two_threads else ""
    command += f" --ref {args.ref}" if args.ref else ""
    command += " --no-malloc-trim" if args.no_malloc_trim else ""
    write_markdown(out, results, command)
    plot(out, results)
    (out / "fleet.json").write_text(json.dumps(results, indent=1, default=str))
    hooks_table(out, args.quick)
    for t in results["targets"]:
        log(f"  target {t['target']}: {t['measured']} ({t['met']})")
    if not ok:
        log("ACCURACY CHECK FAILED: the fleet's RMSE differs from the loop's by more than 1e-9")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(ARGS))
