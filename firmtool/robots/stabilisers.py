"""A robot's node stabilisers: how a node holds the robot, and the belief at a start that is no node.

:class:`NodeStabilisers` is what the design stage (:mod:`firmtool.roadmap.design`), the roadmap's
loader and execution ask of a robot, declared once with the defaults
:class:`firmtool.robots.Robot` inherits: stationary SLQR / SLQG of the linear model
(:func:`firmtool.control.stabilisers.design_node`) with the stored arrays as they are, and a start
belief from the stationary Kalman filter at the start. A robot that cannot be held still designs
periodic ones instead (the unicycle: :mod:`firmtool.control.stabilisers`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from firmtool.control.gains import lqr_gain, stationary_kalman
from firmtool.control.stabilisers import design_node

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.control.stabilisers import NodeController
    from firmtool.problem import Problem


class NodeStabilisers:
    """A robot's node stabilisers.

    Declared once: its methods are the protocol and hold the defaults :class:`firmtool.robots.Robot`
    inherits (see the module docs); a robot overrides what differs."""

    def design_node(self, problem: "Problem", center: np.ndarray, Wx: np.ndarray, Wu: np.ndarray,
                    memo: dict) -> "NodeController":
        """The stabiliser of a node at ``center`` (design stage). Default: stationary SLQR / SLQG of
        the linear model, R at the centre, one LQR gain for all nodes (kept in ``memo``, a dict
        shared by the nodes of one design)."""
        model = problem.model
        if "lqr" not in memo:
            memo["lqr"] = lqr_gain(model.A, model.B, Wx, Wu)
        return design_node(model, center, Wx, Wu, problem.perfect, lqr=memo["lqr"])

    def node_controller(self, problem: "Problem", center: np.ndarray, stored: "NodeController") -> "NodeController":
        """A node's stabiliser with everything local controllers need, from what the roadmap stores
        (``stored``: the design's arrays of the node). Default: ``stored`` as it is."""
        return stored

    def start_covariance(self, problem: "Problem", state: np.ndarray) -> np.ndarray:
        """The belief covariance (n, n) at a start state that is no node (imperfect measurements).
        Default: the stationary Kalman filter of the model linearised at the state, at rest."""
        model = problem.model
        A, _ = model.dynamics_jacobians(state, np.zeros(model.m))
        H = model.observation_jacobian(state)
        _, P0, _ = stationary_kalman(A, model.process_cov, H, model.R(state[None]))
        return P0
