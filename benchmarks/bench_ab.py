"""A/B of the estimate stage against a fixed old commit: particle-steps per CPU second of the simulating thread.

    python benchmarks/bench_ab.py [--old 4071a87] [--new WORKTREE] [--scenario scenarios/arm8_lightdark.toml]
                                  [--particles 1000] [--edges 40] [--rounds 3] [--json]
                                  [--stream 1|2] [--streams-differ]

The old commit is checked out as a detached git worktree under a temporary folder (``git worktree add
--detach``, removed at the end with ``git worktree remove --force``); ``--new`` is a tree already on disk
(default: this one). Both trees run the SAME workload in fresh subprocesses, each importing its own
``firmtool`` (``PYTHONPATH`` = the tree's root; the child checks where ``firmtool`` came from), in
alternating order, ``--rounds`` rounds (old, new, new, old, ...: neither tree always runs first).

Workload: the scenario sampled and designed once per tree (outside the timing; the two trees' designs are
checked to give the same edges), then ``--edges`` edges (a fixed random subset, ``rng(0)``; 0: all) estimated
one after the other on one thread, as the estimate stage's single worker does (``estimate_edge``: the edge's
local controller, the initial ensemble, the Monte Carlo in chunks, the per-edge summaries), with the
scenario's seed and chunk, ``--particles`` per edge. The engine is the one the tree chooses by default
(the compiled one). Each tree is warmed once first (numba's disk cache is per tree: the first run compiles).
In each timed child the kernel is loaded by one small untimed call first.

Timing: ``time.thread_time()`` around the edge loop: the CPU time of the simulating thread, which a
loaded machine inflates far less than wall time (wall is reported too). Rate: particle-steps (the
particles' stopping steps summed; checked equal in both trees, as are the outcome counts) per CPU second.
Reported per round: each tree's rate and the ratio new/old; then the median and range of the ratios.

``--stream N`` sets ``FIRMTOOL_STREAM=N`` in every child (the random stream of the roadmaps the trees
sample, issue 55; a tree before stream 2 ignores it). Where the two trees draw different streams (a tree
with stream 2 against one before it), their particles differ: ``--streams-differ`` then skips the check
that particle-steps and outcome counts are equal (the rate is per particle-step either way).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r'''
import json, sys, time
from pathlib import Path
import numpy as np
root, work, scenario, particles, edges_count, mode = sys.argv[1:7]
particles, edges_count = int(particles), int(edges_count)
sys.path.insert(0, root)
import firmtool
assert Path(firmtool.__file__).resolve().is_relative_to(Path(root).resolve()), firmtool.__file__
import scipy.linalg  # noqa: F401  (its BLAS loaded first, so the limit covers it)
from threadpoolctl import threadpool_limits
threadpool_limits(1)
from firmtool.pipeline import design_of, design_stage, problem_of, sample_stage
try:
    from firmtool.estimation.edges import estimate_edge
except ImportError:
    from firmtool.edges import estimate_edge
try:
    from firmtool.io.roadmap_file import RoadmapFile as Roadmap
except ImportError:
    from firmtool.roadmap import Roadmap
out = Path(work) / "designed.h5"
if not out.exists():
    sample_stage(scenario, out)
    design_stage(out, workers=1)
rm = Roadmap(out)
problem, d = problem_of(rm), design_of(rm)
import dataclasses, os
if os.environ.get("FIRMTOOL_STREAM") and hasattr(problem.scenario.estimation, "stream"):  # --stream, a kept design too
    sc = problem.scenario
    problem = dataclasses.replace(problem, scenario=dataclasses.replace(
        sc, estimation=dataclasses.replace(sc.estimation, stream=int(os.environ["FIRMTOOL_STREAM"]))))
regions = d.regions(problem)
sc = problem.scenario
E = d.edge_source.size
edges = np.arange(E) if edges_count <= 0 else np.sort(np.random.default_rng(0).choice(E, min(edges_count, E), replace=False))
pairs = [(int(d.edge_source[e]), int(d.edge_target[e])) for e in edges]
s, t = pairs[0]
estimate_edge(problem, d, regions, s, t, 10, sc.seed, sc.estimation.chunk)  # the kernel compiled or loaded, untimed
if mode == "warm":
    print(json.dumps({"pairs": pairs}))
    sys.exit(0)
ps, counts = 0, []
c0, w0 = time.thread_time(), time.perf_counter()
for s, t in pairs:
    est = estimate_edge(problem, d, regions, s, t, particles, sc.seed, sc.estimation.chunk)
    ps += int(est.particle_steps)
    counts.append([s, t, est.outcomes.tolist(), est.counts.tolist()])
cpu, wall = time.thread_time() - c0, time.perf_counter() - w0
print(json.dumps({"particle_steps": ps, "cpu": cpu, "wall": wall, "counts": counts}))
'''


def run_child(tree: Path, work: Path, args, mode: str, wait: bool = True):
    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
               MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    env.pop("NUMBA_CACHE_DIR", None)  # each tree's own __pycache__: caches stay per tree
    if args.stream is not None:
        env["FIRMTOOL_STREAM"] = str(args.stream)
    script = work / "child.py"
    script.write_text(CHILD)
    proc = subprocess.Popen([sys.executable, str(script), str(tree), str(work), str(Path(args.scenario).resolve()),
                             str(args.particles), str(args.edges), mode], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=work)
    return finish(proc, tree) if wait else (proc, tree)


def finish(proc: subprocess.Popen, tree: Path) -> dict:
    out, err = proc.communicate()
    if proc.returncode != 0:
        raise SystemExit(f"child in {tree} failed:\n{err[-3000:]}")
    return json.loads(out.strip().splitlines()[-1])


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--old", default="4071a87", help="the old commit (a detached worktree of it is made)")
    ap.add_argument("--new", default=str(ROOT), help="the new tree (a folder; default this worktree)")
    ap.add_argument("--new-commit", default=None, help="instead of --new: a commit, checked out like --old")
    ap.add_argument("--scenario", default=str(ROOT / "scenarios" / "arm8_lightdark.toml"))
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--edges", type=int, default=40, help="edges estimated per run (0: all)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--keep", default=None, help="keep the worktrees and designs in this folder (reused if there)")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--stream", type=int, choices=(1, 2), default=None,
                    help="FIRMTOOL_STREAM in every child (default: each tree's default stream)")
    ap.add_argument("--streams-differ", action="store_true",
                    help="the trees draw different streams: do not require equal particle-steps and counts")
    args = ap.parse_args(argv)
    tmp = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="firmtool-ab-"))
    tmp.mkdir(parents=True, exist_ok=True)
    made = []

    def checkout(commit: str) -> Path:
        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short=12", commit], check=True,
                                capture_output=True, text=True).stdout.strip()
        path = tmp / f"tree-{commit}"
        if not path.exists():
            subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path), commit], check=True,
                           capture_output=True)
            made.append(path)
        return path

    try:
        trees = {"old": checkout(args.old),
                 "new": checkout(args.new_commit) if args.new_commit else Path(args.new).resolve()}
        works = {k: tmp / f"work-{trees[k].name}" for k in trees}
        for k in trees:
            works[k].mkdir(exist_ok=True)
        # the warm runs (sample, design, compile: untimed) of both trees at once
        started = {k: run_child(trees[k], works[k], args, "warm", wait=False) for k in trees}
        pairs = {k: finish(*started[k])["pairs"] for k in trees}
        if pairs["old"] != pairs["new"]:
            raise SystemExit("the two trees' designs give different edges: not the same workload")
        rows = []
        for r in range(args.rounds):
            order = ("old", "new") if r % 2 == 0 else ("new", "old")
            got = {k: run_child(trees[k], works[k], args, "time") for k in order}
            if not args.streams_differ and (got["old"]["particle_steps"] != got["new"]["particle_steps"]
                                            or got["old"]["counts"] != got["new"]["counts"]):
                raise SystemExit(f"round {r}: particle-steps or outcome counts differ between the trees")
            rate = {k: got[k]["particle_steps"] / got[k]["cpu"] for k in got}
            rows.append({"round": r, "particle_steps": got["old"]["particle_steps"],
                         "new_particle_steps": got["new"]["particle_steps"],
                         "old_rate": rate["old"], "new_rate": rate["new"], "ratio": rate["new"] / rate["old"],
                         "old_cpu": got["old"]["cpu"], "new_cpu": got["new"]["cpu"],
                         "old_wall": got["old"]["wall"], "new_wall": got["new"]["wall"]})
            row = rows[-1]
            print(f"round {r}: {row['particle_steps']} particle-steps; old {rate['old'] / 1e6:.3f} M/s-CPU "
                  f"({row['old_cpu']:.1f} s CPU, {row['old_wall']:.1f} s wall), new {rate['new'] / 1e6:.3f} "
                  f"({row['new_cpu']:.1f} s CPU, {row['new_wall']:.1f} s wall); new/old {row['ratio']:.3f}",
                  flush=True)
        ratios = [row["ratio"] for row in rows]
        summary = {"old": args.old, "new": args.new_commit or str(trees["new"]), "particles": args.particles,
                   "edges": args.edges, "load": os.getloadavg(), "rounds": rows,
                   "ratio_median": statistics.median(ratios), "ratio_range": [min(ratios), max(ratios)],
                   "old_rate_median": statistics.median(row["old_rate"] for row in rows),
                   "new_rate_median": statistics.median(row["new_rate"] for row in rows)}
        print(f"new/old: median {summary['ratio_median']:.3f}, range {min(ratios):.3f}-{max(ratios):.3f}; "
              f"rates (M particle-steps per CPU s) old {summary['old_rate_median'] / 1e6:.3f}, "
              f"new {summary['new_rate_median'] / 1e6:.3f}; load {os.getloadavg()[0]:.1f}")
        if args.json:
            print(json.dumps(summary))
        return summary
    finally:
        if not args.keep:
            for path in made:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(path)],
                               capture_output=True)
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
