"""Sphinx configuration of firmtool's documentation.

Build (warnings are errors, as in CI)::

    pip install '.[docs]'
    python docs/generate.py
    sphinx-build -W -b html docs docs/_build/html

Pages are Markdown (MyST); the API reference (from the numpydoc docstrings: ``docs/api_markdown.py``,
its groups checked against ``firmtool.__all__`` by ``docs/_ext/firmtool_docs.py``), the scenario
reference, the command pages and the other generated parts are written into the committed pages from firmtool's own schema and command line by
``docs/generate.py`` (checked current by tests/test_generated_docs.py), so that none can drift from
the code and all read on the repository page too.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(HERE.parent))  # a source checkout documents itself even when not installed

import firmtool  # noqa: E402

project = "firmtool"
author = "firmtool developers"
copyright = "2026, firmtool developers"  # noqa: A001 - Sphinx's name
release = firmtool.__version__
version = ".".join(release.split(".")[:2])

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "sphinx.ext.intersphinx",
    "numpydoc",
    "myst_parser",
    "firmtool_docs",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "README.md"]
templates_path: list[str] = []

myst_enable_extensions = ["dollarmath", "amsmath", "deflist", "colon_fence"]
myst_heading_anchors = 3

# numpydoc: the docstrings' own sections; no member tables (autodoc lists members where asked)
numpydoc_show_class_members = False
numpydoc_validation_checks: set[str] = set()
numpydoc_xref_param_type = False

autodoc_member_order = "bysource"
autodoc_typehints = "none"  # the numpydoc Parameters sections say the types, with shapes
autodoc_default_options = {"show-inheritance": False}

intersphinx_mapping: dict[str, tuple[str, None]] = {}  # no network in CI: no external inventories

html_theme = "alabaster"
html_title = f"firmtool {release}"
html_static_path: list[str] = []
html_theme_options = {"description": "FIRM: graph-based stochastic control under uncertainty",
                      "fixed_sidebar": True, "page_width": "1100px", "sidebar_width": "230px"}
