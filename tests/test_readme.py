"""README's copy-paste commands are the ones CI runs; its code fits a page; it lists every notebook; the
README, the docs pages and squkf's docstrings refer only to files in the repository."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"

# a file or folder named in code: words joined by slashes, no spaces (``benchmarks/fleet.py``, ``../spec/``)
PATH = re.compile(r"(?:\.\./)*[A-Za-z_][\w.-]*(?:/[\w.-]+)+/?")


def readme() -> str:
    return (ROOT / "README.md").read_text(encoding="utf-8")


def checkout() -> None:
    """Skip where the tests run from an sdist, which carries neither the notebooks nor the results."""
    if not NOTEBOOKS.is_dir():
        pytest.skip("not a checkout of the repository: no notebooks/")


def test_ci_runs_the_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text()
    blocks = re.findall(r"```(?:bash|sh)\n(.*?)```", readme(), flags=re.S)
    test_block = next(b for b in blocks if "pytest" in b)
    command = [line for line in test_block.splitlines() if "pytest" in line][0].strip()
    ci_lines = [line.strip() for line in ci.splitlines() if not line.strip().startswith("#")]
    assert command in ci_lines, f"CI does not run the README's test command: {command!r}"


def test_readme_python_code_fits_79_columns():
    blocks = re.findall(r"```python\n(.*?)```", readme(), flags=re.S)
    assert len(blocks) >= 3
    assert not [line for block in blocks for line in block.splitlines() if len(line) > 79]


def test_readme_notebook_table_lists_every_notebook():
    checkout()
    section = readme().split("\n## Notebooks\n", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("| [")]
    listed = [m for row in rows for m in re.findall(r"\]\(notebooks/([^)]+\.ipynb)\)", row)]
    assert listed == sorted(p.name for p in NOTEBOOKS.glob("*.ipynb"))


def referenced_paths(path: Path) -> set[str]:
    """Relative paths a file names: Markdown link targets, and code spans that look like a path."""
    text = path.read_text(encoding="utf-8")
    links = re.findall(r"\]\(([^)\s]+)\)", text) if path.suffix == ".md" else []
    # code: ``x`` in reStructuredText and docstrings, `x` in Markdown (not a role's :doc:`x`)
    spans = re.findall(r"``([^`\s]+)``", text) + re.findall(r"(?<![:`])`([^`\s]+)`(?!`)", text)
    named = [s for s in spans if PATH.fullmatch(s)] + [u.split("#")[0] for u in links]
    return {p for p in named if p and not re.match(r"[a-z]+://", p)}


@pytest.mark.parametrize(
    "source",
    ["README.md", "docs/**/*.rst", "squkf/**/*.py"],
)
def test_refers_only_to_files_in_the_repository(source):
    checkout()
    files = [ROOT / source] if "*" not in source else sorted(ROOT.glob(source))
    assert files
    missing = {
        f"{f.relative_to(ROOT)}: {p}" for f in files for p in referenced_paths(f) if not (ROOT / p).exists()
    }
    assert not missing
