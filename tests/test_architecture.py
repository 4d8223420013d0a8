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
