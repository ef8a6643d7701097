"""benchmarks/fleet.py --quick runs, writes its table, figure and JSON, and the fleet matches the loop."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_quick_fleet_benchmark(tmp_path):
    subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "fleet.py"), "--quick", "--out", str(tmp_path)],
        check=True,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert (tmp_path / "fleet.png").stat().st_size > 1000
    text = (tmp_path / "fleet.md").read_text()
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
        acc = res["accuracy"]
        # the fleet and the loop of SquareRootUKF are the same filters: same RMSE, same estimates
        assert acc["fleet_equals_loop"] is True
        assert abs(acc["fleet"]["rmse"] - acc["loop"]["rmse"]) <= 1e-9
        assert acc["loop"]["max_abs_diff"] <= 1e-6  # positions of ~1e3 m: 1e-9 relative
        # filterpy's UKF with the same points is the same filter to rounding
        assert abs(acc["fleet"]["rmse"] - acc["filterpy"]["rmse"]) <= 1e-6 * acc["fleet"]["rmse"]
        if "dynamax" in results["impls"]:
            assert abs(acc["fleet"]["rmse"] - acc["dynamax"]["rmse"]) <= 1e-4 * acc["fleet"]["rmse"]
