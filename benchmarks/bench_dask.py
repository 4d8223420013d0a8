"""dask vs local processes at the same worker count: the arm's edge estimation, interleaved.

    python benchmarks/bench_dask.py [--edges 1200] [--rounds 3] [--workers 2]

Per round, the same edges of the designed arm roadmap are estimated (``parallel.run_edges``, as the
estimate stage runs it) three ways, the order alternating between rounds:

* ``process``: local worker processes (a fresh pool: its start-up is in the time);
* ``cluster``: a dask cluster started beforehand as a user starts one (``dask scheduler`` and
  ``--workers`` ``dask worker`` processes, separate commands, joined by address); each round
  connects a new client and scatters a new job, as a new build would;
* ``local_cluster``: ``--executor dask`` without a scheduler (a LocalCluster started and closed by
  the call: its start-up is in the time).

Before the rounds, the cluster's first use is timed alone (``cluster_first``: its workers build the
problem and load the compiled kernel). Throughputs are particle-steps per wall second; ratios are
per round (dask / process), medians over rounds. On shared cores the wall ratio depends on what
else runs, so each run also records the workers' CPU seconds (local processes: ``RUSAGE_CHILDREN``;
the cluster's workers: ``getrusage`` in each, through ``client.run``) and the client's, and
``cpu_rate`` = particle-steps per worker CPU second (the work and the per-task overhead the
workers carry). Then the cluster's per-task overhead: the same edges in tasks of 1 edge and of 16
(``--overhead-edges``), interleaved. Load average before and after is printed.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import designed_roadmap, load, one_blas_thread  # noqa: E402


def start_cluster(workers: int, folder: Path) -> tuple[str, list[subprocess.Popen]]:
    dask = str(Path(sys.executable).parent / "dask") if (Path(sys.executable).parent / "dask").exists() else shutil.which("dask")
    info = folder / "scheduler.json"
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    # every address on loopback: a benchmark's cluster talks to nothing beyond this machine
    procs = [subprocess.Popen([dask, "scheduler", "--scheduler-file", str(info), "--host", "127.0.0.1", "--port", "0",
                               "--dashboard-address", "127.0.0.1:0"], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, start_new_session=True)]
    while not info.exists():
        time.sleep(0.1)
    address = json.loads(info.read_text())["address"]
    for _ in range(workers):
        procs.append(subprocess.Popen([dask, "worker", address, "--nworkers", "1", "--nthreads", "1", "--host", "127.0.0.1",
                                       "--no-dashboard"],
                                      env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                      start_new_session=True))
    from dask.distributed import Client
    with Client(address, timeout="60s") as c:
        c.wait_for_workers(workers, timeout=120)
    return address, procs


def stop_cluster(procs: list[subprocess.Popen]) -> None:
    for p in procs[::-1]:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--edges", type=int, default=1200)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--overhead-edges", type=int, default=160)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    one_blas_thread()
    import contextlib

    from firmtool.estimation import executors as parallel
    from firmtool.estimation.compiled import engine_choice
    from firmtool.estimation.executors import EstimationJob, job_extras, run_edges
    from firmtool.io.roadmap_file import RoadmapFile

    @contextlib.contextmanager
    def session_of(executor: str, scheduler: str | None):
        """run_edges' session argument: a Workers session, or nothing for a tree without one (before
        issue 19: run_edges then starts its pool or joins the cluster itself)."""
        if not hasattr(parallel, "Workers"):
            yield {}
            return
        with parallel.Workers(args.workers, executor, scheduler) as session:
            yield {"session": session}

    problem, d, _ = load("arm")
    sc = problem.scenario
    rm = RoadmapFile(designed_roadmap("arm"))
    edges = np.sort(np.random.default_rng(0).choice(d.edge_source.size, min(args.edges, d.edge_source.size),
                                                    replace=False)).tolist()
    engine = engine_choice(problem)[0]

    def job() -> EstimationJob:  # a new job per run, as a new estimate stage makes one
        j = EstimationJob(scenario_text=rm.scenario_text, scenario_path=sc.path, design=d,
                          particles=sc.estimation.particles, chunk=sc.estimation.chunk, seed=sc.seed, engine=engine,
                          **job_extras(problem))
        if hasattr(parallel, "remember_problem"):
            parallel.remember_problem(j, problem)
        return j

    def cluster_cpu(address: str) -> float:
        from dask.distributed import Client

        def used() -> float:
            import resource as r
            u = r.getrusage(r.RUSAGE_SELF)
            return u.ru_utime + u.ru_stime

        with Client(address, timeout="60s") as c:
            return sum(c.run(used).values())

    def cpu(who) -> float:
        u = resource.getrusage(who)
        return u.ru_utime + u.ru_stime

    def once(executor: str, scheduler: str | None, per_batch: int | None = None) -> dict:
        w0 = cluster_cpu(scheduler) if scheduler else cpu(resource.RUSAGE_CHILDREN)
        m0 = cpu(resource.RUSAGE_SELF)
        t0 = time.perf_counter()
        with session_of(executor, scheduler) as session:
            ps = sum(e.particle_steps for r in run_edges(job(), edges, workers=args.workers, executor=executor,
                                                         scheduler=scheduler, per_batch=per_batch, **session)
                     for e in r.estimates)
        wall = time.perf_counter() - t0
        worker = (cluster_cpu(scheduler) if scheduler else cpu(resource.RUSAGE_CHILDREN)) - w0
        return {"rate": ps / wall, "wall": wall, "worker_cpu": worker, "client_cpu": cpu(resource.RUSAGE_SELF) - m0,
                "cpu_rate": ps / worker if worker > 0 else float("nan")}

    once("process", None)  # warm-up: this process's caches and the kernel
    load0 = os.getloadavg()
    rows: dict[str, list[dict]] = {"process": [], "cluster": [], "local_cluster": []}
    overhead: dict[int, list[float]] = {1: [], 16: []}
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        address, procs = start_cluster(args.workers, Path(tmp))
        cluster_start = time.perf_counter() - t0
        try:
            first = once("dask", address)
            kinds = [("process", None), ("cluster", address), ("local_cluster", None)]
            for r in range(args.rounds):
                for name, sched in (kinds if r % 2 == 0 else kinds[::-1]):
                    row = once("process" if name == "process" else "dask", sched)
                    rows[name].append(row)
                    print(f"round {r} {name}: {row['rate'] / 1e6:.3f} M particle-steps/s, worker CPU "
                          f"{row['worker_cpu']:.2f} s ({row['cpu_rate'] / 1e6:.3f} M per CPU s), client CPU "
                          f"{row['client_cpu']:.2f} s", flush=True)
            small = edges[:args.overhead_edges]
            for r in range(args.rounds):
                for per_batch in ((1, 16) if r % 2 == 0 else (16, 1)):
                    t = time.perf_counter()
                    with session_of("dask", address) as session:
                        sum(1 for _ in run_edges(job(), small, workers=args.workers, executor="dask",
                                                     scheduler=address, per_batch=per_batch, **session))
                    overhead[per_batch].append(time.perf_counter() - t)
        finally:
            stop_cluster(procs)
    load1 = os.getloadavg()
    med = {k: {q: statistics.median(x[q] for x in v) for q in v[0]} for k, v in rows.items()}
    extra = len(small) - -(-len(small) // 16)
    per_task = (statistics.median(overhead[1]) - statistics.median(overhead[16])) / extra
    res = {"edges": len(edges), "workers": args.workers, "median": med, "cluster_first": first,
           "cluster_start_s": cluster_start,
           "cluster_over_process": statistics.median(a["rate"] / b["rate"] for a, b in zip(rows["cluster"], rows["process"])),
           "cluster_over_process_cpu": statistics.median(a["cpu_rate"] / b["cpu_rate"]
                                                         for a, b in zip(rows["cluster"], rows["process"])),
           "local_cluster_over_process": statistics.median(a["rate"] / b["rate"]
                                                           for a, b in zip(rows["local_cluster"], rows["process"])),
           "cluster_task_overhead_ms": 1e3 * per_task, "load_before": load0, "load_after": load1, "runs": rows}
    if args.json:
        print(json.dumps(res, indent=1))
        return res
    print(f"{len(edges)} arm edges, {args.workers} workers: process {med['process']['rate'] / 1e6:.3f} M/s, dask cluster "
          f"{med['cluster']['rate'] / 1e6:.3f} M/s (x{res['cluster_over_process']:.2f}; per worker CPU second "
          f"x{res['cluster_over_process_cpu']:.2f}; its first use {first['rate'] / 1e6:.3f} M/s), dask LocalCluster "
          f"incl. start-up {med['local_cluster']['rate'] / 1e6:.3f} M/s (x{res['local_cluster_over_process']:.2f}); "
          f"cluster start-up {cluster_start:.1f} s; cluster per-task overhead {res['cluster_task_overhead_ms']:.1f} ms "
          f"({len(small)} edges in 1- vs 16-edge tasks); load {load0[0]:.2f} -> {load1[0]:.2f}")
    print("RESULT " + " ".join(f"{k}_rate={v['rate']} {k}_cpu_rate={v['cpu_rate']}" for k, v in med.items()) +
          f" cluster_over_process={res['cluster_over_process']} cluster_over_process_cpu={res['cluster_over_process_cpu']}"
          f" local_cluster_over_process={res['local_cluster_over_process']} cluster_first_rate={first['rate']}"
          f" cluster_task_overhead_ms={res['cluster_task_overhead_ms']}")
    return res


if __name__ == "__main__":
    main()
