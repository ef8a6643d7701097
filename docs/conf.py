"""Sphinx configuration for squkf's documentation.

Build with ``python -m sphinx -W --keep-going -b html docs docs/_build/html``; the
doctests of the pages and of the documented docstrings run with ``-b doctest``.
"""

import importlib
import sys
from pathlib import Path

# document this checkout's squkf, not whatever copy happens to be installed
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import squkf  # noqa: E402

project = "squkf"
author = "the squkf authors"
copyright = "squkf authors"
version = release = squkf.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.doctest",
    "numpydoc",
]

exclude_patterns = ["_build"]
source_suffix = {".rst": "restructuredtext"}
root_doc = "index"

html_theme = "furo"
html_title = f"squkf {release}"

# autodoc: document what the page names, in source order, with signatures as written
autodoc_default_options = {"member-order": "bysource"}
autodoc_typehints = "signature"
autodoc_preserve_defaults = True
autosummary_generate = False


def _importable(module: str) -> bool:
    try:
        importlib.import_module(module)
    except ImportError:
        return False
    return True


# squkf.dask documents itself with only the docs extra installed: where its extra (dask,
# distributed, and the pandas that dask's dataframes bring) is missing, autodoc imports it
# against stand-ins; where they are installed, against the real modules.
autodoc_mock_imports = [m for m in ("dask", "distributed", "pandas") if not _importable(m)]

# numpydoc: the pages list members themselves (autodoc's :members:), so numpydoc adds no
# autosummary tables of its own
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

# doctest: every example shares these imports
doctest_global_setup = """
import numpy as np
import squkf
"""
