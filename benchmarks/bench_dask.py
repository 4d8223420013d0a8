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
per round (dask / process), medians over rounds. Load average before and after is printed.
"""

from __future__ import annotations

import argparse
import json
import os
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
    procs = [subprocess.Popen([dask, "scheduler", "--scheduler-file", str(info), "--port", "0", "--dashboard-address",
                               ":0"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    while not info.exists():
        time.sleep(0.1)
    address = json.loads(info.read_text())["address"]
    for _ in range(workers):
        procs.append(subprocess.Popen([dask, "worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"],
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
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    one_blas_thread()
    from firmtool.kernels import engine_choice
    from firmtool.parallel import EstimationJob, Workers, job_extras, remember_problem, run_edges
    from firmtool.roadmap import Roadmap

    problem, d, _ = load("arm")
    sc = problem.scenario
    rm = Roadmap(designed_roadmap("arm"))
    edges = np.sort(np.random.default_rng(0).choice(d.edge_source.size, min(args.edges, d.edge_source.size),
                                                    replace=False)).tolist()
    engine = engine_choice(problem)[0]

    def job() -> EstimationJob:  # a new job per run, as a new estimate stage makes one
        j = EstimationJob(scenario_text=rm.scenario_text, scenario_path=sc.path, design=d,
                          particles=sc.estimation.particles, chunk=sc.estimation.chunk, seed=sc.seed, engine=engine,
                          **job_extras(problem))
        remember_problem(j, problem)
        return j

    def once(executor: str, scheduler: str | None) -> float:
        t0 = time.perf_counter()
        with Workers(args.workers, executor, scheduler) as session:
            ps = sum(e.particle_steps for r in run_edges(job(), edges, workers=args.workers, executor=executor,
                                                         scheduler=scheduler, session=session) for e in r.estimates)
        return ps / (time.perf_counter() - t0)

    once("process", None)  # warm-up: this process's caches and the kernel
    load0 = os.getloadavg()
    rows: dict[str, list[float]] = {"process": [], "cluster": [], "local_cluster": []}
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        address, procs = start_cluster(args.workers, Path(tmp))
        cluster_start = time.perf_counter() - t0
        try:
            first = once("dask", address)
            kinds = [("process", None), ("cluster", address), ("local_cluster", None)]
            for r in range(args.rounds):
                for name, sched in (kinds if r % 2 == 0 else kinds[::-1]):
                    rate = once("process" if name == "process" else "dask", sched)
                    rows[name].append(rate)
                    print(f"round {r} {name}: {rate / 1e6:.3f} M particle-steps/s", flush=True)
        finally:
            stop_cluster(procs)
    load1 = os.getloadavg()
    med = {k: statistics.median(v) for k, v in rows.items()}
    res = {"edges": len(edges), "workers": args.workers, "median_rate": med, "cluster_first_rate": first,
           "cluster_start_s": cluster_start,
           "cluster_over_process": statistics.median(a / b for a, b in zip(rows["cluster"], rows["process"])),
           "local_cluster_over_process": statistics.median(a / b for a, b in zip(rows["local_cluster"], rows["process"])),
           "load_before": load0, "load_after": load1, "runs": rows}
    if args.json:
        print(json.dumps(res, indent=1))
        return res
    print(f"{len(edges)} arm edges, {args.workers} workers: process {med['process'] / 1e6:.3f} M/s, dask cluster "
          f"{med['cluster'] / 1e6:.3f} M/s (x{res['cluster_over_process']:.2f}; its first use {first / 1e6:.3f} M/s), "
          f"dask LocalCluster incl. start-up {med['local_cluster'] / 1e6:.3f} M/s "
          f"(x{res['local_cluster_over_process']:.2f}); cluster start-up {cluster_start:.1f} s; load "
          f"{load0[0]:.2f} -> {load1[0]:.2f}")
    print("RESULT " + " ".join(f"{k}_rate={v}" for k, v in med.items()) +
          f" cluster_over_process={res['cluster_over_process']} local_cluster_over_process={res['local_cluster_over_process']}"
          f" cluster_first_rate={first}")
    return res


if __name__ == "__main__":
    main()
