"""The README's quick starts run as written: its Python block, and its command-line block in order."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import matplotlib
from typer.testing import CliRunner

from firmtool.cli import app

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def block(language: str, index: int = 0) -> str:
    return re.findall(rf"```{language}\n(.*?)```", README, re.S)[index]


def test_the_readme_is_short_and_keeps_the_ci_commands_first():
    assert len(README.splitlines()) <= 130
    first = [ln for ln in block("bash", 0).splitlines() if ln.strip()]
    assert first[0].startswith("pip install . && firmtool run ")
    assert first[1].startswith("pip install '.[test]' && pytest ")


def test_the_python_quick_start_runs_as_written(monkeypatch, tmp_path):
    matplotlib.use("Agg")
    monkeypatch.chdir(tmp_path)
    code = block("python")
    assert len(code.strip().splitlines()) <= 6
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)  # noqa: S102 - the README's own example
    assert 0 < namespace["sol"].success_probability <= 1 and len(namespace["res"].episodes) == 200


def test_the_command_line_quick_start_runs_as_written(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    commands = [ln.split("#")[0].strip() for ln in block("bash", 1).splitlines() if ln.strip()]
    assert len(commands) <= 6
    for line in commands:
        for command in line.split("&&"):
            args = shlex.split(command)
            assert args[0] == "firmtool", command
            if args[1] == "execute":
                args += ["-n", "20"]  # fewer episodes than written, to keep the test short
            r = runner.invoke(app, args[1:])
            assert r.exit_code == 0, (command, r.output)
    assert (tmp_path / "artifacts" / "my_room.png").exists()
