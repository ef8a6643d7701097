"""README's copy-paste commands are the ones CI runs."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    blocks = re.findall(r"```(?:bash|sh)\n(.*?)```", readme, flags=re.S)
    test_block = next(b for b in blocks if "pytest" in b)
    command = [line for line in test_block.splitlines() if "pytest" in line][0].strip()
    ci_lines = [line.strip() for line in ci.splitlines() if not line.strip().startswith("#")]
    assert command in ci_lines, f"CI does not run the README's test command: {command!r}"
