"""``firmtool solve``: the constrained graph DP on a roadmap file, and its summary."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Optional

import numpy as np
import typer

from firmtool.cli import console
from firmtool.cli.console import items, num, prob
from firmtool.cli.exits import handles_errors
from firmtool.cli.options import JsonOpt, QuietOpt, check_roadmap_argument, open_roadmap
from firmtool.cli.output import emit
from firmtool.cli.queries import queries_of, query_human
from firmtool.errors import InputError, quoted
from firmtool.io.locking import writer_lock


def solve_human(r: dict) -> str:
    lines = [f"solve: {r['status'].lower()} after {r['iterations']} {r['method']} iterations "
             f"(residual {num(r['residual'], 2)}), failure cost {num(r['failure_cost'])}",
             f"start: success probability {prob(r['start_success_probability'])}"
             + (f" (95% interval from the edge counts {prob(r['start_success_probability_ci95'][0])}-"
                f"{prob(r['start_success_probability_ci95'][1])})" if r.get("start_success_probability_ci95") else "")
             + ", cost-to-go "
             f"{num(r['start_cost_to_go'])} (shortest path: success probability "
             f"{prob(r['shortest_path_start_success_probability'])})",
             f"policy path: {' -> '.join(map(str, r['path']))}"]
    if r.get("path_task_points"):
        lines.append("  in the task space: " + " -> ".join("(" + ", ".join(f"{v:.2f}" for v in q) + ")"
                                                          for q in r["path_task_points"]))
    if r.get("deadline_steps") is not None:
        lines.append(f"within the deadline of {r['deadline_steps']} steps: success probability "
                     f"{prob(r['deadline_success_probability'])} (the time-indexed policy; without a deadline "
                     f"{prob(r['start_success_probability'])})")
    if r["unreachable_nodes"]:
        lines.append(f"{len(r['unreachable_nodes'])} nodes cannot reach the goal: {items(r['unreachable_nodes'])}")
    return "\n".join(lines)


@handles_errors
def solve(roadmap: Path = typer.Argument(..., help="Roadmap file with estimated edges."),
          failure_cost: Optional[float] = typer.Option(None, "--failure-cost", help="Override the scenario's J_F."),
          method: str = typer.Option("value", "--method", help="'value' (value iteration) or 'policy'."),
          goal: Optional[list[str]] = typer.Option(None, "--goal", help="A new query's goal X,Y[,..] (a state, or "
                                                   "with a goal ball its centre); repeat for several queries."),
          goal_radius: Optional[float] = typer.Option(None, "--goal-radius", help="The queries' goal ball radius."),
          goal_confidence: Optional[float] = typer.Option(None, "--goal-confidence",
                                                          help="The queries' goal confidence."),
          start: Optional[str] = typer.Option(None, "--start", help="The queries' start X,Y[,..]."),
          start_covariance: Optional[str] = typer.Option(None, "--start-covariance",
                                                         help="The queries' start covariance (its diagonal)."),
          task: Optional[Path] = typer.Option(None, "--task", help="A TOML file with the queries' task fields "
                                              "(a task table, or its keys at the top)."),
          name: Optional[list[str]] = typer.Option(None, "--name", help="Store each query under this name "
                                                   "(one per --goal; default: q- and its task's hash)."),
          force: bool = typer.Option(False, "--force", metavar="", help="Replace a stored query of the same name."),
          workers: Optional[int] = typer.Option(None, "--workers", "-w", min=1,
                                                help="Worker processes for a query's Monte Carlo (default 1)."),
          deadline: Optional[int] = typer.Option(None, "--deadline", min=1,
                                                 help="Reach the goal within this many steps (default: the "
                                                      "scenario's task.deadline_steps): the policy over node and "
                                                      "steps left, which execute follows and ends at."),
          as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Solve the constrained graph DP (eq. 12) and the success probability of every node; or, with
    --goal / --start / --task, answer new queries on the built roadmap (its nodes, stabilisers and
    estimated edges reused; only the query's goal nodes, their edges and the DP computed) and store
    them in the roadmap by name, for 'firmtool execute/plot ROADMAP --query NAME'.

    Examples:

      firmtool solve artifacts/smoke.h5 --failure-cost 500

      firmtool solve artifacts/point_lightdark.h5 --goal 8.5,5.0 --name east

      firmtool solve artifacts/arm8_lightdark.h5 --goal 0.47,1.01 --goal 0.6,-1.0 --name up --name down
    """
    # lazy: saves firmtool --help the library's import, 2.0 s (firmtool.cli.app)
    import firmtool.api as ft
    check_roadmap_argument(roadmap)
    if method not in ("value", "policy"):
        raise InputError(f"--method: expected 'value' or 'policy', found {quoted(method)}")
    if failure_cost is not None and not (np.isfinite(failure_cost) and failure_cost > 0):
        raise InputError(f"--failure-cost: expected a finite number > 0, found {failure_cost}")
    if goal or task is not None or start is not None:
        queries = queries_of(goal or [], name or [], goal_radius, goal_confidence, start, start_covariance, task)
        if deadline is not None:  # --deadline over a --task file's deadline_steps
            queries = [dataclasses.replace(q, deadline=deadline) for q in queries]
        return _queries(roadmap, queries, failure_cost, method, force, workers, as_json)
    if name or force or goal_radius is not None or goal_confidence is not None or start_covariance is not None:
        raise InputError("--name, --force, --goal-radius, --goal-confidence, --start-covariance: only with a query "
                         "(--goal, --start or --task)")
    # from the first read to the write: the policy is the edges' it was solved from (issue 35); it is
    # written also when the goal is unreachable (inspect shows it), then the run fails
    with writer_lock(roadmap):
        rm = open_roadmap(roadmap)
        if deadline is not None:  # its budget on this roadmap, before the DP allocates anything
            rm.deadline_budget().check(deadline, "--deadline", str(roadmap))
        sol = ft.solve(rm, failure_cost=failure_cost, method=method, progress=console.progress(),
                       allow_unreachable=True, deadline=deadline)
        sol.save()
    if not sol.start_reachable:
        raise sol.unreachable_error()
    emit(sol.to_dict(), as_json, solve_human)
    console.next_step(f"the policy into {roadmap}", f"firmtool execute {roadmap}")


def _queries(roadmap: Path, queries: list, failure_cost: float | None, method: str, force: bool,
             workers: int | None, as_json: bool) -> None:
    """Answer ``queries`` on ``roadmap``, store them (all or none), print them; exit 1 if a query's
    goal cannot be reached from its start (the answers are stored all the same, as build does)."""
    import firmtool.api as ft  # lazy, as in solve
    if failure_cost is not None or method != "value":
        raise InputError("--failure-cost, --method: a query is solved with the scenario's J_F by value iteration")
    rm = open_roadmap(roadmap)
    stored = set(rm.queries)
    for q in queries:  # before any Monte Carlo runs: a name that exists without --force
        if q.name is not None and q.name in stored and not force:
            raise InputError(f"{roadmap}: --name: a query named {quoted(q.name)} is stored already; give --force to "
                             "replace it, or another name")
    sols = ft.solve(rm, queries=queries, workers=workers, progress=console.progress(), allow_unreachable=True)
    names = rm.save_queries(sols, force=force)
    out = [{"query": s.roadmap.report.to_dict(), "solve": s.to_dict()} for s in sols]
    emit({"roadmap": str(roadmap), "queries": out}, as_json,
         lambda r: "\n".join(query_human(q["query"]) + "\n" + solve_human(q["solve"]) for q in r["queries"]))
    for s in sols:
        if not s.start_reachable:
            raise s.unreachable_error(f"{roadmap}#{s.roadmap.report.name}")  # what is missing, named by the query
    console.next_step(f"queries {', '.join(names)} into {roadmap}",
                      f"firmtool execute {roadmap} --query {names[0]}")
