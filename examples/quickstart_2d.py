"""Quickstart: FIRM for a 2-D point robot in a light-dark world, with firmtool's public API.

Builds a roadmap for the shipped scenario ``point_lightdark`` (a double integrator whose position
measurements are noisy far from a light), solves the DP, runs closed-loop episodes of the policy
undisturbed and with an unseen push (the executor replans), and draws both side by side into
``artifacts/quickstart_2d.png``. About 15 s on 2 cores.

    python examples/quickstart_2d.py
"""

from pathlib import Path

import matplotlib.pyplot as plt

import firmtool as ft


def main() -> None:
    sc = ft.load_scenario("point_lightdark")  # a shipped name or a path; sc.replace(seed=1) for a variant
    rm = ft.build(sc, workers=2)  # sample, design, estimate: kept in memory (rm.save(path) writes it)
    print(f"roadmap: {len(rm.nodes)} nodes, {len(rm.edges)} edges x {rm.particles[0]} particles")

    sol = ft.solve(rm)
    lo, hi = sol.success_probability_ci95
    print(f"policy: success probability {sol.success_probability:.3f} (95% {lo:.3f}-{hi:.3f}), "
          f"nominal path {sol.path()}")

    fig, axes = plt.subplots(1, 2, figsize=(12, 6), layout="constrained")
    for ax, pushes in zip(axes, [[], ["push:40:1.5"]]):
        res = ft.simulate(sol, episodes=100, seed=0, disturbances=pushes)
        lo, hi = res.ci95
        print(f"{' '.join(pushes) or 'undisturbed':>12}: executed {res.success_rate:.3f} (95% {lo:.3f}-{hi:.3f}) "
              f"in {len(res.episodes)} episodes, {res.replans} replans")
        ft.plot(sol, res, ax=ax)
        ax.set_title(ax.get_title() + (f"\npushed 1.5 at step 40, {res.replans} replans" if pushes else ""),
                     fontsize=9)

    ep = res.episodes[0]  # every episode keeps its arrays: true states, estimates, covariances, controls
    print(f"episode 0 (pushed): {ep.outcome}, states {ep.states.shape}, covariances {ep.covariances.shape}, "
          f"events {[f'{e.kind}@{e.step}' for e in ep.events]}")

    out = Path("artifacts") / "quickstart_2d.png"
    out.parent.mkdir(exist_ok=True)
    fig.savefig(out, dpi=80)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
