"""firmtool: FIRM (graph-based stochastic control with constraints) in state and belief space.

The public API, NumPy arrays in and out::

    import firmtool as ft
    sc = ft.load_scenario("point_lightdark")      # a shipped name or a path -> ft.Scenario
    rm = ft.build(sc, workers=2)                   # -> ft.Roadmap: nodes, edges, outcome counts
    sol = ft.solve(rm)                             # -> ft.Solution: policy, cost-to-go, success probability
    res = ft.simulate(sol, episodes=200, seed=0)   # -> ft.Results: success rate, episodes
    ft.plot(sol, res, ax=ax)                       # -> matplotlib Axes

    policy = ft.Policy(sol)                        # the policy as an online agent, for a robot's own loop
    policy.reset(); u = policy.act(); events = policy.observe(z)

The ``firmtool`` command line is a thin layer over these calls. Names are imported on first use,
so ``import firmtool`` stays cheap (the Monte Carlo engine and matplotlib load when needed).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.2.0"

# public name -> module that defines it
_EXPORTS = {
    "load_scenario": "firmtool.api",
    "check": "firmtool.api",
    "CheckReport": "firmtool.api",
    "build": "firmtool.api",
    "open_roadmap": "firmtool.api",
    "solve": "firmtool.api",
    "update": "firmtool.api",
    "Query": "firmtool.api",
    "QueryReport": "firmtool.reports",
    "UpdateReport": "firmtool.reports",
    "simulate": "firmtool.api",
    "plot": "firmtool.figures.paths",
    "Roadmap": "firmtool.api",
    "Solution": "firmtool.api",
    "Scenario": "firmtool.scenario",
    "Results": "firmtool.results",
    "Episode": "firmtool.results",
    "Event": "firmtool.results",
    "EventKind": "firmtool.results",
    "Outcome": "firmtool.results",
    "Calibration": "firmtool.results",
    "EdgeCheck": "firmtool.results",
    "ReplanSettings": "firmtool.online.replanning",
    "Policy": "firmtool.online.policy",
    "PolicyStatus": "firmtool.online.policy",
    "SimulatedSystem": "firmtool.sim.environment",
    "episode_seeds": "firmtool.sim.episodes",
    "UserDisturbance": "firmtool.sim.disturbances",
    "Disturbance": "firmtool.sim.disturbances",
    "SolveStatus": "firmtool.graph.dp",
    "SampleReport": "firmtool.reports",
    "DesignReport": "firmtool.reports",
    "EstimateReport": "firmtool.reports",
    "BuildReport": "firmtool.reports",
    "DensifyReport": "firmtool.reports",
    "SolveReport": "firmtool.reports",
    "FailedEdge": "firmtool.reports",
    "RoadmapSummary": "firmtool.reports",
    "FirmtoolError": "firmtool.errors",
    "InputError": "firmtool.errors",
    "ScenarioError": "firmtool.errors",
    "RoadmapError": "firmtool.errors",
    "NumericalError": "firmtool.errors",
    "RunFailure": "firmtool.errors",
    "Unreachable": "firmtool.errors",
    "StaleScenarioWarning": "firmtool.errors",
}

__all__ = sorted(_EXPORTS) + ["__version__", "robots"]

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs; at run time names load lazily
    from firmtool.api import (CheckReport, Query, Roadmap, Solution, build, check, load_scenario, open_roadmap, simulate,
                              solve, update)
    from firmtool.errors import (FirmtoolError, InputError, NumericalError, RoadmapError, RunFailure, ScenarioError,
                                 StaleScenarioWarning, Unreachable)
    from firmtool.figures.paths import plot
    from firmtool.graph.dp import SolveStatus
    from firmtool.online.policy import Policy, PolicyStatus
    from firmtool.online.replanning import ReplanSettings
    from firmtool.reports import (
        BuildReport,
        DensifyReport,
        DesignReport,
        EstimateReport,
        FailedEdge,
        QueryReport,
        RoadmapSummary,
        SampleReport,
        SolveReport,
        UpdateReport,
    )
    from firmtool.results import Calibration, EdgeCheck, Episode, Event, EventKind, Outcome, Results
    from firmtool.scenario import Scenario
    from firmtool.sim.disturbances import Disturbance, UserDisturbance
    from firmtool.sim.environment import SimulatedSystem
    from firmtool.sim.episodes import episode_seeds


# subpackages reachable as attributes (``ft.robots.register(name, cls)``), imported on first use
_SUBMODULES = ("robots",)


def __getattr__(name: str) -> Any:
    if name in _SUBMODULES:
        return importlib.import_module(f"firmtool.{name}")
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'firmtool' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # once loaded, a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted(set(__all__) | {name for name in globals() if name.startswith("__")})
