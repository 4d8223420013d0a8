"""Old vs new, interleaved: run one benchmark command alternately against two source trees.

    python benchmarks/compare.py --old /tmp/base --rounds 3 -- benchmarks/profile_edges.py --repeat 3

Each round runs the command once with ``PYTHONPATH=OLD`` and once with ``PYTHONPATH=NEW`` (default:
this checkout), alternating which goes first, and collects the numbers the command prints as
``key=value`` tokens on lines starting with ``RESULT``. Prints per-key medians and the new/old
ratio of medians, and the load average before and after: on shared cores only ratios measured
this way (same run, interleaved) are meaningful. Make a tree of the old commit with e.g.
``git archive OLD | tar -x -C /tmp/base``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(tree: str, cmd: list[str]) -> dict[str, float]:
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, *cmd], cwd=ROOT, env=env, capture_output=True, text=True, check=True).stdout
    vals: dict[str, float] = {}
    for line in out.splitlines():
        if line.startswith("RESULT"):
            for tok in line.split()[1:]:
                k, _, v = tok.partition("=")
                vals[k] = float(v)
    return vals


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--old", required=True)
    ap.add_argument("--new", default=str(ROOT))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("cmd", nargs=argparse.REMAINDER)
    args = ap.parse_args(argv)
    cmd = args.cmd[1:] if args.cmd[:1] == ["--"] else args.cmd
    load0 = os.getloadavg()
    res: dict[str, list[dict[str, float]]] = {"old": [], "new": []}
    for r in range(args.rounds):
        order = ("old", "new") if r % 2 == 0 else ("new", "old")
        for which in order:
            res[which].append(_run(getattr(args, which), cmd))
            print(which, res[which][-1], flush=True)
    load1 = os.getloadavg()
    keys = sorted(set().union(*res["old"], *res["new"]))
    for k in keys:
        o = statistics.median(v[k] for v in res["old"] if k in v)
        n = statistics.median(v[k] for v in res["new"] if k in v)
        print(f"{k:28s} old {o:12.4g}  new {n:12.4g}  new/old {n / o:6.3f}")
    print(f"load average (1, 5, 15 min) before {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}, "
          f"after {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")


if __name__ == "__main__":
    main()
