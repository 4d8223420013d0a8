"""The options several commands share (one definition, one help text each), and the checks of
arguments that name files."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from firmtool.errors import InputError

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.api import Roadmap

DEFAULT_SCENARIO = "arm8_lightdark"  # a shipped scenario's name (firmtool scenarios)
SCENARIO_HELP = "Scenario: a TOML file, or the name of a shipped scenario (see 'firmtool scenarios')."

JsonOpt = typer.Option(False, "--json", help="Print machine-readable results on stdout.")
WorkersOpt = typer.Option(None, "--workers", "-w", min=1,
                          help="Worker processes (default: all cores; at most 2 per core, and as many as memory "
                               "allows).")
ForceOpt = typer.Option(False, "--force", help="Replace an existing output file even if it is not a firmtool file "
                                               "of the same kind (a roadmap: of the same scenario).")
MaxStepsOpt = typer.Option(1e8, "--max-total-steps", min=1.0,
                           help="Refuse runs of more than this many control steps in the worst case "
                                "(episodes x the scenario's execution.max_steps).")
ExecutorOpt = typer.Option("process", "--executor", help="'process' (local) or 'dask' (dask.distributed).")
CheckpointOpt = typer.Option(10.0, "--checkpoint-seconds", min=0.0,
                             help="Save finished edge estimates into the roadmap this often (resume after a kill).")
SchedulerOpt = typer.Option(None, "--scheduler", help="Dask scheduler address, e.g. tcp://host:8786; "
                            "without it --executor dask starts a LocalCluster.")
QuietOpt = typer.Option(False, "--quiet", "-q", help="Print only errors, notices and --json output: no progress "
                                                     "bar, no summary, no next step.")


def check_exists(path: Path, what: str) -> None:
    if not path.exists():
        raise InputError(f"{path}: no such {what}")


def open_roadmap(path: Path) -> "Roadmap":
    """:func:`firmtool.open_roadmap` for a command. A command cannot pass a Python validity checker, so
    the warning meant for a script (a roadmap built with one was opened without it) is not printed:
    a stage that needs the checker refuses in one line instead (:func:`firmtool.pipeline.problem_of`),
    and the DP, which needs no geometry, runs."""
    import firmtool.api as ft  # lazy: saves firmtool --help the library's import, 2.0 s (firmtool.cli.app)

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*built with a Python validity checker", category=UserWarning)
        return ft.open_roadmap(path)
