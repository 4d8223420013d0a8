"""A fast command line (issue 54, 5): the commands on a built roadmap import neither the engine's
warm-up module (numba's compile machinery, 1.3 s) nor scipy.stats (1.4 s); --help imports neither
numba nor scipy; the compile notice quotes a measured range for the robot's kind. The times
themselves are measured in benchmarks/bench_startup.py (never in a unit test)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from conftest import ROOT


def _imported(*args: str) -> set[str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    res = subprocess.run([sys.executable, "-X", "importtime", "-m", "firmtool", *args], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    return {line.rsplit("|", 1)[1].strip() for line in res.stderr.splitlines() if line.startswith("import time:")
            and "|" in line}


@pytest.mark.parametrize("command", ["check", "inspect", "solve"])
def test_the_commands_on_a_roadmap_import_no_warmup_nor_scipy_stats(command, smoke_roadmap, tmp_path):
    import shutil
    path = tmp_path / "smoke.h5"
    shutil.copyfile(smoke_roadmap[0], path)
    args = {"check": ["check", "smoke"], "inspect": ["inspect", str(path)], "solve": ["solve", str(path), "-q"]}
    mods = _imported(*args[command])
    assert "firmtool.estimation.warmup" not in mods
    assert "scipy.stats" not in mods


def test_help_imports_neither_numba_nor_scipy():
    mods = _imported("--help")
    assert not {m for m in mods if m.split(".")[0] in ("numba", "scipy")}


def test_the_compile_notice_quotes_a_measured_range_per_robot_kind(capsys):
    import firmtool as ft
    from firmtool.cli.exits import _say_compiling
    from firmtool.estimation.warmup import compile_kind, hook_names
    from firmtool.problem import build_problem

    assert compile_kind(hook_names(build_problem(ft.load_scenario("arm7_shelf")))) == "3-D"
    assert compile_kind(hook_names(build_problem(ft.load_scenario("smoke")))) == "planar"
    _say_compiling("3-D")
    _say_compiling("planar")
    err = capsys.readouterr().err.splitlines()
    assert "for a 3-D robot (45 s-3 min on 2 cores, measured" in err[0]
    assert "for a planar robot (20-60 s on 2 cores, measured" in err[1]
