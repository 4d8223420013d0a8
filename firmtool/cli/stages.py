"""The offline stage commands: ``firmtool sample``, ``design``, ``estimate`` one by one, and
``firmtool build``, the three in one (with densification)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from firmtool.cli import console
from firmtool.cli.console import num, prob
from firmtool.cli.exits import fail, handles_errors
from firmtool.cli.options import (
    SCENARIO_HELP,
    CheckpointOpt,
    ExecutorOpt,
    ForceOpt,
    JsonOpt,
    QuietOpt,
    SchedulerOpt,
    WorkersOpt,
    check_roadmap_argument,
    check_scenario_argument,
)
from firmtool.cli.output import emit, print_notices
from firmtool.errors import InputError

OutputOpt = typer.Option(None, "--output", "-o", help="Roadmap file (default artifacts/NAME.h5).")


@handles_errors
def sample(scenario: str = typer.Argument(..., help=SCENARIO_HELP),
           output: Optional[Path] = OutputOpt,
           force: bool = ForceOpt, as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Sample the nodes (start, goal, valid configurations at rest) into a new roadmap file.

    Example: firmtool sample smoke -o artifacts/smoke.h5
    """
    # lazy: saves firmtool --help the pipeline's import, 1.6 s (firmtool.cli.app)
    from firmtool.pipeline import sample_stage
    # the pipeline's boundary reads the scenario (a file or a shipped name) once
    check_scenario_argument(scenario)
    report = sample_stage(scenario, output, force=force, progress=console.progress()).to_dict()
    emit(report, as_json, lambda r: f"sampled {r['nodes']} nodes in {console.seconds(r['seconds'])}")
    print_notices(report)
    console.next_step(report["roadmap"], f"firmtool design {report['roadmap']}")


@handles_errors
def design(roadmap: Path = typer.Argument(..., help="Roadmap file with sampled nodes."),
           as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Design node stabilisers (SLQR/SLQG), node regions and edges (nominal trajectories).

    Example: firmtool design artifacts/smoke.h5
    """
    # lazy: saves firmtool --help the pipeline's import, 1.6 s (firmtool.cli.app)
    from firmtool.pipeline import design_stage
    check_roadmap_argument(roadmap)
    emit(design_stage(roadmap, progress=console.progress()).to_dict(), as_json,
         lambda r: f"designed {r['nodes']} node stabilisers and {r['edges']} edges (mean nominal "
                   f"{num(r['mean_edge_steps'], 3)} steps) in {console.seconds(r['seconds'])}")
    console.next_step(str(roadmap), f"firmtool estimate {roadmap}")


@handles_errors
def estimate(roadmap: Path = typer.Argument(..., help="Roadmap file with designed controllers."),
             workers: Optional[int] = WorkersOpt, executor: str = ExecutorOpt,
             scheduler: Optional[str] = SchedulerOpt, checkpoint_seconds: float = CheckpointOpt,
             fresh: bool = typer.Option(False, "--fresh", metavar="",
                                        help="Estimate every edge from scratch, reusing no stored estimate."),
             as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Estimate every edge by Monte Carlo (landing, failure, timeout counts; cost), in parallel.

    Edges already estimated with the same inputs (in the file, or saved by an interrupted run) are
    reused, not estimated again, unless --fresh (the reference a world update equals bit for bit;
    it also records the swept regions a roadmap estimated by an older firmtool lacks).

    Example: firmtool estimate artifacts/smoke.h5 --workers 2
    """
    # lazy: saves firmtool --help the pipeline's import, 1.6 s (firmtool.cli.app)
    from firmtool.pipeline import estimate_stage
    check_roadmap_argument(roadmap)
    report = estimate_stage(roadmap, workers=workers, executor=executor, scheduler=scheduler,
                            progress=console.progress(), checkpoint_seconds=checkpoint_seconds,
                            fresh=fresh).to_dict()
    emit(report, as_json, lambda r: (f"estimated {r['estimated_edges']} of {r['edges']} edges x "
                                     f"{r['particles_per_edge']} particles ({r['reused_edges']} reused; "
                                     f"{r['simulated_particle_steps']:,} particle-steps in "
                                     f"{console.seconds(r['seconds'])} on {console.count(r['workers'], 'worker')}"
                                     f"{engine_words(r)})"))
    print_notices(report)
    exit_on_failed_edges(report)
    console.next_step(str(roadmap), f"firmtool solve {roadmap}")


def engine_words(report: dict) -> str:
    """``", compiled engine"`` or ``", numpy engine"``: which Monte Carlo engine ran (the notices say why
    the numpy one did where the compiled one cannot)."""
    engine = report.get("engine")
    return f", {'compiled' if engine == 'numba' else 'numpy'} engine" if engine else ""


def exit_on_failed_edges(report: dict) -> None:
    """One line for any number of failed edges (each is listed in the --json report)."""
    failed = report.get("failed_edges") or []
    if failed:
        f = failed[0]
        fail(f"{report['roadmap']}: {len(failed)} edge(s) failed twice and were left out (first: edge {f['edge']} "
              f"({f['source']} -> {f['target']}): {f['error']}); run the same command again to retry them", 1)


def build_human(r: dict) -> str:
    s = r["seconds"]
    text = (f"built {r['roadmap']}: {r['nodes']} nodes, {r['edges']} edges ({r['estimated_edges']} estimated, "
            f"{r['reused_edges']} reused), {r['particles_per_edge']} particles/edge, "
            f"{r['simulated_particle_steps']:,} particle-steps simulated\n"
            f"time: sample {console.seconds(s['sample'])}, design {console.seconds(s['design'])}, "
            f"estimate {console.seconds(s['estimate'])} on {console.count(r['workers'], 'worker')}{engine_words(r)}")
    a = r.get("adaptive")
    if a:
        last = a["rounds"][-1]
        text += (f"\nadaptive Monte Carlo: {a['particles_added']:,} particles added in {len(a['rounds']) - 1} rounds "
                 f"to the {a['first_pass_particles']:,} of the first pass; start success probability "
                 f"{last['start_success_probability']:.4f}, 95% interval +-{a['halfwidth']:.4f} (target "
                 f"+-{a['target_halfwidth']:g} at p = 1/2): {a['reason']}")
    c = r.get("connectivity")
    if c:
        text += (f"\nconnected: {len(c['connected_goal_nodes'])} of {len(c['goal_nodes'])} goal nodes in the start's "
                 f"component ({c['start_component_nodes']} of {r['nodes']} nodes, {c['components']} components); "
                 f"connection stage added {c['added_nodes']} nodes (budget roadmap.bridge_nodes = {c['budget']})")
        if c.get("reachable_goal_nodes") is not None:
            text += (f"\nreachable under the estimated edges: {len(c['reachable_goal_nodes'])} of "
                     f"{len(c['goal_nodes'])} goal nodes")
        text += "".join(f"\nmissing: {m}" for m in c["missing"])
    if r.get("densify"):
        text += "\n" + "\n".join(f"  {x['nodes']} nodes: start success probability "
                                  f"{prob(x['start_success_probability'])}" for x in r["densify"]["rounds"])
        text += f"\n{r['densify']['reason']}"
    return text


@handles_errors
def build(scenario: str = typer.Argument(..., help=SCENARIO_HELP),
          output: Optional[Path] = OutputOpt,
          workers: Optional[int] = WorkersOpt, executor: str = ExecutorOpt,
          scheduler: Optional[str] = SchedulerOpt, checkpoint_seconds: float = CheckpointOpt,
          fresh: bool = typer.Option(False, "--fresh", metavar="",
                                     help="Start a new roadmap even if the output can be reused."),
          p_min: Optional[float] = typer.Option(None, "--p-min", min=0.0, max=1.0,
                                                help="Densify (add nodes, estimate new edges, re-solve) until the "
                                                     "start node's success probability reaches this."),
          max_nodes: Optional[int] = typer.Option(None, "--max-nodes", min=1,
                                                  help="Node budget of --p-min densification."),
          add_nodes: Optional[int] = typer.Option(None, "--add-nodes", min=1,
                                                  help="Nodes added per densification round (default: a quarter "
                                                       "of the current count, at least 5)."),
          force: bool = ForceOpt, as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Run the offline stages: sample, design, estimate (and, with --p-min, densify and solve).

    An existing roadmap at the output, sampled from the same scenario settings, is continued: an
    interrupted build resumes, and edges whose inputs did not change are not estimated again
    (changing only cost weights re-estimates nothing). --fresh starts over.

    Example: firmtool build point_lightdark --workers 2 --p-min 0.8 --max-nodes 120
    """
    # lazy: saves firmtool --help the library's import, 2.0 s (firmtool.cli.app)
    import firmtool.api as ft
    from firmtool.pipeline import default_output
    if max_nodes is not None and p_min is None:
        raise InputError("--max-nodes: only meaningful with --p-min")
    check_scenario_argument(scenario)
    sc = ft.load_scenario(scenario)
    rm = ft.build(sc, output=output or default_output(sc), workers=workers, executor=executor, scheduler=scheduler,
                  progress=console.progress(), fresh=fresh, p_min=p_min, max_nodes=max_nodes,
                  add_nodes=add_nodes, checkpoint_seconds=checkpoint_seconds, force=force)
    report = rm.report.to_dict()
    emit(report, as_json, build_human)
    print_notices(report)
    exit_on_failed_edges(report)
    if report["densify"] and not report["densify"]["reached"]:
        fail(report["densify"]["reason"], 1)
    exit_if_unreachable(report)
    console.next_step(report["roadmap"], f"firmtool solve {report['roadmap']}")


def exit_if_unreachable(report: dict) -> None:
    """Exit 1 when no goal node can be reached from the start (the roadmap cannot be solved)."""
    c = report.get("connectivity")
    if c and c.get("reachable_goal_nodes") is not None and not c["reachable_goal_nodes"]:
        if c.get("goal_confidence_shortfall"):  # more nodes would not help: say what would
            fail(f"{report['roadmap']}: no goal node is reachable from the start: {c['goal_confidence_shortfall']}", 1)
        why = "; ".join(c["missing"]) or "edges leave the start's component but none lands in a goal node"
        fail(f"{report['roadmap']}: no goal node is reachable from the start: {why}; raise roadmap.bridge_nodes "
              "or roadmap.nodes, or use --p-min to densify", 1)



def update_human(r: dict) -> str:
    s = r["seconds"]
    why = "; ".join(f"{why}: {n}" for why, n in sorted(r["reasons"].items())) or "none"
    return (f"updated {r['roadmap']} to the new world ({', '.join(r['changes']) or 'no change'}): "
            f"{r['edges']} edges, {r['kept_edges']} kept, {r['estimated_edges']} estimated ({r['new_edges']} new), "
            f"{r['dropped_edges']} dropped; {r['retired_nodes']} of {r['nodes']} nodes retired\n"
            f"not kept: {why}\n"
            f"time: design {console.seconds(s['design'])}, estimate {console.seconds(s['estimate'])}, "
            f"solve {console.seconds(s['solve'])}; P(success) from the start {prob(r['start_success_probability'])}"
            + _queries_human(r))


def _queries_human(r: dict) -> str:
    """What the update did with the stored queries (nothing when there were none)."""
    kept, answered, dropped = r.get("queries_kept", ()), r.get("queries_answered", ()), r.get("queries_dropped", {})
    lines = []
    if kept:
        lines.append(f"stored queries kept as they were: {', '.join(kept)}")
    if answered:
        lines.append(f"stored queries answered again in the new world: {', '.join(answered)}")
    lines += [f"stored query {name} dropped: {why}" for name, why in dropped.items()]
    return "".join("\n" + ln for ln in lines)


@handles_errors
def update(roadmap: Path = typer.Argument(..., help="Roadmap file with estimated edges."),
           scenario: str = typer.Argument(..., help="The scenario of the new world: the roadmap's, with another "
                                                     "[world] (obstacles added, moved or removed; bounds)."),
           workers: Optional[int] = WorkersOpt, executor: str = ExecutorOpt,
           scheduler: Optional[str] = SchedulerOpt, as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Bring a built roadmap to a changed world, re-estimating only the edges the change can alter.

    Nodes the new world puts in collision are retired with their edges; an edge is estimated again
    only when a changed obstacle or bound comes within the robot's reach of the region its
    particles swept, or its particles landed in a retired node. The result equals, bit for bit,
    'firmtool estimate --fresh' and 'firmtool solve' on the updated node set. The file is replaced
    whole at the end: an interrupted update leaves it as it was.

    Example: firmtool update artifacts/point_lightdark.h5 point_lightdark_door.toml
    """
    # lazy: saves firmtool --help the library's import, 2.0 s (firmtool.cli.app)
    import firmtool.api as ft
    check_roadmap_argument(roadmap)
    check_scenario_argument(scenario)
    report = ft.update(roadmap, scenario, workers=workers, executor=executor, scheduler=scheduler,
                       progress=console.progress()).report.to_dict()
    emit(report, as_json, update_human)
    print_notices(report)
    console.next_step(str(roadmap), f"firmtool execute {roadmap}")
