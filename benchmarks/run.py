"""Run the whole benchmark suite and write benchmarks/results/latest.json.

    python benchmarks/run.py            # everything (about 5-10 minutes on 2 cores)
    python benchmarks/run.py --quick    # fewer repeats and edges (about 2 minutes)
    python benchmarks/run.py --only edges dp

Parts: edges (Monte Carlo throughput), build (arm build by stage), dp (DP + success probability),
online (execution step / replan time), memory (peak memory vs simulated steps); not run unless named
with --only: overhead (end to end vs the engine alone), dask (dask vs local processes), scale (the
arm with ten times the nodes).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only", nargs="+", default=["edges", "build", "dp", "online", "memory"])
    ap.add_argument("--out", default=str(HERE / "results" / "latest.json"))
    args = ap.parse_args(argv)
    import bench_build, bench_dask, bench_dp, bench_edges, bench_memory, bench_online, bench_scale  # noqa: E401
    import profile_edges
    from _common import machine
    q = args.quick
    parts = {
        "edges": lambda: bench_edges.main(["--edges", "20" if q else "40", "--repeat", "3" if q else "5"]),
        "build": lambda: bench_build.main(["--rounds", "1" if q else "2", "--workers", "1", "2"]),
        "overhead": lambda: profile_edges.main(["--repeat", "3" if q else "5"]),
        "dask": lambda: bench_dask.main(["--rounds", "1" if q else "3"]),
        "scale": lambda: bench_scale.main(["--particles", "20" if q else "200"]),
        "dp": lambda: bench_dp.main(["--repeat", "1" if q else "3"]),
        "online": lambda: bench_online.main(["--episodes", "20" if q else "50", "--repeat", "2" if q else "3"]),
        "memory": lambda: bench_memory.main(["--edges", "5" if q else "10"]),
    }
    results = {"machine": machine(), "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    for name in args.only:
        print(f"== {name}", flush=True)
        t0 = time.perf_counter()
        try:
            results[name] = parts[name]()
        except Exception as exc:  # one broken part must not lose the others' results
            import traceback
            traceback.print_exc()
            results[name] = {"error": f"{type(exc).__name__}: {exc}"}
        results[name + "_seconds"] = time.perf_counter() - t0
        out.write_text(json.dumps(results, indent=1, default=str))  # after every part
    print(f"results written to {out}")


if __name__ == "__main__":
    main()
