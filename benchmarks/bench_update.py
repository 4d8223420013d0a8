"""A world update on a built roadmap vs a full rebuild (issue 36), in one run.

    python benchmarks/bench_update.py --scenario arm      # a box that blocks the arm's right passage
    python benchmarks/bench_update.py --scenario point    # point_lightdark's box at (4, 1.2) moved up by 0.6
    python benchmarks/bench_update.py --scenario point --online 200   # and a box told to the policy online

Builds the shipped scenario into a fresh file (``--workers`` workers; its wall time is the
reference a rebuild costs), then in the same run: ``firmtool update`` on a copy with the changed
world (``ft.update``, the same workers, timed: wall seconds of the call), and ``firmtool estimate
--fresh`` plus ``solve`` on a copy of the updated file (the reference the update must equal bit for
bit: every dataset of ``/edges`` and ``/policy`` compared). Reports the edges kept, estimated again
and dropped with the reasons, the update's time over the build's, the fraction of edges estimated,
and what the swept regions add to the file (their bytes over the file's).

``--online EPISODES``: on the built roadmap, a square box (half size 0.35) on the middle edge of the
policy's path appears at step ``--step`` of every episode; the same episodes (common seeds) are run
with the box told to the policy (``obstacle:`` disturbance: ``Policy.update_world`` once it observed
the step) and unseen (``obstacle-unseen:``), and without it. Reports the success rates and the
update's wall time (each computed afresh) against the control period.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SCENARIOS, one_blas_thread  # noqa: E402

# The changes: (what is said, the new obstacle list from the old one).
CHANGES = {
    # the right passage of the arm's bar lies at x in [0.3, 0.65], y 0.7: a box across it
    "arm": ("a box across the right passage (x 0.3-0.65 at y 0.7)",
            lambda old: old + [{"center": [0.475, 0.7], "half_size": [0.175, 0.1]}]),
    # the box at (4.0, 1.2) moved up by 0.6
    "point": ("the box at (4.0, 1.2) moved to (4.0, 1.8)",
              lambda old: [dict(o, center=[4.0, 1.8]) if o["center"] == [4.0, 1.2] else o for o in old]),
}


def _datasets(path: Path, group: str) -> dict:
    import h5py
    with h5py.File(path, "r") as f:
        return {k: f[group][k][()] for k in f[group]}


def bit_identical(a: Path, b: Path) -> list[str]:
    """The datasets of /edges and /policy that differ between two roadmap files (empty: none)."""
    differ = []
    for group in ("edges", "policy"):
        x, y = _datasets(a, group), _datasets(b, group)
        for k in sorted(set(x) | set(y)):
            if k not in x or k not in y or x[k].dtype != y[k].dtype or x[k].tobytes() != y[k].tobytes():
                differ.append(f"/{group}/{k}")
    return differ


def box_across_path(sol, half: float) -> tuple[list[float], list[float]]:
    """A square box of half size ``half`` on the middle of the policy's path (the midpoint of its
    middle edge, away from the start and the goal)."""
    path = sol.path()
    c = sol.roadmap.nodes[:, :2]
    a, b = path[len(path) // 2 - 1], path[len(path) // 2]
    mid = (c[a] + c[b]) / 2
    return mid.round(3).tolist(), [half, half]


def online(base: Path, episodes: int, seed: int, step: int = 10, half: float = 0.35) -> dict:
    """The same episodes with the box told to the policy at ``step`` or unseen; the policy's
    update_world times (each computed afresh: its answers' cache emptied first) against ``dt``."""
    import numpy as np

    import firmtool as ft
    from firmtool.sim.episodes import run_episodes

    sol = ft.solve(ft.open_roadmap(base))
    center, half_size = box_across_path(sol, half)
    spec = f"{{}}:{step}:{center[0]},{center[1]}:{half_size[0]},{half_size[1]}"
    policy = ft.Policy(sol)
    update, times = policy.update_world, []

    def timed(obstacles, **kw):
        policy._worlds.forget()
        t = time.perf_counter()
        events = update(obstacles, **kw)
        if len(list(obstacles)) > len(sol.roadmap.scenario.world.obstacles):  # the box's update, not the restore
            times.append(time.perf_counter() - t)
        return events

    policy.update_world = timed
    told = run_episodes(policy, episodes, seed, disturbances=[spec.format("obstacle")])
    unseen = run_episodes(ft.Policy(sol), episodes, seed, disturbances=[spec.format("obstacle-unseen")])
    plain = run_episodes(ft.Policy(sol), episodes, seed)
    dt = sol.roadmap.problem.model.dt
    t = np.array(times)
    return {"box": {"center": center, "half_size": half_size, "step": step}, "episodes": episodes,
            "success_told": told.success_rate, "success_unseen": unseen.success_rate,
            "success_without_box": plain.success_rate, "gain": told.success_rate - unseen.success_rate,
            "update_world_s": {"mean": float(t.mean()), "p50": float(np.quantile(t, 0.5)),
                               "p99": float(np.quantile(t, 0.99)), "max": float(t.max()), "count": int(t.size)},
            "dt": dt, "p99_over_dt": float(np.quantile(t, 0.99)) / dt}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="point", choices=sorted(CHANGES))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--online", type=int, default=0, metavar="EPISODES",
                    help="also: a box across the policy's path appears at step --step of each of EPISODES episodes, "
                         "told to the policy (Policy.update_world) or not")
    ap.add_argument("--step", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    one_blas_thread()

    import firmtool as ft
    from firmtool.pipeline import build, estimate_stage, solve_stage

    tmp = Path(tempfile.mkdtemp(prefix="firmtool-bench-update-"))
    base = tmp / "roadmap.h5"
    t0 = time.perf_counter()
    built = build(SCENARIOS[args.scenario], base, workers=args.workers)
    build_s = time.perf_counter() - t0
    print(f"build: {build_s:.2f} s wall ({built.nodes} nodes, {built.edges} edges)", flush=True)

    sc = ft.open_roadmap(base).scenario
    what, change = CHANGES[args.scenario]
    new = sc.replace(world={"obstacles": change([o.to_table() for o in sc.world.obstacles])})
    updated, fresh = tmp / "updated.h5", tmp / "fresh.h5"
    shutil.copyfile(base, updated)
    t0 = time.perf_counter()
    report = ft.update(updated, new, workers=args.workers).report
    update_s = time.perf_counter() - t0
    shutil.copyfile(updated, fresh)
    t0 = time.perf_counter()
    estimate_stage(fresh, workers=args.workers, fresh=True)
    solve_stage(fresh)
    fresh_s = time.perf_counter() - t0
    differ = bit_identical(updated, fresh)

    e = _datasets(updated, "edges")
    swept_bytes = int(e["swept_lo"].nbytes + e["swept_hi"].nbytes)
    file_bytes = updated.stat().st_size
    out = {
        "scenario": args.scenario, "change": what, "build_s": build_s, "update_s": update_s, "fresh_s": fresh_s,
        "update_over_build": update_s / build_s, "edges": report.edges, "kept_edges": report.kept_edges,
        "estimated_edges": report.estimated_edges, "estimated_fraction": report.estimated_edges / report.edges,
        "new_edges": report.new_edges, "dropped_edges": report.dropped_edges, "retired_nodes": report.retired_nodes,
        "reasons": dict(report.reasons), "update_seconds": dict(report.seconds),
        "simulated_particle_steps": report.simulated_particle_steps, "build_particle_steps": built.simulated_particle_steps,
        "bit_identical": not differ, "differing": differ,
        "swept_bytes": swept_bytes, "file_bytes": file_bytes, "swept_fraction_of_file": swept_bytes / file_bytes,
    }
    if args.online:
        out["online"] = online(base, args.online, args.seed, args.step)
    print(json.dumps(out, indent=1))
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    shutil.rmtree(tmp, ignore_errors=True)
    if differ:
        sys.exit(f"update differs from the fresh estimate: {', '.join(differ)}")


if __name__ == "__main__":
    main()
