"""Packaging beyond pyproject.toml: the top-level ``scenarios/`` folder is installed as the package
``firmtool.scenarios`` (its TOML files as package data), so that ``firmtool run`` finds the shipped
scenarios from any folder. pyproject.toml cannot add a package from outside ``firmtool/`` to the
automatically found ones; listing every package by hand there would silently drop a new subpackage."""

from setuptools import find_packages, setup

setup(packages=find_packages(include=["firmtool", "firmtool.*"]) + ["firmtool.scenarios"],
      package_dir={"firmtool.scenarios": "scenarios"},
      package_data={"firmtool.scenarios": ["*.toml", "robots/*.urdf", "*.yaml", "*.pgm", "*.png"]})
