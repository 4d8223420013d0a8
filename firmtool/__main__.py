"""The ``firmtool`` console script and ``python -m firmtool``.

The Ctrl-C handler is installed when this module is imported, the earliest moment firmtool's own
code runs (before numpy, scipy and typer are imported); see :mod:`firmtool.util.interrupts`. The
interpreter's own start-up before it (a few tens of milliseconds) is outside firmtool's reach.
"""

from firmtool.util import interrupts

interrupts.install()


def main() -> None:
    """Run the command line (imported only now, after the handler is in place)."""
    # lazy, on purpose: the CLI's imports take 0.25 s (firmtool.cli.app), and a Ctrl-C during them
    # ends in the handler's one line, not a traceback
    from firmtool.cli import main as cli_main

    cli_main()


if __name__ == "__main__":
    main()
