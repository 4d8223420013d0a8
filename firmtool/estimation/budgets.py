"""Resource bounds: refuse up front a scenario that asks for more memory or work than is sensible.

The Monte Carlo of a build costs about ``particles x edges x (nominal steps + controller.max_steps)``
particle-steps in the worst case (every particle runs to its timeout); at the measured ~3M
particle-steps/s on two cores (DESIGN.md), the default budget of 1e10 is about an hour. The check
runs before the first stage writes anything (an estimate from the roadmap settings) and again
before the Monte Carlo (with the designed edges and their nominal lengths).

The same kind of bound applies to the worker processes (:func:`check_workers`: by cores and by the
memory each needs) and to closed-loop execution (:func:`check_execution`: episodes x
``execution.max_steps`` control steps, and the memory of recorded episodes).

Every other kind of work a scenario or a roadmap file from someone else can ask for is bounded too,
at ``check`` time and where the work starts:

- sampling and design (:func:`offline_budget`, :func:`check_offline`): the worst-case sampling
  attempts and the design's Riccati steps (every edge's nominal length), at the measured rates,
  within :data:`MAX_OFFLINE_SECONDS`; a roadmap file's own node count is checked the same way
  before its design (:func:`check_roadmap_nodes`);
- a push disturbance against the configuration bounds (:func:`check_push_size`: a push longer than
  their diagonal leaves them from every state, and its collision check would be sized by its length);
- the control period (:func:`check_time_step`): a ``model.dt`` at which one step at the nominals'
  speed crosses the whole configuration space makes every edge fail.
"""

from __future__ import annotations

import math
import os

import numpy as np

from firmtool.errors import InputError, RoadmapError, ScenarioError, quoted
from firmtool.graph.deadline import deadline_budget
from firmtool.problem import Problem
from firmtool.roadmap.nodes import ATTEMPTS_PER_NODE, MIN_ATTEMPTS

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
# Sampling and design, before any Monte Carlo: at most the hour the default Monte Carlo budget stands
# for (estimation.max_particle_steps 1e10 at RATE), estimated at the fastest rates measured on the
# reference machine (2 cores, loaded; point, unicycle and arm shipped scenarios): a validity check of
# one sampling attempt 4.7-5.2e-5 s (2-D boxes), a design step (one Riccati step of an edge's TV-LQG
# controller, every nominal step of every edge) 1.5e-4 s (arm), 2.3e-4 s (point), 2.2e-3 s
# (unicycle). The fastest are used, so a refusal always stands for more than the hour.
MAX_OFFLINE_SECONDS = 3600.0
SAMPLE_ATTEMPT_SECONDS = 4.5e-5
DESIGN_STEP_SECONDS = 1.5e-4


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
    if edges is None:  # before the design: its own work, and a control period every edge fails at
        check_time_step(problem)
        check_offline(problem)
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
    check_deadline_steps(problem)
    return b


def check_deadline_steps(problem: Problem) -> None:
    """Refuse a ``task.deadline_steps`` beyond the budget known without a roadmap
    (:func:`firmtool.graph.deadline.deadline_budget`: firmtool's cap, and the DP's memory at the scenario's
    node count; the roadmap's own budget is checked when it is solved)."""
    sc = problem.scenario
    T = sc.task.deadline_steps
    if T is None:
        return
    nodes = sc.roadmap.nodes + sc.roadmap.goal_nodes + 1  # the fewest a roadmap of the scenario holds
    try:
        deadline_budget(nodes).check(T, "task.deadline_steps")
    except InputError as exc:
        raise ScenarioError(sc.path, "task.deadline_steps", str(exc).split(": ", 1)[1]) from None


def offline_budget(problem: Problem, nodes: int | None = None) -> dict:
    """Estimates of the sampling and design work of a roadmap of ``nodes`` regular nodes (default:
    the scenario's ``roadmap.nodes``).

    Returns
    -------
    dict with ``sample_attempts`` (the most :func:`firmtool.roadmap.nodes.sample_nodes` may make),
    ``edges``, ``design_steps`` (edges x nominal steps), ``seconds`` (at the measured rates).
    """
    sc = problem.scenario
    regular = sc.roadmap.nodes if nodes is None else int(nodes)
    total = regular + sc.roadmap.goal_nodes + 1
    attempts = float(ATTEMPTS_PER_NODE) * regular + MIN_ATTEMPTS
    b = budget(problem, edges=total * min(sc.roadmap.neighbors, max(total - 1, 1)))
    steps = b["edges"] * (b["steps_per_edge"] - sc.controller.max_steps)  # the nominals, not the timeouts
    seconds = attempts * SAMPLE_ATTEMPT_SECONDS + steps * DESIGN_STEP_SECONDS
    return {"sample_attempts": attempts, "edges": b["edges"], "design_steps": steps, "seconds": seconds,
            "node_bytes": 8.0 * total * (6 * problem.model.n ** 2 + 2 * problem.model.n)}


def _offline_too_long(b: dict, nodes: int) -> str:
    return (f"sampling and designing {nodes} nodes would take ~{b['seconds'] / 3600:.3g} h (up to "
            f"{b['sample_attempts']:.3g} sampling attempts, {b['edges']} edges of {b['design_steps']:.3g} design steps "
            f"in all, at the fastest measured rates), more than the {MAX_OFFLINE_SECONDS / 3600:g} h a build may take "
            "before its Monte Carlo; use fewer nodes (densify with --p-min to grow a roadmap where it helps)")


def separated_capacity(problem: Problem) -> float:
    """The most configurations ``roadmap.min_separation`` apart that fit in the configuration bounds
    (inf without a separation): balls of half the separation around them are disjoint and lie in the
    bounds widened by that half, so there are at most vol(widened bounds) / vol(ball) of them."""
    sep = float(problem.scenario.roadmap.min_separation)
    if not sep > 0:
        return math.inf
    d = int(problem.config_dim)
    span = np.asarray(problem.config_hi, dtype=float) - np.asarray(problem.config_lo, dtype=float)
    r = sep / 2
    log_box = float(np.sum(np.log(span + sep)))
    log_ball = d / 2 * math.log(math.pi) - math.lgamma(d / 2 + 1) + d * math.log(r)
    return math.exp(min(log_box - log_ball, 700.0))


def check_offline(problem: Problem) -> dict:
    """Raise :class:`ScenarioError` naming ``roadmap.nodes`` if more nodes are asked for than fit at
    ``roadmap.min_separation`` (:func:`separated_capacity`: sampling would draw its every attempt in
    vain), or if sampling and designing them would take longer than :data:`MAX_OFFLINE_SECONDS`
    (:func:`offline_budget`)."""
    b = offline_budget(problem)
    sc = problem.scenario
    fit = separated_capacity(problem)
    if sc.roadmap.nodes > fit:
        raise ScenarioError(sc.path, "roadmap.nodes", f"expected at most {int(fit)} nodes at roadmap.min_separation "
                            f"{sc.roadmap.min_separation:g}: no more configurations that far apart fit in the "
                            f"configuration bounds, and sampling {sc.roadmap.nodes} would make up to "
                            f"{b['sample_attempts']:.3g} attempts in vain; lower roadmap.nodes or "
                            "roadmap.min_separation")
    if not math.isfinite(b["seconds"]) or b["seconds"] > MAX_OFFLINE_SECONDS:
        raise ScenarioError(sc.path, "roadmap.nodes", f"expected fewer nodes: {_offline_too_long(b, sc.roadmap.nodes)}")
    return b


def check_roadmap_nodes(problem: Problem, path: str, nodes: int) -> dict:
    """Refuse (:class:`RoadmapError` naming ``/nodes/centers``) a roadmap file whose ``nodes`` nodes
    would take longer than :data:`MAX_OFFLINE_SECONDS` to design, or whose node matrices would need
    more than :data:`MAX_BYTES` (the file's node count, not the scenario's ``roadmap.nodes``)."""
    b = offline_budget(problem, nodes)
    b["seconds"] -= b["sample_attempts"] * SAMPLE_ATTEMPT_SECONDS  # the nodes are sampled already
    if b["node_bytes"] > MAX_BYTES:
        raise RoadmapError(f"{path}: '/nodes/centers' holds {nodes} nodes, whose node matrices need "
                           f"~{_gib(b['node_bytes'])} (limit {_gib(MAX_BYTES)}; file damaged or not for this machine)")
    if not math.isfinite(b["seconds"]) or b["seconds"] > MAX_OFFLINE_SECONDS:
        raise RoadmapError(f"{path}: '/nodes/centers' holds {nodes} nodes: designing them would take "
                           f"~{b['seconds'] / 3600:.3g} h ({b['edges']} edges of {b['design_steps']:.3g} design steps "
                           f"in all, at the fastest measured rate), more than {MAX_OFFLINE_SECONDS / 3600:g} h "
                           "(file damaged or not for this machine)")
    return b


def configuration_diagonal(problem: Problem) -> float:
    """The length of the configuration bounds' diagonal: no two configurations in bounds are farther apart."""
    span = np.asarray(problem.config_hi, dtype=float) - np.asarray(problem.config_lo, dtype=float)
    return float(np.linalg.norm(span))


def check_push_size(problem: Problem, spec: str, size: float, flag: str = "--disturbance") -> None:
    """Refuse a push longer than the configuration bounds' diagonal (:class:`InputError` naming ``flag``):
    it leaves the bounds from every state, so it only fails, and its collision check along the push
    would be sized by its length."""
    diagonal = configuration_diagonal(problem)
    if not (math.isfinite(size) and size <= diagonal):
        raise InputError(f"{flag} {quoted(spec)}: SIZE {size:g} is longer than the diagonal of the configuration bounds "
                         f"({diagonal:.4g}): a push that long leaves them from every state; expected SIZE <= "
                         f"{diagonal:.4g}")


def check_time_step(problem: Problem) -> None:
    """Refuse (:class:`ScenarioError` naming ``model.dt``) a control period in which one step at
    ``controller.max_speed`` crosses the whole configuration space: no nominal trajectory has a step
    inside it, and every edge fails."""
    sc = problem.scenario
    diagonal = configuration_diagonal(problem)
    reach = sc.model.dt * sc.controller.max_speed
    if not (math.isfinite(reach) and reach < diagonal):
        raise ScenarioError(sc.path, "model.dt", f"expected a control period in which one step at "
                            f"controller.max_speed {sc.controller.max_speed:g} stays inside the configuration bounds "
                            f"(diagonal {diagonal:.4g}); dt = {sc.model.dt:g} s moves {reach:.3g} (every edge would "
                            "fail)")


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
        raise InputError(f"--workers: expected an integer >= 1, found {quoted(workers)}")
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
                    max_total_steps: float = MAX_EXECUTION_STEPS,
                    names: tuple[str, str, str] = ("--episodes", "--max-total-steps", "--save-episodes")) -> dict:
    """Refuse (:class:`InputError`) closed-loop runs that could take hours or exhaust memory.

    Parameters
    ----------
    episodes : episodes to run; each may take up to ``execution.max_steps`` control steps.
    record : episodes are kept in memory (``--save-episodes``): states, estimates, covariances per step.
    max_total_steps : the bound of episodes x ``execution.max_steps`` (``--max-total-steps``).
    names : what the messages call episodes, the bound and recording (the options; the API's arguments).

    Returns
    -------
    dict with ``steps`` (the worst case) and ``record_bytes``.
    """
    flag_episodes, flag_bound, flag_record = names
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1:
        raise InputError(f"{flag_episodes}: expected an integer >= 1, found {quoted(episodes)}")
    if isinstance(max_total_steps, bool) or not isinstance(max_total_steps, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(max_total_steps) and max_total_steps >= 1):
        raise InputError(f"{flag_bound}: expected a finite number >= 1, found {quoted(max_total_steps)}")
    per_episode = problem.scenario.execution.max_steps
    steps = float(episodes) * per_episode
    if steps > max_total_steps:
        raise InputError(f"{flag_episodes}: {episodes} episodes x execution.max_steps {per_episode} = {steps:.3g} "
                         f"control steps in the worst case (~{steps * 60e-6 / 3600:.3g} h at ~60 us a step), more than "
                         f"{flag_bound} {max_total_steps:.3g}; run fewer episodes, or raise {flag_bound}")
    n = int(problem.model.n)
    record_bytes = steps * 8.0 * (3 * n + n * n + int(problem.model.m)) if record else 0.0
    if record_bytes > MAX_BYTES:
        raise InputError(f"{flag_record}: {episodes} recorded episodes of up to {per_episode} steps may need "
                         f"~{_gib(record_bytes)} of memory (limit {_gib(MAX_BYTES)}); record fewer episodes")
    return {"steps": steps, "record_bytes": record_bytes}
