"""``firmtool solve``: the constrained graph DP on a roadmap file, and its summary."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np
import typer

from firmtool.cli import console
from firmtool.cli.console import items, num, prob
from firmtool.cli.exits import handles_errors
from firmtool.cli.options import JsonOpt, QuietOpt, check_roadmap_argument, open_roadmap
from firmtool.cli.output import emit
from firmtool.errors import InputError
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
    if r["unreachable_nodes"]:
        lines.append(f"{len(r['unreachable_nodes'])} nodes cannot reach the goal: {items(r['unreachable_nodes'])}")
    return "\n".join(lines)


@handles_errors
def solve(roadmap: Path = typer.Argument(..., help="Roadmap file with estimated edges."),
          failure_cost: Optional[float] = typer.Option(None, "--failure-cost", help="Override the scenario's J_F."),
          method: str = typer.Option("value", "--method", help="'value' (value iteration) or 'policy'."),
          as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Solve the constrained graph DP (eq. 12) and the success probability of every node.

    Example: firmtool solve artifacts/smoke.h5 --failure-cost 500
    """
    # lazy: saves firmtool --help the library's import, 2.0 s (firmtool.cli.app)
    import firmtool.api as ft
    check_roadmap_argument(roadmap)
    if method not in ("value", "policy"):
        raise InputError(f"--method: expected 'value' or 'policy', found {method!r}")
    if failure_cost is not None and not (np.isfinite(failure_cost) and failure_cost > 0):
        raise InputError(f"--failure-cost: expected a finite number > 0, found {failure_cost}")
    # from the first read to the write: the policy is the edges' it was solved from (issue 35); it is
    # written also when the goal is unreachable (inspect shows it), then the run fails
    with writer_lock(roadmap):
        sol = ft.solve(open_roadmap(roadmap), failure_cost=failure_cost, method=method, progress=console.progress(),
                       allow_unreachable=True)
        sol.save()
    if not sol.start_reachable:
        raise sol.unreachable_error()
    emit(sol.to_dict(), as_json, solve_human)
    console.next_step(f"the policy into {roadmap}", f"firmtool execute {roadmap}")

