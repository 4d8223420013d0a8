"""The compiled kernel's goal test in a 3-D task space (a URDF arm's tip): the goal region of a goal
ball, tested per particle and step, as :mod:`firmtool.estimation.compiled.goal` does it in 2-D.

:func:`goal_test_3d` asks for the estimate's task point in the ball, then the chance constraint on the
task covariance ``J P J'`` (the robot's compiled ``task_covariance``, six entries) by the exact
bounds of :func:`firmtool.problem.goal.confidence_bounds` (Anderson's theorem and the inner cube
along the eigenvectors accept, the slabs along the mean and along the top eigenvector and the outer
cube reject) and, between them, by the 3-D direction rule
of :func:`firmtool.problem.goal.meets_confidence`: Gauss-Legendre nodes in the polar cosine times
equally spaced azimuths (:func:`firmtool.problem.goal.directions`), refined level by level up to
:data:`~firmtool.problem.goal.MAX_LEVEL_3D` until the gap to the confidence exceeds four times the
change between levels. The direction tables are computed once in Python (:func:`goal_group_3d`) and
read by the kernel.

The 3-D goal group is the 2-D one (:func:`firmtool.estimation.compiled.goal.goal_group`, its
``q_conf`` = chi2_3.ppf(confidence)) followed by ``(directions (Q, 3), weights (Q,), level_start
(levels + 1,))``: level ``l``'s rule is rows ``level_start[l]:level_start[l + 1]``.
"""

from __future__ import annotations

import math

import numpy as np

from firmtool.estimation.compiled.goal import goal_group
from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba
from firmtool.problem.goal import MAX_LEVEL_3D, MIN_STD_FRACTION, chi2_ppf, directions

# The robot's hooks goal_test_3d is compiled against (firmtool.jit.specialise binds them per robot).
task_point = task_covariance = None

_RULES: tuple | None = None


def direction_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(directions (Q, 3), weights (Q,), level_start (levels + 1,))`` of every level of the 3-D rule."""
    global _RULES
    if _RULES is None:
        rules = [directions(3, level) for level in range(MAX_LEVEL_3D + 1)]
        start = np.cumsum([0] + [u.shape[0] for u, _ in rules]).astype(np.int64)
        _RULES = (np.ascontiguousarray(np.concatenate([u for u, _ in rules])),
                  np.ascontiguousarray(np.concatenate([w for _, w in rules])), start)
    return _RULES


def goal_group_3d(regions, P_steps: np.ndarray, k_end: int, d_cfg: int, perfect: bool, goal_node: int) -> tuple:
    """The kernel's 3-D goal group (module notes)."""
    group = goal_group(regions, P_steps, k_end, d_cfg, perfect, goal_node)
    if group[0]:
        group = group[:4] + (float(chi2_ppf(group[3], 3)),) + group[5:]
    return group + direction_tables()


if numba is not None:
    from firmtool.estimation.compiled.goal import _ndtr, all_zero

    njit = cached_njit(**KERNEL_OPTIONS)

    @njit
    def _chi2_3_cdf(t):
        """The chi-square CDF with 3 degrees of freedom (:func:`firmtool.problem.goal._chi2_cdf`)."""
        return math.erf(math.sqrt(0.5 * t)) - math.sqrt(2.0 * t / np.pi) * math.exp(-0.5 * t)

    @njit
    def _ray_rule_3d(m, L, r, U, W, first, last):
        """The direction rule of rows ``first:last`` of ``(U, W)`` (:func:`firmtool.problem.goal._ray_rule`)."""
        c = m[0] * m[0] + m[1] * m[1] + m[2] * m[2] - r * r
        total = 0.0
        for q in range(first, last):
            l0 = L[0, 0] * U[q, 0]
            l1 = L[1, 0] * U[q, 0] + L[1, 1] * U[q, 1]
            l2 = L[2, 0] * U[q, 0] + L[2, 1] * U[q, 1] + L[2, 2] * U[q, 2]
            a = l0 * l0 + l1 * l1 + l2 * l2
            b = l0 * m[0] + l1 * m[1] + l2 * m[2]
            disc = b * b - a * c
            if disc <= 0.0:
                continue
            root = math.sqrt(disc)
            far = (-b + root) / a
            if far <= 0.0:
                continue
            near = max((-b - root) / a, 0.0)
            # near is 0 when the mean lies in the ball (the goal test's case), and chi2's CDF at 0 is 0
            total += (_chi2_3_cdf(far * far) - (_chi2_3_cdf(near * near) if near > 0.0 else 0.0)) * W[q]
        return total

    @njit
    def ball_decision_3d(m, S, r, conf, q_conf, U, W, level_start):
        """Whether N(m (3,), S (3, 3)) puts at least ``conf`` on the ball of radius r about the origin.
        Twin of :func:`firmtool.problem.goal.meets_confidence` (3-D); pinned by
        tests/test_kernels_3d.py::test_compiled_3d_decision_is_the_numpy_one."""
        floor = (MIN_STD_FRACTION * r) ** 2
        sym = 0.5 * (S + S.T)
        lam, V = np.linalg.eigh(sym)
        lam_min, lam_max = max(lam[0], floor), max(lam[2], floor)
        d = math.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])
        if d < r and (r - d) * (r - d) >= q_conf * lam_max:
            return True
        # the cubes along the eigenvectors (confidence_bounds): inside the ball (accept), around it (reject)
        inner, outer = 1.0, 1.0
        h = r / math.sqrt(3.0)
        for i in range(3):
            mu = V[0, i] * m[0] + V[1, i] * m[1] + V[2, i] * m[2]
            sd = math.sqrt(max(lam[i], floor))
            inner *= _ndtr((h - mu) / sd) - _ndtr((-h - mu) / sd)
            outer *= _ndtr((r - mu) / sd) - _ndtr((-r - mu) / sd)
        if d < r and inner >= conf:
            return True
        if d > 0.0:
            u0, u1, u2 = m[0] / d, m[1] / d, m[2] / d
        else:
            u0, u1, u2 = V[0, 2], V[1, 2], V[2, 2]
        quad = 0.0
        for i in range(3):
            ui = u0 if i == 0 else (u1 if i == 1 else u2)
            quad += ui * (S[i, 0] * u0 + S[i, 1] * u1 + S[i, 2] * u2)
        su = math.sqrt(max(quad, lam_min))
        slab = _ndtr((r - d) / su) - _ndtr((-r - d) / su)
        mt = V[0, 2] * m[0] + V[1, 2] * m[1] + V[2, 2] * m[2]
        st = math.sqrt(lam_max)
        slab = min(slab, min(_ndtr((r - mt) / st) - _ndtr((-r - mt) / st), outer))
        if slab < conf:
            return False
        L = np.linalg.cholesky(sym + floor * np.eye(3))
        p = _ray_rule_3d(m, L, r, U, W, level_start[0], level_start[1])
        for level in range(1, level_start.shape[0] - 1):
            new = _ray_rule_3d(m, L, r, U, W, level_start[level], level_start[level + 1])
            change = abs(new - p)
            p = new
            if abs(p - conf) > 4.0 * change:
                break
        return min(max(p, 0.0), 1.0) >= conf

    def goal_test_3d(xh, k, params, goal, work):
        """Whether the belief ``(xh (n,), Pcfg[k + 1])`` of a particle lies in the goal region of the
        3-D goal ball. Twin of :meth:`firmtool.problem.goal.GoalRegion.contains`; pinned by
        tests/test_kernels_3d.py::test_urdf_arm_same_noise_same_outcomes (through the goal landings)."""
        active, center, r, conf, q_conf, Pcfg, goal_node, is_goal, true_scale, U, W, level_start = goal
        tx, ty, tz = task_point(xh, params, work)
        m = np.empty(3)
        m[0], m[1], m[2] = tx - center[0], ty - center[1], tz - center[2]
        if not (m[0] * m[0] + m[1] * m[1] + m[2] * m[2] < r * r):  # a NaN estimate is outside, as in numpy
            return False
        P = Pcfg[k + 1]
        if all_zero(P):  # perfect measurements: the mean alone decides
            return True
        s11, s12, s13, s22, s23, s33 = task_covariance(P, params, work)
        S = np.empty((3, 3))
        S[0, 0], S[0, 1], S[0, 2] = s11, s12, s13
        S[1, 0], S[1, 1], S[1, 2] = s12, s22, s23
        S[2, 0], S[2, 1], S[2, 2] = s13, s23, s33
        return ball_decision_3d(m, S, r, conf, q_conf, U, W, level_start)

    @cached_njit(**KERNEL_OPTIONS, inline="always")
    def true_inside_3d(PX, PY, PZ, tip, a, center, r):
        """Whether particle ``a``'s TRUE task point (key point ``tip``) lies in the goal ball."""
        ex, ey, ez = PX[tip, a] - center[0], PY[tip, a] - center[1], PZ[tip, a] - center[2]
        return ex * ex + ey * ey + ez * ez < r * r
