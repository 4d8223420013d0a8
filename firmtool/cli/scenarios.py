"""Scenario commands: ``firmtool init`` (a commented scenario to start from), ``firmtool check``
(validate one without building) and ``firmtool scenarios`` (the shipped ones)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from firmtool.cli import console
from firmtool.cli.console import num
from firmtool.cli.exits import handles_errors
from firmtool.cli.options import SCENARIO_HELP, JsonOpt, QuietOpt, check_scenario_argument
from firmtool.cli.output import emit, print_notices


@handles_errors
def init(name: str = typer.Argument(..., help="The scenario's name: writes NAME.toml (letters, digits, '-', "
                                              "'_', '.')."),
         robot: Optional[str] = typer.Option(None, "--robot", "-r",
                                             help="The robot (default point): a built-in one (point, arm, unicycle), "
                                                  "or a registered robot that has a template."),
         output: Optional[Path] = typer.Option(None, "--output", "-o", help="Scenario file (default NAME.toml)."),
         force: bool = typer.Option(False, "--force", metavar="", help="Replace an existing file."),
         quiet: bool = QuietOpt) -> None:
    """Write a commented scenario for a built-in robot that builds as it is: every key listed with
    what it is (from the scenario schema), the keys at their defaults commented out.

    Example: firmtool init my_room --robot point
    """
    # lazy: saves firmtool --help the robots' and the scenario docs' import, 0.7 s (firmtool.cli.app)
    from firmtool.robots.registry import DEFAULT_ROBOT
    from firmtool.scenario.docs import write_template
    out = write_template(output or Path(f"{name}.toml"), name, robot or DEFAULT_ROBOT, force=force)
    console.next_step(str(out), f"firmtool check {out}")


def _check_human(r: dict) -> str:
    world = f"{r['world_dim']}-D world, " + (f"map {r['map']}, " if r.get("map") else "") + \
        f"{r['obstacles']} obstacle{'s' if r['obstacles'] != 1 else ''} ({r['collision_backend']})"
    sensing = "perfect measurements" if r["measurement"] == "perfect" else \
        f"{r['measurements']} imperfect measurements ({r['noise']} noise)"
    return (f"ok: {r['scenario']}: scenario {r['name']!r}: robot {r['robot']} ({r['states']} states, "
            f"{r['inputs']} inputs), {sensing}, {world}, goal {r['goal']}; {r['nodes']} nodes x "
            f"{r['particles']} particles per edge, at most ~{num(r['max_particle_steps'], 2)} particle-steps")


@handles_errors
def check(scenario: str = typer.Argument(..., help=SCENARIO_HELP),
          as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Validate a scenario without building: every mistake of the file at once (one line each), then
    the problem it describes (start and goal valid, the model stabilisable, the work within budget).

    Example: firmtool check my_room.toml
    """
    from firmtool.api.check import check as check_scenario  # lazy: saves firmtool --help 2 s (firmtool.cli.app)
    check_scenario_argument(scenario)
    report = check_scenario(scenario).to_dict()
    emit(report, as_json, _check_human)
    print_notices(report)
    console.next_step(None, f"firmtool build {scenario}")


@handles_errors
def scenarios(as_json: bool = JsonOpt) -> None:
    """List the shipped scenarios, one a line: name and description. Every command that takes a
    scenario accepts one of these names as well as a TOML file (an existing file wins).

    Example: firmtool build point_lightdark
    """
    # lazy: saves firmtool --help the scenario package's import, 0.5 s (firmtool.cli.app)
    from firmtool.scenario import scenario_description, shipped_scenarios
    shipped = [{"name": name, "description": scenario_description(path), "path": str(path)}
               for name, path in shipped_scenarios().items()]
    width = max((len(s["name"]) for s in shipped), default=0)
    emit({"scenarios": shipped}, as_json,
         lambda r: "\n".join(f"{s['name']:<{width}}  {s['description']}" for s in r["scenarios"]), roadmap=False)

