"""python-fcl collision backend: capsule robots in 2-D or 3-D worlds of boxes, spheres, capsules,
cylinders and triangle meshes (name ``"fcl"``); the general backend, and the oracle of the planar ones.

Obstacles become fcl objects in a ``DynamicAABBTreeCollisionManager`` (broadphase): ``fcl.Box``,
``fcl.Sphere``, ``fcl.Capsule`` (its local z axis rotated onto the segment, centred at its
midpoint) and, for meshes, an ``fcl.BVHModel`` (OBB-RSS bounding volume hierarchy over the
triangles). A 2-D world is the plane z = 0 of the 3-D one: a box gets a depth, a sphere's and a
capsule's sections by that plane are the disc and the planar capsule of the same radius, so the
planar decisions are exact. A robot capsule is an ``fcl.Capsule`` (a ``fcl.Sphere`` if shorter than
:data:`MIN_LENGTH`).

fcl treats a mesh as a surface. A closed mesh bounds a solid, so a capsule whose end lies inside
it (found by the winding number of :meth:`firmtool.geometry.shapes.Mesh.contains`) collides even
without touching the surface; an open mesh is a thin wall.

Per configuration fcl costs several microseconds (DESIGN.md: >= 7 us), so configurations are first
screened with numpy over the whole ensemble: one that stays inside the workspace (the same
arithmetic as the planar backends, :func:`~firmtool.geometry.backends.outside_workspace`), whose
capsules' bounding boxes meet no obstacle's bounding box and (with self-collision) no other
non-adjacent capsule's box grown by ``2 r``, is free; only the rest go through fcl. The screen
only skips tests that cannot find a contact.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from firmtool.errors import InputError, quoted
from firmtool.geometry.backends import _check_capsules, _check_world, nonadjacent_pairs, outside_workspace
from firmtool.geometry.distance3d import segment_box_distance_sq, segment_point_distance_sq
from firmtool.geometry.shapes import Box, Capsule, Cylinder, Mesh, Obstacle, Sphere

MIN_LENGTH = 1e-12  # robot segments shorter than this are spheres
PLANAR_DEPTH = 1.0  # extent along z of a 2-D world's boxes


def axis_rotation(u: np.ndarray) -> np.ndarray:
    """A 3x3 rotation taking the local z axis onto the unit vector ``u`` (3,)."""
    u = np.asarray(u, dtype=float)
    helper = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(helper, u)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    return np.column_stack([e1, e2, u])


def _pad3(p: np.ndarray) -> np.ndarray:
    p = np.asarray(p, dtype=float)
    return p if p.shape[-1] == 3 else np.concatenate([p, np.zeros(p.shape[:-1] + (3 - p.shape[-1],))], axis=-1)


class FclCollisionBackend:
    """python-fcl backend for 2-D and 3-D worlds (see the module docs).

    Parameters
    ----------
    obstacles : the world's obstacles (:mod:`firmtool.geometry.shapes`), all of the world's dimension.
    workspace_lo, workspace_hi : (D,) corners of the axis-aligned workspace box, D = 2 or 3.
    self_collision : also test non-adjacent capsules of a configuration against each other.
    box_angles : optional (K,) rotation about z (radians, counter-clockwise) of each obstacle; boxes
        only (the planar cross-checks' rotated rectangles).
    """

    dimensions = (2, 3)

    def __init__(self, obstacles: Sequence[Obstacle], workspace_lo: np.ndarray, workspace_hi: np.ndarray, *,
                 self_collision: bool, box_angles: np.ndarray | None = None, depth: float = PLANAR_DEPTH) -> None:
        import fcl  # imported lazily: the planar backends do not need it

        self._fcl = fcl
        lo, hi = np.asarray(workspace_lo, dtype=float), np.asarray(workspace_hi, dtype=float)
        if lo.ndim != 1 or lo.shape != hi.shape or lo.size not in self.dimensions:
            raise InputError(f"workspace_lo/workspace_hi: expected shape (2,) or (3,) but found {lo.shape}, {hi.shape}")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))) or np.any(hi <= lo):
            raise InputError(f"workspace: expected finite lo < hi but found lo={lo}, hi={hi}")
        self.lo, self.hi, self.dim = lo, hi, lo.size
        self.self_collision = bool(self_collision)
        self.obstacles = tuple(obstacles)
        angles = np.zeros(len(self.obstacles)) if box_angles is None else np.asarray(box_angles, dtype=float)
        objects, box_lo, box_hi = [], [], []
        self._closed: list[Mesh] = []
        for o, angle in zip(self.obstacles, angles):
            if o.dim != self.dim:
                raise InputError(f"obstacle {o}: expected a {self.dim}-D {o.kind}")
            geom, tf = self._geometry(o, float(angle), float(depth))
            objects.append(fcl.CollisionObject(geom, tf))
            a, b = o.aabb()
            if angle != 0.0:  # a rotated rectangle's box: its circumscribed square
                c, r = 0.5 * (a + b), np.linalg.norm(0.5 * (b - a))
                a, b = c - r, c + r
            box_lo.append(a)
            box_hi.append(b)
            if isinstance(o, Mesh) and o.closed:
                self._closed.append(o)
        self._objects = objects
        self._box_lo = np.array(box_lo, dtype=float).reshape(-1, self.dim)
        self._box_hi = np.array(box_hi, dtype=float).reshape(-1, self.dim)
        # 3-D worlds of axis-aligned boxes and spheres: capsules of their own radii are decided in numpy
        # (firmtool.geometry.distance3d), the rest through fcl
        self._vectorised = self.dim == 3 and all(isinstance(o, (Box, Sphere)) for o in self.obstacles)
        if self._vectorised:  # (K,) is a sphere, (K, 3) centres, (K, 3) boxes' half sizes, (K,) spheres' radii,
            # (K, 3, 3) boxes' rotations
            self._solids = (np.array([isinstance(o, Sphere) for o in self.obstacles], dtype=bool),
                            np.array([o.center for o in self.obstacles], dtype=float).reshape(-1, 3),
                            np.array([o.half_size if isinstance(o, Box) else (0.0, 0.0, 0.0) for o in self.obstacles],
                                     dtype=float).reshape(-1, 3),
                            np.array([o.radius if isinstance(o, Sphere) else 0.0 for o in self.obstacles], dtype=float),
                            np.array([o.rotation() if isinstance(o, Box) else np.eye(3) for o in self.obstacles],
                                     dtype=float).reshape(-1, 3, 3))
        self._manager = None
        if objects:
            self._manager = fcl.DynamicAABBTreeCollisionManager()
            self._manager.registerObjects(objects)
            self._manager.setup()

    @classmethod
    def from_world(cls, world, *, self_collision: bool) -> "FclCollisionBackend":
        """The backend of a scenario's world (:class:`firmtool.scenario.WorldSpec`)."""
        return cls(world.obstacles, np.array(world.lo), np.array(world.hi), self_collision=self_collision)

    @classmethod
    def from_boxes(cls, obstacle_centers, obstacle_half_sizes, workspace_lo, workspace_hi, *, self_collision: bool,
                   obstacle_angles=None, depth: float = PLANAR_DEPTH) -> "FclCollisionBackend":
        """A planar world of (rotated) rectangles: the constructor of the planar backends."""
        c, h, lo, hi, a = _check_world(obstacle_centers, obstacle_half_sizes, workspace_lo, workspace_hi,
                                       obstacle_angles)
        boxes = [Box(tuple(ci), tuple(hi_)) for ci, hi_ in zip(c, h)]
        return cls(boxes, lo, hi, self_collision=self_collision, box_angles=a, depth=depth)

    def _geometry(self, o: Obstacle, angle: float, depth: float):
        fcl = self._fcl
        if isinstance(o, Box):
            size = 2.0 * np.asarray(o.half_size, dtype=float)
            if self.dim == 2:
                size = np.append(size, depth)
            R = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]])
            if o.rpy is not None:
                R = o.rotation()
            return fcl.Box(*size), fcl.Transform(R, _pad3(o.center))
        if isinstance(o, Cylinder):
            return fcl.Cylinder(float(o.radius), float(o.length)), fcl.Transform(o.rotation(), _pad3(o.center))
        if angle != 0.0:
            raise InputError(f"obstacle angles: only boxes rotate, found a {o.kind}")
        if isinstance(o, Sphere):
            return fcl.Sphere(float(o.radius)), fcl.Transform(_pad3(o.center))
        if isinstance(o, Capsule):
            return self._segment_geometry(_pad3(o.start), _pad3(o.end), float(o.radius))
        if isinstance(o, Mesh):
            model = fcl.BVHModel()
            model.beginModel(int(o.vertices.shape[0]), int(o.triangles.shape[0]))
            model.addSubModel(np.asarray(o.vertices, dtype=float), np.asarray(o.triangles, dtype=np.int64))
            model.endModel()
            return model, fcl.Transform()
        raise InputError(f"collision backend 'fcl': obstacle kind {quoted(o.kind)} is not supported")

    def _segment_geometry(self, p: np.ndarray, q: np.ndarray, r: float):
        """A capsule (or a sphere, if shorter than MIN_LENGTH) around the segment [p, q] (3-D points)."""
        fcl = self._fcl
        d = q - p
        length = float(np.linalg.norm(d))
        mid = 0.5 * (p + q)
        if length < MIN_LENGTH:
            return fcl.Sphere(r), fcl.Transform(mid)
        return fcl.Capsule(r, length), fcl.Transform(axis_rotation(d / length), mid)

    def _hits_obstacles(self, obj) -> bool:
        fcl = self._fcl
        data = fcl.CollisionData()
        self._manager.collide(obj, data, fcl.defaultCollisionCallback)
        return bool(data.result.is_collision)

    def _screen(self, starts: np.ndarray, ends: np.ndarray, r: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
        """bool (M,): configurations some exact test could find in collision (see the module docs);
        ``r`` (L,) the capsules' radii."""
        rr = r[:, None]
        lo, hi = np.minimum(starts, ends) - rr, np.maximum(starts, ends) + rr  # (M, L, D)
        near = np.zeros(starts.shape[0], dtype=bool)
        if self._box_lo.shape[0]:
            near |= ((lo[:, :, None, :] <= self._box_hi) & (hi[:, :, None, :] >= self._box_lo)).all(-1).any(axis=(1, 2))
        if pa.size:
            rb = r[pb][:, None]
            near |= ((lo[:, pa] - rb <= hi[:, pb]) & (hi[:, pa] + rb >= lo[:, pb])).all(-1).any(axis=1)
        return near

    def capsules_collide(self, starts: np.ndarray, ends: np.ndarray, radius: float) -> np.ndarray:
        """See :class:`~firmtool.geometry.backends.CollisionBackend`. Returns bool (M,)."""
        starts, ends, r = _check_capsules(starts, ends, radius, self.dim)
        return self._collide(starts, ends, np.full(starts.shape[1], r))

    def capsules_collide_radii(self, starts: np.ndarray, ends: np.ndarray, radii: np.ndarray) -> np.ndarray:
        """:meth:`capsules_collide` with a radius per capsule: ``radii`` (L,) positive (a URDF arm's
        links, :mod:`firmtool.robots.urdf_arm`). Returns bool (M,)."""
        starts, ends, _ = _check_capsules(starts, ends, 1.0, self.dim)
        r = np.asarray(radii, dtype=float).reshape(-1)
        if r.shape != (starts.shape[1],) or not (np.all(np.isfinite(r)) and np.all(r > 0)):
            raise InputError(f"radii: expected {starts.shape[1]} positive finite radii, found {r.shape}")
        if self._vectorised and not self.self_collision:
            return self._collide_vectorised(starts, ends, r)
        return self._collide(starts, ends, r)

    def _collide_vectorised(self, starts: np.ndarray, ends: np.ndarray, r: np.ndarray) -> np.ndarray:
        """:meth:`_collide` in numpy for a 3-D world of axis-aligned boxes and spheres: the exact
        distance of every capsule whose bounding box meets an obstacle's (module docs' screen)."""
        out = outside_workspace(starts, ends, r[:, None], self.lo, self.hi)
        if not self.obstacles:
            return out
        rr = r[:, None]
        lo, hi = np.minimum(starts, ends) - rr, np.maximum(starts, ends) + rr  # (M, L, 3)
        near = ((lo[:, :, None, :] <= self._box_hi) & (hi[:, :, None, :] >= self._box_lo)).all(-1)  # (M, L, K)
        near &= ~out[:, None, None]
        m, l, k = np.nonzero(near)
        if m.size == 0:
            return out
        sphere, centre, extent, radius, rotation = self._solids
        a, b = starts[m, l] - centre[k], ends[m, l] - centre[k]
        # in each box's own frame (R' (p - c)), where it is the axis-aligned [-h, h]
        a_box, b_box = np.einsum("nji,nj->ni", rotation[k], a), np.einsum("nji,nj->ni", rotation[k], b)
        d2 = np.where(sphere[k], segment_point_distance_sq(a, b, 0.0),
                      segment_box_distance_sq(a_box, b_box, -extent[k], extent[k]))
        hit = d2 < (r[l] + radius[k]) ** 2
        out[m[hit]] = True
        return out

    def _collide(self, starts: np.ndarray, ends: np.ndarray, r: np.ndarray) -> np.ndarray:
        fcl = self._fcl
        M, L = starts.shape[:2]
        out = np.zeros(M, dtype=bool)
        if L == 0 or M == 0:
            return out
        out |= outside_workspace(starts, ends, r[:, None], self.lo, self.hi)
        pa, pb = nonadjacent_pairs(L) if self.self_collision else (np.zeros(0, np.intp), np.zeros(0, np.intp))
        todo = np.flatnonzero(~out)
        todo = todo[self._screen(starts[todo], ends[todo], r, pa, pb)]
        if todo.size and self._closed:  # a capsule end inside a closed mesh: inside the solid
            ends_3d = np.concatenate([starts[todo], ends[todo]], axis=1).reshape(-1, 3)
            for mesh in self._closed:
                out[todo] |= mesh.contains(ends_3d).reshape(todo.size, 2 * L).any(axis=1)
            todo = todo[~out[todo]]
        S, E = _pad3(starts), _pad3(ends)
        request = fcl.CollisionRequest()
        for m in todo:
            objs = [fcl.CollisionObject(*self._segment_geometry(S[m, l], E[m, l], float(r[l]))) for l in range(L)]
            hit = False
            if self._manager is not None:
                hit = any(self._hits_obstacles(o) for o in objs)
            if not hit:
                for a, b in zip(pa, pb):
                    if fcl.collide(objs[a], objs[b], request, fcl.CollisionResult()):
                        hit = True
                        break
            out[m] = hit
        return out

    def shapes_collide(self, objects: Sequence) -> bool:
        """Whether any of the fcl ``objects`` (``fcl.CollisionObject``) meets an obstacle: the exact
        test of a robot's own shapes (a URDF link's boxes, cylinders and meshes)."""
        return self._manager is not None and any(self._hits_obstacles(o) for o in objects)
