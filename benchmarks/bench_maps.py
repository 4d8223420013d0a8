"""Occupancy maps (issue 50): the Monte Carlo engine on a 400 x 400 map against the same world written as
boxes, and ``firmtool check`` on a map scenario.

    nice -n 10 python benchmarks/bench_maps.py              # ROUNDS=9 EDGES=40 PARTICLES=300 by default

Engine A/B: the shipped ``point_lightdark`` scenario (double-integrator point robot, 5 boxes, bounds
10 x 6 m) is sampled and designed once; its boxes are rasterised into a 400 x 400 map of 0.025 m cells
(10 x 10 m; a cell is occupied where its square meets a box), and the same scenario with ``map =`` that
map, no boxes and the same bounds is the B world. Both problems run the SAME edges (controllers, node
regions, start ensembles, random seeds) with one worker, rounds alternating the order; reported:
particle-steps per second of each, median over rounds, and the median [min, max] of the per-round ratio
map / boxes (each ratio from one round, i.e. the same machine state). Per engine: compiled (the kernel's
own noise, as in builds) and numpy. Target: ratio >= 0.8 (compiled engine, 1 worker).

check: ``firmtool check`` on the map scenario in a subprocess, warm (the first run not counted), wall
time median of 5. Target: < 2 s.
"""

from __future__ import annotations

import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import _TMP, SCENARIOS, designed_roadmap, one_blas_thread  # noqa: E402

CELLS, RES = 400, 0.025


def rasterise(obstacles, cells: int = CELLS, res: float = RES) -> np.ndarray:
    """(cells, cells) bool, row 0 the bottom: True where the cell's square meets a (axis-aligned) box."""
    edges = np.arange(cells + 1) * res
    grid = np.zeros((cells, cells), dtype=bool)
    for o in obstacles:
        lo, hi = np.array(o.center) - o.half_size, np.array(o.center) + o.half_size
        cols = (edges[1:] >= lo[0]) & (edges[:-1] <= hi[0])
        rows = (edges[1:] >= lo[1]) & (edges[:-1] <= hi[1])
        grid[np.ix_(rows, cols)] = True
    return grid


def map_scenario(folder: Path) -> Path:
    """point_lightdark with its boxes as a 400 x 400 map (PGM, image top row = map top)."""
    import firmtool as ft
    sc = ft.load_scenario(SCENARIOS["point"])
    grid = rasterise(sc.world.obstacles)
    img = np.where(grid[::-1], 0, 254).astype(np.uint8)
    (folder / "bench_map.pgm").write_bytes(b"P5\n%d %d\n255\n" % (CELLS, CELLS) + img.tobytes())
    (folder / "bench_map.yaml").write_text(f"image: bench_map.pgm\nresolution: {RES}\norigin: [0.0, 0.0, 0.0]\n")
    text = SCENARIOS["point"].read_text()
    text = re.sub(r"(?ms)^obstacles = \[.*?^\]\n", 'map = "bench_map.yaml"\n', text)
    text = text.replace('collision_backend = "numba"', 'collision_backend = "numpy"')
    path = folder / "point_map.toml"
    path.write_text(text)
    return path


def engine_ab(rounds: int, n_edges: int, particles: int, map_path: Path) -> None:
    import firmtool as ft
    from firmtool.estimation.edges import initial_ensemble, simulate
    from firmtool.io.roadmap_file import RoadmapFile
    from firmtool.pipeline import design_of, problem_of
    from firmtool.problem import build_problem
    from firmtool.roadmap.design import local_controller

    rm = RoadmapFile(designed_roadmap("point"))
    boxes, d = problem_of(rm), design_of(rm)
    mapped = build_problem(ft.load_scenario(map_path))
    assert mapped.scenario.world.grid.shape == (CELLS, CELLS) and not mapped.scenario.world.obstacles
    regions = d.regions(boxes)
    edges = np.sort(np.random.default_rng(0).choice(d.edge_source.size, min(n_edges, d.edge_source.size), replace=False))
    lcs = [local_controller(boxes, d, int(d.edge_source[e]), int(d.edge_target[e])) for e in edges]
    for lc in lcs:
        lc.P  # the filter recursion outside the timing
    starts = [initial_ensemble(boxes, d, int(d.edge_source[e]), particles, np.random.default_rng([1, e])) for e in edges]

    def run(problem, engine):
        steps, failed, t0, c0 = 0, 0, time.perf_counter(), time.thread_time()
        for e, lc, (x, xh) in zip(edges, lcs, starts):
            o = simulate(problem, lc, regions, x.copy(), xh.copy(), np.random.default_rng([2, e]), engine)
            steps += int(o.steps.sum())
            failed += int((o.outcome == -1).sum())
        return steps, time.perf_counter() - t0, time.thread_time() - c0, failed

    for engine in ("numba", "numpy"):
        for p in (boxes, mapped):
            run(p, engine)  # compile / warm
        rates = {(w, c): [] for w in ("boxes", "map") for c in ("wall", "cpu")}
        for r in range(rounds):
            order = [("boxes", boxes), ("map", mapped)]
            for name, p in (order if r % 2 == 0 else order[::-1]):
                steps, seconds, cpu, failed = run(p, engine)
                rates[name, "wall"].append(steps / seconds)
                rates[name, "cpu"].append(steps / cpu)
        for clock in ("cpu", "wall"):
            ratio = [m / b for m, b in zip(rates["map", clock], rates["boxes", clock])]
            print(f"{engine:5s} engine, {edges.size} edges x {particles} particles, {rounds} rounds, {clock:4s} time: "
                  f"boxes {statistics.median(rates['boxes', clock]) / 1e6:.3f} M particle-steps/s, "
                  f"map {statistics.median(rates['map', clock]) / 1e6:.3f} M/s; ratio map/boxes "
                  f"{statistics.median(ratio):.3f} [{min(ratio):.3f}, {max(ratio):.3f}]")


def check_time(map_path: Path, runs: int = 5) -> None:
    """Wall and CPU (user + sys of the child) seconds of ``firmtool check``: the map scenario and, in
    the same rounds, the shipped box scenario it was made from (the load of the shared machine moves
    the wall time; the ratio and the CPU time say what the map costs)."""
    cmds = {"map": [sys.executable, "-m", "firmtool", "check", str(map_path)],
            "boxes": [sys.executable, "-m", "firmtool", "check", str(SCENARIOS["point"])]}
    for cmd in cmds.values():
        subprocess.run(cmd, check=True, capture_output=True)  # warm: numba's and Python's caches
    wall = {k: [] for k in cmds}
    cpu = {k: [] for k in cmds}
    for _ in range(runs):
        for name, cmd in cmds.items():
            before = os.times()
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            wall[name].append(time.perf_counter() - t0)
            after = os.times()
            cpu[name].append(after.children_user - before.children_user + after.children_system - before.children_system)
    for name in cmds:
        print(f"firmtool check, {name:5s} scenario{' (400 x 400 map)' if name == 'map' else ''}, warm, {runs} runs: "
              f"wall median {statistics.median(wall[name]):.2f} s [{min(wall[name]):.2f}, {max(wall[name]):.2f}], "
              f"CPU median {statistics.median(cpu[name]):.2f} s")


def main() -> None:
    one_blas_thread()
    rounds = int(os.environ.get("ROUNDS", "9"))
    print(f"load average before {os.getloadavg()[0]:.2f}")
    path = map_scenario(_TMP)
    check_time(path)
    engine_ab(rounds, int(os.environ.get("EDGES", "40")), int(os.environ.get("PARTICLES", "300")), path)
    print(f"load average after {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
