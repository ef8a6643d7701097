"""The package type-checks with mypy, and a user's code sees its annotations.

mypy runs in a subprocess: once on the package with the project's configuration (``[tool.mypy]`` in
pyproject.toml), and once on a small user script outside the source tree, which finds squkf on
``PYTHONPATH`` as an installed package. mypy reads an installed package's annotations only if it
carries ``py.typed``, so the script's ``assert_type`` checks pass only if the marker is there and the
annotations are what a user sees. A misuse in the same script must then be reported, on its line.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("mypy")

ROOT = Path(__file__).resolve().parents[1]

USER_SCRIPT = textwrap.dedent(
    """\
    import numpy as np
    from typing_extensions import assert_type

    from squkf import MerweScaledWeights, SquareRootUKF, unscented_transform


    def fx(x: np.ndarray, dt: float) -> np.ndarray:
        return np.array([x[0] + dt * x[1], x[1]])


    def hx(x: np.ndarray) -> np.ndarray:
        return x[:1]


    points = MerweScaledWeights(alpha=0.5, beta=2.0, kappa=0.0)
    ukf = SquareRootUKF(dim_x=2, dim_z=1, dt=0.1, hx=hx, fx=fx, points=points)
    ukf.predict()
    ukf.update(np.array([0.3]))
    assert_type(ukf.dim_x, int)
    assert_type(ukf.P1_2, np.ndarray)
    assert_type(ukf.Wm, np.ndarray)
    assert_type(ukf.y_whitened, np.ndarray)  # (a per-step record of the registry: its typed descriptor)
    assert_type(points.num_sigmas(2), int)
    mean, S = unscented_transform(np.square, np.zeros(2), np.eye(2), points=points)
    print(ukf.x, mean, S)
    """
)

# Each is wrong only by its types (it runs without error), so only a type checker that sees squkf's
# annotations reports it.
MISUSES = [
    "n_points: str = points.num_sigmas(2)",
    "P1_2: list = ukf.P1_2",
    "w: list = ukf.y_whitened",
    "ukf.y_whitened = np.zeros(2)",
]


@pytest.fixture(scope="module")
def mypy_cache(tmp_path_factory) -> Path:
    # shared by the runs (numpy is analysed once), and kept out of the source tree
    return tmp_path_factory.mktemp("mypy_cache")


def _mypy(args: list[str], cwd: Path, cache: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "mypy", "--cache-dir", str(cache), *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


def _error_lines(output: str, filename: str) -> set[int]:
    return {int(m) for m in re.findall(rf"^{re.escape(filename)}:(\d+): error:", output, flags=re.M)}


def test_package_is_clean_under_the_project_configuration(mypy_cache):
    run = _mypy([], ROOT, mypy_cache)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "error:" not in run.stdout, run.stdout


def test_users_code_sees_the_annotations(tmp_path, mypy_cache):
    (tmp_path / "mypy.ini").write_text("[mypy]\n")  # the user's own (default) configuration
    script = tmp_path / "user.py"
    script.write_text(USER_SCRIPT)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    args = ["--python-version", "3.10", "--config-file", str(tmp_path / "mypy.ini"), script.name]

    run = _mypy(args, tmp_path, mypy_cache, env)
    assert run.returncode == 0, run.stdout + run.stderr
    # the script is a real use of the API: it runs as written
    ran = subprocess.run([sys.executable, script.name], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert ran.returncode == 0, ran.stderr

    script.write_text(USER_SCRIPT + "\n".join(MISUSES) + "\n")
    first = USER_SCRIPT.count("\n") + 1
    run = _mypy(args, tmp_path, mypy_cache, env)
    assert run.returncode == 1, run.stdout + run.stderr
    assert _error_lines(run.stdout, script.name) == set(range(first, first + len(MISUSES))), run.stdout
