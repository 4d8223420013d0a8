"""The documentation builds with warnings as errors (``sphinx-build -W``), as in CI.

Runs only where the ``docs`` extra is installed (``pip install '.[docs]'``); CI builds the docs in a
venv of their own (``.ci/run``). A warning is how the documentation's own checks fail: a command
without a page, a public name without an API entry, a figure that is missing, a broken reference.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("sphinx")
pytest.importorskip("myst_parser")
pytest.importorskip("numpydoc")

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.docs
def test_docs_build_with_warnings_as_errors(tmp_path):
    out = tmp_path / "html"
    p = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                        "-d", str(tmp_path / "doctrees"), str(ROOT / "docs"), str(out)],
                       capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert p.returncode == 0, p.stderr[-4000:]
    reference = (out / "scenario-reference.html").read_text()
    for anchor in ("scenario-key-model-dt", "scenario-key-model-robot-arm-link-lengths",
                   "scenario-key-world-obstacles-kind-sphere-radius", "scenario-key-measurement-kind-imperfect-noise-"
                   "lightdark-std-eta"):
        assert anchor in reference, anchor
    for command in ("init", "check", "build", "solve", "execute", "plot"):
        assert (out / "guide" / f"{command}.html").exists(), command
    assert "firmtool.simulate" in (out / "api" / "index.html").read_text()
