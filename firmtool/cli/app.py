"""The ``firmtool`` command line: the typer app, its commands in the order ``--help`` lists them, and
:func:`main`, the console script's entry (through :mod:`firmtool.__main__`).

Each command is a thin function of its group's module (it parses, calls the library, prints, exits):
:mod:`~firmtool.cli.scenarios` (init, check, scenarios), :mod:`~firmtool.cli.stages` (sample, design,
estimate, build), :mod:`~firmtool.cli.solve`, :mod:`~firmtool.cli.execute`, :mod:`~firmtool.cli.show`
(plot, inspect) and :mod:`~firmtool.cli.run`; errors become one line and an exit code in
:mod:`~firmtool.cli.exits`, results are printed by :mod:`~firmtool.cli.output` and
:mod:`~firmtool.cli.console`.

Start-up time: what the imports inside the commands save
--------------------------------------------------------
The command modules import typer, numpy and firmtool's light modules (errors, the console, atomic
writes) at their top, and the library (:mod:`firmtool.api`, the pipeline, the engines, matplotlib,
h5py) only inside the command that needs it. Measured (issue 34) on this machine kind, 2 cores
shared with other work (load ~5.5: times are ~2.5x a quiet machine's), min of 5 runs each: the
house before the split, as it is ("lazy"), and with every import inside a command moved to its
module's top ("eager")::

                                              house      lazy      eager
    firmtool --help                           1.64 s     1.67 s    11.5 s
    firmtool --version                        0.83 s     1.02 s    10.1 s
    a usage error (firmtool nosuch)           1.67 s     1.57 s     9.9 s
    firmtool scenarios                        8.6 s      5.9 s     10.3 s
    firmtool check scenarios/smoke.toml       7.1 s      7.4 s     10.5 s
    import firmtool.cli (python -X importtime)  0.58 s   0.46 s     8.2 s

What each lazy import saves ``firmtool --help`` (its import after ``import firmtool.cli``, same
load, min of 7): firmtool.api 4.8 s, the pipeline 5.4 s, the figures (matplotlib) 7.3 s,
firmtool.cli.check 6.2 s, firmtool.cli.inspect 5.1 s, the budgets 4.6 s, the replanning settings
5.1 s, the disturbances 5.6 s, the scenario package 1.8 s, its docs 2.0 s, the robots 1.8 s, the
problem 4.9 s, the engine's warm-up 4.3 s, scipy.linalg 0.6 s, rich's progress bars 0.1 s; h5py
(the roadmap and episode files) 0.2-0.3 s of the 0.8-1.2 s import of firmtool.cli (``--help`` 1.2 s
without it, 1.7 s with it, min of 12). The imports kept at the top cost less: io.atomic 0.01 s,
threadpoolctl 0.004 s.
"""

from __future__ import annotations

import sys

import typer

from firmtool import __version__
from firmtool.cli import execute, run, scenarios, show, solve, stages
from firmtool.cli.exits import OneLineErrors
from firmtool.io import interrupts

app = typer.Typer(cls=OneLineErrors,
    name="firmtool",
    help=("FIRM: graph-based stochastic control with constraints, in state space (perfect measurements) "
          "and belief space (imperfect measurements).\n\n"
          "Typical use:\n\n"
          "  firmtool scenarios\n\n"
          "  firmtool build point_lightdark\n\n"
          "  firmtool solve artifacts/point_lightdark.h5\n\n"
          "  firmtool execute artifacts/point_lightdark.h5 --episodes 200 --json"),
    no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
)

# in the order firmtool --help lists them
COMMANDS = (scenarios.init, scenarios.check, stages.sample, stages.design, stages.estimate, stages.build,
            solve.solve, execute.execute, show.plot, show.inspect, run.run, scenarios.scenarios)
for _command in COMMANDS:
    app.command()(_command)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"firmtool {__version__}")
        raise typer.Exit()


@app.callback()
def _options(version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True,
                                          help="Print firmtool's version and exit.")) -> None:
    """Options of every command (the help text is the app's)."""


def main() -> None:
    """Run the CLI on ``sys.argv`` and exit with its code (the console script, firmtool.__main__, installs
    the Ctrl-C handler before this module's imports)."""
    interrupts.install()
    sys.exit(app(standalone_mode=False))
