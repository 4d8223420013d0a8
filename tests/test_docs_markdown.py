"""The committed Markdown reads whole on a repository page (issue 54, 6): no Sphinx roles left
unrendered (``{doc}``, ``{class}``, ``{meth}``...: plain Markdown links and code spans instead), no
reStructuredText or API directives (the API reference is generated into Markdown), install lines
that work from a checkout, and every relative link to a page that exists."""

from __future__ import annotations

import re
import subprocess

from conftest import ROOT

ROLE = re.compile(r"\{[a-z][a-z0-9:_-]*\}`")  # MyST's inline role syntax: {name}`...`
DIRECTIVES_LEFT = ("toctree", "include")  # the site's navigation: nothing a reader misses on the page
LINK = re.compile(r"\]\(([^)\s#]+\.md)(#[^)]*)?\)")


def _markdown() -> list:
    files = subprocess.run(["git", "ls-files", "*.md"], cwd=ROOT, capture_output=True, text=True, check=True)
    return [ROOT / f for f in files.stdout.split() if (ROOT / f).is_file()]


def test_no_unrendered_sphinx_roles_in_the_committed_markdown():
    found = [f"{p.relative_to(ROOT)}:{i}: {line.strip()[:120]}" for p in _markdown()
             for i, line in enumerate(p.read_text().splitlines(), 1) if ROLE.search(line)]
    assert not found, "Sphinx roles show raw on a repository page:\n" + "\n".join(found)


def test_only_navigation_directives_are_left():
    found = []
    for p in _markdown():
        for i, line in enumerate(p.read_text().splitlines(), 1):
            m = re.match(r"\s*(```+|:::+)\{([a-z-]+)\}", line)
            if m and m.group(2) not in DIRECTIVES_LEFT:
                found.append(f"{p.relative_to(ROOT)}:{i}: {line.strip()}")
    assert not found, "directives that show raw on a repository page:\n" + "\n".join(found)


def test_relative_links_name_pages_that_exist():
    broken = [f"{p.relative_to(ROOT)}: {m.group(1)}" for p in _markdown() for m in LINK.finditer(p.read_text())
              if not m.group(1).startswith(("http:", "https:")) and not (p.parent / m.group(1)).resolve().is_file()]
    assert not broken, "\n".join(broken)


def test_install_lines_work_from_a_checkout():
    """``pip install 'firmtool[ros]'`` works only once firmtool is installed from the checkout; the
    pages show the checkout's form."""
    found = [f"{p.relative_to(ROOT)}:{i}" for p in _markdown() if p.name != "CHANGELOG.md"
             for i, line in enumerate(p.read_text().splitlines(), 1)
             if re.search(r"^\s*pip install '?firmtool\[", line)]
    assert not found, found
