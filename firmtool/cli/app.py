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
writes, threadpoolctl) at their top, and the library (:mod:`firmtool.api`, the pipeline, the
engines, matplotlib, h5py) only inside the command that needs it. Measured (issue 34) on this
machine kind (2 cores, load ~1.5), min of 5 runs each: the house before the split, as it is
("lazy"), and with every import inside a command moved to its module's top ("eager")::

                                               house     lazy     eager
    firmtool --help                            0.40 s    0.40 s   3.42 s
    firmtool --version                         0.25 s    0.27 s   3.04 s
    a usage error (firmtool nosuch)            0.39 s    0.61 s   3.16 s
    firmtool scenarios                         2.01 s    2.09 s   2.86 s
    firmtool check scenarios/smoke.toml        2.35 s    2.28 s   3.98 s
    import firmtool.cli (python -X importtime) 0.17 s    0.24 s   2.89 s

(15 more runs of the first three, house against lazy: 0.46 / 0.47 s, 0.28 / 0.30 s, 0.41 / 0.44 s.)
What each lazy import saves ``firmtool --help`` (its import after ``import firmtool.cli``, min of
7): firmtool.api 2.0 s, the pipeline 1.6 s, the figures with matplotlib 1.9 s, firmtool.api.check
(the API's import) 2.0 s, the budgets 1.3 s, the replanning settings 1.35 s, the
disturbances 1.45 s, the scenario package 0.5 s, its docs 0.7 s, the robots 0.6 s, the engine's
warm-up 1.3 s, scipy.linalg 0.22 s, h5py with the roadmap file's module 0.05 s and the episode
files' 0.03 s, rich's progress bars 0.035 s: each 7% or more of ``--help``. At the top, costing a
few milliseconds each: io.atomic (0.01 s), threadpoolctl (0.004 s). On a loaded machine (load
~5.5) every number above is 2.5-3 times larger (``--help`` 1.7 s lazy, 11.5 s eager).
"""

from __future__ import annotations

import sys

import typer

from firmtool import __version__
from firmtool.cli import execute, ros, run, scenarios, show, solve, stages
from firmtool.cli.exits import OneLineErrors
from firmtool.util import interrupts

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
            stages.update, solve.solve, execute.execute, show.plot, show.inspect, run.run, scenarios.scenarios,
            ros.ros, ros.ros_sim)
for _command in COMMANDS:
    # the ROS commands pass the arguments after their own to ROS (--ros-args ...)
    app.command(**(ros.COMMAND_SETTINGS if _command in (ros.ros, ros.ros_sim) else {}))(_command)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"firmtool {__version__}")
        raise typer.Exit()


@app.callback()
def _options(version: bool = typer.Option(False, "--version", metavar="", callback=_print_version, is_eager=True,
                                          help="Print firmtool's version and exit.")) -> None:
    """Options of every command (the help text is the app's)."""


def main() -> None:
    """Run the CLI on ``sys.argv`` and exit with its code (the console script, firmtool.__main__, installs
    the Ctrl-C handler before this module's imports)."""
    interrupts.install()
    sys.exit(app(standalone_mode=False))
