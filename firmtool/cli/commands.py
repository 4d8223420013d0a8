"""The ``firmtool`` command line: parse, call the library, print, exit.

Exit codes: 0 success, 1 a run that failed on its own terms (unreachable goal, numerical failure,
disk full), 2 bad input (scenario, roadmap file, option or output path), 130 interrupted (Ctrl-C).
Errors are one line on stderr, never a traceback; that includes usage errors (a bad option value, an
unknown command, a missing argument), which click would print as a multi-line panel.
"""

from __future__ import annotations

import functools
import json
import os
import sys
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np
import typer
from typer.core import TyperGroup

from firmtool import __version__
from firmtool.cli import console
from firmtool.cli.console import interval, items, num, prob
from firmtool.errors import FirmtoolError, InputError, NumericalError, RunFailure, ScenarioError
from firmtool.io import interrupts
from firmtool.io.locking import writer_lock

DEFAULT_SCENARIO = "arm8_lightdark"  # a shipped scenario's name (firmtool scenarios)
# The click that typer's commands raise from: recent typer vendors its own copy as typer._click,
# whose exceptions are not the click package's; older typer uses the click package (typer.core.click),
# which firmtool does not import itself (it is typer's dependency, not firmtool's).
_click: Any = getattr(typer, "_click", None) or typer.core.click
_NoArgsIsHelp: type = getattr(_click.exceptions, "NoArgsIsHelpError", ())  # click >= 8.2


class _OneLineErrors(TyperGroup):
    """The command group: usage errors in one line (``error: ...``, exit 2) instead of click's panel."""

    def main(self, args: Any = None, prog_name: str | None = None, complete_var: str | None = None,
             standalone_mode: bool = True, **extra: Any) -> Any:
        try:
            rv = super().main(args=args, prog_name=prog_name, complete_var=complete_var, standalone_mode=False,
                              **extra)
            code = rv if isinstance(rv, int) and not isinstance(rv, bool) else 0
        except _NoArgsIsHelp as exc:  # 'firmtool' alone: the help (typer's rich help printed itself already)
            text = exc.format_message()
            if text.strip():
                typer.echo(text)
            code = 0
        except _click.exceptions.UsageError as exc:
            where = f"{exc.ctx.command_path}: " if exc.ctx is not None else ""
            hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
            typer.echo(f"error: {where}{_one_line(exc.format_message())}{hint}", err=True)
            code = 2
        except _click.exceptions.ClickException as exc:
            typer.echo(f"error: {_one_line(exc.format_message())}", err=True)
            code = exc.exit_code
        except (typer.Abort, KeyboardInterrupt):
            typer.echo("error: interrupted", err=True)
            code = interrupts.INTERRUPTED_EXIT
        if standalone_mode:
            sys.exit(code)
        return code


def _one_line(text: str) -> str:
    return " ".join(text.split())


app = typer.Typer(cls=_OneLineErrors,
    name="firmtool",
    help=("FIRM: graph-based stochastic control with constraints, in state space (perfect measurements) "
          "and belief space (imperfect measurements).\n\n"
          "Typical use:\n\n"
          "  firmtool scenarios\n\n"
          "  firmtool build point_lightdark\n\n"
          "  firmtool solve artifacts/point_lightdark.h5\n\n"
          "  firmtool execute artifacts/point_lightdark.h5 --episodes 200 --json"),
    no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
)

JsonOpt = typer.Option(False, "--json", help="Print machine-readable results on stdout.")
WorkersOpt = typer.Option(None, "--workers", "-w", min=1,
                         help="Worker processes (default: all cores; at most 2 per core, and as many as memory allows).")
ForceOpt = typer.Option(False, "--force", help="Replace an existing output file even if it is not a firmtool file "
                                               "of the same kind.")
MaxStepsOpt = typer.Option(1e8, "--max-total-steps", min=1.0,
                           help="Refuse runs of more than this many control steps in the worst case "
                                "(episodes x the scenario's execution.max_steps).")
ExecutorOpt = typer.Option("process", "--executor", help="'process' (local) or 'dask' (dask.distributed).")
CheckpointOpt = typer.Option(10.0, "--checkpoint-seconds", min=0.0,
                             help="Save finished edge estimates into the roadmap this often (resume after a kill).")
SchedulerOpt = typer.Option(None, "--scheduler", help="Dask scheduler address, e.g. tcp://host:8786; "
                            "without it --executor dask starts a LocalCluster.")
QuietOpt = typer.Option(False, "--quiet", "-q", help="Print only errors, notices and --json output: no progress "
                                                     "bar, no summary, no next step.")
SCENARIO_HELP = "Scenario: a TOML file, or the name of a shipped scenario (see 'firmtool scenarios')."


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"firmtool {__version__}")
        raise typer.Exit()


@app.callback()
def _options(version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True,
                                          help="Print firmtool's version and exit.")) -> None:
    """Options of every command (the help text is the app's)."""


def _fail(message: str, code: int) -> None:
    console.close_progress()
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


def _say_compiling() -> None:
    typer.echo("firmtool: compiling the Monte Carlo engine, once per install (10-30 s; later runs load it)",
               err=True)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:300] if text else type(exc).__name__


def handles_errors(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Map library exceptions to one-line messages and exit codes."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        console.configure(quiet=bool(kwargs.get("quiet", False)), json=bool(kwargs.get("as_json", False)))
        try:
            import scipy.linalg  # noqa: F401  (loads scipy's own BLAS, so that the limit below covers it)
            from threadpoolctl import threadpool_limits

            from firmtool.estimation import warmup
            warmup.set_notifier(_say_compiling)  # a background compile on a cold cache says so on stderr
            # firmtool's linear algebra is many small matrices: threaded BLAS only adds contention
            with threadpool_limits(limits=1):
                return fn(*args, **kwargs)
        except ScenarioError as exc:
            _fail_scenario(exc)
        except InputError as exc:
            _fail(str(exc), 2)
        except KeyboardInterrupt as exc:
            if isinstance(exc, FirmtoolError):  # the stage saved what it had (EstimationInterrupted)
                _fail(str(exc), 130)
            _fail("interrupted; the roadmap file is unchanged by the stage that was running", 130)
        except (RunFailure, NumericalError) as exc:
            _fail(str(exc), 1)
        except FirmtoolError as exc:  # pragma: no cover - every subclass is mapped above
            _fail(str(exc), 1)
        except (typer.Exit, typer.Abort, _click.exceptions.ClickException):
            raise
        except OSError as exc:
            if os.environ.get("FIRMTOOL_DEBUG") or not exc.filename:
                raise
            # a file the user named that cannot be read or written (permissions, disk full, ...)
            from firmtool.io.atomic import write_failure
            failure = write_failure(exc.filename, exc)
            _fail(str(failure), 1 if isinstance(failure, RunFailure) else 2)
        except MemoryError:
            _fail("out of memory; lower roadmap.nodes, estimation.particles or estimation.chunk", 1)
        except RecursionError:
            _fail("input nested too deeply to process (a bug in firmtool if it came from a checked file)", 1)
        except Exception as exc:
            if os.environ.get("FIRMTOOL_DEBUG"):
                raise
            _fail(f"unexpected error (a bug in firmtool; rerun with FIRMTOOL_DEBUG=1 for the traceback): "
                  f"{type(exc).__name__}: {_first_line(exc)}", 1)
        finally:
            console.close_progress()

    return wrapper


def _fail_scenario(exc: ScenarioError) -> None:
    """Every mistake of a scenario file, one line each (``error: FILE: FIELD: expected``), exit 2."""
    console.close_progress()
    for field, expected in exc.errors:
        typer.echo(f"error: {exc.path}: {field}: {expected}" if field else f"error: {exc.path}: {expected}", err=True)
    raise typer.Exit(2)


def _emit(report: dict, as_json: bool, human: Callable[[dict], str], roadmap: bool = True) -> None:
    """Print ``report`` (its keys without a leading underscore) as text, or as JSON stamped with
    ``firmtool_version`` and, for a command that reads or writes a roadmap, its ``schema_version``."""
    public = {k: v for k, v in report.items() if not k.startswith("_")}
    console.close_progress()  # the bars go before the results
    if as_json:
        stamp: dict[str, Any] = {"firmtool_version": __version__}
        if roadmap:
            from firmtool.io.roadmap_file import SCHEMA_VERSION
            stamp["schema_version"] = SCHEMA_VERSION  # inspect reports the file's own version instead
        typer.echo(to_json({**stamp, **public}))
    elif not console.quiet():
        typer.echo(human(public))


def to_json(value: Any) -> str:
    """RFC 8259 JSON: numpy values as plain ones, non-finite numbers as null (JSON has no NaN or
    Infinity); ``allow_nan=False`` makes any that slipped through an error, not invalid output."""
    return json.dumps(_plain(value), indent=2, allow_nan=False)


def _plain(o: Any) -> Any:
    if isinstance(o, dict):
        return {str(k): _plain(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_plain(v) for v in o]
    if isinstance(o, np.ndarray):
        return _plain(o.tolist())
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not np.isfinite(o):
        return None
    if o is None or isinstance(o, (str, int, float, bool)):
        return o
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _check_exists(path: Path, what: str) -> None:
    if not path.exists():
        raise InputError(f"{path}: no such {what}")


@app.command()
@handles_errors
def init(name: str = typer.Argument(..., help="The scenario's name: writes NAME.toml (letters, digits, '-', '_', '.')."),
         robot: Optional[str] = typer.Option(None, "--robot", "-r",
                                             help="The robot (default point): a built-in one (point, arm, unicycle), "
                                                  "or a registered robot that has a template."),
         output: Optional[Path] = typer.Option(None, "--output", "-o", help="Scenario file (default NAME.toml)."),
         force: bool = typer.Option(False, "--force", help="Replace an existing file."),
         quiet: bool = QuietOpt) -> None:
    """Write a commented scenario for a built-in robot that builds as it is: every key listed with
    what it is (from the scenario schema), the keys at their defaults commented out.

    Example: firmtool init my_room --robot point
    """
    from firmtool.robots.base import DEFAULT_ROBOT
    from firmtool.scenario.docs import write_template
    out = write_template(output or Path(f"{name}.toml"), name, robot or DEFAULT_ROBOT, force=force)
    console.next_step(str(out), f"firmtool check {out}")


def _check_human(r: dict) -> str:
    world = f"{r['world_dim']}-D world, {r['obstacles']} obstacle{'s' if r['obstacles'] != 1 else ''} " \
            f"({r['collision_backend']})"
    sensing = "perfect measurements" if r["measurement"] == "perfect" else \
        f"{r['measurements']} imperfect measurements ({r['noise']} noise)"
    return (f"ok: {r['scenario']}: scenario {r['name']!r}: robot {r['robot']} ({r['states']} states, "
            f"{r['inputs']} inputs), {sensing}, {world}, goal {r['goal']}; {r['nodes']} nodes x "
            f"{r['particles']} particles per edge, at most ~{num(r['max_particle_steps'], 2)} particle-steps")


@app.command()
@handles_errors
def check(scenario: str = typer.Argument(..., help=SCENARIO_HELP),
          as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Validate a scenario without building: every mistake of the file at once (one line each), then
    the problem it describes (start and goal valid, the model stabilisable, the work within budget).

    Example: firmtool check my_room.toml
    """
    from firmtool.cli.check import check_scenario
    report = check_scenario(scenario).to_dict()
    _emit(report, as_json, _check_human)
    console.next_step(None, f"firmtool build {scenario}")


@app.command()
@handles_errors
def sample(scenario: str = typer.Argument(..., help=SCENARIO_HELP),
           output: Optional[Path] = typer.Option(None, "--output", "-o", help="Roadmap file (default artifacts/NAME.h5)."),
           force: bool = ForceOpt, as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Sample the nodes (start, goal, valid configurations at rest) into a new roadmap file.

    Example: firmtool sample smoke -o artifacts/smoke.h5
    """
    from firmtool.api import load_scenario
    from firmtool.pipeline import sample_stage
    report = sample_stage(load_scenario(scenario), output, force=force, progress=console.progress()).to_dict()
    _emit(report, as_json, lambda r: f"sampled {r['nodes']} nodes in {console.seconds(r['seconds'])}")
    console.next_step(report["roadmap"], f"firmtool design {report['roadmap']}")


@app.command()
@handles_errors
def design(roadmap: Path = typer.Argument(..., help="Roadmap file with sampled nodes."),
           as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Design node stabilisers (SLQR/SLQG), node regions and edges (nominal trajectories).

    Example: firmtool design artifacts/smoke.h5
    """
    from firmtool.pipeline import design_stage
    _check_exists(roadmap, "roadmap file")
    _emit(design_stage(roadmap, progress=console.progress()).to_dict(), as_json,
          lambda r: f"designed {r['nodes']} node stabilisers and {r['edges']} edges (mean nominal "
                    f"{num(r['mean_edge_steps'], 3)} steps) in {console.seconds(r['seconds'])}")
    console.next_step(str(roadmap), f"firmtool estimate {roadmap}")


@app.command()
@handles_errors
def estimate(roadmap: Path = typer.Argument(..., help="Roadmap file with designed controllers."),
             workers: Optional[int] = WorkersOpt, executor: str = ExecutorOpt,
             scheduler: Optional[str] = SchedulerOpt, checkpoint_seconds: float = CheckpointOpt,
             as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Estimate every edge by Monte Carlo (landing, failure, timeout counts; cost), in parallel.

    Edges already estimated with the same inputs (in the file, or saved by an interrupted run) are
    reused, not estimated again.

    Example: firmtool estimate artifacts/smoke.h5 --workers 2
    """
    from firmtool.pipeline import estimate_stage
    _check_exists(roadmap, "roadmap file")
    report = estimate_stage(roadmap, workers=workers, executor=executor, scheduler=scheduler,
                            progress=console.progress(), checkpoint_seconds=checkpoint_seconds).to_dict()
    _emit(report, as_json, lambda r: (f"estimated {r['estimated_edges']} of {r['edges']} edges x "
                                      f"{r['particles_per_edge']} particles ({r['reused_edges']} reused; "
                                      f"{r['simulated_particle_steps']:,} particle-steps in "
                                      f"{console.seconds(r['seconds'])} on {r['workers']} workers)"))
    _print_notices(report)
    _exit_on_failed_edges(report)
    console.next_step(str(roadmap), f"firmtool solve {roadmap}")


def _print_notices(report: dict) -> None:
    """One line on stderr per notice of a stage (e.g. why the numpy Monte Carlo engine ran)."""
    for notice in report.get("notices") or []:
        typer.echo(f"notice: {notice}", err=True)


def _exit_on_failed_edges(report: dict) -> None:
    """One line for any number of failed edges (each is listed in the --json report)."""
    failed = report.get("failed_edges") or []
    if failed:
        f = failed[0]
        _fail(f"{report['roadmap']}: {len(failed)} edge(s) failed twice and were left out (first: edge {f['edge']} "
              f"({f['source']} -> {f['target']}): {f['error']}); run the same command again to retry them", 1)


def _build_human(r: dict) -> str:
    s = r["seconds"]
    text = (f"built {r['roadmap']}: {r['nodes']} nodes, {r['edges']} edges ({r['estimated_edges']} estimated, "
            f"{r['reused_edges']} reused), {r['particles_per_edge']} particles/edge, "
            f"{r['simulated_particle_steps']:,} particle-steps simulated\n"
            f"time: sample {console.seconds(s['sample'])}, design {console.seconds(s['design'])}, "
            f"estimate {console.seconds(s['estimate'])} on {r['workers']} workers")
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
        text += "\n" + "\n".join(f"  {x['nodes']} nodes: start success probability {prob(x['start_success_probability'])}"
                                  for x in r["densify"]["rounds"])
        text += f"\n{r['densify']['reason']}"
    return text


@app.command()
@handles_errors
def build(scenario: str = typer.Argument(..., help=SCENARIO_HELP),
          output: Optional[Path] = typer.Option(None, "--output", "-o", help="Roadmap file (default artifacts/NAME.h5)."),
          workers: Optional[int] = WorkersOpt, executor: str = ExecutorOpt,
          scheduler: Optional[str] = SchedulerOpt, checkpoint_seconds: float = CheckpointOpt,
          fresh: bool = typer.Option(False, "--fresh", help="Start a new roadmap even if the output can be reused."),
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
    import firmtool.api as ft
    from firmtool.pipeline import default_output
    if max_nodes is not None and p_min is None:
        raise InputError("--max-nodes: only meaningful with --p-min")
    sc = ft.load_scenario(scenario)
    rm = ft.build(sc, output=output or default_output(sc), workers=workers, executor=executor, scheduler=scheduler,
                  progress=console.progress(), fresh=fresh, p_min=p_min, max_nodes=max_nodes,
                  add_nodes=add_nodes, checkpoint_seconds=checkpoint_seconds, force=force)
    report = rm.report.to_dict()
    _emit(report, as_json, _build_human)
    _print_notices(report)
    _exit_on_failed_edges(report)
    if report["densify"] and not report["densify"]["reached"]:
        _fail(report["densify"]["reason"], 1)
    _exit_if_unreachable(report)
    console.next_step(report["roadmap"], f"firmtool solve {report['roadmap']}")


def _exit_if_unreachable(report: dict) -> None:
    """Exit 1 when no goal node can be reached from the start (the roadmap cannot be solved)."""
    c = report.get("connectivity")
    if c and c.get("reachable_goal_nodes") is not None and not c["reachable_goal_nodes"]:
        why = "; ".join(c["missing"]) or "edges leave the start's component but none lands in a goal node"
        _fail(f"{report['roadmap']}: no goal node is reachable from the start: {why}; raise roadmap.bridge_nodes "
              "or roadmap.nodes, or use --p-min to densify", 1)


def _solve_human(r: dict) -> str:
    lines = [f"solve: {r['status'].lower()} after {r['iterations']} {r['method']} iterations "
             f"(residual {num(r['residual'], 2)}), failure cost {num(r['failure_cost'])}",
             f"start: success probability {prob(r['start_success_probability'])}"
             + (f" (95% interval from the edge counts {prob(r['start_success_probability_ci95'][0])}-"
                f"{prob(r['start_success_probability_ci95'][1])})" if r.get("start_success_probability_ci95") else "")
             + ", cost-to-go "
             f"{num(r['start_cost_to_go'])} (shortest path: success probability "
             f"{prob(r['shortest_path_start_success_probability'])})",
             f"policy path: {' -> '.join(map(str, r['path']))}"]
    if r.get("path_task_points"):
        lines.append("  in the task space: " + " -> ".join("(" + ", ".join(f"{v:.2f}" for v in q) + ")"
                                                          for q in r["path_task_points"]))
    if r["unreachable_nodes"]:
        lines.append(f"{len(r['unreachable_nodes'])} nodes cannot reach the goal: {items(r['unreachable_nodes'])}")
    return "\n".join(lines)


@app.command()
@handles_errors
def solve(roadmap: Path = typer.Argument(..., help="Roadmap file with estimated edges."),
          failure_cost: Optional[float] = typer.Option(None, "--failure-cost", help="Override the scenario's J_F."),
          method: str = typer.Option("value", "--method", help="'value' (value iteration) or 'policy'."),
          as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Solve the constrained graph DP (eq. 12) and the success probability of every node.

    Example: firmtool solve artifacts/smoke.h5 --failure-cost 500
    """
    import firmtool.api as ft
    from firmtool.pipeline import unreachable_failure
    _check_exists(roadmap, "roadmap file")
    if method not in ("value", "policy"):
        raise InputError(f"--method: expected 'value' or 'policy', found {method!r}")
    if failure_cost is not None and not (np.isfinite(failure_cost) and failure_cost > 0):
        raise InputError(f"--failure-cost: expected a finite number > 0, found {failure_cost}")
    with writer_lock(roadmap):  # from the first read to the write: the policy is the edges' it was solved from
        sol = ft.solve(ft.open_roadmap(roadmap), failure_cost=failure_cost, method=method,
                       progress=console.progress())
        sol.save()
    if not sol.start_reachable:
        raise unreachable_failure(roadmap, sol.unreachable_nodes.size, sol.cost_to_go.size)
    _emit(sol.to_dict(), as_json, _solve_human)
    console.next_step(f"the policy into {roadmap}", f"firmtool execute {roadmap}")


def _execute_human(r: dict) -> str:
    pred = r["predicted_success_probability"]
    stuck = f", {r['stuck']} stuck (no policy edge or no controller to a node)" if r.get("stuck") else ""
    predicted = "" if pred is None else f"; predicted {prob(pred)}" + (
        f" (95% {interval(r['predicted_success_probability_ci95'])}, from the edge counts)"
        if r.get("predicted_success_probability_ci95") else "")
    missed = (f", {r['goal_misses']} goal misses (arrival declared, the true state not in the goal)"
              if r.get("goal_misses") else "")
    return (f"{r['episodes']} episodes: {r['successes']} successes, {r['collisions']} collisions, "
            f"{r['timeouts']} timeouts{stuck}{missed}\n"
            f"success rate {prob(r['success_rate'])} (95% {interval(r['success_rate_ci95'])}), judged on the true "
            f"state{predicted}\n"
            f"mean steps {num(r['mean_steps'], 3)}, mean cost {num(r['mean_cost'])}, replans {r['replans']}"
            + _execute_extra_human(r))


def _execute_extra_human(r: dict) -> str:
    lines = []
    if r.get("disturbances"):
        lines.append(f"disturbances {', '.join(r['disturbances'])}: {r['disturbances_applied']} applied")
    if "step_time_us_mean" in r:
        rt = r.get("replan_time_us_mean")
        lines.append(f"policy compute per control step {num(r['step_time_us_mean'], 3)} us mean, "
                     f"{num(r['step_time_us_p99'], 3)} us p99"
                     + ("" if rt is None else f"; per replan decision {num(rt / 1000, 3)} ms mean, "
                        f"{num(r['replan_time_us_p99'] / 1000, 3)} ms p99"))
    if r.get("replan_decisions"):
        lines.append(f"replan deadline {1000 * r['replan_deadline_s']:.0f} ms ({r['replan_clock']} clock): "
                     f"{r['replan_deadline_hits']} of {r['replan_decisions']} decisions cut short, "
                     f"{r['replan_over_deadline']} over it in wall time")
    cal = r.get("calibration")
    if cal:
        lines.append(f"calibration: {cal['edges_checked']} of {cal['edges_taken']} edges taken checked "
                     f"(>= {cal['min_traversals']} traversals), flagged: {items(cal['flagged_edges'])}")
    return "".join("\n" + line for line in lines)


def _parse_start(text: str | None) -> np.ndarray | None:
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise InputError(f"--start: expected comma-separated numbers, e.g. 3.0,1.5; found {text!r}") from None
    if not np.all(np.isfinite(values)):
        raise InputError(f"--start: expected finite numbers, found {text!r}")
    return np.asarray(values)


@app.command()
@handles_errors
def execute(roadmap: Path = typer.Argument(..., help="Solved roadmap file."),
            episodes: int = typer.Option(100, "--episodes", "-n", min=1, help="Closed-loop episodes to run."),
            seed: int = typer.Option(0, "--seed", min=0, help="Seed of the simulated true system."),
            policy_name: str = typer.Option("firm", "--policy",
                                            help="'firm' (the DP's policy) or 'shortest-path' (the baseline "
                                                 "that ignores uncertainty: shortest configuration-space path)."),
            disturbance: Optional[list[str]] = typer.Option(
                None, "--disturbance", "-d",
                help="Inject a large disturbance into the simulated true system (the filter is not told): "
                     "push:STEP:SIZE (true configuration moved SIZE scenario units in a random direction at "
                     "control step STEP), push:random:SIZE:RATE (pushes at random steps, probability RATE per "
                     "step), kidnap:STEP (true state jumps to a random valid state at rest), kidnap:random:RATE. "
                     "Repeatable."),
            no_replan: bool = typer.Option(False, "--no-replan",
                                           help="Follow the stored controllers only: no real-time replanning."),
            replan_threshold: float = typer.Option(
                3.0, "--replan-threshold",
                help="Replan when the estimate leaves the running controller's nominal by more than this, in "
                     "the rms-scaled norm of node regions (rms over coordinates of deviation / node spread; "
                     "node regions default to 1.5). A windowed innovation test also triggers a replan."),
            replan_deadline: Optional[float] = typer.Option(
                None, "--replan-deadline",
                help="Seconds a replan decision may take (default: the control period dt). When the Monte "
                     "Carlo scoring of candidates runs out of time, the best candidate scored so far is "
                     "taken (an anytime decision)."),
            replan_clock: str = typer.Option(
                "work", "--replan-clock",
                help="How the deadline is counted: 'work' (default: each scored candidate costs a fixed, "
                     "measured time, so results do not depend on the machine's load) or 'wall' (real "
                     "time: as on a robot; results then depend on the load)."),
            replan_latency: str = typer.Option(
                "0", "--replan-latency",
                help="'0' (default): a replanned controller runs from the next step. 'measured': the "
                     "running controller goes on for ceil(t / dt) steps, t the decision's time on its clock."),
            goal_check: Optional[float] = typer.Option(
                None, "--goal-check",
                help="Tail probability per onset at which the jump test questions a goal arrival: the "
                     "declaration waits while it does (default 0.1; 0: declare at once). Needs replanning "
                     "(the jump test). See docs/online.md."),
            jump_false_alarm: Optional[float] = typer.Option(
                None, "--jump-false-alarm",
                help="The jump test's false-alarm probability per step (default: 0.25 nominal false alarms "
                     "over the policy's nominal path). Laxer finds more pushes and costs undisturbed "
                     "success. Needs replanning; see docs/online.md."),
            jump_window: Optional[int] = typer.Option(
                None, "--jump-window",
                help="Onsets the jump test rejects on, and the steps a goal declaration may wait on its "
                     "question (default 20). Longer finds some pushes sooner and costs a higher bound per "
                     "onset. Needs replanning; see docs/online.md."),
            goal_lookback: Optional[int] = typer.Option(
                None, "--goal-lookback",
                help="Onsets (steps back since the last decision) the goal check asks (default 40, at "
                     "least the jump window); those older than the window at a tenth of --goal-check. "
                     "Needs replanning; see docs/online.md."),
            start: Optional[str] = typer.Option(
                None, "--start",
                help="Start at this configuration (comma-separated, e.g. 3.0,1.5) or full state instead of the "
                     "start node; a start in no node gets an initial controller to the best nearby node."),
            save_episodes: Optional[Path] = typer.Option(
                None, "--save-episodes",
                help="Write every episode (true states, estimates, covariances, controls, nodes, events) to "
                     "this HDF5 file (atomic write)."),
            force: bool = ForceOpt, max_total_steps: float = MaxStepsOpt, as_json: bool = JsonOpt,
            quiet: bool = QuietOpt) -> None:
    """Run closed-loop episodes of the policy on a simulated true system, with real-time replanning
    after large disturbances, and check the plan against what happened (predicted success probability
    with its interval from the edge counts, executed rate with its Wilson interval, per-edge landing
    and failure frequencies of the edges taken).

    Examples:

      firmtool execute artifacts/smoke.h5 --episodes 200 --seed 1 --json

      firmtool execute artifacts/point_lightdark.h5 -n 200 -d push:random:2.5:0.01

      firmtool execute artifacts/point_lightdark.h5 -n 200 -d push:40:2.0 --no-replan

      firmtool execute artifacts/point_lightdark.h5 -d kidnap:40 --save-episodes episodes.h5

      firmtool execute artifacts/point_lightdark.h5 --start 6.0,1.0
    """
    import firmtool.api as ft
    from firmtool.estimation.budgets import check_execution
    from firmtool.online.replanning import CLOCKS, GOAL_CHECK, GOAL_LOOKBACK, JUMP_WINDOW, LATENCIES, ReplanSettings
    from firmtool.sim.disturbances import parse_disturbances
    _check_exists(roadmap, "roadmap file")
    dists = parse_disturbances(disturbance)
    if not (np.isfinite(replan_threshold) and replan_threshold > 0):
        raise InputError(f"--replan-threshold: expected a finite number > 0, found {replan_threshold}")
    if replan_deadline is not None and not (np.isfinite(replan_deadline) and replan_deadline > 0):
        raise InputError(f"--replan-deadline: expected a number of seconds > 0, found {replan_deadline}")
    if replan_clock not in CLOCKS:
        raise InputError(f"--replan-clock: expected one of {', '.join(CLOCKS)}, found {replan_clock!r}")
    if replan_latency not in LATENCIES:
        raise InputError(f"--replan-latency: expected one of {', '.join(LATENCIES)}, found {replan_latency!r}")
    if goal_check is not None and not (np.isfinite(goal_check) and 0.0 <= goal_check < 1.0):
        raise InputError(f"--goal-check: expected a probability in [0, 1), found {goal_check}")
    if jump_false_alarm is not None and not (np.isfinite(jump_false_alarm) and 0.0 < jump_false_alarm < 1.0):
        raise InputError(f"--jump-false-alarm: expected a probability in (0, 1), found {jump_false_alarm}")
    for flag, steps in (("--jump-window", jump_window), ("--goal-lookback", goal_lookback)):
        if steps is not None and steps < 1:
            raise InputError(f"{flag}: expected a number of steps >= 1, found {steps}")
    levels = {"--goal-check": goal_check, "--jump-false-alarm": jump_false_alarm, "--jump-window": jump_window,
              "--goal-lookback": goal_lookback}
    if no_replan and any(v is not None for v in levels.values()):
        flag = next(name for name, v in levels.items() if v is not None)
        raise InputError(f"{flag}: a setting of the jump test, which --no-replan turns off; drop one of them")
    start_state = _parse_start(start)
    _check_policy(policy_name)
    if save_episodes is not None:
        from firmtool.io.episodes import check_output
        check_output(save_episodes, force)  # before the episodes run, not after
    rm = ft.open_roadmap(roadmap)
    check_execution(rm.problem, episodes, record=save_episodes is not None, max_total_steps=max_total_steps)
    sol = rm.solution()
    settings = ReplanSettings(enabled=not no_replan, threshold=replan_threshold, deadline=replan_deadline,
                              clock=replan_clock, latency=replan_latency, jump_false_alarm=jump_false_alarm,
                              goal_check=GOAL_CHECK if goal_check is None else goal_check,
                              jump_window=JUMP_WINDOW if jump_window is None else jump_window,
                              goal_lookback=GOAL_LOOKBACK if goal_lookback is None else goal_lookback)
    res = ft.simulate(sol, episodes, seed, policy=policy_name, start=start_state, disturbances=dists,
                      replan=settings, record=save_episodes is not None, progress=console.progress(),
                      max_total_steps=max_total_steps)
    report = res.to_dict()
    if save_episodes is not None:
        from firmtool.io.episodes import save_episodes as write_episodes
        write_episodes(save_episodes, res.episodes,
                       {"roadmap": str(roadmap), "seed": seed, "policy": policy_name,
                        "disturbances": ";".join(report["disturbances"]), "replanning": not no_replan,
                        "replan_threshold": replan_threshold,
                        # the jump test's levels as they ran (HDF5 attributes hold no null: absent without it)
                        **{k: report[k] for k in ("jump_false_alarm", "goal_check", "jump_window", "goal_lookback")
                           if report[k] is not None}},
                       force=force)
        report["episodes_file"] = str(save_episodes)
    _emit(report, as_json, _execute_human)
    _exit_if_all_stuck(report, roadmap)
    console.next_step(str(save_episodes) if save_episodes is not None else None,
                      f"firmtool plot {roadmap}" + (f" --seed {seed}" if seed else ""))


def _exit_if_all_stuck(report: dict, roadmap: Path) -> None:
    """Exit 1 when no episode ran at all: every one ended before its first step."""
    if report["episodes"] and report.get("stuck") == report["episodes"]:
        _fail(f"{roadmap}: every episode was stuck at its start (no policy edge from the start node, or no "
              "controller from the start to any node); the policy cannot be executed", 1)


def _check_policy(name: str) -> None:
    if name not in ("firm", "shortest-path"):
        raise InputError(f"--policy: expected 'firm' or 'shortest-path', found {name!r}")


@app.command()
@handles_errors
def plot(roadmap: Path = typer.Argument(..., help="Solved roadmap file."),
         output: Optional[Path] = typer.Option(None, "--output", "-o", help="PNG file (default: next to the roadmap)."),
         policy_name: str = typer.Option("both", "--policy", help="'both' (side by side), 'firm' or 'shortest-path'."),
         seed: int = typer.Option(0, "--seed", min=0, help="Seed of the episodes (as in 'firmtool execute')."),
         episodes: int = typer.Option(20, "--episodes", "-n", min=0,
                                      help="Episodes run per policy: the panel shows their success rate and draws "
                                           "the first successful one (0: the roadmap and the policy only)."),
         dpi: int = typer.Option(120, "--dpi", min=30, max=600), force: bool = ForceOpt,
         kind: str = typer.Option("paths", "--kind", help="'paths' (the paper's Fig. 1) or 'calibration' (predicted "
                                                          "vs executed probabilities of the policy edges)."),
         unit: str = typer.Option("m", "--unit", help="The length unit of the scenario's world (axis labels)."),
         max_total_steps: float = MaxStepsOpt, quiet: bool = QuietOpt) -> None:
    """Draw the paper's Fig. 1: obstacles, sensing field, goal, roadmap, policy path, and an executed
    episode's estimated mean with 3-sigma ellipses of the robot's followed point (the arm's tip); or,
    with --kind calibration, the predicted vs executed probabilities of the policy edges.

    Examples:

      firmtool plot artifacts/arm8_lightdark.h5 -o fig.png --episodes 100

      firmtool plot artifacts/point_lightdark.h5 --kind calibration -n 400 -o calibration.png
    """
    import firmtool.api as ft
    from firmtool.estimation.budgets import check_execution
    from firmtool.figures import FIGURE_KINDS, FigureOptions, check_output, make_figure, save_figure
    _check_exists(roadmap, "roadmap file")
    names = {"both": ["firm", "shortest-path"], "firm": ["firm"], "shortest-path": ["shortest-path"]}
    if policy_name not in names:
        raise InputError(f"--policy: expected 'both', 'firm' or 'shortest-path', found {policy_name!r}")
    if kind not in FIGURE_KINDS:
        raise InputError(f"--kind: expected one of {', '.join(FIGURE_KINDS)}, found {kind!r}")
    out = check_output(output or roadmap.with_suffix(".png"), force)  # before the episodes run
    rm = ft.open_roadmap(roadmap)
    if episodes:
        check_execution(rm.problem, episodes * len(names[policy_name]), max_total_steps=max_total_steps)
    options = FigureOptions(episodes=episodes, seed=seed, policies=tuple(names[policy_name]), dpi=dpi, unit=unit,
                            progress=console.progress(), max_total_steps=max_total_steps)
    save_figure(make_figure(kind, rm.solution(), options), out, force=force)
    console.next_step(str(out))


@app.command()
@handles_errors
def inspect(roadmap: Path = typer.Argument(..., help="Roadmap file."), as_json: bool = JsonOpt,
            quiet: bool = QuietOpt) -> None:
    """Summarise a roadmap file: stages done, nodes, edges, particles, solve status.

    Example: firmtool inspect artifacts/smoke.h5 --json
    """
    from firmtool.cli import inspect as inspect_module
    _check_exists(roadmap, "roadmap file")
    report = inspect_module.summarize(roadmap).to_dict()
    _emit(report, as_json, lambda r: "\n".join(f"{k.replace('_', ' ')}: {console.value(v, k)}" for k, v in r.items()
                                               if v is not None and v != []))
    stages = report.get("stages") or []
    stale = report.get("stale_stages") or []
    following = {"nodes": "design", "controllers": "estimate", "edges": "solve", "policy": "execute"}
    done = [s for s in stages if s not in stale]
    if done and done[-1] in following:
        console.next_step(None, f"firmtool {following[done[-1]]} {roadmap}")


@app.command()
@handles_errors
def run(scenario: str = typer.Argument(DEFAULT_SCENARIO, help=SCENARIO_HELP),
        output: Optional[Path] = typer.Option(None, "--output", "-o"),
        episodes: int = typer.Option(200, "--episodes", "-n", min=1),
        seed: int = typer.Option(0, "--seed", min=0),
        workers: Optional[int] = WorkersOpt, force: bool = ForceOpt, max_total_steps: float = MaxStepsOpt,
        as_json: bool = JsonOpt, quiet: bool = QuietOpt) -> None:
    """Build, solve and execute a scenario in one go (default: the paper's 8-link arm experiment):
    the same calls, and the same numbers, as 'firmtool build', 'solve' and 'execute' one by one.

    Example: firmtool run smoke --episodes 50
    """
    import firmtool.api as ft
    from firmtool.estimation.budgets import check_execution
    from firmtool.pipeline import default_output, unreachable_failure
    from firmtool.problem import build_problem
    sc = ft.load_scenario(scenario)
    check_execution(build_problem(sc), episodes, max_total_steps=max_total_steps)
    out = output or default_output(sc)
    bar = console.progress()
    rm = ft.build(sc, output=out, workers=workers, progress=bar, force=force)
    _exit_on_failed_edges(rm.report.to_dict())
    sol = ft.solve(rm, progress=bar)
    sol.save()
    if not sol.start_reachable:
        raise unreachable_failure(out, sol.unreachable_nodes.size, sol.cost_to_go.size)
    res = ft.simulate(sol, episodes, seed, record=False, progress=bar, max_total_steps=max_total_steps)
    report = {"build": rm.report.to_dict(), "solve": sol.to_dict(), "execute": res.to_dict()}
    _emit(report, as_json, lambda r: "\n".join([_build_human(r["build"]), _solve_human(r["solve"]),
                                                  _execute_human(r["execute"])]))
    _print_notices(report["build"])
    console.next_step(str(out), f"firmtool plot {out}" + (f" --seed {seed}" if seed else ""))


@app.command()
@handles_errors
def scenarios(as_json: bool = JsonOpt) -> None:
    """List the shipped scenarios, one a line: name and description. Every command that takes a
    scenario accepts one of these names as well as a TOML file (an existing file wins).

    Example: firmtool build point_lightdark
    """
    from firmtool.scenario import scenario_description, shipped_scenarios
    shipped = [{"name": name, "description": scenario_description(path), "path": str(path)}
               for name, path in shipped_scenarios().items()]
    width = max((len(s["name"]) for s in shipped), default=0)
    _emit({"scenarios": shipped}, as_json,
          lambda r: "\n".join(f"{s['name']:<{width}}  {s['description']}" for s in r["scenarios"]), roadmap=False)


def main() -> None:
    """Run the CLI on ``sys.argv`` and exit with its code (the console script, firmtool.__main__, installs
    the Ctrl-C handler before this module's imports)."""
    interrupts.install()
    sys.exit(app(standalone_mode=False))


if __name__ == "__main__":  # python -m firmtool.cli.commands (tests run the CLI with the interpreter they use)
    main()
