"""What a change touches: the one answer to "which nodes, edges and stored particle blocks does this
change reach?" that a query (:mod:`firmtool.pipeline.query`), a world update
(:mod:`firmtool.pipeline.update`) and an online world change (:mod:`firmtool.online.world`) all ask.

An edge's Monte Carlo reads the rest of the roadmap and the world in three ways only, and a change
reaches an edge (or one of its stored particle blocks) through one of them:

- its two ends: a node retired, moved or made invalid has another stabiliser or none
  (:attr:`Change.ends`);
- the nodes its particles landed in: a landing there would now stop elsewhere, or not at all
  (:attr:`Change.landings`), and, when the goal moved, a particle that missed the old goal
  (:data:`~firmtool.estimation.outcomes.GOAL_MISS`) would be judged against the new one
  (:attr:`Change.goal_moved`);
- the world its particles were tested against: a changed box that meets the region they swept,
  grown by the robot's reach (:func:`firmtool.roadmap.world_change.meets`; :attr:`Change.world`).

Everything the change does not reach runs, particle for particle, as it ran (same random streams,
same verdicts): its stored estimates are reused as they are, bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from firmtool.estimation.outcomes import GOAL_MISS
from firmtool.roadmap.world_change import WorldChange, meets


@dataclass(frozen=True, eq=False)  # arrays: compared by identity
class Change:
    """A change of a roadmap, as its edges' Monte Carlo sees it.

    Attributes
    ----------
    ends : (N,) bool, the nodes whose edges (as source or target) the change reaches; None: none.
    landings : (N,) bool, the nodes a particle that landed there makes its edge reached; None: none.
    goal_moved : whether a particle that missed the goal makes its edge reached.
    world : the world's changed boxes (:func:`firmtool.roadmap.world_change.world_change`); None: the
        world is the same.
    reach : how far from its key points the robot's world tests reach (with ``world``).
    """

    ends: np.ndarray | None = None
    landings: np.ndarray | None = None
    goal_moved: bool = False
    world: WorldChange | None = None
    reach: float = 0.0


@dataclass(frozen=True, eq=False)
class Touched:
    """Which rows of an edge table a :class:`Change` reaches, and through what.

    Attributes
    ----------
    ends : (E,) bool, an end node is reached; landed : (E,) bool, a particle landed in a reached node
        or missed a moved goal; swept : (E, K) bool, its swept region meets the K-th changed box.
    """

    ends: np.ndarray
    landed: np.ndarray
    swept: np.ndarray

    @property
    def edges(self) -> np.ndarray:
        """(E,) bool: the rows the change reaches (through any way)."""
        return self.ends | self.landed | self.swept.any(axis=1)


def touched(change: Change, table: Mapping[str, np.ndarray]) -> Touched:
    """The rows of an edge table (``/edges``: ``source``, ``target``, the sparse outcome counts
    ``outcome_edge`` / ``outcome_code`` and, for a world change, ``swept_lo`` / ``swept_hi``) that
    ``change`` reaches (module notes).

    Raises
    ------
    KeyError
        A world change on a table without swept regions (the caller refuses it first, naming the file).
    """
    source = np.asarray(table["source"]).astype(np.int64)
    target = np.asarray(table["target"]).astype(np.int64)
    E = source.size
    ends = np.zeros(E, dtype=bool)
    if change.ends is not None:
        ends = change.ends[source] | change.ends[target]
    landed = np.zeros(E, dtype=bool)
    if change.landings is not None or change.goal_moved:
        code = np.asarray(table["outcome_code"]).astype(np.int64)
        edge = np.asarray(table["outcome_edge"]).astype(np.int64)
        bad = np.zeros(code.size, dtype=bool)
        if change.landings is not None:
            land = code >= 0
            bad[land] = change.landings[code[land]]
        if change.goal_moved:
            bad |= code == GOAL_MISS
        landed[np.unique(edge[bad])] = True
    if change.world is None:
        swept = np.zeros((E, 0), dtype=bool)
    else:
        swept = meets(table["swept_lo"], table["swept_hi"], change.world, change.reach)  # (E, K)
    return Touched(ends=ends, landed=landed, swept=swept)


def touches(change: Change, estimate: Any) -> bool:
    """Whether ``change`` reaches one stored estimate (an
    :class:`~firmtool.estimation.edges.EdgeEstimate`: a stored particle block may hold particles its
    table row has not, so its own landings and swept region decide). An estimate without a swept
    region is reached by any world change (what it tested is not known)."""
    if change.ends is not None and (change.ends[estimate.source] or change.ends[estimate.target]):
        return True
    outcomes = np.asarray(estimate.outcomes)
    if change.landings is not None and change.landings[outcomes[outcomes >= 0]].any():
        return True
    if change.goal_moved and bool(np.any(outcomes == GOAL_MISS)):
        return True
    if change.world is not None:
        if estimate.swept is None:
            return True
        return bool(meets(estimate.swept[:1], estimate.swept[1:], change.world, change.reach).any())
    return False
