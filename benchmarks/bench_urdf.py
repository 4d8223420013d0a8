"""The URDF arm (issue 38), in one run: its capsules against python-fcl on the exact link shapes, the
compiled engine against the numpy one on its edges, its Monte Carlo throughput against the planar
8-link arm's, and the shipped arm7_shelf scenario built, solved and executed.

    python benchmarks/bench_urdf.py                      # all four (about 8 minutes on 2 cores)
    python benchmarks/bench_urdf.py --configs 100000 --agree-edges 50 --episodes 400 --json

1. Conservative capsules: ``--configs`` configurations uniform in the joint ranges of
   scenarios/robots/arm7.urdf, in arm7_shelf's world; each decided by the capsules (the robot's
   collision model, numpy narrow phase) and by python-fcl on the links' exact shapes (cylinders,
   the gripper's box) against the obstacles. Reported: collisions fcl finds that the capsules miss
   (the target: none), the capsules' false alarms (colliding where the shapes are free, over the
   configurations the shapes are free in), and the cost per configuration of each test.
2. Engines agree: ``--agree-edges`` edges of arm7_shelf, each estimated by the numpy engine and by
   the compiled one with independent noise (``--agree-particles`` each); per edge, two-proportion z
   tests of the probability of landing at the edge's target and of failing, Holm's correction over
   all of them; reported: the smallest adjusted p-value and the number of rejections at 0.05.
3. Throughput: the edge Monte Carlo alone (``firmtool.estimation.edges.simulate``, one process, the
   scenario's particles, gains designed beforehand) on ``--edges`` edges of arm7_shelf and of
   arm8_lightdark, numpy and compiled engines, in the same run: particle-steps per second and
   their ratios.
4. arm7_shelf: ``ft.build`` (``--workers``), its wall time; FIRM's and the shortest path's predicted
   success; each executed ``--episodes`` times (common seeds) with Wilson 95% intervals.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, SCENARIOS, load, median_of, one_blas_thread  # noqa: E402

SHELF = ROOT / "scenarios" / "arm7_shelf.toml"
SCENARIOS.setdefault("arm7", SHELF)


def conservative(configs: int) -> dict:
    import firmtool as ft
    from firmtool.problem import build_problem
    robot = build_problem(ft.load_scenario(SHELF)).robot
    X = np.random.default_rng(38).uniform(robot.config_lo, robot.config_hi, size=(configs, robot.config_dim))
    C = robot.arm.radii.size
    t0 = time.perf_counter()
    P = robot.points(X)
    capsules = robot.collision()._collide_vectorised(P[:, 0:2 * C:2], P[:, 1:2 * C:2], robot.arm.radii)
    t_caps = time.perf_counter() - t0
    t0 = time.perf_counter()
    exact = robot.exact_collisions(X)
    t_exact = time.perf_counter() - t0
    from firmtool.geometry.backends import outside_workspace
    outside = outside_workspace(P[:, 0:2 * C:2], P[:, 1:2 * C:2], robot.arm.radii[:, None],
                                robot.collision().lo, robot.collision().hi)
    obstacle_capsules = capsules & ~outside  # the exact test leaves the bounds out: compared on obstacles only
    free = ~exact & ~outside
    return {"configs": configs, "exact_collisions": int((exact & ~outside).sum()),
            "missed": int((exact & ~capsules).sum()), "false_alarms": int((obstacle_capsules & free).sum()),
            "false_alarm_rate": float((obstacle_capsules & free).sum() / max(free.sum(), 1)),
            "outside_bounds": int(outside.sum()),
            "us_per_config_capsules": 1e6 * t_caps / configs, "us_per_config_exact_fcl": 1e6 * t_exact / configs}


def engines_agree(edges_count: int, particles: int) -> dict:
    from scipy.stats import norm

    from firmtool.estimation.edges import FAILURE, estimate_edge
    problem, d, regions = load("arm7")
    pick = np.sort(np.random.default_rng(5).choice(d.edge_source.size, min(edges_count, d.edge_source.size),
                                                   replace=False))
    pvalues, rows = [], []
    for e in pick:
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        est = {eng: estimate_edge(problem, d, regions, s, t, particles, seed, 256, engine=eng)
               for eng, seed in (("numpy", 11), ("numba", 12))}
        for what, code in (("target", t), ("failure", FAILURE)):
            k = {eng: int(r.counts[r.outcomes == code].sum()) for eng, r in est.items()}
            pooled = (k["numpy"] + k["numba"]) / (2 * particles)
            se = np.sqrt(max(pooled * (1 - pooled), 1e-300) * 2 / particles)
            z = (k["numpy"] - k["numba"]) / particles / se if 0 < pooled < 1 else 0.0
            pvalues.append(2 * norm.sf(abs(z)))
            rows.append((int(e), what, k["numpy"], k["numba"]))
    order = np.argsort(pvalues)
    m = len(pvalues)
    adjusted = np.maximum.accumulate([min(1.0, (m - i) * pvalues[j]) for i, j in enumerate(order)])
    return {"edges": int(pick.size), "particles": particles, "tests": m,
            "min_adjusted_p": float(adjusted.min()), "rejected_at_0.05": int((adjusted < 0.05).sum()),
            "landings": int(sum(r[2] + r[3] for r in rows if r[1] == "target")),
            "failures": int(sum(r[2] + r[3] for r in rows if r[1] == "failure"))}


def throughput(name: str, edges_count: int, repeat: int, engines: tuple[str, ...]) -> dict:
    from firmtool.estimation.edges import initial_ensemble, simulate
    from firmtool.roadmap.design import local_controller
    problem, d, regions = load(name)
    M = problem.scenario.estimation.particles
    pick = np.sort(np.random.default_rng(0).choice(d.edge_source.size, min(edges_count, d.edge_source.size),
                                                   replace=False))
    lcs = [local_controller(problem, d, int(d.edge_source[e]), int(d.edge_target[e])) for e in pick]
    starts = [initial_ensemble(problem, d, int(d.edge_source[e]), M, np.random.default_rng([1, e])) for e in pick]

    def run(eng: str) -> float:
        ps, t0 = 0, time.perf_counter()
        for e, lc, (x, xh) in zip(pick, lcs, starts):
            ps += int(simulate(problem, lc, regions, x.copy(), xh.copy(), np.random.default_rng([2, e]), eng).steps.sum())
        return ps / (time.perf_counter() - t0)

    out = {"edges": int(pick.size), "particles": M}
    for eng in engines:
        run(eng)  # warm-up: imports, the compiled kernel's cache
        out[eng] = median_of(lambda: run(eng), repeat)[0]
    return out


def shelf(workers: int, episodes: int) -> dict:
    import firmtool as ft
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        rm = ft.build(SHELF, workers=workers, output=Path(tmp) / "arm7_shelf.h5")
        build_s = time.perf_counter() - t0
        sol = ft.solve(rm)
        out = {"build_s": build_s, "workers": workers, "nodes": len(rm.nodes), "edges": len(rm.edges),
               "stage_s": {k: round(v, 1) for k, v in rm.report.seconds.items()}, "notices": list(rm.report.notices),
               "predicted": {"firm": sol.success_probability, "firm_ci95": list(sol.success_probability_ci95),
                             "shortest-path": sol.report.shortest_path_start_success_probability},
               "path": {"firm": sol.path(), "shortest-path": sol.path("shortest-path")}}
        for policy in ("firm", "shortest-path"):
            t0 = time.perf_counter()
            res = ft.simulate(sol, episodes=episodes, seed=0, policy=policy)
            out[f"executed_{policy}"] = {"success": res.success_rate, "ci95": list(res.ci95),
                                         "seconds": time.perf_counter() - t0}
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs", type=int, default=100_000)
    ap.add_argument("--edges", type=int, default=30)
    ap.add_argument("--agree-edges", type=int, default=50)
    ap.add_argument("--agree-particles", type=int, default=400)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--episodes", type=int, default=400)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    one_blas_thread()
    res = {"capsules": conservative(args.configs)}
    c = res["capsules"]
    print(f"capsules on {c['configs']} configurations: fcl finds {c['exact_collisions']} in an obstacle, the capsules "
          f"miss {c['missed']}; false alarms {c['false_alarms']} ({100 * c['false_alarm_rate']:.2f}% of the free ones); "
          f"{c['us_per_config_capsules']:.1f} us/config (capsules, numpy) vs {c['us_per_config_exact_fcl']:.1f} "
          "(exact shapes, fcl)", flush=True)
    res["agree"] = a = engines_agree(args.agree_edges, args.agree_particles)
    print(f"engines agree on {a['edges']} arm7_shelf edges ({a['particles']} particles each, {a['tests']} "
          f"two-proportion tests, Holm): smallest adjusted p {a['min_adjusted_p']:.3f}, rejected at 0.05: "
          f"{a['rejected_at_0.05']} ({a['landings']} landings, {a['failures']} failures in all)", flush=True)
    res["throughput"] = {"arm7": throughput("arm7", args.edges, args.repeat, ("numpy", "numba")),
                         "arm8": throughput("arm", args.edges, args.repeat, ("numpy", "numba"))}
    t7, t8 = res["throughput"]["arm7"], res["throughput"]["arm8"]
    print(f"throughput (1 process): arm7 numpy {t7['numpy'] / 1e6:.3f}, compiled {t7['numba'] / 1e6:.3f} M "
          f"particle-steps/s; arm8 numpy {t8['numpy'] / 1e6:.3f}, compiled {t8['numba'] / 1e6:.3f}; arm7 compiled / "
          f"numpy {t7['numba'] / t7['numpy']:.2f}, arm7/arm8 compiled {t7['numba'] / t8['numba']:.3f}", flush=True)
    res["shelf"] = s = shelf(args.workers, args.episodes)
    e, p = s["executed_firm"], s["executed_shortest-path"]
    print(f"arm7_shelf: built in {s['build_s']:.1f} s ({s['workers']} workers; {s['nodes']} nodes, {s['edges']} edges); "
          f"predicted FIRM {s['predicted']['firm']:.3f}, shortest path {s['predicted']['shortest-path']:.3f}; executed "
          f"({args.episodes} episodes) FIRM {e['success']:.3f} [{e['ci95'][0]:.3f}, {e['ci95'][1]:.3f}], shortest path "
          f"{p['success']:.3f} [{p['ci95'][0]:.3f}, {p['ci95'][1]:.3f}]", flush=True)
    if args.json:
        print(json.dumps(res, indent=2, default=float))
    return res


if __name__ == "__main__":
    main()
