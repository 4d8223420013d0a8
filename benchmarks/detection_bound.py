"""What a better detector could recover after a push: success in closed loop for detectors that know
more than the policy's (issue 17).

    python benchmarks/detection_bound.py --robot point --roadmaps DIR --times 0 20 90 100 \
        --episodes 500 --seed 1 --workers 2

benchmarks/push_evidence.py asks how often a test told the onset (and the direction) of a push would
have found it; this asks what finding it would have been worth. The sweep's pushed episodes again
(episode ``i`` draws from ``episode_seeds(seed, i)``, so every column runs the same episodes), each
run by the replanning policy in several ways:

- **policy**: as it is (the sweep's ``replan`` mode);
- **told k late**: the informed mode (:func:`firmtool.sim.sweep.informed`: the belief widened by the
  push's law, then a decision) applied ``k`` steps after the push instead of at once (``--delays``;
  1 is the sweep's ``informed``): the recovery left once a detector has needed ``k`` steps;
- **told onset and direction**: a detector told the push's onset and its displacement ``delta``,
  the Neyman-Pearson test of that push against none on the innovations since the onset,
  ``z = delta' d / sqrt(delta' C delta)`` (``d``, ``C`` as in :class:`firmtool.online.innovation.JumpTest`,
  its recursion on the filter's own gains), which fires at ``z > norm.isf(alpha)`` with ``alpha``
  the policy's per-step false alarm (no search over onsets or directions to pay for); when it fires,
  the belief is corrected by that onset's jump estimate (in full) and the policy decides
  (:meth:`~firmtool.Policy.relocalise`). The same detector with ``alpha`` split as the policy's own
  bound splits it (families x window), though it searches neither onsets nor directions.
- **told onset only**: the same detector told the onset but not the direction: the jump test's
  statistic at that onset (its likelihood ratio maximised over the push's direction and size),
  beyond ``chi2.isf(alpha, p)``, at the policy's per-step false alarm or at those of
  ``--onset-alphas`` (e.g. the rate at which the policy's test really rejects, which its bound
  over correlated onsets makes lower than nominal). Against the column above: what knowing the
  direction is worth, apart from knowing the onset.

``--columns`` picks which of these run (default: all). ``--measure-rate N`` first runs ``N``
undisturbed episodes (the same seeds): their success (the line is 0.10 under it), and how often
the policy's jump test rejects per step, none of them pushed; a told-onset column at that rate
follows.

A told detector runs until the policy's own test decides first (then the policy goes on as it is).
No detector at that false alarm that sees only the measurements finds a push sooner than the
first, so where even it stays below the undisturbed rate minus 0.10, the shortfall is not
detection's to close.

The episode loop is :func:`firmtool.sim.episodes.run_episode`'s (the same streams: the policy column
equals the sweep's ``replan``), written out here because the told detectors act between steps, a
place the library's loop keeps for nobody (the policy must not be told); the filter steps and the
push come from benchmarks/push_evidence.py's record of them.
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import sys
from collections import Counter
from pathlib import Path

import numpy as np
from scipy.stats import chi2, norm

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import one_blas_thread  # noqa: E402
from push_evidence import recording  # noqa: E402
from sweep_disturbances import ROBOTS, solution  # noqa: E402

_JOB: dict = {}  # what forked workers inherit: the policy, the system, the settings


class ToldDetector:
    """The Neyman-Pearson test of a push by ``delta`` (d,) with a known onset: a
    :class:`~firmtool.online.innovation.JumpTest` of the configuration started at the push's onset,
    fed the policy's filter steps (recorded by :func:`push_evidence.recording`). It keeps every later
    onset as well (a :class:`JumpTest` drops its oldest), of which only the first is read.
    ``direction`` False: told the onset only, the test's statistic at it beyond ``chi2.isf(alpha, d)``."""

    def __init__(self, n: int, delta: np.ndarray, alpha: float, direction: bool = True) -> None:
        from firmtool.online.innovation import JumpTest

        self.delta = delta if direction else None
        self.limit = float(norm.isf(alpha)) if direction else float(chi2.isf(alpha, delta.size))
        self.test = JumpTest(np.eye(n)[:, :delta.size], window=1 << 20, false_alarm=0.5)

    def add(self, step, A, H, L, S_inv, gamma) -> None:
        self.test.add(step, A, H, L, S_inv, gamma)

    def fires(self) -> bool:
        t = self.test
        if t.onset.size == 0:
            return False
        if self.delta is None:  # told the onset only: the likelihood ratio maximised over directions
            return float(t.statistics[0]) > self.limit
        q = float(self.delta @ t.C[0] @ self.delta)
        return q > 0 and float(self.delta @ t.d[0]) / np.sqrt(q) > self.limit


def episode(i: int, mode: tuple[str, float]) -> tuple[str, int | None]:
    """Episode ``i`` pushed at ``_JOB['step']`` in ``mode``: ``("policy", 0)``, ``("told", k)``,
    ``("detector", alpha)`` (told onset and direction) or ``("onset", alpha)`` (told the onset only);
    its outcome and the steps from the push to the told detector's action."""
    from firmtool.sim.disturbances import as_disturbances, schedule
    from firmtool.online.policy import PolicyStatus
    from firmtool.sim.episodes import episode_seeds
    from firmtool.sim.sweep import DECISIONS, informed

    policy, system, t_push, size, seed = (_JOB[k] for k in ("policy", "system", "step", "size", "seed"))
    problem = policy.state.problem
    n, d = problem.model.n, problem.config_dim
    kind, value = mode
    seeds = episode_seeds(seed, i)
    rng = np.random.default_rng(seeds.system)
    mean, covariance = policy.start_belief(None)
    system.reset(mean, covariance, rng)
    if problem.true_start is not None:
        system.set_state(problem.true_start)
    policy.reset(rng=np.random.default_rng(seeds.policy))
    key = tuple(seeds.disturbances)
    due = schedule(as_disturbances((f"push:{t_push}:{size:g}",)), policy.state.max_steps,
                   np.random.default_rng(np.random.SeedSequence([*key])))
    pushed = detector = acted = None
    fed = 0  # the recorded filter steps the told detector has taken in
    # push_evidence's record of the policy's filter steps and of the push's displacement, for the
    # told detector only
    with recording() if kind in ("detector", "onset") else contextlib.nullcontext(([], [])) as (steps, moves):
        while not policy.done:
            u = policy.act()
            now = policy.state.steps - 1
            if due and due[0][0] <= now:
                _, dist = due.pop(0)
                system.disturb(dist, np.random.default_rng(np.random.SeedSequence([*key, 1])))
                pushed = now
                if kind in ("detector", "onset"):
                    detector, fed = ToldDetector(n, moves[-1][:d], value, kind == "detector"), len(steps)
            z, valid = system.step(u)
            if not valid:
                return "collision", acted
            events = policy.observe(z)
            if detector is not None:
                for step in steps[fed:]:
                    detector.add(*step)
                fed = len(steps)
            if pushed is None or acted is not None or policy.done:
                continue
            if any(e.kind in DECISIONS for e in events):  # the policy's own test came first
                detector, acted = None, -1
            elif kind == "told" and now - pushed + 1 >= value:
                informed(size)(policy, system)
                acted = now - pushed + 1
            elif detector is not None and detector.fires():
                shift, cov, _ = detector.test.correction(0)
                policy.relocalise(policy.state.mean + shift, policy.state.covariance + cov)
                detector, acted = None, now - pushed + 1
    if policy.state.status == PolicyStatus.GOAL:
        inside = policy.state.regions.true_arrival(np.array([policy.state.node]), system.state,
                                             angles=problem.robot.angle_coordinates)[0]
        return ("success" if inside else "goal_miss"), acted
    return str(policy.state.status), acted


def _undisturbed(task: tuple[int, int]) -> tuple[int, int, int]:
    """Undisturbed episodes ``i0..i1``: the jump test's filter steps, its rejections (each a false
    alarm, none of them pushed) and the successes."""
    from firmtool.online import innovation
    from firmtool.results import Outcome
    from firmtool.sim.episodes import episode_seeds, run_episode

    i0, i1 = task
    tested = rejected = successes = 0
    add = innovation.JumpTests.add

    def counted(self, *step):
        nonlocal tested, rejected
        rejects = add(self, *step)
        tested, rejected = tested + 1, rejected + bool(rejects)
        return rejects

    innovation.JumpTests.add = counted
    try:
        for i in range(i0, i1):
            ep = run_episode(_JOB["policy"], _JOB["system"], episode_seeds(_JOB["seed"], i))
            successes += ep.outcome == Outcome.SUCCESS
    finally:
        innovation.JumpTests.add = add
    return tested, rejected, successes


def _map(fn, tasks: list, workers: int) -> list:
    if workers > 1:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            return pool.map(fn, tasks, chunksize=1)
    return [fn(task) for task in tasks]


def _chunk(task: tuple[int, int, tuple[str, float]]) -> list[tuple[str, int | None]]:
    i0, i1, mode = task
    return [episode(i, mode) for i in range(i0, i1)]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robot", default="point", choices=sorted(ROBOTS), help="as benchmarks/sweep_disturbances.py")
    p.add_argument("--roadmaps", type=Path, help="DIR/<scenario>.h5, built and solved (else built here)")
    p.add_argument("--times", type=int, nargs="+", default=[20, 90])
    p.add_argument("--size", type=float, default=1.0)
    p.add_argument("--delays", type=int, nargs="+", default=[1, 3, 5])
    p.add_argument("--columns", nargs="+", default=["policy", "late", "direction", "onset"],
                   choices=["policy", "late", "direction", "onset"])
    p.add_argument("--onset-alphas", type=float, nargs="+",
                   help="false alarms of the detector told the onset only (default: the policy's)")
    p.add_argument("--measure-rate", type=int, default=0, metavar="EPISODES",
                   help="measure the jump test's per-step rejection rate on that many undisturbed episodes "
                        "(the same seeds) and add a told-onset column at it")
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=1)
    args = p.parse_args()
    one_blas_thread()
    from firmtool.sim.environment import SimulatedSystem
    from firmtool.sim.sweep import policies_of

    sol = solution(ROBOTS[args.robot][0], args.roadmaps)
    policy = policies_of(sol, modes=("replan",))["replan"]
    policy.prepare()  # the jump test's false-alarm level is resolved when prepared
    n, d = policy.state.problem.model.n, policy.state.problem.config_dim
    families = 2 if d < n else 1
    alpha = policy.state.jump_false_alarm
    split = alpha / (families * policy.state.settings.jump_window)
    columns = {"policy": [(("policy", 0), "policy")],
               "late": [(("told", k), f"told {k} late") for k in args.delays],
               "direction": [(("detector", alpha), f"told onset+direction, {alpha:.2g}"),
                             (("detector", split), f"the same at {split:.2g} (the policy's split)")],
               "onset": [(("onset", a), f"told onset only, {a:.2g}") for a in (args.onset_alphas or [alpha])]}
    _JOB.update(policy=policy, system=SimulatedSystem(policy.state.problem), size=args.size, seed=args.seed)
    if args.measure_rate:  # the rate the test really rejects at: a told-onset column at it
        counts = np.sum(_map(_undisturbed, [(i0, min(args.measure_rate, i0 + 25))
                                            for i0 in range(0, args.measure_rate, 25)], args.workers), axis=0)
        tested, rejected, successes = (int(c) for c in counts)
        rate = max(rejected, 1) / tested  # none rejected: a column at one in that many steps, not at 0
        print(f"undisturbed, {args.measure_rate} episodes: success {successes / args.measure_rate:.3f}; the jump "
              f"test rejected at {rejected} of {tested} steps, {rejected / tested:.2g} per step against its "
              f"nominal {alpha:.2g}")
        columns["onset"].append((("onset", rate), f"told onset only, {rate:.2g} (the measured rate)"))
    chosen = [c for name in args.columns for c in columns[name]]
    modes, names = [m for m, _ in chosen], [name for _, name in chosen]
    print(f"{ROBOTS[args.robot][0]}: pushes of {args.size:g}, {args.episodes} episodes a time, seed {args.seed}; "
          f"the policy's jump test at {alpha:.3g} per step")
    print("push step | " + " | ".join(names) + "  (success rate; a told detector: rate, acted first / median steps)")
    for t in args.times:
        _JOB["step"] = t
        chunk = 25
        tasks = [(i0, min(args.episodes, i0 + chunk), m) for m in modes for i0 in range(0, args.episodes, chunk)]
        results = _map(_chunk, tasks, args.workers)
        per_mode: dict = {}
        for (_, _, m), rows in zip(tasks, results):
            per_mode.setdefault(m, []).extend(rows)
        cells = []
        for m in modes:
            rows = per_mode[m]
            rate = Counter(o for o, _ in rows)["success"] / len(rows)
            acted = [a for _, a in rows if a is not None and a > 0]
            cells.append(f"{rate:.3f}" if m[0] not in ("detector", "onset") else
                         f"{rate:.3f}, {len(acted)} / {np.median(acted) if acted else float('nan'):g}")
        print(f"{t} | " + " | ".join(cells), flush=True)


if __name__ == "__main__":
    main()
