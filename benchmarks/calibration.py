"""Calibration benchmark: predicted success probability vs executed success rate (issue 16, item 5).

For every scenario and seed: build (the scenario's seed replaced), solve, and execute ``--episodes``
undisturbed episodes of the FIRM policy from the start node (public API only: ``firmtool.build``,
``solve``, ``simulate``, so the benchmark runs unchanged when the success criterion changes).
Per case: the prediction with its stored 95% interval, the executed rate with its Wilson 95%
interval, whether the prediction lies in the executed interval, the difference, and the per-edge
calibration flags (Fisher's exact test, Holm). Summary: the fraction of cases whose prediction lies
in the executed interval, and the largest difference. ``--png`` draws a reliability diagram.

    python benchmarks/calibration.py --json out.json --png docs/results/reliability.png --markdown table.md
    python benchmarks/calibration.py --scenario scenarios/point_lightdark.toml --seeds 1 2 --episodes 800
    python benchmarks/calibration.py --start region      # node-region starts instead of the scenarios' own
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

SCENARIOS = [ROOT / "scenarios" / f"{name}.toml" for name in
             ("point_lightdark", "point_perfect", "maze_lightdark", "unicycle_lightdark", "unicycle_perfect",
              "arm8_lightdark")] + \
            [ROOT / "benchmarks" / "scenarios" / f"{name}.toml" for name in
             ("arm8_mirrored", "noisy_single_integrator", "goal_by_obstacle")]


def posterior_mean_prediction(rm, policy) -> float:
    """The start's success probability under ``policy`` with every edge's outcome probabilities at
    their posterior means (Dirichlet, prior 1/2 on every observed outcome and on failure): the
    conservative alternative to the plug-in frequencies (the winner's-curse check)."""
    import numpy as np
    import scipy.sparse

    from firmtool.estimation.calibration import posterior_rows
    from firmtool.graph.dp import success_probability

    E, N = rm.edges.shape[0], rm.nodes.shape[0]
    edge, code, alpha = posterior_rows(rm.edge_counts, np.arange(E))
    w = alpha / np.bincount(edge, weights=alpha, minlength=E)[edge]
    land = code >= 0
    landing = scipy.sparse.csr_matrix((w[land], (edge[land], code[land])), shape=(E, N))
    return float(success_probability(N, rm.goals, policy, landing)[0])


def run_case(path: Path, seed: int, episodes: int, workers: int, estimation: dict) -> dict:
    import firmtool as ft

    sc = ft.load_scenario(path).replace(seed=seed)
    if estimation:
        sc = sc.replace(estimation=estimation)
    t0 = time.perf_counter()
    rm = ft.build(sc, workers=workers)
    t_build = time.perf_counter() - t0
    sol = ft.solve(rm, allow_unreachable=True)
    if not sol.start_reachable:
        return {"scenario": sc.name, "seed": seed, "error": "the goal is unreachable from the start"}
    t0 = time.perf_counter()
    res = ft.simulate(sol, episodes=episodes, seed=seed, record=False)
    t_exec = time.perf_counter() - t0
    p = sol.success_probability
    lo, hi = res.ci95
    cal = res.calibration
    rep = rm.report
    return {"scenario": sc.name, "seed": seed, "nodes": int(rm.nodes.shape[0]), "edges": int(rm.edges.shape[0]),
            "particles": int(rm.particles.sum()),
            "adaptive_particles_added": rep.adaptive.particles_added if rep.adaptive else 0,
            "predicted": p, "predicted_ci95": list(sol.success_probability_ci95),
            "posterior_mean_predicted": posterior_mean_prediction(rm, sol.policy),
            "executed": res.success_rate, "executed_ci95": [lo, hi], "episodes": episodes,
            "inside": bool(lo <= p <= hi), "difference": p - res.success_rate,
            "edges_checked": cal.edges_checked if cal else 0,
            "flagged_edges": list(cal.flagged_edges) if cal else [],
            "build_seconds": t_build, "execute_seconds": t_exec}


def summary(cases: list[dict]) -> dict:
    ok = [c for c in cases if "error" not in c]
    inside = sum(c["inside"] for c in ok)
    inside_pm = sum(c["executed_ci95"][0] <= c["posterior_mean_predicted"] <= c["executed_ci95"][1] for c in ok)
    return {"cases": len(cases), "solved": len(ok), "inside": inside,
            "posterior_mean_inside": inside_pm,
            "posterior_mean_max_abs_difference": max((abs(c["posterior_mean_predicted"] - c["executed"]) for c in ok),
                                                     default=0.0),
            "posterior_mean_mean_difference": sum(c["posterior_mean_predicted"] - c["executed"] for c in ok) / len(ok)
            if ok else 0.0,
            "inside_fraction": inside / len(ok) if ok else 0.0,
            "max_abs_difference": max((abs(c["difference"]) for c in ok), default=0.0),
            "mean_difference": sum(c["difference"] for c in ok) / len(ok) if ok else 0.0,
            "flagged_cases": sum(bool(c["flagged_edges"]) for c in ok)}


def markdown(cases: list[dict], summ: dict) -> str:
    lines = ["| scenario | seed | nodes / edges | particles (adaptive +) | predicted (95% interval) | "
             "executed (Wilson 95%) | inside | difference | flagged edges |",
             "|---|---|---|---|---|---|---|---|---|"]
    for c in cases:
        if "error" in c:
            lines.append(f"| {c['scenario']} | {c['seed']} | - | - | - | - | - | - | {c['error']} |")
            continue
        lines.append(f"| {c['scenario']} | {c['seed']} | {c['nodes']} / {c['edges']} | {c['particles']:,} "
                     f"(+{c['adaptive_particles_added']:,}) | {c['predicted']:.3f} ({c['predicted_ci95'][0]:.3f}-"
                     f"{c['predicted_ci95'][1]:.3f}) | {c['executed']:.3f} ({c['executed_ci95'][0]:.3f}-"
                     f"{c['executed_ci95'][1]:.3f}) | {'yes' if c['inside'] else 'no'} | {c['difference']:+.3f} | "
                     f"{len(c['flagged_edges'])} of {c['edges_checked']} |")
    lines.append("")
    lines.append(f"Prediction inside the executed interval in {summ['inside']} of {summ['solved']} cases "
                 f"({100 * summ['inside_fraction']:.0f}%); largest difference {summ['max_abs_difference']:.3f}; "
                 f"mean difference (predicted - executed) {summ['mean_difference']:+.4f}.")
    return "\n".join(lines)


def diagram(cases: list[dict], path: Path, title: str) -> None:
    from matplotlib.figure import Figure

    ok = [c for c in cases if "error" not in c]
    fig = Figure(figsize=(4.2, 4.2), dpi=90)
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1], color="0.6", lw=1, zorder=0)
    names = sorted({c["scenario"] for c in ok})
    markers = "osD^vP*Xh<>"
    for k, name in enumerate(names):
        cs = [c for c in ok if c["scenario"] == name]
        x = [c["predicted"] for c in cs]
        y = [c["executed"] for c in cs]
        yerr = [[c["executed"] - c["executed_ci95"][0] for c in cs], [c["executed_ci95"][1] - c["executed"] for c in cs]]
        xerr = [[c["predicted"] - c["predicted_ci95"][0] for c in cs], [c["predicted_ci95"][1] - c["predicted"] for c in cs]]
        ax.errorbar(x, y, yerr=yerr, xerr=xerr, fmt=markers[k % len(markers)], ms=4, lw=0.8, capsize=1.5, label=name)
    ax.set_xlabel("predicted success probability")
    ax.set_ylabel("executed success rate (Wilson 95%)")
    ax.set_xlim(-0.02, 1.02)
    ax.set_ylim(-0.02, 1.02)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=6, loc="upper left")
    fig.tight_layout()
    fig.savefig(path)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", action="append", type=Path, help="scenario file (repeatable; default: the nine)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--episodes", type=int, default=800)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--start", choices=("center", "region"), help="estimation.start for every scenario")
    ap.add_argument("--target-halfwidth", type=float, help="estimation.target_halfwidth for every scenario")
    ap.add_argument("--adaptive-particles", type=int, help="estimation.adaptive_particles (0: uniform only)")
    ap.add_argument("--json", type=Path, help="write every case and the summary here")
    ap.add_argument("--png", type=Path, help="reliability diagram")
    ap.add_argument("--markdown", type=Path, help="results table")
    args = ap.parse_args(argv)
    from _common import one_blas_thread
    one_blas_thread()
    estimation = {k: v for k, v in (("start", args.start), ("target_halfwidth", args.target_halfwidth),
                                    ("adaptive_particles", args.adaptive_particles)) if v is not None}
    cases = []
    for path in args.scenario or SCENARIOS:
        for seed in args.seeds:
            c = run_case(path, seed, args.episodes, args.workers, estimation)
            cases.append(c)
            if "error" in c:
                print(f"{c['scenario']} seed {seed}: {c['error']}", flush=True)
            else:
                print(f"{c['scenario']} seed {seed}: predicted {c['predicted']:.4f} ({c['predicted_ci95'][0]:.4f}-"
                      f"{c['predicted_ci95'][1]:.4f}) executed {c['executed']:.4f} ({c['executed_ci95'][0]:.4f}-"
                      f"{c['executed_ci95'][1]:.4f}) inside {c['inside']} diff {c['difference']:+.4f} flagged "
                      f"{c['flagged_edges']} build {c['build_seconds']:.0f}s exec {c['execute_seconds']:.0f}s",
                      flush=True)
            if args.json:  # after every case: a long run can be followed and keeps what it did
                args.json.write_text(json.dumps({"settings": vars(args) | {"estimation": estimation},
                                                 "cases": cases, "summary": summary(cases)}, indent=1, default=str))
    summ = summary(cases)
    print(json.dumps(summ, indent=1))
    if args.markdown:
        args.markdown.write_text(markdown(cases, summ) + "\n")
    if args.png:
        diagram(cases, args.png, f"{summ['inside']} of {summ['solved']} inside, max |diff| "
                                 f"{summ['max_abs_difference']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
