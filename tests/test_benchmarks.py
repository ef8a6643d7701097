"""The benchmark's --quick mode runs and writes complete results (no time is asserted)."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_quick_benchmark_writes_results(tmp_path):
    subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "run.py"), "--quick", "--out", str(tmp_path)],
        check=True,
        capture_output=True,
        text=True,
        timeout=300,
    )
    text = (tmp_path / "results.md").read_text()
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
    assert len(cells) == 7 and abs(sum(cells.values()) - whole) < 0.5
    assert (tmp_path / "scaling.png").stat().st_size > 1000
    assert (tmp_path / "failure_map.png").stat().st_size > 1000
