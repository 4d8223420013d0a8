"""The Monte Carlo of one estimate stage: the uniform first pass, the adaptive rounds' particle
blocks, and the checkpoints that let an interrupted stage resume where it stopped.

:class:`EdgeRuns` holds what the stage has estimated so far (per edge, and every estimate made
with its key, for the checkpoints and for reuse), so that the first pass, the adaptive rounds and a
Ctrl-C all save the same way.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator

import numpy as np

from firmtool.estimation.adaptive import AdaptiveReport, AdaptiveSettings, refine
from firmtool.estimation.edge_table import KEY_BYTES, blocks_key, to_arrays
from firmtool.estimation.edges import EdgeEstimate, merge_estimates
from firmtool.estimation.executors import BatchResult, EstimationJob, Workers, run_edges
from firmtool.io.memory_file import MemoryFile
from firmtool.io.roadmap_file import concat_edge_tables, write_edge_cache
from firmtool.io.roadmap_format import GOAL
from firmtool.pipeline.settings import WorkerSettings
from firmtool.pipeline.target import RoadmapTarget
from firmtool.progress import Counter
from firmtool.scenario import Scenario
from firmtool.util import interrupts


class EdgeRuns:
    """The edge estimates of one estimate stage, and its checkpoints to ``/edge_cache``.

    Parameters
    ----------
    target : the roadmap the checkpoints go to.
    job : what the workers run (:class:`firmtool.estimation.executors.EstimationJob`).
    keys : (E, 32) uint8, every designed edge's key (:func:`firmtool.estimation.edge_table.edge_keys`).
    known : estimates stored before (``/edges`` and ``/edge_cache``), by key: reused, not estimated.
    cache : the ``/edge_cache`` table read at the start (kept in every checkpoint).
    table_hash : the ``inputs_sha256`` the new ``/edges`` gets (the checkpoints record it).
    workers, session : where the Monte Carlo runs (``session``: the calling command's workers).
    checkpoint_seconds : seconds between checkpoints (the first comes after the first batch).

    Attributes
    ----------
    estimates : per edge, its estimate so far (None: still to do).
    failed : edge -> the error of an edge whose Monte Carlo failed twice.
    estimated : edges estimated by this stage's first pass.
    simulated : particle-steps simulated by this stage.
    saved : estimates made by this stage that a checkpoint saved.
    """

    def __init__(self, target: RoadmapTarget, job: EstimationJob, keys: np.ndarray, known: dict[bytes, EdgeEstimate],
                 cache: dict[str, np.ndarray], table_hash: str, workers: WorkerSettings, session: Workers | None,
                 checkpoint_seconds: float, scenario: Scenario) -> None:
        self.target, self.job, self.keys, self.known, self.cache = target, job, keys, known, cache
        self.table_hash, self.workers, self.session = table_hash, workers, session
        self.checkpoint_seconds, self.scenario = checkpoint_seconds, scenario
        self.estimates: list[EdgeEstimate | None] = [known.get(bytes(k)) for k in keys]
        self.fresh: list[tuple[EdgeEstimate, np.ndarray]] = []  # estimates made by this run, with their keys
        self.converted: dict[str, np.ndarray] = {}  # the table of the edges checkpointed so far
        self.history: dict[bytes, EdgeEstimate] = {}  # every estimate of the table and the rounds, by key
        self.failed: dict[int, str] = {}
        self.estimated = self.simulated = self.saved = 0
        self._last = time.monotonic()

    # checkpoints
    def checkpoint(self) -> None:
        """Save the estimates made since the last checkpoint into ``/edge_cache`` (with the cache read)."""
        if len(self.fresh) > self.saved:
            batch = self.fresh[self.saved:]
            self.converted = concat_edge_tables(self.converted, to_arrays(
                [x for x, _ in batch], np.array([k for _, k in batch]), self.scenario.cost))
            write_edge_cache(self.target, concat_edge_tables(self.cache, self.converted),
                             {"controllers_sha256": self.table_hash})
            self.saved = len(self.fresh)

    def _maybe_checkpoint(self) -> None:
        # the first checkpoint comes after the first batch, the others every checkpoint_seconds; a
        # roadmap in memory (a query's, an update's, ft.build's without a file) outlives no crash, and
        # each checkpoint rewrote its whole image: only Ctrl-C's checkpoint is kept for it
        if isinstance(self.target, MemoryFile):
            return
        if not self.saved or time.monotonic() - self._last >= self.checkpoint_seconds:
            self.checkpoint()
            self._last = time.monotonic()

    def _run(self, job: EstimationJob, items: list[int], counter: Counter | None = None) -> Iterator[BatchResult]:
        s = self.workers
        return run_edges(job, items, workers=s.workers, executor=s.executor, scheduler=s.scheduler,
                         progress=counter.callback() if counter else None, session=self.session)

    # the first pass
    def first_pass(self, todo: list[int], counter: Counter | None) -> None:
        """Estimate the edges ``todo`` with ``estimation.particles`` particles each (Ctrl-C is raised
        only between batches, where the finished edges can be saved)."""
        for r in self._run(self.job, todo, counter):
            if r.error is not None:
                self.failed[r.edges[0]] = r.error
            for e, x in zip(r.edges, r.estimates):
                self.estimates[e] = x
                self.fresh.append((x, self.keys[e]))
                self.simulated += x.particle_steps
                self.estimated += 1
            self._maybe_checkpoint()
            interrupts.check()
        interrupts.check()
        self.history = {bytes(self.keys[e]): x for e, x in enumerate(self.estimates) if x is not None}

    # adaptive Monte Carlo
    def refine(self, n_nodes: int, kinds: np.ndarray) -> AdaptiveReport:
        """Adaptive rounds (:func:`firmtool.estimation.adaptive.refine`) on the first pass: particle
        blocks for the edges the DP's policy depends on. A refinement that failed keeps the edge's
        earlier estimate, so no edge is left out afterwards."""
        sc = self.scenario
        B, E = sc.estimation.particles, len(self.estimates)
        settings = AdaptiveSettings(
            target_halfwidth=sc.estimation.target_halfwidth,
            budget=int(sc.estimation.adaptive_particles if sc.estimation.adaptive_particles is not None else B * E),
            block_size=B, failure_cost=sc.cost.failure_cost)
        goals = np.flatnonzero(kinds == GOAL)
        refined, report = refine(self.estimates, self.keys, n_nodes, goals, sc.cost,  # type: ignore[arg-type]
                                 settings, sc.seed, self.run_blocks)
        self.estimates = list(refined)
        self.failed = {}
        interrupts.check()
        return report

    def _block_tasks(self, want: dict[int, int], current: list[EdgeEstimate]
                     ) -> tuple[dict[int, EdgeEstimate], list[tuple[int, int, int]], dict[int, EdgeEstimate]]:
        """The estimates of ``want`` found by key, and the (edge, blocks done, blocks to add) tasks of
        the others with the estimate each task goes on from (the largest stored block count on the way)."""
        B = self.scenario.estimation.particles
        found: dict[int, EdgeEstimate] = {}
        tasks: list[tuple[int, int, int]] = []
        start: dict[int, EdgeEstimate] = {}
        for e, n in sorted(want.items()):
            k_target, k_now = n // B, current[e].particles // B
            hit = self.known.get(bytes(blocks_key(self.keys[e], k_target)))
            if hit is not None:
                found[e] = hit
                continue
            begin, k0 = current[e], k_now
            for k in range(k_target - 1, k_now, -1):
                stored = self.known.get(bytes(blocks_key(self.keys[e], k)))
                if stored is not None:
                    begin, k0 = stored, k
                    break
            start[len(tasks)] = begin
            tasks.append((e, k0, k_target - k0))
        return found, tasks, start

    def run_blocks(self, want: dict[int, int], current: list[EdgeEstimate]) -> dict[int, EdgeEstimate]:
        """``want``'s edges with that many particles: their earlier blocks plus new ones (the
        ``run_blocks`` of :func:`firmtool.estimation.adaptive.refine`)."""
        B = self.scenario.estimation.particles
        out, tasks, start = self._block_tasks(want, current)
        block_job = dataclasses.replace(self.job, block_tasks=np.array(tasks, dtype=np.int64).reshape(-1, 3))
        for r in self._run(block_job, list(range(len(tasks)))):
            if r.error is not None:  # the edge keeps its particles so far
                self.failed[int(tasks[r.edges[0]][0])] = r.error
                continue
            for t, blocks in zip(r.edges, r.estimates):
                e = int(tasks[t][0])
                merged = start[t]
                for b in blocks:  # in block order: the same numbers however the work was split
                    merged = merge_estimates(merged, b)
                    self.simulated += b.particle_steps
                key = blocks_key(self.keys[e], merged.particles // B)
                out[e] = self.known[bytes(key)] = self.history[bytes(key)] = merged
                self.fresh.append((merged, key))
            self._maybe_checkpoint()
            interrupts.check()
        for e, x in out.items():
            self.history.setdefault(bytes(blocks_key(self.keys[e], x.particles // B)), x)
        return out

    # the result
    def tables(self) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray] | None]:
        """The new ``/edges`` table (the estimated edges, keyed by their block counts), and the
        estimates it does not hold, kept for reuse (the earlier blocks of the refined edges; None if none)."""
        sc = self.scenario
        done = [e for e, x in enumerate(self.estimates) if x is not None]
        final_keys = np.array([blocks_key(self.keys[e], self.estimates[e].particles  # type: ignore[union-attr]
                                          // sc.estimation.particles) for e in done]).reshape(-1, KEY_BYTES)
        arrays = to_arrays([self.estimates[e] for e in done], final_keys, sc.cost)
        final = {bytes(k) for k in final_keys}
        spare = [(x, np.frombuffer(k, dtype=np.uint8)) for k, x in self.history.items() if k not in final]
        spare_table = to_arrays([x for x, _ in spare], np.array([k for _, k in spare]).reshape(-1, KEY_BYTES),
                                sc.cost) if spare else None
        return arrays, spare_table
