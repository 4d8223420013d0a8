"""The first run on a cold numba cache: one background process compiles the engine, the CLI says
so on stderr (never on --json's stdout), and what it compiled is what other problems need.

Every process here uses its own empty numba cache (NUMBA_CACHE_DIR), so the test sees a fresh
install whatever the state of the package's own cache.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MESSAGE = "compiling the Monte Carlo engine, once per install"

# After the warm-up: design a small arm roadmap (another robot), estimate one of its edges alone and a
# batch as a worker does, and list the engine's functions numba had to compile for it (none expected:
# all loaded from cache, the design's nominals and the batched filter recursions included).
ARM_EDGE = """
import numpy as np
from numba.core import event
from firmtool.estimation import warmup
from firmtool.roadmap.design import design
from firmtool.estimation.edges import estimate_edge
from firmtool.roadmap.nodes import roadmap_nodes
from firmtool.problem import build_problem
from firmtool.scenario import parse_scenario, shipped_scenarios

engine = {f"{d.py_func.__module__}.{d.py_func.__qualname__}" for d in warmup.engine_functions()}
compiled = []

class Listener(event.Listener):
    def on_start(self, ev):
        name = f"{ev.data['dispatcher'].py_func.__module__}.{ev.data['dispatcher'].py_func.__qualname__}"
        if name in engine:
            compiled.append(name)
    def on_end(self, ev):
        pass

event.register("numba:compile", Listener())
text = shipped_scenarios()["arm8_lightdark"].read_text()
text = text.replace("nodes = 300", "nodes = 12").replace("bridge_nodes = 150", "bridge_nodes = 0")
problem = build_problem(parse_scenario(text, "arm.toml"))
centers, kinds = roadmap_nodes(problem, np.random.default_rng(1))
d = design(problem, centers, kinds)
estimate_edge(problem, d, d.regions(problem), int(d.edge_source[0]), int(d.edge_target[0]), 16, 0, 16, "numba")
# the estimation workers' path: a batch of edges whose controllers are designed together
from firmtool.estimation.executors import EstimationJob, remember_problem, run_batch
job = EstimationJob(scenario_text=text, scenario_path="arm.toml", design=d, particles=16, chunk=16, seed=0,
                    engine="numba")
remember_problem(job, problem)
run_batch(job, [0, 1, 2])
print(sorted(set(compiled)))
"""


def _env(cache: Path) -> dict:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "CI": "1"}
    env.pop("FIRMTOOL_ENGINE", None)
    return env


def _run(args, cache: Path, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, env=_env(cache), cwd=cwd,
                          timeout=1800)


@pytest.mark.slow  # issue 54: among the longest cases of the suite (durations in the report); CI runs -m slow
def test_a_cold_cache_is_compiled_once_announced_and_reused(tmp_path):
    cache = tmp_path / "numba-cache"
    cached = [sys.executable, "-c", "from firmtool.estimation import warmup; print(warmup.engine_is_cached())"][1:]
    assert _run(cached, cache, tmp_path).stdout.strip() == "False"

    # the console script from the repository root, as the README says (a source tree in the working
    # folder must not be what the background process compiles, nor where it looks for 'smoke')
    firmtool = Path(sys.executable).parent / "firmtool"
    cold = subprocess.run([firmtool, "build", "smoke", "-o", tmp_path / "a.h5", "--workers", "2", "--json"],
                          capture_output=True, text=True, cwd=ROOT, timeout=1800, env=_env(cache))
    assert cold.returncode == 0, cold.stderr
    assert MESSAGE in cold.stderr and cold.stderr.count(MESSAGE) == 1
    report = json.loads(cold.stdout)  # the message is not on stdout
    assert report["estimated_edges"] == report["edges"] > 0
    assert _run(cached, cache, tmp_path).stdout.strip() == "True"

    warm = _run(["-m", "firmtool", "build", "smoke", "-o", "b.h5", "--workers", "2"], cache, tmp_path)
    assert warm.returncode == 0, warm.stderr
    assert MESSAGE not in warm.stderr

    arm = _run(["-c", ARM_EDGE], cache, tmp_path)
    assert arm.returncode == 0, arm.stderr
    assert arm.stdout.strip() == "[]", f"compiled again for the arm: {arm.stdout}"
