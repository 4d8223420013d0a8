"""Robots as plugins: the :class:`Robot` interface and the registry of robots by name.

Built in: ``point`` (:mod:`firmtool.robots.point`), ``arm`` (:mod:`firmtool.robots.arm`),
``unicycle`` (:mod:`firmtool.robots.unicycle`) and ``urdf`` (:mod:`firmtool.robots.urdf_arm`, any serial arm
from its URDF file; :func:`urdf` reads one), each one module through the same interface as a
user's robot. A user registers a robot from Python with :func:`register`, or ships one in a
package through the entry-point group ``firmtool.robots``; scenario files name it in
``[model] robot``. See :mod:`firmtool.robots.base` for the interface, one small protocol per
question (:class:`RobotModel`, :class:`RobotGeometry`, :class:`TaskSpace`, :class:`NodeStabilisers`,
:class:`Nominals`, :class:`JumpAnswers`, :class:`Relocalising`, :class:`Drawable`), and
:mod:`firmtool.robots.registry` for the registry.
"""

from firmtool.robots.base import Robot
from firmtool.robots.compiled import CompiledKinematics
from firmtool.robots.drawing import Drawable
from firmtool.robots.geometry import RobotGeometry
from firmtool.robots.jumps import JumpAnswers
from firmtool.robots.linear import LinearRobot
from firmtool.robots.model import RobotModel
from firmtool.robots.nominals import Nominals
from firmtool.robots.registry import ENTRY_POINT_GROUP, get, names, register
from firmtool.robots.relocalisation import Relocalising
from firmtool.robots.stabilisers import NodeStabilisers
from firmtool.robots.task import TaskSpace
from firmtool.robots.urdf_arm import urdf  # a URDF's chain, read and checked as robot = "urdf" reads it
from firmtool.util.schema import Field  # a robot declares its [model] keys with it

__all__ = ["ENTRY_POINT_GROUP", "CompiledKinematics", "Drawable", "Field", "JumpAnswers", "LinearRobot",
           "NodeStabilisers", "Nominals", "Relocalising", "Robot", "RobotGeometry", "RobotModel", "TaskSpace", "get",
           "names", "register", "urdf"]
