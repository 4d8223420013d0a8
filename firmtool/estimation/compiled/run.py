"""The compiled Monte Carlo kernel: the steps of all live particles of an edge, structure of arrays,
compiled against a robot's compiled hooks, in a 2-D or a 3-D world.

:func:`run` is the kernel's Python code; :func:`kernel` compiles it per set of hook functions
(:class:`~firmtool.robots.compiled.CompiledKinematics`: key points, goal gate, in 3-D sensing, and
through the goal test the task point and its covariance) and world dimension, with the names of
:mod:`firmtool.estimation.compiled.bindings` bound as the code's global names by
:func:`firmtool.jit.specialise`. The kernel is thereby specialised on the
hooks, not on robot classes, and is cached on disk like every other compiled function: each hook
set is one entry of the kernel's index file, keyed by the hooks' modules, names and sources. Hooks
that another process cannot import by name (a script's or notebook's ``__main__``) are compiled
without the disk cache, in each process (:func:`disk_cached` says which).

The kernel's arguments come in groups (plain tuples: numba dispatches them faster than named ones),
each unpacked by the names below where it is used:

- ensemble ``(alive, x, xhat, outcome, steps, effort, swept)``: the particles, updated in place, and
  their swept region (2, D) (:func:`firmtool.estimation.compiled.collide.sweep`)
- draws ``(noise, rng_state)``: numpy's stream (empty: draw here) and the generator's state
  (:mod:`firmtool.estimation.compiled.rng`): 4 words, xoshiro256++'s (stream 1); 2 words, stream 2's
  Philox key (each particle's normals a function of the key, its index and the step)
- model ``(A, B, F, H)``: the linear Gaussian model's matrices
- controller ``(x_ref, u_ref, K, L)``: the local controller's reference, LQR and Kalman gains per step
- candidates, regions: node membership (:mod:`firmtool.estimation.compiled.locate`)
- sensor ``(form, light_x, eta, sigma_b, a, c, std)``: the measurement noise
  (:data:`firmtool.estimation.compiled.step.NOISE_FORMS`)
- robot ``(params, sensing, n_points, n_seg, seg_offset, self_collision, half_lengths, work_size,
  stride, n_sensing, has_limits, limit_lo, limit_hi)``: the hooks' constants
  (:class:`~firmtool.robots.compiled.CompiledKinematics`; ``sensing[j]`` the row of the sensing
  coordinates that sets measurement j's noise: in 2-D the key point whose x does) and the robot's
  state limits (:meth:`~firmtool.robots.RobotGeometry.state_limits`; a true state outside them fails)
- world: bounds, obstacles and the capsule radii (:mod:`firmtool.estimation.compiled.collide`,
  :mod:`firmtool.estimation.compiled.collide3d`)
- goal: the goal ball and the goal nodes (:mod:`firmtool.estimation.compiled.goal`,
  :mod:`firmtool.estimation.compiled.goal3d`)
"""

from __future__ import annotations

from typing import Callable, Mapping

import numpy as np

from firmtool.errors import InputError
from firmtool.estimation.outcomes import FAILURE, GOAL_MISS
from firmtool.jit import KERNEL_OPTIONS, importable, numba, specialise

if numba is not None:
    from firmtool.estimation.compiled.bindings import bindings
    from firmtool.estimation.compiled.rng import draw_noise, draw_philox, take_noise
    from firmtool.estimation.compiled.step import (
        control,
        control_effort,
        gather_columns,
        scatter_columns,
    )
    from firmtool.roadmap.membership import locate

#: the names of a robot's hook functions the kernel is compiled against (CompiledKinematics.functions), and
#: what its model steps are specialised on (``step``: a nonlinear model's hook; ``sensor``: "landmarks" or None,
#: :func:`firmtool.estimation.compiled.model.model_functions`)
HOOK_NAMES = ("key_points", "task_point", "task_covariance", "goal_gate", "sense", "step", "sensor")
# The functions of firmtool.estimation.compiled.bindings, which kernel_for binds per hook set and
# dimension (the unbound run is never compiled).
points = sense = sweep_points = gate = particle_collides = goal_gate = goal_test = true_inside = None
advance = update = None


def run(k, k_end, n_alive, pos, ensemble, draws, model, controller, candidates, regions, sensor, robot,
        world, perfect, goal):
    """Advance the live particles ``alive[:n_alive]`` from step ``k`` to ``k_end`` (or until all stop).

    The arguments after ``pos`` are the groups of the module notes. The noise comes from ``noise``
    (numpy's stream, per step ``(alive, r + nz)`` row-major) when ``noise`` is not empty, and the kernel
    then also stops when it cannot feed a whole step; otherwise it is drawn here from ``rng_state``.
    Returns the next step, the number of live particles (compacted in place, order kept) and the
    position in ``noise``. The candidate nodes of step k are ``cand_idx[cand_ptr[k]:cand_ptr[k + 1]]``.

    The live particles' states are held as columns (state index, particle) while the kernel runs,
    so that every step helper is a loop over particles (SIMD); the per-particle decisions (exact
    collision test where the gate passed, the goal test where the goal gate passed, node membership,
    stopping) follow in one loop. The whole step is the numpy path's
    (:func:`firmtool.estimation.edges.simulate`); pinned particle by particle by tests/test_kernels.py's
    ``*_same_noise_same_outcomes`` tests.

    Longer than the 80 lines a function may have: the compiled kernel's inner step. Its stages are
    already compiled helpers; what is left is the loop that owns the live columns and the work arrays
    and the per-particle decisions that read and write a dozen of them (collision, goal, membership,
    compaction), which a helper would need as arguments."""
    alive, x, xhat, outcome, steps, effort, swept = ensemble
    noise, rng_state = draws
    A, B, F, H = model
    x_ref, u_ref, K, L = controller
    cand_ptr, cand_idx, cand_key = candidates
    params, sensing, n_pts = robot[0], robot[1], robot[2]
    work_size, n_sense, has_limits, limit_lo, limit_hi = robot[7], robot[9], robot[10], robot[11], robot[12]
    n, m, nz = A.shape[0], B.shape[1], H.shape[0]
    d = F.shape[1] if perfect else F.shape[1] + nz
    stream = noise.shape[0] > 0
    philox = rng_state.shape[0] == 2  # stream 2 (rng.draw_philox); else xoshiro256++ (stream 1)
    N = n_alive
    X, XH, XN = np.empty((n, N)), np.empty((n, N)), np.empty((n, N))
    gather_columns(x, alive, X, N)
    gather_columns(xhat, alive, XH, N)
    PRED, DX, TMP = np.empty((n, N)), np.empty((n, N)), np.empty((n, N))
    U, W, E, Z = np.empty((m, N)), np.empty((d, N)), np.empty(N), np.empty((4, N))
    HZ, INN = np.empty((nz, N)), np.empty((nz, N))
    G = np.empty(N, dtype=np.uint8)
    PX, PY, PZ, PHI = np.empty((n_pts, N)), np.empty((n_pts, N)), np.empty((n_pts, N)), np.empty(N)
    SB = np.empty((n_sense, N))
    px, py, xh1 = np.empty(max(n_pts, 8)), np.empty(max(n_pts, 8)), np.empty(n)
    CS = np.empty(work_size)
    goal_on = goal[0]
    goal_node = goal[6]
    tip = n_pts - 1  # the true task point: the last key point
    GG, EE, BB = np.zeros(N, dtype=np.uint8), np.empty(N), np.empty(N)
    na = N
    while k < k_end and na > 0:
        if stream:
            if pos + na * d > noise.shape[0]:
                break
            pos = take_noise(noise, pos, W, d, na)
        elif philox:
            draw_philox(rng_state, k, alive, W, Z, d, na)
        else:
            draw_noise(rng_state, W, d, na)
        control(XH, x_ref[k], u_ref[k], K[k], DX, U, na)
        advance(A, B, F, params, X, U, W, XN, TMP, na)
        X, XN = XN, X
        points(X, params, PX, PY, PZ, PHI, na)  # once per step: for the sensor noise and the collision test
        sweep_points(PX, PY, PZ, n_pts, na, swept)
        if perfect:
            for j in range(n):
                for a in range(na):
                    XH[j, a] = X[j, a]
        else:
            rows = sense(PX, PY, PZ, params, SB, na)
            update(A, B, H, L[k], X, XH, U, W, rows, sensor, sensing, params, PRED, HZ, INN, TMP, na)
        control_effort(U, E, na)
        gate(PX, PY, PZ, na, robot, world, G)
        if goal_on:
            goal_gate(X, XH, PX, PY, PZ, params, goal[1], goal[2], EE, BB, GG, na)
        # per particle: constraints on the true state, node membership, compaction (order kept)
        test_nodes = cand_ptr[k + 1] > cand_ptr[k]
        kept = 0
        for a in range(na):
            i = alive[a]
            effort[i] += E[a]
            failed = False
            if G[a]:  # only where a prefilter passed (the same tests as in the exact test)
                failed = particle_collides(PX, PY, PZ, a, px, py, robot, world)
            if has_limits and not failed:  # the state limits (Problem.states_valid)
                for j in range(n):
                    if not (X[j, a] >= limit_lo[j] and X[j, a] <= limit_hi[j]):
                        failed = True
            node = -1
            gated = goal_on and GG[a] and not failed
            if (test_nodes or gated) and not failed:
                for j in range(n):
                    xh1[j] = XH[j, a]
            if gated:
                if goal_test(xh1, k, params, goal, CS):
                    node = goal_node if true_inside(PX, PY, PZ, tip, a, goal[1], goal[2]) else GOAL_MISS
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


_kernels: dict[tuple, Callable] = {}


def disk_cached(hooks) -> bool:
    """Whether the kernel compiled against ``hooks`` (a :class:`~firmtool.robots.compiled.CompiledKinematics`)
    is cached on disk: every hook function is importable by name in another process
    (:func:`firmtool.jit.importable`)."""
    return all(importable(fn) for fn in hooks.functions().values() if fn is not None)


def kernel(hooks, sensor: str | None = None) -> Callable:
    """The kernel compiled against the robot's ``hooks`` (a
    :class:`~firmtool.robots.compiled.CompiledKinematics`) and its model's ``sensor`` ("landmarks" or
    None, the robot's own): :func:`kernel_for` its functions."""
    return kernel_for({**hooks.functions(), "step": hooks.step, "sensor": sensor})


def kernel_for(functions: Mapping[str, Callable | None]) -> Callable:
    """:func:`run` compiled with its names bound to ``functions`` (``key_points``, ``task_point``,
    ``task_covariance``, ``goal_gate`` and, for a 3-D robot, ``sense``; a goal gate of None tests every
    particle) through :func:`firmtool.estimation.compiled.bindings.bindings`, compiled on first use (or
    loaded from numba's disk cache unless a hook is not importable) once per set of hook functions
    and process. A ``sense`` hook makes it the 3-D kernel."""
    if numba is None:  # pragma: no cover
        raise InputError("the compiled Monte Carlo engine needs numba")
    key = tuple(functions.get(name) for name in HOOK_NAMES)
    hit = _kernels.get(key)
    if hit is None:
        cache = all(importable(fn) for fn in key if callable(fn))
        dim = 2 if functions.get("sense") is None else 3
        hit = _kernels[key] = specialise(run, bindings(functions, dim, cache), KERNEL_OPTIONS, cache=cache)
    return hit


def kernels() -> list[Callable]:
    """The kernels this process compiled (or loaded) so far, one per set of hook functions."""
    return list(_kernels.values())
