"""``firmtool run``: build, solve and execute a scenario in one go, with the calls and the output of
the three commands one by one."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from firmtool.cli import console
from firmtool.cli.execute import execute_human
from firmtool.cli.exits import handles_errors
from firmtool.cli.options import (
    DEFAULT_SCENARIO,
    SCENARIO_HELP,
    ForceOpt,
    JsonOpt,
    MaxStepsOpt,
    QuietOpt,
    WorkersOpt,
    check_scenario_argument,
)
from firmtool.cli.output import emit, print_notices
from firmtool.cli.solve import solve_human
from firmtool.cli.stages import build_human, exit_on_failed_edges


@handles_errors
def run(scenario: str = typer.Argument(DEFAULT_SCENARIO, help=SCENARIO_HELP),
        output: Optional[Path] = typer.Option(None, "--output", "-o",
                                              help="Roadmap file (default: artifacts/NAME.h5)."),
        episodes: int = typer.Option(200, "--episodes", "-n", min=1, help="Episodes to execute."),
        seed: int = typer.Option(0, "--seed", min=0, help="Seed of the episodes (as in 'firmtool execute')."),
        workers: Optional[int] = WorkersOpt, force: bool = ForceOpt, max_total_steps: float = MaxStepsOpt,
        as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Build, solve and execute a scenario in one go (default: the paper's 8-link arm experiment):
    the same calls, and the same numbers, as 'firmtool build', 'solve' and 'execute' one by one.

    Example: firmtool run smoke --episodes 50
    """
    # lazy: saves firmtool --help the library's import, 2.0 s (firmtool.cli.app)
    import firmtool.api as ft
    from firmtool.estimation.budgets import check_execution
    from firmtool.pipeline import default_output
    from firmtool.problem import build_problem
    check_scenario_argument(scenario)
    sc = ft.load_scenario(scenario)
    check_execution(build_problem(sc), episodes, max_total_steps=max_total_steps)
    out = output or default_output(sc)
    bar = console.progress()
    rm = ft.build(sc, output=out, workers=workers, progress=bar, force=force)
    exit_on_failed_edges(rm.report.to_dict())
    sol = ft.solve(rm, progress=bar, allow_unreachable=True)
    sol.save()
    if not sol.start_reachable:
        raise sol.unreachable_error()
    res = ft.simulate(sol, episodes, seed, record=False, progress=bar, max_total_steps=max_total_steps)
    report = {"build": rm.report.to_dict(), "solve": sol.to_dict(), "execute": res.to_dict()}
    emit(report, as_json, lambda r: "\n".join([build_human(r["build"]), solve_human(r["solve"]),
                                                 execute_human(r["execute"])]))
    print_notices(report["build"])
    console.next_step(str(out), f"firmtool plot {out}" + (f" --seed {seed}" if seed else ""))

