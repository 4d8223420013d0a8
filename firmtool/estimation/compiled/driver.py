"""The compiled engine's Python driver: :func:`simulate`, the data it prepares for the kernel (once per
problem, once per segment of an edge's steps), and its caches.

Steps are run in segments; per segment the local controller's filter recursion is run as far as the
segment's end (lazily: particles mostly stop within a few steps of the edge's end, long before the
controller's ~edge + 200 steps) and the node candidates of its steps are computed at once.
"""

from __future__ import annotations

import numpy as np

from firmtool.errors import InputError, quoted
from firmtool.estimation.compiled.collide import world_group
from firmtool.estimation.compiled.collide3d import world_group_3d
from firmtool.estimation.compiled.goal import goal_group
from firmtool.estimation.compiled.goal3d import goal_group_3d
from firmtool.estimation.compiled.locate import segment_candidates
from firmtool.estimation.compiled.model import LANDMARKS, landmark_group
from firmtool.estimation.compiled.rng import philox_key
from firmtool.estimation.compiled.run import kernel
from firmtool.estimation.compiled.select import supports
from firmtool.estimation.compiled.step import sensor_group
from firmtool.estimation.outcomes import TIMEOUT, ParticleOutcomes, cost_terms, empty_swept
from firmtool.roadmap.membership import locate_data
from firmtool.scenario import stream_of

FIRST_SEGMENT_PAST_EDGE = 8  # the first segment: the edge and this many stabiliser steps
SEGMENT_STEPS = (16, 32, 64)  # the following segments (the last length repeats)
CALL_PARTICLE_STEPS = 1024  # particle-steps of noise drawn per kernel call


class _ProblemData:
    """Per-problem constant arrays for the kernel: the model's matrices, the sensor, the robot's
    compiled hooks and their constants and state limits (the kernel's robot group), the world."""

    def __init__(self, problem) -> None:
        model = problem.model
        self.hooks = hooks = problem.robot.compiled_kinematics()
        self.mats = tuple(np.ascontiguousarray(M, dtype=float) for M in model_matrices(model, hooks.step is not None))
        self.r, self.nz = model.F.shape[1], model.nz
        self.sensor = LANDMARKS if getattr(model.noise, "compiled", None) == LANDMARKS else None
        self.noise = landmark_group(model) if self.sensor else sensor_group(model.noise)
        n_seg, seg_offset = hooks.segments
        n = model.n
        limits = problem.robot.state_limits()
        lo, hi = (np.full(n, -np.inf), np.full(n, np.inf)) if limits is None else \
            (np.ascontiguousarray(limits[0], dtype=float), np.ascontiguousarray(limits[1], dtype=float))
        if lo.shape != (n,) or hi.shape != (n,):  # the kernel reads them unchecked
            raise InputError(f"robot {quoted(problem.scenario.model.robot)}: state_limits() must give two ({n},) arrays, "
                             f"found {lo.shape} and {hi.shape}")
        self.robot = (hooks.params, hooks.sensing, hooks.n_points, n_seg, seg_offset, hooks.self_collision,
                      hooks.half_lengths, hooks.work_size, hooks.stride, hooks.n_sensing, limits is not None, lo, hi)
        self.dim = hooks.dim
        self.world = world_group(problem.scenario.world) if hooks.dim == 2 else \
            world_group_3d(problem.scenario.world, hooks.radii, hooks.self_pairs)
        self.goal_group = goal_group if hooks.dim == 2 else goal_group_3d
        self._run = None

    @property
    def run(self):
        """The kernel compiled against the robot's hooks (:func:`kernel`), looked up once per problem, not per
        edge (the lookup builds the hooks' dictionary and key)."""
        if self._run is None:
            self._run = kernel(self.hooks, self.sensor)
        return self._run


def model_matrices(model, nonlinear: bool) -> tuple[np.ndarray, ...]:
    """The kernel's model group ``(A, B, F, H)``: a linear model's matrices; for a nonlinear one (its step
    the robot's hook) zeros of A's and B's shapes; for a measurement model (landmarks) zeros of H's
    shape (nz, n); a nonlinear model's sensor must be linear, ``h = H x`` (the unicycle's position).
    The kernel reads its dimensions from them."""
    n, m, nz = model.n, model.m, model.nz
    A, B = (np.zeros((n, n)), np.zeros((n, m))) if nonlinear else (model.A, model.B)
    if hasattr(model, "measure"):
        H = np.zeros((nz, n))
    else:  # a nonlinear model's sensor is linear (the unicycle measures its position): its constant Jacobian
        H = model.H if hasattr(model, "H") else model.observation_jacobian(np.zeros(n))
    return A, B, model.F, H


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


def _checked_problem_data(problem) -> _ProblemData:
    """:func:`_problem_data`, the problem checked once (a frozen dataclass), not per edge."""
    hit = _problem_cache.get(id(problem))
    if hit is None or hit[0] is not problem:
        reason = supports(problem)
        if reason is not None:
            raise InputError(f"the compiled Monte Carlo engine cannot run this problem: {reason}")
    return _problem_data(problem)


class _NumpyStream:
    """numpy's stream of normals (``numpy_noise=True``): drawn a few steps ahead, what the kernel has
    not consumed yet carried on to the next block."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng, self.noise, self.pos = rng, np.empty(0), 0

    def ahead(self, count: int) -> np.ndarray:
        """The unconsumed normals and ``count`` fresh ones (the kernel reads them from position 0)."""
        fresh = self.rng.standard_normal(count)
        self.noise = np.concatenate([self.noise[self.pos:], fresh]) if self.pos < self.noise.shape[0] else fresh
        return self.noise


def _segment_end(k: int, segment: int, lc) -> int:
    """The step the segment that starts at step ``k`` (the ``segment``-th, 0 the first) runs to."""
    if segment == 0:
        return min(lc.steps, max(1, lc.edge_steps + FIRST_SEGMENT_PAST_EDGE))
    return min(lc.steps, k + SEGMENT_STEPS[min(segment - 1, len(SEGMENT_STEPS) - 1)])


def _update_candidates(regions, P_steps: np.ndarray, lo_t: int, k_end: int, cand_ptr: np.ndarray) -> tuple:
    """The node candidates of steps ``lo_t`` to ``k_end`` (the kernel's candidates group; ``cand_ptr``
    (T + 1,) filled in place) from the filter covariances ``P_steps``, in one compiled pass
    (:func:`~firmtool.estimation.compiled.locate.segment_candidates`)."""
    return segment_candidates(regions, P_steps, lo_t, k_end, cand_ptr)


def _run_on_stream(run, k: int, k_end: int, n_alive: int, ensemble: tuple, stream: _NumpyStream,
                   rng_state: np.ndarray, d: int, first_test: int, groups: tuple) -> tuple[int, int]:
    """One segment with numpy's stream: kernel calls of ~:data:`CALL_PARTICLE_STEPS` particle-steps of
    noise each (little is drawn ahead, the last draw is wasted where particles stop; few kernel calls
    when few particles remain)."""
    while k < k_end and n_alive > 0:
        ahead = min(k_end - k, max(1, CALL_PARTICLE_STEPS // n_alive))
        if k <= first_test:  # most particles stop at the first test step: no block runs past it
            ahead = min(ahead, first_test + 1 - k)
        noise = stream.ahead(n_alive * d * ahead)
        k, n_alive, stream.pos = run(k, k_end, n_alive, 0, ensemble, (noise, rng_state), *groups)
    return k, n_alive


def simulate(problem, lc, regions, x: np.ndarray, xhat: np.ndarray, rng: np.random.Generator,
             numpy_noise: bool = False, goal_node: int = 1, stream: int | None = None):
    """Compiled twin of :func:`firmtool.estimation.edges.simulate` (same arguments, same result type).

    ``x`` and ``xhat`` (M, n) are updated in place for the particles' last live step, like the
    numpy path does.

    ``numpy_noise``: False (the default) draws the noise inside the kernel (xoshiro256++ seeded from
    four words of ``rng``, ziggurat normals): fast, and reproducible from ``rng``'s state. True feeds
    the kernel ``rng.standard_normal`` in the numpy path's order instead, so that both engines
    simulate the same particles (the tests' particle-by-particle check of the arithmetic).

    ``stream``: which stream the kernel draws (None: the problem's, :func:`firmtool.scenario.stream_of`):
    1, xoshiro256++ seeded from four words of ``rng``; 2, Philox keyed by ``rng``'s seed sequence
    (:func:`firmtool.estimation.compiled.rng.philox_key`), every particle's normals at every step a
    function of the key, its index in ``x`` and the step (:mod:`firmtool.estimation.compiled.rng`).
    """
    pd = _checked_problem_data(problem)
    run = pd.run
    perfect = problem.perfect
    M, T = x.shape[0], lc.steps
    outcome, steps, effort = np.full(M, TIMEOUT, dtype=np.int64), np.full(M, T, dtype=np.int64), np.zeros(M)
    X, Xh = np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(xhat, dtype=float)
    d = pd.r + (0 if perfect else pd.nz)
    n_alive, k = M, 0
    rng_state, no_stream = np.zeros(4, dtype=np.uint64), np.empty(0)
    numbers = stream_of(problem.scenario) if stream is None else stream
    stream = _NumpyStream(rng) if numpy_noise else None
    if not numpy_noise and numbers == 2:
        rng_state = philox_key(rng)  # 2 words: the kernel draws stream 2
    elif not numpy_noise:
        rng_state[:] = rng.bit_generator.random_raw(4)
        rng_state[0] |= np.uint64(rng_state.any() == 0)  # xoshiro's one forbidden state: all zero
    x_ref, u_ref, K_ = (np.ascontiguousarray(a, dtype=float) for a in (lc.x_ref, lc.u_ref, lc.K))
    swept = empty_swept(pd.dim)
    ensemble = (np.arange(M, dtype=np.int64), X, Xh, outcome, steps, effort, swept)  # the kernel's argument groups
    first_test = lc.edge_steps - 1  # membership is tested from step edge_steps - 1 (0-based) on
    candidates = (np.zeros(T + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0))
    segment = 0
    while k < T and n_alive > 0:
        # a segment of steps: the filter recursion and the node candidates only that far
        k_end = _segment_end(k, segment, lc)
        segment += 1
        Ld, P_ = lc.compute(k_end)  # L[:k_end], P[:k_end + 1] final (the buffers are filled in place)
        lo_t = max(k, first_test)
        if lo_t < k_end:
            candidates = _update_candidates(regions, P_, lo_t, k_end, candidates[0])
        goal = pd.goal_group(regions, P_, k_end, pd.hooks.task_block, perfect, goal_node)
        groups = (pd.mats, (x_ref, u_ref, K_, np.ascontiguousarray(Ld, dtype=float)), candidates,
                  locate_data(regions), pd.noise, pd.robot, pd.world, bool(perfect), goal)
        if stream is None:
            k, n_alive, _ = run(k, k_end, n_alive, 0, ensemble, (no_stream, rng_state), *groups)
        else:
            k, n_alive = _run_on_stream(run, k, k_end, n_alive, ensemble, stream, rng_state, d, first_test, groups)
    if X is not x:
        x[...] = X
    if Xh is not xhat:
        xhat[...] = Xh
    return ParticleOutcomes(outcome=outcome, steps=steps, terms=cost_terms(lc, steps, effort), swept=swept)
