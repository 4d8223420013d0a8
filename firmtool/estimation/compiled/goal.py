"""The compiled kernel's goal test: the goal region of a task's goal ball (:mod:`firmtool.problem.goal`),
tested per particle and step.

:func:`goal_test` asks for the estimate's task point in the ball, then the chance constraint on the
task covariance ``J P J'`` by the same exact bounds and the same direction rule as
:func:`firmtool.problem.goal.meets_confidence` (:func:`ball_decision`); the kernel ends a landing
whose TRUE task point (the true state's last key point) lies outside the ball with ``GOAL_MISS``.
The task point and its covariance are the robot's compiled hooks
(:class:`~firmtool.robots.compiled.CompiledKinematics`): :func:`goal_test` is compiled against them
(:func:`firmtool.estimation.compiled.run.kernel`), as is the kernel. Before it, the robot's goal
gate (a cheap necessary condition, vectorised over particles; by default :func:`every_particle`)
spares the particles that cannot land.

The kernel's goal group ``(active, center, radius, confidence, q_conf, Pcfg, goal_node, is_goal,
true_scale)`` (:func:`goal_group`): the goal ball (active False: none), chi2_2.ppf(confidence), the
task block of the filter covariance per step (``Pcfg[k + 1]`` after step k's update; zeros with
perfect measurements), the landing's code; the goal nodes (N,) and the true state's spread at each
node (N, n) (a goal state's landing is judged on the true state: ``NodeRegions.true_arrival``).
"""

from __future__ import annotations

import math

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba

# The robot's hooks goal_test is compiled against (firmtool.jit.specialise binds them per robot; the
# unbound function is never compiled).
task_point = task_covariance = None


def goal_test(xh, k, params, goal, work):
    """Whether the belief ``(xh (n,), Pcfg[k + 1])`` of a particle lies in the goal region of the goal
    ball (the mean's task point in the ball, the chance constraint met); ``params`` the robot's hook
    constants, ``work`` its hooks' work array. Called where the goal gate passed. Twin of
    :meth:`firmtool.problem.goal.GoalRegion.contains`; pinned by
    tests/test_goal.py::test_kernel_goal_landing_is_the_numpy_one."""
    active, center, r, conf, q_conf, Pcfg, goal_node, is_goal, true_scale = goal
    cx, cy = center[0], center[1]
    tx, ty = task_point(xh, params, work)
    mx, my = tx - cx, ty - cy
    if not (mx * mx + my * my < r * r):  # a NaN estimate is outside, as in numpy
        return False
    P = Pcfg[k + 1]
    if all_zero(P):  # perfect measurements: the mean alone decides
        return True
    s11, s12, s22 = task_covariance(P, params, work)
    return ball_decision(mx, my, s11, s12, s22, r, conf, q_conf)


_NO_GOAL_CENTER = np.zeros(2)
_NO_GOAL_P = np.zeros((1, 1, 1))


_node_goal_cache: dict[int, tuple[object, tuple]] = {}


def node_goal_data(regions) -> tuple:
    """``(is_goal (N,) bool, true_scale (N, n))`` of ``regions`` (once per regions object)."""
    hit = _node_goal_cache.get(id(regions))
    if hit is not None and hit[0] is regions:
        return hit[1]
    N = regions.count
    is_goal = np.zeros(N, dtype=np.bool_) if regions.goal_nodes is None else \
        np.asarray(regions.goal_nodes, dtype=np.bool_)
    scale = regions.true_scale if regions.true_scale is not None else regions.scale
    data = (np.ascontiguousarray(is_goal), np.ascontiguousarray(scale, dtype=float))
    if len(_node_goal_cache) > 8:
        _node_goal_cache.clear()
    _node_goal_cache[id(regions)] = (regions, data)
    return data


def goal_group(regions, P_steps: np.ndarray, k_end: int, d_cfg: int, perfect: bool, goal_node: int) -> tuple:
    """The kernel's goal group for steps up to ``k_end`` (module notes), ``d_cfg`` the robot's task block:
    the ball inactive without one."""
    is_goal, true_scale = node_goal_data(regions)
    goal_region = regions.goal
    if goal_region is None:
        return (False, _NO_GOAL_CENTER, 1.0, 0.5, 1.0, _NO_GOAL_P, -1, is_goal, true_scale)
    Pcfg = (np.zeros((k_end + 1, d_cfg, d_cfg)) if perfect
            else np.ascontiguousarray(P_steps[:k_end + 1, :d_cfg, :d_cfg], dtype=float))
    conf = float(goal_region.confidence)
    return (True, np.ascontiguousarray(goal_region.center, dtype=float), float(goal_region.radius), conf,
            -2.0 * math.log1p(-conf), Pcfg, int(goal_node), is_goal, true_scale)  # chi2_2.ppf(conf)


if numba is not None:
    from firmtool.problem.goal import BASE_DIRECTIONS, MAX_LEVEL, MIN_STD_FRACTION

    njit = cached_njit(**KERNEL_OPTIONS)
    # inlined into the kernel at numba's IR level (cold compile: see firmtool.estimation.compiled.step)
    step = cached_njit(**KERNEL_OPTIONS, inline="always")

    @step
    def all_zero(P):
        """Whether every entry of ``P`` is 0 (a covariance of perfect measurements)."""
        for i in range(P.shape[0]):
            for j in range(P.shape[1]):
                if P[i, j] != 0.0:
                    return False
        return True

    @njit
    def _ndtr(x):
        return 0.5 * math.erfc(-x * 0.7071067811865476)

    @njit
    def _ray_sum(mx, my, l11, l21, l22, r, first, step, count):
        """Sum over the angles ``2 pi (first + step i) / (count step)`` of the direction rule's integrand
        (:func:`firmtool.problem.goal._ray_rule` in 2-D: ``F_2(rho_2^2) - F_2(rho_1^2)``)."""
        total = 0.0
        c = mx * mx + my * my - r * r
        n = count * step
        for i in range(count):
            phi = 2.0 * np.pi * (first + step * i) / n
            ux, uy = np.cos(phi), np.sin(phi)
            lx = l11 * ux
            ly = l21 * ux + l22 * uy
            a = lx * lx + ly * ly
            b = lx * mx + ly * my
            disc = b * b - a * c
            if disc <= 0.0:
                continue
            root = np.sqrt(disc)
            far = (-b + root) / a
            if far <= 0.0:
                continue
            near = max((-b - root) / a, 0.0)
            total += math.exp(-0.5 * near * near) - math.exp(-0.5 * far * far)
        return total

    @njit
    def ball_decision(mx, my, s11, s12, s22, r, conf, q_conf):
        """Whether N((mx, my), [[s11, s12], [s12, s22]]) puts at least ``conf`` on the disc of radius r
        about the origin: the exact bounds, then the direction rule refined until the gap to ``conf``
        exceeds four times the change between levels. Twin of :func:`firmtool.problem.goal.meets_confidence`
        (2-D); pinned by tests/test_goal.py::test_compiled_decision_is_the_numpy_one."""
        floor = (MIN_STD_FRACTION * r) ** 2
        a_, b_, c_ = s11 + floor, s12, s22 + floor
        half_tr, det = 0.5 * (a_ + c_), a_ * c_ - b_ * b_
        gap = np.sqrt(max(half_tr * half_tr - det, 0.0))
        lam_max, lam_min = half_tr + gap, max(half_tr - gap, floor)
        d = np.sqrt(mx * mx + my * my)
        if d < r and (r - d) * (r - d) >= q_conf * lam_max:
            return True
        # the top eigenvector
        if abs(b_) > 0.0:
            vx, vy = lam_max - c_, b_
        elif a_ >= c_:
            vx, vy = 1.0, 0.0
        else:
            vx, vy = 0.0, 1.0
        vn = np.sqrt(vx * vx + vy * vy)
        vx, vy = vx / vn, vy / vn
        if d > 0.0:
            ux, uy = mx / d, my / d
        else:
            ux, uy = vx, vy
        su = np.sqrt(max(ux * ux * a_ + 2.0 * ux * uy * b_ + uy * uy * c_, lam_min))
        slab = _ndtr((r - d) / su) - _ndtr((-r - d) / su)
        mt = vx * mx + vy * my
        st = np.sqrt(lam_max)
        slab = min(slab, _ndtr((r - mt) / st) - _ndtr((-r - mt) / st))
        if slab < conf:
            return False
        l11 = np.sqrt(a_)
        l21 = b_ / l11
        l22 = np.sqrt(max(c_ - l21 * l21, floor))
        N = BASE_DIRECTIONS
        p = _ray_sum(mx, my, l11, l21, l22, r, 0, 1, N) / N
        for level in range(1, MAX_LEVEL + 1):
            new = 0.5 * (p + _ray_sum(mx, my, l11, l21, l22, r, 1, 2, N) / N)
            change = abs(new - p)
            p = new
            N *= 2
            if abs(p - conf) > 4.0 * change:
                break
        return p >= conf

    @step
    def every_particle(X, XH, PX, PY, params, center, r, E, bound, GG, na):
        """The goal gate of a robot that gives none: ``GG[a] = 1`` for every particle (each runs
        :func:`goal_test`, which decides)."""
        for a in range(na):
            GG[a] = 1
