"""Edge Monte Carlo throughput (particle-steps per second) on the arm and on the point robot.

    python benchmarks/bench_edges.py [--edges 60] [--repeat 5] [--json]

Two measurements per robot, on the same fixed random subset of the scenario's edges:

* engine: ``firmtool.estimation.edges.simulate`` alone (gains designed beforehand), one process: the numpy
  path, the compiled kernel fed numpy's noise (``numpy_noise=True``: exactly the numpy path's
  particles) and the compiled kernel as it runs in builds (noise drawn in the kernel);
* estimate: ``parallel.run_edges`` end to end (per edge: the local controller's gains, node
  candidates, then the Monte Carlo), 1 and 2 worker processes, scenario particle counts; the
  numpy path on 5x ``--edges`` edges, the compiled engine on 25x.

Medians of ``--repeat`` runs; speed-ups are ratios of medians taken in the same run.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
from _common import engine, load, median_of, one_blas_thread  # noqa: E402


def _edges(d, count: int, seed: int = 0) -> np.ndarray:
    return np.sort(np.random.default_rng(seed).choice(d.edge_source.size, min(count, d.edge_source.size), replace=False))


def engine_throughput(name: str, edges_count: int, repeat: int, particles: int | None = None) -> dict:
    from firmtool.estimation.edges import initial_ensemble, simulate
    from firmtool.roadmap.design import local_controller
    problem, d, regions = load(name)
    M = particles or problem.scenario.estimation.particles
    edges = _edges(d, edges_count)
    lcs = [local_controller(problem, d, int(d.edge_source[e]), int(d.edge_target[e])) for e in edges]
    starts = [initial_ensemble(problem, d, int(d.edge_source[e]), M, np.random.default_rng([1, e])) for e in edges]

    def run(variant: str) -> float:
        eng, numpy_noise = {"numpy": ("numpy", False), "numba_numpy_noise": ("numba", True),
                            "numba": ("numba", False)}[variant]
        ps, t0 = 0, time.perf_counter()
        for e, lc, (x, xh) in zip(edges, lcs, starts):
            out = simulate(problem, lc, regions, x.copy(), xh.copy(), np.random.default_rng([2, e]), eng, numpy_noise)
            ps += int(out.steps.sum())
        return ps / (time.perf_counter() - t0)

    run("numba")  # compile / load the cache outside the timing
    res = {}
    for variant in ("numpy", "numba_numpy_noise", "numba"):
        med, vals = median_of(lambda: run(variant), repeat)
        res[variant] = {"median": med, "runs": vals}
    res["speedup"] = res["numba"]["median"] / res["numpy"]["median"]
    res.update(edges=int(edges.size), particles=M)
    return res


def estimate_throughput(name: str, edges_count: int, repeat: int, workers: int, eng: str) -> dict:
    from _common import designed_roadmap

    from firmtool.estimation.executors import EstimationJob, run_edges
    from firmtool.io.roadmap_file import RoadmapFile
    problem, d, _ = load(name)
    sc = problem.scenario
    rm = RoadmapFile(designed_roadmap(name))
    edges = _edges(d, edges_count).tolist()
    job = EstimationJob(scenario_text=rm.scenario_text, scenario_path=str(rm.path), design=d,
                        particles=sc.estimation.particles, chunk=sc.estimation.chunk, seed=sc.seed)

    def run() -> float:
        t0 = time.perf_counter()
        ps = sum(e.particle_steps for r in run_edges(job, edges, workers=workers) for e in r.estimates)
        return ps / (time.perf_counter() - t0)

    with engine(eng):
        run()  # warm-up (numba cache, imports)
        med, vals = median_of(run, repeat)
    return {"median": med, "runs": vals, "edges": len(edges), "workers": workers, "engine": eng,
            "particles": sc.estimation.particles}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--edges", type=int, default=60)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--robots", nargs="+", default=["arm", "point"], choices=("arm", "point"))
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="estimate rows (numba engine)")
    ap.add_argument("--no-numpy-estimate", action="store_true", help="skip the numpy engine's estimate row")
    args = ap.parse_args(argv)
    one_blas_thread()
    out = {}
    rows = ([] if args.no_numpy_estimate else [(1, "numpy")]) + [(w, "numba") for w in args.workers]
    for name in args.robots:
        out[name] = {"engine": engine_throughput(name, args.edges, args.repeat),
                     "engine_1000_particles": engine_throughput(name, max(10, args.edges // 4), args.repeat, 1000),
                     # the compiled rows on 25x --edges: a 2-worker pool's start-up (~0.1-0.5 s) must be
                     # small against the run (200 arm edges take ~0.5 s now)
                     "estimate": [estimate_throughput(name, args.edges * (5 if e == "numpy" else 25), args.repeat, w, e)
                                  for w, e in rows]}
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        for name, r in out.items():
            for key in ("engine", "engine_1000_particles"):
                g = r[key]
                print(f"{name:5s} {key:22s} numpy {g['numpy']['median'] / 1e6:6.3f} M/s  numba, numpy's noise "
                      f"{g['numba_numpy_noise']['median'] / 1e6:6.3f} M/s  numba {g['numba']['median'] / 1e6:6.3f} M/s  "
                      f"x{g['speedup']:.2f}  ({g['edges']} edges x {g['particles']})")
            for g in r["estimate"]:
                print(f"{name:5s} estimate {g['engine']:5s} {g['workers']} worker(s) {g['median'] / 1e6:6.3f} M/s "
                      f"({g['edges']} edges x {g['particles']})")
        print("RESULT " + " ".join(
            [f"{n}_engine_{e}={r[key][e]['median']}" for n, r in out.items() for key in ("engine",)
             for e in ("numpy", "numba_numpy_noise", "numba")]
            + [f"{n}_engine1000_numba={r['engine_1000_particles']['numba']['median']}" for n, r in out.items()]
            + [f"{n}_estimate_{g['engine']}_w{g['workers']}={g['median']}" for n, r in out.items() for g in r["estimate"]]))
    return out


if __name__ == "__main__":
    main()
