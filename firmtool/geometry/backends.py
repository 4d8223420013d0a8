"""Collision backends: capsule robots against obstacles inside a workspace box.

One interface (:class:`CollisionBackend`), implementations registered by name
(:mod:`firmtool.geometry.registry`):

* :class:`NumpyCollisionBackend` (``"numpy"``) -- exact planar geometry (2-D worlds of boxes)
  vectorised over the whole ensemble (no Python loop at all: capsule/obstacle and capsule/capsule
  candidates are gathered with an AABB prefilter and tested in one batch).
* ``NumbaCollisionBackend`` (:mod:`firmtool.geometry._numba`, ``"numba"``) -- the same formulas
  compiled, one configuration at a time with early exit; about 10x faster than numpy.
* ``FclCollisionBackend`` (:mod:`firmtool.geometry.fcl`, ``"fcl"``) -- python-fcl: 2-D and 3-D
  worlds of boxes, spheres, capsules and triangle meshes; the general backend and the reference
  oracle of the planar ones.

Semantics shared by all (and by the tests)
------------------------------------------
* The robot of one configuration is ``L`` capsules of a common radius ``r > 0``: the set of points
  within distance ``r`` of a segment ``[start, end]``; a zero-length segment is a disc (a ball).
* Obstacles are solids. The planar backends take rectangles (centre, half-size, optional rotation
  angle in radians, counter-clockwise). A capsule hits an obstacle iff the segment-to-rectangle distance is ``< r``
  (touching, distance exactly ``r``, is *not* a collision in the numpy backend; fcl decides exact
  contact with its own tolerances, which is why cross-checks skip a band around ``|d - r| < 1e-6``).
* Workspace: the box ``[lo, hi]`` is axis-aligned. A capsule lies inside iff both endpoints lie in
  the box shrunk by ``r``; anything else is a collision. Both backends evaluate this with the same
  plain arithmetic (fcl has no "outside" test), see :func:`outside_workspace`.
* Self-collision (``self_collision=True``): capsules ``a`` and ``b`` of the same configuration with
  ``|a - b| >= 2`` in chain order collide iff their segments are closer than ``2 r``. Adjacent
  links share a joint and are never counted.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from firmtool.errors import InputError, quoted
from firmtool.geometry.distance import (
    segment_box_distance_sq_local,
    segment_segment_distance_sq,
)
from firmtool.geometry.registry import get_backend


@runtime_checkable
class CollisionBackend(Protocol):
    """Batch collision test for an ensemble of capsule robots in a D-dimensional world."""

    self_collision: bool

    def capsules_collide(self, starts: np.ndarray, ends: np.ndarray, radius: float) -> np.ndarray:
        """``starts, ends`` (M, L, D) segment endpoints of L capsules per configuration -> bool (M,).

        True where any capsule intersects an obstacle or leaves the workspace box, or (with
        ``self_collision``) two non-adjacent capsules of the same configuration intersect.
        """
        ...


# ---------------------------------------------------------------------------------------------
# validation shared by both backends


def _check_world(centers, half_sizes, lo, hi, angles) -> tuple[np.ndarray, ...]:
    try:
        c = np.asarray(centers, dtype=float)
        h = np.asarray(half_sizes, dtype=float)
        lo = np.asarray(lo, dtype=float)
        hi = np.asarray(hi, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"collision world: expected numeric arrays ({exc})") from None
    if c.size == 0:
        c = c.reshape(0, 2)
    if h.size == 0:
        h = h.reshape(0, 2)
    if c.ndim != 2 or c.shape[1] != 2:
        raise InputError(f"obstacle_centers: expected shape (K, 2) but found {c.shape}")
    if h.shape != c.shape:
        raise InputError(f"obstacle_half_sizes: expected shape {c.shape} but found {h.shape}")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(h))) or np.any(h <= 0):
        raise InputError("obstacles: expected finite centres and positive finite half sizes")
    if lo.shape != (2,) or hi.shape != (2,):
        raise InputError(f"workspace_lo/workspace_hi: expected shape (2,) but found {lo.shape}, {hi.shape}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))) or np.any(hi <= lo):
        raise InputError(f"workspace: expected finite lo < hi but found lo={lo}, hi={hi}")
    if angles is None:
        a = np.zeros(c.shape[0])
    else:
        a = np.asarray(angles, dtype=float).reshape(-1)
        if a.shape != (c.shape[0],) or not np.all(np.isfinite(a)):
            raise InputError(f"obstacle_angles: expected {c.shape[0]} finite angles but found shape {a.shape}")
    return c, h, lo, hi, a


def _check_capsules(starts, ends, radius, dim: int = 2) -> tuple[np.ndarray, np.ndarray, float]:
    starts = np.asarray(starts, dtype=float)
    ends = np.asarray(ends, dtype=float)
    if starts.ndim != 3 or starts.shape[2] != dim:
        raise InputError(f"starts: expected shape (M, L, {dim}) but found {starts.shape}")
    if ends.shape != starts.shape:
        raise InputError(f"ends: expected shape {starts.shape} but found {ends.shape}")
    try:
        r = float(radius)
    except (TypeError, ValueError):
        raise InputError(f"radius: expected a positive number but found {quoted(radius)}") from None
    if not (np.isfinite(r) and r > 0):
        raise InputError(f"radius: expected a positive finite number but found {quoted(radius)}")
    return starts, ends, r


def planar_world(world, backend: str) -> None:
    """InputError naming ``world.collision_backend`` unless ``world`` is 2-D with box obstacles only."""
    if len(world.lo) != 2:
        raise InputError(f"world.collision_backend: {backend} handles planar (2-D) worlds only, found a "
                         f"{len(world.lo)}-D world; use 'fcl'")
    kinds = sorted({o.kind for o in world.obstacles} - {"box"})
    if kinds:
        raise InputError(f"world.collision_backend: {backend} handles box obstacles only, found {', '.join(kinds)}; "
                         "use 'fcl'")


def outside_workspace(starts: np.ndarray, ends: np.ndarray, radius: float, lo: np.ndarray,
                      hi: np.ndarray) -> np.ndarray:
    """bool (M,): some capsule is not inside the box ``[lo, hi]`` shrunk by ``radius``.

    A capsule is the convex hull of its two end discs, so it is inside iff both endpoints are in
    ``[lo + r, hi - r]`` (touching the wall is allowed). NaN coordinates count as outside.
    """
    lo_r, hi_r = lo + radius, hi - radius
    inside = (starts >= lo_r) & (starts <= hi_r) & (ends >= lo_r) & (ends <= hi_r)
    return ~inside.all(axis=(1, 2))


def nonadjacent_pairs(L: int) -> tuple[np.ndarray, np.ndarray]:
    """Index arrays ``(a, b)`` of the capsule pairs with ``b - a >= 2`` (chain order)."""
    a, b = np.triu_indices(L, k=2)
    return a.astype(np.intp), b.astype(np.intp)


# ---------------------------------------------------------------------------------------------
# numpy


class NumpyCollisionBackend:
    """Exact planar collision checks vectorised over the ensemble.

    Parameters
    ----------
    obstacle_centers : (K, 2) rectangle centres (K may be 0).
    obstacle_half_sizes : (K, 2) positive half sizes.
    workspace_lo, workspace_hi : (2,) corners of the axis-aligned workspace box.
    self_collision : also test non-adjacent capsules of a configuration against each other.
    obstacle_angles : optional (K,) rotation of each rectangle about its centre (radians, CCW).
    prefilter : gather only the capsule/obstacle and capsule/capsule pairs whose AABBs overlap
        before the exact test (pays as soon as most pairs are far apart; see
        ``benchmarks/bench_collision.py``).

    Configurations are decided in stages (workspace, obstacles, self-collision); a configuration
    already in collision is dropped from later stages.
    """

    def __init__(self, obstacle_centers: np.ndarray, obstacle_half_sizes: np.ndarray,
                 workspace_lo: np.ndarray, workspace_hi: np.ndarray, *, self_collision: bool,
                 obstacle_angles: np.ndarray | None = None, prefilter: bool = True) -> None:
        c, h, lo, hi, a = _check_world(obstacle_centers, obstacle_half_sizes, workspace_lo, workspace_hi,
                                       obstacle_angles)
        self.centers, self.half_sizes, self.angles = c, h, a
        self.lo, self.hi = lo, hi
        self.self_collision = bool(self_collision)
        self.prefilter = bool(prefilter)
        self._rotated = bool(np.any(a != 0.0))
        self._cos, self._sin = np.cos(a), np.sin(a)
        # world AABB of each (possibly rotated) rectangle
        ext = np.abs(self._cos)[:, None] * h + np.abs(self._sin)[:, None] * h[:, ::-1]
        self._ext = ext
        self._box_lo, self._box_hi = c - ext, c + ext

    @classmethod
    def from_boxes(cls, *args, **kwargs) -> "NumpyCollisionBackend":
        """The constructor (the planar interface of :func:`make_backend`)."""
        return cls(*args, **kwargs)

    @classmethod
    def from_world(cls, world, *, self_collision: bool) -> "NumpyCollisionBackend":
        """The backend of a scenario's world (:class:`firmtool.scenario.WorldSpec`): 2-D, boxes only."""
        planar_world(world, cls.__name__)
        return cls(np.array([o.center for o in world.obstacles], dtype=float).reshape(-1, 2),
                   np.array([o.half_size for o in world.obstacles], dtype=float).reshape(-1, 2),
                   np.array(world.lo), np.array(world.hi), self_collision=self_collision)

    @property
    def n_obstacles(self) -> int:
        return self.centers.shape[0]

    # --- helpers --------------------------------------------------------------------------

    def _local(self, p: np.ndarray, k: np.ndarray | slice) -> np.ndarray:
        """World points ``p`` (..., 2) -> frame of obstacle(s) ``k`` (broadcast with p's leading axes)."""
        q = p - self.centers[k]
        if not self._rotated:
            return q
        c, s = self._cos[k], self._sin[k]
        return np.stack([c * q[..., 0] + s * q[..., 1], -s * q[..., 0] + c * q[..., 1]], axis=-1)

    def _obstacle_d2_all(self, S: np.ndarray, E: np.ndarray) -> np.ndarray:
        """(m, L, K) squared segment-to-rectangle distances (no prefilter)."""
        k = slice(None)
        a = self._local(S[:, :, None, :], k)
        b = self._local(E[:, :, None, :], k)
        return segment_box_distance_sq_local(a, b, self.half_sizes)

    def _obstacle_hits(self, S: np.ndarray, E: np.ndarray, r: float) -> np.ndarray:
        m = S.shape[0]
        if not self.prefilter:
            return (self._obstacle_d2_all(S, E) < r * r).any(axis=(1, 2))
        lo = np.minimum(S, E) - r
        hi = np.maximum(S, E) + r
        cand = ((lo[:, :, None, :] <= self._box_hi) & (hi[:, :, None, :] >= self._box_lo)).all(axis=-1)
        i, l, k = np.nonzero(cand)
        hit = np.zeros(m, dtype=bool)
        if i.size == 0:
            return hit
        a = self._local(S[i, l], k)
        b = self._local(E[i, l], k)
        d2 = segment_box_distance_sq_local(a, b, self.half_sizes[k])
        hit[i[d2 < r * r]] = True
        return hit

    def _self_hits(self, S: np.ndarray, E: np.ndarray, r: float) -> np.ndarray:
        m, L = S.shape[:2]
        pa, pb = nonadjacent_pairs(L)
        hit = np.zeros(m, dtype=bool)
        if pa.size == 0:
            return hit
        lim = (2.0 * r) ** 2
        if not self.prefilter:
            d2 = segment_segment_distance_sq(S[:, pa], E[:, pa], S[:, pb], E[:, pb])
            return (d2 < lim).any(axis=1)
        lo = np.minimum(S, E)
        hi = np.maximum(S, E)
        cand = ((lo[:, pa] - 2.0 * r <= hi[:, pb]) & (hi[:, pa] + 2.0 * r >= lo[:, pb])).all(axis=-1)
        i, j = np.nonzero(cand)
        if i.size == 0:
            return hit
        a, b = pa[j], pb[j]
        d2 = segment_segment_distance_sq(S[i, a], E[i, a], S[i, b], E[i, b])
        hit[i[d2 < lim]] = True
        return hit

    # --- public ---------------------------------------------------------------------------

    def capsules_collide(self, starts: np.ndarray, ends: np.ndarray, radius: float) -> np.ndarray:
        """See :class:`CollisionBackend`. Returns bool (M,)."""
        starts, ends, r = _check_capsules(starts, ends, radius)
        M, L = starts.shape[:2]
        out = np.zeros(M, dtype=bool)
        if L == 0 or M == 0:
            return out
        out |= outside_workspace(starts, ends, r, self.lo, self.hi)
        if self.n_obstacles:
            alive = np.flatnonzero(~out)
            if alive.size:
                out[alive] = self._obstacle_hits(starts[alive], ends[alive], r)
        if self.self_collision and L >= 3:
            alive = np.flatnonzero(~out)
            if alive.size:
                out[alive] = self._self_hits(starts[alive], ends[alive], r)
        return out

    def clearance(self, starts: np.ndarray, ends: np.ndarray, radius: float) -> np.ndarray:
        """Signed margin (M,): >= 0 free, < 0 in collision (no prefilter, every pair evaluated).

        The minimum of: the segment-to-rectangle distances minus ``r``; the distance of the
        endpoints to the workspace walls minus ``r``; and (with ``self_collision``) the distances
        between non-adjacent segments minus ``2 r``. Negative values are *not* penetration depths
        (a segment inside a rectangle gives ``-r``). ``capsules_collide == (clearance < 0)`` up to
        rounding; cross-checks skip ``|clearance| < tol``.
        """
        starts, ends, r = _check_capsules(starts, ends, radius)
        M, L = starts.shape[:2]
        out = np.full(M, np.inf)
        if L == 0 or M == 0:
            return out
        P = np.concatenate([starts, ends], axis=1)
        ws = np.minimum(P - self.lo, self.hi - P).min(axis=(1, 2)) - r
        ws = np.where(np.isnan(ws), -np.inf, ws)
        out = np.minimum(out, ws)
        if self.n_obstacles:
            out = np.minimum(out, np.sqrt(self._obstacle_d2_all(starts, ends).min(axis=(1, 2))) - r)
        if self.self_collision:
            pa, pb = nonadjacent_pairs(L)
            if pa.size:
                d2 = segment_segment_distance_sq(starts[:, pa], ends[:, pa], starts[:, pb], ends[:, pb])
                out = np.minimum(out, np.sqrt(d2.min(axis=1)) - 2.0 * r)
        return out


# ---------------------------------------------------------------------------------------------

def make_backend(name: str, obstacle_centers: np.ndarray, obstacle_half_sizes: np.ndarray,
                 workspace_lo: np.ndarray, workspace_hi: np.ndarray, *, self_collision: bool,
                 obstacle_angles: np.ndarray | None = None, **options) -> CollisionBackend:
    """A planar backend of the registry (``"numpy"``, ``"numba"``, ``"fcl"``) over rectangles.

    Extra keyword ``options`` go to the backend's constructor. Raises :class:`InputError` for an
    unknown name. (A world of any kind and dimension: :func:`firmtool.geometry.registry.backend_for_world`.)
    """
    cls = get_backend(name).load()
    if not hasattr(cls, "from_boxes"):
        raise InputError(f"collision backend {quoted(name)} does not take planar rectangles")
    return cls.from_boxes(obstacle_centers, obstacle_half_sizes, workspace_lo, workspace_hi,
                          self_collision=self_collision, obstacle_angles=obstacle_angles, **options)
