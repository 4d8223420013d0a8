"""The estimate stage's rate at few particles per edge against its rate at many (issue 55 item 3), in two
trees: particle-steps per CPU second of the simulating thread at ``--few`` (200, the shipped setting) and
``--many`` (1000) particles per edge, and their ratio, which the per-edge work that does not grow with the
particles (the local controllers, the node candidates, the ensembles' setup, the summaries) pulls below 1.

    python benchmarks/bench_particles.py [--old 666db62] [--new WORKTREE] [--robot arm point]
                                         [--edges 48] [--rounds 3] [--repeat 3] [--json]

Each tree (``--old``: a commit, its files extracted by ``git archive`` into a temporary folder removed at
the end; ``--new``: a folder, default this tree) runs in fresh subprocesses importing its own
``firmtool`` (``PYTHONPATH``), alternating old/new/new/old... over ``--rounds`` rounds, one BLAS thread.
A child samples and designs the shipped scenario once per tree (untimed, kept in the work folder), then
estimates a fixed subset of its edges (``rng(0)``) as the estimate stage's single worker does
(``run_batch`` on tasks of 16 edges: the batch's local controllers, then every edge's Monte Carlo,
with the scenario's seed and chunk), at ``--few`` and at ``--many`` particles, alternating,
``--repeat`` times each after one untimed warm pass of each; the rate of each is its median over the
repeats. Both trees' outcome counts are checked equal (the change is bit for bit).

    python benchmarks/bench_particles.py --parts [--robot arm point] [--edges 48] [--repeat 5]

instead shows where this tree's time per edge goes at ``--few`` and ``--many`` particles: CPU microseconds of
the thread per edge in each part of ``run_batch`` (the batch's local controllers, the initial ensembles,
the node candidates, the kernel's calls, the cost terms, the summaries; ``simulate`` holds the candidates,
the kernel and the cost terms), by timers wrapped around those functions, the median of ``--repeat`` passes.
A part whose time does not grow with the particles is what holds the ratio below 1.
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
SCENARIOS = {"arm": "arm8_lightdark.toml", "point": "point_lightdark.toml"}

CHILD = r'''
import json, statistics, sys, time
from pathlib import Path
import numpy as np
root, work, scenario, few, many, edges_count, repeat = sys.argv[1:8]
few, many, edges_count, repeat = int(few), int(many), int(edges_count), int(repeat)
sys.path.insert(0, root)
import firmtool
assert Path(firmtool.__file__).resolve().is_relative_to(Path(root).resolve()), firmtool.__file__
import scipy.linalg  # noqa: F401  (its BLAS loaded first, so the limit covers it)
from threadpoolctl import threadpool_limits
threadpool_limits(1)
from firmtool.estimation.executors import EstimationJob, run_batch
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.pipeline import design_of, design_stage, problem_of, sample_stage
out = Path(work) / (Path(scenario).stem + ".h5")
if not out.exists():
    sample_stage(scenario, out)
    design_stage(out, workers=1)
rm = RoadmapFile(out)
problem, d = problem_of(rm), design_of(rm)
sc = problem.scenario
E = d.edge_source.size
edges = np.sort(np.random.default_rng(0).choice(E, min(edges_count, E), replace=False)).tolist()
tasks = [edges[i:i + 16] for i in range(0, len(edges), 16)]
jobs = {M: EstimationJob(scenario_text=rm.scenario_text, scenario_path=str(rm.path), design=d, particles=M,
                         chunk=sc.estimation.chunk, seed=sc.seed) for M in (few, many)}
counts = {}
for M, job in jobs.items():  # warm: the kernel loaded, the problem and regions built
    counts[M] = [[r.outcomes.tolist(), r.counts.tolist()] for b in tasks for r in run_batch(job, b)]
rates = {few: [], many: []}
steps = {}
for r in range(repeat):
    for M in ((few, many) if r % 2 == 0 else (many, few)):
        c0 = time.thread_time()
        ps = sum(int(e.particle_steps) for b in tasks for e in run_batch(jobs[M], b))
        rates[M].append(ps / (time.thread_time() - c0))
        steps[M] = ps
print(json.dumps({"few": statistics.median(rates[few]), "many": statistics.median(rates[many]),
                  "steps": [steps[few], steps[many]], "counts": counts[few] + counts[many]}))
'''


def parts(robot: str, edges_count: int, particles: int, repeat: int) -> dict:
    """Where this tree's time per edge goes (``--parts``): CPU microseconds of the simulating thread per edge
    in each part of ``run_batch`` (timers wrapped around its functions in this process; median of
    ``repeat`` passes over the edges, after a warm pass), at ``particles`` per edge."""
    import functools
    import time

    import numpy as np
    from _common import designed_roadmap, load, one_blas_thread
    one_blas_thread()
    import firmtool.estimation.compiled.driver as drv
    import firmtool.estimation.edges as E
    import firmtool.estimation.tasks as T
    from firmtool.estimation.executors import EstimationJob, run_batch
    from firmtool.io.roadmap_file import RoadmapFile
    acc: dict[str, float] = {}

    def timed(mod, name, label):
        f = getattr(mod, name)

        @functools.wraps(f)
        def wrapped(*a, **k):
            t0 = time.thread_time()
            try:
                return f(*a, **k)
            finally:
                acc[label] = acc.get(label, 0.0) + time.thread_time() - t0
        setattr(mod, name, wrapped)
        return f

    labels = [(T, "local_controllers", "local controllers (batch)"), (E, "initial_ensembles", "initial ensembles"),
              (drv, "_update_candidates", "node candidates"), (drv, "cost_terms", "cost terms"),
              (E, "summarise", "summaries"), (E, "simulate", "simulate (driver + kernel)")]
    originals = [(mod, name, timed(mod, name, label)) for mod, name, label in labels]
    problem, d, regions = load(robot)
    kernel_run = drv._ProblemData.run

    def run_prop(self):
        run = kernel_run.fget(self)

        def call(*args):
            t0 = time.thread_time()
            try:
                return run(*args)
            finally:
                acc["kernel"] = acc.get("kernel", 0.0) + time.thread_time() - t0
        return call
    drv._ProblemData.run = property(run_prop)
    try:
        sc = problem.scenario
        rm = RoadmapFile(designed_roadmap(robot))
        E_ = d.edge_source.size
        edges = np.sort(np.random.default_rng(0).choice(E_, min(edges_count, E_), replace=False)).tolist()
        tasks = [edges[i:i + 16] for i in range(0, len(edges), 16)]
        job = EstimationJob(scenario_text=rm.scenario_text, scenario_path=str(rm.path), design=d, particles=particles,
                            chunk=sc.estimation.chunk, seed=sc.seed)
        for b in tasks:
            run_batch(job, b)
        runs: dict[str, list[float]] = {}
        for _ in range(repeat):
            acc.clear()
            t0 = time.thread_time()
            ps = sum(r.particle_steps for b in tasks for r in run_batch(job, b))
            acc["total"] = time.thread_time() - t0
            for k, v in acc.items():
                runs.setdefault(k, []).append(v)
        out = {k: 1e6 * statistics.median(v) / len(edges) for k, v in runs.items()}
        out["particle_steps_per_edge"] = ps / len(edges)
        return out
    finally:
        drv._ProblemData.run = kernel_run
        for mod, name, f in originals:
            setattr(mod, name, f)


def run_child(tree: Path, work: Path, robot: str, args) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
               MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    env.pop("NUMBA_CACHE_DIR", None)  # each tree's own __pycache__
    script = work / "child.py"
    script.write_text(CHILD)
    proc = subprocess.run([sys.executable, str(script), str(tree), str(work), str(ROOT / "scenarios" / SCENARIOS[robot]),
                           str(args.few), str(args.many), str(args.edges), str(args.repeat)], env=env,
                          capture_output=True, text=True, cwd=work)
    if proc.returncode != 0:
        raise SystemExit(f"child in {tree} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--old", default="666db62", help="the old commit (its files extracted by git archive)")
    ap.add_argument("--new", default=str(ROOT), help="the new tree (a folder; default this worktree)")
    ap.add_argument("--robot", nargs="+", default=["arm", "point"], choices=sorted(SCENARIOS))
    ap.add_argument("--few", type=int, default=200)
    ap.add_argument("--many", type=int, default=1000)
    ap.add_argument("--edges", type=int, default=48)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--keep", default=None, help="keep the old tree and the designs in this folder (reused if there)")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--parts", action="store_true",
                    help="instead: where this tree's time per edge goes, at --few and --many (in this process)")
    args = ap.parse_args(argv)
    if args.parts:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        sys.path.insert(0, str(ROOT))
        table = {}
        for robot in args.robot:
            for M in (args.few, args.many):
                table[f"{robot} {M}"] = got = parts(robot, args.edges, M, args.repeat)
                print(f"{robot} {M}: " + ", ".join(f"{k} {v:.0f}" for k, v in got.items()), flush=True)
        if args.json:
            print(json.dumps(table))
        return table
    tmp = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="firmtool-particles-"))
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short=12", args.old], check=True,
                                capture_output=True, text=True).stdout.strip()
        old = tmp / f"tree-{commit}"
        if not old.exists():  # the commit's files (git archive): no worktree registered in the repository
            old.mkdir()
            archive = subprocess.run(["git", "-C", str(ROOT), "archive", commit], check=True, capture_output=True).stdout
            subprocess.run(["tar", "-x", "-C", str(old)], input=archive, check=True)
        trees = {"old": old, "new": Path(args.new).resolve()}
        summary: dict = {"old": args.old, "new": str(trees["new"]), "load_start": os.getloadavg(), "robots": {}}
        for robot in args.robot:
            rows = []
            for r in range(args.rounds):
                order = ("old", "new") if r % 2 == 0 else ("new", "old")
                got = {}
                for k in order:
                    work = tmp / f"work-{k}"
                    work.mkdir(exist_ok=True)
                    got[k] = run_child(trees[k], work, robot, args)
                if got["old"]["counts"] != got["new"]["counts"] or got["old"]["steps"] != got["new"]["steps"]:
                    raise SystemExit(f"{robot} round {r}: the trees' outcome counts differ")
                row = {k: {"few": got[k]["few"], "many": got[k]["many"], "ratio": got[k]["few"] / got[k]["many"]}
                       for k in got}
                rows.append(row)
                print(f"{robot} round {r}: " + "; ".join(
                    f"{k} {row[k]['few'] / 1e6:.3f} / {row[k]['many'] / 1e6:.3f} M/s = {row[k]['ratio']:.3f}"
                    for k in ("old", "new")) + f"  (load {os.getloadavg()[0]:.1f})", flush=True)
            med = {k: {q: statistics.median(row[k][q] for row in rows) for q in ("few", "many", "ratio")}
                   for k in ("old", "new")}
            summary["robots"][robot] = {"rounds": rows, "median": med, "steps": got["new"]["steps"]}
            print(f"{robot}: {args.few}/{args.many} ratio, median of {args.rounds}: old {med['old']['ratio']:.3f}, "
                  f"new {med['new']['ratio']:.3f}; new/old rate at {args.few}: "
                  f"{med['new']['few'] / med['old']['few']:.3f}, at {args.many}: {med['new']['many'] / med['old']['many']:.3f}")
        summary["load_end"] = os.getloadavg()
        if args.json:
            print(json.dumps(summary))
        return summary
    finally:
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
