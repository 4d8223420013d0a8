"""Monte Carlo estimation of one edge (paper Sec. IV-E), vectorised over particles.

Per step, for all live particles at once: control from the estimate -> true-state step with
process noise -> constraint test of the true state -> observation with R at the TRUE state ->
filter update with the precomputed gain -> the goal region of a goal ball (every step) -> node
membership (from the stabiliser phase on).
Each particle ends landed in a node, failed (constraint violation) or timed out. A particle whose
belief lands in the goal (the goal region of a goal ball, :mod:`firmtool.problem.goal`, or a goal node)
ends there only if its TRUE state is where the goal is (:meth:`firmtool.roadmap.nodes.NodeRegions.true_arrival`),
else with :data:`GOAL_MISS` (the policy would declare an arrival the environment refutes): the DP
and the success probabilities count it as a failure, so that they predict success judged on the
true state.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from firmtool.control.local import LocalController
from firmtool.errors import NumericalError
from firmtool.estimation import compiled as kernels
from firmtool.estimation.compiled.summary import STEPS_SPAN, outcome_histogram
from firmtool.estimation.outcomes import (  # noqa: F401
    FAILURE,
    GOAL_MISS,
    TIMEOUT,
    ParticleOutcomes,
    cost_terms,
    cost_weights,
    edge_seed_sequence,
    empty_swept,
    goal_code,
    grow_swept,
)
from firmtool.io.roadmap_format import GOAL_INDEX, START
from firmtool.models.base import Model
from firmtool.problem import Problem
from firmtool.roadmap.design import Design, local_controller, start_covariance
from firmtool.roadmap.nodes import NodeRegions
from firmtool.scenario import START_MODES, CostSpec


def control_and_move(model: Model, lc: LocalController, k: int, x: np.ndarray, xhat: np.ndarray,
                     w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Control from the estimate, then the true-state step: returns the new true states and the controls."""
    u = lc.u_ref[k] - (xhat - lc.x_ref[k]) @ lc.K[k].T
    return model.f(x, u) + w @ model.F.T, u


def filter_update(model: Model, lc: LocalController, k: int, x: np.ndarray, xhat: np.ndarray,
                  u: np.ndarray, v: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """Observe the new true states ``x`` (noise variance ``variance``, at the TRUE state) and update
    with the precomputed gain (an extended Kalman filter for a nonlinear model: the prediction and
    the innovation use ``f`` and ``h``, the gain is linearised along the nominal once per edge)."""
    pred = model.f(xhat, u)
    measure = getattr(model, "measure", None)
    if measure is not None:  # a measurement model (landmarks): rows not seen are NaN, bearings wrap
        return pred + model.innovation(measure(x, v), pred) @ lc.L[k].T
    z = model.h(x) + np.sqrt(variance) * v
    return pred + (z - model.h(pred)) @ lc.L[k].T


def belief_step(model: Model, lc: LocalController, k: int, x: np.ndarray, xhat: np.ndarray,
                w: np.ndarray, v: np.ndarray, perfect: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Advance true states and estimates by one step of the local controller.

    Parameters
    ----------
    x, xhat : (M, n) true states and estimates.
    w : (M, r) standard normal process noise; v : (M, nz) standard normal measurement noise.

    Returns
    -------
    x, xhat, u : the new true states and estimates, and the applied controls (M, m).
    """
    x, u = control_and_move(model, lc, k, x, xhat, w)
    if perfect:
        return x, x, u
    variance = None if hasattr(model, "measure") else model.measurement_variance(x)
    return x, filter_update(model, lc, k, x, xhat, u, v, variance), u


def simulate(problem: Problem, lc: LocalController, regions: NodeRegions, x: np.ndarray, xhat: np.ndarray,
             rng: np.random.Generator, engine: str | None = None, numpy_noise: bool = False,
             goal_node: int = GOAL_INDEX) -> ParticleOutcomes:
    """Run ``lc`` on an ensemble until every particle lands, fails or times out.

    ``goal_node``: the outcome of a particle whose belief lands in the goal region of a goal ball
    with its true task point in the ball (:func:`goal_code`).

    ``engine``: ``"numpy"`` (this function's body), ``"numba"`` (:func:`firmtool.estimation.compiled.simulate`,
    the same step compiled) or None: chosen by :func:`firmtool.estimation.compiled.engine_for` (the compiled one
    when it supports the problem; ``FIRMTOOL_ENGINE=numpy|numba`` overrides). The compiled engine
    draws its noise inside the kernel from ``rng``'s seed, unless ``numpy_noise``: then it consumes
    ``rng.standard_normal`` exactly as this body does, and both engines simulate the same particles.
    """
    if (engine or kernels.engine_for(problem)) == "numba":
        return kernels.simulate(problem, lc, regions, x, xhat, rng, numpy_noise, goal_node)
    model, perfect = problem.model, problem.perfect
    M = x.shape[0]
    outcome = np.full(M, TIMEOUT, dtype=np.int64)
    steps = np.full(M, lc.steps, dtype=np.int64)
    effort = np.zeros(M)
    candidates = regions.covariance_candidates(lc.P[1:])  # (T, N), once per edge
    goal = regions.goal
    swept = empty_swept(problem.scenario.world.dim)
    alive = np.arange(M)
    r, nz = model.F.shape[1], model.nz
    measures = hasattr(model, "measure")  # a measurement model: its noise is its own (landmarks)
    for k in range(lc.steps):
        if alive.size == 0:
            break
        noise = rng.standard_normal((alive.size, r + (0 if perfect else nz)))
        # the same step as belief_step, with the robot's kinematics computed once for both the
        # collision test and the state-dependent sensor noise
        x_a, u = control_and_move(model, lc, k, x[alive], xhat[alive], noise[:, :r])
        pts = problem.geometry.points(x_a)
        grow_swept(swept, pts)
        if perfect:
            xhat_a = x_a
        else:
            variance = None if measures else model.noise.variance(problem.geometry.sensing_from_points(pts))
            xhat_a = filter_update(model, lc, k, x_a, xhat[alive], u, noise[:, r:], variance)
        x[alive], xhat[alive] = x_a, xhat_a
        effort[alive] += np.einsum("ij,ij->i", u, u)
        failed = ~problem.states_valid(x_a, pts)
        done = failed.copy()
        outcome[alive[failed]] = FAILURE
        if goal is not None:  # the goal region of a goal ball, along the whole edge
            arrived = ~failed
            arrived[arrived] = goal.contains(xhat_a[arrived], lc.P[k + 1])
            if arrived.any():
                outcome[alive[arrived]] = np.where(goal.true_inside(x_a[arrived]), goal_node, GOAL_MISS)
                done |= arrived
        if k + 1 >= lc.edge_steps and candidates[k].any():
            node = regions.locate(xhat_a, candidates[k])
            landed = (node >= 0) & ~done
            at_goal = np.flatnonzero(landed)[regions.goal_nodes[node[landed]]] if regions.goal_nodes is not None \
                else np.zeros(0, dtype=np.int64)
            if at_goal.size:  # a goal state's node: judged on the true state too
                node[at_goal] = np.where(regions.true_arrival(node[at_goal], x_a[at_goal]), node[at_goal], GOAL_MISS)
            outcome[alive[landed]] = node[landed]
            done |= landed
        steps[alive[done]] = k + 1
        alive = alive[~done]
    return ParticleOutcomes(outcome=outcome, steps=steps, terms=cost_terms(lc, steps, effort), swept=swept)


@dataclass(frozen=True)
class EdgeEstimate:
    """Outcome counts and cost statistics of one edge."""

    source: int
    target: int
    particles: int
    outcomes: np.ndarray  # (K,) distinct outcomes (node ids, FAILURE, TIMEOUT, GOAL_MISS)
    counts: np.ndarray  # (K,) particle counts
    terms_mean: np.ndarray  # (3,) mean of the cost terms (ParticleOutcomes.terms)
    terms_cov: np.ndarray  # (3, 3) their sample covariance (ddof 1; zeros for one particle)
    steps_mean: float
    particle_steps: int
    # (2, D) the swept region of its particles (:attr:`ParticleOutcomes.swept`, and the start
    # candidates a region start tested); None for an estimate stored before regions were recorded
    swept: np.ndarray | None = None
    # (3, H) the step histogram per outcome: rows outcome code, steps taken, particles (sorted by code,
    # then steps; a deadline's DP reads it, firmtool.graph.deadline); None for an estimate stored before
    step_histogram: np.ndarray | None = None

    def cost_mean(self, spec: CostSpec) -> float:
        return float(self.terms_mean @ cost_weights(spec))

    def cost_std(self, spec: CostSpec) -> float:
        w = cost_weights(spec)
        return float(np.sqrt(max(w @ self.terms_cov @ w, 0.0)))


REGION_DRAW_ROUNDS = 64  # rejection rounds of a region start (each draws 2 M candidates)
ENSEMBLE_GROUP = 16  # edges whose initial ensembles edge_starts draws (and holds) at once


def initial_ensemble(problem: Problem, design_: Design, source: int, M: int, rng: np.random.Generator,
                     start: str = "center", swept: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Start of every particle of an edge's Monte Carlo: (true states, estimates), each (M, n).

    ``"center"`` (the paper's eq. 8: the node's centre represents the node): the estimate at the
    node centre ``v``, the true state drawn from the node's belief, ``N(v, P_s)``.

    ``"region"``: beliefs spread over the node's region, as a robot arrives there in execution: the
    estimate drawn from the stationary distribution of the estimate under the node's stabiliser,
    ``N(v, Sigma)``, restricted to the region (``rms((xhat - v) / s) < radius``, by rejection), and the
    true state ``N(xhat, P_s)`` around it (the filter's error is independent of its estimate), kept
    only where the true state is valid (a robot arriving at a node is alive; without this a node
    near an obstacle would count starts inside it as failures). In execution, arrivals' rms offsets
    follow this law closely (quantiles 0.52/0.91/1.38 vs 0.53/0.90/1.30 on point_perfect). ``swept``
    (2, D), if given, grows to hold the key points of every candidate tested (the test reads the world).

    From a start node whose start belief the task gives (``task.start_covariance``): the estimate at
    the start's mean and the true state drawn from that belief, in either mode.
    """
    v = design_.centers[source]
    n = len(v)
    if problem.start_covariance is not None and design_.kinds[source] == START and not problem.perfect:
        # the task's start belief (whatever the start mode: the start node is never landed in)
        xhat = np.repeat(v[None], M, axis=0)
        chol = np.linalg.cholesky(start_covariance(problem, design_, source) + 1e-15 * np.eye(n))
        return xhat + rng.standard_normal((M, n)) @ chol.T, xhat
    if start == "center":
        xhat = np.repeat(v[None], M, axis=0)
        if problem.perfect:
            return xhat.copy(), xhat
        return xhat + rng.standard_normal((M, n)) @ _start_factor(design_, source).T, xhat
    if start != "region":
        raise ValueError(f"start: expected one of {START_MODES}, found {start!r}")
    return _region_rounds(problem, design_, source, M, rng, swept)


def _region_draw(problem: Problem, design_: Design, source: int, M: int,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One rejection round of a region start (:func:`initial_ensemble`): ``(x, xhat)`` of the beliefs
    drawn inside the node's region, before the true states' validity test."""
    v = design_.centers[source]
    radius = problem.scenario.controller.node_radius
    chol_s = _start_factor(design_, source, "Sigma")
    scale = design_.scale[source]
    z = rng.standard_normal((2 * M, v.shape[0])) @ chol_s.T
    xhat = v + z[np.sqrt(np.mean((z / scale) ** 2, axis=1)) < radius]
    x = xhat if problem.perfect else xhat + rng.standard_normal(xhat.shape) @ _start_factor(design_, source).T
    return x, xhat


def _region_rounds(problem: Problem, design_: Design, source: int, M: int, rng: np.random.Generator,
                   swept: np.ndarray | None, first: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A region start's rejection rounds (:func:`initial_ensemble`); ``first``: round 0 drawn and tested
    by the caller, ``(x, xhat, alive, points)`` (:func:`initial_ensembles` tests a batch's at once)."""
    xs, xhats, drawn = [], [], 0
    for r in range(REGION_DRAW_ROUNDS):  # a node region holds most of the stationary mass: few rounds
        if r == 0 and first is not None:
            x, xhat, alive, points = first
            if swept is not None:
                grow_swept(swept, points)
        else:
            x, xhat = _region_draw(problem, design_, source, M, rng)
            if swept is not None:  # a robot that arrived is alive: its true state is valid
                alive, points = problem.valid_with_points(x)
                grow_swept(swept, points)
            else:
                alive = problem.is_valid(x)
        xs.append(x[alive])
        xhats.append(xhat[alive])
        drawn += int(alive.sum())
        if drawn >= M:
            break
    else:
        raise NumericalError(f"node {source}: fewer than {M} of {REGION_DRAW_ROUNDS * 2 * M} beliefs drawn over its "
                             "region have a valid true state; a region start is impossible there")
    x, xhat = np.concatenate(xs)[:M], np.concatenate(xhats)[:M]
    return (xhat.copy(), xhat) if problem.perfect else (x, xhat)


def initial_ensembles(problem: Problem, design_: Design, starts: list[tuple[int, int, np.random.Generator]],
                      start: str, swepts: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`initial_ensemble` of many ensembles ``(source, M, rng)``, each growing its ``swepts[i]``:
    the same arrays, bit for bit (each draws from its own generator as it alone would). Region starts
    test the true states of every ensemble's first rejection round in one call
    (:meth:`~firmtool.problem.Problem.valid_with_points`: the robot's key points and the geometry's test,
    row by row), instead of one call per edge (issue 55: the calls' fixed cost was ~5% of a
    200-particle edge); the rare later rounds follow one ensemble at a time."""
    if start != "region" or len(starts) < 2 or problem.validity is not None:  # a user's checker: per call, as given
        return [initial_ensemble(problem, design_, s, M, rng, start, sw) for (s, M, rng), sw in zip(starts, swepts)]
    own = [problem.start_covariance is not None and design_.kinds[s] == START and not problem.perfect
           for s, _, _ in starts]
    drawn = [None if own[i] else _region_draw(problem, design_, s, M, rng) for i, (s, M, rng) in enumerate(starts)]
    xs = [d[0] for d in drawn if d is not None]
    if xs:
        alive, points = problem.valid_with_points(np.concatenate(xs))
        bounds = np.cumsum([0] + [x.shape[0] for x in xs])
    out, j = [], 0
    for i, ((s, M, rng), sw) in enumerate(zip(starts, swepts)):
        if drawn[i] is None:  # the task's start belief (initial_ensemble's first case)
            out.append(initial_ensemble(problem, design_, s, M, rng, start, sw))
            continue
        a, b = bounds[j], bounds[j + 1]
        j += 1
        out.append(_region_rounds(problem, design_, s, M, rng, sw, (*drawn[i], alive[a:b], points[a:b])))
    return out


_factor_cache: dict[tuple[int, int, str], tuple[Design, np.ndarray]] = {}


def _start_factor(design_: Design, source: int, which: str = "P") -> np.ndarray:
    """The Cholesky factor of node ``source``'s covariance ``which`` (``"P"``, its belief's; ``"Sigma"``,
    its estimate's stationary spread; jittered by 1e-15 I), once per design and node: a worker's batch
    of edges shares a few sources (edges come sorted by source)."""
    key = (id(design_), source, which)
    hit = _factor_cache.get(key)
    if hit is not None and hit[0] is design_:
        return hit[1]
    C = getattr(design_, which)[source]
    chol = np.linalg.cholesky(C + 1e-15 * np.eye(C.shape[0]))
    if len(_factor_cache) >= 256:
        _factor_cache.clear()
    _factor_cache[key] = (design_, chol)
    return chol


@dataclass(frozen=True)
class EdgeStart:
    """An edge's first chunk set up before its Monte Carlo (:func:`edge_starts`): its random stream
    (:func:`edge_seed_sequence` of chunk 0, after the ensemble's draws), its initial ensemble ``x``,
    ``xhat`` (M, n) and the swept region ``swept`` (2, D) of the ensemble's validity tests."""

    source: int
    rng: np.random.Generator
    x: np.ndarray
    xhat: np.ndarray
    swept: np.ndarray


def edge_starts(problem: Problem, design_: Design, pairs: list[tuple[int, int]], particles: int, seed: int,
                chunk: int, start: str | None = None) -> Iterator[EdgeStart | None]:
    """Per edge ``(source, target)``, its :class:`EdgeStart` for :func:`estimate_edge` (``prepared``), set up
    :data:`ENSEMBLE_GROUP` edges at a time (the ensembles of a group held at once): the streams, the
    initial ensembles with a region start's first round tested in one call (:func:`initial_ensembles`).
    None for an edge of more than one chunk (its chunks are drawn in their own order)."""
    start = problem.scenario.estimation.start if start is None else start
    if particles > chunk:
        yield from (None for _ in pairs)
        return
    dim = problem.scenario.world.dim
    for g in range(0, len(pairs), ENSEMBLE_GROUP):
        group = pairs[g:g + ENSEMBLE_GROUP]
        rngs = [np.random.default_rng(edge_seed_sequence(seed, s, t, 0)) for s, t in group]
        swepts = [empty_swept(dim) for _ in group]
        ensembles = initial_ensembles(problem, design_, [(s, particles, rng) for (s, _), rng in zip(group, rngs)],
                                      start, swepts)
        for (s, _), rng, (x, xhat), swept in zip(group, rngs, ensembles, swepts):
            yield EdgeStart(s, rng, x, xhat, swept)


def estimate_edge(problem: Problem, design_: Design, regions: NodeRegions, source: int, target: int,
                  particles: int, seed: int, chunk: int, engine: str | None = None,
                  numpy_noise: bool = False, start: str | None = None,
                  controller: LocalController | None = None, prepared: EdgeStart | None = None) -> EdgeEstimate:
    """Monte Carlo of the local controller ``source -> target`` from the source node.

    The gains are computed once; particles are simulated in chunks (cache-friendly sizes), each chunk
    with its own seed derived from ``(seed, source, target, chunk index)``. ``engine`` and
    ``numpy_noise``: as in :func:`simulate`; ``start``: as in :func:`initial_ensemble` (None: the
    scenario's ``estimation.start``). ``controller``:
    the edge's local controller if the caller designed it already
    (:func:`firmtool.roadmap.design.local_controllers` designs a batch of edges at once, bit for bit the
    controller designed here otherwise). ``prepared``: the edge's first chunk set up already
    (:func:`edge_starts`, with a batch's other edges; bit for bit what is drawn here otherwise). This is
    block 0 of :func:`estimate_blocks`.
    """
    return estimate_blocks(problem, design_, regions, source, target, particles, 0, 1, seed, chunk, engine,
                           numpy_noise, start, controller, prepared)[0]


def estimate_blocks(problem: Problem, design_: Design, regions: NodeRegions, source: int, target: int,
                    block_size: int, first_block: int, blocks: int, seed: int, chunk: int, engine: str | None = None,
                    numpy_noise: bool = False, start: str | None = None,
                    controller: LocalController | None = None, prepared: EdgeStart | None = None) -> list[EdgeEstimate]:
    """Blocks ``first_block .. first_block + blocks - 1`` of an edge's particles, one estimate each.

    An edge's particles come in blocks of ``block_size`` (the scenario's ``estimation.particles``);
    block ``b`` is simulated in ``ceil(block_size / chunk)`` chunks whose indices continue those of
    the blocks before it (block ``b``, chunk ``j``: index ``b * ceil(block_size / chunk) + j``), each
    chunk drawing from :func:`edge_seed_sequence`. So the particles of an edge with ``k`` blocks are a
    function of the seed, the edge and ``k`` alone: more particles for an edge are new chunks, and an
    estimate with ``k`` blocks is the in-order merge (:func:`merge_estimates`) of blocks 0 to k - 1,
    whoever computed them and in whatever batches. ``controller``: as in :func:`estimate_edge`;
    ``prepared``: block 0's single chunk set up already (:func:`edge_starts`).
    """
    lc = controller if controller is not None else local_controller(problem, design_, source, target)
    start = problem.scenario.estimation.start if start is None else start
    per_block = -(-block_size // chunk)
    if prepared is not None and (first_block != 0 or per_block != 1 or prepared.source != source
                                 or prepared.x.shape[0] != block_size):
        raise ValueError(f"edge {source} -> {target}: a prepared start is block 0's single chunk of this edge")
    out = []
    for b in range(first_block, first_block + blocks):
        results = []
        swept = empty_swept(problem.scenario.world.dim)
        for j, first in enumerate(range(0, block_size, chunk)):
            M = min(chunk, block_size - first)
            if b == 0 and prepared is not None:
                rng, x, xhat, swept = prepared.rng, prepared.x, prepared.xhat, prepared.swept
            else:
                rng = np.random.default_rng(edge_seed_sequence(seed, source, target, b * per_block + j))
                x, xhat = initial_ensemble(problem, design_, source, M, rng, start, swept)
            results.append(simulate(problem, lc, regions, x, xhat, rng, engine, numpy_noise,
                                    goal_code(design_, target)))
            swept = join_swept(swept, results[-1].swept)
        out.append(summarise(source, target, results, swept))
    return out


def summarise(source: int, target: int, results: list[ParticleOutcomes], swept: np.ndarray | None) -> EdgeEstimate:
    """The estimate of one block of an edge's particles from its chunks' outcomes (in chunk order).

    The step histogram, the outcome counts and the particle-steps (integers) come from one compiled pass
    (:func:`firmtool.estimation.compiled.summary.outcome_histogram`; without numba: the counts read off
    the histogram, its codes sorted and each code's particles summed), the same as ``np.unique``'s."""
    if len(results) == 1:
        outcome, steps, terms = results[0].outcome, results[0].steps, results[0].terms
    else:
        outcome = np.concatenate([r.outcome for r in results])
        steps = np.concatenate([r.steps for r in results])
        terms = np.concatenate([r.terms for r in results])
    M = outcome.shape[0]
    ok = False
    if outcome_histogram is not None and outcome.dtype == np.int64 and steps.dtype == np.int64:
        ok, histogram, values, counts, total = outcome_histogram(outcome, steps)  # one compiled pass
    if not ok:
        histogram = step_histogram(outcome, steps)
        first = np.flatnonzero(np.concatenate([[True], histogram[0, 1:] != histogram[0, :-1]]))
        values, counts, total = histogram[0, first], np.add.reduceat(histogram[2], first), int(steps.sum())
    cov = np.cov(terms, rowvar=False, ddof=1) if M > 1 else np.zeros((3, 3))
    # steps.mean() is the exact integer sum (below 2^53) divided by M once: the same float as total / M
    return EdgeEstimate(source=source, target=target, particles=M, outcomes=values, counts=counts,
                        terms_mean=terms.mean(axis=0), terms_cov=np.atleast_2d(cov),
                        steps_mean=float(total) / M, particle_steps=int(total), swept=swept,
                        step_histogram=histogram)




def step_histogram(outcome: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """(3, H) int64: the distinct (outcome code, steps) pairs of particles (M,) and their counts, sorted."""
    outcome, steps = np.asarray(outcome, dtype=np.int64), np.asarray(steps, dtype=np.int64)
    if steps.size and (steps.min() < 0 or steps.max() >= STEPS_SPAN):  # pragma: no cover - never in a run
        pairs, counts = np.unique(np.stack([outcome, steps]), axis=1, return_counts=True)
        return np.vstack([pairs, counts[None]])
    # one int64 key per pair, ordered as the pairs are (outcome first, then steps): np.unique over the
    # pairs' columns (axis=1) sorts a structured view, ~10x slower per edge (issue 55)
    keys, counts = np.unique(outcome * STEPS_SPAN + steps, return_counts=True)
    return np.vstack([keys >> 32, keys & (STEPS_SPAN - 1), counts])


def join_histograms(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
    """The step histogram (3, H) of the particles of both; None if either is unknown."""
    if a is None or b is None:
        return None
    both = np.concatenate([a, b], axis=1)
    pairs, index = np.unique(both[:2], axis=1, return_inverse=True)
    return np.vstack([pairs, np.bincount(index.ravel(), weights=both[2], minlength=pairs.shape[1]).astype(np.int64)[None]])


def merge_estimates(a: EdgeEstimate, b: EdgeEstimate) -> EdgeEstimate:
    """One estimate from the particles of two estimates of the same edge: counts added, means and
    sample covariances pooled exactly (Chan et al.'s parallel update); swept regions joined."""
    n1, n2 = a.particles, b.particles
    n = n1 + n2
    outcomes = np.union1d(a.outcomes, b.outcomes)
    counts = np.zeros(outcomes.size, dtype=np.int64)
    counts[np.searchsorted(outcomes, a.outcomes)] += a.counts
    counts[np.searchsorted(outcomes, b.outcomes)] += b.counts
    delta = b.terms_mean - a.terms_mean
    mean = a.terms_mean + delta * (n2 / n)
    m2 = a.terms_cov * max(n1 - 1, 0) + b.terms_cov * max(n2 - 1, 0) + np.outer(delta, delta) * (n1 * n2 / n)
    return EdgeEstimate(source=a.source, target=a.target, particles=n, outcomes=outcomes, counts=counts,
                        terms_mean=mean, terms_cov=m2 / (n - 1), steps_mean=(a.steps_mean * n1 + b.steps_mean * n2) / n,
                        particle_steps=a.particle_steps + b.particle_steps, swept=join_swept(a.swept, b.swept),
                        step_histogram=join_histograms(a.step_histogram, b.step_histogram))


def join_swept(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
    """The region (2, D) that holds both swept regions; None if either is unknown."""
    if a is None or b is None:
        return None
    return np.array([np.fmin(a[0], b[0]), np.fmax(a[1], b[1])])
