"""The public API: scenario -> roadmap -> solution -> results -> figure, with NumPy arrays in and out.

::

    import firmtool as ft
    sc = ft.load_scenario("point_lightdark")      # a shipped name or a path -> ft.Scenario
    rm = ft.build(sc, workers=2)                   # -> ft.Roadmap (in memory; rm.save(path) writes it)
    sol = ft.solve(rm)                             # -> ft.Solution
    res = ft.simulate(sol, episodes=200, seed=0)   # -> ft.Results
    ft.plot(sol, res, ax=ax)                       # -> matplotlib Axes

The command line is a thin layer over exactly these calls (``firmtool build/solve/execute/plot``),
so the same scenario and seeds give the same numbers either way.

Modules: :mod:`~firmtool.api.check` (check a scenario without building), :mod:`~firmtool.api.roadmap`
(load a scenario, build or open a roadmap; :meth:`Roadmap.summary`, what it holds),
:mod:`~firmtool.api.solution` (solve it), :mod:`~firmtool.api.execution` (simulate the policy).
Each input is checked once, where it enters here; the pipeline below takes typed values.
"""

from firmtool.api.check import CheckReport, check
from firmtool.api.execution import DisturbanceFunction, simulate
from firmtool.api.roadmap import Roadmap, build, load_scenario, open_roadmap
from firmtool.api.queries import solve
from firmtool.api.solution import POLICIES, Solution
from firmtool.api.updates import update
from firmtool.pipeline.query import Query

__all__ = ["CheckReport", "DisturbanceFunction", "POLICIES", "Query", "Roadmap", "Solution", "build", "check",
           "load_scenario", "open_roadmap", "simulate", "solve", "update"]
