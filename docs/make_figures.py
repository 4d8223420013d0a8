"""Regenerate every figure of the documentation, and the runs its results pages quote:
``python docs/make_figures.py``.

Each figure is made by the firmtool commands listed with it (the documentation shows them), run
here one after the other from the repository root; roadmaps go to ``artifacts/docs/`` (built once,
then reused: ``firmtool build`` continues a roadmap whose inputs did not change; delete the folder
for fresh build times), figures to ``docs/figures/``. Then the runs whose numbers the results pages
quote (:data:`RUNS`), each ``--json`` report kept in ``artifacts/docs/``; ``--summary`` prints their
numbers as the pages give them.

    python docs/make_figures.py                 # every figure and run (about 15 minutes on 2 cores)
    python docs/make_figures.py arm8_lightdark  # the figures and runs whose name contains this
    python docs/make_figures.py --list          # what would be made, and how
    python docs/make_figures.py --summary       # the numbers of the last runs

Figures are written at a modest resolution (``--dpi 70`` or ``80``) so that each stays under 300 KB.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIGURES_DIR = Path("docs/figures")
ARTIFACTS = Path("artifacts/docs")
MAX_BYTES = 300_000


@dataclass(frozen=True)
class DocFigure:
    """A figure of the documentation: its file (in docs/figures), what it shows, the commands that
    make it (run in order from the repository root; the last one writes the file)."""

    file: str
    what: str
    commands: tuple[str, ...]

    @property
    def command(self) -> str:
        """The command that draws the figure (the last one), as the documentation shows it."""
        return self.commands[-1]


def _roadmap(name: str) -> tuple[str, ...]:
    """Build and solve a shipped scenario into artifacts/docs/NAME.h5, keeping the JSON reports."""
    out = ARTIFACTS / f"{name}.h5"
    return (f"firmtool build scenarios/{name}.toml -o {out} --json > {ARTIFACTS}/{name}.build.json",
            f"firmtool solve {out} --json > {ARTIFACTS}/{name}.solve.json")


FIGURES: tuple[DocFigure, ...] = (
    DocFigure("arm8_lightdark.png",
              "the paper's experiment: FIRM through the lit left passage, the shortest path through the dark right one",
              _roadmap("arm8_lightdark") + (
                  f"firmtool plot {ARTIFACTS}/arm8_lightdark.h5 --episodes 200 --seed 1 --dpi 70 --force "
                  f"-o {FIGURES_DIR}/arm8_lightdark.png",)),
    DocFigure("calibration_arm8_lightdark.png",
              "the arm's policy edges: Monte Carlo predictions against executed frequencies",
              _roadmap("arm8_lightdark") + (
                  f"firmtool plot {ARTIFACTS}/arm8_lightdark.h5 --kind calibration --episodes 400 --seed 1 "
                  f"--dpi 80 --force -o {FIGURES_DIR}/calibration_arm8_lightdark.png",)),
    DocFigure("rollout_arm8_lightdark.png",
              "the same episode of the arm under FIRM (settling at every node) and rollout FIRM (heading on)",
              _roadmap("arm8_lightdark") + (
                  f"firmtool plot {ARTIFACTS}/arm8_lightdark.h5 --policy firm-rollout --episodes 30 --seed 1 "
                  f"--dpi 70 --force -o {FIGURES_DIR}/rollout_arm8_lightdark.png",)),
    DocFigure("point_lightdark.png",
              "a double-integrator point robot in a light-dark world: FIRM and the shortest path",
              _roadmap("point_lightdark") + (
                  f"firmtool plot {ARTIFACTS}/point_lightdark.h5 --episodes 200 --dpi 80 --force "
                  f"-o {FIGURES_DIR}/point_lightdark.png",)),
    DocFigure("calibration_point_lightdark.png",
              "the point robot's policy edges: Monte Carlo predictions against executed frequencies",
              _roadmap("point_lightdark") + (
                  f"firmtool plot {ARTIFACTS}/point_lightdark.h5 --kind calibration --episodes 400 --dpi 80 "
                  f"--force -o {FIGURES_DIR}/calibration_point_lightdark.png",)),
    DocFigure("unicycle_lightdark.png",
              "the unicycle: estimated position and heading with 3-sigma ellipses along an episode",
              _roadmap("unicycle_lightdark") + (
                  f"firmtool plot {ARTIFACTS}/unicycle_lightdark.h5 --policy firm --episodes 100 --seed 7 "
                  f"--dpi 80 --force -o {FIGURES_DIR}/unicycle_lightdark.png",)),
    DocFigure("unicycle_office.png",
              "a unicycle in an office map: FIRM the long way past the landmarks, the shortest path through the dark door",
              _roadmap("unicycle_office") + (
                  f"firmtool plot {ARTIFACTS}/unicycle_office.h5 --episodes 100 --seed 7 --dpi 80 --force "
                  f"-o {FIGURES_DIR}/unicycle_office.png",)),
    DocFigure("platt_lightdark.png",
              "Platt et al.'s light-dark problem: FIRM localises in the light, then goes to the goal",
              _roadmap("platt_lightdark") + (
                  f"firmtool plot {ARTIFACTS}/platt_lightdark.h5 --episodes 100 --dpi 64 --force "
                  f"-o {FIGURES_DIR}/platt_lightdark.png",)),
    DocFigure("custom_robot_3d.png",
              "a robot of your own (examples/custom_robot_3d.py): a 3-D flyer seen from above",
              (f"python examples/custom_robot_3d.py {FIGURES_DIR}/custom_robot_3d.png",)),
    DocFigure("arm7_shelf.png",
              "your arm from its URDF (examples/urdf_arm.py): arm7_shelf's tip paths in 3-D",
              (f"python examples/urdf_arm.py {FIGURES_DIR}/arm7_shelf.png",)),
)


def _execute(name: str, tag: str, options: str) -> tuple[str, ...]:
    """A run of ``firmtool execute`` on a docs roadmap, its report kept as NAME.TAG.json."""
    return _roadmap(name) + (f"firmtool execute {ARTIFACTS}/{name}.h5 {options} --json > {ARTIFACTS}/{name}.{tag}.json",)


# The runs whose numbers the results pages quote (docs/results/), by name.
RUNS: dict[str, tuple[str, ...]] = {
    "arm8_lightdark.firm": _execute("arm8_lightdark", "firm", "-n 200 --seed 1"),
    "arm8_lightdark.shortest": _execute("arm8_lightdark", "shortest", "-n 200 --seed 1 --policy shortest-path"),
    "point_lightdark.firm": _execute("point_lightdark", "firm", "-n 200 --seed 0"),
    "point_perfect.firm": _execute("point_perfect", "firm", "-n 200 --seed 0"),
    "unicycle_lightdark.firm": _execute("unicycle_lightdark", "firm", "-n 200 --seed 7"),
    "unicycle_lightdark.noreplan": _execute("unicycle_lightdark", "noreplan", "-n 200 --seed 7 --no-replan"),
    "unicycle_perfect.firm": _execute("unicycle_perfect", "firm", "-n 200 --seed 7"),
    "platt_lightdark.firm": _execute("platt_lightdark", "firm", "-n 200 --seed 0"),
    "point_lightdark.push40": _execute("point_lightdark", "push40", "-n 200 --seed 0 -d push:40:2.0"),
    "point_lightdark.push40_off": _execute("point_lightdark", "push40_off", "-n 200 --seed 0 -d push:40:2.0 --no-replan"),
    "point_lightdark.kidnap40": _execute("point_lightdark", "kidnap40", "-n 200 --seed 0 -d kidnap:40"),
    "point_lightdark.kidnap40_off": _execute("point_lightdark", "kidnap40_off", "-n 200 --seed 0 -d kidnap:40 --no-replan"),
    "arm8_lightdark.push110": _execute("arm8_lightdark", "push110", "-n 200 --seed 3 -d push:110:1.0"),
    "arm8_lightdark.push110_off": _execute("arm8_lightdark", "push110_off", "-n 200 --seed 3 -d push:110:1.0 --no-replan"),
}


def summary() -> None:
    """The numbers of the last runs (build, solve, execute reports in artifacts/docs/)."""
    folder = ROOT / ARTIFACTS
    for path in sorted(folder.glob("*.build.json")):
        b = json.loads(path.read_text())
        s = b["seconds"]
        print(f"{path.name}: {b['nodes']} nodes, {b['edges']} edges x {b['particles_per_edge']} particles, "
              f"{b['simulated_particle_steps']:,} particle-steps; sample {s['sample']:.1f} s, design {s['design']:.1f} s, "
              f"estimate {s['estimate']:.1f} s, {b['workers']} workers")
    for path in sorted(folder.glob("*.solve.json")):
        r = json.loads(path.read_text())
        ci = r.get("start_success_probability_ci95")
        print(f"{path.name}: predicted {r['start_success_probability']:.4f}"
              + (f" ({ci[0]:.3f}-{ci[1]:.3f})" if ci else "")
              + f", shortest path {r['shortest_path_start_success_probability']:.4f}, path {r['path']}")
    for name in RUNS:
        path = folder / f"{name}.json"
        if not path.exists():
            continue
        r = json.loads(path.read_text())
        lo, hi = r["success_rate_ci95"]
        pred, pci = r.get("predicted_success_probability"), r.get("predicted_success_probability_ci95")
        cal = r.get("calibration") or {}
        print(f"{name}: {r['successes']}/{r['episodes']} = {r['success_rate']:.3f} ({lo:.3f}-{hi:.3f}); predicted "
              + ("-" if pred is None else f"{pred:.3f}") + (f" ({pci[0]:.3f}-{pci[1]:.3f})" if pci else "")
              + (f"; estimate criterion {r['estimate_success_rate']:.3f}, goal misses {r['goal_misses']}"
                 if r.get("estimate_success_rate") is not None else "")
              + f"; replans/episode {r['replans_per_episode']:.2f}; collisions {r['collisions']}, timeouts "
              f"{r['timeouts']}; calibration {cal.get('edges_checked')} of {cal.get('edges_taken')} checked, "
              f"flagged {cal.get('flagged_edges')}")


def run_commands(commands: tuple[str, ...], done: set[str]) -> None:
    for command in commands:
        if command in done:  # a roadmap built and solved for an earlier figure
            continue
        print(f"$ {command}", flush=True)
        t0 = time.perf_counter()
        subprocess.run(command, shell=True, check=True, cwd=ROOT)
        print(f"  ({time.perf_counter() - t0:.0f} s)", flush=True)
        done.add(command)


def run(figure: DocFigure, done: set[str]) -> None:
    run_commands(figure.commands, done)
    path = ROOT / FIGURES_DIR / figure.file
    size = path.stat().st_size
    if size > MAX_BYTES:
        raise SystemExit(f"{path}: {size} bytes, more than {MAX_BYTES}: lower its --dpi")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("only", nargs="*", help="make only the figures whose file name contains one of these")
    parser.add_argument("--list", action="store_true", help="list the figures and their commands, make nothing")
    parser.add_argument("--summary", action="store_true", help="print the numbers of the last runs, make nothing")
    args = parser.parse_args(argv)
    if args.summary:
        summary()
        return 0
    chosen = [f for f in FIGURES if not args.only or any(o in f.file for o in args.only)]
    runs = {n: c for n, c in RUNS.items() if not args.only or any(o in n for o in args.only)}
    if args.list:
        for f in chosen:
            print(f"{FIGURES_DIR / f.file}: {f.what}\n" + "".join(f"  $ {c}\n" for c in f.commands))
        for name, commands in runs.items():
            print(f"run {name}:\n" + "".join(f"  $ {c}\n" for c in commands))
        return 0
    (ROOT / ARTIFACTS).mkdir(parents=True, exist_ok=True)
    (ROOT / FIGURES_DIR).mkdir(parents=True, exist_ok=True)
    done: set[str] = set()
    for f in chosen:
        run(f, done)
        print(f"wrote {FIGURES_DIR / f.file} ({(ROOT / FIGURES_DIR / f.file).stat().st_size // 1000} KB)", flush=True)
    for commands in runs.values():
        run_commands(commands, done)
    summary()
    return 0


if __name__ == "__main__":
    sys.exit(main())
