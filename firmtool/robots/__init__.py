"""Robots as plugins: the :class:`Robot` interface and the registry of robots by name.

Built in: ``point`` (:mod:`firmtool.robots.point`), ``arm`` (:mod:`firmtool.robots.arm`) and
``unicycle`` (:mod:`firmtool.robots.unicycle`), each one module through the same interface as a
user's robot. A user registers a robot from Python with :func:`register`, or ships one in a
package through the entry-point group ``firmtool.robots``; scenario files name it in
``[model] robot``. See :mod:`firmtool.robots.base`.
"""

from firmtool.io.schema import Field  # a robot declares its [model] keys with it
from firmtool.robots.base import ENTRY_POINT_GROUP, Robot, get, names, register
from firmtool.robots.compiled import CompiledKinematics
from firmtool.robots.linear import LinearRobot

__all__ = ["ENTRY_POINT_GROUP", "CompiledKinematics", "Field", "LinearRobot", "Robot", "get", "names", "register"]
