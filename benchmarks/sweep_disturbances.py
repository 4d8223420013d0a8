"""Recovery at any moment: success against the time of a push (two sizes) or a kidnap, with and
without replanning (and with an oracle detector, and one told when a push hit), on the point robot, the arm and the unicycle (issue 17),
and on a user's robot nobody tuned for (``--robots flyer``: the 3-D flyer of examples/custom_robot_3d.py, built here).

    python benchmarks/sweep_disturbances.py --robots point arm unicycle --episodes 150 --workers 2 \
        --roadmaps DIR --out sweep.json --plot docs/sweep_disturbances.png

For each robot: the typical episode length L (median steps of successful undisturbed episodes), then
a disturbance at every ``--every``-th step from 0 to L (default 10; the unicycle's episodes are
~2000 steps, so it takes every 100th), each with ``--episodes`` episodes in each mode (``--modes``:
replan, none, oracle, informed, rollout; see firmtool/sim/sweep.py), on common random numbers (episode i draws the same
noise in every condition), next to undisturbed baselines of twice as many episodes. ``--roadmaps DIR`` reads DIR/<scenario>.h5 (built
and solved) instead of building in memory. Results (JSON) give per point the success rate with its
Wilson 95% interval, replans, and the collisions within 5 steps of the disturbance.
``--plot FILE`` draws success vs time (Wilson intervals), one column per robot, pushes of each size
and kidnaps in rows, one line per mode, the undisturbed rates as bands.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, one_blas_thread  # noqa: E402

ROBOTS = {  # scenario, push sizes, disturbance every N steps
    "point": ("point_lightdark", (1.0, 2.0), 10),
    "arm": ("arm8_lightdark", (1.0, 2.0), 10),
    "unicycle": ("unicycle_lightdark", (0.5, 1.0), 100),
    "flyer": ("custom_robot_3d", (1.0,), 10),  # a user's robot: examples/custom_robot_3d.py
}
EXAMPLES = {"custom_robot_3d"}  # scenarios defined (with their robot) by a script in examples/


def solution(name: str, roadmaps: Path | None):
    import firmtool as ft
    if name in EXAMPLES:  # run the example as a module: it registers its robot and defines SCENARIO
        import runpy
        example = runpy.run_path(str(ROOT / "examples" / f"{name}.py"), run_name=f"example_{name}")
        return ft.solve(ft.build(ft.Scenario.from_toml(example["SCENARIO"], f"{name}.toml"), workers=2))
    if roadmaps is not None and (roadmaps / f"{name}.h5").exists():
        return ft.open_roadmap(roadmaps / f"{name}.h5").solution()
    return ft.solve(ft.build(ft.load_scenario(ROOT / "scenarios" / f"{name}.toml"), workers=2))


def sweep_robot(robot: str, args) -> dict:
    from firmtool.sim.sweep import disturbance_sweep, policies_of, typical_steps
    scenario, sizes, every = ROBOTS[robot]
    every = args.every or every
    sol = solution(scenario, args.roadmaps)
    policies = policies_of(sol, modes=args.modes)
    t0 = time.perf_counter()
    L = typical_steps(next(iter(policies.values())), args.typical, args.seed)
    last = args.last if args.last is not None else int(L // every * every)
    times = list(range(args.first, last + 1, every))
    sw = disturbance_sweep(policies, times, list(args.sizes or sizes), kidnap=not args.no_kidnap,
                           episodes=args.episodes, seed=args.seed, workers=args.workers, typical_steps=L)
    out = {"robot": robot, "scenario": scenario, "every": every, "seconds": time.perf_counter() - t0,
           "predicted": sol.success_probability, **sw.to_dict()}
    print(f"{robot}: L = {L:.0f} steps, {len(times)} times, {out['seconds']:.0f} s", file=sys.stderr)
    return out


COLORS = {"replan": "tab:blue", "none": "tab:red", "oracle": "tab:green", "informed": "tab:purple",
          "rollout": "tab:orange"}
LABELS = {"replan": "replanning", "none": "no replanning", "oracle": "replanning, oracle (told the true state)",
          "informed": "replanning, told when and how large (pushes)", "rollout": "rollout FIRM, replanning"}


def summary(result: dict, margin: float = 0.10) -> list[str]:
    """Lines: per disturbance, the range of success rates per mode, and the times where replanning
    falls more than ``margin`` below the undisturbed rate (with the oracle's rate there)."""
    pts = result["points"]
    base = {p["mode"]: p for p in pts if p["kind"] == "none"}
    ref = base.get("replan") or next(iter(base.values()))
    lines = [f"{result['robot']}: undisturbed " + ", ".join(f"{m} {p['rate']:.3f}" for m, p in base.items())
             + f" ({ref['episodes']} episodes); L = {result['typical_steps']:.0f}"]
    for kind, size in [("push", s) for s in result["sizes"]] + [("kidnap", None)]:
        by_mode = {m: {p["step"]: p for p in pts if p["kind"] == kind and p["size"] == size and p["mode"] == m}
                   for m in base}
        if not any(by_mode.values()):
            continue
        name = f"{kind}:{size:g}" if size else kind
        ranges = ", ".join(f"{m} {min(p['rate'] for p in v.values()):.2f}-{max(p['rate'] for p in v.values()):.2f}"
                           for m, v in by_mode.items() if v)
        below = [p for p in by_mode.get("replan", {}).values() if ref["rate"] - p["rate"] > margin]
        oracle, told = by_mode.get("oracle", {}), by_mode.get("informed", {})
        lines.append(f"  {name}: {ranges}; replanning more than {margin} below undisturbed at "
                     + (", ".join(f"t={p['step']} ({p['rate']:.2f}"
                                  + (f", oracle {oracle[p['step']]['rate']:.2f}" if p["step"] in oracle else "")
                                  + (f", informed {told[p['step']]['rate']:.2f}" if p["step"] in told else "")
                                  + f", immediate collisions {p['immediate_collisions']})" for p in below)
                        or "no time"))
    return lines


def plot(results: list[dict], path: Path) -> None:
    from matplotlib.figure import Figure
    rows = max(len(r["sizes"]) + (1 if any(p["kind"] == "kidnap" for p in r["points"]) else 0) for r in results)
    fig = Figure(figsize=(4.2 * len(results), 2.4 * rows), dpi=80)
    axes = fig.subplots(rows, len(results), squeeze=False)
    for col, r in enumerate(results):
        pts = r["points"]
        base = {p["mode"]: p for p in pts if p["kind"] == "none"}
        kinds = [("push", s) for s in r["sizes"]] + [("kidnap", None)]
        for row, (kind, size) in enumerate(kinds):
            ax = axes[row][col]
            for mode, b in base.items():
                color = COLORS[mode]
                if mode in ("replan", "none", "rollout"):  # the oracles' undisturbed episodes are the replanning ones
                    ax.axhspan(*b["ci95"], color=color, alpha=0.12, lw=0)
                    ax.axhline(b["rate"], color=color, lw=0.8, ls=":")
                sel = sorted((p for p in pts if p["kind"] == kind and p["size"] == size and p["mode"] == mode),
                             key=lambda p: p["step"])
                if not sel:
                    continue
                t = [p["step"] for p in sel]
                y = [p["rate"] for p in sel]
                err = [[p["rate"] - p["ci95"][0] for p in sel], [p["ci95"][1] - p["rate"] for p in sel]]
                ax.errorbar(t, y, yerr=err, color=color, marker="o", ms=2.5, lw=1, capsize=1.5, label=LABELS[mode],
                            alpha=0.6 if mode in ("oracle", "informed") else 1.0)
            ref = base.get("replan")
            if ref is not None and ref["rate"] > 0.1:
                ax.axhline(ref["rate"] - 0.10, color=COLORS["replan"], lw=0.6, ls="--")
            ax.set_ylim(-0.02, 1.02)
            name = f"push {size:g}" if kind == "push" else "kidnap"
            ax.set_title(f"{r['robot']}: {name}", fontsize=9)
            ax.tick_params(labelsize=7)
            if row == len(kinds) - 1:
                ax.set_xlabel("disturbance step", fontsize=8)
            if col == 0:
                ax.set_ylabel("success rate", fontsize=8)
        for row in range(len(kinds), rows):
            axes[row][col].set_visible(False)
    axes[0][0].legend(fontsize=6, loc="lower left")
    fig.suptitle("Success vs disturbance time (Wilson 95%; bands: undisturbed, dashed: 0.10 below it)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", nargs="+", default=["point", "arm", "unicycle"], choices=sorted(ROBOTS))
    ap.add_argument("--episodes", type=int, default=150)
    ap.add_argument("--typical", type=int, default=60, help="episodes to find the typical length")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--every", type=int, default=None, help="disturbance every N steps (default per robot)")
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--last", type=int, default=None, help="last disturbance step (default: the typical length)")
    ap.add_argument("--sizes", type=float, nargs="+", default=None, help="push sizes (default per robot)")
    ap.add_argument("--no-kidnap", action="store_true")
    ap.add_argument("--modes", nargs="+", default=["replan", "none", "oracle", "informed"],
                    choices=["replan", "none", "oracle", "informed", "rollout"])
    ap.add_argument("--roadmaps", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=None, help="JSON file")
    ap.add_argument("--plot", type=Path, default=None, help="PNG file")
    ap.add_argument("--from-json", type=Path, nargs="+", default=None, help="plot/summarise saved results only")
    args = ap.parse_args(argv)
    one_blas_thread()
    if args.from_json:
        results = [r for f in args.from_json for r in json.loads(f.read_text())]
    else:
        results = [sweep_robot(r, args) for r in args.robots]
    if args.out:
        args.out.write_text(json.dumps(results, indent=1))
    for r in results:
        print("\n".join(summary(r)))
    if args.plot:
        plot(results, args.plot)
    return results


if __name__ == "__main__":
    main()
