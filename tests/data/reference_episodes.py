"""Reference episodes: what execution gave before the policy/environment split (issue 17).

``tests/data/reference_episodes.json`` was written by this module on main at 77e6db3, before the
executor was split into the agent (:mod:`firmtool.online`) and the simulated system
(:mod:`firmtool.sim`), and written again with the executor of branch i15 at 3378044 (issue 15: success
judged on the true state, goal misses; before the split was merged there:
``git archive 3378044 firmtool scenarios | tar -x -C OLD`` then ``PYTHONPATH=OLD python -c "import
reference_episodes as r; r.main()"`` from tests/data); the unicycle's kidnap case was written again when a kidnap began to set the unicycle down facing
anywhere (issue 17; every other case unchanged); ``tests/test_episodes_unchanged.py`` runs the same cases on the current code
and compares every episode: outcome, steps, cost, nodes, edges, events (step, kind, node, value,
detail), calibration traversals, and rows of the recorded states, estimates, covariances and controls.

Regenerate (only when a change of episodes is intended, and say why in the commit)::

    python tests/data/reference_episodes.py

The cases are small roadmaps built in seconds (smoke, a reduced point_lightdark, the unicycle tests'
tiny scenario), with disturbances, replanning on and off, and a start state in no node.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
FIXTURE = HERE / "reference_episodes.json"

# A copy of tests/test_unicycle.py's tiny scenario, on purpose: this module also runs on an old
# checkout (firmtool and scenarios only, see above), and the reference must not move when those tests do.
UNICYCLE_TINY = """
[scenario]
name = "unicycle_tiny"
seed = 4

[model]
robot = "unicycle"
dynamics = "unicycle"
dt = 0.1
process_noise_std = 0.02
heading_noise_std = 0.02
max_turn_rate = 1.5
orbit_radius = 0.08
orbit_speed = 0.25

[measurement]
kind = "imperfect"
noise = "lightdark_variance"
light_x = 3.0
a = 0.002
c = 0.0004

[world]
bounds = [[0.0, 0.0], [3.0, 2.0]]
robot_radius = 0.05
obstacles = [ { center = [1.5, 0.5], half_size = [0.15, 0.5] } ]

[task]
start = [0.4, 0.4]
goal = [2.6, 0.4]

[roadmap]
nodes = 5
neighbors = 4
min_separation = 0.5
max_edge_length = 2.2

[controller]
velocity_weight = 0.5
control_weight = 0.5
max_speed = 0.6
node_radius = 1.5
covariance_tolerance = 0.3
max_steps = 200

[estimation]
particles = 100

[cost]
alpha_covariance = 1.0
alpha_time = 0.1
failure_cost = 100.0
"""

# roadmap name -> how to make its scenario
ROADMAPS = ("smoke", "point_small", "unicycle_tiny")

# (roadmap, episodes, seed, disturbances, replanning, options)
CASES = [
    ("smoke", 8, 1, [], True, {}),
    ("smoke", 8, 1, ["push:8:1.0"], True, {}),
    ("smoke", 8, 1, ["push:8:1.0"], False, {}),
    ("smoke", 8, 2, ["kidnap:5"], True, {}),
    ("smoke", 8, 7, ["push:random:0.6:0.05", "kidnap:random:0.01"], True, {}),
    ("smoke", 6, 3, ["push:30:1.5", "kidnap:20"], True, {}),
    ("smoke", 5, 0, [], True, {"start": [0.5, 2.5]}),
    ("smoke", 6, 4, ["push:8:1.0"], True, {"risk_particles": 0}),
    ("point_small", 8, 0, [], True, {}),
    ("point_small", 8, 0, ["push:30:1.5"], True, {}),
    ("point_small", 8, 0, ["kidnap:40"], True, {}),
    ("point_small", 8, 0, ["kidnap:40"], False, {}),
    ("unicycle_tiny", 5, 0, [], True, {}),
    ("unicycle_tiny", 6, 0, ["push:20:0.3"], True, {}),
    ("unicycle_tiny", 6, 1, ["kidnap:15"], True, {}),
]


def scenario(name: str):
    import firmtool as ft
    from firmtool.scenario import parse_scenario

    if name == "smoke":
        return ft.load_scenario("smoke")
    if name == "point_small":
        return ft.load_scenario("point_lightdark").replace(roadmap={"nodes": 25}, estimation={"particles": 100})
    if name == "unicycle_tiny":
        return parse_scenario(UNICYCLE_TINY, "unicycle_tiny.toml")
    raise KeyError(name)


# Estimation settings that give the roadmaps of 77e6db3 on later code (issue 16 made adaptive Monte
# Carlo and edge starts over the node region the defaults; the reference roadmaps had neither; issue 55
# made stream 2 the new roadmaps' random stream, the reference roadmaps drew stream 1).
REFERENCE_ESTIMATION = {"adaptive_particles": 0, "start": "center", "stream": 1}


# Roadmaps whose reference was built by the numpy Monte Carlo engine, the only one the unicycle had
# then (its compiled engine, issue 55, is held to the numpy one particle by particle in tests/test_landmarks.py).
NUMPY_ENGINE = ("unicycle_tiny",)


def solution(name: str):
    import os

    import firmtool as ft
    from firmtool.scenario import EstimationSpec

    sc = scenario(name)
    fields = getattr(EstimationSpec, "__dataclass_fields__", {})
    settings = {k: v for k, v in REFERENCE_ESTIMATION.items() if k in fields}
    if settings:
        sc = sc.replace(estimation=settings)
    before = os.environ.get("FIRMTOOL_ENGINE")
    if name in NUMPY_ENGINE:
        os.environ["FIRMTOOL_ENGINE"] = "numpy"
    try:
        return ft.solve(ft.build(sc, workers=1))
    finally:
        if before is None:
            os.environ.pop("FIRMTOOL_ENGINE", None)
        else:
            os.environ["FIRMTOOL_ENGINE"] = before


def run_case(sol, episodes: int, seed: int, disturbances: list[str], replanning: bool, options: dict):
    import firmtool as ft

    opts = dict(options)
    start = opts.pop("start", None)
    fields = getattr(ft.ReplanSettings, "__dataclass_fields__", {})
    if "deadline" in fields:  # the settings of the executor before the split (the fields it did not have):
        opts.setdefault("deadline", 1e9)  # no deadline: one that never binds
        for name in ("partial_window", "jump_test", "refilter"):  # the fixes issue 17's sweep motivated, off
            opts.setdefault(name, False)
    replan = ft.ReplanSettings(enabled=replanning, **opts)
    return ft.simulate(sol, episodes, seed, disturbances=disturbances, replan=replan,
                       start=None if start is None else np.asarray(start, dtype=float), record=True)


def _value(v: float) -> float | None:
    return None if math.isnan(v) else float(v)


def _rows(a: np.ndarray) -> list:
    """The first, middle and last rows of a recorded array (exact floats)."""
    idx = sorted({0, a.shape[0] // 2, a.shape[0] - 1}) if a.shape[0] else []
    return [np.asarray(a[i], dtype=float).ravel().tolist() for i in idx]


def episode_record(ep) -> dict:
    """What must not change: discrete history exactly, numbers to the last bit on one machine."""
    return {
        "outcome": str(ep.outcome), "steps": int(ep.steps), "cost": float(ep.cost),
        "nodes": [int(n) for n in ep.nodes], "edges": [int(e) for e in ep.edges],
        "replans": int(ep.replans), "replan_failures": int(ep.replan_failures), "disturbances": int(ep.disturbances),
        "events": [[int(e.step), str(e.kind), int(e.node), _value(e.value), e.detail] for e in ep.events],
        "traversals": [[int(e), int(o)] for e, o in ep.traversals],
        "states": _rows(ep.states), "estimates": _rows(ep.estimates),
        "covariance_trace": _rows(np.trace(ep.covariances, axis1=1, axis2=2)[:, None]),
        "controls": _rows(ep.controls),
    }


def fingerprint(sol) -> dict:
    """The roadmap's policy: if it differs, the reference is of another roadmap, not another executor."""
    return {"policy": [int(e) for e in sol.policy], "success_probability": float(sol.success_probability)}


def main() -> None:
    from threadpoolctl import threadpool_limits

    out: dict = {"roadmaps": {}, "cases": []}
    with threadpool_limits(1):
        sols = {name: solution(name) for name in ROADMAPS}
        for name, sol in sols.items():
            out["roadmaps"][name] = fingerprint(sol)
        for case in CASES:
            name, episodes, seed, dists, replanning, options = case
            res = run_case(sols[name], episodes, seed, dists, replanning, options)
            out["cases"].append({"roadmap": name, "episodes": episodes, "seed": seed, "disturbances": dists,
                                 "replanning": replanning, "options": options,
                                 "results": [episode_record(ep) for ep in res.episodes]})
            print(name, dists, replanning, options, res.success_rate, res.replans, file=sys.stderr)
    FIXTURE.write_text(json.dumps(out, separators=(",", ":")) + "\n")
    print(f"wrote {FIXTURE} ({FIXTURE.stat().st_size} bytes)", file=sys.stderr)


if __name__ == "__main__":
    main()
