"""The options several commands share (one definition, one help text each), and the checks of
arguments that name files."""

from __future__ import annotations

from pathlib import Path

import typer

from firmtool.errors import InputError

DEFAULT_SCENARIO = "arm8_lightdark"  # a shipped scenario's name (firmtool scenarios)
SCENARIO_HELP = "Scenario: a TOML file, or the name of a shipped scenario (see 'firmtool scenarios')."

JsonOpt = typer.Option(False, "--json", help="Print machine-readable results on stdout.")
WorkersOpt = typer.Option(None, "--workers", "-w", min=1,
                          help="Worker processes (default: all cores; at most 2 per core, and as many as memory "
                               "allows).")
ForceOpt = typer.Option(False, "--force", help="Replace an existing output file even if it is not a firmtool file "
                                               "of the same kind.")
MaxStepsOpt = typer.Option(1e8, "--max-total-steps", min=1.0,
                           help="Refuse runs of more than this many control steps in the worst case "
                                "(episodes x the scenario's execution.max_steps).")
ExecutorOpt = typer.Option("process", "--executor", help="'process' (local) or 'dask' (dask.distributed).")
CheckpointOpt = typer.Option(10.0, "--checkpoint-seconds", min=0.0,
                             help="Save finished edge estimates into the roadmap this often (resume after a kill).")
SchedulerOpt = typer.Option(None, "--scheduler", help="Dask scheduler address, e.g. tcp://host:8786; "
                            "without it --executor dask starts a LocalCluster.")
QueryOpt = typer.Option(None, "--query", help="A query stored in the roadmap (firmtool solve ROADMAP --goal ... "
                                                "--name NAME): run its policy instead of the roadmap's own.")
QuietOpt = typer.Option(False, "--quiet", "-q", help="Print only errors, notices and --json output: no progress "
                                                     "bar, no summary, no next step.")


def check_exists(path: Path, what: str) -> None:
    if not path.exists():
        raise InputError(f"{path}: no such {what}")
