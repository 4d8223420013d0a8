"""Collision backends timing: an 8-link planar arm against 6 rectangles, with self-collision.

    PYTHONPATH=. python benchmarks/bench_collision.py [--M 1000] [--repeat 5]

Two ensembles of M configurations:
* ``random``: joint angles uniform in [-pi, pi) (most collide; early exit helps);
* ``free``: only collision-free configurations (worst case: every stage runs on every configuration).
Prints microseconds per configuration (best of ``repeat``) for numpy (with/without AABB prefilter),
numba (compiled before timing) and fcl.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from firmtool.geometry import make_backend
from firmtool.models.planar_arm import link_segments

LINKS = np.full(8, 0.45)
CENTERS = np.array([[2.0, 1.5], [-2.0, 2.0], [1.5, -2.0], [-2.5, -1.5], [3.2, -0.2], [0.0, 3.3]])
HALF = np.array([[0.4, 0.3], [0.5, 0.4], [0.3, 0.6], [0.4, 0.4], [0.3, 0.5], [0.6, 0.2]])
LO, HI = np.array([-4.0, -4.0]), np.array([4.0, 4.0])
RADIUS = 0.05


def ensembles(M: int, seed: int = 0) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    ref = make_backend("numpy", CENTERS, HALF, LO, HI, self_collision=True)
    rand = link_segments(rng.uniform(-np.pi, np.pi, (M, LINKS.size)), LINKS)
    free_S, free_E = [], []
    n = 0
    while n < M:
        th = rng.uniform(-np.pi, np.pi, (20 * M, LINKS.size)) * 0.35
        S, E = link_segments(th, LINKS)
        ok = ~ref.capsules_collide(S, E, RADIUS)
        free_S.append(S[ok]), free_E.append(E[ok])
        n += int(ok.sum())
    return {"random": rand, "free": (np.concatenate(free_S)[:M], np.concatenate(free_E)[:M])}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--M", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    backends = {
        "numpy": make_backend("numpy", CENTERS, HALF, LO, HI, self_collision=True),
        "numpy (no prefilter)": make_backend("numpy", CENTERS, HALF, LO, HI, self_collision=True, prefilter=False),
        "numba": make_backend("numba", CENTERS, HALF, LO, HI, self_collision=True),
        "fcl": make_backend("fcl", CENTERS, HALF, LO, HI, self_collision=True),
    }
    for name, (S, E) in ensembles(args.M).items():
        ref = backends["numpy"].capsules_collide(S, E, RADIUS)
        print(f"ensemble {name}: M={args.M}, colliding fraction {ref.mean():.2f}")
        for bname, b in backends.items():
            b.capsules_collide(S[:2], E[:2], RADIUS)  # warm-up / compile
            reps = 1 if bname == "fcl" else args.repeat
            best = np.inf
            for _ in range(reps):
                t = time.perf_counter()
                res = b.capsules_collide(S, E, RADIUS)
                best = min(best, time.perf_counter() - t)
            agree = int((res == ref).sum())
            print(f"  {bname:22s} {1e6 * best / args.M:9.2f} us/config   (agrees with numpy on {agree}/{args.M})")


if __name__ == "__main__":
    main()
