"""The documentation builds without a warning, covers the public API, and its examples run.

The HTML build and Sphinx's doctest builder run in subprocesses, as CI would run them, with
``-W`` (warnings are errors). The doctest builder runs the examples of the pages and of every
docstring the pages document, so an example in a public docstring is tested here.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

import squkf

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

# modules documented on pages of their own, besides the names in squkf.__all__
MODULES = [
    "squkf.nag",
    "squkf.batch",
    "squkf.smoother",
    "squkf.angles",
    "squkf.ut",
    "squkf.errors",
    "squkf.dask",
]


@pytest.fixture(scope="module")
def doctrees(tmp_path_factory) -> Path:
    """One doctree cache for both builds: the second reuses the parsed pages."""
    return tmp_path_factory.mktemp("doctrees")


def sphinx(builder: str, out: Path, doctrees: Path) -> subprocess.CompletedProcess:
    pytest.importorskip("sphinx")
    pytest.importorskip("numpydoc")
    pytest.importorskip("furo")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    cmd = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", builder]
    cmd += ["-d", str(doctrees), str(DOCS), str(out)]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)


def test_html_build_has_no_warning_and_documents_the_public_api(tmp_path, doctrees):
    result = sphinx("html", tmp_path, doctrees)
    assert result.returncode == 0, result.stdout + result.stderr
    from sphinx.util.inventory import InventoryFile

    with open(tmp_path / "objects.inv", "rb") as f:
        inventory = InventoryFile.load(f, "", lambda base, uri: uri)
    documented = {name for entries in inventory.values() for name in entries}
    missing = [name for name in squkf.__all__ if f"squkf.{name}" not in documented]
    assert not missing, f"public names without an API entry: {missing}"
    # the faces' members written once in a base (squkf.boundary) are documented with the faces
    inherited = [
        f"squkf.{face}.{m}" for face in ("SquareRootUKF", "Fleet") for m in ("fx_noise", "hx_noise", "gate")
    ]
    assert not [name for name in inherited if name not in documented]
    assert not [m for m in MODULES if m not in inventory["py:module"]]
    # the internals are not part of the reference
    assert not [m for m in inventory["py:module"] if m in ("squkf.step", "squkf.lane")]


def test_doctests_of_pages_and_docstrings_pass(tmp_path, doctrees):
    result = sphinx("doctest", tmp_path, doctrees)
    report = (tmp_path / "output.txt").read_text() if (tmp_path / "output.txt").exists() else ""
    assert result.returncode == 0, report + result.stdout + result.stderr
    # guard against a build that silently tested nothing (e.g. the doctest extension dropped)
    for page in ("index", "guide/filterpy", "guide/g13ej", "api/protocols", "api/weights", "api/errors"):
        assert f"Document: {page}\n" in report, f"no doctests ran in {page}"
    assert " 0 failures in tests" in report
