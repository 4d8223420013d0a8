"""The compiled Monte Carlo engine against the machine: particle-steps/s, flops per particle-step, and
the fraction of the core's double-precision peak as numpy sees it, measured in the same run.

    python benchmarks/bench_peak.py [--robots point arm unicycle] [--particles 1000 200] [--edges 40]
                                    [--rounds 5] [--json]

Peak: numpy's single-threaded matrix product (threadpoolctl: one BLAS thread), float64, square
``--matmul`` (512) matrices, ``2 n^3`` flops per product; per round the best of a few products (the
peak is what the core can do, not what it does on average). Engine: the compiled engine's
``simulate`` (noise drawn in the kernel, as builds run it) over the same fixed random subset of a
shipped scenario's edges (the unicycle, which offers no compiled hooks, on the numpy engine), local controllers designed and their filter recursion run beforehand (so
the figure is the Monte Carlo: the kernel and its per-edge driver), one thread; particle-steps are
the particles' stopping steps summed. Rounds alternate the peak and the engine, and each round's
fraction is its engine flop rate over its own peak; reported are medians over rounds with their range,
and the 200- to 1000-particle throughput ratio per round.

Flops per particle-step, from the robot's dimensions (n states, m inputs, r process-noise inputs,
nz measurements, p key points, s capsules, o obstacles, c self-collision pairs), counted as a dense
implementation of the engine's step does them (a multiply-add is 2, a comparison, min, max, sqrt,
sin or cos 1; integer work of the random generator not counted):

==========================  ===============================================================
control                      ``n + 2 m n + m``              (x - x_ref, K dx, u_ref - .)
true step                    ``2 n^2 + 2 n m + 2 n r + 2 n`` (A x + B u + F w)
filter update                ``2 n^2 + 2 n m + n + 4 nz n + 8 nz + 2 n nz + n``
                             (prediction, H x and H x_pred, noise std at the true state,
                             innovation, correction L inn)
control effort               ``2 m``
kinematics                   ``8 p``                        (sin, cos, 2 multiply-adds, angle sum)
collision gate               ``4 p + 12 s o + 20 c``        (bounds; capsule boxes vs each box;
                             self pairs: AABB and bounding circles)
draws                        ``4 (r + nz)``                 (ziggurat: scale, sign, compare, store)
==========================  ===============================================================

The exact tests that run only where a gate passed, the goal and node-membership tests (per particle,
from the stabiliser phase on) are not counted: the figure is a lower bound on the work done. The
engine skips the exact zeros of A, B, H and K (:func:`firmtool.control.linalg.mat_rows`), so it does
fewer flops than counted; ``executed`` in the output counts the products by the matrices' nonzeros
instead, for reference. Peak fractions use the dense count (the issue's convention: ~3k flops for the
arm's particle-step).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, SCENARIOS, load, machine, one_blas_thread  # noqa: E402

SCENARIOS.setdefault("unicycle", ROOT / "scenarios" / "unicycle_lightdark.toml")


def matmul_peak(size: int = 512, products: int = 5) -> float:
    """The best flop rate of ``products`` single-threaded float64 products of two ``size`` square matrices."""
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((size, size)), rng.standard_normal((size, size))
    c = np.empty((size, size))
    np.matmul(a, b, out=c)  # warm
    best = np.inf
    for _ in range(products):
        t0 = time.perf_counter()
        np.matmul(a, b, out=c)
        best = min(best, time.perf_counter() - t0)
    return 2.0 * size ** 3 / best


def dimensions(problem) -> dict:
    """The dimensions the flop count reads (module notes) and the matrices' nonzeros."""
    model = problem.model
    hooks = problem.robot.compiled_kinematics()
    n_pts, n_seg, self_coll = (1, 1, False) if hooks is None else (hooks.n_points, hooks.segments[0],
                                                                   hooks.self_collision)
    n, m, r, nz = model.n, model.m, model.F.shape[1], (0 if problem.perfect else model.nz)
    self_pairs = sum(max(0, n_seg - a - 2) for a in range(n_seg)) if self_coll else 0
    dense = {"A": n * n, "B": n * m, "F": n * r, "H": nz * n}  # a nonlinear model: its Jacobians, dense
    nnz = {k: int(np.count_nonzero(getattr(model, k))) if hasattr(model, k) else dense[k] for k in dense}
    return dict(n=n, m=m, r=r, nz=nz, p=int(n_pts), s=int(n_seg), o=len(problem.scenario.world.obstacles),
                c=self_pairs, nnz=nnz)


def flops_per_particle_step(dim: dict, executed: bool = False) -> dict:
    """Flops of one particle-step by part (module notes); ``executed``: products by nonzeros (K, L dense)."""
    n, m, r, nz, p, s, o, c = (dim[k] for k in "n m r nz p s o c".split())
    nnz = dim["nnz"] if executed else {"A": n * n, "B": n * m, "F": n * r, "H": nz * n}
    parts = {
        "control": n + 2 * m * n + m,
        "true step": 2 * nnz["A"] + 2 * nnz["B"] + 2 * nnz["F"] + 2 * n,
        "filter": (2 * nnz["A"] + 2 * nnz["B"] + n + 4 * nnz["H"] + 8 * nz + 2 * n * nz + n) if nz else 0,
        "effort": 2 * m,
        "kinematics": 8 * p,
        "collision gate": 4 * p + 12 * s * o + 20 * c,
        "draws": 4 * (r + nz),
    }
    parts["total"] = sum(parts.values())
    return parts


def engine_case(name: str, edges_count: int, particles: int) -> dict:
    """A shipped scenario's fixed edge subset: controllers (recursion run), starts at ``particles``."""
    from firmtool.estimation.edges import initial_ensemble
    from firmtool.roadmap.design import local_controller
    problem, d, regions = load(name)
    edges = np.sort(np.random.default_rng(0).choice(d.edge_source.size, min(edges_count, d.edge_source.size),
                                                    replace=False))
    lcs = [local_controller(problem, d, int(d.edge_source[e]), int(d.edge_target[e])) for e in edges]
    for lc in lcs:
        lc.P  # the filter recursion outside the timing
    starts = [initial_ensemble(problem, d, int(d.edge_source[e]), particles, np.random.default_rng([1, e]))
              for e in edges]
    from firmtool.estimation.compiled import engine_choice
    return dict(problem=problem, regions=regions, edges=edges, lcs=lcs, starts=starts,
                engine=engine_choice(problem)[0])


def engine_rate(case: dict) -> float:
    """Particle-steps per second of the engine a build runs (the compiled one where it supports the
    problem, else numpy's) over the case's edges (wall time, one thread)."""
    from firmtool.estimation.edges import simulate
    ps, t0 = 0, time.perf_counter()
    for e, lc, (x, xh) in zip(case["edges"], case["lcs"], case["starts"]):
        out = simulate(case["problem"], lc, case["regions"], x.copy(), xh.copy(), np.random.default_rng([2, e]))
        ps += int(out.steps.sum())
    return ps / (time.perf_counter() - t0)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", nargs="+", default=["point", "arm", "unicycle"], choices=["point", "arm", "unicycle"])
    ap.add_argument("--particles", nargs="+", type=int, default=[1000, 200])
    ap.add_argument("--edges", type=int, default=40)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--matmul", type=int, default=512)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--result", action="store_true", help="also print RESULT key=value lines (benchmarks/compare.py)")
    args = ap.parse_args(argv)
    one_blas_thread()
    cases = {(rb, M): engine_case(rb, args.edges, M) for rb in args.robots for M in args.particles}
    for case in cases.values():
        engine_rate(case)  # compile / load the kernel, warm the caches
    flops = {rb: (dimensions(cases[rb, args.particles[0]]["problem"])) for rb in args.robots}
    counts = {rb: flops_per_particle_step(dim) for rb, dim in flops.items()}
    executed = {rb: flops_per_particle_step(dim, executed=True)["total"] for rb, dim in flops.items()}
    peaks, rates = [], {key: [] for key in cases}
    for r in range(args.rounds):
        keys = list(cases) if r % 2 == 0 else list(cases)[::-1]
        peak = [matmul_peak(args.matmul)]
        for key in keys:
            rates[key].append(engine_rate(cases[key]))
        peak.append(matmul_peak(args.matmul))
        peaks.append(max(peak))
    med = statistics.median
    rows = []
    for (rb, M), vals in rates.items():
        fr = [v * counts[rb]["total"] / p for v, p in zip(vals, peaks)]
        row = dict(robot=rb, particles=M, engine=cases[rb, M]["engine"], particle_steps_per_s=med(vals), flops=counts[rb]["total"],
                   executed_flops=executed[rb], fraction_of_peak=med(fr), fraction_range=[min(fr), max(fr)],
                   runs=vals)
        if M != args.particles[0]:
            ratio = [a / b for a, b in zip(vals, rates[rb, args.particles[0]])]
            row[f"ratio_to_{args.particles[0]}"] = med(ratio)
            row["ratio_range"] = [min(ratio), max(ratio)]
        rows.append(row)
    out = dict(machine=machine(), peak_gflops=med(peaks) / 1e9, peak_range=[min(peaks) / 1e9, max(peaks) / 1e9],
               flop_parts=counts, dimensions=flops, rows=rows, rounds=args.rounds, edges=args.edges)
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        print(f"peak (numpy matmul {args.matmul}, 1 thread): {out['peak_gflops']:.1f} GFLOP/s median "
              f"[{out['peak_range'][0]:.1f}, {out['peak_range'][1]:.1f}] over {args.rounds} rounds")
        for rb in args.robots:
            parts = ", ".join(f"{k} {v}" for k, v in counts[rb].items() if k != "total")
            print(f"{rb}: {counts[rb]['total']} flops per particle-step (executed {executed[rb]}): {parts}")
        for row in rows:
            extra = ""
            if "ratio_range" in row:
                k = next(k for k in row if k.startswith("ratio_to_"))
                extra = (f"; {k.replace('_', ' ')} {row[k]:.3f} [{row['ratio_range'][0]:.3f}, "
                         f"{row['ratio_range'][1]:.3f}]")
            print(f"{row['robot']:9s} {row['particles']:5d} particles/edge ({row['engine']} engine): "
                  f"{row['particle_steps_per_s'] / 1e6:.2f} M particle-steps/s, fraction of peak "
                  f"{row['fraction_of_peak']:.3f} [{row['fraction_range'][0]:.3f}, {row['fraction_range'][1]:.3f}]{extra}")
    if args.result:
        tokens = [f"peak_gflops={out['peak_gflops']}"]
        for row in rows:
            key = f"{row['robot']}_{row['particles']}"
            tokens += [f"{key}_Mps={row['particle_steps_per_s'] / 1e6}", f"{key}_fraction={row['fraction_of_peak']}"]
            tokens += [f"{key}_ratio={row[k]}" for k in row if k.startswith("ratio_to_")]
        print("RESULT " + " ".join(tokens))
    return out


if __name__ == "__main__":
    main()
