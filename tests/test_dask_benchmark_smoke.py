"""The Dask benchmark's --quick mode runs on a LocalCluster and writes complete results (no time asserted)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("distributed")
pytest.importorskip("psutil")

ROOT = Path(__file__).resolve().parents[1]


def test_quick_dask_benchmark_writes_results(tmp_path):
    subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "dask_bench.py"), "--quick", "--out", str(tmp_path)],
        check=True,
        capture_output=True,
        text=True,
        timeout=300,
    )
    text = (tmp_path / "dask.md").read_text()
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
