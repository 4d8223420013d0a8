"""``firmtool execute``: closed-loop episodes of a solved roadmap's policy on the simulated system,
with real-time replanning after large disturbances, and the check of the plan against them."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Optional

import numpy as np
import typer

from firmtool.cli import console
from firmtool.cli.console import interval, items, num, prob
from firmtool.cli.exits import fail, handles_errors
from firmtool.cli.options import (
    ForceOpt,
    JsonOpt,
    MaxStepsOpt,
    QueryOpt,
    QuietOpt,
    check_roadmap_argument,
    open_roadmap,
)
from firmtool.cli.output import emit
from firmtool.errors import InputError, quoted

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.online.replanning import ReplanSettings

SolvedRoadmapArg = typer.Argument(..., help="Solved roadmap file.")
EpisodesOpt = typer.Option(100, "--episodes", "-n", min=1, help="Closed-loop episodes to run.")
SeedOpt = typer.Option(0, "--seed", min=0, help="Seed of the simulated true system.")
PolicyOpt = typer.Option("firm", "--policy",
                         help="'firm' (the DP's policy), 'rollout' (the DP's policy as rollout FIRM: from the "
                              "current belief it heads on to the next nodes of its path instead of settling at "
                              "each) or 'shortest-path' (the baseline that ignores uncertainty: shortest "
                              "configuration-space path).")
DisturbanceOpt = typer.Option(
    None, "--disturbance", "-d",
    help="Inject a large disturbance into the simulated true system (the filter is not told): "
         "push:STEP:SIZE (true configuration moved SIZE scenario units in a random direction at "
         "control step STEP), push:random:SIZE:RATE (pushes at random steps, probability RATE per "
         "step), kidnap:STEP (true state jumps to a random valid state at rest), kidnap:random:RATE, "
         "obstacle:STEP:CX,CY:HX,HY (a box appears in the true world at step STEP and the policy is told, as "
         "by a map update), obstacle-unseen:STEP:CX,CY:HX,HY (the same box, the policy not told). Repeatable.")
NoReplanOpt = typer.Option(False, "--no-replan", metavar="",
                           help="Follow the stored controllers only: no real-time replanning.")
ReplanThresholdOpt = typer.Option(
    3.0, "--replan-threshold",
    help="Replan when the estimate leaves the running controller's nominal by more than this, in "
         "the rms-scaled norm of node regions (rms over coordinates of deviation / node spread; "
         "node regions default to 1.5). A windowed innovation test also triggers a replan.")
ReplanDeadlineOpt = typer.Option(
    None, "--replan-deadline",
    help="Seconds a replan decision may take (default: the control period dt). When the Monte "
         "Carlo scoring of candidates runs out of time, the best candidate scored so far is "
         "taken (an anytime decision).")
ReplanClockOpt = typer.Option(
    "work", "--replan-clock",
    help="How the deadline is counted: 'work' (default: each scored candidate costs a fixed, "
         "measured time, so results do not depend on the machine's load) or 'wall' (real "
         "time: as on a robot; results then depend on the load).")
ReplanLatencyOpt = typer.Option(
    "0", "--replan-latency",
    help="'0' (default): a replanned controller runs from the next step. 'measured': the "
         "running controller goes on for ceil(t / dt) steps, t the decision's time on its clock.")
RolloutSizingOpt = typer.Option(
    "fixed", "--rollout-sizing",
    help="Rollout FIRM (--policy rollout): 'fixed' (default: 64 particles, 2 nodes ahead; the same "
         "episodes on any machine) or 'measured' (each decision sized from its measured time to half "
         "the control period, as on a robot; results then depend on the load).")
GoalCheckOpt = typer.Option(
    None, "--goal-check",
    help="Tail probability per onset at which the jump test questions a goal arrival: the "
         "declaration waits while it does (default 0.1; 0: declare at once). Needs replanning "
         "(the jump test). See docs/online.md.")
JumpFalseAlarmOpt = typer.Option(
    None, "--jump-false-alarm",
    help="The jump test's false-alarm probability per step (default: 0.25 nominal false alarms "
         "over the policy's nominal path). Laxer finds more pushes and costs undisturbed "
         "success. Needs replanning; see docs/online.md.")
JumpWindowOpt = typer.Option(
    None, "--jump-window",
    help="Onsets the jump test rejects on, and the steps a goal declaration may wait on its "
         "question (default 20). Longer finds some pushes sooner and costs a higher bound per "
         "onset. Needs replanning; see docs/online.md.")
GoalLookbackOpt = typer.Option(
    None, "--goal-lookback",
    help="Onsets (steps back since the last decision) the goal check asks (default 40, at "
         "least the jump window); those older than the window at a tenth of --goal-check. "
         "Needs replanning; see docs/online.md.")
StartOpt = typer.Option(
    None, "--start",
    help="Start at this configuration (comma-separated, e.g. 3.0,1.5) or full state instead of the "
         "start node; a start in no node gets an initial controller to the best nearby node.")
SimulatorOpt = typer.Option(
    "firmtool", "--simulator",
    help="The true system: 'firmtool' (its own simulator: the Monte Carlo's capsules, kinematics and noise) or "
         "'mujoco' (a URDF arm loaded by MuJoCo from the URDF the roadmap carries: collisions of its real meshes, "
         "joint limits and the goal judged by MuJoCo; needs the physics extra: pip install 'firmtool[physics]').")
SaveEpisodesOpt = typer.Option(
    None, "--save-episodes",
    help="Write every episode (true states, estimates, covariances, controls, nodes, events) to "
         "this HDF5 file (atomic write).")


def execute_human(r: dict) -> str:
    pred = r["predicted_success_probability"]
    stuck = f", {r['stuck']} stuck (no policy edge or no controller to a node)" if r.get("stuck") else ""
    T = r.get("deadline_steps")
    what = "predicted" if T is None else f"predicted P(goal within {T} steps)"
    predicted = "" if pred is None else f"; {what} {prob(pred)}" + (
        f" (95% {interval(r['predicted_success_probability_ci95'])}, from the edge counts)"
        if r.get("predicted_success_probability_ci95") else "")
    if T is not None:  # a deadline policy runs: say which, before the numbers
        predicted += (f"\npolicy: the deadline policy (the edge at each node chosen by the steps left of {T}; "
                      f"every episode ends by step {T})")
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
    sim = r.get("simulator")
    if sim:
        lines.append(f"judged by {sim['engine']} {sim['version']}: {sim['mujoco_contacts']} contact steps, "
                     f"{sim['joint_limits']} past a joint limit; capsules and meshes disagreed at "
                     f"{sim['capsules_only'] + sim['mujoco_only']} of {sim['steps']} steps (capsules only "
                     f"{sim['capsules_only']}: their conservatism; meshes only {sim['mujoco_only']})")
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


def parse_start(text: str | None) -> np.ndarray | None:
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise InputError(f"--start: expected comma-separated numbers, e.g. 3.0,1.5; found {quoted(text)}") from None
    if not np.all(np.isfinite(values)):
        raise InputError(f"--start: expected finite numbers, found {quoted(text)}")
    return np.asarray(values)


@handles_errors
def execute(roadmap: Path = SolvedRoadmapArg, episodes: int = EpisodesOpt, seed: int = SeedOpt,
            policy_name: str = PolicyOpt, disturbance: Optional[list[str]] = DisturbanceOpt,
            no_replan: bool = NoReplanOpt, replan_threshold: float = ReplanThresholdOpt,
            replan_deadline: Optional[float] = ReplanDeadlineOpt, replan_clock: str = ReplanClockOpt,
            replan_latency: str = ReplanLatencyOpt, rollout_sizing: str = RolloutSizingOpt,
            goal_check: Optional[float] = GoalCheckOpt,
            jump_false_alarm: Optional[float] = JumpFalseAlarmOpt, jump_window: Optional[int] = JumpWindowOpt,
            goal_lookback: Optional[int] = GoalLookbackOpt, start: Optional[str] = StartOpt,
            save_episodes: Optional[Path] = SaveEpisodesOpt, query: Optional[str] = QueryOpt,
            force: bool = ForceOpt, max_total_steps: float = MaxStepsOpt, as_json: bool = JsonOpt,
            quiet: bool = QuietOpt, simulator: str = SimulatorOpt) -> None:
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

      firmtool execute artifacts/arm7_shelf.h5 --simulator mujoco -n 400
    """
    # lazy: saves firmtool --help the library's import, 2.0 s, and h5py's, 0.03 s (firmtool.cli.app)
    import firmtool.api as ft
    from firmtool.estimation.budgets import check_execution
    from firmtool.io.episodes import check_output as check_episodes_output
    from firmtool.io.episodes import save_episodes as write_episodes
    from firmtool.sim.disturbances import parse_disturbances
    check_roadmap_argument(roadmap)
    dists = parse_disturbances(disturbance)
    settings = replan_settings(no_replan, replan_threshold, replan_deadline, replan_clock, replan_latency,
                               goal_check, jump_false_alarm, jump_window, goal_lookback, rollout_sizing)
    start_state = parse_start(start)
    check_policy(policy_name)
    if save_episodes is not None:
        check_episodes_output(save_episodes, force)  # before the episodes run, not after
    rm = open_roadmap(roadmap)
    if query is not None:
        rm = rm.query(query)
    check_execution(rm.problem, episodes, record=save_episodes is not None, max_total_steps=max_total_steps)
    sol = rm.solution()
    res = ft.simulate(sol, episodes, seed, policy=policy_name, start=start_state, disturbances=dists,
                      replan=settings, record=save_episodes is not None, progress=console.progress(),
                      max_total_steps=max_total_steps, simulator=simulator)
    report = res.to_dict()
    if save_episodes is not None:
        write_episodes(save_episodes, res.episodes,
                       {"roadmap": str(roadmap), "seed": seed, "policy": policy_name,
                        "disturbances": ";".join(report["disturbances"]), "replanning": not no_replan,
                        "replan_threshold": replan_threshold,
                        # the jump test's levels as they ran (HDF5 attributes hold no null: absent without it)
                        **{k: report[k] for k in ("jump_false_alarm", "goal_check", "jump_window", "goal_lookback")
                           if report[k] is not None}},
                       force=force)
        report["episodes_file"] = str(save_episodes)
    emit(report, as_json, execute_human)
    exit_if_all_stuck(report, roadmap)
    console.next_step(str(save_episodes) if save_episodes is not None else None,
                      f"firmtool plot {roadmap}" + (f" --seed {seed}" if seed else ""))


def replan_settings(no_replan: bool, threshold: float, deadline: float | None, clock: str, latency: str,
                    goal_check: float | None, jump_false_alarm: float | None, jump_window: int | None,
                    goal_lookback: int | None, rollout_sizing: str = "fixed") -> "ReplanSettings":
    """The replanning options of ``firmtool execute``, checked (each error names its option) and as
    :class:`~firmtool.online.replanning.ReplanSettings` (None: the option's default)."""
    # lazy: saves firmtool --help the online policy's import, 1.35 s (firmtool.cli.app)
    from firmtool.online.replanning import (CLOCKS, GOAL_CHECK, GOAL_LOOKBACK, JUMP_WINDOW, LATENCIES, ROLLOUT_SIZINGS,
                                            ReplanSettings)
    if not (np.isfinite(threshold) and threshold > 0):
        raise InputError(f"--replan-threshold: expected a finite number > 0, found {threshold}")
    if deadline is not None and not (np.isfinite(deadline) and deadline > 0):
        raise InputError(f"--replan-deadline: expected a number of seconds > 0, found {deadline}")
    if clock not in CLOCKS:
        raise InputError(f"--replan-clock: expected one of {', '.join(CLOCKS)}, found {quoted(clock)}")
    if latency not in LATENCIES:
        raise InputError(f"--replan-latency: expected one of {', '.join(LATENCIES)}, found {quoted(latency)}")
    if rollout_sizing not in ROLLOUT_SIZINGS:
        raise InputError(f"--rollout-sizing: expected one of {', '.join(ROLLOUT_SIZINGS)}, found {quoted(rollout_sizing)}")
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
    return ReplanSettings(enabled=not no_replan, threshold=threshold, deadline=deadline, clock=clock,
                          latency=latency, jump_false_alarm=jump_false_alarm,
                          goal_check=GOAL_CHECK if goal_check is None else goal_check,
                          jump_window=JUMP_WINDOW if jump_window is None else jump_window,
                          goal_lookback=GOAL_LOOKBACK if goal_lookback is None else goal_lookback,
                          rollout_sizing=rollout_sizing)


def exit_if_all_stuck(report: dict, roadmap: Path) -> None:
    """Exit 1 when no episode ran at all: every one ended before its first step."""
    if report["episodes"] and report.get("stuck") == report["episodes"]:
        fail(f"{roadmap}: every episode was stuck at its start (no policy edge from the start node, or no "
              "controller from the start to any node); the policy cannot be executed", 1)


def check_policy(name: str) -> None:
    if name not in ("firm", "rollout", "shortest-path"):
        raise InputError(f"--policy: expected 'firm', 'rollout' or 'shortest-path', found {quoted(name)}")
