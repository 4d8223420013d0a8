"""Resource bounds: refuse up front a scenario that asks for more memory or work than is sensible.

The Monte Carlo of a build costs about ``particles x edges x (nominal steps + controller.max_steps)``
particle-steps in the worst case (every particle runs to its timeout); at the measured ~3M
particle-steps/s on two cores (DESIGN.md), the default budget of 1e10 is about an hour. The check
runs before the first stage writes anything (an estimate from the roadmap settings) and again
before the Monte Carlo (with the designed edges and their nominal lengths).
"""

from __future__ import annotations

import math

import numpy as np

from firmtool.errors import ScenarioError
from firmtool.problem import Problem

# Largest working set we allow one stage to ask for: node matrices, or one chunk of particles
# with one edge's gains. Beyond it a stage would swap or be killed, not fail cleanly.
MAX_BYTES = 4 * 2**30
# Measured particle-steps per second on the reference machine (2 cores), for the time estimate.
RATE = 3e6
# Working arrays per particle of one chunk (true state, estimate, noise, proposals, outcomes...).
ARRAYS_PER_PARTICLE = 12


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
