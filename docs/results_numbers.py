"""The numbers of the results pages (``docs/results/*.md``), measured by their commands and kept in
``docs/results/numbers.json`` with the firmtool version and commit that produced them; the pages'
``<!-- generated: results NAME -->`` blocks are written from that file by ``docs/generate.py``
(issue 54: a page showed 0.750/0.810 where its command gave 0.781/0.845).

Each measurement is recorded twice: at the page's size (``full``: what the page shows) and at a
reduced size (``reduced``: a smaller roadmap, fewer particles and episodes, the same code path).
``tests/test_results_numbers.py`` runs the reduced command again and fails when a number differs
from the recorded one: a change of the code that moves a page's numbers shows in the same commit,
and ``python docs/results_numbers.py NAME`` measures both again (``--reduced`` only the reduced one).

Every number is deterministic (the scenario's seed, the episodes' seed; not the workers) except the
build's wall time, which is shown and never compared.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
NUMBERS = DOCS / "results" / "numbers.json"
sys.path.insert(0, str(ROOT))

import firmtool as ft  # noqa: E402

# name -> the page's command (scenario, episodes, seed) and the reduced size's overrides.
MEASUREMENTS: dict[str, dict[str, Any]] = {
    "point_lightdark": {"scenario": "point_lightdark", "episodes": 200, "seed": 0,
                        "reduced": {"roadmap": {"nodes": 24}, "estimation": {"particles": 60}}, "reduced_episodes": 20},
    "point_perfect": {"scenario": "point_perfect", "episodes": 200, "seed": 0,
                      "reduced": {"roadmap": {"nodes": 24}, "estimation": {"particles": 60}}, "reduced_episodes": 20},
}


STREAM = 1  # the random stream of the recorded measurements (firmtool.scenario.STREAMS)


def measure(name: str, reduced: bool, workers: int = 2) -> dict[str, Any]:
    """Build, solve and execute one measurement (at the reduced size if ``reduced``): its numbers."""
    m = MEASUREMENTS[name]
    # the pages' numbers were measured with stream 1 (issue 55 made stream 2 new roadmaps' default): kept so
    # that they stay what the pages say; measure them again with STREAM = 2 to move them
    sc = ft.load_scenario(m["scenario"]).replace(estimation={"stream": STREAM})
    if reduced:
        sc = sc.replace(**m["reduced"])
    t0 = time.perf_counter()
    rm = ft.build(sc, workers=workers)
    seconds = time.perf_counter() - t0
    sol = ft.solve(rm)
    res = ft.simulate(sol, episodes=m["reduced_episodes"] if reduced else m["episodes"], seed=m["seed"])
    lo, hi = sol.success_probability_ci95
    rlo, rhi = res.success_rate_ci95
    return {"nodes": int(len(rm.nodes)), "edges": int(len(rm.edges)), "path": [int(i) for i in sol.path()],
            "predicted": round(float(sol.success_probability), 3), "predicted_ci95": [round(lo, 3), round(hi, 3)],
            "episodes": len(res.episodes), "seed": m["seed"], "executed": round(float(res.success_rate), 3),
            "executed_ci95": [round(float(rlo), 3), round(float(rhi), 3)], "goal_misses": int(res.goal_misses),
            "estimate_criterion": round(float(res.estimate_success_rate), 3),
            "build_seconds": round(seconds, 1)}


COMPARED = ("nodes", "edges", "path", "predicted", "predicted_ci95", "episodes", "executed", "executed_ci95",
            "goal_misses", "estimate_criterion")  # build_seconds: a wall time, shown, never compared


def recorded() -> dict[str, Any]:
    return json.loads(NUMBERS.read_text()) if NUMBERS.exists() else {}


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def render(names: list[str]) -> str:
    """The Markdown of a ``results NAME...`` block: the first one's commands and one row per name,
    stamped with the version and commit that measured them."""
    data = recorded()
    missing = [n for n in names if n not in data or n not in MEASUREMENTS]
    if missing:
        raise KeyError(f"results: no recorded numbers for {missing} in docs/results/numbers.json "
                       f"(python docs/results_numbers.py {' '.join(missing)})")
    m0 = MEASUREMENTS[names[0]]
    f0 = data[names[0]]["full"]
    out = [f"```bash\nfirmtool build {m0['scenario']} -o artifacts/docs/{m0['scenario']}.h5\n"
           f"firmtool solve artifacts/docs/{m0['scenario']}.h5\n"
           f"firmtool execute artifacts/docs/{m0['scenario']}.h5 -n {m0['episodes']} --seed {m0['seed']}\n```\n",
           f"| scenario | nodes / edges | build (2 workers) | predicted success (95% interval) | executed "
           f"({f0['episodes']} episodes, seed {f0['seed']}; 95% interval) | goal misses | estimate criterion |",
           "|---|---|---|---|---|---|---|"]
    stamps = []
    for name in names:
        m, d = MEASUREMENTS[name], data[name]
        f = d["full"]
        out.append(f"| `{m['scenario']}` | {f['nodes']} / {f['edges']} | {f['build_seconds']:.1f} s | {f['predicted']:.3f} "
                   f"({f['predicted_ci95'][0]:.3f}-{f['predicted_ci95'][1]:.3f}) | {f['executed']:.3f} "
                   f"({f['executed_ci95'][0]:.3f}-{f['executed_ci95'][1]:.3f}) | {f['goal_misses']} | "
                   f"{f['estimate_criterion']:.3f} |")
        stamps.append(f"`{m['scenario']}`: policy path {' -> '.join(map(str, f['path']))}, measured with firmtool "
                      f"{d['version']} (commit {d['commit']})")
    out += ["", "; ".join(stamps) + ". The build times are wall times of the measuring machine (2 cores, "
            "shared); every other number is deterministic, and `tests/test_results_numbers.py` checks at a "
            "reduced size that the code still gives them (`python docs/results_numbers.py` measures them again)."]
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help=f"measurements (default: all: {', '.join(MEASUREMENTS)})")
    parser.add_argument("--reduced", action="store_true", help="measure the reduced size only")
    args = parser.parse_args(argv)
    data = recorded()
    for name in args.names or list(MEASUREMENTS):
        entry = data.get(name, {})
        entry["reduced"] = measure(name, reduced=True)
        if not args.reduced:
            entry["full"] = measure(name, reduced=False)
            entry["version"], entry["commit"] = ft.__version__, _commit()
        data[name] = entry
        print(f"{name}: {json.dumps(entry)}")
    NUMBERS.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
