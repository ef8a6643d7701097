"""Throughput of ``squkf.dask`` on a LocalCluster of one and two worker processes.

The model is :mod:`dask_bench_models` (n = 4 constant velocity in the plane,
range-bearing radar, m = 2). Measurements are simulated on the workers, one
seeded block per chunk of filters, and persisted before timing (as if loaded
from storage), so that a timed run is: filter every chunk and gather the means
to the client. The same filters run in this process with
:meth:`squkf.Fleet.batch_filter` on the same measurements, interleaved with the
cluster runs over repetitions (the machine may be shared); medians are reported.

A final run at K = 10**6 with ``keep="means"`` reduces each chunk's means to
the squared position error summed over its filters per time step (so that the
1.3 GB of means never gather anywhere) while the workers' resident memory is
polled.

Usage: ``python benchmarks/dask_bench.py [--quick] [--out DIR]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # before numpy, and inherited by the worker processes

import argparse  # noqa: E402
import logging  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(ROOT), str(HERE)]
# worker processes import squkf from this checkout and the model functions by module name
os.environ["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(HERE), os.environ.get("PYTHONPATH", "")])

import dask  # noqa: E402
import dask.array as da  # noqa: E402
import distributed  # noqa: E402
import numpy as np  # noqa: E402
from dask_bench_models import cv_fx, initial_states, range_bearing_hx, simulated_block, worker_rss  # noqa: E402

import squkf  # noqa: E402
import squkf.dask as sd  # noqa: E402
from squkf import Fleet, MerweScaledWeights  # noqa: E402

P0 = np.diag([100.0, 100.0, 25.0, 25.0])
Q = np.diag([1e-4, 1e-4, 0.05**2, 0.05**2])
R = np.diag([0.5**2, 0.005**2])


def template(K: int, chunk: int, seed: int) -> Fleet:
    """The template fleet: every filter starts near its target's true initial state."""
    fleet = Fleet(K, 4, 2, 1.0, range_bearing_hx, cv_fx, MerweScaledWeights(1.0, 2.0, 0.0))
    sizes = chunk_sizes(K, chunk)
    fleet.x = np.concatenate([initial_states(s, seed + b) for b, s in enumerate(sizes)])
    fleet.P, fleet.Q, fleet.R = P0, Q, R
    return fleet


def chunk_sizes(K: int, chunk: int) -> tuple[int, ...]:
    return tuple(min(chunk, K - lo) for lo in range(0, K, chunk))


def simulated(K: int, T: int, chunk: int, seed: int) -> da.Array:
    """Truth and measurements ``(K, T, 6)``: ``[..., :4]`` truth, ``[..., 4:]`` measurements."""
    sizes = chunk_sizes(K, chunk)
    blocks = [
        da.from_delayed(dask.delayed(simulated_block)(s, T, seed + b), (s, T, 6), dtype=float)
        for b, s in enumerate(sizes)
    ]
    return da.concatenate(blocks, axis=0)


def start_cluster(n_workers: int, tuned: bool = True) -> distributed.Client:
    """``squkf.dask.local_cluster`` (or, untuned, a LocalCluster under dask's default environment)."""
    # a nanny writes its pre-spawn variables into this process's environment, which later workers
    # inherit: an untuned cluster must not see an earlier tuned one's
    os.environ.pop("MALLOC_MMAP_THRESHOLD_", None)
    options = {"host": "127.0.0.1", "dashboard_address": None, "silence_logs": 40}
    if tuned:
        cluster = sd.local_cluster(n_workers, **options)
    else:
        one_thread = {"threads_per_worker": 1, "processes": True}
        cluster = distributed.LocalCluster(n_workers=n_workers, **one_thread, **options)
    client = distributed.Client(cluster)
    seen = set(client.run(_mmap_threshold).values())
    want = {str(sd.MMAP_THRESHOLD) if tuned else None}
    if seen != want:
        raise RuntimeError(f"workers' MALLOC_MMAP_THRESHOLD_ is {seen}, expected {want}")
    return client


def _mmap_threshold() -> str | None:
    return os.environ.get("MALLOC_MMAP_THRESHOLD_")


UNTUNED = "1 worker, dask's default environment"


def stop_cluster(client: distributed.Client) -> None:
    cluster = client.cluster
    client.close()
    cluster.close()


def timed_dask(client, fleet: Fleet, zs: da.Array) -> tuple[float, np.ndarray]:
    lazy = sd.batch_filter(fleet, zs, keep="means")
    t0 = time.perf_counter()
    means = client.compute(lazy.means).result()
    return time.perf_counter() - t0, means


def timed_fleet(fleet: Fleet, zs: np.ndarray) -> tuple[float, np.ndarray]:
    f = fleet.subset(slice(None))
    t0 = time.perf_counter()
    res = f.batch_filter(zs, keep="means")
    return time.perf_counter() - t0, res.means


def throughput(K: int, T: int, chunk: int, reps: int, clients: dict, seed: int = 0) -> dict:
    """Interleaved repetitions: in-process fleet, then each cluster, in a rotating order."""
    fleet = template(K, chunk, seed)
    sim = simulated(K, T, chunk, seed)
    zs_np = sim[..., 4:].compute(scheduler="synchronous")
    zs = {name: c.persist(sim[..., 4:]) for name, c in clients.items()}
    for z in zs.values():
        distributed.wait(z)
    runs: dict[str, list[float]] = {"in-process Fleet": [], **{name: [] for name in clients}}
    identical = True
    names = list(runs)
    loads = []
    for r in range(reps):
        order = names[r % len(names) :] + names[: r % len(names)]
        for name in order:
            loads.append(os.getloadavg()[0])
            if name == "in-process Fleet":
                dt, means = timed_fleet(fleet, zs_np)
                ref = means
            else:
                dt, means = timed_dask(clients[name], fleet, zs[name])
                got = means
            runs[name].append(dt)
        identical &= bool(np.array_equal(got, ref))
    for c, z in zip(clients.values(), zs.values()):
        c.cancel(z)
    return {"K": K, "T": T, "chunk": chunk, "runs": runs, "identical": identical, "load": loads}


def memory_run(client, K: int, T: int, chunk: int, seed: int = 1, poll: float = 0.25) -> dict:
    """K filters with keep="means", each chunk reduced on its worker; peak RSS per worker."""
    fleet = template(K, chunk, seed)
    sim = simulated(K, T, chunk, seed)
    lazy = sd.batch_filter(fleet, sim[..., 4:], keep="means")
    err2 = ((lazy.means[..., :2] - sim[..., :2]) ** 2).sum(axis=-1)  # (K, T) squared position error
    sse = err2.sum(axis=0)  # (T,)
    n_failed = lazy.failed.sum()
    baseline = client.run(worker_rss)
    peak = dict(baseline)
    stop = threading.Event()

    def watch():
        while not stop.is_set():
            try:
                for w, rss in client.run(worker_rss).items():
                    peak[w] = max(peak.get(w, 0), rss)
            except Exception:  # a poll racing the end of the run
                pass
            stop.wait(poll)

    thread = threading.Thread(target=watch, daemon=True)
    t0 = time.perf_counter()
    load0 = os.getloadavg()[0]
    thread.start()
    sse_v, nf = client.compute([sse, n_failed], sync=True)
    dt = time.perf_counter() - t0
    stop.set()
    thread.join()
    template_mb = len(distributed.protocol.pickle.dumps(fleet.subset(slice(0, chunk)))) / 1e6
    return {
        "K": K,
        "T": T,
        "chunk": chunk,
        "seconds": dt,
        "rmse_last": float(np.sqrt(sse_v[-1] / K)),
        "rmse_first": float(np.sqrt(sse_v[0] / K)),
        "failed": int(nf),
        "baseline_mb": {w: v / 1e6 for w, v in baseline.items()},
        "peak_mb": {w: v / 1e6 for w, v in peak.items()},
        "template_mb": template_mb,
        "chunk_means_mb": chunk * T * 4 * 8 / 1e6,
        "chunk_sim_mb": chunk * T * 6 * 8 / 1e6,
        "load": (load0, os.getloadavg()[0]),
    }


def report(tp: dict, mem: dict, quick: bool, command: str) -> str:
    K, T = tp["K"], tp["T"]
    steps = K * T
    med = {name: statistics.median(v) for name, v in tp["runs"].items()}
    one, two, inproc, untuned = med["1 worker"], med["2 workers"], med["in-process Fleet"], med[UNTUNED]
    lines = [
        "# squkf.dask on a LocalCluster" + (" (--quick: sizes too small to mean anything)" if quick else ""),
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, shared with other jobs; Python "
        f"{platform.python_version()}, numpy {np.__version__}, dask {dask.__version__}, distributed "
        f"{distributed.__version__}, squkf {squkf.__version__}. BLAS threads 1; workers are processes "
        "with one thread each, started by `squkf.dask.local_cluster(n_workers)` (a `LocalCluster` with "
        "`threads_per_worker=1, processes=True` under `squkf.dask.worker_environ()`) except where a row "
        "says otherwise.",
        "",
        "Model: `benchmarks/dask_bench_models.py`, a constant-velocity target in the plane (n = 4) and a "
        "range-bearing radar (m = 2), Merwe points (alpha=1, beta=2, kappa=0), redrawn scheme. Measurements "
        "are simulated on the workers per chunk and persisted before timing; a timed run filters "
        '`keep="means"` and gathers the means to the client (in process: `Fleet.batch_filter(keep="means")` '
        f"on the same measurements). Command: `{command}`.",
        "",
        f"## Throughput at K = {K:,}, T = {T}, chunks of {tp['chunk']:,} filters",
        "",
        f"{len(tp['runs']['1 worker'])} interleaved repetitions (order rotated each time); 1-minute load "
        f"average at the start of each run: {', '.join(f'{x:.1f}' for x in tp['load'])}.",
        "",
        "| run | median s | filter-steps/s | all runs (s) |",
        "|---|---|---|---|",
    ]
    for name, v in tp["runs"].items():
        lines.append(
            f"| {name} | {med[name]:.2f} | {steps / med[name]:,.0f} | {', '.join(f'{x:.2f}' for x in v)} |"
        )
    lines += [
        "",
        f"- two workers / one worker: **{one / two:.2f}x** speed-up (target >= 1.6x; at most 2x on 2 cores).",
        f"- one worker / in-process fleet: **{one / inproc:.2f}x** the time (target <= 1.25x).",
        f"- one worker under dask's default environment / in-process fleet: **{untuned / inproc:.2f}x**: "
        "dask's nanny sets `MALLOC_TRIM_THRESHOLD_`, which under glibc pins malloc's mmap threshold at "
        "128 KiB, so each of the step's ~1 MB temporaries is a fresh zero-filled mapping; "
        "`worker_environ()` adds `MALLOC_MMAP_THRESHOLD_` (16 MiB).",
        f"- means bit-identical to the in-process fleet's in every repetition: {tp['identical']}.",
        "",
        f'## K = {mem["K"]:,}, T = {mem["T"]}, keep="means", 2 workers, chunks of {mem["chunk"]:,}',
        "",
        f"The means of the whole run would be {mem['K'] * mem['T'] * 4 * 8 / 1e9:.2f} GB; instead each "
        "chunk's means are reduced on its worker, with the chunk's simulated truth, to the squared position "
        "error summed over its filters per time step (a `(T,)` array), and only those sums are gathered "
        "(`((means[..., :2] - truth[..., :2])**2).sum(-1).sum(0)`, graph fused by dask). Worker memory "
        "(resident set) is polled with `client.run(psutil.Process().memory_info().rss)` every 0.25 s.",
        "",
        f"- time {mem['seconds']:.1f} s = {mem['K'] * mem['T'] / mem['seconds']:,.0f} filter-steps/s "
        f"(load average {mem['load'][0]:.1f} at the start, {mem['load'][1]:.1f} at the end).",
        f"- position RMSE over all {mem['K']:,} filters: {mem['rmse_first']:.2f} m at the first step, "
        f"{mem['rmse_last']:.2f} m at the last; {mem['failed']} filters failed.",
        "",
        "| worker | RSS before (MB) | peak RSS (MB) |",
        "|---|---|---|",
    ]
    for i, w in enumerate(sorted(mem["peak_mb"])):
        lines.append(f"| {i} | {mem['baseline_mb'][w]:.0f} | {mem['peak_mb'][w]:.0f} |")
    per_chunk = mem["chunk_means_mb"] + mem["chunk_sim_mb"] + mem["template_mb"]
    above = max(mem["peak_mb"][w] - mem["baseline_mb"][w] for w in mem["peak_mb"])
    lines += [
        "",
        f"The largest peak is {above:.0f} MB above its worker's resting size: about {above / per_chunk:.1f} "
        f"chunks' worth of data ({per_chunk:.0f} MB each, counted below).",
        "",
        f"Per chunk: means {mem['chunk_means_mb']:.0f} MB, simulated truth and measurements "
        f"{mem['chunk_sim_mb']:.0f} MB; each task carries its chunk's rows of the template fleet "
        f"(initial states, factors and records, {mem['template_mb']:.0f} MB pickled), "
        "not the whole template.",
        "",
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes, one repetition (a smoke test)")
    ap.add_argument("--out", type=Path, default=HERE / "results", help="folder for dask.md")
    ap.add_argument("--reps", type=int, default=None, help="repetitions of the throughput runs (default 3)")
    ap.add_argument("--mem-K", type=int, default=None, help="filters in the memory run (default 10**6)")
    ap.add_argument("--mem-T", type=int, default=None, help="steps in the memory run (default 40)")
    args = ap.parse_args(argv)
    logging.getLogger("distributed").setLevel(logging.ERROR)
    if args.quick:
        K, T, chunk, reps, K_mem, T_mem, chunk_mem = 1_000, 5, 250, 1, 2_000, 5, 500
    else:
        K, T, chunk, reps, K_mem, T_mem, chunk_mem = 100_000, 40, 25_000, 3, 1_000_000, 40, 50_000
    reps = args.reps or reps
    K_mem, T_mem = args.mem_K or K_mem, args.mem_T or T_mem
    untuned = start_cluster(1, tuned=False)  # first: see start_cluster
    clients = {"1 worker": start_cluster(1), "2 workers": start_cluster(2), UNTUNED: untuned}
    try:
        tp = throughput(K, T, chunk, reps, clients)
        print(f"throughput done: {tp['runs']}", flush=True)
        stop_cluster(clients.pop("1 worker"))
        stop_cluster(clients.pop(UNTUNED))
        mem = memory_run(clients["2 workers"], K_mem, T_mem, chunk_mem)
        print(f"memory run done: {mem}", flush=True)
    finally:
        for c in clients.values():
            stop_cluster(c)
    options = ["--quick"] if args.quick else []
    options += [
        f"--{name.replace('_', '-')} {v}"
        for name, v in vars(args).items()
        if name in ("reps", "mem_K", "mem_T") and v
    ]
    text = report(tp, mem, args.quick, " ".join(["python benchmarks/dask_bench.py", *options]))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "dask.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
