"""Resource bounds: refuse up front a scenario that asks for more memory or work than is sensible.

The Monte Carlo of a build costs about ``particles x edges x (nominal steps + controller.max_steps)``
particle-steps in the worst case (every particle runs to its timeout); at the measured ~3M
particle-steps/s on two cores (DESIGN.md), the default budget of 1e10 is about an hour. The check
runs before the first stage writes anything (an estimate from the roadmap settings) and again
before the Monte Carlo (with the designed edges and their nominal lengths).

The same kind of bound applies to the worker processes (:func:`check_workers`: by cores and by the
memory each needs) and to closed-loop execution (:func:`check_execution`: episodes x
``execution.max_steps`` control steps, and the memory of recorded episodes).
"""

from __future__ import annotations

import math
import os

import numpy as np

from firmtool.errors import InputError, ScenarioError
from firmtool.problem import Problem

# Largest working set we allow one stage to ask for: node matrices, or one chunk of particles
# with one edge's gains. Beyond it a stage would swap or be killed, not fail cleanly.
MAX_BYTES = 4 * 2**30
# Measured particle-steps per second on the reference machine (2 cores), for the time estimate.
RATE = 3e6
# Working arrays per particle of one chunk (true state, estimate, noise, proposals, outcomes...).
ARRAYS_PER_PARTICLE = 12
# Memory of one worker process before its chunk: the interpreter with numpy, scipy, numba and the
# problem (measured: ~120 MB resident per worker of a smoke build, its parent ~200 MB), with a
# margin for larger designs (the arm's).
WORKER_BASE_BYTES = 300 * 2**20
# More worker processes than this many per core only add memory and contention (the work is
# CPU-bound and parallel across edges); at least MIN_WORKER_LIMIT are always allowed.
WORKERS_PER_CORE, MIN_WORKER_LIMIT = 2, 4
# Control steps one execute command may simulate (episodes x execution.max_steps, the worst case):
# ~60 us a step on the reference machine makes 1e8 about 1.7 h; --max-total-steps raises it.
MAX_EXECUTION_STEPS = 1e8


def _gib(b: float) -> str:
    return f"{b / 2**30:.3g} GiB"


def budget(problem: Problem, edges: int | None = None, mean_nominal_steps: float | None = None) -> dict:
    """Estimates of the work and memory a build of ``problem`` asks for.

    Parameters
    ----------
    edges, mean_nominal_steps : known after design; before it, estimated from the roadmap settings
        (nodes x neighbors edges, each as long as ``max_edge_length`` at ``max_speed``).

    Returns
    -------
    dict with ``particle_steps``, ``chunk_bytes``, ``node_bytes``, ``edges``, ``steps_per_edge``.
    """
    sc = problem.scenario
    rm, c, est = sc.roadmap, sc.controller, sc.estimation
    n = int(problem.model.n)
    # the connection stage's nodes (up to roadmap.bridge_nodes, usually a handful) are counted once the
    # designed edges are known (estimate_stage checks again with them)
    nodes = rm.nodes + rm.goal_nodes + 1
    if edges is None:
        edges = nodes * min(rm.neighbors, max(nodes - 1, 1))
    if mean_nominal_steps is None:
        span = float(np.max(np.asarray(problem.config_hi) - np.asarray(problem.config_lo)))
        length = min(rm.max_edge_length, span)
        factor = 1.5 if problem.velocity_dim else 1.0
        mean_nominal_steps = factor * length / c.max_speed / sc.model.dt
    steps = float(mean_nominal_steps) + c.max_steps
    particle_steps = float(est.particles) * float(edges) * steps
    chunk = min(est.chunk, est.particles)
    chunk_bytes = 8.0 * (chunk * n * ARRAYS_PER_PARTICLE + steps * 3 * n * n + est.particles * 3)
    node_bytes = 8.0 * nodes * (6 * n * n + 2 * n)
    return {"particle_steps": particle_steps, "chunk_bytes": chunk_bytes, "node_bytes": node_bytes,
            "edges": int(edges), "steps_per_edge": steps}


def check_budget(problem: Problem, edges: int | None = None, mean_nominal_steps: float | None = None) -> dict:
    """Raise :class:`ScenarioError` (naming the fields to change) if :func:`budget` exceeds the bounds."""
    b = budget(problem, edges, mean_nominal_steps)
    sc = problem.scenario
    limit = sc.estimation.max_particle_steps
    if b["node_bytes"] > MAX_BYTES:
        raise ScenarioError(sc.path, "roadmap.nodes",
                            f"expected fewer nodes: {sc.roadmap.nodes} nodes of state dimension {problem.model.n} "
                            f"need ~{_gib(b['node_bytes'])} of node matrices (limit {_gib(MAX_BYTES)})")
    if not math.isfinite(b["particle_steps"]) or b["particle_steps"] > limit:
        hours = b["particle_steps"] / RATE / 3600
        raise ScenarioError(sc.path, "estimation.particles",
                            f"expected at most {limit:.3g} particle-steps (estimation.max_particle_steps) but "
                            f"estimation.particles x edges x (nominal + controller.max_steps steps) = "
                            f"{sc.estimation.particles} x {b['edges']} x {b['steps_per_edge']:.0f} = "
                            f"{b['particle_steps']:.3g} (~{hours:.3g} h at {RATE:.0e}/s); lower them, or raise "
                            f"estimation.max_particle_steps")
    if b["chunk_bytes"] > MAX_BYTES:
        raise ScenarioError(sc.path, "estimation.chunk",
                            f"expected a smaller estimation.chunk / estimation.particles / controller.max_steps: "
                            f"one chunk needs ~{_gib(b['chunk_bytes'])} (limit {_gib(MAX_BYTES)})")
    return b


def cores() -> int:
    """CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def available_memory() -> int | None:
    """Bytes of memory available to new processes (Linux ``MemAvailable``), or None if unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        return None


def check_workers(workers: int, problem: Problem | None = None) -> int:
    """``workers`` if this machine can run that many worker processes, else :class:`InputError`.

    Bounds: at most ``WORKERS_PER_CORE`` per core (at least ``MIN_WORKER_LIMIT``), and their memory
    (``WORKER_BASE_BYTES`` plus one chunk of particles of ``problem`` each) within what is available.
    """
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise InputError(f"--workers: expected an integer >= 1, found {workers!r}")
    n_cores = cores()
    top = max(MIN_WORKER_LIMIT, WORKERS_PER_CORE * n_cores)
    if workers > top:
        raise InputError(f"--workers: expected at most {top} ({WORKERS_PER_CORE} per core, {n_cores} cores), found "
                         f"{workers}; more processes than cores only add memory and contention")
    each = WORKER_BASE_BYTES + (budget(problem)["chunk_bytes"] if problem is not None else 0)
    free = available_memory()
    if workers > 1 and free is not None and workers * each > free:
        raise InputError(f"--workers: {workers} workers need ~{_gib(workers * each)} (~{_gib(each)} each) but "
                         f"{_gib(free)} of memory is available; use at most {max(1, int(free // each))}")
    return int(workers)


def check_execution(problem: Problem, episodes: int, record: bool = False,
                    max_total_steps: float = MAX_EXECUTION_STEPS) -> dict:
    """Refuse (:class:`InputError`) closed-loop runs that could take hours or exhaust memory.

    Parameters
    ----------
    episodes : episodes to run; each may take up to ``execution.max_steps`` control steps.
    record : episodes are kept in memory (``--save-episodes``): states, estimates, covariances per step.
    max_total_steps : the bound of episodes x ``execution.max_steps`` (``--max-total-steps``).

    Returns
    -------
    dict with ``steps`` (the worst case) and ``record_bytes``.
    """
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1:
        raise InputError(f"--episodes: expected an integer >= 1, found {episodes!r}")
    if not (math.isfinite(max_total_steps) and max_total_steps >= 1):
        raise InputError(f"--max-total-steps: expected a finite number >= 1, found {max_total_steps}")
    per_episode = problem.scenario.execution.max_steps
    steps = float(episodes) * per_episode
    if steps > max_total_steps:
        raise InputError(f"--episodes: {episodes} episodes x execution.max_steps {per_episode} = {steps:.3g} control "
                         f"steps in the worst case (~{steps * 60e-6 / 3600:.3g} h at ~60 us a step), more than "
                         f"--max-total-steps {max_total_steps:.3g}; run fewer episodes, or raise --max-total-steps")
    n = int(problem.model.n)
    record_bytes = steps * 8.0 * (3 * n + n * n + int(problem.model.m)) if record else 0.0
    if record_bytes > MAX_BYTES:
        raise InputError(f"--save-episodes: {episodes} recorded episodes of up to {per_episode} steps may need "
                         f"~{_gib(record_bytes)} of memory (limit {_gib(MAX_BYTES)}); record fewer episodes")
    return {"steps": steps, "record_bytes": record_bytes}
