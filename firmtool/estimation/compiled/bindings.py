"""What the compiled kernel calls per world dimension: the robot's hooks and the geometry, bound by
name (:func:`firmtool.jit.specialise`) into :func:`firmtool.estimation.compiled.run.run`.

The kernel is written once for both dimensions; it keeps three key-point arrays ``PX, PY, PZ`` (``PZ``
unused in 2-D) and calls, per step:

- ``points(X, params, PX, PY, PZ, lane, na)``: the key points (2-D: the robot's planar
  ``key_points`` hook, through :func:`points_2d`; 3-D: the robot's hook itself);
- ``sense(PX, PY, PZ, params, S, na) -> rows``: the array whose row ``sensing[j]`` sets measurement
  j's noise (2-D: ``PX`` itself, the key points' x; 3-D: the robot's ``sense`` hook fills ``S``);
- ``sweep_points``: the swept region (:func:`firmtool.estimation.compiled.collide.sweep`, both);
- ``gate`` and ``particle_collides``: the collision gate and the exact collision test of one particle
  (:mod:`~firmtool.estimation.compiled.collide` in 2-D, :mod:`~firmtool.estimation.compiled.collide3d`
  in 3-D);
- ``goal_gate(X, XH, PX, PY, PZ, params, center, r, E, B, GG, na)``, ``goal_test`` and ``true_inside``:
  the goal ball's gate, its test on the estimate and its test of the true task point
  (:mod:`~firmtool.estimation.compiled.goal`, :mod:`~firmtool.estimation.compiled.goal3d`);
- ``advance`` and ``update``: the model's true step and filter update (:mod:`~firmtool.estimation.compiled.model`:
  linear or the robot's ``step`` hook, the robot's sensor or landmarks).

The 2-D functions here only adapt the planar kernel's calls to these names: the planar arithmetic is
the one of the planar kernel before 3-D existed (the same tests pin it).
"""

from __future__ import annotations

from typing import Callable, Mapping

from firmtool.estimation.compiled.model import model_functions
from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba, specialise

INLINE = {**KERNEL_OPTIONS, "inline": "always"}
# the robot's hooks the 2-D adapters are compiled against (specialise binds them per robot)
key_points = planar_goal_gate = None


if numba is not None:
    from firmtool.estimation.compiled import goal as goal_2d
    from firmtool.estimation.compiled import goal3d
    from firmtool.estimation.compiled.collide import collides, collision_gate, sweep
    from firmtool.estimation.compiled.collide3d import collision_gate_3d, particle_collides_3d
    from firmtool.estimation.compiled.goal import every_particle

    step = cached_njit(**INLINE)

    def points_2d(X, params, PX, PY, PZ, lane, na):
        """The planar ``key_points`` hook (PZ unused)."""
        key_points(X, params, PX, PY, lane, na)

    def goal_gate_2d(X, XH, PX, PY, PZ, params, center, r, E, bound, GG, na):
        """The planar ``goal_gate`` hook (PZ unused)."""
        planar_goal_gate(X, XH, PX, PY, params, center, r, E, bound, GG, na)

    @step
    def every_particle_3d(X, XH, PX, PY, PZ, params, center, r, E, bound, GG, na):
        """The 3-D goal gate of a robot that gives none: every particle runs the goal test."""
        for a in range(na):
            GG[a] = 1

    @step
    def sense_2d(PX, PY, PZ, params, S, na):
        """In 2-D measurement j's noise is set by the x of key point ``sensing[j]``: the rows are PX."""
        return PX

    @step
    def gate_2d(PX, PY, PZ, na, robot, world, G):
        params, sensing, n_pts, n_seg, seg_offset, self_collision, half, work_size = robot[:8]
        collision_gate(PX, PY, na, n_seg, seg_offset, world, self_collision, half, G)

    @step
    def particle_collides_2d(PX, PY, PZ, a, px, py, robot, world):
        """Particle ``a``'s planar collision test (its key points copied to ``px``, ``py``)."""
        params, sensing, n_pts, n_seg, seg_offset, self_collision, half, work_size = robot[:8]
        for p in range(n_pts):
            px[p] = PX[p, a]
            py[p] = PY[p, a]
        return collides(px, py, n_seg, seg_offset, world, self_collision, half)

    @step
    def true_inside_2d(PX, PY, PZ, tip, a, center, r):
        ex, ey = PX[tip, a] - center[0], PY[tip, a] - center[1]
        return ex * ex + ey * ey < r * r

    @step
    def gate_3d(PX, PY, PZ, na, robot, world, G):
        n_seg, seg_offset, stride = robot[3], robot[4], robot[8]
        collision_gate_3d(PX, PY, PZ, na, n_seg, stride, seg_offset, world, G)

    @step
    def particle_collides_3d_robot(PX, PY, PZ, a, px, py, robot, world):
        """Particle ``a``'s 3-D collision test (``px``: the segment test's work array)."""
        n_seg, seg_offset, stride = robot[3], robot[4], robot[8]
        return particle_collides_3d(PX, PY, PZ, a, px, n_seg, stride, seg_offset, world)


def bindings(functions: Mapping[str, Callable | None], dim: int, cache: bool) -> dict[str, Callable]:
    """The kernel's names bound to the functions of a robot's hooks (``functions``, as
    :meth:`~firmtool.robots.compiled.CompiledKinematics.functions` gives them) in a ``dim``-D world;
    ``cache``: whether the specialisations may be cached on disk (the hooks are importable)."""
    hooks = {"task_point": functions["task_point"], "task_covariance": functions["task_covariance"]}
    steps = model_functions(functions.get("step"), functions.get("sensor") or "")
    return {**steps, **_geometry_bindings(functions, dim, cache, hooks)}


def _geometry_bindings(functions: Mapping[str, Callable | None], dim: int, cache: bool,
                       hooks: dict) -> dict[str, Callable]:
    """The kinematics', geometry's and goal's names of :func:`bindings`."""
    if dim == 2:
        test = specialise(goal_2d.goal_test, hooks, KERNEL_OPTIONS, cache=cache)
        return {"points": specialise(points_2d, {"key_points": functions["key_points"]}, INLINE, cache=cache),
                "goal_gate": specialise(goal_gate_2d, {"planar_goal_gate": functions["goal_gate"] or every_particle},
                                        INLINE, cache=cache),
                "sense": sense_2d, "sweep_points": sweep, "gate": gate_2d, "particle_collides": particle_collides_2d,
                "goal_test": test, "true_inside": true_inside_2d}
    test = specialise(goal3d.goal_test_3d, hooks, KERNEL_OPTIONS, cache=cache)
    return {"points": functions["key_points"], "goal_gate": functions["goal_gate"] or every_particle_3d,
            "sense": functions["sense"], "sweep_points": sweep, "gate": gate_3d,
            "particle_collides": particle_collides_3d_robot, "goal_test": test, "true_inside": goal3d.true_inside_3d}
