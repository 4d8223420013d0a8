"""Shared fixtures: small scenario texts and a built smoke roadmap; the number of test workers."""

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_TEST_WORKERS = 4  # beyond, each worker's session fixtures (built roadmaps) cost more than it saves


def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (pyproject's addopts): one worker per core this process may use, at most
    :data:`MAX_TEST_WORKERS`."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cores, MAX_TEST_WORKERS))

class _Progress:
    """A progress line with an estimate of the time left, every tenth of the tests (issue 54: the suite
    printed dots and no estimate; on a busy 2-core machine it looked stuck). In the controller only:
    with xdist the workers' reports arrive there; the total is the collection's."""

    def __init__(self, config) -> None:
        self.config, self.total, self.done, self.next, self.t0 = config, 0, 0, 0.1, None

    def start(self, total: int) -> None:
        import time
        if not self.total:
            self.total, self.t0 = total, time.monotonic()

    def report(self, report) -> None:
        import time
        if report.when != "teardown" or not self.total or self.t0 is None:
            return
        self.done += 1
        if self.done / self.total + 1e-9 < self.next:
            return
        self.next = (int(self.done * 10 / self.total) + 1) / 10
        elapsed = time.monotonic() - self.t0
        left = elapsed * (self.total - self.done) / self.done
        writer = self.config.pluginmanager.get_plugin("terminalreporter")
        if writer is not None:
            writer.ensure_newline()
            writer.write_line(f"progress: {self.done} of {self.total} tests in {elapsed:.0f} s, about {left:.0f} s "
                              "left")


def pytest_configure(config):
    global _config
    _config = config
    if not hasattr(config, "workerinput"):  # the controller (or a run without xdist), not an xdist worker
        config._firmtool_progress = _Progress(config)


def pytest_collection_finish(session):
    progress = getattr(session.config, "_firmtool_progress", None)
    if progress is not None and not session.config.pluginmanager.has_plugin("dsession"):
        progress.start(len(session.items))


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_node_collection_finished(node, ids):
    progress = getattr(node.config, "_firmtool_progress", None)
    if progress is not None:
        progress.start(len(ids))


_config = None


def pytest_runtest_logreport(report):
    progress = getattr(_config, "_firmtool_progress", None)
    if progress is not None:
        progress.report(report)


OPEN_WORLD = """
[scenario]
name = "open"
seed = 5

[model]
robot = "point"
dynamics = "{dynamics}"
dt = 0.1
process_noise_std = {q}

[measurement]
{measurement}

[world]
bounds = [[0.0, 0.0], [6.0, 6.0]]
robot_radius = 0.05
obstacles = {obstacles}

[task]
start = [1.0, 1.0]
goal = [4.0, 3.0]

[roadmap]
nodes = 4
neighbors = 5
min_separation = 1.0

[controller]
node_radius = 1.5
covariance_tolerance = 0.3
max_steps = 300

[estimation]
particles = 200
"""

IMPERFECT = 'kind = "imperfect"\nnoise = "constant"\nstd = {std}'
PERFECT = 'kind = "perfect"'


ROOM_3D = """[scenario]
name = "room"
[model]
robot = "point"
dynamics = "double_integrator"
dt = 0.1
process_noise_std = 0.05
[measurement]
kind = "perfect"
[world]
bounds = [[0.0, 0.0, 0.0], [6.0, 5.0, 4.0]]
robot_radius = 0.2
collision_backend = "fcl"
obstacles = [OBSTACLES]
[task]
start = [1.0, 1.0, 1.0]
goal = [5.0, 1.0, 2.0]
[roadmap]
nodes = 5
"""


def room_3d(obstacles: str) -> str:
    """A 3-D room for the point robot, perfect measurements, python-fcl, with ``obstacles`` (the TOML
    text of the obstacle tables, comma-separated)."""
    return ROOM_3D.replace("OBSTACLES", obstacles)


def open_world(dynamics="double_integrator", q=0.05, measurement=None, std=0.05, obstacles="[]") -> str:
    m = measurement if measurement is not None else IMPERFECT.format(std=std)
    return OPEN_WORLD.format(dynamics=dynamics, q=q, measurement=m, obstacles=obstacles)


@pytest.fixture(scope="session")
def smoke_roadmap(tmp_path_factory):
    """The smoke scenario built, solved (one worker), as a path; tests must not modify it."""
    from firmtool.pipeline import build, solve_stage
    out = tmp_path_factory.mktemp("smoke") / "smoke.h5"
    report = build(ROOT / "scenarios" / "smoke.toml", out, workers=1)
    solve_stage(out)
    return out, report
