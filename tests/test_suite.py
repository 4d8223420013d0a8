"""The suite on 2 busy cores (issue 54, 8): the README's ``pytest`` leaves the long cases (marked
slow) to ``pytest -m slow``, which CI runs too, and prints its progress with an estimate of the time
left (tests/conftest.py). The whole suite's time is measured by the integrator, not here."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys

from conftest import ROOT


def test_ci_runs_the_slow_cases_and_the_default_run_leaves_them_out():
    text = (ROOT / "pyproject.toml").read_text()
    assert re.search(r"""addopts = ".*-m 'not slow'""", text)
    ci = (ROOT / ".ci" / "run").read_text()
    assert re.search(r"^step .*pytest -p no:cacheprovider -m slow", ci, re.M)


def test_the_suite_prints_its_progress_with_the_time_left(tmp_path):
    shutil.copyfile(ROOT / "tests" / "conftest.py", tmp_path / "conftest.py")
    (tmp_path / "test_many.py").write_text("import pytest\n\n@pytest.mark.parametrize('i', range(30))\n"
                                           "def test_one(i):\n    assert i >= 0\n")
    res = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-n", "0", "-q", str(tmp_path)],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout[-2000:]
    lines = re.findall(r"progress: (\d+) of 30 tests in \d+ s, about \d+ s left", res.stdout)
    assert [int(n) for n in lines] == [3, 6, 9, 12, 15, 18, 21, 24, 27, 30], res.stdout[-2000:]
