"""The documentation reads the same on the repository page and in the built site, and says what the
code does (issue 42).

- The generated parts of the pages (scenario reference, command help and table, templates, figures,
  the tutorials' code, the README's first part on the front page) are committed Markdown, current
  with the code: ``python docs/generate.py`` writes them, this test fails when a page is stale.
- No page relies on a Sphinx-only directive for its text (empty on the repository page).
- Facts a newcomer meets first are checked against the code: every shipped scenario is listed,
  the robot tutorial's table names methods with the code's signatures, installation.md's check
  command runs outside the source tree, its install commands are the README's.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from firmtool.cli import app
from firmtool.robots import LinearRobot, Robot
from firmtool.scenario import shipped_scenarios

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _generate():
    spec = importlib.util.spec_from_file_location("docs_generate", DOCS / "generate.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(spec.name, module)
    spec.loader.exec_module(sys.modules[spec.name])
    return sys.modules[spec.name]


def test_the_generated_pages_are_current():
    # in a process of its own: the pages list the robots a fresh interpreter knows (built-in and
    # installed), and a test run in this process (a worker runs many files) may have registered its own
    res = subprocess.run([sys.executable, str(DOCS / "generate.py"), "--check"], capture_output=True, text=True,
                         cwd=ROOT, timeout=600)
    assert res.returncode == 0, f"stale generated docs (run python docs/generate.py): {res.stdout}{res.stderr}"


def test_a_stale_page_is_found_and_rewritten(tmp_path):
    gen = _generate()
    page = tmp_path / "run.md"
    page.write_text("# run\n\n<!-- generated: help run -->\nold text\n<!-- end generated -->\n\nafter\n")
    assert gen.stale(tmp_path) == [page]
    text = gen.render_page(page, page.read_text())
    assert "old text" not in text and "firmtool run [OPTIONS] [SCENARIO]" in text and text.endswith("\n\nafter\n")
    page.write_text(text)
    assert gen.stale(tmp_path) == []
    page.write_text("<!-- generated: help no-such-command -->\n<!-- end generated -->\n")
    with pytest.raises(gen.GenerateError, match="no-such-command"):
        gen.stale(tmp_path)


def test_an_include_block_is_the_file_and_links_it(tmp_path):
    gen = _generate()
    (tmp_path / "code.py").write_text("import os\n\n\n@dataclass\nclass A:\n    x = 1\n\n\ndef f():\n    return 2\n")
    page = tmp_path / "page.md"
    assert gen.include(page, ["code.py", "pyobject=A"]) == \
        "`A` in [`code.py`](code.py):\n\n```python\n@dataclass\nclass A:\n    x = 1\n```\n"
    assert gen.include(page, ["code.py", "start-at=x = 1", "end-before=return", "language=text"]) == \
        "[`code.py`](code.py):\n\n```text\n    x = 1\n\n\ndef f():\n```\n"
    with pytest.raises(gen.GenerateError, match="no class or function 'B'"):
        gen.include(page, ["code.py", "pyobject=B"])


# Sphinx-only ways to put text in a page: empty on the repository page.
SITE_ONLY = ("{literalinclude}", "{firmtool-help}", "{scenario-reference}", "{firmtool-commands}",
             "{firmtool-template}", "{firmtool-figures}", "{include}")


def test_no_page_needs_the_built_site_for_its_text():
    gen = _generate()
    for page in gen.pages():
        text = page.read_text()
        for directive in SITE_ONLY:
            if directive == "{include}" and page.name == "changelog.md":
                assert "the file `CHANGELOG.md`" in text  # the site includes it; the repository page names it
                continue
            assert directive not in text, f"{page.relative_to(ROOT)} uses {directive}: use docs/generate.py"


def test_the_front_page_is_the_readme():
    index = (DOCS / "index.md").read_text()
    assert index.startswith("<!-- generated: readme -->\n# firmtool\n")
    readme = (ROOT / "README.md").read_text()
    intro = readme[:readme.index("\n## Documentation")]
    for line in intro.splitlines():  # every line, links made relative to docs/
        assert line.replace("](docs/", "](") in index, line


def test_every_shipped_scenario_is_listed():
    names = set(shipped_scenarios())
    assert {"smoke", "arm8_lightdark", "maze_lightdark", "platt_lightdark"} <= names
    for page in (DOCS / "scenarios.md", ROOT / "README.md"):
        text = page.read_text()
        missing = sorted(n for n in names if f"`{n}`" not in text)
        assert not missing, f"{page.relative_to(ROOT)} does not list the shipped scenarios {missing}"


# Names in the table's "how" column that are no attributes of a robot: a scenario key (`[model]
# dynamics`) and an argument of a method the cell names (goal_state's `start`).
NOT_ATTRIBUTES = {"dynamics", "start"}


def _robot_table() -> list[list[str]]:
    text = (DOCS / "tutorials" / "robot.md").read_text()
    table = text[text.index("| what | how"):].split("\n\n")[0]
    return [[c.strip() for c in row.strip("|").split(" | ")] for row in table.splitlines()[2:]]


def test_the_robot_tutorials_table_names_the_codes_methods():
    rows = _robot_table()
    assert len(rows) >= 15
    checked = 0
    for what, how, protocol, _default in rows:
        for name, args in re.findall(r"`([a-z_][a-z0-9_]*)(?:\(([^)]*)\))?`", how):
            if name in NOT_ATTRIBUTES:
                continue
            owner = next((c for c in (Robot, LinearRobot) if hasattr(c, name) or name in _annotations(c)), None)
            assert owner is not None, f"robot tutorial, {what!r}: Robot has no {name!r}"
            if f"`{name}(" in how:
                params = [p for p in inspect.signature(getattr(owner, name)).parameters if p != "self"]
                written = [a.strip() for a in args.split(",") if a.strip()]
                if written and written[-1] == "...":
                    assert params[:len(written) - 1] == written[:-1], (name, params)
                else:
                    assert params == written, f"robot tutorial: {name}({', '.join(written)}) but the code has {params}"
            checked += 1
        for target in re.findall(r"\{class\}`~?([\w.]+)`", protocol):
            module, _, attr = target.rpartition(".")
            assert hasattr(importlib.import_module(module), attr), target
    assert checked >= 30


def _annotations(cls) -> set[str]:
    return {n for c in cls.__mro__ for n in getattr(c, "__annotations__", {})}


def test_the_installation_check_runs_outside_the_source_tree(monkeypatch, tmp_path):
    text = (DOCS / "installation.md").read_text()
    block = re.search(r"Check the installation.*?```bash\n(.*?)```", text, re.S).group(1)
    args = shlex.split(block.split("#")[0])
    assert args[:2] == ["firmtool", "run"] and args[2] in shipped_scenarios(), args
    monkeypatch.chdir(tmp_path)  # no scenarios/ folder here
    r = CliRunner().invoke(app, args[1:])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "artifacts" / f"{args[2]}.h5").exists()


def _pip_commands(text: str) -> set[str]:
    return {" ".join(m.split()) for m in re.findall(r"pip install [^`#&\n]*[^\s`#&]", text)}


def test_the_install_commands_are_the_readmes():
    readme = _pip_commands((ROOT / "README.md").read_text())
    installation = _pip_commands((DOCS / "installation.md").read_text())
    assert {"pip install .", "pip install '.[docs]'"} <= readme
    assert readme <= installation, readme - installation
    for page in (ROOT / "README.md", DOCS / "installation.md", DOCS / "conf.py"):
        assert "pip install -e" not in page.read_text(), page


def test_the_online_page_is_a_users_page_and_its_measurements_kept():
    online = (DOCS / "online.md").read_text()
    assert len(online.splitlines()) <= 300  # 641 before it was cut to a user's page
    assert "Tried and not kept" not in online
    benchmarks = (ROOT / "benchmarks" / "README.md").read_text()
    for moved in ("Tried and not kept (point robot, 100 episodes per point)",
                  "python benchmarks/bench_online.py --scenario point arm unicycle --episodes 30"):
        assert moved in benchmarks, moved
