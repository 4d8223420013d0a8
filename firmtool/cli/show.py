"""Commands that show a roadmap: ``firmtool plot`` (the paper's Fig. 1, or the calibration of the
policy edges) and ``firmtool inspect`` (what the file holds)."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Optional

import typer

from firmtool.cli import console
from firmtool.cli.exits import handles_errors
from firmtool.cli.options import (
    ForceOpt,
    JsonOpt,
    MaxStepsOpt,
    QueryOpt,
    QuietOpt,
    check_roadmap_argument,
    open_roadmap,
)
from firmtool.cli.output import emit
from firmtool.errors import InputError


@handles_errors
def plot(roadmap: Path = typer.Argument(..., help="Solved roadmap file."),
         output: Optional[Path] = typer.Option(None, "--output", "-o", help="Image file: PNG, PDF or SVG by its "
                                                                           "extension (default: a PNG next to the "
                                                                           "roadmap)."),
         policy_name: str = typer.Option("both", "--policy", help="'both' (FIRM and the shortest path side by side), "
                                         "'firm', 'shortest-path', 'rollout' (rollout FIRM), or 'firm-rollout' (FIRM "
                                         "and rollout FIRM side by side, the same episode in both)."),
         seed: int = typer.Option(0, "--seed", min=0, help="Seed of the episodes (as in 'firmtool execute')."),
         episodes: int = typer.Option(20, "--episodes", "-n", min=0,
                                      help="Episodes run per policy: the panel shows their success rate and draws "
                                           "the first successful one (0: the roadmap and the policy only)."),
         dpi: int = typer.Option(120, "--dpi", min=30, max=600, help="Resolution of a PNG (dots per inch)."),
         force: bool = ForceOpt,
         kind: str = typer.Option("paths", "--kind", help="'paths' (the paper's Fig. 1) or 'calibration' (predicted "
                                                          "vs executed probabilities of the policy edges)."),
         unit: str = typer.Option("m", "--unit", help="The length unit of the scenario's world (axis labels)."),
         max_total_steps: float = MaxStepsOpt, query: Optional[str] = QueryOpt, quiet: bool = QuietOpt) -> None:
    """Draw the paper's Fig. 1: obstacles, sensing field, goal, roadmap, policy path, and an executed
    episode's estimated mean with 3-sigma ellipses of the robot's followed point (the arm's tip); or,
    with --kind calibration, the predicted vs executed probabilities of the policy edges.

    Examples:

      firmtool plot artifacts/arm8_lightdark.h5 -o fig.png --episodes 100

      firmtool plot artifacts/point_lightdark.h5 --kind calibration -n 400 -o calibration.png
    """
    # lazy: saves firmtool --help the library's and matplotlib's import, 2 s (firmtool.cli.app)
    from firmtool.estimation.budgets import check_execution
    from firmtool.api.figures import FIGURE_KINDS, FigureOptions, figure_provenance, make_figure
    from firmtool.io.figure_file import check_output, save_figure
    check_roadmap_argument(roadmap)
    names = {"both": ["firm", "shortest-path"], "firm": ["firm"], "shortest-path": ["shortest-path"],
             "rollout": ["rollout"], "firm-rollout": ["firm", "rollout"]}
    if policy_name not in names:
        raise InputError(f"--policy: expected one of {', '.join(repr(n) for n in names)}, found {policy_name!r}")
    if kind not in FIGURE_KINDS:
        raise InputError(f"--kind: expected one of {', '.join(FIGURE_KINDS)}, found {kind!r}")
    out = check_output(output or roadmap.with_suffix(".png"), force)  # before the episodes run
    rm = open_roadmap(roadmap)
    if query is not None:
        rm = rm.query(query)
    if episodes:
        check_execution(rm.problem, episodes * len(names[policy_name]), max_total_steps=max_total_steps)
    options = FigureOptions(episodes=episodes, seed=seed, policies=tuple(names[policy_name]), dpi=dpi, unit=unit,
                            progress=console.progress(), max_total_steps=max_total_steps)
    sol = rm.solution()
    save_figure(make_figure(kind, sol, options), out, force=force, provenance=figure_provenance(sol, options))
    console.next_step(str(out))


@handles_errors
def inspect(roadmap: Path = typer.Argument(..., help="Roadmap file."), as_json: bool = JsonOpt,
            quiet: bool = QuietOpt) -> None:
    """Summarise a roadmap file: stages done, nodes, edges, particles, solve status.

    Example: firmtool inspect artifacts/smoke.h5 --json
    """
    import firmtool.api as ft  # lazy: saves firmtool --help the library's import, 2.0 s (firmtool.cli.app)
    check_roadmap_argument(roadmap)
    with warnings.catch_warnings():  # the file as it is: no advice on its scenario file or validity checker
        warnings.simplefilter("ignore")
        report = ft.open_roadmap(roadmap).summary().to_dict()
    emit(report, as_json, lambda r: "\n".join(f"{k.replace('_', ' ')}: {console.value(v, k)}" for k, v in r.items()
                                              if v is not None and v != []))
    stages = report.get("stages") or []
    stale = report.get("stale_stages") or []
    following = {"nodes": "design", "controllers": "estimate", "edges": "solve", "policy": "execute"}
    done = [s for s in stages if s not in stale]
    if done and done[-1] == "policy":  # solved: maybe executed already (run does), which the file cannot tell
        console.next_step(None, f"firmtool execute {roadmap} (episodes of the policy) or firmtool plot {roadmap}")
    elif done and done[-1] in following:
        console.next_step(None, f"firmtool {following[done[-1]]} {roadmap}")

