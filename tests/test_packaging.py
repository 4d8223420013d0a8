"""What a fresh install needs: every imported module declared, optional features as extras with a
one-line error naming the extra, the shipped scenarios installed as package data, one version.

The import checks read the source (ast), so they hold for code paths no other test runs.
"""

import ast
import functools
import importlib.metadata
import re
import sys
import tomllib
from pathlib import Path

import pytest

import firmtool
from firmtool.errors import InputError
from firmtool.scenario import load_scenario, resolve_scenario, shipped_scenarios

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def _normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _requirement_names(requirements: list[str]) -> set[str]:
    return {_normalise(re.match(r"[A-Za-z0-9._-]+", r).group(0)) for r in requirements}


RUNTIME = _requirement_names(PYPROJECT["dependencies"])
EXTRAS = {extra: _requirement_names(reqs) for extra, reqs in PYPROJECT["optional-dependencies"].items()}


def _imports(folder: Path) -> list[tuple[str, Path, ast.AST, list[ast.AST]]]:
    """(top-level module, file, import node, enclosing nodes) of every absolute third-party import."""
    # the folder's own modules, and the repository's scripts a test reaches by sys.path (benchmarks/peers/rhc)
    local = {p.stem for f in {folder, ROOT / "benchmarks", ROOT / "examples"} for p in f.rglob("*.py")} | {"firmtool"}
    found = []
    for path in sorted(folder.rglob("*.py")):
        tree = ast.parse(path.read_text())

        def visit(node, parents):
            for child in ast.iter_child_nodes(node):
                names = []
                if isinstance(child, ast.Import):
                    names = [a.name for a in child.names]
                elif isinstance(child, ast.ImportFrom) and child.level == 0:
                    names = [child.module]
                for name in names:
                    top = name.split(".")[0]
                    if top not in sys.stdlib_module_names and top not in local:
                        found.append((top, path, child, parents))
                visit(child, parents + [child])

        visit(tree, [])
    return found


@functools.cache
def _module_distributions() -> dict[str, list[str]]:
    return importlib.metadata.packages_distributions()


def _distributions(module: str) -> set[str]:
    return {_normalise(d) for d in _module_distributions().get(module, [])}


def _named_distributions(module: str) -> set[str]:
    """Where ``module`` is not installed, the distributions that would provide it by name: its own
    name, and for ROS 2 packages (rclpy, std_msgs, ...) the wheel's, ``ros-`` and the package name."""
    return {_normalise(module), _normalise(f"ros-{module}")}


def _guard_names_extra(path: Path, parents: list[ast.AST], extra: str) -> bool:
    """Whether the import sits in a ``try`` whose ImportError handler names ``firmtool[extra]``."""
    text = path.read_text()
    for node in reversed(parents):
        if isinstance(node, ast.Try):
            for handler in node.handlers:
                caught = ast.get_source_segment(text, handler.type) if handler.type else ""
                if ("ImportError" in caught or "ModuleNotFoundError" in caught) and \
                        f"firmtool[{extra}]" in ast.get_source_segment(text, handler):
                    return True
    return False


def test_every_runtime_import_is_declared():
    problems = []
    for module, path, node, parents in _imports(ROOT / "firmtool"):
        dists = _distributions(module)
        where = f"{path.relative_to(ROOT)}:{node.lineno} imports {module}"
        if not dists:  # an optional extra that is not installed here, guarded by a handler naming it
            extras = [e for e, names in EXTRAS.items() if _named_distributions(module) & names and e != "test"]
            if not any(_guard_names_extra(path, parents, e) for e in extras):
                problems.append(f"{where}, which no installed distribution provides (nor an extra guarded by an "
                                f"ImportError handler naming it)")
        elif not dists & RUNTIME:
            extras = [e for e, names in EXTRAS.items() if dists & names and e != "test"]
            if not extras:
                problems.append(f"{where} ({', '.join(sorted(dists))}): not in [project].dependencies")
            elif not any(_guard_names_extra(path, parents, e) for e in extras):
                problems.append(f"{where}: only in the extra(s) {extras}, but the import is not guarded by an "
                                f"ImportError handler naming pip install 'firmtool[{extras[0]}]'")
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("folder", ["tests", "benchmarks", "examples"])
def test_test_and_example_imports_are_declared_for_the_test_extra(folder):
    if not (ROOT / folder).is_dir():
        pytest.skip(f"no {folder}/ folder")
    allowed = RUNTIME | EXTRAS["test"]
    # an optional extra's module (benchmarks/peers: pomdp-py) only behind an ImportError handler naming it
    problems = [f"{path.relative_to(ROOT)}:{node.lineno} imports {module} ({', '.join(sorted(_distributions(module))) or 'not installed'})"
                for module, path, node, parents in _imports(ROOT / folder) if not _distributions(module) & allowed
                and not any((_distributions(module) or _named_distributions(module)) & EXTRAS[e]  # not installed: its name
                            and _guard_names_extra(path, parents, e) for e in EXTRAS if e != "test")]
    assert not problems, "\n".join(problems)


def test_a_missing_extra_is_one_line_naming_it(monkeypatch):
    from firmtool.estimation.executors import run_edges
    monkeypatch.setitem(sys.modules, "dask", None)  # import dask... raises ImportError
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    with pytest.raises(InputError, match=re.escape("pip install 'firmtool[dask]'")) as info:
        list(run_edges(None, [0], workers=1, executor="dask"))
    assert "\n" not in str(info.value)


def test_the_ros_commands_without_the_extra_are_one_line(monkeypatch, smoke_roadmap):
    from typer.testing import CliRunner

    from firmtool.cli import app
    for name in [m for m in sys.modules if m == "rclpy" or m.startswith(("rclpy.", "firmtool.ros."))]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "rclpy", None)  # import rclpy raises ImportError
    res = CliRunner().invoke(app, ["ros", str(smoke_roadmap[0])])
    assert res.exit_code == 2, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "pip install 'firmtool[ros]'" in lines[0], res.output


def test_importing_firmtool_and_its_cli_imports_no_ros():
    import subprocess
    code = ("import sys, firmtool, firmtool.cli.app, firmtool.ros, firmtool.ros.checks, firmtool.ros.confine; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'std_msgs', 'geometry_msgs')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr


def test_shipped_scenarios_are_the_repository_files():
    """In a non-editable install (CI) this reads the installed package data."""
    files = {p.stem: p for p in (ROOT / "scenarios").glob("*.toml")}
    shipped = shipped_scenarios()
    assert list(shipped) == sorted(files) and "arm8_lightdark" in shipped
    for name, path in shipped.items():
        assert path.read_bytes() == files[name].read_bytes(), name


def test_a_shipped_name_loads_from_any_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    sc = load_scenario("smoke")
    assert sc.name == "smoke" and Path(sc.path) == shipped_scenarios()["smoke"]


def test_an_existing_path_wins_over_a_shipped_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    own = (ROOT / "scenarios" / "smoke.toml").read_text().replace('name = "smoke"', 'name = "mine"')
    Path("smoke").write_text(own)
    assert resolve_scenario("smoke") == Path("smoke") and load_scenario("smoke").name == "mine"


def test_an_unknown_name_lists_the_shipped_ones(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError) as info:
        load_scenario("arm9")
    text = str(info.value)
    assert text.startswith("arm9: no such file") and "\n" not in text
    assert all(name in text for name in shipped_scenarios())


def test_one_version():
    assert importlib.metadata.version("firmtool") == firmtool.__version__
