"""What happened in one run of the online policy: its events, nodes, edges, replans and traversals.

The traversals are what the calibration check compares with the edge Monte Carlo
(:func:`firmtool.estimation.calibration.edge_calibration`): a policy edge counts only while it runs
as its Monte Carlo ran it, from its node and with the filter never reset (no correction, no
re-localisation); the run "spoils" a traversal as soon as the belief is replaced.
"""

from __future__ import annotations

from firmtool.online.running import RunningController
from firmtool.results import Event


class Traversal(tuple):
    """``(edge, outcome, first_step, last_step)`` of a policy edge run from its node to its end without
    a belief reset; outcome a node id or ``firmtool.estimation.edges.TIMEOUT`` (a simulation adds the collisions,
    ``FAILURE``, and drops the traversals a disturbance hit: :mod:`firmtool.sim.episodes`)."""

    __slots__ = ()


class RunRecord:
    """The history of one run (from one :meth:`~firmtool.online.Policy.reset`).

    Attributes
    ----------
    events : list of Event, every event in order.
    nodes : the nodes the belief entered, in order; edges : the policy edges taken, in order.
    traversals : list of :class:`Traversal`.
    replans, replan_failures : decisions that took a new controller, and that found none.
    rollouts : rollout decisions that took a new controller (rollout FIRM).
    clean : the running controller is a policy edge run from its node, so far undisturbed.
    run_start : the step at which the running controller began.
    """

    def __init__(self) -> None:
        self.events: list[Event] = []
        self.nodes: list[int] = []
        self.edges: list[int] = []
        self.traversals: list[Traversal] = []
        self.replans = self.replan_failures = self.rollouts = 0
        self.clean, self.run_start = False, 0

    def emit(self, out: list[Event], event: Event) -> None:
        """Add ``event`` to this step's events ``out`` and to the run's."""
        out.append(event)
        self.events.append(event)

    def began(self, run: RunningController, step: int) -> None:
        """A controller began at ``step``: a traversal if it is a policy edge (from its node)."""
        self.clean = run.edge >= 0
        self.run_start = step

    def spoil(self) -> None:
        """The filter was reset: the running edge is no longer the edge the Monte Carlo ran."""
        self.clean = False

    def traversed(self, edge: int, outcome: int, step: int) -> None:
        """The running edge ended at ``step`` with ``outcome``: a traversal if it ran clean."""
        if self.clean:
            self.traversals.append(Traversal((edge, outcome, self.run_start, step)))

    def running(self, run: RunningController | None) -> tuple[int, int] | None:
        """``(edge, first_step)`` of ``run`` if it still counts as a clean traversal, else None."""
        if run is None or not self.clean:
            return None
        return run.edge, self.run_start
