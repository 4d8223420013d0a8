"""Connected roadmaps on any seed (issue 16, item 1): a per-seed table of builds.

For each seed: ``firmtool build`` (the scenario's seed replaced; the connection stage on, as by
default), then ``solve``. Per seed: nodes (and how many the connection stage added), goal nodes in
the start's component and reachable under the estimated edges, the goal families they belong to,
the predicted success probability, and the build time. For the planar arm scenarios a goal node's
family is the passage its body takes through the row of bars (L or R: where its links cross the
bars' height), so the table says whether the goal is reached through both passages; for other
scenarios the family column is empty.

    python benchmarks/connectivity.py --scenario scenarios/arm8_lightdark.toml --seeds 1 2 3 4 5 6 7 8 9 10
    python benchmarks/connectivity.py --scenario benchmarks/scenarios/arm8_mirrored.toml --markdown t.md
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def passage(problem, q: np.ndarray) -> str:
    """L or R: the side of the central bar where the arm's links cross the bars' height (the x of the
    first crossing of the row of obstacles), '?' if they do not cross it."""
    obstacles = problem.scenario.world.obstacles
    y = float(np.mean([o.center[1] for o in obstacles]))
    P = problem.geometry.points(q[None])[0]
    xs = [p0[0] + (y - p0[1]) / (p1[1] - p0[1]) * (p1[0] - p0[0])
          for p0, p1 in zip(P[:-1], P[1:]) if (p0[1] - y) * (p1[1] - y) < 0]
    if not xs:
        return "?"
    return "L" if xs[0] < 0 else "R"


def run(path: Path, seed: int, workers: int) -> dict:
    import firmtool as ft

    sc = ft.load_scenario(path).replace(seed=seed)
    t0 = time.perf_counter()
    rm = ft.build(sc, workers=workers)
    seconds = time.perf_counter() - t0
    c = rm.report.connectivity
    problem = rm.problem
    arm = problem.goal_disc is not None
    family = {int(g): passage(problem, rm.nodes[g]) if arm else "" for g in c.goal_nodes}
    sol = ft.solve(rm, allow_unreachable=True)  # an unsolvable seed is a row of the table, not an error
    reach = c.reachable_goal_nodes or ()
    return {"seed": seed, "nodes": int(rm.nodes.shape[0]), "connect_added": c.added_nodes,
            "goal_nodes": len(c.goal_nodes), "connected_goal_nodes": len(c.connected_goal_nodes),
            "reachable_goal_nodes": len(reach),
            "goal_families": "".join(sorted(set(family.values()))),
            "reachable_families": "".join(sorted({family[g] for g in reach})),
            "both_passages": arm and {"L", "R"} <= {family[g] for g in reach},
            "solvable": bool(sol.start_reachable), "predicted": sol.success_probability,
            "predicted_ci95": list(sol.success_probability_ci95), "policy_passage":
                passage(problem, rm.nodes[sol.path()[-1]]) if arm and sol.start_reachable
                else "",
            "build_seconds": seconds, "sample_seconds": rm.report.seconds["sample"], "missing": list(c.missing)}


def markdown(name: str, rows: list[dict]) -> str:
    lines = [f"`{name}`:", "",
             "| seed | nodes (connection +) | goal nodes connected / reachable of | goal families reachable | "
             "both passages | predicted success (95%) | policy's passage | build (sample) s |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['seed']} | {r['nodes']} (+{r['connect_added']}) | {r['connected_goal_nodes']} / "
                     f"{r['reachable_goal_nodes']} of {r['goal_nodes']} | {r['reachable_families'] or '-'} | "
                     f"{'yes' if r['both_passages'] else 'no'} | {r['predicted']:.3f} ({r['predicted_ci95'][0]:.3f}-"
                     f"{r['predicted_ci95'][1]:.3f}) | {r['policy_passage'] or '-'} | {r['build_seconds']:.0f} "
                     f"({r['sample_seconds']:.0f}) |")
    both = sum(r["both_passages"] for r in rows)
    solv = sum(r["solvable"] for r in rows)
    full = sum(r["connected_goal_nodes"] == r["goal_nodes"] for r in rows)
    lines += ["", f"Solvable {solv} of {len(rows)}; every goal node connected {full} of {len(rows)}; goal reached "
                  f"through both passages {both} of {len(rows)}."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", type=Path, required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--markdown", type=Path)
    args = ap.parse_args(argv)
    from _common import one_blas_thread
    one_blas_thread()
    rows = []
    for seed in args.seeds:
        r = run(args.scenario, seed, args.workers)
        rows.append(r)
        print(json.dumps({k: v for k, v in r.items() if k != "missing"}), flush=True)
        for m in r["missing"]:
            print("   missing:", m, flush=True)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=1))
    text = markdown(args.scenario.stem, rows)
    print(text)
    if args.markdown:
        args.markdown.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
