"""The options several commands share (one definition, one help text each), and the checks of
arguments that name files."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from firmtool.errors import InputError
from firmtool.io.file_kind import file_kind

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.api import Roadmap

DEFAULT_SCENARIO = "arm8_lightdark"  # a shipped scenario's name (firmtool scenarios)
SCENARIO_HELP = "Scenario: a TOML file, or the name of a shipped scenario (see 'firmtool scenarios')."

JsonOpt = typer.Option(False, "--json", metavar="", help="Print machine-readable results on stdout.")
WorkersOpt = typer.Option(None, "--workers", "-w", min=1,
                          help="Worker processes (default: all cores; at most 2 per core, and as many as memory "
                               "allows).")
ForceOpt = typer.Option(False, "--force", metavar="",
                        help="Replace an existing output file even if it is not a firmtool file of the same kind (a "
                             "roadmap: of the same scenario).")
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
QuietOpt = typer.Option(False, "--quiet", "-q", metavar="",
                        help="Print only errors, notices and --json output: no progress bar, no summary, no next step.")


def check_exists(path: Path, what: str) -> None:
    if not path.exists():
        raise InputError(f"{path}: no such {what}")


def check_roadmap_argument(path: Path) -> None:
    """A roadmap argument that exists; a scenario file given where a roadmap is expected is told
    which command makes its roadmap (rather than HDF5's "file signature not found")."""
    check_exists(path, "roadmap file")
    if file_kind(path) == "scenario":
        raise InputError(f"{path}: a scenario file, not a roadmap; build its roadmap first: firmtool build {path}")


def check_scenario_argument(scenario: str) -> None:
    """A roadmap given where a scenario is expected is told what it is and what takes it."""
    if file_kind(scenario) == "roadmap":
        raise InputError(f"{scenario}: an HDF5 file (a roadmap?), not a scenario; a roadmap is what solve, execute, "
                         f"plot and inspect take: firmtool inspect {scenario}")


def open_roadmap(path: Path) -> "Roadmap":
    """:func:`firmtool.open_roadmap` for a command. A command cannot pass a Python validity checker, so
    the warning meant for a script (a roadmap built with one was opened without it) is not printed:
    a stage that needs the checker refuses in one line instead (:func:`firmtool.pipeline.problem_of`),
    and the DP, which needs no geometry, runs. A scenario file edited since the build is one
    ``warning:`` line on stderr (:class:`firmtool.StaleScenarioWarning`)."""
    import firmtool.api as ft  # lazy: saves firmtool --help the library's import, 2.0 s (firmtool.cli.app)

    from firmtool.errors import StaleScenarioWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", StaleScenarioWarning)
        warnings.filterwarnings("ignore", message=".*built with a Python validity checker", category=UserWarning)
        roadmap = ft.open_roadmap(path)
    for w in caught:  # one line each on stderr, before the command's own output
        if issubclass(w.category, StaleScenarioWarning):
            typer.echo(f"warning: {w.message}", err=True)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return roadmap
