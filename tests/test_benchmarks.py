"""The benchmarks' --quick modes run and write complete results (no time is asserted).

benchmarks/run.py (the single filter), benchmarks/fleet.py (its table, figure and JSON, and the
fleet matching the loop), benchmarks/dask_bench.py (on a LocalCluster) and benchmarks/blas_threads.py
(a large filter's step with the BLAS at its default threads and on one), benchmarks/dropin_costs.py
(filterpy's Saver, deepcopy and a new filter, side by side with filterpy).
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def run_quick(script: str, out: Path, result: str, timeout: int = 300) -> str:
    """Run ``benchmarks/<script> --quick --out <out>`` (it must succeed) and read the ``result`` it wrote."""
    subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / script), "--quick", "--out", str(out)],
        check=True,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    return (out / result).read_text()


def test_quick_benchmark_writes_results(tmp_path):
    text = run_quick("run.py", tmp_path, "results.md")
    for name in ("filterpy UKF", "squkf redrawn per-point", "squkf augmented vectorised"):
        assert f"| g13ej robot n=3 | {name} |" in text
        assert f"| coordinated turn n=5 | {name} |" in text
    # SquareRootUKF completes the near-singular sweep at every P0
    sweep = text.split("## Near-singular sweep")[1].split("##")[0]
    rows = [line for line in sweep.splitlines() if line.startswith("| 1e+")]
    assert len(rows) == 5
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[2:6] == ["completed"] * 4, row
    # the hand-inlined reference step is the same filter (same RMSE and NEES as SquareRootUKF)
    rows = {
        cells[1]: cells
        for line in text.splitlines()
        if line.startswith("| g13ej robot n=3 |")
        for cells in [[c.strip() for c in line.strip("|").split("|")]]
    }
    ref = rows["reference: inlined step, no checks vectorised"]
    assert ref[5:7] == rows["squkf redrawn vectorised"][5:7]
    assert "| g13ej robot n=3 | " in text.split("## Where the library's time goes")[1]
    # the profile's parts add up to the whole step (the facade's share is the remainder, so
    # this checks that every part was measured and written)
    profile = text.split("## Profile of one step")[1].split("##")[0]
    cells = {
        row.split("|")[1].strip(): float(row.split("|")[2])
        for row in profile.splitlines()
        if row.startswith("| ") and "---" not in row and "part" not in row
    }
    whole = cells.pop("whole step")
    assert len(cells) == 5 and abs(sum(cells.values()) - whole) < 0.5
    # the Python per step: both routes counted, each target judged on its count
    python = text.split("## Python per step")[1].split("##")[0]
    for route in ("vectorised", "per point"):
        row = next(line for line in python.splitlines() if line.startswith(f"| {route} |"))
        calls, depth, modules = (int(c) for c in row.strip("|").split("|")[1:])
        assert calls > 0 and 1 <= depth <= calls and 1 <= modules <= calls
        verdict = next(line for line in python.splitlines() if line.startswith(f"- {route}:"))
        assert f"calls {calls} (<= 50: {'met' if calls <= 50 else 'not met'})" in verdict
    # the targets of the single filter, each with its ratio (Lorenz-96 is not run with --quick)
    targets = text.split("## Targets")[1].split("##")[0]
    for sc in ("g13ej robot n=3", "coordinated turn n=5"):
        assert f"| {sc} | per-point | filterpy UKF | <= 0.35 |" in targets
        assert f"| {sc} | vectorised | filterpy UKF | <= 0.2 |" in targets
    assert (tmp_path / "scaling.png").stat().st_size > 1000
    assert (tmp_path / "failure_map.png").stat().st_size > 1000


def test_inlined_reference_is_the_library_step_bit_for_bit():
    """benchmarks/floor.py's floor drives the library's kernels as its default route does."""
    res = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "floor.py"), "--steps", "10"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    rows = [line for line in res.stdout.splitlines() if line.startswith("| ") and "scenario" not in line]
    assert len(rows) == 6, res.stdout + res.stderr  # three scenarios, vectorised and per point
    assert all(row.endswith("| the same, bit for bit |") for row in rows), res.stdout
    assert res.returncode == 0


def test_quick_fleet_benchmark(tmp_path):
    text = run_quick("fleet.py", tmp_path, "fleet.md")
    assert (tmp_path / "fleet.png").stat().st_size > 1000
    results = json.loads((tmp_path / "fleet.json").read_text())
    assert set(results) >= {"machine", "impls", "skipped", "models", "targets"}
    assert {"fleet", "loop", "filterpy"} <= set(results["impls"])
    assert len(results["models"]) == 2
    for name, res in results["models"].items():
        assert f"## {name}" in text
        assert set(res["timing"]) == {"1", "10"}
        for row in res["timing"].values():
            assert row["fleet"]["us"] > 0 and row["loop"]["us"] > 0 and row["filterpy"]["us"] > 0
        assert all(m["peak_MB"] > 0 for m in res["memory"].values())
        # three steps measured: each one's peak RSS growth and the fleet's peak RSS (the memory target's)
        rss = res["rss"]
        assert all(
            rss[f"step{t}_peak_MB"] >= 0 and math.isfinite(rss[f"step{t}_total_MB"]) for t in (1, 2, 3)
        )
        assert f"| {rss['step3_total_MB']:.3g} |" in text.split("## Peak memory of one fleet step")[1]
        acc = res["accuracy"]
        # the fleet and the loop of SquareRootUKF are the same filters: same RMSE, same estimates
        assert acc["fleet_equals_loop"] is True
        assert abs(acc["fleet"]["rmse"] - acc["loop"]["rmse"]) <= 1e-9
        assert acc["loop"]["max_abs_diff"] <= 1e-6  # positions of ~1e3 m: 1e-9 relative
        # filterpy's UKF with the same points is the same filter to rounding
        assert abs(acc["fleet"]["rmse"] - acc["filterpy"]["rmse"]) <= 1e-6 * acc["fleet"]["rmse"]
        if "dynamax" in results["impls"]:
            assert abs(acc["fleet"]["rmse"] - acc["dynamax"]["rmse"]) <= 1e-4 * acc["fleet"]["rmse"]
        # each ratio's spread over the repetitions holds its median
        for row in res["timing"].values():
            for name in set(row) & {"loop", "filterpy", "dynamax"}:
                lo, hi = row[name]["speedup_range"]
                assert lo <= row[name]["speedup"] <= hi
    # Fleet.batch_filter with a Dask worker's MALLOC_TRIM_THRESHOLD_ and without, in pairs of processes
    trim = results["malloc_trim"]
    assert [r["trim"] for r in trim["runs"]["set"]] == ["65536"] * trim["reps"]
    assert [r["trim"] for r in trim["runs"]["unset"]] == [None] * trim["reps"]
    ratios = [s["wall_s"] / u["wall_s"] for u, s in zip(trim["runs"]["unset"], trim["runs"]["set"])]
    assert trim["range"] == [min(ratios), max(ratios)] and min(ratios) <= trim["ratio"] <= max(ratios)
    assert f"**{trim['ratio']:.3f}x**" in text.split("## MALLOC_TRIM_THRESHOLD_=65536")[1]
    # every fleet target of issue 30 is reported, measured or not
    reported = [t["target"] for t in results["targets"]]
    for start in (
        "K = 10^4, one thread: fleet's time <= 0.5x",
        "K = 10^5: two threads >= 1.6x",
        "K = 10^5: one fleet step's peak memory no higher than at",
        "MALLOC_TRIM_THRESHOLD_=65536",
    ):
        assert any(t.startswith(start) for t in reported), start


def test_quick_dask_benchmark_writes_results(tmp_path):
    pytest.importorskip("distributed")
    pytest.importorskip("psutil")
    text = run_quick("dask_bench.py", tmp_path, "dask.md")
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if line.startswith("| ") and len(cells) == 4:
            rows[cells[0]] = cells
    for name in ("in-process Fleet", "1 worker", "2 workers", "1 worker, dask's default environment"):
        assert float(rows[name][1]) > 0, name
        assert float(rows[name][2].replace(",", "")) > 0, name
    # the cluster's means are bit-identical to Fleet.batch_filter's in this process
    assert "bit-identical to the in-process fleet's in every repetition: True" in text
    speedups = re.findall(r"\*\*([0-9.]+)x\*\*", text)
    assert len(speedups) == 3  # two workers / one, one worker / in process, untuned worker / in process
    # the reduced run: every filter converged (no failures, a few metres of error), memory polled per worker
    mem = text.split('keep="means", 2 workers')[1]
    assert "0 filters failed" in mem
    first, last = (float(v) for v in re.search(r"([0-9.]+) m at the first step, ([0-9.]+) m", mem).groups())
    assert 0 < last < first < 20
    peaks = [line for line in mem.splitlines() if re.match(r"\| [01] \| \d+ \| \d+ \|", line)]
    assert len(peaks) == 2


def test_fleet_profile_splits_the_whole_step():
    """benchmarks/fleet_profile.py: the kernels, the model functions and the rest make up the step, the
    kernel table put back afterwards."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import fleet_profile
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    from squkf.kernels import table

    installed = table.KERNELS
    row = fleet_profile.split(K=64, steps=2, reps=2)
    assert table.KERNELS is installed
    assert row["kernels"] > 0 and row["model"] > 0
    assert math.isclose(row["kernels"] + row["model"] + row["rest"], row["whole"])


def test_quick_blas_threads_benchmark_writes_results(tmp_path):
    text = run_quick("blas_threads.py", tmp_path, "blas_threads.md")
    arms = ("default threads (squkf's hold on)", "OPENBLAS_NUM_THREADS=1", "default threads, hold off")
    for arm in arms:
        (row,) = [line for line in text.splitlines() if line.startswith(f"| {arm}")]
        assert float(row.split("|")[2]) > 0, row
    (target,) = [line for line in text.splitlines() if line.startswith("| a step at n = 81")]
    assert re.search(r"\| \d+\.\d\dx \(per repetition: \d+\.\d\d\) \| (met|\*\*not met\*\*) \|$", target)


def test_quick_dropin_costs_benchmark_writes_every_ratio(tmp_path):
    text = run_quick("dropin_costs.py", tmp_path, "dropin_costs.md")
    rows = [line for line in text.splitlines() if line.startswith("| ") and "---" not in line][1:]
    assert len(rows) == 3
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        fp, sq, ratio = float(cells[1]), float(cells[2]), float(cells[3])
        assert fp > 0 and sq > 0 and math.isclose(ratio, sq / fp, rel_tol=0.05, abs_tol=0.02), row


@pytest.mark.slow  # about a minute: the robot's fits run at Python speed (its residual_z is a hook)
def test_quick_tune_benchmark_writes_every_ratio(tmp_path):
    text = run_quick("tune.py", tmp_path, "tune.md", timeout=600)
    ratios = [line for line in text.splitlines() if line.endswith(("| met |", "| missed |"))]
    assert len(ratios) == 6  # the robot's four, the constant-velocity model's two
    for row in ratios:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert float(cells[1]) > 0 and cells[3] in ("met", "missed"), row
    # each optimiser reports the log-likelihood it reached, a finite number
    fits = [
        r for r in text.split("| ratio |")[0].splitlines() if "Nelder-Mead over" in r or "fit_noise |" in r
    ]
    reached = [r.split("|")[3].strip() for r in fits]
    assert len(reached) == 3 and all(np.isfinite(float(v)) for v in reached)
