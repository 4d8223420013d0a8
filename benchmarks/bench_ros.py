"""Issue 41: the ROS 2 nodes in real time. Does the control keep its period behind the middleware?

The policy node (``firmtool ros``) and the simulated robot (``firmtool ros-sim --timed``) run as two
processes over Fast DDS at ``--rate`` Hz (default 20), inside a private network namespace holding only
loopback (firmtool.ros.confine: no packet leaves it). The simulator's timer steps the true system
once per period with the newest control and measures, at the robot's side of the messages:

- the control messages' inter-arrival times, and their jitter ``|interval - period|`` (target: p99
  under 20% of the period);
- the latency from a measurement's publication to the arrival of the control that answers it
  (DDS both ways, the node's observe, decision and act);
- ``held``: periods in which no new control had come (the last one applied again).

    python benchmarks/bench_ros.py                     # point_lightdark (small build), 20 Hz, 10 episodes
    python benchmarks/bench_ros.py --rate 50 --episodes 5 --json out.json

Needs the ros extra and root (``unshare --net``). The roadmap is built here with small settings
(30 nodes, 60 particles), as tests/test_ros.py builds it: the timing is the online loop's, not the
roadmap's.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import firmtool as ft
from firmtool.ros.confine import confined_command, confinement_problem, environment


def build(folder: Path) -> Path:
    sc = ft.load_scenario("point_lightdark").replace(estimation={"particles": 60, "adaptive_particles": 0},
                                                     roadmap={"nodes": 30})
    out = folder / "point_lightdark.h5"
    ft.solve(ft.build(sc, workers=1, output=out)).save()
    return out


def run(roadmap: Path, rate: float, episodes: int, seed: int, folder: Path) -> dict:
    """Both nodes in one private namespace; the simulator's summary (JSON)."""
    py = shlex.quote(sys.executable)
    rm = shlex.quote(str(roadmap))
    script = (f"{py} -m firmtool ros {rm} --rate {rate} --ros-args -p autostart:=false 2> {folder}/node.log & "
              f"node=$!; {py} -m firmtool ros-sim {rm} --timed --rate {rate} --episodes {episodes} --seed {seed} "
              f"--json 2> {folder}/sim.log; rc=$?; kill -INT $node; wait $node; exit $rc")
    env = environment(folder, 10 + os.getpid() % 90)
    env["OPENBLAS_NUM_THREADS"] = "1"
    res = subprocess.run(confined_command(["sh", "-c", script]), env=env, capture_output=True, text=True,
                         timeout=1800)
    if res.returncode != 0:
        raise SystemExit(f"bench_ros: the run failed ({res.returncode}): {res.stderr[-2000:]}"
                         f"{(folder / 'sim.log').read_text()[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rate", type=float, default=20.0, help="control rate, Hz")
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path, help="write the summary here")
    args = ap.parse_args(argv)
    problem = confinement_problem()
    if problem:
        raise SystemExit(f"bench_ros: {problem}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        t0 = time.perf_counter()
        roadmap = build(folder)
        built = time.perf_counter() - t0
        t0 = time.perf_counter()
        s = run(roadmap, args.rate, args.episodes, args.seed, folder)
        wall = time.perf_counter() - t0
    period = 1e3 / args.rate
    j, lat, iv = s["jitter_ms"], s["latency_ms"], s["control_interval_ms"]
    steps = sum(r["steps"] for r in s["outcomes"])
    print(f"build {built:.1f} s; run {wall:.1f} s: {s['episodes']} episodes, {steps} steps at {args.rate:g} Hz "
          f"(period {period:.1f} ms), load average {os.getloadavg()[0]:.2f}")
    print(f"control interval ms: p50 {iv['p50']:.2f}  p99 {iv['p99']:.2f}  max {iv['max']:.2f}  (n = {iv['count']})")
    print(f"jitter ms:           p50 {j['p50']:.2f}  p99 {j['p99']:.2f}  max {j['max']:.2f}  "
          f"-> p99 = {100 * j['p99'] / period:.1f}% of the period (target < 20%)")
    print(f"latency ms (measurement -> control): p50 {lat['p50']:.2f}  p99 {lat['p99']:.2f}  max {lat['max']:.2f}")
    print(f"held periods (no new control in time): {s['held']}; success rate {s['success_rate']:.2f}")
    if args.json:
        args.json.write_text(json.dumps({"rate": args.rate, "build_s": built, "run_s": wall, **s}, indent=1))
    return 0 if j["p99"] < 0.2 * period else 1


if __name__ == "__main__":
    sys.exit(main())
