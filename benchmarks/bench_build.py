"""Full build time of scenarios/arm8_lightdark.toml by stage (pipeline.build: sample, design, estimate).

    python benchmarks/bench_build.py [--workers 2] [--repeat 3] [--engine numba|numpy] [--json]

Medians of ``--repeat`` builds into a temporary folder.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SCENARIOS, engine, one_blas_thread  # noqa: E402


def build_times(workers: int, repeat: int, eng: str | None, scenario: str = "arm") -> dict:
    from firmtool.pipeline import build
    one_blas_thread()  # as the CLI does
    runs = []
    with engine(eng), tempfile.TemporaryDirectory() as tmp:
        for i in range(repeat):
            r = build(SCENARIOS[scenario], Path(tmp) / f"b{i}.h5", workers=workers)
            s = dict(r.seconds)
            runs.append({**s, "total": sum(s.values()), "particle_steps_per_second": r.particle_steps_per_second,
                         "edges": r.edges, "nodes": r.nodes, "particle_steps": r.particle_steps})
    med = {k: statistics.median(run[k] for run in runs) for k in runs[0]}
    return {"median": med, "runs": runs, "workers": workers, "engine": eng or "auto"}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--engine", default=None)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    out = [build_times(w, args.repeat, args.engine) for w in args.workers]
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        for r in out:
            m = r["median"]
            print(f"arm build, {r['workers']} worker(s), engine {r['engine']}: sample {m['sample']:.1f} s, design "
                  f"{m['design']:.1f} s, estimate {m['estimate']:.1f} s, total {m['total']:.1f} s "
                  f"({m['edges']:.0f} edges, {m['particle_steps_per_second'] / 1e6:.2f} M particle-steps/s in estimate)")
        print("RESULT " + " ".join(f"w{r['workers']}_{k}={r['median'][k]}" for r in out
                                   for k in ("sample", "design", "estimate", "total", "particle_steps_per_second")))
    return {"builds": out}


if __name__ == "__main__":
    main()
