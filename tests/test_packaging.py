"""The sdist and the wheel carry the licence, the typing marker and what the sdist's own tests read;
the version is written once; the `notebook` extra installs what the notebooks import.

The distributions are built with setuptools' PEP 517 backend in a subprocess, from a copy of the
source tree (the backend writes ``squkf.egg-info`` beside the sources); the wheel is built from the
unpacked sdist, as pip does.
"""

from __future__ import annotations

import ast
import importlib.metadata
import json
import re
import shutil
import subprocess
import sys
import tarfile
import zipfile
from email.parser import Parser
from pathlib import Path
from urllib.parse import unquote, urlparse

import pytest

import squkf

ROOT = Path(__file__).resolve().parents[1]

NOT_SOURCES = shutil.ignore_patterns(
    ".git",
    ".venv*",
    "venv",
    "build",
    "dist",
    "*.egg-info",
    "__pycache__",
    "*.pyc",
    ".pytest_cache",
    ".ruff_cache",
    ".hypothesis",
    ".ipynb_checkpoints",
)

# Files the tests open by path (tests/test_readme.py, tests/models.py, tests/test_benchmarks.py
# and the files benchmarks/run.py imports), besides every tests/*.py and benchmarks/*.py.
READ_BY_TESTS = ["README.md", ".ci/run", "squkf/examples/g13ej_example.json"]


def backend(hook: str, source: Path, out: Path, pattern: str) -> Path:
    """Run ``setuptools.build_meta.<hook>(out)`` in ``source``; the one file it made in ``out``."""
    out.mkdir()
    subprocess.run(
        [sys.executable, "-c", f"import setuptools.build_meta as b; b.{hook}({str(out)!r})"],
        cwd=source,
        check=True,
        capture_output=True,
        text=True,
        timeout=120,
    )
    (made,) = out.glob(pattern)
    return made


@pytest.fixture(scope="module")
def dists(tmp_path_factory) -> dict:
    tmp = tmp_path_factory.mktemp("packaging")
    source = tmp / "source"
    shutil.copytree(ROOT, source, ignore=NOT_SOURCES)
    sdist = backend("build_sdist", source, tmp / "sdist", "squkf-*.tar.gz")
    with tarfile.open(sdist) as tar:
        names = tar.getnames()
        # the "data" filter where this Python has it (3.12+ warn without a filter)
        tar.extractall(tmp / "unpacked", **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))
    (top,) = {name.split("/")[0] for name in names}
    wheel = backend("build_wheel", tmp / "unpacked" / top, tmp / "wheel", "squkf-*.whl")
    return {
        "sdist_names": {name.split("/", 1)[1] for name in names if "/" in name},
        "pkg_info": (tmp / "unpacked" / top / "PKG-INFO").read_text(encoding="utf-8"),
        "wheel": wheel,
    }


def metadata(text: str):
    return Parser().parsestr(text)


def test_sdist_carries_the_licence_and_everything_its_tests_read(dists):
    names = dists["sdist_names"]
    wanted = {"LICENSE", "CHANGELOG.md", "pyproject.toml", "squkf/py.typed", *READ_BY_TESTS}
    wanted |= {"tests/conftest.py", "tests/models.py"}
    wanted |= {p.relative_to(ROOT).as_posix() for p in ROOT.glob("tests/*.py")}
    wanted |= {p.relative_to(ROOT).as_posix() for p in ROOT.glob("benchmarks/*.py")}
    wanted |= {p.relative_to(ROOT).as_posix() for p in ROOT.glob("squkf/**/*.py")}
    assert wanted <= names, sorted(wanted - names)
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc")]
    meta = metadata(dists["pkg_info"])
    assert meta["Version"] == squkf.__version__
    assert meta["License-Expression"] == "MIT"


def test_wheel_carries_the_licence_and_the_typing_marker(dists):
    with zipfile.ZipFile(dists["wheel"]) as whl:
        names = set(whl.namelist())
        (info,) = {n.split("/")[0] for n in names if n.split("/")[0].endswith(".dist-info")}
        meta = metadata(whl.read(f"{info}/METADATA").decode())
        licence = whl.read(f"{info}/licenses/LICENSE").decode()
    assert "MIT License" in licence and "the squkf developers" in licence
    assert {"squkf/py.typed", "squkf/_version.py", "squkf/examples/g13ej_example.json"} <= names
    # only the package and its metadata: tests and benchmarks stay in the sdist
    assert {n.split("/")[0] for n in names} == {"squkf", info}
    assert meta["Version"] == squkf.__version__
    assert meta["License-Expression"] == "MIT"
    extras = set(meta.get_all("Provides-Extra"))
    assert {"test", "progress", "notebook"} <= extras


def installed_is_imported(dist: importlib.metadata.Distribution) -> bool:
    """Whether the installed distribution ``squkf`` is the package this test imported."""
    imported = Path(squkf.__file__).resolve()
    direct = dist.read_text("direct_url.json")
    if direct and json.loads(direct).get("dir_info", {}).get("editable"):
        source = Path(unquote(urlparse(json.loads(direct)["url"]).path)).resolve()
        return imported.parent.parent == source
    return Path(dist.locate_file("squkf/__init__.py")).resolve() == imported


def test_installed_version_is_the_package_version():
    try:
        dist = importlib.metadata.distribution("squkf")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("squkf is not installed (imported from the source tree)")
    if not installed_is_imported(dist):
        pytest.skip(f"the installed squkf is another copy than the imported {squkf.__file__}")
    assert squkf.__version__ == importlib.metadata.version("squkf"), (
        "installed metadata is stale: reinstall (pip install -e .)"
    )


# -- the notebook extra ----------------------------------------------------------------------------

NOTEBOOKS = ROOT / "notebooks"

# import names of distributions whose name differs
DISTRIBUTION_OF = {"IPython": "ipython", "sklearn": "scikit-learn"}

# squkf's modules that need an extra of their own
EXTRA_OF = {"squkf.dask": "dask"}


def normalized(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def requirements(meta, extra: str | None) -> set[str]:
    """The distributions the wheel's metadata requires with ``extra`` (``None``: at run time).

    squkf's own extras named in it (``squkf[dask]``) are expanded.
    """
    names = set()
    for line in meta.get_all("Requires-Dist"):
        requirement, _, marker = line.partition(";")
        if (extra is None and marker) or (extra is not None and f'extra == "{extra}"' not in marker):
            continue
        name, extras = re.fullmatch(r"\s*([A-Za-z0-9._-]+)\s*(?:\[([^\]]*)\])?.*", requirement).groups()
        if normalized(name) == "squkf":
            for own in (extras or "").split(","):
                names |= requirements(meta, own.strip())
        else:
            names.add(normalized(name))
    return names


def imported_modules(notebook: Path) -> set[str]:
    """Dotted names of the modules a notebook's code cells import (``from a import b``: ``a`` and ``a.b``)."""
    modules = set()
    for cell in json.loads(notebook.read_text(encoding="utf-8"))["cells"]:
        if cell["cell_type"] != "code":
            continue
        lines = "".join(cell["source"]).splitlines()
        code = "\n".join(line for line in lines if not line.lstrip().startswith(("%", "!")))  # IPython's
        for node in ast.walk(ast.parse(code)):
            if isinstance(node, ast.Import):
                modules |= {alias.name for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                modules |= {node.module} | {f"{node.module}.{alias.name}" for alias in node.names}
    return modules


def needed_distributions(modules: set[str], meta) -> set[str]:
    """What installing ``modules`` takes: third-party distributions, and those of squkf's extras they use."""
    local = {p.stem for p in NOTEBOOKS.glob("*.py")}
    needed = set()
    for module in modules:
        top = module.split(".")[0]
        if module in EXTRA_OF:
            needed |= requirements(meta, EXTRA_OF[module])
        elif top not in sys.stdlib_module_names and top not in local and top != "squkf":
            needed.add(normalized(DISTRIBUTION_OF.get(top, top)))
    return needed


def wheel_metadata(wheel: Path):
    with zipfile.ZipFile(wheel) as whl:
        (info,) = {n.split("/")[0] for n in whl.namelist() if n.split("/")[0].endswith(".dist-info")}
        return metadata(whl.read(f"{info}/METADATA").decode())


def test_notebook_extra_installs_what_every_notebook_imports(dists):
    if not NOTEBOOKS.is_dir():
        pytest.skip("not a checkout of the repository: no notebooks/ (the sdist carries none)")
    meta = wheel_metadata(dists["wheel"])
    provided = requirements(meta, None) | requirements(meta, "notebook")
    notebooks = sorted(NOTEBOOKS.glob("*.ipynb"))
    assert len(notebooks) >= 8
    lacking = {
        nb.name: sorted(needed_distributions(imported_modules(nb), meta) - provided) for nb in notebooks
    }
    assert not {name: missing for name, missing in lacking.items() if missing}
    # the reading itself: notebook 07 imports dask, pandas and squkf.dask
    assert {"dask", "pandas", "distributed"} <= needed_distributions(
        imported_modules(NOTEBOOKS / "07_dask.ipynb"), meta
    )


def test_the_blas_hold_comes_with_the_runtime_dependencies(dists):
    """squkf.blas holds the BLAS through threadpoolctl: a runtime dependency, so the hold is on by
    default, not only with an extra (issue 35)."""
    meta = wheel_metadata(dists["wheel"])
    assert "threadpoolctl" in requirements(meta, None)
    assert "threads" not in meta.get_all("Provides-Extra")


def test_readme_and_landing_page_name_every_dependency_and_extra(dists):
    meta = wheel_metadata(dists["wheel"])
    extras = meta.get_all("Provides-Extra")
    runtime = requirements(meta, None)
    assert "numba" in runtime and {"plot", "dask", "notebook"} <= set(extras)
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    landing = (ROOT / "docs" / "index.rst").read_text(encoding="utf-8")
    for page, code in ((readme, "`{}`"), (landing, "``{}``")):
        assert not [extra for extra in extras if code.format(extra) not in page]
        assert not [name for name in runtime if not re.search(rf"\b{name}\b", page)]


def _modules() -> list[str]:
    import pkgutil

    return sorted(
        info.name
        for info in pkgutil.walk_packages(squkf.__path__, "squkf.")
        if not info.name.startswith("squkf.examples")
    )


@pytest.mark.parametrize("name", _modules())
def test_every_name_a_module_exports_exists(name):
    """``__all__`` names only what the module defines: ``from module import *`` works."""
    import importlib

    module = importlib.import_module(name)
    missing = [n for n in getattr(module, "__all__", ()) if not hasattr(module, n)]
    assert not missing, f"{name}.__all__ names {missing}"
