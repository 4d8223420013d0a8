"""Landmark sensing and the unicycle's compiled engine (issues 50 and 55 item 4), ratios in one run.

    nice -n 10 python benchmarks/bench_landmarks.py        # ROUNDS=5 EDGES=12 PARTICLES=300 by default

1. The unicycle, compiled against numpy: ``unicycle_lightdark`` (its nodes reduced to 20), the SAME
   edges (controllers, start ensembles, seeds) run by the numpy engine and the compiled one (its own
   noise, as in builds), one worker, rounds alternating the order. Target (issue 55): compiled at
   least 5x numpy.
2. Landmark sensing with occlusion against the light-dark sensor: the same world, nodes and edges
   (each sensor's own controllers, designed on the same node centres), 20 landmarks seen through
   the walls rasterised into a 0.05 m occupancy grid (the ray march), against the scenario's own
   light-dark sensor; compiled engine, one worker, for the unicycle and for the point robot
   (``point_lightdark``). Target (issue 50): landmarks at least 0.5 of the light-dark rate.

Reported: particle-steps per second, the median over rounds, and the median [min, max] of the
per-round ratio (each from one round, the same machine state).
"""

from __future__ import annotations

import dataclasses
import os
import re
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import one_blas_thread  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
LANDMARKS_20 = [[x, y] for x in (0.3, 2.8, 5.2, 7.6, 9.7) for y in (0.3, 2.0, 4.0, 5.7)]  # 20, beside the walls


def _text(name: str, nodes: int, landmarks: bool) -> str:
    text = (ROOT / "scenarios" / f"{name}.toml").read_text()
    text = re.sub(r"(?m)^nodes = .*$", f"nodes = {nodes}", text)
    if landmarks:
        m = re.search(r"(?s)\[measurement\].*?\n\n", text)
        text = text[:m.start()] + ('[measurement]\nkind = "imperfect"\nmodel = "landmarks"\n'
                                   f"landmarks = {LANDMARKS_20}\nmax_range = 4.0\nrange_std = 0.03\n"
                                   "range_std_growth = 0.02\nbearing_std = 0.03\n\n") + text[m.end():]
    return text


def _grid(problem, res: float = 0.05):
    """The scenario's boxes as an occupancy grid of ``res`` cells (a cell is occupied where its square
    meets a box), for the landmark model's occlusion."""
    from firmtool.models.landmarks import OcclusionGrid

    w = problem.scenario.world
    cols, rows = int(round((w.hi[0] - w.lo[0]) / res)), int(round((w.hi[1] - w.lo[1]) / res))
    xe, ye = w.lo[0] + np.arange(cols + 1) * res, w.lo[1] + np.arange(rows + 1) * res
    occ = np.zeros((rows, cols), dtype=np.uint8)
    for o in w.obstacles:
        lo, hi = np.array(o.center) - o.half_size, np.array(o.center) + o.half_size
        occ[np.ix_((ye[1:] >= lo[1]) & (ye[:-1] <= hi[1]), (xe[1:] >= lo[0]) & (xe[:-1] <= hi[0]))] = 1
    return OcclusionGrid(occ, res, (w.lo[0], w.lo[1]))


def _problems(name: str, nodes: int):
    from firmtool.problem import build_problem
    from firmtool.roadmap.design import design, unstabilisable_nodes
    from firmtool.roadmap.nodes import roadmap_nodes
    from firmtool.scenario import parse_scenario

    dark = build_problem(parse_scenario(_text(name, nodes, False), f"{name}.toml"))
    lm = build_problem(parse_scenario(_text(name, nodes, True), f"{name}_landmarks.toml"))
    model = dataclasses.replace(lm.model, grid=_grid(lm))
    lm.robot.model = model
    lm = dataclasses.replace(lm, model=model)
    centers, kinds = roadmap_nodes(dark, np.random.default_rng(0))
    bad, _ = unstabilisable_nodes(lm, centers, kinds)
    keep = np.ones(centers.shape[0], dtype=bool)
    keep[bad] = False
    centers, kinds = centers[keep], kinds[keep]
    return (dark, design(dark, centers, kinds)), (lm, design(lm, centers, kinds))


def _runner(problem, d, edges, particles):
    from firmtool.estimation.edges import initial_ensemble, simulate
    from firmtool.roadmap.design import local_controller

    regions = d.regions(problem)
    lcs = [local_controller(problem, d, int(d.edge_source[e]), int(d.edge_target[e])) for e in edges]
    for lc in lcs:
        lc.P  # the filter recursion outside the timing
    starts = [initial_ensemble(problem, d, int(d.edge_source[e]), particles, np.random.default_rng([1, e]))
              for e in edges]

    def run(engine):
        steps, t0 = 0, time.perf_counter()
        for e, lc, (x, xh) in zip(edges, lcs, starts):
            o = simulate(problem, lc, regions, x.copy(), xh.copy(), np.random.default_rng([2, e]), engine)
            steps += int(o.steps.sum())
        return steps / (time.perf_counter() - t0)

    return run


def _ab(label: str, a, b, rounds: int) -> None:
    """``a`` and ``b`` (() -> rate), rounds alternating; prints the medians and the ratio b / a."""
    a(), b()  # compile / warm
    ra, rb = [], []
    for r in range(rounds):
        for which in ((0, 1) if r % 2 == 0 else (1, 0)):
            (ra if which == 0 else rb).append((a if which == 0 else b)())
    ratio = [y / x for x, y in zip(ra, rb)]
    print(f"{label}: {statistics.median(ra) / 1e6:.3f} vs {statistics.median(rb) / 1e6:.3f} M particle-steps/s; "
          f"ratio {statistics.median(ratio):.2f} [{min(ratio):.2f}, {max(ratio):.2f}]", flush=True)


def main() -> None:
    one_blas_thread()
    rounds, n_edges, particles = (int(os.environ.get(k, v)) for k, v in
                                  (("ROUNDS", "5"), ("EDGES", "12"), ("PARTICLES", "300")))
    print(f"load average before {os.getloadavg()[0]:.2f}", flush=True)
    for name in ("unicycle_lightdark", "point_lightdark"):
        (dark, dd), (lm, dl) = _problems(name, 20)
        pairs = set(zip(dd.edge_source.tolist(), dd.edge_target.tolist())) & \
            set(zip(dl.edge_source.tolist(), dl.edge_target.tolist()))
        pairs = sorted(pairs)[:n_edges]
        ed = [int(np.flatnonzero((dd.edge_source == s) & (dd.edge_target == t))[0]) for s, t in pairs]
        el = [int(np.flatnonzero((dl.edge_source == s) & (dl.edge_target == t))[0]) for s, t in pairs]
        run_dark, run_lm = _runner(dark, dd, ed, particles), _runner(lm, dl, el, particles)
        if name.startswith("unicycle"):
            _ab(f"{name}, {len(ed)} edges x {particles}: numpy engine vs compiled (ratio compiled / numpy)",
                lambda: run_dark("numpy"), lambda: run_dark("numba"), rounds)
        _ab(f"{name}, {len(ed)} edges x {particles}, compiled: light-dark vs 20 landmarks with occlusion "
            "(ratio landmarks / light-dark)", lambda: run_dark("numba"), lambda: run_lm("numba"), rounds)
    print(f"load average after {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
