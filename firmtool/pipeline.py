"""The offline stages as library calls: sample, design, estimate, solve. Each reads the roadmap file
the previous stage wrote and adds its own group; each returns a plain dict report (the CLI prints it).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np
import scipy.sparse

from firmtool.design import Design, design
from firmtool.edges import FAILURE, TIMEOUT
from firmtool.errors import RoadmapError, RunFailure
from firmtool.graph import shortest_path_policy, solve_dp, success_probability
from firmtool.nodes import GOAL, START_INDEX, roadmap_nodes
from firmtool.parallel import EstimationJob, default_workers, run_edges
from firmtool.problem import Problem, build_problem
from firmtool.resources import check_budget
from firmtool.roadmap import Roadmap, create_roadmap, inputs_hash, write_stage
from firmtool.scenario import Scenario, load_scenario, parse_scenario


def default_output(scenario: Scenario) -> Path:
    return Path("artifacts") / f"{scenario.name}.h5"


def problem_of(roadmap: Roadmap) -> Problem:
    """Rebuild the problem from the scenario text stored in the roadmap."""
    return build_problem(parse_scenario(roadmap.scenario_text, f"{roadmap.path}:scenario_toml"))


def design_of(roadmap: Roadmap) -> Design:
    nodes = roadmap.require("nodes", "centers", "kind")
    c = roadmap.require("controllers", "u_eq", "K", "S", "L", "P", "Sigma", "scale",
                        "edge_source", "edge_target", "edge_steps")
    return Design(centers=nodes["centers"], kinds=nodes["kind"], u_eq=c["u_eq"], K=c["K"], S=c["S"], L=c["L"], P=c["P"],
                  Sigma=c["Sigma"], scale=c["scale"], edge_source=c["edge_source"].astype(np.int64),
                  edge_target=c["edge_target"].astype(np.int64), edge_steps=c["edge_steps"].astype(np.int64))


def sample_stage(scenario_path: str | Path, output: str | Path | None) -> dict:
    """Sample the nodes of a new roadmap (start, goal, then valid configurations at rest)."""
    t0 = time.perf_counter()
    scenario = load_scenario(scenario_path)
    problem = build_problem(scenario)
    check_budget(problem)  # refuse up front what would take hours or exhaust memory
    rng = np.random.default_rng(np.random.SeedSequence([scenario.seed, 0x5A4D]))
    centers, kinds = roadmap_nodes(problem, rng)
    out = Path(output) if output else default_output(scenario)
    create_roadmap(out, scenario.text, scenario.sha256, scenario.seed)
    write_stage(out, "nodes", {"centers": centers, "kind": kinds},
                {"inputs_sha256": inputs_hash(scenario.sha256, "nodes"),
                 "start": START_INDEX, "goals": np.flatnonzero(kinds == GOAL)})
    return {"roadmap": str(out), "nodes": int(centers.shape[0]), "requested_nodes": scenario.roadmap.nodes,
            "seconds": time.perf_counter() - t0}


def design_stage(path: str | Path) -> dict:
    """Design node stabilisers, node regions and edges (nominal trajectories)."""
    t0 = time.perf_counter()
    roadmap = Roadmap(path)
    problem = problem_of(roadmap)
    nodes = roadmap.require("nodes", "centers", "kind")
    centers = nodes["centers"]
    d = design(problem, centers, nodes["kind"])
    if d.edge_source.size == 0:
        raise RunFailure(f"{path}: no collision-free edge between any two nodes; add nodes or neighbours")
    arrays = {name: getattr(d, name) for name in ("u_eq", "K", "S", "L", "P", "Sigma", "scale",
                                                  "edge_source", "edge_target", "edge_steps")}
    write_stage(path, "controllers", arrays,
                {"inputs_sha256": inputs_hash(roadmap.scenario_sha256, centers),
                 "node_radius": problem.scenario.controller.node_radius,
                 "covariance_tolerance": problem.scenario.controller.covariance_tolerance})
    return {"roadmap": str(path), "nodes": int(centers.shape[0]), "edges": int(d.edge_source.size),
            "mean_edge_steps": float(d.edge_steps.mean()), "seconds": time.perf_counter() - t0}


def estimate_stage(path: str | Path, *, workers: int | None = None, executor: str = "process",
                   scheduler: str | None = None,
                   progress_factory: Callable[[int], Callable[[int], None]] | None = None) -> dict:
    """Monte Carlo estimation of every edge, in parallel; writes ``/edges``."""
    t0 = time.perf_counter()
    roadmap = Roadmap(path)
    problem = problem_of(roadmap)
    d = design_of(roadmap)
    check_budget(problem, d.edge_source.size, float(d.edge_steps.mean()) if d.edge_steps.size else 0.0)
    sc = problem.scenario
    workers = workers or default_workers()
    job = EstimationJob(scenario_text=roadmap.scenario_text, scenario_path=str(path), design=d,
                        particles=sc.estimation.particles, chunk=sc.estimation.chunk, seed=sc.seed)
    E = d.edge_source.size
    progress = progress_factory(E) if progress_factory else None
    results: dict[int, object] = {}
    for batch, out in run_edges(job, range(E), workers=workers, executor=executor, scheduler=scheduler,
                                progress=progress):
        results.update(zip(batch, out))
    est = [results[e] for e in range(E)]
    rows = [(e, int(code), int(cnt)) for e, r in enumerate(est) for code, cnt in zip(r.outcomes, r.counts)]
    table = np.array(rows, dtype=np.int64).reshape(-1, 3)
    arrays = {
        "source": d.edge_source, "target": d.edge_target,
        "particles": np.array([r.particles for r in est], dtype=np.int64),
        "cost_mean": np.array([r.cost_mean for r in est]), "cost_std": np.array([r.cost_std for r in est]),
        "steps_mean": np.array([r.steps_mean for r in est]),
        "particle_steps": np.array([r.particle_steps for r in est], dtype=np.int64),
        "outcome_edge": table[:, 0], "outcome_code": table[:, 1], "outcome_count": table[:, 2],
    }
    write_stage(path, "edges", arrays,
                {"inputs_sha256": inputs_hash(roadmap.attrs("controllers")["inputs_sha256"],
                                              sc.estimation.particles, sc.seed),
                 "seed": sc.seed, "failure_code": FAILURE, "timeout_code": TIMEOUT})
    seconds = time.perf_counter() - t0
    steps = int(arrays["particle_steps"].sum())
    return {"roadmap": str(path), "edges": E, "particles_per_edge": sc.estimation.particles,
            "particle_steps": steps, "particle_steps_per_second": steps / seconds if seconds else 0.0,
            "workers": workers, "executor": executor, "seconds": seconds}


def edge_probabilities(roadmap: Roadmap) -> tuple[scipy.sparse.csr_matrix, np.ndarray, np.ndarray, np.ndarray]:
    """Landing matrix (E, N), failure and timeout probabilities (E,), particles (E,) from ``/edges``."""
    e = roadmap.require("edges", "source", "particles", "outcome_edge", "outcome_code", "outcome_count")
    N = roadmap.require("nodes", "centers")["centers"].shape[0]
    E = e["source"].size
    n = e["particles"].astype(float)
    edge, code, count = e["outcome_edge"], e["outcome_code"], e["outcome_count"].astype(float)
    if np.any(code >= N) or np.any(code < TIMEOUT):
        raise RoadmapError(f"{roadmap.path}: /edges holds outcome codes outside the node range")
    land = code >= 0
    landing = scipy.sparse.csr_matrix((count[land] / n[edge[land]], (edge[land], code[land])), shape=(E, N))
    fail = np.bincount(edge[code == FAILURE], weights=count[code == FAILURE], minlength=E) / n
    timeout = np.bincount(edge[code == TIMEOUT], weights=count[code == TIMEOUT], minlength=E) / n
    return landing, fail, timeout, e["particles"]


def solve_stage(path: str | Path, *, failure_cost: float | None = None, method: str = "value") -> dict:
    """Solve the constrained graph DP (eq. 12) and the success probabilities; writes ``/policy``.

    Timeouts count as failures. Raises :class:`RunFailure` (after writing the policy) if the goal is
    unreachable from the start node.
    """
    t0 = time.perf_counter()
    roadmap = Roadmap(path)
    problem = problem_of(roadmap)
    edges = roadmap.require("edges", "source", "target", "cost_mean")
    landing, fail, timeout, _ = edge_probabilities(roadmap)
    N = landing.shape[1]
    goals = np.flatnonzero(roadmap.require("nodes", "kind")["kind"] == GOAL)
    JF = float(failure_cost if failure_cost is not None else problem.scenario.cost.failure_cost)
    res = solve_dp(N, goals, edges["source"].astype(np.int64), edges["cost_mean"], landing,
                   fail + timeout, JF, method=method)
    p = success_probability(N, goals, res.policy, landing)
    next_node = np.where(res.policy >= 0, edges["target"][np.maximum(res.policy, 0)], -1)
    # The baseline that ignores uncertainty: shortest configuration-space path on the same roadmap.
    centers = roadmap.require("nodes", "centers")["centers"][:, :problem.config_dim]
    length = np.linalg.norm(centers[edges["target"]] - centers[edges["source"]], axis=1)
    sp = shortest_path_policy(N, goals, edges["source"], edges["target"], length)
    p_sp = success_probability(N, goals, sp, landing)
    write_stage(path, "policy",
                {"cost_to_go": res.cost_to_go, "edge": res.policy, "next_node": next_node,
                 "success_probability": p, "unreachable": res.unreachable,
                 "shortest_path_edge": sp, "shortest_path_success_probability": p_sp},
                {"inputs_sha256": inputs_hash(roadmap.attrs("edges")["inputs_sha256"], JF, method),
                 "status": res.status.name, "iterations": res.iterations, "residual": res.residual,
                 "failure_cost": JF, "method": method})
    report = {"roadmap": str(path), "status": res.status.name, "iterations": int(res.iterations),
              "residual": float(res.residual), "failure_cost": JF, "method": method,
              "start_cost_to_go": _finite_or_none(res.cost_to_go[START_INDEX]),
              "start_success_probability": float(p[START_INDEX]),
              "shortest_path_start_success_probability": float(p_sp[START_INDEX]),
              "unreachable_nodes": [int(i) for i in res.unreachable],
              "path": policy_path(res.policy, edges["target"], START_INDEX, goals),
              "seconds": time.perf_counter() - t0}
    if not np.isfinite(res.cost_to_go[START_INDEX]):
        raise RunFailure(f"{path}: the goal is unreachable from the start node under the estimated edges "
                         f"({len(res.unreachable)} of {N} nodes cannot reach it); add nodes or neighbours",
                         ) from None
    return report


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def policy_path(policy: np.ndarray, target: np.ndarray, start: int, goals: np.ndarray) -> list[int]:
    """The nominal node sequence: follow each chosen edge's target from ``start`` to a goal."""
    path, seen = [start], {start}
    node = start
    while node not in set(np.atleast_1d(goals).tolist()) and policy[node] >= 0:
        node = int(target[policy[node]])
        if node in seen:
            break
        path.append(node)
        seen.add(node)
    return path


def build(scenario_path: str | Path, output: str | Path | None, *, workers: int | None = None,
          executor: str = "process", scheduler: str | None = None,
          progress_factory: Callable[[int], Callable[[int], None]] | None = None) -> dict:
    """sample + design + estimate; returns a report with seconds per stage."""
    s = sample_stage(scenario_path, output)
    path = s["roadmap"]
    d = design_stage(path)
    e = estimate_stage(path, workers=workers, executor=executor, scheduler=scheduler,
                       progress_factory=progress_factory)
    return {"roadmap": path, "nodes": s["nodes"], "edges": d["edges"],
            "particles_per_edge": e["particles_per_edge"], "particle_steps": e["particle_steps"],
            "particle_steps_per_second": e["particle_steps_per_second"], "workers": e["workers"],
            "executor": executor,
            "seconds": {"sample": s["seconds"], "design": d["seconds"], "estimate": e["seconds"]}}
