"""Whole builds of scenarios/arm8_lightdark.toml by stage, 1 vs 2 workers (pipeline.build), interleaved.

    python benchmarks/bench_build.py [--workers 1 2] [--rounds 3] [--executor process|dask] [--json]
                                     [--scenario arm] [--set nodes=3000 ...]

Each round builds the scenario once per worker count (alternating which goes first) into a fresh
file and records, per build:

* wall seconds per stage (sample, design, estimate) and in total;
* ``parallel_s``: wall seconds inside the workers' sessions (``parallel.Workers.run``: tasks out,
  results in), ``serial_s`` = total - parallel_s (what no number of workers shortens), and the
  number of tasks;
* CPU seconds of this process and of its worker processes (``getrusage``; dask workers are not
  children, so not counted), and the load average before and after.

Ratios are per round (the 1-worker total over the 2-worker total of the same round), so load that
changes between rounds cancels. ``cpu_speedup`` = (CPU of the 1-worker build) / (this process's CPU
+ the workers' CPU / workers): the 2-worker time if each process had a core of its own, i.e. the
speed-up net of other jobs on the cores.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SCENARIOS, engine, one_blas_thread  # noqa: E402


def _cpu(who) -> float:
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def scenario_text(name: str, settings: list[str]) -> str:
    text = SCENARIOS[name].read_text()
    for item in settings:
        key, _, value = item.partition("=")
        text, n = re.subn(rf"(?m)^{re.escape(key)} = .*$", f"{key} = {value}", text)
        if not n:
            raise SystemExit(f"--set {item}: no key {key!r} in the scenario")
    return text


class SessionTimer:
    """Times parallel.Workers.run (the parallel sections) and counts tasks, by wrapping it."""

    def __init__(self) -> None:
        from firmtool.estimation import executors as parallel
        self.parallel = parallel
        self.real = getattr(getattr(parallel, "Workers", None), "run", None)  # None: an older tree
        self.seconds, self.tasks, self.by_fn = (0.0 if self.real else float("nan")), 0, {}

    def __enter__(self):
        timer = self
        if self.real is None:
            return self

        def run(session, job, fn, work, **kwargs):
            t0 = time.perf_counter()
            try:
                yield from timer.real(session, job, fn, work, **kwargs)
            finally:
                dt = time.perf_counter() - t0
                timer.seconds += dt
                timer.tasks += len(work)
                timer.by_fn[fn.__name__] = timer.by_fn.get(fn.__name__, 0.0) + dt

        self.parallel.Workers.run = run
        return self

    def __exit__(self, *exc) -> None:
        if self.real is not None:
            self.parallel.Workers.run = self.real


def build_once(text: str, workers: int, executor: str, scheduler: str | None) -> dict:
    from firmtool.pipeline import build
    from firmtool.scenario import parse_scenario
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "s.toml"
        path.write_text(text)
        sc = parse_scenario(text, str(path))
        try:  # every build pays the robot's task set-up (the arm's goal by inverse kinematics), as a new process would
            from firmtool import problem as problem_module
            problem_module._task_cache.clear()
        except AttributeError:
            pass
        load0 = os.getloadavg()[0]
        m0, c0 = _cpu(resource.RUSAGE_SELF), _cpu(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        with SessionTimer() as timer:
            r = build(sc, Path(tmp) / "b.h5", workers=workers, executor=executor, scheduler=scheduler)
        total = time.perf_counter() - t0
        main_cpu, child_cpu = _cpu(resource.RUSAGE_SELF) - m0, _cpu(resource.RUSAGE_CHILDREN) - c0
    s = dict(r.seconds)
    return {**s, "total": total, "parallel_s": timer.seconds, "serial_s": total - timer.seconds,
            "tasks": timer.tasks, "parallel_by_task": timer.by_fn, "main_cpu": main_cpu, "worker_cpu": child_cpu,
            "estimate_rate": r.particle_steps_per_second, "edges": r.edges, "nodes": r.nodes,
            "particle_steps": r.particle_steps, "load_before": load0, "load_after": os.getloadavg()[0]}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=None, help="alias of --rounds")
    ap.add_argument("--engine", default=None)
    ap.add_argument("--executor", default="process")
    ap.add_argument("--scheduler", default=None)
    ap.add_argument("--scenario", default="arm", choices=sorted(SCENARIOS))
    ap.add_argument("--set", nargs="*", default=[], help="scenario settings KEY=VALUE (e.g. nodes=600)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rounds = args.repeat or args.rounds
    one_blas_thread()  # as the CLI does
    text = scenario_text(args.scenario, args.set)
    runs: dict[int, list[dict]] = {w: [] for w in args.workers}
    with engine(args.engine):
        build_once(text.replace("particles = 200", "particles = 20"), 1, "process", None)  # warm-up: caches, imports
        for r in range(rounds):
            for w in (args.workers if r % 2 == 0 else args.workers[::-1]):
                row = build_once(text, w, args.executor if w > 1 else "process", args.scheduler)
                runs[w].append(row)
                print(f"round {r} workers {w}: " + " ".join(f"{k}={v:.3f}" for k, v in row.items()
                                                              if isinstance(v, float)), flush=True)
    med = {w: {k: statistics.median(x[k] for x in v) for k in v[0] if isinstance(v[0][k], (int, float))}
           for w, v in runs.items()}
    out = {"median": med, "runs": runs, "executor": args.executor, "settings": args.set}
    if 1 in runs and len(args.workers) > 1:
        for w in args.workers:
            if w == 1:
                continue
            pairs = list(zip(runs[1], runs[w]))
            out[f"speedup_{w}"] = statistics.median(a["total"] / b["total"] for a, b in pairs)
            out[f"estimate_speedup_{w}"] = statistics.median(a["estimate"] / b["estimate"] for a, b in pairs)
            out[f"cpu_speedup_{w}"] = statistics.median(
                a["main_cpu"] / (b["main_cpu"] + b["worker_cpu"] / w) for a, b in pairs)
    if args.json:
        print(json.dumps(out, indent=1))
        return out
    for w, m in med.items():
        print(f"{args.scenario} build, {w} worker(s) ({args.executor if w > 1 else 'in process'}): sample "
              f"{m['sample']:.2f} s, design {m['design']:.2f} s, estimate {m['estimate']:.2f} s, total {m['total']:.2f} s "
              f"(serial {m['serial_s']:.2f} s, parallel {m['parallel_s']:.2f} s, {m['tasks']:.0f} tasks); CPU: this "
              f"process {m['main_cpu']:.2f} s, workers {m['worker_cpu']:.2f} s; {m['edges']:.0f} edges, "
              f"{m['nodes']:.0f} nodes, estimate {m['estimate_rate'] / 1e6:.2f} M particle-steps/s; load "
              f"{m['load_before']:.1f} -> {m['load_after']:.1f}")
    for w in args.workers:
        if w != 1 and f"speedup_{w}" in out:
            print(f"{w} vs 1 workers: whole build x{out[f'speedup_{w}']:.2f}, estimate x{out[f'estimate_speedup_{w}']:.2f}, "
                  f"CPU-time based x{out[f'cpu_speedup_{w}']:.2f} (medians of per-round ratios)")
    print("RESULT " + " ".join(f"w{w}_{k}={m[k]}" for w, m in med.items()
                               for k in ("sample", "design", "estimate", "total", "serial_s", "parallel_s", "tasks",
                                         "main_cpu", "worker_cpu")) +
          "".join(f" {k}={v}" for k, v in out.items() if k.startswith(("speedup", "estimate_speedup", "cpu_speedup"))))
    return out


if __name__ == "__main__":
    main()
