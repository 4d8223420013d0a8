"""A changing world: one roadmap, a door that closes, and a box that appears while the robot drives.

Builds the shipped ``point_lightdark`` roadmap into ``artifacts/changing_world.h5``, then

1. runs episodes in which a box appears across the policy's path at step 10: told to the policy
   (``Policy.update_world``, as a map update would tell a robot) or not;
2. closes the wall's left gap (x in [1.6, 2.4] at y 3) with a box and brings the roadmap to that
   world with ``ft.update``: only the edges whose particles came near the new box are estimated
   again, and the result is, bit for bit, what a fresh estimate of the updated roadmap gives.

About 30 s on 2 cores.

    python examples/changing_world.py
"""

from pathlib import Path

import firmtool as ft


def main() -> None:
    out = Path("artifacts") / "changing_world.h5"
    out.parent.mkdir(exist_ok=True)
    sc = ft.load_scenario("point_lightdark")
    ft.build(sc, output=out, workers=2, fresh=True)
    before = ft.solve(ft.open_roadmap(out))
    print(f"built: P(success) {before.success_probability:.3f}, path {before.path()}")

    # 1. a box across the path, appearing at step 10, told to the policy or not
    path = before.path()
    a, b = path[len(path) // 2 - 1], path[len(path) // 2]
    x, y = (before.roadmap.nodes[a, :2] + before.roadmap.nodes[b, :2]) / 2
    for kind in ("obstacle", "obstacle-unseen"):
        res = ft.simulate(before, episodes=100, seed=0, disturbances=[f"{kind}:10:{x:.3f},{y:.3f}:0.35,0.35"])
        print(f"a box at ({x:.2f}, {y:.2f}) from step 10, {'told' if kind == 'obstacle' else 'unseen'}: "
              f"success {res.success_rate:.2f}")

    # 2. the left gap closed: the same scenario, one more box
    door = {"center": [2.0, 3.0], "half_size": [0.4, 0.3]}
    closed = sc.replace(world={"obstacles": [o.to_table() for o in sc.world.obstacles] + [door]})
    rm = ft.update(out, closed, workers=2)
    r = rm.report
    print(f"updated: {r.kept_edges} of {r.edges} edges kept, {r.estimated_edges} estimated again, "
          f"{r.dropped_edges} dropped, {r.retired_nodes} nodes retired, in {r.seconds['total']:.1f} s")
    for why, count in sorted(r.reasons.items()):
        print(f"  not kept: {why}: {count}")
    after = ft.solve(rm)
    res = ft.simulate(after, episodes=100, seed=0)
    print(f"in the new world: P(success) {after.success_probability:.3f}, executed {res.success_rate:.2f}, "
          f"path {after.path()}")

if __name__ == "__main__":
    main()
