"""The documentation builds without a warning, covers the public API, and its examples run.

The HTML build and Sphinx's doctest builder run in subprocesses, as CI would run them, with
``-W`` (warnings are errors). The doctest builder runs the examples of the pages and of every
docstring the pages document, so an example in a public docstring is tested here.
"""

import os
import re
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
    "squkf.tune",
    "squkf.consistency",
]


@pytest.fixture(scope="module")
def doctrees(tmp_path_factory) -> Path:
    """One doctree cache for both builds: the second reuses the parsed pages."""
    return tmp_path_factory.mktemp("doctrees")


# the modules of the `dask` extra (pandas comes with dask's dataframes), absent where only the
# `docs` extra is installed
DASK_EXTRA = ("dask", "distributed", "pandas")


def without(modules: tuple[str, ...]) -> str:
    """Python code that makes ``modules`` (and their submodules) unimportable, as if not installed."""
    return f"""
import sys

class NotInstalled:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {modules!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)

sys.meta_path.insert(0, NotInstalled())
"""


def run_python(code: str, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    cmd = [sys.executable, "-c", code, *args]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)


def sphinx(
    builder: str, out: Path, doctrees: Path, missing: tuple[str, ...] = ()
) -> subprocess.CompletedProcess:
    """Sphinx's build, as ``python -m sphinx`` runs it, with the ``missing`` modules unimportable."""
    pytest.importorskip("sphinx")
    pytest.importorskip("numpydoc")
    pytest.importorskip("furo")
    main = "from sphinx.cmd.build import main; sys.exit(main(sys.argv[1:]))"
    args = ["-W", "--keep-going", "-q", "-b", builder, "-d", str(doctrees), str(DOCS), str(out)]
    return run_python(without(missing) + main, *args)


def inventory(html: Path) -> dict:
    from sphinx.util.inventory import InventoryFile

    with open(html / "objects.inv", "rb") as f:
        return InventoryFile.load(f, "", lambda base, uri: uri)


def test_html_build_has_no_warning_and_documents_the_public_api(tmp_path, doctrees):
    result = sphinx("html", tmp_path, doctrees)
    assert result.returncode == 0, result.stdout + result.stderr
    objects = inventory(tmp_path)
    documented = {name for entries in objects.values() for name in entries}
    missing = [name for name in squkf.__all__ if f"squkf.{name}" not in documented]
    assert not missing, f"public names without an API entry: {missing}"
    # the faces' members written once in a base (squkf.boundary) are documented with the faces
    inherited = [
        f"squkf.{face}.{m}" for face in ("SquareRootUKF", "Fleet") for m in ("fx_noise", "hx_noise", "gate")
    ]
    assert not [name for name in inherited if name not in documented]
    assert not [m for m in MODULES if m not in objects["py:module"]]
    # the internals are not part of the reference
    assert not [m for m in objects["py:module"] if m in ("squkf.step", "squkf.lane")]


def test_html_build_needs_only_the_docs_extra(tmp_path):
    # the README's docs command where the dask extra is not installed (a doctree cache of its own:
    # every page is read again, squkf.dask imported without dask)
    result = sphinx("html", tmp_path / "html", tmp_path / "doctrees", missing=DASK_EXTRA)
    assert result.returncode == 0, result.stdout + result.stderr
    functions = inventory(tmp_path / "html")["py:function"]
    assert {f"squkf.dask.{name}" for name in ("batch_filter", "filter_frame", "compute")} <= set(functions)


def test_squkf_dask_without_its_extra_says_which_extra_to_install():
    # the docs' stand-ins for the dask extra are the docs build's alone: a user still gets the error
    result = run_python(without(DASK_EXTRA) + "import squkf.dask")
    assert result.returncode != 0
    assert 'ModuleNotFoundError: squkf.dask needs its extra: pip install "squkf[dask]"' in result.stderr


def test_doctests_of_pages_and_docstrings_pass(tmp_path, doctrees):
    result = sphinx("doctest", tmp_path, doctrees)
    report = (tmp_path / "output.txt").read_text() if (tmp_path / "output.txt").exists() else ""
    assert result.returncode == 0, report + result.stdout + result.stderr
    # guard against a build that silently tested nothing (e.g. the doctest extension dropped)
    for page in ("index", "guide/filterpy", "guide/g13ej", "api/protocols", "api/weights", "api/errors"):
        assert f"Document: {page}\n" in report, f"no doctests ran in {page}"
    assert " 0 failures in tests" in report


def code_lines(rst: str) -> list[str]:
    """The lines of a page's doctest blocks and literal blocks (``::``, ``.. code-block::``), as rendered."""
    code: list[str] = []
    opener = content = None  # indents of the line that opens a literal block, and of its first line
    doctest = False
    for line in rst.splitlines():
        indent = len(line) - len(line.lstrip())
        if not line.strip():
            doctest = False
            continue
        if opener is not None and indent > opener:
            content = indent if content is None else content
            code.append(line[content:])
            continue
        opener = content = None
        doctest = doctest or line.startswith(">>>")
        if doctest:
            code.append(line)
        elif line.rstrip().endswith("::") or line.lstrip().startswith(".. code-block::"):
            opener = indent
    return code


def test_landing_page_code_fits_79_columns():
    code = code_lines((DOCS / "index.rst").read_text(encoding="utf-8"))
    assert any(line.startswith(">>> ukf = SquareRootUKF(") for line in code)  # the quick start is read
    assert "   pip install -e ." not in code and "pip install -e ." in code  # block indent stripped
    assert not [line for line in code if len(line) > 79]


def test_landing_page_links_every_part_of_the_library():
    page = (DOCS / "index.rst").read_text(encoding="utf-8")
    parts = ["api/fleet", "api/gating", "api/noise", "api/core", "api/errors", "api/protocols"]
    assert not [p for p in parts if f":doc:`{p}`" not in page]
    assert ":class:`~squkf.Fleet`" in page and ":mod:`squkf.dask`" in page


def test_scheme_docstrings_name_every_scheme_by_name():
    from squkf import Fleet, SquareRootUKF
    from squkf.generators import as_generator

    with pytest.raises(squkf.ParameterError) as info:
        as_generator("no such scheme")
    accepted = set(re.findall(r"'(\w+)'", str(info.value).split(" or ")[0]))
    assert {"redrawn", "augmented", "propagated"} <= accepted
    for face in (SquareRootUKF, Fleet):
        (documented,) = re.findall(r"scheme : \{([^}]*)\}", face.__doc__)
        assert set(re.findall(r'"(\w+)"', documented)) == accepted, face.__name__


def test_every_promise_names_test_files_that_exist_and_the_mid_step_rules_are_promised():
    """docs/api/promises.rst: each promise ends with the test files that check it, and those exist.

    Among them the rules a migrating program meets mid-step (issue 35): a configuration changed
    between predict and update, placeholders, the sigma points handed out, written records.
    """
    text = (DOCS / "api" / "promises.rst").read_text()
    labels = re.findall(r"^\.\. _(promise-[\w-]+):$", text, flags=re.M)
    for label in ("promise-configuration", "promise-placeholders", "promise-sigmas", "promise-records"):
        assert label in labels, label
    sections = re.split(r"^\.\. _promise-[\w-]+:$", text, flags=re.M)[1:]
    assert len(sections) == len(labels)
    for label, section in zip(labels, sections):
        named = set(re.findall(r"``(test_\w+\.py)``", section))
        assert named, f"{label} names no test file"
        for name in named:
            assert (ROOT / "tests" / name).is_file(), (label, name)
    configuration = sections[labels.index("promise-configuration")]
    for word in ("points_fn", "scheme", "gate", "next"):
        assert word in configuration, word
