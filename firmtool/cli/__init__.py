"""The command line: a thin layer over firmtool.api."""
