"""How much a push shows in the measurements, and what the jump test makes of it (issue 17).

    python benchmarks/push_evidence.py --robot point --roadmaps DIR --times 0 20 70 80 90 \
        --size 1.0 --episodes 100

The sweep's pushed episodes again (replanning policy; episode ``i`` draws from ``episode_seeds(seed,
i)``, so they are the sweep's), each with a record of what its jump test saw. For a push of ``delta``
(the true displacement) at step ``t``, the evidence the filter's innovations carry of it from step
``t`` to the episode's first decision (or its end) is ``rho^2 = delta' C delta``, with
``C = sum_k G_k' S_k^-1 G_k`` the information of the push's signature ``G_k`` in the innovations, as the
test itself computes it (:class:`firmtool.online.innovation.JumpTest`) along the steps the episode
ran. Three detectors at the policy's per-step false alarm ``alpha``:

- the policy's test (unknown onset and direction, the false alarm split over its families and
  onsets: noncentral chi-square beyond ``chi2.isf(alpha / (families x window), p)``), on the evidence
  of the ``window`` steps it keeps an onset for;
- a test told the onset, not the direction (beyond ``chi2.isf(alpha, p)``), on the evidence to the
  first decision or the end;
- a test told onset and direction (the Neyman-Pearson test of that push against none: normal,
  ``Phi(rho - z_{1-alpha})``), on the same: no detector that sees only those measurements does better.

Printed per push time: episodes pushed, successes, episodes with a decision after the push, failures
without one; over the episodes without a decision that ran at least one step after the push, the
median ``rho^2`` in the policy's window and to the end, and each detector's detection probability
averaged over those episodes (what it would have found of what the policy missed); and, for the
failures without a decision, the test's statistic at the true onset within its window.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi2, ncx2, norm

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import one_blas_thread  # noqa: E402
from sweep_disturbances import ROBOTS, solution  # noqa: E402


@contextlib.contextmanager
def recording():
    """Record every jump-test step ``(step, A, H, L, S_inv, gamma)`` and every disturbance's
    displacement of the true state, for the episode running."""
    from firmtool.online import innovation
    from firmtool.sim.environment import SimulatedSystem

    steps: list = []
    moves: list = []
    add, disturb = innovation.JumpTests.add, SimulatedSystem.disturb

    def recorded_add(self, step, A, H, L, S_inv, gamma):
        steps.append((step, A.copy(), H.copy(), L.copy(), S_inv.copy(), np.array(gamma, dtype=float)))
        return add(self, step, A, H, L, S_inv, gamma)

    def recorded_disturb(self, dist, rng):
        before = self.state.copy()
        out = disturb(self, dist, rng)
        moves.append(self.state - before)
        return out

    innovation.JumpTests.add, SimulatedSystem.disturb = recorded_add, recorded_disturb
    try:
        yield steps, moves
    finally:
        innovation.JumpTests.add, SimulatedSystem.disturb = add, disturb


def evidence(steps: list, t: int, delta: np.ndarray, until: int, n: int) -> tuple[float, float, int]:
    """``rho^2 = delta' C delta`` of a push of the configuration by ``delta`` (d,) before step ``t + 1``
    (the policy's step count when it observes the pushed step), over the recorded steps from
    ``t + 1`` to ``until``, the test's statistic ``d' C^+ d`` at that onset over them, and their number.

    The policy's own :class:`~firmtool.online.innovation.JumpTest` run on those steps: its first
    onset is the push's, kept to the end (a window as long as the steps)."""
    from firmtool.online.innovation import JumpTest

    run = [s for s in steps if t + 1 <= s[0] <= until]
    if not run:
        return 0.0, 0.0, 0
    test = JumpTest(np.eye(n)[:, :delta.size], window=len(run), false_alarm=0.5)
    for step, A, H, L, S_inv, gamma in run:
        test.add(step, A, H, L, S_inv, gamma)
    C, dv = test.C[0], test.d[0]
    stat = float(dv @ np.linalg.lstsq(C, dv, rcond=None)[0])
    return float(delta @ C @ delta), stat, len(run)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robot", default="point", choices=sorted(ROBOTS), help="as benchmarks/sweep_disturbances.py")
    p.add_argument("--roadmaps", type=Path, help="DIR/<scenario>.h5, built and solved (else built here)")
    p.add_argument("--times", type=int, nargs="+", default=[0, 20, 70, 80, 90])
    p.add_argument("--size", type=float, default=1.0)
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    one_blas_thread()
    from firmtool.sim.disturbances import as_disturbances
    from firmtool.results import EventKind, Outcome
    from firmtool.sim.environment import SimulatedSystem
    from firmtool.sim.episodes import episode_seeds, run_episode
    from firmtool.sim.sweep import policies_of

    scenario = ROBOTS[args.robot][0]
    sol = solution(scenario, args.roadmaps)
    policy = policies_of(sol, modes=("replan",))["replan"]
    policy.prepare()  # the jump test's false-alarm level is resolved when prepared
    system = SimulatedSystem(policy.state.problem)
    n, d = policy.state.problem.model.n, policy.state.problem.config_dim
    families = 2 if d < n else 1  # a push (the configuration) and, when there is more, a kidnap (the state)
    window = policy.state.settings.jump_window
    alpha = policy.state.jump_false_alarm
    bound = chi2.isf(alpha / (families * window), d)
    told_onset = chi2.isf(alpha, d)
    decisions = {EventKind.INNOVATION_ALARM, EventKind.REPLAN, EventKind.KEPT_CONTROLLER, EventKind.REPLAN_FAILED}
    print(f"{scenario}: jump test at {alpha:.3g} per step, bound {bound:.1f} "
          f"({families} families x {window} onsets, p = {d}); told the onset: {told_onset:.1f}")
    print("push step | pushed | successes | decided | failed undecided | median rho^2 undecided (window / to the end) | "
          "P(detect), mean over undecided: policy's test / told onset / told onset+direction | "
          "statistic at the onset in the window, failed undecided")
    for t in args.times:
        rows = []
        for i in range(args.episodes):
            with recording() as (steps, moves):
                ep = run_episode(policy, system, episode_seeds(args.seed, i),
                                 disturbances=as_disturbances((f"push:{t}:{args.size:g}",)))
            if not moves:  # the episode ended before the push
                continue
            first = min((e.step for e in ep.events if e.kind in decisions and e.step > t), default=None)
            end = first if first is not None else ep.steps
            in_window, stat, seen = evidence(steps, t, moves[0][:d], min(end, t + window), n)
            to_end = evidence(steps, t, moves[0][:d], end, n)[0]
            rows.append((ep.outcome == Outcome.SUCCESS, first is not None, in_window, to_end, stat, seen))
        if not rows:
            print(f"{t} | 0 pushed")
            continue
        undecided = [r for r in rows if not r[1] and r[5] > 0]  # no decision, at least a step seen
        missed = [r[4] for r in undecided if not r[0]]
        line = (f"{t} | {len(rows)} | {sum(r[0] for r in rows)} | {sum(r[1] for r in rows)} | "
                f"{sum(1 for r in rows if not r[0] and not r[1])} | ")
        if undecided:
            w, e = np.array([r[2] for r in undecided]), np.array([r[3] for r in undecided])
            powers = (ncx2.sf(bound, d, w).mean(), ncx2.sf(told_onset, d, e).mean(),
                      norm.sf(norm.isf(alpha) - np.sqrt(e)).mean())
            line += (f"{np.median(w):.1f} / {np.median(e):.1f} | {powers[0]:.2f} / {powers[1]:.2f} / {powers[2]:.2f} | "
                     + (f"{min(missed):.1f}-{max(missed):.1f} (median {np.median(missed):.1f})" if missed else "-"))
        else:
            line += "- | - | -"
        print(line, flush=True)


if __name__ == "__main__":
    main()
