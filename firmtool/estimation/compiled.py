"""Compiled Monte Carlo engine: the whole edge step in one numba kernel (plain loops, no temporaries).

:func:`simulate` is a drop-in twin of :func:`firmtool.estimation.edges.simulate` for the problems it knows:
a :class:`~firmtool.models.linear.LinearGaussianModel` on a robot whose compiled hook names one of
its two planar kinematics (a point; a chain of links) with the numpy or numba collision geometry. Per step and per live particle it does, in this order, exactly
what the numpy path does:

    control from the estimate -> true-state step with process noise -> kinematics (once) ->
    observation noise with R at the TRUE state -> filter update with the precomputed gain ->
    control effort -> collision test -> goal region of a goal ball (every step) -> node membership
    (from the stabiliser phase on)

Compiled functions
    Each stage is a named compiled function, called by the kernel :func:`run`: :func:`control`,
    :func:`true_step`, :func:`kinematics` (planar point or planar chain), :func:`measurement_variance`
    and :func:`filter_update`, :func:`control_effort`, :func:`collision_gate` then :func:`collides`,
    :func:`locate`. Each one's docstring names the numpy function it reproduces and the test that
    pins the two together. The kernel's arguments come in a few groups (tuples: the particles, the
    noise source, model matrices, controller arrays, node candidates, membership regions, sensor,
    robot, world; listed above the compiled functions). They are cached on disk by
    :func:`firmtool.jit.cached_njit`, whose key also covers the compiled functions of other modules
    they call (the controllers' product, the geometry's distances): an edit of those recompiles the
    kernel instead of loading stale machine code.

Layout
    While the kernel runs, the live particles' states are columns of (state, particle) arrays, so
    that the linear algebra, the kinematics and the collision prefilters are loops over particles
    (SIMD lanes), with the matrices' entries as loop constants; products add their terms in column
    order and skip exact zeros, which per particle is the value of the dense row product. Only the
    decisions (exact collision tests where a prefilter passed, node membership, stopping) run
    particle by particle. The gate that selects particles for the exact collision test evaluates
    the same comparisons as the prefilters inside :func:`collides`, so no collision is missed.

Random numbers
    By default the noise is drawn inside the kernel: xoshiro256++ (Blackman & Vigna) seeded with four
    words of the caller's ``np.random.Generator`` (whose seed comes from the scenario seed and the
    edge, :func:`firmtool.estimation.edges.edge_seed_sequence`), normals by the ziggurat (Marsaglia & Tsang,
    256 layers), ~2.4 ns a normal against ~10 ns for ``Generator.standard_normal``. Results are a
    function of the seed only (not of workers or executor); the numpy path draws other numbers,
    so the two engines agree in distribution (tests: the normal law of the draws, probabilities
    within confidence intervals). With ``numpy_noise=True`` the kernel instead consumes
    ``rng.standard_normal`` in the numpy path's order (per step ``(alive, r + nz)`` row-major, the
    live particles in their original order), drawn a few steps ahead; both engines then simulate
    the same particles, and their outcomes agree particle by particle (up to summation order, which
    can flip a decision only on a knife edge): the tests' check of the kernel's arithmetic.

Node membership
    :meth:`firmtool.roadmap.nodes.NodeRegions.locate` is reproduced exactly without its k-d tree: the nodes
    whose covariance test passes at the step (few, and sorted once per edge by their first
    coordinate) are scanned inside a window of that coordinate outside of which the exact test
    cannot pass; the nearest passing node in the outer metric is kept only if fewer than ``k = 8``
    nodes (all nodes, as in the tree query) are nearer in that metric.

Goal region
    A task's goal ball (:mod:`firmtool.problem.goal`) is tested per particle and step by :func:`goal_test`:
    the estimate's task point (a point robot's position, a chain's tip) in the ball, then the
    chance constraint on the task covariance ``J P J'`` by the same exact bounds and the same
    direction rule as :func:`firmtool.problem.goal.meets_confidence` (:func:`ball_decision`); a landing whose
    TRUE task point lies outside the ball ends with ``GOAL_MISS``. For a chain a cheap necessary
    condition comes first: the estimate's tip is within ``sum_l l_l |e_l|`` of the true tip (``e_l``
    the error of link l's absolute angle), so particles whose true tip is farther than that from the
    ball skip the estimate's kinematics.

Selection: :func:`firmtool.estimation.edges.simulate` dispatches here when :func:`engine_for` says so: the
environment variable ``FIRMTOOL_ENGINE=numpy`` forces the numpy path; unset, ``auto`` or ``numba``
use this kernel whenever numba is importable and the kernel computes exactly the problem's Monte
Carlo (:func:`supports`: the robot's compiled hook, a linear model, a compiled noise form, planar
box geometry of numpy/numba, no user's validity checker), and the numpy path otherwise, with a
one-line notice saying why (:func:`engine_choice`).
"""

from __future__ import annotations

import math
import os

import numpy as np

from firmtool.errors import InputError
from firmtool.estimation.outcomes import FAILURE, GOAL_MISS, TIMEOUT, ParticleOutcomes, cost_terms
from firmtool.models.linear import LinearGaussianModel

try:  # numba is a dependency, but keep the numpy path usable without it
    import numba
except ImportError:  # pragma: no cover
    numba = None

ROBOT_POINT, ROBOT_ARM = 0, 1
KINEMATICS = {"planar_point": ROBOT_POINT, "planar_chain": ROBOT_ARM}  # robots' compiled hooks
NOISE_FORMS = {"lightdark_std": 0, "lightdark_variance": 1, "constant": 2}
COMPILED_BACKENDS = ("numpy", "numba")  # the collision geometry the kernel reproduces exactly
# Steps are run in segments; per segment the local controller's filter recursion is run as far as
# the segment's end (lazily: particles mostly stop within a few steps of the edge's end, long before
# the controller's ~edge + 200 steps) and the node candidates of its steps are computed at once.
FIRST_SEGMENT_PAST_EDGE = 8  # the first segment: the edge and this many stabiliser steps
SEGMENT_STEPS = (16, 32, 64)  # the following segments (the last length repeats)
CALL_PARTICLE_STEPS = 1024  # particle-steps of noise drawn per kernel call
LOCATE_K = 8  # neighbours the k-d tree query of NodeRegions.locate considers

ENGINE_ENV = "FIRMTOOL_ENGINE"


# ---------------------------------------------------------------------------------------------
# selection


def supports(problem) -> str | None:
    """None if the compiled engine computes exactly ``problem``'s Monte Carlo, else why it cannot.

    The robot says whether its kinematics are one of the kernel's kinds (its compiled hook,
    :meth:`firmtool.robots.Robot.compiled_kinematics`); the kernel also needs a linear model, a
    noise form with a compiled twin, the problem's validity to be exactly the scenario's planar
    geometry (numpy/numba backend, boxes, the robot's own test, no user's checker), and a goal ball's
    task point to be the kinematics' last key point."""
    if numba is None:
        return "numba is not installed"
    if len(problem.scenario.world.lo) != 2:
        return f"the compiled engine is planar, this world is {len(problem.scenario.world.lo)}-D"
    robot = problem.robot
    if robot is None or robot.compiled_kinematics() is None:
        return f"robot {problem.scenario.model.robot!r} has no compiled kinematics"
    if type(problem.model) is not LinearGaussianModel:
        return f"model {type(problem.model).__name__} is not a LinearGaussianModel"
    if problem.validity is not None:
        return "the problem has a Python validity checker, which the compiled engine does not compute"
    if not (problem.points_valid == robot.points_valid and problem.points == robot.points
            and problem.sensing_from_points == robot.sensing_from_points):
        return "the problem's key points, sensing or validity are not its robot's own"
    w = problem.scenario.world
    if w.collision_backend not in COMPILED_BACKENDS:
        return f"collision backend {w.collision_backend!r} is not compiled (numpy/numba geometry only)"
    if len(w.lo) != 2 or any(o.kind != "box" for o in w.obstacles):
        return "the compiled engine's geometry is planar boxes only"
    if problem.goal_region is not None:
        from firmtool.robots.arm import ArmRobot
        from firmtool.robots.base import Robot
        from firmtool.robots.point import PointRobot

        if type(robot).task_point is not Robot.task_point or \
                type(robot).task_jacobian not in (Robot.task_jacobian, PointRobot.task_jacobian, ArmRobot.task_jacobian):
            return "the robot's task point is its own, which the compiled goal test does not compute"
    noise = problem.model.noise
    if getattr(noise, "compiled", None) not in NOISE_FORMS:
        return f"measurement noise {getattr(noise, 'form', type(noise).__name__)!r} is not compiled"
    return None


def engine_choice(problem) -> tuple[str, str | None]:
    """``("numba" | "numpy", notice)`` for this problem, honouring ``FIRMTOOL_ENGINE``.

    The compiled engine runs only where it computes exactly the problem's Monte Carlo
    (:func:`supports`); where it was asked for (``auto`` with numba installed, or ``numba``) but
    cannot, the numpy engine runs and ``notice`` says why, in one line (else None)."""
    choice = os.environ.get(ENGINE_ENV, "auto").strip().lower() or "auto"
    if choice not in ("auto", "numpy", "numba"):
        raise InputError(f"{ENGINE_ENV}: expected 'auto', 'numpy' or 'numba' but found {choice!r}")
    if choice == "numpy":
        return "numpy", None
    reason = supports(problem)
    if reason is None:
        return "numba", None
    asked = f"{ENGINE_ENV}=numba" if choice == "numba" else "the compiled Monte Carlo engine"
    return "numpy", f"numpy Monte Carlo engine: {asked} cannot run this problem ({reason})"


def engine_for(problem) -> str:
    """``"numba"`` or ``"numpy"`` for this problem (:func:`engine_choice` without its notice)."""
    return engine_choice(problem)[0]


# ---------------------------------------------------------------------------------------------
# data preparation (Python, once per problem / once per edge)


class _ProblemData:
    """Per-problem constant arrays for the kernel."""

    def __init__(self, problem) -> None:
        sc, model = problem.scenario, problem.model
        self.mats = tuple(np.ascontiguousarray(M, dtype=float) for M in (model.A, model.B, model.F, model.H))
        self.r, self.nz = model.F.shape[1], model.nz
        nm = model.noise
        p = nm.compiled_params()
        self.noise = (NOISE_FORMS[nm.compiled], *(float(p.get(k, 0.0)) for k in ("light_x", "eta", "sigma_b", "a", "c",
                                                                              "std")))
        w = sc.world
        hook = problem.robot.compiled_kinematics()
        self.robot = KINEMATICS[hook.kind]
        self.lengths = np.asarray(hook.link_lengths, dtype=float).reshape(-1)
        self.self_collision = bool(hook.self_collision)
        C = np.array([o.center for o in w.obstacles], dtype=float).reshape(-1, 2)
        Hs = np.array([o.half_size for o in w.obstacles], dtype=float).reshape(-1, 2)
        ang = np.array([getattr(o, "angle", 0.0) for o in w.obstacles], dtype=float)
        cs, sn = np.cos(ang), np.sin(ang)
        ext = np.abs(cs)[:, None] * Hs + np.abs(sn)[:, None] * Hs[:, ::-1]
        rotated = ang != 0.0
        self.world = (np.array(w.lo, float), np.array(w.hi, float), C, Hs, np.where(rotated, cs, 1.0),
                      np.where(rotated, sn, 0.0), C - ext, C + ext, float(w.robot_radius))


_problem_cache: dict[int, tuple[object, _ProblemData]] = {}


def _problem_data(problem) -> _ProblemData:
    hit = _problem_cache.get(id(problem))
    if hit is not None and hit[0] is problem:
        return hit[1]
    data = _ProblemData(problem)
    if len(_problem_cache) > 8:
        _problem_cache.clear()
    _problem_cache[id(problem)] = (problem, data)
    return data


_order_cache: dict[int, tuple[object, np.ndarray]] = {}


def _first_coordinate_order(regions) -> np.ndarray:
    """The nodes sorted by their centre's first coordinate (stable), once per regions object."""
    hit = _order_cache.get(id(regions))
    if hit is not None and hit[0] is regions:
        return hit[1]
    order = np.argsort(regions.centers[:, 0], kind="stable")
    if len(_order_cache) > 8:
        _order_cache.clear()
    _order_cache[id(regions)] = (regions, order)
    return order


_locate_cache: dict[int, tuple[object, tuple]] = {}


def _locate_data(regions) -> tuple:
    """The membership test's constant arguments for ``regions`` (once per regions object): centres,
    scales, 1 / outer spread, radius squared, the window of the first coordinate outside which the
    exact test cannot pass, and the k of the tree query."""
    hit = _locate_cache.get(id(regions))
    if hit is not None and hit[0] is regions:
        return hit[1]
    outer = np.asarray(regions._outer, dtype=float)
    radius, n = float(regions.radius), regions.centers.shape[1]
    # the exact test needs |xhat_0 - c_0| < radius sqrt(n) scale_c0 <= radius sqrt(n) outer_0
    window = radius * np.sqrt(n) * float(outer[0]) * (1.0 + 1e-9)
    data = (np.ascontiguousarray(regions.centers, dtype=float), np.ascontiguousarray(regions.scale, dtype=float),
            1.0 / outer, radius * radius, window, min(LOCATE_K, regions.count))
    if len(_locate_cache) > 8:
        _locate_cache.clear()
    _locate_cache[id(regions)] = (regions, data)
    return data


def locate_one(regions, xhat: np.ndarray, candidates: np.ndarray) -> int:
    """:meth:`NodeRegions.locate` for one estimate ``xhat`` (n,) through the kernel's membership test
    (the same decision without a tree query: ~5 us a call instead of ~30), or -1."""
    order = _first_coordinate_order(regions)
    idx = order[candidates[order]]
    data = _locate_data(regions)
    return int(locate(np.ascontiguousarray(xhat, dtype=float), 0, idx.size, idx, np.ascontiguousarray(data[0][idx, 0]),
                      data))


_NO_GOAL_CENTER = np.zeros(2)
_NO_GOAL_P = np.zeros((1, 1, 1))


_node_goal_cache: dict[int, tuple[object, tuple]] = {}


def _node_goal_data(regions) -> tuple:
    """``(is_goal (N,) bool, true_scale (N, n))`` of ``regions`` (once per regions object)."""
    hit = _node_goal_cache.get(id(regions))
    if hit is not None and hit[0] is regions:
        return hit[1]
    N = regions.count
    is_goal = np.zeros(N, dtype=np.bool_) if regions.goal_nodes is None else np.asarray(regions.goal_nodes, dtype=np.bool_)
    scale = regions.true_scale if regions.true_scale is not None else regions.scale
    data = (np.ascontiguousarray(is_goal), np.ascontiguousarray(scale, dtype=float))
    if len(_node_goal_cache) > 8:
        _node_goal_cache.clear()
    _node_goal_cache[id(regions)] = (regions, data)
    return data


def _goal_group(regions, P_steps: np.ndarray, k_end: int, d_cfg: int, perfect: bool, goal_node: int) -> tuple:
    """The kernel's goal group for steps up to ``k_end`` (module notes): the ball inactive without one."""
    is_goal, true_scale = _node_goal_data(regions)
    goal_region = regions.goal
    if goal_region is None:
        return (False, _NO_GOAL_CENTER, 1.0, 0.5, 1.0, _NO_GOAL_P, -1, is_goal, true_scale)
    Pcfg = (np.zeros((k_end + 1, d_cfg, d_cfg)) if perfect
            else np.ascontiguousarray(P_steps[:k_end + 1, :d_cfg, :d_cfg], dtype=float))
    conf = float(goal_region.confidence)
    return (True, np.ascontiguousarray(goal_region.center, dtype=float), float(goal_region.radius), conf,
            -2.0 * math.log1p(-conf), Pcfg, int(goal_node), is_goal, true_scale)  # chi2_2.ppf(conf)


def _robot_group(pd: _ProblemData) -> tuple:
    """The kernel's robot group ``(kind, lengths, sensing, self_collision)``: measurement j of a chain
    senses at the end of link j (key point j + 1), every measurement of a point robot at its point."""
    if pd.robot == PLANAR_CHAIN:
        sensing = np.arange(1, pd.nz + 1, dtype=np.int64)
    else:
        sensing = np.zeros(pd.nz, dtype=np.int64)
    return pd.robot, pd.lengths, sensing, pd.self_collision


def _candidate_lists(regions, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per step, the candidate nodes sorted by their centre's first coordinate (CSR: ptr (T+1,), idx, key)."""
    order = _first_coordinate_order(regions)
    sorted_cand = cand[:, order]
    counts = sorted_cand.sum(axis=1)
    ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    t, j = np.nonzero(sorted_cand)
    idx = order[j].astype(np.int64)
    return ptr, idx, np.ascontiguousarray(regions.centers[idx, 0])


# ---------------------------------------------------------------------------------------------
# the kernel

def _ziggurat_tables(layers: int = 256, r: float = 3.6541528853610088, v: float = 0.00492867323399):
    """Layer tables of the normal ziggurat (Marsaglia & Tsang 2000, Sec. 3's recipe, 52-bit abscissae):
    ``K[i]`` the integer bound below which a draw in layer i is accepted at once, ``W[i]`` the scale
    from integer to abscissa, ``F[i]`` the density at the layer's edge. ``r`` is the base layer's
    right edge and ``v`` every layer's area for 256 layers."""
    m = 2.0 ** 52
    K, W, F = np.zeros(layers, dtype=np.uint64), np.zeros(layers), np.zeros(layers)
    dn = tn = r
    q = v / np.exp(-0.5 * dn * dn)
    K[0], K[1] = np.uint64(dn / q * m), np.uint64(0)
    W[0], W[-1] = q / m, dn / m
    F[0], F[-1] = 1.0, np.exp(-0.5 * dn * dn)
    for i in range(layers - 2, 0, -1):
        dn = np.sqrt(-2.0 * np.log(v / dn + np.exp(-0.5 * dn * dn)))
        K[i + 1] = np.uint64(dn / tn * m)
        tn = dn
        F[i], W[i] = np.exp(-0.5 * dn * dn), dn / m
    return K, W, F


ZIG_K, ZIG_W, ZIG_F = _ziggurat_tables()
ZIG_R = 3.6541528853610088
ZIG_INV_R = 1.0 / ZIG_R

_kernel = None
PLANAR_POINT, PLANAR_CHAIN = ROBOT_POINT, ROBOT_ARM  # the kernel's two kinematics kinds


# Module-level functions (not closures): numba keys its on-disk cache of a closure by its cells,
# and a cell holding another dispatcher pickles with a per-process uuid, so every process recompiled.
# The kernel calls compiled functions of other modules (the controllers' skip-zero product, the
# geometry's distances): firmtool.jit's cache key covers their source files, so an edit of them is
# compiled, not loaded stale from the cache.
#
# The kernel's arguments come in groups (plain tuples: numba dispatches them faster than named ones),
# each unpacked by the names below where it is used:
#   ensemble   (alive, x, xhat, outcome, steps, effort): the particles, updated in place
#   draws      (noise, rng_state): numpy's stream (empty: draw here) and the xoshiro256++ state
#   model      (A, B, F, H): the linear Gaussian model's matrices
#   controller (x_ref, u_ref, K, L): the local controller's reference, LQR and Kalman gains per step
#   candidates (cand_ptr, cand_idx, cand_key): per step, the nodes whose covariance test passes (CSR)
#   regions    (centers, scale, inv_outer, radius2, window, knn): the membership test (_locate_data)
#   sensor     (form, light_x, eta, sigma_b, a, c, std): the measurement noise (NOISE_FORMS)
#   robot      (kind, lengths, sensing, self_collision): kinematics kind and constants; ``sensing[j]``
#              the key point whose x sets measurement j's noise
#   world      (lo, hi, C, Hs, cs, sn, blo, bhi, radius): bounds, boxes (centre, half size, rotation,
#              bounding box) and the robot's capsule radius
#   goal       (active, center, radius, confidence, q_conf, Pcfg, goal_node, is_goal, true_scale): the goal
#              ball (active False: none), chi2_2.ppf(confidence), the configuration block of the filter
#              covariance per step (Pcfg[k + 1] after step k's update; zeros with perfect measurements),
#              the landing's code; the goal nodes (N,) and the true state's spread at each node (N, n)
#              (a goal state's landing is judged on the true state: NodeRegions.true_arrival)
if numba is not None:
    from firmtool.control.linalg import mat_rows
    from firmtool.geometry._numba import seg_box_d2, seg_seg_d2
    from firmtool.jit import cached_njit
    from firmtool.problem.goal import BASE_DIRECTIONS, MAX_LEVEL, MIN_STD_FRACTION

    njit = cached_njit(nogil=True, fastmath=False, error_model="numpy")
    # The step's helpers are inlined into the kernel at numba's IR level: compiled separately (and
    # then inlined by LLVM), they ran at the same speed but made the kernel's cold compile ~15% longer
    # (each separately compiled function costs its own typing and optimisation passes). Called from
    # Python (the tests) they compile as usual.
    step = cached_njit(nogil=True, fastmath=False, error_model="numpy", inline="always")

    # -- arithmetic primitives ---------------------------------------------------------------------

    @njit
    def sincos(a):
        """(sin a, cos a): Cody-Waite reduction by pi/2 and fdlibm's minimax polynomials on
        [-pi/4, pi/4] (within an ulp or two of libm; branch-free but for the quadrant select).
        Twin of ``np.sin``, ``np.cos``; pinned by tests/test_kernels.py::test_kinematics_are_the_robots_points."""
        q = np.floor(a * 0.6366197723675814 + 0.5)
        y = (a - q * 1.57079632673412561417e+00) - q * 6.07710050650619224932e-11
        z = y * y
        sp = y + y * z * (-1.66666666666666324348e-01 + z * (8.33333333332248946124e-03 + z * (
            -1.98412698298579493134e-04 + z * (2.75573137070700676789e-06 + z * (
                -2.50507602534068634195e-08 + z * 1.58969099521155010221e-10)))))
        cp = 1.0 - 0.5 * z + z * z * (4.16666666666666019037e-02 + z * (-1.38888888888741095749e-03 + z * (
            2.48015872894767294178e-05 + z * (-2.75573143513906633035e-07 + z * (
                2.08757232129817482790e-09 + z * -1.13596475577881948265e-11)))))
        k = int(q) & 3
        if k == 0:
            return sp, cp
        if k == 1:
            return cp, -sp
        if k == 2:
            return -sp, -cp
        return -cp, sp

    @step
    def linear_step(A, B, X, U, out, TMP, na):
        """``out = A X + B U`` over the first ``na`` particle columns (``TMP``: work array): the
        noise-free dynamics. Twin of :meth:`firmtool.models.linear.LinearGaussianModel.f`; pinned by
        tests/test_kernels.py::test_control_and_true_step_are_the_numpy_step."""
        n = A.shape[0]
        mat_rows(A, X, out, n, na)
        mat_rows(B, U, TMP, n, na)
        for j in range(n):
            for a in range(na):
                out[j, a] += TMP[j, a]

    # -- the particles as columns ------------------------------------------------------------------

    @step
    def gather_columns(rows, alive, cols, na):
        """``cols[:, a] = rows[alive[a]]`` for ``a < na``: particles (rows) to the kernel's columns."""
        for a in range(na):
            i = alive[a]
            for j in range(rows.shape[1]):
                cols[j, a] = rows[i, j]

    @step
    def scatter_columns(cols, alive, rows, na):
        """``rows[alive[a]] = cols[:, a]`` for ``a < na``: back to the caller's (particle, state) rows."""
        for a in range(na):
            i = alive[a]
            for j in range(rows.shape[1]):
                rows[i, j] = cols[j, a]

    @step
    def take_noise(noise, pos, W, d, na):
        """``W[:d, :na]`` from numpy's stream at ``pos`` (``(particle, d)`` row-major, as the numpy path
        draws a step's noise); returns the new position."""
        for a in range(na):
            for j in range(d):
                W[j, a] = noise[pos + a * d + j]
        return pos + na * d

    @step
    def draw_noise(rng_state, W, d, na):
        """``W[:d, :na]`` standard normals drawn here, row by row (:func:`fill_normals`)."""
        for j in range(d):
            fill_normals(rng_state, W[j], na)

    # -- one step of the local controller, all particles ----------------------------------------

    @step
    def control(XH, x_ref_k, u_ref_k, K_k, DX, U, na):
        """``U = u_ref - K (XH - x_ref)``: the step's controls from the estimates (``DX``: work array).
        Twin of the control line of :func:`firmtool.estimation.edges.control_and_move`; pinned by
        tests/test_kernels.py::test_control_and_true_step_are_the_numpy_step."""
        n, m = XH.shape[0], U.shape[0]
        for j in range(n):
            xr = x_ref_k[j]
            for a in range(na):
                DX[j, a] = XH[j, a] - xr
        mat_rows(K_k, DX, U, m, na)
        for j in range(m):
            ur = u_ref_k[j]
            for a in range(na):
                U[j, a] = ur - U[j, a]

    @step
    def true_step(A, B, F, X, U, W, XN, TMP, na):
        """``XN = (A X + B U) + F W[:r]``: the true states' step with process noise (``W``'s first ``r =
        F.shape[1]`` rows). Twin of :func:`firmtool.estimation.edges.control_and_move`'s ``model.f(x, u) + w F'``;
        pinned by tests/test_kernels.py::test_control_and_true_step_are_the_numpy_step."""
        n = A.shape[0]
        linear_step(A, B, X, U, XN, TMP, na)
        mat_rows(F, W, TMP, n, na)
        for j in range(n):
            for a in range(na):
                XN[j, a] += TMP[j, a]

    @step
    def planar_point_kinematics(X, PX, PY, na):
        """The key point of a planar point robot: its first two state coordinates. Twin of the point
        robot's ``Problem.points`` (:mod:`firmtool.problem`); pinned by
        tests/test_kernels.py::test_kinematics_are_the_robots_points."""
        for a in range(na):
            PX[0, a] = X[0, a]
            PY[0, a] = X[1, a]

    @step
    def planar_chain_kinematics(X, lengths, PX, PY, PHI, na):
        """The base (at the origin), the joints and the tip of a planar chain whose first ``L`` state
        coordinates are the relative joint angles (``PHI``: work array, the absolute angles). Twin of
        :func:`firmtool.models.planar_arm.chain_points`; pinned by
        tests/test_kernels.py::test_kinematics_are_the_robots_points."""
        for a in range(na):
            PHI[a] = 0.0
            PX[0, a] = 0.0
            PY[0, a] = 0.0
        for l in range(lengths.shape[0]):
            ll = lengths[l]
            for a in range(na):
                PHI[a] += X[l, a]
                s_phi, c_phi = sincos(PHI[a])
                PX[l + 1, a] = PX[l, a] + ll * c_phi
                PY[l + 1, a] = PY[l, a] + ll * s_phi

    @step
    def kinematics(robot, X, PX, PY, PHI, na):
        """The robot's key points ``(PX, PY)`` (points, particles) from the true states: once per step,
        for both the sensor noise and the collision test."""
        kind, lengths, sensing, self_collision = robot
        if kind == PLANAR_CHAIN:
            planar_chain_kinematics(X, lengths, PX, PY, PHI, na)
        else:
            planar_point_kinematics(X, PX, PY, na)

    @step
    def measurement_variance(sensor, sensing_x):
        """The measurement noise variance for a sensing point at x-coordinate ``sensing_x``, per form:
        light-dark standard deviation (paper eq. 14), light-dark variance (Platt et al.), constant.
        Twin of :meth:`firmtool.models.linear.LightDarkNoise.variance`; pinned by
        tests/test_kernels.py::test_measurement_variance_is_the_noise_models."""
        form, light_x, eta, sigma_b, na_, nc, nstd = sensor
        dd = sensing_x - light_x
        if form == 0:
            s_ = eta * abs(dd) + sigma_b
            return s_ * s_
        if form == 1:
            return na_ * dd * dd + nc
        return nstd * nstd

    @step
    def filter_update(A, B, H, L_k, X, XH, U, W, PX, sensor, sensing, PRED, HZ, INN, TMP, na):
        """The estimates' update in place: prediction ``A XH + B U``, measurement of the true states
        ``H X`` with noise ``W[r:]`` scaled by the standard deviation at the TRUE state (its sensing
        points' x in ``PX[sensing]``), innovation against ``H`` of the prediction, correction by the
        precomputed gain ``L_k``. Twin of :func:`firmtool.estimation.edges.filter_update` (the variance as
        ``model.noise.variance(problem.sensing_from_points(points))``); pinned by
        tests/test_kernels.py::test_filter_update_is_the_numpy_update."""
        n, nz, r = A.shape[0], H.shape[0], W.shape[0] - H.shape[0]
        linear_step(A, B, XH, U, PRED, TMP, na)
        mat_rows(H, X, HZ, nz, na)
        mat_rows(H, PRED, INN, nz, na)
        for j in range(nz):
            prow = PX[sensing[j]]
            for a in range(na):
                var = measurement_variance(sensor, prow[a])
                INN[j, a] = (HZ[j, a] + np.sqrt(var) * W[r + j, a]) - INN[j, a]
        mat_rows(L_k, INN, TMP, n, na)
        for j in range(n):
            for a in range(na):
                XH[j, a] = PRED[j, a] + TMP[j, a]

    @step
    def control_effort(U, E, na):
        """``E[a] = |U[:, a]|^2``: the step's control effort per particle. Twin of
        :func:`firmtool.estimation.edges.simulate`'s ``einsum("ij,ij->i", u, u)``; pinned by the cost terms of
        tests/test_kernels.py::test_point_robot_same_noise_same_outcomes."""
        for a in range(na):
            E[a] = 0.0
        for j in range(U.shape[0]):
            for a in range(na):
                E[a] += U[j, a] * U[j, a]

    # -- constraints: the collision test ---------------------------------------------------------

    @njit
    def collides(px, py, n_seg, seg_offset, world, self_collision, half):
        """Capsules [p[l], p[l + seg_offset]] for l < n_seg (seg_offset 0: discs at the points);
        ``half[l]`` bounds half the length of segment l (for the self-collision prefilter). Twin of
        the numpy backend's ``capsules_collide`` (:mod:`firmtool.geometry.backends`, as
        ``Problem.points_valid`` calls it); pinned by
        tests/test_kernels.py::test_collision_test_is_the_numpy_backends."""
        lo, hi, C, Hs, cs, sn, blo, bhi, r = world
        r2, lim = r * r, 4.0 * r * r
        for l in range(n_seg):
            ax, ay, bx, by = px[l], py[l], px[l + seg_offset], py[l + seg_offset]
            for c in range(2):
                lr, hr = lo[c] + r, hi[c] - r
                if c == 0:
                    a_, b_ = ax, bx
                else:
                    a_, b_ = ay, by
                if not (a_ >= lr and a_ <= hr and b_ >= lr and b_ <= hr):
                    return True
        for l in range(n_seg):
            ax, ay, bx, by = px[l], py[l], px[l + seg_offset], py[l + seg_offset]
            lox, hix = min(ax, bx) - r, max(ax, bx) + r
            loy, hiy = min(ay, by) - r, max(ay, by) + r
            for k in range(C.shape[0]):
                if lox > bhi[k, 0] or hix < blo[k, 0] or loy > bhi[k, 1] or hiy < blo[k, 1]:
                    continue
                qax, qay = ax - C[k, 0], ay - C[k, 1]
                qbx, qby = bx - C[k, 0], by - C[k, 1]
                c_, s_ = cs[k], sn[k]
                if s_ != 0.0 or c_ != 1.0:
                    qax, qay = c_ * qax + s_ * qay, -s_ * qax + c_ * qay
                    qbx, qby = c_ * qbx + s_ * qby, -s_ * qbx + c_ * qby
                if seg_box_d2(qax, qay, qbx, qby, Hs[k, 0], Hs[k, 1]) < r2:
                    return True
        if self_collision:
            tr = 2.0 * r
            for a in range(n_seg):
                a0x, a0y, a1x, a1y = px[a], py[a], px[a + seg_offset], py[a + seg_offset]
                alox, ahix = min(a0x, a1x), max(a0x, a1x)
                aloy, ahiy = min(a0y, a1y), max(a0y, a1y)
                for b in range(a + 2, n_seg):
                    b0x, b0y, b1x, b1y = px[b], py[b], px[b + seg_offset], py[b + seg_offset]
                    # AABB prefilter (the numpy backend's): farther than 2r apart on an axis cannot hit
                    if not (alox - tr <= max(b0x, b1x) and ahix + tr >= min(b0x, b1x)
                            and aloy - tr <= max(b0y, b1y) and ahiy + tr >= min(b0y, b1y)):
                        continue
                    # bounding circles about the midpoints: farther apart than the half lengths + 2r
                    ex = 0.5 * (a0x + a1x - b0x - b1x)
                    ey = 0.5 * (a0y + a1y - b0y - b1y)
                    reach = half[a] + half[b] + tr
                    if ex * ex + ey * ey > reach * reach * (1.0 + 1e-9):
                        continue
                    if seg_seg_d2(a0x, a0y, a1x, a1y, b0x, b0y, b1x, b1y) < lim:
                        return True
        return False

    @njit
    def collision_gate(PX, PY, na, n_seg, seg_offset, world, self_collision, half, G):
        """``G[a] = 1`` where :func:`collides` could return True for particle a: a point outside the
        world's bounds, or any prefilter of an obstacle or self pair passing (the same comparisons, on
        all particles at once so that they vectorise); elsewhere ``collides`` returns False. Pinned
        with it by tests/test_kernels.py::test_collision_test_is_the_numpy_backends."""
        lo, hi, C, Hs, cs, sn, blo, bhi, r = world
        for a in range(na):
            G[a] = 0
        for c in range(2):
            lr, hr = lo[c] + r, hi[c] - r
            P = PX if c == 0 else PY
            for p in range(n_seg + seg_offset):
                row = P[p]
                for a in range(na):
                    v = row[a]
                    G[a] |= not (v >= lr and v <= hr)
        for l in range(n_seg):
            ax_, ay_, bx_, by_ = PX[l], PY[l], PX[l + seg_offset], PY[l + seg_offset]
            for k in range(blo.shape[0]):
                b0x, b1x, b0y, b1y = blo[k, 0], bhi[k, 0], blo[k, 1], bhi[k, 1]
                for a in range(na):
                    lox, hix = min(ax_[a], bx_[a]) - r, max(ax_[a], bx_[a]) + r
                    loy, hiy = min(ay_[a], by_[a]) - r, max(ay_[a], by_[a]) + r
                    G[a] |= not (lox > b1x or hix < b0x or loy > b1y or hiy < b0y)
        if self_collision:
            tr = 2.0 * r
            for i in range(n_seg):
                a0x, a0y, a1x, a1y = PX[i], PY[i], PX[i + seg_offset], PY[i + seg_offset]
                for j in range(i + 2, n_seg):
                    b0x, b0y, b1x, b1y = PX[j], PY[j], PX[j + seg_offset], PY[j + seg_offset]
                    reach = half[i] + half[j] + tr
                    reach2 = reach * reach * (1.0 + 1e-9)
                    for a in range(na):
                        near = (min(a0x[a], a1x[a]) - tr <= max(b0x[a], b1x[a])
                                and max(a0x[a], a1x[a]) + tr >= min(b0x[a], b1x[a])
                                and min(a0y[a], a1y[a]) - tr <= max(b0y[a], b1y[a])
                                and max(a0y[a], a1y[a]) + tr >= min(b0y[a], b1y[a]))
                        ex = 0.5 * (a0x[a] + a1x[a] - b0x[a] - b1x[a])
                        ey = 0.5 * (a0y[a] + a1y[a] - b0y[a] - b1y[a])
                        G[a] |= near and not (ex * ex + ey * ey > reach2)

    @step
    def robot_segments(robot):
        """``(n_seg, seg_offset)`` of the robot's capsules over its key points: a chain's links
        (point l to l + 1), or a point robot's disc (its one point)."""
        if robot[0] == PLANAR_CHAIN:
            return robot[1].shape[0], 1
        return 1, 0

    # -- node membership -------------------------------------------------------------------------

    @njit
    def locate(xh, lo_ptr, hi_ptr, cand_idx, cand_key, regions):
        """The node estimate ``xh`` (n,) lands in among the candidates ``cand_idx[lo_ptr:hi_ptr]``
        (sorted by ``cand_key``, their centres' first coordinate): the nearest (outer metric) passing
        candidate among the ``knn`` nearest nodes, or -1. Twin of
        :meth:`firmtool.roadmap.nodes.NodeRegions.locate` (without its k-d tree); pinned by
        tests/test_execute.py::test_executor_membership_is_the_node_regions_one (through
        :func:`locate_one`) and the whole-step tests of tests/test_kernels.py."""
        centers, scale, inv_outer, radius2, window, knn = regions
        n = xh.shape[0]
        x0 = xh[0]
        # first candidate whose key >= x0 - window (binary search)
        a, b = lo_ptr, hi_ptr
        lo_key = x0 - window
        while a < b:
            mid = (a + b) // 2
            if cand_key[mid] < lo_key:
                a = mid + 1
            else:
                b = mid
        hi_key = x0 + window
        limit = radius2 * n
        best, best_d = -1, np.inf
        for q in range(a, hi_ptr):
            if cand_key[q] > hi_key:
                break
            c = cand_idx[q]
            s = 0.0
            for i in range(n):
                z = (xh[i] - centers[c, i]) / scale[c, i]
                s += z * z
                if s >= limit:
                    break
            if s / n < radius2:
                d = 0.0
                for i in range(n):
                    e = xh[i] * inv_outer[i] - centers[c, i] * inv_outer[i]
                    d += e * e
                if d < best_d:
                    best, best_d = c, d
        if best < 0:
            return -1
        nearer = 0
        for j in range(centers.shape[0]):
            d = 0.0
            for i in range(n):
                e = xh[i] * inv_outer[i] - centers[j, i] * inv_outer[i]
                d += e * e
                if d >= best_d:
                    break
            if d < best_d:
                nearer += 1
                if nearer >= knn:
                    return -1
        return best

    # -- the goal region of a goal ball --------------------------------------------------------------

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
    def goal_gate(X, XH, PX, PY, tip, kind, lengths, goal, E, bound, GG, na):
        """``GG[a] = 1`` where :func:`goal_test` could pass for particle a (all particles at once, so
        that it vectorises): a point robot's estimate in the ball; a chain's true tip within the ball
        grown by ``sum_l l_l |e_l|`` (``e_l`` the estimate's error of link l's absolute angle). Elsewhere
        ``goal_test`` returns False (``E``, ``bound``: work arrays)."""
        center, r = goal[1], goal[2]
        cx, cy = center[0], center[1]
        if kind == PLANAR_CHAIN:
            for a in range(na):
                E[a] = 0.0
                bound[a] = 0.0
            for l in range(lengths.shape[0]):
                ll = lengths[l]
                for a in range(na):
                    E[a] += XH[l, a] - X[l, a]
                    bound[a] += ll * abs(E[a])
            for a in range(na):
                ex, ey = PX[tip, a] - cx, PY[tip, a] - cy
                reach = r + bound[a]
                GG[a] = ex * ex + ey * ey < reach * reach
        else:
            r2 = r * r
            for a in range(na):
                ex, ey = XH[0, a] - cx, XH[1, a] - cy
                GG[a] = ex * ex + ey * ey < r2

    @njit
    def goal_test(xh, k, kind, lengths, goal, cs):
        """Whether the belief ``(xh (n,), Pcfg[k + 1])`` of a particle lies in the goal region of the goal
        ball (mean's task point in the ball, chance constraint met); ``cs`` (2, L) a work array (a
        chain's cos and sin of the absolute link angles, shared by the tip and its Jacobian). Called
        where :func:`goal_gate` passed. Twin of :meth:`firmtool.problem.goal.GoalRegion.contains`; pinned by
        tests/test_goal.py::test_kernel_goal_landing_is_the_numpy_one."""
        active, center, r, conf, q_conf, Pcfg, goal_node, is_goal, true_scale = goal
        cx, cy = center[0], center[1]
        if kind == PLANAR_CHAIN:
            L = lengths.shape[0]
            tx, ty, phi = 0.0, 0.0, 0.0
            for l in range(L):
                phi += xh[l]
                sp, cp = sincos(phi)
                cs[0, l], cs[1, l] = cp, sp
                tx += lengths[l] * cp
                ty += lengths[l] * sp
        else:
            L = 2
            tx, ty = xh[0], xh[1]
        mx, my = tx - cx, ty - cy
        if mx * mx + my * my >= r * r:
            return False
        P = Pcfg[k + 1]
        perfect = True
        for i in range(P.shape[0]):
            for j in range(P.shape[1]):
                if P[i, j] != 0.0:
                    perfect = False
        if perfect:
            return True
        if kind == PLANAR_CHAIN:
            # J[:, j] = sum_{l >= j} l_l (-sin phi_l, cos phi_l); S = J P J'
            jx, jy = np.empty(L), np.empty(L)
            for l in range(L):
                jx[l] = -lengths[l] * cs[1, l]
                jy[l] = lengths[l] * cs[0, l]
            for l in range(L - 2, -1, -1):
                jx[l] += jx[l + 1]
                jy[l] += jy[l + 1]
            s11, s12, s22 = 0.0, 0.0, 0.0
            for i in range(L):
                ax, ay = 0.0, 0.0
                for j in range(L):
                    ax += P[i, j] * jx[j]
                    ay += P[i, j] * jy[j]
                s11 += jx[i] * ax
                s12 += jx[i] * ay
                s22 += jy[i] * ay
        else:
            s11, s12, s22 = P[0, 0], 0.5 * (P[0, 1] + P[1, 0]), P[1, 1]
        return ball_decision(mx, my, s11, s12, s22, r, conf, q_conf)

    # -- random numbers inside the kernel: xoshiro256++ and a 256-layer ziggurat -----------------

    @njit
    def _rotl(x, k):
        return (x << np.uint64(k)) | (x >> np.uint64(64 - k))

    @njit
    def _next(s0, s1, s2, s3):
        """One xoshiro256++ output and the advanced state (Blackman & Vigna)."""
        out = _rotl(s0 + s3, 23) + s0
        t = s1 << np.uint64(17)
        s2 ^= s0
        s3 ^= s1
        s1 ^= s2
        s0 ^= s3
        s2 ^= t
        s3 = _rotl(s3, 45)
        return out, s0, s1, s2, s3

    @njit
    def fill_normals(state, out, count):
        """``out[:count]`` = standard normals (ziggurat of Marsaglia & Tsang, numpy's 256-layer
        variant: 8 bits pick the layer, 1 the sign, 52 the abscissa); ``state`` (4 uint64) advances.
        Not a twin of numpy's draws (other numbers, the same law); pinned by
        tests/test_kernels.py::test_kernel_normals_are_standard_normal."""
        s0, s1, s2, s3 = state[0], state[1], state[2], state[3]
        i = 0
        while i < count:
            r, s0, s1, s2, s3 = _next(s0, s1, s2, s3)
            idx = np.int64(r & np.uint64(0xFF))
            r >>= np.uint64(8)
            rabs = (r >> np.uint64(1)) & np.uint64(0x000FFFFFFFFFFFFF)
            x = float(rabs) * ZIG_W[idx]
            if r & np.uint64(1):
                x = -x
            if rabs < ZIG_K[idx]:  # ~99% of draws: inside a layer's rectangle
                out[i] = x
                i += 1
                continue
            if idx == 0:  # the tail beyond ZIG_R (Marsaglia's exponential-majorant method)
                while True:
                    a, s0, s1, s2, s3 = _next(s0, s1, s2, s3)
                    b, s0, s1, s2, s3 = _next(s0, s1, s2, s3)
                    xx = -ZIG_INV_R * np.log1p(-float(a >> np.uint64(11)) * 1.1102230246251565e-16)
                    yy = -np.log1p(-float(b >> np.uint64(11)) * 1.1102230246251565e-16)
                    if yy + yy > xx * xx:
                        out[i] = -(ZIG_R + xx) if (rabs >> np.uint64(8)) & np.uint64(1) else ZIG_R + xx
                        i += 1
                        break
            else:  # the wedge between the rectangle and the density
                a, s0, s1, s2, s3 = _next(s0, s1, s2, s3)
                u = float(a >> np.uint64(11)) * 1.1102230246251565e-16
                if (ZIG_F[idx - 1] - ZIG_F[idx]) * u + ZIG_F[idx] < np.exp(-0.5 * x * x):
                    out[i] = x
                    i += 1
        state[0], state[1], state[2], state[3] = s0, s1, s2, s3

    # -- the kernel: steps of all live particles, structure of arrays ----------------------------

    @njit
    def run(k, k_end, n_alive, pos, ensemble, draws, model, controller, candidates, regions, sensor, robot,
            world, perfect, goal):
        """Advance the live particles ``alive[:n_alive]`` from step ``k`` to ``k_end`` (or until all stop).

        The arguments after ``pos`` are the groups listed above this module's compiled functions. The
        noise comes from ``noise`` (numpy's stream, per step ``(alive, r + nz)`` row-major) when
        ``noise`` is not empty, and the kernel then also stops when it cannot feed a whole step;
        otherwise it is drawn here from ``rng_state``. Returns the next step, the number of live
        particles (compacted in place, order kept) and the position in ``noise``. The candidate
        nodes of step k are ``cand_idx[cand_ptr[k]:cand_ptr[k + 1]]``.

        The live particles' states are held as columns (state index, particle) while the kernel runs,
        so that every step helper is a loop over particles (SIMD); the per-particle decisions (exact
        collision test where the gate passed, node membership, stopping) follow in one loop. The
        whole step is the numpy path's (:func:`firmtool.estimation.edges.simulate`); pinned particle by particle
        by tests/test_kernels.py's ``*_same_noise_same_outcomes`` tests."""
        alive, x, xhat, outcome, steps, effort = ensemble
        noise, rng_state = draws
        A, B, F, H = model
        x_ref, u_ref, K, L = controller
        cand_ptr, cand_idx, cand_key = candidates
        kind, lengths, sensing, self_collision = robot
        n, m, nz = A.shape[0], B.shape[1], H.shape[0]
        d = F.shape[1] if perfect else F.shape[1] + nz
        stream = noise.shape[0] > 0
        N = n_alive
        X, XH, XN = np.empty((n, N)), np.empty((n, N)), np.empty((n, N))
        gather_columns(x, alive, X, N)
        gather_columns(xhat, alive, XH, N)
        PRED, DX, TMP = np.empty((n, N)), np.empty((n, N)), np.empty((n, N))
        U, W, E = np.empty((m, N)), np.empty((d, N)), np.empty(N)
        HZ, INN = np.empty((nz, N)), np.empty((nz, N))
        G = np.empty(N, dtype=np.uint8)
        half = 0.5 * lengths * (1.0 + 1e-12)
        n_seg, seg_offset = robot_segments(robot)
        n_pts = n_seg + seg_offset
        PX, PY, PHI = np.empty((n_pts, N)), np.empty((n_pts, N)), np.empty(N)
        px, py, xh1 = np.empty(n_pts), np.empty(n_pts), np.empty(n)
        CS = np.empty((2, max(lengths.shape[0], 1)))
        goal_on = goal[0]
        goal_node = goal[6]
        tip = n_pts - 1  # the task point: a chain's last key point, a point robot's only one
        GG, EE, BB = np.zeros(N, dtype=np.uint8), np.empty(N), np.empty(N)
        na = N
        while k < k_end and na > 0:
            if stream:
                if pos + na * d > noise.shape[0]:
                    break
                pos = take_noise(noise, pos, W, d, na)
            else:
                draw_noise(rng_state, W, d, na)
            control(XH, x_ref[k], u_ref[k], K[k], DX, U, na)
            true_step(A, B, F, X, U, W, XN, TMP, na)
            X, XN = XN, X
            kinematics(robot, X, PX, PY, PHI, na)
            if perfect:
                for j in range(n):
                    for a in range(na):
                        XH[j, a] = X[j, a]
            else:
                filter_update(A, B, H, L[k], X, XH, U, W, PX, sensor, sensing, PRED, HZ, INN, TMP, na)
            control_effort(U, E, na)
            collision_gate(PX, PY, na, n_seg, seg_offset, world, self_collision, half, G)
            if goal_on:
                goal_gate(X, XH, PX, PY, tip, kind, lengths, goal, EE, BB, GG, na)
            # per particle: constraints on the true state, node membership, compaction (order kept)
            test_nodes = cand_ptr[k + 1] > cand_ptr[k]
            kept = 0
            for a in range(na):
                i = alive[a]
                effort[i] += E[a]
                failed = False
                if G[a]:  # only where a prefilter passed (the same tests as in collides)
                    for p in range(n_pts):
                        px[p] = PX[p, a]
                        py[p] = PY[p, a]
                    failed = collides(px, py, n_seg, seg_offset, world, self_collision, half)
                node = -1
                gated = goal_on and GG[a] and not failed
                if (test_nodes or gated) and not failed:
                    for j in range(n):
                        xh1[j] = XH[j, a]
                if gated:
                    if goal_test(xh1, k, kind, lengths, goal, CS):
                        cx, cy = goal[1][0], goal[1][1]
                        ex, ey = PX[tip, a] - cx, PY[tip, a] - cy
                        node = goal_node if ex * ex + ey * ey < goal[2] * goal[2] else GOAL_MISS
                if node == -1 and test_nodes and not failed:
                    node = locate(xh1, cand_ptr[k], cand_ptr[k + 1], cand_idx, cand_key, regions)
                    if node >= 0 and goal[7][node]:  # a goal state's node: judged on the true state too
                        centers, tscale = regions[0], goal[8]
                        s_ = 0.0
                        for j in range(n):
                            z_ = (X[j, a] - centers[node, j]) / tscale[node, j]
                            s_ += z_ * z_
                        if s_ / n >= regions[3]:
                            node = GOAL_MISS
                if failed or node != -1:
                    outcome[i] = FAILURE if failed else node
                    steps[i] = k + 1
                    for j in range(n):
                        x[i, j] = X[j, a]
                        xhat[i, j] = XH[j, a]
                    continue
                if kept != a:
                    for j in range(n):
                        X[j, kept] = X[j, a]
                        XH[j, kept] = XH[j, a]
                    alive[kept] = i
                kept += 1
            na = kept
            k += 1
        scatter_columns(X, alive, x, na)
        scatter_columns(XH, alive, xhat, na)
        return k, na, pos


def kernel():
    """The compiled kernel (compiled on first use; cached on disk by numba)."""
    global _kernel
    if _kernel is None:
        if numba is None:  # pragma: no cover
            from firmtool.errors import InputError
            raise InputError("the compiled Monte Carlo engine needs numba")
        _kernel = run
    return _kernel


# ---------------------------------------------------------------------------------------------
# driver


def simulate(problem, lc, regions, x: np.ndarray, xhat: np.ndarray, rng: np.random.Generator,
             numpy_noise: bool = False, goal_node: int = 1):
    """Compiled twin of :func:`firmtool.estimation.edges.simulate` (same arguments, same result type).

    ``x`` and ``xhat`` (M, n) are updated in place for the particles' last live step, like the
    numpy path does.

    ``numpy_noise``: False (the default) draws the noise inside the kernel (xoshiro256++ seeded from
    four words of ``rng``, ziggurat normals): fast, and reproducible from ``rng``'s state. True feeds
    the kernel ``rng.standard_normal`` in the numpy path's order instead, so that both engines
    simulate the same particles (the tests' particle-by-particle check of the arithmetic).
    """
    hit = _problem_cache.get(id(problem))
    if hit is None or hit[0] is not problem:  # checked once per problem (a frozen dataclass), not per edge
        reason = supports(problem)
        if reason is not None:
            raise InputError(f"the compiled Monte Carlo engine cannot run this problem: {reason}")
    run = kernel()
    pd = _problem_data(problem)
    perfect = problem.perfect
    M, n = x.shape
    T = lc.steps
    outcome = np.full(M, TIMEOUT, dtype=np.int64)
    steps = np.full(M, T, dtype=np.int64)
    effort = np.zeros(M)
    X = np.ascontiguousarray(x, dtype=float)
    Xh = np.ascontiguousarray(xhat, dtype=float)
    d = pd.r + (0 if perfect else pd.nz)
    alive = np.arange(M, dtype=np.int64)
    n_alive, k, pos = M, 0, 0
    noise = np.empty(0)
    rng_state = np.zeros(4, dtype=np.uint64)
    if not numpy_noise:
        rng_state[:] = rng.bit_generator.random_raw(4)
        rng_state[0] |= np.uint64(rng_state.any() == 0)  # xoshiro's one forbidden state: all zero
    x_ref = np.ascontiguousarray(lc.x_ref, dtype=float)
    u_ref = np.ascontiguousarray(lc.u_ref, dtype=float)
    K_ = np.ascontiguousarray(lc.K, dtype=float)
    # the kernel's argument groups (listed above its compiled functions)
    ensemble = (alive, X, Xh, outcome, steps, effort)
    model, membership, robot = pd.mats, _locate_data(regions), _robot_group(pd)
    first_test = lc.edge_steps - 1  # membership is tested from step edge_steps - 1 (0-based) on
    d_cfg = 2 if pd.robot == PLANAR_POINT else pd.lengths.size
    cand_ptr = np.zeros(T + 1, dtype=np.int64)
    cand_idx, cand_key = np.zeros(0, dtype=np.int64), np.zeros(0)
    k_end, segment = 0, 0
    while k < T and n_alive > 0:
        # a segment of steps: the filter recursion and the node candidates only that far
        if k_end == 0:
            k_end = min(T, max(1, lc.edge_steps + FIRST_SEGMENT_PAST_EDGE))
        else:
            k_end = min(T, k + SEGMENT_STEPS[min(segment, len(SEGMENT_STEPS) - 1)])
            segment += 1
        Ld, P_ = lc.compute(k_end)  # L[:k_end], P[:k_end + 1] final (the buffers are filled in place)
        Ld = np.ascontiguousarray(Ld, dtype=float)
        lo_t = max(k, first_test)
        if lo_t < k_end:
            cand = regions.covariance_candidates(P_[1 + lo_t:1 + k_end])
            ptr, cand_idx, cand_key = _candidate_lists(regions, cand)
            cand_ptr[:] = 0
            cand_ptr[lo_t:k_end + 1] = ptr
            cand_ptr[k_end + 1:] = ptr[-1]
        goal = _goal_group(regions, P_, k_end, d_cfg, perfect, goal_node)
        groups = (model, (x_ref, u_ref, K_, Ld), (cand_ptr, cand_idx, cand_key), membership, pd.noise, robot, pd.world,
                  bool(perfect), goal)
        if not numpy_noise:
            k, n_alive, _ = run(k, k_end, n_alive, 0, ensemble, (noise, rng_state), *groups)
            continue
        while k < k_end and n_alive > 0:
            # noise for ~CALL_PARTICLE_STEPS particle-steps: little is drawn ahead (the last
            # draw is wasted where particles stop), few kernel calls when few particles remain
            ahead = min(k_end - k, max(1, CALL_PARTICLE_STEPS // n_alive))
            if k <= first_test:  # most particles stop at the first test step: no block runs past it
                ahead = min(ahead, first_test + 1 - k)
            fresh = rng.standard_normal(n_alive * d * ahead)
            noise = np.concatenate([noise[pos:], fresh]) if pos < noise.shape[0] else fresh
            k, n_alive, pos = run(k, k_end, n_alive, 0, ensemble, (noise, rng_state), *groups)
    if X is not x:
        x[...] = X
    if Xh is not xhat:
        xhat[...] = Xh
    return ParticleOutcomes(outcome=outcome, steps=steps, terms=cost_terms(lc, steps, effort))
