"""Sphinx hook that checks firmtool's API reference against firmtool itself, so that it cannot drift.

The API reference is Markdown written into the committed pages by ``python docs/generate.py``
(``docs/api_markdown.py``: the docstrings of the public names of ``firmtool.__all__`` by group), like
everything else firmtool says about itself (the scenario reference, the command pages and their
table, the ``firmtool init`` template, the figures, the tutorials' code), so that it reads on the
repository page too; a test fails when those pages are stale (tests/test_generated_docs.py). This
hook only warns (an error under ``-W``) when a name of ``firmtool.__all__`` is in no group of the
reference, or a group names one it lacks.
"""

from __future__ import annotations

import sys
from pathlib import Path

from sphinx.util import logging

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # docs/: api_markdown

import api_markdown  # noqa: E402

logger = logging.getLogger(__name__)


def _check(app) -> None:
    try:
        api_markdown.check_groups()
    except api_markdown.ApiError as exc:
        logger.warning(f"firmtool_docs: {exc}")


def setup(app):
    app.connect("builder-inited", _check)
    return {"version": "2", "parallel_read_safe": True, "parallel_write_safe": True}
