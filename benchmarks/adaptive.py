"""Adaptive Monte Carlo vs a uniform allocation reaching the same half-width (issue 16, item 2).

For each scenario: a default build (uniform first pass, then adaptive rounds until the 95% interval
of the start's success probability is at most +-``estimation.target_halfwidth``), then uniform
builds (``adaptive_particles = 0``) with the per-edge particles doubled from the scenario's until
their interval is as narrow as the adaptive one's. Reported per build: particles per edge, total
particles, particle-steps, the start's success probability, its interval's half-width, wall time.
If the largest uniform build tried is still wider, the particles it would need are extrapolated
from the half-width's 1/sqrt(n) law (marked so).

    python benchmarks/adaptive.py --scenario scenarios/point_lightdark.toml --max-particles 9600
    python benchmarks/adaptive.py --scenario scenarios/arm8_lightdark.toml --max-particles 800 --json out.json
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def run(path: Path, out: Path, workers: int, **estimation) -> dict:
    import firmtool as ft
    from firmtool.pipeline import build, solve_stage

    sc = ft.load_scenario(path)
    if estimation:
        sc = sc.replace(estimation=estimation)
    t0 = time.perf_counter()
    report = build(sc, out, workers=workers, fresh=True)
    seconds = time.perf_counter() - t0
    sol = solve_stage(out)
    lo, hi = sol.start_success_probability_ci95
    from firmtool.io.roadmap_file import RoadmapFile
    e = RoadmapFile(out).require("edges", "particles", "particle_steps")
    return {"particles_per_edge_first_pass": sc.estimation.particles, "edges": report.edges,
            "particles": int(e["particles"].sum()), "particle_steps": int(e["particle_steps"].sum()),
            "p": sol.start_success_probability, "ci95": [lo, hi], "halfwidth": 0.5 * (hi - lo),
            "seconds": seconds, "adaptive_rounds": len(report.adaptive.rounds) - 1 if report.adaptive else 0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", action="append", required=True, help="scenario file (repeatable)")
    ap.add_argument("--max-particles", type=int, default=10_000, help="largest uniform particles per edge tried")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", type=Path, help="write the results here")
    args = ap.parse_args(argv)
    from _common import one_blas_thread
    one_blas_thread()
    results = {}
    with tempfile.TemporaryDirectory(prefix="firmtool-adaptive-") as tmp:
        for path in map(Path, args.scenario):
            import firmtool as ft
            base = ft.load_scenario(path).estimation.particles
            adaptive = run(path, Path(tmp) / "a.h5", args.workers)
            print(f"{path.stem}: adaptive  {adaptive}", flush=True)
            uniform = []
            n = base
            while n <= args.max_particles:
                u = run(path, Path(tmp) / f"u{n}.h5", args.workers, particles=n, adaptive_particles=0)
                u["particles_per_edge"] = n
                uniform.append(u)
                print(f"{path.stem}: uniform {n:6d}  {u}", flush=True)
                if u["halfwidth"] <= adaptive["halfwidth"]:
                    break
                n *= 2
            last = uniform[-1]
            reached = last["halfwidth"] <= adaptive["halfwidth"]
            needed = last["particles"] if reached else \
                last["particles"] * (last["halfwidth"] / adaptive["halfwidth"]) ** 2
            results[path.stem] = {"adaptive": adaptive, "uniform": uniform, "uniform_reached": reached,
                                  "uniform_particles_needed": needed,
                                  "uniform_particles_needed_is": "measured" if reached else "extrapolated (1/sqrt(n))",
                                  "ratio": needed / adaptive["particles"]}
            print(f"{path.stem}: adaptive {adaptive['particles']:,} particles (half-width "
                  f"{adaptive['halfwidth']:.4f}); uniform {'reached it with' if reached else 'would need ~'} "
                  f"{needed:,.0f} particles: x{needed / adaptive['particles']:.1f}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
