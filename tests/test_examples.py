"""The scripts in examples/ run as a user runs them: ``python examples/NAME.py``, no arguments
(slow: CI runs them; ``pytest -m slow tests/test_examples.py``)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_custom_robot_3d_runs_with_its_robot_defined_in_the_script(tmp_path):
    """A 3-D robot defined and registered in __main__: built with 2 worker processes (the class
    travels pickled by value), solved, executed and plotted, in under two minutes."""
    out = tmp_path / "fig.png"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.run([sys.executable, str(ROOT / "examples" / "custom_robot_3d.py"), str(out)], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120, env=env)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "policy: success probability" in p.stdout and "in 100 episodes" in p.stdout and out.stat().st_size > 10_000
