"""The house keeps its shape (issue 34; docs/architecture.md): import-linter's contracts hold (the
layers from the command line down to files and errors, no import circles in any package), every
module of firmtool/ sits in a layer, and no module or function outgrows what a maintainer reads at
once."""

import ast
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "firmtool"
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 80
# The compiled kernel's inner step: one numba function on purpose (its helpers are inlined at numba's
# IR level; a call per particle and step would cost what the kernel exists to save).
LONG_FUNCTIONS = {("firmtool/estimation/compiled/run.py", "run")}
MAX_TOP_LEVEL_MODULES = 15


def _config() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]


def test_import_contracts_hold():
    pytest.importorskip("importlinter")
    lint = Path(sys.executable).with_name("lint-imports")
    out = subprocess.run([str(lint) if lint.exists() else "lint-imports"], cwd=ROOT, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
    assert "BROKEN" not in out.stdout and out.stdout.count("KEPT") == len(_config()["contracts"])


def test_every_module_of_the_package_is_in_a_layer():
    layers = next(c for c in _config()["contracts"] if c["type"] == "layers")["layers"]
    named = {name.strip() for layer in layers for name in layer.split("|")}
    tops = {f"firmtool.{p.stem}" for p in PACKAGE.glob("*.py") if p.stem != "__init__"}
    tops |= {f"firmtool.{p.name}" for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    assert tops - named == set(), "modules in no layer of pyproject.toml's contract"
    assert named - tops == set(), "layers naming modules that do not exist"


def test_no_module_or_function_outgrows_a_read():
    too_long = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        text = path.read_text()
        if len(text.splitlines()) > MAX_MODULE_LINES:
            too_long.append(f"{rel}: {len(text.splitlines())} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES and (rel, node.name) not in LONG_FUNCTIONS:
                    too_long.append(f"{rel}: {node.name}() {lines} lines")
    assert not too_long, too_long


def test_few_modules_at_the_top():
    tops = [p.name for p in PACKAGE.glob("*.py")]
    assert len(tops) <= MAX_TOP_LEVEL_MODULES, sorted(tops)


def test_the_engine_names_no_robot():
    """Robot classes and robot kinds are named only in firmtool/robots/: the engine, the planner and the
    policy see a robot through its interface."""
    import re

    pattern = re.compile(r"ArmRobot|PointRobot|UnicycleRobot|ROBOT_(ARM|POINT)|PLANAR_(CHAIN|POINT)")
    found = [f"{p.relative_to(ROOT)}:{i}" for p in PACKAGE.rglob("*.py") if "robots" not in p.relative_to(PACKAGE).parts
             for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert not found, found


def _package_bullets(text: str) -> dict[str, str]:
    """docs/architecture.md's "What lives where" bullets: ``- `name/`: ...`` (continued on indented lines)
    by package name, and the top-level modules' bullet under ``""``."""
    import re

    section = text.split("## What lives where, package by package", 1)[1].split("\n## ", 1)[0]
    bullets: dict[str, str] = {}
    for item in re.split(r"\n(?=- )", section):
        m = re.match(r"- `([a-z_]+)/`:", item)
        if m:
            bullets[m.group(1)] = item
        elif item.startswith("- Top-level modules:"):
            bullets[""] = item
    return bullets


def _undescribed(text: str) -> list[str]:
    """What docs/architecture.md's ``text`` does not describe (see the test below)."""
    table = text.split("## The layers", 1)[1].split("\n## ", 1)[0]
    bullets = _package_bullets(text)
    missing = []
    for p in sorted(PACKAGE.iterdir()):
        if (p / "__init__.py").is_file():
            if f"`firmtool.{p.name}`" not in table:
                missing.append(f"firmtool.{p.name}: not in the layers table")
            bullet = bullets.get(p.name)
            if bullet is None:
                missing.append(f"{p.name}/: no bullet in 'What lives where'")
                continue
            for module in sorted(p.rglob("*.py")):
                if module.stem != "__init__" and f"`{module.stem}`" not in bullet:
                    missing.append(f"{module.relative_to(PACKAGE)}: not named in the {p.name}/ bullet")
            for sub in sorted(q for q in p.rglob("*") if (q / "__init__.py").is_file()):
                if f"`{sub.name}/`" not in bullet:
                    missing.append(f"{sub.relative_to(PACKAGE)}/: not named in the {p.name}/ bullet")
        elif p.suffix == ".py" and p.stem != "__init__":
            if f"`firmtool.{p.stem}`" not in table or f"`{p.stem}`" not in bullets.get("", ""):
                missing.append(f"firmtool.{p.stem}: not in the layers table and the top-level modules' bullet")
    return missing


def test_the_architecture_page_describes_every_module():
    """docs/architecture.md names every package and top-level module in its layers table, and every
    module of a package (a subpackage's too) in that package's bullet: a module added without a word
    there fails here."""
    missing = _undescribed((ROOT / "docs" / "architecture.md").read_text())
    assert not missing, missing


def test_the_architecture_check_sees_what_is_missing():
    """The check can fail: a page without a module, a package's bullet or a layer row is caught."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    assert _undescribed(text.replace("`file_kind`", "file kind")) == ["io/file_kind.py: not named in the io/ bullet"]
    assert "util/: no bullet in 'What lives where'" in _undescribed(text.replace("- `util/`:", "- util:"))
    assert "firmtool.jit: not in the layers table and the top-level modules' bullet" in _undescribed(
        text.replace("`firmtool.jit`", "firmtool.jit"))
