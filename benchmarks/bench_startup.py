"""Start-up of the command line (issue 54): ``firmtool --help``, and ``check``, ``inspect`` and
``solve`` on a built roadmap of every shipped scenario, warm (Python's bytecode and numba's caches
filled by a first run that is not counted), as fresh processes the way a user runs them::

    python benchmarks/bench_startup.py [--repeat 3] [--scenarios smoke arm7_shelf] [--full]

Each command's wall time (the least of the repeats: the one least disturbed by other jobs) and its
CPU time (user + sys of the process, median of the repeats: on a busy machine the closer estimate of
an idle machine's wall time, since the command is one process on one core). The roadmaps are built
at a reduced size (roadmap.nodes 30, estimation.particles 60) unless ``--full``: start-up and the
solve's fixed costs dominate there; a full roadmap adds the DP and its interval draws. Prints the
load average before and after. Targets (issue 54, idle 2-core machine): --help < 0.5 s; check,
inspect, solve < 1.5 s each.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted(p.stem for p in (ROOT / "scenarios").glob("*.toml"))


def timed(args: list[str], env: dict) -> tuple[float, float]:
    """(wall seconds, user + sys CPU seconds) of ``firmtool ARGS`` as a fresh process."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "firmtool", *args], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"firmtool {' '.join(args)}: exit {os.waitstatus_to_exitcode(status)}: "
                         f"{proc.stderr.read()[-500:]}")
    return wall, usage.ru_utime + usage.ru_stime


def build(name: str, out: Path, full: bool) -> None:
    import firmtool as ft
    sc = ft.load_scenario(name)
    if not full:
        sc = sc.replace(roadmap={"nodes": 30}, estimation={"particles": 60})
    ft.build(sc, output=out, workers=2)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--scenarios", nargs="*", default=SHIPPED)
    parser.add_argument("--full", action="store_true", help="build the roadmaps at the scenarios' own size")
    args = parser.parse_args(argv)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}  # a user's Python writes .pyc
    tmp = Path(tempfile.mkdtemp(prefix="firmtool-startup-"))
    try:
        print(f"load average before: {' '.join(f'{x:.1f}' for x in os.getloadavg())}", flush=True)
        rows = []
        commands = [("--help", ["--help"])]
        for name in args.scenarios:
            out = tmp / f"{name}.h5"
            build(name, out, args.full)
            commands += [(f"check {name}", ["check", name]), (f"inspect {name}", ["inspect", str(out)]),
                         (f"solve {name}", ["solve", str(out), "-q"])]
        for label, cmd in commands:
            timed(cmd, env)  # warm: bytecode and caches filled, not counted
            runs = [timed(cmd, env) for _ in range(args.repeat)]
            rows.append((label, min(w for w, _ in runs), statistics.median(c for _, c in runs)))
            print(f"| {label} | {rows[-1][1]:.2f} s | {rows[-1][2]:.2f} s |", flush=True)
        print(f"load average after: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
