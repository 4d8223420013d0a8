"""How a robot looks in a 2-D figure (a 3-D robot is drawn from above).

:class:`Drawable` is what the figures (:mod:`firmtool.figures`) ask of a robot, declared once with the
defaults :class:`firmtool.robots.Robot` inherits: no heading, a disc for one key point
and a polyline through several.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.scenario import Scenario


class Drawable:
    """How a robot is drawn.

    Declared once: its methods are the protocol and hold the defaults :class:`firmtool.robots.Robot`
    inherits (see the module docs); a robot overrides what differs."""

    scenario: "Scenario"

    def heading(self, X: np.ndarray) -> np.ndarray | None:
        """The robot's heading in the workspace's x-y plane (radians) at states (M, n) -> (M,), for
        figures; None (the default) for a robot without one."""
        return None

    def draw(self, ax: Any, state: np.ndarray, *, color: str, label: str, lw: float = 2.0) -> None:
        """Draw the robot at ``state`` (n,) on a matplotlib Axes in the workspace's x-y plane (a 3-D
        robot seen from above): a disc for one key point (with an arrow along its :meth:`heading`,
        if it has one), a polyline through several."""
        # a measured lazy load: matplotlib.patches adds 0.5-0.7 s to importing firmtool.robots
        # (python -X importtime, 2 cores), which every stage and worker pays and only figures need
        from matplotlib.patches import Circle, FancyArrow

        X = np.asarray(state, dtype=float)[None]
        pts = self.points(X)[0][:, :2]
        if pts.shape[0] == 1:
            r = self.scenario.world.robot_radius
            ax.add_patch(Circle(pts[0], r, color=color, zorder=6, label=label))
            heading = self.heading(X)
            if heading is not None:
                length = 3.0 * r
                ax.add_patch(FancyArrow(pts[0, 0], pts[0, 1], length * np.cos(heading[0]),
                                        length * np.sin(heading[0]), width=0.35 * r, head_width=1.1 * r,
                                        head_length=0.9 * r, length_includes_head=True, color=color, zorder=7))
        else:
            ax.plot(pts[:, 0], pts[:, 1], "-o", color=color, lw=lw, ms=3, zorder=6, label=label)

    def sensing_field(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """What a figure shades as the sensing field: the sensing coordinate at points ``xy`` (N, 2)
        of the workspace's x-y plane (N,), and where to mark the light (2,); None (the default) when
        the coordinate is the workspace's x, which the figure shades with the light's line at
        ``light_x``."""
        return None
