"""FIRM's policy in a user's own control loop: the robot here is a few lines of numpy, not firmtool's.

The policy (``ft.Policy``) is the agent: each control period it gives a control (``act``), the robot
applies it and measures, and the policy takes the measurement (``observe``), returning what happened
(node reached, innovation alarm, replan, goal declared). It never sees the true state. This script
builds and solves a point-robot scenario, drives the policy with its own simulator of that robot,
prints the controls and events, and checks that each episode is the one ``ft.simulate`` gives for
the same seed (same draws, same math: the same outcome, steps, cost and events).

    python examples/external_loop.py                          # point_lightdark, 3 episodes, seed 0
    python examples/external_loop.py --scenario smoke --episodes 5 --every 1

On a real robot the loop is the same, with the measurement from the sensors and the control sent to
the actuators at the control period (docs/online.md shows it inside a ROS 2 node).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import firmtool as ft


class PointRobot:
    """A point robot in a light-dark world: ``x' = A x + B u + F w``, ``z = position + noise`` with
    variance ``a (x - light_x)^2 + c`` at the TRUE position; a disc of ``radius`` among rectangles.

    Parameters
    ----------
    A, B, F : (n, n), (n, m), (n, r) the discrete dynamics and process-noise factor.
    light_x, a, c : the light-dark sensor.
    radius, lo, hi, boxes : the robot's radius, the world's bounds (2,), and the obstacles (K, 4) as
        centre x, centre y, half width, half height.
    rng : numpy Generator of this robot's noise.
    """

    def __init__(self, A, B, F, light_x, a, c, radius, lo, hi, boxes, rng):
        self.A, self.B, self.F = A, B, F
        self.light_x, self.a, self.c = light_x, a, c
        self.radius, self.lo, self.hi = radius, np.asarray(lo), np.asarray(hi)
        self.boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)  # (K, 4), K = 0 in an open world
        self.rng = rng

    def start(self, mean, covariance):
        """The true start state, drawn from the policy's start belief."""
        n = mean.size
        self.x = mean + self.rng.standard_normal((1, n)) @ np.linalg.cholesky(covariance + 1e-15 * np.eye(n)).T

    def apply(self, u):
        """Move one period under control ``u`` and measure: (z, in collision)."""
        noise = self.rng.standard_normal((1, self.F.shape[1] + 2))  # process noise, then sensor noise
        w, v = noise[:, :self.F.shape[1]], noise[:, self.F.shape[1]:]
        self.x = self.x @ self.A.T + u[None] @ self.B.T + w @ self.F.T
        p = self.x[0, :2]
        d = p[0] - self.light_x
        z = p + np.sqrt(self.a * d * d + self.c) * v[0]
        outside = np.any(p - self.radius < self.lo) or np.any(p + self.radius > self.hi)
        gap = np.maximum(np.abs(p - self.boxes[:, :2]) - self.boxes[:, 2:], 0.0)
        return z, bool(outside or np.any(np.hypot(gap[:, 0], gap[:, 1]) < self.radius))


def robot_of(solution, rng) -> PointRobot:
    """This scenario's robot (the dynamics as the roadmap discretised them, the world as written)."""
    sc, model = solution.roadmap.scenario, solution.roadmap.problem.model
    m, w = sc.measurement, sc.world
    if sc.model.robot != "point" or m.kind != "imperfect" or m.noise != "lightdark_variance":
        raise SystemExit(f"{sc.name}: this example simulates point robots with lightdark_variance sensing")
    boxes = [[*o.center, *o.half_size] for o in w.obstacles]
    return PointRobot(model.A, model.B, model.F, m.light_x, m.a, m.c, w.robot_radius, w.lo, w.hi, boxes, rng)


def show(ev: ft.Event, out) -> None:
    node = f"node {ev.node}" if ev.node >= 0 else ""
    print(f"  step {ev.step:4d}  {ev.kind:<17} {node:<9} {ev.detail}".rstrip(), file=out)


def run(solution, episodes: int, seed: int, every: int = 10, out=sys.stdout) -> list[dict]:
    """Drive the policy with the robot above; print controls (every ``every`` steps) and events."""
    policy = ft.Policy(solution)
    runs = []
    for i in range(episodes):
        seeds = ft.episode_seeds(seed, i)  # the streams ft.simulate gives episode i
        events = policy.reset(rng=np.random.default_rng(seeds.policy))
        robot = robot_of(solution, np.random.default_rng(seeds.system))
        robot.start(policy.state.mean, policy.state.covariance)
        true_start = solution.roadmap.problem.true_start
        if true_start is not None:  # the task says where the robot truly is (after the same draw as ft.simulate)
            robot.x = np.asarray(true_start, dtype=float)[None].copy()
        print(f"episode {i}", file=out)
        for ev in events:
            show(ev, out)
        outcome = None
        while not policy.done:
            u = policy.act()
            z, collided = robot.apply(u)
            if policy.state.steps % every == 0:
                print(f"  step {policy.state.steps:4d}  u = {np.array2string(u, precision=3, sign='+')}", file=out)
            if collided:
                outcome = "collision"
                events.append(ft.Event(policy.state.steps, ft.EventKind.COLLISION, policy.state.target))
                print(f"  step {policy.state.steps:4d}  collision ({policy.state.controller})", file=out)
                break
            new = policy.observe(z)
            events += new
            for ev in new:
                show(ev, out)
        if outcome is None and policy.state.status is ft.PolicyStatus.GOAL:
            # the policy declares arrival on its belief; whether the robot is there is the world's to say
            # (here the scenario's goal region, tested at the robot's true state, as ft.simulate does)
            node = policy.state.node
            inside = policy.state.arrived_in_goal(robot.x)
            outcome = "success" if inside else "goal_miss"
            if not inside:
                j = max(j for j, ev in enumerate(events) if ev.kind == ft.EventKind.GOAL)
                events[j] = ft.Event(events[j].step, ft.EventKind.GOAL_MISS, node,
                                     detail="arrival declared; the true state is not in the goal")
                print(f"  step {policy.state.steps:4d}  the robot is not in the goal", file=out)
        outcome = outcome or policy.state.status.value
        runs.append({"outcome": outcome, "steps": policy.state.steps, "cost": policy.state.cost,
                     "events": [(e.step, str(e.kind), e.node) for e in events]})
    return runs


def same_as_simulate(solution, runs: list[dict], seed: int) -> list[bool]:
    """Whether each episode is the one ``ft.simulate`` gives (outcome, steps, cost, events)."""
    res = ft.simulate(solution, len(runs), seed, record=False)
    return [r["outcome"] == str(ep.outcome) and r["steps"] == ep.steps and np.isclose(r["cost"], ep.cost, rtol=1e-9)
            and r["events"] == [(e.step, str(e.kind), e.node) for e in ep.events]
            for r, ep in zip(runs, res.episodes)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="point_lightdark", help="a shipped point-robot scenario or a file")
    ap.add_argument("--episodes", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--every", type=int, default=10, help="print the control every so many steps")
    args = ap.parse_args(argv)
    sol = ft.solve(ft.build(ft.load_scenario(args.scenario)))
    print(f"{sol!r}")
    runs = run(sol, args.episodes, args.seed, args.every)
    same = same_as_simulate(sol, runs, args.seed)
    for i, (r, ok) in enumerate(zip(runs, same)):
        print(f"episode {i}: {r['outcome']} after {r['steps']} steps, cost {r['cost']:.2f}: "
              f"{'the same as' if ok else 'DIFFERENT FROM'} ft.simulate(seed={args.seed})")
    return 0 if all(same) else 1


if __name__ == "__main__":
    sys.exit(main())
