"""The command line: a thin layer over firmtool.api (:mod:`firmtool.cli.app` has the map of its modules).

``app`` is the typer application and ``main`` the console script's entry (:mod:`firmtool.__main__`).
"""

from firmtool.cli.app import app, main

__all__ = ["app", "main"]
