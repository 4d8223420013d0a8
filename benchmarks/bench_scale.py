"""Roadmaps ten times larger: the arm built with ``--scale`` x its nodes, time by stage and peak memory.

    python benchmarks/bench_scale.py [--nodes 300 4000] [--particles 200] [--workers 2] [--json]

Each build runs in a fresh process (so that its peak resident set size is its own): the arm scenario
with ``roadmap.nodes`` set to each of ``--nodes`` (the shipped 300 give 410 nodes with the goal
nodes and the bridges; 3900 give ~4000, ten times as many), the shipped bridge budget (150: a
larger one makes the bridging rounds, each a pass over all nodes, the sampling's bottleneck), and
``estimation.particles`` set to ``--particles``. Reported per build:
nodes, edges, particle-steps, seconds by stage, the file's size, and the peak RSS of the building
process and of the largest worker process (``getrusage``: ``RUSAGE_SELF`` and ``RUSAGE_CHILDREN``,
whose ``ru_maxrss`` is the largest of the finished children).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

CHILD = r"""
import json, os, re, resource, sys, tempfile, time
sys.path.insert(0, {here!r})
from _common import SCENARIOS, one_blas_thread
one_blas_thread()
from firmtool.pipeline import build
from firmtool.scenario import parse_scenario
text = SCENARIOS["arm"].read_text()
for key, value in {settings!r}.items():
    text = re.sub(rf"(?m)^{{key}} = .*$", f"{{key}} = {{value}}", text)
with tempfile.TemporaryDirectory() as tmp:
    path = os.path.join(tmp, "arm.toml")
    open(path, "w").write(text)
    out = os.path.join(tmp, "arm.h5")
    t0 = time.perf_counter()
    r = build(parse_scenario(text, path), out, workers={workers})
    wall = time.perf_counter() - t0
    size = os.path.getsize(out)
self_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
child_rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
print(json.dumps({{"nodes": r.nodes, "edges": r.edges, "particles": {particles}, "particle_steps": r.particle_steps,
                  "seconds": r.seconds, "wall": wall, "file_mib": size / 2**20, "peak_rss_mib": self_rss,
                  "worker_peak_rss_mib": child_rss, "rate": r.particle_steps_per_second, "failed": len(r.failed_edges)}}))
"""


def measure(nodes: int, particles: int, workers: int) -> dict:
    settings = {"nodes": nodes, "particles": particles}
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", CHILD.format(here=str(HERE), settings=settings, workers=workers,
                                                             particles=particles)],
                         capture_output=True, text=True, env=env)
    if out.returncode != 0:
        raise SystemExit(out.stderr[-3000:])
    return {**json.loads(out.stdout.strip().splitlines()[-1]), "requested_nodes": nodes, "workers": workers,
            "load_after": os.getloadavg()[0]}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--nodes", type=int, nargs="+", default=[300, 3900])
    ap.add_argument("--particles", type=int, default=200)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for nodes in args.nodes:
        rows.append(measure(nodes, args.particles, args.workers))
        r = rows[-1]
        if not args.json:
            s = r["seconds"]
            print(f"roadmap.nodes = {nodes}: {r['nodes']} nodes, {r['edges']} edges, {r['particles']} particles/edge, "
                  f"{r['particle_steps'] / 1e6:.1f} M particle-steps; sample {s['sample']:.1f} s, design {s['design']:.1f} s, "
                  f"estimate {s['estimate']:.1f} s ({r['rate'] / 1e6:.2f} M/s), wall {r['wall']:.1f} s; file "
                  f"{r['file_mib']:.1f} MiB; peak RSS: build process {r['peak_rss_mib']:.0f} MiB, largest worker "
                  f"{r['worker_peak_rss_mib']:.0f} MiB; load after {r['load_after']:.1f}", flush=True)
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        print("RESULT " + " ".join(f"n{r['requested_nodes']}_{k}={r[k]}" for r in rows
                                   for k in ("nodes", "edges", "wall", "peak_rss_mib", "worker_peak_rss_mib", "file_mib")))
    return {"scale": rows}


if __name__ == "__main__":
    main()
